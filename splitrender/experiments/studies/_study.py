"""What every study's ``run(out_dir, quick)`` does around its own work (a leading underscore keeps this module out
of study discovery).

A study sets up its folder and clock, runs its cells, writes its tables, draws its charts and returns its section of
the report (and a full run may publish its results in the source tree).  :class:`Study` holds those steps and what
they share; a study subclasses it, names its section (:attr:`Study.title`), and writes :meth:`Study.cells`,
:meth:`Study.text` and, where it has them, :meth:`Study.charts` and :meth:`Study.publish`.  A study whose cells are
run configurations runs them with :meth:`Study.run_grid`: through the sweep executor into the study's own result
store (``<out>/store``, so a second invocation only runs what changed), each invocation appended to the store's
history (:func:`~._util.store_history_text` quotes it).
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Iterable

from ...tabular import write_csv
from ..sections import Section
from ..store import ResultStore
from ..sweep import ExecResult, run_configs
from ._util import executor, git_commit, read_history, save_figure, write_history


STOPPED_NOTE = "stopped before it finished: what it had run by then"
"""An invocation's history entry while its runs go on: an invocation stopped before the end (a study past its time
limit is killed) keeps it, so the runs it left in the store are still accounted for."""


class _HistoryTally:
    """The sweep's progress (:class:`~splitrender.experiments.sweep.RunProgress`) kept in the store's history: this
    invocation's entry is written as its runs start and rewritten as each one finishes (the runs done, failed ones
    included, and the seconds so far), then once more with the final counts (:meth:`write`)."""

    def __init__(self, path: Path, entry: dict[str, Any], t0: float) -> None:
        self.path, self.entry, self.t0 = path, entry, t0
        self.before = read_history(path)

    def start_all(self, total: int) -> None:
        self._save()

    def run_update(self, key: str, label: str, done: int, total: int) -> None:
        pass

    def run_done(self, key: str, label: str) -> None:
        self.entry["ran"] += 1
        self.entry["runs_s"] = round(time.perf_counter() - self.t0, 1)
        self._save()

    def write(self, **final: Any) -> list[dict[str, Any]]:
        """The entry with ``final``'s counts; the whole history, this invocation last."""
        self.entry.update(final)
        return self._save()

    def _save(self) -> list[dict[str, Any]]:
        hist = [*self.before, dict(self.entry)]
        write_history(self.path, hist)
        return hist


@dataclass
class GridRun:
    """What :meth:`Study.run_grid` ran: the sweep's result, how long its runs took (s) and where, at which commit,
    and the store's whole history (this invocation last)."""

    result: ExecResult
    runs_s: float
    workers: int
    dask: str | None
    commit: str
    history: list[dict[str, Any]]


class Study:
    """One run of a study into ``out_dir`` (created); ``quick`` for the short version."""

    name: ClassVar[str] = ""
    """The study's name (its module's): the store's history is ``<out>/store/<name>_history.json``."""
    title: ClassVar[str] = ""
    """The heading of the study's section in the report."""

    def __init__(self, out_dir: str | Path, quick: bool) -> None:
        self.out = Path(out_dir)
        self.out.mkdir(parents=True, exist_ok=True)
        self.quick = quick
        self.t0 = time.perf_counter()
        self.cells_s = 0.0
        """Seconds :meth:`cells` took (set by :meth:`run`)."""
        self.figures: list[Path] = []
        self.tables: list[Path] = []

    def run(self) -> Section:
        """Cells, charts, the text; the full run publishes it (:meth:`publish`); the report's section."""
        self.cells()
        self.cells_s = time.perf_counter() - self.t0
        self.charts()
        text = self.text()
        if not self.quick:
            self.publish(text)
        return self.section(text)

    # ------------------------------------------------------------------ the steps a study writes
    def cells(self) -> None:
        """Run the study's cells and keep what the tables, charts and text need."""
        raise NotImplementedError

    def charts(self) -> None:
        """Draw the study's charts (:meth:`pyplot`, :meth:`figure`); none by default."""

    def text(self) -> str:
        """The section's Markdown."""
        raise NotImplementedError

    def publish(self, text: str) -> None:
        """What a full run (not ``quick``) writes into the source tree besides ``out_dir``; nothing by default."""

    def section(self, text: str) -> Section:
        """The report's section: :attr:`title`, ``text``, the figures and tables written so far."""
        return Section(self.title, text, list(self.figures), list(self.tables))

    # ------------------------------------------------------------------ what the steps share
    @functools.cached_property
    def store(self) -> ResultStore:
        """The study's result store, ``<out>/store``."""
        return ResultStore(self.out / "store")

    @property
    def history_path(self) -> Path:
        return self.out / "store" / f"{self.name}_history.json"

    def run_grid(self, configs: Iterable[Any], default_workers: int = 2) -> GridRun:
        """Run the configs the store does not hold yet through the sweep executor (worker processes or Dask, from
        ``splitrender study --workers/--dask``, else ``default_workers`` processes) and append the invocation to the
        store's history."""
        ex = executor(default_workers)
        commit = git_commit()   # the code that runs them (HEAD may move while they run)
        t0 = time.perf_counter()
        entry = {"utc": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "commit": commit, "ran": 0, "cached": 0,
                 "failed": 0, "runs_s": 0.0, "workers": ex["workers"], "dask": ex["dask"] or "", "note": STOPPED_NOTE}
        tally = _HistoryTally(self.history_path, entry, t0)
        res = run_configs(list(configs), self.store, progress=tally, **ex)
        runs_s = time.perf_counter() - t0
        entry.pop("note")
        history = tally.write(ran=len(res.ran), cached=len(res.cached), failed=len(res.failures),
                              runs_s=round(runs_s, 1))
        return GridRun(res, runs_s, ex["workers"], ex["dask"], commit, history)

    def table(self, name: str, rows: Iterable[dict[str, Any]], columns: Iterable[str] | None = None) -> Path:
        """Write ``rows`` to ``out_dir/name`` (CSV) as one of the section's tables."""
        p = self.out / name
        write_csv(p, rows, list(columns) if columns is not None else None)
        self.tables.append(p)
        return p

    @staticmethod
    def pyplot() -> Any:
        """``matplotlib.pyplot`` on the Agg backend (no display)."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        return plt

    def figure(self, fig: Any, name: str, svg: bool = False) -> Path:
        """Save ``fig`` as ``out_dir/name`` (PNG; ``svg``: an SVG beside it), close it, and add it to the section."""
        p = save_figure(fig, self.out / name, svg=svg)
        self.figures.append(p)
        return p
