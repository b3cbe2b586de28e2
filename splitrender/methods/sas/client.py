"""The SAS client half: keeps PVS geometry and atlas coordinates, draws at its own pose.

State grows with the PVS only: per patch its object slot, triangle count and
object-space slot positions (sent once when it enters the PVS), its block rectangle
(sent when it moves in the atlas) and per object its newest transform.  Patches that
leave the PVS (``drop``, or absent from an I-frame's ``pvs`` list) are forgotten.

Rendering is one draw call: a vertex buffer with a slot of three triangles per PVS
patch (atlas coordinates and the block's texel-centre clamp rectangle baked in; only
the slots of patches that changed are recomputed, freed slots are zeroed and reused) and the object transforms in a storage buffer, extrapolated
from the two newest updates to the display time (:func:`extrapolate_transforms`).
Pixels no patch covers are holes (filled with the sky colour,
which the session data carries, as the server's clear colour).

The client imports only the wire format (:mod:`.wire`) from the server's side; every
frame is validated there before any state changes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...render.canvas import Canvas, upload_image
from ...render.gl import grow_vertex_buffer, load_program
from ...scene.pose import Pose
from ..base import ClientFrame, ClientHalf, DecodedUpdate
from .slots import PatchSlots
from .wire import SasMetaError, parse_frame_meta, parse_session

SHADERS = Path(__file__).parent / "shaders"


MAX_EXTRAPOLATION_S = 0.25
"""Longest time (s) an object transform is extrapolated past its newest update."""


def extrapolate_transforms(prev: np.ndarray, prev_t: np.ndarray, cur: np.ndarray, cur_t: np.ndarray, t_s: float) -> np.ndarray:
    """(N, 4, 4) object transforms at scene time ``t_s`` from the two newest updates (constant velocity).

    Translation moves linearly; the linear part turns by the rotation between the two
    samples, scaled in angle (Rodrigues).  Objects with one sample, samples at the same
    time, or a linear part that is not a rotation times the previous one keep ``cur``;
    extrapolation stops :data:`MAX_EXTRAPOLATION_S` past the newest sample.  Never raises:
    an object whose previous sample is not invertible or whose extrapolated transform is not
    finite in float32 keeps ``cur`` (the wire checks every sample, so neither happens with
    a well-behaved server; a display frame must not fail on it either way).
    """
    out = cur.astype(np.float64).copy()
    dt = cur_t - prev_t
    ok = np.isfinite(dt) & (dt > 1e-6)
    if ok.any():
        a0_all = prev[:, :3, :3].astype(np.float64)
        with np.errstate(all="ignore"):
            det = np.linalg.det(a0_all) if a0_all.size else np.zeros(0)
        ok &= np.isfinite(det) & (np.abs(det) > 1e-12) & np.isfinite(prev).all(axis=(1, 2)) & np.isfinite(cur).all(axis=(1, 2))
    if not ok.any():
        return out.astype(np.float32)
    k = np.flatnonzero(ok)
    with np.errstate(all="ignore"):      # non-finite results are replaced below
        alpha = np.clip(t_s - cur_t[k], 0.0, MAX_EXTRAPOLATION_S) / dt[k]              # (K,) in units of dt
        a0, a1 = prev[k, :3, :3].astype(np.float64), cur[k, :3, :3].astype(np.float64)
        d = a1 @ np.linalg.inv(a0)                                                     # rotation from prev to cur
        orthonormal = np.abs(d @ d.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2)) < 1e-3
        cos = np.clip((np.trace(d, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        ang = np.arccos(cos)
        axis = np.stack([d[:, 2, 1] - d[:, 1, 2], d[:, 0, 2] - d[:, 2, 0], d[:, 1, 0] - d[:, 0, 1]], 1)
        axis /= np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-12)
        th = (ang * alpha)[:, None, None]
        kx = np.zeros((k.size, 3, 3))
        kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
        kx[:, 1, 0], kx[:, 2, 0], kx[:, 2, 1] = axis[:, 2], -axis[:, 1], axis[:, 0]
        rot = np.eye(3) + np.sin(th) * kx + (1.0 - np.cos(th)) * (kx @ kx)
        rot = np.where(((ang > 1e-9) & orthonormal)[:, None, None], rot, np.eye(3))
        out[k, :3, :3] = rot @ a1
        t0, t1 = prev[k, :3, 3].astype(np.float64), cur[k, :3, 3].astype(np.float64)
        out[k, :3, 3] = t1 + (t1 - t0) * alpha[:, None]
        shown = out.astype(np.float32)
    bad = ~np.isfinite(shown).all(axis=(1, 2))
    if bad.any():                        # e.g. 3e38 m moving at 6e38 m per update: show the newest sample
        shown[bad] = cur[bad]
    return shown


class ObjectTransforms:
    """Each object's two newest transforms and their scene times, and the storage buffer the display stage reads.

    :meth:`update` takes new samples (the current one becomes the previous one when the
    time differs); :meth:`bind` writes the transforms extrapolated to the display time
    (:func:`extrapolate_transforms`) into the buffer and binds it to ``binding``.
    """

    def __init__(self, gl: Any, n_objects: int) -> None:
        self.models = np.tile(np.eye(4, dtype=np.float32), (n_objects, 1, 1))
        self.models_prev = self.models.copy()
        self.models_t = np.full(n_objects, np.nan)
        self.models_prev_t = np.full(n_objects, np.nan)
        self.ssbo = gl.buffer(reserve=max(1, n_objects) * 64)

    def update(self, objects: np.ndarray | slice, xf: np.ndarray, t_s: float) -> None:
        """New transforms ``xf`` of ``objects`` (indices, or a slice for all) sampled at scene time ``t_s``."""
        idx = np.arange(self.models.shape[0])[objects]
        fresh = idx[self.models_t[idx] != t_s]        # a newer sample: the current one becomes previous
        self.models_prev[fresh] = self.models[fresh]
        self.models_prev_t[fresh] = self.models_t[fresh]
        self.models[idx] = xf
        self.models_t[idx] = t_s

    def bind(self, t_s: float, binding: int = 0) -> None:
        shown = extrapolate_transforms(self.models_prev, self.models_prev_t, self.models, self.models_t, t_s)
        self.ssbo.write(np.ascontiguousarray(shown.transpose(0, 2, 1), np.float32).tobytes())
        self.ssbo.bind_to_storage_buffer(binding)


class SasClient(ClientHalf):
    """Shading atlas streaming, client half."""

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        self.session = parse_session(self.session_data)
        self.atlas_size = self.session.atlas_size
        self.n_obj = self.session.n_objects
        self.sky = self.session.sky
        self.obj_box = self.session.obj_box
        i = self.intrinsics
        self.canvas = Canvas(self.gl, i.width, i.height)
        self.prog = load_program(self.gl, SHADERS / "client.vert", SHADERS / "client.frag")
        self.xf = ObjectTransforms(self.gl, self.n_obj)   # the two newest transforms per object, for extrapolation
        self.slots = PatchSlots(self.session)               # per-patch state and the vertex slots, keyed by patch id
        self._tex: Any = None
        self._vao: Any = None
        self._vbo: Any = None
        self._dirty = True

    @property
    def geo(self) -> dict[int, tuple[int, int, np.ndarray]]:
        return self.slots.geo

    @property
    def rect(self) -> dict[int, np.ndarray]:
        return self.slots.rect

    # ------------------------------------------------------------------ updates
    def apply(self, update: DecodedUpdate) -> None:
        """Apply one frame; malformed metadata raises :class:`SasMetaError` and leaves the state as it was."""
        m = parse_frame_meta(update.meta, self.session)
        atlas = update.planes.get("atlas")
        if atlas is not None:
            w, h = self.atlas_size
            if not isinstance(atlas, np.ndarray) or atlas.dtype != np.uint8 or atlas.shape != (h, w, 3):
                raise SasMetaError(f"sas atlas plane: shape {getattr(atlas, 'shape', None)}, expected ({h}, {w}, 3) uint8")
            self._tex = upload_image(self.gl, atlas, self._tex)
        self.slots.apply(m)
        self.xf.update(m.xf_obj.astype(np.int64), m.xf, update.t_s)
        self._dirty = True
        self.has_content = True

    def _rebuild(self) -> None:
        """Update the slots of the patches that changed since the last draw, then upload once."""
        self.slots.rebuild()
        data = self.slots.rows[:self.slots.high].tobytes()
        self._vbo, self._vao = grow_vertex_buffer(self.gl, self.prog, self._vbo, self._vao, len(data), "3f 2f 1f 4f",
                                                  ("in_position", "in_atlas_uv", "in_object", "in_clamp"), 4096)
        if data:
            self._vbo.write(data)
        self._dirty = False

    # ------------------------------------------------------------------ display
    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        i = self.intrinsics
        if self._dirty:
            self._rebuild()
        self.canvas.use()
        self.canvas.clear((*self.sky, 0.0))
        if self._vao is not None and self._tex is not None:
            gl = self.gl
            gl.enable(gl.DEPTH_TEST)
            gl.disable(gl.CULL_FACE)
            self.xf.bind(t_s)
            self.prog["u_view"].write(np.asarray(pose.view_matrix(), "f4").T.tobytes())
            self.prog["u_proj"].write(np.asarray(i.projection(), "f4").T.tobytes())
            self._tex.use(location=0)
            self.prog["u_atlas"].value = 0
            # SasConfig.atlas_filter (read by name: the client imports nothing but the wire format from its package)
            self.prog["u_bicubic"].value = int(getattr(self.config, "atlas_filter", "bicubic") == "bicubic")
            if self.slots.high:
                self._vao.render(vertices=9 * self.slots.high)
        color, covered = self.canvas.read()
        return ClientFrame(color, ~covered, {"cli_triangles": float(self.slots.n_tri)})
