"""Parameter sweeps: a TOML file expanded into RunConfigs, run in parallel, cached by key.

Sweep file format (every table optional; see ``examples/sweep_atw.toml`` and
``docs/experiments.md``)::

    [sweep]
    name = "atw-overscan"                 # free text, shown in the report
    description = "..."
    scenes = ["default"]                  # default ["default"]
    traces = ["walk", "turn"]             # built-in names or trace files; default ["walk"]
    networks = ["ideal", "lan", "cloud", "delay 100ms 10ms loss 1%"]   # profiles or netem; default ["ideal"]
    seeds = [0, 1]                        # default [0]

    [base]                                # RunConfig overrides applied to every run
    width = 320
    height = 180
    duration_s = 2.0
    flip_every = 6

    [grid]                                # RunConfig fields to vary (each a non-empty list)
    server_fps = [30, 15]

    [methods.video]                       # an empty table runs the method with its defaults
    [methods.atw]                         # a list is a grid axis, a scalar a fixed value
    overscan = [1.1, 1.3, 1.5]
    bitrate_kbps = [1000, 3000]

Without a ``[methods]`` table every available method runs with its defaults.  The
expansion is the Cartesian product method x params x scene x trace x network x grid x
seed, in that order (the row order of ``runs.csv``).  Mistakes (unknown keys, unknown
methods or parameters, empty grids, wrong types) raise :class:`ConfigError` naming
the key, before anything runs.

Execution: serial (``workers=1``), a local process pool (default, ``spawn`` start
method, one :class:`Renderer` per worker process), or Dask (``dask="local"`` starts a
``LocalCluster`` of processes; any other string is a scheduler address).  Each worker
keeps one Renderer per thread in a module global created lazily
(:func:`worker_renderer`).  Results are returned to the caller and written by it, so a
remote cluster needs no shared filesystem; runs whose folder already exists are not
run again.  The same sweep gives the same tables (apart from wall-clock columns, see
:data:`store.TIMING_COLUMNS`) in every mode.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import logging
import multiprocessing as mp
import os
import queue as queue_mod
import threading
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Protocol, Sequence

from ..errors import ConfigError
from ..methods import available_methods, get_method, make_config, methods_for_scene
from ..netsim import parse_path
from ..render.renderer import Renderer
from ..sim.config import RunConfig, load_toml
from ..sim.runner import VirtualTimeRun
from ..sim.truth import shared_cache_setting
from .store import ResultStore, Row

log = logging.getLogger(__name__)

AXES_FIELDS = ("method", "method_params", "scene", "trace", "network", "seed")
TOP_KEYS = ("sweep", "base", "grid", "methods")
SWEEP_KEYS = ("name", "description", "scenes", "traces", "networks", "seeds")


# ---------------------------------------------------------------------------------
# Sweep files
# ---------------------------------------------------------------------------------


@dataclass
class Sweep:
    """An expanded sweep: its name and the RunConfigs in table order (deduplicated by key)."""

    name: str
    description: str
    configs: list[RunConfig]
    source: dict[str, Any] = field(default_factory=dict)


def _str_list(where: str, v: Any) -> list[str]:
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise ConfigError(f"{where}: expected a list of strings, got {v!r}")
    if not v:
        raise ConfigError(f"{where}: empty list (nothing to sweep)")
    return list(v)


def _grid(where: str, v: Any) -> list[Any]:
    if isinstance(v, dict):
        raise ConfigError(f"{where}: expected a value or a list of values, got a table")
    vals = v if isinstance(v, list) else [v]
    if not vals:
        raise ConfigError(f"{where}: empty grid (nothing to sweep)")
    return vals


def _product(axes: dict[str, list[Any]]) -> Iterator[dict[str, Any]]:
    keys = list(axes)
    for combo in itertools.product(*(axes[k] for k in keys)):
        yield dict(zip(keys, combo))


def parse_sweep(data: dict[str, Any], source: str = "<sweep>") -> Sweep:
    """Expand a parsed sweep file into RunConfigs; :class:`ConfigError` names the bad key."""
    def err(key: str, msg: str) -> ConfigError:
        return ConfigError(f"sweep {source}: {key}: {msg}")

    if not isinstance(data, dict):
        raise ConfigError(f"sweep {source}: expected a table")
    for k in data:
        if k not in TOP_KEYS:
            raise err(k, f"unknown table (valid: {', '.join(TOP_KEYS)})")
    for k in TOP_KEYS:
        if k in data and not isinstance(data[k], dict):
            raise err(k, f"must be a table, got {type(data[k]).__name__}")
    sw = data.get("sweep", {})
    for k in sw:
        if k not in SWEEP_KEYS:
            raise err(f"sweep.{k}", f"unknown key (valid: {', '.join(SWEEP_KEYS)})")
    for k in ("name", "description"):
        if k in sw and not isinstance(sw[k], str):
            raise err(f"sweep.{k}", f"expected a string, got {sw[k]!r}")
    scenes = _str_list(f"sweep {source}: sweep.scenes", sw.get("scenes", ["default"]))
    traces = _str_list(f"sweep {source}: sweep.traces", sw.get("traces", ["walk"]))
    networks = _str_list(f"sweep {source}: sweep.networks", sw.get("networks", ["ideal"]))
    seeds = sw.get("seeds", [0])
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and not isinstance(s, bool) for s in seeds):
        raise err("sweep.seeds", f"expected a non-empty list of integers, got {seeds!r}")
    for n in networks:
        try:
            parse_path(n)
        except Exception as exc:  # NetworkConfigError
            raise err("sweep.networks", f"{n!r}: {exc}") from None

    names = {f.name for f in dataclasses.fields(RunConfig)}
    base = dict(data.get("base", {}))
    grid_in = data.get("grid", {})
    for table, d in (("base", base), ("grid", grid_in)):
        for k in d:
            if k in AXES_FIELDS:
                raise err(f"{table}.{k}", "is set by the sweep axes ([sweep] scenes/traces/networks/seeds, [methods])")
            if k not in names:
                raise err(f"{table}.{k}", f"unknown run config key (valid: {', '.join(sorted(names - set(AXES_FIELDS)))})")
    try:
        RunConfig.from_dict(base)
    except ConfigError as exc:
        raise err("base", str(exc)) from None
    grid = {k: _grid(f"sweep {source}: grid.{k}", v) for k, v in grid_in.items()}
    for k, vals in grid.items():
        for v in vals:
            try:
                RunConfig.from_dict({**base, k: v})
            except ConfigError as exc:
                raise err(f"grid.{k}", str(exc)) from None

    methods_t = data.get("methods")
    if methods_t is None:
        usable = [set(methods_for_scene(sc)) for sc in scenes]     # on every scene of the sweep
        methods_t = {m: {} for m in available_methods() if all(m in u for u in usable)}
    if not methods_t:
        raise err("methods", "empty table (name at least one method, or leave [methods] out for all)")
    method_grids: list[tuple[str, dict[str, Any]]] = []
    for m, params in methods_t.items():
        if not isinstance(params, dict):
            raise err(f"methods.{m}", f"must be a table of parameters, got {type(params).__name__}")
        try:
            spec = get_method(m)
        except ConfigError as exc:
            raise err(f"methods.{m}", str(exc)) from None
        axes = {k: _grid(f"sweep {source}: methods.{m}.{k}", v) for k, v in params.items()}
        for combo in _product(axes):
            try:
                make_config(spec.config, combo)
            except (ConfigError, TypeError, ValueError) as exc:
                raise err(f"methods.{m}", str(exc)) from None
            method_grids.append((m, combo))

    configs: list[RunConfig] = []
    seen: set[str] = set()
    for m, params in method_grids:
        for scene, trace, network in itertools.product(scenes, traces, networks):
            for g in _product(grid):
                for seed in seeds:
                    d = {**base, **g, "method": m, "method_params": params, "scene": scene, "trace": trace,
                         "network": network, "seed": seed}
                    cfg = RunConfig.from_dict(d)
                    if cfg.key() not in seen:
                        seen.add(cfg.key())
                        configs.append(cfg)
    return Sweep(sw.get("name", Path(source).stem), sw.get("description", ""), configs, data)


def load_sweep(path: str | Path) -> Sweep:
    """Read and expand a sweep TOML file."""
    return parse_sweep(load_toml(path, "sweep"), str(path))


# ---------------------------------------------------------------------------------
# Running configs: serial, process pool, Dask
# ---------------------------------------------------------------------------------

_RENDERERS: dict[int, Any] = {}
_PROGRESS_Q: Any = None


def worker_renderer() -> Any:
    """This thread's Renderer, created on first use (one GL context per owning thread)."""
    tid = threading.get_ident()
    r = _RENDERERS.get(tid)
    if r is None:
        r = _RENDERERS[tid] = Renderer()
    return r


ORPHAN_POLL_S = 1.0
"""How often a pool worker checks that the process that started it is still alive (seconds)."""


def exit_when_orphaned(parent: int, poll_s: float = ORPHAN_POLL_S) -> threading.Thread:
    """Start a daemon thread that ends this process (``os._exit(1)``) once ``parent`` is no longer its parent.

    A pool worker blocks on its call queue, whose pipe the other workers hold open too, so a parent killed by a
    signal (no executor shutdown) left its workers and their runs going: a ``splitrender study`` stopped with
    SIGTERM kept four workers computing for 10-14 minutes.  Reparenting (to init or a subreaper) is what a dead
    parent looks like from here; ``PR_SET_PDEATHSIG`` would not do, since it fires when the *thread* that forked
    exits, and the executor starts replacement workers from its management thread."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(1)

    t = threading.Thread(target=watch, name="orphan-watch", daemon=True)
    t.start()
    return t


def _init_worker(q: Any, gl_threads: int | None = None) -> None:
    global _PROGRESS_Q
    _PROGRESS_Q = q
    exit_when_orphaned(os.getppid())
    if gl_threads is not None:   # before this process makes its GL context (Mesa reads it then)
        os.environ.setdefault("LP_NUM_THREADS", str(gl_threads))


def pool_gl_threads(workers: int) -> int | None:
    """llvmpipe's threads per pool worker: one when the workers already fill the CPUs (each worker's own render
    threads would only compete with the other workers': the quick demo took 120 s with llvmpipe's default and
    106 s with one thread per worker on two cores), else Mesa's default.  ``LP_NUM_THREADS`` set by the user wins."""
    return 1 if workers >= (os.cpu_count() or 1) else None


def execute_config(cfg: RunConfig, report: Callable[[str, int, int], None] | None = None) -> Row:
    """Run one config on this worker's Renderer; returns its summary, frames and updates.

    ``report(key, done, total)`` gets per-frame progress; in a pool worker progress goes
    to the queue set by the pool initializer instead.
    """
    key = cfg.key()
    q = _PROGRESS_Q
    last = [0.0]

    def progress(done: int, total: int) -> None:
        if report is not None:
            report(key, done, total)
        elif q is not None:
            now = time.monotonic()
            if done == total or now - last[0] > 0.25:
                last[0] = now
                try:
                    q.put_nowait((key, done, total))
                except Exception:  # noqa: BLE001 - progress is best effort
                    pass

    t0 = time.perf_counter()
    res = VirtualTimeRun(cfg, worker_renderer(), progress).run()
    return {"key": key, "summary": res.summary, "frames": res.frames, "updates": res.updates,
            "wall_s": time.perf_counter() - t0, "pid": os.getpid()}


class RunProgress(Protocol):
    """What the executor tells a progress display."""

    def start_all(self, total: int) -> None: ...
    def run_update(self, key: str, label: str, done: int, total: int) -> None: ...
    def run_done(self, key: str, label: str) -> None: ...


def label_of(cfg: RunConfig) -> str:
    p = ",".join(f"{k}={v}" for k, v in sorted(cfg.method_params.items()))
    return f"{cfg.method}{'(' + p + ')' if p else ''} / {cfg.network} / {cfg.trace}"


@dataclass
class RunFailure:
    key: str
    label: str
    error: str


@dataclass
class ExecResult:
    """What :func:`run_configs` did: keys run now, keys reused, failures."""

    ran: list[str] = field(default_factory=list)
    cached: list[str] = field(default_factory=list)
    failures: list[RunFailure] = field(default_factory=list)
    wall_s: dict[str, float] = field(default_factory=dict)


def end_process(proc: Any, wait_s: float) -> None:
    """Join ``proc`` (a multiprocessing process) within ``wait_s``, then terminate it, then kill it."""
    proc.join(timeout=wait_s)
    if proc.is_alive():
        proc.terminate()
        proc.join(timeout=5)
        if proc.is_alive():
            proc.kill()
            proc.join()


def default_workers() -> int:
    return max(1, os.cpu_count() or 1)


def run_configs(cfgs: Sequence[RunConfig], store: ResultStore, workers: int | None = None, dask: str | None = None,
                progress: RunProgress | None = None, rerun: bool = False) -> ExecResult:
    """Run every config whose results are not in ``store`` yet and save them there."""
    out = ExecResult()
    todo: list[RunConfig] = []
    seen: set[str] = set()
    for c in cfgs:
        k = c.key()
        if k in seen:
            continue
        seen.add(k)
        if not rerun and store.has(c):
            out.cached.append(k)
        else:
            todo.append(c)
    if progress:
        progress.start_all(len(todo))
    log.info("%d runs to do, %d cached", len(todo), len(out.cached))
    if not todo:
        return out
    by_key = {c.key(): c for c in todo}

    def finish(res: Row) -> None:
        cfg = by_key[res["key"]]
        store.save(cfg, res["summary"], res["frames"], res["updates"])
        out.ran.append(res["key"])
        out.wall_s[res["key"]] = res["wall_s"]
        if progress:
            progress.run_done(res["key"], label_of(cfg))

    def fail(cfg: RunConfig, exc: BaseException) -> None:
        tb = "".join(traceback.format_exception_only(type(exc), exc)).strip()
        log.error("run %s (%s) failed: %s", cfg.key(), label_of(cfg), tb)
        out.failures.append(RunFailure(cfg.key(), label_of(cfg), tb))
        if progress:
            progress.run_done(cfg.key(), label_of(cfg))

    n = workers or default_workers()
    if dask:
        _run_dask(todo, dask, n, finish, fail)
    elif n <= 1 or len(todo) == 1:
        def rep(key: str, done: int, total: int) -> None:
            if progress:
                progress.run_update(key, label_of(by_key[key]), done, total)

        for cfg in todo:
            try:
                finish(execute_config(cfg, rep))
            except Exception as exc:  # noqa: BLE001 - one bad run must not stop the sweep
                fail(cfg, exc)
    else:
        _run_pool(todo, min(n, len(todo)), finish, fail, progress, by_key)
    return out


def _run_pool(todo: Sequence[RunConfig], n: int, finish: Callable[[Row], None], fail: Callable[[RunConfig, BaseException], None],
              progress: RunProgress | None, by_key: dict[str, RunConfig]) -> None:
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    with ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=_init_worker, initargs=(q, pool_gl_threads(n))) as ex:
        futs: dict[Future[Row], RunConfig] = {ex.submit(execute_config, c): c for c in todo}
        pending = set(futs)
        while pending:
            done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            _drain(q, progress, by_key)
            if done:
                time.sleep(0.05)  # let the last progress message of a finished run arrive first
                _drain(q, progress, by_key)
            for f in done:
                try:
                    finish(f.result())
                except Exception as exc:  # noqa: BLE001
                    fail(futs[f], exc)
        _drain(q, progress, by_key)


def _drain(q: Any, progress: RunProgress | None, by_key: dict[str, RunConfig]) -> None:
    while True:
        try:
            key, done, total = q.get_nowait()
        except (queue_mod.Empty, OSError, EOFError):
            return
        if progress and key in by_key:
            progress.run_update(key, label_of(by_key[key]), done, total)


def _run_dask(todo: Sequence[RunConfig], address: str, n: int, finish: Callable[[Row], None],
              fail: Callable[[RunConfig, BaseException], None]) -> None:
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if address == "local":
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.WARNING)
        client = Client(cluster)
    else:
        client = Client(address)
    try:
        futs = {client.submit(execute_config, c, pure=False, key=f"run-{c.key()}"): c for c in todo}
        for f in as_completed(list(futs)):
            try:
                finish(f.result())
            except Exception as exc:  # noqa: BLE001
                fail(futs[f], exc)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


# ---------------------------------------------------------------------------------
# Progress display (rich) used by the CLI entry points
# ---------------------------------------------------------------------------------


class RichRunProgress:
    """An overall bar plus one bar per active run, with ETA, on a rich Progress."""

    def __init__(self, title: str) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        self.title = title
        self.progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                                 TextColumn("eta"), TimeRemainingColumn())
        self._overall: Any = None
        self._tasks: dict[str, Any] = {}
        self._done: set[str] = set()

    def __enter__(self) -> "RichRunProgress":
        self.progress.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.progress.__exit__(*exc)

    def start_all(self, total: int) -> None:
        self._overall = self.progress.add_task(f"[bold]{self.title}[/] runs", total=total)

    def run_update(self, key: str, label: str, done: int, total: int) -> None:
        if key in self._done:
            return
        t = self._tasks.get(key)
        if t is None:
            t = self._tasks[key] = self.progress.add_task(f"  {label}", total=total)
        self.progress.update(t, completed=done, total=total)

    def run_done(self, key: str, label: str) -> None:
        self._done.add(key)
        t = self._tasks.pop(key, None)
        if t is not None:
            self.progress.remove_task(t)
        if self._overall is not None:
            self.progress.advance(self._overall)


# ---------------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------------


def run_sweep(path: str | Path, out: str | Path, workers: int | None = None, dask: str | None = None,
              progress: RunProgress | None = None) -> tuple[Sweep, ExecResult]:
    """Expand ``path``, run what is missing into ``out/runs`` and write ``out/runs.csv`` and ``out/frames.csv``."""
    sweep = load_sweep(path)
    store = ResultStore(out)
    store.root.mkdir(parents=True, exist_ok=True)
    (store.root / "sweep.toml").write_text(Path(path).read_text())
    # one ground-truth cache for every run that does not name its own (splitrender.sim.truth)
    shared = shared_cache_setting(out)
    sweep.configs[:] = [c if c.truth_cache else c.replace(truth_cache=shared) for c in sweep.configs]
    res = run_configs(sweep.configs, store, workers, dask, progress)
    ok = [c for c in sweep.configs if store.has(c)]
    store.write_tables(ok)
    return sweep, res


def main_sweep(ns: argparse.Namespace) -> int:
    """``splitrender sweep FILE [--out DIR] [--workers N] [--dask ADDRESS|local] [--report]``."""
    sweep = load_sweep(ns.file)  # validate before the bar shows
    with RichRunProgress(sweep.name) as bar:
        sweep, res = run_sweep(ns.file, ns.out, ns.workers, ns.dask, bar)
    print(f"sweep {sweep.name}: {len(sweep.configs)} runs ({len(res.ran)} run now, {len(res.cached)} cached, "
          f"{len(res.failures)} failed) -> {ns.out / 'runs.csv'}")
    for f in res.failures:
        print(f"  FAILED {f.key} {f.label}: {f.error}")
    if ns.report:
        from .report import build_report

        print(f"report: {build_report(ns.out, title=f'sweep {sweep.name}')}")
    return 1 if res.failures else 0


__all__ = ["ExecResult", "RichRunProgress", "RunFailure", "Sweep", "execute_config", "label_of", "load_sweep", "main_sweep",
           "parse_sweep", "run_configs", "run_sweep", "worker_renderer"]
