"""Writing result tables: a list of dicts to CSV, whole (:func:`write_csv`, written to a
temporary file and renamed, so a reader never sees half a table) or row by row
(:class:`CsvAppender`, flushed per row, so a process killed at any moment leaves every row
it had finished).

It imports nothing else from the project, so every layer (the simulator, the live
client and server, the experiments) can write its tables through it without reaching
sideways into another's module.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

__all__ = ["CsvAppender", "atomic_file", "atomic_write_bytes", "write_csv", "write_csv_passes"]


@contextmanager
def atomic_file(path: Path, mode: str = "w", newline: str | None = None) -> Iterator[IO[Any]]:
    """A file opened at a temporary name in ``path``'s folder and renamed to ``path`` once written: a reader (or
    a process killed meanwhile) sees the old file or the whole new one, never part of it."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with open(tmp, mode, newline=newline) as f:
            yield f
    except BaseException:
        tmp.unlink(missing_ok=True)  # the old file stays as it was, and no half-written one is left beside it
        raise
    os.replace(tmp, path)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """``data`` to ``path`` through :func:`atomic_file`."""
    with atomic_file(path, "wb") as f:
        f.write(data)


class CsvAppender:
    """A CSV file written one row at a time with fixed columns; each row is flushed to the operating system as
    it is appended.  Keys a row has beyond the columns are left out (counted in :attr:`extra_keys`)."""

    def __init__(self, path: Path, fieldnames: Iterable[str]) -> None:
        self.path = path
        self.fieldnames = list(fieldnames)
        self._cols = set(self.fieldnames)
        self._f: IO[str] | None = open(path, "w", newline="")
        self._w = csv.DictWriter(self._f, fieldnames=self.fieldnames, restval="", extrasaction="ignore")
        self._w.writeheader()
        self._f.flush()
        self.rows = 0
        self.extra_keys = 0

    def append(self, row: dict[str, Any]) -> None:
        if self._f is None:
            raise ValueError(f"{self.path}: appended to after close")
        self.extra_keys += sum(1 for k in row if k not in self._cols)
        self._w.writerow({k: _fmt(v) for k, v in row.items() if k in self._cols})
        self._f.flush()
        self.rows += 1

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None


def write_csv(path: Path, rows: Iterable[dict[str, Any]], columns: Sequence[str] | None = None) -> None:
    """``rows`` as a CSV table whose columns are ``columns`` (other keys left out) or else every key in order of
    first appearance; NaN is an empty cell; written whole through :func:`atomic_file`.  The project's one CSV
    writer (``experiments.store.write_csv`` is this with bools as 0/1)."""
    rows = list(rows)
    write_csv_passes(path, lambda: rows, columns)


def write_csv_passes(path: Path, rows: Callable[[], Iterable[dict[str, Any]]],
                     columns: Sequence[str] | None = None) -> int:
    """:func:`write_csv` for rows read twice from their source (``rows()`` gives a fresh iterable each call: once
    for the columns, once to write), so that memory stays flat however many there are.  Returns the rows
    written."""
    keys: dict[str, None] = dict.fromkeys(columns) if columns is not None else {}
    if columns is None:
        for r in rows():
            keys.update(dict.fromkeys(r))
    n = 0
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(Path(path), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(keys), restval="", extrasaction="ignore")
        w.writeheader()
        for r in rows():
            w.writerow({k: _fmt(v) for k, v in r.items()})
            n += 1
    return n


def _fmt(v: Any) -> Any:
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return v
