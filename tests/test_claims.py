"""The claims ledger (issue 50, part 3): the verdict rule on numbers, and the quick study's ledger end to end."""

from __future__ import annotations

import math
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from splitrender.experiments.studies import claims
from splitrender.experiments.store import read_csv

VERDICTS = {"holds", "holds with another magnitude", "does not hold"}


def _claim(**kw: object) -> claims.Claim:
    base = dict(id="X-1", paper="P", where="table 1", text="a beats b", paper_number="+1 to +2 dB", setting="s",
                metric="model PSNR", terms=((1, "a"), (-1, "b")), paper_range=(1.0, 2.0))
    base.update(kw)
    return claims.Claim(**base)  # type: ignore[arg-type]


def test_measure_diff_and_ratio() -> None:
    assert claims.measure(_claim(), {"a": 30.0, "b": 28.5}) == pytest.approx(1.5)
    four = _claim(terms=((1, "a"), (-1, "b"), (-1, "c"), (1, "d")))
    assert claims.measure(four, {"a": 30.0, "b": 25.0, "c": 31.0, "d": 29.0}) == pytest.approx(3.0)
    ratio = _claim(op="ratio", threshold=1.0, terms=((1, "a"), (1, "b")))
    assert claims.measure(ratio, {"a": 300.0, "b": 100.0}) == pytest.approx(3.0)
    assert math.isnan(claims.measure(ratio, {"a": 300.0}))


def test_verdict_rule() -> None:
    c = _claim()
    assert claims.verdict(c, {"duck / still": 1.2, "duck / moving": 1.8})[0] == "holds"
    v, why, med = claims.verdict(c, {"duck / still": 5.0, "duck / moving": 6.0})
    assert (v, med) == ("holds with another magnitude", 5.5) and "more than 2x off" in why
    v, why, _ = claims.verdict(c, {"duck / still": 1.5, "engine / moving": -0.3})
    assert v == "does not hold" and "fails in 1 of 2 cells (engine / moving)" in why and "holds in duck / still" in why
    assert claims.verdict(_claim(paper_range=None), {"a / b": 0.01})[0] == "holds"
    assert claims.verdict(_claim(expect="below"), {"a / b": -1.5})[0] == "holds"
    assert claims.verdict(c, {"a / b": math.nan})[0] == "not measured"


def test_claims_are_well_formed() -> None:
    ids = [c.id for c in claims.CLAIMS]
    assert len(ids) == len(set(ids)) >= 20
    for c in claims.CLAIMS:
        assert c.metric in claims.METRICS, c.id
        assert all(r in claims.RUNS for r in c.all_runs()), c.id
        assert c.op in ("diff", "ratio") and c.expect in ("above", "below"), c.id
        assert c.op == "diff" or len(c.terms) == 2, c.id
        assert set(c.cameras) <= set(claims.CAMERAS), c.id


@pytest.mark.slow
def test_quick_ledger(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(claims, "DOC", None)  # the quick run must not touch docs/claims.md
    sec = claims.run(tmp_path, quick=True)
    assert sec.title == "Claims ledger"
    text = (tmp_path / "claims.md").read_text()
    assert text.startswith("# Claims ledger\n") and "--quick" in text
    summary = read_csv(tmp_path / "claims.csv")
    assert [r["claim"] for r in summary] == [c.id for c in claims.CLAIMS]
    grid_scenes = set(claims.available_scenes(claims.GRID[True]["scenes"]) or ["default"])
    elsewhere = {c.id for c in claims.CLAIMS if c.scenes is not None and not grid_scenes & set(c.scenes)}
    assert elsewhere == {"D-F6-2"}  # checked on the default scene only, which the quick grid leaves out
    for r in summary:  # every claim has a verdict computed from a number, but one whose scenes the grid lacks
        if r["claim"] in elsewhere:
            assert r["verdict"] == "not measured" and int(r["cells"]) == 0, r
            continue
        assert r["verdict"] in VERDICTS, r
        assert isinstance(r["median"], (int, float)) and math.isfinite(r["median"]), r
        assert f"[{r['claim']}]" in text and f"**{r['verdict']}**" in text
    cells = read_csv(tmp_path / "claims_cells.csv")
    assert {r["claim"] for r in cells} == {c.id for c in claims.CLAIMS} - elsewhere
    for r in cells:  # each row carries its runs' configs and commands
        c = next(x for x in claims.CLAIMS if x.id == r["claim"])
        keys = str(r["config_keys"]).split()
        assert len(keys) == len(c.terms)
        for k in keys:
            assert (tmp_path / "store" / "runs" / k / "config.toml").is_file()
        assert str(r["commands"]).count("splitrender run") == len(c.terms)
    # the command reproduces the run: `splitrender run` with it gives the same config key
    row = next(r for r in cells if r["claim"] == "B-ATW-1")
    cmd = str(row["commands"]).split(" ; ")[1].split(": ", 1)[1]  # video cloud, the cheapest
    out = tmp_path / "rerun"
    argv = shlex.split(cmd)[2:]
    subprocess.run([sys.executable, "-m", "splitrender.cli", "run", *argv, "--out", str(out)], check=True,
                   capture_output=True, timeout=120)
    assert str(read_csv(out / "summary.csv")[0]["config_key"]) == str(row["config_keys"]).split()[1]


def test_tss_claim_quotes_the_papers_protocol(tmp_path: Path) -> None:
    """T-T4-1's evidence paragraph is built from the view-cell benchmark's JSON: the trend is named where ``sas``'s
    DSSIM rises more than ``tss``'s from the first cell to the last."""
    import json

    def run(scene: str, cell: str, m: str, dssim: float, samples: float) -> dict[str, object]:
        return {"scene": scene, "cell": cell, "run": m, "model_dssim": dssim, "samples": samples}

    p = tmp_path / "cells.json"
    p.write_text(json.dumps({"commit": "abc", "setting": "s", "cells": ["p0", "p3"], "runs": [
        run("A", "p0", "sas", 0.01, 5e5), run("A", "p3", "sas", 0.06, 5e5), run("A", "p0", "tss", 0.05, 8e4),
        run("A", "p3", "tss", 0.05, 3e5),
        run("B", "p0", "sas", 0.002, 4e5), run("B", "p3", "sas", 0.003, 4e5), run("B", "p0", "tss", 0.009, 2e4),
        run("B", "p3", "tss", 0.012, 2e4)]}))
    text = claims.tss_viewcell_evidence(p)
    assert "appears in A;" in text and "ahead of `sas` in A." in text, text
    assert "| B | 0.0020 -> 0.0030 | 0.0090 -> 0.0120 | 400k -> 400k | 20k -> 20k | +0.0090 |" in text
    assert claims.tss_viewcell_evidence(tmp_path / "absent.json") == ""
    t41 = next(c for c in claims.CLAIMS if c.id == "T-T4-1")
    assert t41.evidence is not None and "bench_tss_viewcells.py" in t41.evidence()


def test_a_failing_cell_near_the_threshold_is_called_a_tie_but_still_fails() -> None:
    c = _claim()
    v, why, _ = claims.verdict(c, {"duck / still": -0.1, "engine / still": -0.6, "duck / moving": 2.0})
    assert v == "does not hold"
    assert "fails in 2 of 3 cells (duck / still, engine / still)" in why
    assert "1 of the failing cells within 0.25 dB of it (a tie there, not a win: duck / still)" in why
    ratio = _claim(op="ratio", threshold=1.0, terms=((1, "a"), (1, "b")), metric="kbit/s", paper_range=None)
    v, why, _ = claims.verdict(ratio, {"a / b": 0.97, "c / d": 0.5})
    assert v == "does not hold" and "within 5% of 1" in why and "c / d" not in why.split("a tie there")[1]
    assert "tie" not in claims.verdict(c, {"duck / still": -0.3})[1]


def test_a_claim_shows_its_diagnostic_runs_and_why_it_fails() -> None:
    c = _claim(terms=((1, "atw cloud"), (-1, "video cloud")), diagnostics=("atw cloud turn",), cause="it orbits")
    rows = [{"claim": "X-1", "scene": "duck", "camera": "moving", "measure": -3.0, "value[atw cloud]": 22.0,
             "value[video cloud]": 25.0, "value[atw cloud turn]": 27.5,
             "commands": "atw cloud: splitrender run a ; video cloud: splitrender run b ; atw cloud turn: splitrender run c"}]
    info = {"size": (320, 180), "runs": 3, "ran": 3, "cached": 0, "failures": 0, "failed": [], "duration_s": 1.0,
            "scenes": ["duck"], "cameras": ["moving"]}
    text, summary = claims.ledger([c], rows, info, quick=False, took_s=1.0)
    assert summary[0]["verdict"] == "does not hold"
    assert "| duck | moving | -3 | 22 | 25 | 27.5 |" in text
    assert "**Why** (diagnostic runs, outside the measure: `atw cloud turn`): it orbits" in text
    # a claim that holds prints no cause; a row without the diagnostic (a quick run) leaves its column out
    rows[0].update(measure=1.0, **{"value[atw cloud]": 26.0})
    del rows[0]["value[atw cloud turn]"]
    text, _ = claims.ledger([c], rows, info, quick=False, took_s=1.0)
    assert "**Why**" not in text and "| duck | moving | 1 | 26 | 25 |" in text
    for k in c.all_runs():
        assert k in claims.RUNS
