"""Study: virtual time against live, the same seeded session both ways (:mod:`..agreement`).

For each cell of impairment (no loss, 2 % random loss, bursty Gilbert-Elliott loss, a rate
limit below the stream's bit rate) x loss recovery (NACK alone, NACK with FEC, the
patient client with FEC and a 300 ms playout delay, no NACK), the session runs in
virtual time and live on loopback through the shaping relay, and the chart sets the two
side by side: frames shown, the longest freeze, NACKs, PLIs, keyframes and mean PSNR.

Running the live half needs the machine to itself (a live server that skips ticks under
load measures the load), so the quick run (inside the demo, beside the other studies)
charts the grid recorded by ``benchmarks/bench_agreement.py`` when it is there, and runs
only the 2 % loss cell with NACK anew; the full run runs the whole grid.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

from ...tabular import write_csv
from ..agreement import COMPARED, IMPAIRMENTS, RECOVERY, run_cell, within_targets
from ..sections import Section
from ._util import save_figure

log = logging.getLogger(__name__)

RECORDED = Path(__file__).resolve().parents[3] / "benchmarks" / "results" / "bench_agreement.json"
"""The grid as the benchmark last recorded it (present in a source checkout)."""

PANELS = (("shown_pct", "frames shown (%)"), ("longest_freeze_ms", "longest freeze (ms)"), ("nacks", "NACKs sent"),
          ("keyframe_requests", "PLIs sent"), ("keyframes", "keyframes sent"), ("mean_psnr_db", "mean PSNR (dB)"))


def chart(rows: list[dict[str, Any]], path: Path, title: str) -> Path:
    """Six panels, one bar pair (virtual time, live) per cell."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    labels = [f"{r['impairment']}\n{r['recovery']}" for r in rows]
    x = np.arange(len(rows))
    fig, axes = plt.subplots(3, 2, figsize=(max(8.0, 0.75 * len(rows) + 3), 9.5))
    for ax, (key, name) in zip(axes.ravel(), PANELS):
        vt = [float(r.get(f"{key}_vt", math.nan)) for r in rows]
        lv = [float(r.get(f"{key}_live", math.nan)) for r in rows]
        ax.bar(x - 0.2, vt, 0.4, label="virtual time", color="#4878a8")
        ax.bar(x + 0.2, lv, 0.4, label="live (loopback relay)", color="#e0803a")
        ax.set_title(name, fontsize=9)
        ax.set_xticks(x, labels, fontsize=6, rotation=90)
        ax.tick_params(axis="y", labelsize=7)
        ax.grid(axis="y", alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> Path:
    write_csv(path, rows)
    return path


def _table(rows: list[dict[str, Any]]) -> str:
    head = "| impairment | recovery | shown % (vt / live) | longest freeze ms | NACKs | PLIs | keyframes | PSNR dB | targets |\n" \
           "|---|---|---|---|---|---|---|---|---|\n"
    out = []
    for r in rows:
        t = within_targets(r)
        ok = "all met" if all(t.values()) else "missed: " + ", ".join(k for k, v in t.items() if not v)
        out.append(f"| {r['impairment']} | {r['recovery']} | {r['shown_pct_vt']:.1f} / {r['shown_pct_live']:.1f} | "
                   f"{r['longest_freeze_ms_vt']:.0f} / {r['longest_freeze_ms_live']:.0f} | {r['nacks_vt']:.0f} / {r['nacks_live']:.0f} | "
                   f"{r['keyframe_requests_vt']:.0f} / {r['keyframe_requests_live']:.0f} | {r['keyframes_vt']:.0f} / "
                   f"{r['keyframes_live']:.0f} | {r['mean_psnr_db_vt']:.2f} / {r['mean_psnr_db_live']:.2f} | {ok} |")
    return head + "\n".join(out)


def run(out_dir: Path, quick: bool) -> Section:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    recorded: list[dict[str, Any]] = []
    if quick and RECORDED.is_file():
        recorded = json.loads(RECORDED.read_text()).get("rows", [])
    if quick:
        fresh = [run_cell("loss 2%", "nack", duration_s=6.0, seed=1)]
    else:
        fresh = [run_cell(i, r, duration_s=8.0, seed=1) for i in IMPAIRMENTS for r in RECOVERY]
    figs = [chart(fresh, out_dir / "agreement_now.png", "virtual time against live: this run")]
    if recorded:
        figs.insert(0, chart(recorded, out_dir / "agreement_recorded.png",
                             "virtual time against live: the grid recorded by benchmarks/bench_agreement.py"))
    tables = [_write_csv(out_dir / "agreement.csv", fresh)]
    met = sum(all(within_targets(r).values()) for r in (recorded or fresh))
    text = (
        "The same seeded session (`video` on `minimal` at 160x90, 15 server frames and 30 display ticks a second, "
        "MTU 300) runs in virtual time and live on loopback through the shaping relay, under each impairment on both "
        "directions, with each loss-recovery set-up.  Both modes run the same sans-IO session cores "
        "(`splitrender.pipeline.session`: RTCP, NACK and retransmission, PLI, FEC, playout delay, stall detection), "
        "so what differs is the random draws of the two network models (the relay's and the simulator's) and the live "
        "machine's scheduling.  Targets: frames shown within 5 percentage points, NACK and keyframe counts within 20 % "
        f"(or 2).  {met} of {len(recorded or fresh)} cells meet all three"
        + (" in the recorded grid.\n\n" if recorded else ".\n\n")
        + ("**Recorded grid** (`benchmarks/bench_agreement.py`):\n\n" + _table(recorded) + "\n\n" if recorded else "")
        + "**This run**:\n\n" + _table(fresh) + "\n")
    log.info("agreement study: %d cells run", len(fresh))
    return Section("Virtual time against live", text, figs, tables)


__all__ = ["COMPARED", "run"]
