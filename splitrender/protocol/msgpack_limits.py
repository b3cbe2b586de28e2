"""Bounded msgpack decoding: a structural scan before any Python object is built.

A few bytes of msgpack can ask for a great deal of memory: an array header claiming
four billion elements is preallocated by the C unpacker, and a 4 MiB body of empty
arrays becomes four million list objects (about 250 MB).  :func:`check_msgpack`
walks the encoding without building anything and refuses a stream whose total number
of objects, container length, string/binary/extension length or nesting depth is over
its limits; :func:`bounded_unpackb` then unpacks it with the same per-container limits
handed to msgpack itself.  Limits are per call site, sized from its schema.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import msgpack

__all__ = ["MsgpackLimits", "MsgpackLimitError", "check_msgpack", "bounded_unpackb"]


class MsgpackLimitError(ValueError):
    """Raised by :func:`check_msgpack`; callers wrap it in their own ``RemoteProtocolError``."""


@dataclass(frozen=True)
class MsgpackLimits:
    """Limits of one msgpack document: objects in all (containers and scalars), elements
    per array, pairs per map, bytes per str/bin/ext, nesting depth."""

    max_objects: int = 4096
    max_array_len: int = 1024
    max_map_len: int = 256
    max_str_len: int = 4096
    max_bin_len: int = 64 * 1024
    max_ext_len: int = 64 * 1024
    max_depth: int = 32

    def unpacker_kwargs(self) -> dict[str, int]:
        """The matching keyword arguments of ``msgpack.unpackb`` / ``Unpacker``."""
        return {"max_array_len": self.max_array_len, "max_map_len": self.max_map_len,
                "max_str_len": self.max_str_len, "max_bin_len": self.max_bin_len,
                "max_ext_len": self.max_ext_len}


# (extra header bytes holding a length, or -1) per type byte 0xc0 .. 0xdf; see the spec
_FIXED: dict[int, int] = {0xc0: 0, 0xc2: 0, 0xc3: 0, 0xca: 4, 0xcb: 8, 0xcc: 1, 0xcd: 2, 0xce: 4, 0xcf: 8,
                          0xd0: 1, 0xd1: 2, 0xd2: 4, 0xd3: 8, 0xd4: 2, 0xd5: 3, 0xd6: 5, 0xd7: 9, 0xd8: 17}
_LEN = {1: struct.Struct(">B"), 2: struct.Struct(">H"), 4: struct.Struct(">I")}
# type byte -> (kind, bytes of the length field)
_SIZED: dict[int, tuple[str, int]] = {0xc4: ("bin", 1), 0xc5: ("bin", 2), 0xc6: ("bin", 4),
                                      0xc7: ("ext", 1), 0xc8: ("ext", 2), 0xc9: ("ext", 4),
                                      0xd9: ("str", 1), 0xda: ("str", 2), 0xdb: ("str", 4),
                                      0xdc: ("array", 2), 0xdd: ("array", 4), 0xde: ("map", 2), 0xdf: ("map", 4)}


def check_msgpack(data: bytes | bytearray | memoryview, limits: MsgpackLimits) -> int:
    """Number of objects in the one msgpack document ``data``; raises
    :class:`MsgpackLimitError` (saying which limit and where) if it breaks ``limits``,
    is truncated or has trailing bytes.  Builds no Python object per msgpack object."""
    buf = memoryview(data).cast("B") if not isinstance(data, bytes) else data
    n = len(buf)
    pos = 0
    objects = 0
    # stack of items still expected per open container; the document is one item
    stack = [1]
    while stack:
        if stack[-1] == 0:
            stack.pop()
            continue
        stack[-1] -= 1
        if pos >= n:
            raise MsgpackLimitError(f"truncated at byte {pos}")
        objects += 1
        if objects > limits.max_objects:
            raise MsgpackLimitError(f"more than {limits.max_objects} objects (at byte {pos})")
        start = pos
        b = buf[pos]
        pos += 1
        if b <= 0x7f or b >= 0xe0:
            continue
        if b <= 0x9f:  # fixmap 0x80.., fixarray 0x90..
            count = b & 0x0f
            kind = "map" if b <= 0x8f else "array"
        elif b <= 0xbf:  # fixstr
            length = b & 0x1f
            pos += length
            if length > limits.max_str_len:
                raise MsgpackLimitError(f"str of {length} bytes exceeds {limits.max_str_len} (at byte {start})")
            continue
        elif b in _FIXED:
            pos += _FIXED[b]
            continue
        elif b in _SIZED:
            kind, width = _SIZED[b]
            if pos + width > n:
                raise MsgpackLimitError(f"truncated {kind} header at byte {start}")
            length = _LEN[width].unpack_from(buf, pos)[0]
            pos += width
            if kind in ("array", "map"):
                count = length
            else:
                cap = {"bin": limits.max_bin_len, "ext": limits.max_ext_len, "str": limits.max_str_len}[kind]
                if length > cap:
                    raise MsgpackLimitError(f"{kind} of {length} bytes exceeds {cap} (at byte {start})")
                pos += length + (1 if kind == "ext" else 0)
                continue
        else:  # 0xc1, never used
            raise MsgpackLimitError(f"invalid type byte 0x{b:02x} at byte {start}")
        cap = limits.max_map_len if kind == "map" else limits.max_array_len
        if count > cap:
            raise MsgpackLimitError(f"{kind} of {count} entries exceeds {cap} (at byte {start})")
        items = 2 * count if kind == "map" else count
        if items > n - pos:  # every item takes at least one byte
            raise MsgpackLimitError(f"{kind} of {count} entries at byte {start} is longer than the data")
        if items:
            if len(stack) > limits.max_depth:
                raise MsgpackLimitError(f"nested deeper than {limits.max_depth} (at byte {start})")
            stack.append(items)
    if pos > n:
        raise MsgpackLimitError(f"truncated: needs {pos} bytes, have {n}")
    if pos != n:
        raise MsgpackLimitError(f"{n - pos} bytes of trailing data after the document")
    return objects


def bounded_unpackb(data: bytes, limits: MsgpackLimits, *, ext_hook: Callable[[int, bytes], Any] | None = None,
                    strict_map_key: bool = True) -> Any:
    """:func:`check_msgpack`, then ``msgpack.unpackb`` with the same limits.

    Raises :class:`MsgpackLimitError` from the scan; whatever msgpack (or ``ext_hook``)
    raises passes through for the caller to wrap."""
    check_msgpack(data, limits)
    kwargs: dict[str, Any] = dict(limits.unpacker_kwargs())
    if ext_hook is not None:
        kwargs["ext_hook"] = ext_hook
    return msgpack.unpackb(data, raw=False, strict_map_key=strict_map_key, use_list=True, **kwargs)
