"""The one CSV writer (``splitrender.tabular.write_csv``), which the result store's ``write_csv`` goes through."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from splitrender.experiments.store import read_csv, write_csv


def test_store_tables_round_trip_with_columns_bools_and_nan(tmp_path: Path) -> None:
    p = write_csv(tmp_path / "sub" / "t.csv", [{"a": 1, "b": True, "c": math.nan, "x": "drop"}, {"a": 2.5, "b": False}],
                  columns=["a", "b", "c"])
    assert p.read_text().splitlines() == ["a,b,c", "1,1,", "2.5,0,"]
    rows = read_csv(p)
    assert rows[0]["a"] == 1 and rows[0]["b"] == 1 and math.isnan(rows[0]["c"]) and "x" not in rows[0]
    assert write_csv(tmp_path / "empty.csv", [], columns=["a", "b"]).read_text().strip() == "a,b"


def test_a_writer_that_fails_leaves_the_old_table_whole(tmp_path: Path) -> None:
    """The store's writer used to write in place: a run killed mid-table left half a summary.csv behind."""
    p = write_csv(tmp_path / "t.csv", [{"a": 1}])

    class Unprintable:
        def __str__(self) -> str:
            raise RuntimeError("killed while writing")

    with pytest.raises(RuntimeError, match="killed while writing"):
        write_csv(p, [{"a": 2}, {"a": Unprintable()}])   # fails on the second row, after the first was written
    assert p.read_text().splitlines() == ["a", "1"]
    assert sorted(q.name for q in tmp_path.iterdir()) == ["t.csv"]   # no temporary file left beside it
