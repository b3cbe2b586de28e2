"""The papers study (SAS figs. 13-15, QUASAR tables 1 and 4) on a shrunken grid."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from splitrender.experiments.studies import papers
from splitrender.experiments.studies._util import DASK_ENV, WORKERS_ENV
from splitrender.sim.truth import ENV_VAR

TINY = {
    "size": (160, 90), "duration_s": 0.3, "pred_duration_s": 0.4,
    "fig13_fps": (30, 60), "fig13_latency_ms": (0, 100), "fig13_methods": ("sas", "atw"),
    "fig14_client_fps": 60, "fig14_server_fps": (30,), "fig14_methods": ("sas", "atw"),  # reuses fig. 13's 0 ms runs
    "fig15_fps": (30, 60), "fig15_kbps": (300, 2000), "fig15_methods": ("video",),
    "t4_fps": (30, 60), "t4_networks": ("lan",), "t4_configs": ("ATW",),
    "t1_networks": ("lan",), "t1_predictors": ("none", "ca"),
}


def test_papers_study_tiny(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, truth_cache: str) -> None:
    monkeypatch.setitem(papers.GRID, True, TINY)
    # the study's runs (all on the walk at 160x90, shown at 60 Hz) take their ground truth from the session's truth
    # cache (the variable the demo and sweeps read): rendered once for the scored runs here and shared with
    # test_runner's (a hit is the same frame); the grid runs on a Dask LocalCluster, as `study papers --dask local`
    monkeypatch.setenv(ENV_VAR, truth_cache)
    monkeypatch.setenv(DASK_ENV, "local")
    sec = papers.run(tmp_path, quick=True)
    # 11 points, 9 runs: figure 14's 30 Hz points are figure 13's 0 ms runs (same config, one run)
    assert "11 points from 9 distinct runs" in sec.text_md and "9 run now and 0 taken from" in sec.text_md, sec.text_md
    names = {p.name for p in sec.figures}
    assert names == {"papers_sas_fig13.png", "papers_sas_fig14.png", "papers_sas_fig15.png", "papers_quasar_t4.png",
                     "papers_quasar_t1.png"}
    for p in sec.figures:
        assert p.is_file() and p.with_suffix(".svg").is_file()
    assert [p.name for p in sec.tables] == ["papers_results.csv"]
    with open(sec.tables[0]) as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4 + 2 + 2 + 1 + 2

    def get(exp: str, **kw: str) -> dict[str, float]:
        r = [r for r in rows if r["experiment"] == exp and all(r[k] == v for k, v in kw.items())]
        assert len(r) == 1, (exp, kw)
        return {k: float(v) if v != "" else math.nan for k, v in r[0].items()   # NaN is written as an empty cell
                if k in ("psnr_db", "ssim", "kbps", "pred_err_cm", "pred_err_deg")}

    # SAS fig. 13: from 0 to 100 ms atw loses more than sas, and at 100 ms sas is well ahead.  Measured: sas 25.82 ->
    # 16.51 dB (SSIM 0.895 -> 0.563), atw 21.82 -> 10.27 (0.825 -> 0.260).  sas lost 6.1 dB before its atlas
    # filtered textures per texel for the display, 8.2 before its 12 Mpix atlas and Catmull-Rom lookup: each raised
    # its 0 ms score more than its 100 ms one
    at = {(m, ms): get("sas_fig13", method=m, latency_ms=ms) for m in ("sas", "atw") for ms in ("0", "100")}
    loss = {m: at[(m, "0")]["psnr_db"] - at[(m, "100")]["psnr_db"] for m in ("sas", "atw")}
    ssim_loss = {m: at[(m, "0")]["ssim"] - at[(m, "100")]["ssim"] for m in ("sas", "atw")}
    assert loss["atw"] - loss["sas"] > 1.8 and ssim_loss["atw"] - ssim_loss["sas"] > 0.18, (loss, ssim_loss)
    assert at[("sas", "100")]["psnr_db"] > at[("atw", "100")]["psnr_db"] + 5.0, at
    # SAS fig. 15: the higher bitrate buys video PSNR (measured 442 -> 2028 kbit/s, +3.9 dB)
    lo, hi = get("sas_fig15", method="video", bitrate_kbps="300"), get("sas_fig15", method="video", bitrate_kbps="2000")
    assert hi["kbps"] > 3 * lo["kbps"] and hi["psnr_db"] - lo["psnr_db"] > 3.0, (lo, hi)
    # QUASAR table 1: prediction cuts the position error under lan (measured 11.4 cm -> 0.74 cm)
    none, ca = get("quasar_t1", label="none"), get("quasar_t1", label="ca")
    assert ca["pred_err_cm"] < 0.1 * none["pred_err_cm"], (none, ca)
    for needle in ("SAS figure 13", "crossover point is already at 20 ms", "QUASAR table 4", "24.11 / 24.94 / 25.42 / 22.89",
                   "9 ± 6 / 46 cm", "runs as 8 Hz"):
        assert needle in sec.text_md, needle

    # a second invocation (serial, no Dask) takes every run from the store and writes the same table
    monkeypatch.delenv(DASK_ENV)
    monkeypatch.setenv(WORKERS_ENV, "1")
    first = [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]
    sec2 = papers.run(tmp_path, quick=True)
    with open(sec2.tables[0]) as f:
        again = [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(f)]
    assert again == first
    assert "0 run now and 9 taken from the study's result store" in sec2.text_md, sec2.text_md
    # every row says how to reproduce it
    assert all(r["command"].startswith("splitrender run --method ") and r["config_key"] for r in first)
    assert any("--ssim-sigma 2" in r["command"] for r in first) and any("--no-metrics" in r["command"] for r in first)


def test_run_command_reproduces_whole_trace_runs() -> None:
    """A point with no duration (table 1's predictor runs: the whole trace) has a command without ``--duration``."""
    from splitrender.experiments.studies._util import run_command

    g = dict(papers.GRID[False])
    pred = [p["cfg"] for p in papers.plan(g) if p["experiment"] == "quasar_t1"]
    assert pred and all(c.duration_s is None for c in pred)
    cmd = run_command(pred[0])
    assert "--duration" not in cmd and "--no-metrics" in cmd and "--width 64 --height 36" in cmd, cmd
    assert "--duration 3 " in run_command(papers.plan(g)[0]["cfg"])


def test_study_grid_executor_refuses_nonsense(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """``study --workers/--dask`` reach the grids through the environment; a bad worker count is named, both on the
    command line and in the variable a study process reads."""
    from splitrender.cli import main
    from splitrender.errors import ConfigError
    from splitrender.experiments.studies._util import executor

    monkeypatch.delenv(DASK_ENV, raising=False)
    monkeypatch.setenv(WORKERS_ENV, "two")
    with pytest.raises(ConfigError, match="SPLITRENDER_STUDY_WORKERS: expected a whole number of workers, got 'two'"):
        executor()
    monkeypatch.setenv(WORKERS_ENV, "0")
    with pytest.raises(ConfigError, match="expected at least 1 worker, got 0"):
        executor()
    monkeypatch.setenv(WORKERS_ENV, "3")
    monkeypatch.setenv(DASK_ENV, "local")
    assert executor() == {"workers": 3, "dask": "local"}
    assert main(["study", "papers", "--workers", "0", "--out", str(tmp_path)]) == 2
    assert "study --workers: must be at least 1, got 0" in capsys.readouterr().err


def test_store_history_text_and_summary_floats(tmp_path: Path) -> None:
    """The helpers papers and claims share: the sentence on what filled a study's store (invocations that ran
    nothing left out; where they ran when the entry says), and a stored run's summary fields as floats, NaN for a
    missing, empty or unreadable field and for a run the store lacks."""
    from splitrender.experiments.store import ResultStore
    from splitrender.experiments.studies._util import store_history_text, summary_floats
    from splitrender.sim.config import RunConfig

    assert store_history_text([]) == "" and store_history_text([{"ran": 0, "runs_s": 3.0}]) == ""
    hist = [{"utc": "U1", "commit": "c1", "ran": 8, "cached": 0, "runs_s": 65.2, "note": "stopped"},
            {"utc": "U2", "commit": "c2", "ran": 0, "cached": 8, "runs_s": 0.1},
            {"utc": "U3", "commit": "c3", "ran": 4, "cached": 8, "runs_s": 20.0, "workers": 2, "dask": ""},
            {"utc": "U4", "commit": "c4", "ran": 1, "cached": 11, "runs_s": 4.6, "workers": 1, "dask": "local"}]
    assert store_history_text(hist) == (
        "The stored runs were made by 3 invocation(s), 90 s of runs in all (U1 at c1: 8 runs in 65 s (stopped); "
        "U3 at c3: 4 runs in 20 s on 2 worker processes; U4 at c4: 1 runs in 5 s on Dask (local)).")

    cfg = RunConfig(method="video", scene="minimal", duration_s=0.1)
    store = ResultStore(tmp_path / "store")
    nan = summary_floats(store, cfg, ("mean_psnr_db", "mean_kbps"))
    assert list(nan) == ["mean_psnr_db", "mean_kbps"] and all(math.isnan(v) for v in nan.values())

    class Stored:
        def load_summary(self, c: object) -> dict[str, object]:
            assert c is cfg
            return {"mean_psnr_db": 31.5, "mean_kbps": "", "mean_ssim": "n/a", "frames": 0}

    got = summary_floats(Stored(), cfg, ("mean_psnr_db", "mean_kbps", "mean_ssim", "frames", "absent"))
    assert got["mean_psnr_db"] == 31.5 and got["frames"] == 0.0
    assert all(math.isnan(got[k]) for k in ("mean_kbps", "mean_ssim", "absent"))


def test_study_base_runs_cells_charts_text_and_section(tmp_path: Path) -> None:
    """:class:`Study`'s frame: cells, then charts, then the text; the full run (not quick) publishes; the section
    holds the tables and figures written, in order."""
    from splitrender.experiments.studies._study import Study

    calls: list[str] = []

    class Tiny(Study):
        name, title = "tiny", "A tiny study"

        def cells(self) -> None:
            calls.append("cells")
            self.table("tiny.csv", [{"a": 1, "b": math.nan}, {"a": 2, "b": 0.5}])

        def charts(self) -> None:
            calls.append("charts")
            fig, ax = self.pyplot().subplots()
            ax.plot([0, 1], [1, 0])
            self.figure(fig, "tiny.png", svg=True)

        def text(self) -> str:
            calls.append("text")
            return f"cells took {self.cells_s:.1f} s"

        def publish(self, text: str) -> None:
            calls.append("publish")

    sec = Tiny(tmp_path / "q", quick=True).run()
    assert calls == ["cells", "charts", "text"] and sec.title == "A tiny study" and sec.text_md.startswith("cells took")
    assert sec.tables == [tmp_path / "q" / "tiny.csv"] and sec.figures == [tmp_path / "q" / "tiny.png"]
    assert (tmp_path / "q" / "tiny.csv").read_text().splitlines() == ["a,b", "1,", "2,0.5"]
    assert (tmp_path / "q" / "tiny.svg").is_file()
    calls.clear()
    Tiny(tmp_path / "full", quick=False).run()
    assert calls == ["cells", "charts", "text", "publish"]


def test_an_invocation_stopped_mid_grid_keeps_its_history_entry(tmp_path: Path) -> None:
    """A study's store history is written as its runs finish, not only at the end: an invocation killed at its time
    limit (claims' full grid took 3,601 s against the 3,600 s limit once, and its 260 runs then read as cached with no
    invocation that made them) leaves its entry with the runs done so far and the stopped note; one that finishes
    replaces the note with its final counts."""
    from splitrender.experiments.studies._study import STOPPED_NOTE, _HistoryTally
    from splitrender.experiments.studies._util import read_history, store_history_text, write_history

    path = tmp_path / "store" / "x_history.json"
    write_history(path, [{"utc": "U0", "commit": "c0", "ran": 3, "cached": 0, "runs_s": 9.0}])
    entry = {"utc": "U1", "commit": "c1", "ran": 0, "cached": 0, "failed": 0, "runs_s": 0.0, "workers": 2,
             "dask": "", "note": STOPPED_NOTE}
    tally = _HistoryTally(path, entry, t0=0.0)
    tally.start_all(5)
    tally.run_done("k1", "a")
    tally.run_done("k2", "b")        # ... and the process is killed here
    hist = read_history(path)
    assert [h["utc"] for h in hist] == ["U0", "U1"] and hist[1]["ran"] == 2 and hist[1]["note"] == STOPPED_NOTE
    assert "U1 at c1: 2 runs in " in store_history_text(hist) and f"({STOPPED_NOTE})" in store_history_text(hist)
    entry.pop("note")
    final = tally.write(ran=5, cached=7, failed=0, runs_s=12.5)
    assert final == read_history(path) and final[1]["ran"] == 5 and "note" not in final[1]
    assert read_history(tmp_path / "missing.json") == []
    (tmp_path / "bad.json").write_text("{not json")
    assert read_history(tmp_path / "bad.json") == []
