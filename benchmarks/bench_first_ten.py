"""The first ten minutes, per commit (issue 49): ``splitrender demo --quick`` and the test suite, each as a whole
process, wall and CPU seconds, appended to a history so that a regression shows.

Each measurement runs a fresh process on a checkout (``PYTHONPATH`` set to it, its own folder as the working
directory): the demo as the README runs it (``splitrender demo --quick --out DIR``), the suite as the README runs
it (``python3 -m pytest -q``, so with the project's own ``addopts``: under pytest-xdist, two workers).  CPU seconds
are the process tree's (``RUSAGE_CHILDREN`` of this process around the child: every waited-for descendant).
With ``--tree PATH`` (``git worktree add /tmp/before <commit>``) the other checkout is measured too, alternately
with this one (this, before, this, ...), so both see the same machine; quote their ratio, not the seconds.

Appends one row per measured checkout and repeat to ``benchmarks/results/bench_first_ten.csv`` (commit, date,
machine, load average before and after, what was run, wall and CPU seconds, the suite's pass/fail count) and writes
the run's medians to ``benchmarks/results/bench_first_ten.json``.  Run::

    python benchmarks/bench_first_ten.py                      # demo and suite, this checkout, once
    python benchmarks/bench_first_ten.py --only demo --repeat 3
    python benchmarks/bench_first_ten.py --tree /tmp/before   # and the commit before, alternately
    python benchmarks/bench_first_ten.py --from-log ci.log --commit 5e1a817 --note "clean clone, idle"

(``--from-log``: a suite run already made, such as a clean clone's ``bash .ci/run`` saved to a file, recorded from its
last lines without running anything: the pytest summary's count and seconds, and for CPU seconds the session
summary's per-file CPU plus the background stress suite's, tests/conftest.py; the workers' start-up and collection
are not in that figure, so it reads a few per cent under a measured run's)

(the demo takes about 2 minutes and the suite about 10-14 on 2 idle cores: measure with the machine otherwise idle,
or say what ran beside it).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _trees import commit_of  # noqa: E402  (beside this script)

ROOT = Path(__file__).resolve().parents[1]
HISTORY = ROOT / "benchmarks" / "results" / "bench_first_ten.csv"
SUMMARY = ROOT / "benchmarks" / "results" / "bench_first_ten.json"
COLUMNS = ("commit", "date_utc", "machine", "cpus", "load_before", "load_after", "what", "wall_s", "cpu_s", "passed",
           "failed", "note")


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def measure(tree: Path, what: str) -> dict[str, object]:
    """One whole-process run of ``what`` (``demo`` or ``suite``) on ``tree``: wall and CPU seconds and, for the
    suite, how many tests passed and failed."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    with tempfile.TemporaryDirectory(prefix="sr-first-ten-") as out:
        if what == "demo":
            cmd = [sys.executable, "-m", "splitrender.cli", "demo", "--quick", "--out", out]
        else:
            cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"]
        load0 = os.getloadavg()[0]
        c0, t0 = _children_cpu(), time.perf_counter()
        p = subprocess.run(cmd, cwd=str(tree), env=env, capture_output=True, text=True)
        wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
        load1 = os.getloadavg()[0]
    tail = (p.stdout + p.stderr)[-4000:]
    passed = failed = ""
    if what == "suite":
        m = re.search(r"(\d+) passed", tail)
        f = re.search(r"(\d+) failed", tail)
        passed, failed = (m.group(1) if m else "0"), (f.group(1) if f else "0")
    elif p.returncode:
        raise RuntimeError(f"demo on {tree} failed:\n{tail}")
    return {"commit": commit_of(tree), "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
            "machine": platform.platform(), "cpus": os.cpu_count(), "load_before": round(load0, 2),
            "load_after": round(load1, 2), "what": what, "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
            "passed": passed, "failed": failed, "note": "" if not p.returncode or what == "suite" else f"exit {p.returncode}"}


def from_log(path: Path, commit: str) -> dict[str, object]:
    """The suite's row from a saved run's output (``python3 -m pytest -q`` or ``bash .ci/run``): its last summary
    line (``1604 passed, 1 warning in 644.58s``) for the wall seconds and the counts, and CPU seconds as the sum of
    tests/conftest.py's ``CPU seconds by file (all files N`` and ``background stress suite: ..., C CPU s`` (blank
    where the log lacks them; the second not added where the first's list names test_stress.py, which holds it)."""
    text = path.read_text(errors="replace")
    done = [m for m in re.finditer(r"^=*\s*(.*\bin ([0-9.]+)s\b.*?)\s*=*$", text, re.M) if "passed" in m.group(1)
            or "failed" in m.group(1)]
    if not done:
        raise SystemExit(f"{path}: no pytest summary line ('N passed ... in S s')")
    line, wall = done[-1].group(1), float(done[-1].group(2))
    p, f = re.search(r"(\d+) passed", line), re.search(r"(\d+) failed", line)
    files = re.findall(r"CPU seconds by file \(all files (\d+)", text)
    stress = re.findall(r"background stress suite: [0-9.]+ s, ([0-9.]+) CPU s", text)
    # since 08bfeb1 the per-file list charges the stress suite's CPU to test_stress.py (it reaps the suite), so the
    # files' total holds it already: add it only where the list does not name that file
    counted = re.search(r"CPU seconds by file \(all files \d+[^\n]*\btest_stress\.py \d+", text)
    cpu = round(float(files[-1]) + (float(stress[-1]) if stress and not counted else 0.0), 1) if files else ""
    return {"commit": commit, "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime(path.stat().st_mtime)),
            "machine": platform.platform(), "cpus": os.cpu_count(), "load_before": "", "load_after": "",
            "what": "suite", "wall_s": round(wall, 1), "cpu_s": cpu, "passed": p.group(1) if p else "0",
            "failed": f.group(1) if f else "0", "note": f"from the log {path.name}"}


def append_history(row: dict[str, object]) -> None:
    new = not HISTORY.exists()
    with open(HISTORY, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        if new:
            w.writeheader()
        w.writerow(row)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", choices=("demo", "suite"), help="measure only this (default: both)")
    ap.add_argument("--repeat", type=int, default=1, help="measurements of each, per checkout")
    ap.add_argument("--tree", type=Path, help="another checkout to measure alternately (the commit before)")
    ap.add_argument("--note", default="", help="what else ran on the machine, for the history")
    ap.add_argument("--from-log", type=Path, help="record a suite run already made, from its saved output (runs nothing)")
    ap.add_argument("--commit", help="with --from-log: the commit that log ran (a clean clone's HEAD)")
    ns = ap.parse_args()
    if ns.from_log:
        if not ns.commit:
            ap.error("--from-log needs --commit (the log does not name its commit)")
        if not ns.from_log.is_file():
            ap.error(f"--from-log {ns.from_log}: no such file")
        full = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--verify", ns.commit + "^{commit}"],
                              capture_output=True, text=True)
        if full.returncode:
            ap.error(f"--commit {ns.commit}: not a commit of {ROOT}")
        row = from_log(ns.from_log, full.stdout.strip())
        row["note"] = "; ".join(x for x in (str(row["note"]), ns.note) if x)
        append_history(row)
        print(json.dumps(row))
        return
    whats = [ns.only] if ns.only else ["demo", "suite"]
    trees = [("this", ROOT)] + ([("before", ns.tree.resolve())] if ns.tree else [])
    rows: dict[tuple[str, str], list[dict[str, object]]] = {}
    for _ in range(ns.repeat):
        for what in whats:
            for label, tree in trees:
                row = measure(tree, what)
                row["note"] = "; ".join(x for x in (str(row["note"]), ns.note) if x)
                append_history(row)
                rows.setdefault((label, what), []).append(row)
                print(json.dumps(row), flush=True)
    out: dict[str, object] = {"machine": platform.platform(), "cpus": os.cpu_count(), "note": ns.note}
    for (label, what), rs in rows.items():
        out[f"{label} {what}"] = {"commit": rs[0]["commit"], "wall_s_median": statistics.median(float(r["wall_s"]) for r in rs),
                                  "cpu_s_median": statistics.median(float(r["cpu_s"]) for r in rs), "runs": len(rs)}
    if ns.tree:
        for what in whats:
            a, b = out.get(f"this {what}"), out.get(f"before {what}")
            if isinstance(a, dict) and isinstance(b, dict):
                out[f"{what} wall ratio (this / before)"] = round(a["wall_s_median"] / b["wall_s_median"], 3)
                out[f"{what} cpu ratio (this / before)"] = round(a["cpu_s_median"] / b["cpu_s_median"], 3)
    SUMMARY.write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
