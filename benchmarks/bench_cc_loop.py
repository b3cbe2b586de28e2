"""Benchmark the send-rate estimator in its closed loop (:mod:`splitrender.sim.cc_loop`), virtual time.

Issue 35's estimator targets, measured on generated capacity traces (no trace file is
committed; the generators are :mod:`splitrender.netsim.traces`):

* **step**: 5 s at 20 Mbit/s, 5 s at 2, 10 s at 20, one-way delay 10, 20 and 50 ms:
  how long after the drop the encoder rate (and the delay-based target) is within 1.2x
  the new capacity (target: 1 s), how long after the rise the target passes 70 % of it
  (target: 5 s), the share of the capacity sent over the steady parts (target: 80 %),
  and the 95th percentile one-way delay there;
* **cellular**: a 60 s cellular-like trace (mean 8 Mbit/s, coefficient of variation 0.5,
  1 s correlation time, 2 % outages of 0.3 s mean), 20 ms each way: utilisation and the
  delay distribution;

each beside the same loop without probing (multiplicative increase alone), measured in
the same run.  Writes ``benchmarks/results/bench_cc_loop.json`` and a timeline chart
``bench_cc_loop.png`` (capacity, target, encoder rate, one-way delay).

    python benchmarks/bench_cc_loop.py [--seeds 0,1,2]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout
from splitrender.netsim.models import LinkSpec  # noqa: E402
from splitrender.netsim.traces import cellular_trace, step_trace, trace_stats, write_mahimahi  # noqa: E402
from splitrender.pipeline.gcc import GccConfig  # noqa: E402
from splitrender.sim.cc_loop import LoopResult, run_loop  # noqa: E402

OUT = Path(__file__).resolve().parent / "results"


def _first_after(t: np.ndarray, cond: np.ndarray, t0: float) -> float:
    hit = t[(t > t0) & cond]
    return float(hit[0] - t0) if hit.size else float("nan")


def step_figures(r: LoopResult) -> dict[str, float]:
    t, enc, tgt = r.column("t_s"), r.column("encoder_mbps"), r.column("target_mbps")
    sent, cap, d = r.column("sent_mbps"), r.column("capacity_mbps"), r.column("delay_ms")
    steady = ((t > 2) & (t < 5)) | ((t > 7) & (t < 10)) | ((t > 13) & (t < 20))
    return {"down_encoder_s": _first_after(t, enc <= 2.4, 5.0), "down_target_s": _first_after(t, tgt <= 2.4, 5.0),
            "up_target_s": _first_after(t, tgt >= 14.0, 10.0), "utilisation": float(sent[steady].sum() / cap[steady].sum()),
            "p95_delay_ms_steady": float(np.nanpercentile(d[steady], 95)), "max_delay_ms": float(np.nanmax(d)),
            "probe_share": r.probe_bytes / max(1, r.probe_bytes + r.media_bytes), "packets_lost": r.packets_lost}


def cellular_figures(r: LoopResult) -> dict[str, float]:
    sent, cap, d = r.column("sent_mbps"), r.column("capacity_mbps"), r.column("delay_ms")
    return {"utilisation": float(sent.sum() / cap.sum()), "p50_delay_ms": float(np.nanpercentile(d, 50)),
            "p95_delay_ms": float(np.nanpercentile(d, 95)), "max_delay_ms": float(np.nanmax(d)),
            "probe_share": r.probe_bytes / max(1, r.probe_bytes + r.media_bytes), "packets_lost": r.packets_lost}


def chart(runs: dict[str, LoopResult], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(runs), figsize=(6 * len(runs), 6), sharex="col", squeeze=False)
    for j, (name, r) in enumerate(runs.items()):
        t = r.column("t_s")
        ax = axes[0][j]
        ax.step(t, r.column("capacity_mbps"), where="post", color="k", lw=1.5, label="capacity")
        ax.plot(t, r.column("target_mbps"), label="target (delay/loss based)")
        ax.plot(t, r.column("encoder_mbps"), label="encoder rate", lw=1)
        ax.set_ylabel("Mbit/s")
        ax.set_title(name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        ax2 = axes[1][j]
        ax2.plot(t, r.column("delay_ms"), color="#d62728", lw=1)
        ax2.set_ylabel("median one-way delay (ms)")
        ax2.set_xlabel("time (s)")
        ax2.set_yscale("log")
        ax2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="0,1,2")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    out: dict[str, Any] = {"machine": platform.platform(), "step": [], "cellular": []}
    tmp = Path(tempfile.mkdtemp())
    step = write_mahimahi(step_trace([(5, 20), (5, 2), (10, 20)]), tmp / "step.mm")
    shown: dict[str, LoopResult] = {}
    for delay in (10, 20, 50):
        for seed in seeds:
            for probe in (True, False):
                r = run_loop(LinkSpec(delay_ms=delay, jitter_ms=2.0 if seed else 0.0, trace_path=str(step),
                                      limit_packets=300), 20.0, seed=seed, cfg=GccConfig(probe=probe))
                out["step"].append({"delay_ms": delay, "seed": seed, "probing": probe, **step_figures(r)})
                if delay == 20 and seed == seeds[0] and probe:
                    shown["step 20 -> 2 -> 20 Mbit/s, 20 ms"] = r
    for seed in seeds:
        stamps = cellular_trace(60, mean_mbps=8.0, cv=0.5, corr_time_s=1.0, outage_share=0.02, outage_mean_s=0.3, seed=seed)
        path = write_mahimahi(stamps, tmp / f"cell{seed}.mm")
        for probe in (True, False):
            r = run_loop(LinkSpec(delay_ms=20, trace_path=str(path), limit_packets=300), 60.0, seed=seed,
                         cfg=GccConfig(probe=probe))
            out["cellular"].append({"seed": seed, "probing": probe, "trace": trace_stats(stamps), **cellular_figures(r)})
            if seed == seeds[0] and probe:
                shown["cellular-like, mean 8 Mbit/s, 20 ms"] = r
    OUT.mkdir(exist_ok=True)
    (OUT / "bench_cc_loop.json").write_text(json.dumps(out, indent=1))
    chart(shown, OUT / "bench_cc_loop.png")
    for row in out["step"]:
        print("step", {k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()})
    for row in out["cellular"]:
        print("cell", {k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items() if k != "trace"})


if __name__ == "__main__":
    main()
