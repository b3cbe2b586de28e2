"""The SAS server half: PVS, level selection, atlas allocation, shading, metadata.

Per server frame (paper figure 2):

1. visibility: EVS samples from the newest client pose to ``target + one frame`` in
   steps of ``pvs_step_ms``, at most ``pvs_max_samples`` of them (poses from the pose predictor, animated objects at each
   sample's time; ``pvs_prediction="none"`` uses the newest pose only, objects at
   the frame's time), each with the field of view enlarged by ``fov_margin``; the
   PVS is their union;
2. level selection (eq. 1-3) at the predicted pose, with hysteresis;
3. atlas memory management (:class:`~.allocator.PatchAllocator`); the memory load is
   checked every ``reset_period`` frames, and an atlas reset (global repack, always an
   I-frame) happens when it passes ``high_water``, or at once when an allocation fails;
   other I-frames come every ``gop`` frames and on a full resend;
4. shading of every PVS patch into its block with ``shading.glsl`` (the ground
   truth's shader); on I-frames the atlas is cleared first so unused blocks are black;
5. metadata: geometry of patches entering the PVS, block rectangles of patches
   that were (re)placed, ids of patches leaving, dynamic object transforms every frame.

Loss recovery: when the client asks for a keyframe or reports lost frames, the next
frame is an I-frame with a *full* resend: the complete PVS list, every block rectangle
and all geometry (the client may have missed geometry sent "once"); the client
replaces its state with it.  Atlas resets also carry the full PVS list and block
table (every block moved) but no geometry the client already has.

Several sessions on one server share :class:`SasProducer`: the scene's patches, the
patch-id pass, the shading program and each frame's scene state (transforms, patches
in world space) are made once; a session keeps what depends on its client: its PVS,
levels, atlas, shading at its client's eye, metadata and encoder.

The wire format is in :mod:`.wire`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...codecs.video import VideoCodecConfig
from ...render.gl import grow_vertex_buffer, has_uniform, load_program, read_shader, runs, set_reference_view
from ...render.renderer import MAP_UNITS, light_view_projection
from ...scene.pose import CameraIntrinsics
from ..base import AnyStreamSpec, SceneProducer, ServerContext, ServerHalf, StreamSpec, Update
from .config import SasConfig
from .allocator import PatchAllocator
from .levels import LevelChoice, footprint, log_size, patch_extent_px, patch_world_slots, select_levels
from .patches import ScenePatches, build_scene_patches, split_scene_meshes
from .pvs import PatchIdPass, PoseSample, evs_samples, model_bytes
from .wire import META_VERSION, SLOT_LAYOUT, TRI_SLOTS, block_inset, block_layout_xy, encode_geometry, encode_ids

log = logging.getLogger(__name__)
SHADERS = Path(__file__).parent / "shaders"
VERTEX_FLOATS = 2 + 3 + 3 + 2 + 4 + 4 + 2
"""Floats per atlas-shading vertex: atlas xy, position, normal, uv, tangent, block rect, footprint."""
TEXTURE_MAPS = ("texture", "normal_texture", "metallic_roughness_texture", "occlusion_texture", "emissive_texture")
"""Material maps whose detail makes a patch textured (:attr:`SasConfig.fill_max_density` applies, else ``_plain``)."""
EXPAND_TEXELS = 1.5
"""How far each triangle is grown in the atlas (texels) so every texel a bilinear tap of the client may read is shaded."""
INSET_GROW_TEXELS = 0.25
"""How far an edge on an inset block side is grown: just past the border texels' centres, which it runs through (the block's side is half a texel further)."""
SHARED_GROW_TEXELS = 1.0 / 32.0
"""How far an edge shared with another triangle of the patch is grown: the neighbour shades the texels beyond it
itself, so only far enough that texel centres on the edge (a block's diagonal runs through some) are not lost to
rounding of the two triangles' vertices: more than a rasteriser's 1/256-texel snap (not growing it left cracks),
less than any other texel centre's distance from a block's diagonal (0.06 texels in a 16 x 2 block), so only
the centres on the edge are drawn twice."""


def shared_edges(tris: np.ndarray) -> np.ndarray:
    """(T, 3) bool for triangles ``tris`` (T, 3) slot triples (rows of -1 unused): whether edge ``e`` (slot
    ``e`` to ``e + 1``) is shared with another triangle of the patch."""
    out = np.zeros(tris.shape, bool)
    for t, tri in enumerate(tris):
        if tri[0] < 0:
            continue
        for e in range(3):
            a, b = int(tri[e]), int(tri[(e + 1) % 3])
            out[t, e] = any(u != t and a in row and b in row for u, row in enumerate(tris.tolist()))
    return out


TRI_SHARED: dict[int, np.ndarray] = {k: shared_edges(v) for k, v in TRI_SLOTS.items()}
"""Per patch size, which triangle edges are shared inside the patch (:func:`shared_edges`)."""
PER_OBJECT_UNIFORMS = frozenset({"u_model", "u_normal_matrix", "u_base_color", "u_specular", "u_shininess",
                                 "u_metallic", "u_roughness", "u_normal_scale", "u_occlusion_strength", "u_emissive",
                                 "u_uv_transform", "u_albedo", "u_has_texture", "u_footprint"}
                                | set(MAP_UNITS) | {"u_has_" + k[2:] for k in MAP_UNITS})
"""The shading program's uniforms set per object draw (its matrices, ``Renderer.bind_material``'s material); every
other uniform is the frame's (lighting, view, atlas size) and goes into :func:`frame_uniform_key`."""
SHADOW_NORMAL_OFFSET_M = 0.03
"""``shadow_factor`` looks the shadow up this far along the (view-flipped) normal (``shading.glsl``)."""
SHADOW_REACH_TEXELS = 3.0
"""How many shadow-map texels around its lookup a texel's shadow reads or a caster's box may touch: the 3 x 3
PCF taps (one texel), the comparison sampler's bilinear footprint (one more) and rasterisation past the box's
projection (one more)."""


SHADOW_FACTOR_SIGNATURE = "float shadow_factor(vec3 world_pos, vec3 n) {"
"""``shading.glsl``'s shadow lookup, renamed ``shadow_factor_lookup`` for the shadow cache (``atlas_shade.frag``)."""
SHADOW_UNIFORMS = ("u_has_shadow", "u_light_vp", "u_sun_dir")
"""The frame uniforms a texel's shadow factor reads (the maps aside)."""
FLIP_MARGIN = 1e-3
"""A triangle's side towards the eye is known when every n_i . (eye - x_j) of its (grown) vertices is this far
(relative to |n_i| |eye - x_j|) from 0 on the same side: float rounding in the shader cannot flip it ..."""
FLIP_SPREAD = 0.05
"""... and this far relative to the largest of them: a fragment at a triangle's edge may carry weights a little
below 0 (its centre against the rasteriser's snapped vertices), which cannot then outweigh the smallest term."""
SHADOW_CACHE_UNIT = 9
"""Texture unit of the shadow cache (the shading program uses 0-8)."""


EYE_UNIFORMS = frozenset({"u_eye", "u_view_proj"})
"""The frame uniforms that follow the client's eye (its position; the reference view the texture gradients are
taken in): with :attr:`SasConfig.reshade_eye_deg` a block is kept over their change by its own test."""


def frame_uniform_key(prog: Any, skip: frozenset[str] = frozenset()) -> bytes:
    """The bytes of every uniform of ``prog`` that is not set per object (:data:`PER_OBJECT_UNIFORMS`) nor in
    ``skip``: what a texel's shading reads besides its vertex attributes, its object's matrices and material, and
    the textures."""
    parts = []
    for name in sorted(prog):
        if name in PER_OBJECT_UNIFORMS or name in skip:
            continue
        m = prog[name]
        if hasattr(m, "array_length") and hasattr(m, "read") and not hasattr(m, "binding"):
            parts += [name.encode(), m.read()]
    return b"".join(parts)


def light_rects(light_vp: np.ndarray, pts: np.ndarray, grow: np.ndarray | float = 0.0) -> np.ndarray:
    """(N, 4) light-clip rectangles (x0, y0, x1, y1) of point sets ``pts`` (N, K, 3) world metres under the sun's
    orthographic ``light_vp``, each grown by ``grow`` clip units."""
    xy = pts @ light_vp[:2, :3].T + light_vp[:2, 3]
    g = np.asarray(grow, np.float64).reshape(-1, 1)
    return np.concatenate([xy.min(axis=1) - g, xy.max(axis=1) + g], axis=1)


def rects_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a),) whether each rectangle of ``a`` (N, 4) overlaps any of ``b`` (M, 4)."""
    if a.shape[0] == 0 or b.shape[0] == 0:
        return np.zeros(a.shape[0], bool)
    return ((a[:, None, 0] <= b[None, :, 2]) & (b[None, :, 0] <= a[:, None, 2])
            & (a[:, None, 1] <= b[None, :, 3]) & (b[None, :, 1] <= a[:, None, 3])).any(axis=1)


def caster_rects(vp: np.ndarray, lo: np.ndarray, hi: np.ndarray, placements: tuple[np.ndarray, ...],
                 reach: float) -> np.ndarray:
    """(len(placements) * K, 4) the light-clip rectangles of K casters' object boxes (corners ``lo``, ``hi``: (K, 3))
    placed by each of ``placements`` (their (K, 4, 4) object matrices: where a moved caster was and is) under the
    sun's ``vp``, each grown by ``reach`` clip units."""
    corners = np.stack([np.where(np.array([(i >> j) & 1 for j in range(3)], bool), hi, lo) for i in range(8)], axis=1)
    return np.concatenate([light_rects(vp, corners @ m[:, :3, :3].transpose(0, 2, 1) + m[:, None, :3, 3], reach)
                           for m in placements])


def refresh_due(stale: np.ndarray, shaded_at: np.ndarray, frame: int, refresh: int) -> np.ndarray:
    """Which of the ``stale`` items (late, not wrong: ``live_refresh_frames``) are shaded again this ``frame``: those
    last shaded (``shaded_at``) ``refresh`` or more frames ago, and the longest-kept of the rest up to a ``1 /
    refresh`` share of the stale ones, so that none stays older than ``refresh - 1`` frames."""
    due = stale & (frame - shaded_at >= refresh)
    quota = -(-int(stale.sum()) // refresh) - int(due.sum())
    if quota > 0:
        cand = np.flatnonzero(stale & ~due)
        due[cand[np.argsort(shaded_at[cand], kind="stable")[:quota]]] = True
    return due


def has_texture_detail(material: Any) -> bool:
    """Whether one of ``material``'s maps (:data:`TEXTURE_MAPS`) varies: a constant map (a loader's 2x2 grey for
    a model without one) carries no detail more texels could resolve."""
    for k in TEXTURE_MAPS:
        m = getattr(material, k, None)
        if m is not None and m.size:
            flat = np.asarray(m).reshape(-1, m.shape[-1] if m.ndim == 3 else 1)
            if bool((flat != flat[0]).any()):
                return True
    return False


def object_boxes(meshes: list[Any]) -> np.ndarray:
    """(n_obj, 2, 3) float32 object-space bounding boxes (lo, hi corners, metres) of ``meshes``."""
    lo = np.array([m.positions.min(axis=0) for m in meshes], np.float32).reshape(-1, 3)
    hi = np.array([m.positions.max(axis=0) for m in meshes], np.float32).reshape(-1, 3)
    return np.stack([lo, hi], axis=1)


def quantize_vertices(meshes: list[Any], box: np.ndarray) -> np.ndarray:
    """(V_scene, 3) uint16: every vertex quantised in its object's box, as :func:`~.wire.quantize_slots` does."""
    if not meshes:
        return np.zeros((0, 3), np.uint16)
    q = []
    for m, bx in zip(meshes, box):
        ext = np.maximum(bx[1] - bx[0], 1e-9)
        q.append(np.rint((m.positions - bx[0]) / ext * 65535.0).clip(0, 65535).astype(np.uint16))
    return np.concatenate(q)


def load_scene_patches(scene: Any, config: SasConfig, intr: CameraIntrinsics) -> ScenePatches:
    """Scene-level work done once at load: split the meshes, group them into patches.

    Depends only on the scene, the config and the display, not on a client's state.
    """
    meshes, edge = split_scene_meshes(scene, config.split_edge_m(intr), config.split_max_triangles)
    sp = build_scene_patches(scene, meshes)
    log.info("sas: %d triangles split to %d (edges <= %.3f m) in %d patches",
             scene.triangle_count, sum(m.triangle_count for m in meshes), edge, sp.count)
    return sp


def expand_triangles(p: np.ndarray, d: float | np.ndarray) -> np.ndarray:
    """Barycentric weights (N, 3, 3) of 2D triangles ``p`` (N, 3, 2) with their edges moved outward by ``d``.

    ``d``: one distance, or one per edge (3,) or (N, 3), edge ``k`` running from vertex ``k``
    to ``k + 1``.  Each vertex moves to where its two moved edges meet (a miter).  Row
    ``k`` gives the new vertex ``k`` as weights of the original three, so any attribute
    is extrapolated linearly with ``weights @ attributes``.
    """
    e_next = np.roll(p, -1, axis=1) - p                   # edge k: p_k -> p_{k+1}
    area2 = e_next[:, 0, 0] * e_next[:, 1, 1] - e_next[:, 0, 1] * e_next[:, 1, 0]
    sgn = np.where(area2 >= 0, 1.0, -1.0)[:, None]
    ln = np.maximum(np.linalg.norm(e_next, axis=2), 1e-9)
    nrm = np.stack([e_next[..., 1], -e_next[..., 0]], axis=-1) / ln[..., None] * sgn[..., None]   # outward
    dist = np.broadcast_to(np.asarray(d, np.float64), (p.shape[0], 3))
    n_in, d_in = np.roll(nrm, 1, axis=1), np.roll(dist, 1, axis=1)   # edge ending at vertex k
    n_out, d_out = nrm, dist                                         # edge starting at vertex k
    dots = (n_in * n_out).sum(-1)
    # equal distances: the miter d (n_in + n_out) / (1 + dots), held at about 6.3 d at a sliver's sharp tip
    d_max = np.maximum(d_in, d_out)
    miter = d_max[..., None] * (n_in + n_out) / np.maximum(1.0 + dots, 0.05)[..., None]
    # unequal: the point at d_in from the incoming edge's line and d_out from the outgoing one's,
    # o = a n_in + b n_out with a + b dots = d_in and a dots + b = d_out (the miter where the edges
    # are nearly parallel or that point runs past 20 d)
    den = 1.0 - dots * dots
    ok = (den > 1e-6) & (d_in != d_out)
    den = np.where(ok, den, 1.0)
    a = (d_in - dots * d_out) / den
    b = (d_out - dots * d_in) / den
    solved = a[..., None] * n_in + b[..., None] * n_out
    ok &= np.linalg.norm(solved, axis=-1) <= 20.0 * d_max
    off = np.where(ok[..., None], solved, miter)
    q = p + off
    # barycentrics of q w.r.t. p
    a0, b0, c0 = p[:, 0], p[:, 1], p[:, 2]
    v0, v1 = b0 - a0, c0 - a0
    dd = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    dd = np.where(np.abs(dd) < 1e-12, 1e-12, dd)
    w = q - a0[:, None]
    l1 = (w[..., 0] * v1[:, None, 1] - w[..., 1] * v1[:, None, 0]) / dd[:, None]
    l2 = (v0[:, None, 0] * w[..., 1] - v0[:, None, 1] * w[..., 0]) / dd[:, None]
    return np.stack([1 - l1 - l2, l1, l2], axis=-1)


def boundary_axes(layout_uv: np.ndarray) -> np.ndarray:
    """(3,) int per edge of a triangle with block-local corners ``layout_uv`` (3, 2): the layout axis (0 = u,
    1 = v) across which the edge lies on a side of the block (its coordinate there is 0 or 1), or -1.

    Growing an edge on a side only draws texels outside the block, which the shading
    stage discards: the triangles keep those edges where they are (on the default view the
    grown triangles covered about 7 times the blocks' texels), or, along an inset side,
    grow them just past the border texels' centres.  Nothing inside the block is lost: the
    grown triangle is the intersection of its edges' half-planes; a point of the block
    within the growth distance of the triangle lies inside every kept side's half-plane
    (that side's line bounds the block) and inside every moved one."""
    nxt = np.roll(layout_uv, -1, axis=0)
    out = np.full(3, -1, np.int64)
    for c in (1, 0):
        on = (layout_uv[:, c] == nxt[:, c]) & ((layout_uv[:, c] == 0) | (layout_uv[:, c] == 1))
        out[on] = c
    return out


@dataclass
class PatchSet:
    """The scene-level state of one patch set (one display size), built once and shared by every session.

    ``patches`` (:func:`load_scene_patches`); ``obj_box`` (n_obj, 2, 3) object-space boxes (metres, the
    geometry's quantisation boxes, :func:`object_boxes`) and ``vertex_q`` (V_scene, 3) every vertex quantised
    in them (:func:`quantize_vertices`); ``animated`` (A,) the patches of animated objects, ascending, and
    ``animated_row`` (P,) each patch's row among them (-1: a still object's); ``still_world`` (P, 5, 3) the
    still objects' slots in world space (metres; placed once, a still object's model matrix never changes;
    animated rows unused)."""

    patches: ScenePatches
    obj_box: np.ndarray
    vertex_q: np.ndarray
    animated: np.ndarray
    animated_row: np.ndarray
    still_world: np.ndarray

    @staticmethod
    def build(scene: Any, patches: ScenePatches) -> "PatchSet":
        obj_box = object_boxes(patches.meshes)
        animated_obj = np.array([o.animation is not None for o in scene.objects], bool)
        is_anim = animated_obj[patches.object_index] if patches.count else np.zeros(0, bool)
        animated = np.flatnonzero(is_anim)
        row = np.full(patches.count, -1, np.int64)
        row[animated] = np.arange(animated.size)
        still = np.flatnonzero(~is_anim)
        world = np.zeros((patches.count, patches.slot_pos.shape[1], 3))
        if still.size:
            world[still] = patch_world_slots(patches, still, np.stack([o.model_matrix(0.0) for o in scene.objects]))
        return PatchSet(patches, obj_box, quantize_vertices(patches.meshes, obj_box), animated, row, world)


@dataclass
class SasFrame:
    """One server frame's scene state, prepared once for every session (:meth:`SasProducer.prepare`).

    ``models`` (n_obj, 4, 4) object-to-world at ``t_s``; ``animated_world`` per patch set (keyed by
    ``id``) the animated patches' slots in world space at ``t_s``; the model and normal matrices' uniform
    bytes per object, made by the first session that draws the object.
    """

    frame_id: int
    t_s: float
    models: np.ndarray
    animated_world: dict[int, np.ndarray] = field(default_factory=dict)
    _model_u: dict[int, bytes] = field(default_factory=dict)
    _normal_u: dict[int, bytes] = field(default_factory=dict)

    def place(self, ps: PatchSet) -> np.ndarray:
        """The animated patches of ``ps`` in world space at this frame's time ((A, 5, 3) metres), placed once."""
        got = self.animated_world.get(id(ps))
        if got is None:
            got = self.animated_world[id(ps)] = patch_world_slots(ps.patches, ps.animated, self.models)
        return got

    def world_slots(self, ps: PatchSet, ids: np.ndarray) -> np.ndarray:
        """(N, 5, 3) world positions of the slots of patches ``ids`` at this frame's time: the same numbers as
        :func:`~.levels.patch_world_slots` gives (each row is computed on its own either way)."""
        out = ps.still_world[ids]
        row = ps.animated_row[ids]
        moving = row >= 0
        if moving.any():
            out[moving] = self.place(ps)[row[moving]]
        return out

    def model_uniform(self, k: int) -> bytes:
        """Object ``k``'s model matrix as ``u_model`` bytes."""
        got = self._model_u.get(k)
        if got is None:
            got = self._model_u[k] = model_bytes(self.models[k])
        return got

    def normal_uniform(self, k: int) -> bytes:
        """Object ``k``'s normal matrix (inverse transpose of the model's 3x3) as ``u_normal_matrix`` bytes."""
        got = self._normal_u.get(k)
        if got is None:
            got = self._normal_u[k] = np.asarray(np.linalg.inv(self.models[k][:3, :3]).T, "f4").T.tobytes()
        return got


class SasProducer(SceneProducer):
    """The scene-level half of SAS, shared by every session of a server.

    Built once per display size (:class:`PatchSet`): the split meshes and their patches
    (:func:`load_scene_patches`), the geometry's quantisation boxes and quantised
    vertices, the still objects' patches in world space, the patch-id pass's GPU buffers
    and culling clusters (with the still clusters' world-space spheres); once per GL
    context, the atlas-shading program; once per server frame (:meth:`prepare`,
    :class:`SasFrame`), the object transforms, the animated objects' patches in world
    space and the matrices' uniform bytes.  What is left to a session depends on its
    client's pose or its own atlas: the patch-id passes at the client's poses, level
    selection, allocation, shading (view-dependent: specular and texture filtering
    follow the client's eye), metadata and encoding.
    """

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        self._patches: dict[tuple[int, int, float], ScenePatches] = {}
        self._sets: dict[tuple[int, int, float], PatchSet] = {}
        self._ids: dict[tuple[int, int, float], PatchIdPass] = {}
        self._programs: dict[Any, tuple[Any, Any]] = {}
        self._textured: np.ndarray | None = None
        self._frame: SasFrame | None = None
        self.patch_build_ms = 0.0
        self._stats: dict[str, float] = {}

    def patches_for(self, intr: CameraIntrinsics) -> ScenePatches:
        """The scene's patches for a display of ``intr`` (the split edge length depends on it); built once per size."""
        return self.patch_set(intr).patches

    def patch_set(self, intr: CameraIntrinsics) -> PatchSet:
        """The scene-level state of a display of ``intr`` (:class:`PatchSet`); built once per size."""
        key = (intr.width, intr.height, float(intr.fov_y_deg))
        got = self._sets.get(key)
        if got is None:
            t0 = time.perf_counter()
            patches = self._patches[key] = load_scene_patches(self.scene, self.config, intr)  # type: ignore[arg-type]
            got = self._sets[key] = PatchSet.build(self.scene, patches)
            self.patch_build_ms += (time.perf_counter() - t0) * 1e3
        return got

    def textured_objects(self) -> np.ndarray:
        """(n_objects,) bool: which objects' materials have texture detail (:func:`has_texture_detail`), scanned once."""
        if self._textured is None:
            self._textured = np.array([has_texture_detail(o.material) for o in self.scene.objects], bool)
        return self._textured

    def id_pass(self, renderer: Any, patches: ScenePatches) -> PatchIdPass:
        """The patch-id pass of ``patches`` (GPU buffers and clusters), built on first use on the server's GL thread."""
        key = next(k for k, v in self._patches.items() if v is patches)
        if key not in self._ids:
            self._ids[key] = PatchIdPass(renderer, self.scene, patches)
        return self._ids[key]

    def shade_program(self, ctx: Any) -> Any:
        """The atlas-shading program on GL context ``ctx``, compiled once.  Every session sets every uniform it
        reads before each draw (lighting, its view, its atlas size, each object's matrices and material), so
        the sessions share it."""
        got = self._programs.get(id(ctx))
        if got is None or got[0] is not ctx:
            got = self._programs[id(ctx)] = (ctx, load_program(ctx, SHADERS / "atlas_shade.vert", SHADERS / "atlas_shade.frag"))
        return got[1]

    def shade_programs(self, ctx: Any) -> dict[str, Any] | None:
        """The atlas-shading program's two shadow-cache variants on GL context ``ctx`` (``store``: takes the shadow
        maps' taps and writes each texel's factor to attachment 1; ``reuse``: reads it from ``u_shadow_cache``),
        compiled once; None where ``shading.glsl`` has no :data:`SHADOW_FACTOR_SIGNATURE` to rename."""
        key = ("cache", id(ctx))
        got = self._programs.get(key)
        if got is None or got[0] is not ctx:
            vs = read_shader(SHADERS / "atlas_shade.vert")
            fs = read_shader(SHADERS / "atlas_shade.frag")
            progs: dict[str, Any] | None = None
            # shading.glsl's (included before the cache's own, which atlas_shade.frag defines under SHADOW_CACHE)
            if fs.count(SHADOW_FACTOR_SIGNATURE) == 2 and fs.index(SHADOW_FACTOR_SIGNATURE) < fs.index("#ifdef SHADOW_CACHE"):
                fs = fs.replace(SHADOW_FACTOR_SIGNATURE, "float shadow_factor(vec3 world_pos, vec3 n);\n"
                                + SHADOW_FACTOR_SIGNATURE.replace("shadow_factor", "shadow_factor_lookup"), 1)
                head, rest = fs.split("\n", 1)
                progs = {name: ctx.program(vertex_shader=vs, fragment_shader=f"{head}\n#define SHADOW_CACHE {v}\n{rest}")
                         for name, v in (("store", 1), ("reuse", 2))}
            else:
                log.warning("sas: shading.glsl's shadow_factor not found, the shadow cache is off")
            got = self._programs[key] = (ctx, progs)
        return got[1]

    def prepare(self, frame_id: int, t_s: float) -> SasFrame:
        """Server frame ``frame_id`` at scene time ``t_s``, shared by all sessions (:class:`SasFrame`): the object
        transforms and every patch set's animated patches in world space."""
        f = self._frame
        if f is not None and f.frame_id == frame_id and f.t_s == t_s:
            return f
        models = np.stack([o.model_matrix(t_s) for o in self.scene.objects]) if self.scene.objects else np.zeros((0, 4, 4))
        f = self._frame = SasFrame(frame_id, t_s, models)
        for ps in self._sets.values():
            f.place(ps)
        self._stats = {"patch_sets": float(len(self._sets)),
                       "animated_patches": float(sum(ps.animated.size for ps in self._sets.values()))}
        return f

    def stats(self) -> dict[str, float]:
        return dict(self._stats)


class SasServer(ServerHalf):
    """Shading atlas streaming, server half (per session).

    Scene-level state (patches, quantised geometry, the patch-id pass, the shading program, each frame's
    :class:`SasFrame`) comes from the shared :class:`SasProducer`; a session holds its allocator, the patches'
    shading vertices at their blocks, its PVS history, what its client has, its atlas texture and vertex buffer.
    """

    config: SasConfig

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        if not isinstance(self.producer, SasProducer):  # a half used on its own builds its own scene state
            self.producer = SasProducer(self.config, self.scene, self.server_fps)
        self.patch_set = self.producer.patch_set(self.intrinsics)
        self.patches: ScenePatches = self.patch_set.patches
        self.patch_build_ms = self.producer.patch_build_ms
        self.layout = self.config.atlas_layout(self.intrinsics)
        self.allocator = PatchAllocator(self.patches.count, self.layout, self.config.strategy)
        self.transposed = np.zeros(self.patches.count, bool)
        self.client_has = np.zeros(self.patches.count, bool)    # geometry the client holds (no loss assumed)
        self._vcache = np.zeros((self.patches.count, 3, 3, VERTEX_FLOATS), np.float32)   # atlas-shading vertices per patch
        self._vcache_ok = np.zeros(self.patches.count, bool)
        # what the atlas's texels were shaded with (shade_changed_only): per patch whether its block holds last
        # frame's shading and the footprint it took; the frame's uniforms, the probes' state and the object matrices
        self._texels_ok = np.zeros(self.patches.count, bool)
        self._shaded_foot = np.zeros((self.patches.count, 2), np.float32)
        self._shaded_key: tuple[Any, ...] | None = None
        self._shaded_models: np.ndarray | None = None
        # the shadow cache (reuse_shadow): whether a patch's texels' factors are in it, at which side (_flip_code)
        self._shadow_ok = np.zeros(self.patches.count, bool)
        self._shadow_code = np.zeros(self.patches.count, np.int8)
        self._shadow_key = b""
        n = self.patches.count
        self._flip_nx = np.zeros((n, 3, 3, 3))                 # _flip_terms, per patch at its block
        self._flip_n = np.zeros((n, 3, 3, 3))
        self._flip_len = np.zeros((n, 3, 3))
        self._flip_c = np.zeros((n, 3))
        self._flip_r = np.zeros(n)
        self._lrect = np.zeros((self.patches.count, 4))       # _light_rects of still patches at their blocks
        self._lrect_ok = np.zeros(self.patches.count, bool)
        self._lrect_vp: np.ndarray | None = None
        self._vp = np.eye(4)
        self._vp_frame: SasFrame | None = None
        self._reused_count = 0
        # reshade_eye_deg: per patch the server frame its block was last shaded in and the flip code then; per
        # recent frame the eye and the reference view's rotation it was shaded at
        self._shaded_at = np.zeros(self.patches.count, np.int64)
        self._shaded_flip = np.zeros(self.patches.count, np.int8)
        self._eye_hist: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._code = np.zeros(self.patches.count, np.int8)      # this frame's _flip_code per patch, where _code_ok
        self._code_ok = np.zeros(self.patches.count, bool)
        self._kept_count = 0
        # live_refresh_frames: the probes' state of the last frame, a count of its changes, per patch the count its
        # block was shaded under, and how many blocks a frame kept that a later eye, footprint or probes would change
        self._gi_state: Any = None
        self._gi_gen = 0
        self._shaded_gen = np.zeros(self.patches.count, np.int64)
        self._stale_kept_count = 0
        self._last_seen = np.full(self.patches.count, -(1 << 40), np.int64)   # server frame a patch was last in an EVS
        self._frame_t: list[float] = []      # the scene times of the last pvs_linger_frames frames (_linger_frames)
        self.n_obj = len(self.scene.objects)
        self._ids: PatchIdPass | None = None
        self._gl: Any = None
        self._frames = 0
        self._since_i = 0
        self._since_check = 0
        self._lost_seen = 0
        self._stats: dict[str, float] = {}
        self._shaded_count = 0
        self.dynamic = np.array([o.dynamic for o in self.scene.objects], bool)
        self.sent_static = np.zeros(self.n_obj, bool)
        self.obj_box = self.patch_set.obj_box                          # (n_obj, 2, 3) metres, object space
        self.vertex_q = self.patch_set.vertex_q
        # how far the fill may raise each patch's level: texture maps carry detail that more texels resolve,
        # a material without one shades smoothly (lighting, shadows), where they mostly cost bits
        textured = self.producer.textured_objects()
        self.fill_density = np.where(textured, self.config.fill_max_density, self.config.fill_max_density_plain)[self.patches.object_index] \
            if self.n_obj else np.zeros(0)

    # ------------------------------------------------------------------ interface
    def streams(self) -> list[AnyStreamSpec]:
        c = self.config
        if c.lossless:   # bit-exact atlas: HEVC lossless in planar RGB
            v = VideoCodecConfig(codec="hevc", pix_fmt="gbrp", lossless=True, crf=None, gop=c.gop, preset=c.preset, fps=self.server_fps)
        else:
            v = c.video(self.server_fps)
        return [StreamSpec("atlas", v, self.layout.width, self.layout.height)]

    def session_data(self) -> dict[str, Any]:
        return {"v": META_VERSION, "atlas": [self.layout.width, self.layout.height], "n_objects": self.n_obj,
                "n_patches": self.patches.count, "patch_base": self.patches.base.astype(np.int64),
                "sky": list(map(float, self.scene.sky_color)), "obj_box": self.obj_box, "inset": int(self.config.inset_min_texels)}

    def stats(self) -> dict[str, float]:
        return dict(self._stats)

    # ------------------------------------------------------------------ GL
    def _setup_gl(self, renderer: Any) -> None:
        ctx = renderer.ctx
        assert isinstance(self.producer, SasProducer)
        self._ids = self.producer.id_pass(renderer, self.patches)
        self._prog = self.producer.shade_program(ctx)
        self._tex = ctx.texture((self.layout.width, self.layout.height), 4, dtype="f1")
        self._fbo = ctx.framebuffer([self._tex])
        self._fbo.use()
        self._fbo.clear(0.0, 0.0, 0.0, 1.0)
        self._gl = ctx
        self._sg = renderer.upload(self.scene)
        self._vbo: Any = None
        self._vao: Any = None
        self._vao_reuse: Any = None
        # the shadow cache: a float factor per texel in two textures, read from one and written to the other
        self._sc = self.producer.shade_programs(ctx) if self.config.reuse_shadow else None
        if self._sc is not None:
            size = (self.layout.width, self.layout.height)
            self._sc_tex = [ctx.texture(size, 1, dtype="f4") for _ in range(2)]
            for t in self._sc_tex:
                t.filter = (ctx.NEAREST, ctx.NEAREST)
            self._sc_fbo = [ctx.framebuffer([self._tex, t]) for t in self._sc_tex]   # atlas + the cache written
            self._sc_copy = [ctx.framebuffer([t]) for t in self._sc_tex]
            self._sc_write = 0

    # ------------------------------------------------------------------ frame
    def pvs_samples(self, ctx: ServerContext) -> list[PoseSample]:
        """EVS samples of the PVS (:func:`~.pvs.evs_samples`)."""
        return evs_samples(ctx, self.config.pvs_prediction, self.config.pvs_step_ms, self.server_fps,
                           self.config.pvs_max_samples)

    def _linger_frames(self, ctx: ServerContext) -> int:
        """How many frames a patch stays in the PVS after its last EVS: :attr:`SasConfig.pvs_linger_frames`; live (the
        renderer relights the probes at a rate, as :meth:`_live_refresh` tells), the frames of the time that many
        take at ``server_fps`` (8 / 30 s), at least one: a live server making a frame in 0.6 s kept a patch 4.8 s
        after it was last seen, and most blocks it shaded were of such patches (issue 49).  Virtual time makes its
        frames at ``server_fps`` and keeps the count."""
        n = self.config.pvs_linger_frames
        if n == 0 or getattr(ctx.renderer, "gi_hz", 0.0) <= 0:
            return n
        span = n / self.server_fps
        return max(1, sum(1 for t in self._frame_t if ctx.t_s - t <= span * (1 + 1e-9)))

    def frame_state(self, ctx: ServerContext) -> SasFrame:
        """The shared state of ``ctx``'s server frame: the producer's (``ctx.shared``), or prepared here when the
        half runs without one."""
        if isinstance(ctx.shared, SasFrame) and ctx.shared.t_s == ctx.t_s:
            return ctx.shared
        assert isinstance(self.producer, SasProducer)
        return self.producer.prepare(ctx.frame_id, ctx.t_s)

    def produce(self, ctx: ServerContext) -> Update:
        c = self.config
        if self._gl is None:
            self._setup_gl(ctx.renderer)
        assert self._ids is not None
        frame = self.frame_state(ctx)
        t0, u0 = time.perf_counter(), time.process_time()
        big = self.intrinsics.enlarged(1.0 + c.fov_margin, keep_pixel_density=True) if c.fov_margin > 0 else self.intrinsics
        samples = self.pvs_samples(ctx)
        area = self._ids.pvs_area(samples, big)
        self._last_seen[area > 0] = self._frames
        pvs = np.flatnonzero(self._last_seen >= self._frames - self._linger_frames(ctx))
        t1, u1 = time.perf_counter(), time.process_time()
        # level selection at the predicted eye
        models = frame.models
        world = frame.world_slots(self.patch_set, pvs)
        eye = np.asarray(ctx.target_pose.position, np.float64)
        px_per_rad = self.intrinsics.width / math.radians(self.intrinsics.fov_x_deg)
        ext = patch_extent_px(self.patches, pvs, world, eye, px_per_rad)
        A, asp = log_size(ext, c.texels_per_px)
        al = self.allocator
        def levels(current: bool = False) -> LevelChoice:   # eq. 1-3 for the PVS; with the current blocks (hysteresis) or afresh
            return select_levels(A, asp, self.layout, c.bias_fill * self.layout.area,
                                 al.level_w[pvs] if current else None, al.level_h[pvs] if current else None,
                                 self.transposed[pvs] if current else None, c.hysteresis,
                                 fill=c.fill_atlas, fill_max_density=self.fill_density[pvs])

        choice = levels(current=True)
        # I-frame / reset decisions
        # the client reported atlas frames it never got (feedback): resend the whole PVS
        lost = ctx.feedback.newly_lost("atlas")
        full = ctx.keyframe_requested or bool(lost) or self._frames == 0
        self._lost_seen += len(lost)
        # the memory load is checked every reset_period frames (and on a full resend); a reset is an I-frame, so
        # is the GOP's end; else P-frames keep refining an atlas that did not change (a still camera converges)
        check = full or self._since_check >= c.reset_period
        reset = al.can_reset and (self._frames == 0 or (check and al.memory_load() > c.high_water))
        iframe = full or reset or self._since_i >= c.gop
        if reset:
            choice = levels()
        res = al.update(pvs, choice.lw, choice.lh, reset=reset)
        if res.failed.size and al.can_reset and not reset:
            choice = levels()
            res2 = al.update(pvs, choice.lw, choice.lh, reset=True)
            res = type(res)(np.union1d(res.placed, res2.placed), res.released, res2.failed, True)
            reset = iframe = True
        # a block's layout orientation only changes when the patch is (re)placed
        self.transposed[res.placed] = choice.transposed[np.searchsorted(pvs, res.placed)]
        self._vcache_ok[res.placed] = False
        self._texels_ok[res.placed] = False
        self._shadow_ok[res.placed] = False
        self._lrect_ok[res.placed] = False
        t2, u2 = time.perf_counter(), time.process_time()
        live = pvs[al.level_w[pvs] >= 0]
        in_live = np.searchsorted(pvs, live)
        foot = footprint(type(ext)(ext.width[in_live], ext.height[in_live], ext.area[in_live]),
                         al.level_w[live], al.level_h[live], self.transposed[live])
        self._shade(ctx, live, frame, foot, clear=iframe)
        atlas = np.frombuffer(self._fbo.read(components=3, alignment=1), np.uint8).reshape(self.layout.height, self.layout.width, 3).copy()
        t3, u3 = time.perf_counter(), time.process_time()
        meta = self._meta(ctx, pvs, live, res, iframe, reset, full, models)
        self._frame_t = (self._frame_t + [ctx.t_s])[-c.pvs_linger_frames:] if c.pvs_linger_frames else []
        self._since_i = 1 if iframe else self._since_i + 1
        self._since_check = 1 if (check or reset) else self._since_check + 1
        self._frames += 1
        mem = al.memory()
        t4, u4 = time.perf_counter(), time.process_time()
        self._stats = {
            "pvs_patches": float(pvs.size), "evs_samples": float(len(samples)), "pvs_ms": (t1 - t0) * 1e3, "alloc_ms": (t2 - t1) * 1e3,
            "shade_ms": (t3 - t2) * 1e3, "meta_ms": (t4 - t3) * 1e3,
            # process CPU time of the same stages (llvmpipe's rasterising threads included)
            "pvs_cpu_ms": (u1 - u0) * 1e3, "alloc_cpu_ms": (u2 - u1) * 1e3, "shade_cpu_ms": (u3 - u2) * 1e3,
            "meta_cpu_ms": (u4 - u3) * 1e3,
            "atlas_used_pct": 100.0 * mem.allocated / self.layout.area,
            "atlas_load_pct": 100.0 * al.memory_load(), "reset": float(reset), "iframe": float(iframe),
            "failed": float(res.failed.size), "bias": choice.bias, "placed": float(res.placed.size),
            "geo_sent": float(np.asarray(meta.get("geo_id", ())).size),
            "samples": float(((1 << al.level_w[live].astype(np.int64)) * (1 << al.level_h[live].astype(np.int64))).sum()),
            "shaded_patches": float(self._shaded_count), "shadow_reused_patches": float(self._reused_count),
            "eye_kept_patches": float(self._kept_count), "stale_kept_patches": float(self._stale_kept_count),
        }
        return Update(ctx.frame_id, ctx.t_s, ctx.target_pose, {"atlas": atlas}, meta, force_idr=iframe)

    def _shade(self, ctx: ServerContext, live: np.ndarray, frame: SasFrame, foot: np.ndarray, clear: bool) -> None:
        """Shading stage: the live PVS patches into their blocks (one draw per object; the objects' matrices from the
        shared ``frame``); with :attr:`SasConfig.shade_changed_only` on a P-frame only those :meth:`_changed` says
        would come out differently, the others keep last frame's texels (live, with :attr:`SasConfig.live_refresh_frames`,
        also a while over a change of the eye, footprint or probes: :meth:`_live_changed`); with :attr:`SasConfig.reuse_shadow` the
        drawn patches whose shadow factors cannot have changed (:meth:`_shadow_reusable`) read them from the cache."""
        gl = self._gl
        self._fbo.use()
        gl.viewport = (0, 0, self.layout.width, self.layout.height)
        if clear:
            self._fbo.clear(0.0, 0.0, 0.0, 1.0)
        self._shaded_count = self._reused_count = self._kept_count = self._stale_kept_count = 0
        if live.size == 0:
            self._texels_ok[:] = False
            self._shadow_ok[:] = False
            self._shaded_key = None
            return
        P = self.patches
        stale = live[~self._vcache_ok[live]]
        if stale.size:
            self._vcache[stale] = self._shade_vertices(stale)
            self._vcache_ok[stale] = True
            if self._sc is not None or self._eye_tol > 0:
                self._flip_terms(stale)
        prog = self._prog
        ctx.renderer.bind_shading(prog, self.scene, ctx.t_s)
        prog["u_atlas_size"].value = (float(self.layout.width), float(self.layout.height))
        if has_uniform(prog, "u_eye"):
            prog["u_eye"].value = tuple(float(x) for x in ctx.target_pose.position)
        set_reference_view(prog, self.intrinsics, ctx.target_pose)   # textures filtered for its pixel footprint
        foot32 = np.asarray(foot, np.float32)
        tol = self._eye_tol
        key = self._frame_key(ctx, prog, EYE_UNIFORMS if tol > 0 else frozenset())
        refresh = self._live_refresh(ctx)
        if key is not None and key[1] != self._gi_state:
            self._gi_state, self._gi_gen = key[1], self._gi_gen + 1
        old = self._shaded_key
        same = key is not None and old is not None and (key[0] == old[0] if refresh else key == old)
        eye = np.asarray(ctx.target_pose.position, np.float64)
        rot = np.asarray(ctx.target_pose.view_matrix(), np.float64)[:3, :3]
        self._code_ok[:] = False
        prev = self._shaded_models
        moved = np.ones(self.n_obj, bool) if prev is None or prev.shape != frame.models.shape \
            else (frame.models != prev).any(axis=(1, 2))
        if clear or not self.config.shade_changed_only or not same:
            draw = live
        elif refresh:
            draw = live[self._live_changed(live, frame, foot32, moved, eye, rot, refresh)]
        else:
            changed = self._changed(live, frame, foot32, moved)
            if tol > 0:
                cand = np.flatnonzero(~changed)
                changed[cand] = self._eye_moved(live[cand], frame, eye, rot)
            draw = live[changed]
        reuse = np.zeros(draw.size, bool)
        code = np.zeros(draw.size, np.int8)
        if self._sc is not None and draw.size:
            skey = b"".join(prog[k].read() for k in SHADOW_UNIFORMS if has_uniform(prog, k))
            if clear or skey != self._shadow_key:
                self._shadow_ok[:] = False
            self._shadow_key = skey
            code = self._frame_codes(draw, frame, eye)
            reuse = self._shadow_ok[draw] & (code != 0) & (code == self._shadow_code[draw]) \
                & ~moved[P.object_index[draw]]
            if reuse.any():
                cand = np.flatnonzero(reuse)
                reuse[cand] = ~self._near_moved_casters(draw[cand], frame, moved)
        # what the atlas and the cache hold after this frame
        self._texels_ok[:] = False
        self._texels_ok[live] = True
        self._shaded_foot[draw] = foot32[np.searchsorted(live, draw)]   # the others' footprint is as it was shaded
        self._shaded_key = key
        self._shaded_models = frame.models.copy()
        self._shaded_count = int(draw.size)
        self._kept_count = int(live.size - draw.size)
        self._reused_count = int(reuse.sum())
        kept = self._shadow_ok[live].copy()
        self._shadow_ok[:] = False
        self._shadow_ok[live] = kept
        self._shadow_ok[draw] = reuse | (code != 0)
        self._shadow_code[draw] = code
        self._shaded_at[draw] = self._frames
        self._shaded_gen[draw] = self._gi_gen
        if tol > 0:
            self._shaded_flip[draw] = code if self._sc is not None else self._frame_codes(draw, frame, eye)
            self._eye_hist[self._frames] = (eye, rot)
            for f in [f for f in self._eye_hist if f <= self._frames - self.config.reshade_max_age]:
                del self._eye_hist[f]
        if self._sc is not None:
            # the cache written this frame starts as last frame's (blocks not drawn keep their factors)
            w = self._sc_write
            gl.copy_framebuffer(self._sc_copy[w], self._sc_copy[1 - w])
            self._sc_write = 1 - w
            fbo = self._sc_fbo[w]
        else:
            fbo = self._fbo
        fbo.use()   # bind_shading may have rendered the shadow map
        gl.viewport = (0, 0, self.layout.width, self.layout.height)
        gl.disable(gl.DEPTH_TEST)
        gl.disable(gl.CULL_FACE)
        if draw.size == 0:
            return
        order = np.concatenate([np.flatnonzero(~reuse), np.flatnonzero(reuse)])   # each part in object order
        ids = draw[order]
        li, ti = np.nonzero(np.arange(3)[None, :] < P.size[ids][:, None])  # the used (patch, triangle) pairs
        v = self._vcache.reshape(-1, 3, VERTEX_FLOATS)[ids[li] * 3 + ti]  # (n_tri, 3, VERTEX_FLOATS)
        v[..., VERTEX_FLOATS - 2:] = foot32[np.searchsorted(live, ids)[li]][:, None, :]
        o = P.object_index[ids[li]]
        part = reuse[order][li]                                           # (n_tri,) drawn by the reuse program
        data = v.tobytes()
        layout, names = "2f 3f 3f 2f 4f 4f 2f", ("in_atlas", "in_position", "in_normal", "in_uv", "in_tangent", "in_rect", "in_footprint")
        main = prog if self._sc is None else self._sc["store"]
        vbo0 = self._vbo
        self._vbo, self._vao = grow_vertex_buffer(gl, main, self._vbo, self._vao, len(data), layout, names)
        self._vbo.write(data)
        passes = [(main, self._vao, ~part)]
        if self._sc is not None:
            if self._vao_reuse is None or self._vbo is not vbo0:
                if self._vao_reuse is not None:
                    self._vao_reuse.release()
                self._vao_reuse = gl.vertex_array(self._sc["reuse"], [(self._vbo, layout, *names)])
            passes.append((self._sc["reuse"], self._vao_reuse, part))
        for pr, vao, sel in passes:
            idx = np.flatnonzero(sel)
            if idx.size == 0:
                continue
            if pr is not prog:
                self._copy_frame_uniforms(prog, pr)
                if pr is self._sc["reuse"]:   # type: ignore[index]
                    self._sc_tex[1 - self._sc_write].use(location=SHADOW_CACHE_UNIT)
                    pr["u_shadow_cache"].value = SHADOW_CACHE_UNIT
            for s, e in runs(o[idx[0]:idx[-1] + 1]):
                s, e = s + int(idx[0]), e + int(idx[0])
                k = int(o[s])
                og = self._sg.objects[k]
                pr["u_model"].write(frame.model_uniform(k))
                pr["u_normal_matrix"].write(frame.normal_uniform(k))
                ctx.renderer.bind_material(pr, og)
                vao.render(first=3 * s, vertices=3 * (e - s))

    @staticmethod
    def _copy_frame_uniforms(src: Any, dst: Any) -> None:
        """The frame's uniforms (lighting, view, GI, atlas size; not the per-object ones) of ``src`` onto ``dst``,
        a variant of the same shader: ``bind_shading`` set them on ``src`` (and bound the textures they name)."""
        for name in src:
            if name in PER_OBJECT_UNIFORMS or name not in dst:
                continue
            m = src[name]
            if hasattr(m, "array_length") and hasattr(m, "read") and not hasattr(m, "binding"):
                dst[name].write(m.read())

    def _frame_key(self, ctx: ServerContext, prog: Any, skip: frozenset[str] = frozenset()) -> tuple[Any, ...] | None:
        """What every texel's shading reads this frame besides its patch, block, footprint, object and the shadow
        maps: the frame's uniforms (:func:`frame_uniform_key`: lights, eye, reference view, atlas size) and the GI
        probes' state; None when the probes' state cannot be told (a source outside this renderer's volume)."""
        gi: Any = None
        if has_uniform(prog, "u_gi") and prog["u_gi"].value:
            r = ctx.renderer
            if r.gi_sources.get(id(self.scene)) is not None:
                return None
            vol = r.gi_volume(self.scene)
            gi = getattr(vol, "_key", None) if vol is not None else None
            if gi is None:
                return None
            gi = (id(vol), gi)
        return frame_uniform_key(prog, skip), gi

    def _live_refresh(self, ctx: ServerContext) -> int:
        """:attr:`SasConfig.live_refresh_frames` where it applies (``shade_changed_only`` on and the renderer relighting
        the probes at a rate: a live server), else 0 (virtual time: a block is kept only while :meth:`_changed` and
        :meth:`_eye_moved` say its texels would come out as they are)."""
        c = self.config
        return int(c.live_refresh_frames) if c.shade_changed_only and getattr(ctx.renderer, "gi_hz", 0.0) > 0 else 0

    def _live_changed(self, live: np.ndarray, frame: SasFrame, foot: np.ndarray, moved: np.ndarray, eye: np.ndarray,
                      rot: np.ndarray, refresh: int) -> np.ndarray:
        """(len(live),) bool, live (:meth:`_live_refresh` > 0): which live blocks are shaded this frame.  Those whose
        texels would be wrong, not only late: not shaded into their block, of a moved object, near a moved shadow
        caster (:meth:`_changed`'s tests) or, with :attr:`SasConfig.reshade_eye_deg`, whose texels' normals are no
        longer all on the side of the eye they were shaded at (:meth:`_flip_code`).  The others shaded at another
        footprint, eye (:meth:`_eye_moved`'s tolerances) or state of the probes are stale; of those, every one shaded
        ``refresh`` or more frames ago and the longest-kept others up to a ``1 / refresh`` share (rounded up) are
        shaded: each stale block at most ``refresh`` frames after its last shading."""
        P = self.patches
        hard = ~self._texels_ok[live] | moved[P.object_index[live]]
        cand = np.flatnonzero(~hard)
        if cand.size:
            hard[cand] = self._near_moved_casters(live[cand], frame, moved)
        tol = self._eye_tol
        old = self._shaded_foot[live]
        stale = ((np.abs(foot - old) > tol * old) if tol > 0 else (foot != old)).any(axis=1)
        stale |= self._shaded_gen[live] != self._gi_gen
        if tol > 0:
            cand = np.flatnonzero(~hard)
            code = self._frame_codes(live[cand], frame, eye)
            hard[cand] = (code == 0) | (code != self._shaded_flip[live[cand]])
            cand = np.flatnonzero(~hard & ~stale)
            if cand.size:
                stale[cand] = self._eye_moved(live[cand], frame, eye, rot, flip=False)
        stale &= ~hard
        due = refresh_due(stale, self._shaded_at[live], self._frames, refresh)
        self._stale_kept_count = int((stale & ~due).sum())
        return hard | due

    @property
    def _eye_tol(self) -> float:
        """:attr:`SasConfig.reshade_eye_deg` in radians where it applies (``shade_changed_only`` on), else 0."""
        c = self.config
        return math.radians(c.reshade_eye_deg) if c.shade_changed_only else 0.0

    def _eye_moved(self, ids: np.ndarray, frame: SasFrame, eye: np.ndarray, rot: np.ndarray, flip: bool = True) -> np.ndarray:
        """(len(ids),) bool, with :attr:`SasConfig.reshade_eye_deg`: which blocks of patches ``ids`` (each unchanged
        otherwise since it was last shaded) are shaded again for the eye ``eye`` and reference view rotation ``rot``:
        those shaded ``reshade_max_age`` or more frames ago, whose texels' normals are not all on one side of the
        eye as they were (:meth:`_flip_code`), whose reference view turned by the tolerance or more, or where the
        eye moved by at least the tolerance times its distance from the patch (its grown triangles' sphere): within
        it, the eye's direction from every point of the patch turned, and its distance changed relatively, by less
        than the tolerance (radians).  ``flip`` False leaves the side test out (:meth:`_live_changed` makes it)."""
        if ids.size == 0:
            return np.zeros(0, bool)
        tol = self._eye_tol
        at = self._shaded_at[ids]
        out = (self._frames - at >= self.config.reshade_max_age)
        frames_at = np.unique(at[~out])
        if any(int(f) not in self._eye_hist for f in frames_at):
            return np.ones(ids.size, bool)
        old_eye = np.zeros((ids.size, 3))
        for f in frames_at.tolist():
            e0, r0 = self._eye_hist[f]
            sel = at == f
            old_eye[sel] = e0
            cos = (float(np.trace(rot @ r0.T)) - 1.0) / 2.0
            if cos < math.cos(tol):
                out |= sel
        m = frame.models[self.patches.object_index[ids]]
        c = np.einsum("nij,nj->ni", m[:, :3, :3], self._flip_c[ids]) + m[:, :3, 3]
        r = self._flip_r[ids] * np.linalg.norm(m[:, :3, :3], axis=1).max(axis=1)
        dist = np.minimum(np.linalg.norm(eye - c, axis=1), np.linalg.norm(old_eye - c, axis=1)) - r
        out |= ~(np.linalg.norm(eye - old_eye, axis=1) < tol * np.maximum(dist, 0.0))
        cand = np.flatnonzero(~out)
        if cand.size and flip:
            code = self._frame_codes(ids[cand], frame, eye)
            out[cand] = (code == 0) | (code != self._shaded_flip[ids[cand]])
        return out

    def _changed(self, live: np.ndarray, frame: SasFrame, foot: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """(len(live),) bool: which live patches' texels differ from last frame's, the frame's uniforms and probes
        being the same: those not shaded into their block last frame, with another footprint (with
        :attr:`SasConfig.reshade_eye_deg`, one that changed by that tolerance in radians, relatively, since the block
        was shaded), of an object whose matrix changed (``moved``, per object), or near a shadow caster that moved
        (:meth:`_near_moved_casters`)."""
        P = self.patches
        old = self._shaded_foot[live]
        tol = self._eye_tol
        refoot = (np.abs(foot - old) > tol * old) if tol > 0 else (foot != old)
        out = ~self._texels_ok[live] | moved[P.object_index[live]] | refoot.any(axis=1)
        cand = np.flatnonzero(~out)
        if cand.size:
            out[cand] = self._near_moved_casters(live[cand], frame, moved)
        return out

    def _near_moved_casters(self, ids: np.ndarray, frame: SasFrame, moved: np.ndarray) -> np.ndarray:
        """(len(ids),) bool: whether patches ``ids``' shadow lookups (their texels, which lie in the grown shading
        triangles, moved along the normal; the PCF taps) reach the sun's shadow map where a dynamic caster that
        moved since last frame (``moved``, per object) was or is (its box, grown by :data:`SHADOW_REACH_TEXELS`)."""
        casters = np.flatnonzero(moved & self.dynamic)
        sun = self.scene.sun
        prev = self._shaded_models
        if casters.size == 0 or sun is None or ids.size == 0:
            return np.zeros(ids.size, bool)
        if prev is None or prev.shape != frame.models.shape:
            return np.ones(ids.size, bool)
        vp = self._sun_vp(frame)
        reach = SHADOW_REACH_TEXELS * 2.0 / sun.shadow_map_size
        boxes = caster_rects(vp, self.obj_box[casters, 0], self.obj_box[casters, 1],
                             (prev[casters], frame.models[casters]), reach)
        return rects_overlap(self._light_rects(ids, frame, vp), boxes)

    def _sun_vp(self, frame: SasFrame) -> np.ndarray:
        """The sun's world -> light-clip matrix (``light_view_projection``, which walks the scene's bounds), once a
        frame."""
        if self._vp_frame is not frame:
            self._vp, self._vp_frame = light_view_projection(self.scene), frame
        return self._vp

    def _light_rects(self, ids: np.ndarray, frame: SasFrame, vp: np.ndarray) -> np.ndarray:
        """(len(ids), 4) the sun-map rectangles patches ``ids``' shadow lookups fall in: their grown shading
        triangles placed at ``frame``, grown by the lookup's normal offset.  A still object's are kept while the
        patch's block (its shading vertices) stays put and the sun's projection ``vp`` is the same."""
        P = self.patches
        if self._lrect_vp is None or not np.array_equal(self._lrect_vp, vp):
            self._lrect_ok[:] = False
            self._lrect_vp = vp.copy()
        out = np.empty((ids.size, 4))
        ok = self._lrect_ok[ids]
        out[ok] = self._lrect[ids[ok]]
        todo = ids[~ok]
        if todo.size:
            pos = self._vcache[:, :, :, 2:5][todo].astype(np.float64)      # (n, 3 tris, 3 verts, 3)
            unused = np.arange(3)[None, :] >= P.size[todo][:, None]
            pos = np.where(unused[:, :, None, None], pos[:, :1, :1], pos).reshape(todo.size, 9, 3)
            m = frame.models[P.object_index[todo]]
            world = pos @ m[:, :3, :3].transpose(0, 2, 1) + m[:, None, :3, 3]
            scale = float(np.linalg.norm(vp[:2, :3], axis=1).max())        # clip units per metre (orthographic)
            r = light_rects(vp, world, SHADOW_NORMAL_OFFSET_M * scale)
            out[~ok] = r
            still = ~self.dynamic[P.object_index[todo]] & (self.patch_set.animated_row[todo] < 0)
            self._lrect[todo[still]] = r[still]
            self._lrect_ok[todo[still]] = True
        return out

    def _flip_terms(self, ids: np.ndarray) -> None:
        """Keep what :meth:`_flip_code` needs of patches ``ids``' shading vertices (object space, fixed while the
        block stays put): n_i . x_j per grown triangle, the normals, their lengths, a centre and radius."""
        v = self._vcache[ids][..., 2:8].astype(np.float64)                # (n, 3 tris, 3 verts, position + normal)
        x, n = v[..., :3], v[..., 3:]
        self._flip_nx[ids] = n @ x.transpose(0, 1, 3, 2)                  # (n, t, i, j) n_i . x_j
        self._flip_n[ids] = n
        self._flip_len[ids] = np.sqrt((n * n).sum(-1))
        used = (np.arange(3)[None, :] < self.patches.size[ids][:, None])[:, :, None]
        pts = np.where(used[..., None], x, x[:, :1, :1])                   # unused triangles: the first vertex
        c = pts.reshape(ids.size, 9, 3).mean(axis=1)
        self._flip_c[ids] = c
        self._flip_r[ids] = np.sqrt(((pts.reshape(ids.size, 9, 3) - c[:, None]) ** 2).sum(-1)).max(axis=1)

    def _frame_codes(self, ids: np.ndarray, frame: SasFrame, eye: np.ndarray) -> np.ndarray:
        """:meth:`_flip_code` of patches ``ids`` at this frame's eye, each patch's taken once a frame (the eye test
        and the shadow cache ask for overlapping sets; each row is computed on its own, so the same numbers)."""
        todo = ids[~self._code_ok[ids]]
        if todo.size:
            self._code[todo] = self._flip_code(todo, frame, eye)
            self._code_ok[todo] = True
        return self._code[ids]

    def _flip_code(self, ids: np.ndarray, frame: SasFrame, eye: Any) -> np.ndarray:
        """(len(ids),) int8 per patch: 1 when every texel's normal faces the eye (the shader keeps it), -1 when every
        one faces away (the shader flips it), 0 when that cannot be told.  A texel's n . (eye - x), n and x
        interpolated with weights b in a grown triangle, is sum_ij b_i b_j n_i . (eye - x_j): of one sign where
        every term is, each by :data:`FLIP_MARGIN` of |n_i| |eye - x_j| (the shader's float rounding) and by
        :data:`FLIP_SPREAD` of the largest (a fragment's weights may dip a little below 0 at the triangle's edge).
        The terms are the same in object space (the normal matrix is the model's inverse transpose), where the eye
        is placed per object.  The shadow lookup moves along that normal, so a cached factor holds only while the
        side is the same."""
        P = self.patches
        if ids.size == 0:
            return np.zeros(0, np.int8)
        models = frame.models
        eye_obj = np.einsum("kij,kj->ki", np.linalg.inv(models[:, :3, :3]), np.asarray(eye, np.float64) - models[:, :3, 3])
        e = eye_obj[P.object_index[ids]]                                  # (n, 3)
        ne = (self._flip_n[ids] @ e[:, None, :, None])[..., 0]            # (n, t, i) n_i . eye
        dots = ne[..., :, None] - self._flip_nx[ids]                      # (n, t, i, j) n_i . (eye - x_j)
        reach = np.sqrt(((e - self._flip_c[ids]) ** 2).sum(-1)) + self._flip_r[ids]    # >= |eye - x_j|
        bound = np.maximum(FLIP_MARGIN * self._flip_len[ids][..., None] * reach[:, None, None, None],
                           FLIP_SPREAD * np.abs(dots).max(axis=(2, 3), keepdims=True))
        unused = np.arange(3)[None, :] >= P.size[ids][:, None]
        front = ((dots > bound).all(axis=(2, 3)) | unused).all(axis=1)
        back = ((dots < -bound).all(axis=(2, 3)) | unused).all(axis=1)
        return np.where(front, 1, np.where(back, -1, 0)).astype(np.int8)

    def _shade_vertices(self, ids: np.ndarray) -> np.ndarray:
        """(N, 3, 3, VERTEX_FLOATS) float32 atlas-shading vertices of patches ``ids`` at their blocks (unused triangles zero).

        Per vertex: atlas xy (texels), object-space position, normal, uv, tangent (xyz,
        handedness), block rect, footprint (filled per frame).  Depends only on the patch and its block, so it is
        computed when a patch is (re)placed and reused while the block stays put.
        """
        P = self.patches
        out = np.zeros((ids.size, 3, 3, VERTEX_FLOATS), np.float32)
        rect = self.allocator.blocks(ids).astype(np.float64)
        size = P.size[ids]
        for k in (1, 2, 3):
            sel = np.flatnonzero(size == k)
            if sel.size == 0:
                continue
            sid = ids[sel]
            inset = self.config.inset_min_texels
            xy = block_layout_xy(np.broadcast_to(SLOT_LAYOUT[k], (sel.size, 5, 2)), rect[sel], self.transposed[sid], inset)
            ins = block_inset(rect[sel], inset) > 0                    # (n, 2) inset along atlas x, y
            # every slot's atlas xy, position, normal, uv and tangent, extrapolated at once per triangle below
            attr = np.concatenate([xy, P.slot_pos[sid], P.slot_nrm[sid], P.slot_uv[sid], P.slot_tan[sid]], axis=2,
                                  dtype=np.float64)                    # (n, 5, 14)
            for t, tri in enumerate(TRI_SLOTS[k]):
                if tri[0] < 0:
                    continue
                p2 = xy[:, tri]                                        # (n, 3, 2)
                # edges inside the block grow by EXPAND_TEXELS, those shared with another triangle of the patch by
                # only SHARED_GROW_TEXELS (the neighbour shades its side; grown by EXPAND_TEXELS the later triangle's
                # extrapolation overwrote the earlier one's texels near the diagonal, 1.65 fragments per texel); those on a side stay (texels beyond it are another block's), or on an inset side
                # grow past the border texels' centres
                axes = boundary_axes(SLOT_LAYOUT[k][tri])              # layout axis per edge, -1 inside
                d = np.full((sel.size, 3), EXPAND_TEXELS)
                if not self.config.grow_block_sides:
                    d[:, TRI_SHARED[k][t]] = SHARED_GROW_TEXELS
                    for e in np.flatnonzero(axes >= 0).tolist():
                        atlas_axis = np.where(self.transposed[sid], 1 - axes[e], axes[e])
                        d[:, e] = np.where(ins[np.arange(sel.size), atlas_axis], INSET_GROW_TEXELS, 0.0)
                w = expand_triangles(p2, d)   # (n, 3, 3)
                a = attr[:, tri]                                       # (n, 3 corners, 14)
                v = np.einsum("nkj,njc->nkc", w, a)
                v[..., 13] = a[:, None, 0, 13]                         # handedness is not interpolated
                out[sel, t, :, :14] = v
                out[sel, t, :, 14:VERTEX_FLOATS - 2] = rect[sel][:, None, :]
        return out

    def _meta(self, ctx: ServerContext, pvs: np.ndarray, live: np.ndarray, res: Any, iframe: bool, reset: bool,
              full: bool, models: np.ndarray) -> dict[str, Any]:
        P = self.patches
        if full:
            self.client_has[:] = False
            self.sent_static[:] = False
        # the client keeps geometry only for PVS patches
        gone = np.flatnonzero(self.client_has)
        gone = gone[~np.isin(gone, live)]   # left the PVS, or lost its block
        self.client_has[gone] = False
        geo = live[~self.client_has[live]]
        self.client_has[geo] = True
        uv_all = live if (reset or full) else np.intersect1d(res.placed, live)
        uv_only = np.setdiff1d(uv_all, geo)                 # the new patches' rects come first, without ids
        uv_ids = np.concatenate([geo, uv_only])
        rect = self.allocator.blocks(uv_ids)
        lw = self.allocator.level_w[uv_ids]
        lh = self.allocator.level_h[uv_ids]
        uv_rect = np.stack([rect[:, 0], rect[:, 1], lw, lh, self.transposed[uv_ids]], axis=1).astype(np.uint16)
        objs_needed = np.unique(P.object_index[live])
        send = objs_needed[self.dynamic[objs_needed] | ~self.sent_static[objs_needed]]
        self.sent_static[send] = True
        meta: dict[str, Any] = {
            "v": META_VERSION,
            "iframe": bool(iframe), "reset": bool(reset), "full": bool(full),
            "drop": encode_ids(gone),
            **encode_geometry(geo, P.size[geo], P.slot_vertex[geo], self.vertex_q),
            "uv_id": encode_ids(uv_only), "uv_rect": uv_rect,
            "xf_obj": send.astype(np.uint16), "xf": models[send].astype(np.float32),
        }
        if reset or full:
            meta["pvs"] = encode_ids(live)
        # absent = empty / false on the wire: a frame with nothing new costs a few bytes
        return {k: v for k, v in meta.items()
                if not ((isinstance(v, np.ndarray) and v.size == 0) or v is False)}
