"""Control messages: golden bytes, round trips, exact field errors, fuzzing."""

from __future__ import annotations

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.errors import RemoteProtocolError
from splitrender.protocol import (
    MESSAGE_CLASSES,
    Bye,
    DataChunk,
    Error,
    Feedback,
    FrameMeta,
    Hello,
    KeyframeRequest,
    MessageError,
    MessageType,
    Pose,
    Stats,
    StreamDescription,
    Welcome,
    encode_frame,
)

POSE = Pose(1000, 7, (1.0, 2.0, -0.5), (0.0, 0.0, 0.0, 1.0))
EXAMPLES = {
    "Hello": Hello(1, "secret", ("video", "atw"), ("h264", "hevc"), 1280, 720, 90.0),
    "Welcome": Welcome(
        "s1", "video", {"fov": 90},
        (StreamDescription("color", "h264", 0x11223344, 96, 5004, "v=0\r\n"),),
    ),
    "Pose": POSE,
    "FrameMeta": FrameMeta(42, 123456, {"color": 90000}, POSE, b"\x01\x02", True),
    "Feedback": Feedback(42, 1, 2, 3, 0, 900, {"render": 5000}),
    "KeyframeRequest": KeyframeRequest("color", "loss"),
    "Stats": Stats({"packets": 10, "ratio": 0.5}),
    "Bye": Bye("done"),
    "Error": Error(401, "bad token"),
    "DataChunk": DataChunk("quads", 7, 0, 3, b"abc"),
}
# Frame = b"SR" | version 2 | type | flags 0 | u32 length | msgpack map body.
GOLDEN = {
    "Hello": "53520201000000006887a776657273696f6e01aa617574685f746f6b656ea6736563726574a76d6574686f647392a5766964656fa3617477a6636f6465637392a468323634a468657663a57769647468cd0500a6686569676874cd02d0aa646973706c61795f687acb4056800000000000",
    "Welcome": "53520202000000008a84aa73657373696f6e5f6964a27331a66d6574686f64a5766964656fad6d6574686f645f706172616d7381a3666f765aa773747265616d739187a46e616d65a5636f6c6f72a5636f646563a468323634a473737263ce11223344ac7061796c6f61645f7479706560aa636c6f636b5f72617465ce00015f90a4706f7274cd138ca3736470a5763d300d0a",
    "Pose": "53520203000000006484a4745f7573cd03e8a373657107a8706f736974696f6e93cb3ff0000000000000cb4000000000000000cbbfe0000000000000ab6f7269656e746174696f6e94cb0000000000000000cb0000000000000000cb0000000000000000cb3ff0000000000000",
    "FrameMeta": "5352020400000000a486a86672616d655f69642aa4745f7573ce0001e240a67274705f747381a5636f6c6f72ce00015f90a4706f736584a4745f7573cd03e8a373657107a8706f736974696f6e93cb3ff0000000000000cb4000000000000000cbbfe0000000000000ab6f7269656e746174696f6e94cb0000000000000000cb0000000000000000cb0000000000000000cb3ff0000000000000a46d657461c4020102a86b65796672616d65c3",
    "Feedback": "53520205000000007489a76170706c69656480a46c6f737480a86672616d655f69642aab72656365697665645f757301aa6465636f6465645f757302ac646973706c617965645f757303ac6c6f73745f7061636b65747300ac706f73655f74696d655f7573cd0384a97365727665725f757381a672656e646572cd1388",
    "KeyframeRequest": "53520206000000001a82a673747265616da5636f6c6f72a6726561736f6ea46c6f7373",
    "Stats": "53520207000000002381a8636f756e7465727382a77061636b6574730aa5726174696fcb3fe0000000000000",
    "Bye": "53520208000000000d81a6726561736f6ea4646f6e65",
    "DataChunk": "5352020a000000003185a673747265616da57175616473a86672616d655f696407a66f666673657400a5746f74616c03a464617461c403616263",
    "Error": "53520209000000001882a4636f6465cd0191a474657874a962616420746f6b656e",
}


def test_message_type_numbers() -> None:
    assert {t.name: int(t) for t in MessageType} == {
        "HELLO": 1, "WELCOME": 2, "POSE": 3, "FRAME_META": 4, "FEEDBACK": 5,
        "KEYFRAME_REQUEST": 6, "STATS": 7, "BYE": 8, "ERROR": 9, "DATA_CHUNK": 10,
    }
    assert set(MESSAGE_CLASSES) == set(MessageType)


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_golden_frame_bytes(name: str) -> None:
    frame = encode_frame(EXAMPLES[name])
    assert frame.hex() == GOLDEN[name]
    assert frame[:3] == b"SR\x02" and frame[3] == EXAMPLES[name].TYPE and frame[4] == 0
    assert int.from_bytes(frame[5:9], "big") == len(frame) - 9


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_round_trip(name: str) -> None:
    msg = EXAMPLES[name]
    assert type(msg).decode(msg.encode()) == msg


def test_frame_meta_dict_metadata_round_trips() -> None:
    msg = FrameMeta(1, 2, {"a": 0, "b": 4294967295}, POSE, {"quads": [1, 2.5, b"x", None]}, False)
    assert FrameMeta.decode(msg.encode()) == msg


def _pose_body(**override: object) -> bytes:
    d = POSE.to_wire()
    d.update(override)
    return msgpack.packb({k: v for k, v in d.items() if v is not ...}, use_bin_type=True)


@pytest.mark.parametrize(
    ("override", "text"),
    [
        ({"position": [1.0, 2.0]}, r"^Pose\.position: expected 3 floats, got 2$"),
        ({"position": "abc"}, r"^Pose\.position: expected 3 floats, got str$"),
        ({"position": [1.0, "x", 2.0]}, r"^Pose\.position\[1\]: expected float, got str$"),
        ({"position": [1.0, float("nan"), 2.0]}, r"^Pose\.position\[1\]: nan is not finite$"),
        ({"orientation": [0.0, 0.0, 0.0, 2.0]}, r"^Pose\.orientation: quaternion norm 2 is not 1$"),
        ({"seq": -1}, r"^Pose\.seq: -1 out of range \[0, 4294967295\]$"),
        ({"seq": True}, r"^Pose\.seq: expected int, got bool$"),
        ({"t_us": ...}, r"^Pose: missing field 't_us'$"),
    ],
)
def test_pose_field_errors(override: dict, text: str) -> None:
    with pytest.raises(MessageError, match=text) as info:
        Pose.decode(_pose_body(**override))
    assert info.value.code == 400


def test_body_errors() -> None:
    with pytest.raises(MessageError, match=r"^Hello: body is not valid msgpack"):
        Hello.decode(b"\xc1")
    with pytest.raises(MessageError, match=r"^Bye: body must be a msgpack map, got list$"):
        Bye.decode(msgpack.packb([1, 2]))
    with pytest.raises(MessageError, match=r"^Hello\.codecs: unknown codec 'vp8'"):
        Hello.decode(msgpack.packb({**EXAMPLES["Hello"].to_wire(), "codecs": ["vp8"]}))
    with pytest.raises(MessageError, match=r"^Hello\.width: 0 out of range \[1, 16384\]$"):
        Hello.decode(msgpack.packb({**EXAMPLES["Hello"].to_wire(), "width": 0}))
    bad_stream = {**EXAMPLES["Welcome"].to_wire()}
    bad_stream["streams"] = [{**bad_stream["streams"][0], "clock_rate": 48000}]
    with pytest.raises(MessageError, match=r"^Welcome\.streams\[0\]\.clock_rate: expected 90000, got 48000$"):
        Welcome.decode(msgpack.packb(bad_stream))
    with pytest.raises(MessageError, match=r"^FrameMeta\.pose\.position: expected 3 floats, got 0$"):
        FrameMeta.decode(msgpack.packb({**EXAMPLES["FrameMeta"].to_wire(), "pose": {**POSE.to_wire(), "position": []}}))
    with pytest.raises(MessageError, match=r"^FrameMeta\.meta: unsupported value of type ExtType$"):
        FrameMeta.decode(msgpack.packb({**EXAMPLES["FrameMeta"].to_wire(), "meta": {"x": msgpack.ExtType(5, b"")}}))
    with pytest.raises(MessageError, match=r"^Stats\.counters\['x'\]: expected number, got 'y'$"):
        Stats.decode(msgpack.packb({"counters": {"x": "y"}}))


def test_unknown_fields_are_ignored() -> None:
    body = msgpack.packb({"reason": "x", "future_field": [1, 2]})
    assert Bye.decode(body) == Bye("x")


msgpack_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=8)
    | st.binary(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=12), inner, max_size=6),
    max_leaves=20,
)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(sorted(MESSAGE_CLASSES)), st.binary(max_size=200))
def test_fuzz_decode_random_bytes(msg_type: MessageType, body: bytes) -> None:
    try:
        MESSAGE_CLASSES[msg_type].decode(body)
    except RemoteProtocolError:
        pass


@settings(max_examples=400, deadline=None)
@given(st.sampled_from(sorted(MESSAGE_CLASSES)), st.data())
def test_fuzz_decode_mutated_maps(msg_type: MessageType, data: st.DataObject) -> None:
    """Valid maps with fields replaced by arbitrary values: parse or MessageError."""
    cls = MESSAGE_CLASSES[msg_type]
    base = next(m for m in EXAMPLES.values() if type(m) is cls).to_wire()
    keys = data.draw(st.lists(st.sampled_from(sorted(base)), max_size=3))
    for k in keys:
        base[k] = data.draw(msgpack_values)
    try:
        cls.decode(msgpack.packb(base, use_bin_type=True))
    except MessageError:
        pass


def test_stream_description_fec_field_round_trips_and_is_checked() -> None:
    from splitrender.protocol.errors import MessageError

    d = StreamDescription("color", "h264", 0x11223344, 96, 5004, "v=0\r\n", fec_ssrc=0x55667788, fec_payload_type=127)
    w = d.to_wire()
    assert w["fec"] == [0x55667788, 127] and StreamDescription.from_wire("s", w) == d
    assert "fec" not in StreamDescription("color", "h264", 1, 96, 5004, "").to_wire()   # without FEC: the old bytes
    for bad, text in (([1], "expected \\[ssrc"), ([1, 95], "expected \\[ssrc"), ("x", "expected \\[ssrc"),
                      ([0x11223344, 127], "the FEC stream must differ"), ([5, 96], "the FEC stream must differ"), ([True, 127], "expected \\[ssrc")):
        with pytest.raises(MessageError, match=r"^s\.fec: " + text):
            StreamDescription.from_wire("s", {**w, "fec": bad})


def test_a_pose_far_beyond_any_scene_is_the_peers_error() -> None:
    """The long fuzz run's find: a Pose at x = 1.8e306 (finite) passed, and the server's predictor extrapolated it
    to inf.  Coordinates are bounded (``MAX_POSITION_M``, 1e6 m)."""
    from splitrender.protocol import MessageError, Pose

    wire = Pose(1, 2, (0.0, 1.6, 2.5), (0.0, 0.0, 0.0, 1.0)).to_wire()
    with pytest.raises(MessageError, match=r"Pose.position: \[1.797693134862316e\+306, 1.6, 2.49\] is more than 1e\+06 m"):
        Pose.from_wire({**wire, "position": [1.797693134862316e306, 1.6, 2.49]})
    assert Pose.from_wire({**wire, "position": [999_999.0, 1.6, -2.5]}).position == (999_999.0, 1.6, -2.5)
