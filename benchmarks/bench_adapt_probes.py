"""``probes`` under a changing link, adaptation off, rate and full, in one run (issue 48, part 3).

As ``benchmarks/bench_adapt.py`` (virtual time, the ``walk`` trace, 320x180, a 30 Hz display, 20 ms each way over
a generated step trace: ``--steps`` seconds at 20 Mbit/s, then at 2, then at 20 again, default 3, 4 and 3 s), on
the default scene *with* its GI (``default``: probes streams it; the other methods' bench runs ``default+nogi``).
``rate`` has no encoder to steer (the probe pictures are lossless, the rest is data), so it differs from ``off``
only by the estimator's pacing and probing; ``full`` moves the client's operating point (``probe_bits``,
``vis_bits``, ``probe_div``, then ``frame_div``) over the one GI server.  Each run's figures are the link study's
(:func:`splitrender.experiments.studies.link.figures`), beside the bits sent in the low step and its p95 update age.

Writes ``benchmarks/results/bench_adapt_probes.json``.

    python benchmarks/bench_adapt_probes.py [--steps 3,4,3] [--adapt off,rate,full]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout
from splitrender.experiments.studies.link import figures, step_spans  # noqa: E402
from splitrender.netsim.traces import step_trace, write_mahimahi  # noqa: E402

OUT = Path(__file__).resolve().parent / "results"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", default="3,4,3", help="seconds at 20, 2 and 20 Mbit/s (the walk trace lasts 10 s)")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--adapt", default="off,rate,full", help="the adaptation modes to run, comma-separated")
    args = ap.parse_args()
    from splitrender.render.renderer import Renderer
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import run

    steps = tuple(float(x) for x in args.steps.split(","))
    assert len(steps) == 3
    w, h = (int(x) for x in args.size.split("x"))
    tmp = Path(tempfile.mkdtemp(prefix="bench_adapt_probes_"))
    plan = [(steps[0], 20.0), (steps[1], 2.0), (steps[2], 20.0)]
    stamps = step_trace(plan)
    trace = write_mahimahi(stamps, tmp / "step.trace")
    steady, low = step_spans(plan)
    renderer = Renderer()
    runs = []
    t0 = time.perf_counter()
    for adapt in args.adapt.split(","):
        w0 = time.perf_counter()
        cfg = RunConfig(method="probes", scene="default", trace="walk", network=f"delay 20ms trace {trace}",
                        duration_s=sum(steps), width=w, height=h, client_fps=30, flip_every=0, seed=0,
                        transport_cc=True, adapt=adapt, truth_cache=str(tmp / "truth"))
        res = run(cfg, renderer=renderer)
        f = figures(res, stamps, steady, low)
        a, b = low
        f["low_kbps"] = sum(u["bytes"] for u in res.updates if a <= u["t_s"] < b) * 8 / (b - a) / 1000
        ages = np.array([x["update_age_ms"] for x in res.frames if a <= x["t_s"] < b and np.isfinite(x["update_age_ms"])])
        f["low_age_p95_ms"] = float(np.percentile(ages, 95)) if ages.size else float("nan")
        f["keyframes"] = int(res.summary.get("keyframes", 0))
        points = [(round(float(u["t_s"]), 3), int(u["adapt_point"])) for u in res.updates if "adapt_point" in u]
        f["points"] = [p for i, p in enumerate(points) if i == 0 or p[1] != points[i - 1][1]]
        runs.append({"method": "probes", "adapt": adapt, **f, "wall_s": time.perf_counter() - w0})
        print(f"probes {adapt:4s} mtp p95 {f['mtp_p95_ms']:7.0f} ms (low step {f['low_mtp_p95_ms']:7.0f}), age p95 low "
              f"{f['low_age_p95_ms']:6.0f} ms, freezes>500 {f['freezes_over_500ms']}, longest {f['longest_freeze_ms']:5.0f} ms, "
              f"model PSNR {f['model_psnr_db']:.2f} (low {f['low_model_psnr_db']:.2f}), {f['mean_kbps']:.0f} kbit/s "
              f"(low step {f['low_kbps']:.0f}), points {f['points']}", flush=True)
    OUT.mkdir(parents=True, exist_ok=True)
    out = {"benchmark": "bench_adapt_probes", "steps_s": steps, "capacity_mbps": [20, 2, 20], "size": [w, h],
           "scene": "default", "trace": "walk", "runs": runs, "wall_s": time.perf_counter() - t0,
           "machine": platform.machine(), "cpus": os.cpu_count(), "load_avg": os.getloadavg()}
    (OUT / "bench_adapt_probes.json").write_text(json.dumps(out, indent=1) + "\n")
    print(f"-> {OUT / 'bench_adapt_probes.json'}")


if __name__ == "__main__":
    main()
