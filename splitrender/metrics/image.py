"""Image quality metrics on (H, W, 3) uint8 sRGB images.

- :func:`psnr`: over all three channels, peak 255, in dB, capped at
  :data:`PSNR_CAP_DB` = 60 dB (libvmaf's cap for 8-bit video: an MSE below
  0.065 is "identical"), so identical frames do not drag a mean to infinity.
  :func:`psnr_from_mse` turns a mean MSE into a PSNR (FFmpeg's "average").
- :func:`ssim`: luminance (ITU-R BT.601 luma) SSIM with the constants of Wang et al.
  2004: Gaussian window sigma = 1.5 px by default (``sigma`` argument; the SAS paper
  uses 2), taps out to 3.5 sigma, K1 = 0.01, K2 = 0.03, L = 255, population
  covariance.  :func:`dssim` is ``(1 - SSIM) / 2`` (the SAS and TSS papers).
- :func:`flip`: NVIDIA's LDR-FLIP (flip-evaluator), mean error in [0, 1], lower is
  better, for the default 67 pixels-per-degree viewing condition.
- :func:`lab_error_rate`: share of pixels whose CIE L*a*b* distance (CIE76, D65)
  exceeds 20, the "error pixel" measure of the image-warping paper.
- :func:`hole_rate`: share of pixels a method did not draw from received content.
- :func:`region_masks`: the ``model`` region (pixels the ground truth shows the scene's
  model on: a loaded model, or a built-in scene less its floor), its ``interior`` (model
  pixels more than :data:`REGION_RING_PX` px from the model's outline) and its ``edge``
  (every pixel within that distance of the outline, on either side of it).  Scores over
  a region (:func:`score_frame`) use the same metrics over its pixels only.

This module imports nothing else from splitrender.
"""

from __future__ import annotations

import math
from typing import Any, Iterable

import numpy as np

PSNR_CAP_DB = 60.0
SSIM_SIGMA = 1.5
BACKGROUND_TOLERANCE = 6  # code values: a shown pixel this far from a background truth pixel shows geometry
SSIM_K1 = 0.01
SSIM_K2 = 0.03
LAB_ERROR_THRESHOLD = 20.0
REGION_RING_PX = 2
"""Half-width of the ``edge`` ring about a model's outline (Chebyshev distance, pixels)."""
REGIONS = ("model", "interior", "edge")


def _check(a: np.ndarray, b: np.ndarray) -> None:
    if a.shape != b.shape:
        raise ValueError(f"image shapes differ: {a.shape} vs {b.shape}")
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"expected (H, W, 3) images, got {a.shape}")


def mse(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean squared error over all channels (code values squared); over ``mask`` pixels
    only when given (NaN for an empty mask)."""
    _check(a, b)
    d = (a.astype(np.float64) - b.astype(np.float64)) ** 2
    if mask is not None:
        m = np.asarray(mask, bool)
        return float(d[m].mean()) if m.any() else float("nan")
    return float(d.mean())


def psnr_from_mse(m: float) -> float:
    """PSNR in dB (peak 255) of a mean squared error, capped at :data:`PSNR_CAP_DB`; NaN stays NaN."""
    if math.isnan(m):
        return float("nan")
    if m <= 0:
        return PSNR_CAP_DB
    return float(min(PSNR_CAP_DB, 10.0 * math.log10(255.0**2 / m)))


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB (peak 255), capped at 60 dB."""
    return psnr_from_mse(mse(a, b))


def luma(img: np.ndarray) -> np.ndarray:
    x = img.astype(np.float64)
    return 0.299 * x[..., 0] + 0.587 * x[..., 1] + 0.114 * x[..., 2]


def ssim(a: np.ndarray, b: np.ndarray, sigma: float = SSIM_SIGMA) -> float:
    """Mean SSIM of the luma channel; ``sigma`` is the Gaussian window in pixels (constants in the module docstring)."""
    return ssim_map(a, b, sigma)[0]


def ssim_map(a: np.ndarray, b: np.ndarray, sigma: float = SSIM_SIGMA) -> tuple[float, np.ndarray]:
    """:func:`ssim` and the per-pixel SSIM map (H, W) it averages; the mean leaves out a border as wide as half
    the window (scikit-image's rule), which is NaN in the map returned so masked means leave it out too."""
    from skimage.metrics import structural_similarity

    _check(a, b)
    m, s = structural_similarity(luma(a), luma(b), data_range=255.0, gaussian_weights=True, sigma=sigma,
                                 use_sample_covariance=False, K1=SSIM_K1, K2=SSIM_K2, full=True)
    pad = int(3.5 * sigma + 0.5)  # skimage's window radius for gaussian_weights (truncate = 3.5)
    s = np.array(s, np.float64)
    if pad:
        s[:pad], s[-pad:], s[:, :pad], s[:, -pad:] = np.nan, np.nan, np.nan, np.nan
    return float(m), s


def region_masks(model: np.ndarray, ring_px: int = REGION_RING_PX) -> dict[str, np.ndarray]:
    """The scoring regions of a frame from its ground-truth model mask (H, W) bool: ``model`` itself,
    ``interior`` (model pixels whose every neighbour within ``ring_px`` (Chebyshev) is model too) and ``edge``
    (pixels with both model and non-model pixels within ``ring_px``: the outline's ring, both sides of it).
    The frame's border is not an outline: a model running off screen has no edge there."""
    from scipy.ndimage import binary_dilation, binary_erosion

    m = np.asarray(model, bool)
    k = np.ones((2 * ring_px + 1, 2 * ring_px + 1), bool)
    inner = binary_erosion(m, k, border_value=1)
    outer = binary_dilation(m, k, border_value=0)
    return {"model": m, "interior": inner, "edge": outer & ~inner}


def flip_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-pixel LDR-FLIP error (H, W) in [0, 1] between ``a`` (test) and ``b`` (reference)."""
    import flip_evaluator

    _check(a, b)
    ref = b.astype(np.float32) / 255.0
    test = a.astype(np.float32) / 255.0
    err, _, _ = flip_evaluator.evaluate(ref, test, "LDR", applyMagma=False)
    return np.asarray(err, np.float64).reshape(a.shape[:2])


def flip(a: np.ndarray, b: np.ndarray) -> float:
    """Mean LDR-FLIP error between ``a`` (test) and ``b`` (reference), in [0, 1]."""
    return float(flip_map(a, b).mean())


def srgb_to_lab(img: np.ndarray) -> np.ndarray:
    from skimage.color import rgb2lab

    return rgb2lab(img.astype(np.float64) / 255.0)


def lab_error_mask(a: np.ndarray, b: np.ndarray, threshold: float = LAB_ERROR_THRESHOLD) -> np.ndarray:
    """Pixels whose CIE76 Lab distance exceeds ``threshold``."""
    _check(a, b)
    d = np.linalg.norm(srgb_to_lab(a) - srgb_to_lab(b), axis=-1)
    return d > threshold


def lab_error_rate(a: np.ndarray, b: np.ndarray, threshold: float = LAB_ERROR_THRESHOLD) -> float:
    """Share (0..1) of error pixels: Lab distance above ``threshold`` (20 in the warping paper)."""
    return float(lab_error_mask(a, b, threshold).mean())


def hole_rate(mask: np.ndarray | None) -> float:
    """Share (0..1) of hole pixels; 0 when the method reports no mask."""
    if mask is None:
        return 0.0
    return float(np.asarray(mask, bool).mean())


def dssim(a: np.ndarray, b: np.ndarray, sigma: float = SSIM_SIGMA) -> float:
    """Structural dissimilarity ``(1 - SSIM) / 2`` as in the SAS and TSS papers."""
    return (1.0 - ssim(a, b, sigma)) / 2.0


def foreground_mask(shown: np.ndarray, truth: np.ndarray, truth_geometry: np.ndarray,
                    shown_geometry: np.ndarray | None = None) -> np.ndarray:
    """Pixels covered by geometry in either image (H, W) bool.

    ``truth_geometry`` comes from the ground truth's object ids.  Where the method does
    not report its own coverage (``shown_geometry`` is None), a shown pixel counts as
    geometry when the truth there is background and the shown colour is more than
    :data:`BACKGROUND_TOLERANCE` code values away from it in some channel: the
    background is one flat sky colour, so anything else drawn there (a stale object,
    a hole fill, codec ringing) is something the viewer sees in place of the sky.
    """
    _check(shown, truth)
    tg = np.asarray(truth_geometry, bool)
    if shown_geometry is not None:
        return tg | np.asarray(shown_geometry, bool)
    diff = np.abs(shown.astype(np.int16) - truth.astype(np.int16)).max(axis=-1) > BACKGROUND_TOLERANCE
    return tg | diff


def score_frame(shown: np.ndarray, holes: np.ndarray | None, truth: np.ndarray, truth_geometry: np.ndarray | None,
                with_flip: bool, ssim_sigma: float = SSIM_SIGMA, shown_geometry: np.ndarray | None = None,
                truth_model: np.ndarray | None = None) -> dict[str, float]:
    """Every per-frame quality number of one displayed image against its ground truth.

    ``holes`` (bool, H x W) marks the pixels the client did not draw from received content;
    ``hole_pct`` counts them wherever they lie, sky included (a black border over the sky is
    as much a hole as one over a wall).  ``truth_geometry`` (bool, H x W) marks pixels where
    the ground truth shows geometry; ``hole_geom_pct`` counts only the holes there (NaN
    without it).  Returns ``mse``, ``psnr_db`` (capped at 60 dB), ``ssim``, ``dssim``,
    ``flip`` (NaN unless ``with_flip``), ``lab_err_pct``, ``hole_pct``, ``hole_geom_pct``
    and the foreground scores over :func:`foreground_mask`: ``fg_pct`` (its share of the
    frame), ``fg_mse``, ``fg_psnr_db`` and ``fg_flip`` (NaN on a frame without foreground).

    ``truth_model`` (bool, H x W: where the ground truth shows the scene's model) adds, for each
    region of :func:`region_masks` (``model``, ``interior``, ``edge``), ``<region>_pct`` (its share of
    the frame), ``<region>_mse``, ``<region>_psnr_db``, ``<region>_ssim`` (the mean of the SSIM map over
    the region), ``<region>_dssim`` and ``<region>_flip`` (NaN unless ``with_flip``): NaN for a region
    the frame does not have, and all NaN without ``truth_model``.
    """
    geom_pct = float("nan")
    if truth_geometry is not None:
        geom_pct = 0.0 if holes is None else 100.0 * hole_rate(np.asarray(holes, bool) & np.asarray(truth_geometry, bool))
    fg = None
    if truth_geometry is not None:
        fg = foreground_mask(shown, truth, truth_geometry, shown_geometry)
    m = mse(shown, truth)
    s, smap = ssim_map(shown, truth, ssim_sigma)
    fmap = flip_map(shown, truth) if with_flip else None
    fg_mse = mse(shown, truth, fg) if fg is not None else float("nan")
    has_fg = fg is not None and bool(fg.any())
    return {**_region_scores(shown, truth, truth_model, smap, fmap),
        "mse": m,
        "psnr_db": psnr_from_mse(m),
        "ssim": s,
        "dssim": (1.0 - s) / 2.0,
        "flip": float(fmap.mean()) if fmap is not None else float("nan"),
        "lab_err_pct": 100.0 * lab_error_rate(shown, truth),
        "hole_pct": 100.0 * hole_rate(holes),
        "hole_geom_pct": geom_pct,
        "fg_pct": 100.0 * float(fg.mean()) if fg is not None else float("nan"),
        "fg_mse": fg_mse,
        "fg_psnr_db": psnr_from_mse(fg_mse),
        "fg_flip": float(fmap[fg].mean()) if fmap is not None and has_fg else float("nan"),
    }


def _region_scores(shown: np.ndarray, truth: np.ndarray, truth_model: np.ndarray | None, smap: np.ndarray,
                   fmap: np.ndarray | None) -> dict[str, float]:
    nan = float("nan")
    out: dict[str, float] = {}
    masks = region_masks(truth_model) if truth_model is not None else {}
    for r in REGIONS:
        mask = masks.get(r)
        if mask is None or not mask.any():
            out.update({f"{r}_pct": 0.0 if mask is not None else nan, f"{r}_mse": nan, f"{r}_psnr_db": nan,
                        f"{r}_ssim": nan, f"{r}_dssim": nan, f"{r}_flip": nan})
            continue
        e = mse(shown, truth, mask)
        sv = smap[mask]
        sv = sv[~np.isnan(sv)]
        sm = float(sv.mean()) if sv.size else nan
        out.update({f"{r}_pct": 100.0 * float(mask.mean()), f"{r}_mse": e, f"{r}_psnr_db": psnr_from_mse(e),
                    f"{r}_ssim": sm, f"{r}_dssim": (1.0 - sm) / 2.0, f"{r}_flip": float(fmap[mask].mean()) if fmap is not None else nan})
    return out


def finite_column(rows: Iterable[dict[str, Any]], key: str) -> np.ndarray:
    """``key`` over the rows that have a number there (NaN and absent cells left out)."""
    a = np.array([float(r.get(key, math.nan)) for r in rows], dtype=np.float64)
    return a[~np.isnan(a)]


def mean_of(rows: Iterable[dict[str, Any]], key: str) -> float:
    """The mean of ``key`` over the rows that have a number there (NaN if none)."""
    a = finite_column(rows, key)
    return float(a.mean()) if a.size else math.nan


def pct_of(rows: Iterable[dict[str, Any]], key: str, q: float) -> float:
    """The ``q``-th percentile of ``key`` over the rows that have a number there (NaN if none)."""
    a = finite_column(rows, key)
    return float(np.percentile(a, q)) if a.size else math.nan


def quality_summary(rows: list[dict[str, Any]]) -> dict[str, float | int]:
    """The run's quality aggregates from per-frame rows of :func:`score_frame` (NaN cells skipped).

    ``mean_psnr_db``: mean of the capped per-frame PSNRs; ``psnr_mse_db``: PSNR of the
    mean MSE (FFmpeg's "average", finite as soon as one frame differs); ``p5_psnr_db``;
    ``mean_ssim`` and ``mean_dssim``; ``mean_flip`` over the ``flip_frames`` scored;
    ``mean_lab_err_pct``, ``mean_hole_pct``; foreground: ``mean_fg_psnr_db`` (mean of
    capped per-frame foreground PSNRs), ``fg_psnr_mse_db`` (from the mean foreground
    MSE), ``mean_fg_flip``, ``mean_fg_pct`` and ``fg_frames`` (frames with foreground); per region of
    :func:`region_masks`, e.g. ``model``: ``mean_model_psnr_db``, ``model_psnr_mse_db``, ``mean_model_ssim``,
    ``mean_model_dssim``, ``mean_model_flip``, ``mean_model_pct`` and ``model_frames`` (frames showing it).
    """
    def col(k: str) -> np.ndarray:
        return finite_column(rows, k)

    def mean(k: str) -> float:
        return mean_of(rows, k)

    p = col("psnr_db")
    return {
        "mean_psnr_db": mean("psnr_db"), "psnr_mse_db": psnr_from_mse(mean("mse")),
        "p5_psnr_db": float(np.percentile(p, 5)) if p.size else math.nan,
        "mean_ssim": mean("ssim"), "mean_dssim": mean("dssim"),
        "mean_flip": mean("flip"), "flip_frames": int(col("flip").size),
        "mean_lab_err_pct": mean("lab_err_pct"), "mean_hole_pct": mean("hole_pct"),
        "mean_hole_geom_pct": mean("hole_geom_pct"),
        "mean_fg_psnr_db": mean("fg_psnr_db"), "fg_psnr_mse_db": psnr_from_mse(mean("fg_mse")),
        "mean_fg_flip": mean("fg_flip"), "mean_fg_pct": mean("fg_pct"), "fg_frames": int(col("fg_psnr_db").size),
        **{k: v for r in REGIONS for k, v in (
            (f"mean_{r}_psnr_db", mean(f"{r}_psnr_db")), (f"{r}_psnr_mse_db", psnr_from_mse(mean(f"{r}_mse"))),
            (f"mean_{r}_ssim", mean(f"{r}_ssim")), (f"mean_{r}_dssim", mean(f"{r}_dssim")),
            (f"mean_{r}_flip", mean(f"{r}_flip")), (f"mean_{r}_pct", mean(f"{r}_pct")),
            (f"{r}_frames", int(col(f"{r}_psnr_db").size)))},
    }


CONTENT_SUFFIX = "_content"
"""Suffix of the aggregates over frames with content (:func:`content_quality_summary`)."""


def has_content(row: dict[str, Any]) -> bool:
    """Whether a per-frame row is a displayed frame *with content*: one that shows an update (``update_frame_id`` >= 0).

    The display ticks before it (``update_frame_id`` -1: no update applied yet, or only updates whose content was
    lost) show the black start-up background; once an update with content is shown, every later tick has content.
    A row without the column (a table from elsewhere) counts as content."""
    v = row.get("update_frame_id", 0)
    try:
        return not float(v) < 0
    except (TypeError, ValueError):
        return True


def content_quality_summary(rows: list[dict[str, Any]]) -> dict[str, float | int]:
    """:func:`quality_summary` over the frames with content only (:func:`has_content`), every key with
    :data:`CONTENT_SUFFIX` (``mean_model_psnr_db_content``, ``mean_flip_content``, ...), and ``content_frames``.

    The start-up ticks are black: in a short run a few of them can outweigh every other frame's error (a FLIP of 0.06
    over all frames against 0.0002 over the frames with content), so the two aggregates are reported side by side."""
    shown = [r for r in rows if has_content(r)]
    out: dict[str, float | int] = {f"{k}{CONTENT_SUFFIX}": v for k, v in quality_summary(shown).items()}
    out["content_frames"] = len(shown)
    return out
