"""The ``quads`` server half: G-buffers at the predicted pose, quads, atlas, temporal compression.

**QUASAR** per frame (paper sections 3.2-3.5):

1. the visible G-buffer at the predicted pose; on a **reference frame** (every
   ``reference_every`` frames, when the pose has moved or turned past ``reference_distance_m`` or
   ``reference_angle_deg`` from the reference pose, on a keyframe request, after a reported loss, or when the
   cached mesh drawn from the frame's pose in the reference view's colour scores below ``reference_error_db``
   against the frame's own render, :meth:`QuadsServer._residual_psnr`) its quads
   (its background too only with ``background_quads``: by default, as in QUASAR's code, the
   client makes the sky's quads itself) are the client's new reference set, its colour atlas slot 0;
2. on a **residual frame**: the G-buffer at the reference pose and the current time;
   pixels whose depth or normal changed since what the client holds get quads
   (``update``, cached by the client; the render's colour refreshes slot 0 for all
   cached quads), then the G-buffer at the current pose is masked by the cached mesh
   drawn from that pose, and the scene pixels it does not cover, grown by their 8
   neighbours, get quads (``revealed``, slot 1; ``residual_mask = "coverage"``, QUASAR's
   rule; ``"depth"`` also resends pixels more than 2 % in front of the mesh, and the
   background);
3. **hidden layers** by depth peeling from the visible layer, each kept where the
   parallax test (:mod:`.edp`) says an eye in the view sphere could see it, merged with
   relaxed thresholds;
4. the **wide view** (``wide_fov_deg``, half resolution): only its pixels outside the
   main view's frustum get quads.

**QuadStream**: views at the centre and the eight corners of a cube of side
``view_cell_m`` plus the wide view, each masked by the mesh of the views before it (with
one-pixel boundary expansion), the full set every frame; by default its atlas is packed
quad by quad (:mod:`.packing`), each quad's atlas position on the wire.  With ``centre_guard`` (the default) the
mesh that masks a view is drawn as the client draws it: the later views behind the centre view
(:meth:`.mesh.QuadMeshGL.set_guard`).
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np
from scipy.ndimage import binary_dilation, maximum_filter

from ...render.canvas import upload_image
from ...scene.pose import CameraIntrinsics, Pose
from ..base import DataStreamSpec, ServerContext, ServerHalf, StreamSpec, Update
from .accounting import quasar_frame_bytes
from .config import QuadsConfig
from .edp import edp_keep
from .gen import BACKGROUND_FAR, QuadSet, generate, rays
from .mesh import (VERTEX_FLOATS, QuadMeshGL, ReferenceCache, build_mesh, index_map_of, join_meshes, scene_sides,
                   select)
from .underlap import reference_extend
from .packing import copy_texels, fitting, pack_squares, packed_size, source_order, tile_side, whole_tiles
from .wire import (KIND_HIDDEN, KIND_REFERENCE, KIND_REVEALED, KIND_UPDATE, KIND_VIEW, KIND_WIDE, WIRE_VERSION, WireSet,
                   encode_camera, encode_sets)

log = logging.getLogger(__name__)
RESIDUAL_PSNR_CAP_DB = 60.0
"""The ``residual_psnr_db`` statistic's ceiling (``metrics.PSNR_CAP_DB``, which a method half does not import)."""
META_VERSION = 1
CHANGE_REL = 0.01
"""A reference pixel changed when its depth moved by more than this fraction (or its normal by more than ~8 degrees)."""
STAGES = ("gbuffer_ms", "quadgen_ms", "merge_ms", "edp_ms", "mask_ms")
"""Server stages timed per frame (``srv_<stage>``; packing adds ``pack_ms``)."""
MASK_REL = 0.02
"""A pixel of a new view is explained by the cached mesh when their depths agree within this fraction."""
PARTIAL_TEST = True
"""The residual-error test shades the reference view first only where the cached mesh, drawn in the last colour sent
at the reference pose, errs most, and stops there when those pixels alone put the frame under
``reference_error_db`` (:meth:`QuadsServer._partial_verdict`: the same verdicts, the view shaded whole otherwise)."""
PARTIAL_TARGET = 1.3
"""The blocks shaded first carry this many times the error the threshold allows, by the last colour's estimate."""
PARTIAL_BLOCK = 16
"""The partial test's blocks (pixels a side); each is shaded grown by an eighth of it (a frame's parallax)."""
PARTIAL_MAX = 0.5
"""More than this share of the blocks needed: the view is shaded whole at once (the frame is likely residual)."""
ESTIMATE_MARGIN_DB = 2.0
"""The residual-error test's estimate (the cached mesh drawn in the last colour sent at the reference pose, the view a
frame or more earlier: :meth:`QuadsServer._estimate`) decides a reference frame alone when it scores this far under
``reference_error_db``: the reference view at this time is then neither drawn nor shaded.  Not a bound (the scene's
shading at the reference pose may change between the two times), a margin: the estimate lies under the exact test,
within 0.3 dB on the default scene's walk, strafe and orbit and the duck's orbit at 320x180 (the walk 24.0-25.0 dB
against 24.2-25.1), 0.6 dB on the fast walk and the turns' frames near 30 dB, 1.1 dB with the ball crossing a creeping
camera's view and 1.25 dB while the sun dims (``docs/methods.md``).  Only while the lights and the scene's version are
as they were when that colour was drawn (:func:`lights_at`): a light's change leaves the exact test to decide.  0: off
(every verdict from the exact test)."""

QS_EXPAND_EDGES = False
"""QuadStream's views grow every silhouette by a pixel, as ``qs_simulator`` does (``expandEdges``, QUASAR's
``gen_quadmap.comp``): a background pixel with a valid 8-neighbour becomes a quad at the farthest such neighbour's
depth and normal, with its colour (:func:`expand_edges`).  Off by default (issue 50: measured on the peer benchmark
only, ``docs/quasar.md``)."""


def expand_edges(color: np.ndarray, depth: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``color``, ``depth`` and ``normal`` with every background pixel (non-finite depth) that has a valid
    8-neighbour given the farthest such neighbour's depth, normal and colour (QUASAR's ``expandEdges``)."""
    valid = np.isfinite(depth) & (depth > 0)
    if valid.all() or not valid.any():
        return color, depth, normal
    h, w = depth.shape
    ys, xs = np.mgrid[0:h, 0:w]
    best = np.full((h, w), -np.inf)
    by, bx = ys.copy(), xs.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy == 0 and dx == 0:
                continue
            sy, sx = np.clip(ys + dy, 0, h - 1), np.clip(xs + dx, 0, w - 1)
            d = np.where(valid[sy, sx], depth[sy, sx], -np.inf)
            better = d > best
            best = np.where(better, d, best)
            by, bx = np.where(better, sy, by), np.where(better, sx, bx)
    grow = ~valid & np.isfinite(best)
    color, depth, normal = color.copy(), depth.copy(), normal.copy()
    color[grow] = color[by[grow], bx[grow]]
    depth[grow] = best[grow]
    normal[grow] = normal[by[grow], bx[grow]]
    return color, depth, normal


def slot_grid(n_slots: int) -> tuple[int, int]:
    """(columns, rows) of the atlas: two rows (one for a single slot)."""
    rows = 1 if n_slots == 1 else 2
    return math.ceil(n_slots / rows), rows


def n_slots(cfg: QuadsConfig) -> int:
    """The atlas's display-sized slots (:attr:`QuadsConfig.atlas_slots`, which the client's limits check too)."""
    return cfg.atlas_slots


def wide_intrinsics(intr: CameraIntrinsics, fov_y_deg: float, scale: float = 0.5) -> CameraIntrinsics:
    """The wide G-buffer: ``fov_y_deg`` vertically at ``scale`` times the display's resolution (even sizes)."""
    return CameraIntrinsics(max(2, int(intr.width * scale / 2) * 2), max(2, int(intr.height * scale / 2) * 2), fov_y_deg,
                            intr.near_m, intr.far_m)


def colour_ring(emit: np.ndarray) -> np.ndarray:
    """The pixels whose colour a masked slot sends: ``emit`` and one pixel around it (the client's bilinear lookup
    reaches half a texel past a quad's edge)."""
    return binary_dilation(emit, structure=np.ones((3, 3), bool))


def masked_colour(color: np.ndarray, emit: np.ndarray, ring: np.ndarray | None = None) -> np.ndarray:
    """A masked slot's colour: ``color`` at :func:`colour_ring` of ``emit`` (``ring`` when given), black elsewhere."""
    if ring is None:
        ring = colour_ring(emit)
    return np.where(ring[..., None], color, 0).astype(np.uint8)


def outside_frustum(wide: CameraIntrinsics, main: CameraIntrinsics) -> np.ndarray:
    """(H, W) bool: wide-view pixels whose ray falls outside the main view's image (same pose)."""
    ys, xs = np.mgrid[0:wide.height, 0:wide.width].astype(np.float64)
    d = rays(wide, xs + 0.5, ys + 0.5)
    f = main.focal_px()
    u = d[..., 0] / -d[..., 2] * f + main.width / 2
    v = -d[..., 1] / -d[..., 2] * f + main.height / 2
    return ~((u >= 0) & (u < main.width) & (v >= 0) & (v < main.height))


def timeless(scene: Any) -> bool:
    """Whether ``scene`` renders the same at every time: nothing moves, no light's intensity changes and no GI
    probes are relit (a render at one pose is then the same bytes at any time)."""
    const = scene.light_intensities()
    return not scene.dynamic_ids() and all(len(s.values) == 1 for s in const) and scene.gi == "none"


def lights_at(scene: Any, t_s: float) -> tuple[Any, ...]:
    """The scene's version and its lights' intensities at ``t_s``: where two times give the same, a view's shading
    changes between them only with what moves (:data:`ESTIMATE_MARGIN_DB`)."""
    return (scene.version, *(s.value(t_s) for s in scene.light_intensities()))


def same_pose(a: Pose, b: Pose) -> bool:
    """Whether ``a`` and ``b`` are the same pose to the bit (a render from either is the same)."""
    return bool(np.array_equal(a.position, b.position) and np.array_equal(a.orientation, b.orientation))


class QuadsServer(ServerHalf):
    """QUASAR or QuadStream, one session."""

    config: QuadsConfig

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        cfg = self.config
        self.slots = n_slots(cfg)
        self.cols, self.rows = slot_grid(self.slots)
        self.wide = wide_intrinsics(self.intrinsics, cfg.wide_fov_deg, cfg.wide_res) if cfg.wide_fov_deg else None
        i = self.intrinsics
        self.packed: tuple[int, int] | None = None
        if cfg.atlas_layout == "packed":
            views = [i] * (self.slots - (1 if self.wide else 0)) + ([self.wide] if self.wide else [])
            self.packed = packed_size(i.width, i.height, sum(v.width * v.height for v in views), i.width * self.cols)
        self.atlas_wh = self.packed or (i.width * self.cols, i.height * self.rows)
        self._wide_out = outside_frustum(self.wide, self.intrinsics) if self.wide else None
        self.cache = ReferenceCache()
        self._ref_due = True
        self._ref_depth: np.ndarray | None = None
        self._ref_normal: np.ndarray | None = None
        self._ref_view: tuple[Any, int] | None = None   # a timeless scene's reference G-buffer and scene version
        self._views: dict[tuple[Any, ...], tuple[Any, Any]] = {}      # last frame's G-buffers of a timeless scene
        self._views_now: dict[tuple[Any, ...], tuple[Any, Any]] = {}  # this frame's (peel input, G-buffer) by view
        self._mesh: QuadMeshGL | None = None
        self._colour_tex: Any = None
        self._part_tex: Any = None      # the partial test's last colour at the reference pose, and its exact mask
        self._ref_colour: np.ndarray | None = None     # the colour last sent at the reference pose (slot 0)
        self._ref_colour_at: tuple[Any, ...] = ()       # its scene version and lights (:func:`lights_at`)
        self._stats: dict[str, float] = {}
        self.last_sets: list[WireSet] = []

    # ------------------------------------------------------------------ session
    def streams(self) -> list[Any]:
        return [StreamSpec("atlas", self.config.video(self.server_fps), *self.atlas_wh),
                DataStreamSpec("quads"), DataStreamSpec("offsets")]

    def session_data(self) -> dict[str, Any]:
        d = {"v": META_VERSION, "wire": WIRE_VERSION, "variant": self.config.variant, "slots": self.slots,
             "cols": self.cols, "rows": self.rows, "slot_size": [self.intrinsics.width, self.intrinsics.height]}
        if self.packed is not None:
            d["packed_atlas"] = list(self.packed)
        return d

    def stats(self) -> dict[str, float]:
        return dict(self._stats)

    # ------------------------------------------------------------------ helpers
    def _slot_origin(self, slot: int) -> tuple[int, int]:
        return (slot % self.cols) * self.intrinsics.width, (slot // self.cols) * self.intrinsics.height

    def _place(self, atlas: np.ndarray, slot: int, img: np.ndarray) -> None:
        x, y = self._slot_origin(slot)
        atlas[y:y + img.shape[0], x:x + img.shape[1]] = img

    def _gbuffer(self, ctx: ServerContext, pose: Pose, intr: CameraIntrinsics, times: dict[str, float],
                 peel: np.ndarray | None = None, colour: bool = True) -> Any:
        """Depth, normals and (with ``colour``) colour at ``pose``; the time goes to ``times["gbuffer_ms"]``.  A
        :func:`timeless` scene's view drawn last frame (a still camera) is that frame's G-buffer (the same bytes).

        Drawn in two passes, the G-buffer unshaded then its surfaces shaded (``Renderer.shade``: the same bytes as
        one pass, each visible fragment shaded once); ``colour=False`` leaves the second to :meth:`_colour`, for
        the pixels that need it.  A supersampled renderer draws one pass (its colour is a block mean)."""
        key = None
        if timeless(self.scene):   # the same view of a timeless scene as last frame's (a still camera): kept from it
            key = (pose.position.tobytes(), pose.orientation.tobytes(), intr, colour, self.scene.version,
                   ctx.renderer.supersample)
            hit = self._views.get(key)
            if hit is not None and hit[0] is peel:     # a peeled layer: behind the very same layer
                self._views_now[key] = hit
                return hit[1]
        t0 = time.perf_counter()
        r = ctx.renderer
        if colour and peel is None and r.supersample != 1:
            g = r.render(self.scene, ctx.t_s, pose, intr, ("color", "depth", "normal"))
        else:
            g = r.render(self.scene, ctx.t_s, pose, intr, ("depth", "normal"), peel=peel)
            if colour:
                g.color = r.shade(g)
        times["gbuffer_ms"] += (time.perf_counter() - t0) * 1e3
        if key is not None:
            self._views_now[key] = (peel, g)
        return g

    def _colour(self, ctx: ServerContext, g: Any, where: np.ndarray, times: dict[str, float]) -> None:
        """``g.color`` (a G-buffer drawn without it) at the pixels ``where``; the time goes to ``gbuffer_ms``.  A
        G-buffer kept from the last frame (:meth:`_gbuffer`) already coloured at the same pixels keeps its colour."""
        done = getattr(g, "quads_where", None)
        if done is not None and np.array_equal(done, where):
            return
        t0 = time.perf_counter()
        g.color = ctx.renderer.shade(g, where)
        g.quads_where = where
        times["gbuffer_ms"] += (time.perf_counter() - t0) * 1e3

    def _start(self) -> tuple[dict[str, float], np.ndarray]:
        """A frame's stage times (all zero) and its empty atlas."""
        self._stats = {}
        self._views, self._views_now = self._views_now, {}
        return dict.fromkeys(STAGES, 0.0), np.zeros((self.atlas_wh[1], self.atlas_wh[0], 3), np.uint8)

    def _gl_mesh(self, ctx: ServerContext) -> QuadMeshGL:
        if self._mesh is None:
            self._mesh = QuadMeshGL(ctx.renderer.ctx)
        return self._mesh

    def _mesh_depth(self, ctx: ServerContext, parts: list[tuple[np.ndarray, np.ndarray]], pose: Pose,
                    intr: CameraIntrinsics) -> np.ndarray:
        mesh = self._gl_mesh(ctx)
        mesh.upload(*join_meshes(parts))
        return mesh.depth_at(pose, intr)

    def _unexplained(self, depth: np.ndarray, mesh_z: np.ndarray) -> np.ndarray:
        """Pixels the mesh does not explain: uncovered, or whose surface lies more than :data:`MASK_REL`
        in front of the mesh (a surface behind the mesh would not show from here; background
        pixels stand on the far plane the visible layer gives them)."""
        zd = np.where(np.isfinite(depth), depth, BACKGROUND_FAR * self.intrinsics.far_m)
        return ~np.isfinite(mesh_z) | (zd < mesh_z * (1.0 - MASK_REL))

    def _reference_due(self, ctx: ServerContext) -> bool:
        fb = ctx.feedback
        lost = any(fb.newly_lost(s) for s in ("atlas", "quads", "offsets"))
        cfg = self.config
        if (self._ref_due or ctx.keyframe_requested or lost or cfg.reference_every == 1
                or ctx.frame_id - self.cache.frame_id >= cfg.reference_every):
            return True
        ref = self.cache.pose
        if ref is None:
            return True
        pose = ctx.target_pose
        return ((cfg.reference_distance_m > 0 and pose.distance_m(ref) > cfg.reference_distance_m)
                or (cfg.reference_angle_deg > 0 and pose.angle_deg(ref) > cfg.reference_angle_deg))

    # ------------------------------------------------------------------ produce
    def produce(self, ctx: ServerContext) -> Update:
        if self.config.variant == "quadstream":
            return self._produce_quadstream(ctx)
        return self._produce_quasar(ctx)

    def _hidden_and_wide(self, ctx: ServerContext, pose: Pose, front: Any, first_slot: int, cam: int, wide_cam: int,
                         sets: list[WireSet], atlas: np.ndarray, times: dict[str, float]) -> None:
        cfg, intr = self.config, self.intrinsics
        hp = cfg.hidden_params
        prev = front.depth
        radius = cfg.view_cell_m / 2
        for k in range(1, cfg.layers):
            g = self._gbuffer(ctx, pose, intr, times, peel=prev, colour=False)
            t1 = time.perf_counter()
            keep = edp_keep(front.depth, g.depth, intr, radius, cfg.edp_tolerance)
            q = generate(g.depth, g.normal, pose.view_matrix()[:3, :3], intr, hp, emit=keep)
            times["edp_ms"] += (time.perf_counter() - t1) * 1e3 - q.stats["gen_ms"] - q.stats["merge_ms"]
            self._account(times, q)
            self._stats[f"hidden{k}_fragments"] = float(np.isfinite(g.depth).sum())
            self._stats[f"hidden{k}_kept"] = float(keep.sum())
            sets.append(WireSet(KIND_HIDDEN, first_slot + k - 1, cam, q))
            ring = colour_ring(keep)
            self._colour(ctx, g, ring, times)     # the layer's colour is sent only there: shaded only there
            self._place(atlas, first_slot + k - 1, masked_colour(g.color, keep, ring))
            prev = g.depth
            if not np.isfinite(g.depth).any():
                break
        if self.wide is not None:
            g = self._gbuffer(ctx, pose, self.wide, times)
            q = generate(g.depth, g.normal, pose.view_matrix()[:3, :3], self.wide, hp, emit=self._wide_out,
                         background=cfg.background_quads)
            self._account(times, q)
            sets.append(WireSet(KIND_WIDE, self.slots - 1, wide_cam, q))
            self._place(atlas, self.slots - 1, g.color)

    @staticmethod
    def _account(times: dict[str, float], q: QuadSet) -> None:
        times["quadgen_ms"] += q.stats["gen_ms"]
        times["merge_ms"] += q.stats["merge_ms"]

    def _upload_cached(self, ctx: ServerContext, ref_pose: Pose) -> None:
        """The residual-error test's mesh uploaded: the cached quads' scene quads, as the client holds them before this
        frame's update (drawn as the client draws them)."""
        intr = self.intrinsics
        cached = self.cache.quads
        assert cached is not None
        scene = select(cached, ~cached.background(intr))
        if self.config.silhouette_clamp:   # as the client draws it (the set's pixel map rasterised once for both)
            im = index_map_of(scene, intr)
            part = build_mesh(scene, ref_pose, intr, (0, 0), "quad", grow=scene_sides(scene, intr, im),
                              extend=reference_extend(scene, intr, self.config, im))
        else:
            part = build_mesh(scene, ref_pose, intr, (0, 0), "view")
        self._gl_mesh(ctx).upload(*join_meshes([part]))

    def _estimate(self, ctx: ServerContext, pose: Pose, g0: Any) -> tuple[np.ndarray, np.ndarray, float] | None:
        """The uploaded mesh (:meth:`_upload_cached`) drawn from ``pose`` in the last colour sent at the reference pose
        (:attr:`_ref_colour`: the view a frame or more earlier) against this frame's render ``g0``: (its squared
        error per pixel (H, W) int64, 0 where it covers no scene pixel; the pixels it covers; its PSNR in dB, inf
        where it covers none), or None before any colour was sent or where neither :data:`PARTIAL_TEST` nor
        :data:`ESTIMATE_MARGIN_DB` uses it."""
        if self._ref_colour is None or not (PARTIAL_TEST or ESTIMATE_MARGIN_DB > 0):
            return None
        est = self._mesh_rgba(ctx, pose, self._ref_colour)
        px = (est[..., 3] > 0) & np.isfinite(g0.depth)
        d = est[..., :3].astype(np.int16) - g0.color
        err = np.einsum("ijk,ijk->ij", d, d, dtype=np.int64) * px
        n = int(px.sum())
        sse = int(err.sum())
        psnr = math.inf if n == 0 else 10 * math.log10(255.0 ** 2 * 3 * n / max(sse, 3 * n * 1e-10))
        return err, px, psnr

    def _residual_psnr(self, ctx: ServerContext, pose: Pose, g0: Any, gr: Any,
                       est: tuple[np.ndarray, np.ndarray, float] | None = None) -> float:
        """What a residual frame would show from ``pose`` of the scene pixels its cached quads cover: the cached
        mesh (uploaded, :meth:`_upload_cached`) drawn from ``pose`` with the reference view's colour at this time
        (``gr``), its PSNR (dB) against this frame's own render ``g0`` over the scene pixels it covers (inf when it
        covers none).  The revealed quads fill the rest from ``pose`` itself.  ``est``: :meth:`_estimate`'s."""
        if gr.color.size == 0:      # drawn without colour (PARTIAL_TEST): shaded part first, whole when undecided
            bound = self._partial_verdict(ctx, pose, g0, gr, est)
            if bound is not None:
                return bound
        rgba = self._mesh_rgba(ctx, pose, gr.color)
        px = (rgba[..., 3] > 0) & np.isfinite(g0.depth)
        if not px.any():
            return math.inf
        mse = float(((rgba[..., :3][px].astype(np.float64) - g0.color[px].astype(np.float64)) ** 2).mean())
        return 10 * math.log10(255.0 ** 2 / max(mse, 1e-10))

    def _mesh_rgba(self, ctx: ServerContext, pose: Pose, img: np.ndarray) -> np.ndarray:
        """The uploaded mesh drawn from ``pose`` in ``img`` (a colour at the reference view's pixels; (H, W, 4): its
        alpha drawn filtered as the colour is): (H, W, 4), top row first, alpha 255 where it covers (``img``'s
        filtered alpha there when it has one), 0 elsewhere."""
        intr = self.intrinsics
        tex = self._colour_tex = upload_image(ctx.renderer.ctx, img, self._colour_tex, linear=True)
        _, color, _ = self._gl_mesh(ctx).draw(pose, intr, tex, (intr.width, intr.height), atlas_alpha=img.shape[2] == 4)
        return np.frombuffer(color.read(), np.uint8).reshape(intr.height, intr.width, 4)[::-1]

    def _partial_blocks(self, est: tuple[np.ndarray, np.ndarray, float]) -> np.ndarray | None:
        """(H, W) bool: the blocks of :data:`PARTIAL_BLOCK` pixels to shade first, where the estimate ``est``
        (:meth:`_estimate`: the cached mesh drawn in the last colour sent at the reference pose) errs most against
        this frame's render, until they carry :data:`PARTIAL_TARGET` times the error the threshold allows; None where
        that takes more than :data:`PARTIAL_MAX` of them (or nothing is covered).  An estimate: which texels are
        shaded changes no verdict, only how soon one is reached.  (Drawn at half the size, it ranked the blocks by
        their edges: 40 % of them at 640x360 where the whole size needs 15-24 %.)"""
        intr = self.intrinsics
        h, w = intr.height, intr.width
        err, px, _ = est
        b = PARTIAL_BLOCK
        hb, wb = -(-h // b), -(-w // b)
        blocks = np.zeros((hb * b, wb * b), np.int64)
        blocks[:h, :w] = err
        per = blocks.reshape(hb, b, wb, b).sum((1, 3)).ravel()
        allowed = 3 * int(px.sum()) * 255.0 ** 2 / 10 ** (self.config.reference_error_db / 10)
        order = np.argsort(-per, kind="stable")
        k = int(np.searchsorted(np.cumsum(per[order]), PARTIAL_TARGET * allowed)) + 1
        if not px.any() or k > PARTIAL_MAX * per.size:
            return None
        chosen = np.zeros(per.size, bool)
        chosen[order[:k]] = True
        return np.repeat(np.repeat(chosen.reshape(hb, wb), b, 0), b, 1)[:h, :w]

    def _partial_verdict(self, ctx: ServerContext, pose: Pose, g0: Any, gr: Any,
                         est: tuple[np.ndarray, np.ndarray, float] | None) -> float | None:
        """The residual-error test's verdict from part of the reference view ``gr`` (drawn without colour): an upper
        bound of its PSNR (dB) when that part alone puts it under ``reference_error_db`` (a reference frame), else
        None with ``gr.color`` shaded whole (the same bytes as one pass) for the exact test.

        The squared error only grows with the pixels counted and their number is known from coverage alone, so the
        pixels drawn from shaded texels only bound it from below.  The texels shaded first: :meth:`_partial_blocks`
        grown by an eighth of a block (a frame's parallax).  Which pixels are exact: the colour is drawn with an
        alpha of 255 on the shaded texels shrunk by one and 128 elsewhere, so a pixel's filtered alpha is over 128
        only where one of its bilinear taps lies in the shrunk set, and then all four lie in the shaded one."""
        r = ctx.renderer
        core = None if est is None else self._partial_blocks(est)
        if core is None:
            gr.color = r.shade(gr)
            return None
        grow = max(1, PARTIAL_BLOCK // 8)
        core = core.astype(np.uint8)
        shaded = maximum_filter(core, size=2 * grow + 1) > 0
        part = r.shade(gr, shaded)
        alpha = np.uint8(128) + maximum_filter(core, size=2 * grow - 1) * np.uint8(127)
        got = self._mesh_rgba(ctx, pose, np.dstack([part, alpha]))
        px = (got[..., 3] > 0) & np.isfinite(g0.depth)
        at = px & (got[..., 3] > 128)
        n = int(px.sum())
        d = got[..., :3][at].astype(np.int32) - g0.color[at]
        sse = int(np.einsum("ij,ij->", d, d, dtype=np.int64))
        if sse > 3 * n * 255.0 ** 2 / 10 ** (self.config.reference_error_db / 10) * (1 + 1e-6):
            self._stats["residual_psnr_partial"] = float(at.sum()) / float(n)
            return 10 * math.log10(255.0 ** 2 * 3 * n / sse)
        rest = r.shade(gr, ~shaded)
        gr.color = np.where(shaded[..., None], part, rest)
        return None

    def _reference_view(self, ctx: ServerContext, pose: Pose, ref_pose: Pose, g0: Any, times: dict[str, float],
                        colour: bool = True) -> Any:
        """The G-buffer at the reference pose and this time: the one just drawn when the eye has not moved since the
        reference frame, the reference frame's own when the scene is :func:`timeless` (the same render either way,
        so the same bytes; a still camera or a still scene draws one view fewer), else drawn."""
        if same_pose(ref_pose, pose):
            return g0
        if self._ref_view is not None and self._ref_view[1] == self.scene.version and timeless(self.scene):
            return self._ref_view[0]
        return self._gbuffer(ctx, ref_pose, self.intrinsics, times, colour=colour)

    def _produce_quasar(self, ctx: ServerContext) -> Update:
        cfg, intr = self.config, self.intrinsics
        pose = ctx.target_pose
        times, atlas = self._start()
        sets: list[WireSet] = []
        reference = self._reference_due(ctx)
        g0 = self._gbuffer(ctx, pose, intr, times)
        rot = pose.view_matrix()[:3, :3]
        p = cfg.params
        gr = None
        if not reference and cfg.reference_error_db > 0:
            ref_pose = self.cache.pose
            assert ref_pose is not None
            if not same_pose(ref_pose, pose):
                t1 = time.perf_counter()
                self._upload_cached(ctx, ref_pose)
                est = self._estimate(ctx, pose, g0)
                times["mask_ms"] += (time.perf_counter() - t1) * 1e3
                if (est is not None and ESTIMATE_MARGIN_DB > 0 and est[2] < cfg.reference_error_db - ESTIMATE_MARGIN_DB
                        and lights_at(self.scene, ctx.t_s) == self._ref_colour_at):
                    psnr = est[2]       # the estimate alone: the reference view at this time is not drawn
                    self._stats["residual_psnr_estimate"] = 1.0
                else:
                    gr = self._reference_view(ctx, pose, ref_pose, g0, times,
                                              colour=not PARTIAL_TEST or ctx.renderer.supersample != 1)
                    t1 = time.perf_counter()
                    psnr = self._residual_psnr(ctx, pose, g0, gr, est)
                    times["mask_ms"] += (time.perf_counter() - t1) * 1e3
                # reported as every PSNR of the project is (capped at 60 dB, finite: the wire refuses inf, which a
                # view with no reference pixels in it gives); the rule compares the exact figure (or, decided from
                # part of the view, a bound of it under the threshold: residual_psnr_partial is then set; or the
                # estimate, far enough under it: residual_psnr_estimate)
                self._stats["residual_psnr_db"] = min(psnr, RESIDUAL_PSNR_CAP_DB)
                reference = psnr < cfg.reference_error_db
        if reference:
            q = generate(g0.depth, g0.normal, rot, intr, p, background=cfg.background_quads)
            self._account(times, q)
            self.cache.set_reference(q, pose, intr, ctx.frame_id)
            self._ref_depth, self._ref_normal = g0.depth.copy(), g0.normal.copy()
            self._ref_view = (g0, self.scene.version) if timeless(self.scene) else None
            self._ref_colour = g0.color
            self._ref_colour_at = lights_at(self.scene, ctx.t_s)
            sets.append(WireSet(KIND_REFERENCE, 0, 1, q))
            self._place(atlas, 0, g0.color)
            self._ref_due = False
            cameras = [encode_camera(pose, intr), encode_camera(pose, intr)]
        else:
            ref_pose = self.cache.pose
            assert ref_pose is not None and self._ref_depth is not None and self._ref_normal is not None
            if gr is None:
                gr = self._reference_view(ctx, pose, ref_pose, g0, times)
            t1 = time.perf_counter()
            a, b = self._ref_depth, gr.depth
            fin_a, fin_b = np.isfinite(a), np.isfinite(b)
            changed = (fin_a != fin_b) | (fin_a & fin_b & (np.abs(np.where(fin_a, a, 0) - np.where(fin_b, b, 0))
                                                          > CHANGE_REL * np.where(fin_b, b, 1)))
            changed |= fin_a & fin_b & ((self._ref_normal * gr.normal).sum(-1) < 0.99)
            times["mask_ms"] += (time.perf_counter() - t1) * 1e3
            qu = generate(gr.depth, gr.normal, ref_pose.view_matrix()[:3, :3], intr, p, emit=changed, background=True)
            self._account(times, qu)
            if len(qu):
                self.cache.apply_update(qu)
            self._ref_depth = np.where(changed, gr.depth, self._ref_depth)
            self._ref_normal = np.where(changed[..., None], gr.normal, self._ref_normal)
            sets.append(WireSet(KIND_UPDATE, 0, 1, qu))
            self._place(atlas, 0, gr.color)
            self._ref_colour = gr.color
            self._ref_colour_at = lights_at(self.scene, ctx.t_s)
            t1 = time.perf_counter()
            assert self.cache.quads is not None
            if cfg.residual_mask == "coverage":
                # QUASAR's FrameGenerator: what the cached mesh (its scene quads) does not cover from here, grown
                # by the 8 neighbours; the background gets no quads (the client fills it)
                cached = self.cache.quads
                fg = select(cached, ~cached.background(intr))
                mesh_z = self._mesh_depth(ctx, [build_mesh(fg, ref_pose, intr, (0, 0))], pose, intr)
                scene_px = np.isfinite(g0.depth)
                revealed = binary_dilation(scene_px & ~np.isfinite(mesh_z), structure=np.ones((3, 3), bool)) & scene_px
                background = False
            else:
                mesh_z = self._mesh_depth(ctx, [build_mesh(self.cache.quads, ref_pose, intr, (0, 0))], pose, intr)
                revealed = binary_dilation(self._unexplained(g0.depth, mesh_z), iterations=1)
                background = True
            times["mask_ms"] += (time.perf_counter() - t1) * 1e3
            qn = generate(g0.depth, g0.normal, rot, intr, p, emit=revealed, background=background)
            self._account(times, qn)
            sets.append(WireSet(KIND_REVEALED, 1, 0, qn))
            self._place(atlas, 1, masked_colour(g0.color, revealed))
            self._stats["changed_px"] = float(changed.sum())
            self._stats["revealed_px"] = float(revealed.sum())
            self._stats["freed"] = float(self.cache.freed)
            cameras = [encode_camera(pose, intr), encode_camera(ref_pose, intr)]
        first_hidden = 1 + (1 if cfg.reference_every > 1 else 0)
        cameras.append(encode_camera(pose, self.wide) if self.wide else encode_camera(pose, intr))
        self._hidden_and_wide(ctx, pose, g0, first_hidden, 0, 2, sets, atlas, times)
        return self._finish(ctx, pose, sets, atlas, cameras, times, "reference" if reference else "residual")

    def _produce_quadstream(self, ctx: ServerContext) -> Update:
        cfg, intr = self.config, self.intrinsics
        pose = ctx.target_pose
        times, atlas = self._start()
        if self._mesh is not None:
            self._mesh.clear_guard()
        rot = pose.matrix()[:3, :3]
        h = cfg.view_cell_m / 2
        offsets = [np.zeros(3)] + [np.array([sx, sy, sz]) * h for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
        views = [(Pose(pose.position + rot @ o, pose.orientation), intr) for o in offsets]
        if self.wide is not None:
            views.append((pose, self.wide))
        sets: list[WireSet] = []
        parts: list[tuple[np.ndarray, np.ndarray]] = []
        cameras = []
        colors = []
        p = cfg.params
        for v, (vp, vi) in enumerate(views):
            g = self._gbuffer(ctx, vp, vi, times)
            g_color, g_depth, g_normal = g.color, g.depth, g.normal
            if QS_EXPAND_EDGES:
                g_color, g_depth, g_normal = expand_edges(g_color, g_depth, g_normal)
            if parts:
                t1 = time.perf_counter()
                mesh = self._gl_mesh(ctx)
                if len(parts) == 1:     # the views so far: the mesh grows by the last one (mesh.append)
                    mesh.upload(np.zeros((0, VERTEX_FLOATS), np.float32), np.zeros(0, np.uint32))
                mesh.append(*parts[-1])
                new = self._unexplained(g_depth, mesh.depth_at(vp, vi))
                emit = binary_dilation(new, iterations=1)   # one-pixel boundary quads
                if vi is self.wide:
                    emit &= self._wide_out
                times["mask_ms"] += (time.perf_counter() - t1) * 1e3
            else:
                emit = None
            q = generate(g_depth, g_normal, vp.view_matrix()[:3, :3], vi, p, emit=emit, background=True)
            self._account(times, q)
            kind = KIND_WIDE if vi is self.wide else KIND_VIEW
            sets.append(WireSet(kind, v, v, q))
            cameras.append(encode_camera(vp, vi))
            if self.packed is None:
                self._place(atlas, v, g_color if emit is None else masked_colour(g_color, emit))
            colors.append(g_color)
            parts.append(build_mesh(q, vp, vi, (0, 0), view=v if cfg.centre_guard else 0))
            if v == 0 and cfg.centre_guard:   # the later views are masked by the mesh as the client draws it
                self._gl_mesh(ctx).set_guard(*parts[0], vp, vi)
        if self.packed is not None:
            self._pack(sets, colors, atlas, times)
        return self._finish(ctx, pose, sets, atlas, cameras, times, "reference")

    def _pack(self, sets: list[WireSet], colors: list[np.ndarray], atlas: np.ndarray, times: dict[str, float]) -> None:
        """QuadStream's packed atlas: the centre view whole at the top left (where the atlas can hold it), every
        later quad's texels at a position of its own, set on its set's ``tex``.  Quads beyond the atlas's capacity
        (views in order, the centre first) are left out and counted."""
        assert self.packed is not None
        t0 = time.perf_counter()
        i = self.intrinsics
        tile = tile_side(i.width, i.height)
        rx, ry = whole_tiles(i.width, i.height)
        whole = bool(sets) and rx * tile <= self.packed[0] and ry * tile <= self.packed[1]
        reserved = (rx, ry) if whole else (0, 0)
        if whole:
            c = sets[0]
            c.tex = np.stack([c.quads.x, c.quads.y], axis=-1).astype(np.int64)
            copy_texels(atlas, colors[0], c.quads.level, c.quads.x, c.quads.y, c.tex[:, 0], c.tex[:, 1])
        binned = list(zip(sets, colors, range(len(sets))))[1 if whole else 0:]
        sizes = 1 << np.concatenate([s.quads.level for s, _, _ in binned] or [np.zeros(0, np.uint8)]).astype(np.int64)
        keep = fitting(sizes, self.packed[0] * self.packed[1] - rx * ry * tile * tile * whole)
        self._stats["atlas_dropped"] = float(sizes.size - keep)
        key = source_order(np.concatenate([np.full(len(s.quads), v) for s, _, v in binned] or [np.zeros(0)]),
                           *(np.concatenate([getattr(s.quads, k) for s, _, _ in binned] or [np.zeros(0)])
                             for k in ("level", "x", "y")))
        ax, ay = pack_squares(sizes[:keep], tile, *self.packed, key=key[:keep], reserved=reserved)
        a = 0
        for s, img, _ in binned:
            if a + len(s.quads) > keep:    # the kept quads are a prefix in view order
                s.quads = select(s.quads, np.arange(len(s.quads)) < keep - a)
            n = len(s.quads)
            s.tex = np.stack([ax[a:a + n], ay[a:a + n]], axis=-1)
            copy_texels(atlas, img, s.quads.level, s.quads.x, s.quads.y, ax[a:a + n], ay[a:a + n])
            a += n
        times["pack_atlas_ms"] = (time.perf_counter() - t0) * 1e3

    def _finish(self, ctx: ServerContext, pose: Pose, sets: list[WireSet], atlas: np.ndarray, cameras: list[list[float]],
                times: dict[str, float], frame_kind: str) -> Update:
        t0 = time.perf_counter()
        quads, offsets = encode_sets(sets)
        times["pack_ms"] = (time.perf_counter() - t0) * 1e3
        self.last_sets = sets
        self._stats.update(times)
        self._stats["quads"] = float(sum(len(s.quads) for s in sets))
        self._stats["nonflat"] = float(sum(int((~s.quads.flat).sum()) for s in sets))
        self._stats["cached"] = float(len(self.cache))
        self._stats["reference"] = 1.0 if frame_kind == "reference" else 0.0
        qb = quasar_frame_bytes(sets, frame_kind == "reference")      # the frame as QUASAR's simulators count it
        self._stats["quasar_bytes"], self._stats["quasar_proxies"] = qb.bytes, float(qb.proxies)
        for s in sets:
            key = {KIND_REFERENCE: "ref", KIND_UPDATE: "update", KIND_REVEALED: "revealed", KIND_HIDDEN: "hidden",
                   KIND_WIDE: "wide", KIND_VIEW: "views"}[s.kind]
            self._stats[f"quads_{key}"] = self._stats.get(f"quads_{key}", 0.0) + len(s.quads)
        meta = {"v": META_VERSION, "frame": frame_kind, "ref_frame": int(self.cache.frame_id), "cameras": cameras}
        return Update(ctx.frame_id, ctx.t_s, pose, {"atlas": atlas}, meta, force_idr=False,
                      data={"quads": quads, "offsets": offsets})
