"""Study: under a changing link (issue 35; issue 48, part 5).

Every thin-client method (``video``, ``atw``, ``warp``, ``sas``, ``tss``, ``quads``; not ``probes``, whose client draws
the scene) with rate adaptation off, ``rate`` (the encoders follow the estimate) and ``full`` (the method's own
knobs too), over generated capacity traces with 20 ms each way, transport-wide feedback in every run:

- a **step** trace, 20 -> 2 -> 20 Mbit/s (5, 5 and 10 s; the quick study 3, 4 and 3 s);
- two **cellular-like** traces (:data:`~splitrender.netsim.traces.CELLULAR_LIKE`, the adaptation benchmarks' own:
  cv 0.5, 1 s correlation, 2 % outages, 20 s, seed 0): ``cellular`` at a mean of 4 Mbit/s, where every method meets
  the link, and ``cellular8`` at 8 Mbit/s, where ``sas`` and ``tss`` meet it only in its dips; not in the quick study.

Per run: model PSNR (the scene's model, without sky and floor), motion-to-photon p50 and p95, freezes (display
stretches showing one update) longer than 250 and 500 ms, utilisation (bits sent over the capacity in the steady
parts: each step less its first second; the whole cellular run less its first second), and for the step the time
after the drop until the p95 update age over 0.5 s is back under 150 ms; and per 0.5 s (:func:`timeline`) the sent
rate, the capacity, the model PSNR, the p95 motion-to-photon, the oldest update shown and the operating point.
Charts: per trace, those over time, a column per method and a line per mode (:func:`chart`); and the quality-latency
front, per method each mode's point (p95 motion-to-photon, model PSNR; :func:`front_chart`).

Each (trace, method, mode) is one :class:`~splitrender.sim.config.RunConfig` run through the sweep executor into the
study's result store (:meth:`LinkStudy.cells`, ``<out>/store``; ``splitrender study link --workers N --dask ADDRESS``):
a second invocation runs only what is missing, and ``store/link_history.json`` keeps what each invocation ran, as the
runs finish.  The figures come from the stored run's tables (its frames and updates), so a run made by an earlier
invocation counts the same.  The trace files are written under ``<out>/traces/`` with a digest of their content in
the name, which the run's network string (and so its key) names: the same trace gives the same key in every
invocation, another trace another key.  So is the camera's ``walk`` where the runs are longer than a built-in
trace's 10 s (:func:`camera_trace`: a run on a built-in trace stops at 10 s, so until this study ran on the store its
"20 s" runs were 10 s long).  The full run publishes its section, charts and tables in
``docs/results/link/`` (:data:`DOC_DIR`) in a source checkout.  The grid is module-level (:data:`GRID`) so a test can
shrink it.

The figures, the timelines and the chart are this module's, shared with ``benchmarks/bench_adapt.py``.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ...methods import get_method, methods_for_scene
from ...netsim.models import load_mahimahi_trace
from ...netsim.traces import CELLULAR_LIKE, named_cellular_trace, step_trace, trace_stats, write_mahimahi
from ...scene.trace import BUILTIN_TRACES, DEFAULT_DURATION_S
from ...sim.config import RunConfig
from ...sim.truth import shared_cache_setting
from ..charts import method_order
from ..sections import Section
from ._study import Study
from ._util import ROOT, STUDY_SCENE, run_command, save_figure, store_history_text

log = logging.getLogger(__name__)

MODES = ("off", "rate", "full")
STEP_FULL = ((5.0, 20.0), (5.0, 2.0), (10.0, 20.0))
STEP_QUICK = ((3.0, 20.0), (4.0, 2.0), (3.0, 20.0))
COLUMNS = ("trace", "method", "adapt", "model_psnr_db", "low_model_psnr_db", "mtp_p50_ms", "mtp_p95_ms",
           "low_mtp_p95_ms", "freezes_over_250ms", "freezes_over_500ms", "longest_freeze_ms", "utilisation",
           "recovery_s", "mean_kbps", "encoder_restarts", "point_moves", "lowest_point")
TIMELINE_COLUMNS = ("trace", "method", "adapt", "t_s", "capacity_mbps", "sent_kbps", "model_psnr_db", "mtp_p95_ms",
                    "max_age_ms", "point")
TIMELINE_S = 0.5
"""The study's timeline step (s)."""
NETWORK = "delay 20ms trace {path}"
"""Every run's network: 20 ms each way and the trace's capacity downlink."""

#: the grid per mode (``GRID[quick]``); ``methods`` None: every thin-client method of the scene; a test may replace
#: entries
GRID: dict[bool, dict[str, Any]] = {
    True: {"size": (320, 180), "steps": STEP_QUICK, "cellular": (), "cellular_s": 20.0, "modes": ("off", "full"),
           "methods": None, "workers": 2},
    False: {"size": (320, 180), "steps": STEP_FULL, "cellular": ("cellular", "cellular8"), "cellular_s": 20.0,
            "modes": MODES, "methods": None, "workers": 2},
}

DOC_DIR: Path | None = ROOT / "docs" / "results" / "link" if (ROOT / "docs").is_dir() else None
"""Where the full run publishes its section, charts and tables in a source checkout (a test may set it to None)."""


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
    """A run's figures (module docstring); ``res`` a run result or a :class:`StoredRun` (``frames``, ``updates``,
    ``summary``); ``steady``: the spans utilisation is measured over; ``low``: the low-capacity span of a step trace
    (its own MTP and PSNR, and the recovery after its start)."""
    fr, ups = res.frames, res.updates
    t = np.array([f["t_s"] for f in fr])
    mtp = np.array([f["motion_to_photon_ms"] for f in fr], dtype=float)
    age = np.array([f["update_age_ms"] for f in fr], dtype=float)
    psnr = np.array([f.get("model_psnr_db", np.nan) for f in fr], dtype=float)
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
    """Per ``step_s``: the sent rate (kbit/s), the oldest update shown (ms), the mean model PSNR (dB), the p95
    motion-to-photon (ms) and the operating point at the last update (``adapt_point``; NaN without)."""
    ups, fr = res.updates, res.frames
    end = max(f["t_s"] for f in fr)
    edges = np.arange(0.0, end + step_s, step_s)
    ft = np.array([f["t_s"] for f in fr])
    fage = np.array([f["update_age_ms"] for f in fr], dtype=float)
    fpsnr = np.array([f.get("model_psnr_db", np.nan) for f in fr], dtype=float)
    fmtp = np.array([f["motion_to_photon_ms"] for f in fr], dtype=float)
    ut = np.array([u["t_s"] for u in ups])
    ubytes = np.array([u["bytes"] for u in ups], dtype=float)
    upoint = np.array([u.get("adapt_point", np.nan) for u in ups], dtype=float)
    out: dict[str, list[float]] = {"t_s": [], "sent_kbps": [], "max_age_ms": [], "model_psnr_db": [],
                                   "mtp_p95_ms": [], "point": []}
    for s in edges[:-1]:
        w = (ft >= s) & (ft < s + step_s)
        u = (ut >= s) & (ut < s + step_s)
        a, p, m = fage[w & np.isfinite(fage)], fpsnr[w & np.isfinite(fpsnr)], fmtp[w & np.isfinite(fmtp)]
        out["t_s"].append(float(s))
        out["sent_kbps"].append(float(ubytes[u].sum()) * 8 / step_s / 1000)
        out["max_age_ms"].append(float(a.max()) if a.size else math.nan)
        out["model_psnr_db"].append(float(p.mean()) if p.size else math.nan)
        out["mtp_p95_ms"].append(float(np.percentile(m, 95)) if m.size else math.nan)
        out["point"].append(float(upoint[u][-1]) if u.any() else math.nan)
    return out


def _log_if_wide(ax: Any, axis: str = "y", ratio: float = 5.0) -> None:
    """A log scale (plain numbers on its ticks) where the axis's data spans more than ``ratio``, else linear."""
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    lo, hi = ax.dataLim.intervaly if axis == "y" else ax.dataLim.intervalx
    if np.isfinite(lo) and np.isfinite(hi) and lo > 0 and hi / lo > ratio:
        getattr(ax, f"set_{axis}scale")("log")
        a = ax.yaxis if axis == "y" else ax.xaxis
        a.set_major_formatter(ScalarFormatter())
        a.set_minor_formatter(NullFormatter())


MODE_STYLE = {"off": "--", "rate": ":"}
"""A mode's line in the charts (``full`` and others: solid)."""
MODE_MARKER = {"off": "o", "rate": "s", "full": "^"}


def chart(runs: Sequence[dict[str, Any]], stamps_ms: np.ndarray, title: str, path: Path,
          shade: tuple[float, float] | None = None) -> Path:
    """Per method (a column each): sent rate against the capacity, the model PSNR, the p95 motion-to-photon (where
    the timelines have it) and the oldest update shown, over time, one line per mode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(dict.fromkeys(r["method"] for r in runs))
    rows = ["sent", "psnr", *(["mtp"] if all("mtp_p95_ms" in r["timeline"] for r in runs) else []), "age"]
    fig, axes = plt.subplots(len(rows), len(methods), figsize=(3.0 * len(methods), 2.4 * len(rows) + 0.2),
                             sharex=True, squeeze=False)
    step = min(float(np.diff(r["timeline"]["t_s"]).min()) if len(r["timeline"]["t_s"]) > 1 else 0.25 for r in runs)
    end = max(max(r["timeline"]["t_s"]) for r in runs) + step
    ct = np.arange(0.0, end, step)
    cap = [capacity_mbps(stamps_ms, a, a + step) for a in ct]
    ylabel = {"sent": "sent (Mbit/s)", "psnr": "model PSNR (dB)", "mtp": "motion-to-photon p95 (ms)",
              "age": "oldest update shown (ms)"}
    for j, m in enumerate(methods):
        ax = {k: axes[i][j] for i, k in enumerate(rows)}
        ax["sent"].step(ct, cap, where="post", color="0.6", lw=1, label="capacity")
        for r in runs:
            if r["method"] != m:
                continue
            style, tl, lab = MODE_STYLE.get(r["adapt"], "-"), r["timeline"], f"adapt {r['adapt']}"
            ax["sent"].plot(tl["t_s"], np.maximum(np.array(tl["sent_kbps"]) / 1000, 1e-3), style, label=lab)
            ax["psnr"].plot(tl["t_s"], tl["model_psnr_db"], style, label=lab)
            if "mtp" in ax:
                ax["mtp"].plot(tl["t_s"], tl["mtp_p95_ms"], style, label=lab)
            ax["age"].plot(tl["t_s"], tl["max_age_ms"], style, label=lab)
        ax["sent"].set_title(m)
        for k in ("sent", "mtp", "age"):
            if k in ax:
                _log_if_wide(ax[k])
        axes[-1][j].set_xlabel("time (s)")
        for k, a in ax.items():
            if j == 0:
                a.set_ylabel(ylabel[k])
            if shade is not None:
                a.axvspan(*shade, color="0.92", zorder=0)
            a.grid(alpha=0.3)
        if j == 0:
            ax["sent"].legend(fontsize=7)
    fig.suptitle(title)
    return save_figure(fig, path)


def front_chart(rows: Sequence[dict[str, Any]], titles: dict[str, str], path: Path) -> Path:
    """The quality-latency front, a panel per trace: per method (a colour) each mode's point (a marker), p95
    motion-to-photon against model PSNR, the modes joined in :data:`MODES` order."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    traces = list(dict.fromkeys(r["trace"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    colours = {m: f"C{i % 10}" for i, m in enumerate(methods)}
    fig, axes = plt.subplots(1, len(traces), figsize=(max(7.5, 4.6 * len(traces)), 4.2), squeeze=False)
    for ax, tr in zip(axes[0], traces):
        for m in methods:
            pts = [r for mode in MODES for r in rows if r["trace"] == tr and r["method"] == m and r["adapt"] == mode
                   and np.isfinite(r["mtp_p95_ms"]) and np.isfinite(r["model_psnr_db"])]
            if not pts:
                continue
            ax.plot([r["mtp_p95_ms"] for r in pts], [r["model_psnr_db"] for r in pts], "-", color=colours[m], lw=1,
                    alpha=0.6)
            for r in pts:
                ax.plot(r["mtp_p95_ms"], r["model_psnr_db"], MODE_MARKER.get(r["adapt"], "o"), color=colours[m], ms=7)
        _log_if_wide(ax, "x")
        ax.set_xlabel("motion-to-photon p95 (ms)")
        ax.set_ylabel("model PSNR (dB)")
        ax.set_title(titles.get(tr, tr), fontsize=9)
        ax.grid(alpha=0.3, which="both")
    handles = ([Line2D([], [], color=colours[m], lw=2, label=m) for m in methods]
               + [Line2D([], [], color="0.3", marker=MODE_MARKER[k], ls="", label=f"adapt {k}") for k in MODES
                  if any(r["adapt"] == k for r in rows)])
    axes[0][-1].legend(handles=handles, fontsize=7, loc="best")
    fig.suptitle("Model PSNR against p95 motion-to-photon, each mode's point (up and left is better)", fontsize=10)
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


@dataclass(frozen=True)
class LinkTrace:
    """One capacity trace of the study: its name, timestamps (ms), the runs' duration (s), the spans utilisation is
    measured over, the low step's span (step traces) and the chart's title."""

    name: str
    stamps: np.ndarray
    duration_s: float
    steady: list[tuple[float, float]]
    low: tuple[float, float] | None
    title: str


def study_traces(g: dict[str, Any]) -> list[LinkTrace]:
    """The grid's traces: the step, the named cellular-like ones, and a user's (:data:`TRACES_ENV`, its first 20 s)."""
    steps = g["steps"]
    spans, low = step_spans(steps)
    out = [LinkTrace("step", step_trace(list(steps)), float(sum(d for d, _ in steps)), spans, low,
                     "Step: " + " -> ".join(f"{mbps:g}" for _, mbps in steps) + " Mbit/s (shaded: the low step)")]
    dur = float(g["cellular_s"])
    for name in g["cellular"]:
        p = CELLULAR_LIKE[name]
        out.append(LinkTrace(name, named_cellular_trace(name, dur), dur, [(1.0, dur)], None,
                             f"{name}: cellular-like, mean {p['mean_mbps']:g} Mbit/s, cv {p['cv']:g}, "
                             f"{100 * p.get('outage_share', 0.02):g} % outages"))
    for path, stamps in extra_traces():   # public traces a user brings (never committed): their first 20 s
        st = trace_stats(stamps)
        d = min(20.0, float(stamps[-1]) / 1000)
        out.append(LinkTrace(Path(path).stem, stamps, d, [(1.0, d)], None,
                             f"{Path(path).stem} (its first {d:g} s; whole trace: mean {st['mean_mbps']:.1f} Mbit/s, "
                             f"cv {st['cv']:.2f}, {100 * st['outage_share']:.0f} % outages)"))
    return out


def trace_file(folder: Path, tr: LinkTrace) -> Path:
    """``folder/<name>-<digest>.trace`` (absolute; written unless there): the digest of the timestamps names the file,
    so a run's network string, and so its key, changes exactly when its trace does."""
    digest = hashlib.sha256(np.asarray(tr.stamps, "<i8").tobytes()).hexdigest()[:12]
    p = (folder / f"{tr.name}-{digest}.trace").resolve()
    if not p.is_file():
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(p.name + ".tmp")
        write_mahimahi(tr.stamps, tmp)
        tmp.replace(p)
    return p


CAMERA = "walk"
"""The camera's built-in trace in every run."""


def camera_trace(folder: Path, duration_s: float) -> str:
    """The camera trace of runs ``duration_s`` long: :data:`CAMERA` itself where its default length covers them (10 s:
    a built-in trace in a run is that long), else the same walk generated for ``duration_s`` (its first 10 s are the
    built-in's, bit for bit) and written to ``folder/<name>-<duration>s-<digest>.csv`` (absolute), the digest naming
    its content as :func:`trace_file`'s does."""
    if duration_s <= DEFAULT_DURATION_S:
        return CAMERA
    text = BUILTIN_TRACES[CAMERA](duration_s).to_text()
    digest = hashlib.sha256(text.encode()).hexdigest()[:12]
    p = (folder / f"{CAMERA}-{duration_s:g}s-{digest}.csv").resolve()
    if not p.is_file():
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(p.name + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(p)
    return str(p)


def run_config(g: dict[str, Any], method: str, mode: str, path: Path, duration_s: float, camera: str = CAMERA,
               truth_cache: str = "") -> RunConfig:
    """One cell's run: ``method`` adapting by ``mode`` on the capacity trace file ``path``, the camera on the trace
    ``camera`` (:func:`camera_trace`)."""
    w, h = g["size"]
    return RunConfig(method=method, scene=STUDY_SCENE, trace=camera, network=NETWORK.format(path=path),
                     duration_s=duration_s, width=w, height=h, client_fps=30, flip_every=0, seed=0,
                     transport_cc=True, adapt=mode, truth_cache=truth_cache)


@dataclass
class StoredRun:
    """A run read back from the result store: what :func:`figures` and :func:`timeline` read."""

    summary: dict[str, Any]
    frames: list[dict[str, Any]]
    updates: list[dict[str, Any]]


def load_run(store: Any, cfg: RunConfig) -> StoredRun | None:
    """The stored run of ``cfg``, or None where it failed or is not in ``store``."""
    try:
        key = cfg.key()
        return StoredRun(store.load_summary(cfg), store.load_frames(key), store.load_updates(key))
    except (OSError, IndexError, ValueError):
        return None


class LinkStudy(Study):
    """The grid run into the study's store, ``link_results.csv`` and ``link_timelines.csv``, a chart per trace, the
    front, and the section (published in :data:`DOC_DIR` by the full run)."""

    name = "link"
    title = "Under a changing link (rate adaptation)"

    def __init__(self, out_dir: Path, quick: bool, methods: Sequence[str] | None = None,
                 modes: Sequence[str] | None = None) -> None:
        super().__init__(out_dir, quick)
        self.g = GRID[quick]
        ms = methods if methods is not None else self.g.get("methods")
        self.methods = list(ms) if ms is not None else [
            m for m in method_order(methods_for_scene(STUDY_SCENE)) if not get_method(m).client_draws_scene]
        self.modes = list(modes if modes is not None else self.g["modes"])
        self.traces = study_traces(self.g)
        self.rows: list[dict[str, Any]] = []
        self.runs: dict[str, list[dict[str, Any]]] = {}
        self.info: dict[str, Any] = {}

    def cells(self) -> None:
        """Run the cells the store does not hold yet, then read every cell's figures and timeline from the store."""
        truth = shared_cache_setting(self.out)
        camera = camera_trace(self.out / "traces", max(tr.duration_s for tr in self.traces))
        cells: list[tuple[LinkTrace, str, str, RunConfig]] = []
        for tr in self.traces:
            path = trace_file(self.out / "traces", tr)
            cells += [(tr, m, mode, run_config(self.g, m, mode, path, tr.duration_s, camera, truth))
                      for m in self.methods for mode in self.modes]
        grid = self.run_grid([c[3] for c in cells], self.g.get("workers", 2))
        res = grid.result
        failed: list[str] = []
        timelines: list[dict[str, Any]] = []
        for tr, m, mode, cfg in cells:
            run = load_run(self.store, cfg)
            if run is None or not run.frames:
                f = {k: math.nan for k in COLUMNS[3:]}
                failed.append(f"{tr.name} {m} {mode}")
            else:
                f = figures(run, tr.stamps, tr.steady, tr.low)
                tl = timeline(run, TIMELINE_S)
                self.runs.setdefault(tr.name, []).append({"method": m, "adapt": mode, "timeline": tl})
                for i, t in enumerate(tl["t_s"]):
                    timelines.append({"trace": tr.name, "method": m, "adapt": mode, "t_s": t,
                                      "capacity_mbps": capacity_mbps(tr.stamps, t, t + TIMELINE_S),
                                      **{k: tl[k][i] for k in TIMELINE_COLUMNS[5:]}})
            self.rows.append({"trace": tr.name, "method": m, "adapt": mode, **f, "config_key": cfg.key(),
                              "command": run_command(cfg)})
        self.info = {"runs": len(cells), "ran": len(res.ran), "cached": len(res.cached), "failed": failed,
                     "runs_s": grid.runs_s, "history": grid.history, "workers": grid.workers, "dask": grid.dask}
        self.table("link_results.csv", ({k: r[k] for k in (*COLUMNS, "config_key", "command")} for r in self.rows))
        self.table("link_timelines.csv", timelines, TIMELINE_COLUMNS)

    def charts(self) -> None:
        for tr in self.traces:
            if self.runs.get(tr.name):
                p = chart(self.runs[tr.name], tr.stamps, tr.title, self.out / f"link_{tr.name}.png", tr.low)
                self.figures.append(p)
        ok = [r for r in self.rows if np.isfinite(r["mtp_p95_ms"])]
        if ok:
            self.figures.append(front_chart(ok, {tr.name: tr.title for tr in self.traces}, self.out / "link_front.png"))

    def text(self) -> str:
        return _text(self.rows, self.traces, self.g, self.quick, self.info)

    def publish(self, text: str) -> None:
        if DOC_DIR is not None:
            _publish(DOC_DIR, text, self.figures, self.tables, self.history_path)


def run(out_dir: Path, quick: bool, methods: Sequence[str] | None = None, modes: Sequence[str] | None = None) -> Section:
    """Run the study into ``out_dir``: ``link_results.csv``, ``link_timelines.csv``, a chart per trace, the front,
    and the section."""
    return LinkStudy(out_dir, quick, methods, modes).run()


def _cell(v: float, fmt: str) -> str:
    return "-" if not np.isfinite(v) else format(v, fmt)


def _text(rows: list[dict[str, Any]], traces: list[LinkTrace], g: dict[str, Any], quick: bool,
          info: dict[str, Any]) -> str:
    w, h = g["size"]
    head = ("| trace | method | adapt | model PSNR dB | MTP p50 / p95 ms | freezes >250 / >500 ms | longest freeze ms | "
            "utilisation | recovery s |\n|---|---|---|---|---|---|---|---|---|")
    lines = [f"| {r['trace']} | {r['method']} | {r['adapt']} | {_cell(r['model_psnr_db'], '.2f')} | "
             f"{_cell(r['mtp_p50_ms'], '.0f')} / {_cell(r['mtp_p95_ms'], '.0f')} | "
             + ("- / -" if not np.isfinite(r['freezes_over_250ms']) else
                f"{r['freezes_over_250ms']} / {r['freezes_over_500ms']}")
             + f" | {_cell(r['longest_freeze_ms'], '.0f')} | {_cell(r['utilisation'], '.2f')} | "
             f"{_cell(r['recovery_s'], '.1f')} |" for r in rows]
    names = ", ".join(f"`{t.name}` ({t.duration_s:g} s)" for t in traces)
    longest = max(t.duration_s for t in traces)
    walk = (f" (generated for {longest:g} s: a built-in trace runs {DEFAULT_DURATION_S:g} s at most, and its first "
            f"{DEFAULT_DURATION_S:g} s are the built-in's)" if longest > DEFAULT_DURATION_S else "")
    fails = info.get("failed", [])
    runs = (f"{info['runs']} runs ({info['ran']} run now and {info['cached']} taken from the study's result store"
            + (f"; {len(fails)} failed: {', '.join(fails)}" if fails else "")
            + (f"; the runs now took {info['runs_s']:.0f} s on "
               + (f"Dask ({info['dask']})" if info.get("dask") else f"{info['workers']} worker processes")
               if info["ran"] else "") + "). ")
    hist = store_history_text(info.get("history", []))
    return (
        "Every thin-client method with rate adaptation off, `rate` (each lossy encoder follows the estimate) and "
        "`full` (the method's own knobs too: resolution, atlas budget, depth bits and samples, layers, server frame "
        f"rate) over generated capacity traces ({names}), 20 ms each way; `{STUDY_SCENE}`, the `{CAMERA}` camera "
        f"trace{walk}, {w}x{h} at 30 Hz"
        f"{'' if not quick else ' (quick: the short step, ' + ' and '.join(g['modes']) + ' only)'}; "
        + runs + (hist + " " if hist else "")
        + "Motion-to-photon is from the pose a frame was made for to its display; utilisation is over the steady parts "
        "(each step less its first second; a cellular trace less its first second); recovery is the time from the "
        "drop until the p95 update age over 0.5 s is under 150 ms (- : never within the low step). Per 0.5 s, the "
        "sent rate, capacity, model PSNR, p95 motion-to-photon, oldest update shown and operating point of every run "
        "are in `link_timelines.csv`; the front chart puts each mode's p95 motion-to-photon against its model PSNR.\n\n"
        f"{head}\n" + "\n".join(lines) + "\n\n"
        f"At {w}x{h} each method's own operating point uses a fraction of 20 Mbit/s and adaptation never asks more "
        "than the method takes at its own rate control, so utilisation is low where the link is wide by design; "
        "where it binds (the low step, the cellular dips), what matters is whether the queue stays short."
    )


def _publish(dest: Path, text: str, figs: list[Path], tables: list[Path], history: Path) -> None:
    """The full run's results into the source tree: the section as ``link.md`` with its charts (PNG), the tables and
    the store's history (what ran when, at which commit, how long)."""
    import shutil

    dest.mkdir(parents=True, exist_ok=True)
    for f in [*tables, *figs, *([history] if history.is_file() else [])]:
        shutil.copyfile(f, dest / f.name)
    charts = "\n".join(f"![{f.stem}]({f.name})" for f in figs)
    (dest / "link.md").write_text(
        "# Under a changing link\n\nGenerated by `splitrender study link` "
        "(`splitrender/experiments/studies/link.py`, full mode); nothing here is typed by hand. "
        "Every run: " + ", ".join(f"[{t.name}]({t.name})" for t in tables)
        + f"; what filled the store: [{history.name}]({history.name}).\n\n" + text + "\n\n## Charts\n\n" + charts + "\n")
    log.info("link study: wrote %s", dest)
