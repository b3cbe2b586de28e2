"""Ground truth rendered once: a mini demo (2 methods x 2 networks) without and with the cache.

The demo's runs share one trace, size and frame rate, so with ``truth_cache`` set the
first run renders the ground truth and the other three read it; a second demo in a
fresh result folder (same cache) reads every frame.  Runs are serial (one worker) so
the comparison does not depend on how many cores are free.

Writes ``benchmarks/results/bench_truth_cache.json``.  Run: ``python benchmarks/bench_truth_cache.py``;
``--sweep24`` instead times a 24-run sweep on a 2-process pool (``bench_truth_cache_sweep24.json``).
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
BASE: dict = dict(scene="default", trace="walk", width=320, height=180, duration_s=1.0, client_fps=30, server_fps=30, flip_every=6)
REPEATS = 2
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


def per_frame_ms(frames: int = 30) -> dict[str, float]:
    """In one process: ms per ground-truth frame rendered, rendered and stored (a miss), read (a hit)."""
    from splitrender.render import Renderer
    from splitrender.scene import get_scene
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.trace import get_trace
    from splitrender.sim.truth import truth_source

    r, scene, trace = Renderer(), get_scene(BASE["scene"]), get_trace(BASE["trace"])
    intr = CameraIntrinsics(BASE["width"], BASE["height"], 60.0)
    ts = [i / BASE["client_fps"] for i in range(frames)]
    r.render(scene, 0.0, trace.pose_at(0.0), intr, ("color", "object_id"))  # warm up
    out = {}
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        src = truth_source(d, r, scene, trace, intr, BASE["client_fps"])
        out["key_ms"] = (time.perf_counter() - t0) * 1000
        for label, fn in (("render_ms", r), ("miss_ms", src), ("hit_ms", src)):
            t0 = time.perf_counter()
            for t in ts:
                fn.render(scene, t, trace.pose_at(t), intr, ("color", "object_id"))
            out[label] = (time.perf_counter() - t0) / len(ts) * 1000
    return out


def main() -> None:
    walls: dict[str, list[float]] = {"no_cache": [], "cold_cache": [], "warm_cache": []}
    scores: dict[str, list[dict[str, float]]] = {}
    run_demo("")  # warm up: imports, shader compilation, page cache
    n_files, cache_bytes = 0, 0
    for _ in range(REPEATS):  # alternate the arms so load changes hit all of them
        with tempfile.TemporaryDirectory() as cache:
            for arm, setting in (("no_cache", ""), ("cold_cache", cache), ("warm_cache", cache)):
                wall, sc = run_demo(setting)
                walls[arm].append(wall)
                scores.setdefault(arm, sc)
            n_files = sum(1 for _ in Path(cache).rglob("*.srgt"))
            cache_bytes = sum(p.stat().st_size for p in Path(cache).rglob("*.srgt"))
    same = all(
        all(a[k] == b[k] or (math.isnan(a[k]) and math.isnan(b[k])) for k in SCORES)
        for arm in ("cold_cache", "warm_cache") for a, b in zip(scores["no_cache"], scores[arm])
    ) and all(len(v) == len(METHODS) * len(NETWORKS) for v in scores.values())
    best = {k: min(v) for k, v in walls.items()}
    out = {
        "what": (f"mini demo: {', '.join(METHODS)} x {', '.join(NETWORKS)} on {BASE['scene']}/{BASE['trace']}, "
                 f"{BASE['duration_s']} s at {BASE['width']}x{BASE['height']}, client {BASE['client_fps']} fps, "
                 f"FLIP every {BASE['flip_every']}th frame, serial; best of {REPEATS} alternating repeats"),
        "runs": len(METHODS) * len(NETWORKS),
        "wall_s": walls,
        "wall_s_no_cache": best["no_cache"],
        "wall_s_cold_cache": best["cold_cache"],
        "wall_s_warm_cache": best["warm_cache"],
        "speedup_cold": best["no_cache"] / best["cold_cache"],
        "speedup_warm": best["no_cache"] / best["warm_cache"],
        "cached_frames": n_files,
        "cache_kib_per_frame": cache_bytes / max(1, n_files) / 1024,
        "identical_scores": same,
        "per_frame": per_frame_ms(),
        "loadavg": os.getloadavg(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))


SWEEP_METHODS = ("video", "atw", "warp", "sas")
SWEEP_NETWORKS = ("ideal", "lan", "cloud")
SWEEP_SEEDS = (0, 1)
SWEEP_BASE: dict = dict(BASE, duration_s=0.5, flip_every=0)


def sweep24() -> None:
    """A 24-run sweep (4 methods x 3 networks x 2 seeds, one trace) on a 2-process pool, without the
    cache and with a cold one (its processes share the file store); writes ``bench_truth_cache_sweep24.json``."""
    cfgs = {arm: [RunConfig.from_dict({**SWEEP_BASE, "method": m, "network": n, "seed": sd, "truth_cache": setting})
                  for m in SWEEP_METHODS for n in SWEEP_NETWORKS for sd in SWEEP_SEEDS]
            for arm, setting in (("no_cache", ""), ("cold_cache", "<tmp>"))}
    walls, scores = {}, {}
    with tempfile.TemporaryDirectory() as cache:
        for arm, cs in cfgs.items():
            cs = [c.replace(truth_cache=cache) if c.truth_cache == "<tmp>" else c for c in cs]
            with tempfile.TemporaryDirectory(prefix="bench-sweep-") as d:
                t0 = time.perf_counter()
                res = run_configs(cs, ResultStore(d), workers=2)
                walls[arm] = time.perf_counter() - t0
                if res.failures:
                    raise RuntimeError(f"bench: {len(res.failures)} runs failed: {res.failures[0].error}")
                scores[arm] = _summaries(Path(d))
        n_files = sum(1 for _ in Path(cache).rglob("*.srgt"))
    same = len(scores["no_cache"]) == len(scores["cold_cache"]) == 24 and all(
        all(a[k] == b[k] or (math.isnan(a[k]) and math.isnan(b[k])) for k in SCORES)
        for a, b in zip(scores["no_cache"], scores["cold_cache"]))
    out = {
        "what": (f"24-run sweep: {', '.join(SWEEP_METHODS)} x {', '.join(SWEEP_NETWORKS)} x seeds {SWEEP_SEEDS} on "
                 f"{SWEEP_BASE['scene']}/{SWEEP_BASE['trace']}, {SWEEP_BASE['duration_s']} s at "
                 f"{SWEEP_BASE['width']}x{SWEEP_BASE['height']}, 2-process pool, no FLIP"),
        "wall_s_no_cache": walls["no_cache"], "wall_s_cold_cache": walls["cold_cache"],
        "speedup": walls["no_cache"] / walls["cold_cache"], "cached_frames": n_files, "identical_scores": same,
        "loadavg": os.getloadavg(), "cpus": os.cpu_count(), "python": platform.python_version(),
    }
    path = RESULTS.with_name("bench_truth_cache_sweep24.json")
    path.write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    sweep24() if "--sweep24" in sys.argv[1:] else main()
