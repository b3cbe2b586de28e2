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
from bisect import bisect_left
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
    """One transport-cc feedback packet, held sparsely: its status count and the packets it reports received.

    ``received`` holds ``(i, ticks)`` for each status ``i`` (sequence ``base_seq + i`` mod 2**16) reported received,
    ``i`` ascending, ``ticks`` its arrival in 250 us ticks since the reference time's zero (``reference_time * 256``
    plus the deltas up to it); every other status up to ``status_count`` is 'not received'.  A packet may declare
    65,535 statuses in a few bytes (run-length chunks of 'not received'), so nothing here costs more than the
    received statuses, each of which its sender paid for with at least one byte of receive delta.
    """

    ssrc: int
    media_ssrc: int
    base_seq: int
    reference_time: int
    """24 bits, in 64 ms units."""
    fb_count: int
    status_count: int
    received: tuple[tuple[int, int], ...]

    def __post_init__(self) -> None:
        if not 1 <= self.status_count <= MAX_STATUS_COUNT:
            raise ValueError(f"transport-cc feedback: {self.status_count} packet statuses, must be 1..{MAX_STATUS_COUNT}")
        if not 0 <= self.reference_time < _REF_MOD:
            raise ValueError(f"transport-cc feedback: reference time {self.reference_time} is not 24 bits")
        last = -1
        for i, _ in self.received:
            if not last < i < self.status_count:
                raise ValueError(f"transport-cc feedback: received status {i} out of order or past the status count "
                                 f"{self.status_count}")
            last = i

    @classmethod
    def from_arrivals(cls, ssrc: int, media_ssrc: int, base_seq: int, reference_time: int, fb_count: int,
                      arrivals: Sequence[int | None]) -> TransportFeedback:
        """From one arrival (ticks) or None per status, in sequence order."""
        return cls(ssrc, media_ssrc, base_seq, reference_time, fb_count, len(arrivals),
                   tuple((i, a) for i, a in enumerate(arrivals) if a is not None))

    @property
    def arrivals(self) -> tuple[int | None, ...]:
        """One arrival (ticks) or None per status: ``status_count`` items (a convenience for small packets)."""
        out: list[int | None] = [None] * self.status_count
        for i, a in self.received:
            out[i] = a
        return tuple(out)

    def arrival_us(self, i: int) -> int | None:
        """Arrival of status ``i`` in microseconds on the feedback sender's clock, or None."""
        k = bisect_left(self.received, (i, -(1 << 62)))
        if k < len(self.received) and self.received[k][0] == i:
            return self.received[k][1] * TICK_US
        return None

    def __bytes__(self) -> bytes:
        runs: list[list[int]] = []          # [symbol, count], consecutive symbols alike merged
        deltas = bytearray()
        last, nxt = self.reference_time * _TICKS_PER_REF, 0

        def add(s: int, n: int) -> None:
            if runs and runs[-1][0] == s:
                runs[-1][1] += n
            else:
                runs.append([s, n])

        for i, a in self.received:
            if i > nxt:
                add(0, i - nxt)
            d = a - last
            last, nxt = a, i + 1
            if 0 <= d <= 0xFF:
                add(1, 1)
                deltas.append(d)
            elif -0x8000 <= d <= 0x7FFF:
                add(2, 1)
                deltas += struct.pack("!h", d)
            else:
                raise ValueError(f"transport-cc feedback: receive delta of {d * TICK_US} us does not fit 16 bits")
        if self.status_count > nxt:
            add(0, self.status_count - nxt)
        body = _FIXED.pack(self.ssrc, self.media_ssrc, self.base_seq & 0xFFFF, self.status_count,
                           self.reference_time << 8 | (self.fb_count & 0xFF))
        body += b"".join(struct.pack("!H", c) for c in _chunks(runs)) + bytes(deltas)
        body += bytes(-len(body) % 4)
        return struct.pack("!BBH", 0x80 | RTPFB_TWCC, 205, len(body) // 4) + body


def _chunks(runs: list[list[int]]) -> list[int]:
    """Greedy chunking of ``[symbol, count]`` runs: 14 or more alike as one run-length chunk (at most 8,191 a chunk),
    else fourteen 1-bit symbols where they are all 0/1, else seven 2-bit symbols (the last vector padded with 'not
    received', which the count cuts off).  Work is bounded by the chunks made, not the statuses they carry."""
    out: list[int] = []
    k, used = 0, 0                           # the current run, and how many of its symbols are chunked
    total_left = sum(n for _, n in runs)

    def peek(m: int) -> list[int]:
        got: list[int] = []
        j, u = k, used
        while len(got) < m and j < len(runs):
            take = min(m - len(got), runs[j][1] - u)
            got += [runs[j][0]] * take
            j, u = j + 1, 0
        return got

    def advance(m: int) -> None:
        nonlocal k, used, total_left
        total_left -= m
        while m:
            take = min(m, runs[k][1] - used)
            used += take
            m -= take
            if used == runs[k][1]:
                k, used = k + 1, 0

    while total_left:
        s = runs[k][0]
        run = min(runs[k][1] - used, _RUN_MAX)
        if run >= 14 or run == total_left and run >= 7:
            out.append(s << 13 | run)
            advance(run)
            continue
        part = peek(14)
        if all(x <= 1 for x in part):
            out.append(0x8000 | sum(x << (13 - j) for j, x in enumerate(part)))
        else:
            part = part[:7]
            out.append(0xC000 | sum(x << (12 - 2 * j) for j, x in enumerate(part)))
        advance(len(part))
    return out


def parse_transport_feedback(body: bytes, where: str = "transport-cc feedback") -> TransportFeedback:
    """The RTPFB FMT 15 body after the RTCP header (padding removed); :class:`RtcpError` names what is wrong.

    Work and memory are bounded by ``len(body)``: 'not received' runs are skipped by count, and a run of received
    statuses longer than the bytes left to carry their receive deltas is refused before it is expanded."""
    if len(body) < _FIXED.size:
        raise RtcpError(f"{where}: body of {len(body)} bytes is shorter than its {_FIXED.size}-byte fixed part")
    ssrc, media, base, count, ref_fb = _FIXED.unpack_from(body)
    if count == 0:
        raise RtcpError(f"{where}: packet status count is 0")
    pos = _FIXED.size
    got: list[tuple[int, int]] = []          # (status index, symbol 1 or 2) of the received statuses
    n = 0                                    # statuses read so far
    while n < count:
        if pos + 2 > len(body):
            raise RtcpError(f"{where}: packet chunks end after {n} of {count} statuses")
        (c,) = struct.unpack_from("!H", body, pos)
        pos += 2
        if not c & 0x8000:
            s, run = c >> 13 & 3, c & _RUN_MAX
            if run == 0:
                raise RtcpError(f"{where}: run-length chunk at byte {pos - 2} has run length 0")
            run = min(run, count - n)
            if s == 3:
                raise RtcpError(f"{where}: packet status {n} uses the reserved symbol 3")
            if s:
                if len(got) + run > len(body) - pos:     # each received status needs a delta byte at least
                    raise RtcpError(f"{where}: run-length chunk at byte {pos - 2} declares {run} received statuses "
                                    f"but only {len(body) - pos} bytes are left for their receive deltas")
                got += [(n + j, s) for j in range(run)]
            n += run
        else:
            syms = [c >> (13 - k) & 1 for k in range(14)] if not c & 0x4000 else \
                [c >> (12 - 2 * k) & 3 for k in range(7)]
            for j, s in enumerate(syms[:count - n]):
                if s == 3:
                    raise RtcpError(f"{where}: packet status {n + j} uses the reserved symbol 3")
                if s:
                    got.append((n + j, s))
            n += min(len(syms), count - n)
    received: list[tuple[int, int]] = []
    t = (ref_fb >> 8) * _TICKS_PER_REF
    for i, s in got:
        w = 1 if s == 1 else 2
        if pos + w > len(body):
            raise RtcpError(f"{where}: receive deltas end before status {i} of {count}")
        t += body[pos] if w == 1 else struct.unpack_from("!h", body, pos)[0]
        pos += w
        received.append((i, t))
    if any(body[pos:]):
        raise RtcpError(f"{where}: {len(body) - pos} bytes after the receive deltas are not zero padding")
    return TransportFeedback(ssrc, media, base, ref_fb >> 8, ref_fb & 0xFF, count, tuple(received))


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
        out: list[TransportFeedback] = []
        received: list[tuple[int, int]] = []
        base = seqs[0] if self._next is None or seqs[0] - self._next >= MAX_STATUS_COUNT else self._next
        ref, last, shift, prev = 0, 0, 0, base - 1
        for ext in seqs:             # work by arrivals, not by the sequence numbers between them
            tick = self._pending[ext] // TICK_US
            span = ext - base + 1
            if received and (span > MAX_STATUS_COUNT or not -0x8000 <= tick - last <= 0x7FFF):
                # close the packet: through ext - 1 ('not received' up to it) where that fits, else through the
                # last arrival (a gap of more than 65,535 sequence numbers is not reported: the sender's history
                # forgets those packets by age)
                out.append(self._packet(base, ref, ext - base if span - 1 <= MAX_STATUS_COUNT else prev - base + 1,
                                        received))
                received, base = [], ext
            if not received:          # the packet's reference time: its first arrival's 64 ms period (24 bits)
                ref = (tick // _TICKS_PER_REF) % _REF_MOD
                shift = (tick // _TICKS_PER_REF - ref) * _TICKS_PER_REF   # whole wraps of the 24-bit reference
            last, prev = tick, ext
            received.append((ext - base, tick - shift))
        out.append(self._packet(base, ref, prev - base + 1, received))
        self._next = seqs[-1] + 1
        self._pending.clear()
        return out

    def _packet(self, base: int, ref: int, count: int, received: list[tuple[int, int]]) -> TransportFeedback:
        fb = TransportFeedback(self.ssrc, self.media_ssrc, base & 0xFFFF, ref, self._fb_count, count, tuple(received))
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
        """The sent packets ``fb`` reports on, in sequence order (arrival None: lost).  Work is bounded by the packets
        this history holds, whatever status count the feedback declares."""
        out: list[PacketResult] = []
        if not self._sent:
            self.unknown += fb.status_count
            return out
        newest = next(reversed(self._sent))
        base = newest + ((fb.base_seq - newest) & 0xFFFF)
        if base > newest:
            base -= 1 << 16
        end = base + fb.status_count                  # exclusive
        arrived = {base + i: a * TICK_US for i, a in fb.received}
        lo, hi = max(base, next(iter(self._sent))), min(end, newest + 1)
        if hi - lo <= len(self._sent):
            seqs: Iterable[int] = range(lo, hi)
        else:
            seqs = [s for s in self._sent if lo <= s < hi]
        found = 0
        for s in seqs:
            sent = self._sent.pop(s, None)
            if sent is None:
                continue
            found += 1
            out.append(PacketResult(s, sent[0], sent[1], arrived.get(s), sent[2]))
        self.unknown += fb.status_count - found
        return out

    @property
    def in_flight(self) -> int:
        """Packets sent and not yet reported."""
        return len(self._sent)
