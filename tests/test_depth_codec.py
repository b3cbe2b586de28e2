"""Depth coding for ``warp``: 16-bit inverse-depth codes, lossless HEVC planes, BC4-like blocks."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.codecs.depth import (CODE_MAX, bc4_decode, bc4_encode, dequantize_depth, pack_depth_planes, quantize_depth,
                                      unpack_depth_planes)
from splitrender.codecs.video import VideoCodecConfig, VideoDecoder, VideoEncoder
from splitrender.errors import CodecError


def scene_like_depth(h: int = 90, w: int = 160, seed: int = 0) -> np.ndarray:
    """A floor ramp, a box in front and sky: smooth areas, edges, background."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    d = 1.6 * 156 / np.maximum(yy - h / 2 + 0.5, 0.5)
    d[: h // 2] = np.inf
    d[20:60, 40:90] = 3.0 + 0.01 * xx[20:60, 40:90]
    d += rng.normal(0, 1e-3, d.shape).astype(np.float32)
    return d


def test_quantize_roundtrip_relative_error() -> None:
    d = scene_like_depth()
    codes = quantize_depth(d, 0.1)
    back = dequantize_depth(codes, 0.1)
    fin = np.isfinite(d)
    assert (codes[~fin] == 0).all() and (codes[fin] >= 1).all()
    assert np.isinf(back[~fin]).all()
    rel = np.abs(back[fin] / d[fin] - 1)
    bound = 0.5 / codes[fin] + 1e-6
    assert (rel <= bound).all(), f"relative error {rel.max():.2e} exceeds 0.5/code"


def test_pack_unpack_planes_exact() -> None:
    codes = np.arange(0, 65536, dtype=np.uint32).astype(np.uint16).reshape(256, 256)
    planes = pack_depth_planes(codes)
    assert planes.shape == (512, 256) and planes.dtype == np.uint8
    assert np.array_equal(unpack_depth_planes(planes), codes)
    # folding keeps a smooth ramp continuous across byte wraps
    ramp = np.arange(200, 800, dtype=np.uint16)[None, :].repeat(2, 0)
    lo = pack_depth_planes(ramp)[2:]
    assert np.abs(np.diff(lo.astype(int), axis=1)).max() == 1


def test_lossless_hevc_depth_roundtrip_bit_exact() -> None:
    """Three frames of 16-bit codes through lossless HEVC 4:0:0 come back bit-exactly."""
    cfg = VideoCodecConfig(codec="hevc", pix_fmt="gray", input_format="gray", lossless=True, crf=None, gop=30)
    enc = VideoEncoder(cfg, 160, 180)
    dec = VideoDecoder("hevc", "gray")
    for k in range(3):
        codes = quantize_depth(scene_like_depth(seed=k) * (1 + 0.05 * k), 0.1)
        codes[0, :4] = (0, 1, CODE_MAX - 1, CODE_MAX)
        out = unpack_depth_planes(dec.decode(enc.encode(pack_depth_planes(codes)).data))
        assert np.array_equal(out, codes), f"frame {k}: {int((out != codes).sum())} codes differ"


def test_bc4_error_bound_and_background() -> None:
    codes = quantize_depth(scene_like_depth(91, 157), 0.1)
    data = bc4_encode(codes)
    back = bc4_decode(data)
    assert back.shape == codes.shape
    assert np.array_equal(back == 0, codes == 0), "background must survive exactly"
    # per block, error <= span / 14 + 1
    err = np.abs(back.astype(int) - codes.astype(int))
    h, w = codes.shape
    for by in range(0, h, 8):
        for bx in range(0, w, 8):
            blk = codes[by:by + 8, bx:bx + 8]
            fg = blk[blk > 0].astype(int)
            if fg.size:
                span = fg.max() - fg.min()
                assert err[by:by + 8, bx:bx + 8].max() <= span / 12 + 1
    assert len(data) < codes.nbytes / 3, f"bc4 is {len(data)} bytes for {codes.nbytes} raw"


def test_bc4_constant_block_with_background() -> None:
    codes = np.zeros((8, 8), np.uint16)
    codes[:4] = 1234
    assert np.array_equal(bc4_decode(bc4_encode(codes)), codes)
    codes[:4] = CODE_MAX
    assert np.array_equal(bc4_decode(bc4_encode(codes)), codes)


@pytest.mark.parametrize("bad, msg", [
    (b"", "shorter than"),
    (b"XXXX" + bytes(8), "bad magic"),
    (b"BC4D\x09\x00" + bytes(6), "unsupported version"),
    (b"BC4D\x01\x00\x08\x00\x08\x00\x08\x00" + b"garbage", "zstd"),
])
def test_bc4_decode_rejects_malformed(bad: bytes, msg: str) -> None:
    with pytest.raises(CodecError, match=msg):
        bc4_decode(bad)


def test_bc4_decode_refuses_an_unexpected_size_before_decompressing() -> None:
    """A header claiming 65535x65535 (a 3.8 GB body) is refused from the header alone when the
    caller knows the size; the right size decodes."""
    codes = np.full((16, 24), 1000, np.uint16)
    data = bc4_encode(codes)
    assert np.array_equal(bc4_decode(data, expect_shape=(16, 24)), codes)
    with pytest.raises(CodecError, match=r"^bc4: size 24x16 does not match the expected 24x8$"):
        bc4_decode(data, expect_shape=(8, 24))
    huge = b"BC4D\x01\x00\x08\x00\xff\xff\xff\xff" + data[12:]
    with pytest.raises(CodecError, match=r"^bc4: size 65535x65535 does not match the expected 24x16$"):
        bc4_decode(huge, expect_shape=(16, 24))


def test_bad_shapes_raise() -> None:
    with pytest.raises(CodecError, match="2-D"):
        quantize_depth(np.ones((2, 2, 2)), 0.1)
    with pytest.raises(CodecError, match="near_m"):
        quantize_depth(np.ones((2, 2)), 0.0)
    with pytest.raises(CodecError, match=r"\(2H, W\)"):
        unpack_depth_planes(np.zeros((3, 4), np.uint8))
    with pytest.raises(CodecError, match="uint16"):
        pack_depth_planes(np.zeros((3, 4), np.float32))


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=200))
def test_bc4_fuzz_only_codec_errors(data: bytes) -> None:
    try:
        bc4_decode(b"BC4D\x01\x00\x08\x00" + data)
    except CodecError:
        pass


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 40), st.integers(1, 40), st.integers(0, 2**32 - 1))
def test_bc4_random_sizes(h: int, w: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    codes = rng.integers(0, CODE_MAX + 1, (h, w)).astype(np.uint16)
    back = bc4_decode(bc4_encode(codes))
    assert back.shape == (h, w)
    assert np.array_equal(back == 0, codes == 0)
