"""Shared fixtures: one headless GL renderer per test session (EGL through Mesa on CI)."""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

# Fuzz tests: no per-example deadline (shared 2-core machines are noisy); under CI the
# examples are derandomised so a run is repeatable (locally each run explores anew).
settings.register_profile("ci", derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("dev", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if os.environ.get("CI") else "dev")


@pytest.fixture(scope="session")
def session_renderer():  # type: ignore[no-untyped-def]
    """The session's renderer, by a name no test module overrides (``test_tss`` and ``test_probes`` have a
    ``renderer`` of their own)."""
    from splitrender.render import Renderer

    return Renderer()


@pytest.fixture(scope="session")
def renderer(session_renderer):  # type: ignore[no-untyped-def]
    return session_renderer


@pytest.fixture(scope="session")
def gl(renderer):
    return renderer.ctx


@pytest.fixture(scope="session")
def truth_cache(tmp_path_factory) -> str:  # type: ignore[no-untyped-def]
    """One ground-truth cache folder (``RunConfig.truth_cache``, :mod:`splitrender.sim.truth`) for the session's
    virtual-time runs.  A truth frame depends only on the scene, the trace, the image size, the field of view and
    the display rate, not on the method or the network, so the runs of every test on the same trace render each
    frame once; a hit is the rendered frame bit for bit, so no score changes."""
    return str(tmp_path_factory.mktemp("truth_cache"))


@pytest.fixture(scope="session")
def shared_run(session_renderer, truth_cache):  # type: ignore[no-untyped-def]
    """``shared_run(cfg)``: the virtual-time run of ``cfg`` (with the session's renderer and truth cache), made once
    per session.  Runs with the fixed cost model are deterministic, and several tests assert on the same run (e.g.
    ``atw`` on the default walk under ``cloud`` beside ``sas`` and beside ``tss``).  The result is shared: read it,
    never change it.  Not for runs that measure wall-clock costs or that a test has monkeypatched."""
    from splitrender.sim.runner import run

    memo: dict = {}

    def get(cfg):  # type: ignore[no-untyped-def]
        assert cfg.cost_model == "fixed", "a measured-cost run is not repeatable: run it, do not share it"
        key = cfg.key()
        if key not in memo:
            memo[key] = run(cfg.replace(truth_cache=truth_cache), renderer=session_renderer)
        return memo[key]

    return get


# ----------------------------------------------------------------------------- ordering and the stress suite
#
# The stability suite (tests/test_stress.py, ~5 min of two worker processes) needs no quiet machine: it runs in
# virtual time.  When its tests are selected it starts in the background as the session starts, beside the
# deterministic tests; its tests come after those, and the live tests (wall-clock bounds: frames per second,
# shutdown within 2 s, sessions that must keep streaming) come last, once the background suite has finished.

LIVE_FILES = frozenset({"test_live_e2e.py", "test_live_errors.py", "test_live_interop.py", "test_hostile_live.py",
                        "test_hostile_decoders.py", "test_rtp_interop.py", "test_netsim_relay.py", "test_pipeline.py",
                        "test_sdp.py", "test_cli.py", "test_browser.py", "test_browser_front.py"})
STRESS_FILE = "test_stress.py"
_STRESS_SCRIPT = """
import pickle, sys
from splitrender.experiments.stress import run_stress
res = run_stress(sys.argv[1], quick=True, workers=2, timeout_s=120)
with open(sys.argv[1] + "/rows.pickle", "wb") as f:
    pickle.dump(res.rows, f)
"""


def _start_stress(config) -> None:  # type: ignore[no-untyped-def]
    """Start the quick stress suite in a child process (its result: ``background_stress``)."""
    import subprocess
    import sys
    import tempfile

    out = tempfile.mkdtemp(prefix="sr-stress-")
    log = open(os.path.join(out, "log.txt"), "wb")  # noqa: SIM115 - closed at session end
    config._sr_stress = (out, log, subprocess.Popen([sys.executable, "-c", _STRESS_SCRIPT, out], stdout=log,
                                                    stderr=subprocess.STDOUT))


def pytest_collection_modifyitems(session, config, items) -> None:  # type: ignore[no-untyped-def]
    def rank(item) -> int:  # type: ignore[no-untyped-def]
        name = item.path.name
        return 2 if name in LIVE_FILES else 1 if name == STRESS_FILE else 0

    items.sort(key=rank)          # stable: each file's tests stay together and in order
    if any(item.path.name == STRESS_FILE and "suite" in getattr(item, "fixturenames", ()) for item in items):
        _start_stress(config)


def pytest_sessionfinish(session, exitstatus) -> None:  # type: ignore[no-untyped-def]
    bg = getattr(session.config, "_sr_stress", None)
    if bg is not None:
        import shutil

        out, log, proc = bg
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        log.close()
        shutil.rmtree(out, ignore_errors=True)


@pytest.fixture(scope="session")
def background_stress(request):  # type: ignore[no-untyped-def]
    """``(out folder, rows)`` of the quick stress suite: the run started as the session began (or now)."""
    import pickle
    import subprocess
    from pathlib import Path

    if getattr(request.config, "_sr_stress", None) is None:
        _start_stress(request.config)
    out, log, proc = request.config._sr_stress
    try:
        proc.wait(timeout=1800)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    log.flush()
    text = Path(out, "log.txt").read_text(errors="replace")
    assert proc.returncode == 0, f"the background stress suite failed (exit {proc.returncode}):\n{text[-3000:]}"
    with open(os.path.join(out, "rows.pickle"), "rb") as f:
        return Path(out), pickle.load(f)


def _rss_mb() -> float:
    """This process's resident set size, MB (Linux /proc; NaN elsewhere)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


@pytest.fixture
def rss_mb():  # type: ignore[no-untyped-def]
    """``rss_mb()``: this process's resident set size now, MB."""
    return _rss_mb
