"""H.264 (RFC 6184) and H.265 (RFC 7798) payload formats: golden payloads, exact
errors, round trips and fuzzing."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.errors import LocalProtocolError, RemoteProtocolError
from splitrender.protocol import (
    PayloadError,
    RtpPacketizer,
    depacketize,
    h264_depayload,
    h264_payloads,
    h265_depayload,
    h265_payloads,
    join_annexb,
    split_annexb,
)

SPS = bytes.fromhex("6742001f")
PPS = bytes.fromhex("68ce3c80")
IDR = bytes.fromhex("65888400ffeedd")
VPS5 = bytes.fromhex("40010c01")
SPS5 = bytes.fromhex("42010101")
IDR5 = bytes.fromhex("2601af00112233")  # IDR_W_RADL, type 19
AU264 = b"\x00\x00\x00\x01" + SPS + b"\x00\x00\x01" + PPS + b"\x00\x00\x00\x01" + IDR + b"\x00"


def test_split_annexb() -> None:
    assert split_annexb(AU264) == [SPS, PPS, IDR]
    assert join_annexb([SPS, PPS]) == b"\x00\x00\x00\x01" + SPS + b"\x00\x00\x00\x01" + PPS
    with pytest.raises(LocalProtocolError, match="^access unit does not start with an Annex-B start code$"):
        split_annexb(b"\x01\x02\x00\x00\x01\x65")


def test_h264_golden_stap_a_and_single() -> None:
    assert h264_payloads([SPS, PPS, IDR], mtu=20) == [
        bytes.fromhex("78" "0004" "6742001f" "0004" "68ce3c80"),  # STAP-A, NRI=3
        IDR,  # single NAL unit packet
    ]


def test_h264_golden_fu_a() -> None:
    assert h264_payloads([IDR], mtu=5) == [
        bytes.fromhex("7c85888400"),  # FU indicator NRI=3|28, FU header S|5
        bytes.fromhex("7c45ffeedd"),  # FU header E|5
    ]
    assert h264_depayload(h264_payloads([IDR], mtu=5)) == [IDR]


def test_hevc_golden_ap_and_single() -> None:
    assert h265_payloads([VPS5, SPS5, IDR5], mtu=20) == [
        bytes.fromhex("6001" "0004" "40010c01" "0004" "42010101"),  # AP: type 48, TID 1
        IDR5,
    ]


def test_hevc_golden_fu() -> None:
    assert h265_payloads([IDR5], mtu=6) == [
        bytes.fromhex("620193af0011"),  # payload hdr type 49, FU hdr S|19
        bytes.fromhex("62015322" "33"),  # FU hdr E|19
    ]
    assert h265_depayload(h265_payloads([IDR5], mtu=6)) == [IDR5]


def test_packetizer_marker_and_sequence_wrap() -> None:
    pk = RtpPacketizer("h264", ssrc=5, payload_type=96, mtu=5, first_sequence=65535)
    pkts = pk.packetize(AU264, 1234)
    assert [p.sequence_number for p in pkts] == [65535, 0, 1, 2]  # SPS, PPS, 2 x FU-A
    assert [p.marker for p in pkts] == [False] * 3 + [True]
    assert {p.timestamp for p in pkts} == {1234}
    assert all(len(p.payload) <= 5 for p in pkts)
    assert depacketize("h264", [p.payload for p in pkts]) == join_annexb([SPS, PPS, IDR])
    assert pk.sequence_number == 3 and pk.packets_sent == 4


@pytest.mark.parametrize(
    ("payloads", "text"),
    [
        ([b""], r"^H\.264 payload 0: empty$"),
        ([b"\xe5\x00"], r"^H\.264 payload 0: forbidden_zero_bit is set$"),
        ([b"\x7c\x05\xaa"], r"^H\.264 payload 0: FU-A fragment without a start fragment$"),
        ([b"\x7c\xc5\xaa"], r"^H\.264 payload 0: FU-A has both start and end bits$"),
        ([b"\x7c\x85"], r"^H\.264 payload 0: FU-A of 2 bytes is truncated$"),
        ([b"\x7c\x85\xaa"], r"^H\.264: FU-A of type 5 incomplete at end of access unit$"),
        ([b"\x7c\x85\xaa", b"\x7c\x41\xbb"], r"^H\.264 payload 1: FU-A type 1 does not match started type 5$"),
        ([b"\x7c\x85\xaa", b"\x7c\x85\xbb"], r"^H\.264 payload 1: FU-A start while a type 5 NAL unit is incomplete$"),
        ([b"\x7c\x85\xaa", b"\x65\x00"], r"^H\.264 payload 1: type 5 packet inside an incomplete FU-A$"),
        ([b"\x7c\x98\xaa"], r"^H\.264 payload 0: FU-A carries invalid NAL unit type 24$"),
        ([b"\x78\x00\x05\x67"], r"^H\.264 payload 0: STAP-A NAL unit of 5 bytes at offset 3 runs past end of 4-byte payload$"),
        ([b"\x78\x00"], r"^H\.264 payload 0: STAP-A size field at offset 1 is truncated$"),
        ([b"\x78"], r"^H\.264 payload 0: STAP-A contains no NAL units$"),
        ([b"\x78\x00\x00"], r"^H\.264 payload 0: STAP-A contains a zero-length NAL unit$"),
        ([b"\x78\x00\x01\x80"], r"^H\.264 payload 0: STAP-A NAL unit at offset 3 has forbidden_zero_bit set$"),
        ([b"\x79\x00"], r"^H\.264 payload 0: unsupported NAL unit type 25 \(STAP-B\)$"),
        ([b"\x60\x00"], r"^H\.264 payload 0: unsupported NAL unit type 0 \(reserved\)$"),
    ],
)
def test_h264_depayload_errors(payloads: list[bytes], text: str) -> None:
    with pytest.raises(PayloadError, match=text):
        h264_depayload(payloads)


@pytest.mark.parametrize(
    ("payloads", "text"),
    [
        ([b"\x26"], r"^HEVC payload 0: 1 bytes is shorter than the 2-byte header$"),
        ([b"\xa6\x01"], r"^HEVC payload 0: payload header forbidden_zero_bit is set$"),
        ([b"\x26\x00"], r"^HEVC payload 0: payload header nuh_temporal_id_plus1 is 0$"),
        ([b"\x62\x01\x13\xaa"], r"^HEVC payload 0: FU fragment without a start fragment$"),
        ([b"\x62\x01\xd3\xaa"], r"^HEVC payload 0: FU has both start and end bits$"),
        ([b"\x62\x01\x93"], r"^HEVC payload 0: FU of 3 bytes is truncated$"),
        ([b"\x62\x01\xb0\xaa"], r"^HEVC payload 0: FU carries invalid NAL unit type 48$"),
        ([b"\x62\x01\x93\xaa"], r"^HEVC: FU of type 19 incomplete at end of access unit$"),
        ([b"\x62\x01\x93\xaa", b"\x62\x01\x41\xaa"], r"^HEVC payload 1: FU type 1 does not match started type 19$"),
        ([b"\x60\x01\x00\x09\x40"], r"^HEVC payload 0: AP NAL unit of 9 bytes at offset 4 runs past end of 5-byte payload$"),
        ([b"\x60\x01\x00"], r"^HEVC payload 0: AP size field at offset 2 is truncated$"),
        ([b"\x60\x01"], r"^HEVC payload 0: AP contains no NAL units$"),
        ([b"\x60\x01\x00\x01\x40"], r"^HEVC payload 0: AP NAL unit size 1 at offset 2 is below 2$"),
        ([b"\x60\x01\x00\x02\xc0\x01"], r"^HEVC payload 0: AP NAL unit at offset 4 forbidden_zero_bit is set$"),
        ([b"\x64\x01"], r"^HEVC payload 0: unsupported NAL unit type 50$"),
    ],
)
def test_hevc_depayload_errors(payloads: list[bytes], text: str) -> None:
    with pytest.raises(PayloadError, match=text):
        h265_depayload(payloads)


h264_nal = st.builds(
    lambda hdr, body: bytes([hdr]) + body,
    st.sampled_from([0x67, 0x68, 0x65, 0x41, 0x01, 0x06, 0x09]),
    st.binary(min_size=0, max_size=300),
)
hevc_nal = st.builds(
    lambda t, tid, body: bytes([t << 1, tid]) + body,
    st.sampled_from([32, 33, 34, 19, 1, 39, 35]),
    st.integers(1, 7),
    st.binary(min_size=0, max_size=300),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(h264_nal, min_size=1, max_size=8), st.integers(3, 400))
def test_h264_round_trip(nals: list[bytes], mtu: int) -> None:
    payloads = h264_payloads(nals, mtu)
    assert all(len(p) <= mtu for p in payloads)
    assert h264_depayload(payloads) == nals


@settings(max_examples=300, deadline=None)
@given(st.lists(hevc_nal, min_size=1, max_size=8), st.integers(4, 400))
def test_hevc_round_trip(nals: list[bytes], mtu: int) -> None:
    payloads = h265_payloads(nals, mtu)
    assert all(len(p) <= mtu for p in payloads)
    assert h265_depayload(payloads) == nals


@settings(max_examples=1000, deadline=None)
@given(st.lists(st.binary(max_size=24), max_size=5))
def test_fuzz_depayload_random(payloads: list[bytes]) -> None:
    for fn in (h264_depayload, h265_depayload):
        try:
            fn(payloads)
        except RemoteProtocolError:
            pass


@settings(max_examples=500, deadline=None)
@given(st.lists(h264_nal, min_size=1, max_size=5), st.integers(3, 60), st.data())
def test_fuzz_depayload_mutated(nals: list[bytes], mtu: int, data: st.DataObject) -> None:
    for pay, depay in ((h264_payloads, h264_depayload), (h265_payloads, h265_depayload)):
        payloads = pay([b"\x26\x01" + n for n in nals] if pay is h265_payloads else nals, max(mtu, 4))
        i = data.draw(st.integers(0, len(payloads) - 1))
        p = bytearray(payloads[i])
        j = data.draw(st.integers(0, len(p) - 1))
        p[j] = data.draw(st.integers(0, 255))
        cut = data.draw(st.integers(0, len(p)))
        payloads[i] = bytes(p[:cut])
        if data.draw(st.booleans()):
            del payloads[data.draw(st.integers(0, len(payloads) - 1))]
        try:
            depay(payloads)
        except RemoteProtocolError:
            pass
