"""HEVC streams name a real level (issue 37, conformance): RFC 7798 ``level-id`` is general_level_idc,
30 x the level of H.265 Table A.8, and was 255 for the lossless depth stream because x265 writes
level 8.5 ("no limits") in lossless mode and refuses ``level-idc`` there (constant QP).  The encoder now
writes the lowest level whose picture size and sample rate limits fit into its VPS and SPS, in-band and
in the SDP's sprop sets alike; lossy streams keep x265's own choice, which is already a real level."""

from __future__ import annotations

import base64
from fractions import Fraction

import numpy as np
import pytest

from splitrender.codecs.video import VideoCodecConfig, VideoDecoder, VideoEncoder
from splitrender.methods import StreamSpec, Update
from splitrender.pipeline import ServerPipeline, StreamEncoder
from splitrender.protocol import JitterBuffer, RtpPacket, make_sdp, nal_type, parse_fmtp, parse_hevc_sps, split_annexb
from splitrender.protocol.sps import (HEVC_LEVELS, hevc_level_idc, hevc_level_of, is_hevc_level, nal_to_rbsp, rbsp_to_nal,
                                      set_hevc_level)
from splitrender.scene.pose import Pose

VPS, SPS, PPS = 32, 33, 34


def _depth(width: int, height: int, fps: int = 30) -> VideoCodecConfig:
    """The warp method's depth stream: lossless HEVC 4:0:0, 8-bit (its two byte planes stacked)."""
    return VideoCodecConfig(codec="hevc", pix_fmt="gray", input_format="gray", lossless=True, crf=None, fps=fps)


# --------------------------------------------------------------------------- the level table


@pytest.mark.parametrize(("width", "height", "fps", "level_id"), [
    (320, 180, 30, 60),       # 320x184 coded = 58880 <= 122880 samples, 1.77 M/s <= 3.69 M/s: level 2
    (320, 360, 30, 60),       # the warp depth picture of a 320x180 view (two planes stacked)
    (640, 360, 30, 63),       # 230400 <= 245760, 6.9 M/s <= 7.37 M/s: 2.1
    (640, 360, 60, 90),       # 13.8 M/s: 3
    (1280, 720, 30, 93),      # 3.1
    (1280, 720, 60, 120),     # 55.3 M/s > 33.2 M/s (3.1): 4
    (1920, 1080, 30, 120),    # 4
    (1920, 1080, 60, 123),    # 125 M/s: 4.1
    (3840, 2160, 60, 153),    # 5.1
    (3840, 2160, 120, 156),   # 5.2
    (7680, 4320, 60, 183),    # 6.1
    (8192, 4320, 120, 186),   # 6.2
    (8192, 4320, 300, 255),   # beyond 6.2: only level 8.5 fits
    (16, 16, 30, 30),         # 1
    (1024, 8, 1, 63),         # 8192 samples fit level 1, but a width over sqrt(8 MaxLumaPs) needs 2.1
])
def test_lowest_level_whose_picture_size_and_sample_rate_limits_fit(width: int, height: int, fps: int,
                                                                    level_id: int) -> None:
    assert hevc_level_idc(width, height, fps) == level_id


def test_level_table_is_increasing_and_every_entry_is_a_level() -> None:
    idcs = [idc for idc, _, _ in HEVC_LEVELS]
    assert idcs == [30, 60, 63, 90, 93, 120, 123, 150, 153, 156, 180, 183, 186]
    assert all(a[1] <= b[1] and a[2] <= b[2] for a, b in zip(HEVC_LEVELS, HEVC_LEVELS[1:]))
    assert all(is_hevc_level(i) for i in idcs) and not any(is_hevc_level(i) for i in (0, 255, 31, 61, 93 + 1))
    # exactly at a level's limits still fits it; one sample more does not
    assert hevc_level_idc(384, 320, 30) == 60 and hevc_level_idc(384, 328, 30) == 63   # MaxLumaPs 122880
    with pytest.raises(ValueError):
        hevc_level_idc(0, 180, 30)


# --------------------------------------------------------------------------- encoders, SPS and SDP


def _encode_idr(enc: VideoEncoder, shape: tuple[int, ...]) -> tuple[np.ndarray, bytes]:
    plane = (np.random.default_rng(5).random(shape) * 255).astype(np.uint8)
    f = enc.encode(plane, force_idr=True)
    assert f.keyframe
    return plane, f.data


@pytest.mark.parametrize(("cfg", "width", "height", "level_id"), [
    (_depth(320, 180), 320, 180, 60),
    (_depth(320, 360), 320, 360, 60),
    (VideoCodecConfig(codec="hevc"), 320, 180, 60),
    (VideoCodecConfig(codec="hevc", lossless=True, pix_fmt="yuv444p"), 320, 180, 60),
    (_depth(1280, 720, fps=60), 1280, 720, 120),
], ids=["lossless-depth-320x180", "lossless-warp-depth-320x360", "lossy-320x180", "lossless444-320x180",
        "lossless-depth-720p60"])
def test_sps_in_band_sprop_and_sdp_name_the_same_real_level(cfg: VideoCodecConfig, width: int, height: int,
                                                             level_id: int) -> None:
    enc = VideoEncoder(cfg, width, height)
    sets = enc.parameter_sets()
    shape = (height, width) if cfg.input_format == "gray" else (height, width, 3)
    plane, data = _encode_idr(enc, shape)
    inband = {nal_type("hevc", n): n for n in split_annexb(data) if nal_type("hevc", n) in (VPS, SPS, PPS)}
    assert tuple(inband[t] for t in (VPS, SPS, PPS)) == sets  # the sets repeated before the IDR are those described
    sps = parse_hevc_sps(inband[SPS])
    assert sps.level_idc == level_id == hevc_level_of(inband[VPS])
    assert sps.level_idc == hevc_level_idc(sps.width, sps.height, float(sps.frame_rate or 0))
    assert sps.frame_rate == Fraction(cfg.fps) and (sps.width, sps.height) == (width, height)
    fmtp = parse_fmtp(make_sdp("hevc", 5004, 96, parameter_sets=sets))
    assert int(fmtp["level-id"]) == level_id and int(fmtp["tier-flag"]) == sps.tier_flag == 0
    assert base64.b64decode(fmtp["sprop-sps"]) == inband[SPS]
    if cfg.lossless and cfg.input_format == "gray":  # the rewritten sets decode, bit-exactly
        assert np.array_equal(VideoDecoder("hevc", "gray").decode(data), plane)


def test_lossy_streams_keep_x265s_level_which_also_counts_the_bit_rate() -> None:
    """2 Mbit/s at 320x180 is over level 2's MaxBR (1.5 Mbit/s): x265 says 2.1, more than size and rate
    alone need, and that is what the SDP says (``level-idc`` is not forced on lossy streams)."""
    enc = VideoEncoder(VideoCodecConfig(codec="hevc", bitrate_kbps=2000.0), 320, 180)
    sets = enc.parameter_sets()
    sps = parse_hevc_sps(next(n for n in sets if nal_type("hevc", n) == SPS))
    assert sps.level_idc == 63 > hevc_level_idc(320, 180, 30)
    assert int(parse_fmtp(make_sdp("hevc", 5004, 96, parameter_sets=sets))["level-id"]) == 63


def test_the_warp_depth_streams_welcome_sdp_and_rtp_stream_agree_on_the_level() -> None:
    """Through the pipeline: the Welcome SDP's level-id, the sprop SPS and the SPS received in the RTP packets."""
    tx = ServerPipeline([StreamSpec("depth", _depth(320, 360), 320, 360)], rng=np.random.default_rng(4))
    encoder = StreamEncoder(tx.specs)
    encoder.open()
    tx.described_sets.update(encoder.described_sets())
    (desc,) = tx.describe("127.0.0.1", 5004, "t")
    plane = (np.random.default_rng(6).random((360, 320)) * 255).astype(np.uint8)
    enc = encoder.encode(Update(0, 0.0, Pose(), {"depth": plane}, {}), force_idr=True)
    out = tx.packetize(enc, lambda m: b"", 0, 0, 0, 0, 0.0, {}, {})
    jb = JitterBuffer("hevc")
    aus = []
    for _, _, data in out.datagrams:  # all at once: 134 packets, more than the frame timeout at 1 ms each
        aus += jb.insert(RtpPacket.parse(data), now_ms=0.0)
    assert len(aus) == 1 and aus[0].keyframe
    received = next(n for n in split_annexb(aus[0].data) if nal_type("hevc", n) == SPS)
    fmtp = parse_fmtp(desc.sdp)
    assert fmtp["level-id"] == "60" and base64.b64decode(fmtp["sprop-sps"]) == received
    assert parse_hevc_sps(received).level_idc == 60


# --------------------------------------------------------------------------- rewriting and the SDP fallback


def test_set_level_changes_one_byte_and_redoes_emulation_prevention() -> None:
    sets = VideoEncoder(_depth(320, 180), 320, 180).parameter_sets()
    for nal in sets[:2]:  # VPS, SPS
        assert rbsp_to_nal(nal_to_rbsp(nal[2:])) == nal[2:]
        zero = set_hevc_level(nal, 0)  # after the zero constraint bytes: 00 00 00 needs an emulation byte
        assert hevc_level_of(zero) == 0 and b"\x00\x00\x03\x00" in zero and len(zero) == len(nal) + 1
        assert set_hevc_level(zero, hevc_level_of(nal)) == nal
        before, after = nal_to_rbsp(nal[2:]), nal_to_rbsp(set_hevc_level(nal, 93)[2:])
        assert [i for i, (a, b) in enumerate(zip(before, after)) if a != b] == [15 if nal_type("hevc", nal) == VPS else 12]
    assert rbsp_to_nal(b"\x00\x00\x00\x00\x01\x00\x00") == b"\x00\x00\x03\x00\x00\x03\x01\x00\x00\x03"


def test_sdp_gives_a_real_level_for_a_foreign_sps_that_names_none() -> None:
    """An SPS saying 255 (as x265's own lossless output does): the SDP's level-id is the level its size and VUI
    frame rate need; the sprop SPS stays as given."""
    sets = VideoEncoder(_depth(1280, 720, fps=60), 1280, 720).parameter_sets()
    foreign = [set_hevc_level(n, 255) if nal_type("hevc", n) in (VPS, SPS) else n for n in sets]
    assert parse_hevc_sps(foreign[1]).level_idc == 255
    fmtp = parse_fmtp(make_sdp("hevc", 5004, 96, parameter_sets=foreign))
    assert fmtp["level-id"] == "120" and base64.b64decode(fmtp["sprop-sps"]) == foreign[1]
