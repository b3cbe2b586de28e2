"""H.265/HEVC RTP payload format, RFC 7798 (no DONL: sprop-max-don-diff = 0).

Single NAL unit packets, aggregation packets (AP, type 48) and fragmentation units
(FU, type 49).  PACI (type 50) and types 51..63 are rejected.  The NAL unit header is
two bytes: F(1) | Type(6) | LayerId(6) | TID(3).
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from typing import Final

from splitrender.protocol.errors import PayloadError

__all__ = ["NAL_AP", "NAL_FU", "NAL_PACI", "h265_payloads", "h265_depayload"]

NAL_AP: Final = 48
NAL_FU: Final = 49
NAL_PACI: Final = 50
NAL_HEADER_SIZE: Final = 2
FU_HEADER_SIZE: Final = 3  # payload header (2) + FU header (1)
MIN_MTU: Final = FU_HEADER_SIZE + 1
_U16: Final = struct.Struct("!H")


def _fu(nal: bytes, mtu: int) -> list[bytes]:
    ph = bytes([(nal[0] & 0x81) | (NAL_FU << 1), nal[1]])
    t = (nal[0] >> 1) & 0x3F
    data = memoryview(nal)[NAL_HEADER_SIZE:]
    room = mtu - FU_HEADER_SIZE
    count = -(-len(data) // room)
    chunk = -(-len(data) // count)
    out = []
    for k in range(count):
        hdr = t | (0x80 if k == 0 else 0) | (0x40 if k == count - 1 else 0)
        out.append(ph + bytes([hdr]) + data[k * chunk : (k + 1) * chunk])
    return out


def _ap_header(group: Sequence[bytes]) -> bytes:
    f = 0x80 if any(g[0] & 0x80 for g in group) else 0
    layer = min(((g[0] & 1) << 5) | (g[1] >> 3) for g in group)
    tid = min(g[1] & 0x07 for g in group)
    return bytes([f | (NAL_AP << 1) | (layer >> 5), ((layer & 0x1F) << 3) | tid])


def h265_payloads(nals: Sequence[bytes], mtu: int = 1200) -> list[bytes]:
    """RTP payloads (each at most ``mtu`` bytes) for the NAL units of one access unit."""
    if mtu < MIN_MTU:
        raise ValueError(f"mtu {mtu} is below the minimum of {MIN_MTU} bytes")
    out: list[bytes] = []
    i, n = 0, len(nals)
    while i < n:
        nal = nals[i]
        if len(nal) < NAL_HEADER_SIZE:
            raise ValueError(f"HEVC NAL unit of {len(nal)} bytes is shorter than its header")
        if len(nal) > mtu:
            out.extend(_fu(nal, mtu))
            i += 1
            continue
        size, j = NAL_HEADER_SIZE + 2 + len(nal), i + 1
        while j < n and len(nals[j]) >= NAL_HEADER_SIZE and size + 2 + len(nals[j]) <= mtu:
            size += 2 + len(nals[j])
            j += 1
        if j - i == 1:
            out.append(nal)
        else:
            group = nals[i:j]
            parts = [_ap_header(group)]
            for g in group:
                parts.append(_U16.pack(len(g)))
                parts.append(g)
            out.append(b"".join(parts))
        i = j
    return out


def _check_header(index: int, where: str, b0: int, b1: int) -> None:
    if b0 & 0x80:
        raise PayloadError(f"HEVC payload {index}: {where} forbidden_zero_bit is set")
    if b1 & 0x07 == 0:
        raise PayloadError(f"HEVC payload {index}: {where} nuh_temporal_id_plus1 is 0")


def h265_depayload(payloads: Iterable[bytes]) -> list[bytes]:
    """NAL units from the RTP payloads of one access unit, in order.

    Raises :class:`PayloadError` for malformed payloads.
    """
    nals: list[bytes] = []
    fu: list[bytes] | None = None
    fu_type = 0
    for index, p in enumerate(payloads):
        if len(p) < NAL_HEADER_SIZE:
            raise PayloadError(f"HEVC payload {index}: {len(p)} bytes is shorter than the 2-byte header")
        b0, b1 = p[0], p[1]
        _check_header(index, "payload header", b0, b1)
        t = (b0 >> 1) & 0x3F
        if t == NAL_FU:
            if len(p) < 4:
                raise PayloadError(f"HEVC payload {index}: FU of {len(p)} bytes is truncated")
            fh = p[2]
            start, end, ft = fh & 0x80, fh & 0x40, fh & 0x3F
            if ft >= NAL_AP:
                raise PayloadError(f"HEVC payload {index}: FU carries invalid NAL unit type {ft}")
            if start:
                if end:
                    raise PayloadError(f"HEVC payload {index}: FU has both start and end bits")
                if fu is not None:
                    raise PayloadError(
                        f"HEVC payload {index}: FU start while a type {fu_type} NAL unit is incomplete"
                    )
                fu, fu_type = [bytes([(b0 & 0x81) | (ft << 1), b1]), p[3:]], ft
            else:
                if fu is None:
                    raise PayloadError(f"HEVC payload {index}: FU fragment without a start fragment")
                if ft != fu_type:
                    raise PayloadError(
                        f"HEVC payload {index}: FU type {ft} does not match started type {fu_type}"
                    )
                fu.append(p[3:])
                if end:
                    nals.append(b"".join(fu))
                    fu = None
            continue
        if fu is not None:
            raise PayloadError(f"HEVC payload {index}: type {t} packet inside an incomplete FU")
        if t == NAL_PACI or t > NAL_PACI:
            raise PayloadError(f"HEVC payload {index}: unsupported NAL unit type {t}")
        if t == NAL_AP:
            pos, n = NAL_HEADER_SIZE, len(p)
            if n == NAL_HEADER_SIZE:
                raise PayloadError(f"HEVC payload {index}: AP contains no NAL units")
            while pos < n:
                if pos + 2 > n:
                    raise PayloadError(f"HEVC payload {index}: AP size field at offset {pos} is truncated")
                size = (p[pos] << 8) | p[pos + 1]
                pos += 2
                if size < NAL_HEADER_SIZE:
                    raise PayloadError(
                        f"HEVC payload {index}: AP NAL unit size {size} at offset {pos - 2} is below 2"
                    )
                if pos + size > n:
                    raise PayloadError(
                        f"HEVC payload {index}: AP NAL unit of {size} bytes at offset {pos} "
                        f"runs past end of {n}-byte payload"
                    )
                _check_header(index, f"AP NAL unit at offset {pos}", p[pos], p[pos + 1])
                nals.append(p[pos : pos + size])
                pos += size
            continue
        nals.append(p)
    if fu is not None:
        raise PayloadError(f"HEVC: FU of type {fu_type} incomplete at end of access unit")
    return nals
