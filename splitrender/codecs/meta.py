"""Method metadata on the wire: msgpack, then zstd, with hard limits.

numpy arrays are carried as msgpack ext type 1: ``dtype str | shape | raw bytes``
(little-endian, C order), so methods can put vertex or index arrays in metadata.

Decoding is bounded before anything is allocated: the zstd frame's declared size is
checked against ``max_bytes`` (:func:`~splitrender.codecs.bounded.bounded_zstd_decompress`),
then the msgpack document is scanned against :data:`META_LIMITS` (objects in all,
per-container lengths, nesting) before it is unpacked, and an array header may have at
most :data:`MAX_NDIM` dimensions.  Every failure is a :class:`CodecError`.
"""

from __future__ import annotations

import math
from typing import Any, TypedDict

import msgpack
import numpy as np
import zstandard

from ..errors import CodecError, RemoteProtocolError
from ..protocol.msgpack_limits import MsgpackLimitError, MsgpackLimits, bounded_unpackb
from .bounded import bounded_zstd_decompress

NDARRAY_EXT = 1
DEFAULT_MAX_BYTES = 64 * 1024 * 1024
MAX_NDIM = 8
"""Most dimensions of an array carried in metadata."""
META_LIMITS = MsgpackLimits(max_objects=65536, max_array_len=65536, max_map_len=4096, max_str_len=64 * 1024,
                            max_bin_len=DEFAULT_MAX_BYTES, max_ext_len=DEFAULT_MAX_BYTES, max_depth=32)
"""Per-document msgpack limits: metadata is a few small maps whose bulk is numpy arrays
(ext type 1, one object each), so 65536 objects is far above any method's schema while
bounding the Python objects a blob can create to a few MB."""
_ARRAY_HEADER_LIMITS = MsgpackLimits(max_objects=2 + MAX_NDIM, max_array_len=MAX_NDIM, max_map_len=0,
                                     max_str_len=8, max_bin_len=0, max_ext_len=0, max_depth=2)
_ARRAY_HEADER_MAX = 128  # bytes: [dtype, shape] with 8 uint64 sizes takes at most 80
_ALLOWED_DTYPES = {"|u1", "|i1", "<u2", "<i2", "<u4", "<i4", "<u8", "<i8", "<f2", "<f4", "<f8", "|b1"}


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        if a.dtype.byteorder == ">":
            a = a.astype(a.dtype.newbyteorder("<"))
        dt = a.dtype.str
        if dt not in _ALLOWED_DTYPES:
            raise CodecError(f"metadata: numpy dtype {dt} is not supported on the wire")
        head = msgpack.packb([dt, list(a.shape)])
        return msgpack.ExtType(NDARRAY_EXT, head + a.tobytes())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    raise TypeError(f"metadata: cannot serialise {type(obj).__name__}")


def _ext_hook(code: int, data: bytes) -> Any:
    if code != NDARRAY_EXT:
        raise CodecError(f"metadata: unknown msgpack extension type {code}")
    up = msgpack.Unpacker(max_buffer_size=_ARRAY_HEADER_MAX, **_ARRAY_HEADER_LIMITS.unpacker_kwargs())
    up.feed(data[:_ARRAY_HEADER_MAX])  # the header only: the payload is not copied into the unpacker
    try:
        dt, shape = next(up)
    except Exception as exc:
        raise CodecError(f"metadata: malformed array header: {type(exc).__name__}: {exc}") from exc
    if (dt not in _ALLOWED_DTYPES or not isinstance(shape, list) or len(shape) > MAX_NDIM
            or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in shape)):
        raise CodecError(f"metadata: bad array header dtype={dt!r} shape={shape!r}"[:200])
    off = up.tell()
    raw = memoryview(data)[off:]  # no copy: the .copy() below is the only one
    n = 1
    for s in shape:  # Python ints: no int64 wrap
        n *= s
    need = n * np.dtype(dt).itemsize
    if need != len(raw):
        raise CodecError(f"metadata: array of shape {shape} {dt} needs {need} bytes, got {len(raw)}")
    return np.frombuffer(raw, dtype=dt).reshape(shape).copy()


def pack_meta(meta: dict[str, Any], level: int = 3, max_bytes: int = DEFAULT_MAX_BYTES) -> bytes:
    """Serialise and compress ``meta``; raises :class:`CodecError` past ``max_bytes``."""
    try:
        raw = msgpack.packb(meta, default=_default, use_bin_type=True)
    except (TypeError, ValueError) as exc:
        raise CodecError(f"metadata: {exc}") from exc
    out = zstandard.ZstdCompressor(level=level).compress(raw)
    if len(out) > max_bytes:
        raise CodecError(f"metadata: {len(out)} bytes compressed exceeds the limit of {max_bytes}")
    return out


def unpack_meta(data: bytes, max_bytes: int = DEFAULT_MAX_BYTES) -> dict[str, Any]:
    """Inverse of :func:`pack_meta`; refuses output larger than ``max_bytes`` before
    allocating it (zstd bombs) and msgpack beyond :data:`META_LIMITS`.  Raises only
    :class:`CodecError`."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise CodecError(f"metadata: expected bytes, got {type(data).__name__}")
    raw = bounded_zstd_decompress(data, max_bytes, "metadata")
    try:
        obj = bounded_unpackb(raw, META_LIMITS, ext_hook=_ext_hook, strict_map_key=False)
    except CodecError:
        raise
    except MsgpackLimitError as exc:
        raise CodecError(f"metadata: msgpack: {exc}") from None
    except MemoryError:
        raise CodecError(f"metadata: msgpack: out of memory unpacking {len(raw)} bytes") from None
    except Exception as exc:
        raise CodecError(f"metadata: msgpack: {type(exc).__name__}: {exc}") from exc
    if not isinstance(obj, dict):
        raise CodecError(f"metadata: expected a map at the top level, got {type(obj).__name__}")
    return obj


# ----------------------------------------------------------------------------- update envelope
class MetaEnvelopeError(RemoteProtocolError, CodecError):
    """The envelope around a method's per-frame metadata is malformed (names the field)."""


class UpdateEnvelope(TypedDict):
    """The validated envelope of one update's metadata blob (``FrameMeta.method_meta``).

    ``t_s`` scene time (s), ``pose`` [x, y, z, qx, qy, qz, qw] (metres, unit
    quaternion), ``m`` the method's own metadata (validated by its client half),
    ``timing_us`` server stage times (µs, ints), ``srv`` server statistics (numbers),
    ``target_t_s`` the scene time the server predicted for (s, or ``None``).
    """

    t_s: float
    pose: list[float]
    m: dict[str, Any]
    timing_us: dict[str, int]
    srv: dict[str, float]
    target_t_s: float | None


ENVELOPE_MAX_KEYS = 64
"""Most entries in ``timing_us`` and ``srv``."""
_I64 = 2**63
_QUAT_NORM_TOLERANCE = 1e-3


def _finite(where: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)) or abs(v) > 1e300:
        raise MetaEnvelopeError(f"{where} must be a finite number, got {_show(v)}")
    return float(v)


def _show(v: Any) -> str:
    return repr(v)[:80] if isinstance(v, (int, float, str, bool, type(None))) else type(v).__name__


def _str_map(where: str, v: Any) -> dict[str, Any]:
    if not isinstance(v, dict):
        raise MetaEnvelopeError(f"{where} must be a map, got {_show(v)}")
    if len(v) > ENVELOPE_MAX_KEYS or not all(isinstance(k, str) for k in v):
        raise MetaEnvelopeError(f"{where} must map at most {ENVELOPE_MAX_KEYS} string keys")
    return v


def parse_update_envelope(obj: Any, where: str = "metadata") -> UpdateEnvelope:
    """Validate an unpacked update blob field by field (what the live client reads
    before the method's half sees ``m``); raises :class:`MetaEnvelopeError` naming the field."""
    if not isinstance(obj, dict):
        raise MetaEnvelopeError(f"{where}: expected a map, got {_show(obj)}")
    for key in ("t_s", "pose", "m"):
        if key not in obj:
            raise MetaEnvelopeError(f"{where}: missing field {key!r}")
    t_s = _finite(f"{where}.t_s", obj["t_s"])
    pose = obj["pose"]
    if not isinstance(pose, list) or len(pose) != 7:
        raise MetaEnvelopeError(f"{where}.pose must be a list of 7 numbers [x, y, z, qx, qy, qz, qw], got {_show(pose)}")
    p = [_finite(f"{where}.pose[{i}]", v) for i, v in enumerate(pose)]
    norm = math.sqrt(sum(v * v for v in p[3:]))
    if abs(norm - 1.0) > _QUAT_NORM_TOLERANCE:
        raise MetaEnvelopeError(f"{where}.pose: quaternion norm {norm:.6g} is not 1")
    m = obj["m"]
    if not isinstance(m, dict):
        raise MetaEnvelopeError(f"{where}.m must be a map, got {_show(m)}")
    timing = _str_map(f"{where}.timing_us", obj.get("timing_us", {}))
    for k, v in timing.items():
        if isinstance(v, bool) or not isinstance(v, int) or not -_I64 <= v < _I64:
            raise MetaEnvelopeError(f"{where}.timing_us[{k[:32]!r}] must be an int64 of µs, got {_show(v)}")
    srv = _str_map(f"{where}.srv", obj.get("srv", {}))
    srv_out = {k: _finite(f"{where}.srv[{k[:32]!r}]", v) for k, v in srv.items()}
    target = obj.get("target_t_s")
    return UpdateEnvelope(t_s=t_s, pose=p, m=m, timing_us=dict(timing), srv=srv_out,
                          target_t_s=None if target is None else _finite(f"{where}.target_t_s", target))
