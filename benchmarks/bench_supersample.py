"""Supersampled ground truth: what ``supersample = 2`` changes for each method, and what it costs.

Every method on the default scene, 1 s of ``walk`` at 320x180, ``ideal`` and ``lan``,
with ``supersample`` 1 and 2 (the ground truth and the servers' shared-renderer draws
at twice the size, box-filtered down; the clients draw without anti-aliasing).  For
each run: PSNR, foreground PSNR, SSIM, and the ground-truth and server milliseconds;
the JSON quotes the quality change in dB and the cost as a ratio to the same run
without supersampling (same process, same load).

Writes ``benchmarks/results/bench_supersample.json``.  Run: ``python benchmarks/bench_supersample.py``.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, not an installed one

from splitrender.methods import available_methods  # noqa: E402
from splitrender.render.renderer import Renderer  # noqa: E402
from splitrender.sim.config import RunConfig  # noqa: E402
from splitrender.sim.runner import run  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "bench_supersample.json"
NETWORKS = ("ideal", "lan")
BASE: dict = dict(scene="default", trace="walk", width=320, height=180, duration_s=1.0, client_fps=30, flip_every=0, seed=0)


def main() -> None:
    renderer = Renderer()
    rows = []
    t0 = time.perf_counter()
    for m in available_methods():
        for net in NETWORKS:
            by_k = {}
            for k in (1, 2):
                s = run(RunConfig.from_dict({**BASE, "method": m, "network": net, "supersample": k}), renderer=renderer).summary
                by_k[k] = s
                print(f"{m:6s} {net:6s} x{k}: {s['mean_psnr_db']:.2f} dB, fg {s['mean_fg_psnr_db']:.2f} dB, "
                      f"gt {s['mean_gt_ms']:.0f} ms, server {s['mean_server_ms']:.0f} ms", flush=True)
            a, b = by_k[1], by_k[2]
            rows.append({
                "method": m, "network": net,
                "psnr_db": [a["mean_psnr_db"], b["mean_psnr_db"]], "delta_psnr_db": b["mean_psnr_db"] - a["mean_psnr_db"],
                "fg_psnr_db": [a["mean_fg_psnr_db"], b["mean_fg_psnr_db"]],
                "delta_fg_psnr_db": b["mean_fg_psnr_db"] - a["mean_fg_psnr_db"],
                "ssim": [a["mean_ssim"], b["mean_ssim"]],
                "gt_ms_ratio": b["mean_gt_ms"] / a["mean_gt_ms"], "server_ms_ratio": b["mean_server_ms"] / a["mean_server_ms"],
            })
    out = {"config": BASE, "networks": NETWORKS, "rows": rows, "wall_s": time.perf_counter() - t0,
           "load_avg": os.getloadavg(), "machine": platform.machine(), "cpus": os.cpu_count(),
           "note": "supersample 2 = 4 samples per pixel for the ground truth and the servers' renders; clients draw without AA"}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=1))
    print(f"-> {RESULTS}")


if __name__ == "__main__":
    main()
