"""RTP payload format for method ``data`` streams sent as datagrams (splitrender, v1).

A data frame (one method payload of one server frame, any bytes) is cut into RTP
payloads of at most ``mtu`` bytes, each starting with one header byte::

    bits 7..4  version (1)
    bit  0     S: first fragment of the frame
    bits 3..1  reserved, zero

followed by the fragment.  All fragments of a frame share the RTP timestamp; the
marker bit is set on the last one.  A frame is only usable whole: the jitter buffer
reassembles it like a video access unit, a lost fragment loses the frame.  Every data
frame is independent (there are no predicted frames), so it counts as a keyframe.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Final

from splitrender.protocol.errors import PayloadError

__all__ = ["DATA_PAYLOAD_VERSION", "data_payloads", "data_depayload"]

DATA_PAYLOAD_VERSION: Final = 1
_FIRST: Final = 0x01
_HEADER_FIRST: Final = bytes([(DATA_PAYLOAD_VERSION << 4) | _FIRST])
_HEADER_NEXT: Final = bytes([DATA_PAYLOAD_VERSION << 4])


def data_payloads(frame: bytes, mtu: int) -> list[bytes]:
    """RTP payloads (header byte + fragment, each at most ``mtu`` bytes) for one data frame."""
    if mtu < 2:
        raise ValueError(f"mtu {mtu} too small for a data payload")
    step = mtu - 1
    if not frame:
        return [_HEADER_FIRST]
    return [(_HEADER_FIRST if i == 0 else _HEADER_NEXT) + frame[i:i + step] for i in range(0, len(frame), step)]


def data_depayload(payloads: Iterable[bytes]) -> list[bytes]:
    """The frame bytes (as a one-item list, like the video depayloaders) from its fragments.

    Raises :class:`PayloadError` naming the fragment that is wrong.
    """
    parts: list[bytes] = []
    for i, p in enumerate(payloads):
        if not p:
            raise PayloadError(f"data fragment {i}: empty RTP payload")
        version, first = p[0] >> 4, bool(p[0] & _FIRST)
        if version != DATA_PAYLOAD_VERSION:
            raise PayloadError(f"data fragment {i}: payload version {version}, expected {DATA_PAYLOAD_VERSION}")
        if p[0] & 0x0E:
            raise PayloadError(f"data fragment {i}: reserved header bits set (0x{p[0]:02x})")
        if first != (i == 0):
            raise PayloadError(f"data fragment {i}: {'unexpected' if first else 'missing'} first-fragment flag")
        parts.append(p[1:])
    if not parts:
        raise PayloadError("data frame: no fragments")
    return [b"".join(parts)]
