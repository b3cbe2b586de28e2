"""The link study (under a changing link) on a shrunken grid, through its result store."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

from splitrender.experiments.studies import link
from splitrender.experiments.studies._util import DASK_ENV, WORKERS_ENV
from splitrender.sim.truth import ENV_VAR

TINY = {"size": (160, 90), "steps": ((1.5, 20.0), (0.5, 2.0)), "cellular": (), "cellular_s": 2.0,
        "modes": ("off", "full"), "methods": ("video", "atw"), "workers": 2}


def _rows(p: Path) -> list[dict[str, str]]:
    with open(p) as f:
        return list(csv.DictReader(f))


def test_link_study_tiny_grid_twice_into_one_store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   truth_cache: str) -> None:
    """Two methods, off and full, on a 2 s step: the first invocation runs the four cells (two worker processes), the
    second takes all four from the store and writes the same tables; the history keeps both invocations."""
    monkeypatch.setitem(link.GRID, True, TINY)
    monkeypatch.setenv(ENV_VAR, truth_cache)
    monkeypatch.delenv(DASK_ENV, raising=False)
    monkeypatch.delenv(link.TRACES_ENV, raising=False)
    monkeypatch.setenv(WORKERS_ENV, "2")
    sec = link.run(tmp_path, quick=True)
    assert "4 runs (4 run now and 0 taken from the study's result store" in sec.text_md, sec.text_md
    assert [p.name for p in sec.tables] == ["link_results.csv", "link_timelines.csv"]
    assert {p.name for p in sec.figures} == {"link_step.png", "link_front.png"}
    assert all(p.is_file() for p in sec.figures)
    rows = _rows(sec.tables[0])
    assert [(r["trace"], r["method"], r["adapt"]) for r in rows] == [
        ("step", m, a) for m in ("video", "atw") for a in ("off", "full")]
    for r in rows:
        # measured (160x90, 2 s): model PSNR 21-24 dB, p95 motion-to-photon 75-92 ms over a 20 ms path
        psnr, p95 = float(r["model_psnr_db"]), float(r["mtp_p95_ms"])
        assert 12.0 < psnr < 45.0 and 40.0 < p95 < 1000.0, r
        assert float(r["mean_kbps"]) > 0 and r["config_key"], r
        assert ("--adapt full" in r["command"]) == (r["adapt"] == "full"), r["command"]
        assert "--transport-cc" in r["command"] and "trace " in r["command"], r["command"]
    tl = _rows(sec.tables[1])
    per_run = {(r["method"], r["adapt"]): [] for r in rows}
    for r in tl:
        per_run[(r["method"], r["adapt"])].append(r)
    for got in per_run.values():   # 0, 0.5, 1 and 1.5 s (the last frame before 2 s)
        assert [float(r["t_s"]) for r in got] == [0.0, 0.5, 1.0, 1.5], got
        # the step's capacity per half second: 20 Mbit/s, then 2 from 1.5 s
        assert [round(float(r["capacity_mbps"])) for r in got] == [20, 20, 20, 2], got
    hist = json.loads((tmp_path / "store" / "link_history.json").read_text())
    assert [h["ran"] for h in hist] == [4]

    # a second invocation (serial) runs nothing and gives the same tables
    monkeypatch.setenv(WORKERS_ENV, "1")
    sec2 = link.run(tmp_path, quick=True)
    assert "4 runs (0 run now and 4 taken from the study's result store" in sec2.text_md, sec2.text_md
    assert _rows(sec2.tables[0]) == rows and _rows(sec2.tables[1]) == tl
    hist = json.loads((tmp_path / "store" / "link_history.json").read_text())
    assert [(h["ran"], h["cached"], h["failed"]) for h in hist] == [(4, 0, 0), (0, 4, 0)]
    assert "note" not in hist[0] and "note" not in hist[1]


def test_link_trace_files_key_the_runs_by_their_content(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A trace is written once under a name with its content's digest: the same grid gives the same run keys in
    every invocation, another trace parameter other keys; the two cellular-like traces are the benchmarks'."""
    monkeypatch.delenv(link.TRACES_ENV, raising=False)
    g = {**link.GRID[False], "cellular_s": 2.0}

    def keys(grid: dict[str, object]) -> list[str]:
        out = []
        for tr in link.study_traces(grid):
            p = link.trace_file(tmp_path / "traces", tr)
            assert p.is_absolute() and p.is_file() and p.name.startswith(f"{tr.name}-")
            out.append(link.run_config(grid, "video", "full", p, tr.duration_s).key())
        return out

    first = keys(g)
    assert len(set(first)) == 3 and keys(g) == first
    assert len(list((tmp_path / "traces").iterdir())) == 3
    other = keys({**g, "steps": ((5.0, 20.0), (5.0, 3.0), (10.0, 20.0))})
    assert other[0] != first[0] and other[1:] == first[1:]
    from splitrender.netsim.traces import cellular_trace, trace_stats

    trs = {t.name: t for t in link.study_traces({**g, "cellular_s": 20.0})}
    assert (trs["cellular8"].stamps == cellular_trace(20.0, 8.0, 0.5, seed=0)).all()
    assert (trs["cellular"].stamps == cellular_trace(20.0, 4.0, 0.5, seed=0)).all()
    assert math.isclose(trace_stats(trs["cellular"].stamps)["mean_mbps"], 4.0, rel_tol=0.25)
