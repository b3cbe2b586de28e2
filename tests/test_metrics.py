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


def test_identical_frame_scores_the_60_db_cap():
    a = np.full((16, 16, 3), 77, np.uint8)
    assert metrics.PSNR_CAP_DB == 60.0
    assert metrics.psnr(a, a) == 60.0
    s = metrics.score_frame(a, None, a, np.zeros((16, 16), bool), with_flip=True)
    assert s["psnr_db"] == 60.0 and s["mse"] == 0.0 and s["dssim"] == pytest.approx(0.0)
    # an MSE of 0.05 (below 255^2 / 10^6 = 0.065) also reads 60 dB, not 61
    assert metrics.psnr_from_mse(0.05) == 60.0


def test_run_psnr_from_mean_mse_is_finite_and_differs_from_mean_of_frames():
    a = np.zeros((16, 16, 3), np.uint8)
    b = np.full((16, 16, 3), 10, np.uint8)   # MSE 100: 28.13 dB
    rows = [metrics.score_frame(a, None, a, None, False), metrics.score_frame(b, None, a, None, False)]
    q = metrics.quality_summary(rows)
    assert q["mean_psnr_db"] == pytest.approx((60.0 + 10 * math.log10(255**2 / 100.0)) / 2)   # 44.07 dB
    assert q["psnr_mse_db"] == pytest.approx(10 * math.log10(255**2 / 50.0))                   # 31.14 dB
    assert math.isfinite(q["psnr_mse_db"]) and q["psnr_mse_db"] < q["mean_psnr_db"] - 12
    assert q["flip_frames"] == 0 and math.isnan(q["mean_flip"])


def test_dssim_beside_ssim_and_the_window_is_a_parameter():
    rng = np.random.default_rng(2)
    a = (rng.random((64, 64, 3)) * 255).astype(np.uint8)
    b = np.clip(a.astype(int) + rng.integers(-30, 31, a.shape), 0, 255).astype(np.uint8)
    s15, s2 = metrics.ssim(b, a), metrics.ssim(b, a, sigma=2.0)
    assert s15 == pytest.approx(0.97391, abs=1e-5) and s2 == pytest.approx(0.97458, abs=1e-5)   # measured
    assert metrics.dssim(b, a, 2.0) == pytest.approx((1 - s2) / 2)
    row = metrics.score_frame(b, None, a, None, False, ssim_sigma=2.0)
    assert row["ssim"] == pytest.approx(s2) and row["dssim"] == pytest.approx((1 - s2) / 2)


def test_foreground_covers_geometry_in_either_image():
    sky = (140, 178, 230)
    truth = np.zeros((20, 40, 3), np.uint8)
    truth[:] = sky
    truth[5:10, 5:10] = (200, 50, 50)            # an object in the truth: 25 px
    geo = np.zeros((20, 40), bool)
    geo[5:10, 5:10] = True
    shown = truth.copy()
    shown[5:10, 5:10] = sky                      # the method missed it ...
    shown[12:16, 20:30] = (200, 50, 50)          # ... and draws it elsewhere: 40 px
    shown[0, :] = (141, 177, 231)                # codec noise of 1 on the sky is not geometry
    fg = metrics.foreground_mask(shown, truth, geo)
    assert fg.sum() == 25 + 40
    s = metrics.score_frame(shown, None, truth, geo, with_flip=True)
    assert s["fg_pct"] == pytest.approx(100 * 65 / 800)
    assert s["fg_mse"] == pytest.approx(s["mse"] * 800 / 65, rel=1e-3)   # the 40 noise px add 3 each to the sum
    assert s["fg_psnr_db"] < s["psnr_db"] - 10
    assert s["fg_flip"] > 4 * s["flip"]
    # no foreground anywhere: NaN, left out of the means
    e = metrics.score_frame(truth, None, truth, np.zeros((20, 40), bool), with_flip=True)
    assert math.isnan(e["fg_psnr_db"]) and math.isnan(e["fg_flip"])
    q = metrics.quality_summary([s, e])
    assert q["fg_frames"] == 1 and q["mean_fg_psnr_db"] == pytest.approx(s["fg_psnr_db"])


def test_region_masks_ring_both_sides_of_the_outline_not_the_frame_border():
    m = np.zeros((40, 60), bool)
    m[10:30, 20:40] = True                      # a 20 x 20 model
    m[0:6, 0:8] = True                          # a model cut by the frame's corner
    r = metrics.region_masks(m)
    assert r["model"] is not None and (r["model"] == m).all()
    # the ring about the square: every pixel within 2 px (Chebyshev) of its outline, inside and out
    sq = np.zeros_like(m)
    sq[8:32, 18:42] = True
    sq[12:28, 22:38] = False
    assert (r["edge"][:, 12:] == sq[:, 12:]).all() and r["edge"][:, 12:].sum() == 24 * 24 - 16 * 16
    assert r["interior"][12:28, 22:38].all() and r["interior"][10:30, 20:40].sum() == 16 * 16
    # the corner model: no ring along the frame's border, only along its two inner sides
    assert r["interior"][0:4, 0:6].all() and not r["edge"][0:4, 0:6].any() and r["edge"][0:8, 0:10].sum() == 8 * 10 - 4 * 6
    assert not (r["interior"] & r["edge"]).any() and not (r["interior"] & ~m).any()


def test_region_scores_on_a_frame_with_known_error_per_region():
    """Interior off by 4 code values, the outline ring by 10, the rest exact: each region's MSE is known."""
    truth = np.full((40, 60, 3), 100, np.uint8)
    model = np.zeros((40, 60), bool)
    model[10:30, 20:40] = True
    truth[model] = (180, 60, 40)
    r = metrics.region_masks(model)
    shown = truth.copy()
    shown[r["interior"]] += 4
    shown[r["edge"]] += 10
    s = metrics.score_frame(shown, None, truth, model, with_flip=True, truth_model=model)
    assert s["interior_mse"] == pytest.approx(16.0) and s["edge_mse"] == pytest.approx(100.0)
    n_in, n_ring_in = 16 * 16, 20 * 20 - 16 * 16
    assert s["model_mse"] == pytest.approx((n_in * 16 + n_ring_in * 100) / 400)
    assert s["model_pct"] == pytest.approx(100 * 400 / 2400) and s["edge_pct"] == pytest.approx(100 * 320 / 2400)
    assert s["interior_psnr_db"] == pytest.approx(10 * math.log10(255**2 / 16))
    assert s["mse"] == pytest.approx((n_in * 16 + 320 * 100) / 2400)
    # SSIM and FLIP are means of their maps over each region: the ring, with the larger error, scores worse
    assert s["edge_ssim"] < s["interior_ssim"] < 1.0 and s["edge_dssim"] == pytest.approx((1 - s["edge_ssim"]) / 2)
    assert s["edge_flip"] > s["interior_flip"] > 0
    # no model in view: the regions are empty (0 %, NaN scores) and the summary leaves the frame out
    e = metrics.score_frame(truth, None, truth, model, with_flip=False, truth_model=np.zeros_like(model))
    assert e["model_pct"] == 0 and math.isnan(e["model_psnr_db"]) and math.isnan(e["edge_ssim"])
    q = metrics.quality_summary([s, e])
    assert q["model_frames"] == 1 and q["mean_model_psnr_db"] == pytest.approx(s["model_psnr_db"])
    assert q["edge_psnr_mse_db"] == pytest.approx(10 * math.log10(255**2 / 100))
    # without a model mask there are no region scores at all
    none = metrics.score_frame(shown, None, truth, model, with_flip=False)
    assert all(math.isnan(none[f"{g}_{k}"]) for g in metrics.REGIONS for k in ("pct", "mse", "psnr_db", "ssim"))


def test_scene_model_leaves_out_the_floor_and_the_added_ground(tmp_path):
    import trimesh

    from splitrender.scene.loader import get_scene

    default = get_scene("default+nogi")
    floor = [o.object_id for o in default.objects if o.name == "floor"]
    assert floor and set(default.model_ids()) == {o.object_id for o in default.objects} - set(floor)
    path = tmp_path / "box.obj"
    trimesh.creation.box().export(path)
    plain, grounded = get_scene(str(path)), get_scene(f"{path}+ground")
    assert list(plain.model_ids()) == [1] and list(grounded.model_ids()) == [1] and len(grounded.objects) == 2
    ids = np.array([[0, 1], [2, 1]])
    assert (grounded.model_mask(ids) == np.array([[False, True], [False, True]])).all()
