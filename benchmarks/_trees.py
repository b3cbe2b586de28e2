"""What the before/after benchmarks share: one configuration in a child process on a given checkout.

A benchmark that compares this checkout with the commit before a change (``git worktree add /tmp/before <commit>``)
runs each configuration as ``python -c CHILD ARG`` with ``PYTHONPATH`` set to the tree, so both trees are measured
in the same invocation on the same loaded machine; ``CHILD`` prints its figures as one ``RESULT {json}`` line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path


def run_in_tree(tree: Path, child: str, arg: dict, what: str) -> dict:
    """``child`` run on ``tree`` with ``arg`` (JSON) as its argument: its ``RESULT`` dict and ``wall_s``; a failure
    raises naming ``what`` with the child's error output."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", child, json.dumps(arg)], env=env, cwd=str(tree), capture_output=True,
                       text=True)
    line = [x for x in p.stdout.splitlines() if x.startswith("RESULT ")]
    if p.returncode or not line:
        raise RuntimeError(f"{what} from {tree} failed:\n{p.stderr[-3000:]}")
    out = json.loads(line[-1][7:])
    out["wall_s"] = time.perf_counter() - t0
    return out


def run_cell(tree: str | Path, script: str, arg: dict, what: str) -> dict:
    """``python script --cell ARG`` on ``tree`` (a benchmark that measures one cell per process, itself the child):
    the JSON dict its last line of output prints, checked to come from ``tree``; a failure raises naming ``what``."""
    p = subprocess.run([sys.executable, script, "--cell", json.dumps(arg)], env=dict(os.environ, PYTHONPATH=str(tree)),
                       cwd=str(tree), capture_output=True, text=True)
    if p.returncode:
        raise RuntimeError(f"{what} on {tree}:\n{p.stderr[-3000:]}")
    got = json.loads(p.stdout.strip().splitlines()[-1])
    assert got["tree"] == str(Path(tree).resolve()), (got["tree"], tree)
    return got


def commit_of(tree: Path, paths: str = "splitrender") -> str:
    """The tree's commit, and whether ``paths`` in it carry uncommitted changes."""
    r = subprocess.run(["git", "-C", str(tree), "rev-parse", "HEAD"], capture_output=True, text=True)
    d = subprocess.run(["git", "-C", str(tree), "status", "--porcelain", "--", paths], capture_output=True, text=True)
    return r.stdout.strip() + (f" + uncommitted {paths} changes" if d.stdout.strip() else "")
