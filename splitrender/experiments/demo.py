"""``splitrender demo``: every available method on the default scene under ideal, lan and
cloud, in a process pool, then a self-contained HTML report; the full demo also runs the
studies that set each method beside its paper (``splitrender study`` runs them on their own).

Outputs in ``DIR``: ``runs/<key>/`` (per-run CSVs and ``config.toml``), ``runs.csv``
(one row per run), ``summary.csv`` (one row per method x network, mean over traces),
``frames.csv`` (every displayed frame with ``run``/``method``/``network`` columns),
``figures/`` (PNG + SVG + CSV per chart), ``studies/<name>/`` (each with its
``section.json``) and ``report.html``, which opens with the headline tables
(:mod:`.headline`) and the speed-against-accuracy chart.

``--quick`` (:data:`QUICK`) runs 320x180, 1 s of the walk trace at 30 fps with FLIP
on every 6th frame, without the studies (``--studies`` starts them alongside the runs,
at low priority, stopping any still running 720 s after the start; ``splitrender study
all --out DIR --quick`` runs them afterwards and adds them to the report).  The default
(:data:`FULL`) runs 640x360 over the full 10 s walk and turn traces, and the studies.
"""

from __future__ import annotations

import argparse
import logging
import multiprocessing as mp
import os
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from ..errors import ConfigError
from ..methods import available_methods, methods_for_scene
from ..sim.config import RunConfig, session_options
from ..sim.truth import shared_cache_setting
from .headline import headline_rows, headline_text
from .report import META_FILE, build_report, save_meta
from .sections import Section, discover_studies, load_study_sections, save_study_section
from .store import ResultStore, Row, fnum, network_columns, read_csv, summarise, write_csv
from .studies._util import DASK_ENV, WORKERS_ENV
from .sweep import RichRunProgress, RunProgress, end_process, run_configs

log = logging.getLogger(__name__)

NETWORKS = ("ideal", "lan", "cloud")
QUICK: dict[str, Any] = {"width": 320, "height": 180, "duration_s": 1.0, "client_fps": 30, "server_fps": 30, "flip_every": 6,
                         "traces": ("walk",)}
FULL: dict[str, Any] = {"width": 640, "height": 360, "duration_s": None, "client_fps": 60, "server_fps": 30, "flip_every": 4,
                        "traces": ("walk", "turn")}
QUICK_BUDGET_S = 720.0
RUN_COST: dict[str, float] = {"sas": 7.0, "quads": 5.5, "tss": 4.0, "video": 3.5, "warp": 2.5, "atw": 2.0, "probes": 1.5}
"""Relative wall time of a demo run per method (server plus client ms over the ground truth's, measured on the quick
demo): the pool takes the slowest first.  Unknown methods count 3."""
FULL_STUDY_TIMEOUT_S = 3600.0
SUMMARY_COLUMNS = ("method", "network", "traces", "runs", "mean_psnr_db", "psnr_mse_db", "p5_psnr_db", "mean_ssim", "mean_dssim",
                   "mean_flip", "flip_frames", "mean_model_psnr_db", "model_psnr_mse_db", "mean_model_ssim", "mean_model_flip",
                   "mean_model_pct", "mean_interior_psnr_db", "mean_edge_psnr_db", "mean_fg_psnr_db", "mean_fg_flip", "mean_fg_pct",
                   "mean_kbps", "steady_kbps", "session_kb", "mean_hole_pct", "mean_lab_err_pct", "mean_update_age_ms", "mean_server_ms", "mean_client_ms",
                   "mean_gt_ms", "client_over_gt", "lost_frames", "net_delay_ms", "net_jitter_ms",
                   # over the frames with content (the black start-up ticks left out): what the headline shows first
                   "mean_psnr_db_content", "psnr_mse_db_content", "mean_flip_content", "mean_model_psnr_db_content",
                   "model_psnr_mse_db_content", "mean_model_flip_content", "content_frames", "frames_before_content")


@dataclass
class DemoResult:
    out: Path
    report: Path
    summary: list[Row]
    configs: list[RunConfig]
    elapsed_s: float
    study_notes: list[str] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)


def demo_configs(quick: bool, methods: Sequence[str] | None = None, networks: Sequence[str] = NETWORKS,
                 duration_s: float | None = None, size: tuple[int, int] | None = None,
                 traces: Sequence[str] | None = None, session: dict[str, Any] | None = None) -> list[RunConfig]:
    """The demo's runs: method x network x trace on the default scene."""
    p = dict(QUICK if quick else FULL)
    all_methods = available_methods()
    methods = list(methods) if methods else methods_for_scene("default")
    for m in methods:
        if m not in all_methods:
            raise ConfigError(f"demo --methods: unknown method {m!r}; available: {', '.join(all_methods)}")
        if m not in methods_for_scene("default"):
            raise ConfigError(f"demo --methods: {m} cannot run on the demo's scene")
    if not networks:
        raise ConfigError("demo --networks: no network given")
    w, h = size or (p["width"], p["height"])
    dur = duration_s if duration_s is not None else p["duration_s"]
    out = []
    for m in methods:
        for net in networks:
            for tr in (traces or p["traces"]):
                out.append(RunConfig.from_dict({"method": m, "network": net, "trace": tr, "scene": "default", "width": w, "height": h,
                                                **(session or {}),
                                                "duration_s": dur, "client_fps": p["client_fps"], "server_fps": p["server_fps"],
                                                "flip_every": p["flip_every"]}))
    return out


def intro_markdown(cfgs: Sequence[RunConfig], quick: bool, runs: Sequence[Row], notes: Sequence[str]) -> str:
    """What was run, how FLIP was sampled and what latencies were modelled."""
    c = cfgs[0]
    dur = f"{c.duration_s:g} s of" if c.duration_s else "the full"
    traces = ", ".join(dict.fromkeys(x.trace for x in cfgs))
    flip_n = [fnum(r.get("flip_frames")) for r in runs]
    frames_n = [fnum(r.get("frames")) for r in runs]
    lines = [
        "## What ran",
        f"Every available method ({', '.join(dict.fromkeys(x.method for x in cfgs))}) on the `{c.scene}` scene, {dur} the "
        f"{traces} trace(s), {c.width}x{c.height} at {c.fov_y_deg:g} degrees vertical field of view, server at {c.server_fps} fps, "
        f"client at {c.client_fps} fps, pose predictor `{c.predictor}`, seed {c.seed}"
        + (" (**quick mode**: reduced resolution and trace length)." if quick else "."),
        "",
        "## How quality was scored",
        "- PSNR, SSIM, Lab error pixels and holes are scored on **every** displayed frame against the ground truth rendered "
        "at the client's true pose and time.",
        "- Each is scored over the whole frame and over three regions from the ground truth's object ids: `model` (the "
        "pixels showing the scene's model: a loaded file's model, or a built-in scene less its floor; the sky and the floor "
        "left out), `interior` (model pixels more than 2 px from the model's outline) and `edge` (the 2 px ring about the "
        "outline, both sides of it, where colour bleeds across the silhouette). The headline table and the speed-against-"
        "accuracy chart use `model`; the other charts say which they use. `runs.csv` has every region's PSNR, SSIM and FLIP.",
        f"- FLIP is expensive and is sampled: `flip_every = {c.flip_every}`, i.e. every {c.flip_every}th displayed frame "
        f"({int(sum(flip_n))} FLIP-scored frames of {int(sum(frames_n))} displayed frames in total); mean FLIP is the mean over "
        f"the sampled frames only." if c.flip_every else "- FLIP was not scored (`flip_every = 0`).",
        "",
        "## Modelled latencies (simulated clock, not this machine's speed)",
        f"- server processing (render + encode) `server_latency_ms = {c.server_latency_ms:g}` ms, client decode "
        f"`decode_latency_ms = {c.decode_latency_ms:g}` ms, plus on average half a display interval "
        f"({500.0 / c.client_fps:.1f} ms).",
    ]
    for net in dict.fromkeys(x.network for x in cfgs):
        try:
            nc = network_columns(net)
            lines.append(f"- `{net}`: one-way delay {nc['net_delay_ms']:g} ms +- {nc['net_jitter_ms']:g} ms (uniform) each way, "
                         f"round trip {nc['net_rtt_ms']:g} ms; expected update age at display about "
                         f"{c.server_latency_ms + c.decode_latency_ms + nc['net_delay_ms'] + 500.0 / c.client_fps:.0f} ms.")
        except Exception:  # noqa: BLE001
            lines.append(f"- `{net}`")
    lines.append("- Wall-clock times (server ms, client ms, ground-truth ms) are measured on this machine (Mesa llvmpipe, "
                 "CPU) and never move the simulated clock.")
    if notes:
        lines += ["", "## Notes"] + [f"- {n}" for n in notes]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------
# Studies, each in its own process with a time limit
# ---------------------------------------------------------------------------------


def _study_child(name: str, out_dir: str, quick: bool, nice: int, conn: Any) -> None:
    try:
        import importlib

        if nice:
            os.nice(nice)  # the demo's own runs come first; studies use the CPU they leave

        mod = importlib.import_module(name if "." in name else f"splitrender.experiments.studies.{name}")
        sec = mod.run(Path(out_dir), quick)
        if not isinstance(sec, Section):
            raise TypeError(f"study {name}: run() returned {type(sec).__name__}, not a Section")
        conn.send(("ok", sec))
    except BaseException:  # noqa: BLE001 - report every failure to the parent
        conn.send(("error", traceback.format_exc()))
    finally:
        conn.close()


@dataclass
class _StudyProc:
    name: str
    out_dir: Path
    proc: Any
    conn: Any
    t0: float
    msg: tuple[str, Any] | None = None
    done: bool = False


def _start_study(name: str, out_dir: Path, quick: bool, nice: int = 0) -> _StudyProc:
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    out_dir.mkdir(parents=True, exist_ok=True)
    proc = ctx.Process(target=_study_child, args=(name, str(out_dir), quick, nice, child), name=f"study-{name}")
    proc.start()
    child.close()
    return _StudyProc(name, out_dir, proc, parent, time.monotonic())


def _stop(sp: _StudyProc) -> None:
    end_process(sp.proc, 5 if sp.msg is not None else 0.5)
    sp.done = True


def _study_section(sp: _StudyProc, timeout_s: float) -> Section:
    took = time.monotonic() - sp.t0
    if sp.msg is None:
        if took >= timeout_s - 1:
            text = (f"**Not completed**: stopped after {took:.0f} s (time limit {timeout_s:.0f} s; in quick mode the demo's "
                    f"{QUICK_BUDGET_S:.0f} s budget). Run `splitrender demo` without `--quick` for this study.")
        else:
            text = f"**Study crashed** (exit code {sp.proc.exitcode}) after {took:.0f} s without a result."
        log.warning("study %s: %s", sp.name, text)
        return Section(f"Study: {sp.name} (not completed)", text)
    if sp.msg[0] == "error":
        log.error("study %s failed:\n%s", sp.name, sp.msg[1])
        return Section(f"Study: {sp.name} (failed)", f"**The study raised an error** after {took:.0f} s:\n\n```\n{sp.msg[1]}\n```")
    log.info("study %s done in %.0f s", sp.name, took)
    sec: Section = sp.msg[1]
    return sec


def run_study(name: str, out_dir: Path, quick: bool, timeout_s: float) -> Section:
    """Run one study in a spawned process; failures and timeouts become an error Section.

    ``name`` is a module of :mod:`splitrender.experiments.studies` or a dotted module path.
    """
    sp = _start_study(name, out_dir, quick)
    if sp.conn.poll(timeout_s):
        try:
            sp.msg = sp.conn.recv()
        except EOFError:
            sp.msg = None
    _stop(sp)
    return _study_section(sp, timeout_s)


EXCLUSIVE_STUDIES = ("live",)
"""Studies that measure this machine's wall-clock speed: they run after the others, one at a time, with nothing of
the demo's beside them."""


class StudyRunner:
    """Studies started together in their own processes, collected by a deadline.

    ``start()`` launches every study but the :data:`EXCLUSIVE_STUDIES` (``nice`` lowers
    their priority so the demo's runs, started afterwards, come first); ``collect(deadline)``
    waits for them, then runs the exclusive ones one at a time, and stops any still running
    at ``deadline`` (monotonic s; ``None``: :data:`FULL_STUDY_TIMEOUT_S`).
    """

    def __init__(self, out: Path, quick: bool, nice: int = 0, names: Sequence[str] | None = None) -> None:
        self.out, self.quick, self.nice = out, quick, nice
        self.names = list(names) if names is not None else discover_studies()
        self.procs: list[_StudyProc] = []

    def start(self) -> "StudyRunner":
        for name in self.names:
            if name not in EXCLUSIVE_STUDIES:
                self.procs.append(_start_study(name, self.out / "studies" / name, self.quick, self.nice))
        return self

    @staticmethod
    def _wait(running: list[_StudyProc], limit: float, results: dict[str, Section], took: dict[str, float]) -> None:
        while running:
            for sp in list(running):
                if sp.conn.poll(0.1):
                    try:
                        sp.msg = sp.conn.recv()
                    except EOFError:
                        sp.msg = None
                elif sp.proc.is_alive() and time.monotonic() < limit:
                    continue
                _stop(sp)
                took[sp.name] = time.monotonic() - sp.t0
                results[sp.name] = _study_section(sp, limit - sp.t0)
                running.remove(sp)

    def collect(self, deadline: float | None) -> tuple[list[Section], list[str]]:
        t_start = min((sp.t0 for sp in self.procs), default=time.monotonic())
        limit = deadline if deadline is not None else t_start + FULL_STUDY_TIMEOUT_S
        results: dict[str, Section] = {}
        took: dict[str, float] = {}
        self._wait(list(self.procs), limit, results, took)
        for name in self.names:          # the studies that measure this machine's speed, alone and one by one
            if name in EXCLUSIVE_STUDIES:
                sp = _start_study(name, self.out / "studies" / name, self.quick, self.nice)
                self.procs.append(sp)
                self._wait([sp], limit, results, took)
        secs, notes = [], []
        for name in self.names:
            sec = results[name]
            sec.figures = [_rel(Path(f), self.out, self.out / "studies" / name) for f in sec.figures]
            sec.tables = [_rel(Path(t), self.out, self.out / "studies" / name) for t in sec.tables]
            sec.elapsed_s = round(took[name], 1)
            save_study_section(self.out, name, sec)
            status = " - " + sec.title if sec.title.endswith(("(not completed)", "(failed)", "(skipped)")) else ""
            notes.append(f"study `{name}`: {took[name]:.0f} s" + status)
            secs.append(sec)
        return secs, notes


def run_studies(out: Path, quick: bool, deadline: float | None) -> tuple[list[Section], list[str]]:
    """Every study at once, each in its own process, stopped at ``deadline`` (monotonic s)."""
    return StudyRunner(out, quick).start().collect(deadline)


def _rel(p: Path, root: Path, study_dir: Path) -> Path:
    if not p.is_absolute():
        cand = study_dir / p
        p = cand if cand.exists() else root / p
    try:
        return p.resolve().relative_to(root.resolve())
    except ValueError:
        return p


# ---------------------------------------------------------------------------------
# The demo
# ---------------------------------------------------------------------------------


def run_demo(out: str | Path, quick: bool = True, methods: Sequence[str] | None = None, networks: Sequence[str] = NETWORKS,
             workers: int | None = None, studies: bool | None = None, duration_s: float | None = None,
             size: tuple[int, int] | None = None, traces: Sequence[str] | None = None,
             progress: RunProgress | None = None, session: dict[str, Any] | None = None) -> DemoResult:
    """Run the demo into ``out`` and write its report; see the module docstring.  ``studies``: run the studies too
    (default: in the full demo, not with ``quick``; ``splitrender study`` runs them on their own)."""
    t0 = time.monotonic()
    if studies is None:
        studies = not quick
    deadline = t0 + QUICK_BUDGET_S if quick else None
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # one ground truth for every method and network (splitrender.sim.truth)
    cfgs = [c.replace(truth_cache=shared_cache_setting(out)) for c in demo_configs(quick, methods, networks, duration_s, size, traces, session)]
    # the slowest runs first, so that the pool does not end with one worker busy on a long run and the other idle
    cfgs.sort(key=lambda c: -RUN_COST.get(c.method, 3.0))
    store = ResultStore(out)
    # Studies start first at low priority, so they use whatever CPU the runs leave.
    studies_run = StudyRunner(out, quick, nice=10).start() if studies else None
    ex = run_configs(cfgs, store, workers, None, progress)
    ok = [c for c in cfgs if store.has(c)]
    if not ok:
        raise ConfigError(f"demo: every run failed ({'; '.join(f.error for f in ex.failures)[:500]})")
    store.write_tables(ok)
    runs = read_csv(out / "runs.csv")
    summary = summarise(runs)
    write_csv(out / "summary.csv", summary, [c for c in SUMMARY_COLUMNS] + sorted({k for r in summary for k in r if k.startswith("kbps_")}))
    notes = [f"run {f.key} ({f.label}) FAILED: {f.error}" for f in ex.failures]
    notes.append(f"{len(ex.ran)} runs computed, {len(ex.cached)} reused from an earlier demo in this folder; runs took "
                 f"{time.monotonic() - t0:.0f} s wall clock with {workers or 'CPU-count'} workers.")
    sections: list[Section] = []
    if studies_run is not None:
        sections, snotes = studies_run.collect(deadline)
        notes += snotes
    else:
        notes.append("studies not run with this demo: `splitrender study all --out " + str(out) + (" --quick" if quick else "")
                     + "` runs them and adds them to this report.")
    title = "splitrender demo" + (" (quick)" if quick else "")
    intro = intro_markdown(cfgs, quick, runs, notes)
    save_meta(out, title, intro, [])
    report = build_report(out, title=title, intro_md=intro)
    return DemoResult(out, report, summary, cfgs, time.monotonic() - t0, notes, [f.error for f in ex.failures])


def main_demo(ns: argparse.Namespace) -> int:
    """``splitrender demo [--out DIR] [--quick] [--methods a,b] [--networks ...] [--workers N] [--no-studies]``."""
    methods = [m.strip() for m in ns.methods.split(",") if m.strip()] if ns.methods else None
    networks = [n.strip() for n in ns.networks.split(",") if n.strip()]
    session = session_options(ns)   # the client's loss recovery (--playout-delay, --nack-tries, ..., --fec)
    if getattr(ns, "adapt", None) not in (None, "off"):     # --adapt rate|full: the estimator's feedback with it
        session.update(adapt=ns.adapt, transport_cc=True)
    demo_configs(ns.quick, methods, networks, session=session)  # validate before the bar shows
    studies = True if ns.studies else (False if ns.no_studies else None)
    with RichRunProgress("demo" + (" --quick" if ns.quick else "")) as bar:
        res = run_demo(ns.out, quick=ns.quick, methods=methods, networks=networks, workers=ns.workers,
                       studies=studies, progress=bar, session=session)
    print(headline_text(headline_rows(res.summary)))
    for n in res.study_notes:
        if "FAILED" in n or "not completed" in n or "failed" in n:
            print(f"note: {n}")
    print(f"demo done in {res.elapsed_s:.0f} s -> {res.report}")
    return 1 if res.failures else 0


def main_study(ns: argparse.Namespace) -> int:
    """``splitrender study NAME[,NAME]|all [--out DIR] [--quick] [--timeout S] [--workers N] [--dask ADDRESS]``:
    the studies that set methods beside
    their papers, each in its own process, into ``DIR/studies/<name>/``; the report of ``DIR`` (a demo's folder, or
    a folder of its own) is written again with them."""
    known = discover_studies()
    names = known if ns.names.strip() == "all" else [n.strip() for n in ns.names.split(",") if n.strip()]
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise ConfigError(f"study: unknown study {', '.join(unknown) or '(none given)'}; available: all, {', '.join(known)}")
    if not ns.timeout > 0:
        raise ConfigError(f"study --timeout: must be > 0 s, got {ns.timeout}")
    workers, dask = getattr(ns, "workers", None), getattr(ns, "dask", None)
    if workers is not None:
        if workers < 1:
            raise ConfigError(f"study --workers: must be at least 1, got {workers}")
        os.environ[WORKERS_ENV] = str(workers)  # the study processes inherit it
    if dask:
        os.environ[DASK_ENV] = dask
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    secs, notes = StudyRunner(out, ns.quick, names=names).start().collect(t0 + ns.timeout)
    for n in notes:
        print(n)
    if not (out / META_FILE).exists() and not (out / "runs.csv").exists():
        save_meta(out, "splitrender studies", "", [])
    report = build_report(out)
    print(f"{len(secs)} studies done in {time.monotonic() - t0:.0f} s -> {report}")
    return 1 if any(s.title.endswith(("(failed)", "(not completed)")) for s in secs) else 0


__all__ = ["DemoResult", "FULL", "NETWORKS", "QUICK", "demo_configs", "discover_studies", "load_study_sections", "main_demo",
           "main_study", "run_demo", "run_studies", "run_study", "save_study_section", "summarise"]
