"""PyAV H.264/HEVC round trips, forced IDRs, lossless modes and errors."""

from __future__ import annotations

import numpy as np
import pytest

from splitrender.codecs.video import VideoCodecConfig, VideoDecoder, VideoEncoder, contains_idr, iter_nal_units
from splitrender.errors import CodecError, ConfigError
from splitrender.metrics import psnr


def _frames(n: int, w: int = 320, h: int = 180) -> list[np.ndarray]:
    y, x = np.mgrid[0:h, 0:w]
    out = []
    for i in range(n):
        r = (128 + 100 * np.sin((x + 4 * i) / 13.0)).astype(np.uint8)
        g = (128 + 100 * np.cos((y - 2 * i) / 9.0)).astype(np.uint8)
        b = ((x + y + 3 * i) % 256).astype(np.uint8)
        out.append(np.stack([r, g, b], -1))
    return out


@pytest.mark.parametrize("codec", ["h264", "hevc"])
def test_round_trip_quality_and_gop(codec):
    frames = _frames(12)
    enc = VideoEncoder(VideoCodecConfig(codec=codec, crf=20, gop=5), 320, 180)
    dec = VideoDecoder(codec)
    keys = []
    for i, f in enumerate(frames):
        ef = enc.encode(f, force_idr=(i == 7))
        keys.append(ef.keyframe)
        out = dec.decode(ef.data)
        q = psnr(out, f)
        assert q > 32.0, f"{codec} frame {i}: PSNR {q:.1f} dB <= 32 dB at CRF 20"
    # IDR at 0, after a GOP of 5, where forced (7); the forced IDR restarts the GOP (next one would be 12)
    assert [i for i, k in enumerate(keys) if k] == [0, 5, 7], keys


@pytest.mark.parametrize("codec", ["h264", "hevc"])
def test_bitrate_mode_tracks_target(codec):
    frames = _frames(30)
    target = 800.0
    enc = VideoEncoder(VideoCodecConfig(codec=codec, bitrate_kbps=target, crf=None, gop=30, fps=30), 320, 180)
    total = sum(enc.encode(f).nbytes for f in frames)
    kbps = total * 8 / 1.0 / 1000
    assert 0.3 * target < kbps < 2.0 * target, f"{codec}: {kbps:.0f} kbit/s for a {target:.0f} kbit/s target"


def test_lossless_hevc_gbrp_is_bit_exact():
    f = (np.random.default_rng(1).random((64, 96, 3)) * 255).astype(np.uint8)
    enc = VideoEncoder(VideoCodecConfig(codec="hevc", lossless=True, crf=None, pix_fmt="gbrp"), 96, 64)
    out = VideoDecoder("hevc").decode(enc.encode(f).data)
    assert np.array_equal(out, f)


def test_annexb_helpers():
    enc = VideoEncoder(VideoCodecConfig(codec="h264"), 64, 64)
    ef = enc.encode(np.zeros((64, 64, 3), np.uint8))
    types = [n[0] & 0x1F for n in iter_nal_units(ef.data)]
    assert 7 in types and 8 in types and 5 in types  # SPS, PPS, IDR
    assert contains_idr(ef.data, "h264")


def test_errors_name_what_was_wrong():
    with pytest.raises(ConfigError, match="codec: 'vp9'"):
        VideoCodecConfig(codec="vp9")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="gop: must be >= 1"):
        VideoCodecConfig(gop=0)
    with pytest.raises(ConfigError, match="must be positive and even"):
        VideoEncoder(VideoCodecConfig(), 65, 64)
    enc = VideoEncoder(VideoCodecConfig(), 64, 64)
    with pytest.raises(CodecError, match="got a plane of shape"):
        enc.encode(np.zeros((32, 32, 3), np.uint8))
    dec = VideoDecoder("h264")
    with pytest.raises(CodecError):
        dec.decode(b"\x00\x00\x01\x65garbage-not-a-slice" * 3)
