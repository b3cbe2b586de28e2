"""A QUASAR server frame stage by stage against the ground-truth render in the same process (issue 49, item 3).

Each cell (scene, camera, 320x180) runs in its own process: after two warm-up frames, ``--frames`` server frames,
each followed by the ground truth of the same frame by a renderer of its own (``gt``, as ``bench_quads_server``'s
``gt_own``).  The server's stages are timed by wrapping the functions it calls (CPU seconds of the process,
``time.process_time``, llvmpipe's threads included), the median over the frames:

- ``render``: its G-buffer renders (the visible view; the reference view at this time for the residual-error test
  and the update; the peeled hidden layer; the wide view), colour, depth and normals read back (a hidden layer's
  colour, shaded after its parallax test where it is sent, included);
- ``generate``: quad generation and merging of every set (reference or update and revealed, hidden layer, wide
  view);
- ``residual_test``: the residual-error test (the cached mesh drawn from the frame's pose; its estimate in the last
  colour sent, which may decide alone: ``estimated`` counts those frames), and inside it
  ``rt_extend`` (the underlap's sides), ``rt_mesh`` (``build_mesh``), ``rt_sides`` (``scene_sides``) and ``rt_draw``;
- ``edp``: the parallax test of the hidden layer; ``mask_mesh``: a residual frame's coverage mask (the cached mesh's
  depth); ``encode``: the wire sets; ``accounting``: QUASAR's own byte count;
- ``rest``: the server frame less the stages above.

``--before-tree DIR`` (``git worktree add --detach DIR REV``) runs each cell alternately in that tree and this one,
``--rounds`` times, each side's median-of-frames from its best (lowest server/GT) run.

Writes ``benchmarks/results/bench_quads_stages.json`` (``--out``).
Run: ``python benchmarks/bench_quads_stages.py [--before-tree DIR] [--frames N] [--rounds R]``.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from _trees import run_cell  # noqa: E402

OUT = Path(__file__).parent / "results" / "bench_quads_stages.json"
DUCK = "/usr/share/assimp/models/Collada/duck.dae"
CELLS = [("default", "default", "walk"), ("default_nogi", "default+nogi", "walk"), ("duck", f"{DUCK}+ground", "orbit")]
SIZE = (320, 180)
TOP = ("render", "generate", "residual_test", "edp", "mask_mesh", "encode", "accounting")


def time_cell(scene_name: str, trace: str, frames: int) -> dict[str, object]:
    import splitrender
    import splitrender.methods.quads.mesh as mesh_mod
    import splitrender.methods.quads.server as srv_mod
    from splitrender.methods import get_method, make_config
    from splitrender.pipeline.direct import server_context
    from splitrender.render.renderer import Renderer
    from splitrender.scene.loader import get_scene
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.trace import get_trace

    cpu = time.process_time
    acc: collections.Counter[str] = collections.Counter()
    depth = [0]

    def wrap(obj: object, name: str, label: str) -> None:
        f = getattr(obj, name)

        def timed(*a: object, **k: object) -> object:
            t0 = cpu()
            try:
                return f(*a, **k)
            finally:
                acc[label] += (cpu() - t0) * 1e3

        setattr(obj, name, timed)

    wrap(srv_mod, "generate", "generate")
    wrap(srv_mod, "edp_keep", "edp")
    wrap(srv_mod.QuadsServer, "_gbuffer", "render")
    if hasattr(srv_mod.QuadsServer, "_colour"):      # a hidden layer's colour, shaded after its parallax test
        wrap(srv_mod.QuadsServer, "_colour", "render")
    wrap(srv_mod.QuadsServer, "_residual_psnr", "residual_test")
    wrap(srv_mod.QuadsServer, "_mesh_depth", "mask_mesh")
    wrap(srv_mod, "encode_sets", "encode")
    wrap(srv_mod, "quasar_frame_bytes", "accounting")
    wrap(srv_mod, "reference_extend", "rt_extend")
    wrap(srv_mod, "scene_sides", "rt_sides")
    wrap(mesh_mod.QuadMeshGL, "draw", "rt_draw")
    # build_mesh inside the residual test only (the mask mesh calls it too)
    build = srv_mod.build_mesh

    def build_timed(*a: object, **k: object) -> object:
        t0 = cpu()
        try:
            return build(*a, **k)
        finally:
            if depth[0]:
                acc["rt_mesh"] += (cpu() - t0) * 1e3

    srv_mod.build_mesh = build_timed
    # the test's mesh and its estimate (methods of their own since the estimate may decide alone) count in it too
    marked = ["_residual_psnr"] + [m for m in ("_upload_cached", "_estimate") if hasattr(srv_mod.QuadsServer, m)]
    for m in marked[1:]:
        wrap(srv_mod.QuadsServer, m, "residual_test")
    for m in marked:
        def mark(f: object) -> object:
            def rp_marked(*a: object, **k: object) -> object:
                depth[0] += 1
                try:
                    return f(*a, **k)  # type: ignore[operator]
                finally:
                    depth[0] -= 1
            return rp_marked

        setattr(srv_mod.QuadsServer, m, mark(getattr(srv_mod.QuadsServer, m)))
    intr = CameraIntrinsics(*SIZE)
    r, r_gt = Renderer(), Renderer()
    scene = get_scene(scene_name)
    tr = get_trace(trace, scene=scene, aspect=SIZE[0] / SIZE[1])
    spec = get_method("quads")
    cfg = make_config(spec.config, {})
    srv = spec.server_class(cfg, intr, scene, 30, None)
    rows: list[dict[str, float]] = []
    for f in range(frames + 2):
        t = 0.5 + f / 30
        pose = tr.pose_at(t)
        ctx = server_context(scene, r, intr, pose, t_s=t, frame_id=f)
        acc.clear()
        c0 = cpu()
        srv.produce(ctx)
        c1 = cpu()
        r_gt.render(scene, t, pose, intr)
        c2 = cpu()
        if f >= 2:
            row = {k: float(acc.get(k, 0.0)) for k in (*TOP, "rt_extend", "rt_mesh", "rt_sides", "rt_draw")}
            row["server"], row["gt"] = (c1 - c0) * 1e3, (c2 - c1) * 1e3
            row["rest"] = row["server"] - sum(row[k] for k in TOP)
            row["reference"] = srv.stats()["reference"]
            row["estimated"] = srv.stats().get("residual_psnr_estimate", 0.0)
            rows.append(row)
    med = {k: statistics.median(x[k] for x in rows) for k in rows[0]}
    return {"tree": str(Path(splitrender.__file__).resolve().parents[1]), "median_ms": med,
            "server_over_gt": med["server"] / med["gt"], "render_over_gt": med["render"] / med["gt"],
            "rest_of_server_over_gt": (med["server"] - med["render"]) / med["gt"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--before-tree", default=None)
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--cell", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.cell:
        c = json.loads(args.cell)
        print(json.dumps(time_cell(c["scene"], c["trace"], c["frames"])))
        return
    if args.frames < 1 or args.rounds < 1:
        raise SystemExit(f"--frames and --rounds must be at least 1, got {args.frames} and {args.rounds}")
    here = str(Path(__file__).resolve().parents[1])
    sides = {"before": args.before_tree, "after": here} if args.before_tree else {"after": here}
    out: dict[str, object] = {"machine": platform.platform(), "size": list(SIZE), "frames": args.frames,
                              "rounds": args.rounds, "trees": sides, "load_before": os.getloadavg()[0], "cells": {}}
    for label, scene, trace in CELLS:
        if scene.startswith(DUCK) and not os.path.exists(DUCK):
            continue
        name = f"{label}_{trace}"
        runs: dict[str, list[dict[str, object]]] = {s: [] for s in sides}
        for _ in range(args.rounds):
            for side, tree in sides.items():
                arg = {"scene": scene, "trace": trace, "frames": args.frames}
                runs[side].append(run_cell(tree, __file__, arg, name))
        cell = {side: {**min(rs, key=lambda x: float(x["server_over_gt"])),  # type: ignore[arg-type]
                       "runs_server_over_gt": [x["server_over_gt"] for x in rs]} for side, rs in runs.items()}
        out["cells"][name] = cell  # type: ignore[index]
        for side, c in cell.items():
            m = c["median_ms"]
            print(f"{name} {side}: server/GT {c['server_over_gt']:.2f} (renders {c['render_over_gt']:.2f}, the rest "
                  f"{c['rest_of_server_over_gt']:.2f}); ms: " + ", ".join(f"{k} {v:.1f}" for k, v in m.items()),
                  flush=True)
        out["load_after"] = os.getloadavg()[0]
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
