"""Every thin-client method under a changing link, rate adaptation off and on, in one run (issue 35).

Virtual time, the default scene without GI (``default+nogi``), the ``walk`` trace, 320x180, a 30 Hz display, 20 ms
each way over a generated step trace (no trace file is committed; :func:`splitrender.netsim.traces.step_trace`):
``--steps`` seconds at 20 Mbit/s, then at 2, then at 20 again (default 3, 4 and 3 s: the walk lasts 10 s; the
issue's study asks for 5, 5 and 10 on a longer trace).  For ``video``, ``atw``, ``warp``, ``sas``, ``tss`` and ``quads``, each with ``--adapt off`` (the method's
fixed operating point) and ``--adapt rate`` (both with transport-wide feedback, so the estimator is measured the
same way):

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
from splitrender.netsim.traces import step_trace, write_mahimahi  # noqa: E402

OUT = Path(__file__).resolve().parent / "results"
METHODS = ("video", "atw", "warp", "sas", "tss", "quads")


def freezes(frames: list[dict[str, Any]]) -> list[float]:
    """Durations (ms) of display stretches showing one update (the first update onwards)."""
    out, start, cur = [], None, None
    for f in frames:
        u = f["update_frame_id"]
        if u < 0:
            continue
        if u != cur:
            if start is not None:
                out.append((f["t_s"] - start) * 1000)
            start, cur = f["t_s"], u
    if start is not None and frames:
        out.append((frames[-1]["t_s"] - start) * 1000)
    return out


def figures(res: Any, steps: tuple[float, float, float]) -> dict[str, Any]:
    a, b, _ = steps
    lo, hi = a, a + b                                   # the low step
    fr, ups = res.frames, res.updates
    mtp = np.array([f["motion_to_photon_ms"] for f in fr])
    t = np.array([f["t_s"] for f in fr])
    age = np.array([f["update_age_ms"] for f in fr])
    low = (t >= lo) & (t < hi)
    ok = np.isfinite(mtp)
    psnr = np.array([f.get("model_psnr_db", np.nan) for f in fr])
    fz = freezes(fr)
    # utilisation over the steady parts: each step less its first second
    cap = {0: 20.0, 1: 2.0, 2: 20.0}
    bounds = [(0.0, a), (a, a + b), (a + b, sum(steps))]
    sent = cap_sum = 0.0
    for k, (s, e) in enumerate(bounds):
        byts = sum(u["bytes"] for u in ups if s + 1.0 <= u["t_s"] < e)
        sent += byts * 8 / 1e6
        cap_sum += cap[k] * max(0.0, e - s - 1.0)
    recovery = float("nan")
    for t0 in np.arange(lo, hi, 0.1):
        w = (t >= t0) & (t < t0 + 0.5) & np.isfinite(age)
        if w.any() and np.percentile(age[w], 95) < 150:
            recovery = float(t0 - lo)
            break
    return {"mtp_p50_ms": float(np.percentile(mtp[ok], 50)), "mtp_p95_ms": float(np.percentile(mtp[ok], 95)),
            "low_mtp_p50_ms": float(np.percentile(mtp[ok & low], 50)) if (ok & low).any() else float("nan"),
            "low_mtp_p95_ms": float(np.percentile(mtp[ok & low], 95)) if (ok & low).any() else float("nan"),
            "freezes_over_250ms": int(sum(x > 250 for x in fz)), "freezes_over_500ms": int(sum(x > 500 for x in fz)),
            "longest_freeze_ms": float(max(fz)) if fz else float("nan"), "utilisation": sent / cap_sum,
            "model_psnr_db": float(np.nanmean(psnr)), "low_model_psnr_db": float(np.nanmean(psnr[low])),
            "recovery_s": recovery, "mean_kbps": float(res.summary["mean_kbps"]),
            "encoder_restarts": int(res.summary.get("encoder_restarts", 0))}


def low_utilisation(res: Any, steps: tuple[float, float, float]) -> float:
    """Bits of the updates that arrived during the low step (its first second left out) over its capacity
    (2 Mbit/s): where the link binds.  Probes and retransmissions are not counted."""
    a, b, _ = steps
    got = sum(u["bytes"] for u in res.updates if np.isfinite(u.get("arrival_s", np.nan)) and a + 1.0 <= u["arrival_s"] < a + b)
    return float(got * 8 / (b - 1.0) / 2e6) if b > 1.0 else float("nan")


def timeline(res: Any, step_s: float = 0.25) -> dict[str, list[float]]:
    ups, fr = res.updates, res.frames
    end = max(f["t_s"] for f in fr)
    edges = np.arange(0.0, end + step_s, step_s)
    kbps, age = [], []
    for s in edges[:-1]:
        kbps.append(sum(u["bytes"] for u in ups if s <= u["t_s"] < s + step_s) * 8 / step_s / 1000)
        a = [f["update_age_ms"] for f in fr if s <= f["t_s"] < s + step_s and np.isfinite(f["update_age_ms"])]
        age.append(float(max(a)) if a else float("nan"))
    return {"t_s": [float(x) for x in edges[:-1]], "sent_kbps": kbps, "max_age_ms": age}


def chart(runs: list[dict[str, Any]], steps: tuple[float, float, float], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(dict.fromkeys(r["method"] for r in runs))
    fig, axes = plt.subplots(2, len(methods), figsize=(3.0 * len(methods), 5.2), sharex=True, squeeze=False)
    a, b, c = steps
    cap_t = [0, a, a, a + b, a + b, a + b + c]
    cap_v = [20, 20, 2, 2, 20, 20]
    for j, m in enumerate(methods):
        top, bot = axes[0][j], axes[1][j]
        for r in runs:
            if r["method"] != m:
                continue
            style = "-" if r["adapt"] == "rate" else "--"
            tl = r["timeline"]
            top.plot(tl["t_s"], np.array(tl["sent_kbps"]) / 1000, style, label=f"adapt {r['adapt']}")
            bot.plot(tl["t_s"], tl["max_age_ms"], style, label=f"adapt {r['adapt']}")
        top.plot(cap_t, cap_v, color="0.6", lw=1, label="capacity")
        top.set_title(m)
        top.set_yscale("log")
        bot.set_yscale("log")
        bot.set_xlabel("time (s)")
        if j == 0:
            top.set_ylabel("sent (Mbit/s)")
            bot.set_ylabel("oldest update shown (ms)")
            top.legend(fontsize=7)
        for ax in (top, bot):
            ax.axvspan(a, a + b, color="0.92", zorder=0)
            ax.grid(alpha=0.3)
    fig.suptitle("Under a changing link: 20 -> 2 -> 20 Mbit/s (shaded: the low step)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--steps", default="3,4,3", help="seconds at 20, 2 and 20 Mbit/s (the walk trace lasts 10 s)")
    ap.add_argument("--size", default="320x180")
    args = ap.parse_args()
    from splitrender.render.renderer import Renderer
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import run

    steps = tuple(float(x) for x in args.steps.split(","))
    assert len(steps) == 3
    w, h = (int(x) for x in args.size.split("x"))
    tmp = Path(tempfile.mkdtemp(prefix="bench_adapt_"))
    trace = write_mahimahi(step_trace([(steps[0], 20.0), (steps[1], 2.0), (steps[2], 20.0)]), tmp / "step.trace")
    renderer = Renderer()
    runs = []
    t0 = time.perf_counter()
    for m in args.methods.split(","):
        for adapt in ("off", "rate"):
            w0 = time.perf_counter()
            cfg = RunConfig(method=m, scene="default+nogi", trace="walk", network=f"delay 20ms trace {trace}",
                            duration_s=sum(steps), width=w, height=h, client_fps=30, flip_every=0, seed=0,
                            transport_cc=True, adapt=adapt, truth_cache=str(tmp / "truth"))
            res = run(cfg, renderer=renderer)
            f = figures(res, steps)  # type: ignore[arg-type]
            tl = timeline(res)
            f["low_utilisation"] = low_utilisation(res, steps)  # type: ignore[arg-type]
            runs.append({"method": m, "adapt": adapt, **f, "timeline": tl, "wall_s": time.perf_counter() - w0})
            print(f"{m:6s} {adapt:4s} mtp p95 {f['mtp_p95_ms']:7.0f} ms (low step {f['low_mtp_p95_ms']:7.0f}), "
                  f"freezes>500 {f['freezes_over_500ms']}, longest {f['longest_freeze_ms']:5.0f} ms, "
                  f"util {f['utilisation']:.2f} (low {f['low_utilisation']:.2f}), model PSNR {f['model_psnr_db']:.2f} (low {f['low_model_psnr_db']:.2f}), "
                  f"recovery {f['recovery_s']:.2f} s, {f['mean_kbps']:.0f} kbit/s", flush=True)
    compare = {}
    for m in dict.fromkeys(r["method"] for r in runs):
        off = next(r for r in runs if r["method"] == m and r["adapt"] == "off")
        on = next(r for r in runs if r["method"] == m and r["adapt"] == "rate")
        compare[m] = {"low_mtp_p95_ms_off": off["low_mtp_p95_ms"], "low_mtp_p95_ms_rate": on["low_mtp_p95_ms"],
                      "psnr_db_rate_minus_off": on["model_psnr_db"] - off["model_psnr_db"],
                      "utilisation_off": off["utilisation"], "utilisation_rate": on["utilisation"],
                      "low_utilisation_off": off["low_utilisation"], "low_utilisation_rate": on["low_utilisation"],
                      "recovery_s_off": off["recovery_s"], "recovery_s_rate": on["recovery_s"]}
    OUT.mkdir(parents=True, exist_ok=True)
    out = {"benchmark": "bench_adapt", "steps_s": steps, "capacity_mbps": [20, 2, 20], "size": [w, h],
           "scene": "default+nogi", "trace": "walk", "compare": compare, "runs": runs,
           "wall_s": time.perf_counter() - t0, "machine": platform.machine(), "cpus": os.cpu_count(),
           "load_avg": os.getloadavg()}
    (OUT / "bench_adapt.json").write_text(json.dumps(out, indent=1) + "\n")
    chart(runs, steps, OUT / "bench_adapt.png")  # type: ignore[arg-type]
    print(f"-> {OUT / 'bench_adapt.json'}, {OUT / 'bench_adapt.png'}")


if __name__ == "__main__":
    main()
