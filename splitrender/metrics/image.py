"""Image quality metrics on (H, W, 3) uint8 sRGB images.

- :func:`psnr`: over all three channels, peak 255, in dB; identical images give
  :data:`PSNR_CAP_DB` (100 dB) rather than infinity so means stay finite.
- :func:`ssim`: luminance (ITU-R BT.601 luma) SSIM with the constants of Wang et al.
  2004: Gaussian window sigma = 1.5 px (11 x 11 taps, truncate 3.5), K1 = 0.01,
  K2 = 0.03, L = 255, population covariance.  That is the MSSIM the SAS and TSS
  papers report (``DSSIM = (1 - SSIM) / 2``).
- :func:`flip`: NVIDIA's LDR-FLIP (flip-evaluator), mean error in [0, 1], lower is
  better, for the default 67 pixels-per-degree viewing condition.
- :func:`lab_error_rate`: share of pixels whose CIE L*a*b* distance (CIE76, D65)
  exceeds 20, the "error pixel" measure of the image-warping paper.
- :func:`hole_rate`: share of pixels a method did not draw from received content.

This module imports nothing else from splitrender.
"""

from __future__ import annotations

import numpy as np

PSNR_CAP_DB = 100.0
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
LAB_ERROR_THRESHOLD = 20.0


def _check(a: np.ndarray, b: np.ndarray) -> None:
    if a.shape != b.shape:
        raise ValueError(f"image shapes differ: {a.shape} vs {b.shape}")
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"expected (H, W, 3) images, got {a.shape}")


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB (peak 255), capped at 100 dB."""
    _check(a, b)
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    if mse <= 0:
        return PSNR_CAP_DB
    return min(PSNR_CAP_DB, 10.0 * np.log10(255.0**2 / mse))


def luma(img: np.ndarray) -> np.ndarray:
    x = img.astype(np.float64)
    return 0.299 * x[..., 0] + 0.587 * x[..., 1] + 0.114 * x[..., 2]


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM of the luma channel (constants in the module docstring)."""
    from skimage.metrics import structural_similarity

    _check(a, b)
    return float(
        structural_similarity(
            luma(a), luma(b), data_range=255.0, gaussian_weights=True, sigma=SSIM_SIGMA,
            use_sample_covariance=False, K1=SSIM_K1, K2=SSIM_K2,
        )
    )


def flip(a: np.ndarray, b: np.ndarray) -> float:
    """Mean LDR-FLIP error between ``a`` (test) and ``b`` (reference), in [0, 1]."""
    import flip_evaluator

    _check(a, b)
    ref = b.astype(np.float32) / 255.0
    test = a.astype(np.float32) / 255.0
    _, mean_err, _ = flip_evaluator.evaluate(ref, test, "LDR")
    return float(mean_err)


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


def dssim(a: np.ndarray, b: np.ndarray) -> float:
    """Structural dissimilarity ``(1 - SSIM) / 2`` as in the TSS paper."""
    return (1.0 - ssim(a, b)) / 2.0


def score_frame(shown: np.ndarray, holes: np.ndarray | None, truth: np.ndarray, truth_geometry: np.ndarray | None,
                with_flip: bool) -> dict[str, float]:
    """Every per-frame quality number of one displayed image against its ground truth.

    ``holes`` (bool, H x W) marks the pixels the client did not draw from received content;
    ``hole_pct`` counts them wherever they lie, sky included (a black border over the sky is
    as much a hole as one over a wall).  ``truth_geometry`` (bool, H x W) marks pixels where
    the ground truth shows geometry; ``hole_geom_pct`` counts only the holes there (NaN
    without it).  Returns ``psnr_db``, ``ssim``, ``flip`` (NaN unless ``with_flip``),
    ``lab_err_pct``, ``hole_pct`` and ``hole_geom_pct``.
    """
    geom_pct = float("nan")
    if truth_geometry is not None:
        geom_pct = 0.0 if holes is None else 100.0 * hole_rate(np.asarray(holes, bool) & np.asarray(truth_geometry, bool))
    return {
        "psnr_db": psnr(shown, truth),
        "ssim": ssim(shown, truth),
        "flip": flip(shown, truth) if with_flip else float("nan"),
        "lab_err_pct": 100.0 * lab_error_rate(shown, truth),
        "hole_pct": 100.0 * hole_rate(holes),
        "hole_geom_pct": geom_pct,
    }
