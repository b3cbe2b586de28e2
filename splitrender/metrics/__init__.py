"""Metrics: image quality, holes, error pixels, bit and latency accounting.  Imports nothing else from splitrender."""

from .image import LAB_ERROR_THRESHOLD, PSNR_CAP_DB, dssim, flip, hole_rate, lab_error_mask, lab_error_rate, psnr, score_frame, ssim

__all__ = ["LAB_ERROR_THRESHOLD", "PSNR_CAP_DB", "dssim", "flip", "hole_rate", "lab_error_mask", "lab_error_rate", "psnr", "score_frame", "ssim"]
