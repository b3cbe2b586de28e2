"""Settings of the ``quads`` method (QUASAR and its QuadStream baseline)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from ...errors import ConfigError
from ...limits import ClientSize
from ...scene.pose import CameraIntrinsics
from ..base import FRAME_DIV_KNOB, Knob, MethodConfig, QualityModel, with_model
from .packing import packed_size

Variant = Literal["quasar", "quadstream"]
Atlas = Literal["slots", "packed"]
ResidualMask = Literal["coverage", "depth"]


@dataclass(frozen=True)
class QuadParams:
    """Thresholds of one quad generation pass (paper section 3.2; units of the public code).

    - ``delta_max``: corner snapping and the coarse passes' depth-discontinuity test, in
      window depth (the ``[0, 1]`` depth-buffer value): a corner snaps to its neighbours'
      planes when their distance along the ray, as a window depth, is below it (1e-4 with
      a 5 cm near plane means "closer than the near distance"), and a coarse pass merges four
      quads whose centre depths differ by less than it in NDC;
    - ``delta_sim``: largest distance between two normalised plane equations ``(n, w)``
      (``w`` in metres) for a merge;
    - ``delta_flatten``: a quad is flat (no depth offsets sent) when all 16 offsets, in
      metres along the ray, are below it;
    - ``coarse_passes``: the first merge passes that also merge across no depth discontinuity.
    """

    delta_max: float = 1e-4
    delta_sim: float = 0.5
    delta_flatten: float = 0.2
    coarse_passes: int = 3

    def relaxed(self, factor: float, coarse_passes: int) -> "QuadParams":
        """The hidden layers' and wide view's thresholds: ``delta_sim`` and ``delta_flatten`` times ``factor``."""
        return QuadParams(self.delta_max, self.delta_sim * factor, self.delta_flatten * factor, coarse_passes)


QUAD_LAYER_COST = (1.0, 0.65)
"""Geometry and offsets at one layer over those at two (the knob's prior; ``benchmarks/bench_knobs.py``); each further
hidden layer dropped is taken to save as much."""
QUALITY = QualityModel(
    (("layers", (0.0, -0.13)), ("frame_div", (0.0, 0.49, 0.81, 1.38))),
    latency_db_per_100ms=0.64, rate_db_per_halving=0.82,
    measured="benchmarks/bench_knobs.py --quality, 2026-12-06, fb7ffbf: default+nogi, walk, 320x180, 2 s, delay 20ms, "
             "model PSNR after 0.5 s; frame_div again 2026-12-07 at 5e1a817 (--knobs frame_div)")
"""quads's quality model (:class:`~splitrender.methods.base.QualityModel`): model PSNR 23.96 dB at its own point;
the visible layer alone measures 0.13 dB *better* (the walk disoccludes little that the hidden layer holds) for 36 %
fewer bytes; +200 ms of motion-to-photon 1.28 dB; crf 29 (0.66x the colour atlas's bits) 0.50 dB.  Measured at the
default config (two layers).  One server frame in 2, 3, 5: 0.49, 0.81, 1.38 dB, measured again at 5e1a817 (its own
point 24.44 dB; ``benchmarks/results/bench_knobs_quality_quads_frame_div_2s.json``, the same figures as at 4a7a27a);
fb7ffbf's 0.32, 0.53, 0.99 had gone stale with quads's changes since."""


@dataclass(frozen=True)
class QuadsConfig(MethodConfig):
    """Settings of the ``quads`` method.

    - ``variant``: ``quasar`` (effective depth peeling, temporal compression) or
      ``quadstream`` (a cube view cell sampled by 10 views, the full set every frame);
    - ``view_cell_m``: the view cell's diameter (QUASAR: a sphere; QuadStream: a cube of this side);
    - ``layers``: G-buffer layers in all, the visible one included (QUASAR: at most 4).  The
      default is 2 (one hidden layer): on the default view the second hidden layer keeps
      1.2k fragments, 84 % of them seen from no eye in a 50 cm view cell, and on the
      default walk under ``cloud`` it cost 10-11 % of QUASAR's bits for 0.01-0.03 dB (the
      strafe, railing and latency-spike stress cases alike; see ``docs/methods.md``); a
      third held 9 of the 6.1k hidden fragments any eye sees;
    - ``wide_fov_deg``: vertical field of view of the wide G-buffer; 0 leaves it out;
    - ``wide_scale``: the wide G-buffer's resolution over the display's; ``None`` takes the
      variant's (QUASAR 1/2: 960x540 for 1080p; QuadStream 2/3: the paper's 1280x720);
    - ``delta_max``, ``delta_sim``, ``delta_flatten``, ``coarse_passes``: the visible layer's
      thresholds (:class:`QuadParams`); ``None`` takes the variant's defaults (QUASAR 1e-4,
      0.5, 0.2, 3; QuadStream 1e-4, 0.1, 0.05, 1);
    - ``relax``, ``relaxed_coarse_passes``: hidden layers and wide view merge with
      ``delta_sim`` and ``delta_flatten`` times ``relax`` and this many coarse passes
      (QUASAR: 10x, 4);
    - ``reference_every``: a reference frame every n frames; the others are residual
      frames (QUASAR only; 1 streams reference frames only);
    - ``reference_distance_m``, ``reference_angle_deg`` (QUASAR): a reference frame as soon as the
      target pose lies more than this far from the reference pose, or its view direction has turned
      more than this, whichever comes first with ``reference_every`` (section 3.5.1: "based on
      distance and angle thresholds"); 0 turns a threshold off;
    - ``reference_error_db`` (QUASAR): a frame that would be a residual frame is a reference frame when the
      cached mesh (its scene quads), drawn from the frame's pose with the reference view's colour at this time,
      scores below this PSNR (dB) against the frame's own render over the scene pixels it covers (0: off; a still
      camera never draws it).  A residual frame shows the cached quads in the reference view's colours, drawn
      from the reference pose up to ``reference_every - 1`` frames back, so it cannot follow shading that changes
      with the view: one server frame (5.5 cm) into 2CylinderEngine's orbit its exact quads score 22 dB, where the
      duck's cached mesh scores 31-35 dB and the default scene's 24-26 (issue 50: QUASAR trailed MeshWarp 60 on
      the engine's model under ``cloud``, its residual frames 0.5-1.9 dB behind and its reference frames level;
      ``benchmarks/bench_quads_models_budget.py``).  30 dB by default: the engine and the default scene then send
      reference frames (``orbit`` under ``cloud``, model 21.27 -> 21.80 and 24.23 -> 24.86 dB against MeshWarp 60's
      21.88 and 24.16, at 1.45x and 1.27x the bits); the duck and TextureTransformTest keep their residual frames,
      where those lead (the same model PSNR);
    - ``edp_tolerance``: relative depth slack of the parallax test;
    - ``atlas``: ``slots`` (QUASAR's linear packing: each G-buffer's colour whole, side by
      side; a quad's texels follow from its x and y) or ``packed`` (QuadStream's binning:
      the centre view whole at the top left, every later quad's own texels packed square by square around it,
      its atlas position sent with it, :mod:`.packing`); ``None`` takes the variant's own (QUASAR ``slots``, QuadStream
      ``packed``).  QUASAR needs ``slots`` (its cached quads keep slot 0);
    - ``residual_mask`` (QUASAR): which pixels of a residual frame get new quads.  ``coverage``
      (QUASAR's ``FrameGenerator``): scene pixels the cached mesh, less its background quads,
      does not cover from the current pose, grown by the 8 neighbours; background pixels get
      none (the client fills them).  ``depth`` (before issue 38): pixels uncovered by the
      whole mesh or whose surface lies more than 2 % in front of it, grown by 4 neighbours,
      background included: flat merged quads may sit up to ``delta_flatten`` (0.2 m) off
      the surface, more than 2 % of a few metres, so those pixels went again in every
      residual frame (4x QUASAR's residual quads on ``benchmarks/peer_quasar.py``);
    - ``hidden_sky_px`` (QUASAR): the client lays sky quads this far (pixels) behind the model's silhouette against
      the sky, each coloured by the nearest sky texel, so the sky a moving client reveals is drawn instead of a hole
      the fill paints with the model's colour (:func:`.mesh.hidden_sky`; :data:`.mesh.HIDDEN_SKY_PX` is the reach
      measured).  Off (0) by default: on the peer benchmark's comparable (lossless) runs 8 pixels brought the bleed
      over the sky from 12.3 to 4.3 % (Wuson) and 25.0 to 13.7 % (Spider) and the whole frame up 1.9-2.9 dB, but cost
      0.8-1.05 dB on the model, and the claims ledger measures the model region (QUASAR against MeshWarp 60, moving:
      duck -0.59 dB, TextureTransformTest -0.35 dB with it); docs/quasar.md has the trade;
    - ``background_quads`` (QUASAR): the visible layer's and the wide view's background (sky) pixels go on the
      wire as quads on a far plane.  Off by default, as in QUASAR's code, where a background pixel has no valid
      depth and makes no quad: the client makes those quads itself over the pixels its reference set (and each wide
      set, outside the main view) leaves uncovered, so it draws the same sky for no bytes (on 2CylinderEngine at
      320x180 they were 22-35 % of a reference frame's quads).  QuadStream's views keep theirs;
    - ``centre_guard`` (QuadStream): the client draws a later view's fragment only where, seen from the centre
      view's camera, it lies behind the centre view's own surface (:meth:`.mesh.QuadMeshGL.set_guard`), and the
      server masks each view with the earlier views' mesh drawn so.  On by default (issue 50: without it the later
      views' duplicates and silhouette overhang won the depth test over the centre view, 20.2 dB on 2CylinderEngine's
      model at the server's own pose, lossless, where the centre view alone is exact).  With it the centre view's
      quads also filter across their borders along a surface (:func:`.mesh.continuous_sides`);
    - ``silhouette_clamp`` (QUASAR): the reference set's colour lookup filters across quad borders only where the
      pixel beyond is the model (:func:`.mesh.scene_sides`), not into the sky texels beside the silhouette.  On by
      default (issue 50: on the peer benchmark's Spider, 40 % of our QUASAR's model error lay in covered silhouette
      pixels drawn as a blend of model and sky, where QUASAR's code, sampling its view nearest, has none);
    - ``sky_edge_px``: the client draws each of QuadStream's centre view's flat quads (QUASAR: its reference set's
      scene quads, :func:`.underlap.open_sides`) this many pixels past
      every side that borders the view's sky, on the quad's own plane (:func:`.mesh.sky_sides`), so that a display
      pixel whose centre lies on the model between the last model pixel and the true outline is covered from a
      nearby pose; ``seal_cracks``: QuadStream's centre view and QUASAR's reference set drawn 0.45 pixels past every
      side where the surface goes on (:func:`.mesh.sealed`), so that no crack opens between two flattened quads
      whose planes disagree at their shared border.  Off by default (issue 50: on the peer benchmark's Spider and
      Wuson, unlit, they take QuadStream's missed model pixels under twice QUASAR's code's and lift our QUASAR's
      model there, but on 2CylinderEngine+ground under ``cloud`` orbit they cost both variants 0.8-1.1 dB on the
      model; docs/quasar.md has the numbers.  QUASAR's code grows every view's outline by a whole pixel instead,
      ``expandEdges``);
    - ``underlap_px`` (QUASAR): the client draws each quad of the reference set this many pixels past every side
      along which its plane, carried on, lies behind the surface the set shows beyond it (:mod:`.underlap`), so
      that the sliver a depth edge opens seen from a nearby pose shows the farther surface rather than a hole; from
      the reference pose nothing changes (under half a pixel, hidden by the nearer surface).  0.45 by default (issue
      50: on the claims ledger's orbits under ``cloud``, model +0.15 dB on 2CylinderEngine, +0.41 duck, +0.02
      TextureTransformTest, +0.06 default, whole frame +0.13, +0.08, 0.00, +0.01; still cameras unchanged); 0 is off;
    - ``merge_scale``: every merge threshold (``delta_sim``, ``delta_flatten``, the hidden layers' too) times
      this;
    - ``chroma``: the atlas in 4:4:4 by default (at the bits of 4:2:0: model +2.1 dB, whole
      frame +1.6 dB, median of 12 cells, ``benchmarks/bench_chroma.py``).
    """

    chroma: str | int = "444"
    variant: Variant = "quasar"
    view_cell_m: float = 0.5
    layers: int = 2
    wide_fov_deg: float = 120.0
    wide_scale: float | None = None
    delta_max: float | None = None
    delta_sim: float | None = None
    delta_flatten: float | None = None
    coarse_passes: int | None = None
    relax: float = 10.0
    relaxed_coarse_passes: int = 4
    reference_every: int = 5
    reference_distance_m: float = 0.0
    reference_angle_deg: float = 0.0
    reference_error_db: float = 30.0
    edp_tolerance: float = 0.01
    atlas: Atlas | None = None
    merge_scale: float = 1.0
    residual_mask: ResidualMask = "coverage"
    background_quads: bool = False
    hidden_sky_px: int = 0
    centre_guard: bool = True
    silhouette_clamp: bool = True
    sky_edge_px: float = 0.0
    seal_cracks: bool = False
    underlap_px: float = 0.45

    def adapt_knobs(self) -> tuple[Knob, ...]:
        """Layers (the hidden ones dropped one by one: their quads unsent, their atlas slots black), then the
        server's frame rate.  (Wider merge thresholds, ``merge_scale``, and rarer reference frames saved 2-9 % and
        nothing on the default walk, ``benchmarks/bench_knobs.py``: residual frames there carry as many quads as
        reference ones; neither is a knob.)"""
        out = []
        if self.variant == "quasar" and self.layers > 1:
            levels = tuple(range(self.layers, 0, -1))
            out.append(Knob("layers", levels, tuple(QUAD_LAYER_COST[1] ** (i / (len(levels) - 1)) for i in range(len(levels))),
                            "data", "G-buffer layers sent (the hidden ones dropped)"))
        return with_model((*out, FRAME_DIV_KNOB), QUALITY)

    def __post_init__(self) -> None:
        super().__post_init__()
        n = type(self).__name__
        if self.variant not in ("quasar", "quadstream"):
            raise ConfigError(f"{n}.variant: {self.variant!r} is not one of ['quasar', 'quadstream']")
        if not 0.0 <= self.view_cell_m <= 10.0:
            raise ConfigError(f"{n}.view_cell_m: must be in [0, 10] metres, got {self.view_cell_m}")
        if not 1 <= self.layers <= 4:
            raise ConfigError(f"{n}.layers: must be 1 to 4 (the visible layer and up to 3 hidden ones), got {self.layers}")
        if self.wide_fov_deg != 0.0 and not 60.0 <= self.wide_fov_deg <= 170.0:
            raise ConfigError(f"{n}.wide_fov_deg: must be 0 (off) or in [60, 170] degrees, got {self.wide_fov_deg}")
        if self.wide_scale is not None and not 0.1 <= self.wide_scale <= 1.0:
            raise ConfigError(f"{n}.wide_scale: must be in [0.1, 1] (the wide view shares a display-sized slot), got {self.wide_scale}")
        for k in ("delta_max", "delta_sim", "delta_flatten"):
            v = getattr(self, k)
            if v is not None and not 0.0 <= v <= 100.0:
                raise ConfigError(f"{n}.{k}: must be in [0, 100], got {v}")
        if self.coarse_passes is not None and not 0 <= self.coarse_passes <= 12:
            raise ConfigError(f"{n}.coarse_passes: must be in [0, 12], got {self.coarse_passes}")
        if not 1.0 <= self.relax <= 1000.0:
            raise ConfigError(f"{n}.relax: must be in [1, 1000], got {self.relax}")
        if not 0 <= self.relaxed_coarse_passes <= 12:
            raise ConfigError(f"{n}.relaxed_coarse_passes: must be in [0, 12], got {self.relaxed_coarse_passes}")
        if not 0.1 <= self.merge_scale <= 100:
            raise ConfigError(f"{n}.merge_scale: must be in [0.1, 100], got {self.merge_scale}")
        if self.residual_mask not in ("coverage", "depth"):
            raise ConfigError(f"{n}.residual_mask: {self.residual_mask!r} is not one of ['coverage', 'depth']")
        if not 1 <= self.reference_every <= 1000:
            raise ConfigError(f"{n}.reference_every: must be in [1, 1000], got {self.reference_every}")
        if not 0.0 <= self.reference_distance_m <= 100.0:
            raise ConfigError(f"{n}.reference_distance_m: must be in [0, 100] metres (0: off), got {self.reference_distance_m}")
        if not 0.0 <= self.reference_angle_deg <= 180.0:
            raise ConfigError(f"{n}.reference_angle_deg: must be in [0, 180] degrees (0: off), got {self.reference_angle_deg}")
        if not 0.0 <= self.reference_error_db <= 100.0:
            raise ConfigError(f"{n}.reference_error_db: must be in [0, 100] dB (0: off), got {self.reference_error_db}")
        if self.atlas not in (None, "slots", "packed"):
            raise ConfigError(f"{n}.atlas: {self.atlas!r} is not one of ['slots', 'packed']")
        if self.variant == "quasar" and self.atlas == "packed":
            raise ConfigError(f"{n}.atlas: 'packed' is QuadStream's atlas; QUASAR's cached quads need 'slots'")
        if isinstance(self.hidden_sky_px, bool) or not isinstance(self.hidden_sky_px, int) or not 0 <= self.hidden_sky_px <= 64:
            raise ConfigError(f"{n}.hidden_sky_px: must be an integer in [0, 64] pixels (0: off), got {self.hidden_sky_px!r}")
        if not 0.0 <= self.sky_edge_px < 0.5:
            raise ConfigError(f"{n}.sky_edge_px: must be in [0, 0.5) pixels (0: off), got {self.sky_edge_px}")
        if not 0.0 <= self.underlap_px < 0.5:
            raise ConfigError(f"{n}.underlap_px: must be in [0, 0.5) pixels (0: off), got {self.underlap_px}")
        if not 0.0 <= self.edp_tolerance < 0.5:
            raise ConfigError(f"{n}.edp_tolerance: must be in [0, 0.5), got {self.edp_tolerance}")

    @property
    def atlas_slots(self) -> int:
        """Display-sized slots of the atlas: QuadStream's 9 views, or QUASAR's visible layer, its revealed pixels
        (with residual frames), its hidden layers; and the wide view."""
        wide = 1 if self.wide_fov_deg else 0
        if self.variant == "quadstream":
            return 9 + wide
        return 1 + (1 if self.reference_every > 1 else 0) + (self.layers - 1) + wide

    def atlas_wh(self, display: CameraIntrinsics) -> tuple[int, int]:
        """The atlas for a display of ``display``: its slots in two rows (one for a single slot), or QuadStream's
        packed atlas (at most 4096 a side)."""
        slots = self.atlas_slots
        rows = 1 if slots == 1 else 2
        cols = math.ceil(slots / rows)
        w, h = display.width, display.height
        if self.atlas_layout == "packed":
            wide = max(2, int(w * self.wide_res / 2) * 2) * max(2, int(h * self.wide_res / 2) * 2) if self.wide_fov_deg else 0
            try:
                return packed_size(w, h, (slots - (1 if self.wide_fov_deg else 0)) * w * h + wide, w * cols)
            except ConfigError:   # a view wider than the packed atlas can address: the server refuses it
                pass
        return w * cols, h * rows

    def client_sizes(self, display: CameraIntrinsics) -> tuple[ClientSize, ...]:
        """The atlas (against ``max_atlas_pixels``), named by ``variant`` for QuadStream's ten views, else by
        ``layers``."""
        w, h = self.atlas_wh(display)
        field = "variant" if self.variant == "quadstream" else "layers"
        return (ClientSize(field, "max_atlas_pixels", w * h, "texels",
                           f"the quads atlas {w}x{h} ({self.atlas_slots} views of a {display.width}x{display.height} "
                           f"display: variant {self.variant}, layers {self.layers}, "
                           f"{'a wide view' if self.wide_fov_deg else 'no wide view'}, atlas {self.atlas_layout})"),)

    @property
    def params(self) -> QuadParams:
        """The visible layer's thresholds, the variant's defaults filled in."""
        d = QuadParams() if self.variant == "quasar" else QuadParams(1e-4, 0.1, 0.05, 1)
        m = self.merge_scale
        return QuadParams(d.delta_max if self.delta_max is None else self.delta_max,
                          m * (d.delta_sim if self.delta_sim is None else self.delta_sim),
                          m * (d.delta_flatten if self.delta_flatten is None else self.delta_flatten),
                          d.coarse_passes if self.coarse_passes is None else self.coarse_passes)

    @property
    def wide_res(self) -> float:
        """The wide G-buffer's resolution scale, the variant's own filled in."""
        if self.wide_scale is not None:
            return self.wide_scale
        return 2.0 / 3.0 if self.variant == "quadstream" else 0.5

    @property
    def atlas_layout(self) -> Atlas:
        """The atlas layout, the variant's own filled in."""
        if self.atlas is not None:
            return self.atlas
        return "packed" if self.variant == "quadstream" else "slots"

    @property
    def hidden_params(self) -> QuadParams:
        """Thresholds of hidden layers and the wide view."""
        return self.params.relaxed(self.relax, self.relaxed_coarse_passes)
