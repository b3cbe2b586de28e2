"""Metric values on known images."""

from __future__ import annotations

import math

import numpy as np
import pytest

from splitrender import metrics


def test_psnr_known_values():
    a = np.zeros((10, 10, 3), np.uint8)
    b = np.full((10, 10, 3), 10, np.uint8)
    assert metrics.psnr(a, b) == pytest.approx(10 * math.log10(255**2 / 100.0))
    assert metrics.psnr(a, a) == metrics.PSNR_CAP_DB


def test_ssim_bounds_and_ordering():
    rng = np.random.default_rng(0)
    a = (rng.random((64, 64, 3)) * 255).astype(np.uint8)
    assert metrics.ssim(a, a) == pytest.approx(1.0)
    small = np.clip(a.astype(int) + rng.integers(-5, 6, a.shape), 0, 255).astype(np.uint8)
    big = np.clip(a.astype(int) + rng.integers(-60, 61, a.shape), 0, 255).astype(np.uint8)
    assert 1.0 > metrics.ssim(a, small) > metrics.ssim(a, big) > 0.0
    # a constant offset only moves the luminance term: SSIM stays high
    assert metrics.ssim(a, np.clip(a.astype(int) + 3, 0, 255).astype(np.uint8)) > 0.99


def test_flip_zero_for_identical_and_grows_with_error():
    rng = np.random.default_rng(1)
    a = (rng.random((48, 64, 3)) * 255).astype(np.uint8)
    assert metrics.flip(a, a) == pytest.approx(0.0, abs=1e-6)
    b = np.clip(a.astype(int) + 20, 0, 255).astype(np.uint8)
    c = 255 - a
    assert 0 < metrics.flip(b, a) < metrics.flip(c, a) <= 1.0


def test_lab_error_pixels_threshold_20():
    a = np.zeros((4, 4, 3), np.uint8)
    b = a.copy()
    b[0, 0] = (255, 255, 255)   # Lab distance 100: an error pixel
    b[1, 1] = (8, 8, 8)         # Lab distance about 2.2: not one
    assert metrics.lab_error_rate(b, a) == pytest.approx(1 / 16)
    assert metrics.lab_error_mask(b, a)[0, 0] and not metrics.lab_error_mask(b, a)[1, 1]


def test_hole_rate_and_dssim():
    m = np.zeros((10, 10), bool)
    m[:5] = True
    assert metrics.hole_rate(m) == 0.5
    assert metrics.hole_rate(None) == 0.0
    a = np.full((16, 16, 3), 100, np.uint8)
    assert metrics.dssim(a, a) == pytest.approx(0.0)


def test_holes_count_where_the_truth_is_background():
    """Issue 17: a hole is any pixel the client did not draw, sky included; ``hole_geom_pct`` keeps the
    holes over geometry only."""
    truth = np.zeros((16, 16, 3), np.uint8)
    geometry = np.zeros((16, 16), bool)
    geometry[8:] = True          # bottom half geometry, top half sky
    holes = np.zeros((16, 16), bool)
    holes[0] = True              # a black top row over the sky: 16 pixels
    holes[15, :4] = True         # 4 over geometry
    s = metrics.score_frame(truth, holes, truth, geometry, with_flip=False)
    assert s["hole_pct"] == pytest.approx(100 * 20 / 256)
    assert s["hole_geom_pct"] == pytest.approx(100 * 4 / 256)
    none = metrics.score_frame(truth, None, truth, geometry, with_flip=False)
    assert none["hole_pct"] == 0.0 and none["hole_geom_pct"] == 0.0
    assert np.isnan(metrics.score_frame(truth, holes, truth, None, with_flip=False)["hole_geom_pct"])


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="image shapes differ"):
        metrics.psnr(np.zeros((4, 4, 3), np.uint8), np.zeros((4, 5, 3), np.uint8))


def test_ssim_closed_form_on_constant_images():
    # Constant grey images have no variance: SSIM is the luminance term alone,
    # (2 mx my + C1) / (mx^2 + my^2 + C1) with C1 = (K1 * 255)^2.
    a = np.full((32, 32, 3), 100, np.uint8)
    b = np.full((32, 32, 3), 110, np.uint8)
    c1 = (metrics.image.SSIM_K1 * 255) ** 2
    expect = (2 * 100 * 110 + c1) / (100**2 + 110**2 + c1)
    assert metrics.ssim(a, b) == pytest.approx(expect, abs=1e-6)
