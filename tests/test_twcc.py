"""Transport-wide congestion control feedback: the wire format, the receiver's recorder, the sender's history."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.protocol.errors import RtcpError, RtpError
from splitrender.protocol.rtcp import GenericNack, parse_rtcp, serialize_rtcp
from splitrender.protocol.rtp import RtpPacket
from splitrender.protocol.twcc import (TICK_US, FeedbackRecorder, SendHistory, TransportFeedback, one_byte_extension,
                                       parse_one_byte_extension, parse_transport_feedback)


def test_a_feedback_packet_byte_for_byte() -> None:
    """Statuses: received (+1 ms), lost, received (+0.25 ms), received 2 ms early (a negative delta): one 2-bit
    vector chunk; deltas 4, 1, -8 ticks from a reference of 1 x 64 ms."""
    ref_ticks = 256
    fb = TransportFeedback.from_arrivals(0x11111111, 0x22222222, 65534, 1, 7, (ref_ticks + 4, None, ref_ticks + 5, ref_ticks - 3))
    data = bytes(fb)
    chunk = 0xC000 | 1 << 12 | 0 << 10 | 1 << 8 | 2 << 6     # seven 2-bit symbols: 1, 0, 1, 2, then padding
    body = (struct.pack("!IIHHI", 0x11111111, 0x22222222, 65534, 4, 1 << 8 | 7) + struct.pack("!H", chunk)
            + bytes([4, 1]) + struct.pack("!h", -8))
    body += bytes(-len(body) % 4)
    assert data == struct.pack("!BBH", 0x8F, 205, len(body) // 4) + body
    assert parse_rtcp(data) == [fb]
    assert fb.arrival_us(0) == (256 + 4) * TICK_US and fb.arrival_us(1) is None


def test_chunk_kinds_round_trip() -> None:
    """A long run (run-length chunk), a 0/1 pattern (1-bit vectors) and large deltas (2-bit vectors)."""
    t = 1000 * 256
    run = tuple(t + i for i in range(40))                          # 40 received, 0.25 ms apart
    pattern = tuple(None if i % 3 == 0 else t + 100 + i for i in range(30))
    large = tuple(t + 400 + 300 * i for i in range(9))             # 75 ms apart: 2-byte deltas
    fb = TransportFeedback.from_arrivals(1, 2, 100, 1000, 0, run + pattern + large)
    data = bytes(fb)
    chunks = struct.unpack_from(f"!{(len(data) - 20) // 2}H", data, 20)
    kinds = {c >> 14 for c in chunks[:6]}
    assert chunks[0] == 1 << 13 | 40 and 2 in kinds and 3 in kinds  # run-length, 1-bit vector, 2-bit vector
    assert parse_rtcp(data) == [fb]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.one_of(st.none(), st.integers(-2000, 60000)), min_size=1, max_size=300),
       st.integers(0, 0xFFFF), st.integers(0, 0xFF))
def test_any_feedback_round_trips(steps: list[int | None], base: int, count: int) -> None:
    """Arrivals as running sums of steps in ticks (None = lost); whatever is encodable comes back unchanged."""
    ref = 5000
    arrivals: list[int | None] = []
    t = ref * 256
    for s in steps:
        if s is None:
            arrivals.append(None)
        else:
            t += s if s <= 0x7FFF else 0x7FFF
            arrivals.append(t)
    fb = TransportFeedback.from_arrivals(9, 10, base, ref, count, tuple(arrivals))
    data = bytes(fb)
    assert len(data) % 4 == 0 and parse_rtcp(data + bytes(GenericNack(1, 2, (5,)))) == [fb, GenericNack(1, 2, (5,))]


@pytest.mark.parametrize("body, message", [
    (b"\x00" * 12, "body of 12 bytes is shorter than its 16-byte fixed part"),
    (struct.pack("!IIHHI", 1, 2, 0, 0, 0), "packet status count is 0"),
    (struct.pack("!IIHHI", 1, 2, 0, 20, 0) + struct.pack("!H", 0xC000 | 1 << 12), "packet chunks end after 7 of 20"),
    (struct.pack("!IIHHI", 1, 2, 0, 2, 0) + struct.pack("!H", 0x2000 | 0) + b"\0\0", "has run length 0"),
    (struct.pack("!IIHHI", 1, 2, 0, 1, 0) + struct.pack("!H", 0x6001) + b"\0\0", "status 0 uses the reserved symbol 3"),
    (struct.pack("!IIHHI", 1, 2, 0, 3, 0) + struct.pack("!H", 0x2003), "declares 3 received statuses but only 0 bytes"),
    (struct.pack("!IIHHI", 1, 2, 0, 2, 0) + struct.pack("!H", 0xC000 | 2 << 12 | 2 << 10) + b"\x00\x05",
     "receive deltas end before status 1 of 2"),
    (struct.pack("!IIHHI", 1, 2, 0, 1, 0) + struct.pack("!H", 0x2001) + b"\x05\x07", "1 bytes after the receive deltas"),
])
def test_malformed_feedback_is_named(body: bytes, message: str) -> None:
    with pytest.raises(RtcpError, match=message):
        parse_transport_feedback(body)
    with pytest.raises(RtcpError, match="transport-cc feedback at offset 0"):
        body4 = body + bytes(-len(body) % 4)
        parse_rtcp(struct.pack("!BBH", 0x8F, 205, len(body4) // 4) + body4)


def test_one_byte_header_extension() -> None:
    prof, ext = one_byte_extension({5: struct.pack("!H", 0xABCD), 3: b"\x01\x02\x03"})
    pkt = RtpPacket(96, 1, 2, 3, b"payload", extension_profile=prof, extension_data=ext)
    back = RtpPacket.parse(bytes(pkt))
    assert parse_one_byte_extension(back.extension_profile, back.extension_data) == {5: b"\xab\xcd", 3: b"\x01\x02\x03"}
    assert parse_one_byte_extension(None, b"") == {} and parse_one_byte_extension(0x1000, b"\x51\x00\x00\x00") == {}
    with pytest.raises(RtpError, match="element 5 of 4 bytes runs past the 4-byte extension"):
        parse_one_byte_extension(0xBEDE, b"\x53\x00\x00\x00")
    with pytest.raises(ValueError, match="id 15 must be 1..14"):
        one_byte_extension({15: b"x"})


def test_recorder_and_history_match_sends_with_arrivals_across_the_wrap() -> None:
    """Sequence numbers wrap at 65535; a lost packet is reported as not received; a gap of 20 ms and of 10 s
    (a delta that does not fit) both survive; a late arrival for a reported sequence is counted, not reported."""
    hist, rec = SendHistory(window_us=60_000_000), FeedbackRecorder(ssrc=7)
    hist._seq = 65530                                          # start just before the wrap
    sent = []
    t = 1_000_000
    for i in range(12):
        seq = hist.on_sent(t, 1000 + i)
        sent.append((seq, t))
        t += 20_000 if i != 8 else 10_000_000
    assert [s for s, _ in sent[:7]] == [65530, 65531, 65532, 65533, 65534, 65535, 0]
    arrive = {s: ts + 30_000 for s, ts in sent if s not in (65533, 2)}
    for s in sorted(arrive, key=lambda s: arrive[s]):
        rec.on_packet(s, arrive[s])
    fbs = rec.feedback()
    assert len(fbs) == 2                                       # split at the 10 s gap
    back = [parse_rtcp(bytes(fb))[0] for fb in fbs]
    results = [r for fb in back for r in hist.on_feedback(fb)]
    assert [(r.seq & 0xFFFF, r.size, r.arrival_us) for r in results] == [
        (s, 1000 + i, None if s in (65533, 2) else arrive[s] // TICK_US * TICK_US) for i, (s, _) in enumerate(sent)]
    assert hist.in_flight == 0 and hist.unknown == 0 and rec.feedback() == []
    rec.on_packet(65533, t)                                    # far too late
    assert rec.late == 1 and rec.feedback() == []


def test_recorder_is_bounded() -> None:
    rec = FeedbackRecorder(ssrc=1, max_pending=100)
    for i in range(250):
        rec.on_packet(i, 1000 * i)
    assert rec.pending == 100 and rec.overflow == 150
    fbs = rec.feedback()
    assert fbs[0].base_seq == 150 and sum(len(f.arrivals) for f in fbs) == 100


def test_serialize_with_other_feedback() -> None:
    fb = TransportFeedback.from_arrivals(1, 2, 3, 4, 5, (4 * 256,))
    assert parse_rtcp(serialize_rtcp([GenericNack(1, 2, (7, 9)), fb])) == [GenericNack(1, 2, (7, 9)), fb]
