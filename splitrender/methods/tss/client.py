"""The TSS client half: caches triangle geometry, draws the live triangles at its own pose.

State: per triangle ever sent its object and object-space corners (``geo``; bounded by
the scene's triangle count), the live triangles' descriptors as the reliable ``tris``
stream builds them (full tables on I-frames, deltas between), and the pair drawn: the
newest atlas with the table of its frame and the object transforms at that frame's
time.  When the atlas of a frame is missing, the previous pair stays on screen; the
table state and the geometry still advance (both streams are reliable and cumulative).

Per fragment (``shaders/client.frag``): object-space barycentrics from the rasteriser,
the inverse perspective encoding (paper eq. 5) with the triangle's vertex depths at the
frame's reference pose (computed here from the frame's pose and transforms), then the
L-packing or oversampling layout and one bilinear tap.  Pixels no triangle covers
are holes (sky colour).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...render.canvas import Canvas, upload_image
from ...render.gl import grow_vertex_buffer, load_program, set_uniform
from ...scene.pose import Pose
from ..base import ClientFrame, ClientHalf, DecodedUpdate
from ..sas.client import ObjectTransforms
from .layout import KIND_OS, layout_attributes
from .wire import TssWireError, Table, decode_geometry, decode_table, parse_session, parse_transforms

SHADERS = Path(__file__).parent / "shaders"
VERTEX_FLOATS = 3 + 1 + 3 + 4 + 4 + 4


class TssClient(ClientHalf):
    """Tessellated shading streaming, client half."""

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        self.session = parse_session(self.session_data)
        s = self.session
        if s.n_triangles > self.limits.max_scene_triangles:   # before the per-triangle arrays below
            raise TssWireError(f"tss session data: n_triangles: {s.n_triangles} triangles, over this client's limit "
                               f"max_scene_triangles {self.limits.max_scene_triangles}")
        i = self.intrinsics
        self.canvas = Canvas(self.gl, i.width, i.height)
        self.prog = load_program(self.gl, SHADERS / "client.vert", SHADERS / "client.frag")
        n = s.n_triangles
        self.has = np.zeros(n, bool)
        self.obj = np.zeros(n, np.int64)
        self.pos = np.zeros((n, 3, 3), np.float32)
        self.xf = ObjectTransforms(self.gl, s.n_objects)
        self.table: Table | None = None              # what is drawn: the table of the newest atlas
        self.live = np.zeros(n, bool)                 # the table state the tris stream built
        self.st = Table(np.zeros(0, np.int64), np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros((n, 3, 2), np.int64),
                        np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros(n), np.ones(n, bool),
                        np.zeros(n, np.int64))
        self._tex: Any = None
        self._vbo: Any = None
        self._vao: Any = None
        self._n = 0

    def apply(self, update: DecodedUpdate) -> None:
        """Apply one frame; malformed data raises :class:`TssWireError` and leaves the drawn state as it was.

        Geometry is checked and taken first (it is cumulative, and later tables name it),
        then the table and atlas; a bad table does not cost the geometry that came with it.
        """
        s = self.session
        xf = parse_transforms(update.meta, s.n_objects)
        geo = update.data.get("geo")
        if geo is not None:
            g = decode_geometry(geo, s.n_triangles, s.tri_base, s.box)
            self.has[g.ids] = True
            self.obj[g.ids] = g.obj
            self.pos[g.ids] = g.pos
        tris = update.data.get("tris")
        atlas = update.planes.get("atlas")
        W, H = s.atlas
        if atlas is not None and (not isinstance(atlas, np.ndarray) or atlas.dtype != np.uint8 or atlas.shape != (H, W, 3)):
            raise TssWireError(f"tss atlas plane: shape {getattr(atlas, 'shape', None)}, expected ({H}, {W}, 3) uint8")
        if tris is not None:
            rows, gone = decode_table(tris, s.n_triangles, s.atlas, s.strip, s.os_grid, s.block)
            if gone is not None and rows.single_px != self.st.single_px:
                raise TssWireError(f"tss tris: a delta table changes the single-texel cell side from {self.st.single_px} "
                                   f"to {rows.single_px}")
            if gone is not None and gone.size and not self.live[gone].all():
                raise TssWireError(f"tss tris: {int((~self.live[gone]).sum())} triangles leave that were not live")
            if rows.ids.size and not self.has[rows.ids].all():
                raise TssWireError(f"tss tris: {int((~self.has[rows.ids]).sum())} live triangles have no geometry")
            if gone is None:
                self.live[:] = False
            else:
                self.live[gone] = False
            self.live[rows.ids] = True
            st, i = self.st, rows.ids
            st.kind[i], st.level[i], st.origin[i], st.w[i], st.w2[i] = rows.kind, rows.level, rows.origin, rows.w, rows.w2
            st.h[i], st.a[i], st.persp[i], st.base[i] = rows.h, rows.a, rows.persp, rows.base
            st.single_px = rows.single_px
        if atlas is None or (tris is None and self.table is None):
            return   # no frame before the first table (a frame without one keeps the table the stream built)
        st = self.st
        i = np.flatnonzero(self.live)
        table = Table(i, st.kind[i], st.level[i], st.origin[i], st.w[i], st.w2[i], st.h[i], st.a[i], st.persp[i], st.base[i],
                      st.single_px)
        self.xf.update(slice(None), xf, update.t_s)
        self._tex = upload_image(self.gl, atlas, self._tex)
        self.table = table
        self._upload(table, update.pose, xf)
        self.has_content = True

    def _upload(self, t: Table, pose: Pose, xf: np.ndarray) -> None:
        """The vertex buffer of table ``t``: per vertex its object-space position, object, reference depths, layout."""
        n = t.ids.size
        rot = np.where(t.kind == KIND_OS, t.base, 0)
        order = (rot[:, None] + np.arange(3)) % 3
        pos = np.take_along_axis(self.pos[t.ids], order[:, :, None], axis=1).astype(np.float64)
        obj = self.obj[t.ids]
        m = xf[obj].astype(np.float64)
        view = np.asarray(pose.view_matrix(), np.float64)
        world = np.einsum("nij,nkj->nki", m[:, :3, :3], pos) + m[:, None, :3, 3]
        z = -(world @ view[2, :3] + view[2, 3])                                # (n, 3) depths at the reference view
        o0, o1 = layout_attributes(t.kind, t.origin, t.w, t.w2, t.h, t.a, np.zeros(n))
        info = np.stack([t.kind, t.level, t.persp.astype(np.float64), np.zeros(n)], 1)
        flat = np.concatenate([obj[:, None].astype(np.float64), z, info, o0, o1], 1)[:, None, :].repeat(3, axis=1)
        data = np.concatenate([pos, flat], axis=2).astype(np.float32).tobytes()
        self._vbo, self._vao = grow_vertex_buffer(self.gl, self.prog, self._vbo, self._vao, len(data), "3f 1f 3f 4f 4f 4f",
                                                  ("in_position", "in_object", "in_zref", "in_info", "in_o0", "in_o1"), 4096)
        if data:
            self._vbo.write(data)
        self._n = n

    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        i = self.intrinsics
        self.canvas.use()
        self.canvas.clear((*self.session.sky, 0.0))
        if self._vao is not None and self._tex is not None and self._n:
            gl = self.gl
            gl.enable(gl.DEPTH_TEST)
            gl.disable(gl.CULL_FACE)
            self.xf.bind(t_s)
            self.prog["u_view"].write(np.asarray(pose.view_matrix(), "f4").T.tobytes())
            self.prog["u_proj"].write(np.asarray(i.projection(), "f4").T.tobytes())
            self._tex.use(location=0)
            self.prog["u_atlas"].value = 0
            self.prog["u_atlas_size"].value = tuple(float(x) for x in self.session.atlas)
            set_uniform(self.prog, "u_os_centred", int(self.session.os_grid == "centred"))
            set_uniform(self.prog, "u_lp_inset", float(self.config.lp_inset))
            set_uniform(self.prog, "u_lp_cubic", int(self.config.lp_filter == "cubic"))
            set_uniform(self.prog, "u_single_px", self.table.single_px if self.table is not None else 1)
            self._vao.render(vertices=3 * self._n)
        color, covered = self.canvas.read()
        return ClientFrame(color, ~covered, {"cli_triangles": float(self._n)})
