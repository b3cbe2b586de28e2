"""Potentially visible set (paper sections 3.1 and 5.1).

An *exact visible set* (EVS) is the set of patches with at least one pixel in a
depth-tested patch-ID buffer rendered at one pose and time; its per-patch pixel counts
are the patches' projected areas.  The PVS is the union of EVS samples at the current
pose and at poses predicted along the expected latency, each with an enlarged field of
view (the ID buffer grows around the original view, keeping its pixel density).  A
sample is a ``(t_s, pose)`` pair: animated objects are placed at the sample's own time
(the paper: "the motion of animated objects corresponding to the predicted time for
which an EVS is created"), so an object moving into view is in the PVS before it
arrives.

:func:`pvs_rates` computes the section 5.1 measures: with ``v`` the area of patches
visible at the *true* sample poses (regular field of view, area-weighted by their
projected pixels), ``fn`` the area of those the PVS missed and ``fp`` the area (in the
PVS's own ID buffers) of PVS patches never truly visible, coverage ``rc = 1 - fn / v``
and overestimation ``ro = fp / v``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ...render.gl import load_program, read_shader
from ...scene.model import Scene
from ...scene.pose import CameraIntrinsics, Pose
from .patches import ScenePatches

SHADERS = Path(__file__).parent / "shaders"
PoseSample = tuple[float, Pose]
"""One EVS sample: scene time (seconds; places animated objects) and camera pose."""


CLUSTER_TRIANGLES = 256
"""Triangles per culling cluster (consecutive in patch order, so spatially coherent)."""
PLACEMENT_TIMES = 16
"""Scene times whose object placement a patch-id pass keeps (:meth:`PatchIdPass.placement`): a frame's EVS samples
(3-4 at the default step) and the next frame's."""


@dataclass
class PatchClusters:
    """Scene-level culling data, built once at load (depends only on the scene's patches).

    Per object: its triangles sorted by patch (``indices`` (T, 3) uint32), the patch of
    each sorted triangle, and clusters of :data:`CLUSTER_TRIANGLES` consecutive sorted
    triangles with object-space bounding spheres (``centers`` (C, 3), ``radii`` (C,)
    metres); ``tri_base`` is the object's first scene-wide sorted triangle.
    """

    indices: list[np.ndarray]
    tri_patch: np.ndarray          # (T_scene,) global patch of each sorted triangle
    tri_base: np.ndarray           # (n_objects,)
    centers: list[np.ndarray]
    radii: list[np.ndarray]
    sphere: np.ndarray             # (n_objects, 4) object-space sphere of the whole mesh: centre, radius

    @staticmethod
    def build(scene: Scene, patches: ScenePatches) -> "PatchClusters":
        meshes = patches.meshes or [o.mesh for o in scene.objects]
        indices, tri_patch, tri_base, centers, radii, sphere = [], [], [], [], [], []
        base = tbase = 0
        for k, m in enumerate(meshes):
            t = m.triangle_count
            local = patches.tri_to_patch[tbase:tbase + t]
            order = np.argsort(local, kind="stable")
            idx = np.ascontiguousarray(m.indices[order], np.uint32)
            indices.append(idx)
            tri_patch.append(local[order])
            tri_base.append(base)
            p = m.positions[idx.astype(np.int64)]                                   # (T, 3, 3)
            n_cl = max(1, -(-t // CLUSTER_TRIANGLES))
            lo = np.full((n_cl, 3), np.inf)
            hi = np.full((n_cl, 3), -np.inf)
            if t:
                cl = np.arange(t) // CLUSTER_TRIANGLES
                np.minimum.at(lo, cl, p.min(axis=1))
                np.maximum.at(hi, cl, p.max(axis=1))
            c = np.where(np.isfinite(lo), (lo + hi) / 2, 0.0)
            r = np.where(np.isfinite(lo).all(1), np.linalg.norm(hi - lo, axis=1) / 2, 0.0)
            centers.append(c)
            radii.append(r)
            if t:
                mlo, mhi = m.positions.min(axis=0), m.positions.max(axis=0)
                sphere.append([*((mlo + mhi) / 2), float(np.linalg.norm(mhi - mlo) / 2)])
            else:
                sphere.append([0.0, 0.0, 0.0, -1.0])
            base += t
            tbase += t
        return PatchClusters(indices, np.concatenate(tri_patch) if tri_patch else np.zeros(0, np.int32),
                             np.array(tri_base, np.int64), centers, radii, np.array(sphere, np.float64).reshape(-1, 4))


def frustum_planes(view_proj: np.ndarray) -> np.ndarray:
    """(6, 4) normalised planes ``n.x + d >= 0`` inside, of the clip matrix ``view_proj`` (world -> clip)."""
    m = view_proj
    pl = np.stack([m[3] + m[0], m[3] - m[0], m[3] + m[1], m[3] - m[1], m[3] + m[2], m[3] - m[2]])
    return pl / np.linalg.norm(pl[:, :3], axis=1, keepdims=True)


def world_spheres(models: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-space centres (N, 3) and radii (N,) of one object-space sphere per model (N, 4, 4); a negative
    radius (an object with no triangles) stays negative."""
    c = np.einsum("nij,nj->ni", models[:, :3, :3], centers) + models[:, :3, 3]
    return c, radii * np.linalg.norm(models[:, :3, :3], axis=1).max(axis=1)


def in_frustum(planes: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Which world-space spheres (centres (N, 3), radii (N,)) intersect the frustum ``planes``.

    Element by element, not a matrix product: a sphere's answer does not depend on the
    spheres tested with it (BLAS rounds a product differently for different row counts),
    so one test over every object's clusters answers what a test per object does."""
    d = (centers[:, 0, None] * planes[:, 0] + centers[:, 1, None] * planes[:, 1]
         + centers[:, 2, None] * planes[:, 2] + planes[:, 3])
    return (d >= -radii[:, None]).all(axis=1)


def placed_spheres(model: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-space centres (N, 3) and radii (N,) of object-space spheres placed by ``model`` (4, 4)."""
    return centers @ model[:3, :3].T + model[:3, 3], radii * float(np.linalg.norm(model[:3, :3], axis=0).max())


def spheres_visible(planes: np.ndarray, model: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Which object-space spheres, placed by ``model`` (4, 4), intersect the frustum ``planes``."""
    return in_frustum(planes, *placed_spheres(model, centers, radii))


def model_bytes(model: np.ndarray) -> bytes:
    """``model`` (4, 4) as a GLSL ``mat4`` uniform's bytes (float32, column-major)."""
    return np.asarray(model, "f4").T.tobytes()


class PatchIdPass:
    """Renders depth-tested patch-ID buffers of ``scene`` and turns them into EVS areas.

    Only objects and clusters of :class:`PatchClusters` that intersect the sample's
    frustum are drawn: one frustum test per sample over every cluster of the objects in
    view, whose world-space spheres (and model-matrix bytes) are placed once for the
    still objects and at the sample's time for the animated ones.  A pass depends only
    on the scene and its patches, so one pass (one set of GPU buffers) serves every
    session of a server (``sas``'s and ``tss``'s scene producers hold it).
    :meth:`pvs_area` counts pixels per patch on the GPU (a compute pass with atomic
    counters, then a max over the samples) and reads back one count per patch;
    :meth:`evs_area` reads the ID buffer back and counts on the CPU (the reference
    path, also used by :func:`pvs_rates`).
    """

    def __init__(self, renderer: Any, scene: Scene, patches: ScenePatches, clusters: PatchClusters | None = None,
                 gpu_count: bool = True) -> None:
        self.renderer = renderer
        self.ctx = renderer.ctx
        self.scene = scene
        self.patches = patches
        self.clusters = clusters or PatchClusters.build(scene, patches)
        self.prog = load_program(self.ctx, SHADERS / "patch_id.vert", SHADERS / "patch_id.frag")
        meshes = patches.meshes or [o.mesh for o in scene.objects]
        self.objects: list[tuple[Any, Any]] = []
        for o, m, idx in zip(scene.objects, meshes, self.clusters.indices):
            vbo = self.ctx.buffer(np.ascontiguousarray(m.positions, "f4").tobytes())
            ibo = self.ctx.buffer(idx.tobytes() if idx.size else b"\0" * 12)
            self.objects.append((o, self.ctx.vertex_array(self.prog, [(vbo, "3f", "in_position")], ibo)))
        self._fbos: dict[tuple[int, int], tuple[Any, Any]] = {}
        # whole-object spheres in world space, tested against a frustum all at once (a scene of a hundred
        # objects paid more for a numpy call per object than for drawing nothing): the still objects' once,
        # the animated ones' at each sample's time
        sph = self.clusters.sphere
        self._has_tris = np.array([idx.shape[0] > 0 for idx in self.clusters.indices], bool)
        self._animated = np.array([o.animation is not None for o in scene.objects], bool)
        models = np.stack([np.asarray(o.model_matrix(0.0), np.float64) for o in scene.objects]) if scene.objects \
            else np.zeros((0, 4, 4))
        self._world_c, self._world_r = world_spheres(models, sph[:, :3], sph[:, 3])
        # every object's clusters one after another: the still objects' placed in the world once
        cl = self.clusters
        n_cl = np.array([c.shape[0] for c in cl.centers], np.int64)
        self._cl_first = np.concatenate([[0], np.cumsum(n_cl)])          # (n_objects + 1,) first cluster
        self._cl_obj = np.repeat(np.arange(len(n_cl)), n_cl)            # (C,) object of each cluster
        self._cl_c = np.zeros((int(self._cl_first[-1]), 3))
        self._cl_r = np.zeros(int(self._cl_first[-1]))
        self._model_bytes: list[bytes | None] = [None] * len(n_cl)
        for k in np.flatnonzero(~self._animated).tolist():
            a, b = self._cl_first[k], self._cl_first[k + 1]
            self._cl_c[a:b], self._cl_r[a:b] = placed_spheres(models[k], cl.centers[k], cl.radii[k])
            self._model_bytes[k] = model_bytes(models[k])
        # scene-wide sorted triangle index + 1 -> patch id + 1 (0 stays background)
        self.lookup = np.concatenate([[0], self.clusters.tri_patch.astype(np.int64) + 1])
        self.drawn_triangles = 0
        self._placed: dict[float, tuple[np.ndarray, np.ndarray, dict[int, tuple[np.ndarray, np.ndarray, bytes]]]] = {}
        self.gpu_count = gpu_count
        self._count: Any = None
        if gpu_count:
            try:
                self._count = self.ctx.compute_shader(read_shader(SHADERS / "patch_count.comp"))
                self._count_max = self.ctx.compute_shader(read_shader(SHADERS / "patch_count_max.comp"))
                n = max(1, patches.count)
                self._lookup_buf = self.ctx.buffer(self.lookup.astype(np.uint32).tobytes())
                self._counts = self.ctx.buffer(reserve=4 * n)
                self._acc = self.ctx.buffer(reserve=4 * n)
                self._counts.clear()
            except Exception:   # no compute shaders: count on the CPU
                self._count = None
                self.gpu_count = False

    def _fbo(self, w: int, h: int) -> tuple[Any, Any]:
        f = self._fbos.get((w, h))
        if f is None:
            tex = self.ctx.texture((w, h), 1, dtype="u4")
            fbo = self.ctx.framebuffer([tex], self.ctx.depth_renderbuffer((w, h)))
            f = self._fbos[(w, h)] = (fbo, tex)
        return f

    def placement(self, t_s: float) -> tuple[np.ndarray, np.ndarray, dict[int, tuple[np.ndarray, np.ndarray, bytes]]]:
        """Every object's world-space sphere (centres (n_obj, 3), radii) and per animated object its clusters'
        world-space spheres and model-matrix bytes, at scene time ``t_s``: what a patch-id pass needs of the scene
        besides the pose.  Kept for the newest :data:`PLACEMENT_TIMES` times, so the sessions of a server, whose EVS
        samples fall at the same times (each frame's window starts at its newest pose's time and steps
        ``pvs_step_ms``), and the next frame's overlapping window place the animated objects once per time.  The
        same numbers as placing them at each pass (each object on its own)."""
        got = self._placed.get(t_s)
        if got is not None:
            return got
        cl = self.clusters
        wc, wr = self._world_c, self._world_r
        anim = np.flatnonzero(self._animated)
        models = {int(k): np.asarray(self.scene.objects[k].model_matrix(t_s), np.float64) for k in anim}
        placed: dict[int, tuple[np.ndarray, np.ndarray, bytes]] = {}
        if anim.size:
            wc, wr = wc.copy(), wr.copy()
            wc[anim], wr[anim] = world_spheres(np.stack([models[int(k)] for k in anim]), cl.sphere[anim, :3],
                                               cl.sphere[anim, 3])
            for k, m in models.items():
                placed[k] = (*placed_spheres(m, cl.centers[k], cl.radii[k]), model_bytes(m))
        got = self._placed[t_s] = (wc, wr, placed)
        while len(self._placed) > PLACEMENT_TIMES:
            del self._placed[next(iter(self._placed))]
        return got

    def render_ids(self, pose: Pose, intr: CameraIntrinsics, t_s: float) -> Any:
        """Draw the ID buffer (frustum-culled per object and cluster); returns its texture."""
        fbo, tex = self._fbo(intr.width, intr.height)
        fbo.use()
        self.ctx.viewport = (0, 0, intr.width, intr.height)
        # one GL clear of the ids (an unsigned-integer attachment: moderngl clears it with glClearBufferuiv) and the
        # depth; the ids were cleared by uploading a buffer of zeros each pass
        fbo.clear(color=(0, 0, 0, 0), depth=1.0)
        self.ctx.enable(self.ctx.DEPTH_TEST)
        self.ctx.disable(self.ctx.CULL_FACE)
        view, proj = pose.view_matrix(), intr.projection()
        planes = frustum_planes(proj @ view)
        self.prog["u_view"].write(np.asarray(view, "f4").T.tobytes())
        self.prog["u_proj"].write(np.asarray(proj, "f4").T.tobytes())
        cl = self.clusters
        drawn = 0
        wc, wr, placed = self.placement(t_s)
        objs = np.flatnonzero(self._has_tris & in_frustum(planes, wc, wr))
        if objs.size == 0:
            self.drawn_triangles = 0
            return tex
        # the clusters of the objects in view, the animated ones placed at t_s, tested at once
        first, last = self._cl_first[objs], self._cl_first[objs + 1]
        n = last - first
        sel = np.repeat(first - np.concatenate([[0], np.cumsum(n)[:-1]]), n) + np.arange(int(n.sum()))
        cc, cr = self._cl_c[sel], self._cl_r[sel]
        moving = [k for k in objs.tolist() if k in placed]
        model_b = self._model_bytes
        if moving:
            model_b = list(model_b)
            at = np.concatenate([[0], np.cumsum(n)])
            pos = {k: i for i, k in enumerate(objs.tolist())}
            for k in moving:
                a, b = at[pos[k]], at[pos[k] + 1]
                cc[a:b], cr[a:b], model_b[k] = placed[k]
        vis = sel[in_frustum(planes, cc, cr)]          # visible clusters, ascending: objects, then clusters in order
        if vis.size == 0:
            self.drawn_triangles = 0
            return tex
        # runs of consecutive visible clusters of one object -> triangle ranges, drawn in object order
        obj = self._cl_obj[vis]
        brk = np.flatnonzero((np.diff(vis) != 1) | (np.diff(obj) != 0)) + 1
        starts = vis[np.concatenate([[0], brk])]
        ends = vis[np.concatenate([brk - 1, [vis.size - 1]])] + 1
        current = -1
        for a, b, k in zip(starts.tolist(), ends.tolist(), obj[np.concatenate([[0], brk])].tolist()):
            if k != current:
                current = k
                vao = self.objects[k][1]
                n_tri = cl.indices[k].shape[0]
                base = int(self._cl_first[k])
                self.prog["u_model"].write(model_b[k])
            t0, t1 = (a - base) * CLUSTER_TRIANGLES, min((b - base) * CLUSTER_TRIANGLES, n_tri)
            self.prog["u_tri_base"].value = int(cl.tri_base[k]) + t0
            vao.render(first=3 * t0, vertices=3 * (t1 - t0))
            drawn += t1 - t0
        self.drawn_triangles = drawn
        return tex

    def id_buffer(self, pose: Pose, intr: CameraIntrinsics, t_s: float) -> np.ndarray:
        """(H, W) int64 patch id + 1 per pixel (0 = background), row 0 at the top."""
        tex = self.render_ids(pose, intr, t_s)
        ids = np.frombuffer(tex.read(), np.uint32).reshape(intr.height, intr.width)[::-1]
        return self.lookup[ids]

    def evs_area(self, pose: Pose, intr: CameraIntrinsics, t_s: float) -> np.ndarray:
        """(P,) pixels covered by each patch at ``pose`` (the EVS with projected areas), counted on the CPU."""
        return np.bincount(self.id_buffer(pose, intr, t_s).ravel(), minlength=self.patches.count + 1)[1:]

    def pvs_area(self, samples: Sequence[PoseSample], intr: CameraIntrinsics, gpu: bool | None = None) -> np.ndarray:
        """(P,) per patch the largest EVS area over ``samples`` (``(t_s, pose)``); > 0 means in the PVS.

        ``gpu`` (default: the pass's ``gpu_count``) counts with the compute passes.
        """
        if not (self.gpu_count if gpu is None else gpu) or self._count is None:
            acc = np.zeros(self.patches.count, np.int64)
            for t_s, p in samples:
                np.maximum(acc, self.evs_area(p, intr, t_s), out=acc)
            return acc
        n = self.patches.count
        any_drawn = False
        self._lookup_buf.bind_to_storage_buffer(1)
        self._counts.bind_to_storage_buffer(2)
        self._acc.bind_to_storage_buffer(3)
        self._count["u_size"].value = (intr.width, intr.height)
        self._count_max["u_n"].value = n
        for t_s, p in samples:
            tex = self.render_ids(p, intr, t_s)
            if self.drawn_triangles == 0:
                continue          # nothing in the frustum: no pixel to count
            if not any_drawn:
                self._acc.clear()
                self._counts.clear()
                any_drawn = True
            tex.bind_to_image(0, read=True, write=False)
            self._lookup_buf.bind_to_storage_buffer(1)
            self._counts.bind_to_storage_buffer(2)
            self._acc.bind_to_storage_buffer(3)
            self._count.run(-(-intr.width // 16), -(-intr.height // 16))
            self.ctx.memory_barrier()
            self._count_max.run(-(-max(n, 1) // 256))
            self.ctx.memory_barrier()
        if not any_drawn:
            return np.zeros(n, np.int64)
        return np.frombuffer(self._acc.read(size=4 * n), np.uint32).astype(np.int64)


SAMPLE_MERGE_STEPS = 0.05
"""A sample closer than this fraction of a step to the window's end is left out (the last step grows to at most
1.05 steps): the end sample shows the same pose.  The default step (33.3 ms) over a 30 fps frame's window put a
sample 0.03 ms before the end, a third of the frame's ID passes for no patch."""


def sample_times(t_from_s: float, t_to_s: float, step_s: float, max_samples: int = 0) -> list[float]:
    """EVS sample times from ``t_from_s`` to ``t_to_s`` (both included) in steps of ``step_s`` (one closer to the
    end than :data:`SAMPLE_MERGE_STEPS` of a step left out).  ``max_samples`` (>= 2; 0: no limit): a window that
    would take more is sampled at that many evenly spaced times instead, its ends included (the steps grow)."""
    if t_to_s <= t_from_s or step_s <= 0:
        return [t_from_s]
    n = max(1, int(np.ceil((t_to_s - t_from_s) / step_s - SAMPLE_MERGE_STEPS)))
    if max_samples >= 2 and n + 1 > max_samples:
        return [t_from_s + (t_to_s - t_from_s) * k / (max_samples - 1) for k in range(max_samples - 1)] + [t_to_s]
    ts = [t_from_s + k * step_s for k in range(n)]
    return ts + [t_to_s]


def evs_samples(ctx: Any, prediction: str, step_ms: float, server_fps: int, max_samples: int = 0) -> list[PoseSample]:
    """EVS samples ``(t_s, pose)`` of a server frame (``ctx``: a ``ServerContext``): the newest pose, then
    predictions in ``step_ms`` steps to one frame past the target (at most ``max_samples`` of them in all:
    :func:`sample_times`).  Animated objects are placed at each sample's time; with ``prediction = "none"`` the
    one sample shows the newest pose at the frame's time."""
    if prediction == "none":
        return [(ctx.t_s, ctx.latest_pose)]
    t_end = max(ctx.target_t_s, ctx.latest_pose_t_s) + 1.0 / server_fps
    ts = sample_times(ctx.latest_pose_t_s, t_end, step_ms / 1e3, max_samples)
    return [(ts[0], ctx.latest_pose)] + [(t, ctx.predict(t)) for t in ts[1:]]


@dataclass
class PvsRates:
    """Section 5.1 rates, area-weighted (fractions, 0..1)."""

    coverage: float
    overestimation: float
    visible_px: float


def pvs_rates(ids: PatchIdPass, pvs_samples: Sequence[PoseSample], true_samples: Sequence[PoseSample],
              intr: CameraIntrinsics, fov_factor: float) -> PvsRates:
    """Coverage and overestimation of the PVS from ``pvs_samples`` against the EVS union of ``true_samples``.

    Both are ``(t_s, pose)`` pairs; objects are placed at each sample's time.
    """
    big = intr.enlarged(fov_factor, keep_pixel_density=True) if fov_factor > 1.0 else intr
    pvs = ids.pvs_area(pvs_samples, big)
    truth = np.zeros_like(pvs)
    for t_s, p in true_samples:
        truth += ids.evs_area(p, intr, t_s)
    v = float(truth.sum())
    if v == 0:
        return PvsRates(1.0, 0.0, 0.0)
    fn = float(truth[pvs == 0].sum())
    fp = float(pvs[(truth == 0) & (pvs > 0)].sum())
    return PvsRates(1.0 - fn / v, fp / v, v)


PosePredictor = Callable[[float], Pose]
