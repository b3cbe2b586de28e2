"""``quads`` (QUASAR, the default variant, and QuadStream) server and client cost against the ground-truth render (issue 49, item 3).

Each cell (scene, camera, 320x180) runs in its own process: after two warm-up frames, ``--frames`` server frames,
each followed in the same process by

- the ground truth of the same frame by a renderer of its own (``gt_own``: it relights the scene's GI probes and
  draws its shadow map for the frame itself, as a forward renderer on its own does every frame);
- the ground truth by the server's renderer right after the server frame (``gt_shared``: the GI probes and shadow
  map the server's first G-buffer drew for this time are reused, so this is the render alone; ``bench_quads``
  measures this way);
- the client taking the update (``apply``: cache, mesh, atlas upload) and drawing one display frame half a
  server frame later (``draw``: the layered mesh and hole filling), whose PSNR against the ground truth at that
  pose and time (rendered outside the timings) is kept (``client_psnr_db``, the mean over the frames).

Times are CPU seconds of the process (``time.process_time``: llvmpipe's threads included; the machine is shared,
so wall time mostly measures the other jobs), the median over the frames.  Ratios: server/GT and client/GT,
the client as ``draw`` (what it spends per display frame) and ``draw + apply`` (per server frame); the
headline ratios divide by ``gt_own``.  Every cell hashes the updates (atlas, quads, offsets) and the client's
frames, so ``identical`` says whether two trees made the same bytes (then quality and bits are unchanged).

``--before-tree DIR`` (``git worktree add --detach DIR REV``) runs each cell alternately in that tree and this one,
``--rounds`` times, each side's best (lowest server/GT) run kept with every run's ratios.

Cells whose label starts ``qs_`` run QuadStream, the others QUASAR.  ``--size WxH`` sets the display (320x180 by
default).

Writes ``benchmarks/results/bench_quads_server.json`` (``--out``).
Run: ``python benchmarks/bench_quads_server.py [--before-tree DIR] [--frames N] [--rounds R] [--size WxH]``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from _trees import run_cell  # noqa: E402

OUT = Path(__file__).parent / "results" / "bench_quads_server.json"
DUCK = "/usr/share/assimp/models/Collada/duck.dae"
CELLS = [("default", "default", "walk"), ("default", "default", "static"), ("default_nogi", "default+nogi", "walk"),
         ("duck", f"{DUCK}+ground", "orbit"), ("duck", f"{DUCK}+ground", "static"),
         ("qs_default", "default", "walk"), ("qs_default_nogi", "default+nogi", "walk")]
"""(label, scene, trace); the default scene also without its GI (then a ground truth relights nothing: the harder
comparison for the server); the duck as ``bench_quads_models`` loads it (with a ground), skipped when absent.
Labels starting ``qs_`` run QuadStream (``variant = "quadstream"``), the others QUASAR (the default)."""
SIZE = (320, 180)


def time_cell(scene_name: str, trace: str, frames: int, variant: str = "quasar",
              size: tuple[int, int] = SIZE) -> dict[str, object]:
    import numpy as np

    import splitrender
    from splitrender.methods import DecodedUpdate, get_method, make_config
    from splitrender.metrics.image import psnr
    from splitrender.pipeline.direct import server_context
    from splitrender.render.renderer import Renderer
    from splitrender.scene.loader import get_scene
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.trace import get_trace

    intr = CameraIntrinsics(*size)
    r, r_gt = Renderer(), Renderer()
    scene = get_scene(scene_name)
    tr = get_trace(trace, scene=scene, aspect=size[0] / size[1])
    spec = get_method("quads")
    cfg = make_config(spec.config, {"variant": variant})
    srv = spec.server_class(cfg, intr, scene, 30, None)
    cli = None
    cpu = time.process_time
    rows: list[dict[str, float]] = []
    dig_u, dig_c = hashlib.sha256(), hashlib.sha256()
    for f in range(frames + 2):
        t = 0.5 + f / 30
        pose = tr.pose_at(t)
        ctx = server_context(scene, r, intr, pose, t_s=t, frame_id=f)
        c0 = cpu()
        u = srv.produce(ctx)
        c1 = cpu()
        r.render(scene, t, pose, intr)
        c2 = cpu()
        r_gt.render(scene, t, pose, intr)
        c3 = cpu()
        if cli is None:
            cli = spec.client_class(cfg, intr, r.ctx, srv.session_data())
        c4 = cpu()
        cli.apply(DecodedUpdate(u.frame_id, u.t_s, u.pose, u.planes, u.meta, dict(u.data)))
        c5 = cpu()
        shown = cli.render(tr.pose_at(t + 0.5 / 30), t + 0.5 / 30)
        c6 = cpu()
        truth = r_gt.render(scene, t + 0.5 / 30, tr.pose_at(t + 0.5 / 30), intr).color
        dig_u.update(np.ascontiguousarray(u.planes["atlas"]).tobytes())
        dig_u.update(u.data["quads"])
        dig_u.update(u.data["offsets"])
        dig_c.update(np.ascontiguousarray(shown.color).tobytes())
        if f >= 2:
            st = srv.stats()
            rows.append({"server_ms": (c1 - c0) * 1e3, "gt_shared_ms": (c2 - c1) * 1e3, "gt_own_ms": (c3 - c2) * 1e3,
                         "apply_ms": (c5 - c4) * 1e3, "draw_ms": (c6 - c5) * 1e3, "reference": st["reference"],
                         "quads": st["quads"], "client_psnr_db": psnr(shown.color, truth)})
    med = {k: statistics.median(x[k] for x in rows) for k in rows[0] if k != "client_psnr_db"}
    gt = med["gt_own_ms"]
    return {"tree": str(Path(splitrender.__file__).resolve().parents[1]), "median": med,
            "server_over_gt": med["server_ms"] / gt, "server_over_gt_shared": med["server_ms"] / med["gt_shared_ms"],
            "draw_over_gt": med["draw_ms"] / gt, "client_over_gt": (med["draw_ms"] + med["apply_ms"]) / gt,
            "draw_over_gt_shared": med["draw_ms"] / med["gt_shared_ms"],
            "client_over_gt_shared": (med["draw_ms"] + med["apply_ms"]) / med["gt_shared_ms"],
            "client_psnr_db": statistics.fmean(x["client_psnr_db"] for x in rows), "update_digest": dig_u.hexdigest(), "client_digest": dig_c.hexdigest(), "frames": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--before-tree", default=None)
    ap.add_argument("--cells", default="", help="only these cells (e.g. default_walk)")
    ap.add_argument("--size", default="320x180", help="display size WxH (default 320x180)")
    ap.add_argument("--out", default=str(OUT), help="results JSON (default benchmarks/results/bench_quads_server.json)")
    ap.add_argument("--cell", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.cell:
        c = json.loads(args.cell)
        print(json.dumps(time_cell(c["scene"], c["trace"], c["frames"], c["variant"], tuple(c["size"]))))
        return
    here = str(Path(__file__).resolve().parents[1])
    sides = {"before": args.before_tree, "after": here} if args.before_tree else {"after": here}
    only = set(filter(None, args.cells.split(",")))
    size = tuple(int(v) for v in args.size.lower().split("x"))
    if len(size) != 2 or min(size) < 16:
        raise SystemExit(f"--size must be WxH with both at least 16, got {args.size!r}")
    out_path = Path(args.out)
    out: dict[str, object] = {"machine": platform.platform(), "size": list(size), "frames": args.frames,
                              "rounds": args.rounds, "trees": sides, "targets": {"server_over_gt": 3.0,
                                                                                  "draw_over_gt": 0.3},
                              "load_before": os.getloadavg()[0], "cells": {}}
    for label, scene, trace in CELLS:
        name = f"{label}_{trace}"
        if (scene.startswith(DUCK) and not os.path.exists(DUCK)) or (only and name not in only):
            continue
        runs: dict[str, list[dict[str, object]]] = {s: [] for s in sides}
        for _ in range(args.rounds):
            for side, tree in sides.items():
                arg = {"scene": scene, "trace": trace, "frames": args.frames, "size": size,
                       "variant": "quadstream" if label.startswith("qs_") else "quasar"}
                runs[side].append(run_cell(tree, __file__, arg, name))
        cell: dict[str, object] = {}
        for side, rs in runs.items():
            best = min(rs, key=lambda x: float(x["server_over_gt"]))  # type: ignore[arg-type]
            cell[side] = {**best, "runs": {k: [x[k] for x in rs] for k in ("server_over_gt", "server_over_gt_shared",
                                                                            "draw_over_gt", "client_over_gt")}}
        cell["identical_updates"] = len({x["update_digest"] for rs in runs.values() for x in rs}) == 1
        cell["identical_client_frames"] = len({x["client_digest"] for rs in runs.values() for x in rs}) == 1
        out["cells"][name] = cell  # type: ignore[index]
        msg = "; ".join(f"{s}: server/GT {c['server_over_gt']:.2f} (shared GT {c['server_over_gt_shared']:.2f}), "  # type: ignore[index]
                        f"draw/GT {c['draw_over_gt']:.2f}, draw+apply/GT {c['client_over_gt']:.2f}"  # type: ignore[index]
                        for s, c in cell.items() if isinstance(c, dict))
        print(f"{name}: {msg}; identical updates {cell['identical_updates']}, client frames "
              f"{cell['identical_client_frames']}; client PSNR "
              + " -> ".join(f"{c['client_psnr_db']:.3f}" for c in cell.values() if isinstance(c, dict)), flush=True)
        out["load_after"] = os.getloadavg()[0]
        out_path.parent.mkdir(parents=True, exist_ok=True)
        out_path.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {out_path}")


if __name__ == "__main__":
    main()
