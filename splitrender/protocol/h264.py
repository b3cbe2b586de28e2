"""H.264 RTP payload format, RFC 6184, packetization-mode 1.

Single NAL unit packets (types 1..23), STAP-A aggregation (type 24) and FU-A
fragmentation (type 28).  STAP-B, MTAP and FU-B (interleaved mode) are rejected.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from typing import Final

from splitrender.protocol.errors import PayloadError

__all__ = ["NAL_STAP_A", "NAL_FU_A", "h264_payloads", "h264_depayload"]

NAL_STAP_A: Final = 24
NAL_STAP_B: Final = 25
NAL_MTAP16: Final = 26
NAL_MTAP24: Final = 27
NAL_FU_A: Final = 28
NAL_FU_B: Final = 29
_UNSUPPORTED: Final = {0: "reserved", 25: "STAP-B", 26: "MTAP16", 27: "MTAP24", 29: "FU-B",
                       30: "reserved", 31: "reserved"}
FU_A_HEADER_SIZE: Final = 2
MIN_MTU: Final = FU_A_HEADER_SIZE + 1
_U16: Final = struct.Struct("!H")


def _fu_a(nal: bytes, mtu: int) -> list[bytes]:
    indicator = bytes([(nal[0] & 0xE0) | NAL_FU_A])
    t = nal[0] & 0x1F
    data = memoryview(nal)[1:]
    room = mtu - FU_A_HEADER_SIZE
    count = -(-len(data) // room)
    chunk = -(-len(data) // count)  # balanced fragment sizes
    out = []
    for k in range(count):
        hdr = t | (0x80 if k == 0 else 0) | (0x40 if k == count - 1 else 0)
        out.append(indicator + bytes([hdr]) + data[k * chunk : (k + 1) * chunk])
    return out


def h264_payloads(nals: Sequence[bytes], mtu: int = 1200) -> list[bytes]:
    """RTP payloads (each at most ``mtu`` bytes) for the NAL units of one access unit."""
    if mtu < MIN_MTU:
        raise ValueError(f"mtu {mtu} is below the minimum of {MIN_MTU} bytes")
    out: list[bytes] = []
    i, n = 0, len(nals)
    while i < n:
        nal = nals[i]
        if len(nal) > mtu:
            out.extend(_fu_a(nal, mtu))
            i += 1
            continue
        size, j = 1 + 2 + len(nal), i + 1
        while j < n and size + 2 + len(nals[j]) <= mtu:
            size += 2 + len(nals[j])
            j += 1
        if j - i == 1:
            out.append(nal)
        else:
            group = nals[i:j]
            f_nri = max(g[0] & 0x60 for g in group) | (0x80 if any(g[0] & 0x80 for g in group) else 0)
            parts = [bytes([f_nri | NAL_STAP_A])]
            for g in group:
                parts.append(_U16.pack(len(g)))
                parts.append(g)
            out.append(b"".join(parts))
        i = j
    return out


def h264_depayload(payloads: Iterable[bytes]) -> list[bytes]:
    """NAL units from the RTP payloads of one access unit, in order.

    Raises :class:`PayloadError` for malformed payloads (empty, forbidden bit,
    unsupported type, truncated STAP-A, FU-A continuation without start, ...).
    """
    nals: list[bytes] = []
    fu: list[bytes] | None = None
    fu_type = 0
    for index, p in enumerate(payloads):
        if not p:
            raise PayloadError(f"H.264 payload {index}: empty")
        h = p[0]
        if h & 0x80:
            raise PayloadError(f"H.264 payload {index}: forbidden_zero_bit is set")
        t = h & 0x1F
        if t == NAL_FU_A:
            if len(p) < 3:
                raise PayloadError(f"H.264 payload {index}: FU-A of {len(p)} bytes is truncated")
            fh = p[1]
            start, end, ft = fh & 0x80, fh & 0x40, fh & 0x1F
            if ft in _UNSUPPORTED or ft in (NAL_STAP_A, NAL_FU_A):
                raise PayloadError(f"H.264 payload {index}: FU-A carries invalid NAL unit type {ft}")
            if start:
                if end:
                    raise PayloadError(f"H.264 payload {index}: FU-A has both start and end bits")
                if fu is not None:
                    raise PayloadError(
                        f"H.264 payload {index}: FU-A start while a type {fu_type} NAL unit is incomplete"
                    )
                fu, fu_type = [bytes([(h & 0xE0) | ft]), p[2:]], ft
            else:
                if fu is None:
                    raise PayloadError(f"H.264 payload {index}: FU-A fragment without a start fragment")
                if ft != fu_type:
                    raise PayloadError(
                        f"H.264 payload {index}: FU-A type {ft} does not match started type {fu_type}"
                    )
                fu.append(p[2:])
                if end:
                    nals.append(b"".join(fu))
                    fu = None
            continue
        if fu is not None:
            raise PayloadError(f"H.264 payload {index}: type {t} packet inside an incomplete FU-A")
        if t in _UNSUPPORTED:
            raise PayloadError(
                f"H.264 payload {index}: unsupported NAL unit type {t} ({_UNSUPPORTED[t]})"
            )
        if t == NAL_STAP_A:
            pos, n = 1, len(p)
            if n == 1:
                raise PayloadError(f"H.264 payload {index}: STAP-A contains no NAL units")
            while pos < n:
                if pos + 2 > n:
                    raise PayloadError(
                        f"H.264 payload {index}: STAP-A size field at offset {pos} is truncated"
                    )
                size = (p[pos] << 8) | p[pos + 1]
                pos += 2
                if size == 0:
                    raise PayloadError(f"H.264 payload {index}: STAP-A contains a zero-length NAL unit")
                if pos + size > n:
                    raise PayloadError(
                        f"H.264 payload {index}: STAP-A NAL unit of {size} bytes at offset {pos} "
                        f"runs past end of {n}-byte payload"
                    )
                nal = p[pos : pos + size]
                if nal[0] & 0x80:
                    raise PayloadError(
                        f"H.264 payload {index}: STAP-A NAL unit at offset {pos} has forbidden_zero_bit set"
                    )
                nals.append(nal)
                pos += size
            continue
        nals.append(p)
    if fu is not None:
        raise PayloadError(f"H.264: FU-A of type {fu_type} incomplete at end of access unit")
    return nals
