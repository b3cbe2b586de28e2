"""Issue 47's bound on the front doors: the session lives in the cores (:mod:`splitrender.pipeline`), and the five
door files that drive them stay thin.  Counted as ``wc -l`` counts (newlines), docstrings and comments included."""

from __future__ import annotations

from pathlib import Path

import splitrender

DOORS = ("sim/runner.py", "server/session.py", "server/worker.py", "client/session.py", "webrtc/session.py")
"""The virtual-time runner, the RTP server's session and its render worker, the live client, the browser session."""
BOUND = 1700
"""Issue 47's "Done when": the five together at most this many lines."""


def door_lines() -> dict[str, int]:
    root = Path(splitrender.__file__).parent
    return {name: (root / name).read_bytes().count(b"\n") for name in DOORS}


def test_the_door_files_exist_and_are_counted() -> None:
    lines = door_lines()
    assert all(n > 100 for n in lines.values()), lines   # a moved or emptied door is a change to this test too


def test_the_five_doors_are_at_most_1700_lines() -> None:
    lines = door_lines()
    total = sum(lines.values())
    assert total <= BOUND, f"the five front doors are {total} lines (bound {BOUND}): " + ", ".join(
        f"{k} {v}" for k, v in lines.items())
