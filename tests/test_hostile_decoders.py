"""Decoders under hostile input (issue 16): the seven reproducers of the fuzzing campaign
each raise their documented error with bounded memory, and bounded hypothesis fuzzing
of every untrusted-input entry point lets nothing else out.

Memory is measured with ``tracemalloc`` (zstandard, msgpack and numpy allocate through
it), as the peak of traced memory during the call.
"""

from __future__ import annotations

import struct
import time
import tracemalloc
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.codecs.bounded import bounded_zstd_decompress
from splitrender.codecs.depth import BC4_MAX_PIXELS, bc4_decode, bc4_encode
from splitrender.codecs.meta import META_LIMITS, MetaEnvelopeError, pack_meta, parse_update_envelope, unpack_meta
from splitrender.errors import CodecError, LocalProtocolError, RemoteProtocolError
from splitrender.methods.sas.wire import META_VERSION, SasMetaError, SessionInfo, encode_ids, parse_frame_meta, parse_session
from splitrender.protocol import (
    NEED_DATA,
    Bye,
    ClientConnection,
    Error,
    FrameDecoder,
    FrameMeta,
    Hello,
    JitterBuffer,
    MessageType,
    Pose,
    RtpPacket,
    RtpPacketizer,
    ServerConnection,
    State,
    Welcome,
    encode_frame,
)
from splitrender.protocol.errors import MessageError
from splitrender.protocol.framing import HEADER, MAGIC
from splitrender.protocol.messages import MAX_BODY_SIZE, PROTOCOL_VERSION, StreamDescription
from splitrender.protocol.msgpack_limits import MsgpackLimitError, MsgpackLimits, check_msgpack
from splitrender.protocol.sdp import make_sdp, parameter_sets_from_sdp, parse_fmtp

MB = 1024 * 1024
ZSTD_BOMB_1TB = b"\x28\xb5\x2f\xfd\xe0" + (2**40).to_bytes(8, "little") + b"\x09\x00\x00\x80"
"""Issue 16 item 1: a zstd frame header declaring 1 TiB of content (17 bytes)."""


def _zstd_declaring(size: int) -> bytes:
    return b"\x28\xb5\x2f\xfd\xe0" + size.to_bytes(8, "little") + b"\x09\x00\x00\x80"


def _peak(fn: Callable[[], Any]) -> tuple[BaseException | None, int, float]:
    """(exception raised or None, tracemalloc peak in bytes above the start, seconds of a
    second call made without tracemalloc, which slows Python code tenfold)."""
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        err: BaseException | None = None
        try:
            fn()
        except BaseException as exc:  # noqa: BLE001 - the test inspects it
            err = exc
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    t0 = time.perf_counter()
    try:
        fn()
    except BaseException:  # noqa: BLE001
        pass
    return err, peak, time.perf_counter() - t0


# ------------------------------------------------------------------ 1. metadata zstd bomb
@pytest.mark.parametrize("declared", [512 * MB, 2**40, 2**64 - 2])
def test_metadata_bomb_is_refused_before_allocating(declared: int) -> None:
    # before the fix: 512 MiB declared grew the process by 512 MB, 1 TiB raised MemoryError
    err, peak, _ = _peak(lambda: unpack_meta(_zstd_declaring(declared)))
    assert isinstance(err, CodecError), err
    assert str(err) == f"metadata: zstd frame declares {declared} bytes, over the limit of {64 * MB}"
    assert peak < 64 * 1024, peak  # measured about 2 KB


def test_undeclared_size_is_streamed_under_a_hard_cap() -> None:
    bomb = zstandard.ZstdCompressor(level=3, write_content_size=False).compress(bytes(64 * MB))
    assert len(bomb) < 4096 and zstandard.frame_content_size(bomb) == -1
    err, peak, _ = _peak(lambda: bounded_zstd_decompress(bomb, 4 * MB, "data"))
    assert str(err) == f"data: zstd frame decompresses to more than the limit of {4 * MB} bytes"
    assert peak < 4 * MB + 2 * MB, peak  # the limit plus at most a few 128 KiB blocks; measured 4.6 MB
    # a window larger than the limit is refused before the decoder allocates it
    err, peak, _ = _peak(lambda: bounded_zstd_decompress(bomb, 1 * MB, "data"))
    assert str(err) == "data: zstd window of 2097152 bytes exceeds the 1048576-byte limit"
    assert peak < 64 * 1024, peak
    ok = zstandard.ZstdCompressor(level=3, write_content_size=False).compress(b"x" * 100_000)
    assert bounded_zstd_decompress(ok, 100_000, "data") == b"x" * 100_000
    with pytest.raises(CodecError, match=r"^data: zstd frame is truncated$"):
        bounded_zstd_decompress(ok[:-3], 100_000, "data")
    with pytest.raises(CodecError, match=r"^data: not a zstd frame"):
        bounded_zstd_decompress(b"nope", 100, "data")


# ------------------------------------------------------------------ 2. BC4 bomb and pixel limit
def _bc4_header(h: int, w: int) -> bytes:
    return struct.pack("<4sBxHHH", b"BC4D", 1, 8, h, w)


def test_bc4_bomb_and_pixel_limit() -> None:
    err, peak, _ = _peak(lambda: bc4_decode(_bc4_header(65535, 65535) + ZSTD_BOMB_1TB))
    assert str(err) == f"bc4: size 65535x65535 exceeds the limit of {BC4_MAX_PIXELS} pixels"
    assert peak < 64 * 1024, peak
    # a size within the pixel limit: the body size follows from the header, a frame
    # declaring more is refused before decompressing (before the fix: MemoryError)
    err, peak, _ = _peak(lambda: bc4_decode(_bc4_header(64, 64) + ZSTD_BOMB_1TB))
    assert str(err) == "bc4: zstd frame declares 1099511627776 bytes, over the limit of 1792", err
    assert peak < 64 * 1024, peak
    err, _, _ = _peak(lambda: bc4_decode(_bc4_header(64, 64) + _zstd_declaring(1000)))
    assert str(err) == "bc4: zstd frame declares 1000 bytes, expected 1792"
    codes = np.arange(64 * 64, dtype=np.uint16).reshape(64, 64)
    assert bc4_decode(bc4_encode(codes)).shape == (64, 64)


def test_bc4_bomb_is_a_warp_meta_error() -> None:
    from splitrender.methods.base import DecodedUpdate
    from splitrender.methods.warp import WarpConfig, WarpMetaError, parse_update
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.pose import Pose as ScenePose

    intr = CameraIntrinsics(64, 36, 60.0)
    pose = [0.0, 1.6, 2.5, 0.0, 0.0, 0.0, 1.0]
    meta = {"v": 1, "depth_coding": "bc4", "depth_near_m": 0.1, "ref": [64, 36, 60.0],
            "views": [{"pose": pose, "ids": np.zeros((36, 64), np.uint8), "bc4": _bc4_header(36, 64) + ZSTD_BOMB_1TB}],
            "obj_ids": np.zeros(0, np.int32), "obj_model": np.zeros((0, 4, 4), np.float32),
            "dyn_ids": np.zeros(0, np.int32), "dyn_prev": np.zeros((0, 4, 4), np.float32), "dt_s": 1 / 30}
    upd = DecodedUpdate(3, 0.0, ScenePose.from_list(pose), {"color0": np.zeros((36, 64, 3), np.uint8)}, meta)
    err, peak, _ = _peak(lambda: parse_update(upd, WarpConfig(views=1, depth_coding="bc4"), intr))
    assert isinstance(err, WarpMetaError) and isinstance(err, RemoteProtocolError), repr(err)
    assert "bc4: zstd frame declares 1099511627776 bytes, over the limit of" in str(err), err
    assert peak < 1 * MB, peak  # measured 4 KB


# ------------------------------------------------------------------ 3. msgpack amplification
def _empty_arrays_blob(n: int) -> bytes:
    """A metadata blob whose ``m`` is one array of ``n`` empty arrays (16 MiB -> about 540 bytes)."""
    raw = b"\x81\xa1m\xdd" + n.to_bytes(4, "big") + b"\x90" * n
    return zstandard.ZstdCompressor(level=19).compress(raw)


def test_metadata_msgpack_amplification_is_refused() -> None:
    blob = _empty_arrays_blob(16 * MB)
    assert len(blob) < 1024, len(blob)
    # before the fix: about 700 MB and 4.8 s; now the decompressed 16 MiB and a scan
    err, peak, dt = _peak(lambda: unpack_meta(blob))
    assert str(err) == f"metadata: msgpack: array of {16 * MB} entries exceeds 65536 (at byte 3)", err
    assert peak < 16 * MB + 1 * MB, peak  # the decompressed 16 MiB; measured 16.78 MB
    assert dt < 0.25, dt  # measured 0.01 s
    # the same objects spread over nested arrays inside the per-array limit: the object count stops it
    inner = b"\xdc" + (60000).to_bytes(2, "big") + b"\x90" * 60000
    raw = b"\x81\xa1m\xdc" + (256).to_bytes(2, "big") + inner * 256
    nested = zstandard.ZstdCompressor(level=19).compress(raw)
    err, peak, dt = _peak(lambda: unpack_meta(nested))
    assert str(err).startswith(f"metadata: msgpack: more than {META_LIMITS.max_objects} objects"), err
    assert peak < len(raw) + 1 * MB, peak  # measured 15.36 MB for 15.36 MB decompressed
    assert dt < 0.25, dt  # a Python scan of 65537 objects; measured 0.05 s


def test_metadata_arrays_are_bounded_and_copied_once() -> None:
    a = np.random.default_rng(0).integers(0, 255, 16 * MB, dtype=np.uint8)
    blob = pack_meta({"a": a, "b": np.arange(12.0).reshape(3, 4)})
    err, peak, _ = _peak(lambda: unpack_meta(blob))
    assert err is None
    # the decompressed document, msgpack's ext bytes and the array: 3 x 16 MiB (measured 50.4 MB)
    assert peak < 3 * 16 * MB + 1 * MB, peak
    out = unpack_meta(blob)
    assert np.array_equal(out["a"], a) and out["a"].flags.writeable and out["b"].shape == (3, 4)
    with pytest.raises(CodecError, match=r"^metadata: malformed array header: ValueError: 9 exceeds max_array_len\(8\)$"):
        unpack_meta(pack_meta({"a": np.zeros((1,) * 9)}))
    # sizes multiplied in Python ints: 2**32 x 2**32 wraps to 0 in int64, and 0 bytes follow
    head = msgpack.packb(["|u1", [2**32, 2**32]])
    raw = msgpack.packb({"a": msgpack.ExtType(1, head)})
    with pytest.raises(CodecError, match=r"needs 18446744073709551616 bytes, got 0$"):
        unpack_meta(zstandard.ZstdCompressor().compress(raw))


def _frame_meta_body(meta: Any) -> dict[str, Any]:
    return {"frame_id": 1, "t_us": 0, "rtp_ts": {}, "pose": {"t_us": 0, "seq": 0, "p": [0.0, 0.0, 0.0],
                                                                "q": [0.0, 0.0, 0.0, 1.0]},
            "meta": meta, "keyframe": False}


def test_frame_meta_amplification_is_refused_before_unpacking() -> None:
    n = MAX_BODY_SIZE[MessageType.FRAME_META] - 64
    raw = b"\x81\xa4meta\x81\xa1x\xdd" + n.to_bytes(4, "big") + b"\x90" * n
    raw = raw[:MAX_BODY_SIZE[MessageType.FRAME_META]]
    body = zstandard.ZstdCompressor(level=19, write_content_size=True).compress(raw)
    frame = HEADER.pack(MAGIC, PROTOCOL_VERSION, MessageType.FRAME_META, 1, len(body)) + body
    assert len(frame) < 200, len(frame)  # the was 166 bytes
    def decode() -> Any:
        dec = FrameDecoder()
        dec.receive_data(frame)
        return dec.next_event()

    err, peak, dt = _peak(decode)
    assert isinstance(err, MessageError), repr(err)
    assert str(err).startswith("FrameMeta: body is not valid msgpack (array of"), err
    assert peak < len(raw) + 1 * MB, peak  # the decompressed body; measured 4.2 MB
    assert dt < 0.1, dt  # before the fix: 0.43 s unpacking it; measured 0.01 s


def test_check_msgpack_limits_and_counts() -> None:
    lim = MsgpackLimits(max_objects=10, max_array_len=4, max_map_len=2, max_str_len=3, max_bin_len=3,
                        max_ext_len=3, max_depth=3)
    assert check_msgpack(msgpack.packb({"a": [1, 2.5, None]}), lim) == 6
    for obj, text in [([1] * 5, "array of 5 entries exceeds 4"), ({str(i): i for i in range(3)}, "map of 3 entries"),
                      ("abcd", "str of 4 bytes exceeds 3"), (b"abcd", "bin of 4 bytes exceeds 3"),
                      ([[[[1]]]], "nested deeper than 3"), ([[1, 2, 3, 4]] * 3, "more than 10 objects")]:
        with pytest.raises(MsgpackLimitError, match=text):
            check_msgpack(msgpack.packb(obj, use_bin_type=True), lim)
    with pytest.raises(MsgpackLimitError, match=r"^invalid type byte 0xc1 at byte 0$"):
        check_msgpack(b"\xc1", lim)
    with pytest.raises(MsgpackLimitError, match="longer than the data"):
        check_msgpack(b"\x94\x01", lim)
    with pytest.raises(MsgpackLimitError, match="trailing data"):
        check_msgpack(b"\x01\x02", lim)
    with pytest.raises(MsgpackLimitError, match="truncated"):
        check_msgpack(b"\xcb\x00", lim)


@given(st.recursive(st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=5)
                    | st.binary(max_size=5),
                    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=3), c, max_size=3),
                    max_leaves=20))
@settings(max_examples=200)
def test_check_msgpack_agrees_with_msgpack(obj: Any) -> None:
    def count(o: Any) -> int:
        if isinstance(o, dict):
            return 1 + sum(count(k) + count(v) for k, v in o.items())
        if isinstance(o, list):
            return 1 + sum(count(v) for v in o)
        return 1

    data = msgpack.packb(obj, use_bin_type=True)
    assert check_msgpack(data, MsgpackLimits()) == count(obj)
    for cut in (len(data) - 1, len(data) // 2):  # any truncation is refused by the scan
        if cut > 0:
            with pytest.raises(MsgpackLimitError):
                check_msgpack(data[:cut], MsgpackLimits())


# ------------------------------------------------------------------ 4./5. sas overflow past validation
SESSION = SessionInfo((64, 64), 1, 4, (0.0, 0.0, 0.0), np.zeros((1, 2, 3), np.float32), np.zeros(1, np.int64))


def test_sas_block_bounds_do_not_wrap() -> None:
    for x in (2**63 - 2, 2**63 - 1, 63):
        meta = {"v": META_VERSION, "uv_id": encode_ids(np.array([0])), "uv_rect": np.array([[x, 0, 1, 1, 0]], np.int64)}
        with pytest.raises(SasMetaError, match=r"^sas metadata: uv_rect: a block lies outside the atlas$"):
            parse_frame_meta(meta, SESSION)
    ok = {"v": META_VERSION, "uv_id": encode_ids(np.array([0])), "uv_rect": np.array([[62, 0, 1, 1, 0]], np.int64)}
    assert parse_frame_meta(ok, SESSION).uv_rect.tolist() == [[62, 0, 1, 1, 0]]


def test_sas_floats_checked_in_float32() -> None:
    xf = np.tile(np.eye(4), (1, 1, 1))
    xf[0, 0, 3] = 1e39  # finite in float64, inf in float32
    meta = {"v": META_VERSION, "xf_obj": np.array([0], np.uint16), "xf": xf}
    with pytest.raises(SasMetaError, match=r"^sas metadata: xf\[0\]: not finite in float32$"):
        parse_frame_meta(meta, SESSION)
    box = np.zeros((1, 2, 3))
    box[0, 1, 2] = -1e39
    sd = {"v": META_VERSION, "atlas": [64, 64], "n_objects": 1, "n_patches": 4, "obj_box": box,
          "patch_base": np.zeros(1, np.int64)}
    with pytest.raises(SasMetaError, match=r"^sas session data: obj_box: values not finite in float32$"):
        parse_session(sd)
    with pytest.raises(SasMetaError, match=r"^sas session data: sky\[1\]: expected a finite number in \[-1e\+06, 1e\+06\], got nan$"):
        parse_session({**sd, "obj_box": np.zeros((1, 2, 3)), "sky": [0.0, float("nan"), 0.0]})
    assert parse_session({**sd, "obj_box": np.ones((1, 2, 3))}).obj_box.dtype == np.float32
    ok = {**sd, "obj_box": np.ones((1, 2, 3))}
    assert parse_session(ok).inset == 0 and parse_session({**ok, "inset": 8}).inset == 8    # absent: every side spanned
    for inset in (-1, 4097, 2.5, True, "8"):
        with pytest.raises(SasMetaError, match=r"^sas session data: inset: expected an integer in 0\.\.4096, got "):
            parse_session({**ok, "inset": inset})


# ------------------------------------------------------------------ 6. send_error after Bye
HELLO = Hello(PROTOCOL_VERSION, "", ("video",), ("h264",), 160, 90, 30.0)


def test_send_error_after_bye_does_not_raise() -> None:
    c, s = ClientConnection(), ServerConnection()
    s.receive_data(c.send(HELLO))
    assert s.next_event() == HELLO
    welcome = Welcome("sid", "video", {}, (StreamDescription("color", "h264", 1, 96, 5004, ""),))
    c.receive_data(s.send(welcome))
    assert c.next_event() == welcome
    s.receive_data(c.send(Bye("done")) + b"GET / HTTP/1.1\r\n")  # Bye, then garbage
    assert s.next_event() == Bye("done")
    assert s.state is State.CLOSED
    with pytest.raises(RemoteProtocolError, match="bad frame magic"):
        s.next_event()
    data = s.send_error(400, "bad frame magic")  # before the fix: LocalProtocolError
    dec = FrameDecoder()
    dec.receive_data(data)
    assert dec.next_event() == Error(400, "bad frame magic")
    assert s.state is State.CLOSED
    with pytest.raises(LocalProtocolError, match="^server cannot send Bye in state CLOSED$"):
        s.send(Bye("again"))


# ------------------------------------------------------------------ 7. the live client's envelope
GOOD_ENV = {"t_s": 1.5, "pose": [0.0, 1.6, 2.5, 0.0, 0.0, 0.0, 1.0], "m": {}, "target_t_s": 1.6,
            "timing_us": {"render": 1200, "encode": 800, "encoded_at": 1_700_000_000_000_000}, "srv": {"views": 1.0}}


@pytest.mark.parametrize(("change", "text"), [
    ({"t_s": "soon"}, "metadata.t_s must be a finite number, got 'soon'"),
    ({"t_s": float("inf")}, "metadata.t_s must be a finite number, got inf"),
    ({"pose": None}, "metadata: missing field 'pose'"),
    ({"pose": [0.0] * 6}, "metadata.pose must be a list of 7 numbers [x, y, z, qx, qy, qz, qw], got list"),
    ({"pose": [0.0] * 7}, "metadata.pose: quaternion norm 0 is not 1"),
    ({"pose": [0.0, "a", 0, 0, 0, 0, 1]}, "metadata.pose[1] must be a finite number, got 'a'"),
    ({"m": [1]}, "metadata.m must be a map, got list"),
    ({"timing_us": [1, 2]}, "metadata.timing_us must be a map, got list"),
    ({"timing_us": {"render": 1.5}}, "metadata.timing_us['render'] must be an int64 of µs, got 1.5"),
    ({"srv": {"x": "y"}}, "metadata.srv['x'] must be a finite number, got 'y'"),
])
def test_envelope_fields_are_validated(change: dict[str, Any], text: str) -> None:
    env = {k: v for k, v in {**GOOD_ENV, **change}.items() if v is not None}
    with pytest.raises(MetaEnvelopeError) as info:
        parse_update_envelope(unpack_meta(pack_meta(env)))
    assert str(info.value) == text
    assert isinstance(info.value, RemoteProtocolError) and isinstance(info.value, CodecError)


def test_envelope_round_trip() -> None:
    env = parse_update_envelope(unpack_meta(pack_meta(GOOD_ENV)))
    assert env == {**GOOD_ENV, "pose": GOOD_ENV["pose"]}
    assert parse_update_envelope({"t_s": 0, "pose": GOOD_ENV["pose"], "m": {}})["timing_us"] == {}


def test_live_client_rejects_a_bad_frame_meta_as_a_protocol_error() -> None:
    """The live client's control path (its session core's ``receive_data``, which owns the control connection, run
    for every FrameMeta's bytes, through the client's pipeline) raises a RemoteProtocolError for each reproducer
    that reaches the client: bomb, amplification, bad envelope."""
    from splitrender.client.session import ClientConfig, LiveClient
    from splitrender.pipeline import ClientPipeline

    from splitrender.pipeline import ClientOptions, ClientSession
    from splitrender.protocol.framing import encode_frame

    client = LiveClient(ClientConfig())
    client.rx = ClientPipeline((), [])
    client.core = ClientSession(client.rx, ClientOptions(), 30.0)
    try:
        blobs = [ZSTD_BOMB_1TB, _empty_arrays_blob(1 * MB), pack_meta({**GOOD_ENV, "t_s": "x"}),
                 pack_meta({"t_s": 0.0, "m": {}}), pack_meta({**GOOD_ENV, "timing_us": [1]})]
        for i, blob in enumerate(blobs):
            msg = FrameMeta(i, 0, {}, Pose(0, 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), blob, False)
            err, peak, _ = _peak(lambda: client.core.receive_data(encode_frame(msg), 0.0))  # noqa: B023
            assert isinstance(err, RemoteProtocolError), (i, repr(err))
            assert str(err).startswith(f"FrameMeta {i}: metadata"), err
            assert peak < 2 * MB, (i, peak)  # measured at most 1.05 MB (the 1 MiB amplification blob)
        good = FrameMeta(9, 0, {}, Pose(0, 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), pack_meta(GOOD_ENV), False)
        client.core.receive_data(encode_frame(good), 0.0)
        assert client.counters["frames_complete"] == 1  # no streams: complete at once
    finally:
        for ex in (client.gl_executor, client.decode_executor, client.io_executor):
            ex.shutdown(wait=True)


# ------------------------------------------------------------------ bounded fuzzing of the entry points
def _flip(data: bytes, draw: Any) -> bytes:
    b = bytearray(data)
    for i in draw(st.lists(st.integers(0, max(len(b) * 8 - 1, 0)), max_size=8)):
        if b:
            b[i // 8] ^= 1 << (i % 8)
    cut = draw(st.integers(0, len(b)))
    return bytes(b[:cut]) + draw(st.binary(max_size=16))


@st.composite
def mutated(draw: Any, seed: bytes) -> bytes:
    return _flip(seed, draw)


META_SEED = pack_meta({**GOOD_ENV, "m": {"v": 1, "a": np.arange(12, dtype=np.float32).reshape(3, 4), "s": "x" * 20}})


@given(st.one_of(mutated(META_SEED), mutated(msgpack.packb(GOOD_ENV)), st.binary(max_size=200)))
def test_fuzz_unpack_meta(data: bytes) -> None:
    try:
        obj = unpack_meta(data)
    except CodecError:
        return
    try:
        parse_update_envelope(obj)
    except MetaEnvelopeError:
        pass


SESSION_SEED = {"v": 2, "atlas": [64, 64], "n_objects": 1, "n_patches": 4, "sky": [0.1, 0.2, 0.3],
                "obj_box": np.zeros((1, 2, 3), np.float32)}


@given(st.one_of(mutated(pack_meta(SESSION_SEED)),
                 st.fixed_dictionaries({k: st.one_of(st.just(v), st.integers(-(2**64), 2**64), st.floats(),
                                                     st.lists(st.floats(), max_size=3), st.none())
                                        for k, v in SESSION_SEED.items()})))
def test_fuzz_parse_session(data: Any) -> None:
    try:
        sd = unpack_meta(data) if isinstance(data, bytes) else data
        parse_session(sd)
    except (CodecError, SasMetaError):
        pass


def _rtp_seed(codec: str) -> list[bytes]:
    from splitrender.codecs.video import VideoCodecConfig, VideoEncoder

    enc = VideoEncoder(VideoCodecConfig(codec=codec, gop=4), 64, 36)  # type: ignore[arg-type]
    pk = RtpPacketizer(codec, 0x1234, 96, mtu=200)  # type: ignore[arg-type]
    out = []
    for i in range(3):
        ef = enc.encode(np.full((36, 64, 3), 40 * i, np.uint8))
        out += [bytes(p) for p in pk.packetize(ef.data, i * 3000)]
    return out


@pytest.fixture(scope="module")
def rtp_seeds() -> dict[str, list[bytes]]:
    return {c: _rtp_seed(c) for c in ("h264", "hevc")}


@given(data=st.data())
@settings(max_examples=60)
def test_fuzz_jitter_buffer(rtp_seeds: dict[str, list[bytes]], data: Any) -> None:
    codec = data.draw(st.sampled_from(["h264", "hevc"]))
    seeds = rtp_seeds[codec]
    jb = JitterBuffer(codec, max_packets=64)  # type: ignore[arg-type]
    order = data.draw(st.permutations(range(len(seeds))))
    now = 0.0
    for k in order:
        raw = seeds[k] if data.draw(st.booleans()) else data.draw(mutated(seeds[k]))
        try:
            pkt = RtpPacket.parse(raw)
        except RemoteProtocolError:
            continue
        now += data.draw(st.floats(0, 50))
        for au in jb.insert(pkt, now):  # malformed payloads are counted, never raised
            assert isinstance(au.data, bytes)
    jb.poll(now + 1000)
    jb.missing()


SDP_SEED = make_sdp("h264", 5004, 96, parameter_sets=[b"\x67\x42\x00\x1e\xab", b"\x68\xce\x3c\x80"]) \
    + make_sdp("hevc", 5006, 97, parameter_sets=[b"\x40\x01\x0c", b"\x42\x01\x01", b"\x44\x01\xc1"])


@given(st.one_of(mutated(SDP_SEED.encode()), st.binary(max_size=200)))
def test_fuzz_sdp(data: bytes) -> None:
    text = data.decode("utf-8", "replace")
    parse_fmtp(text)
    try:
        parameter_sets_from_sdp(text)
    except RemoteProtocolError:
        pass


@given(data=st.data())
@settings(max_examples=40)
def test_fuzz_video_decoder_on_garbage(rtp_seeds: dict[str, list[bytes]], data: Any) -> None:
    from splitrender.codecs.video import VideoDecoder

    codec = data.draw(st.sampled_from(["h264", "hevc"]))
    dec = VideoDecoder(codec, "rgb24")  # type: ignore[arg-type]
    for _ in range(3):
        au = data.draw(st.one_of(st.binary(max_size=300),
                                 mutated(b"\x00\x00\x00\x01" + RtpPacket.parse(rtp_seeds[codec][0]).payload)))
        try:
            dec.decode(au)
        except CodecError:
            pass


def _connection_seed() -> bytes:
    meta = FrameMeta(1, 2, {"color": 3}, Pose(1, 2, (0.0, 1.0, 2.0), (0.0, 0.0, 0.0, 1.0)), META_SEED, True)
    return encode_frame(meta) + encode_frame(Bye("x")) + encode_frame(Error(400, "y" * 2000))


@given(st.one_of(mutated(_connection_seed()), st.binary(max_size=300)), st.integers(1, 64))
def test_fuzz_connection_receive_data(data: bytes, step: int) -> None:
    c, s = ClientConnection(), ServerConnection()
    s.receive_data(c.send(HELLO))
    s.next_event()
    c.receive_data(s.send(Welcome("sid", "video")))
    assert c.next_event() == Welcome("sid", "video") and c.state is State.STREAMING  # FrameMeta is legal now
    try:
        for i in range(0, len(data), step):
            c.receive_data(data[i:i + step])
            while c.next_event() is not NEED_DATA:
                pass
        c.receive_data(b"")
        c.next_event()
    except RemoteProtocolError:
        c.send_error(400, "bad")  # must not raise in any state reached by peer input
