"""``atw``: the config and the geometry both halves share (the halves import this, never the package)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ...errors import ConfigError
from ...limits import ClientSize
from ...scene.pose import CameraIntrinsics, quat_to_matrix3
from ..base import MethodConfig

SHADERS = Path(__file__).parent.parent / "shaders"


@dataclass(frozen=True)
class AtwConfig(MethodConfig):
    """``overscan``: image-plane scale of the server frame (1.3 = 30% wider and taller).  ``chroma``: 4:4:4 by
    default (at the bits of 4:2:0: model +1.4 dB, whole frame +1.1 dB, median of 12 cells,
    ``benchmarks/bench_chroma.py``)."""

    chroma: str | int = "444"
    overscan: float = 1.3
    fill: Literal["edge", "black"] = "edge"

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
