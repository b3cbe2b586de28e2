"""``warp``: the config, wire constants and view geometry both halves share (the halves and :mod:`.wire` import
this, never the package)."""

from __future__ import annotations

import dataclasses

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ...errors import ConfigError
from ...limits import ClientSize
from ...scene.pose import CameraIntrinsics, Pose, quat_to_matrix3
from ..base import SCALE_KNOB, Knob, MethodConfig, QualityModel, with_model

SHADERS = Path(__file__).parent.parent / "shaders"
META_VERSION = 1
MAX_OBJECT_ID = 65535
MAX_COORD_M = 1e6  # largest pose coordinate, matrix entry, near distance or dt accepted from the server (float32 on the GPU)
Reconstruction = Literal["points", "quads", "mesh"]

DEPTH_BITS_COST = {16: 1.0, 12: 0.75, 10: 0.42, 8: 0.15}
DEPTH_STEP2_COST = 0.41
"""Lossless depth bits at ``depth_step`` 2 over those at 1 (the knob's prior; ``benchmarks/bench_knobs.py``)."""
"""Lossless depth bits at ``depth_bits`` over those at 16 (the knob's prior; ``benchmarks/bench_knobs.py``)."""
DEPTH_BITS_DB = {16: 0.0, 12: 0.005, 10: 0.021, 8: 0.241}
"""Model PSNR (dB) lost at ``depth_bits`` against 16 (``benchmarks/bench_knobs.py --quality``; :data:`QUALITY`)."""
QUALITY_MEASURED = ("benchmarks/bench_knobs.py --quality, 2026-12-06, fb7ffbf: default+nogi, walk, 320x180, 2 s, "
                    "delay 20ms, model PSNR after 0.5 s")
QUALITY = QualityModel(
    (("depth_bits", tuple(DEPTH_BITS_DB.values())), ("depth_step", (0.0, 0.20)), ("scale", (0.0, 0.59, 1.83))),
    latency_db_per_100ms=0.41, rate_db_per_halving=0.90, measured=QUALITY_MEASURED)
"""warp's quality model at its default config (:class:`~splitrender.methods.base.QualityModel`; a config's own levels
take theirs from :data:`DEPTH_BITS_DB`): model PSNR 23.70 dB at its own point; 12, 10 and 8 depth
bits lose 0.005, 0.02 and 0.24 dB for 17, 42 and 64 % of the bytes; one depth sample in four 0.20 dB (45 %); the
colour at scale 0.75 and 0.5 0.59 and 1.83 dB; +200 ms of motion-to-photon 0.82 dB; crf 29 (0.57x the colour's
bits) 0.74 dB."""
SecondView = Literal["stereo", "back", "motion"]
ViewMerge = Literal["holes", "depth"]
DepthCoding = Literal["lossless", "bc4"]


@dataclass(frozen=True)
class WarpConfig(MethodConfig):
    """Settings of the ``warp`` method.

    - ``views``: reference views per frame (1 or 2);
    - ``second_view``: where view 2 goes; view 1 is always the predicted pose (moving it
      off the prediction costs more than view 2 gains): ``stereo`` (view 2 ``baseline_m``
      to the right along the camera's x axis, the paper's widened eye separation),
      ``back`` (``baseline_m`` behind), ``motion`` (``baseline_m`` further along the
      predicted motion; to the right when still);
    - ``view_merge``: how the other views join the one nearest the display pose:
      ``holes`` (they only fill pixels the nearest view left uncovered) or ``depth``
      (the paper's plain depth test; their pixel-phase-shifted silhouettes then widen
      every foreground edge and thin structure, which costs more PSNR than the filled
      disocclusions gain);
    - ``fov_scale``: image-plane scale of the reference views (1 = display FOV;
      3.0 turns a 60 degree display into about 120 degrees, "MW 120");
    - ``resolution_scale``: reference pixels per display pixel along each axis at equal
      pixel density (1 keeps the density; the reference is ``fov_scale *
      resolution_scale`` times the display size);
    - ``reconstruction``: ``points``, ``quads`` or ``mesh``;
    - ``depth_coding``: ``lossless`` (HEVC, bit-exact 16-bit codes) or ``bc4``;
    - ``depth_bits``: significant bits of each 16-bit depth code (the rest zero, which lossless HEVC codes
      almost for free; rate adaptation lowers it under ``--adapt full``);
    - ``depth_step``: lossless depth keeps one sample in ``depth_step`` along each axis, in the plane's top-left
      corner (the rest zero, almost free to code); the client repeats each sample (rate adaptation's coarsest
      depth);
    - ``depth_near_m``: the depth quantiser's near distance (metres);
    - ``depth_discontinuity``: relative depth step that cuts mesh triangles and
      one-sides the Jacobian;
    - ``hole_fill``: epipolar hole filling on/off; ``max_scan_px``: scan length;
    - ``extrapolate``: extrapolate object motion between updates (else objects jump);
      ``max_extrapolation_s`` caps it;
    - ``max_splat_px``: largest point/quad splat;
    - ``splat_slack_px``: point size is ``ceil(S - slack)``; 0 is the paper's strict
      ``ceil`` (every magnification above 1 doubles the splat and thickens edges by half a
      pixel); the default lets near-1 magnifications keep 1-pixel splats and leaves the
      rare crack to hole filling;
    - ``chroma``: the colour views in 4:4:4 by default (at the bits of 4:2:0: model +1.9 dB,
      whole frame +1.5 dB, median of 12 cells, ``benchmarks/bench_chroma.py``); the depth
      stream is 4:0:0 whatever it says.
    """

    chroma: str | int = "444"
    views: int = 1
    second_view: SecondView = "stereo"
    view_merge: ViewMerge = "holes"
    baseline_m: float = 0.3
    fov_scale: float = 1.3
    resolution_scale: float = 1.0
    reconstruction: Reconstruction = "points"
    depth_coding: DepthCoding = "lossless"
    depth_bits: int = 16
    depth_step: int = 1
    depth_near_m: float = 0.1
    depth_discontinuity: float = 0.15
    hole_fill: bool = True
    max_scan_px: int = 64
    extrapolate: bool = True
    max_extrapolation_s: float = 0.5
    max_splat_px: float = 8.0
    splat_slack_px: float = 0.25

    def for_codecs(self, codecs: tuple[str, ...]) -> WarpConfig:
        """As :meth:`MethodConfig.for_codecs`; a client that does not decode HEVC gets its depth as BC4 over a data
        stream instead of lossless HEVC."""
        out = super().for_codecs(codecs)
        assert isinstance(out, WarpConfig)
        if codecs and "hevc" not in codecs and out.depth_coding == "lossless":
            out = dataclasses.replace(out, depth_coding="bc4")
        return out

    def client_sizes(self, display: CameraIntrinsics) -> tuple[ClientSize, ...]:
        """The reference image (against ``max_reference_pixels``, named by ``resolution_scale`` when that is above 1,
        else by ``fov_scale``), then all ``views`` of it (named by ``views``), and for ``reconstruction = "mesh"`` the
        grid mesh (against ``max_mesh_vertices``)."""
        ref = reference_intrinsics(display, self.fov_scale, self.resolution_scale)
        px = ref.width * ref.height
        image = (f"{ref.width}x{ref.height} (fov_scale {self.fov_scale:g} x resolution_scale "
                 f"{self.resolution_scale:g} at a {display.width}x{display.height} display)")
        scale = "resolution_scale" if self.resolution_scale > 1 else "fov_scale"
        out = [ClientSize(scale, "max_reference_pixels", px, "pixels", f"the warp reference image {image}")]
        if self.views > 1:
            out.append(ClientSize("views", "max_reference_pixels", self.views * px, "pixels",
                                  f"{self.views} warp reference views of {image}"))
        if self.reconstruction == "mesh":
            out.append(ClientSize("reconstruction", "max_mesh_vertices", (ref.width + 2) * (ref.height + 2), "vertices",
                                  f"the warp mesh (reconstruction 'mesh') over the reference image {image}"))
        return tuple(out)

    def adapt_knobs(self) -> tuple[Knob, ...]:
        """Depth precision (lossless depth only: BC4 is a fixed rate); the pipeline adds its colour scale."""
        b = self.depth_bits
        levels = (b, *(x for x in (12, 10, 8) if x < b))
        if self.depth_coding != "lossless" or len(levels) < 2:
            return with_model((SCALE_KNOB,), QUALITY)        # the colour's scale only, with warp's model
        bits, cost = zip(*sorted(DEPTH_BITS_COST.items()))
        prior = [float(np.interp(x, bits, cost)) for x in levels]
        out = [Knob("depth_bits", levels, tuple(c / prior[0] for c in prior), "data",
                    "significant bits of the lossless depth codes")]
        if self.depth_step == 1:
            out.append(Knob("depth_step", (1, 2), (1.0, DEPTH_STEP2_COST), "data", "depth samples kept: one in n per axis"))
        bits_db, db = zip(*sorted(DEPTH_BITS_DB.items()))
        lost = [float(np.interp(x, bits_db, db)) for x in levels]
        model = dataclasses.replace(QUALITY, knob_db=(("depth_bits", tuple(x - lost[0] for x in lost)),
                                                      *QUALITY.knob_db[1:]))
        return with_model(tuple(out), model)

    def __post_init__(self) -> None:
        super().__post_init__()
        n = type(self).__name__
        if self.views not in (1, 2):
            raise ConfigError(f"{n}.views: must be 1 or 2, got {self.views}")
        if self.second_view not in ("stereo", "back", "motion"):
            raise ConfigError(f"{n}.second_view: {self.second_view!r} is not one of ['stereo', 'back', 'motion']")
        if self.view_merge not in ("holes", "depth"):
            raise ConfigError(f"{n}.view_merge: {self.view_merge!r} is not one of ['holes', 'depth']")
        if self.reconstruction not in ("points", "quads", "mesh"):
            raise ConfigError(f"{n}.reconstruction: {self.reconstruction!r} is not one of ['points', 'quads', 'mesh']")
        if self.depth_coding not in ("lossless", "bc4"):
            raise ConfigError(f"{n}.depth_coding: {self.depth_coding!r} is not one of ['lossless', 'bc4']")
        if not 0.0 <= self.baseline_m <= 5.0:
            raise ConfigError(f"{n}.baseline_m: must be in [0, 5] metres, got {self.baseline_m}")
        if not 1.0 <= self.fov_scale <= 6.0:
            raise ConfigError(f"{n}.fov_scale: must be in [1, 6], got {self.fov_scale}")
        if not 0.1 <= self.resolution_scale <= 4.0:
            raise ConfigError(f"{n}.resolution_scale: must be in [0.1, 4], got {self.resolution_scale}")
        if self.depth_step not in (1, 2, 3, 4):
            raise ConfigError(f"{n}.depth_step: must be 1 to 4, got {self.depth_step}")
        if not 8 <= self.depth_bits <= 16:
            raise ConfigError(f"{n}.depth_bits: must be 8 to 16, got {self.depth_bits}")
        if not self.depth_near_m > 0:
            raise ConfigError(f"{n}.depth_near_m: must be > 0, got {self.depth_near_m}")
        if not self.depth_discontinuity > 0:
            raise ConfigError(f"{n}.depth_discontinuity: must be > 0, got {self.depth_discontinuity}")
        if self.max_scan_px < 1:
            raise ConfigError(f"{n}.max_scan_px: must be >= 1, got {self.max_scan_px}")
        if not 1.0 <= self.max_splat_px <= 64.0:
            raise ConfigError(f"{n}.max_splat_px: must be in [1, 64], got {self.max_splat_px}")
        if not 0.0 <= self.splat_slack_px < 1.0:
            raise ConfigError(f"{n}.splat_slack_px: must be in [0, 1), got {self.splat_slack_px}")
        if self.max_extrapolation_s < 0:
            raise ConfigError(f"{n}.max_extrapolation_s: must be >= 0, got {self.max_extrapolation_s}")


def fov_scale_for(display: CameraIntrinsics, fov_y_deg: float) -> float:
    """The ``fov_scale`` that gives reference views a vertical FOV of ``fov_y_deg``."""
    return math.tan(math.radians(fov_y_deg) / 2) / math.tan(math.radians(display.fov_y_deg) / 2)


def reference_intrinsics(display: CameraIntrinsics, fov_scale: float, resolution_scale: float) -> CameraIntrinsics:
    """Reference-view camera: display FOV enlarged by ``fov_scale``, even pixel size."""
    big = display.enlarged(fov_scale, keep_pixel_density=False)
    w = max(2, int(round(display.width * fov_scale * resolution_scale / 2)) * 2)
    h = max(2, int(round(display.height * fov_scale * resolution_scale / 2)) * 2)
    return CameraIntrinsics(w, h, big.fov_y_deg, display.near_m, display.far_m)


def reference_poses(cfg: WarpConfig, target: Pose, motion_dir: np.ndarray | None) -> list[Pose]:
    """The reference view poses for one frame (view 0 first; see ``WarpConfig.second_view``)."""
    if cfg.views == 1:
        return [target]
    r = quat_to_matrix3(target.orientation)
    right, back = r[:, 0], r[:, 2]
    b = cfg.baseline_m
    if cfg.second_view == "stereo":
        return [target, Pose(target.position + right * b, target.orientation)]
    if cfg.second_view == "back":
        return [target, Pose(target.position + back * b, target.orientation)]
    d = motion_dir if motion_dir is not None and np.linalg.norm(motion_dir) > 1e-9 else right
    return [target, Pose(target.position + d / np.linalg.norm(d) * b, target.orientation)]
