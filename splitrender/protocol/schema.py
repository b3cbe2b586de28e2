"""Declarative validation of what a peer sent: decoded msgpack values, checked once.

A :class:`Schema` is a tree of fields (usually a :class:`Map` at the root), the place it
validates (``"tss metadata"``) and the caller's
:class:`~splitrender.errors.RemoteProtocolError` subclass.  :meth:`Schema.parse` takes a
value as the bounded msgpack layer decoded it (dicts, lists, Python scalars, numpy
arrays from the metadata's array extension; numpy scalars where a session is built in
process) and returns the validated values, converted (Python ``int``/``float``/``bool``,
arrays cast to the dtype the caller works in), or raises the caller's class with the
full field path: ``tss metadata: xf[3]: singular transform (|det| 0 < 1e-12)``.

Fields: :class:`Int`, :class:`Float`, :class:`Bool`, :class:`Str`, :class:`Const` and
:class:`Version`, :class:`Seq` and :class:`Tup`, :class:`Map`, :class:`Array`,
:class:`Transforms`; wrappers :class:`Opt` (absent: a default), :class:`Nullable` (nil
allowed) and :class:`Check` (a predicate after a field).  Sizes are tied together by
named dimensions: an array dimension, a list length or a bound given as a name takes its
value from ``parse(dims=...)`` (what the session declared) or from the first field that
binds it (``Int(bind=...)``, an array's or a list's first use of the name), and every
later use must agree; a :class:`Map` with ``scope=True`` keeps the names its fields bind
to itself (per object of a list).  A method's own rule is a :class:`Field` subclass or a
check after :meth:`Schema.parse` raising :meth:`Schema.error_at`, in the same format.

Why not msgspec (``Struct`` + ``Meta`` constraints, validated while decoding MessagePack):
our metadata reaches a client half already decoded by the bounded msgpack layer, whose
extension hook builds numpy arrays, and most of what a client must check is about those
arrays (dtype, shape against the session, finiteness in float32, invertible transforms),
which msgspec's constraints do not express.  ``msgspec.convert`` on the decoded value
also refuses the numpy integer scalars an in-process session carries, so it would have
been a new dependency covering the scalar fields while every array kept a hand check in
a second error format.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any, Generic, TypeVar

import numpy as np

from splitrender.errors import RemoteProtocolError

__all__ = ["Array", "Bool", "Check", "Const", "Dim", "Field", "Float", "Int", "Invalid", "Map", "Nullable", "Opt",
           "Schema", "Seq", "Str", "Transforms", "Tup", "Version", "show"]

E = TypeVar("E", bound=RemoteProtocolError)
_MISSING: Any = object()
_I64 = 2**63
_AFFINE_ROW = np.array([0.0, 0.0, 0.0, 1.0])


class Invalid(Exception):
    """A field's complaint: ``reason``, and ``path`` (keys and indices, innermost first) filled in while it
    propagates out of the containers.  :meth:`Schema.parse` turns it into the caller's error class."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason
        self.path: list[str | int] = []


def format_path(path: list[str | int]) -> str:
    """``["xf", 3]`` (outermost first) as ``xf[3]``, ``["objects", 0, "positions"]`` as ``objects[0].positions``."""
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


def show(v: Any) -> str:
    """A short description of a peer value for an error message (never its whole contents)."""
    if isinstance(v, np.ndarray):
        return f"array {v.dtype} {v.shape}"
    if isinstance(v, np.generic):
        v = v.item()
    if v is None or isinstance(v, (bool, int, float, str, bytes)):
        r = repr(v)
        return r if len(r) <= 60 else r[:57] + "..."
    if isinstance(v, (list, tuple)):
        if len(v) <= 8 and all(x is None or isinstance(x, (bool, int, float, str)) for x in v):
            r = repr(list(v))
            if len(r) <= 60:
                return r
        return f"{type(v).__name__} of {len(v)}"
    if isinstance(v, dict):
        return f"map of {len(v)}"
    return type(v).__name__


def _resolve(b: Any, ctx: dict[str, Any]) -> Any:
    """A bound given as a name: its value in ``ctx`` (dims passed to :meth:`Schema.parse` or bound earlier)."""
    return ctx[b] if isinstance(b, str) else b


def _num(x: float) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


class Field:
    """One kind of value: :meth:`check` validates and converts a present value, :meth:`absent` answers for a missing
    map entry (an error unless the field says otherwise).  ``ctx`` holds the named dimensions."""

    def check(self, v: Any, ctx: dict[str, Any]) -> Any:
        raise NotImplementedError

    def absent(self, ctx: dict[str, Any]) -> Any:
        raise Invalid("missing")


class Int(Field):
    """An integer in ``lo..hi`` (inclusive; a bound may be a dimension name): Python or numpy integers, not bools,
    floats or arrays.  ``bind`` names a dimension the value defines for later fields."""

    def __init__(self, lo: int | str | None = None, hi: int | str | None = None, *, bind: str | None = None) -> None:
        self.lo, self.hi, self.bind = lo, hi, bind

    def _what(self, ctx: dict[str, Any]) -> str:
        lo, hi = _resolve(self.lo, ctx), _resolve(self.hi, ctx)
        if lo is None and hi is None:
            return "an integer"
        if hi is None:
            return f"an integer >= {lo}"
        if lo is None:
            return f"an integer <= {hi}"
        return f"an integer in {lo}..{hi}"

    def check(self, v: Any, ctx: dict[str, Any]) -> int:
        if type(v) is not int:
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise Invalid(f"expected {self._what(ctx)}, got {show(v)}")
            v = int(v)
        lo, hi = _resolve(self.lo, ctx), _resolve(self.hi, ctx)
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise Invalid(f"expected {self._what(ctx)}, got {show(v)}")
        if self.bind is not None:
            ctx[self.bind] = v
        return v


class Float(Field):
    """A real number in ``[lo, hi]`` (``lo_open``/``hi_open``: the bound excluded), finite unless ``finite=False``:
    Python or numpy ints and floats, not bools or arrays.  Returns a Python float."""

    def __init__(self, lo: float = -math.inf, hi: float = math.inf, *, lo_open: bool = False, hi_open: bool = False,
                 finite: bool = True) -> None:
        self.lo, self.hi, self.lo_open, self.hi_open, self.finite = lo, hi, lo_open, hi_open, finite

    def _what(self) -> str:
        what = "a finite number" if self.finite else "a number"
        if self.lo == -math.inf and self.hi == math.inf:
            return what
        return f"{what} in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}"

    def check(self, v: Any, ctx: dict[str, Any]) -> float:
        if type(v) is float:
            f = v
        elif isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
            try:
                f = float(v)
            except OverflowError:      # an int beyond the float range
                raise Invalid(f"expected {self._what()}, got {show(v)}") from None
        else:
            raise Invalid(f"expected {self._what()}, got {show(v)}")
        if math.isnan(f) or (self.finite and math.isinf(f)) or f < self.lo or f > self.hi \
                or (self.lo_open and f == self.lo) or (self.hi_open and f == self.hi):
            raise Invalid(f"expected {self._what()}, got {show(v)}")
        return f


class Bool(Field):
    """``true`` or ``false`` (a numpy bool too); not 0/1, not an array."""

    def check(self, v: Any, ctx: dict[str, Any]) -> bool:
        if isinstance(v, (bool, np.bool_)):
            return bool(v)
        raise Invalid(f"expected a bool, got {show(v)}")


class Str(Field):
    """A string, one of ``choices`` when given, at most ``max_len`` characters when given."""

    def __init__(self, choices: tuple[str, ...] | list[str] | None = None, *, max_len: int | None = None) -> None:
        self.choices = tuple(choices) if choices is not None else None
        self.max_len = max_len

    def check(self, v: Any, ctx: dict[str, Any]) -> str:
        if not isinstance(v, str):
            raise Invalid(f"expected {'one of ' + repr(list(self.choices)) if self.choices else 'a string'}, got {show(v)}")
        if self.choices is not None and v not in self.choices:
            raise Invalid(f"{show(v)} is not one of {list(self.choices)}")
        if self.max_len is not None and len(v) > self.max_len:
            raise Invalid(f"string of {len(v)} characters, at most {self.max_len}")
        return v


class Const(Field):
    """Exactly ``value`` (an int or a string; an int also as a numpy integer, never a bool, float or array)."""

    def __init__(self, value: int | str) -> None:
        self.value = value

    def _ok(self, v: Any) -> bool:
        if isinstance(self.value, str):
            return isinstance(v, str) and v == self.value
        return (type(v) is int or (isinstance(v, np.integer))) and int(v) == self.value

    def reason(self, v: Any) -> str:
        return f"expected {self.value!r}, got {show(v)}"

    def check(self, v: Any, ctx: dict[str, Any]) -> Any:
        if not self._ok(v):
            raise Invalid(self.reason(v))
        return self.value


class Version(Const):
    """A wire version this client speaks."""

    def reason(self, v: Any) -> str:
        return f"version {show(v)}, this client speaks {self.value}"


class Seq(Field):
    """A list (or tuple) of ``item``, ``length`` long (an int or a dimension name, bound on first use) or
    ``min_len..max_len``; ``arrays=True`` also takes a 1-D numpy array (as its ``tolist()``).  Returns a list."""

    def __init__(self, item: Field, length: int | str | None = None, *, min_len: int = 0, max_len: int | str | None = None,
                 arrays: bool = False) -> None:
        self.item, self.length, self.min_len, self.max_len, self.arrays = item, length, min_len, max_len, arrays

    def _what(self, ctx: dict[str, Any]) -> str:
        n = ctx.get(self.length, self.length) if isinstance(self.length, str) else self.length
        if n is not None:
            return f"a list of {n}"
        hi = _resolve(self.max_len, ctx)
        if hi is None:
            return "a list" if not self.min_len else f"a list of at least {self.min_len}"
        return f"a list of {self.min_len} to {hi}" if self.min_len else f"a list of at most {hi}"

    def check(self, v: Any, ctx: dict[str, Any]) -> list[Any]:
        if type(v) is not list and not isinstance(v, tuple):
            if not (self.arrays and isinstance(v, np.ndarray) and v.ndim == 1):
                raise Invalid(f"expected {self._what(ctx)}, got {show(v)}")
        n = len(v)
        if isinstance(self.length, str):
            want = ctx.get(self.length)
            if want is None:
                ctx[self.length] = n
            elif n != want:
                raise Invalid(f"expected {self._what(ctx)}, got {show(v)}")
        elif self.length is not None and n != self.length:
            raise Invalid(f"expected {self._what(ctx)}, got {show(v)}")
        else:
            hi = _resolve(self.max_len, ctx)
            if n < self.min_len or (hi is not None and n > hi):
                raise Invalid(f"expected {self._what(ctx)}, got {show(v)}")
        if isinstance(v, np.ndarray):
            v = v.tolist()
        item = self.item.check
        out = []
        i = 0
        try:
            for i, x in enumerate(v):
                out.append(item(x, ctx))
        except Invalid as exc:
            exc.path.append(i)
            raise
        return out


class Tup(Field):
    """A list of fixed length whose positions have their own fields.  Returns a list."""

    def __init__(self, *items: Field) -> None:
        self.items = items

    def check(self, v: Any, ctx: dict[str, Any]) -> list[Any]:
        if (type(v) is not list and not isinstance(v, tuple)) or len(v) != len(self.items):
            raise Invalid(f"expected a list of {len(self.items)}, got {show(v)}")
        out = []
        i = 0
        try:
            for i, (f, x) in enumerate(zip(self.items, v)):
                out.append(f.check(x, ctx))
        except Invalid as exc:
            exc.path.append(i)
            raise
        return out


class Map(Field):
    """A map with the given string keys (others are ignored: a newer peer may add fields), validated in order, so
    a dimension a field binds is known to the fields after it.  Returns a dict of the declared keys present (or
    defaulted).  ``scope=True``: dimensions bound inside stay inside (each object of a list has its own)."""

    def __init__(self, fields: Mapping[str, Field], *, scope: bool = False) -> None:
        self.fields = tuple(fields.items())
        self.scope = scope

    def check(self, v: Any, ctx: dict[str, Any]) -> dict[str, Any]:
        if not isinstance(v, dict):
            raise Invalid(f"expected a map, got {show(v)}")
        if self.scope:
            ctx = dict(ctx)
        out: dict[str, Any] = {}
        key = ""
        try:
            for key, f in self.fields:
                x = v.get(key, _MISSING)
                out[key] = f.absent(ctx) if x is _MISSING else f.check(x, ctx)
        except Invalid as exc:
            exc.path.append(key)
            raise
        return out


class Opt(Field):
    """``field`` when present; ``default`` (returned as is: make it immutable) when the key is absent."""

    def __init__(self, field: Field, default: Any = None) -> None:
        self.field, self.default = field, default

    def check(self, v: Any, ctx: dict[str, Any]) -> Any:
        return self.field.check(v, ctx)

    def absent(self, ctx: dict[str, Any]) -> Any:
        return self.default


class Nullable(Field):
    """``field`` or nil (``None``)."""

    def __init__(self, field: Field) -> None:
        self.field = field

    def check(self, v: Any, ctx: dict[str, Any]) -> Any:
        return None if v is None else self.field.check(v, ctx)

    def absent(self, ctx: dict[str, Any]) -> Any:
        return self.field.absent(ctx)


class Check(Field):
    """``field``, then ``ok(value)`` must hold, else ``reason`` (a string, or a function of the value giving one)."""

    def __init__(self, field: Field, ok: Callable[[Any], bool], reason: str | Callable[[Any], str]) -> None:
        self.field, self.ok, self.reason = field, ok, reason

    def check(self, v: Any, ctx: dict[str, Any]) -> Any:
        out = self.field.check(v, ctx)
        if not self.ok(out):
            raise Invalid(self.reason if isinstance(self.reason, str) else self.reason(out))
        return out

    def absent(self, ctx: dict[str, Any]) -> Any:
        return self.field.absent(ctx)


class Dim:
    """An array dimension: named (bound on first use, then every use must agree) and/or within ``lo..hi``
    (``hi`` may be a dimension name or a limit passed as a dim)."""

    __slots__ = ("name", "lo", "hi")

    def __init__(self, name: str | None = None, lo: int = 0, hi: int | str | None = None) -> None:
        self.name, self.lo, self.hi = name, lo, hi


_KINDS = {"b": "bools", "i": "signed integers", "u": "unsigned integers", "iu": "integers", "ui": "integers",
          "f": "floats", "fiu": "numbers", "iuf": "numbers"}


class Array(Field):
    """A numpy array: ``kind`` (dtype kinds, e.g. ``"iu"``, ``"f"``) or exact ``dtype`` (one or a tuple), ``shape``
    (per dimension an int, a name, a :class:`Dim` or ``None`` for any), values ``finite`` and within ``lo..hi``
    (ints or dimension names), cast to ``cast`` (ints beyond int64 and floats beyond float32 refused, not wrapped:
    checks run on the cast values).  ``empty_if_absent``: an absent key is an empty array (first dimension 0),
    checked like a present one, so an absent array whose length another field fixed is an error."""

    def __init__(self, kind: str | None = None, shape: tuple[Any, ...] | None = None, *,
                 dtype: Any = None, cast: Any = None, finite: bool = False, lo: int | float | str | None = None,
                 hi: int | float | str | None = None, empty_if_absent: bool = False) -> None:
        self.kind = kind
        self.dtypes = None if dtype is None else tuple(np.dtype(d) for d in (dtype if isinstance(dtype, tuple) else (dtype,)))
        self.shape = shape
        self.cast = None if cast is None else np.dtype(cast)
        self.finite, self.lo, self.hi, self.empty_if_absent = finite, lo, hi, empty_if_absent

    def _dtype_text(self) -> str:
        if self.dtypes is not None:
            return "/".join(d.name for d in self.dtypes)
        return _KINDS.get(self.kind, f"dtype kind {self.kind!r}") if self.kind else "any dtype"

    def _what(self) -> str:
        shape = f" of shape {self._shape_text({})}" if self.shape is not None else ""
        return f"an array of {self._dtype_text()}{shape}"

    def _shape_text(self, ctx: dict[str, Any]) -> str:
        assert self.shape is not None
        parts = []
        for d in self.shape:
            name = d.name if isinstance(d, Dim) else d
            if isinstance(name, str):
                parts.append(str(ctx.get(name, name)))
            elif isinstance(d, Dim) or d is None:
                parts.append("N")
            else:
                parts.append(str(d))
        return f"({parts[0]},)" if len(parts) == 1 else f"({', '.join(parts)})"

    def _check_shape(self, shape: tuple[int, ...], ctx: dict[str, Any]) -> None:
        spec = self.shape
        if spec is None:
            return
        if len(shape) != len(spec):
            raise Invalid(f"shape {shape}, expected {self._shape_text(ctx)}")
        for n, d in zip(shape, spec):
            if d is None:
                continue
            if type(d) is int:
                if n != d:
                    raise Invalid(f"shape {shape}, expected {self._shape_text(ctx)}")
                continue
            name = d if isinstance(d, str) else d.name
            if isinstance(d, Dim):
                hi = _resolve(d.hi, ctx)
                if n < d.lo or (hi is not None and n > hi):
                    raise Invalid(f"shape {shape}: a dimension of {n} is not in {d.lo}..{hi}")
            if name is not None:
                want = ctx.get(name)
                if want is None:
                    ctx[name] = n
                elif n != want:
                    raise Invalid(f"shape {shape}, expected {self._shape_text(ctx)}")

    def check(self, v: Any, ctx: dict[str, Any]) -> np.ndarray:
        if not isinstance(v, np.ndarray):
            raise Invalid(f"expected {self._what()}, got {show(v)}")
        dt = v.dtype
        if (self.dtypes is not None and dt not in self.dtypes) or (self.kind is not None and dt.kind not in self.kind):
            raise Invalid(f"dtype {dt}, expected {self._dtype_text()}")
        self._check_shape(v.shape, ctx)
        out = v
        cast = self.cast
        if cast is not None and dt != cast:
            if cast.kind in "iu":
                if dt.kind == "u" and dt.itemsize >= 8 and v.size and int(v.max()) >= _I64:
                    raise Invalid("values beyond int64")
                out = v.astype(cast)
            else:
                with np.errstate(over="ignore", invalid="ignore"):
                    out = v.astype(cast)
        if self.finite and out.dtype.kind == "f" and not np.isfinite(out).all():
            cast_only = out is not v and (v.dtype.kind != "f" or np.isfinite(v).all())   # e.g. 1e39 as float32
            raise Invalid(f"values not finite{' in ' + out.dtype.name if cast_only else ''}")
        if (self.lo is not None or self.hi is not None) and out.size:
            lo, hi = _resolve(self.lo, ctx), _resolve(self.hi, ctx)
            mn, mx = out.min().item(), out.max().item()
            if (lo is not None and mn < lo) or (hi is not None and mx > hi):
                raise Invalid(f"values must be in {_num(lo) if lo is not None else '-inf'}..{_num(hi) if hi is not None else 'inf'}, "
                              f"got {_num(mn)}..{_num(mx)}")
        return out

    def absent(self, ctx: dict[str, Any]) -> np.ndarray:
        if not self.empty_if_absent or self.shape is None:
            raise Invalid("missing")
        dims = [0]
        for d in self.shape[1:]:
            name = d if isinstance(d, str) else d.name if isinstance(d, Dim) else None
            dims.append(d if type(d) is int else int(ctx.get(name, 0)) if name is not None else 0)
        empty = np.zeros(tuple(dims), self.cast or (self.dtypes[0] if self.dtypes else np.float64))
        try:
            return self.check(empty, ctx)
        except Invalid:
            raise Invalid(f"missing, expected shape {self._shape_text(ctx)}") from None


class Transforms(Field):
    """4x4 float matrices (``n`` of them, shape (n, 4, 4), ``n`` an int or a dimension name; ``None``: one (4, 4)),
    cast to ``dtype``: finite, every entry within +-``max_abs``, the last row (0, 0, 0, 1) when ``affine``, and the
    3x3 part invertible: ``|det| >= min_det`` and condition number (largest over smallest singular value)
    ``<= max_cond``.  The defaults suit scenes in metres: 1e6 m is beyond any scene here, and a 3x3 part with
    ``|det| < 1e-12`` (every axis scaled by less than 1e-4) or a condition number over 1e7 (float32 keeps about
    7 digits) cannot be inverted usefully on the client."""

    def __init__(self, n: int | str | None = None, *, max_abs: float = 1e6, min_det: float = 1e-12, max_cond: float = 1e7,
                 affine: bool = True, dtype: Any = np.float32, empty_if_absent: bool = False) -> None:
        self.n, self.max_abs, self.min_det, self.max_cond, self.affine = n, max_abs, min_det, max_cond, affine
        self.dtype = np.dtype(dtype)
        self.empty_if_absent = empty_if_absent

    def _shape_text(self, ctx: dict[str, Any]) -> str:
        if self.n is None:
            return "(4, 4)"
        return f"({ctx.get(self.n, self.n) if isinstance(self.n, str) else self.n}, 4, 4)"

    def check(self, v: Any, ctx: dict[str, Any]) -> np.ndarray:
        if not isinstance(v, np.ndarray) or v.dtype.kind != "f":
            raise Invalid(f"expected a float array {self._shape_text(ctx)}, got {show(v)}")
        single = self.n is None
        if single:
            if v.shape != (4, 4):
                raise Invalid(f"shape {v.shape}, expected (4, 4)")
        else:
            want = ctx.get(self.n) if isinstance(self.n, str) else self.n
            if v.ndim != 3 or v.shape[1:] != (4, 4) or (want is not None and v.shape[0] != want):
                raise Invalid(f"shape {v.shape}, expected {self._shape_text(ctx)}")
            if want is None:
                ctx[str(self.n)] = v.shape[0]
        with np.errstate(over="ignore", invalid="ignore"):
            out = v.astype(self.dtype)
        m = out.reshape(-1, 4, 4)
        if not m.shape[0]:
            return out

        def fail(k: int, reason: str) -> Invalid:
            exc = Invalid(reason)
            if not single:
                exc.path.append(k)
            return exc

        # fast paths first (one reduction each over every matrix); the per-matrix reasons only when one fails
        top = np.abs(m).max()
        if not top <= self.max_abs:                      # also NaN
            bad = ~np.isfinite(m).all(axis=(1, 2))
            if bad.any():
                k = int(np.argmax(bad))
                cast_only = self.dtype != v.dtype and np.isfinite(v.reshape(-1, 4, 4)[k]).all()   # e.g. 1e300 as float32
                raise fail(k, f"not finite{' in ' + self.dtype.name if cast_only else ''}")
            big = np.abs(m).max(axis=(1, 2))
            k = int(np.argmax(big > self.max_abs))
            raise fail(k, f"entry {big[k]:.3g} beyond +-{self.max_abs:g}")
        if self.affine and not (m[:, 3] == _AFFINE_ROW).all():
            off = np.abs(m[:, 3] - _AFFINE_ROW).max(axis=1)
            if (off > 1e-6).any():
                k = int(np.argmax(off > 1e-6))
                raise fail(k, f"last row {[float(x) for x in m[k, 3]]} is not (0, 0, 0, 1)")
        a = m[:, :3, :3].astype(np.float64)
        det = np.abs(np.linalg.det(a))
        if (det < self.min_det).any():
            k = int(np.argmax(det < self.min_det))
            raise fail(k, f"singular transform (|det| {det[k]:.3g} < {self.min_det:g})")
        # sigma1 / sigma3 = sigma1^2 sigma2 / |det| <= |A|_F^3 / |det|: the singular values only where that bound fails
        maybe = np.flatnonzero(np.einsum("nij,nij->n", a, a) ** 1.5 > self.max_cond * det)
        if maybe.size:
            sv = np.linalg.svd(a[maybe], compute_uv=False)
            cond = sv[:, 0] / sv[:, 2]
            if (cond > self.max_cond).any():
                j = int(np.argmax(cond > self.max_cond))
                raise fail(int(maybe[j]), f"ill-conditioned transform (condition number {cond[j]:.3g} > {self.max_cond:g})")
        return out

    def absent(self, ctx: dict[str, Any]) -> np.ndarray:
        if not self.empty_if_absent or self.n is None:
            raise Invalid("missing")
        want = ctx.get(self.n) if isinstance(self.n, str) else self.n
        if want:
            raise Invalid(f"missing, expected shape {self._shape_text(ctx)}")
        return self.check(np.zeros((0, 4, 4), self.dtype), ctx)


class Schema(Generic[E]):
    """A field tree, where it applies (the message prefix) and the error class it raises."""

    def __init__(self, where: str, error: type[E], root: Field) -> None:
        self.where, self.error, self.root = where, error, root

    def parse(self, value: Any, dims: Mapping[str, Any] | None = None, where: str | None = None) -> Any:
        """The validated, converted ``value``; raises the schema's error class naming the field path.
        ``dims``: named dimensions and bounds known beforehand (from the session); ``where`` overrides the prefix
        (e.g. with the frame id)."""
        ctx = dict(dims) if dims else {}
        try:
            return self.root.check(value, ctx)
        except Invalid as exc:
            raise self.error_at(list(reversed(exc.path)), exc.reason, where) from None

    def error_at(self, path: str | list[str | int], reason: str, where: str | None = None) -> E:
        """The error for a check made after :meth:`parse` (a rule between fields), in the same format."""
        p = format_path(path) if isinstance(path, list) else path
        return self.error(f"{where or self.where}: {p}: {reason}" if p else f"{where or self.where}: {reason}")
