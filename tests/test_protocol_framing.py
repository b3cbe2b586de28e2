"""Framing: byte-at-a-time parsing, EOF, size limits from the header, zstd bomb, fuzzing."""

from __future__ import annotations

import struct

from splitrender.protocol import PROTOCOL_VERSION

import msgpack
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.errors import LocalProtocolError, RemoteProtocolError
from splitrender.protocol import (
    CONNECTION_CLOSED,
    FLAG_ZSTD,
    MAX_BODY_SIZE,
    NEED_DATA,
    Bye,
    ErrorCode,
    FrameDecoder,
    FrameMeta,
    FramingError,
    MessageType,
    Pose,
    Stats,
    TooLargeError,
    VersionError,
    encode_frame,
)

POSE = Pose(1000, 7, (1.0, 2.0, -0.5), (0.0, 0.0, 0.0, 1.0))
BIG_META = FrameMeta(1, 2, {"color": 3}, POSE, {"quads": list(range(3000))}, False)
STREAM = encode_frame(POSE) + encode_frame(BIG_META) + encode_frame(Stats({"a": 1})) + encode_frame(Bye("x"))


def _events(chunks: list[bytes]) -> list[object]:
    dec = FrameDecoder()
    out: list[object] = []
    for c in [*chunks, b""]:
        dec.receive_data(c)
        while True:
            ev = dec.next_event()
            if ev is NEED_DATA:
                break
            out.append(ev)
            if ev is CONNECTION_CLOSED:
                return out
    return out


def test_big_body_is_compressed() -> None:
    frame = encode_frame(BIG_META)
    assert frame[4] == FLAG_ZSTD
    assert len(frame) < len(BIG_META.encode())
    assert encode_frame(POSE)[4] == 0


def test_whole_and_one_byte_at_a_time_give_same_events() -> None:
    expected = [POSE, BIG_META, Stats({"a": 1}), Bye("x"), CONNECTION_CLOSED]
    assert _events([STREAM]) == expected
    assert _events([STREAM[i : i + 1] for i in range(len(STREAM))]) == expected
    assert _events([STREAM[i : i + 7] for i in range(0, len(STREAM), 7)]) == expected


def test_need_data_then_partial_frame_at_eof() -> None:
    frame = encode_frame(POSE)
    dec = FrameDecoder()
    dec.receive_data(frame[:5])
    assert dec.next_event() is NEED_DATA
    dec.receive_data(b"")
    with pytest.raises(FramingError, match=r"^connection closed mid-frame: have 5 of 9 header bytes$"):
        dec.next_event()
    dec = FrameDecoder()
    dec.receive_data(frame[:20])
    dec.receive_data(b"")
    with pytest.raises(FramingError, match=r"^connection closed mid-frame: have 11 of 100 Pose body bytes$"):
        dec.next_event()


def test_errors_are_sticky_and_data_after_eof_is_local_error() -> None:
    dec = FrameDecoder()
    dec.receive_data(b"XX" + bytes(7))
    with pytest.raises(FramingError, match=r"^bad frame magic b'XX', expected b'SR'$"):
        dec.next_event()
    with pytest.raises(FramingError, match="bad frame magic"):
        dec.next_event()
    dec = FrameDecoder()
    dec.receive_data(b"")
    with pytest.raises(LocalProtocolError):
        dec.receive_data(b"x")


def _header(version: int = PROTOCOL_VERSION, msg_type: int = 3, flags: int = 0, length: int = 0) -> bytes:
    return struct.pack(">2sBBBI", b"SR", version, msg_type, flags, length)


def test_wrong_version_names_both_versions() -> None:
    dec = FrameDecoder()
    dec.receive_data(_header(version=3))
    with pytest.raises(VersionError, match=r"^peer speaks protocol version 3, this side speaks version 2$") as info:
        dec.next_event()
    assert info.value.code == ErrorCode.BAD_VERSION == 505


def test_unknown_type_and_flags() -> None:
    dec = FrameDecoder()
    dec.receive_data(_header(msg_type=77))
    with pytest.raises(FramingError, match=r"^unknown message type 77$"):
        dec.next_event()
    dec = FrameDecoder()
    dec.receive_data(_header(flags=0x82))
    with pytest.raises(FramingError, match=r"^Pose frame has unknown flags 0x82$"):
        dec.next_event()


@pytest.mark.parametrize("msg_type", list(MessageType))
def test_oversized_frame_rejected_from_header_alone(msg_type: MessageType) -> None:
    limit = MAX_BODY_SIZE[msg_type]
    dec = FrameDecoder()
    dec.receive_data(_header(msg_type=msg_type, length=limit + 1))  # no body byte at all
    with pytest.raises(TooLargeError, match=rf"frame body of {limit + 1} bytes exceeds the limit of {limit} bytes$") as info:
        dec.next_event()
    assert info.value.code == ErrorCode.TOO_LARGE == 413


def test_size_limits() -> None:
    assert MAX_BODY_SIZE[MessageType.HELLO] == 4096
    assert MAX_BODY_SIZE[MessageType.POSE] == 256
    assert MAX_BODY_SIZE[MessageType.FRAME_META] == 4 * 1024 * 1024


def test_zstd_bomb_rejected_before_decompressing() -> None:
    body = msgpack.packb({"reason": "x" * 10_000_000})
    bomb = zstandard.ZstdCompressor(level=19).compress(body)
    assert len(bomb) < 1024
    dec = FrameDecoder()
    dec.receive_data(_header(msg_type=MessageType.BYE, flags=FLAG_ZSTD, length=len(bomb)) + bomb)
    with pytest.raises(TooLargeError, match=r"^Bye body decompresses to 10000013 bytes, over the limit of 1024 bytes$"):
        dec.next_event()


def test_zstd_without_content_size_or_lying_rejected() -> None:
    body = msgpack.packb({"reason": "y" * 500})
    no_size = zstandard.ZstdCompressor(write_content_size=False).compress(body)
    dec = FrameDecoder()
    dec.receive_data(_header(msg_type=MessageType.BYE, flags=FLAG_ZSTD, length=len(no_size)) + no_size)
    with pytest.raises(FramingError, match=r"^Bye zstd frame does not declare its content size$"):
        dec.next_event()
    dec = FrameDecoder()
    dec.receive_data(_header(msg_type=MessageType.BYE, flags=FLAG_ZSTD, length=4) + b"abcd")
    with pytest.raises(FramingError, match=r"^Bye body is not a zstd frame$"):
        dec.next_event()


def test_local_oversize_send_is_local_error() -> None:
    with pytest.raises(LocalProtocolError, match=r"^Bye body of \d+ bytes exceeds the limit of 1024 bytes$"):
        encode_frame(Bye("z" * 2000))


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=300), st.integers(1, 16))
def test_fuzz_framing_random(data: bytes, chunk: int) -> None:
    dec = FrameDecoder()
    try:
        for i in range(0, len(data), chunk):
            dec.receive_data(data[i : i + chunk])
            while dec.next_event() is not NEED_DATA:
                pass
        dec.receive_data(b"")
        while dec.next_event() is not CONNECTION_CLOSED:
            pass
    except RemoteProtocolError:
        pass


@settings(max_examples=500, deadline=None)
@given(st.integers(0, len(STREAM) - 1), st.integers(0, 255), st.integers(1, 64))
def test_fuzz_framing_mutated_stream(pos: int, value: int, chunk: int) -> None:
    data = bytearray(STREAM)
    data[pos] = value
    try:
        _events([bytes(data[i : i + chunk]) for i in range(0, len(data), chunk)])
    except RemoteProtocolError:
        pass


def test_the_protocol_document_gives_the_version_the_code_speaks() -> None:
    """docs/protocol.md said version 1 in the frame table while the code sent 2 (issue 34): the title, the frame
    header table, the version check and Hello's field all give ``PROTOCOL_VERSION``."""
    import re
    from pathlib import Path

    from splitrender.protocol import PROTOCOL_VERSION

    doc = (Path(__file__).resolve().parents[1] / "docs" / "protocol.md").read_text()
    v = str(PROTOCOL_VERSION)
    assert re.search(r"^# splitrender wire protocol \(version (\d+)\)", doc, re.M).group(1) == v  # type: ignore[union-attr]
    assert re.search(r"\| protocol version \| `(\d+)` \(`PROTOCOL_VERSION`\) \|", doc).group(1) == v  # type: ignore[union-attr]
    assert re.search(r"version ≠ (\d+) → `VersionError\(\"peer speaks protocol version \d+, this side speaks version (\d+)\"\)",
                     doc).groups() == (v, v)  # type: ignore[union-attr]
    assert re.search(r"protocol version the client speaks \(must be (\d+)\)", doc).group(1) == v  # type: ignore[union-attr]
