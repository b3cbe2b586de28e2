"""Charts for the demo and sweep reports (matplotlib, Agg backend), saved as PNG and SVG.

Each chart function takes tidy rows (``runs.csv`` / ``frames.csv`` / ``updates.csv``
as lists of dicts), draws every method present with the baselines (``video``,
``atw``) first and dashed, saves ``<name>.png`` and ``<name>.svg`` under ``figdir``
plus the data behind it as ``<name>.csv``, and returns a :class:`Chart`, or ``None``
when the rows hold nothing to draw.
"""

from __future__ import annotations

import logging
import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .headline import draws_scene  # noqa: E402
from .store import Row, fnum, write_csv  # noqa: E402

log = logging.getLogger(__name__)

BASELINES = ("video", "atw")
QUALITY = (("mean_psnr_db", "PSNR (dB)", True), ("mean_ssim", "SSIM", True), ("mean_flip", "FLIP (lower is better)", False))
FAIL_PSNR_DB = 20.0
FAIL_HOLE_PCT = 5.0
_PALETTE = ["#444444", "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf", "#bcbd22"]


@dataclass
class Chart:
    """A saved chart: its PNG and SVG, the CSV of the data drawn, a caption."""

    name: str
    png: Path
    svg: Path
    csv: Path | None
    caption: str


def method_order(methods: Sequence[str]) -> list[str]:
    """Baselines first (video, atw), then the others in first-seen order."""
    seen = list(dict.fromkeys(methods))
    return [m for m in BASELINES if m in seen] + [m for m in seen if m not in BASELINES]


def style(method: str, methods: Sequence[str]) -> dict[str, Any]:
    """Line style per method: baselines dashed grey/blue, methods solid in distinct colours, methods whose client
    renders the scene dotted and labelled so."""
    order = method_order(methods)
    i = order.index(method) if method in order else len(order)
    scene = draws_scene(method)
    return {"color": _PALETTE[i % len(_PALETTE)], "linestyle": "--" if method in BASELINES else ":" if scene else "-",
            "marker": "os^Dv<>pPX"[i % 10],
            "label": method + (" (baseline)" if method in BASELINES else " (client renders the scene)" if scene else "")}


def _save(fig: Any, figdir: Path, name: str, caption: str, data: Sequence[Row] | None) -> Chart:
    figdir.mkdir(parents=True, exist_ok=True)
    png, svg = figdir / f"{name}.png", figdir / f"{name}.svg"
    fig.savefig(png, dpi=110, bbox_inches="tight")
    fig.savefig(svg, bbox_inches="tight")
    plt.close(fig)
    csv = write_csv(figdir / f"{name}.csv", data) if data else None
    return Chart(name, png, svg, csv, caption)


def _mean(vals: Sequence[Any]) -> float:
    a = np.array([fnum(v) for v in vals], dtype=np.float64)
    a = a[~np.isnan(a)]
    return float(a.mean()) if a.size else math.nan


def _group(rows: Sequence[Row], *keys: str) -> dict[tuple[Any, ...], list[Row]]:
    g: dict[tuple[Any, ...], list[Row]] = defaultdict(list)
    for r in rows:
        g[tuple(r.get(k) for k in keys)].append(r)
    return g


def _methods(rows: Sequence[Row]) -> list[str]:
    return method_order([str(r.get("method")) for r in rows])


def _missing_baselines_note(ax: Any, methods: Sequence[str]) -> None:
    missing = [b for b in BASELINES if b not in methods]
    if missing:
        ax.text(0.01, 0.01, f"baselines not in these results: {', '.join(missing)}", transform=ax.transAxes,
                fontsize=7, color="#a00", va="bottom")


def quality_vs_latency(runs: Sequence[Row], figdir: Path, name: str = "quality_vs_latency") -> Chart | None:
    """PSNR, SSIM and FLIP against modelled one-way latency, one line per method (SAS fig. 13 style)."""
    rows = [r for r in runs if not math.isnan(fnum(r.get("net_delay_ms")))]
    if not rows:
        return None
    methods = _methods(rows)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), layout="constrained")
    data: list[Row] = []
    for m in methods:
        pts = sorted((d, grp) for (mm, d), grp in _group(rows, "method", "net_delay_ms").items() if mm == m)
        xs = [fnum(d) for d, _ in pts]
        for ax, (col, label, _) in zip(axes, QUALITY):
            ys = [_mean([g[col] for g in grp]) for _, grp in pts]
            ax.plot(xs, ys, **style(m, methods))
        for d, grp in pts:
            data.append({"method": m, "net_delay_ms": d, "networks": "|".join(sorted({str(g["network"]) for g in grp})),
                         **{c: _mean([g[c] for g in grp]) for c, _, _ in QUALITY}})
    for ax, (_, label, _) in zip(axes, QUALITY):
        ax.set_xlabel("modelled one-way network delay (ms)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    _missing_baselines_note(axes[0], methods)
    fig.suptitle("Quality against network latency")
    return _save(fig, figdir, name, "Mean quality per method against the modelled one-way delay (mean over traces, seeds "
                 "and parameters at each delay); whole-frame scores.", data)


def quality_timeline(frames: Sequence[Row], figdir: Path, network: str, trace: str | None = None,
                     name: str = "psnr_timeline") -> Chart | None:
    """Per-frame PSNR over time, one line per method, for one network (and trace)."""
    rows = [f for f in frames if str(f.get("network")) == network and (trace is None or str(f.get("trace")) == trace)]
    if not rows:
        return None
    methods = _methods(rows)
    fig, ax = plt.subplots(figsize=(11, 3.8))
    data: list[Row] = []
    for m in methods:
        runs_m = list(dict.fromkeys(str(f["run"]) for f in rows if f["method"] == m))
        run = runs_m[0]  # the first run of this method (default parameters in the demo)
        fr = [f for f in rows if f["run"] == run]
        ax.plot([fnum(f["t_s"]) for f in fr], [fnum(f["psnr_db"]) for f in fr], lw=1.2, **{**style(m, methods), "marker": None})
        data += [{"method": m, "run": run, "t_s": f["t_s"], "psnr_db": f["psnr_db"]} for f in fr]
    ax.axhline(FAIL_PSNR_DB, color="#a00", lw=0.8, ls=":", label=f"failure floor {FAIL_PSNR_DB:g} dB")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("PSNR (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=3)
    _missing_baselines_note(ax, methods)
    tr = f", trace {trace}" if trace else ""
    ax.set_title(f"Quality over time on {network}{tr}")
    return _save(fig, figdir, name, f"Per-frame PSNR over the whole frame, over time, for each method on `{network}`{tr}.", data)


def bitrate_stacked(runs: Sequence[Row], figdir: Path, name: str = "bitrate_by_stream") -> Chart | None:
    """Mean bitrate per method, stacked by stream (colour, depth, meta, ...)."""
    if not runs:
        return None
    methods = _methods(runs)
    streams: list[str] = []
    for r in runs:
        for k in r:
            if k.startswith("kbps_") and k not in streams and not math.isnan(fnum(r[k])):
                streams.append(k)
    once = [_mean([r.get("session_kb", math.nan) for r in runs if r["method"] == m]) for m in methods]
    if "kbps_session" in streams and not all(math.isnan(v) for v in once):
        streams.remove("kbps_session")  # one-off data: written beside the bar in kB, not averaged into a rate
    streams.sort(key=lambda s: (s in ("kbps_meta", "kbps_session"), s))
    fig, ax = plt.subplots(figsize=(max(5, 1.4 * len(methods) + 2), 4))
    bottom = np.zeros(len(methods))
    data: list[Row] = [{"method": m} for m in methods]
    cmap = plt.get_cmap("tab10")
    for si, s in enumerate(streams):
        vals = np.array([_mean([r.get(s, math.nan) for r in runs if r["method"] == m]) for m in methods])
        vals = np.nan_to_num(vals)
        ax.bar(methods, vals, bottom=bottom, label=s.removeprefix("kbps_"), color=cmap(si % 10),
               hatch=None if s not in ("kbps_meta", "kbps_session") else "//")
        bottom += vals
        for d, v in zip(data, vals):
            d[s] = float(v)
    for i, m in enumerate(methods):
        up = once[i] if not math.isnan(once[i]) and once[i] >= 0.5 else 0.0
        ax.text(i, bottom[i], f"{bottom[i]:.0f}" + (f"\n+ {up:.0f} kB once" if up else ""), ha="center", va="bottom", fontsize=8)
        data[i]["total_kbps"] = float(bottom[i])
        data[i]["session_kb"] = up
    ax.set_ylabel("mean bitrate (kbit/s)")
    ax.set_title("Steady bitrate per method by stream (mean over runs)")
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, figdir, name, "Bits on the wire per method, stacked by stream; `meta` is the msgpack+zstd metadata. "
                 "One-off session data (a scene upload) is not a rate: it is written above the bar in kB (`+ N kB once`).",
                 data)


def client_cost(runs: Sequence[Row], figdir: Path, name: str = "client_cost") -> Chart | None:
    """Client render time as a ratio of the ground-truth render time, per method."""
    if not runs:
        return None
    methods = _methods(runs)
    data: list[Row] = []
    for m in methods:
        rr = [r for r in runs if r["method"] == m]
        c, g = _mean([r["mean_client_ms"] for r in rr]), _mean([r["mean_gt_ms"] for r in rr])
        data.append({"method": m, "mean_client_ms": c, "mean_gt_ms": g, "client_over_gt": c / g if g > 0 else math.nan})
    fig, ax = plt.subplots(figsize=(max(5, 1.4 * len(methods) + 2), 3.6))
    vals = [d["client_over_gt"] for d in data]
    ax.bar(methods, vals, color=[style(m, methods)["color"] for m in methods])
    for i, d in enumerate(data):
        ax.text(i, d["client_over_gt"] if not math.isnan(d["client_over_gt"]) else 0,
                f"{d['client_over_gt']:.2f}\n({d['mean_client_ms']:.1f} ms)", ha="center", va="bottom", fontsize=8)
    ax.axhline(1.0, color="#a00", lw=0.8, ls=":", label="= rendering the full frame locally")
    ax.set_ylabel("client ms / ground-truth ms")
    ax.set_title("Client cost relative to rendering the ground truth")
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, figdir, name, "Mean client time per displayed frame (apply + render, wall clock on this machine) divided "
                 "by the mean time to render the ground-truth frame with the full scene on the same GL context.", data)


def rate_distortion(runs: Sequence[Row], figdir: Path, name: str = "rate_distortion") -> Chart | None:
    """PSNR/SSIM/FLIP against kbit/s: one curve per method, one column per network."""
    if not runs:
        return None
    methods = _methods(runs)
    nets = list(dict.fromkeys(str(r["network"]) for r in sorted(runs, key=lambda r: fnum(r.get("net_delay_ms")))))
    fig, axes = plt.subplots(3, len(nets), figsize=(4.2 * len(nets) + 1, 9), squeeze=False)
    data: list[Row] = []
    for j, net in enumerate(nets):
        for m in methods:
            rr = [r for r in runs if r["network"] == net and r["method"] == m]
            if not rr:
                continue
            # one point per distinct parameter set (means over traces/seeds)
            pts = []
            for params, grp in _group(rr, "params").items():
                pts.append((_mean([_steady_kbps(g) for g in grp]), {c: _mean([g[c] for g in grp]) for c, _, _ in QUALITY}, params[0]))
            pts.sort(key=lambda p: p[0])
            for i, (col, label, _) in enumerate(QUALITY):
                ax = axes[i][j]
                ax.plot([p[0] for p in pts], [p[1][col] for p in pts], **style(m, methods))
            data += [{"network": net, "method": m, "params": p[2], "mean_kbps": p[0], **p[1]} for p in pts]
        for i, (_, label, _) in enumerate(QUALITY):
            axes[i][j].set_ylabel(label)
            axes[i][j].grid(alpha=0.3)
            axes[2][j].set_xlabel("steady bitrate (kbit/s)")
        axes[0][j].set_title(net if len(net) < 40 else net[:37] + "...")
    axes[0][0].legend(fontsize=7)
    _missing_baselines_note(axes[0][0], methods)
    fig.suptitle("Rate-distortion per latency profile")
    return _save(fig, figdir, name, "Whole-frame quality against the steady bitrate (every stream but one-off session "
                 "data); each point is one parameter set (mean over traces and seeds), one column per network.", data)


def _steady_kbps(r: Row) -> float:
    """A run's rate without its one-off session data (``steady_kbps``; ``mean_kbps`` for results from before it)."""
    v = fnum(r.get("steady_kbps"))
    return v if not math.isnan(v) else fnum(r.get("mean_kbps"))


def model_psnr(r: Row) -> float:
    """A run's PSNR over the scene's model, whole-frame for runs without one, as the headline ranks it: over the frames
    with content (``mean_model_psnr_db_content``), over all frames (``mean_model_psnr_db``) for results from before
    that split."""
    for col in ("mean_model_psnr_db_content", "mean_model_psnr_db", "mean_psnr_db_content", "mean_psnr_db"):
        v = fnum(r.get(col))
        if not math.isnan(v):
            return v
    return math.nan


def quality_vs_frame_ratio(runs: Sequence[Row], figdir: Path, name: str = "quality_vs_frame_ratio") -> Chart | None:
    """PSNR and SSIM against server_fps / client_fps (only when the results vary it)."""
    ratios = {round(fnum(r.get("frame_ratio")), 4) for r in runs if not math.isnan(fnum(r.get("frame_ratio")))}
    if len(ratios) < 2:
        return None
    methods = _methods(runs)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    data: list[Row] = []
    for m in methods:
        pts = sorted((fnum(k[1]), grp) for k, grp in _group([r for r in runs if r["method"] == m], "method", "frame_ratio").items())
        for ax, col in zip(axes, ("mean_psnr_db", "mean_ssim")):
            ax.plot([p[0] for p in pts], [_mean([g[col] for g in p[1]]) for p in pts], **style(m, methods))
        data += [{"method": m, "frame_ratio": x, "mean_psnr_db": _mean([g["mean_psnr_db"] for g in grp]),
                  "mean_ssim": _mean([g["mean_ssim"] for g in grp])} for x, grp in pts]
    for ax, lab in zip(axes, ("PSNR (dB)", "SSIM")):
        ax.set_xlabel("server fps : client fps")
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    _missing_baselines_note(axes[0], methods)
    fig.suptitle("Quality against the server:client frame ratio")
    return _save(fig, figdir, name, "Mean whole-frame quality against the ratio of server to client frame rate.", data)


def pareto_front(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """Points not dominated by any other (lower cost ``x`` and higher quality ``y`` are better), by x."""
    pts = sorted((p for p in points if not (math.isnan(p[0]) or math.isnan(p[1]))), key=lambda p: (p[0], -p[1]))
    front: list[tuple[float, float]] = []
    best = -math.inf
    for x, y in pts:
        if y > best:
            front.append((x, y))
            best = y
    return front


def speed_accuracy(runs: Sequence[Row], figdir: Path, name: str = "speed_vs_accuracy") -> Chart | None:
    """Model PSNR (:func:`model_psnr`) against server ms/frame and client ms/frame; every run a point, Pareto front
    marked."""
    if not runs:
        return None
    methods = _methods(runs)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    data: list[Row] = []
    for ax, col, lab in ((axes[0], "mean_server_ms", "server ms / frame (render + pack)"),
                         (axes[1], "mean_client_ms", "client ms / displayed frame")):
        allpts = []
        for m in methods:
            rr = [r for r in runs if r["method"] == m]
            xs, ys = [fnum(r[col]) for r in rr], [model_psnr(r) for r in rr]
            st = style(m, methods)
            ax.scatter(xs, ys, color=st["color"], marker=st["marker"], label=st["label"], alpha=0.8)
            if not draws_scene(m):  # the front is the thin clients'
                allpts += list(zip(xs, ys))
        front = pareto_front(allpts)
        if front:
            ax.step([p[0] for p in front], [p[1] for p in front], where="post", color="k", lw=1, label="Pareto front")
            ax.scatter([p[0] for p in front], [p[1] for p in front], facecolors="none", edgecolors="k", s=90)
        data += [{"axis": col, "x_ms": x, "model_psnr_db": y, "pareto": 1} for x, y in front]
        ax.set_xlabel(lab)
        ax.set_ylabel("model PSNR (dB)")
        ax.grid(alpha=0.3)
    data += [{"axis": "run", "run": r.get("run"), "method": r["method"], "params": r.get("params"), "network": r["network"],
              "mean_server_ms": r["mean_server_ms"], "mean_client_ms": r["mean_client_ms"], "mean_psnr_db": r["mean_psnr_db"],
              "model_psnr_db": model_psnr(r)}
             for r in runs]
    axes[0].legend(fontsize=8)
    _missing_baselines_note(axes[0], methods)
    fig.suptitle("Speed against accuracy (wall clock on this machine)")
    return _save(fig, figdir, name, "Each point is one run, scored over the scene's model (model PSNR: the pixels where "
                 "the ground truth shows the model, the sky and the floor left out; whole-frame PSNR for results without it) "
                 "over the frames with content, as the headline ranks (the black start-up ticks left out); "
                 "the black step line is the thin clients' Pareto front (no other run is both faster and better); methods "
                 "whose client renders the scene itself are a different class, drawn but not on the front.", data)


def failure_mask(frames: Sequence[Row], floor_db: float = FAIL_PSNR_DB, hole_pct: float = FAIL_HOLE_PCT) -> list[bool]:
    """Failure frames: PSNR below ``floor_db`` or more than ``hole_pct`` % holes where the ground truth
    shows geometry (``hole_geom_pct``; ``hole_pct`` for rows that predate it), so a method that leaves
    the sky to its clear colour (``sas``) does not fail on every sky-heavy frame."""
    def holes(f: Row) -> float:
        g = fnum(f.get("hole_geom_pct"))
        return fnum(f.get("hole_pct")) if g != g else g
    return [fnum(f.get("psnr_db")) < floor_db or holes(f) > hole_pct for f in frames]


def run_timeline(frames: Sequence[Row], updates: Sequence[Row], figdir: Path, title: str, server_fps: float,
                 name: str = "run_timeline") -> Chart | None:
    """Per-frame quality, update age and bitrate of one run, failure frames marked."""
    if not frames:
        return None
    t = np.array([fnum(f["t_s"]) for f in frames])
    psnr = np.array([fnum(f["psnr_db"]) for f in frames])
    fail = np.array(failure_mask(frames))
    fig, axes = plt.subplots(3, 1, figsize=(11, 7), sharex=True)
    axes[0].plot(t, psnr, lw=1, color="#1f77b4", label="PSNR")
    axes[0].scatter(t[fail], psnr[fail], color="#d62728", s=14, zorder=3, label=f"failure (<{FAIL_PSNR_DB:g} dB or holes >{FAIL_HOLE_PCT:g}%)")
    axes[0].axhline(FAIL_PSNR_DB, color="#a00", lw=0.8, ls=":")
    axes[0].set_ylabel("PSNR (dB)")
    axes[0].legend(fontsize=8)
    axes[1].plot(t, [fnum(f["update_age_ms"]) for f in frames], lw=1, color="#2ca02c")
    axes[1].set_ylabel("update age (ms)")
    if updates:
        tu = [fnum(u["t_s"]) for u in updates]
        kb = [fnum(u["bytes"]) * 8 * server_fps / 1000 for u in updates]
        axes[2].plot(tu, kb, lw=1, color="#9467bd", label="all streams")
        lost = [(x, y) for x, y, u in zip(tu, kb, updates) if fnum(u.get("delivered")) == 0]
        if lost:
            axes[2].scatter(*zip(*lost), color="#d62728", s=14, label="lost frame")
        axes[2].legend(fontsize=8)
    axes[2].set_ylabel("bitrate (kbit/s)")
    axes[2].set_xlabel("time (s)")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    data = [{"t_s": f["t_s"], "psnr_db": f["psnr_db"], "ssim": f.get("ssim"), "hole_pct": f.get("hole_pct"),
             "update_age_ms": f["update_age_ms"], "failure": int(x)} for f, x in zip(frames, fail)]
    return _save(fig, figdir, name, f"Per-frame timelines of {title}; red points are failure frames "
                 f"({int(fail.sum())} of {len(frames)}).", data)


__all__ = ["BASELINES", "Chart", "FAIL_HOLE_PCT", "FAIL_PSNR_DB", "bitrate_stacked", "client_cost", "failure_mask", "method_order",
           "pareto_front", "quality_timeline", "quality_vs_frame_ratio", "quality_vs_latency", "rate_distortion", "run_timeline",
           "speed_accuracy", "style"]
