"""``warp``, client half: warps the newest reference views to the display pose (sees only what arrived)."""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np

from ...render.canvas import FullscreenPass, upload_image
from ...render.gl import load_program, set_uniform
from ...scene.pose import CameraIntrinsics, Pose, quat_from_matrix3, quat_slerp, quat_to_matrix3
from ..base import ClientFrame, ClientHalf, DecodedUpdate
from .config import SHADERS, WarpConfig, reference_intrinsics
from .wire import ReferenceFrame, ReferenceView, WarpMetaError, parse_update

log = logging.getLogger(__name__)


def extrapolate_model(prev: np.ndarray, cur: np.ndarray, u: float) -> np.ndarray:
    """Model matrix ``u`` steps past ``cur`` (``u`` in units of the prev->cur interval):
    slerp on the rotation, linear on the translation, scale kept from ``cur``."""
    sp = np.linalg.norm(prev[:3, :3], axis=0)
    sc = np.linalg.norm(cur[:3, :3], axis=0)
    qp = quat_from_matrix3(prev[:3, :3] / sp)
    qc = quat_from_matrix3(cur[:3, :3] / sc)
    out = np.eye(4)
    out[:3, :3] = quat_to_matrix3(quat_slerp(qp, qc, 1.0 + u)) * sc
    out[:3, 3] = cur[:3, 3] + u * (cur[:3, 3] - prev[:3, 3])
    return out


def warp_matrices(frame: ReferenceFrame, view: ReferenceView, ref: CameraIntrinsics, pose: Pose, intr: CameraIntrinsics,
                  t_s: float, extrapolate: bool, max_extrapolation_s: float, n_ids: int) -> np.ndarray:
    """(n_ids, 5, 4) float32 texture rows: the columns of each object's warp matrix
    ``P_cur V_cur O_i(t) O_i(ref)^-1 V_ref^-1`` and a (dynamic, 0, 0, 0) flag texel."""
    base = intr.projection() @ pose.view_matrix()
    ref_inv = view.pose.matrix()
    out = np.zeros((n_ids, 5, 4), np.float32)
    static = base @ ref_inv
    out[:, :4, :] = static.T.astype(np.float32)
    h = float(np.clip(t_s - frame.t_s, 0.0, max_extrapolation_s))
    for i, cur in frame.model.items():
        if i >= n_ids:
            continue
        prev = frame.prev.get(i)
        now = cur
        # a peer's huge or degenerate matrices overflow quietly here; the finite check below falls back
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            if prev is not None:  # a dynamic object: cut mesh triangles at its border, extrapolate its motion
                out[i, 4, 0] = 1.0
                if extrapolate:
                    now = extrapolate_model(prev, cur, h / frame.dt_s)
            m = base @ now @ np.linalg.inv(cur) @ ref_inv
        if not np.all(np.isfinite(m)) or np.abs(m).max() > F32_SAFE:
            m = static  # a near-singular transform from the wire: draw the object where the reference view has it
        out[i, :4, :] = m.T.astype(np.float32)
    return out


F32_SAFE = 1e30
"""Largest warp-matrix entry drawn as computed; beyond it float32 would overflow."""


def fill_holes(fill: FullscreenPass, out_fbo: Any, warped: Any, wdepth: Any, intr: CameraIntrinsics, pose: Pose,
               eye: np.ndarray, max_scan_px: int, enabled: bool) -> tuple[np.ndarray, np.ndarray]:
    """Run ``warp_holefill.frag`` over ``warped`` (RGBA8, alpha = coverage) and ``wdepth`` (view depth)
    into ``out_fbo``, scanning along the epipolar direction of the reference camera at ``eye``
    seen from ``pose``; returns (colour (H, W, 3) uint8, hole mask before filling (H, W) bool)."""
    ctx = out_fbo.ctx
    ctx.disable(ctx.DEPTH_TEST)
    out_fbo.use()
    ctx.viewport = (0, 0, intr.width, intr.height)
    e = intr.projection() @ pose.view_matrix() @ np.append(eye, 1.0)
    ep = ((e[0] + e[3]) * 0.5 * intr.width, (e[1] + e[3]) * 0.5 * intr.height, e[3])
    fp = fill.prog
    warped.use(0)
    wdepth.use(1)
    for name, value in (("u_warped", 0), ("u_wdepth", 1), ("u_out_size", (float(intr.width), float(intr.height))),
                        ("u_epipole", tuple(float(x) for x in ep)), ("u_max_scan", int(max_scan_px)),
                        ("u_fill", 1 if enabled else 0)):
        set_uniform(fp, name, value)
    fill.run()
    rgba = np.frombuffer(out_fbo.read(components=4), np.uint8).reshape(intr.height, intr.width, 4)[::-1]
    return np.ascontiguousarray(rgba[..., :3]), rgba[..., 3] == 0


# ----------------------------------------------------------------------------- client: GL
def mesh_grid_indices(width: int, height: int) -> np.ndarray:
    """Triangle indices (flat uint32) of the mesh reconstruction's grid for a ``width`` x ``height``
    reference image: ``(width + 2) x (height + 2)`` vertices, row-major from the top, whose inner
    ``width x height`` are the pixel centres and whose outer ring lies on the image border
    (``warp_mesh.vert``), so the mesh spans the whole image."""
    gw, gh = width + 2, height + 2
    idx = np.arange(gw * gh, dtype=np.uint32).reshape(gh, gw)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    return np.stack([a, c, b, b, c, d], axis=-1).reshape(-1).astype(np.uint32)


class _ViewGPU:
    """Textures of one reference view."""

    def __init__(self) -> None:
        self.color: Any = None
        self.depth: Any = None
        self.ids: Any = None
        self.mats: Any = None


class WarpClient(ClientHalf):
    """Warps the newest reference frame to the display pose, in shaders."""

    config: WarpConfig

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        import moderngl

        self._mgl = moderngl
        cfg = self.config
        i = self.intrinsics
        self.ref_intr = reference_intrinsics(i, cfg.fov_scale, cfg.resolution_scale)
        ctx = self.gl
        w, h = i.width, i.height
        self._warped = ctx.texture((w, h), 4, dtype="f1")
        self._wdepth = ctx.texture((w, h), 1, dtype="f4")
        self._zbuf = ctx.depth_renderbuffer((w, h))
        self._fbo = ctx.framebuffer([self._warped, self._wdepth], self._zbuf)
        self._cover = ctx.texture((w, h), 4, dtype="f1")  # the nearest view's coverage (alpha), for view_merge="holes"
        self._out = ctx.texture((w, h), 4, dtype="f1")
        self._out_fbo = ctx.framebuffer([self._out])
        for t in (self._warped, self._wdepth, self._cover):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        rec = cfg.reconstruction
        if rec == "points":
            self.prog = load_program(ctx, SHADERS / "warp_points.vert", SHADERS / "warp_points.frag")
        elif rec == "quads":
            self.prog = load_program(ctx, SHADERS / "warp_quads.vert", SHADERS / "warp_splat.frag", SHADERS / "warp_quads.geom")
        else:
            self.prog = load_program(ctx, SHADERS / "warp_mesh.vert", SHADERS / "warp_mesh.frag", SHADERS / "warp_mesh.geom")
        rw, rh = self.ref_intr.width, self.ref_intr.height
        if rec == "mesh":
            tris = mesh_grid_indices(rw, rh)
            self._ibo = ctx.buffer(tris.astype("u4").tobytes())
            self.vao = ctx.vertex_array(self.prog, [], index_buffer=self._ibo, index_element_size=4)
            self._mode = moderngl.TRIANGLES
            self._count = len(tris)
            # pixels next to a cut (thin railings, silhouettes) are drawn as point splats too
            self.edge_prog = load_program(ctx, SHADERS / "warp_points.vert", SHADERS / "warp_points.frag")
            self.edge_vao = ctx.vertex_array(self.edge_prog, [])
        else:
            self.vao = ctx.vertex_array(self.prog, [])
            self._mode = moderngl.POINTS
            self._count = rw * rh
        self.fill = FullscreenPass(ctx, SHADERS / "warp_holefill.frag")
        self._views: list[_ViewGPU] = []
        self._frame: ReferenceFrame | None = None
        self._n_ids = 1
        self._max_ids = int(ctx.info["GL_MAX_TEXTURE_SIZE"])

    # ------------------------------------------------------------------ cache
    def apply(self, update: DecodedUpdate) -> None:
        if update.missing:  # a reference view without its colour or depth cannot be warped: keep the last one
            return
        frame = parse_update(update, self.config, self.ref_intr)
        n_ids = 1 + max([int(v.ids.max(initial=0)) for v in frame.views] + list(frame.model) + [0])
        if n_ids > self._max_ids:  # the warp matrices are one texture row per id
            raise WarpMetaError(f"warp metadata frame {update.frame_id}: object id {n_ids - 1} exceeds this client's "
                                f"limit of {self._max_ids - 1} (GL_MAX_TEXTURE_SIZE)")
        while len(self._views) < len(frame.views):
            self._views.append(_ViewGPU())
        for g, v in zip(self._views, frame.views):
            g.color = upload_image(self.gl, v.color, g.color, linear=False)
            g.depth = upload_image(self.gl, v.depth_m.astype(np.float32), g.depth, linear=False)
            g.ids = upload_image(self.gl, v.ids, g.ids, linear=False)
        self._frame = frame
        self._n_ids = n_ids
        self.has_content = True

    # ------------------------------------------------------------------ render
    def _view_order(self, pose: Pose) -> list[int]:
        assert self._frame is not None
        d = [v.pose.distance_m(pose) + 0.01 * v.pose.angle_deg(pose) for v in self._frame.views]
        return sorted(range(len(d)), key=lambda k: d[k])

    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        i = self.intrinsics
        if self._frame is None:
            return ClientFrame(np.zeros((i.height, i.width, 3), np.uint8), np.ones((i.height, i.width), bool))
        t0 = time.perf_counter()
        cfg, ctx, prog, frame, ref = self.config, self.gl, self.prog, self._frame, self.ref_intr
        proj = i.projection()
        self._fbo.use()
        ctx.viewport = (0, 0, i.width, i.height)
        self._fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self._wdepth.write(np.zeros((i.height, i.width), np.float32).tobytes())
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.CULL_FACE | ctx.BLEND)
        ctx.enable(ctx.PROGRAM_POINT_SIZE)
        tan_y = math.tan(math.radians(ref.fov_y_deg) / 2)
        progs = [prog] + ([self.edge_prog] if cfg.reconstruction == "mesh" else [])
        for p in progs:
            self._set(p, "u_ref_size", (ref.width, ref.height))
            self._set(p, "u_tan_half", (tan_y * ref.aspect, tan_y))
            self._set(p, "u_out_size", (float(i.width), float(i.height)))
            self._set(p, "u_proj_zz", (float(proj[2, 2]), float(proj[2, 3])))
            self._set(p, "u_disc", float(cfg.depth_discontinuity))
            self._set(p, "u_max_splat", float(cfg.max_splat_px))
            self._set(p, "u_splat_slack", float(cfg.splat_slack_px))
            self._set(p, "u_edge_only", 0 if p is prog else 1)
            for unit, name in enumerate(("u_color", "u_depth", "u_ids", "u_mats", "u_cover")):
                self._set(p, name, unit)
        order = self._view_order(pose)
        for rank, k in enumerate(order):
            g, view = self._views[k], frame.views[k]
            mats = warp_matrices(frame, view, ref, pose, i, t_s, cfg.extrapolate, cfg.max_extrapolation_s, self._n_ids)
            self._upload_mats(g, mats)
            g.color.use(0)
            g.depth.use(1)
            g.ids.use(2)
            g.mats.use(3)
            holes_only = rank > 0 and cfg.view_merge == "holes"
            if holes_only and rank == 1:
                ctx.copy_framebuffer(self._cover, self._fbo)
                self._fbo.use()
            self._cover.use(4)
            for p in progs:
                self._set(p, "u_bias_rel", 0.0 if rank == 0 else 0.01 * rank)
                self._set(p, "u_holes_only", 1 if holes_only else 0)
            self.vao.render(mode=self._mode, vertices=self._count)
            if cfg.reconstruction == "mesh":
                self.edge_vao.render(mode=self._mgl.POINTS, vertices=ref.width * ref.height)
        color, holes = fill_holes(self.fill, self._out_fbo, self._warped, self._wdepth, i, pose,
                                  frame.views[order[0]].pose.position, cfg.max_scan_px, cfg.hole_fill)
        ms = (time.perf_counter() - t0) * 1e3
        return ClientFrame(color, holes, {"warp_ms": ms, "views": float(len(order))})

    def _upload_mats(self, g: _ViewGPU, mats: np.ndarray) -> Any:
        n = mats.shape[0]
        data = np.ascontiguousarray(mats.reshape(n, 5 * 4), np.float32)
        if g.mats is None or g.mats.size != (5, n):
            if g.mats is not None:
                g.mats.release()
            g.mats = self.gl.texture((5, n), 4, dtype="f4")
            g.mats.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
        g.mats.write(data.tobytes())
        return g.mats

    @staticmethod
    def _set(prog: Any, name: str, value: Any) -> None:
        set_uniform(prog, name, value)
