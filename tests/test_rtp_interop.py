"""Interop of the RTP payload formats with an independent implementation (FFmpeg).

(a) our packetizer -> UDP on loopback -> FFmpeg reading our SDP -> PSNR vs source;
(b) FFmpeg's RTP muxer -> UDP -> our jitter buffer + depacketizer -> PyAV decoder.
Every loop and subprocess is bounded in time; only 127.0.0.1 is used.
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path

import av
from fractions import Fraction
import numpy as np
import pytest

from splitrender.codecs.video import VideoCodecConfig, VideoEncoder, rgb_to_yuv
from splitrender.protocol import (
    JitterBuffer,
    RtpPacket,
    RtpPacketizer,
    make_sdp,
    nal_type,
    parameter_sets_from_sdp,
    parse_fmtp,
    join_annexb,
    split_annexb,
)

pytestmark = pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg CLI not installed")

WIDTH, HEIGHT, FPS, N_FRAMES = 320, 180, 30, 30
EXTRA_FRAMES = 2  # FFmpeg's parser holds a frame until the next one starts
TS_STEP = 90000 // FPS
PSNR_MIN_DB = 30.0
ENCODERS = {"h264": "libx264", "hevc": "libx265"}


def _test_pattern(i: int) -> np.ndarray:
    """Moving gradient with a moving square, RGB uint8 (H, W, 3)."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    img = np.empty((HEIGHT, WIDTH, 3), np.uint8)
    img[..., 0] = (x * 255 // WIDTH + 4 * i) % 256
    img[..., 1] = (y * 255 // HEIGHT) % 256
    img[..., 2] = ((x + y + 8 * i) // 2) % 256
    sx, sy = (10 + 7 * i) % (WIDTH - 40), (20 + 3 * i) % (HEIGHT - 40)
    img[sy : sy + 40, sx : sx + 40] = (255, 255, 255)
    return img


def encode_clip(codec: str, n_frames: int = N_FRAMES) -> tuple[list[bytes], list[np.ndarray]]:
    """Annex-B access units and source Y planes of ``n_frames`` test frames."""
    ctx = av.CodecContext.create(ENCODERS[codec], "w")
    ctx.width, ctx.height, ctx.pix_fmt = WIDTH, HEIGHT, "yuv420p"
    ctx.time_base = Fraction(1, FPS)
    ctx.framerate = Fraction(FPS, 1)
    ctx.max_b_frames = 0
    ctx.gop_size = N_FRAMES
    opts = {"tune": "zerolatency", "preset": "ultrafast", "crf": "18"}
    if codec == "hevc":
        opts["x265-params"] = "bframes=0:log-level=error"
    ctx.options = opts
    aus: list[bytes] = []
    ys: list[np.ndarray] = []
    for i in range(n_frames):
        frame = av.VideoFrame.from_ndarray(_test_pattern(i), format="rgb24").reformat(format="yuv420p")
        frame.pts = i
        ys.append(frame.to_ndarray()[:HEIGHT].copy())
        aus.extend(bytes(p) for p in ctx.encode(frame))
    aus.extend(bytes(p) for p in ctx.encode(None))
    return aus, ys


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 99.0 if mse == 0 else 10 * np.log10(255.0**2 / mse)


def _free_port_pair() -> int:
    """An even UDP port p with p and p+1 free on 127.0.0.1 (RTP and RTCP)."""
    for _ in range(50):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            p = s.getsockname()[1] & ~1
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as a, socket.socket(
                socket.AF_INET, socket.SOCK_DGRAM
            ) as b:
                a.bind(("127.0.0.1", p))
                b.bind(("127.0.0.1", p + 1))
            return p
        except OSError:
            continue
    raise RuntimeError("no free UDP port pair")


def _wait_bound(port: int, deadline_s: float, proc: subprocess.Popen | None = None) -> bool:
    """Wait until someone else has bound UDP ``port`` (bind fails); stop early if ``proc`` has exited."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end and (proc is None or proc.poll() is None):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return True
        time.sleep(0.02)
    return False


def _send_aus(codec: str, aus: list[bytes], port: int) -> None:
    packetizer = RtpPacketizer(codec, ssrc=0x1234ABCD, payload_type=96, first_sequence=65500)  # type: ignore[arg-type]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for i, au in enumerate(aus):
            for pkt in packetizer.packetize(au, 1000 + i * TS_STEP):
                tx.sendto(bytes(pkt), ("127.0.0.1", port))
                time.sleep(0.0005)
            time.sleep(0.005)


def _ffmpeg_cli_decode(codec: str, sdp: str, port: int, aus: list[bytes], tmp_path: Path) -> tuple[list[np.ndarray], str]:
    """Y planes the ``ffmpeg`` CLI decodes from ``aus`` sent as RTP to ``port``, described by ``sdp``."""
    sdp_path = tmp_path / "stream.sdp"
    sdp_path.write_text(sdp)
    proc = subprocess.Popen(
        ["ffmpeg", "-hide_banner", "-loglevel", "error", "-threads", "1",
         "-protocol_whitelist", "file,udp,rtp",
         "-i", str(sdp_path), "-frames:v", str(N_FRAMES), "-vsync", "0",
         "-f", "rawvideo", "-pix_fmt", "yuv420p", "pipe:1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )
    try:
        # a loaded CI machine has taken over 10 s to start ffmpeg: wait up to 30 s, and say why if it exited
        if not _wait_bound(port, 30.0, proc):
            rc = proc.poll()
            err = proc.stderr.read().decode(errors="replace")[-500:] if rc is not None and proc.stderr else ""
            raise AssertionError(f"ffmpeg did not open the RTP port {port} (exit code {rc}): {err}")
        time.sleep(0.2)
        _send_aus(codec, aus, port)
        try:
            out, err = proc.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate(timeout=5)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=5)
    frame_size = WIDTH * HEIGHT * 3 // 2
    ys = [np.frombuffer(out, np.uint8, WIDTH * HEIGHT, i * frame_size).reshape(HEIGHT, WIDTH)
          for i in range(len(out) // frame_size)]
    return ys, err.decode(errors="replace")


@pytest.mark.parametrize("codec", ["h264", "hevc"])
def test_ffmpeg_decodes_our_packets(codec: str, tmp_path: Path) -> None:
    aus, ys = encode_clip(codec, N_FRAMES + EXTRA_FRAMES)
    assert len(aus) == N_FRAMES + EXTRA_FRAMES
    port = _free_port_pair()
    got, err = _ffmpeg_cli_decode(codec, make_sdp(codec, port, 96), port, aus, tmp_path)  # type: ignore[arg-type]
    assert len(got) >= N_FRAMES - 1, f"ffmpeg decoded {len(got)} frames: {err[-500:]}"
    for i, y in enumerate(got):
        assert psnr(y, ys[i]) > PSNR_MIN_DB, f"frame {i}"


PARAMETER_SET_TYPES = {"h264": {7, 8}, "hevc": {32, 33, 34}}


def _pipeline_clip(codec: str, n_frames: int) -> tuple[list[bytes], list[np.ndarray], tuple[bytes, ...]]:
    """Access units of our own encoder with the in-band parameter sets removed, source Y planes, and
    the parameter sets it reports (so a decoder can only get them from the SDP)."""
    enc = VideoEncoder(VideoCodecConfig(codec=codec, crf=18, gop=N_FRAMES), WIDTH, HEIGHT)  # type: ignore[arg-type]
    sets = enc.parameter_sets()
    aus, ys = [], []
    for i in range(n_frames):
        img = _test_pattern(i)
        data = enc.encode(img).data
        nals = split_annexb(data)
        if i == 0:
            assert sets and all(n in nals for n in sets)
        keep = [n for n in nals if nal_type(codec, n) not in PARAMETER_SET_TYPES[codec]]  # type: ignore[arg-type]
        aus.append(join_annexb(keep))
        ys.append(rgb_to_yuv(img, 2)[0])
    return aus, ys, sets


def _pyav_decode_sdp(codec: str, sets: tuple[bytes, ...], aus: list[bytes], tmp_path: Path, n: int,
                     to_array: Callable[[av.VideoFrame], np.ndarray]) -> list[np.ndarray]:
    """Our SDP (with ``sets``) and RTP (``aus``) into FFmpeg's SDP demuxer and decoder through PyAV's ``av.open``: the
    first ``n`` decoded frames, each through ``to_array``; the picture size is checked against the SDP's SPS."""
    sdp_path = tmp_path / "stream.sdp"
    got: list[np.ndarray] = []
    for attempt in range(3):
        # FFmpeg's SDP demuxer reports a port it cannot bind as invalid data: on a busy machine another
        # socket can take the free pair between our check and its bind, so a new pair is drawn then
        port = _free_port_pair()
        sdp_path.write_text(make_sdp(codec, port, 96, parameter_sets=sets))  # type: ignore[arg-type]

        def send(port: int = port) -> None:
            if _wait_bound(port, 10.0):
                time.sleep(0.3)
                _send_aus(codec, aus, port)

        sender = threading.Thread(target=send, daemon=True)
        sender.start()
        try:
            container = av.open(str(sdp_path), options={"protocol_whitelist": "file,udp,rtp", "reorder_queue_size": "0"},
                                timeout=10.0)
        except av.error.InvalidDataError:
            sender.join(timeout=15)
            if attempt == 2:
                raise
            continue
        with container:
            stream = container.streams.video[0]
            assert (stream.codec_context.width, stream.codec_context.height) == (WIDTH, HEIGHT)  # from the sprop SPS
            for frame in container.decode(stream):
                got.append(to_array(frame))
                if len(got) == n:
                    break
        break
    sender.join(timeout=10)
    return got


@pytest.mark.parametrize("codec", ["h264", "hevc"])
def test_ffmpeg_cli_decodes_with_the_parameter_sets_of_the_sdp_only(codec: str, tmp_path: Path) -> None:
    """The AVPF / rtcp-mux SDP with sprop sets from our encoder: the ffmpeg CLI decodes a stream
    that carries no parameter sets in-band (so the SDP's must be the right ones)."""
    aus, ys, sets = _pipeline_clip(codec, N_FRAMES + EXTRA_FRAMES)
    port = _free_port_pair()
    sdp = make_sdp(codec, port, 96, parameter_sets=sets)  # type: ignore[arg-type]
    assert "RTP/AVPF" in sdp and "a=rtcp-mux" in sdp and ("sprop-parameter-sets" in parse_fmtp(sdp) or codec == "hevc")
    got, err = _ffmpeg_cli_decode(codec, sdp, port, aus, tmp_path)
    assert len(got) >= N_FRAMES - 1, f"ffmpeg decoded {len(got)} frames: {err[-500:]}"
    for i, y in enumerate(got):
        limited = np.rint(16 + ys[i] * (219 / 255))  # our stream says full range; -pix_fmt yuv420p scales to limited
        assert psnr(y, limited) > PSNR_MIN_DB, f"frame {i}"


@pytest.mark.parametrize("codec", ["h264", "hevc"])
def test_pyav_opens_the_sdp_and_decodes_with_its_parameter_sets(codec: str, tmp_path: Path) -> None:
    """The same through PyAV's own FFmpeg libraries: ``av.open`` on the SDP file."""
    aus, ys, sets = _pipeline_clip(codec, N_FRAMES + EXTRA_FRAMES)
    got = _pyav_decode_sdp(codec, sets, aus, tmp_path, N_FRAMES - 1,
                           lambda frame: frame.to_ndarray(format="yuv420p")[:HEIGHT].copy())
    assert len(got) == N_FRAMES - 1
    for i, y in enumerate(got):
        assert psnr(y, ys[i]) > PSNR_MIN_DB, f"frame {i}"


@pytest.mark.parametrize("codec", ["h264", "hevc"])
def test_we_depacketize_ffmpeg_rtp(codec: str, tmp_path: Path) -> None:
    port = _free_port_pair()
    sdp_path = tmp_path / "ffmpeg.sdp"
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    rx.bind(("127.0.0.1", port))
    rx.settimeout(0.2)
    datagrams: list[bytes] = []
    stop = threading.Event()

    def listen() -> None:
        end = time.monotonic() + 30
        while not stop.is_set() and time.monotonic() < end:
            try:
                datagrams.append(rx.recv(65536))
            except socket.timeout:
                continue

    thread = threading.Thread(target=listen, daemon=True)
    thread.start()
    extra = ["-x265-params", "bframes=0:log-level=error"] if codec == "hevc" else []
    try:
        subprocess.run(
            ["ffmpeg", "-hide_banner", "-loglevel", "error", "-re", "-f", "lavfi",
             "-i", f"testsrc=size={WIDTH}x{HEIGHT}:rate={FPS}", "-frames:v", str(N_FRAMES),
             "-c:v", ENCODERS[codec], "-bf", "0", *extra, "-sdp_file", str(sdp_path),
             "-f", "rtp", f"rtp://127.0.0.1:{port}"],
            check=True, timeout=30, capture_output=True,
        )
        time.sleep(0.3)
    finally:
        stop.set()
        thread.join(timeout=5)
        rx.close()
    assert datagrams
    sdp = sdp_path.read_text()
    jb = JitterBuffer(codec)
    aus = []
    for k, d in enumerate(datagrams):
        aus.extend(jb.insert(RtpPacket.parse(d), now_ms=float(k)))
    assert len(aus) == N_FRAMES and aus[0].keyframe
    assert jb.missing() == [] and jb.frames_lost == 0
    dec = av.CodecContext.create(codec, "r")
    sets = join_annexb(parameter_sets_from_sdp(sdp))
    frames = []
    for i, au in enumerate(aus):
        data = au.data
        if i == 0 and sets and len(split_annexb(data)) == 1:
            data = sets + data  # parameter sets only out of band
        frames.extend(dec.decode(av.Packet(data)))
    frames.extend(dec.decode(None))
    assert len(frames) == N_FRAMES
    assert (frames[0].width, frames[0].height) == (WIDTH, HEIGHT)


@pytest.mark.parametrize("codec", ["h264", "hevc"])
def test_pyav_opens_a_444_sdp_and_decodes_full_chroma(codec: str, tmp_path: Path) -> None:
    """An independent receiver (FFmpeg's SDP/RTP demuxer and decoder through PyAV's ``av.open``) takes our 4:4:4
    SDP and RTP, with the parameter sets only in the SDP: it decodes 4:4:4 pictures of the SDP's size whose Cb
    and Cr planes match the source's full-resolution chroma within 48 dB (measured at crf 18: 57.3-63.6 dB H.264,
    51.8-55.8 dB HEVC), which no 4:2:0 stream could: the source's own 4:2:0 chroma, repeated over each 2x2
    block, is 35.3 dB (Cb) and 44.4 dB (Cr) from it before any coding."""
    n = 10
    enc = VideoEncoder(VideoCodecConfig(codec=codec, pix_fmt="yuv444p", crf=18, gop=30), WIDTH, HEIGHT)  # type: ignore[arg-type]
    sets = enc.parameter_sets()
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    aus, planes = [], []
    # the first n are compared, but a whole clip is sent: ``av.open`` probes the stream before it returns, and with
    # only n + 2 access units it waited out its 10 s timeout for more (measured: every frame out at 10.0 s, with 26
    # H.264 AUs too; with 32, at 0.56 s H.264 and 0.44 s HEVC)
    for i in range(N_FRAMES + EXTRA_FRAMES):
        img = np.empty((HEIGHT, WIDTH, 3), np.uint8)
        img[:] = (140, 178, 230)
        img[((y - 90) ** 2 + (x - 60 - 8 * i) ** 2) < 40 ** 2] = (250, 220, 30)
        nals = split_annexb(enc.encode(img).data)
        aus.append(join_annexb([m for m in nals if nal_type(codec, m) not in PARAMETER_SET_TYPES[codec]]))  # type: ignore[arg-type]
        planes.append(np.stack(rgb_to_yuv(img, 1)))

    def full_chroma(frame: av.VideoFrame) -> np.ndarray:
        assert frame.format.name in ("yuv444p", "yuvj444p")  # FFmpeg's H.264 decoder says j for full range
        return frame.to_ndarray()

    got = _pyav_decode_sdp(codec, sets, aus, tmp_path, n, full_chroma)
    assert len(got) == n
    for i, out in enumerate(got):
        for k, name in ((1, "Cb"), (2, "Cr")):
            err = out[k].astype(np.float64) - planes[i][k]
            db = 10 * np.log10(255.0 ** 2 / max(float(np.mean(err ** 2)), 1e-9))
            assert db > 48.0, f"{codec} frame {i} {name}: {db:.1f} dB"
