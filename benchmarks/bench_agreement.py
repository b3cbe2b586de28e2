"""Virtual time against live: the full grid of :mod:`splitrender.experiments.agreement`.

Every cell (impairment x loss recovery) runs the same seeded session in virtual time
(the baseline, measured in the same run) and live on loopback through the shaping
relay, for each seed; writes ``benchmarks/results/bench_agreement.json`` with one row
per cell and seed (``<column>_vt`` and ``<column>_live``), the mean over seeds per cell
(``rows``, which the report's "Virtual time against live" study charts) and which
targets each cell meets (frames shown within 5 points, NACK and keyframe counts within
20 % or 2).

Run it on an otherwise idle machine: a live server that skips ticks measures the load.

    python benchmarks/bench_agreement.py [--duration 8] [--seeds 1,2,3] [--cells "loss 2%/nack,bursty/patient"]
                                         [--merge earlier.json ...]

``--merge`` adds the runs an earlier invocation recorded (other seeds, same set-up and duration)
before the means are taken, so seeds can be run in several sittings.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import platform
import time
from pathlib import Path
from typing import Any

from splitrender.experiments.agreement import COMPARED, IMPAIRMENTS, RECOVERY, SETUP, run_cell, within_targets

OUT = Path(__file__).parent / "results" / "bench_agreement.json"


def mean_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per cell: the mean over seeds of every compared column."""
    cells: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in rows:
        cells.setdefault((r["impairment"], r["recovery"]), []).append(r)
    out = []
    for (imp, rec), rr in cells.items():
        m: dict[str, Any] = {"impairment": imp, "recovery": rec, "network": rr[0]["network"], "seeds": len(rr)}
        for k in COMPARED:
            for side in ("vt", "live"):
                v = [float(r[f"{k}_{side}"]) for r in rr if not math.isnan(float(r[f"{k}_{side}"]))]
                m[f"{k}_{side}"] = sum(v) / len(v) if v else math.nan
        m["targets"] = within_targets(m)
        out.append(m)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--cells", default="", help="comma-separated impairment/recovery pairs (default: the whole grid)")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--merge", type=Path, nargs="*", default=[], help="earlier results whose runs join these")
    ns = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    logging.getLogger("splitrender.experiments.agreement").setLevel(logging.INFO)
    cells = [tuple(c.split("/", 1)) for c in ns.cells.split(",") if c] or [(i, r) for i in IMPAIRMENTS for r in RECOVERY]
    seeds = [int(s) for s in ns.seeds.split(",") if s]   # "" with --merge: only average what was recorded
    rows = []
    t0 = time.perf_counter()
    merged_s = 0.0
    for imp, rec in cells:
        for seed in seeds:
            rows.append(run_cell(imp, rec, ns.duration, seed))
    for f in ns.merge:
        old = json.loads(f.read_text())
        if old.get("setup") != SETUP or old.get("duration_s") != ns.duration:
            raise SystemExit(f"{f}: recorded with another set-up or duration; not merged")
        rows += old["runs"]
        merged_s += float(old.get("elapsed_s", 0.0))
        seeds += [s for s in old["seeds"] if s not in seeds]
    means = mean_rows(rows)
    result = {"benchmark": "agreement", "setup": SETUP, "duration_s": ns.duration, "seeds": seeds,
              "impairments": IMPAIRMENTS, "recovery": RECOVERY, "machine": {"python": platform.python_version(),
                                                                            "cpus": os.cpu_count()},
              "elapsed_s": time.perf_counter() - t0 + merged_s, "rows": means, "runs": rows,
              "cells_meeting_all_targets": sum(all(m["targets"].values()) for m in means), "cells": len(means)}
    ns.out.parent.mkdir(parents=True, exist_ok=True)
    ns.out.write_text(json.dumps(result, indent=1, default=str))
    for m in means:
        print(f"{m['impairment']:8s} {m['recovery']:9s} shown {m['shown_pct_vt']:5.1f} / {m['shown_pct_live']:5.1f} %  "
              f"NACKs {m['nacks_vt']:5.1f} / {m['nacks_live']:5.1f}  keyframes {m['keyframes_vt']:4.1f} / "
              f"{m['keyframes_live']:4.1f}  {m['targets']}")
    print(f"{result['cells_meeting_all_targets']} of {len(means)} cells meet every target -> {ns.out}")


if __name__ == "__main__":
    main()
