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
from .wire import (SLOT_LAYOUT, TRI_SLOTS, FrameMeta, SasMetaError, block_clamp_rect, block_layout_xy, dequantize_slots,
                   parse_frame_meta, parse_session)

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


class PatchSlots:
    """The SAS client's state without GL: PVS patches (object slot, triangle count, object-space positions),
    their atlas rectangles, and one vertex slot of three triangles per drawn patch.

    :meth:`apply` takes a frame's validated metadata; :meth:`rebuild` recomputes the slots of the patches that
    changed (freed slots are zeroed and reused) and returns their indices.  :attr:`rows` ``[:high]`` is the
    vertex data: per slot (3 triangles, 3 vertices, 10 floats) object-space position, normalised atlas uv,
    object slot and the block's normalised texel-centre clamp rectangle; unused triangles are zero.  The
    browser front door keeps one for a page (:mod:`splitrender.webrtc.sas`) and sends it the changed slots.
    """

    def __init__(self, session: Any) -> None:
        self.session = session
        self.atlas_size = session.atlas_size
        self.geo: dict[int, tuple[int, int, np.ndarray]] = {}      # id -> (object slot, triangles, (5, 3) positions)
        self.rect: dict[int, np.ndarray] = {}                      # id -> (x, y, lw, lh, transposed)
        self._changed: set[int] = set()
        self._slot: dict[int, int] = {}
        self._free: list[int] = []
        self.rows = np.zeros((0, 3, 3, 10), np.float32)
        self._slot_tris = np.zeros(0, np.int64)
        self.high = 0
        self.n_tri = 0

    @property
    def dirty(self) -> bool:
        return bool(self._changed)

    def apply(self, m: FrameMeta) -> None:
        if m.full:
            self._changed.update(self.geo)
            self._changed.update(self.rect)
            self.geo.clear()
            self.rect.clear()
        self._changed.update(m.drop.tolist())
        self._changed.update(m.geo_id.tolist())
        self._changed.update(m.uv_id.tolist())
        for pid in m.drop.tolist():
            self.geo.pop(pid, None)
            self.rect.pop(pid, None)
        gpos = dequantize_slots(m.geo_pos, m.geo_size, self.session.obj_box[m.geo_obj])
        for pid, o, s, p in zip(m.geo_id.tolist(), m.geo_obj.tolist(), m.geo_size.tolist(), gpos):
            self.geo[pid] = (o, s, p)
        for pid, r in zip(m.uv_id.tolist(), m.uv_rect):
            self.rect[pid] = r
        if m.pvs is not None:
            keep = set(m.pvs.tolist())
            for d in (self.geo, self.rect):
                for pid in [k for k in d if k not in keep]:
                    del d[pid]
                    self._changed.add(pid)

    def _patch_rows(self, ids: list[int]) -> np.ndarray:
        """(N, 3, 3, 10) float32 vertex rows of patches ``ids`` (unused triangles zero): object-space
        position, normalised atlas uv, object slot, the block's normalised texel-centre clamp rectangle."""
        out = np.zeros((len(ids), 3, 3, 10), np.float32)
        obj = np.array([self.geo[p][0] for p in ids], np.float32)
        size = np.array([self.geo[p][1] for p in ids], np.int64)
        pos = np.stack([self.geo[p][2] for p in ids]).astype(np.float32)
        rr = np.stack([self.rect[p] for p in ids]).astype(np.int64)
        rect = np.stack([rr[:, 0], rr[:, 1], 1 << rr[:, 2], 1 << rr[:, 3]], axis=1).astype(np.float64)
        wh = np.array(self.atlas_size, np.float64)
        for k in (1, 2, 3):
            sel = np.flatnonzero(size == k)
            if sel.size == 0:
                continue
            xy = block_layout_xy(np.broadcast_to(SLOT_LAYOUT[k], (sel.size, 5, 2)), rect[sel], rr[sel, 4] != 0,
                                 self.session.inset) / wh
            o = np.broadcast_to(obj[sel][:, None, None], (sel.size, 3, 1))
            clamp = block_clamp_rect(rect[sel]) / np.tile(wh, 2)
            c4 = np.broadcast_to(clamp[:, None, :], (sel.size, 3, 4))
            for t, tri in enumerate(TRI_SLOTS[k]):
                if tri[0] < 0:
                    continue
                out[sel, t] = np.concatenate([pos[sel][:, tri], xy[:, tri], o, c4], axis=2)
        return out

    def rebuild(self) -> np.ndarray:
        """Recompute the slots of the patches that changed since the last call; returns the slot indices
        written (patches drawn anew or moved, and slots freed), ascending."""
        written: set[int] = set()
        drawn = [p for p in self._changed if p in self.geo and p in self.rect]
        for pid in self._changed:
            if pid in self._slot and not (pid in self.geo and pid in self.rect):
                k = self._slot.pop(pid)
                self.rows[k] = 0.0
                self._slot_tris[k] = 0
                self._free.append(k)
                written.add(k)
        for pid in drawn:
            if pid not in self._slot:
                if not self._free:
                    grow = max(64, self.rows.shape[0])
                    self._free = list(range(self.rows.shape[0] + grow - 1, self.rows.shape[0] - 1, -1))
                    self.rows = np.concatenate([self.rows, np.zeros((grow, 3, 3, 10), np.float32)])
                    self._slot_tris = np.concatenate([self._slot_tris, np.zeros(grow, np.int64)])
                self._slot[pid] = self._free.pop()
        if drawn:
            slots = np.array([self._slot[p] for p in drawn], np.int64)
            self.rows[slots] = self._patch_rows(drawn)
            self._slot_tris[slots] = [self.geo[p][1] for p in drawn]
            written.update(slots.tolist())
        self._changed.clear()
        self.high = max(self._slot.values()) + 1 if self._slot else 0
        self.n_tri = int(self._slot_tris[:self.high].sum())
        return np.array(sorted(written), np.int64)


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
