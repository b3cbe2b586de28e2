"""The ``quads`` client half: keeps the reference quads, draws the layered mesh at its own rate."""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from ...render.canvas import FullscreenPass, upload_image
from ...scene.pose import CameraIntrinsics, Pose
from ..base import ClientFrame, ClientHalf, DecodedUpdate
from ..warp import SHADERS as WARP_SHADERS
from ..warp.client import fill_holes
from .config import QuadsConfig
from .gen import QuadSet
from .mesh import (ColourClamp, QuadMeshGL, ReferenceCache, background_quads, build_mesh, continuous_sides, hidden_sky,
                   scene_sides, sealed, sky_sides)
from .server import outside_frustum
from .underlap import reference_extend
from .wire import CACHED_KINDS, KIND_REFERENCE, KIND_UPDATE, KIND_WIDE, QuadsWireError, decode_sets, parse_frame_meta, parse_session

log = logging.getLogger(__name__)


class QuadsClient(ClientHalf):
    """Caches the reference set, rebuilds the mesh per update, draws it per display frame."""

    config: QuadsConfig

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        sess = parse_session(self.session_data)
        self.slots, self.cols, self.rows = sess.slots, sess.cols, sess.rows
        self.slot_size = sess.slot_size
        self.atlas_size = sess.atlas_size
        self.packed: tuple[int, int] | None = sess.packed
        self.cache = ReferenceCache()
        self._broken = True           # no reference yet: residual frames cannot apply
        self._atlas_tex: Any = None
        self._mesh = QuadMeshGL(self.gl)
        self._fill = FullscreenPass(self.gl, str(WARP_SHADERS / "warp_holefill.frag"))
        i = self.intrinsics
        self._out = self.gl.texture((i.width, i.height), 4, dtype="f1")
        self._out_fbo = self.gl.framebuffer([self._out])
        self._pose0: Pose | None = None
        self._stats: dict[str, float] = {}
        self._sky = QuadSet.empty()   # the background quads the client made for its reference set
        self._hidden_sky: tuple[QuadSet, np.ndarray] = (QuadSet.empty(), np.zeros((0, 2)))   # and behind its model
        self._wide_outs: dict[tuple[int, int, float], np.ndarray] = {}
        self._cached_parts: list[tuple[np.ndarray, np.ndarray]] | None = None   # the reference set's mesh parts
        self._sky_parts: list[tuple[np.ndarray, np.ndarray]] = []

    def _wide_out(self, wide: CameraIntrinsics) -> np.ndarray:
        """The wide view's pixels outside the main view (the only ones its set covers), kept per size."""
        key = (wide.width, wide.height, wide.fov_y_deg)
        if key not in self._wide_outs:
            self._wide_outs[key] = outside_frustum(wide, self.intrinsics)
        return self._wide_outs[key]

    def _origin(self, slot: int) -> tuple[int, int]:
        return (slot % self.cols) * self.slot_size[0], (slot // self.cols) * self.slot_size[1]

    # ------------------------------------------------------------------ cache
    def apply(self, update: DecodedUpdate) -> None:
        where = f"frame {update.frame_id}"
        if update.missing:
            # a lost atlas or quad stream: keep showing the last good state; residual frames
            # cannot apply until the reference frame the server sends after the loss report
            self._broken = True
            return
        try:
            cams, sets, kind, ref_frame, atlas = self._check(update, where)
        except QuadsWireError:
            # the server's copy of this client's cache took the frame: residual frames cannot
            # apply until the next reference frame (every reference_every frames, or on a keyframe request)
            self._broken = True
            raise
        if kind == "residual" and (self._broken or self.cache.frame_id != ref_frame):
            log.debug("quads %s: residual frame for reference %d, holding %d; waiting for a reference frame",
                      where, ref_frame, self.cache.frame_id)
            return
        t0 = time.perf_counter()
        # everything is checked: change the state
        for s in sets:
            pose, intr = cams[s.camera]
            if s.kind == KIND_REFERENCE:
                self.cache.set_reference(s.quads, pose, intr, ref_frame)
            elif s.kind == KIND_UPDATE and len(s.quads):
                self.cache.apply_update(s.quads)
        quasar_sky = self.config.variant == "quasar" and not self.config.background_quads
        # QUASAR's slots hold each view's image whole: its lookups filter across quad borders as a mesh over the
        # image would; QuadStream's clamp to each quad's own texels, so its packed and slot atlases look the same
        clamp: ColourClamp = "view" if self.config.variant == "quasar" else "quad"
        parts = []
        if self.cache.quads is not None and self.cache.pose is not None and self.cache.intr is not None:
            new_ref = any(s.kind == KIND_REFERENCE for s in sets)
            if new_ref or any(s.kind == KIND_UPDATE and len(s.quads) for s in sets) or self._cached_parts is None:
                # the cached quads' mesh changes only with them (a residual frame without update quads keeps it)
                im = self.cache.index_map if self.cache.raster else None   # the reference set's, made once
                if self.config.variant == "quasar" and self.config.silhouette_clamp:   # no sky texels at the silhouette
                    sides = scene_sides(self.cache.quads, self.cache.intr, im)
                    # drawn a little past its depth edges, behind the surface beyond (underlap_px), and where asked
                    # past its sides where the surface goes on (seal_cracks) and against the sky (sky_edge_px)
                    cached = [build_mesh(self.cache.quads, self.cache.pose, self.cache.intr, self._origin(0), "quad",
                                         grow=sides, extend=reference_extend(self.cache.quads, self.cache.intr,
                                                                             self.config, im))]
                else:
                    cached = [build_mesh(self.cache.quads, self.cache.pose, self.cache.intr, self._origin(0), clamp)]
                if quasar_sky and (new_ref or self._cached_parts is None):   # the sky the reference set left out
                    self._sky = background_quads(self.cache.quads, self.cache.intr, index_map=im)
                    self._hidden_sky = hidden_sky(self.cache.quads, self.cache.intr, self._origin(0),
                                                  reach=self.config.hidden_sky_px, index_map=im)
                    self._sky_parts = [build_mesh(self._sky, self.cache.pose, self.cache.intr, self._origin(0), "view"),
                                       # and behind the model's silhouette against it, shown where motion reveals it
                                       build_mesh(self._hidden_sky[0], self.cache.pose, self.cache.intr, self._origin(0),
                                                  "quad", self._hidden_sky[1])]
                self._cached_parts = cached + (self._sky_parts if quasar_sky else [])
            parts.extend(self._cached_parts)
        # QuadStream: the views after the centre view are drawn behind what the centre view shows (its guard)
        guard = self.config.variant == "quadstream" and self.config.centre_guard
        centre: int | None = None
        for s in sets:
            if s.kind in CACHED_KINDS:
                continue
            pose, intr = cams[s.camera]
            view = s.camera if guard else 0
            # QuadStream's centre view: its silhouette against the sky drawn a little past its pixels (sky_sides)
            extend = (sky_sides(s.quads, intr, self.config.sky_edge_px)
                      if self.config.variant == "quadstream" and s.camera == 0 and self.config.sky_edge_px > 0 else None)
            if s.tex is None:
                parts.append(build_mesh(s.quads, pose, intr, self._origin(s.slot), clamp, view=view, extend=extend))
                if quasar_sky and s.kind == KIND_WIDE:   # the wide view's sky outside the main view
                    sky = background_quads(s.quads, intr, self._wide_out(intr))
                    parts.append(build_mesh(sky, pose, intr, self._origin(s.slot), "view"))
            else:
                parts.append(build_mesh(s.quads, pose, intr, s.tex - np.stack([s.quads.x, s.quads.y], axis=-1), "quad",
                                        view=view, extend=extend))
            if guard and s.camera == 0 and centre is None:
                centre = len(parts) - 1
                self._mesh.set_guard(*parts[centre], *cams[0])
                origin = self._whole(s, intr)
                if origin is not None and self._mesh.guard_depth is not None:
                    # the atlas holds the centre view's image: filter across quad borders along a surface
                    grow = continuous_sides(s.quads, self._mesh.guard_depth)
                    if self.config.seal_cracks:   # and drawn as far past them: no crack opens between its quads
                        extend = sealed(grow) if extend is None else extend + sealed(grow)
                    parts[centre] = build_mesh(s.quads, pose, intr, origin, "quad", view=view, grow=grow, extend=extend)
        if centre is None:
            self._mesh.clear_guard()
        self._mesh.upload_parts(parts)
        self._atlas_tex = upload_image(self.gl, atlas, self._atlas_tex, linear=True)
        self._pose0 = cams[0][0]
        self._broken = False
        self.has_content = True
        self._stats = {"mesh_ms": (time.perf_counter() - t0) * 1e3, "quads_drawn": float(self._mesh.quads),
                       "quads_cached": float(len(self.cache))}

    def _whole(self, s: Any, intr: CameraIntrinsics) -> tuple[int, int] | None:
        """Where the atlas holds set ``s``'s view whole (its quads cover every pixel at one offset: a slot, or
        QuadStream's centre view in its packed atlas): that offset, else ``None``."""
        if len(s.quads) == 0 or s.quads.pixels() != intr.width * intr.height:
            return None
        if s.tex is None:
            return self._origin(s.slot)
        off = s.tex.astype(np.int64) - np.stack([s.quads.x, s.quads.y], axis=-1).astype(np.int64)
        return (int(off[0, 0]), int(off[0, 1])) if (off == off[0]).all() else None

    def _check(self, update: DecodedUpdate, where: str) -> tuple[Any, Any, str, int, np.ndarray]:
        """Everything of an update checked, nothing changed yet: (cameras, sets, frame kind, reference id, atlas)."""
        info = parse_frame_meta(update.meta, where, self.slot_size)
        cams, kind, ref_frame = info.cameras, info.kind, info.ref_frame
        atlas = update.planes.get("atlas")
        if not isinstance(atlas, np.ndarray) or atlas.shape != (self.atlas_size[1], self.atlas_size[0], 3) or atlas.dtype != np.uint8:
            raise QuadsWireError(f"quads {where}: plane atlas must be {(self.atlas_size[1], self.atlas_size[0], 3)} uint8")
        sets = decode_sets(update.data.get("quads", b""), update.data.get("offsets", b""), where, self.slot_size, self.slots,
                           len(cams), self.intrinsics.far_m, self.packed)
        has_ref = self.cache.quads is not None and kind == "residual"
        for k, s in enumerate(sets):
            if s.kind == KIND_REFERENCE:
                if kind != "reference":
                    raise QuadsWireError(f"quads {where}: set {k} is a reference set in a residual frame")
                has_ref = True
            elif s.kind == KIND_UPDATE and not has_ref:
                raise QuadsWireError(f"quads {where}: set {k} updates a reference set the client does not hold")
        return cams, sets, kind, ref_frame, atlas

    # ------------------------------------------------------------------ render
    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        i = self.intrinsics
        if not self.has_content:
            return ClientFrame(np.zeros((i.height, i.width, 3), np.uint8), np.ones((i.height, i.width), bool))
        t0 = time.perf_counter()
        _, color, depth = self._mesh.draw(pose, i, self._atlas_tex, self.atlas_size)
        assert self._pose0 is not None
        rgb, holes = fill_holes(self._fill, self._out_fbo, color, depth, i, pose, self._pose0.position, 64, True)
        st = dict(self._stats)
        st["draw_ms"] = (time.perf_counter() - t0) * 1e3
        return ClientFrame(rgb, holes, st)

