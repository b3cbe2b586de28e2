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

from ...render.gl import load_program
from ...scene.model import Scene
from ...scene.pose import CameraIntrinsics, Pose
from .patches import ScenePatches

SHADERS = Path(__file__).parent / "shaders"
PoseSample = tuple[float, Pose]
"""One EVS sample: scene time (seconds; places animated objects) and camera pose."""


class PatchIdPass:
    """Renders depth-tested patch-ID buffers of ``scene`` and turns them into EVS areas."""

    def __init__(self, renderer: Any, scene: Scene, patches: ScenePatches) -> None:
        self.renderer = renderer
        self.ctx = renderer.ctx
        self.scene = scene
        self.patches = patches
        self.prog = load_program(self.ctx, SHADERS / "patch_id.vert", SHADERS / "patch_id.frag")
        meshes = patches.meshes or [o.mesh for o in scene.objects]
        # the patches' own (possibly split) meshes, scene-wide triangle order
        self.objects: list[tuple[Any, Any, int]] = []
        base = 0
        for o, m in zip(scene.objects, meshes):
            vbo = self.ctx.buffer(np.ascontiguousarray(m.positions, "f4").tobytes())
            ibo = self.ctx.buffer(np.ascontiguousarray(m.indices, "u4").tobytes())
            self.objects.append((o, self.ctx.vertex_array(self.prog, [(vbo, "3f", "in_position")], ibo), base))
            base += m.triangle_count
        self._fbos: dict[tuple[int, int], tuple[Any, Any]] = {}
        # scene-wide triangle index + 1 -> patch id + 1 (0 stays background)
        self.lookup = np.concatenate([[0], patches.tri_to_patch.astype(np.int64) + 1])

    def _fbo(self, w: int, h: int) -> tuple[Any, Any]:
        f = self._fbos.get((w, h))
        if f is None:
            tex = self.ctx.texture((w, h), 1, dtype="u4")
            fbo = self.ctx.framebuffer([tex], self.ctx.depth_renderbuffer((w, h)))
            f = self._fbos[(w, h)] = (fbo, tex)
        return f

    def id_buffer(self, pose: Pose, intr: CameraIntrinsics, t_s: float) -> np.ndarray:
        """(H, W) int64 patch id + 1 per pixel (0 = background), row 0 at the top."""
        fbo, tex = self._fbo(intr.width, intr.height)
        fbo.use()
        self.ctx.viewport = (0, 0, intr.width, intr.height)
        fbo.clear(depth=1.0)
        tex.write(np.zeros((intr.height, intr.width), np.uint32).tobytes())
        self.ctx.enable(self.ctx.DEPTH_TEST)
        self.ctx.disable(self.ctx.CULL_FACE)
        self.prog["u_view"].write(np.asarray(pose.view_matrix(), "f4").T.tobytes())
        self.prog["u_proj"].write(np.asarray(intr.projection(), "f4").T.tobytes())
        for obj, vao, base in self.objects:
            self.prog["u_model"].write(np.asarray(obj.model_matrix(t_s), "f4").T.tobytes())
            self.prog["u_tri_base"].value = base
            vao.render()
        ids = np.frombuffer(tex.read(), np.uint32).reshape(intr.height, intr.width)[::-1]
        return self.lookup[ids]

    def evs_area(self, pose: Pose, intr: CameraIntrinsics, t_s: float) -> np.ndarray:
        """(P,) pixels covered by each patch at ``pose`` (the EVS with projected areas)."""
        return np.bincount(self.id_buffer(pose, intr, t_s).ravel(), minlength=self.patches.count + 1)[1:]

    def pvs_area(self, samples: Sequence[PoseSample], intr: CameraIntrinsics) -> np.ndarray:
        """(P,) per patch the largest EVS area over ``samples`` (``(t_s, pose)``); > 0 means in the PVS."""
        acc = np.zeros(self.patches.count, np.int64)
        for t_s, p in samples:
            np.maximum(acc, self.evs_area(p, intr, t_s), out=acc)
        return acc


def sample_times(t_from_s: float, t_to_s: float, step_s: float) -> list[float]:
    """EVS sample times from ``t_from_s`` to ``t_to_s`` (both included) in steps of ``step_s``."""
    if t_to_s <= t_from_s or step_s <= 0:
        return [t_from_s]
    n = int(np.ceil((t_to_s - t_from_s) / step_s - 1e-9))
    ts = [t_from_s + k * step_s for k in range(n)]
    return ts + [t_to_s]


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
