"""Annex-B byte streams (ITU-T H.264 / H.265 Annex B): start codes and NAL units."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Final, Literal

from splitrender.errors import LocalProtocolError

__all__ = [
    "START_CODE",
    "Codec",
    "split_annexb",
    "join_annexb",
    "nal_type",
    "is_keyframe_nal",
    "contains_keyframe",
]

START_CODE: Final = b"\x00\x00\x00\x01"
_SC3: Final = b"\x00\x00\x01"

Codec = Literal["h264", "hevc", "data"]
"""RTP payload formats: H.264 (RFC 6184), H.265 (RFC 7798) and splitrender data frames (:mod:`.data`)."""

H264_NAL_IDR: Final = 5
HEVC_NAL_IRAP_FIRST: Final = 16  # BLA_W_LP
HEVC_NAL_IRAP_LAST: Final = 21  # CRA_NUT


def split_annexb(data: bytes) -> list[bytes]:
    """NAL units (without start codes) of an Annex-B access unit.

    Accepts 3- and 4-byte start codes; trailing zero bytes before a start code are
    dropped (a NAL unit never ends in 0x00).  Raises ``LocalProtocolError`` if the
    data does not begin with a start code (this is our own encoder's output).
    """
    find = data.find
    i = find(_SC3)
    if i < 0 or data[:i].strip(b"\x00"):
        raise LocalProtocolError("access unit does not start with an Annex-B start code")
    nals: list[bytes] = []
    start = i + 3
    while True:
        j = find(_SC3, start)
        end = len(data) if j < 0 else j
        while end > start and data[end - 1] == 0:
            end -= 1
        if end > start:
            nals.append(data[start:end])
        if j < 0:
            return nals
        start = j + 3


def join_annexb(nals: Iterable[bytes]) -> bytes:
    """Annex-B bytes with a 4-byte start code before every NAL unit."""
    parts: list[bytes] = []
    for nal in nals:
        parts.append(START_CODE)
        parts.append(nal)
    return b"".join(parts)


def nal_type(codec: Codec, nal: bytes) -> int:
    """``nal_unit_type`` of a NAL unit (5 bits for H.264, 6 bits for HEVC)."""
    if codec == "h264":
        return nal[0] & 0x1F
    return (nal[0] >> 1) & 0x3F


def is_keyframe_nal(codec: Codec, nal: bytes) -> bool:
    """IDR slice (H.264 type 5) or IRAP picture (HEVC types 16..21)."""
    if not nal:
        return False
    t = nal_type(codec, nal)
    if codec == "h264":
        return t == H264_NAL_IDR
    return HEVC_NAL_IRAP_FIRST <= t <= HEVC_NAL_IRAP_LAST


def contains_keyframe(codec: Codec, nals: Iterable[bytes]) -> bool:
    """Whether any NAL unit starts a keyframe."""
    return any(is_keyframe_nal(codec, n) for n in nals)
