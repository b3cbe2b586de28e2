"""Sweep files: expansion, exact errors naming the key, caching, and serial == pool == Dask."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from splitrender.errors import ConfigError
from splitrender.experiments.store import is_timing_column, read_csv
from splitrender.experiments.sweep import load_sweep, parse_sweep, run_sweep

# 0.3 s (10 frames at 30 Hz): enough for the smallest run's mean PSNR to clear the test's 10 dB by 2.25 dB (measured:
# video under cloud 12.25 dB; 10.04 at 0.2 s); the three modes' tables are compared row for row whatever the length,
# and 0.5 s cost the test 25 CPU-s against 18-19
TINY = """
[sweep]
name = "tiny"
scenes = ["default+nogi"]
networks = ["ideal", "cloud"]
[base]
width = 128
height = 72
duration_s = 0.3
flip_every = 0
client_fps = 30
[methods.video]
[methods.atw]
overscan = [1.2]
"""


def _parse(text: str) -> list:
    import tomllib

    return parse_sweep(tomllib.loads(text), "t.toml").configs


def test_expansion_order_and_count() -> None:
    cfgs = _parse("""
[sweep]
traces = ["walk", "turn"]
networks = ["ideal", "lan", "delay 100ms"]
seeds = [0, 1]
[base]
width = 320
height = 180
[grid]
server_fps = [30, 15]
[methods.video]
[methods.atw]
overscan = [1.1, 1.3, 1.5]
bitrate_kbps = [1000, 3000]
""")
    # (1 video + 3*2 atw) x 2 traces x 3 networks x 2 server_fps x 2 seeds
    assert len(cfgs) == 7 * 2 * 3 * 2 * 2
    assert len({c.key() for c in cfgs}) == len(cfgs)
    assert cfgs[0].method == "video" and cfgs[-1].method == "atw"
    assert cfgs[-1].method_params == {"overscan": 1.5, "bitrate_kbps": 3000}
    assert {c.network for c in cfgs} == {"ideal", "lan", "delay 100ms"}
    assert {c.server_fps for c in cfgs} == {30, 15}
    assert all(c.width == 320 and c.height == 180 for c in cfgs)
    # method-major order: the first 24 rows are video
    assert [c.method for c in cfgs[:24]] == ["video"] * 24


def test_no_methods_table_means_all_available() -> None:
    """Every method that runs on the sweep's scenes: ``probes`` only where every scene has global illumination."""
    from splitrender.methods import available_methods

    cfgs = _parse("[base]\nwidth = 64\nheight = 64\n")          # the default scene, which has GI
    assert [c.method for c in cfgs] == available_methods() and "probes" in available_methods()
    cfgs = _parse("[sweep]\nscenes = [\"minimal+gi\"]\n[base]\nwidth = 64\nheight = 64\n")
    assert [c.method for c in cfgs] == available_methods()
    for scenes in ('["default+nogi"]', '["default", "minimal"]'):
        cfgs = _parse(f"[sweep]\nscenes = {scenes}\n[base]\nwidth = 64\nheight = 64\n")
        assert list(dict.fromkeys(c.method for c in cfgs)) == [m for m in available_methods() if m != "probes"], scenes


def test_scalar_param_is_fixed_and_duplicates_collapse() -> None:
    cfgs = _parse("[sweep]\nseeds = [3, 3]\n[methods.atw]\noverscan = 1.2\n")
    assert len(cfgs) == 1 and cfgs[0].method_params == {"overscan": 1.2} and cfgs[0].seed == 3


@pytest.mark.parametrize("text, needle", [
    ("[sweeps]\nname='x'\n", "sweeps: unknown table"),
    ("[sweep]\nnetwork = ['ideal']\n", "sweep.network: unknown key"),
    ("[sweep]\ntraces = 'walk'\n", "sweep.traces: expected a list of strings"),
    ("[sweep]\ntraces = []\n", "sweep.traces: empty list"),
    ("[sweep]\nseeds = ['a']\n", "sweep.seeds: expected a non-empty list of integers"),
    ("[sweep]\nnetworks = ['delay fast']\n", "sweep.networks: 'delay fast'"),
    ("[methods.nosuch]\n", "methods.nosuch: unknown method 'nosuch'"),
    ("[methods.atw]\noverscan = []\n", "methods.atw.overscan: empty grid"),
    ("[methods.atw]\nwobble = [1]\n", "methods.atw: AtwConfig: unknown parameter 'wobble'"),
    ("[methods.atw]\noverscan = ['wide']\n", "methods.atw: "),
    ("[methods.atw]\noverscan = [9.0]\n", "overscan: must be in [1, 3]"),
    ("[methods]\n", "methods: empty table"),
    ("methods = 3\n", "methods: must be a table"),
    ("[base]\nwidth = 'big'\n", "base: "),
    ("[base]\nframes = 3\n", "base.frames: unknown run config key"),
    ("[base]\nmethod = 'atw'\n", "base.method: is set by the sweep axes"),
    ("[grid]\nserver_fps = []\n", "grid.server_fps: empty grid"),
    ("[grid]\nserver_fps = [0]\n", "grid.server_fps: run config server_fps: must be in [1, 1000]"),
    ("[grid]\nnetwork = ['lan']\n", "grid.network: is set by the sweep axes"),
])
def test_nonsense_sweeps_name_the_key(text: str, needle: str) -> None:
    with pytest.raises(ConfigError) as ei:
        _parse(text)
    assert needle in str(ei.value), str(ei.value)
    assert str(ei.value).startswith("sweep t.toml: ")


def test_bad_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="sweep file not found"):
        load_sweep(tmp_path / "missing.toml")
    p = tmp_path / "bad.toml"
    p.write_text("[sweep\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_sweep(p)


def test_example_sweep_parses() -> None:
    ex = Path(__file__).resolve().parents[1] / "examples"
    files = sorted(ex.glob("*.toml"))
    assert files, "examples/*.toml missing"
    for f in files:
        assert load_sweep(f).configs


def _det(rows: list[dict]) -> list[dict]:
    """Rows without the wall-clock columns (NaN normalised so equal rows compare equal)."""
    return [{k: ("nan" if isinstance(v, float) and math.isnan(v) else v) for k, v in r.items() if not is_timing_column(k)}
            for r in rows]


@pytest.mark.slow
def test_serial_pool_and_dask_give_the_same_tables(tmp_path: Path) -> None:
    f = tmp_path / "tiny.toml"
    f.write_text(TINY)
    outs = {}
    for mode, kw in (("serial", {"workers": 1}), ("pool", {"workers": 2}), ("dask", {"workers": 2, "dask": "local"})):
        sweep, res = run_sweep(f, tmp_path / mode, **kw)
        assert not res.failures, res.failures
        assert len(res.ran) == 4 and not res.cached
        outs[mode] = (read_csv(tmp_path / mode / "runs.csv"), read_csv(tmp_path / mode / "frames.csv"))
    runs, frames = outs["serial"]
    assert len(runs) == 4
    assert [r["method"] for r in runs] == ["video", "video", "atw", "atw"]
    assert [r["network"] for r in runs] == ["ideal", "cloud", "ideal", "cloud"]
    assert runs[2]["param_overscan"] == 1.2 and math.isnan(runs[0]["param_overscan"])
    assert all(r["mean_psnr_db"] > 10 for r in runs)
    assert len(frames) == sum(r["frames"] for r in runs)
    assert {fr["run"] for fr in frames} == {r["run"] for r in runs}
    for d in (tmp_path / "serial" / "runs").iterdir():
        assert (d / "config.toml").is_file() and (d / "frames.csv").is_file()
    for mode in ("pool", "dask"):
        assert _det(outs[mode][0]) == _det(runs), mode
        assert _det(outs[mode][1]) == _det(frames), mode
    # a second sweep into the same folder reuses every run
    _, res = run_sweep(f, tmp_path / "serial", workers=1)
    assert res.cached and not res.ran and len(res.cached) == 4
    assert _det(read_csv(tmp_path / "serial" / "runs.csv")) == _det(runs)


_ORPHAN_PARENT = """
import multiprocessing as mp, os, sys, time
from concurrent.futures import ProcessPoolExecutor
from splitrender.experiments.sweep import _init_worker

if __name__ == "__main__":
    ctx = mp.get_context("spawn")
    ex = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_init_worker, initargs=(ctx.Queue(),))
    print(ex.submit(os.getpid).result(), flush=True)
    ex.submit(time.sleep, 120)     # a long run the worker is busy with when its parent dies
    time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"   # a zombie has ended
    except FileNotFoundError:
        return False


def test_pool_worker_ends_when_its_parent_is_killed(tmp_path: Path) -> None:
    """A sweep worker whose parent was killed (SIGKILL: no executor shutdown) ends within seconds instead of
    finishing its run (``exit_when_orphaned``): before it, the worker here would have slept its 120 s."""
    import os
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "parent.py"
    script.write_text(_ORPHAN_PARENT)
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        worker = int(parent.stdout.readline())
        assert _alive(worker)
        time.sleep(0.5)                       # the worker is in its 120 s task now
        assert _alive(worker)
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 30.0    # polls every 1 s; 30 s leaves room for a loaded machine
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(worker), f"pool worker {worker} still running after its parent was killed"
    finally:
        if parent.poll() is None:
            parent.kill()
