"""Forward error correction for RTP: RFC 5109 ULPFEC, one protection level, parity per group (sans-IO).

The sender protects each frame's media packets in groups of at most
:data:`MAX_GROUP` consecutive sequence numbers with one FEC packet per group: the XOR
of the packets' headers' recoverable fields, timestamps, lengths and everything after
their 12-byte fixed headers (RFC 5109 sections 7 and 8).  FEC packets travel as a
separate RTP stream (their own SSRC, payload type and sequence numbers, RFC 5109
section 14.1's "separate stream"), so receivers that do not know them see a foreign SSRC
and ignore it, and the media stream's sequence numbers stay contiguous.

The receiver recovers one missing packet per group once the FEC packet and every other
packet of the group are in: :func:`fec_recover`.  A frame is protected as a whole when
it has at most :data:`MAX_GROUP` packets; larger frames get one FEC packet per group.

FEC packet layout (after the FEC stream's own 12-byte RTP header)::

    0                   1                   2                   3
    |E|L|P|X|  CC   |M| PT recovery |         SN base               |
    |                       TS recovery                             |
    |        length recovery        |      protection length        |
    |   mask (16 bits, L = 0; 48 bits with L = 1)  ...
    |   XOR of the protected packets' bytes after their fixed headers ...
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Callable, Final, Sequence

import numpy as np

from .errors import PayloadError
from .rtp import RTP_HEADER_SIZE, RtpPacket, seq_add

__all__ = ["FecPacket", "MAX_GROUP", "fec_encode", "fec_groups", "fec_recover", "parse_fec"]

MAX_GROUP: Final = 16
"""Media packets one FEC packet protects at most (the short mask, ``L = 0``)."""
MAX_MASK_BITS: Final = 48
_FEC_HEADER: Final = struct.Struct("!BBHIH")  # E|L|P|X|CC, M|PT, SN base, TS recovery, length recovery
_LEVEL0_SHORT: Final = struct.Struct("!HH")  # protection length, 16-bit mask
_LEVEL0_LONG_EXTRA: Final = 4


@dataclass(frozen=True, slots=True)
class FecPacket:
    """A parsed FEC payload: which media packets it protects and their XOR."""

    sn_base: int
    mask: int
    """Bit ``k`` from the most significant of a ``mask_bits`` mask protects ``sn_base + k``."""
    mask_bits: int
    first_bytes: int
    """XOR of the protected packets' first two header bytes (P, X, CC, M, PT; the version bits cleared)."""
    ts_recovery: int
    length_recovery: int
    payload: bytes
    """XOR of the protected packets' bytes after the fixed header, zero-padded to the longest."""

    def protected(self) -> list[int]:
        """16-bit sequence numbers of the protected media packets."""
        return [seq_add(self.sn_base, k) for k in range(self.mask_bits) if self.mask >> (self.mask_bits - 1 - k) & 1]


def _tail(data: bytes) -> bytes:
    return data[RTP_HEADER_SIZE:]


def fec_groups(n: int, max_group: int = MAX_GROUP) -> list[range]:
    """Split ``n`` consecutive packets into groups of at most ``max_group`` (sizes as equal as possible)."""
    if n <= 0:
        return []
    k = -(-n // max_group)
    base, extra = divmod(n, k)
    out, start = [], 0
    for i in range(k):
        size = base + (1 if i < extra else 0)
        out.append(range(start, start + size))
        start += size
    return out


def _xor(blobs: Sequence[bytes], size: int) -> bytes:
    acc = np.zeros(size, np.uint8)
    for b in blobs:
        if b:
            acc[:len(b)] ^= np.frombuffer(b, np.uint8)
    return acc.tobytes()


def fec_encode(media: Sequence[bytes], ssrc: int, payload_type: int, first_seq: int, timestamp: int,
               max_group: int = MAX_GROUP) -> list[RtpPacket]:
    """FEC packets (sequence numbers from ``first_seq``) protecting ``media``, the serialized RTP packets of one
    frame in sequence order (consecutive sequence numbers)."""
    out = []
    for i, grp in enumerate(fec_groups(len(media), max_group)):
        pkts = [media[j] for j in grp]
        if len(pkts) > MAX_MASK_BITS:
            raise ValueError(f"an FEC group of {len(pkts)} packets exceeds {MAX_MASK_BITS}")
        tails = [_tail(p) for p in pkts]
        size = max(len(t) for t in tails)
        first = 0
        ts = 0
        length = 0
        for p, t in zip(pkts, tails):
            first ^= ((p[0] & 0x3F) << 8) | p[1]
            ts ^= struct.unpack_from("!I", p, 4)[0]
            length ^= len(t)
        long = len(pkts) > 16
        bits = MAX_MASK_BITS if long else 16
        mask = ((1 << len(pkts)) - 1) << (bits - len(pkts))
        sn_base = struct.unpack_from("!H", pkts[0], 2)[0]
        head = _FEC_HEADER.pack((0x40 if long else 0) | (first >> 8), first & 0xFF, sn_base, ts, length)
        level = _LEVEL0_SHORT.pack(size, mask >> 32 if long else mask) + (struct.pack("!I", mask & 0xFFFFFFFF) if long else b"")
        out.append(RtpPacket(payload_type, seq_add(first_seq, i), timestamp, ssrc, head + level + _xor(tails, size)))
    return out


def parse_fec(payload: bytes) -> FecPacket:
    """Parse an FEC packet's payload; :class:`~.errors.PayloadError` names what is malformed."""
    if len(payload) < _FEC_HEADER.size + _LEVEL0_SHORT.size:
        raise PayloadError(f"FEC packet: {len(payload)} bytes, shorter than its {_FEC_HEADER.size + _LEVEL0_SHORT.size}-byte headers")
    b0, b1, sn_base, ts, length = _FEC_HEADER.unpack_from(payload)
    if b0 & 0x80:
        raise PayloadError("FEC packet: extension flag E set (reserved, must be 0)")
    long = bool(b0 & 0x40)
    prot, mask = _LEVEL0_SHORT.unpack_from(payload, _FEC_HEADER.size)
    off = _FEC_HEADER.size + _LEVEL0_SHORT.size
    bits = 16
    if long:
        if len(payload) < off + _LEVEL0_LONG_EXTRA:
            raise PayloadError("FEC packet: truncated 48-bit mask")
        mask = mask << 32 | struct.unpack_from("!I", payload, off)[0]
        off += _LEVEL0_LONG_EXTRA
        bits = MAX_MASK_BITS
    if mask == 0:
        raise PayloadError("FEC packet: empty protection mask")
    body = payload[off:]
    if len(body) != prot:
        raise PayloadError(f"FEC packet: protection length {prot}, but {len(body)} bytes follow the headers")
    return FecPacket(sn_base, mask, bits, ((b0 & 0x3F) << 8) | b1, ts, length, body)


def fec_recover(fec: FecPacket, media_ssrc: int, get: Callable[[int], bytes | None]) -> RtpPacket | None:
    """The one missing media packet of ``fec``'s group, rebuilt; ``None`` when none or more than one is missing.

    ``get(seq)`` returns the serialized media packet with 16-bit sequence number ``seq``, or ``None``.
    Raises :class:`~.errors.PayloadError` when the recovered bytes are not a valid RTP packet (a corrupt
    FEC packet or a mismatched group).
    """
    seqs = fec.protected()
    have = [(s, get(s)) for s in seqs]
    missing = [s for s, p in have if p is None]
    if len(missing) != 1:
        return None
    others = [p for _, p in have if p is not None]
    first, ts, length = fec.first_bytes, fec.ts_recovery, fec.length_recovery
    for p in others:
        first ^= ((p[0] & 0x3F) << 8) | p[1]
        ts ^= struct.unpack_from("!I", p, 4)[0]
        length ^= len(p) - RTP_HEADER_SIZE
    if length > len(fec.payload):
        raise PayloadError(f"FEC recovery: length {length} exceeds the protection length {len(fec.payload)}")
    for s, p in have:
        if p is not None and len(p) - RTP_HEADER_SIZE > len(fec.payload):
            raise PayloadError(f"FEC recovery: media packet {s} carries {len(p) - RTP_HEADER_SIZE} bytes, more than "
                               f"the protection length {len(fec.payload)} (the FEC packet does not cover it)")
    tail = _xor([fec.payload] + [_tail(p) for p in others], len(fec.payload))[:length]
    head = struct.pack("!BBHII", 0x80 | (first >> 8), first & 0xFF, missing[0], ts, media_ssrc)
    try:
        return RtpPacket.parse(head + tail)
    except Exception as exc:  # noqa: BLE001 - any parse failure is a corrupt recovery
        raise PayloadError(f"FEC recovery: rebuilt packet {missing[0]} is not valid RTP: {exc}") from None
