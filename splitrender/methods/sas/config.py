"""``sas`` settings, shared by the server and client halves."""

from __future__ import annotations

import math
import dataclasses
from dataclasses import dataclass
from typing import Literal

from ...errors import ConfigError
from ...limits import ClientSize
from ...scene.pose import CameraIntrinsics
from ..base import FRAME_DIV_KNOB, QUEUE_TOLERANT_ESTIMATOR, Knob, MethodConfig, QualityModel, with_model
from .allocator import STRATEGIES, AtlasLayout


KNOB_STEPS = (1.0, 0.66, 0.44, 0.29)
"""The atlas budget's levels, as fractions of the configured one."""
SAS_BUDGET_COST = (1.0, 0.96, 0.81, 0.70)
"""The atlas's bits at each level over those at the first (the knob's prior; ``benchmarks/bench_knobs.py``)."""
SAS_FRAME_DIV_COST = (1.0, 0.61, 0.59, 0.49)
"""Everything sas sends at one server frame in 1, 2, 3, 5 over the first (the ``frame_div`` knob's prior, in place of
the pipeline's one n-th): its frames carry 1.23, 1.76 and 2.43 times the bytes (the atlas's P-frames code the longer
motion, and each frame's PVS, geometry and tables grow with it; ``benchmarks/bench_knobs.py --quality --methods sas
--knobs frame_div``, 2 s, cc91518: ``benchmarks/results/bench_knobs_quality_sas_frame_div_2s.json``).  Per second
one frame in 3 saves little over one in 2."""
QUALITY = QualityModel(
    (("bias_fill", (0.0, 0.55, 1.27, 2.57)), ("texels_per_px", (0.0, 0.55, 1.27, 2.57)),
     ("frame_div", (0.0, 0.81, 1.45, 2.61))),
    latency_db_per_100ms=0.66, rate_db_per_halving=1.40,
    measured="benchmarks/bench_knobs.py --quality --methods sas, 2026-12-06, c06f4f3 with issue 50's I-frames: default+nogi, walk, 320x180, 2 s, delay 20ms, model PSNR after 0.5 s",
    estimator=QUEUE_TOLERANT_ESTIMATOR)
"""sas's quality model (:class:`~splitrender.methods.base.QualityModel`): model PSNR 31.13 dB at its own point;
the atlas budget's levels lose 0.55, 1.27 and 2.57 dB (``texels_per_px``, the budget without ``fill_atlas``, is
taken to lose what ``bias_fill`` does); one server frame in 2, 3, 5: 0.81, 1.45, 2.61 dB; +200 ms of
motion-to-photon 1.31 dB (the geometry is redrawn at the display pose: a quarter of video's loss); crf 29 (0.56x
the atlas's bits) 1.15 dB.  Measured at the default config: another's levels are the same fractions of its own
budget.  With an I-frame every 5 frames (before issue 50): 30.72 dB; 0.68, 1.20, 2.38; 0.64, 1.12, 2.17; 0.60 dB
per 100 ms; 2.23 dB per halving."""


@dataclass(frozen=True)
class SasConfig(MethodConfig):
    """SAS settings.  ``gop``: the longest run of frames between I-frames (30, as for the other methods);
    ``reset_period``: how often (frames) the atlas's memory load is checked against ``high_water`` for an atlas
    reset, which is an I-frame (paper: resets and I-frames both every 5 frames).  An I-frame every 5 frames kept
    a still view from converging at a low rate (issue 50: the duck at 500 kbit/s, 320x180, rose from about 29.5
    to 34 dB in each GOP and fell back; with I-frames only at the GOP's end or a reset, 39 dB within 1 s, the
    lossless atlas's 40.7); the paper's period is for a lossy channel without feedback, where this pipeline's
    client reports losses and the next frame resends the whole PVS.

    ``atlas_mpix_1080p``: atlas size in megapixels for a 1920x1080 display, scaled by
    the display's pixel count (paper: 4 or 8; default 12, where a still camera at zero
    latency is within 1 dB of ``video`` on every test scene, see ``docs/methods.md``);
    ``atlas_width``/``atlas_height`` (texels) override it.  ``atlas_filter``: how the
    client reconstructs the atlas, ``bicubic`` (Catmull-Rom over 4x4 texels, each tap
    clamped to the block) or ``bilinear`` (the paper's one hardware tap).  ``texels_per_px``: target shading rate.  ``bias_fill``: fraction of
    the atlas eq. 3 aims to fill.  ``fill_atlas``: eq. 3's bias in both directions, as the
    paper writes it: with room in the atlas every level goes up until the blocks fill
    ``bias_fill`` of it (the sampling density follows the atlas size); False keeps each
    patch at its ideal level (as many texels as it covers pixels) unless the atlas is short.  ``fill_max_density``: the
    fill raises a patch at most to this many times its ideal texels per pixel per side; ``fill_max_density_plain``
    the same for patches whose material has no map that varies (smooth shading, where texels mostly cost bits).  ``strategy``: allocator S0 (paper) .. S3.
    ``pvs_max_samples``: the most EVS samples (patch-id passes) a frame's PVS takes; a longer window (from the
    newest pose to one frame past the target, ``pvs_step_ms`` apart) is sampled at that many evenly spaced times.
    A live server that makes a frame in 0.6 s expects that much latency, and 33 ms steps took 22 passes, half its
    frame (issue 49); 8 leaves the windows of every network profile in virtual time as they were (ideal to cloud take 3-7).
    ``pvs_linger_frames``: a patch stays in the PVS for this many server frames after
    it was last in an EVS sample, so small patches flickering at the edge of
    visibility do not re-send geometry and blocks every frame; live (the renderer relights the probes at a rate), for
    the time that many frames take at the server's frame rate, at least one frame (a live server making a frame in
    0.6 s kept a patch 4.8 s, and most of the blocks it shaded were of patches no EVS sample saw).  ``split_near_m``: at load time every mesh is split (:func:`~.patches.split_mesh`)
    until each edge, seen from this distance (metres), fits the largest block
    (``superblock_px`` texels at ``texels_per_px``); the paper's "tessellation of overly
    large triangles" (section 6.4).  0 disables it.  ``split_max_triangles`` caps the
    split scene (the edge bound grows until it fits).  ``grow_block_sides``: the shading
    stage grows each triangle (so every texel a client's tap reads is shaded) across its
    edges inside the block that no other triangle of the patch shares (a shared one only
    by a thirty-second of a texel: the neighbour shades beyond it); with this set across
    every edge by the full distance, also those on the block's sides, whose texels outside
    are discarded, and the shared ones, whose texels the neighbour draws again (the same
    blocks, drawn at several times the cost; on only to measure that).  ``inset_min_texels``: along block sides of at least this many texels the patch is inset by
    half a texel (the paper's figure 6), so lookups inside it only interpolate; shorter sides span the block (more
    samples per side); 0 spans every side (wire version 3's layout).  ``shade_changed_only``: a P-frame shades
    only the blocks whose texels would change: a block keeps last frame's texels while its patch, block, footprint,
    object transform, the frame's lighting and view uniforms, the GI probes' state and the moving shadow casters
    over it are all as they were (the atlas is bit for bit the one shading every block gives); off shades every
    block every frame.  ``reuse_shadow``: each texel's sun-shadow factor (the shadow maps' 2 x 9 taps) is kept in
    a float texture beside the atlas, and a block drawn again reads it back while its patch, block, object and
    the sun are unchanged, no moving caster is near, and every texel's normal stays on the same side of the eye
    (the lookup moves along it); the atlas is bit for bit the same.  ``reshade_eye_deg`` (2; 0: off): with
    ``shade_changed_only`` a moving eye no longer makes every block change: a block keeps the texels shaded at an
    earlier eye while, seen from any point of its patch, the eye's direction has turned by less than this many
    degrees and its distance changed by less than that many radians' worth, the reference view's direction has
    turned by less, every texel's normal is on the same side of the eye, and at most ``reshade_max_age`` frames
    have passed (view-dependent terms, specular and texture filtering, lag by that much; the atlas is no longer
    the one shading every block gives).  ``live_refresh_frames`` (4; 0: off): live only (the renderer relights the
    GI probes at a rate, ``Renderer.gi_hz`` > 0; virtual time and the ground truth relight them for every frame and
    are untouched), with ``shade_changed_only`` a block whose texels are late rather than wrong (shaded at another
    eye or footprint past ``reshade_eye_deg``'s tolerances, or under older probes) keeps them a while: each frame
    reshades the longest-kept of those stale blocks, at least a ``1 / live_refresh_frames`` share, so every block is
    shaded again at most this many server frames after it was last shaded (specular, texture filtering and indirect
    light lag by at most that).  A block of a moved object, under a moved shadow caster, newly placed or whose
    texels' normals turned to the other side of the eye is shaded at once.  Without it a live method slower than the
    5 Hz GI rate sees new probes, and on a walk an eye past the tolerances, at every frame and reshades every block.
    """

    gop: int = 30
    reset_period: int = 5
    atlas_mpix_1080p: float = 12.0
    atlas_filter: Literal["bicubic", "bilinear"] = "bicubic"
    atlas_width: int = 0
    atlas_height: int = 0
    superblock_px: int = 32
    strategy: Literal["S0", "S1", "S2", "S3"] = "S0"
    high_water: float = 0.9
    fov_margin: float = 0.2
    pvs_step_ms: float = 33.3
    pvs_max_samples: int = 8
    pvs_prediction: Literal["linear", "none"] = "linear"
    texels_per_px: float = 1.0
    bias_fill: float = 0.75
    fill_atlas: bool = True
    fill_max_density: float = 4.0
    fill_max_density_plain: float = 2.0
    hysteresis: float = 0.75
    lossless: bool = False
    pvs_linger_frames: int = 8
    split_near_m: float = 2.0
    split_max_triangles: int = 200_000
    grow_block_sides: bool = False
    inset_min_texels: int = 8
    shade_changed_only: bool = True
    reuse_shadow: bool = True
    reshade_eye_deg: float = 2.0
    reshade_max_age: int = 8
    live_refresh_frames: int = 4

    def adapt_knobs(self) -> tuple[Knob, ...]:
        """The atlas budget: the fraction of the atlas eq. 3 fills (``bias_fill``; with ``fill_atlas`` off, the
        shading rate ``texels_per_px`` instead), lowered in steps of about 2/3; then the server's frame rate."""
        if self.fill_atlas:
            budget = Knob("bias_fill", tuple(round(self.bias_fill * f, 4) for f in KNOB_STEPS), SAS_BUDGET_COST, "video",
                          "fraction of the atlas the shading fills")
        else:
            budget = Knob("texels_per_px", tuple(round(max(0.05, self.texels_per_px * f), 4) for f in KNOB_STEPS),
                          SAS_BUDGET_COST, "video", "shading texels per pixel")
        frame_div = dataclasses.replace(FRAME_DIV_KNOB, cost=SAS_FRAME_DIV_COST)
        return with_model((budget, frame_div), QUALITY)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.strategy not in STRATEGIES:
            raise ConfigError(f"SasConfig.strategy: {self.strategy!r} is not one of {list(STRATEGIES)}")
        if not 0.0 <= self.fov_margin <= 2.0:
            raise ConfigError(f"SasConfig.fov_margin: must be in [0, 2], got {self.fov_margin}")
        if not 1 <= self.reset_period <= 100_000:
            raise ConfigError(f"SasConfig.reset_period: must be in [1, 100000], got {self.reset_period}")
        if not 0.1 <= self.high_water <= 1.0:
            raise ConfigError(f"SasConfig.high_water: must be in [0.1, 1], got {self.high_water}")
        if not self.pvs_step_ms > 0:
            raise ConfigError(f"SasConfig.pvs_step_ms: must be > 0, got {self.pvs_step_ms}")
        if not 2 <= self.pvs_max_samples <= 1000:
            raise ConfigError(f"SasConfig.pvs_max_samples: must be in [2, 1000], got {self.pvs_max_samples}")
        if not 0.05 <= self.texels_per_px <= 8:
            raise ConfigError(f"SasConfig.texels_per_px: must be in [0.05, 8], got {self.texels_per_px}")
        if self.pvs_prediction not in ("linear", "none"):
            raise ConfigError(f"SasConfig.pvs_prediction: {self.pvs_prediction!r} is not one of ['linear', 'none']")
        if (self.atlas_width > 0) != (self.atlas_height > 0):
            raise ConfigError("SasConfig: give both atlas_width and atlas_height or neither")
        if not 0 <= self.pvs_linger_frames <= 1000:
            raise ConfigError(f"SasConfig.pvs_linger_frames: must be in [0, 1000], got {self.pvs_linger_frames}")
        if not 0.0 <= self.split_near_m <= 1e3:
            raise ConfigError(f"SasConfig.split_near_m: must be in [0, 1000], got {self.split_near_m}")
        if not 1 <= self.split_max_triangles <= 50_000_000:
            raise ConfigError(f"SasConfig.split_max_triangles: must be in [1, 5e7], got {self.split_max_triangles}")
        if not 1.0 <= self.fill_max_density <= 64.0:
            raise ConfigError(f"SasConfig.fill_max_density: must be in [1, 64], got {self.fill_max_density}")
        if not 1.0 <= self.fill_max_density_plain <= 64.0:
            raise ConfigError(f"SasConfig.fill_max_density_plain: must be in [1, 64], got {self.fill_max_density_plain}")
        if not 0 <= self.inset_min_texels <= 4096:
            raise ConfigError(f"SasConfig.inset_min_texels: must be in [0, 4096], got {self.inset_min_texels}")
        if self.atlas_filter not in ("bicubic", "bilinear"):
            raise ConfigError(f"SasConfig.atlas_filter: {self.atlas_filter!r} is not one of ['bicubic', 'bilinear']")
        if not 0.0 <= self.reshade_eye_deg <= 30.0:   # NaN too
            raise ConfigError(f"SasConfig.reshade_eye_deg: must be in [0, 30], got {self.reshade_eye_deg}")
        if not 1 <= self.reshade_max_age <= 1000:
            raise ConfigError(f"SasConfig.reshade_max_age: must be in [1, 1000], got {self.reshade_max_age}")
        if not 0 <= self.live_refresh_frames <= 1000:
            raise ConfigError(f"SasConfig.live_refresh_frames: must be in [0, 1000], got {self.live_refresh_frames}")
        if not self.atlas_mpix_1080p > 0:   # NaN too
            raise ConfigError(f"SasConfig.atlas_mpix_1080p: must be > 0, got {self.atlas_mpix_1080p}")

    def client_sizes(self, display: CameraIntrinsics) -> tuple[ClientSize, ...]:
        """The atlas (against ``max_atlas_pixels``, named by ``atlas_width`` when it is given, else by
        ``atlas_mpix_1080p``) and the split scene whose patches the client may hold (``split_max_triangles``,
        against ``max_scene_triangles``)."""
        at = f"a {display.width}x{display.height} display"
        if self.atlas_width > 0:
            w, h = self.atlas_width, self.atlas_height
            atlas = ClientSize("atlas_width", "max_atlas_pixels", w * h, "texels",
                               f"the sas atlas {w}x{h} (atlas_width x atlas_height)")
        else:
            texels = self.atlas_mpix_1080p * 1e6 * display.width * display.height / (1920 * 1080)
            if texels < 2.0 ** 60:          # inf from a huge atlas_mpix_1080p is over any limit
                lay = self.atlas_layout(display)
                n, size = lay.width * lay.height, f" {lay.width}x{lay.height}"
            else:
                n, size = 2 ** 60, ""
            atlas = ClientSize("atlas_mpix_1080p", "max_atlas_pixels", n, "texels",
                               f"the sas atlas{size} (atlas_mpix_1080p {self.atlas_mpix_1080p:g} at {at})")
        return (atlas, ClientSize("split_max_triangles", "max_scene_triangles", self.split_max_triangles, "triangles",
                                  "the split scene whose patches the sas client may hold"))

    def atlas_layout(self, intr: CameraIntrinsics) -> AtlasLayout:
        """The atlas for a display of ``intr``: 2:1, a multiple of the superblock size."""
        s = self.superblock_px
        if self.atlas_width > 0:
            return AtlasLayout(self.atlas_width, self.atlas_height, s)
        texels = self.atlas_mpix_1080p * 1e6 * intr.width * intr.height / (1920 * 1080)
        h = max(1, round(math.sqrt(texels / 2) / s)) * s
        return AtlasLayout(2 * h, h, s)

    def split_edge_m(self, intr: CameraIntrinsics) -> float:
        """Longest edge (metres) a patch may keep at load time: the largest block seen from ``split_near_m``."""
        if self.split_near_m <= 0:
            return math.inf
        px_per_rad = intr.width / math.radians(intr.fov_x_deg)
        return self.superblock_px / (self.texels_per_px * px_per_rad) * self.split_near_m
