"""``atw``: the config and the geometry both halves share (the halves import this, never the package)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ...errors import ConfigError
from ...limits import ClientSize
from ...scene.pose import CameraIntrinsics, quat_to_matrix3
from ..base import SCALE_KNOB, Knob, MethodConfig, QualityModel, with_model

SHADERS = Path(__file__).parent.parent / "shaders"
QUALITY = QualityModel(
    (("scale", (0.0, 0.70, 1.64)),),
    latency_db_per_100ms=2.27, rate_db_per_halving=0.62,
    measured="benchmarks/bench_knobs.py --quality, 2026-12-06, fb7ffbf: default+nogi, walk, 320x180, 2 s, delay 20ms, model PSNR after 0.5 s")
"""atw's quality model (:class:`~splitrender.methods.base.QualityModel`): model PSNR 23.18 dB at its own point,
22.48 and 21.54 at scale 0.75 and 0.5; +200 ms of motion-to-photon loses 4.55 dB (it corrects rotation only, and
the walk translates); crf 29 (0.57x the bits) 0.51 dB."""


@dataclass(frozen=True)
class AtwConfig(MethodConfig):
    """``overscan``: image-plane scale of the server frame (1.3 = 30% wider and taller).  ``chroma``: 4:4:4 by
    default (at the bits of 4:2:0: model +1.4 dB, whole frame +1.1 dB, median of 12 cells,
    ``benchmarks/bench_chroma.py``)."""

    chroma: str | int = "444"
    overscan: float = 1.3
    fill: Literal["edge", "black"] = "edge"

    def adapt_knobs(self) -> tuple[Knob, ...]:
        """The pipeline's resolution scale, with atw's quality model."""
        return with_model((SCALE_KNOB,), QUALITY)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 1.0 <= self.overscan <= 3.0:
            raise ConfigError(f"AtwConfig.overscan: must be in [1, 3], got {self.overscan}")
        if self.fill not in ("edge", "black"):
            raise ConfigError(f"AtwConfig.fill: {self.fill!r} is not one of ['edge', 'black']")

    def client_sizes(self, display: CameraIntrinsics) -> tuple[ClientSize, ...]:
        """The overscanned frame the client warps from (against ``max_reference_pixels``)."""
        ref = overscan_intrinsics(display, self.overscan)
        return (ClientSize("overscan", "max_reference_pixels", ref.width * ref.height, "pixels",
                           f"the atw frame {ref.width}x{ref.height} (overscan {self.overscan:g} at a "
                           f"{display.width}x{display.height} display)"),)


def overscan_intrinsics(intr: CameraIntrinsics, overscan: float) -> CameraIntrinsics:
    return intr.enlarged(overscan, keep_pixel_density=True)


def pixel_projection(intr: CameraIntrinsics) -> np.ndarray:
    """3x3 map from a camera-space direction to homogeneous top-left pixel coordinates."""
    f = intr.focal_px()
    return np.array([[f, 0.0, -intr.width / 2.0], [0.0, -f, -intr.height / 2.0], [0.0, 0.0, -1.0]])


def rotation_homography(ref: CameraIntrinsics, ref_q: np.ndarray, cur: CameraIntrinsics, cur_q: np.ndarray) -> np.ndarray:
    """Display pixel of the current camera -> pixel of the reference image (rotation only)."""
    r_ref = quat_to_matrix3(ref_q)
    r_cur = quat_to_matrix3(cur_q)
    return pixel_projection(ref) @ r_ref.T @ r_cur @ np.linalg.inv(pixel_projection(cur))
