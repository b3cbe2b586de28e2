"""Every thin-client method under a changing link, rate adaptation off and on, in one run (issue 35).

Virtual time, the default scene without GI (``default+nogi``), the ``walk`` trace, 320x180, a 30 Hz display, 20 ms
each way over a generated step trace (no trace file is committed; :func:`splitrender.netsim.traces.step_trace`):
``--steps`` seconds at 20 Mbit/s, then at 2, then at 20 again (default 3, 4 and 3 s: the walk lasts 10 s; the
issue's study asks for 5, 5 and 10 on a longer trace).  For ``video``, ``atw``, ``warp``, ``sas``, ``tss`` and ``quads``, each with ``--adapt off`` (the method's
fixed operating point) and ``--adapt rate`` (both with transport-wide feedback, so the estimator is measured the
same way) and ``--adapt full`` (the method's own knobs too):

* motion-to-photon p50 and p95 over the run and over the low-capacity step (from its start to the rise);
* freezes: display stretches longer than 250 and 500 ms showing one update, and the longest;
* utilisation: bytes sent over the capacity in the steady parts (each step less its first second), and over the
  low step alone (updates by their arrival), where the link binds (a method at its own operating point uses a fraction of 20 Mbit/s at
  320x180, and adaptation never asks more of it);
* model PSNR (the scene's model, without sky and floor) over the run and over the low step;
* how long after the drop the p95 update age over a 0.5 s window is back under 150 ms (``recovery_s``).

Writes ``benchmarks/results/bench_adapt.json`` and ``bench_adapt.png`` (update age and sent rate against time per
method, off and on, the capacity beside them).

    python benchmarks/bench_adapt.py [--methods video,sas] [--steps 3,4,5]
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
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout
from splitrender.experiments.studies.link import chart, figures, step_spans, timeline  # noqa: E402
from splitrender.netsim.traces import step_trace, write_mahimahi  # noqa: E402

OUT = Path(__file__).resolve().parent / "results"
METHODS = ("video", "atw", "warp", "sas", "tss", "quads")


def low_utilisation(res: Any, steps: tuple[float, float, float]) -> float:
    """Bits of the updates that arrived during the low step (its first second left out) over its capacity
    (2 Mbit/s): where the link binds.  Probes and retransmissions are not counted."""
    a, b, _ = steps
    got = sum(u["bytes"] for u in res.updates if np.isfinite(u.get("arrival_s", np.nan)) and a + 1.0 <= u["arrival_s"] < a + b)
    return float(got * 8 / (b - 1.0) / 2e6) if b > 1.0 else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--methods", default=",".join(METHODS))
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
    tmp = Path(tempfile.mkdtemp(prefix="bench_adapt_"))
    plan = [(steps[0], 20.0), (steps[1], 2.0), (steps[2], 20.0)]
    stamps = step_trace(plan)
    trace = write_mahimahi(stamps, tmp / "step.trace")
    steady, low = step_spans(plan)
    renderer = Renderer()
    runs = []
    t0 = time.perf_counter()
    for m in args.methods.split(","):
        for adapt in args.adapt.split(","):
            w0 = time.perf_counter()
            cfg = RunConfig(method=m, scene="default+nogi", trace="walk", network=f"delay 20ms trace {trace}",
                            duration_s=sum(steps), width=w, height=h, client_fps=30, flip_every=0, seed=0,
                            transport_cc=True, adapt=adapt, truth_cache=str(tmp / "truth"))
            res = run(cfg, renderer=renderer)
            f = figures(res, stamps, steady, low)
            tl = timeline(res)
            f["low_utilisation"] = low_utilisation(res, steps)  # type: ignore[arg-type]
            runs.append({"method": m, "adapt": adapt, **f, "timeline": tl, "wall_s": time.perf_counter() - w0})
            print(f"{m:6s} {adapt:4s} mtp p95 {f['mtp_p95_ms']:7.0f} ms (low step {f['low_mtp_p95_ms']:7.0f}), "
                  f"freezes>500 {f['freezes_over_500ms']}, longest {f['longest_freeze_ms']:5.0f} ms, "
                  f"util {f['utilisation']:.2f} (low {f['low_utilisation']:.2f}), model PSNR {f['model_psnr_db']:.2f} (low {f['low_model_psnr_db']:.2f}), "
                  f"recovery {f['recovery_s']:.2f} s, {f['mean_kbps']:.0f} kbit/s", flush=True)
    compare: dict[str, dict[str, float]] = {}
    for r in runs:       # per method, each mode's figures side by side
        c = compare.setdefault(r["method"], {})
        for k in ("mtp_p95_ms", "low_mtp_p95_ms", "model_psnr_db", "utilisation", "low_utilisation", "recovery_s",
                  "longest_freeze_ms"):
            c[f"{k}_{r['adapt']}"] = r[k]
    OUT.mkdir(parents=True, exist_ok=True)
    out = {"benchmark": "bench_adapt", "steps_s": steps, "capacity_mbps": [20, 2, 20], "size": [w, h],
           "scene": "default+nogi", "trace": "walk", "compare": compare, "runs": runs,
           "wall_s": time.perf_counter() - t0, "machine": platform.machine(), "cpus": os.cpu_count(),
           "load_avg": os.getloadavg()}
    (OUT / "bench_adapt.json").write_text(json.dumps(out, indent=1) + "\n")
    chart(runs, stamps, "Under a changing link: 20 -> 2 -> 20 Mbit/s (shaded: the low step)", OUT / "bench_adapt.png", low)
    print(f"-> {OUT / 'bench_adapt.json'}, {OUT / 'bench_adapt.png'}")


if __name__ == "__main__":
    main()
