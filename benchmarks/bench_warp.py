"""Client cost of ``warp``: ms per displayed frame for point, quad and mesh reconstruction
at 640x360 and 1280x720, against the ground-truth render time of the same scene and pose
in the same run (the ratio is what matters on software GL).  Writes
``benchmarks/results/bench_warp.json``.

Run: ``python benchmarks/bench_warp.py [--frames N] [--sizes 640x360,1280x720]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from splitrender.codecs.meta import pack_meta, unpack_meta
from splitrender.methods.base import DecodedUpdate
from splitrender.methods.warp import WarpClient, WarpConfig, WarpServer
from splitrender.pipeline.direct import server_context
from splitrender.render import Renderer
from splitrender.scene.pose import CameraIntrinsics, Pose
from splitrender.scene.procedural import default_scene

OUT = Path(__file__).parent / "results" / "bench_warp.json"


def bench(size: tuple[int, int], frames: int, renderer: Renderer) -> dict[str, object]:
    w, h = size
    intr = CameraIntrinsics(w, h, 60.0)
    scene = default_scene()
    start = Pose(np.array([0.0, 1.6, 2.5]))
    poses = [Pose(start.position + np.array([0.01 * k, 0.0, -0.01 * k]), start.orientation) for k in range(frames)]
    gt_ms = []
    for p in poses:
        t = time.perf_counter()
        renderer.render(scene, 0.0, p, intr, ("color",))
        gt_ms.append((time.perf_counter() - t) * 1e3)
    out: dict[str, object] = {"size": f"{w}x{h}", "gt_ms": statistics.median(gt_ms)}
    for rec in ("points", "quads", "mesh"):
        cfg = WarpConfig(reconstruction=rec)
        srv = WarpServer(cfg, intr, scene, 30)
        ctx = server_context(scene, renderer, intr, start)
        u = srv.produce(ctx)
        cli = WarpClient(cfg, intr, renderer.ctx, {})
        cli.apply(DecodedUpdate(0, 0.0, u.pose, u.planes, unpack_meta(pack_meta(u.meta))))
        cli.render(poses[0], 0.0)  # warm up (shader compile)
        ms = []
        for p in poses:
            t = time.perf_counter()
            cli.render(p, 0.0)
            ms.append((time.perf_counter() - t) * 1e3)
        med = statistics.median(ms)
        out[rec] = {"client_ms": med, "ratio_to_gt": med / out["gt_ms"], "ref_size": f"{srv.ref_intr.width}x{srv.ref_intr.height}"}  # type: ignore[operator]
        print(f"{w}x{h} {rec:6s} client {med:7.1f} ms  gt {out['gt_ms']:6.1f} ms  ratio {med / out['gt_ms']:.2f}")  # type: ignore[operator]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--sizes", default="640x360,1280x720")
    a = ap.parse_args()
    renderer = Renderer()
    sizes = [tuple(int(v) for v in s.split("x")) for s in a.sizes.split(",")]
    res = {"machine": platform.machine(), "gl_renderer": renderer.ctx.info.get("GL_RENDERER"), "frames": a.frames,
           "note": "median wall-clock ms per displayed frame incl. readback; fov_scale 1.3 reference, one view",
           "results": [bench(s, a.frames, renderer) for s in sizes]}  # type: ignore[arg-type]
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(res, indent=2))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
