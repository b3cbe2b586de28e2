"""Helpers the studies share (a leading underscore keeps this module out of study discovery)."""

from __future__ import annotations

import json
import math
import os
import subprocess
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ...errors import ConfigError
from ...tabular import atomic_write_bytes

ROOT = Path(__file__).resolve().parents[3]
"""The source checkout (where ``docs/`` and ``.git`` are, when the package runs from one)."""

WORKERS_ENV = "SPLITRENDER_STUDY_WORKERS"
DASK_ENV = "SPLITRENDER_STUDY_DASK"
"""How the studies that run a grid through the sweep executor (claims, papers) run it: ``splitrender study
--workers N --dask ADDRESS|local`` sets these for the study processes it starts."""

STUDY_SCENE = "default+nogi"
"""The scene of the studies that set methods beside each other and beside their papers (sas, tss, warp, quads,
papers, cost): the default scene without its global illumination.  The papers measured their methods without
DDGI, and GI's light probes cost about as much per update as rendering the frame three times on llvmpipe
(``benchmarks/bench_gi.py``); the demo's own runs use the default scene as it is, with GI, and the probes study is
where GI is the subject."""


def update_mean(ups: list[dict[str, Any]], key: str) -> float:
    """Mean of ``key`` over a run's updates, the first left out (it compiles shaders); NaN when absent."""
    v = [float(u[key]) for u in ups[1:] if key in u and u[key] == u[key]]
    return float(np.mean(v)) if v else float("nan")


def save_figure(fig: Any, path: Path, svg: bool = False) -> Path:
    """Lay out ``fig``, write it to ``path`` as PNG at 110 dpi (``svg``: and as SVG beside it) and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    if svg:
        fig.savefig(path.with_suffix(".svg"))
    plt.close(fig)
    return path


def executor(default_workers: int = 2) -> dict[str, Any]:
    """``run_configs`` keyword arguments for a study's grid: worker processes and a Dask address, from
    :data:`WORKERS_ENV` and :data:`DASK_ENV` (``splitrender study --workers/--dask``), else ``default_workers``
    local processes."""
    w = os.environ.get(WORKERS_ENV, "").strip()
    try:
        workers = int(w) if w else default_workers
    except ValueError:
        raise ConfigError(f"{WORKERS_ENV}: expected a whole number of workers, got {w!r}") from None
    if workers < 1:
        raise ConfigError(f"{WORKERS_ENV}: expected at least 1 worker, got {workers}")
    return {"workers": workers, "dask": os.environ.get(DASK_ENV, "").strip() or None}


def run_command(cfg: Any) -> str:
    """The ``splitrender run`` line that reproduces the virtual-time run ``cfg`` (a :class:`RunConfig`)."""
    parts = ["splitrender run", f"--method {cfg.method}"]
    for k, v in sorted(cfg.method_params.items()):
        vs = f'"{v}"' if isinstance(v, str) else (str(v).lower() if isinstance(v, bool) else repr(v))
        parts.append(f"--param {k}={vs}" if not isinstance(v, str) else f"--param '{k}={vs}'")
    parts += [f"--scene {cfg.scene}", f"--trace {cfg.trace}", f"--network '{cfg.network}'",
              f"--width {cfg.width}", f"--height {cfg.height}",
              *([f"--duration {cfg.duration_s:g}"] if cfg.duration_s is not None else []),  # None: the whole trace
              f"--server-fps {cfg.server_fps}", f"--client-fps {cfg.client_fps}", f"--flip-every {cfg.flip_every}"]
    if cfg.predictor != "cv":
        parts.append(f"--predictor {cfg.predictor}")
    if cfg.ssim_sigma != 1.5:
        parts.append(f"--ssim-sigma {cfg.ssim_sigma:g}")
    if not cfg.metrics:
        parts.append("--no-metrics")
    if cfg.transport_cc:
        parts.append("--transport-cc")
    if cfg.adapt != "off":
        parts.append(f"--adapt {cfg.adapt}")
    return " ".join(parts)


def git_commit() -> str:
    """The checkout's short commit, or ``"unknown"``."""
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              timeout=10).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def read_history(path: Path) -> list[dict[str, Any]]:
    """A study's store history (the JSON list at ``path``: one entry per invocation, what ran when and how long the
    runs took), empty where there is none or it does not parse."""
    try:
        hist = json.loads(path.read_text()) if path.is_file() else []
    except ValueError:
        return []
    return hist if isinstance(hist, list) else []


def write_history(path: Path, hist: list[dict[str, Any]]) -> None:
    """Write a store history whole (atomically: a study stopped mid-write leaves the old list, not half of one)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, json.dumps(hist, indent=1).encode())


def store_history_text(hist: list[dict[str, Any]]) -> str:
    """One sentence on what filled a study's result store (the list :func:`read_history` reads): every invocation
    that ran something (a rebuild from the store runs nothing and is left out), when, at which commit, how many runs
    in how long, and where when it says; ``""`` when none ran."""
    ran = [h for h in hist if h.get("ran")]
    if not ran:
        return ""
    total = sum(float(h.get("runs_s", 0.0)) for h in ran)

    def where(h: dict[str, Any]) -> str:
        if h.get("dask"):
            return f" on Dask ({h['dask']})"
        return f" on {h['workers']} worker processes" if h.get("workers") else ""

    each = "; ".join(f"{h.get('utc', '?')} at {h.get('commit', '?')}: {h['ran']} runs in "
                     f"{float(h.get('runs_s', 0.0)):.0f} s" + where(h) + (f" ({h['note']})" if h.get("note") else "")
                     for h in ran)
    return f"The stored runs were made by {len(ran)} invocation(s), {total:.0f} s of runs in all ({each})."


def summary_floats(store: Any, cfg: Any, keys: Iterable[str]) -> dict[str, float]:
    """Fields ``keys`` of a stored run's summary (``store`` a :class:`~splitrender.experiments.store.ResultStore`,
    ``cfg`` the run's config) as floats: NaN for a field that is missing or empty, and for every field when the run
    failed or is not in the store."""
    try:
        s = store.load_summary(cfg)
    except (OSError, IndexError, ValueError):
        s = {}
    out: dict[str, float] = {}
    for k in keys:
        v = s.get(k)
        try:
            out[k] = float(v) if v not in (None, "") else math.nan
        except (TypeError, ValueError):
            out[k] = math.nan
    return out
