"""Study: under a changing link (issue 35).

Every thin-client method (``video``, ``atw``, ``warp``, ``sas``, ``tss``, ``quads``; not ``probes``, whose client draws
the scene) with rate adaptation off, ``rate`` (the encoders follow the estimate) and ``full`` (the method's own
knobs too), over two generated capacity traces with 20 ms each way, transport-wide feedback in every run:

- a **step** trace, 20 -> 2 -> 20 Mbit/s (5, 5 and 10 s; the quick study 3, 4 and 3 s);
- a **cellular-like** trace (:func:`~splitrender.netsim.traces.cellular_trace`: mean 8 Mbit/s, coefficient of
  variation 0.5, 1 s correlation, 2 % outages; 20 s, seed 0; not in the quick study).

Per run: model PSNR (the scene's model, without sky and floor), motion-to-photon p50 and p95, freezes (display
stretches showing one update) longer than 250 and 500 ms, utilisation (bits sent over the capacity in the steady
parts: each step less its first second; the whole cellular run less its first second), and for the step the time
after the drop until the p95 update age over 0.5 s is back under 150 ms.  Timelines (sent rate against capacity,
update age) per method and a summary table.

The figures, the timelines and the chart are this module's, shared with ``benchmarks/bench_adapt.py``.
"""

from __future__ import annotations

import logging
import math
import os
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ...methods import get_method, methods_for_scene
from ...netsim.models import load_mahimahi_trace
from ...netsim.traces import cellular_trace, step_trace, trace_stats, write_mahimahi
from ...render.renderer import Renderer
from ...sim.config import RunConfig
from ...sim.runner import run as run_one
from ...tabular import write_csv
from ..charts import method_order
from ..sections import Section
from ._util import STUDY_SCENE, save_figure

log = logging.getLogger(__name__)

MODES = ("off", "rate", "full")
STEP_FULL = ((5.0, 20.0), (5.0, 2.0), (10.0, 20.0))
STEP_QUICK = ((3.0, 20.0), (4.0, 2.0), (3.0, 20.0))
COLUMNS = ("trace", "method", "adapt", "model_psnr_db", "low_model_psnr_db", "mtp_p50_ms", "mtp_p95_ms",
           "low_mtp_p95_ms", "freezes_over_250ms", "freezes_over_500ms", "longest_freeze_ms", "utilisation",
           "recovery_s", "mean_kbps", "encoder_restarts", "point_moves", "lowest_point")


def freezes(frames: Sequence[dict[str, Any]]) -> list[float]:
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


def capacity_mbps(stamps_ms: np.ndarray, a_s: float, b_s: float) -> float:
    """A mahimahi trace's capacity over ``[a_s, b_s)`` (one 1500-byte packet per timestamp)."""
    n = int(((stamps_ms >= a_s * 1000) & (stamps_ms < b_s * 1000)).sum())
    return n * 1500 * 8 / max(1e-9, b_s - a_s) / 1e6


def figures(res: Any, stamps_ms: np.ndarray, steady: Sequence[tuple[float, float]],
            low: tuple[float, float] | None = None) -> dict[str, Any]:
    """A run's figures (module docstring); ``steady``: the spans utilisation is measured over; ``low``: the
    low-capacity span of a step trace (its own MTP and PSNR, and the recovery after its start)."""
    fr, ups = res.frames, res.updates
    t = np.array([f["t_s"] for f in fr])
    mtp = np.array([f["motion_to_photon_ms"] for f in fr])
    age = np.array([f["update_age_ms"] for f in fr])
    psnr = np.array([f.get("model_psnr_db", np.nan) for f in fr])
    ok = np.isfinite(mtp)
    fz = freezes(fr)
    sent = sum(u["bytes"] for a, b in steady for u in ups if a <= u["t_s"] < b) * 8 / 1e6
    cap = sum(capacity_mbps(stamps_ms, a, b) * (b - a) for a, b in steady)
    out: dict[str, Any] = {
        "model_psnr_db": float(np.nanmean(psnr)) if np.isfinite(psnr).any() else math.nan,
        "mtp_p50_ms": float(np.percentile(mtp[ok], 50)) if ok.any() else math.nan,
        "mtp_p95_ms": float(np.percentile(mtp[ok], 95)) if ok.any() else math.nan,
        "freezes_over_250ms": int(sum(x > 250 for x in fz)), "freezes_over_500ms": int(sum(x > 500 for x in fz)),
        "longest_freeze_ms": float(max(fz)) if fz else math.nan, "utilisation": sent / cap if cap > 0 else math.nan,
        "mean_kbps": float(res.summary["mean_kbps"]), "encoder_restarts": int(res.summary.get("encoder_restarts", 0)),
        "point_moves": int(res.summary.get("point_moves", 0)), "lowest_point": int(res.summary.get("lowest_point", 0)),
        "low_model_psnr_db": math.nan, "low_mtp_p95_ms": math.nan, "recovery_s": math.nan}
    if low is not None:
        lo, hi = low
        w = (t >= lo) & (t < hi)
        out["low_model_psnr_db"] = float(np.nanmean(psnr[w])) if np.isfinite(psnr[w]).any() else math.nan
        out["low_mtp_p95_ms"] = float(np.percentile(mtp[ok & w], 95)) if (ok & w).any() else math.nan
        for t0 in np.arange(lo, hi, 0.1):
            win = (t >= t0) & (t < t0 + 0.5) & np.isfinite(age)
            if win.any() and np.percentile(age[win], 95) < 150:
                out["recovery_s"] = float(t0 - lo)
                break
    return out


def timeline(res: Any, step_s: float = 0.25) -> dict[str, list[float]]:
    """Sent rate (kbit/s), the oldest update shown (ms) and the mean model PSNR (dB) per ``step_s``."""
    ups, fr = res.updates, res.frames
    end = max(f["t_s"] for f in fr)
    edges = np.arange(0.0, end + step_s, step_s)
    kbps, age, psnr = [], [], []
    for s in edges[:-1]:
        kbps.append(sum(u["bytes"] for u in ups if s <= u["t_s"] < s + step_s) * 8 / step_s / 1000)
        win = [f for f in fr if s <= f["t_s"] < s + step_s]
        a = [f["update_age_ms"] for f in win if np.isfinite(f["update_age_ms"])]
        age.append(float(max(a)) if a else float("nan"))
        p = [f["model_psnr_db"] for f in win if np.isfinite(f.get("model_psnr_db", np.nan))]
        psnr.append(float(np.mean(p)) if p else float("nan"))
    return {"t_s": [float(x) for x in edges[:-1]], "sent_kbps": kbps, "max_age_ms": age, "model_psnr_db": psnr}


def chart(runs: Sequence[dict[str, Any]], stamps_ms: np.ndarray, title: str, path: Path,
          shade: tuple[float, float] | None = None) -> Path:
    """Per method: sent rate against the capacity (top), the oldest update shown and the model PSNR, one line per
    mode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(dict.fromkeys(r["method"] for r in runs))
    fig, axes = plt.subplots(3, len(methods), figsize=(3.0 * len(methods), 7.4), sharex=True, squeeze=False)
    end = max(max(r["timeline"]["t_s"]) for r in runs) + 0.25
    ct = np.arange(0.0, end, 0.25)
    cap = [capacity_mbps(stamps_ms, a, a + 0.25) for a in ct]
    for j, m in enumerate(methods):
        top, bot, qual = axes[0][j], axes[1][j], axes[2][j]
        top.step(ct, cap, where="post", color="0.6", lw=1, label="capacity")
        for r in runs:
            if r["method"] != m:
                continue
            style = {"off": "--", "rate": ":"}.get(r["adapt"], "-")
            tl = r["timeline"]
            top.plot(tl["t_s"], np.maximum(np.array(tl["sent_kbps"]) / 1000, 1e-3), style, label=f"adapt {r['adapt']}")
            bot.plot(tl["t_s"], tl["max_age_ms"], style, label=f"adapt {r['adapt']}")
            if "model_psnr_db" in tl:
                qual.plot(tl["t_s"], tl["model_psnr_db"], style, label=f"adapt {r['adapt']}")
        top.set_title(m)
        top.set_yscale("log")
        bot.set_yscale("log")
        qual.set_xlabel("time (s)")
        if j == 0:
            top.set_ylabel("sent (Mbit/s)")
            bot.set_ylabel("oldest update shown (ms)")
            qual.set_ylabel("model PSNR (dB)")
            top.legend(fontsize=7)
        for ax in (top, bot, qual):
            if shade is not None:
                ax.axvspan(*shade, color="0.92", zorder=0)
            ax.grid(alpha=0.3)
    fig.suptitle(title)
    return save_figure(fig, path)


def step_spans(steps: Sequence[tuple[float, float]]) -> tuple[list[tuple[float, float]], tuple[float, float]]:
    """The steady spans of a step trace (each step less its first second) and its lowest step's span."""
    spans, t, low, low_rate = [], 0.0, (0.0, 0.0), math.inf
    for dur, mbps in steps:
        if dur > 1.0:
            spans.append((t + 1.0, t + dur))
        if mbps < low_rate:
            low, low_rate = (t, t + dur), mbps
        t += dur
    return spans, low


TRACES_ENV = "SPLITRENDER_LINK_TRACES"
"""Extra capacity traces for the study: mahimahi files (e.g. its public LTE traces), comma-separated."""


def extra_traces() -> list[tuple[str, np.ndarray]]:
    """The trace files named in :data:`TRACES_ENV` with their timestamps, each read once (a
    :class:`NetworkConfigError` names a bad one before anything runs)."""
    paths = [p.strip() for p in os.environ.get(TRACES_ENV, "").split(",") if p.strip()]
    return [(p, load_mahimahi_trace(p)) for p in paths]


def run(out_dir: Path, quick: bool, methods: Sequence[str] | None = None, modes: Sequence[str] = MODES) -> Section:
    """Run the study into ``out_dir``: ``link_results.csv``, one chart per trace, and the section."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if methods is None:
        methods = [m for m in method_order(methods_for_scene(STUDY_SCENE)) if not get_method(m).client_draws_scene]
    if quick:
        modes = tuple(m for m in modes if m != "rate") or modes
    steps = STEP_QUICK if quick else STEP_FULL
    traces: list[tuple[str, np.ndarray, list[tuple[float, float]], tuple[float, float] | None]] = []
    spans, low = step_spans(steps)
    traces.append(("step", step_trace(list(steps)), spans, low))
    if not quick:
        traces.append(("cellular", cellular_trace(20.0, 8.0, 0.5, seed=0), [(1.0, 20.0)], None))
    for path, stamps in extra_traces():   # public traces a user brings (never committed): their first 20 s
        traces.append((Path(path).stem, stamps, [(1.0, 20.0)], None))
    renderer = Renderer()
    rows: list[dict[str, Any]] = []
    runs: dict[str, list[dict[str, Any]]] = {}
    t0 = time.perf_counter()
    for name, stamps, steady, lowspan in traces:
        path = write_mahimahi(stamps, out_dir / f"{name}.trace")
        dur = sum(d for d, _ in steps) if name == "step" else min(20.0, stamps[-1] / 1000)
        for m in methods:
            for adapt in modes:
                cfg = RunConfig(method=m, scene=STUDY_SCENE, trace="walk", network=f"delay 20ms trace {path}",
                                duration_s=dur, width=320, height=180, client_fps=30, flip_every=0, seed=0,
                                transport_cc=True, adapt=adapt)
                res = run_one(cfg, renderer=renderer)
                f = figures(res, stamps, steady, lowspan)
                rows.append({"trace": name, "method": m, "adapt": adapt, **f})
                runs.setdefault(name, []).append({"method": m, "adapt": adapt, "timeline": timeline(res)})
                log.info("link study: %s %s %s -> mtp p95 %.0f ms, %.2f dB", name, m, adapt, f["mtp_p95_ms"],
                         f["model_psnr_db"])
    elapsed = time.perf_counter() - t0
    table = out_dir / "link_results.csv"
    write_csv(table, ({k: r[k] for k in COLUMNS} for r in rows))
    figs = []
    for name, stamps, _, lowspan in traces:
        if name == "step":
            title = "Step: " + " -> ".join(f"{mbps:g}" for _, mbps in steps) + " Mbit/s (shaded: the low step)"
        elif name == "cellular":
            title = "Cellular-like: mean 8 Mbit/s, cv 0.5, 2 % outages"
        else:
            st = trace_stats(stamps)
            title = (f"{name} (its first 20 s; whole trace: mean {st['mean_mbps']:.1f} Mbit/s, cv {st['cv']:.2f}, "
                     f"{100 * st['outage_share']:.0f} % outages)")
        figs.append(chart(runs[name], stamps, title, out_dir / f"link_{name}.png", lowspan))

    def cell(v: float, fmt: str) -> str:
        return "-" if not np.isfinite(v) else format(v, fmt)

    head = ("| trace | method | adapt | model PSNR dB | MTP p50 / p95 ms | freezes >250 / >500 ms | longest freeze ms | "
            "utilisation | recovery s |\n|---|---|---|---|---|---|---|---|---|")
    lines = [f"| {r['trace']} | {r['method']} | {r['adapt']} | {cell(r['model_psnr_db'], '.2f')} | "
             f"{cell(r['mtp_p50_ms'], '.0f')} / {cell(r['mtp_p95_ms'], '.0f')} | {r['freezes_over_250ms']} / "
             f"{r['freezes_over_500ms']} | {cell(r['longest_freeze_ms'], '.0f')} | {cell(r['utilisation'], '.2f')} | "
             f"{cell(r['recovery_s'], '.1f')} |" for r in rows]
    text = (
        "Every thin-client method with rate adaptation off, `rate` (each lossy encoder follows the estimate) and "
        "`full` (the method's own knobs too: resolution, atlas budget, depth bits and samples, layers, server frame "
        f"rate) over generated capacity traces, 20 ms each way; `{STUDY_SCENE}`, `walk`, 320x180 at 30 Hz"
        f"{'' if not quick else ' (quick: the short step, off and full only)'}; {len(rows)} runs in {elapsed:.0f} s. "
        "Motion-to-photon is from the pose a frame was made for to its display; utilisation is over the steady parts "
        "(each step less its first second); recovery is the time from the drop until the p95 update age over 0.5 s "
        "is under 150 ms (- : never within the low step).\n\n"
        f"{head}\n" + "\n".join(lines) + "\n\n"
        "At 320x180 each method's own operating point uses a fraction of 20 Mbit/s and adaptation never asks more "
        "than the method takes at its own rate control, so utilisation is low where the link is wide by design; "
        "where it binds (the low step, the cellular dips), what matters is whether the queue stays short."
    )
    return Section("Under a changing link (rate adaptation)", text, figs, [table])
