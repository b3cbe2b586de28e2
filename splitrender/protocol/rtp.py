"""RTP packets (RFC 3550 section 5.1) with ``parse()`` / ``__bytes__``."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final

from splitrender.protocol.errors import RtpError

__all__ = [
    "RTP_CLOCK_HZ",
    "RTP_VERSION",
    "RTP_HEADER_SIZE",
    "RtpPacket",
    "seq_add",
    "seq_diff",
    "seq_lt",
    "SequenceUnwrapper",
    "is_rtcp",
]

RTP_CLOCK_HZ: Final = 90000
"""The RTP timestamp clock of every stream (video and data), Hz: defined here only."""

RTP_VERSION: Final = 2
RTP_HEADER_SIZE: Final = 12
_HEADER: Final = struct.Struct("!BBHII")
_EXT_HEADER: Final = struct.Struct("!HH")
SEQ_MOD: Final = 1 << 16
TS_MOD: Final = 1 << 32


def seq_add(seq: int, n: int) -> int:
    """``seq + n`` modulo 2**16."""
    return (seq + n) & 0xFFFF


def seq_diff(a: int, b: int) -> int:
    """Signed distance ``a - b`` of 16-bit sequence numbers, in [-32768, 32767]."""
    d = (a - b) & 0xFFFF
    return d - SEQ_MOD if d >= 0x8000 else d


def seq_lt(a: int, b: int) -> bool:
    """``a`` comes before ``b`` (RFC 1982 serial number arithmetic)."""
    return seq_diff(a, b) < 0


class SequenceUnwrapper:
    """Map 16-bit sequence numbers to monotonic 64-bit extended ones."""

    def __init__(self) -> None:
        self._last: int | None = None

    def peek(self, seq: int) -> int | None:
        """The extended number :meth:`unwrap` would give ``seq``, without recording it (``None`` before any)."""
        if self._last is None:
            return None
        return self._last + seq_diff(seq, self._last & 0xFFFF)

    def unwrap(self, seq: int) -> int:
        """Extended sequence number closest to the last one seen."""
        if self._last is None:
            self._last = seq + SEQ_MOD  # start in cycle 1 so small negatives stay >= 0
            return self._last
        ext = self._last + seq_diff(seq, self._last & 0xFFFF)
        if ext > self._last:
            self._last = ext
        return ext


def is_rtcp(data: bytes) -> bool:
    """RFC 5761 demultiplexing: payload-type byte 192..223 means RTCP."""
    return len(data) >= 2 and 192 <= data[1] <= 223


@dataclass(frozen=True, slots=True)
class RtpPacket:
    """One RTP packet.  ``payload`` excludes padding; ``padding_size`` is re-emitted."""

    payload_type: int
    sequence_number: int
    timestamp: int
    """Media timestamp in clock-rate units (90 kHz for video)."""
    ssrc: int
    payload: bytes = b""
    marker: bool = False
    csrc: tuple[int, ...] = ()
    extension_profile: int | None = None
    """16-bit profile of the header extension, or ``None`` when there is none."""
    extension_data: bytes = b""
    """Header extension body (a multiple of 4 bytes)."""
    padding_size: int = 0

    def __bytes__(self) -> bytes:
        has_ext = self.extension_profile is not None
        b0 = (RTP_VERSION << 6) | (0x20 if self.padding_size else 0) | (0x10 if has_ext else 0)
        b0 |= len(self.csrc)
        out = _HEADER.pack(
            b0,
            (0x80 if self.marker else 0) | self.payload_type,
            self.sequence_number,
            self.timestamp,
            self.ssrc,
        )
        if self.csrc:
            out += struct.pack(f"!{len(self.csrc)}I", *self.csrc)
        if has_ext:
            assert self.extension_profile is not None
            if len(self.extension_data) % 4:
                raise ValueError("RTP header extension length must be a multiple of 4 bytes")
            out += _EXT_HEADER.pack(self.extension_profile, len(self.extension_data) // 4)
            out += self.extension_data
        out += self.payload
        if self.padding_size:
            out += bytes(self.padding_size - 1) + bytes([self.padding_size])
        return out

    @classmethod
    def parse(cls, data: bytes) -> RtpPacket:
        """Parse one packet; raises :class:`RtpError` with a precise reason."""
        n = len(data)
        if n < RTP_HEADER_SIZE:
            raise RtpError(f"RTP packet truncated: {n} bytes, header needs {RTP_HEADER_SIZE}")
        b0, b1, seq, ts, ssrc = _HEADER.unpack_from(data)
        version = b0 >> 6
        if version != RTP_VERSION:
            raise RtpError(f"RTP version {version} is not {RTP_VERSION}")
        cc = b0 & 0x0F
        pos = RTP_HEADER_SIZE + 4 * cc
        if pos > n:
            raise RtpError(f"RTP CSRC count {cc} runs past end of {n}-byte packet")
        csrc = struct.unpack_from(f"!{cc}I", data, RTP_HEADER_SIZE) if cc else ()
        ext_profile: int | None = None
        ext_data = b""
        if b0 & 0x10:
            if pos + 4 > n:
                raise RtpError(
                    f"RTP header extension header runs past end of {n}-byte packet"
                )
            ext_profile, words = _EXT_HEADER.unpack_from(data, pos)
            pos += 4
            if pos + 4 * words > n:
                raise RtpError(
                    f"RTP header extension of {4 * words} bytes runs past end of {n}-byte packet"
                )
            ext_data = bytes(data[pos : pos + 4 * words])
            pos += 4 * words
        end = n
        padding = 0
        if b0 & 0x20:
            if end <= pos:
                raise RtpError("RTP padding bit set but packet has no payload")
            padding = data[end - 1]
            if padding == 0:
                raise RtpError("RTP padding length is 0")
            if padding > end - pos:
                raise RtpError(
                    f"RTP padding length {padding} is longer than the {end - pos}-byte payload"
                )
            end -= padding
        return cls(
            payload_type=b1 & 0x7F,
            sequence_number=seq,
            timestamp=ts,
            ssrc=ssrc,
            payload=bytes(data[pos:end]),
            marker=bool(b1 & 0x80),
            csrc=tuple(csrc),
            extension_profile=ext_profile,
            extension_data=ext_data,
            padding_size=padding,
        )
