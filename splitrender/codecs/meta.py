"""Method metadata on the wire: msgpack, then zstd, with a hard size limit.

numpy arrays are carried as msgpack ext type 1: ``dtype str | shape | raw bytes``
(little-endian, C order), so methods can put vertex or index arrays in metadata.
"""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np
import zstandard

from ..errors import CodecError

NDARRAY_EXT = 1
DEFAULT_MAX_BYTES = 64 * 1024 * 1024
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
    up = msgpack.Unpacker(max_buffer_size=len(data) + 16)
    up.feed(data)
    try:
        dt, shape = next(up)
    except Exception as exc:
        raise CodecError(f"metadata: malformed array header: {exc}") from exc
    if dt not in _ALLOWED_DTYPES or not isinstance(shape, list) or not all(isinstance(s, int) and s >= 0 for s in shape):
        raise CodecError(f"metadata: bad array header dtype={dt!r} shape={shape!r}")
    off = up.tell()
    raw = data[off:]
    n = int(np.prod(shape)) if shape else 1
    if n * np.dtype(dt).itemsize != len(raw):
        raise CodecError(f"metadata: array of shape {shape} {dt} needs {n * np.dtype(dt).itemsize} bytes, got {len(raw)}")
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
    """Inverse of :func:`pack_meta`; refuses output larger than ``max_bytes`` (zstd bombs)."""
    try:
        raw = zstandard.ZstdDecompressor().decompress(data, max_output_size=max_bytes)
    except zstandard.ZstdError as exc:
        raise CodecError(f"metadata: zstd: {exc}") from exc
    if len(raw) > max_bytes:
        raise CodecError(f"metadata: {len(raw)} bytes decompressed exceeds the limit of {max_bytes}")
    try:
        obj = msgpack.unpackb(raw, ext_hook=_ext_hook, raw=False, strict_map_key=False)
    except CodecError:
        raise
    except Exception as exc:
        raise CodecError(f"metadata: msgpack: {type(exc).__name__}: {exc}") from exc
    if not isinstance(obj, dict):
        raise CodecError(f"metadata: expected a map at the top level, got {type(obj).__name__}")
    return obj
