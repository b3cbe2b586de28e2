"""``splitrender.protocol.schema``: each field kind against the values a peer can send (Python and numpy scalars,
lists, maps, arrays), exact error texts with the field path, named dimensions, and the h11 rule under fuzzing:
a value validates or raises the schema's error class, nothing else."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.errors import RemoteProtocolError
from splitrender.protocol.schema import (Array, Bool, Check, Dim, Field, Float, Int, Map, Nullable, Opt, Schema, Seq, Str,
                                         Transforms, Tup, Version, show)


class PeerError(RemoteProtocolError):
    """The caller's error class."""


def parse(field: Field, value: Any, **dims: Any) -> Any:
    return Schema("test", PeerError, field).parse(value, dims)


def error(field: Field, value: Any, **dims: Any) -> str:
    with pytest.raises(PeerError) as info:
        parse(field, value, **dims)
    assert type(info.value) is PeerError
    return str(info.value)


def test_int() -> None:
    f = Int(0, 10)
    assert parse(f, 3) == 3 and type(parse(f, np.int64(3))) is int and parse(f, np.uint8(10)) == 10
    for bad, shown in ((True, "True"), (3.0, "3.0"), (float("inf"), "inf"), (np.array([3, 3]), "array int64 (2,)"),
                       (np.bool_(True), "True"), ("3", "'3'"), (11, "11"), (-1, "-1"), (None, "None")):
        assert error(f, bad) == f"test: expected an integer in 0..10, got {shown}"
    assert error(Int(1), 0) == "test: expected an integer >= 1, got 0"
    assert error(Int(hi="n"), 5, n=4) == "test: expected an integer <= 4, got 5"
    assert parse(Int(), 2**64 - 1) == 2**64 - 1


def test_float() -> None:
    f = Float(0.0, 1.0, hi_open=True)
    assert parse(f, 0) == 0.0 and type(parse(f, np.float32(0.5))) is float and parse(f, np.int16(0)) == 0.0
    for bad, shown in ((float("nan"), "nan"), (1.0, "1.0"), (True, "True"), (np.array([0.5]), "array float64 (1,)"),
                       (10**400, repr(10**400)[:57] + "...")):
        assert error(f, bad) == f"test: expected a finite number in [0, 1), got {shown}"
    assert error(Float(), float("inf")) == "test: expected a finite number, got inf"
    assert parse(Float(finite=False), float("inf")) == float("inf")
    assert error(Float(finite=False), float("nan")) == "test: expected a number, got nan"
    assert error(Float(0.0, 1e6, lo_open=True), 0.0) == "test: expected a finite number in (0, 1e+06], got 0.0"


def test_bool_str_version() -> None:
    assert parse(Bool(), np.bool_(False)) is False
    assert error(Bool(), 1) == "test: expected a bool, got 1"
    assert error(Bool(), np.array([True, False])) == "test: expected a bool, got array bool (2,)"
    assert parse(Str(("a", "b")), "b") == "b"
    assert error(Str(("a", "b")), "c") == "test: 'c' is not one of ['a', 'b']"
    assert error(Str(("a", "b")), ["a"]) == "test: expected one of ['a', 'b'], got ['a']"
    assert error(Str(max_len=3), "abcd") == "test: string of 4 characters, at most 3"
    assert parse(Version(3), np.int32(3)) == 3
    for bad, shown in ((np.array([3, 3]), "array int64 (2,)"), (3.0, "3.0"), (True, "True"), ("3", "'3'"), (4, "4")):
        assert error(Version(3), bad) == f"test: version {shown}, this client speaks 3"


def test_seq_tup_and_paths() -> None:
    f = Seq(Int(0, 9), 3)
    assert parse(f, (1, 2, 3)) == [1, 2, 3]
    assert error(f, [1, 2]) == "test: expected a list of 3, got [1, 2]"
    assert error(f, [1, 2, 10]) == "test: [2]: expected an integer in 0..9, got 10"
    assert error(f, np.array([1, 2, 3])) == "test: expected a list of 3, got array int64 (3,)"
    assert parse(Seq(Int(0, 9), 3, arrays=True), np.array([1, 2, 3])) == [1, 2, 3]
    assert error(Seq(Int(), min_len=1, max_len=2), []) == "test: expected a list of 1 to 2, got []"
    assert error(Seq(Int(), max_len="m"), [1] * 9, m=4) == "test: expected a list of at most 4, got list of 9"
    lengths = Map({"a": Seq(Int(), "n"), "b": Seq(Int(), "n")})
    assert parse(lengths, {"a": [1, 2], "b": [3, 4]}) == {"a": [1, 2], "b": [3, 4]}
    assert error(lengths, {"a": [1, 2], "b": [3]}) == "test: b: expected a list of 2, got [3]"
    t = Tup(Float(), Int(1, 5), Str())
    assert parse(t, [0.5, 2, "x"]) == [0.5, 2, "x"]
    assert error(t, [0.5, 9, "x"]) == "test: [1]: expected an integer in 1..5, got 9"
    nested = Map({"objects": Seq(Map({"material": Map({"rgb": Seq(Float(), 3)})}))})
    bad = {"objects": [{"material": {"rgb": [0, 0, 0]}}, {"material": {"rgb": [0, float("nan"), 0]}}]}
    assert error(nested, bad) == "test: objects[1].material.rgb[1]: expected a finite number, got nan"


def test_map_opt_nullable_check() -> None:
    f = Map({"a": Int(), "b": Opt(Int(), 7), "c": Nullable(Int()), "d": Check(Int(), lambda v: v % 2 == 0, "must be even")})
    assert parse(f, {"a": 1, "c": None, "d": 2, "extra": object()}) == {"a": 1, "b": 7, "c": None, "d": 2}
    assert error(f, {"a": 1, "d": 2}) == "test: c: missing"
    assert error(f, {"a": 1, "c": 1, "d": 3}) == "test: d: must be even"
    assert error(f, [1]) == "test: expected a map, got [1]"
    assert error(f, {"a": {"x": 1}}) == "test: a: expected an integer, got map of 1"


def test_array() -> None:
    f = Array("iu", ("n", 2), cast=np.int64, lo=0, hi="last")
    out = parse(f, np.array([[1, 2]], np.uint16), last=5)
    assert out.dtype == np.int64 and out.tolist() == [[1, 2]]
    assert error(f, np.zeros((1, 2), np.float32), last=5) == "test: dtype float32, expected integers"
    assert error(f, np.zeros((1, 3), np.int8), last=5) == "test: shape (1, 3), expected (1, 2)"
    assert error(f, np.array([[1, 6]]), last=5) == "test: values must be in 0..5, got 1..6"
    assert error(f, np.array([[2**63, 0]], np.uint64), last=5) == "test: values beyond int64"
    assert error(f, [[1, 2]], last=5) == "test: expected an array of integers of shape (n, 2), got list of 1"
    pair = Map({"ids": Array("iu", ("X",)), "xf": Array("f", ("X", 4), finite=True, cast=np.float32)})
    assert error(pair, {"ids": np.zeros(2, np.int32), "xf": np.zeros((3, 4))}) == "test: xf: shape (3, 4), expected (2, 4)"
    assert error(pair, {"ids": np.zeros(1, np.int32), "xf": np.full((1, 4), 1e39)}) == "test: xf: values not finite in float32"
    assert error(Array(dtype=(np.uint8, np.uint16)), np.zeros(2, np.int8)) == "test: dtype int8, expected uint8/uint16"
    img = Array(dtype=np.uint8, shape=(Dim(None, 1, 8), Dim(None, 1, 8), 3))
    assert error(img, np.zeros((9, 2, 3), np.uint8)) == "test: shape (9, 2, 3): a dimension of 9 is not in 1..8"
    opt = Map({"ids": Array("iu", ("X",), cast=np.int64, empty_if_absent=True),
               "rows": Array("iu", ("X", 5), cast=np.int64, empty_if_absent=True)})
    got = parse(opt, {})
    assert got["ids"].shape == (0,) and got["rows"].shape == (0, 5) and got["rows"].dtype == np.int64
    assert error(opt, {"ids": np.zeros(3, np.int32)}) == "test: rows: missing, expected shape (3, 5)"
    scoped = Seq(Map({"p": Array("f", ("V", 3)), "n": Array("f", ("V", 3))}, scope=True))
    assert len(parse(scoped, [{"p": np.zeros((2, 3)), "n": np.zeros((2, 3))},
                              {"p": np.zeros((5, 3)), "n": np.zeros((5, 3))}])) == 2


def _rot(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def test_transforms() -> None:
    meta = Schema("tss metadata", PeerError, Map({"v": Version(3), "xf": Transforms("n")}))
    good = np.stack([_rot(10 * k) @ np.diag([2.0, 2.0, 2.0, 1.0]) for k in range(5)])
    good[:, :3, 3] = [1.0, -2.0, 1e5]
    out = meta.parse({"v": 3, "xf": good}, {"n": 5})["xf"]
    assert out.dtype == np.float32 and np.array_equal(out, good.astype(np.float32))

    def err(k: int, m: np.ndarray) -> str:
        xf = good.copy()
        xf[k] = m
        with pytest.raises(PeerError) as info:
            meta.parse({"v": 3, "xf": xf}, {"n": 5})
        return str(info.value)

    singular = np.eye(4)
    singular[:3, :3] = 0.0
    assert err(3, singular) == "tss metadata: xf[3]: singular transform (|det| 0 < 1e-12)"
    assert err(1, np.zeros((4, 4))) == "tss metadata: xf[1]: last row [0.0, 0.0, 0.0, 0.0] is not (0, 0, 0, 1)"
    assert err(2, np.full((4, 4), 1e300)) == "tss metadata: xf[2]: not finite in float32"
    far = np.eye(4)
    far[0, 3] = 3e38
    assert err(0, far) == "tss metadata: xf[0]: entry 3e+38 beyond +-1e+06"
    assert err(4, np.diag([1e3, 1e3, 1e-5, 1.0])) == \
        "tss metadata: xf[4]: ill-conditioned transform (condition number 1e+08 > 1e+07)"
    nan = np.eye(4)
    nan[1, 1] = np.nan
    assert err(0, nan) == "tss metadata: xf[0]: not finite"
    with pytest.raises(PeerError, match=r"^tss metadata: xf: shape \(4, 4, 4\), expected \(5, 4, 4\)$"):
        meta.parse({"v": 3, "xf": good[:4]}, {"n": 5})
    with pytest.raises(PeerError, match=r"^tss metadata: xf: expected a float array \(5, 4, 4\), got array int64"):
        meta.parse({"v": 3, "xf": good.astype(np.int64)}, {"n": 5})
    # a projective matrix where the wire does not promise affine; one 4x4
    proj = np.eye(4)
    proj[3] = [0.0, 0.0, -1.0, 0.0]
    assert parse(Transforms(affine=False), proj).shape == (4, 4)
    assert error(Transforms(), proj) == "test: last row [0.0, 0.0, -1.0, 0.0] is not (0, 0, 0, 1)"
    assert error(Transforms(), np.zeros((4, 4)) + np.eye(4) * [0, 1, 1, 1]) == "test: singular transform (|det| 0 < 1e-12)"


def test_error_at_and_where() -> None:
    s = Schema("sas metadata", PeerError, Map({"v": Version(4)}))
    assert str(s.error_at("uv_rect", "a block lies outside the atlas")) == "sas metadata: uv_rect: a block lies outside the atlas"
    assert str(s.error_at(["geo", 2, "x"], "bad")) == "sas metadata: geo[2].x: bad"
    with pytest.raises(PeerError, match=r"^warp metadata frame 7: v: version 5, this client speaks 4$"):
        s.parse({"v": 5}, where="warp metadata frame 7")
    assert show(np.float32(0.5)) == "0.5" and show({"a": 1}) == "map of 1" and show(object()) == "object"
    assert show(list(range(100))) == "list of 100" and show("x" * 100) == repr("x" * 100)[:57] + "..."


SCHEMA = Schema("fuzz", PeerError, Map({
    "v": Version(1),
    "n": Int(0, 8, bind="n"),
    "sky": Opt(Seq(Float(0.0, 1.0), 3), (0.0, 0.0, 0.0)),
    "kind": Str(("a", "b")),
    "ids": Array("iu", ("n",), cast=np.int64, lo=0, hi=100, empty_if_absent=True),
    "xf": Transforms("n", empty_if_absent=True),
    "cams": Seq(Tup(Float(-1e6, 1e6), Int(1, 4096)), max_len=4),
}))
_SCALARS = (st.none() | st.booleans() | st.integers(-(2**64), 2**64) | st.floats() | st.text(max_size=4)
            | st.builds(np.int64, st.integers(-(2**63), 2**63 - 1)) | st.builds(np.float32, st.floats(width=32)))


def _array(shape: tuple[int, ...], dt: str, fill: Any) -> np.ndarray:
    with np.errstate(all="ignore"):
        return np.full(shape, fill).astype(dt, casting="unsafe")


_ARRAYS = st.builds(_array,
                    st.lists(st.integers(0, 4), max_size=3).map(tuple),
                    st.sampled_from(["int8", "uint64", "float32", "float64", "bool"]),
                    st.sampled_from([0, 1, -1, 1e300, float("nan"), 2**63]))
_VALUES = st.recursive(_SCALARS | _ARRAYS, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=4), c, max_size=4),
                       max_leaves=12)
_GOOD = {"v": 1, "n": 2, "kind": "a", "ids": np.array([1, 2]), "xf": np.tile(np.eye(4), (2, 1, 1)), "cams": [[0.0, 1]]}


@given(st.one_of(_VALUES, st.fixed_dictionaries({k: st.one_of(st.just(v), _VALUES) for k, v in _GOOD.items()})))
@settings(max_examples=300)
def test_fuzz_validates_or_raises_the_schemas_error(value: Any) -> None:
    try:
        out = SCHEMA.parse(value)
    except PeerError as exc:
        assert str(exc).startswith("fuzz: ")
        return
    assert out["v"] == 1 and out["ids"].shape == (out["n"],) and out["xf"].shape == (out["n"], 4, 4)
    assert np.isfinite(out["xf"]).all()
