"""Study: the papers' figures for the methods already built, our numbers beside theirs.

Five experiments on the default scene's ``walk`` trace (without GI, ``default+nogi``), all through the virtual-time
runner with one shared renderer:

1. **SAS figure 13**: PSNR and SSIM against one-way latency (``delay N ms`` both ways,
   ``ideal`` for 0) for ``sas``, ``warp`` and ``atw``; the paper keeps server and
   client at 120 Hz.
2. **SAS figure 14**: the server at 7.5, 15, 30 and 60 Hz (7.5 runs as 8: ``server_fps``
   is an integer), the client at 120 Hz, zero latency.
3. **SAS figure 15**: rate-distortion over a ``bitrate_kbps`` ladder for ``sas``,
   ``warp``, ``atw`` and ``video`` (server 30 Hz, client 120 Hz, zero latency); x is the
   measured bitrate.
4. **QUASAR table 4**: ATW, MW (60°) and MW (120°) under ``lan`` and ``cloud`` (the
   paper's 20 +- 10 ms and 50 +- 20 ms one-way, uniform jitter), server 30 Hz, client
   60 Hz.  MeshWarp is ``warp`` with the ``mesh`` reconstruction and the BC4-like depth
   coding the paper uses; MW (60°) renders the display's field of view at its resolution
   (``fov_scale`` 1, ``resolution_scale`` 1), MW (120°) a 120° vertical field of view
   (``fov_scale`` 3 = tan 60° / tan 30°) at twice the display's resolution per axis
   (``resolution_scale`` 2/3), as the paper's 3840x2160 for a 1920x1080 client.
5. **QUASAR table 1**: the predictors' pose errors under ``lan`` and ``cloud`` (runner,
   ``metrics=False``: the same timeline, horizon and jittered pose arrivals as the
   rendered runs, without scoring).

SAS SSIM uses the paper's Gaussian window (sigma 2); QUASAR's rows use the default.
``quick=True``: 160x90, 0.4 s traces, client 60 Hz (server 30 Hz for figure 13),
latency 0/50/100, server 8/30 Hz, two bitrates without ``warp``, ``lan`` only for
table 4, 0.6 s predictor runs (about a minute on two cores).  Full: 640x360, 3 s traces, the paper's rates and the whole grid,
the whole trace for the predictors: 56 runs, 54 minutes on two cores with two workers.  The grid is module-level
(``GRID``) so a test can shrink it.

The points are planned up front (:func:`plan`) and run through the sweep executor (:meth:`PapersStudy.cells`): the study's result
store under ``<out>/store`` (a second invocation runs only what changed; ``store/papers_history.json`` keeps what
each invocation ran and how long), the truth cache, a pool of worker processes or a Dask cluster
(``splitrender study papers --workers N --dask ADDRESS|local``).  The full run also publishes its section, charts
and table in ``docs/results/papers/`` (:data:`DOC_DIR`) in a source checkout.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any, Callable

from ...sim.config import RunConfig
from ...sim.truth import shared_cache_setting
from ..sections import Section
from ._study import Study
from ._util import ROOT, STUDY_SCENE, run_command, store_history_text, summary_floats

log = logging.getLogger(__name__)

TRACE = "walk"
SAS_SSIM_SIGMA = 2.0  # the SAS paper's SSIM window (section 5.6)
# The papers' MeshWarp: a mesh over the depth map, BC4-like depth, and no per-object motion: QUASAR's
# ``mw_simulator`` moves nothing between updates, where our ``warp`` by default extrapolates each moving object's
# transform to the display time (``extrapolate``), which neither QUASAR nor QuadStream does.  On the default scene's
# moving objects that extension alone put MW 60 2 dB above QUASAR on a still camera (1 s, 320x180, cloud; level
# without it), so a table-4 comparison with it would measure our extension, not the paper's methods.
MW60 = {"reconstruction": "mesh", "fov_scale": 1.0, "resolution_scale": 1.0, "depth_coding": "bc4", "extrapolate": False}
MW120 = {"reconstruction": "mesh", "fov_scale": 3.0, "resolution_scale": 2.0 / 3.0, "depth_coding": "bc4",
         "extrapolate": False}
T4_CONFIGS: dict[str, tuple[str, dict[str, Any]]] = {"ATW": ("atw", {}), "MW (60°)": ("warp", MW60),
                                                      "MW (120°)": ("warp", MW120)}

DOC_DIR: Path | None = ROOT / "docs" / "results" / "papers" if (ROOT / "docs").is_dir() else None
"""Where the full run publishes its section, charts and table in a source checkout (a test may set it to None)."""

#: the grid per mode (``GRID[quick]``); a test may replace entries
GRID: dict[bool, dict[str, Any]] = {
    True: {
        "size": (160, 90), "duration_s": 0.4, "pred_duration_s": 0.6,
        "fig13_fps": (30, 60), "fig13_latency_ms": (0, 50, 100), "fig13_methods": ("sas", "warp", "atw"),
        "fig14_client_fps": 60, "fig14_server_fps": (8, 30), "fig14_methods": ("sas", "warp", "atw"),
        "fig15_fps": (30, 60), "fig15_kbps": (500, 2000), "fig15_methods": ("sas", "atw", "video"),
        "t4_fps": (30, 60), "t4_networks": ("lan",), "t4_configs": tuple(T4_CONFIGS),
        "t1_networks": ("lan", "cloud"), "t1_predictors": ("none", "cv", "ca", "cv_savgol", "ca_savgol"),
        "workers": 2,
    },
    False: {
        "size": (640, 360), "duration_s": 3.0, "pred_duration_s": None,
        "fig13_fps": (120, 120), "fig13_latency_ms": (0, 25, 50, 100), "fig13_methods": ("sas", "warp", "atw"),
        "fig14_client_fps": 120, "fig14_server_fps": (8, 15, 30, 60), "fig14_methods": ("sas", "warp", "atw"),
        "fig15_fps": (30, 120), "fig15_kbps": (500, 1000, 2000, 4000), "fig15_methods": ("sas", "warp", "atw", "video"),
        "t4_fps": (30, 60), "t4_networks": ("lan", "cloud"), "t4_configs": tuple(T4_CONFIGS),
        "t1_networks": ("lan", "cloud"), "t1_predictors": ("none", "cv", "ca", "cv_savgol", "ca_savgol"),
        "workers": 2,
    },
}

COLUMNS = ("experiment", "label", "method", "network", "latency_ms", "server_fps", "client_fps", "bitrate_kbps",
           "predictor", "psnr_db", "ssim", "kbps", "pred_err_cm", "pred_err_deg", "wall_s", "config_key", "command")

# --- the papers' numbers, quoted -------------------------------------------------------------------------------
#: QUASAR table 4 (PSNR dB, SSIM) per scene: Robot Lab, Sun Temple, Viking Village, San Miguel
QUASAR_T4: dict[tuple[str, str], list[tuple[float, float]]] = {
    ("ATW", "lan"): [(24.11, 0.555), (24.94, 0.648), (25.42, 0.698), (22.89, 0.563)],
    ("MW (60°)", "lan"): [(28.09, 0.863), (31.89, 0.943), (29.20, 0.925), (26.30, 0.874)],
    ("MW (120°)", "lan"): [(30.06, 0.915), (30.85, 0.911), (28.44, 0.890), (25.51, 0.812)],
    ("ATW", "cloud"): [(18.82, 0.380), (18.44, 0.476), (20.39, 0.513), (18.70, 0.353)],
    ("MW (60°)", "cloud"): [(24.98, 0.820), (27.82, 0.883), (25.74, 0.899), (21.96, 0.744)],
    ("MW (120°)", "cloud"): [(26.72, 0.872), (28.49, 0.914), (25.52, 0.861), (23.13, 0.792)],
}
#: QUASAR table 1, mean ± std / max: (scene, w/ pred position, w/ pred rotation, w/o pred position, w/o pred rotation)
QUASAR_T1: dict[str, list[tuple[str, str, str, str, str]]] = {
    "lan": [("RL", "9 ± 6 / 46 cm", "0.9 ± 1.3 / 14.7°", "32 ± 12 / 76 cm", "2.3 ± 3.0 / 22.7°"),
            ("ST", "7 ± 4 / 23 cm", "0.6 ± 1.3 / 14.4°", "25 ± 7 / 50 cm", "1.5 ± 2.7 / 21.1°"),
            ("VV", "7 ± 5 / 23 cm", "0.4 ± 0.8 / 8.6°", "27 ± 9 / 45 cm", "1.0 ± 1.6 / 13.3°"),
            ("SM", "2 ± 2 / 14 cm", "0.6 ± 0.8 / 8.5°", "9 ± 4 / 20 cm", "1.8 ± 1.8 / 14.4°")],
    "cloud": [("RL", "53 ± 20 / 122 cm", "2.4 ± 3.2 / 26.1°", "64 ± 24 / 142 cm", "4.7 ± 5.5 / 37.6°"),
              ("ST", "42 ± 12 / 87 cm", "1.5 ± 2.7 / 21.2°", "51 ± 15 / 96 cm", "3.1 ± 5.0 / 29.4°"),
              ("VV", "45 ± 15 / 84 cm", "1.2 ± 1.8 / 12.8°", "56 ± 18 / 88 cm", "2.1 ± 2.9 / 18.0°"),
              ("SM", "15 ± 6 / 39 cm", "1.7 ± 1.8 / 14.6°", "19 ± 8 / 38 cm", "3.6 ± 3.1 / 19.2°")],
}
#: the QUASAR table-1 "w/ Pred" column per network: kinematic (velocity + acceleration), Savitzky-Golay at 50 ms
PAPER_PREDICTOR = {"lan": "ca", "cloud": "ca_savgol"}
NET_LABEL = {"lan": "20 ± 10 ms", "cloud": "50 ± 20 ms", "ideal": "0 ms"}
MARKERS = {"sas": "o", "warp": "s", "atw": "^", "video": "v"}


def _network(latency_ms: int) -> str:
    return "ideal" if latency_ms == 0 else f"delay {latency_ms}ms"


def run_config(g: dict[str, Any], method: str, params: dict[str, Any], network: str, server_fps: int,
               client_fps: int, ssim_sigma: float = 1.5, predictor: str = "cv", metrics: bool = True,
               size: tuple[int, int] | None = None, duration_s: float | None | str = "grid", truth_cache: str = "") -> Any:
    """One point's :class:`RunConfig` (``duration_s="grid"``: the grid's)."""
    w, h = size or g["size"]
    return RunConfig(method=method, method_params=dict(params), scene=STUDY_SCENE, trace=TRACE, network=network,
                     duration_s=g["duration_s"] if duration_s == "grid" else duration_s, width=w, height=h,
                     server_fps=server_fps, client_fps=client_fps, predictor=predictor, seed=0, flip_every=0,
                     metrics=metrics, ssim_sigma=ssim_sigma, truth_cache=truth_cache)


def plan(g: dict[str, Any], truth_cache: str = "") -> list[dict[str, Any]]:
    """Every point of the five experiments: its table columns and its run config under ``"cfg"``.  Points of
    different experiments with the same config (same key) share one run."""
    pts: list[dict[str, Any]] = []

    def add(exp: str, label: str, method: str, params: dict[str, Any], network: str, server_fps: int, client_fps: int,
            **kw: Any) -> None:
        extra = {k: kw.pop(k) for k in ("latency_ms", "bitrate_kbps") if k in kw}
        pts.append({"experiment": exp, "label": label, "method": method, "network": network, "server_fps": server_fps,
                    "client_fps": client_fps, "predictor": kw.get("predictor", "cv"), **extra,
                    "cfg": run_config(g, method, params, network, server_fps, client_fps, truth_cache=truth_cache, **kw)})

    # 1. SAS figure 13: quality against one-way latency
    s13, c13 = g["fig13_fps"]
    for d in g["fig13_latency_ms"]:
        for m in g["fig13_methods"]:
            add("sas_fig13", m, m, {}, _network(d), s13, c13, latency_ms=d, ssim_sigma=SAS_SSIM_SIGMA)
    # 2. SAS figure 14: server rate against a 120 Hz (quick: 60 Hz) client, zero latency
    c14 = g["fig14_client_fps"]
    for sf in g["fig14_server_fps"]:
        for m in g["fig14_methods"]:
            add("sas_fig14", m, m, {}, "ideal", sf, c14, latency_ms=0, ssim_sigma=SAS_SSIM_SIGMA)
    # 3. SAS figure 15: rate-distortion
    s15, c15 = g["fig15_fps"]
    for kb in g["fig15_kbps"]:
        for m in g["fig15_methods"]:
            add("sas_fig15", m, m, {"bitrate_kbps": kb}, "ideal", s15, c15, latency_ms=0, bitrate_kbps=kb,
                ssim_sigma=SAS_SSIM_SIGMA)
    # 4. QUASAR table 4: ATW, MW60, MW120 under lan / cloud
    s4, c4 = g["t4_fps"]
    for net in g["t4_networks"]:
        for label in g["t4_configs"]:
            m, p = T4_CONFIGS[label]
            add("quasar_t4", label, m, p, net, s4, c4)
    # 5. QUASAR table 1: pose prediction errors (no rendering scored)
    for net in g["t1_networks"]:
        for pr in g["t1_predictors"]:
            add("quasar_t1", pr, "video", {}, net, 30, 30, predictor=pr, metrics=False, size=(64, 36),
                duration_s=g["pred_duration_s"])
    return pts


#: the table's score columns and the run summary's fields they come from
SCORES = {"psnr_db": "mean_psnr_db", "ssim": "mean_ssim", "kbps": "mean_kbps", "pred_err_cm": "mean_pred_err_cm",
          "pred_err_deg": "mean_pred_err_deg"}


def _get(rows: list[dict[str, Any]], **kw: Any) -> dict[str, Any] | None:
    return next((r for r in rows if all(r.get(k) == v for k, v in kw.items())), None)


class PapersStudy(Study):
    """The five experiments: their grid run into the study's store, ``papers_results.csv``, a chart each and the
    section (published in :data:`DOC_DIR` by the full run)."""

    name = "papers"
    title = "The papers' figures (SAS figs. 13-15, QUASAR tables 1 and 4)"

    def __init__(self, out_dir: Path, quick: bool) -> None:
        super().__init__(out_dir, quick)
        self.g = GRID[quick]
        self.rows: list[dict[str, Any]] = []
        self.info: dict[str, Any] = {}

    def cells(self) -> None:
        """Run the grid's points that the store does not hold yet (one run per distinct config, the truth cache
        shared) and keep a table row per point, with the run info."""
        pts = plan(self.g, shared_cache_setting(self.out))
        grid = self.run_grid([p["cfg"] for p in pts], self.g.get("workers", 2))
        res = grid.result
        for p in pts:
            cfg = p["cfg"]
            scores = summary_floats(self.store, cfg, SCORES.values())
            self.rows.append({**{k: v for k, v in p.items() if k != "cfg"}, **{k: scores[f] for k, f in SCORES.items()},
                              "wall_s": res.wall_s.get(cfg.key(), math.nan), "config_key": cfg.key(),
                              "command": run_command(cfg)})
        self.info = {"points": len(pts), "runs": len({p["cfg"].key() for p in pts}), "ran": len(res.ran),
                     "cached": len(res.cached), "failed": [f.label for f in res.failures], "runs_s": grid.runs_s,
                     "history": grid.history, "commit": grid.commit, "workers": grid.workers, "dask": grid.dask}
        self.table("papers_results.csv", ({k: r.get(k, "") for k in COLUMNS} for r in self.rows))

    def charts(self) -> None:
        plt = self.pyplot()
        self._sas_figures(plt)
        self._quasar_t4(plt)
        self._quasar_t1(plt)

    def text(self) -> str:
        return _text(self.rows, self.g, self.quick, self.cells_s, self.info)

    def publish(self, text: str) -> None:
        if DOC_DIR is not None:
            _publish(DOC_DIR, text, self.figures, self.tables[0], self.history_path)

    def _by(self, exp: str) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["experiment"] == exp]

    def _sas_figure(self, plt: Any, rs: list[dict[str, Any]], methods: Any, xkey: str, xlabel: str, title: str,
                   name: str, style_x: Any = None) -> None:
        """One SAS figure: PSNR and SSIM against ``xkey``, a line per method."""
        if not rs:
            return
        fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
        for m in methods:
            pts = sorted((r[xkey], r["psnr_db"], r["ssim"]) for r in rs if r["method"] == m)
            ax[0].plot([p[0] for p in pts], [p[1] for p in pts], marker=MARKERS.get(m, "o"), label=m)
            ax[1].plot([p[0] for p in pts], [p[2] for p in pts], marker=MARKERS.get(m, "o"), label=m)
        for a, yl in ((ax[0], "PSNR, dB"), (ax[1], "SSIM (sigma 2)")):
            if style_x is not None:
                style_x(a)
            a.set_xlabel(xlabel)
            a.set_ylabel(yl)
        ax[0].legend(fontsize=8)
        fig.suptitle(title, fontsize=10)
        self.figure(fig, name, svg=True)

    def _sas_figures(self, plt: Any) -> None:
        g = self.g
        (s13, c13), c14, (s15, c15) = g["fig13_fps"], g["fig14_client_fps"], g["fig15_fps"]

        def fig14_axis(a: Any) -> None:
            a.set_xscale("log", base=2)
            a.set_xticks(list(g["fig14_server_fps"]), [("7.5 (8)" if s == 8 else str(s)) for s in g["fig14_server_fps"]])

        self._sas_figure(plt, self._by("sas_fig13"), g["fig13_methods"], "latency_ms", "one-way latency, ms",
                        f"SAS fig. 13: quality vs latency (server {s13} Hz, client {c13} Hz)", "papers_sas_fig13.png")
        self._sas_figure(plt, self._by("sas_fig14"), g["fig14_methods"], "server_fps", f"server Hz (client {c14} Hz)",
                        "SAS fig. 14: quality vs server rate, zero latency", "papers_sas_fig14.png", fig14_axis)
        self._sas_figure(plt, self._by("sas_fig15"), g["fig15_methods"], "kbps", "measured bitrate, kbit/s",
                        f"SAS fig. 15: rate-distortion (server {s15} Hz, client {c15} Hz, zero latency)",
                        "papers_sas_fig15.png", lambda a: a.set_xscale("log"))

    def _quasar_t4(self, plt: Any) -> None:
        """Table 4: ours and the paper's (mean of its four scenes)."""
        r4 = self._by("quasar_t4")
        if not r4:
            return
        nets = [n for n in self.g["t4_networks"]]
        labels = list(self.g["t4_configs"])
        fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
        width = 0.8 / max(1, 2 * len(nets))
        k = 0
        for net in nets:
            ours = [(_get(r4, label=lb, network=net) or {}).get("psnr_db", math.nan) for lb in labels]
            paper = [sum(p for p, _ in QUASAR_T4[(lb, net)]) / 4 for lb in labels]
            for vals, who, hatch in ((ours, "ours", ""), (paper, "paper (4-scene mean)", "//")):
                ax[0].bar([i + (k - (2 * len(nets) - 1) / 2) * width for i in range(len(labels))], vals, width,
                          label=f"{who}, {NET_LABEL[net]}", hatch=hatch, alpha=0.85)
                k += 1
        ax[0].set_xticks(range(len(labels)), labels)
        ax[0].set_ylabel("PSNR, dB")
        ax[0].legend(fontsize=7)
        for lb in labels:
            pts = [(_get(r4, label=lb, network=n) or {}) for n in nets]
            ax[1].scatter([p.get("kbps", math.nan) for p in pts], [p.get("psnr_db", math.nan) for p in pts], label=lb)
            for p, n in zip(pts, nets):
                ax[1].annotate(n, (p.get("kbps", math.nan), p.get("psnr_db", math.nan)), fontsize=7, xytext=(3, 3),
                               textcoords="offset points")
        ax[1].set_xscale("log")
        ax[1].set_xlabel("measured bitrate, kbit/s")
        ax[1].set_ylabel("PSNR, dB (ours)")
        ax[1].legend(fontsize=7)
        fig.suptitle("QUASAR table 4: ATW and MeshWarp at 60° / 120°", fontsize=10)
        self.figure(fig, "papers_quasar_t4.png", svg=True)

    def _quasar_t1(self, plt: Any) -> None:
        r1 = self._by("quasar_t1")
        if not r1:
            return
        preds = list(self.g["t1_predictors"])
        nets = list(self.g["t1_networks"])
        fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
        width = 0.8 / max(1, len(nets))
        for k, net in enumerate(nets):
            xs = [i + (k - (len(nets) - 1) / 2) * width for i in range(len(preds))]
            ax[0].bar(xs, [(_get(r1, label=p, network=net) or {}).get("pred_err_cm", math.nan) for p in preds], width,
                      label=NET_LABEL[net])
            ax[1].bar(xs, [(_get(r1, label=p, network=net) or {}).get("pred_err_deg", math.nan) for p in preds], width,
                      label=NET_LABEL[net])
        for a, yl in ((ax[0], "mean position error, cm"), (ax[1], "mean rotation error, °")):
            a.set_xticks(range(len(preds)), preds)
            a.set_ylabel(yl)
        ax[0].legend(fontsize=8)
        fig.suptitle(f"QUASAR table 1: pose prediction error on `{TRACE}` (ours)", fontsize=10)
        self.figure(fig, "papers_quasar_t1.png", svg=True)


def run(out_dir: Path, quick: bool) -> Section:
    """Run the five experiments; write ``papers_results.csv`` and the charts into ``out_dir``."""
    return PapersStudy(out_dir, quick).run()


def _publish(dest: Path, text: str, figs: list[Path], table: Path, history: Path) -> None:
    """The full run's results into the source tree: the section as ``papers.md`` with its charts (PNG), the table
    and the store's history (what ran when, at which commit, how long)."""
    import shutil

    dest.mkdir(parents=True, exist_ok=True)
    for f in [table, *figs, *([history] if history.is_file() else [])]:
        shutil.copyfile(f, dest / f.name)
    charts = "\n".join(f"![{f.stem}]({f.name})" for f in figs)
    (dest / "papers.md").write_text(
        "# The papers' figures at their settings\n\nGenerated by `splitrender study papers` "
        "(`splitrender/experiments/studies/papers.py`, full mode); nothing here is typed by hand. "
        f"Every run: [{table.name}]({table.name}); what filled the store: [{history.name}]({history.name}).\n\n"
        + text + "\n\n## Charts\n\n" + charts + "\n")
    log.info("papers study: wrote %s", dest)


def _f(v: Any, fmt: str = ".2f") -> str:
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, fmt)


def _psnr_ssim(c: dict[str, Any]) -> str:
    return f"{_f(c.get('psnr_db'))} / {_f(c.get('ssim'), '.3f')}"


def _method_table(rs: list[dict[str, Any]], key: str, values: list[Any], head: Callable[[Any], str],
                  cell: Callable[[dict[str, Any]], str],
                  extra: tuple[str, Callable[[list[dict[str, Any]]], str]] | None = None) -> list[str]:
    """Markdown table lines: a row per method (in first-seen order), a column per value of ``key``
    (``head`` names it, ``cell`` formats the run's row, or ``{}`` when it is missing), and an optional
    last column ``extra`` = (title, fn(that row's cells))."""
    heads = [head(v) for v in values] + ([extra[0]] if extra else [])
    lines = ["| method | " + " | ".join(heads) + " |", "|---" * (len(heads) + 1) + "|"]
    for m in dict.fromkeys(r["method"] for r in rs):
        cells = [_get(rs, method=m, **{key: v}) or {} for v in values]
        tail = [extra[1](cells)] if extra else []
        lines.append(f"| {m} | " + " | ".join([*(cell(c) for c in cells), *tail]) + " |")
    return lines


def _text(rows: list[dict[str, Any]], g: dict[str, Any], quick: bool, elapsed: float, info: dict[str, Any]) -> str:
    w, h = g["size"]
    fails = info.get("failed", [])
    parts = [
        f"Our reproductions of figures and tables of the SAS (Mueller et al.) and QUASAR papers for the methods built "
        f"here, on the default scene's `{TRACE}` trace without GI (`{STUDY_SCENE}`) at {w}x{h}, {g['duration_s']:g} s per run"
        f"{' (quick run: fewer points, client 60 Hz instead of 120 Hz, `warp` left out of figure 15)' if quick else ''}: "
        f"{info['points']} points from {info['runs']} distinct runs (points of different figures with the same "
        f"configuration share a run), {info['ran']} run now and {info['cached']} taken from the study's result store, "
        f"in {elapsed:.0f} s" + (f"; **{len(fails)} failed**: {', '.join(fails)}" if fails else "") + ". "
        "Runs go through the sweep executor (`splitrender study papers --workers N` or `--dask ADDRESS|local`), with "
        "the ground truth of each client timeline rendered once into the truth cache. "
        + (store_history_text(info.get("history", [])) + " " if store_history_text(info.get("history", [])) else "")
        + "The papers measure large game scenes at 1920x1080 for 1200-1500 frames. "
        + ("" if quick else f"The full grid here keeps their rates, latencies, bitrate ladder shape and every method "
           f"and configuration, and cuts the resolution ({w}x{h}: 1/9 of the pixels), the frames ({g['duration_s']:g} s, "
           f"{int(round(g['duration_s'] * g['fig13_fps'][1]))} frames at {g['fig13_fps'][1]} Hz) and the scenes (one, "
           "small and procedural, where the papers use three to four game scenes) to fit two hours on two cores. ")
        + "The shapes of the curves are what can be compared, not the absolute values. SSIM in the SAS experiments "
        "uses the SAS paper's Gaussian window (sigma 2). Each row of `papers_results.csv` carries its run's config key "
        "and the `splitrender run` command that reproduces it.",
    ]

    def rows_of(exp: str) -> list[dict[str, Any]]:
        return [r for r in rows if r["experiment"] == exp]

    r13 = rows_of("sas_fig13")
    if r13:
        s13, c13 = g["fig13_fps"]
        lat = sorted({r["latency_ms"] for r in r13})
        ms = list(dict.fromkeys(r["method"] for r in r13))

        def with_loss(cells: list[dict[str, Any]]) -> str:
            return _f(cells[0].get("psnr_db", math.nan) - cells[-1].get("psnr_db", math.nan))

        lines = _method_table(r13, "latency_ms", lat, lambda d: f"{d} ms PSNR / SSIM", _psnr_ssim,
                              (f"loss 0 -> {lat[-1]} ms, dB", with_loss))
        parts.append(
            f"**SAS figure 13, quality against one-way latency** (server {s13} Hz, client {c13} Hz; the paper runs both "
            "at 120 Hz and plots MSSIM only). The paper: \"While the quality of IBR methods starts to decrease "
            "immediately, SAS manages to keep the quality at a high level due to its geometric model. For large scenes, "
            "the crossover point is already at 20 ms.\" (section 5.6)\n\n" + "\n".join(lines) + "\n\n"
            + _crossover(r13, ms, lat))
    r14 = rows_of("sas_fig14")
    if r14:
        fps = sorted({r["server_fps"] for r in r14})
        lines = _method_table(r14, "server_fps", fps, lambda s: f"{'7.5 (8)' if s == 8 else s} Hz PSNR / SSIM", _psnr_ssim)
        parts.append(
            f"**SAS figure 14, server rate** (client {g['fig14_client_fps']} Hz, zero latency; the paper's 7.5 Hz runs "
            "as 8 Hz because `server_fps` is an integer). The paper: \"ATW cannot compete with the other methods "
            "quality-wise. SAS beats MW and IIW at upsampling rates of 4x (30Hz) or higher for Viking Village, but not "
            "for the smaller scenes, Robot Lab and Sponza\", and \"The average latency resulting from a server "
            "framerate of K Hz is 1/(2K) s\" (section 5.7).\n\n" + "\n".join(lines))
    r15 = rows_of("sas_fig15")
    if r15:
        kbs = sorted({r["bitrate_kbps"] for r in r15})
        ms = list(dict.fromkeys(r["method"] for r in r15))
        lines = _method_table(r15, "bitrate_kbps", kbs, lambda k: f"{k} kbit/s: measured kbit/s, PSNR, SSIM",
                              lambda c: f"{_f(c.get('kbps'), '.0f')}, {_f(c.get('psnr_db'))}, {_f(c.get('ssim'), '.3f')}")
        parts.append(
            f"**SAS figure 15, rate-distortion** (server {g['fig15_fps'][0]} Hz, client {g['fig15_fps'][1]} Hz, zero "
            "latency; `bitrate_kbps` targets, x of the chart is the measured rate of everything sent). The paper varies "
            "5 to 80 Mbps at 1920x1080 (about 0.55 to 9 Mbit/s at 640x360 per pixel) and finds: \"Even at a bitrate of "
            "10 Mbps, ATW is already beaten by the other methods. For the smaller scenes, MW and IIS benefit more from "
            "higher bitrates, outperforming SAS at 20-40 Mbps\" and \"diminishing returns for bitrates above 40 Mbps\" "
            "(section 5.8)." + (" Our `warp` sends lossless depth on top of the colour target, so its measured rate is "
            "above the target." if "warp" in ms else "") + "\n\n" + "\n".join(lines))
    r4 = rows_of("quasar_t4")
    if r4:
        lines = ["| config | network | ours PSNR | ours SSIM | ours kbit/s | paper PSNR (RL / ST / VV / SM) | "
                 "paper SSIM (RL / ST / VV / SM) |", "|---|---|---|---|---|---|---|"]
        for r in r4:
            pp = QUASAR_T4[(r["label"], r["network"])]
            lines.append(f"| {r['label']} | {r['network']} ({NET_LABEL[r['network']]}) | {_f(r['psnr_db'])} | "
                         f"{_f(r['ssim'], '.3f')} | {_f(r['kbps'], '.0f')} | "
                         + " / ".join(f"{p:.2f}" for p, _ in pp) + " | " + " / ".join(f"{s:.3f}" for _, s in pp) + " |")
        nets = list(dict.fromkeys(r["network"] for r in r4))
        notes = []
        if len(nets) > 1:
            for lb in dict.fromkeys(r["label"] for r in r4):
                a, b = _get(r4, label=lb, network=nets[0]), _get(r4, label=lb, network=nets[-1])
                if a and b:
                    paper = [x[0] - y[0] for x, y in zip(QUASAR_T4[(lb, nets[0])], QUASAR_T4[(lb, nets[-1])])]
                    notes.append(f"{lb} loses {_f(a['psnr_db'] - b['psnr_db'])} dB from {nets[0]} to {nets[-1]} "
                                 f"(paper {min(paper):.2f} to {max(paper):.2f} dB)")
        for net in nets:
            a, b = _get(r4, label="MW (60°)", network=net), _get(r4, label="MW (120°)", network=net)
            if a and b and a["kbps"] > 0:
                notes.append(f"under {net} MW (120°) is {_f(b['psnr_db'] - a['psnr_db'], '+.2f')} dB against MW (60°) "
                             f"at {b['kbps'] / a['kbps']:.1f}x its data")
        parts.append(
            f"**QUASAR table 4: ATW and MeshWarp** (server {g['t4_fps'][0]} Hz, client {g['t4_fps'][1]} Hz as in the "
            "paper; `lan` and `cloud` are the paper's 20 ms +- 10 ms and 50 ms +- 20 ms one-way delays with uniform "
            "jitter). MW is `warp` with the `mesh` reconstruction (MeshWarp's dense vertex grid) and BC4-like depth "
            "(the paper: \"depth maps are compressed with a BC4-like 8x8 block scheme\"); the paper's MW (60°) renders "
            "the client's 60° vertical field of view at the client's resolution (`fov_scale` 1, `resolution_scale` 1), "
            "MW (120°) a 120° field of view at twice the resolution per axis, \"3840x2160 for 120°\" (`fov_scale` 3, "
            "`resolution_scale` 2/3). The paper: \"MeshWarp with a 120° FOV provides good image quality, due to a "
            "higher shading rate in peripheral regions compared to the 60° FOV configuration. However, doubling both "
            "FOV and resolution substantially increases data rates by around 3-4x\" (section 4.3). Paper columns: "
            "Robot Lab, Sun Temple, Viking Village, San Miguel.\n\n" + "\n".join(lines)
            + ("\n\n" + "; ".join(notes) + "." if notes else ""))
    r1 = rows_of("quasar_t1")
    if r1:
        nets = list(dict.fromkeys(r["network"] for r in r1))
        preds = list(dict.fromkeys(r["label"] for r in r1))
        lines = ["| predictor | " + " | ".join(f"{n} ({NET_LABEL[n]}) cm / °" for n in nets) + " |",
                 "|---" * (len(nets) + 1) + "|"]
        for p in preds:
            lines.append(f"| {p} | " + " | ".join(
                f"{_f((_get(r1, label=p, network=n) or {}).get('pred_err_cm'))} / "
                f"{_f((_get(r1, label=p, network=n) or {}).get('pred_err_deg'))}" for n in nets) + " |")
        paper = ["| latency | scene | w/ pred position | w/ pred rotation | w/o pred position | w/o pred rotation |",
                 "|---|---|---|---|---|---|"]
        for n in nets:
            for sc, a, b, c, d in QUASAR_T1.get(n, []):
                paper.append(f"| {NET_LABEL[n]} | {sc} | {a} | {b} | {c} | {d} |")
        cmp = []
        for n in nets:
            wp, wo = _get(r1, label=PAPER_PREDICTOR.get(n, "ca"), network=n), _get(r1, label="none", network=n)
            if wp and wo:
                cmp.append(f"{NET_LABEL[n]}: {PAPER_PREDICTOR.get(n)} {_f(wp['pred_err_cm'])} cm / "
                           f"{_f(wp['pred_err_deg'])}° against none {_f(wo['pred_err_cm'])} cm / {_f(wo['pred_err_deg'])}°")
        dur = "the whole trace" if g["pred_duration_s"] is None else f"{g['pred_duration_s']:g} s"
        parts.append(
            "**QUASAR table 1: pose prediction error.** Our predictors through the runner with `metrics=False` "
            f"({dur}, server 30 Hz, tracker 120 Hz): the server predicts the pose at its tick plus the latency it has "
            "measured, from the poses that have crossed the jittered uplink, the same path as the rendered runs; mean "
            "error per server frame. The paper's \"w/ Pred\" is kinematic velocity-plus-acceleration prediction "
            "(our `ca`), with \"pose smoothing using a Savitzky-Golay filter for 50±20 ms latency only\" (our "
            "`ca_savgol`); \"w/o Pred\" is our `none`. Ours: " + "; ".join(cmp) + ". Our `walk` trace moves slower "
            "than the paper's game traces, so our errors are smaller; the ratio with and without prediction is the "
            "comparable part.\n\n" + "\n".join(lines) + "\n\nThe paper's table 1 (mean ± std / max):\n\n"
            + "\n".join(paper))
    return "\n\n".join(parts)


def _crossover(r13: list[dict[str, Any]], methods: list[str], lat: list[int]) -> str:
    """Where ``sas`` first beats each other method in PSNR (the paper's crossover)."""
    if "sas" not in methods:
        return ""
    out = []
    for m in methods:
        if m == "sas":
            continue
        first = next((d for d in lat if (_get(r13, method="sas", latency_ms=d) or {}).get("psnr_db", -1e9)
                      > (_get(r13, method=m, latency_ms=d) or {}).get("psnr_db", 1e9)), None)
        out.append(f"`sas` above `{m}` in PSNR from {first} ms" if first is not None
                   else f"`sas` not above `{m}` in PSNR at any latency run")
    return "Crossover here: " + "; ".join(out) + "."
