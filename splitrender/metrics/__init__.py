"""Metrics: image quality, holes, error pixels, bit and latency accounting.  Imports nothing else from splitrender."""

from .image import (BACKGROUND_TOLERANCE, CONTENT_SUFFIX, content_quality_summary, has_content, LAB_ERROR_THRESHOLD, PSNR_CAP_DB, REGION_RING_PX, REGIONS, SSIM_SIGMA, dssim, flip, flip_map,
                    foreground_mask, hole_rate, lab_error_mask, lab_error_rate, mse, psnr, psnr_from_mse, quality_summary, region_masks,
                    score_frame, ssim, ssim_map)

__all__ = ["BACKGROUND_TOLERANCE", "CONTENT_SUFFIX", "content_quality_summary", "has_content", "LAB_ERROR_THRESHOLD", "PSNR_CAP_DB", "REGION_RING_PX", "REGIONS", "SSIM_SIGMA", "dssim", "flip", "flip_map",
           "foreground_mask", "hole_rate", "lab_error_mask", "lab_error_rate", "mse", "psnr", "psnr_from_mse", "quality_summary",
           "region_masks", "score_frame", "ssim", "ssim_map"]
