"""The TSS server half: triangle PVS, sample distribution, atlas layout, gathering in the tessellator.

Per server frame (paper figure 10):

1. **PVS** at triangle granularity: the ``sas`` ID pass with one patch per triangle,
   EVS samples from the newest pose to one frame past the predicted one, the field
   of view enlarged by ``fov_margin`` (:mod:`splitrender.methods.sas.pvs`); with ``pvs_ring``, while the view
   moves, the triangles beside it (sharing a vertex) at one texel each;
2. **mesh split**: every PVS triangle is projected at the predicted pose; its
   slantedness (longest edge over height, pixels) sends it to oversampling above
   ``slant_threshold``, else to L-packing at the smallest level whose ``v(l)`` covers
   its area times ``samples_per_px``; triangles needing fewer than ``tiny_samples``
   get one texel (a cell of ``single_px`` texels square), or with ``sliver_px`` a few samples along their length
   when they are long; with ``budget_px`` the frame's rate rises while its samples fit the budget
   (:meth:`TssServer.budget_rate`).  Load-time midpoint splits keep
   levels at or below 64 (:meth:`TssConfig.split_edge_m`); the split meshes are snapped to
   the wire's 16-bit position grid and, with ``spatial_order``, their triangles sorted
   along a Z-order curve (:func:`build_scene_triangles`);
3. **atlas mapping** (:class:`~.layout.StableAtlas`): a triangle keeps its cell while
   it stays visible in the same class (with hysteresis on kind, level and sizes); a
   repack in (class, id) order, a deterministic prefix sum, on overflow and on I-frames
   past ``high_water`` (by default every I-frame; every frame with ``layout = "prefix"``)
   forces an I-frame; when
   the set does not fit, the frame's sampling rate drops until it does (``srv_rate``);
   when not even one texel each fits, the triangles needing the fewest samples are
   left out of the frame (``srv_tris_left_out``; the client shows holes there);
4. **gathering**: one patch per triangle through ``shaders/tss_shade.*`` with the
   rasteriser discarded; each tessellator vertex shades its sample with
   ``shading.glsl`` (the ground truth's shader) and stores it into the atlas;
5. **wire** (:mod:`.wire`): the atlas as video, the triangle table and the geometry
   of triangles new to the client as reliable data streams.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...codecs.video import VideoCodecConfig
from ...render.ddgi import gi_time
from ...render.gl import grow_vertex_buffer, read_shader, runs, set_reference_view, set_uniform
from ...render.renderer import light_view_projection
from ...scene.pose import CameraIntrinsics, Pose
from ..base import DataStreamSpec, SceneProducer, ServerContext, ServerHalf, StreamSpec, Update
from ..sas.patches import split_scene_meshes
from ..sas.pvs import PatchIdPass, PoseSample, evs_samples
from ..sas.server import (SHADOW_NORMAL_OFFSET_M, SHADOW_REACH_TEXELS, caster_rects, light_rects, rects_overlap,
                          refresh_due)
from .config import TssConfig
from .layout import (KIND_LP, KIND_OS, KIND_SINGLE, MAX_LEVEL, AtlasPlan, StableAtlas, fill_gutters, layout_attributes, level_for, level_for_own, lp_luma, morton_order,
                     os_sizes, own_count, pitch_level, plan_atlas, v_count)
from .wire import WIRE_VERSION, descriptors, dequantize_positions, encode_geometry, encode_table, quantize_positions

log = logging.getLogger(__name__)
SHADERS = Path(__file__).parent / "shaders"
RASTERIZER_DISCARD = 0x8C89
NEAR_M = 0.05
"""Triangles with a vertex closer than this to the reference eye (or behind it) are shaded without perspective correction."""
ZSTD_LEVEL = 19
"""zstd level of the ``tris`` and ``geo`` streams (:meth:`TssServer.streams`)."""
VERTEX_FLOATS = 3 + 3 + 2 + 4 + 4 + 4 + 4
PERSP_KEEP = 0.02
"""``live_refresh_frames``: a perspective-placed triangle's samples are kept while its corners' view depths relative to
the first one's changed by less than this since they were gathered (the client places the samples with the newest
frame's depths; 2 % moves a sample by under half a per cent of the triangle)."""


@dataclass
class SceneTriangles:
    """The split scene, one row per triangle (scene-wide ids in object order).

    ``obj`` (T,) object index; ``pos``/``nrm`` (T, 3, 3), ``uv`` (T, 3, 2), ``tan``
    (T, 3, 4) object-space vertex attributes; ``meshes`` the split meshes;
    ``tri_to_patch``/``count`` make it a patch table of one triangle per patch for
    the ID pass.  For the wire: ``vid`` (T, 3) scene-wide vertex ids, ``vq`` (V, 3) uint16
    every vertex quantised in its object's ``box`` (O, 2, 3) (lo, hi, object space),
    ``tri_base`` (O,) each object's first triangle id.
    """

    obj: np.ndarray
    pos: np.ndarray
    nrm: np.ndarray
    uv: np.ndarray
    tan: np.ndarray
    meshes: list[Any]
    tri_to_patch: np.ndarray
    vid: np.ndarray
    vq: np.ndarray
    box: np.ndarray
    tri_base: np.ndarray

    @property
    def count(self) -> int:
        return int(self.obj.size)


def build_scene_triangles(scene: Any, config: TssConfig, intr: CameraIntrinsics) -> SceneTriangles:
    """The scene's meshes split for ``intr`` (:meth:`TssConfig.split_edge_m`), one row per triangle; with
    ``spatial_order`` each mesh's triangles are sorted along a Z-order curve of their centroids, so triangles placed
    in id order (single texels, L-packing cells) sit beside their mesh neighbours in the atlas."""
    meshes, edge = split_scene_meshes(scene, config.split_edge_m(intr), config.split_max_triangles)
    if config.spatial_order:
        meshes = [dataclasses.replace(m, indices=m.indices[morton_order(m.positions[m.indices.astype(np.int64)].mean(axis=1))])
                  for m in meshes]
    # snapped to the wire's 16-bit grid in each object's box: the PVS pass, the gathering and the client then
    # rasterise the same triangles (a pixel centre on a moved edge would otherwise fall to a triangle outside the PVS)
    box = np.zeros((len(meshes), 2, 3), np.float32)
    vq = []
    for k, m in enumerate(meshes):
        if m.positions.shape[0]:
            box[k] = m.positions.min(axis=0), m.positions.max(axis=0)
        vq.append(quantize_positions(m.positions, box[k]))
        meshes[k] = dataclasses.replace(m, positions=dequantize_positions(vq[k], box[k]))
    obj, pos, nrm, uv, tan, vid = [], [], [], [], [], []
    base = np.zeros(len(meshes), np.int64)
    nv = nt = 0
    for k, m in enumerate(meshes):
        idx = m.indices.astype(np.int64)
        obj.append(np.full(idx.shape[0], k, np.int64))
        pos.append(m.positions[idx])
        nrm.append(m.normals[idx])
        uv.append(m.uvs[idx])
        tan.append(m.tangent_frame()[idx])
        vid.append(idx + nv)
        base[k] = nt
        nv += m.positions.shape[0]
        nt += idx.shape[0]
    log.info("tss: %d triangles split to %d (edges <= %.3f m)", scene.triangle_count, nt, edge)
    cat = (lambda a, shape: np.concatenate(a).astype(np.float32) if a else np.zeros(shape, np.float32))
    return SceneTriangles(np.concatenate(obj) if obj else np.zeros(0, np.int64), cat(pos, (0, 3, 3)), cat(nrm, (0, 3, 3)),
                          cat(uv, (0, 3, 2)), cat(tan, (0, 3, 4)), list(meshes), np.arange(nt, dtype=np.int32),
                          np.concatenate(vid) if vid else np.zeros((0, 3), np.int64),
                          np.concatenate(vq) if vq else np.zeros((0, 3), np.uint16), box, base)


class TssProducer(SceneProducer):
    """Scene-level TSS work shared by every session: the split triangles (per display size),
    their ID pass, and each frame's object transforms."""

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        self._tris: dict[tuple[int, int, float], SceneTriangles] = {}
        self._ids: dict[tuple[int, int, float], PatchIdPass] = {}

    def triangles_for(self, intr: CameraIntrinsics) -> SceneTriangles:
        key = (intr.width, intr.height, float(intr.fov_y_deg))
        if key not in self._tris:
            self._tris[key] = build_scene_triangles(self.scene, self.config, intr)  # type: ignore[arg-type]
        return self._tris[key]

    def id_pass(self, renderer: Any, tris: SceneTriangles) -> PatchIdPass:
        key = next(k for k, v in self._tris.items() if v is tris)
        if key not in self._ids:
            self._ids[key] = PatchIdPass(renderer, self.scene, tris)  # type: ignore[arg-type]
        return self._ids[key]

    def prepare(self, frame_id: int, t_s: float) -> dict[str, Any]:
        return {"t_s": t_s, "models": np.stack([o.model_matrix(t_s) for o in self.scene.objects])}


def project(world: np.ndarray, pose: Pose, intr: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions (N, 3, 2) and view depths (N, 3) of world-space triangles (N, 3, 3) at ``pose``;
    depths are clamped to :data:`NEAR_M` for the projection."""
    view = np.asarray(pose.view_matrix(), np.float64)
    v = world @ view[:3, :3].T + view[:3, 3]
    z = -v[..., 2]
    zc = np.maximum(z, NEAR_M)
    f = 1.0 / math.tan(math.radians(intr.fov_y_deg) / 2.0)
    aspect = intr.width / intr.height
    x = v[..., 0] / zc * f / aspect
    y = v[..., 1] / zc * f
    px = np.stack([(x + 1) * 0.5 * intr.width, (y + 1) * 0.5 * intr.height], axis=-1)
    return px, z


def visible_area(world: np.ndarray, pose: Pose, intr: CameraIntrinsics, margin: float) -> np.ndarray:
    """(N,) pixels of each world-space triangle (N, 3, 3) inside the view at ``pose``: clipped (Sutherland-Hodgman,
    vectorised) to the near plane and to the frustum widened by ``margin`` on every side (NDC units)."""
    view = np.asarray(pose.view_matrix(), np.float64)
    v = world @ view[:3, :3].T + view[:3, 3]
    n = v.shape[0]
    f = 1.0 / math.tan(math.radians(intr.fov_y_deg) / 2.0)
    fx, s = f / (intr.width / intr.height), 1.0 + margin
    # inside where a . p + b >= 0 (view space, the camera looks down -z)
    planes = [((0.0, 0.0, -1.0), -NEAR_M), ((-fx, 0.0, -s), 0.0), ((fx, 0.0, -s), 0.0), ((0.0, -f, -s), 0.0), ((0.0, f, -s), 0.0)]
    poly = np.zeros((n, 8, 3))
    poly[:, :3] = v
    cnt = np.full(n, 3, np.int64)
    # only the triangles with a corner outside some plane are clipped (a few percent of a frame's PVS); every other
    # row leaves the loop below as it came in, so its area is the same number either way
    cut = np.zeros(n, bool)
    for a, b in planes:
        cut |= ((poly @ np.asarray(a) + b)[:, :3] < 0).any(axis=1)     # as _clip computes it
    if cut.any():
        poly[cut], cnt[cut] = _clip(poly[cut], cnt[cut], planes)
    z = np.maximum(-poly[..., 2], NEAR_M)
    p2 = np.stack([poly[..., 0] / z * fx * intr.width / 2, poly[..., 1] / z * f * intr.height / 2], -1)
    e = p2 - p2[:, :1]
    cross = e[:, 1:-1, 0] * e[:, 2:, 1] - e[:, 1:-1, 1] * e[:, 2:, 0]      # fan triangles (0, k, k+1)
    k = np.arange(1, 7)[None, :]
    return 0.5 * np.abs((cross * (k + 1 < cnt[:, None])).sum(axis=1))


def _clip(poly: np.ndarray, cnt: np.ndarray, planes: list[tuple[tuple[float, float, float], float]]) -> tuple[np.ndarray, np.ndarray]:
    """Sutherland-Hodgman, vectorised: polygons ``poly`` (n, 8, 3) of ``cnt`` (n,) corners clipped to ``planes``
    (inside where ``a . p + b >= 0``); returns the clipped polygons and their corner counts."""
    poly, cnt = poly.copy(), cnt.copy()
    for a, b in planes:
        a_ = np.asarray(a)
        d_all = poly @ a_ + b                                               # (n, 8)
        # a polygon with no corner outside this plane leaves it as it came (its corners in order, zeros past them):
        # only the others go through the loop below (a triangle crosses one or two of the five planes)
        act = np.flatnonzero(((np.arange(8)[None, :] < cnt[:, None]) & (d_all < 0)).any(axis=1))
        if act.size == 0:
            continue
        n = act.size
        rows = np.arange(n)
        full, full_cnt = poly, cnt
        poly, cnt, d = poly[act], cnt[act], d_all[act]
        out = np.zeros_like(poly)
        pos = np.zeros(n, np.int64)
        for i in range(8):
            valid = i < cnt
            j = np.where(cnt > 0, (i + 1) % np.maximum(cnt, 1), 0)
            di, dj = d[:, i], d[rows, j]
            pi, pj = poly[:, i], poly[rows, j]
            e1 = valid & (di >= 0)
            out[rows[e1], np.minimum(pos[e1], 7)] = pi[e1]
            pos += e1
            e2 = valid & ((di >= 0) != (dj >= 0))
            t = di / np.where(e2, di - dj, 1.0)
            x = pi + t[:, None] * (pj - pi)
            out[rows[e2], np.minimum(pos[e2], 7)] = x[e2]
            pos += e2
        full[act], full_cnt[act] = out, np.minimum(pos, 8)
        poly, cnt = full, full_cnt
    return poly, cnt


def moving(samples: list[PoseSample], tol: float = 1e-6) -> bool:
    """Whether the EVS samples' views differ (the camera moves, or is predicted to)."""
    if len(samples) < 2:
        return False
    v0 = np.asarray(samples[0][1].view_matrix(), np.float64)
    return any(float(np.abs(np.asarray(p.view_matrix(), np.float64) - v0).max()) > tol for _, p in samples[1:])


def distinct_samples(samples: list[PoseSample], animated: bool) -> list[PoseSample]:
    """``samples`` without those that draw the same ID buffer as an earlier one: the same view matrix, bit for bit,
    at the same time where objects move.  The PVS is the largest area over the samples, so a repeat adds nothing; a
    still camera's EVS samples are all one view."""
    seen: set[tuple[bytes, float]] = set()
    out = []
    for t_s, p in samples:
        key = (np.asarray(p.view_matrix(), np.float64).tobytes(), float(t_s) if animated else 0.0)
        if key not in seen:
            seen.add(key)
            out.append((t_s, p))
    return out


def plan_samples(kind: np.ndarray, level: np.ndarray, w1: np.ndarray, w2: np.ndarray, h: np.ndarray, grid: str = "paper") -> int:
    """Samples a classification (:func:`classify`'s first five arrays) shades: ``v(l)`` per L-packed triangle, both
    staircases per oversampled one, one per single texel (the plan's ``samples`` without placing anything)."""
    n = np.where(kind == KIND_LP, v_count(np.maximum(level, 1)), 1).astype(np.int64)
    os_ = np.flatnonzero(kind == KIND_OS)
    if os_.size:
        n[os_] = os_sizes(w1[os_], w2[os_], h[os_], grid)[1]
    return int(n.sum())


def capped_lift(min_level: np.ndarray, span: np.ndarray, flip_cap: float) -> np.ndarray:
    """``flip_level``'s lifts (``min_level``, 0: none) capped at ``ceil(flip_cap * span)`` (at least 1), where ``span``
    is the samples the frame's rate puts along each triangle's longest projected edge: a level-``l`` patch has ``l + 1``
    samples along an edge, so the lift goes only as far as the triangle can show.  ``flip_cap`` 0: uncapped."""
    if flip_cap <= 0:
        return min_level
    cap = np.clip(np.ceil(flip_cap * span), 1, MAX_LEVEL).astype(np.int64)
    return np.where(min_level > 0, np.minimum(min_level, cap), 0)


def classify(px: np.ndarray, rate: float, slant_threshold: float, tiny: float,
             visible: np.ndarray | None = None, grid: str = "paper", sliver_px: float = math.inf,
             min_level: np.ndarray | None = None, pitch_block: int = 1, flip_cap: float = 0.0,
             os_min_rows: float = 0.0, os_min_step: float = 0.0, lp_own: bool = False) -> tuple[np.ndarray, ...]:
    """Sample distribution of triangles with pixel corners ``px`` (N, 3, 2) at ``rate`` samples per pixel.

    Returns ``kind, level, w1, w2, h, a, base, slant, need, span``: the kind, L-packing level,
    the oversampling staircases (bases and height in samples, the split fraction ``a``
    quantised to 16 bits as on the wire), the base's start vertex, slantedness,
    samples needed (area times rate) and the samples along the longest edge (:func:`capped_lift`'s ``span``).  ``pitch_block`` > 1 (``fill_pitch``): L-packing levels rise to the highest of
    the same tip pitch (:func:`~.layout.pitch_level`).  With ``visible`` (pixels of each triangle
    inside the widened view, :func:`visible_area`) a triangle reaching out of the view
    gets samples for that part only, spread over the whole triangle (the paper
    samples whole triangles; the part outside the view would need samples only if
    the client turned that way, and the PVS margin already covers that).  ``min_level`` (``flip_level``) lifts
    L-packing levels, capped by :func:`capped_lift` at ``flip_cap``.  ``os_min_rows``: a slanted triangle is
    oversampled only where its height holds at least this many samples at the rate (else L-packed);
    ``os_min_step``: and only where L-packing would put its samples further apart than this many pixels along the
    longest edge (``longest / level``).  ``lp_own``: L-packing levels cover the need with the samples each patch holds
    for itself (:func:`~.layout.level_for_own`: shared edge and corner samples counted once) instead of all ``v(l)``.
    """
    e = np.roll(px, -1, axis=1) - px                       # edge k: vertex k -> k+1
    ln = np.linalg.norm(e, axis=2)
    area = 0.5 * np.abs(e[:, 0, 0] * e[:, 2, 1] - e[:, 0, 1] * e[:, 2, 0])
    base = np.argmax(ln, axis=1)
    r = np.arange(len(ln))
    longest = ln[r, base]
    height = 2.0 * area / np.maximum(longest, 1e-9)
    slant = longest / np.maximum(height, 1e-9)
    shown = area if visible is None else np.minimum(area, visible)
    need = shown * rate
    # one texel only for a triangle that is small in both directions: a sliver (a far floor tile's triangle,
    # 8 px long and a quarter pixel high) would show one colour along its whole length
    span = longest * np.sqrt(rate * shown / np.maximum(area, 1e-12))   # samples along the longest edge
    single = (need < tiny) & (span < sliver_px)
    # a sliver (under ``tiny`` but long) is L-packed at its low level: its corners and centre along its length cost a
    # few samples, where the oversampling staircases its slant would call for take two rows of its length and more
    sliver = need < tiny
    rows = height * np.sqrt(rate * shown / np.maximum(area, 1e-12))      # samples up the height
    level = level_for_own(need) if lp_own else level_for(need)
    slanted = (slant > slant_threshold) & ~sliver & (rows >= os_min_rows) & (longest >= os_min_step * level)
    kind = np.where(single, KIND_SINGLE, np.where(slanted, KIND_OS, KIND_LP)).astype(np.int64)
    if min_level is not None:
        min_level = capped_lift(min_level, span, flip_cap)
        lift = min_level > 0
        kind[lift] = KIND_LP
        level[lift] = np.maximum(level[lift], min_level[lift])
    if pitch_block > 1:
        lp = kind == KIND_LP
        level[lp] = pitch_level(level[lp], pitch_block)
    # eq. 12: where the height meets the base, as a fraction of the base from its start vertex
    b0 = px[r, base]
    apex = px[r, (base + 2) % 3]
    eb = e[r, base]
    a = np.clip(((apex - b0) * eb).sum(1) / np.maximum((eb * eb).sum(1), 1e-12), 0.0, 1.0)
    a = np.rint(a * 65535.0) / 65535.0
    sq = math.sqrt(rate) * np.sqrt(shown / np.maximum(area, 1e-12))
    w1 = np.ceil(a * longest * sq)
    w2 = np.ceil((1.0 - a) * longest * sq)
    h = np.ceil(height * sq)
    # both staircases must fit one patch (v(64) threads): shrink them evenly if not
    total = (w1 + w2 + 4) * (h + 1) if grid == "paper" else (w1 + w2 + 2) * h    # bounds of os_sizes' samples
    shrink = np.sqrt(np.minimum(1.0, 0.9 * int(v_count(MAX_LEVEL)) / np.maximum(total, 1)))
    w1, w2, h = (np.clip(np.floor(v * shrink), 1, 4096).astype(np.int64) for v in (w1, w2, h))
    return kind, level, w1, w2, h, a, base, slant, need, span


class TssServer(ServerHalf):
    """Tessellated shading streaming, server half (per session)."""

    config: TssConfig

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        if not isinstance(self.producer, TssProducer):
            self.producer = TssProducer(self.config, self.scene, self.server_fps)
        self.tris = self.producer.triangles_for(self.intrinsics)
        self.atlas = self.config.atlas_size(self.intrinsics)
        n = self.tris.count
        self.client_has = np.zeros(n, bool)
        self._last_seen = np.full(n, -(1 << 40), np.int64)
        self._frames = 0
        self._since_i = 0
        self._gl: Any = None
        self._stats: dict[str, float] = {}
        self.block = 1 if self.config.lossless else self.config.codec_block
        """The tip blocks' alignment (``codec_block``; 1 for a lossless atlas, whose codec keeps every texel as it is)."""
        self.store = StableAtlas(n, *self.atlas, single_px=self.config.single_px, block=self.block)
        self.pitch_block = self.block if self.config.fill_pitch else 1
        """L-packing levels rise to fill their tip pitch (``fill_pitch``): the block, or 1 (off)."""
        self._n_vertices = int(self.tris.vid.max()) + 1 if self.tris.vid.size else 0
        self._animated = any(o.animation is not None for o in self.scene.objects)
        self._sent_live = np.zeros(n, bool)                 # the client's table after the last update (reliable stream)
        self._sent_desc = np.zeros((n, 17), np.uint8)
        self._sent_origin = np.zeros((n, 3, 2), np.int64)   # where the client finds each triangle's samples
        self._sent_single_px = -1                          # the single-texel cell side the client's table has
        self._sent_atlas: np.ndarray | None = None          # the last atlas sent (codec_block: empty blocks keep it)
        self._prev_a = np.zeros(n)
        self._prev_kind = np.full(n, -1, np.int64)
        self._prev_level = np.zeros(n, np.int64)
        self._prev_w1 = np.zeros(n, np.int64)
        self._prev_w2 = np.zeros(n, np.int64)
        self._prev_h = np.zeros(n, np.int64)
        self._luma = np.full(n, np.nan)
        """Per triangle, the mean luma of its samples when it was last shaded L-packed (``colour_order``; NaN: never)."""
        self.last_plan: AtlasPlan | None = None
        self.left_out = 0
        """Triangles of the last frame's PVS left out because not even one texel each fitted the atlas."""
        self.last_ids = np.zeros(0, np.int64)
        self._min_level: np.ndarray | None = None
        """Per PVS triangle of the frame being planned, the least L-packing level (``flip_level``; None: off)."""
        self.keep_unwritten = False
        """Whether the next gathering leaves the texels it does not write as they were (set per frame: P-frames)."""
        # live_refresh_frames: per triangle the frame it was last gathered in and the view generation (a count of the
        # changes of the eye and the probes' time) then; the last gathering's object matrices and light intensities
        self._gathered_at = np.zeros(n, np.int64)
        self._gathered_gen = np.full(n, -1, np.int64)
        self._gathered_ratio = np.ones((n, 2))
        self._gen = 0
        self._gen_key: Any = None
        self._gathered_models: np.ndarray | None = None
        self._gathered_lights: Any = None
        self._stale_kept = 0
        self._dynamic = np.array([o.dynamic for o in self.scene.objects], bool)

    # ------------------------------------------------------------------ interface
    def streams(self) -> list[Any]:
        c = self.config
        if c.lossless:
            v = VideoCodecConfig(codec="hevc", pix_fmt="gbrp", lossless=True, crf=None, gop=c.gop, preset=c.preset, fps=self.server_fps)
        else:
            v = c.video(self.server_fps)
        # zstd at level 19, not the pipeline's 3: the tables and geometry are a third of tss's bits on a moving view
        # (2CylinderEngine's cloud orbit: 2.6 of 7.3 Mbit/s), and 19 takes 8-16 % off both (frame 0 of the engine
        # still: geo 31.5 -> 28.0 KB, tris 12.9 -> 10.8 KB).  It costs time: those 120 KB raw took 185 ms at 19, 63 at
        # 15 (28.3 and 11.2 KB), 2 at 3 on this 2-core machine under a load of 20; a moving view's ~10 KB a frame ~15 ms
        return [StreamSpec("atlas", v, *self.atlas), DataStreamSpec("tris", "reliable", level=ZSTD_LEVEL),
                DataStreamSpec("geo", "reliable", level=ZSTD_LEVEL)]

    def session_data(self) -> dict[str, Any]:
        return {"v": WIRE_VERSION, "atlas": list(self.atlas), "strip": self.store.strip, "os_grid": self.config.os_grid,
                "block": self.block,
                "n_objects": len(self.scene.objects),
                "n_triangles": self.tris.count, "sky": list(map(float, self.scene.sky_color)),
                "tri_base": self.tris.tri_base, "obj_box": self.tris.box}

    def stats(self) -> dict[str, float]:
        return dict(self._stats)

    # ------------------------------------------------------------------ GL
    def _setup_gl(self, renderer: Any) -> None:
        ctx = renderer.ctx
        assert isinstance(self.producer, TssProducer)
        self._ids = self.producer.id_pass(renderer, self.tris)
        self._prog = ctx.program(vertex_shader=read_shader(SHADERS / "tss_shade.vert"),
                                 tess_control_shader=read_shader(SHADERS / "tss_shade.tesc"),
                                 tess_evaluation_shader=read_shader(SHADERS / "tss_shade.tese"),
                                 fragment_shader=read_shader(SHADERS / "tss_shade.frag"))
        W, H = self.atlas
        self._tex = ctx.texture((W, H), 4, dtype="f1")
        self._fbo = ctx.framebuffer([self._tex])
        self._counter = ctx.buffer(reserve=16)
        self._sg = renderer.upload(self.scene)
        self._tex_size = np.array([og.texture.size if og.texture is not None else (1, 1) for og in self._sg.objects], np.float64)
        self._vbo: Any = None
        self._vao: Any = None
        self._gl = ctx

    # ------------------------------------------------------------------ frame
    def pvs_samples(self, ctx: ServerContext) -> list[PoseSample]:
        """EVS samples of the PVS, as ``sas`` takes them (:func:`~splitrender.methods.sas.pvs.evs_samples`)."""
        return evs_samples(ctx, self.config.pvs_prediction, self.config.pvs_step_ms, self.server_fps,
                           self.config.pvs_max_samples)

    def _hysteresis(self, ids: np.ndarray, kind: np.ndarray, level: np.ndarray, w1: np.ndarray, w2: np.ndarray, h: np.ndarray,
                    a: np.ndarray, slant: np.ndarray, need: np.ndarray) -> None:
        """Keep each triangle's previous kind, level and staircase sizes (in place) while the new ones are close."""
        c = self.config
        hy = c.hysteresis
        pk, pl = self._prev_kind[ids], self._prev_level[ids]
        pw1, pw2, ph = self._prev_w1[ids], self._prev_w2[ids], self._prev_h[ids]
        tiny = c.tiny_samples
        stay = pk == kind
        stay |= (pk == KIND_OS) & (kind == KIND_LP) & (slant > c.slant_threshold * (1 - hy)) & (need >= tiny) \
            & (h >= c.os_min_rows * (1 - hy))
        stay |= (pk == KIND_LP) & (kind == KIND_OS) & (slant < c.slant_threshold * (1 + hy))
        stay |= (pk == KIND_SINGLE) & (need < tiny * (1 + hy))
        stay |= (pk == KIND_LP) & (kind == KIND_SINGLE) & (need >= tiny * (1 - hy))
        kind[:] = np.where(stay & (pk >= 0), pk, kind)
        v_prev = (own_count if c.lp_own else v_count)(np.maximum(pl, 1))
        keep_l = (kind == KIND_LP) & (pk == KIND_LP) & (v_prev >= need * (1 - hy)) & (v_prev <= need * (1 + 2 * hy) + 2)
        level[:] = np.where(keep_l, pl, level)
        # a level that has to rise rises past the need by hy, so a triangle growing on screen moves cells less often
        # (each move is new content for a P-frame: +0.14 to +0.17 dB on the walk for 1 % more bits)
        up = (kind == KIND_LP) & (pk == KIND_LP) & ~keep_l & (level > pl)
        level[:] = np.where(up, (level_for_own if c.lp_own else level_for)(need * (1 + hy)), level)

        def close(old: np.ndarray, new: np.ndarray) -> np.ndarray:
            return (old >= new * (1 - hy)) & (old <= new * (1 + hy) + 1)

        keep_o = (kind == KIND_OS) & (pk == KIND_OS) & close(pw1, w1) & close(pw2, w2) & close(ph, h)
        w1[:], w2[:], h[:] = (np.where(keep_o, o, n) for o, n in ((pw1, w1), (pw2, w2), (ph, h)))
        # the height's foot moves as the view does; keep the sample grid while it moves less than a tenth of hy
        a[:] = np.where(keep_o & (np.abs(a - self._prev_a[ids]) < 0.1 * hy), self._prev_a[ids], a)

    def budget_rate(self, px: np.ndarray, visible: np.ndarray | None) -> float:
        """The frame's sampling rate under ``budget_px``: the highest in [``samples_per_px``, ``budget_max_spp``], on
        steps of 2^(1/8), whose samples (:func:`plan_samples`) stay within ``budget_px`` per display pixel."""
        c = self.config
        target = c.budget_px * self.intrinsics.width * self.intrinsics.height

        def fits(r: float) -> bool:
            k = classify(px, r, c.slant_threshold, c.tiny_samples, visible, c.os_grid, c.sliver_px or math.inf, self._min_level, self.pitch_block, c.flip_cap, c.os_min_rows, c.os_min_step, c.lp_own)
            return plan_samples(*k[:5], grid=c.os_grid) <= target

        lo, hi = math.ceil(8 * math.log2(c.samples_per_px)), math.floor(8 * math.log2(c.top_rate))
        if hi <= lo or not fits(2.0 ** (lo / 8)):
            return c.samples_per_px
        if fits(2.0 ** (hi / 8)):
            return 2.0 ** (hi / 8)
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if fits(2.0 ** (mid / 8)):
                lo = mid
            else:
                hi = mid
        return 2.0 ** (lo / 8)

    def plan(self, ids: np.ndarray, px: np.ndarray, iframe: bool, visible: np.ndarray | None = None
             ) -> tuple[AtlasPlan, np.ndarray, np.ndarray, float, np.ndarray | None]:
        """Classify triangles ``ids`` with pixel corners ``px`` and place them in the atlas; lowers the frame's
        sampling rate (and repacks) until they fit.  Returns the plan, the OS base vertex per triangle, the
        slantedness, the rate used and ``kept``: None when every triangle is placed, else the (sorted) indices
        into ``ids`` of those placed (the plan's arrays follow them) when not even one texel each fits, the
        triangles needing the most samples first."""
        c = self.config
        W, H = self.atlas
        rate = self.budget_rate(px, visible) if c.budget_px > 0 else c.samples_per_px
        # an empty atlas is packed as a repack packs it, in (class, id) order, so that a still view's periodic repack
        # restores the same cells (its I-frames then send no table rows) instead of the stable allocator's id order
        reset = c.layout == "prefix" or (iframe and (self.store.load() > c.high_water or self.store.rows == 0))
        if self.store.single_px != c.single_px:      # back from the last resort's one-texel cells: a repack
            self.store.single_px, reset = c.single_px, True
        failed = None
        for attempt in range(12):
            kind, level, w1, w2, h, a, base, slant, need, span = classify(px, rate, c.slant_threshold, c.tiny_samples, visible, c.os_grid, c.sliver_px or math.inf, self._min_level, self.pitch_block, c.flip_cap, c.os_min_rows, c.os_min_step, c.lp_own)
            if attempt == 0 and c.layout == "stable":
                self._hysteresis(ids, kind, level, w1, w2, h, a, slant, need)
                if self._min_level is not None:      # the hysteresis keeps no lifted triangle below its level
                    ml = capped_lift(self._min_level, span, c.flip_cap)
                    lift = ml > 0
                    kind[lift] = KIND_LP
                    level[lift] = np.maximum(level[lift], ml[lift])
                if self.pitch_block > 1:
                    lp = kind == KIND_LP
                    level[lp] = pitch_level(level[lp], self.pitch_block)
            plan = plan_atlas(self.store, ids, kind, level, w1, w2, h, a, reset=reset or attempt > 0, grid=c.os_grid)
            if not plan.overflow:
                break
            failed = rate
            # samples scale with the rate; cells take about twice the samples' area in texels
            rate *= max(0.2, min(0.9, 0.5 * W * H / max(float(plan.samples.sum()), 1.0)))
        if failed is not None and not plan.overflow:
            # a few bisection steps (geometric) between the rate that fitted and the one that did not
            lo, hi = rate, failed
            good = (plan, kind, level, w1, w2, h, a, base, slant, rate)
            for _ in range(3):
                mid = math.sqrt(lo * hi)
                k2 = classify(px, mid, c.slant_threshold, c.tiny_samples, visible, c.os_grid, c.sliver_px or math.inf, self._min_level, self.pitch_block, c.flip_cap, c.os_min_rows, c.os_min_step, c.lp_own)
                p2 = plan_atlas(self.store, ids, *k2[:6], reset=True, grid=c.os_grid)
                if p2.overflow:
                    hi = mid
                else:
                    lo = mid
                    good = (p2, *k2[:8], mid)
            if good[0] is not plan or good[-1] != rate:
                plan, kind, level, w1, w2, h, a, base, slant, rate = good
                plan = plan_atlas(self.store, ids, kind, level, w1, w2, h, a, reset=True, grid=c.os_grid)   # the store holds the last try
        kept = None
        if plan.overflow:   # the last resort: one texel per triangle (cells of one texel if need be)
            kind[:] = KIND_SINGLE
            plan = plan_atlas(self.store, ids, kind, level, w1, w2, h, a, reset=True, grid=c.os_grid)
            if plan.overflow and self.store.single_px > 1:
                self.store.single_px = 1
                plan = plan_atlas(self.store, ids, kind, level, w1, w2, h, a, reset=True, grid=c.os_grid)
            if plan.overflow:
                # not even that: the triangles needing the most samples (the largest on screen) first, as many as fit
                order = np.lexsort((ids, -need))
                lo, hi = 0, ids.size
                while hi - lo > 1:
                    mid = (lo + hi) // 2
                    sel = np.sort(order[:mid])
                    if plan_atlas(self.store, ids[sel], kind[sel], level[sel], w1[sel], w2[sel], h[sel], a[sel], reset=True,
                                  grid=c.os_grid).overflow:
                        hi = mid
                    else:
                        lo = mid
                kept = np.sort(order[:lo])
                ids, base, slant = ids[kept], base[kept], slant[kept]
                kind, level, w1, w2, h, a = (x[kept] for x in (kind, level, w1, w2, h, a))
                plan = plan_atlas(self.store, ids, kind, level, w1, w2, h, a, reset=True, grid=c.os_grid)
                log.warning("tss: %d triangles do not fit the %dx%d atlas even as one texel each: %d left out",
                            order.size, W, H, order.size - lo)
            else:
                log.warning("tss: %d triangles do not fit the %dx%d atlas at any rate; one texel each", ids.size, W, H)
        self._prev_kind[:] = -1
        self._prev_kind[ids], self._prev_level[ids] = plan.kind, np.where(plan.kind == KIND_LP, level, 0)
        self._prev_w1[ids], self._prev_w2[ids], self._prev_h[ids] = plan.w, plan.w2, plan.h
        self._prev_a[ids] = plan.a
        return plan, base, slant, rate, kept

    def plan_view(self, ctx: ServerContext, iframe: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, AtlasPlan,
                                                                  np.ndarray, np.ndarray, float, float]:
        """The frame's PVS and atlas plan, before any shading: ``pvs`` ids, object ``models`` (O, 4, 4), the PVS's
        pixel corners ``px`` and ``depth``, then :meth:`plan`'s plan, base vertices, slantedness and rate, and the
        ``perf_counter`` time at which the PVS was done.  Triangles the atlas cannot hold at all are left out of
        ``pvs``, ``px`` and ``depth`` (counted in ``self.left_out``)."""
        c = self.config
        if self._gl is None:
            self._setup_gl(ctx.renderer)
        big = self.intrinsics.enlarged(1.0 + c.fov_margin, keep_pixel_density=True) if c.fov_margin > 0 else self.intrinsics
        samples = self.pvs_samples(ctx)
        area = self._ids.pvs_area(distinct_samples(samples, self._animated), big)
        self._last_seen[area > 0] = self._frames
        pvs = np.flatnonzero(self._last_seen >= self._frames - c.pvs_linger_frames)
        ring = None
        if c.pvs_ring > 0 and pvs.size and moving(samples):
            # the triangles beside the PVS (sharing a vertex, pvs_ring rings out) join it at one texel each: where the
            # client's view turns past the EVS samples, a triangle they did not see shows a coarse colour, not a hole
            grown = np.zeros(self.tris.count, bool)
            grown[pvs] = True
            core = grown.copy()
            for _ in range(c.pvs_ring):
                at = np.zeros(self._n_vertices, bool)
                at[self.tris.vid[grown]] = True
                grown = at[self.tris.vid].any(axis=1)
            pvs = np.flatnonzero(grown)
            ring = ~core[pvs]
        t1 = time.perf_counter()
        shared = ctx.shared if isinstance(ctx.shared, dict) and ctx.shared.get("t_s") == ctx.t_s else None
        models = shared["models"] if shared is not None else np.stack([o.model_matrix(ctx.t_s) for o in self.scene.objects])
        T = self.tris
        m = models[T.obj[pvs]].astype(np.float64)                                     # (N, 4, 4)
        world = np.einsum("nij,nkj->nki", m[:, :3, :3], T.pos[pvs].astype(np.float64)) + m[:, None, :3, 3]
        px, depth = project(world, ctx.target_pose, self.intrinsics)
        visible = visible_area(world, ctx.target_pose, self.intrinsics, c.fov_margin)
        if ring is not None:
            visible[ring] = 0.0          # no samples asked for: one texel (classify's single kind)
        self._min_level = None
        if c.flip_level > 0:
            inv_t = np.linalg.inv(models[:, :3, :3].astype(np.float64)).transpose(0, 2, 1)   # per object, then per triangle
            nrm = np.einsum("nij,nkj->nki", inv_t[T.obj[pvs]], T.nrm[pvs].astype(np.float64))
            eye = np.asarray(ctx.target_pose.position, np.float64)
            v = eye - world
            ndv = (nrm * v).sum(axis=2) / np.maximum(np.linalg.norm(nrm, axis=2) * np.linalg.norm(v, axis=2), 1e-12)
            flips = (ndv.min(axis=1) < 0.0) & (ndv.max(axis=1) > 0.0)
            self._min_level = np.where(flips if ring is None else flips & ~ring, c.flip_level, 0).astype(np.int64)
        plan, base, slant, rate, kept = self.plan(pvs, px, iframe, visible)
        self.left_out = 0 if kept is None else pvs.size - kept.size
        if kept is not None:
            pvs, px, depth = pvs[kept], px[kept], depth[kept]
        return pvs, models, px, depth, plan, base, slant, rate, t1

    def produce(self, ctx: ServerContext) -> Update:
        c = self.config
        if self._gl is None:
            self._setup_gl(ctx.renderer)
        t0 = time.perf_counter()
        full = ctx.keyframe_requested or bool(ctx.feedback.newly_lost("atlas")) or self._frames == 0
        iframe = full or self._since_i >= c.gop
        pvs, models, px, depth, plan, base, slant, rate, t1 = self.plan_view(ctx, iframe)
        iframe = iframe or (plan.repacked and c.layout == "stable" and self._frames > 0)
        persp = (depth.min(axis=1) > NEAR_M) & c.perspective
        t2 = time.perf_counter()
        self.keep_unwritten = not iframe
        rows = self._live_rows(ctx, pvs, plan, base, models, iframe, depth, persp)
        shaded = self._gather(ctx, pvs, plan, base, persp, models, px, rows=rows)
        W, H = self.atlas
        rgba = np.frombuffer(self._fbo.read(components=4, alignment=1), np.uint8).reshape(H, W, 4)
        if c.colour_order > 0:
            rows, luma = lp_luma(rgba, plan)
            unknown = plan.repacked and iframe and bool(np.isnan(self._luma[pvs[rows]]).any())
            self._luma[pvs[rows]] = luma
            # the next repack's order: by colour bin, then id; triangles of no known colour last
            self.store.rank = np.where(np.isnan(self._luma), 1 << 30,
                                       np.floor(np.nan_to_num(self._luma) / c.colour_order)).astype(np.int64)
            if unknown:   # a repack placed triangles of no known colour: place them all again by colour, shade again
                plan = plan_atlas(self.store, pvs, plan.kind, plan.level, plan.w, plan.w2, plan.h, plan.a, reset=True,
                                  grid=c.os_grid)
                assert not plan.overflow, "the same classes repacked in another order fit as they did"
                shaded = self._gather(ctx, pvs, plan, base, persp, models, px)
                rgba = np.frombuffer(self._fbo.read(components=4, alignment=1), np.uint8).reshape(H, W, 4)
        atlas = fill_gutters(rgba, plan.height, self.block) if c.gutter_fill else rgba[..., :3].copy()
        if self.block > 1 and c.gutter_fill:
            if not iframe and self._sent_atlas is not None:
                # a block no sample has written keeps last frame's colours: the push-pull fill follows every change
                # around it, which a P-frame would code for texels no client reads
                B = self.block
                empty = ~(rgba[..., 3] > 127).reshape(H // B, B, W // B, B).any(axis=(1, 3))
                keep = np.repeat(np.repeat(empty, B, axis=0), B, axis=1)
                atlas[keep] = self._sent_atlas[keep]
            self._sent_atlas = atlas
        t3 = time.perf_counter()
        new = pvs[~self.client_has[pvs]]
        self.client_has[new] = True
        geo = encode_geometry(new, self.tris.vid, self.tris.vq)
        desc = descriptors(plan, persp, base)
        # a full table only where the client may lack the state (the first frame, a keyframe request, a loss) or the
        # single-texel cell changes: the tris stream is reliable, so a periodic I-frame whose layout kept its cells
        # (a still view's repack restores the same id order) sends the rows that changed, as a P-frame does
        if full or self._frames == 0 or plan.single_px != self._sent_single_px:
            table = encode_table(pvs, plan, desc)
            changed = np.ones(pvs.size, bool)
            send_table = True
        else:
            live = np.zeros(self.tris.count, bool)
            live[pvs] = True
            gone = np.flatnonzero(self._sent_live & ~live)
            # a row whose descriptor is unchanged still moves when its bin's shelves do (per-frame layouts)
            changed = self._rows_changed(pvs, plan, desc)
            table = encode_table(pvs, plan, desc, gone, changed)
            send_table = bool(changed.any() or gone.size)
        self._sent_live[:] = False
        self._sent_live[pvs] = True
        self._sent_desc[pvs] = desc
        self._sent_origin[pvs] = plan.origin
        self._sent_single_px = plan.single_px
        self._since_i = 1 if iframe else self._since_i + 1
        self._frames += 1
        self.last_plan, self.last_ids = plan, pvs
        k = plan.kind
        os_ = k == KIND_OS
        inside = float(((plan.w[os_] + plan.w2[os_]) * plan.h[os_] / 2.0).sum())
        self._stats = {
            "pvs_triangles": float(pvs.size), "pvs_ms": (t1 - t0) * 1e3, "layout_ms": (t2 - t1) * 1e3,
            "shade_ms": (t3 - t2) * 1e3, "samples": float(plan.samples.sum()), "shaded": float(shaded),
            "lp_triangles": float((k == KIND_LP).sum()), "os_triangles": float(os_.sum()),
            "single_triangles": float((k == KIND_SINGLE).sum()), "lp_samples": float(plan.samples[k == KIND_LP].sum()),
            "os_samples": float(plan.samples[os_].sum()), "os_inside": inside,
            "atlas_used_pct": 100.0 * plan.height / H, "rate": rate, "iframe": float(iframe),
            "geo_sent": float(new.size), "table_rows": float(changed.sum()), "repacked": float(plan.repacked), "atlas_load_pct": 100.0 * self.store.load(),
            "slanted_pct": 100.0 * float((slant > c.slant_threshold).mean()) if slant.size else 0.0,
            "tris_left_out": float(self.left_out), "gathered_triangles": float(pvs.size if rows is None else rows.size),
            "stale_kept_triangles": float(self._stale_kept),
        }
        meta = {"v": WIRE_VERSION, "xf": models.astype(np.float32)}
        # no geo message when no triangle is new, no tris message when the table does not change (a still view's
        # P-frames and periodic I-frames): the client keeps the state both reliable streams built.  An empty delta
        # was 113 bytes a frame on the wire, mostly its message's framing (the duck still: 27 kbit/s)
        data: dict[str, bytes] = {"geo": geo} if new.size else {}
        if send_table:
            data["tris"] = table
        return Update(ctx.frame_id, ctx.t_s, ctx.target_pose, {"atlas": atlas}, meta, force_idr=iframe, data=data)

    def _live_refresh(self, ctx: ServerContext) -> int:
        """:attr:`TssConfig.live_refresh_frames` where it applies (the renderer relighting the probes at a rate: a live
        server), else 0 (virtual time: every PVS triangle is gathered every frame)."""
        return int(self.config.live_refresh_frames) if getattr(ctx.renderer, "gi_hz", 0.0) > 0 else 0

    def _live_rows(self, ctx: ServerContext, pvs: np.ndarray, plan: AtlasPlan, base: np.ndarray, models: np.ndarray,
                   iframe: bool, depth: np.ndarray, persp: np.ndarray) -> np.ndarray | None:
        """Which rows of ``pvs`` this frame gathers (sorted; None: all), live (:meth:`_live_refresh` > 0) on a
        P-frame: those whose samples would be wrong, not only late (new to the client's table or in another cell:
        :meth:`_rows_changed`; of a moved object; near a moved shadow caster; placed in
        perspective (``persp``) at corner ``depth`` ratios that changed by :data:`PERSP_KEEP` or more), all of
        them when a light's intensity changed; of the others, gathered at another eye or time of the probes
        (stale), every one gathered ``refresh`` or more frames ago and the longest-kept up to a ``1 / refresh``
        share (rounded up).  Records what it gathers."""
        refresh = self._live_refresh(ctx)
        sc = self.scene
        pose = ctx.target_pose
        ratio = depth[:, 1:] / np.where(np.abs(depth[:, :1]) > 1e-9, depth[:, :1], 1e-9)
        key = (tuple(map(float, pose.position)), tuple(map(float, pose.orientation)),
               gi_time(ctx.t_s, float(getattr(ctx.renderer, "gi_hz", 0.0))))
        if key != self._gen_key:
            self._gen_key, self._gen = key, self._gen + 1
        lights = (float(sc.sun.intensity.value(ctx.t_s)) if sc.sun is not None else None,
                  tuple(float(pl.intensity.value(ctx.t_s)) for pl in sc.point_lights))
        prev, prev_lights = self._gathered_models, self._gathered_lights
        self._gathered_models, self._gathered_lights = models.copy(), lights
        rows = None
        self._stale_kept = 0
        if refresh and not iframe and prev is not None and prev.shape == models.shape and lights == prev_lights \
                and plan.single_px == self._sent_single_px:
            moved = (models != prev).any(axis=(1, 2))
            hard = self._rows_changed(pvs, plan, descriptors(plan, persp, base)) | moved[self.tris.obj[pvs]]
            pp = np.flatnonzero(persp & ~hard)              # depths > NEAR_M now and when gathered (persp is in desc)
            hard[pp] = (np.abs(ratio[pp] / self._gathered_ratio[pvs[pp]] - 1.0) >= PERSP_KEEP).any(axis=1)
            cand = np.flatnonzero(~hard)
            if cand.size:
                hard[cand] = self._near_moved_casters(pvs[cand], models, prev, moved)
            stale = ~hard & (self._gathered_gen[pvs] != self._gen)
            due = refresh_due(stale, self._gathered_at[pvs], self._frames, refresh)
            self._stale_kept = int((stale & ~due).sum())
            rows = np.flatnonzero(hard | due)
        drawn = pvs if rows is None else pvs[rows]
        self._gathered_at[drawn] = self._frames
        self._gathered_gen[drawn] = self._gen
        self._gathered_ratio[drawn] = ratio if rows is None else ratio[rows]
        return rows

    def _rows_changed(self, pvs: np.ndarray, plan: AtlasPlan, desc: np.ndarray) -> np.ndarray:
        """(len(pvs),) bool: which triangles' rows of the client's table change this frame: new to the client, another
        descriptor (:func:`~.wire.descriptors` ``desc``: kind, level, cell) or another origin."""
        return (~self._sent_live[pvs] | (desc != self._sent_desc[pvs]).any(axis=1)
                | (plan.origin != self._sent_origin[pvs]).any(axis=(1, 2)))

    def _near_moved_casters(self, ids: np.ndarray, models: np.ndarray, prev: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """(len(ids),) bool: whether triangles ``ids``' sun-shadow lookups (the triangle at ``models``, grown by the
        lookup's normal offset) reach the sun's map where a dynamic caster that moved (``moved``, per object) was
        (``prev``) or is (its object box, grown by ``sas``'s :data:`~..sas.server.SHADOW_REACH_TEXELS`)."""
        sun = self.scene.sun
        casters = np.flatnonzero(moved & self._dynamic)
        if casters.size == 0 or sun is None or ids.size == 0:
            return np.zeros(ids.size, bool)
        vp = light_view_projection(self.scene)
        box = self.tris.box[casters].astype(np.float64)
        reach = SHADOW_REACH_TEXELS * 2.0 / sun.shadow_map_size
        boxes = caster_rects(vp, box[:, 0], box[:, 1], (prev[casters], models[casters]), reach)
        m = models[self.tris.obj[ids]].astype(np.float64)
        world = np.einsum("nij,nkj->nki", m[:, :3, :3], self.tris.pos[ids].astype(np.float64)) + m[:, None, :3, 3]
        scale = float(np.linalg.norm(vp[:2, :3], axis=1).max())
        return rects_overlap(light_rects(vp, world, SHADOW_NORMAL_OFFSET_M * scale), boxes)

    def _vertices(self, ids: np.ndarray, plan: AtlasPlan, base: np.ndarray, persp: np.ndarray, px: np.ndarray) -> np.ndarray:
        """(N, 3, VERTEX_FLOATS) gathering-stage vertices (OS triangles rotated so the base starts at vertex 0)."""
        T = self.tris
        rot = np.where(plan.kind == KIND_OS, base, 0)
        order = (rot[:, None] + np.arange(3)) % 3
        rows = ids[:, None]
        out = np.empty((ids.size, 3, VERTEX_FLOATS), np.float32)
        out[..., 0:3], out[..., 3:6], out[..., 6:8], out[..., 8:12] = (a[rows, order] for a in (T.pos, T.nrm, T.uv, T.tan))
        # albedo lod as a trilinear forward render picks it: log2 of the longer texel-space
        # derivative of the uv mapping per display pixel (one Jacobian per triangle, at the reference view)
        lod = self._lod(ids, px, order, out[..., 6:8])
        o0, o1 = layout_attributes(plan.kind, plan.origin, plan.w, plan.w2, plan.h, plan.a, plan.samples)
        # the per-triangle attributes cast to float32 once and repeated on the three vertices
        flat = np.empty((ids.size, 12), np.float32)
        flat[:, 0], flat[:, 1], flat[:, 2], flat[:, 3] = plan.kind, plan.level, persp, lod
        flat[:, 4:8], flat[:, 8:12] = o0, o1
        out[..., 12:] = flat[:, None, :]
        return out

    def _lod(self, ids: np.ndarray, px: np.ndarray, order: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """(N,) albedo mip level per triangle: GL's ``log2(max(|d uv/dx|, |d uv/dy|))`` in texels, from the
        triangle's pixel corners ``px`` (N, 3, 2, original order) and ``uv`` (N, 3, 2, rotated by ``order``)."""
        p = np.take_along_axis(px, order[:, :, None], axis=1)
        dp = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=2)           # (N, 2, 2) columns: edges in pixels
        du = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], axis=2) * self._tex_size[self.tris.obj[ids]][:, :, None]
        det = dp[:, 0, 0] * dp[:, 1, 1] - dp[:, 0, 1] * dp[:, 1, 0]
        ok = np.abs(det) > 1e-9
        inv = np.zeros_like(dp)
        inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 0], inv[:, 1, 1] = dp[:, 1, 1], -dp[:, 0, 1], -dp[:, 1, 0], dp[:, 0, 0]
        inv /= np.where(ok, det, 1.0)[:, None, None]
        J = du @ inv                                                              # (N, 2, 2): d(texel)/d(pixel)
        rho = np.maximum(np.linalg.norm(J[:, :, 0], axis=1), np.linalg.norm(J[:, :, 1], axis=1))
        return np.where(ok, np.maximum(0.0, np.log2(np.maximum(rho, 1e-12))), 0.0)

    def _gather(self, ctx: ServerContext, ids: np.ndarray, plan: AtlasPlan, base: np.ndarray, persp: np.ndarray,
                models: np.ndarray, px: np.ndarray, eye: tuple[float, float, float] | None = None,
                rows: np.ndarray | None = None) -> int:
        """Shade every live triangle's samples into the atlas; returns the samples the GPU shaded.  With
        ``keep_unwritten`` (P-frames) the texels no live triangle writes keep the previous frame's colours: no client
        reads them, and a P-frame then spends no bits on the cells that triangles left.  ``eye``: where the shading's
        view-dependent terms look from (None: the target pose; ``benchmarks/bench_tss_churn.py`` separates the two).
        ``rows``: gather only these rows of ``ids`` (:meth:`_live_rows`; the others keep their samples)."""
        if rows is not None:
            ids, base, persp, px = ids[rows], base[rows], persp[rows], px[rows]
            plan = dataclasses.replace(plan, **{k: getattr(plan, k)[rows] for k in
                                                ("kind", "level", "slot", "origin", "w", "w2", "h", "a", "samples")})
        gl = self._gl
        self._fbo.use()
        if not self.keep_unwritten:
            self._fbo.clear(0.0, 0.0, 0.0, 0.0)     # alpha 0: no sample written (fill_gutters)
        self._counter.clear()
        if ids.size == 0:
            return 0
        data = self._vertices(ids, plan, base, persp, px).tobytes()
        self._vbo, self._vao = grow_vertex_buffer(gl, self._prog, self._vbo, self._vao, len(data), "3f 3f 2f 4f 4f 4f 4f",
                                                  ("in_position", "in_normal", "in_uv", "in_tangent", "in_info", "in_o0", "in_o1"))
        self._vbo.write(data)
        prog = self._prog
        ctx.renderer.bind_shading(prog, self.scene, ctx.t_s)
        prog["u_eye"].value = eye if eye is not None else tuple(float(x) for x in ctx.target_pose.position)
        prog["u_view"].write(np.asarray(ctx.target_pose.view_matrix(), "f4").T.tobytes())
        set_reference_view(prog, self.intrinsics, ctx.target_pose)   # per-sample texture gradients
        set_uniform(prog, "u_os_centred", int(self.config.os_grid == "centred"))
        set_uniform(prog, "u_lp_inset", float(self.config.lp_inset))   # layout.lp_inset_offset
        set_uniform(prog, "u_single_px", plan.single_px)
        self._tex.bind_to_image(0, read=False, write=True)
        self._counter.bind_to_storage_buffer(1)
        o = self.tris.obj[ids]
        gl.enable_direct(RASTERIZER_DISCARD)
        try:
            for s, e in runs(o):
                og = self._sg.objects[int(o[s])]
                mm = models[int(o[s])]
                prog["u_model"].write(np.asarray(mm, "f4").T.tobytes())
                prog["u_normal_matrix"].write(np.asarray(np.linalg.inv(mm[:3, :3]).T, "f4").T.tobytes())
                ctx.renderer.bind_material(prog, og)
                self._vao.render(mode=gl.PATCHES, first=3 * s, vertices=3 * (e - s))
        finally:
            gl.disable_direct(RASTERIZER_DISCARD)
        gl.memory_barrier()
        return int(np.frombuffer(self._counter.read(4), np.uint32)[0])
