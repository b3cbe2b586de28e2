"""Transport-wide congestion control feedback (sans-IO): what a delay-based estimator needs.

The format libwebrtc speaks (draft-holmer-rmcat-transport-wide-cc-extensions-01), so
a browser's feedback and ours read alike:

- **The sequence number.** Every RTP packet the sender wants feedback on carries a
  transport-wide sequence number (16 bits, one counter over every stream of the session)
  in an RFC 8285 one-byte header extension (profile ``0xBEDE``), element id negotiated
  in SDP as ``a=extmap:<id> http://www.ietf.org/id/draft-holmer-rmcat-transport-wide-cc-extensions-01``.
- **The feedback** is RTCP RTPFB (PT 205) FMT 15::

      sender SSRC | media SSRC | base sequence (16) | packet status count (16) |
      reference time (24, signed, 64 ms units) | feedback packet count (8) |
      packet chunks (16 bits each) | receive deltas | zero padding to 32 bits

  Each packet from the base sequence on has a status: 0 not received, 1 received with a
  small delta (1 byte, 0..63.75 ms), 2 received with a large or negative delta (2 bytes,
  signed); 3 is reserved.  A *run-length chunk* (top bit 0: 2-bit symbol, 13-bit run)
  or a *status vector chunk* (top bit 1; then 0: fourteen 1-bit symbols, 1: seven 2-bit
  symbols) carries them.  Receive deltas are in 250 us ticks, each from the previous
  received packet's time, the first from the reference time.

:class:`TransportFeedback` builds and is parsed from that body (:mod:`.rtcp` dispatches
FMT 15 to :func:`parse_transport_feedback`); :class:`FeedbackRecorder` is the receiver's
half (arrivals in, feedback packets out), :class:`SendHistory` the sender's (its send
times and sizes matched with the feedback's arrivals, as :class:`PacketResult`).
"""

from __future__ import annotations

import struct
from collections import OrderedDict
from dataclasses import dataclass
from typing import Final, Iterable, Sequence

from splitrender.protocol.errors import RtcpError, RtpError
from splitrender.protocol.rtp import SequenceUnwrapper

__all__ = ["TWCC_URI", "RTPFB_TWCC", "TICK_US", "REFERENCE_US", "DEFAULT_EXTENSION_ID", "TransportFeedback", "PacketResult",
           "FeedbackRecorder", "SendHistory", "one_byte_extension", "parse_one_byte_extension", "parse_transport_feedback",
           "read_transport_seq", "write_transport_seq"]

TWCC_URI: Final = "http://www.ietf.org/id/draft-holmer-rmcat-transport-wide-cc-extensions-01"
RTPFB_TWCC: Final = 15
ONE_BYTE_PROFILE: Final = 0xBEDE
TICK_US: Final = 250
"""Receive-delta unit, microseconds."""
REFERENCE_US: Final = 64_000
"""Reference-time unit, microseconds (256 ticks)."""
_TICKS_PER_REF: Final = REFERENCE_US // TICK_US
_REF_MOD: Final = 1 << 24
MAX_STATUS_COUNT: Final = 0xFFFF
DEFAULT_EXTENSION_ID: Final = 5
"""The one-byte header extension element id of the transport sequence number in this project's sessions."""
_RUN_MAX: Final = 0x1FFF
_FIXED: Final = struct.Struct("!IIHHI")  # sender SSRC, media SSRC, base, count, (reference << 8) | fb count


def one_byte_extension(elements: dict[int, bytes]) -> tuple[int, bytes]:
    """An RFC 8285 one-byte header extension (profile, body padded to 32 bits) holding ``elements`` (id 1..14 ->
    1..16 bytes)."""
    out = bytearray()
    for eid, data in elements.items():
        if not 1 <= eid <= 14 or not 1 <= len(data) <= 16:
            raise ValueError(f"one-byte header extension element: id {eid} must be 1..14, length {len(data)} 1..16")
        out += bytes([eid << 4 | (len(data) - 1)]) + data
    out += bytes(-len(out) % 4)
    return ONE_BYTE_PROFILE, bytes(out)


def parse_one_byte_extension(profile: int | None, data: bytes) -> dict[int, bytes]:
    """The elements of an RFC 8285 one-byte header extension; ``{}`` for no extension or another profile (two-byte
    headers are not used here).  A malformed body raises :class:`RtpError` naming the element."""
    if profile != ONE_BYTE_PROFILE:
        return {}
    out: dict[int, bytes] = {}
    i = 0
    while i < len(data):
        b = data[i]
        if b == 0:       # padding
            i += 1
            continue
        eid, n = b >> 4, (b & 0x0F) + 1
        if eid == 15:    # reserved: stop reading (RFC 8285 4.2)
            break
        if i + 1 + n > len(data):
            raise RtpError(f"RTP header extension element {eid} of {n} bytes runs past the {len(data)}-byte extension")
        out[eid] = bytes(data[i + 1:i + 1 + n])
        i += 1 + n
    return out


def _element_offset(data: bytes, ext_id: int) -> int | None:
    """Byte offset of one-byte extension element ``ext_id``'s data in an RTP packet, or None."""
    if len(data) < 12 or not data[0] & 0x10:
        return None
    pos = 12 + 4 * (data[0] & 0x0F)
    if pos + 4 > len(data) or data[pos:pos + 2] != b"\xbe\xde":
        return None
    end = pos + 4 + 4 * int.from_bytes(data[pos + 2:pos + 4], "big")
    i = pos + 4
    if end > len(data):
        return None
    while i < end:
        b = data[i]
        if b == 0:
            i += 1
            continue
        eid, n = b >> 4, (b & 0x0F) + 1
        if eid == 15 or i + 1 + n > end:
            return None
        if eid == ext_id:
            return i + 1 if n == 2 else None
        i += 1 + n
    return None


def read_transport_seq(data: bytes, ext_id: int) -> int | None:
    """The transport sequence number an RTP packet carries in element ``ext_id`` (None when it has none)."""
    off = _element_offset(data, ext_id)
    return None if off is None else int.from_bytes(data[off:off + 2], "big")


def write_transport_seq(data: bytes, ext_id: int, seq: int) -> bytes:
    """``data`` with its transport sequence number (element ``ext_id``, reserved by the packetizer) set to ``seq``;
    unchanged when it has no such element (FEC packets, RTCP)."""
    off = _element_offset(data, ext_id)
    if off is None:
        return data
    return data[:off] + (seq & 0xFFFF).to_bytes(2, "big") + data[off + 2:]


@dataclass(frozen=True, slots=True)
class TransportFeedback:
    """One transport-cc feedback packet.

    ``arrivals[i]`` is the arrival of sequence ``base_seq + i`` (mod 2**16) in 250 us ticks since the reference
    time's zero (``reference_time * 256`` plus the deltas up to it), or ``None`` when it was not received.
    """

    ssrc: int
    media_ssrc: int
    base_seq: int
    reference_time: int
    """24 bits, in 64 ms units."""
    fb_count: int
    arrivals: tuple[int | None, ...]

    def __post_init__(self) -> None:
        if not 1 <= len(self.arrivals) <= MAX_STATUS_COUNT:
            raise ValueError(f"transport-cc feedback: {len(self.arrivals)} packet statuses, must be 1..{MAX_STATUS_COUNT}")
        if not 0 <= self.reference_time < _REF_MOD:
            raise ValueError(f"transport-cc feedback: reference time {self.reference_time} is not 24 bits")

    def arrival_us(self, i: int) -> int | None:
        """Arrival of status ``i`` in microseconds on the feedback sender's clock, or None."""
        a = self.arrivals[i]
        return None if a is None else a * TICK_US

    def __bytes__(self) -> bytes:
        symbols, deltas = [], bytearray()
        last = self.reference_time * _TICKS_PER_REF
        for a in self.arrivals:
            if a is None:
                symbols.append(0)
                continue
            d = a - last
            last = a
            if 0 <= d <= 0xFF:
                symbols.append(1)
                deltas.append(d)
            elif -0x8000 <= d <= 0x7FFF:
                symbols.append(2)
                deltas += struct.pack("!h", d)
            else:
                raise ValueError(f"transport-cc feedback: receive delta of {d * TICK_US} us does not fit 16 bits")
        body = _FIXED.pack(self.ssrc, self.media_ssrc, self.base_seq & 0xFFFF, len(self.arrivals),
                           self.reference_time << 8 | (self.fb_count & 0xFF))
        body += b"".join(struct.pack("!H", c) for c in _chunks(symbols)) + bytes(deltas)
        body += bytes(-len(body) % 4)
        return struct.pack("!BBH", 0x80 | RTPFB_TWCC, 205, len(body) // 4) + body


def _chunks(symbols: Sequence[int]) -> list[int]:
    """Greedy chunking: a run of 14 or more alike as one run-length chunk, else fourteen 1-bit symbols where they
    are all 0/1, else seven 2-bit symbols (the last vector padded with 'not received', which the count cuts off)."""
    out, i, n = [], 0, len(symbols)
    while i < n:
        s = symbols[i]
        run = 1
        while i + run < n and run < _RUN_MAX and symbols[i + run] == s:
            run += 1
        if run >= 14 or i + run == n and run >= 7:
            out.append(s << 13 | run)
            i += run
        elif all(x <= 1 for x in symbols[i:i + 14]):
            part = symbols[i:i + 14]
            out.append(0x8000 | sum(x << (13 - k) for k, x in enumerate(part)))
            i += len(part)
        else:
            part = symbols[i:i + 7]
            out.append(0xC000 | sum(x << (12 - 2 * k) for k, x in enumerate(part)))
            i += len(part)
    return out


def parse_transport_feedback(body: bytes, where: str = "transport-cc feedback") -> TransportFeedback:
    """The RTPFB FMT 15 body after the RTCP header (padding removed); :class:`RtcpError` names what is wrong."""
    if len(body) < _FIXED.size:
        raise RtcpError(f"{where}: body of {len(body)} bytes is shorter than its {_FIXED.size}-byte fixed part")
    ssrc, media, base, count, ref_fb = _FIXED.unpack_from(body)
    if count == 0:
        raise RtcpError(f"{where}: packet status count is 0")
    pos = _FIXED.size
    symbols: list[int] = []
    while len(symbols) < count:
        if pos + 2 > len(body):
            raise RtcpError(f"{where}: packet chunks end after {len(symbols)} of {count} statuses")
        (c,) = struct.unpack_from("!H", body, pos)
        pos += 2
        if not c & 0x8000:
            s, run = c >> 13 & 3, c & _RUN_MAX
            if run == 0:
                raise RtcpError(f"{where}: run-length chunk at byte {pos - 2} has run length 0")
            symbols += [s] * min(run, count - len(symbols))
        elif not c & 0x4000:
            symbols += [c >> (13 - k) & 1 for k in range(14)][:count - len(symbols)]
        else:
            symbols += [c >> (12 - 2 * k) & 3 for k in range(7)][:count - len(symbols)]
    if 3 in symbols:
        raise RtcpError(f"{where}: packet status {symbols.index(3)} uses the reserved symbol 3")
    arrivals: list[int | None] = []
    t = (ref_fb >> 8) * _TICKS_PER_REF
    for s in symbols:
        if s == 0:
            arrivals.append(None)
            continue
        n = 1 if s == 1 else 2
        if pos + n > len(body):
            raise RtcpError(f"{where}: receive deltas end before status {len(arrivals)} of {count}")
        t += body[pos] if n == 1 else struct.unpack_from("!h", body, pos)[0]
        pos += n
        arrivals.append(t)
    if any(body[pos:]):
        raise RtcpError(f"{where}: {len(body) - pos} bytes after the receive deltas are not zero padding")
    return TransportFeedback(ssrc, media, base, ref_fb >> 8, ref_fb & 0xFF, tuple(arrivals))


class FeedbackRecorder:
    """The receiver's half: transport sequence numbers and arrival times in, feedback packets out.

    :meth:`on_packet` records an arrival (microseconds on the receiver's clock, which must start near zero: the
    reference time is that clock in 64 ms units); :meth:`feedback` returns the packets covering every sequence from
    the first not yet reported to the highest received (gaps as 'not received'), split where a delta would not fit,
    and forgets them.  An arrival for a sequence already reported is counted (``late``) and dropped.  At most
    ``max_pending`` arrivals wait for a report; beyond that the oldest are dropped (``overflow``).
    """

    def __init__(self, ssrc: int, media_ssrc: int = 0, max_pending: int = 4096) -> None:
        self.ssrc, self.media_ssrc, self.max_pending = ssrc, media_ssrc, max_pending
        self._unwrap = SequenceUnwrapper()
        self._pending: OrderedDict[int, int] = OrderedDict()  # extended seq -> arrival us
        self._next: int | None = None      # first extended seq not yet reported
        self._fb_count = 0
        self.late = 0
        self.overflow = 0

    def on_packet(self, transport_seq: int, arrival_us: int) -> None:
        ext = self._unwrap.unwrap(transport_seq & 0xFFFF)
        if self._next is not None and ext < self._next:
            self.late += 1
            return
        if ext not in self._pending:
            self._pending[ext] = int(arrival_us)
            if len(self._pending) > self.max_pending:
                self._pending.popitem(last=False)
                self.overflow += 1

    @property
    def pending(self) -> int:
        return len(self._pending)

    def feedback(self) -> list[TransportFeedback]:
        if not self._pending:
            return []
        seqs = sorted(self._pending)
        start = seqs[0] if self._next is None or seqs[0] - self._next > MAX_STATUS_COUNT else self._next
        out: list[TransportFeedback] = []
        arrivals: list[int | None] = []
        base, ref, last, shift = start, None, 0, 0
        for ext in range(start, seqs[-1] + 1):
            a = self._pending.get(ext)
            tick = None if a is None else a // TICK_US
            if arrivals and (len(arrivals) == MAX_STATUS_COUNT or
                             tick is not None and ref is not None and not -0x8000 <= tick - last <= 0x7FFF):
                out.append(self._packet(base, ref or 0, arrivals))
                arrivals, base, ref = [], ext, None
            if tick is not None:
                if ref is None:           # the packet's reference time: its first arrival's 64 ms period (24 bits)
                    ref = (tick // _TICKS_PER_REF) % _REF_MOD
                    shift = (tick // _TICKS_PER_REF - ref) * _TICKS_PER_REF   # whole wraps of the 24-bit reference
                last = tick
                tick -= shift
            arrivals.append(tick)
        if arrivals:
            out.append(self._packet(base, ref or 0, arrivals))
        self._next = seqs[-1] + 1
        self._pending.clear()
        return out

    def _packet(self, base: int, ref: int, arrivals: list[int | None]) -> TransportFeedback:
        fb = TransportFeedback(self.ssrc, self.media_ssrc, base & 0xFFFF, ref, self._fb_count, tuple(arrivals))
        self._fb_count = (self._fb_count + 1) & 0xFF
        return fb


@dataclass(frozen=True, slots=True)
class PacketResult:
    """A sent packet as the feedback reports it: ``arrival_us`` on the receiver's clock, None when lost."""

    seq: int
    send_us: int
    size: int
    arrival_us: int | None
    probe: int = -1
    """The probe cluster the packet belonged to (-1: media)."""


class SendHistory:
    """The sender's half: every packet sent with a transport sequence number (send time in us, size in bytes), kept
    for ``window_us``, matched with feedback into :class:`PacketResult` in sequence order.  A status for a sequence
    not in the history (too old, never sent, or reported twice) is counted in ``unknown`` and skipped."""

    def __init__(self, window_us: int = 2_000_000, max_packets: int = 1 << 15) -> None:
        self.window_us, self.max_packets = window_us, max_packets
        self._seq = 0
        self._sent: OrderedDict[int, tuple[int, int, int]] = OrderedDict()   # extended seq -> (send us, size, probe)
        self._unwrap = SequenceUnwrapper()
        self.unknown = 0

    def next_seq(self) -> int:
        """The transport sequence number for the next packet (16 bits on the wire)."""
        return self._seq & 0xFFFF

    def on_sent(self, send_us: int, size: int, probe: int = -1) -> int:
        """Record the packet that carries :meth:`next_seq` (``probe``: its probe cluster, -1 for media); returns
        that number."""
        seq = self._seq
        self._seq += 1
        self._sent[seq] = (int(send_us), int(size), int(probe))
        while self._sent and (len(self._sent) > self.max_packets or next(iter(self._sent.values()))[0] < send_us - self.window_us):
            self._sent.popitem(last=False)
        return seq & 0xFFFF

    def on_feedback(self, fb: TransportFeedback) -> list[PacketResult]:
        out = []
        if not self._sent:
            self.unknown += len(fb.arrivals)
            return out
        newest = next(reversed(self._sent))
        base = newest + ((fb.base_seq - newest) & 0xFFFF)
        if base > newest:
            base -= 1 << 16
        for i in range(len(fb.arrivals)):
            sent = self._sent.pop(base + i, None)
            if sent is None:
                self.unknown += 1
                continue
            out.append(PacketResult(base + i, sent[0], sent[1], fb.arrival_us(i), sent[2]))
        return out

    @property
    def in_flight(self) -> int:
        """Packets sent and not yet reported."""
        return len(self._sent)


def results_of(history: SendHistory, feedback: Iterable[TransportFeedback]) -> list[PacketResult]:
    """Every :class:`PacketResult` of a batch of feedback, in order."""
    out: list[PacketResult] = []
    for fb in feedback:
        out += history.on_feedback(fb)
    return out
