"""``tss`` settings, shared by the server and client halves."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Literal

from ...errors import ConfigError
from ...limits import ClientSize
from ...scene.pose import CameraIntrinsics
from ..base import FRAME_DIV_KNOB, QUEUE_TOLERANT_ESTIMATOR, Knob, MethodConfig, QualityModel, with_model


TSS_KNOB_STEPS = (1.0, 0.7, 0.5, 0.35)
"""The atlas budget's levels, as fractions of the configured ``samples_per_px``."""
TSS_BUDGET_COST = (1.0, 0.83, 0.69, 0.57)
"""The atlas's bits at each level over those at the first (the knob's prior; ``benchmarks/bench_knobs.py``)."""
TSS_FRAME_DIV_COST = (1.0, 0.67, 0.49, 0.36)
"""Everything tss sends at one server frame in 1, 2, 3, 5 over the first (the ``frame_div`` knob's prior, in place of
the pipeline's one n-th): its frames carry 1.33, 1.48 and 1.80 times the bytes (the atlas's P-frames code twice,
three and five times the motion; ``benchmarks/bench_knobs.py --quality``, 2 s; 1.34, 1.53, 1.78 over 8 s).  With one n-th a point
at one frame in 2 gave the atlas half its rate, a quarter under what its frames take, and the calibration made there
(a frame's bytes over the prior) put the method's own point a third above its rate, too dear to go back to
(``docs/experiments.md``: tss on the 8 Mbit/s cellular-like trace at one frame in 2 from 1 to 7 s)."""
QUALITY = QualityModel(
    (("samples_per_px", (0.0, 0.58, 1.26, 1.63)), ("budget_px", (0.0, 0.58, 1.26, 1.63)),
     ("frame_div", (0.0, 0.29, 0.81, 1.98))),
    latency_db_per_100ms=0.22, rate_db_per_halving=1.23,
    measured="benchmarks/bench_knobs.py --quality, 2026-12-06, fb7ffbf: default+nogi, walk, 320x180, 2 s, delay 20ms, model PSNR after 0.5 s; "
             "frame_div: --knobs frame_div --duration 8, 2026-12-07, f77d872",
    estimator=QUEUE_TOLERANT_ESTIMATOR + (("probe_media", True),), track_cap=True, up_room=2.0,
    start_boost=True)
"""tss's quality model (:class:`~splitrender.methods.base.QualityModel`): model PSNR 27.59 dB at its own point;
the sample budget's levels lose 0.58, 1.26 and 1.63 dB for 16, 28 and 40 % of the bytes (``budget_px``, the moving
budget, is taken to lose what ``samples_per_px`` does); one server frame in 2, 3, 5: 0.29, 0.81, 1.98 dB over the
walk's 8 s (0.5-8 s, 29.20 dB at its own point; ``benchmarks/results/bench_knobs_quality_tss_frame_div_8s.json``),
where its first 2 s, slower, gave 0.21, 0.44, 0.84 (0.21, 0.45, 0.90 again at f77d872): the adaptation benchmarks
run the whole 8 s, and the frame rate's loss grows with the camera's speed (at 2-3 s one frame in 2 loses 0.5-1.4
dB); +200 ms of motion-to-photon 0.44 dB; crf 29 (0.64x the atlas's bits) 0.80 dB.  Measured at the default
config.  Its adapting session's estimator probes with media (``probe_media``), its first frames take the highest
start-up probe's share (``start_boost``), its atlas's cap follows what its crf sends (``track_cap``), and a point that
fits twice over is taken without the up hold (``up_room``): on the 8 Mbit/s cellular-like trace (8 s, seed 0) full
27.90 -> 27.98 dB (``off`` 28.90; ``benchmarks/results/bench_adapt_quality.json``)."""


@dataclass(frozen=True)
class TssConfig(MethodConfig):
    """TSS settings.

    ``samples_per_px``: shading samples per covered display pixel (the paper's target
    of one).  ``slant_threshold``: a triangle whose longest projected edge over its
    height exceeds this is oversampled, otherwise L-packed (the paper does not give
    the value; 16 here: the study's sweep and ``docs/methods.md`` show L-packing
    spending its samples better than the oversampled staircases at our sizes, and
    the most slanted slivers still oversampled).  ``tiny_samples``: triangles needing fewer samples than this get one
    texel, unless ``sliver_px`` is set (>= 1) and their longest edge spans that many
    sample steps or more (pixels at one sample per pixel): such a sliver is L-packed at its level (its corners and,
    from level 2, its centre: a few samples along its length) instead of one texel at its centroid (0, the default:
    one texel whatever the length, as the paper).  Issue 50: a model's outline is lined with triangles seen edge-on,
    a fraction of a pixel in area and pixels long, and one texel each gave them one colour along the silhouette;
    ``sliver_px = 1`` lifts that floor on real models (lossless, still, 320x180: assimp's duck +1.1 dB at one
    sample per pixel for 3 % more samples, 2CylinderEngine +1.2 dB for 20 % more, +2.2 dB at 4) but costs the
    default scene 22 % more bits for nothing (its far floor's slivers), so it is not the default; any rate above
    one should set it (``benchmarks/bench_tss_models.py``).  ``atlas_mpix_1080p``: atlas megapixels for a 1920x1080 display, scaled by
    the display's pixel count (the paper's 24 Mpix for its walkthroughs); when
    the visible set does not fit, the sampling rate of the frame is lowered until it
    does.  PVS settings as ``sas``: ``fov_margin``, ``pvs_step_ms``,
    ``pvs_prediction``, ``pvs_linger_frames``, ``pvs_max_samples`` (a live server's long windows take at most that
    many patch-id passes; virtual time's networks take fewer).  ``split_near_m``: at load time, meshes
    are split (midpoints) until no edge seen from this distance needs a level above 64
    (the paper's pre-tessellation, done once); 0 disables it.  ``perspective``: place
    samples uniformly in the reference view's screen space ([MHAM08], eq. 5) rather
    than in object space.  ``layout``: ``stable`` keeps a triangle's atlas cell while it
    stays visible in the same class (repacked on I-frames once the atlas is more than
    ``high_water`` full, and whenever it overflows; the default 0 repacks on every
    I-frame, which is intra-coded anyway: the id-ordered layout it restores cost the
    1 s walk at 320x180 4.5 % fewer bits than 0.9 did, the same PSNR); ``prefix`` repacks every frame (a
    deterministic prefix sum by class and id, closest to the paper's per-frame
    binning).  ``hysteresis``: a triangle keeps its kind, level or staircase sizes
    while the new ones are within this fraction of the old (fewer moves in the atlas),
    and an L-packing level that must rise is chosen for this fraction more samples than needed.
    ``os_grid``: where an oversampled triangle's samples sit: ``paper`` (the default:
    the integer lattice of figure 8, rows long enough for a plain bilinear tap past the
    hypotenuse) or ``centred`` (ours: cell centres, the client clamps its taps to each
    row; fewer samples for the same quality, see ``docs/methods.md``).

    For the lossy atlas (issue 33): ``single_px``: a single texel fills a cell this many
    texels square (1, 2 or 4), its cells laid along a Z-order curve in tiles of 16 (a
    2 x 2 cell on even texels is one 4:2:0 chroma sample, and the client reads the
    cell's mean); 2 by default (assimp's duck split fine, still, 320x180: 42.95 dB against
    38.66 with 1; the last resort of an overfull atlas drops to 1).  ``spatial_order``: sort
    each mesh's triangles along a Z-order curve of their centroids at load, so cells
    handed out in id order sit beside their mesh neighbours; off by default, as the
    split meshes' own order is about as coherent (the duck still: +0.12 dB and 1.7 %
    fewer bits; the default scene: +0.01 dB still and on the walk, 1.5 % more bits, its
    geometry coding less).  ``gutter_fill``: texels no sample writes (the gaps between cells, the corner odd
    L-packing levels leave) are filled with their neighbours' colours before coding (:func:`~.layout.fill_gutters`)
    instead of staying black, which the codec blended into every cell's border samples, the seams along each
    triangle's edges (issue 50: TextureTransformTest still, 320x180, 0.3 s: +1.3 dB on the model at 17 % fewer bits;
    at 4 samples per pixel +3.4 dB at 28 % fewer bits).

    ``budget_px`` (0: off, the paper's fixed rate): a sample budget that moves with the scene.  The frame's sampling
    rate rises from ``samples_per_px`` up to ``budget_max_spp`` while the frame's samples stay within ``budget_px``
    per display pixel (``budget_px * width * height``): a model that covers a fifth of the view gets about five times
    the rate of a view it fills.  The rate is found by bisection on the plan's sample count and rounded down to steps
    of 2^(1/8), so a still view keeps its levels; the load-time split is made for ``budget_max_spp`` (up to 16, ``sas``'s
    own density cap on textured patches; a higher cap splits the meshes finer: issue 50 part 1 measured
    ``budget_px = 3`` with ``budget_max_spp = 16`` and ``flip_level = 16``, ``benchmarks/bench_tss_matched.py``: lossless
    it leads ``sas`` in DSSIM on assimp's three models, still, from 0.63-1.15x its samples, at 2.6-3.1x its bits lossy,
    where it does not lead).

    ``flip_level`` (0: off, the paper's sampling): a triangle whose corners' normals face the eye on one side and away
    on the other (``n . v`` changes sign across it, at the predicted pose) is L-packed at this level or its own,
    whichever is higher.  The shader's two-sided lighting flips the interpolated normal where it turns from the eye,
    a step in the truth's colour inside such a triangle along lit outlines, and a few samples (three at the corners,
    or staircase rows past a triangle thinner than one sample step) put the flipped colour on the pixels beside it.
    Issue 50 part 1: this, not the motion, was ``tss``'s gap to ``sas`` on the duck's orbit (zero latency, lossless,
    one fresh frame per pose, 30 poses: 40.39 dB against 43.84; with ``flip_level = 8`` 45.23, the same samples).
    Off by default: on the default scene it buys nothing for 5-16 % more bits (``docs/methods.md``).  ``flip_cap``
    (0: off): the lift goes no higher than ``flip_cap`` times the samples the frame's rate puts along the triangle's
    longest projected edge (a level-``l`` patch has ``l + 1`` along each edge), so a flipped triangle under a pixel
    is not shaded at ``v(flip_level)`` samples.  Issue 50 part 1 (``bench_tss_rd.py``, ``mbc split16 lp 420 block8``,
    crf 31): the default scene's ``cloud`` orbit -2.79 -> -1.57 dB against ``sas`` at 1.19x -> 0.78x its bits (cap 1),
    still -4.99 -> -4.62 (cap 2); but the duck loses 0.06-0.24 dB at equal bits on its orbit (cap 2), so off by
    default (``docs/methods.md``).

    ``os_min_rows`` / ``os_min_step`` (0: off, the slant alone decides): a triangle past ``slant_threshold`` is
    oversampled only where its height holds at least ``os_min_rows`` samples at the frame's rate and L-packing would put
    its samples more than ``os_min_step`` pixels apart along its longest edge (``longest / level``); else L-packed.
    L-packing's rings put ``l + 1`` samples along each edge, so a slanted triangle at its area's level is sampled
    coarsely along its length and finely across: the default scene's brick pillars (24 px strips, level 12) were
    sampled 2 px apart across their mortar lines and aliased, where a thin railing bar (a third of a pixel high) loses
    its shading on one centred row.  Issue 50 part 1 (helper-66, ``docs/methods.md``): with ``slant_threshold = 4``,
    the centred grid, 2 rows and 1.5 px, one uncoded still frame of the default scene: pillar0 29.9 -> 37.7 dB, the
    model 34.4 -> 36.2 at the same samples; the duck's plan unchanged.  Off by default: in ``bench_tss_rd.py`` (crf 31,
    ``tss`` minus ``sas``) it takes the default scene from -4.99 to -4.51 dB still and -2.79 to -1.85 on the ``cloud``
    orbit at fewer bits, but loses on the duck's orbit (-2.20 -> -3.45) and the engine's (-1.51 -> -1.88 at 1.4x the
    bits: the oversampled rows' table entries churn as the view moves).  With 4 rows: default -4.47 still, -1.97 on the
    orbit, the duck as before, the engine's orbit -0.24 to -0.32 dB at crf 29-31 (+0.53 at crf 33): not shown to hold.

    ``pvs_ring`` (0: off, the paper's PVS): while the view moves (the EVS samples' views differ), the triangles sharing
    a vertex with the PVS, this many rings out, join it at one texel each (no samples asked for: the single kind).  The
    PVS is per triangle, and a small triangle the EVS samples did not see (between an engine's fins) was a hole where
    the client's view turned to it; with one texel it shows a coarse colour.  A still view keeps its exact PVS.
    Issue 50 part 1: 2CylinderEngine's ``cloud`` orbit, ``FLIPS`` (``benchmarks/bench_tss_models.py``), lossless:
    model PSNR 27.50 -> 31.91 dB, lossy 27.35 -> 31.15 (``sas`` 31.95), the still views unchanged
    (``docs/methods.md``).  Off by default, as the moving budget it goes with.

    ``codec_block`` (1: off): the lossy atlas aligned to the video codec's transform blocks (issue 50 part 1, the lossy
    half of T-T4-1).  L-packing tip blocks take :func:`~.layout.tip_pitch` texels, ``D(l)`` rounded up to a multiple of
    it (below it to a power of two), and start on multiples of it; L-packing and oversampling shelves start on rows in
    multiples of it, levels of the same pitch share cells (a level that moves within its pitch keeps its cell); the
    padding is filled from each block's own texels (:func:`~.layout.dilate_in_blocks`), and a block no sample wrote
    keeps its colours through a GOP.  Packed edge to edge, tip blocks of 3-8 texels put two to four triangles into most
    of H.264's 4 x 4 transforms, and their border texels took 59 % of the codec's error on the duck
    (``benchmarks/bench_tss_codec.py``); aligned, the same atlas codes in 25-30 % fewer bytes at 3 dB less error.
    A lossless atlas keeps 1 (its codec keeps every texel; the padding would only cost bits).  ``fill_pitch``: with
    ``codec_block``, L-packing levels rise to the highest level of their pitch (:func:`~.layout.pitch_level`), samples
    in the padding's place; off: on the duck at ``TSS_MATCHED`` it wins still (-20 % bits, +0.5 dB) and loses the
    ``cloud`` orbit (-1.3 dB at level bits; ``flip_level`` 14, which it does not lift past, -0.6 dB at 0.79x the bits
    there and -1.7 dB still: the flips' level 16 lifted to 22 is what the still edges gain from), ``docs/methods.md``.

    ``colour_order`` (0: off, id order): a repack places each L-packing class's triangles in the order of the mean luma
    of their samples (:func:`~.layout.lp_luma`, from the last atlas that shaded them) in bins of this many 8-bit levels,
    then by id; a repack with triangles of no known colour (the first frame) shades twice, the second time in that
    order.  Issue 50 part 1: the mosaic of the tiles' means was 65-75 % of the duck's first atlas (crf 31-41); in id
    order a mesh's lit and shadowed triangles alternate in a shelf, in colour order the cells beside each other share
    their means.  The same samples, so a lossless atlas is unchanged at the client; the table pays, its slots no
    longer in id order.  At ``TSS_MATCHED`` + ``codec_block`` 4 with 16 (``benchmarks/bench_tss_rd.py``, still, at
    ``sas``'s bits): the duck -3.33 -> -1.57 dB, 2CylinderEngine -5.18 -> -4.19, TextureTransformTest -3.90 -> -3.87;
    off by default (``docs/methods.md``, "The tiles' order by colour").

    ``lp_own`` (True; False: the paper's count): an L-packing level is chosen so that the samples the patch holds for itself
    cover the triangle's need (:func:`~.layout.own_count`: ``v(l)`` less half of the ``3 l`` on its outer ring, which it
    shares with its neighbours, and the corners' further share), not all ``v(l)``.  A mesh of 1-2 px triangles at
    level 1 was shaded at its vertices only (the default scene's torus, Gouraud on a gold specular: 27.4 dB at any
    rate, ``sas`` 36.8); with it the torus scores 36.1 from the same budget (one uncoded still frame).  The budget's
    rate falls to pay for it (2.38 -> 1.68 on the default scene), so the larger triangles get fewer samples
    (issue 50 part 1, helper-74; ``docs/methods.md``).  ``bench_tss_rd.py``, ``mbc split16 lp 420 block8`` at crf 31,
    on minus off: still +0.08 (duck), +0.52 (2CylinderEngine), +0.25 (default scene), +0.03 dB (TextureTransformTest)
    at 0.97-1.01x the bits; ``cloud`` orbit +0.63 (default), +1.71 (engine, at 0.85x the bits), -0.11 (duck, 1.02x).
    On by default since ``tss``'s own defaults were measured with it at equal bits (``bench_tss_rd.py`` label
    ``h74_defaults_own_ladder``, on minus off at off's bits, model dB): still +1.12 (duck), +0.27
    (TextureTransformTest), +1.04 (2CylinderEngine), +1.30 (default scene, at 1.09x the bits); ``cloud`` orbit +0.54,
    +0.18, +0.43, +0.89.  It spends more samples where triangles are small (the tests that hold the paper's claim
    "better with fewer samples" pin ``lp_own = False``, the paper's count).

    ``lp_filter``: how the client reads an L-packed triangle off its tip blocks: ``linear`` (the default: one bilinear
    tap, or the three samples around the point on a diagonal cell) or ``cubic`` (a Catmull-Rom filter over 4x4 texels
    off the diagonal, each tap clamped to the block and to the point's side of it, as ``sas``'s client reads its
    atlas; the diagonal cells and the innermost ring of odd levels stay linear).  One still frame, no codec, 4 samples
    per covered pixel: TextureTransformTest 46.28 -> 48.19 dB, the default scene 36.70 -> 36.84; the same bits, but
    coded at crf 31 the codec's error hides it (``docs/methods.md``), so off by default.

    ``lp_inset`` (0: the paper's lattice, samples on the edges): how far an L-packed triangle's lattice sits inside its
    edges, in half ring spacings (:func:`~.layout.lp_inset_offset`; 1: the outer ring half a spacing in, no sample
    shared with a neighbour, the same samples ``(l + 1) / l`` times denser along each side; the client extrapolates
    past the outer ring).  Lossless at ``sas``'s budget, 320x180 still: interior +1.1 dB on TextureTransformTest,
    +4.2 on the duck, but the duck's whole model -1.1 (three silhouette pixels extrapolated, not sampled), and coded at
    crf 23 it loses on both (``docs/methods.md``), so off by default.

    ``live_refresh_frames`` (4; 0: off): live only (the renderer relights the GI probes at a rate, ``Renderer.gi_hz``
    > 0; virtual time and the ground truth relight them for every frame and are untouched), a P-frame gathers again
    only the triangles whose samples would be wrong, not only late: new to the atlas or in another cell (the table
    row that changed), of a moved object, near a moved shadow caster, or all of them when a light's intensity
    changed; the others keep their samples while the eye and the probes change, and each frame gathers again the
    longest-kept of them, at least a ``1 / live_refresh_frames`` share, so every triangle is gathered at most this
    many server frames after its last gathering (specular, texture filtering and indirect light lag by at most that).
    Without it a live ``tss`` gathers every PVS triangle every frame.
    """

    gop: int = 30
    samples_per_px: float = 1.0
    slant_threshold: float = 16.0
    tiny_samples: float = 2.0
    sliver_px: float = 0.0
    atlas_mpix_1080p: float = 24.0
    fov_margin: float = 0.2
    pvs_step_ms: float = 33.3
    pvs_prediction: Literal["linear", "none"] = "linear"
    pvs_linger_frames: int = 8
    pvs_max_samples: int = 8
    split_near_m: float = 2.0
    split_max_triangles: int = 200_000
    perspective: bool = True
    layout: Literal["stable", "prefix"] = "stable"
    high_water: float = 0.0
    hysteresis: float = 0.25
    os_grid: Literal["centred", "paper"] = "paper"
    single_px: int = 2
    spatial_order: bool = False
    gutter_fill: bool = True
    budget_px: float = 0.0
    budget_max_spp: float = 8.0
    flip_level: int = 0
    flip_cap: float = 0.0
    os_min_rows: float = 0.0
    os_min_step: float = 0.0
    pvs_ring: int = 0
    codec_block: int = 1
    fill_pitch: bool = False
    colour_order: float = 0.0
    lp_own: bool = True
    lp_filter: Literal["linear", "cubic"] = "linear"
    lp_inset: float = 0.0
    live_refresh_frames: int = 4

    def adapt_knobs(self) -> tuple[Knob, ...]:
        """The atlas budget: shading samples per covered pixel (``samples_per_px``), lowered in steps of about 0.7, or
        with a moving budget the frame's samples per display pixel (``budget_px``); then the server's frame rate (its
        prior tss's own, :data:`TSS_FRAME_DIV_COST`)."""
        frame_div = dataclasses.replace(FRAME_DIV_KNOB, cost=TSS_FRAME_DIV_COST)
        if self.budget_px > 0:
            return with_model((Knob("budget_px", tuple(round(self.budget_px * f, 4) for f in TSS_KNOB_STEPS),
                                    TSS_BUDGET_COST, "video", "shading samples per display pixel"), frame_div), QUALITY)
        return with_model((Knob("samples_per_px", tuple(round(max(0.05, self.samples_per_px * f), 4) for f in TSS_KNOB_STEPS),
                                TSS_BUDGET_COST, "video", "shading samples per covered pixel"), frame_div), QUALITY)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0.05 <= self.samples_per_px <= 8:
            raise ConfigError(f"TssConfig.samples_per_px: must be in [0.05, 8], got {self.samples_per_px}")
        if not 1.0 <= self.slant_threshold <= 1000:
            raise ConfigError(f"TssConfig.slant_threshold: must be in [1, 1000], got {self.slant_threshold}")
        if not 0.0 <= self.tiny_samples <= 64:
            raise ConfigError(f"TssConfig.tiny_samples: must be in [0, 64], got {self.tiny_samples}")
        if not (self.sliver_px == 0.0 or 1.0 <= self.sliver_px <= 1e4):
            raise ConfigError(f"TssConfig.sliver_px: must be 0 (off) or in [1, 10000] pixels, got {self.sliver_px}")
        if not 0.0 < self.atlas_mpix_1080p <= 64:
            raise ConfigError(f"TssConfig.atlas_mpix_1080p: must be in (0, 64], got {self.atlas_mpix_1080p}")
        if not 0.0 <= self.fov_margin <= 2.0:
            raise ConfigError(f"TssConfig.fov_margin: must be in [0, 2], got {self.fov_margin}")
        if not self.pvs_step_ms > 0:
            raise ConfigError(f"TssConfig.pvs_step_ms: must be > 0, got {self.pvs_step_ms}")
        if not 2 <= self.pvs_max_samples <= 1000:
            raise ConfigError(f"TssConfig.pvs_max_samples: must be in [2, 1000], got {self.pvs_max_samples}")
        if self.pvs_prediction not in ("linear", "none"):
            raise ConfigError(f"TssConfig.pvs_prediction: {self.pvs_prediction!r} is not one of ['linear', 'none']")
        if not 0 <= self.pvs_linger_frames <= 1000:
            raise ConfigError(f"TssConfig.pvs_linger_frames: must be in [0, 1000], got {self.pvs_linger_frames}")
        if not 0.0 <= self.split_near_m <= 1e3:
            raise ConfigError(f"TssConfig.split_near_m: must be in [0, 1000], got {self.split_near_m}")
        if self.layout not in ("stable", "prefix"):
            raise ConfigError(f"TssConfig.layout: {self.layout!r} is not one of ['stable', 'prefix']")
        if not 0.0 <= self.high_water <= 1.0:
            raise ConfigError(f"TssConfig.high_water: must be in [0, 1], got {self.high_water}")
        if not 0.0 <= self.hysteresis <= 1.0:
            raise ConfigError(f"TssConfig.hysteresis: must be in [0, 1], got {self.hysteresis}")
        if not 0 <= self.live_refresh_frames <= 1000:
            raise ConfigError(f"TssConfig.live_refresh_frames: must be in [0, 1000], got {self.live_refresh_frames}")
        if self.os_grid not in ("centred", "paper"):
            raise ConfigError(f"TssConfig.os_grid: {self.os_grid!r} is not one of ['centred', 'paper']")
        if self.single_px not in (1, 2, 4):
            raise ConfigError(f"TssConfig.single_px: must be 1, 2 or 4, got {self.single_px}")
        if not 0.0 <= self.budget_px <= 64:
            raise ConfigError(f"TssConfig.budget_px: must be in [0, 64] samples per display pixel, got {self.budget_px}")
        if not 0.05 <= self.budget_max_spp <= 16:
            raise ConfigError(f"TssConfig.budget_max_spp: must be in [0.05, 16], got {self.budget_max_spp}")
        if not 0 <= self.flip_level <= 64:
            raise ConfigError(f"TssConfig.flip_level: must be in [0, 64] (0: off), got {self.flip_level}")
        if not 0.0 <= self.flip_cap <= 64.0:
            raise ConfigError(f"TssConfig.flip_cap: must be in [0, 64] (0: off), got {self.flip_cap}")
        if not 0.0 <= self.os_min_rows <= 64.0:
            raise ConfigError(f"TssConfig.os_min_rows: must be in [0, 64] samples (0: off), got {self.os_min_rows}")
        if not 0.0 <= self.os_min_step <= 64.0:
            raise ConfigError(f"TssConfig.os_min_step: must be in [0, 64] pixels (0: off), got {self.os_min_step}")
        if self.codec_block not in (1, 2, 4, 8, 16):
            raise ConfigError(f"TssConfig.codec_block: must be 1 (off), 2, 4, 8 or 16 texels, got {self.codec_block}")
        if not 0 <= self.pvs_ring <= 8:
            raise ConfigError(f"TssConfig.pvs_ring: must be in [0, 8] rings of neighbours (0: off), got {self.pvs_ring}")
        if not 0.0 <= self.colour_order <= 255.0:
            raise ConfigError(f"TssConfig.colour_order: must be 0 (off) or a luma bin in (0, 255] 8-bit levels, "
                              f"got {self.colour_order}")
        if self.lp_filter not in ("linear", "cubic"):
            raise ConfigError(f"TssConfig.lp_filter: {self.lp_filter!r} is not one of ['linear', 'cubic']")
        if not 0.0 <= self.lp_inset <= 1.0:
            raise ConfigError(f"TssConfig.lp_inset: must be in [0, 1] half ring spacings (0: off), got {self.lp_inset}")
        if not 1 <= self.split_max_triangles <= 50_000_000:
            raise ConfigError(f"TssConfig.split_max_triangles: must be in [1, 5e7], got {self.split_max_triangles}")

    def client_sizes(self, display: CameraIntrinsics) -> tuple[ClientSize, ...]:
        """The atlas (``atlas_mpix_1080p``, against ``max_atlas_pixels``) and the tessellated scene the client keeps
        geometry and a table row for (``split_max_triangles``, against ``max_scene_triangles``; the session data's
        ``n_triangles`` is held to the same limit)."""
        w, h = self.atlas_size(display)
        return (ClientSize("atlas_mpix_1080p", "max_atlas_pixels", w * h, "texels",
                           f"the tss atlas {w}x{h} (atlas_mpix_1080p {self.atlas_mpix_1080p:g} at a "
                           f"{display.width}x{display.height} display)"),
                ClientSize("split_max_triangles", "max_scene_triangles", self.split_max_triangles, "triangles",
                           "the tessellated scene the tss client may hold"))

    def atlas_size(self, intr: CameraIntrinsics) -> tuple[int, int]:
        """The atlas for a display of ``intr``: 2:1, multiples of 16 texels."""
        texels = self.atlas_mpix_1080p * 1e6 * intr.width * intr.height / (1920 * 1080)
        h = max(1, round(math.sqrt(texels / 2) / 16)) * 16
        return 2 * h, h

    @property
    def top_rate(self) -> float:
        """The highest sampling rate a frame may use: ``samples_per_px``, or with a budget ``budget_max_spp``."""
        return max(self.samples_per_px, self.budget_max_spp) if self.budget_px > 0 else self.samples_per_px

    def split_edge_m(self, intr: CameraIntrinsics) -> float:
        """Longest edge (metres) kept at load time: an equilateral triangle with this edge,
        seen face-on from ``split_near_m``, needs at most ``v(64)`` samples."""
        if self.split_near_m <= 0:
            return math.inf
        px_per_rad = intr.width / math.radians(intr.fov_x_deg)
        max_area_px = 3169.0 / self.top_rate
        edge_px = math.sqrt(4.0 * max_area_px / math.sqrt(3.0))
        return edge_px / px_per_rad * self.split_near_m
