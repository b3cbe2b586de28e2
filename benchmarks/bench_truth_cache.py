"""Ground truth rendered once: a mini demo (2 methods x 2 networks) without and with the cache.

The demo's runs share one trace, size and frame rate, so with ``truth_cache`` set the
first run renders the ground truth and the other three read it; a second demo in a
fresh result folder (same cache) reads every frame.  Runs are serial (one worker) so
the comparison does not depend on how many cores are free.

Writes ``benchmarks/results/bench_truth_cache.json``.  Run: ``python benchmarks/bench_truth_cache.py``.
Other work on the machine skews wall-clock numbers: the JSON records the load average.
"""

from __future__ import annotations

import json
import math
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, not an installed one

from splitrender.experiments.store import ResultStore  # noqa: E402
from splitrender.experiments.sweep import run_configs  # noqa: E402
from splitrender.sim.config import RunConfig  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "bench_truth_cache.json"
METHODS = ("video", "atw")
NETWORKS = ("ideal", "cloud")
BASE = dict(scene="default", trace="walk", width=320, height=180, duration_s=2.0, client_fps=30, server_fps=30, flip_every=6)
SCORES = ("mean_psnr_db", "psnr_mse_db", "mean_ssim", "mean_flip", "mean_fg_psnr_db")


def configs(cache: str) -> list[RunConfig]:
    return [RunConfig.from_dict({**BASE, "method": m, "network": n, "truth_cache": cache}) for m in METHODS for n in NETWORKS]


def _summaries(d: Path) -> list[dict[str, float]]:
    import csv

    out = []
    for p in sorted(d.rglob("summary.csv")):
        with open(p, newline="") as f:
            r = next(csv.DictReader(f))
        out.append({k: float(r[k]) if r[k] else math.nan for k in SCORES})
    return out


def run_demo(cache: str) -> tuple[float, list[dict[str, float]]]:
    """Wall seconds of the mini demo in a fresh result folder, and each run's scores."""
    with tempfile.TemporaryDirectory(prefix="bench-truth-") as d:
        t0 = time.perf_counter()
        res = run_configs(configs(cache), ResultStore(d), workers=1)
        wall = time.perf_counter() - t0
        if res.failures:
            raise RuntimeError(f"bench: {len(res.failures)} runs failed: {res.failures[0].error}")
        return wall, _summaries(Path(d))


def main() -> None:
    with tempfile.TemporaryDirectory() as cache:
        run_demo("")  # warm up: imports, shader compilation, page cache
        before, s_before = run_demo("")
        cold, s_cold = run_demo(cache)
        warm, s_warm = run_demo(cache)
        n_files = sum(1 for _ in Path(cache).rglob("*.srgt"))
        cache_bytes = sum(p.stat().st_size for p in Path(cache).rglob("*.srgt"))
    same = all(
        all(a[k] == b[k] or (math.isnan(a[k]) and math.isnan(b[k])) for k in SCORES)
        for a, b in zip(s_before, s_cold + s_warm)
    ) and len(s_before) == len(s_cold) == len(s_warm) == len(METHODS) * len(NETWORKS)
    out = {
        "what": "mini demo: video, atw x ideal, cloud on default/walk, 2 s at 320x180, client 30 fps, FLIP every 6th frame, serial",
        "runs": len(METHODS) * len(NETWORKS),
        "wall_s_no_cache": before,
        "wall_s_cold_cache": cold,
        "wall_s_warm_cache": warm,
        "speedup_cold": before / cold,
        "speedup_warm": before / warm,
        "cached_frames": n_files,
        "cache_kib_per_frame": cache_bytes / max(1, n_files) / 1024,
        "identical_scores": same,
        "loadavg": os.getloadavg(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
