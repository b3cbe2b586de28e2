"""Allocator speed of ``sas`` (paper section 5.3, table 2) on this machine.

Replays the PVS + level sequence of a walk through (a) the default scene at 320x180
and (b) a dense variant with >= 100k patches (the floor subdivided 320x320) at
640x360, through the numpy :class:`PatchAllocator` for strategies S0-S3 and through
a per-patch Python loop baseline, timing each frame.  The paper's figures: CPU
(single-threaded, quadtree) 37.2-377.2 ms per frame, GPU (compute) 0.14-0.24 ms.

Writes ``benchmarks/results/bench_sas_allocator.json``.  Run:
``python benchmarks/bench_sas_allocator.py [--frames N]``.
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

import numpy as np

from splitrender.methods.sas.allocator import STRATEGIES
from splitrender.methods.sas.replay import record_visibility, replay_allocation, replay_baseline
from splitrender.methods.sas.server import SasConfig
from splitrender.render.renderer import Renderer
from splitrender.scene import primitives as P
from splitrender.scene.pose import CameraIntrinsics
from splitrender.scene.procedural import default_scene
from splitrender.scene.trace import get_trace

PAPER_MS = {"cpu_ms": {"Robot Lab": 44.66, "Sponza": 37.21, "Viking Village": 377.20},
            "gpu_ms": {"Robot Lab": 0.19, "Sponza": 0.14, "Viking Village": 0.24}}
OUT = Path(__file__).parent / "results" / "bench_sas_allocator.json"


def dense_scene(cells: int = 320):  # type: ignore[no-untyped-def]
    """The default scene with its floor subdivided ``cells`` x ``cells`` (2 * cells^2 triangles)."""
    s = default_scene()
    floor = s.objects[0]
    floor.mesh = P.grid_plane(16.0, 16.0, cells, cells, uv_scale_m=2.0)
    s.name = f"default_dense{cells}"
    return s


def stats(ms: list[float]) -> dict[str, float]:
    a = np.asarray(ms[1:] if len(ms) > 1 else ms)   # frame 0 is the initial bulk allocation
    return {"mean_ms": float(a.mean()), "p95_ms": float(np.percentile(a, 95)), "max_ms": float(a.max()),
            "first_frame_ms": float(ms[0])}


def bench(name: str, scene, intr: CameraIntrinsics, frames: int, renderer: Renderer) -> dict:  # type: ignore[no-untyped-def]
    layout = SasConfig().atlas_layout(intr)
    patches, seq = record_visibility(renderer, scene, get_trace("walk"), intr, 1.0, frames)
    row: dict = {"scene": name, "patches": patches.count, "triangles": scene.triangle_count,
                 "resolution": [intr.width, intr.height], "atlas": [layout.width, layout.height], "frames": frames,
                 "mean_pvs_patches": float(np.mean([f.pvs.size for f in seq])), "strategies": {}}
    for s in STRATEGIES:
        r = replay_allocation(patches, seq, layout, s)
        row["strategies"][s] = {**stats(r.alloc_ms), "levels_mean_ms": float(np.mean(r.levels_ms)),
                                "mean_placed": float(np.mean(r.placed[1:])), "resets": r.resets, "oom_frames": r.oom_frames}
    row["baseline_python_loop"] = stats(replay_baseline(seq, layout))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=60)
    args = ap.parse_args()
    r = Renderer()
    rows = [bench("default", default_scene(), CameraIntrinsics(320, 180), args.frames, r),
            bench("dense_100k", dense_scene(), CameraIntrinsics(640, 360), args.frames, r)]
    out = {"machine": platform.processor() or platform.machine(), "python": platform.python_version(),
           "paper": PAPER_MS, "results": rows}
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(out, indent=1))
    for row in rows:
        print(f"{row['scene']}: {row['patches']} patches, PVS {row['mean_pvs_patches']:.0f}, atlas {row['atlas']}")
        for s, v in row["strategies"].items():
            print(f"  {s}: mean {v['mean_ms']:.3f} ms  p95 {v['p95_ms']:.3f}  first {v['first_frame_ms']:.2f}  "
                  f"levels {v['levels_mean_ms']:.3f} ms  resets {v['resets']}  oom {v['oom_frames']}")
        b = row["baseline_python_loop"]
        print(f"  python loop baseline: mean {b['mean_ms']:.3f} ms  first {b['first_frame_ms']:.2f}")
    print(f"paper: CPU 37-377 ms, GPU 0.14-0.24 ms -> {OUT}")


if __name__ == "__main__":
    main()
