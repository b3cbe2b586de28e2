"""Instrumentation benchmarks on this machine: scoring throughput, pool and Dask overheads.

1. Displayed frames scored per second (PSNR, SSIM, Lab error, holes, ground-truth render)
   with FLIP on no frame (``flip_every = 0``) and on every frame (``flip_every = 1``).
2. Speed-up of a 4-process pool over serial on a small sweep (8 runs).
3. Overhead of a Dask ``LocalCluster`` (4 worker processes) over the 4-process pool on
   the same sweep (fresh result folders: nothing cached).

Writes ``benchmarks/results/bench_instrument.json``.  Run: ``python benchmarks/bench_instrument.py``.
Other work on the machine skews wall-clock numbers: the JSON records the load average.
"""

from __future__ import annotations

import json
import os
import platform
import tempfile
import time
from pathlib import Path

from splitrender.experiments.store import ResultStore
from splitrender.experiments.sweep import parse_sweep, run_configs
from splitrender.render.renderer import Renderer
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import run

RESULTS = Path(__file__).parent / "results" / "bench_instrument.json"
SWEEP = {
    "sweep": {"name": "bench", "networks": ["ideal", "cloud"], "seeds": [0, 1]},
    "base": {"width": 160, "height": 90, "duration_s": 1.0, "client_fps": 30, "flip_every": 0},
    "methods": {"video": {}, "atw": {}},
}


def scoring_rate() -> dict[str, float]:
    r = Renderer()
    base = RunConfig(method="video", width=320, height=180, duration_s=1.0, client_fps=30)
    run(base.replace(flip_every=0), renderer=r)  # warm up shaders
    out = {}
    for label, fe in (("no_flip", 0), ("flip_every_frame", 1)):
        t0 = time.perf_counter()
        res = run(base.replace(flip_every=fe, seed=1), renderer=r)
        dt = time.perf_counter() - t0
        out[f"frames_per_s_{label}"] = len(res.frames) / dt
    t0 = time.perf_counter()
    res = run(base.replace(metrics=False, seed=2), renderer=r)
    out["frames_per_s_no_metrics"] = len(res.frames) / (time.perf_counter() - t0)
    out["flip_slowdown"] = out["frames_per_s_no_flip"] / out["frames_per_s_flip_every_frame"]
    return out


def sweep_modes() -> dict[str, float]:
    cfgs = parse_sweep(SWEEP, "bench").configs
    times = {}
    for mode, kw in (("serial", {"workers": 1}), ("pool4", {"workers": 4}), ("dask_local4", {"workers": 4, "dask": "local"})):
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            res = run_configs(cfgs, ResultStore(d), **kw)  # type: ignore[arg-type]
            times[f"{mode}_s"] = time.perf_counter() - t0
            assert not res.failures, res.failures
    times["runs"] = len(cfgs)
    times["pool4_speedup_over_serial"] = times["serial_s"] / times["pool4_s"]
    times["dask_over_pool4"] = times["dask_local4_s"] / times["pool4_s"]
    return times


def main() -> None:
    load0 = os.getloadavg()
    res = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "loadavg_before": load0},
           "scoring_320x180": scoring_rate(), "sweep_160x90_1s": sweep_modes()}
    res["machine"]["loadavg_after"] = os.getloadavg()
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(res, indent=2))
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
