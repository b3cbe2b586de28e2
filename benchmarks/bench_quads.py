"""Server cost of ``quads`` per stage, as ratios to the ground-truth render (QUASAR paper, table 2).

Ten frames of the default scene's ``walk`` at 320x180 and 640x360 (one reference frame,
then residual frames, as the method runs by default), for QUASAR and QuadStream.  Per
stage (G-buffers, quad generation, merging, effective depth peeling, masking with the
cached mesh, packing) the median milliseconds over the frames after the first, divided by
the median time of one ground-truth render of the same frame measured in the same
process.  Also the payload per frame: quads before and after zstd, offsets, quads per set,
and the byte planes against the interleaved arrays of wire 1 (zstd level 3, same frames).

Writes ``benchmarks/results/bench_quads.json``.  Run: ``python benchmarks/bench_quads.py``.
"""

from __future__ import annotations

import json
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, not an installed one

import zstandard  # noqa: E402

from splitrender.methods import get_method, make_config  # noqa: E402
from splitrender.methods.quads.server import STAGES as SERVER_STAGES  # noqa: E402
from splitrender.methods.quads.wire import SET_HEADER, from_byte_planes  # noqa: E402
from splitrender.pipeline.direct import server_context  # noqa: E402
from splitrender.render.renderer import Renderer  # noqa: E402
from splitrender.scene.loader import get_scene  # noqa: E402
from splitrender.scene.pose import CameraIntrinsics  # noqa: E402
from splitrender.scene.trace import get_trace  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "bench_quads.json"
STAGES = (*SERVER_STAGES, "pack_ms")
FRAMES = 10


def interleaved(q: bytes) -> bytes:
    """Wire 1's layout of a ``quads`` payload (the arrays' bytes interleaved), the byte planes' baseline; a packed
    atlas's 24-bit positions (wire 3) follow as they are."""
    arrays = 4 + SET_HEADER.size * q[3]
    n = sum(SET_HEADER.unpack_from(q, 4 + SET_HEADER.size * k)[4] for k in range(q[3]))
    return (q[:arrays + 2 * n] + from_byte_planes(q, "<u4", n, arrays + 2 * n).tobytes()
            + from_byte_planes(q, "<f4", n, arrays + 6 * n).tobytes() + q[arrays + 10 * n:])


def one(renderer: Renderer, variant: str, size: tuple[int, int]) -> dict:
    scene = get_scene("default")
    trace = get_trace("walk", scene=scene)
    intr = CameraIntrinsics(*size)
    spec = get_method("quads")
    srv = spec.server_class(make_config(spec.config, {"variant": variant}), intr, scene, 30, None)
    rows, gt = [], []
    zc = zstandard.ZstdCompressor(level=3)
    for f in range(FRAMES):
        t = 0.5 + f / 30
        pose = trace.pose_at(t)
        ctx = server_context(scene, renderer, intr, pose, t_s=t, frame_id=f)
        t0 = time.perf_counter()
        upd = srv.produce(ctx)
        total = (time.perf_counter() - t0) * 1e3
        t1 = time.perf_counter()
        renderer.render(scene, t, pose, intr)
        gt.append((time.perf_counter() - t1) * 1e3)
        st = srv.stats()
        rows.append({"total_ms": total, **{k: st.get(k, 0.0) for k in STAGES}, "quads": st["quads"],
                     "quads_bytes": len(upd.data["quads"]), "quads_zstd_bytes": len(zc.compress(upd.data["quads"])),
                     "quads_zstd_bytes_interleaved": len(zc.compress(interleaved(upd.data["quads"]))),
                     "offsets_bytes": len(upd.data["offsets"]), "reference": st["reference"]})
    later = rows[1:]
    gt_ms = statistics.median(gt[1:])
    med = {k: statistics.median(r[k] for r in later) for k in ("total_ms", *STAGES)}
    return {"variant": variant, "size": list(size), "gt_ms": gt_ms, "median_ms": med,
            "ratio_to_gt": {k: v / gt_ms for k, v in med.items()},
            "quads_per_frame": statistics.median(r["quads"] for r in later),
            "quads_zstd_kb_reference": statistics.median(r["quads_zstd_bytes"] for r in rows if r["reference"]) / 1e3,
            "quads_zstd_kb_residual": (statistics.median(r["quads_zstd_bytes"] for r in later if not r["reference"]) / 1e3
                                       if any(not r["reference"] for r in later) else None),
            "byte_planes_gain": (sum(r["quads_zstd_bytes_interleaved"] for r in rows)
                                 / sum(r["quads_zstd_bytes"] for r in rows)),
            "frames": rows}


def main() -> None:
    renderer = Renderer()
    out = {"machine": platform.platform(), "gl": renderer.ctx.info["GL_RENDERER"], "frames": FRAMES, "runs": []}
    for size in ((320, 180), (640, 360)):
        for variant in ("quasar", "quadstream"):
            r = one(renderer, variant, size)
            out["runs"].append(r)
            ratios = ", ".join(f"{k[:-3]} {v:.2f}x" for k, v in r["ratio_to_gt"].items())
            print(f"{variant:10s} {size[0]}x{size[1]}: ground truth {r['gt_ms']:.1f} ms; {ratios}; "
                  f"{r['quads_per_frame']:.0f} quads a frame; byte planes {r['byte_planes_gain']:.2f}x fewer "
                  f"zstd bytes than interleaved arrays", flush=True)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=1))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
