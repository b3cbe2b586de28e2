"""RTP/RTCP packets: golden bytes, exact parse errors, aiortc cross-checks, fuzzing,
receiver statistics, retransmission history and keyframe rate limiting."""

from __future__ import annotations

import pytest
from aiortc import rtp as artcp
from aiortc.rtp import RtpPacket as AiortcRtpPacket
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.errors import RemoteProtocolError
from splitrender.protocol import (
    GenericNack,
    KeyframeRateLimiter,
    PictureLossIndication,
    ReceiverReport,
    ReceiverStatistics,
    ReportBlock,
    RetransmissionHistory,
    RtcpError,
    RtcpUnknown,
    RtpError,
    RtpPacket,
    SenderReport,
    SequenceUnwrapper,
    is_rtcp,
    ntp_from_seconds,
    parse_rtcp,
    seq_diff,
    serialize_rtcp,
)

PKT = RtpPacket(96, 0x1234, 0xDEADBEEF, 0x11223344, b"\x65\xaa", marker=True)
GOLDEN_RTP = bytes.fromhex("80e01234deadbeef11223344" "65aa")


def test_rtp_golden() -> None:
    assert bytes(PKT) == GOLDEN_RTP
    assert RtpPacket.parse(GOLDEN_RTP) == PKT


def test_rtp_full_header_round_trip_and_aiortc() -> None:
    p = RtpPacket(
        100, 65535, 1, 2, b"payload", marker=False, csrc=(7, 8), extension_profile=0xBEDE,
        extension_data=b"\x10\xff\x00\x00", padding_size=3,
    )
    raw = bytes(p)
    assert raw[0] == 0x80 | 0x20 | 0x10 | 2 and raw[-1] == 3
    assert RtpPacket.parse(raw) == p
    theirs = AiortcRtpPacket.parse(raw)
    assert (theirs.payload_type, theirs.sequence_number, theirs.timestamp, theirs.ssrc) == (100, 65535, 1, 2)
    assert theirs.payload == b"payload" and theirs.csrc == [7, 8] and theirs.padding_size == 3
    ours = RtpPacket.parse(AiortcRtpPacket(payload_type=96, marker=1, sequence_number=9, timestamp=10, ssrc=11, payload=b"xy").serialize())
    assert ours == RtpPacket(96, 9, 10, 11, b"xy", marker=True)


@pytest.mark.parametrize(
    ("data", "text"),
    [
        (GOLDEN_RTP[:7], r"^RTP packet truncated: 7 bytes, header needs 12$"),
        (bytes([0x40]) + GOLDEN_RTP[1:], r"^RTP version 1 is not 2$"),
        (bytes([0x83]) + GOLDEN_RTP[1:], r"^RTP CSRC count 3 runs past end of 14-byte packet$"),
        (bytes([0x90]) + GOLDEN_RTP[1:12] + b"\xbe", r"^RTP header extension header runs past end of 13-byte packet$"),
        (bytes([0x90]) + GOLDEN_RTP[1:12] + b"\xbe\xde\x00\x02\x00", r"^RTP header extension of 8 bytes runs past end of 17-byte packet$"),
        (bytes([0xA0]) + GOLDEN_RTP[1:12] + b"\x01\x09", r"^RTP padding length 9 is longer than the 2-byte payload$"),
        (bytes([0xA0]) + GOLDEN_RTP[1:12] + b"\x01\x00", r"^RTP padding length is 0$"),
        (bytes([0xA0]) + GOLDEN_RTP[1:12], r"^RTP padding bit set but packet has no payload$"),
    ],
)
def test_rtp_parse_errors(data: bytes, text: str) -> None:
    with pytest.raises(RtpError, match=text):
        RtpPacket.parse(data)


@settings(max_examples=1000, deadline=None)
@given(st.binary(max_size=80))
def test_fuzz_rtp(data: bytes) -> None:
    try:
        p = RtpPacket.parse(data)
    except RtpError:
        return
    assert RtpPacket.parse(bytes(p)) == p


def test_seq_arithmetic_and_unwrap() -> None:
    assert seq_diff(0, 65535) == 1 and seq_diff(65535, 0) == -1
    u = SequenceUnwrapper()
    ext = [u.unwrap(s) for s in (65534, 65535, 0, 65533, 1, 2)]
    assert [e - ext[0] for e in ext] == [0, 1, 2, -1, 3, 4]


# ----------------------------------------------------------------------------- RTCP

BLOCK = ReportBlock(ssrc=0xAABBCCDD, fraction_lost=64, packets_lost=-2, highest_sequence=70000,
                    jitter=123, lsr=0x01020304, dlsr=65536)
SR = SenderReport(0x11111111, 0x0102030405060708, 90000, 10, 1000, (BLOCK,))
GOLDEN_RTCP = {
    "pli": (PictureLossIndication(1, 2), "81ce00020000000100000002"),
    "nack": (GenericNack(1, 2, (100, 101, 116)), "81cd0003000000010000000200648001"),
    "rr": (ReceiverReport(5, (BLOCK,)),
           "81c9000700000005" "aabbccdd" "40" "fffffe" "00011170" "0000007b" "01020304" "00010000"),
    "sr": (SR, "81c8000c11111111" "0102030405060708" "00015f90" "0000000a" "000003e8"
               "aabbccdd40fffffe000111700000007b0102030400010000"),
}


@pytest.mark.parametrize("name", sorted(GOLDEN_RTCP))
def test_rtcp_golden(name: str) -> None:
    pkt, hexstr = GOLDEN_RTCP[name]
    assert bytes(pkt).hex() == hexstr
    assert parse_rtcp(bytes.fromhex(hexstr)) == [pkt]
    assert is_rtcp(bytes(pkt))


def test_rtcp_compound_and_aiortc_cross_check() -> None:
    compound = serialize_rtcp([SR, GenericNack(1, 2, (65535, 0, 3)), PictureLossIndication(3, 4)])
    theirs = artcp.RtcpPacket.parse(compound)
    assert isinstance(theirs[0], artcp.RtcpSrPacket) and theirs[0].reports[0].jitter == 123
    assert theirs[0].reports[0].packets_lost == -2
    assert isinstance(theirs[1], artcp.RtcpRtpfbPacket) and sorted(s & 0xFFFF for s in theirs[1].lost) == [0, 3, 65535]  # aiortc does not wrap PID+k
    assert isinstance(theirs[2], artcp.RtcpPsfbPacket) and theirs[2].fmt == 1
    nack = artcp.RtcpRtpfbPacket(fmt=1, ssrc=9, media_ssrc=10)
    nack.lost = [10, 11, 30, 100]
    pli = artcp.RtcpPsfbPacket(fmt=1, ssrc=9, media_ssrc=10)
    rr = artcp.RtcpRrPacket(ssrc=9, reports=[artcp.RtcpReceiverInfo(
        ssrc=1, fraction_lost=2, packets_lost=3, highest_sequence=4, jitter=5, lsr=6, dlsr=7)])
    ours = parse_rtcp(bytes(nack) + bytes(pli) + bytes(rr))
    assert ours == [GenericNack(9, 10, (10, 11, 30, 100)), PictureLossIndication(9, 10),
                    ReceiverReport(9, (ReportBlock(1, 2, 3, 4, 5, 6, 7),))]


def test_rtcp_unknown_kept() -> None:
    bye = bytes.fromhex("81cb000100000005")
    assert parse_rtcp(bye) == [RtcpUnknown(203, 1, bytes.fromhex("00000005"))]
    assert bytes(parse_rtcp(bye)[0]) == bye


@pytest.mark.parametrize(
    ("data", "text"),
    [
        (b"", r"^RTCP packet is empty$"),
        (b"\x81\xce", r"^RTCP header at offset 0 truncated: 2 bytes, needs 4$"),
        (bytes.fromhex("41ce0002" "0000000100000002"), r"^RTCP version 1 at offset 0 is not 2$"),
        (bytes.fromhex("81ce0005" "0000000100000002"), r"^RTCP packet at offset 0 of 24 bytes runs past end of 12-byte data$"),
        (bytes.fromhex("81ce0001" "00000001"), r"^RTCP feedback at offset 0 truncated: body needs 8 bytes$"),
        (bytes.fromhex("82c90001" "00000005"), r"^RTCP RR with 2 report blocks runs past"),
        (bytes.fromhex("80c80001" "00000005"), r"^RTCP SR at offset 0 truncated: body needs 24 bytes$"),
        (bytes.fromhex("a1ce0002" "0000000100000009"), r"^RTCP padding length 9 at offset 0 is invalid$"),
    ],
)
def test_rtcp_parse_errors(data: bytes, text: str) -> None:
    with pytest.raises(RtcpError, match=text):
        parse_rtcp(data)


@settings(max_examples=1000, deadline=None)
@given(st.binary(max_size=120))
def test_fuzz_rtcp(data: bytes) -> None:
    try:
        parse_rtcp(data)
    except RemoteProtocolError:
        pass


def test_receiver_statistics_loss_and_jitter() -> None:
    st_ = ReceiverStatistics(ssrc=7)
    # 10 packets, one frame each 3000 ticks (33.3 ms), seq 65530.. wraps; seq 65533 lost
    for k in range(10):
        if k == 3:
            continue
        arrival = k * 1000 / 30 + (5.0 if k % 2 else 0.0)  # alternate 5 ms late
        st_.receive(RtpPacket(96, (65530 + k) & 0xFFFF, k * 3000, 1), arrival)
    st_.on_sender_report(SR, arrival_ms=100.0)
    rb = st_.report_block(now_ms=150.0)
    assert rb.packets_lost == 1 and rb.fraction_lost == 256 // 10
    assert rb.highest_sequence == (1 << 16) + 3  # one wrap, seq 3
    assert rb.lsr == 0x03040506 and rb.dlsr == int(50 * 65.536)
    # RFC 3550 A.8: |D| = 450 ticks (5 ms) alternating -> J converges towards 450
    assert 150 < rb.jitter < 450
    assert st_.report_block(now_ms=200.0).fraction_lost == 0


def test_ntp() -> None:
    assert ntp_from_seconds(0.5) == (2208988800 << 32) | (1 << 31)


def test_retransmission_history() -> None:
    h = RetransmissionHistory(capacity=3)
    for s in (65534, 65535, 0, 1):
        h.store(RtpPacket(96, s, 0, 1, bytes([s & 0xFF])))
    assert len(h) == 3 and h.get(65534) is None and h.get(0) is not None
    got = [p for s in GenericNack(1, 1, (65535, 1, 5)).lost if (p := h.get(s)) is not None]
    assert [p.sequence_number for p in got] == [65535, 1]


def test_keyframe_rate_limiter() -> None:
    k = KeyframeRateLimiter(min_interval_ms=500)
    assert k.request(0.0)
    assert not k.request(100.0) and k.pending
    assert not k.poll(499.0)
    assert k.poll(500.0) and not k.pending
    assert not k.poll(2000.0)
    k.keyframe_sent(2000.0)  # periodic IDR resets the interval
    assert not k.request(2100.0)
    assert k.request(2600.0)
