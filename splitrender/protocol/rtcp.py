"""RTCP (RFC 3550 section 6, RFC 4585 feedback) packets and sans-IO helpers.

Packets: sender report (SR, PT 200), receiver report (RR, 201), source description
(SDES, 202), generic NACK (RTPFB, PT 205, FMT 1), transport-wide congestion control
feedback (RTPFB FMT 15, :mod:`.twcc`), picture loss indication (PSFB, PT 206, FMT 1) and
full intra request (PSFB FMT 4); other types parse as :class:`RtcpUnknown`.  :func:`compound_feedback`
builds the compound packet RFC 3550 6.1 and RFC 4585 3.1 ask of a receiver: a report
first (an RR, with zero report blocks when none is due), then SDES with the CNAME,
then the feedback messages.  Helpers: :class:`ReceiverStatistics` (RFC 3550 A.1, A.3,
A.8), :class:`RetransmissionHistory`, :class:`KeyframeRateLimiter`.
"""

from __future__ import annotations

import logging
import struct
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final, Union

from splitrender.protocol.errors import RtcpError
from splitrender.protocol.rtp import RTP_CLOCK_HZ, RtpPacket, SequenceUnwrapper, seq_diff
from splitrender.protocol.twcc import RTPFB_TWCC, TransportFeedback, parse_transport_feedback

__all__ = [
    "RTCP_SR",
    "RTCP_RR",
    "RTCP_SDES",
    "RTCP_BYE",
    "RTCP_APP",
    "RTCP_RTPFB",
    "RTCP_PSFB",
    "RTPFB_NACK",
    "PSFB_PLI",
    "ReportBlock",
    "SenderReport",
    "ReceiverReport",
    "SdesChunk",
    "SourceDescription",
    "SDES_CNAME",
    "GenericNack",
    "PictureLossIndication",
    "FullIntraRequest",
    "PSFB_FIR",
    "RtcpUnknown",
    "RtcpPacket",
    "parse_rtcp",
    "rtcp_route_ssrc",
    "serialize_rtcp",
    "compound_feedback",
    "ntp_from_seconds",
    "ntp_middle32",
    "ReceiverStatistics",
    "RetransmissionHistory",
    "KeyframeRateLimiter",
]

logger = logging.getLogger(__name__)

RTCP_SR: Final = 200
RTCP_RR: Final = 201
RTCP_SDES: Final = 202
RTCP_BYE: Final = 203
RTCP_APP: Final = 204
RTCP_RTPFB: Final = 205
RTCP_PSFB: Final = 206
RTPFB_NACK: Final = 1
PSFB_PLI: Final = 1
PSFB_FIR: Final = 4
SDES_CNAME: Final = 1

RTCP_VERSION: Final = 2
_HEADER: Final = struct.Struct("!BBH")
_BLOCK: Final = struct.Struct("!IB3sIIII")
BLOCK_SIZE: Final = _BLOCK.size  # 24
_SR_INFO: Final = struct.Struct("!IQIII")  # ssrc, ntp, rtp ts, packets, octets
_FB: Final = struct.Struct("!II")
_NACK_FCI: Final = struct.Struct("!HH")
NTP_EPOCH_OFFSET_S: Final = 2208988800
"""Seconds from 1900-01-01 (NTP epoch) to 1970-01-01 (Unix epoch)."""
MAX_REPORT_BLOCKS: Final = 31


def ntp_from_seconds(unix_s: float) -> int:
    """64-bit NTP timestamp (32.32 fixed point) of a Unix time in seconds."""
    t = unix_s + NTP_EPOCH_OFFSET_S
    sec = int(t)
    return ((sec & 0xFFFFFFFF) << 32) | int((t - sec) * (1 << 32)) & 0xFFFFFFFF


def ntp_middle32(ntp: int) -> int:
    """The middle 32 bits of a 64-bit NTP timestamp (LSR field)."""
    return (ntp >> 16) & 0xFFFFFFFF


@dataclass(frozen=True, slots=True)
class ReportBlock:
    """Reception report about one source (24 bytes)."""

    ssrc: int
    fraction_lost: int
    """Lost fraction since the last report, 0..255 (/256)."""
    packets_lost: int
    """Cumulative lost packets, signed 24-bit."""
    highest_sequence: int
    """Extended highest sequence number received (cycles << 16 | seq)."""
    jitter: int
    """Interarrival jitter, RTP timestamp units."""
    lsr: int = 0
    """Middle 32 bits of the NTP timestamp of the last SR (0 if none)."""
    dlsr: int = 0
    """Delay since that SR, in 1/65536 s."""

    def __bytes__(self) -> bytes:
        lost = self.packets_lost & 0xFFFFFF
        return _BLOCK.pack(
            self.ssrc, self.fraction_lost, lost.to_bytes(3, "big"),
            self.highest_sequence, self.jitter, self.lsr, self.dlsr,
        )

    @classmethod
    def parse(cls, data: bytes, offset: int) -> ReportBlock:
        ssrc, frac, lost3, hs, jitter, lsr, dlsr = _BLOCK.unpack_from(data, offset)
        lost = int.from_bytes(lost3, "big")
        if lost & 0x800000:
            lost -= 1 << 24
        return cls(ssrc, frac, lost, hs, jitter, lsr, dlsr)


def _header(count: int, packet_type: int, body_len: int) -> bytes:
    return _HEADER.pack((RTCP_VERSION << 6) | count, packet_type, body_len // 4)


@dataclass(frozen=True, slots=True)
class SenderReport:
    """RTCP SR (PT 200)."""

    ssrc: int
    ntp_timestamp: int
    """64-bit NTP wallclock time of the report."""
    rtp_timestamp: int
    packet_count: int
    octet_count: int
    """Payload octets sent."""
    reports: tuple[ReportBlock, ...] = ()

    def __bytes__(self) -> bytes:
        body = _SR_INFO.pack(
            self.ssrc, self.ntp_timestamp, self.rtp_timestamp, self.packet_count, self.octet_count
        ) + b"".join(bytes(r) for r in self.reports)
        return _header(len(self.reports), RTCP_SR, len(body)) + body


@dataclass(frozen=True, slots=True)
class ReceiverReport:
    """RTCP RR (PT 201)."""

    ssrc: int
    reports: tuple[ReportBlock, ...] = ()

    def __bytes__(self) -> bytes:
        body = struct.pack("!I", self.ssrc) + b"".join(bytes(r) for r in self.reports)
        return _header(len(self.reports), RTCP_RR, len(body)) + body


@dataclass(frozen=True, slots=True)
class SdesChunk:
    """One SDES chunk: a source and its items as (type, value) pairs (RFC 3550 6.5)."""

    ssrc: int
    items: tuple[tuple[int, bytes], ...] = ()

    def __bytes__(self) -> bytes:
        out = bytearray(struct.pack("!I", self.ssrc))
        for kind, value in self.items:
            if not 1 <= kind <= 255 or len(value) > 255:
                raise ValueError(f"SDES item type {kind} with {len(value)} bytes is not encodable")
            out += bytes((kind, len(value))) + value
        out += b"\x00" * (4 - len(out) % 4)  # the null item ends the list, then pad to 32 bits
        return bytes(out)

    @property
    def cname(self) -> bytes | None:
        return next((v for k, v in self.items if k == SDES_CNAME), None)


@dataclass(frozen=True, slots=True)
class SourceDescription:
    """RTCP SDES (PT 202)."""

    chunks: tuple[SdesChunk, ...]

    def __bytes__(self) -> bytes:
        body = b"".join(bytes(c) for c in self.chunks)
        return _header(len(self.chunks), RTCP_SDES, len(body)) + body


@dataclass(frozen=True, slots=True)
class GenericNack:
    """RTPFB FMT 1 (RFC 4585 6.2.1): ``lost`` sequence numbers of ``media_ssrc``."""

    ssrc: int
    media_ssrc: int
    lost: tuple[int, ...]

    def __bytes__(self) -> bytes:
        fci = b""
        seqs = sorted(set(self.lost), key=lambda s: seq_diff(s, self.lost[0])) if self.lost else []
        i = 0
        while i < len(seqs):
            pid, blp = seqs[i], 0
            i += 1
            while i < len(seqs) and 0 < seq_diff(seqs[i], pid) <= 16:
                blp |= 1 << (seq_diff(seqs[i], pid) - 1)
                i += 1
            fci += _NACK_FCI.pack(pid, blp)
        body = _FB.pack(self.ssrc, self.media_ssrc) + fci
        return _header(RTPFB_NACK, RTCP_RTPFB, len(body)) + body


@dataclass(frozen=True, slots=True)
class PictureLossIndication:
    """PSFB FMT 1 (RFC 4585 6.3.1): the receiver lost decoder sync; send a keyframe."""

    ssrc: int
    media_ssrc: int

    def __bytes__(self) -> bytes:
        body = _FB.pack(self.ssrc, self.media_ssrc)
        return _header(PSFB_PLI, RTCP_PSFB, len(body)) + body


@dataclass(frozen=True, slots=True)
class FullIntraRequest:
    """PSFB FMT 4 (RFC 5104 4.3.1): send a decoder refresh point (an IDR) on each named stream.  ``requests``: per
    media SSRC, the request's 8-bit sequence number (a repeated number is the same request sent again)."""

    ssrc: int
    requests: tuple[tuple[int, int], ...]

    def __bytes__(self) -> bytes:
        body = _FB.pack(self.ssrc, 0) + b"".join(struct.pack("!IB3x", m, seq & 0xFF) for m, seq in self.requests)
        return _header(PSFB_FIR, RTCP_PSFB, len(body)) + body


@dataclass(frozen=True, slots=True)
class RtcpUnknown:
    """Any other RTCP packet (SDES, BYE, APP, other feedback), kept as raw body."""

    packet_type: int
    count: int
    """The 5-bit RC/FMT field."""
    body: bytes

    def __bytes__(self) -> bytes:
        return _header(self.count, self.packet_type, len(self.body)) + self.body


RtcpPacket = Union[SenderReport, ReceiverReport, SourceDescription, GenericNack, PictureLossIndication, FullIntraRequest,
                   TransportFeedback, RtcpUnknown]


def serialize_rtcp(packets: Iterable[RtcpPacket]) -> bytes:
    """A compound RTCP packet."""
    return b"".join(bytes(p) for p in packets)


def compound_feedback(ssrc: int, cname: bytes, packets: Iterable[RtcpPacket]) -> list[RtcpPacket]:
    """``packets`` as a valid compound RTCP packet from receiver ``ssrc`` (RFC 3550 6.1, RFC 4585 3.1).

    Reports (SR/RR) in ``packets`` go first, or an RR with no report blocks when there is
    none; then an SDES with ``cname`` (unless ``packets`` has one); then the rest
    (feedback messages) in their order.
    """
    packets = list(packets)
    reports = [p for p in packets if isinstance(p, (SenderReport, ReceiverReport))]
    sdes = [p for p in packets if isinstance(p, SourceDescription)]
    rest = [p for p in packets if not isinstance(p, (SenderReport, ReceiverReport, SourceDescription))]
    if not reports:
        reports = [ReceiverReport(ssrc)]
    if not sdes:
        sdes = [SourceDescription((SdesChunk(ssrc, ((SDES_CNAME, cname),)),))]
    return [*reports, *sdes, *rest]


def _sdes(data: bytes, pos: int, body_end: int, count: int) -> SourceDescription:
    chunks = []
    at = pos + 4
    for k in range(count):
        if at + 4 > body_end:
            raise RtcpError(f"RTCP SDES at offset {pos}: chunk {k} of {count} runs past the packet")
        (ssrc,) = struct.unpack_from("!I", data, at)
        at += 4
        items = []
        while True:
            if at >= body_end:
                raise RtcpError(f"RTCP SDES at offset {pos}: chunk {k} has no terminating null item")
            kind = data[at]
            if kind == 0:
                at = (at + 4) & ~3  # the null item and padding to the next 32-bit boundary
                break
            if at + 2 > body_end or at + 2 + data[at + 1] > body_end:
                raise RtcpError(f"RTCP SDES at offset {pos}: item of type {kind} runs past the packet")
            n = data[at + 1]
            items.append((kind, bytes(data[at + 2:at + 2 + n])))
            at += 2 + n
        chunks.append(SdesChunk(ssrc, tuple(items)))
    return SourceDescription(tuple(chunks))


def _blocks(data: bytes, pos: int, end: int, count: int, name: str) -> tuple[ReportBlock, ...]:
    need = pos + count * BLOCK_SIZE
    if need > end:
        raise RtcpError(f"RTCP {name} with {count} report blocks runs past its {end - pos + 8}-byte body")
    return tuple(ReportBlock.parse(data, pos + k * BLOCK_SIZE) for k in range(count))


ROUTE_MAX_HEADERS: Final = 4
"""Most RTCP packet headers :func:`rtcp_route_ssrc` reads in a compound datagram."""


def rtcp_route_ssrc(data: bytes) -> int | None:
    """The media SSRC a compound RTCP datagram is about, read from fixed offsets only, so that a server can find the
    session it belongs to before parsing any of it (RFC 3550 6.1: a compound packet starts with SR or RR).

    At most :data:`ROUTE_MAX_HEADERS` packet headers are read: the first report block's SSRC of an SR or RR, the
    media SSRC of an RTPFB/PSFB packet, or a FIR's first FCI SSRC, whichever comes first.  ``None`` when none of those names one (an RR with no
    report blocks and nothing else); :class:`RtcpError` when the datagram is not RTCP or its headers are broken.
    Constant work whatever the datagram's size."""
    n = len(data)
    if n < 8 or not 192 <= data[1] <= 223:
        raise RtcpError(f"datagram of {n} bytes is not RTCP")
    pos = 0
    for _ in range(ROUTE_MAX_HEADERS):
        if pos + 4 > n:
            return None
        b0, pt, words = _HEADER.unpack_from(data, pos)
        if b0 >> 6 != RTCP_VERSION:
            raise RtcpError(f"RTCP version {b0 >> 6} at offset {pos} is not {RTCP_VERSION}")
        end = pos + 4 + 4 * words
        if end > n:
            raise RtcpError(f"RTCP packet at offset {pos} of {4 + 4 * words} bytes runs past end of {n}-byte data")
        at = {RTCP_RR: pos + 8, RTCP_SR: pos + 28}.get(pt) if b0 & 0x1F else None
        if pt in (RTCP_RTPFB, RTCP_PSFB):   # a FIR's media SSRC is 0 (RFC 5104 4.3.1.2): its first FCI names it
            at = pos + 12 if pt == RTCP_PSFB and b0 & 0x1F == PSFB_FIR else pos + 8
        if at is not None and at + 4 <= end:
            return int.from_bytes(data[at:at + 4], "big")
        pos = end
    return None


def parse_rtcp(data: bytes) -> list[RtcpPacket]:
    """Parse a compound RTCP packet; raises :class:`RtcpError` with a precise reason."""
    packets: list[RtcpPacket] = []
    pos, n = 0, len(data)
    if n == 0:
        raise RtcpError("RTCP packet is empty")
    while pos < n:
        if pos + 4 > n:
            raise RtcpError(f"RTCP header at offset {pos} truncated: {n - pos} bytes, needs 4")
        b0, pt, words = _HEADER.unpack_from(data, pos)
        if b0 >> 6 != RTCP_VERSION:
            raise RtcpError(f"RTCP version {b0 >> 6} at offset {pos} is not {RTCP_VERSION}")
        count = b0 & 0x1F
        end = pos + 4 + 4 * words
        if end > n:
            raise RtcpError(
                f"RTCP packet at offset {pos} of {4 + 4 * words} bytes runs past end of {n}-byte data"
            )
        body_end = end
        if b0 & 0x20:
            pad = data[end - 1] if end > pos + 4 else 0
            if pad == 0 or pad > end - pos - 4:
                raise RtcpError(f"RTCP padding length {pad} at offset {pos} is invalid")
            body_end -= pad
        body = pos + 4
        if pt == RTCP_SR:
            if body + 24 > body_end:
                raise RtcpError(f"RTCP SR at offset {pos} truncated: body needs 24 bytes")
            ssrc, ntp, rts, pc, oc = _SR_INFO.unpack_from(data, body)
            blocks = _blocks(data, body + 24, body_end, count, "SR")
            packets.append(SenderReport(ssrc, ntp, rts, pc, oc, blocks))
        elif pt == RTCP_RR:
            if body + 4 > body_end:
                raise RtcpError(f"RTCP RR at offset {pos} truncated: body needs 4 bytes")
            (ssrc,) = struct.unpack_from("!I", data, body)
            packets.append(ReceiverReport(ssrc, _blocks(data, body + 4, body_end, count, "RR")))
        elif pt == RTCP_SDES:
            packets.append(_sdes(data, pos, body_end, count))
        elif pt in (RTCP_RTPFB, RTCP_PSFB) and count in (RTPFB_NACK, PSFB_PLI):
            if body + 8 > body_end:
                raise RtcpError(f"RTCP feedback at offset {pos} truncated: body needs 8 bytes")
            ssrc, media = _FB.unpack_from(data, body)
            if pt == RTCP_PSFB:
                packets.append(PictureLossIndication(ssrc, media))
            else:
                lost: list[int] = []
                for off in range(body + 8, body_end - 3, 4):
                    pid, blp = _NACK_FCI.unpack_from(data, off)
                    lost.append(pid)
                    lost.extend((pid + k + 1) & 0xFFFF for k in range(16) if blp >> k & 1)
                packets.append(GenericNack(ssrc, media, tuple(lost)))
        elif pt == RTCP_RTPFB and count == RTPFB_TWCC:
            packets.append(parse_transport_feedback(bytes(data[body:body_end]), f"RTCP transport-cc feedback at offset {pos}"))
        elif pt == RTCP_PSFB and count == PSFB_FIR:
            if body + 8 > body_end or (body_end - body - 8) % 8:
                raise RtcpError(f"RTCP FIR at offset {pos}: body of {body_end - body} bytes is not 8 + 8 x n")
            (ssrc,) = struct.unpack_from("!I", data, body)
            reqs = tuple(struct.unpack_from("!IB", data, off) for off in range(body + 8, body_end, 8))
            packets.append(FullIntraRequest(ssrc, reqs))
        else:
            packets.append(RtcpUnknown(pt, count, bytes(data[body:body_end])))
        pos = end
    return packets


class ReceiverStatistics:
    """Per-SSRC reception statistics for receiver report blocks (RFC 3550 A.1, A.3, A.8).

    Times are passed in (ms); ``clock_rate`` is the RTP clock in Hz.
    """

    def __init__(self, ssrc: int, clock_rate: int = RTP_CLOCK_HZ) -> None:
        self.ssrc = ssrc
        self.clock_rate = clock_rate
        self._unwrap = SequenceUnwrapper()
        self._base: int | None = None
        self._max = 0
        self.received = 0
        self._expected_prior = 0
        self._received_prior = 0
        self._transit: float | None = None
        self.jitter = 0.0
        """Interarrival jitter estimate, RTP timestamp units."""
        self._lsr = 0
        self._lsr_arrival_ms: float | None = None

    def receive(self, packet: RtpPacket, arrival_ms: float) -> None:
        """Account one received RTP packet."""
        ext = self._unwrap.unwrap(packet.sequence_number)
        if self._base is None:
            self._base = ext
            self._max = ext
        self._base = min(self._base, ext)
        self._max = max(self._max, ext)
        self.received += 1
        arrival_ts = arrival_ms * self.clock_rate / 1000.0
        transit = arrival_ts - packet.timestamp
        if self._transit is not None:
            d = abs(transit - self._transit)
            self.jitter += (d - self.jitter) / 16.0
        self._transit = transit

    def on_sender_report(self, sr: SenderReport, arrival_ms: float) -> None:
        """Remember the last SR for the LSR/DLSR fields."""
        self._lsr = ntp_middle32(sr.ntp_timestamp)
        self._lsr_arrival_ms = arrival_ms

    @property
    def expected(self) -> int:
        """Packets expected from the first to the highest sequence number."""
        return 0 if self._base is None else self._max - self._base + 1

    @property
    def lost(self) -> int:
        """Cumulative lost packets (can be negative with duplicates)."""
        return self.expected - self.received

    def report_block(self, now_ms: float) -> ReportBlock:
        """The report block for now; starts a new fraction-lost interval."""
        expected = self.expected
        exp_int = expected - self._expected_prior
        rec_int = self.received - self._received_prior
        self._expected_prior, self._received_prior = expected, self.received
        lost_int = exp_int - rec_int
        fraction = 0 if exp_int == 0 or lost_int <= 0 else min(255, (lost_int << 8) // exp_int)
        lost = max(-(1 << 23), min((1 << 23) - 1, self.lost))
        dlsr = 0
        if self._lsr_arrival_ms is not None:
            dlsr = int(max(0.0, now_ms - self._lsr_arrival_ms) * 65536 / 1000.0) & 0xFFFFFFFF
        return ReportBlock(
            ssrc=self.ssrc,
            fraction_lost=fraction,
            packets_lost=lost,
            highest_sequence=(self._max - (1 << 16)) & 0xFFFFFFFF if self._base is not None else 0,
            jitter=int(self.jitter),
            lsr=self._lsr,
            dlsr=dlsr,
        )


class RetransmissionHistory:
    """The last ``capacity`` sent RTP packets by sequence number, to answer NACKs, and when each was last resent
    (ms), so that a sender can refuse a request repeated within a round trip (libwebrtc's ``RtpPacketHistory``)."""

    def __init__(self, capacity: int = 1024) -> None:
        if capacity <= 0:
            raise ValueError("capacity must be positive")
        self.capacity = capacity
        self._packets: OrderedDict[int, RtpPacket] = OrderedDict()
        self._resent_ms: dict[int, float] = {}

    def __len__(self) -> int:
        return len(self._packets)

    def store(self, packet: RtpPacket) -> None:
        """Remember a sent packet; evicts the oldest beyond ``capacity``."""
        seq = packet.sequence_number
        self._packets.pop(seq, None)
        self._resent_ms.pop(seq, None)
        self._packets[seq] = packet
        while len(self._packets) > self.capacity:
            old, _ = self._packets.popitem(last=False)
            self._resent_ms.pop(old, None)

    def get(self, seq: int) -> RtpPacket | None:
        """The stored packet with sequence number ``seq``, if still kept."""
        return self._packets.get(seq)

    def resent_ms(self, seq: int) -> float | None:
        """When the kept packet ``seq`` was last resent (ms, as given to :meth:`mark_resent`); None if never."""
        return self._resent_ms.get(seq)

    def mark_resent(self, seq: int, now_ms: float) -> None:
        """The kept packet ``seq`` was resent at ``now_ms`` (a packet no longer kept is ignored)."""
        if seq in self._packets:
            self._resent_ms[seq] = now_ms


class KeyframeRateLimiter:
    """Answer PLIs / keyframe requests with an IDR at most once per ``min_interval_ms``.

    A request inside the interval is remembered and :meth:`poll` grants it when the
    interval has passed, so no request is lost.
    """

    def __init__(self, min_interval_ms: float = 500.0) -> None:
        self.min_interval_ms = min_interval_ms
        self._last_ms: float | None = None
        self.pending = False
        """A request was suppressed and is still owed."""

    def _ready(self, now_ms: float) -> bool:
        return self._last_ms is None or now_ms - self._last_ms >= self.min_interval_ms

    def request(self, now_ms: float) -> bool:
        """A keyframe was requested at ``now_ms``; True if one should be sent now."""
        if self._ready(now_ms):
            self.keyframe_sent(now_ms)
            return True
        self.pending = True
        return False

    def poll(self, now_ms: float) -> bool:
        """True if a suppressed request should be granted now."""
        if self.pending and self._ready(now_ms):
            self.keyframe_sent(now_ms)
            return True
        return False

    def keyframe_sent(self, now_ms: float) -> None:
        """Record a keyframe (requested or periodic) sent at ``now_ms``."""
        self._last_ms = now_ms
        self.pending = False
