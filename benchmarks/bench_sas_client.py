"""Display cost of ``sas``'s client on this machine (llvmpipe): the Catmull-Rom atlas lookup against one bilinear tap.

A server half and a client half of the default scene (without GI, as :mod:`bench_sas_server`) exchange a few
frames of the ``walk`` trace at zero latency with a lossless atlas; then :meth:`SasClient.render` (one draw of the
PVS, the atlas lookup per pixel, the read-back of the frame) is timed at the last pose, fastest of N, with each
lookup, against the ground-truth forward render of the same pose (and the frame's PSNR against it, so speed
and accuracy are read together).  The issue's concern: a thin client should stay
thin, so the figure to quote is the bicubic / bilinear ratio (and each over the ground truth).

Writes ``benchmarks/results/bench_sas_client.json``.  Run:
``python benchmarks/bench_sas_client.py [--frames N] [--size 640x360]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from splitrender.codecs.meta import pack_meta, unpack_meta  # noqa: E402
from splitrender.methods.base import DecodedUpdate  # noqa: E402
from splitrender.methods.sas import SasClient, SasConfig, SasServer  # noqa: E402
from splitrender.metrics.image import psnr  # noqa: E402
from splitrender.pipeline.direct import server_context  # noqa: E402
from splitrender.render.renderer import Renderer  # noqa: E402
from splitrender.scene.loader import get_scene  # noqa: E402
from splitrender.scene.pose import CameraIntrinsics  # noqa: E402
from splitrender.scene.trace import get_trace  # noqa: E402

OUT = Path(__file__).parent / "results" / "bench_sas_client.json"
SCENE = "default+nogi"


def fastest_ms(fn, n: int) -> float:  # type: ignore[no-untyped-def]
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    return float(np.min(ts))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20, help="timed renders per lookup (fastest counts)")
    ap.add_argument("--size", default="640x360")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    intr = CameraIntrinsics(w, h)
    r = Renderer()
    scene = get_scene(SCENE)
    trace = get_trace("walk")
    res: dict[str, dict[str, float]] = {}
    for lookup in ("bilinear", "bicubic"):
        cfg = SasConfig(lossless=True, atlas_filter=lookup)  # type: ignore[arg-type]
        srv = SasServer(cfg, intr, scene, 30)
        cli = SasClient(cfg, intr, r.ctx, unpack_meta(pack_meta(srv.session_data())))
        t = 1.0
        for f in range(3):
            t = 1.0 + f / 30
            pose = trace.pose_at(t)
            u = srv.produce(server_context(scene, r, intr, pose, t_s=t, frame_id=f, predict=trace.pose_at))
            cli.apply(DecodedUpdate(u.frame_id, t, pose, dict(u.planes), unpack_meta(pack_meta(u.meta))))
        pose = trace.pose_at(t)
        cli.render(pose, t)      # warm-up: vertex buffer, shader compilation
        shown = cli.render(pose, t)
        truth = r.render(scene, t, pose, intr, ("color",)).color
        res[lookup] = {"client_ms": fastest_ms(lambda: cli.render(pose, t), args.frames),
                       "ground_truth_ms": fastest_ms(lambda: r.render(scene, t, pose, intr, ("color",)), max(3, args.frames // 2)),
                       "triangles": float(shown.stats["cli_triangles"]), "psnr_db": psnr(shown.color, truth)}
    ratios = {"bicubic_over_bilinear": res["bicubic"]["client_ms"] / res["bilinear"]["client_ms"],
              "bicubic_over_ground_truth": res["bicubic"]["client_ms"] / res["bicubic"]["ground_truth_ms"],
              "bilinear_over_ground_truth": res["bilinear"]["client_ms"] / res["bilinear"]["ground_truth_ms"]}
    out = {"machine": platform.platform(), "gl_renderer": r.ctx.info.get("GL_RENDERER"), "resolution": [w, h],
           "frames": args.frames, "scene": SCENE, "ratios": ratios, "runs": res}
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps({"ratios": ratios, "runs": res}, indent=1))


if __name__ == "__main__":
    main()
