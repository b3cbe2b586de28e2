"""T-T4-1's evidence from the TSS view-cell benchmark (``claims.tss_viewcell_evidence``): the matched runs' table and
the sentences computed from it, on a small synthetic result file."""

from __future__ import annotations

import json
from pathlib import Path

from splitrender.experiments.studies import claims


def _run(scene: str, cell: str, run: str, size: str, dssim: float, samples: float, kbps: float) -> dict[str, object]:
    return {"scene": scene, "cell": cell, "run": run, "size": size, "model_dssim": dssim, "samples": samples,
            "steady_kbps": kbps}


def _cells(scene: str, size: str, sas: float, tss_bits: float, sas_ll: float, tss_ll: float) -> list[dict[str, object]]:
    """One scene, size and cell (p0) of matched runs: sas at 100 kbit/s from 4e5 samples, tss at 0.5x the samples,
    and at sas's bits both at those samples (``tss_bits``) and at one sample per pixel (twice that DSSIM)."""
    return [_run(scene, "p0", "sas", size, sas, 4e5, 100.0),
            _run(scene, "p0", "tss matched", size, sas * 0.9, 2e5, 300.0),
            _run(scene, "p0", "tss matched @sas bits", size, tss_bits, 2e5, 110.0),
            _run(scene, "p0", "tss @sas bits", size, tss_bits * 2, 2e4, 95.0),  # the worse of the two: not shown
            _run(scene, "p0", "sas lossless", size, sas_ll, 4e5, 900.0),
            _run(scene, "p0", "tss matched lossless", size, tss_ll, 2e5, 800.0)]


def test_matched_runs_give_a_table_and_the_resolution_trend(tmp_path: Path) -> None:
    runs = [_run("A", "p0", "sas", "320x180", 0.002, 4e5, 100.0), _run("A", "p0", "tss", "320x180", 0.008, 2e4, 50.0),
            _run("A", "p3", "sas", "320x180", 0.004, 4e5, 100.0), _run("A", "p3", "tss", "320x180", 0.010, 2e4, 50.0)]
    # A: lossy gap +0.0030 at 320x180 shrinks to -0.0005 at 1280x720 (a flip); lossless leads at both sizes
    runs += _cells("A", "320x180", 0.0020, 0.0050, 0.0011, 0.0004)
    runs += _cells("A", "1280x720", 0.0010, 0.0005, 0.0008, 0.0002)
    # B: one size only, trails lossy and lossless
    runs += _cells("B", "640x360", 0.0030, 0.0060, 0.0010, 0.0020)
    p = tmp_path / "cells.json"
    p.write_text(json.dumps({"commits": ["abc"], "setting": "s", "cells": {"p0": {}, "p3": {}}, "runs": runs}))
    text = claims.tss_viewcell_evidence(p)
    assert "commit abc" in text
    # the default-grid table reads the 320x180 rows only
    assert "| A | 0.0020 -> 0.0040 | 0.0080 -> 0.0100 | 400k -> 400k | 20k -> 20k | +0.0060 |" in text, text
    # the matched table: one row per scene, size and cell, with the ratios to sas and both gaps
    assert "| A | 320x180 | p0 | 0.00200 / 100 | 0.00180 (0.50x, 3.00x) | 0.00500 (1.10x) | 0.00110 | 0.00040 | " \
           "+0.00300 / -0.00070 |" in text, text
    assert "| A | 1280x720 | p0 | 0.00100 / 100 | 0.00090 (0.50x, 3.00x) | 0.00050 (1.10x) | 0.00080 | 0.00020 | " \
           "-0.00050 / -0.00060 |" in text, text
    # B's one-per-pixel run at sas's bits is the better one there
    runs_b = [r for r in runs if r["scene"] == "B" and r["run"] == "tss @sas bits"]
    runs_b[0]["model_dssim"] = 0.0040
    p.write_text(json.dumps({"commits": ["abc"], "setting": "s", "cells": {"p0": {}, "p3": {}}, "runs": runs}))
    text = claims.tss_viewcell_evidence(p)
    assert "| B | 640x360 | p0 | 0.00300 / 100 | 0.00270 (0.50x, 3.00x) | 0.00400 (0.95x) | 0.00100 | 0.00200 | " \
           "+0.00100 / +0.00100 |" in text, text
    # the computed sentences: sample ratios, leads counted per cell, and the trend with resolution
    assert "(0.50-0.50x them; the paper's 0.48-1.61x)" in text, text
    assert "lossless against lossless in 2 of 3 cells (A 320x180 p0, A 1280x720 p0)" in text, text
    assert "each at a crf for those bits) in 1 (A 1280x720 p0)" in text, text
    assert "A p0 320x180 -> 1280x720: lossy +0.00300 (2.50x `sas`'s) -> -0.00050 (0.50x), lossless -0.00070 -> -0.00060" in text, text
    assert "the lossy gap shrinks in 1 of 1 scene-cells (1 as the ratio of the two DSSIMs) and a gap changes sign in 1." in text, text


def test_no_matched_runs_no_matched_section(tmp_path: Path) -> None:
    p = tmp_path / "cells.json"
    p.write_text(json.dumps({"commit": "abc", "setting": "s", "cells": ["p0", "p3"], "runs": [
        {"scene": "A", "cell": c, "run": m, "model_dssim": 0.01, "samples": 1e5} for c in ("p0", "p3")
        for m in ("sas", "tss")]}))
    text = claims.tss_viewcell_evidence(p)
    assert "commit abc" in text and "| A | 0.0100 -> 0.0100 |" in text
    assert "matched runs" not in text
    assert claims.tss_viewcell_evidence(tmp_path / "absent.json") == ""
