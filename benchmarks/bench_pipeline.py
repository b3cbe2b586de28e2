"""Pipeline costs: ground-truth render, encode, decode and each method's client render.

Measured at 640x360 and 1280x720 on the default scene, walking trace, ideal network.
Absolute milliseconds depend on this machine (llvmpipe on CPU cores here); the figures
to quote are the ratios to the ground-truth render measured in the same run:
``client_over_gt`` (how much cheaper than rendering the scene locally a method's client
is) and ``server_over_gt``.

Usage: ``python benchmarks/bench_pipeline.py [--sizes 640x360,1280x720] [--frames 30]
[--methods video,atw,...]``; writes ``benchmarks/results/bench_pipeline.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from splitrender.codecs.video import VideoDecoder, VideoEncoder  # noqa: E402
from splitrender.methods import available_methods  # noqa: E402
from splitrender.render import Renderer  # noqa: E402
from splitrender.scene import CameraIntrinsics, default_scene  # noqa: E402
from splitrender.scene.trace import get_trace  # noqa: E402
from splitrender.sim import RunConfig, run  # noqa: E402


def _median_ms(fn, n: int) -> float:  # type: ignore[no-untyped-def]
    fn(0)
    ts = []
    for i in range(n):
        t = time.perf_counter()
        fn(i)
        ts.append((time.perf_counter() - t) * 1000)
    return statistics.median(ts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="640x360,1280x720")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--methods", default=None)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_pipeline.json")
    ns = ap.parse_args()
    methods = ns.methods.split(",") if ns.methods else available_methods()
    renderer = Renderer()
    scene = default_scene()
    trace = get_trace("walk")
    results: dict = {"machine": platform.platform(), "gl_renderer": renderer.ctx.info.get("GL_RENDERER"), "sizes": {}}
    for size in ns.sizes.split(","):
        w, h = (int(v) for v in size.split("x"))
        intr = CameraIntrinsics(w, h, 60.0)
        poses = [trace.pose_at(i / 30) for i in range(ns.frames + 1)]

        def gt(i: int) -> None:
            renderer.render(scene, i / 30, poses[i], intr, ("color",))
            renderer.ctx.finish()

        gt_ms = _median_ms(gt, ns.frames)
        frames = [renderer.render(scene, i / 30, poses[i], intr, ("color",)).color for i in range(ns.frames + 1)]
        from splitrender.codecs.video import VideoCodecConfig

        codec_rows = {}
        for codec in ("h264", "hevc"):
            enc = VideoEncoder(VideoCodecConfig(codec=codec, crf=23, gop=30), w, h)
            packets: list[bytes] = []

            def encode(i: int) -> None:
                packets.append(enc.encode(frames[i % len(frames)]).data)

            enc_ms = _median_ms(encode, ns.frames)
            dec = VideoDecoder(codec)
            decode_ms = _median_ms(lambda i: dec.decode(packets[i % len(packets)]), min(ns.frames, len(packets)))
            codec_rows[codec] = {"encode_ms": enc_ms, "decode_ms": decode_ms, "encode_over_gt": enc_ms / gt_ms, "decode_over_gt": decode_ms / gt_ms}
        mrows = {}
        for m in methods:
            try:
                res = run(RunConfig(method=m, width=w, height=h, duration_s=ns.frames / 30, client_fps=30, metrics=False, flip_every=0), renderer=renderer)
            except Exception as exc:  # a method that fails here is reported, not hidden
                mrows[m] = {"error": f"{type(exc).__name__}: {exc}"}
                continue
            cms = float(np.median([f["client_ms"] for f in res.frames]))
            sms = float(np.median([u["server_ms"] for u in res.updates]))
            mrows[m] = {"client_ms": cms, "server_ms": sms, "client_over_gt": cms / gt_ms, "server_over_gt": sms / gt_ms,
                        "kbps": res.summary["mean_kbps"]}
        results["sizes"][size] = {"gt_ms": gt_ms, "codecs": codec_rows, "methods": mrows}
        print(f"{size}: ground truth {gt_ms:.1f} ms/frame")
        for c, r in codec_rows.items():
            print(f"  {c}: encode {r['encode_over_gt']:.2f}x GT, decode {r['decode_over_gt']:.2f}x GT")
        for m, r in mrows.items():
            if "error" in r:
                print(f"  {m}: {r['error']}")
            else:
                print(f"  {m}: client {r['client_over_gt']:.3f}x GT, server {r['server_over_gt']:.2f}x GT")
    ns.out.parent.mkdir(parents=True, exist_ok=True)
    ns.out.write_text(json.dumps(results, indent=2))
    print(f"wrote {ns.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
