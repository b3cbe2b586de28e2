"""The server's headless renderer: forward shading with a sun shadow map.

Outputs, all with row 0 at the top of the image:

- ``color``: (H, W, 3) uint8, sRGB-encoded;
- ``depth``: (H, W) float32 view-space depth along -Z in metres, ``inf`` on background;
- ``normal``: (H, W, 3) float32 world normal facing the viewer, zero on background;
- ``object_id``: (H, W) uint32, 0 on background;
- ``triangle_id``: (H, W) uint32 scene-wide triangle index + 1, 0 on background
  (triangle ``k`` of object ``o`` has index ``tri_base[o] + k``; see :meth:`SceneGPU.tri_base`).

A render that asks for no colour draws unshaded (the forward program without its shading), and
:meth:`Renderer.shade` colours such a G-buffer afterwards, each visible fragment once and only at the pixels asked
for, to the same bytes as one pass: a server that sends colour only at some pixels shades only those.

The same renderer draws the ground truth (at the client's true pose and time) and
whatever a server half needs.  Shading lives in ``shaders/shading.glsl``; any program
that includes it can be set up with :meth:`Renderer.bind_shading`.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from ..scene.model import Scene, SceneObject
from ..scene.pose import CameraIntrinsics, Pose, look_at_quat
from .canvas import FullscreenPass, upload_image
from .ddgi import GI_UNITS, DdgiSettings, DdgiVolume, ProbeStates, gi_time
from .gl import SHADER_DIR, get_context, has_uniform, load_program, set_uniform

log = logging.getLogger(__name__)

ALL_OUTPUTS = ("color", "depth", "normal", "object_id", "triangle_id")
SHADING_MODEL_CODES = {"phong": 0, "pbr": 1}   # u_shading_model in shading.glsl
TEXTURE_ANISOTROPY = 1.0
"""Anisotropic filtering of scene textures: off (trilinear).  llvmpipe's anisotropic path
takes seconds for one draw at some views (a 160x90 frame of the default scene's sign at
6.5 s against 2 ms), which stalls whole runs, and it derives its footprint from implicit
derivatives only, so no method that resamples shading (SAS, TSS) could reproduce it."""

MAP_UNITS = {"u_mr_map": 3, "u_normal_map": 4, "u_occlusion_map": 5, "u_emissive_map": 6}
PEEL_UNIT = 7
DRAWN_IDS_UNIT = 8
"""The unit of the drawn ids :meth:`Renderer.shade` compares with (the shadow maps take 1 and 2, DDGI its GI_UNITS)."""
PEEL_EPS = 1e-4
"""Depth peeling keeps a fragment only this far (relative) behind the previous layer (f32 depth noise)."""


@dataclass
class RenderOutput:
    color: np.ndarray
    depth: np.ndarray | None = None
    normal: np.ndarray | None = None
    object_id: np.ndarray | None = None
    triangle_id: np.ndarray | None = None
    drawn: Any = field(default=None, repr=False, compare=False)
    """What :meth:`Renderer.shade` needs to colour this G-buffer (a render without colour, not supersampled)."""


@dataclass(frozen=True)
class _Drawn:
    serial: int
    scene: Scene
    t_s: float
    pose: Pose
    intr: CameraIntrinsics
    object_ids: set[int] | None
    peel: np.ndarray | None


@dataclass
class ObjectGPU:
    obj: SceneObject
    vbo: Any
    ibo: Any
    vao: Any
    shadow_vao: Any
    texture: Any | None
    tri_base: int
    maps: dict[str, Any] = field(default_factory=dict)   # the material's other textures, by uniform name
    tbo: Any = None                                      # per-vertex tangents (4f)
    gbuffer_vao: Any = None                              # on Renderer.gbuffer_prog (made on first use)
    shade_vao: Any = None                                # on Renderer.shade_prog (made on first use)
    matrices: tuple[Any, Any] = (None, None)              # the last model matrix's bytes, its uniform bytes


@dataclass
class SceneGPU:
    """GPU buffers for one scene, built once and reused for every frame."""

    scene: Scene
    objects: list[ObjectGPU] = field(default_factory=list)

    def tri_base(self) -> dict[int, int]:
        return {o.obj.object_id: o.tri_base for o in self.objects}


def light_view_projection(scene: Scene) -> np.ndarray:
    """World -> clip matrix of the sun's orthographic shadow camera."""
    assert scene.sun is not None
    lo, hi = scene.bounds()
    centre = (lo + hi) / 2
    d = np.asarray(scene.sun.direction, np.float64)
    d /= np.linalg.norm(d)
    ext = scene.sun.shadow_extent_m
    eye = centre - d * ext * 2
    f = d
    up = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = r, u, -f
    view[:3, 3] = -view[:3, :3] @ eye
    near, far = 0.1, ext * 4
    proj = np.eye(4)
    proj[0, 0] = proj[1, 1] = 1.0 / ext
    proj[2, 2] = -2.0 / (far - near)
    proj[2, 3] = -(far + near) / (far - near)
    return proj @ view


_F32_MAX = float(np.finfo(np.float32).max)


def normal_matrix(model: np.ndarray) -> np.ndarray | None:
    """The normal matrix (inverse transpose of the 3x3 part) of ``model``, or ``None`` when that part is not finite
    or not invertible (the object cannot be drawn; rendering never raises on it)."""
    mm = np.asarray(model, np.float64)
    if not np.abs(mm).max() <= _F32_MAX:       # not finite (NaN too), or not in the GPU's float32
        return None
    try:
        inv = np.linalg.inv(mm[:3, :3])
    except np.linalg.LinAlgError:
        return None
    return inv.T if np.isfinite(inv).all() else None


class Renderer:
    """Renders a :class:`Scene` at any pose and time into numpy images."""

    def __init__(self, ctx: Any | None = None) -> None:
        self.ctx = ctx if ctx is not None else get_context()
        self.prog = load_program(self.ctx, SHADER_DIR / "forward.vert", SHADER_DIR / "forward.frag")
        self.shadow_prog = load_program(self.ctx, SHADER_DIR / "shadow.vert", SHADER_DIR / "shadow.frag")
        self._gbuffer_prog: Any = None
        self._shade_prog: Any = None
        self._serial = 0      # renders drawn so far (Renderer.shade checks that its G-buffer is still the last one)
        self._scenes: dict[int, SceneGPU] = {}
        self._placeholder_tex: Any = None
        self._peel_tex: Any = None
        self._peel_none: Any = None
        self.supersample = 1
        """Samples per pixel along each axis of :meth:`render` (1: none; 2: 4 samples)."""
        self._fbos: dict[tuple[int, int], tuple[Any, ...]] = {}
        self._shadow: dict[str, tuple[Any, Any]] = {}
        self._shadow_size = 0
        self._shadow_static_key: int | None = None
        self._shadow_key: tuple[int, float] | None = None
        self._background = FullscreenPass(self.ctx, SHADER_DIR / "background.frag")
        self._where_pass: FullscreenPass | None = None
        self._where_tex: Any = None
        self._gi: dict[int, DdgiVolume] = {}
        self.gi_sources: dict[int, Any] = {}
        """Probes to shade a scene with instead of computing its own (by ``id(scene)``; a client's received copy)."""
        self._gi_building: set[int] = set()
        self._gi_none: Any = None
        self.gi_states: ProbeStates | None = None   # made by probe_states() on first use
        self.gi_hz = 0.0
        """The rate the scene's DDGI probes are relit at (0: for every time a render asks; see :func:`gi_time`): a live
        server relights them at its own rate, paid once per period whatever its frame rate, as DDGI engines do."""
        self.gi_ms = 0.0
        """Milliseconds spent relighting probes in renders so far (a caller differences it around a frame)."""

    # ------------------------------------------------------------------ resources
    def upload(self, scene: Scene) -> SceneGPU:
        key = id(scene)
        sg = self._scenes.get(key)
        if sg is not None and sg.scene is scene:
            return sg
        import moderngl

        sg = SceneGPU(scene)
        base = 0
        for o in scene.objects:
            m = o.mesh
            data = np.hstack([m.positions, m.normals, m.uvs]).astype("f4")
            vbo = self.ctx.buffer(data.tobytes())
            tbo = self.ctx.buffer(m.tangent_frame().astype("f4").tobytes())
            ibo = self.ctx.buffer(m.indices.astype("u4").tobytes())
            vao = self.ctx.vertex_array(self.prog, [(vbo, "3f 3f 2f", "in_position", "in_normal", "in_uv"),
                                                    (tbo, "4f", "in_tangent")], ibo)
            svao = self.ctx.vertex_array(self.shadow_prog, [(vbo, "3f 12x 8x", "in_position")], ibo)
            mat = o.material

            def texture(img: np.ndarray | None) -> Any:
                if img is None:
                    return None
                img = np.ascontiguousarray(np.asarray(img)[..., :3], dtype=np.uint8)
                tex = self.ctx.texture((img.shape[1], img.shape[0]), 3, img.tobytes())
                tex.build_mipmaps()
                tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
                tex.anisotropy = TEXTURE_ANISOTROPY
                tex.repeat_x = tex.repeat_y = True
                return tex

            maps = {k: t for k, t in (("u_mr_map", texture(mat.metallic_roughness_texture)),
                                      ("u_normal_map", texture(mat.normal_texture)),
                                      ("u_occlusion_map", texture(mat.occlusion_texture)),
                                      ("u_emissive_map", texture(mat.emissive_texture))) if t is not None}
            sg.objects.append(ObjectGPU(o, vbo, ibo, vao, svao, texture(mat.texture), base, maps, tbo))
            base += m.triangle_count
        self._scenes[key] = sg
        return sg

    def _fbo(self, w: int, h: int) -> tuple[Any, ...]:
        f = self._fbos.get((w, h))
        if f is None:
            color = self.ctx.texture((w, h), 4, dtype="f1")
            normal = self.ctx.texture((w, h), 4, dtype="f2")
            ids = self.ctx.texture((w, h), 2, dtype="u4")
            ids.filter = (self.ctx.NEAREST, self.ctx.NEAREST)
            depth_lin = self.ctx.texture((w, h), 1, dtype="f4")
            zbuf = self.ctx.depth_renderbuffer((w, h))
            fbo = self.ctx.framebuffer([color, normal, ids, depth_lin], zbuf)
            shade_fbo = self.ctx.framebuffer([color], zbuf)     # Renderer.shade: colour over the drawn depths
            depth_fbo = self.ctx.framebuffer(depth_attachment=zbuf)
            f = (fbo, color, normal, ids, depth_lin, shade_fbo, depth_fbo)
            self._fbos[(w, h)] = f
        return f

    @property
    def gbuffer_prog(self) -> Any:
        """The forward program without shading (``NO_COLOR``): a render that asks for no colour draws with it."""
        if self._gbuffer_prog is None:
            self._gbuffer_prog = load_program(self.ctx, SHADER_DIR / "forward.vert", SHADER_DIR / "forward.frag",
                                              defines={"NO_COLOR": 1})
        return self._gbuffer_prog

    @property
    def shade_prog(self) -> Any:
        """The forward program's shading over a G-buffer already drawn (``SHADE_PASS``, :meth:`shade`)."""
        if self._shade_prog is None:
            self._shade_prog = load_program(self.ctx, SHADER_DIR / "forward.vert", SHADER_DIR / "forward.frag",
                                            defines={"SHADE_PASS": 1})
        return self._shade_prog

    def _vao(self, og: ObjectGPU, prog: Any) -> Any:
        """``og``'s vertex array on ``prog`` (the forward program or one of its two variants)."""
        if prog is self.prog:
            return og.vao
        if prog is self._gbuffer_prog:
            if og.gbuffer_vao is None:     # no texture coordinates or tangents: nothing shades
                og.gbuffer_vao = self.ctx.vertex_array(prog, [(og.vbo, "3f 3f 8x", "in_position", "in_normal")], og.ibo)
            return og.gbuffer_vao
        if og.shade_vao is None:
            og.shade_vao = self.ctx.vertex_array(prog, [(og.vbo, "3f 3f 2f", "in_position", "in_normal", "in_uv"),
                                                        (og.tbo, "4f", "in_tangent")], og.ibo)
        return og.shade_vao

    # ------------------------------------------------------------------ shading
    def _shadow_target(self, kind: str, size: int) -> tuple[Any, Any]:
        import moderngl

        if self._shadow_size != size:
            for fbo, tex in self._shadow.values():
                fbo.release()
                tex.release()
            self._shadow = {}
            self._shadow_size = size
            self._shadow_static_key = None
            self._shadow_key = None
        t = self._shadow.get(kind)
        if t is None:
            dtex = self.ctx.depth_texture((size, size))
            dtex.compare_func = "<="
            dtex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            t = (self.ctx.framebuffer(depth_attachment=dtex), dtex)
            self._shadow[kind] = t
        return t

    def _draw_shadow_casters(self, fbo: Any, scene: Scene, t_s: float, dynamic: bool) -> None:
        sg = self.upload(scene)
        fbo.use()
        fbo.clear(depth=1.0)
        self.ctx.enable(self.ctx.DEPTH_TEST)
        self.ctx.disable(self.ctx.CULL_FACE)
        self.shadow_prog["u_light_vp"].write(np.asarray(light_view_projection(scene), "f4").T.tobytes())
        for og in sg.objects:
            if og.obj.dynamic != dynamic:
                continue
            self.shadow_prog["u_model"].write(np.asarray(og.obj.model_matrix(t_s), "f4").T.tobytes())
            og.shadow_vao.render()

    def shadow_pass(self, scene: Scene, t_s: float) -> None:
        """Render the sun's shadow maps for time ``t_s``.

        Static casters go into one map rendered once per scene; animated casters into
        a second map re-rendered when the time changes.  The shader takes the minimum
        of the two lookups, which equals one map holding every caster.
        """
        if scene.sun is None:
            return
        size = scene.sun.shadow_map_size
        fbo_s, _ = self._shadow_target("static", size)
        fbo_d, _ = self._shadow_target("dynamic", size)
        if self._shadow_static_key != id(scene):
            self._draw_shadow_casters(fbo_s, scene, 0.0, dynamic=False)
            self._shadow_static_key = id(scene)
            self._shadow_key = None
        key = (id(scene), float(t_s))
        if self._shadow_key != key:
            self._draw_shadow_casters(fbo_d, scene, t_s, dynamic=True)
            self._shadow_key = key

    def bind_shading(self, prog: Any, scene: Scene, t_s: float, shadow_unit: int = 1, gi: bool = True) -> None:
        """Set the lighting uniforms of ``shading.glsl`` on ``prog`` for time ``t_s``; ``gi=False`` leaves the scene's
        global illumination off (a pass that writes no colour need not relight the probes)."""
        # the probes first: relighting them (at a GI rate, for an earlier time) draws the moving objects' shadow map
        # for their own time and binds textures of its own, which must not undo the frame's bindings below
        self._bind_gi(prog, scene, t_s, gi)
        self.shadow_pass(scene, t_s)
        sun = scene.sun
        if sun is not None:
            d = np.asarray(sun.direction, np.float64)
            d /= np.linalg.norm(d)
            set_uniform(prog, "u_sun_dir", tuple(d))
            set_uniform(prog, "u_sun_color", tuple(np.asarray(sun.color) * sun.intensity.value(t_s)))
            set_uniform(prog, "u_has_shadow", 1)
            if has_uniform(prog, "u_light_vp"):
                prog["u_light_vp"].write(np.asarray(light_view_projection(scene), "f4").T.tobytes())
            self._shadow["static"][1].use(location=shadow_unit)
            self._shadow["dynamic"][1].use(location=shadow_unit + 1)
            set_uniform(prog, "u_shadow_map", shadow_unit)
            set_uniform(prog, "u_shadow_map_dyn", shadow_unit + 1)
        else:
            set_uniform(prog, "u_sun_color", (0.0, 0.0, 0.0))
            set_uniform(prog, "u_sun_dir", (0.0, -1.0, 0.0))
            set_uniform(prog, "u_has_shadow", 0)
        set_uniform(prog, "u_ambient", tuple(scene.ambient))
        set_uniform(prog, "u_sky_env", tuple(float(c) ** 2.2 for c in scene.sky_color))
        set_uniform(prog, "u_shading_model", SHADING_MODEL_CODES[scene.shading])
        n = len(scene.point_lights)
        set_uniform(prog, "u_num_point", n)
        if n:
            pos = np.zeros((8, 4), "f4")
            col = np.zeros((8, 3), "f4")
            for i, pl in enumerate(scene.point_lights):
                pos[i] = (*pl.position, pl.range_m)
                col[i] = np.asarray(pl.color) * pl.intensity.value(t_s)
            if has_uniform(prog, "u_point_pos"):
                prog["u_point_pos"].write(pos.tobytes())
            if has_uniform(prog, "u_point_color"):
                prog["u_point_color"].write(col.tobytes())

    def probe_states(self) -> ProbeStates:
        """The relit probe states this renderer's DDGI volumes share (:class:`~splitrender.render.ddgi.ProbeStates`)."""
        if self.gi_states is None:
            self.gi_states = ProbeStates()
        return self.gi_states

    def gi_volume(self, scene: Scene) -> DdgiVolume | None:
        """The scene's DDGI probes on this renderer (captured on first use; None while being captured)."""
        key = id(scene)
        vol = self._gi.get(key)
        if vol is None or vol.scene is not scene:
            if key in self._gi_building:
                return None
            self._gi_building.add(key)
            try:
                vol = DdgiVolume(self, scene, DdgiSettings(counts=tuple(scene.gi_probes)), self.probe_states())  # type: ignore[arg-type]
            finally:
                self._gi_building.discard(key)
            self._gi[key] = vol
        return vol

    def _bind_gi(self, prog: Any, scene: Scene, t_s: float, on: bool = True) -> None:
        src = self.gi_sources.get(id(scene)) if on else None
        if src is not None:
            src.bind(prog)
            set_uniform(prog, "u_gi", 1)
            return
        vol = self.gi_volume(scene) if on and scene.gi == "ddgi" else None
        if vol is not None:
            if not vol.updating:
                w0 = time.perf_counter()
                vol.recurrent = self.gi_hz > 0
                vol.update(gi_time(t_s, self.gi_hz))
                self.gi_ms += (time.perf_counter() - w0) * 1e3
            vol.bind(prog)
            set_uniform(prog, "u_gi", 1)
            return
        set_uniform(prog, "u_gi", 0)
        if has_uniform(prog, "u_gi_irr") or has_uniform(prog, "u_gi_vis"):   # every sampler gets a texture of its own
            if self._gi_none is None:
                self._gi_none = self.ctx.texture((1, 1), 4, np.zeros(4, "f4").tobytes(), dtype="f4")
            for unit, name in zip(GI_UNITS, ("u_gi_irr", "u_gi_vis")):
                self._gi_none.use(location=unit)
                set_uniform(prog, name, unit)

    def bind_material(self, prog: Any, og: ObjectGPU, texture_unit: int = 0) -> None:
        """Set the material uniforms of ``shading.glsl``: the base-colour texture on ``texture_unit``,
        the other maps on units :data:`MAP_UNITS` (the shadow maps take 1 and 2)."""
        mat = og.obj.material
        set_uniform(prog, "u_base_color", tuple(mat.base_color))
        set_uniform(prog, "u_specular", float(mat.specular))
        set_uniform(prog, "u_shininess", float(mat.shininess))
        set_uniform(prog, "u_metallic", float(mat.metallic))
        set_uniform(prog, "u_roughness", float(mat.roughness))
        set_uniform(prog, "u_normal_scale", float(mat.normal_scale))
        set_uniform(prog, "u_occlusion_strength", float(mat.occlusion_strength))
        set_uniform(prog, "u_emissive", tuple(float(c) for c in mat.emissive))
        uvt = np.eye(3) if mat.uv_transform is None else np.asarray(mat.uv_transform, np.float64)
        if has_uniform(prog, "u_uv_transform"):
            prog["u_uv_transform"].write(np.asarray(uvt, "f4").T.tobytes())
        # Every sampler gets a texture of its own, a 1x1 placeholder where the material has
        # none: an unused sampler left on another object's mipmapped, anisotropic texture
        # costs llvmpipe seconds per draw at some views (its masked-off lanes still sample,
        # and derivatives across a silhouette send the anisotropic footprint far off).
        (og.texture or self._placeholder()).use(location=texture_unit)
        set_uniform(prog, "u_albedo", texture_unit)
        set_uniform(prog, "u_has_texture", int(og.texture is not None))
        for name, unit in MAP_UNITS.items():
            tex = og.maps.get(name)
            if has_uniform(prog, name):
                (tex or self._placeholder()).use(location=unit)
                set_uniform(prog, name, unit)
            set_uniform(prog, "u_has_" + name[2:], int(tex is not None and has_uniform(prog, name)))

    def _bind_peel(self, prog: Any, peel: np.ndarray | None, intr: CameraIntrinsics) -> None:
        """Bind the depth-peeling texture (a 1x1 placeholder when not peeling: every sampler gets a texture)."""
        if peel is None:
            set_uniform(prog, "u_peel_on", 0)
            if self._peel_none is None:
                self._peel_none = self.ctx.texture((1, 1), 1, np.zeros(1, "f4").tobytes(), dtype="f4")
                self._peel_none.filter = (self.ctx.NEAREST, self.ctx.NEAREST)
            tex = self._peel_none
        else:
            if self._peel_tex is None or self._peel_tex.size != (intr.width, intr.height):
                if self._peel_tex is not None:
                    self._peel_tex.release()
                self._peel_tex = self.ctx.texture((intr.width, intr.height), 1, dtype="f4")
                self._peel_tex.filter = (self.ctx.NEAREST, self.ctx.NEAREST)
            self._peel_tex.write(np.ascontiguousarray(np.asarray(peel, np.float32)[::-1]).tobytes())
            set_uniform(prog, "u_peel_on", 1)
            set_uniform(prog, "u_peel_eps", PEEL_EPS)
            tex = self._peel_tex
        tex.use(location=PEEL_UNIT)
        set_uniform(prog, "u_peel", PEEL_UNIT)

    def _placeholder(self) -> Any:
        if self._placeholder_tex is None:
            self._placeholder_tex = self.ctx.texture((1, 1), 4, bytes((255, 255, 255, 255)))
        return self._placeholder_tex

    # ------------------------------------------------------------------ render
    def render(self, scene: Scene, t_s: float, pose: Pose, intr: CameraIntrinsics,
               outputs: Iterable[str] = ("color",), object_ids: set[int] | None = None,
               peel: np.ndarray | None = None) -> RenderOutput:
        """Render ``scene`` at time ``t_s`` from ``pose``; ``object_ids`` limits what is drawn.

        ``peel`` (H, W) float32 view depths turn the pass into one step of depth peeling:
        a fragment is kept only where it lies more than :data:`PEEL_EPS` (relative) behind
        ``peel`` at its pixel (``inf``: nothing is kept there) and faces the eye (a back
        face of a closed surface is hidden by its own front from every viewpoint), so the
        output holds the nearest front-facing surface behind the previous layer.  Peeling
        passes are not supersampled (a sub-sample of the front surface can lie more than the
        gap behind the pixel's one depth and would be kept).

        With :attr:`supersample` ``k`` > 1 the frame is rendered at ``k`` times the size:
        colour is the mean of each ``k`` x ``k`` block (in the stored sRGB code values, as a
        multisample resolve into an 8-bit target does); depth, normals and ids are the
        sample nearest the pixel centre, so they stay consistent with one another."""
        outputs = tuple(outputs)
        for o in outputs:
            if o not in ALL_OUTPUTS:
                raise ValueError(f"unknown render output {o!r}; choose from {ALL_OUTPUTS}")
        k = self.supersample
        if peel is not None and np.shape(peel) != (intr.height, intr.width):
            raise ValueError(f"peel depths must be {(intr.height, intr.width)}, got {np.shape(peel)}")
        if k == 1 or peel is not None:  # peeling compares each pixel with one depth: no sub-samples
            return self._render(scene, t_s, pose, intr, outputs, object_ids, peel)
        big = dataclasses.replace(intr, width=intr.width * k, height=intr.height * k)
        hi = self._render(scene, t_s, pose, big, outputs, object_ids)
        h, w = intr.height, intr.width
        out = RenderOutput(color=np.empty(0, np.uint8))
        if hi.color.size:
            c = hi.color.reshape(h, k, w, k, 3).astype(np.uint32).sum(axis=(1, 3))
            out.color = ((c + (k * k) // 2) // (k * k)).astype(np.uint8)
        for name in ("depth", "normal", "object_id", "triangle_id"):
            a = getattr(hi, name)
            if a is not None:
                setattr(out, name, np.ascontiguousarray(a[k // 2::k, k // 2::k]))
        return out

    def _render(self, scene: Scene, t_s: float, pose: Pose, intr: CameraIntrinsics,
                outputs: tuple[str, ...], object_ids: set[int] | None, peel: np.ndarray | None = None) -> RenderOutput:
        sg = self.upload(scene)
        colour = "color" in outputs
        prog = self.prog if colour else self.gbuffer_prog    # no colour asked: nothing is shaded
        if colour:
            self.bind_shading(prog, scene, t_s)
        self._bind_peel(prog, peel, intr)
        fbo, color, normal, ids, depth_lin, *_ = self._fbo(intr.width, intr.height)
        self._serial += 1
        fbo.use()
        self.ctx.viewport = (0, 0, intr.width, intr.height)
        fbo.clear(depth=1.0)
        self._background.prog["u_sky"].value = tuple(scene.sky_color)
        self._background.run()  # background values in every attachment (ids 0, depth inf)
        self._draw_objects(prog, sg, t_s, pose, intr, object_ids, colour)
        w, h = intr.width, intr.height
        out = RenderOutput(color=np.empty(0, np.uint8))
        if colour:
            out.color = np.frombuffer(fbo.read(components=3, attachment=0), np.uint8).reshape(h, w, 3)[::-1].copy()
        else:
            out.drawn = _Drawn(self._serial, scene, float(t_s), pose, intr, object_ids, peel)
        if "depth" in outputs:
            out.depth = np.frombuffer(depth_lin.read(), np.float32).reshape(h, w)[::-1].copy()
        if "normal" in outputs:
            out.normal = np.frombuffer(normal.read(), np.float16).reshape(h, w, 4)[::-1, :, :3].astype(np.float32)
        if "object_id" in outputs or "triangle_id" in outputs:
            idv = np.frombuffer(ids.read(), np.uint32).reshape(h, w, 2)[::-1]
            if "object_id" in outputs:
                out.object_id = idv[..., 0].copy()
            if "triangle_id" in outputs:
                out.triangle_id = idv[..., 1].copy()
        return out

    def _draw_objects(self, prog: Any, sg: SceneGPU, t_s: float, pose: Pose, intr: CameraIntrinsics,
                      object_ids: set[int] | None, materials: bool) -> None:
        """Draw the scene's objects (those in ``object_ids``) with ``prog`` into the bound framebuffer, depth-tested
        (the caller sets the test's function); ``materials``: bind each one's material (a shading program)."""
        self.ctx.enable(self.ctx.DEPTH_TEST)
        self.ctx.disable(self.ctx.CULL_FACE)
        prog["u_view"].write(np.asarray(pose.view_matrix(), "f4").T.tobytes())
        prog["u_proj"].write(np.asarray(intr.projection(), "f4").T.tobytes())
        set_uniform(prog, "u_eye", tuple(pose.position))
        for og in sg.objects:
            if object_ids is not None and og.obj.object_id not in object_ids:
                continue
            mats = self._matrices(og, t_s)
            if mats is None:    # a transform nothing sensible can be drawn with (a client's scene): skip the object
                continue
            prog["u_model"].write(mats[0])
            prog["u_normal_matrix"].write(mats[1])
            set_uniform(prog, "u_object_id", og.obj.object_id)
            set_uniform(prog, "u_primitive_base", og.tri_base)
            if materials:
                self.bind_material(prog, og)
            self._vao(og, prog).render()

    @staticmethod
    def _matrices(og: ObjectGPU, t_s: float) -> tuple[bytes, bytes] | None:
        """The model and normal matrices' uniform bytes of ``og`` at ``t_s`` (None: not drawable), kept while its
        model matrix stays the same (a static object's always: the inverse is not taken again every pass)."""
        model = np.asarray(og.obj.model_matrix(t_s))
        key = (model.dtype.str, model.shape, model.tobytes())
        if og.matrices[0] != key:
            nm = normal_matrix(model)
            og.matrices = (key, None if nm is None else (np.asarray(model, "f4").T.tobytes(),
                                                         np.asarray(nm, "f4").T.tobytes()))
        return og.matrices[1]

    def shade(self, g: RenderOutput, where: np.ndarray | None = None) -> np.ndarray:
        """The colour :meth:`render` gives with the G-buffer ``g`` (a render that asked for no colour, not
        supersampled), bit for bit, at the pixels ``where`` ((H, W) bool; every pixel by default).

        Only the surfaces ``g`` holds are shaded, each fragment once: ``g``'s depth buffer with an equal test (so a
        hidden fragment is not shaded, whatever the drawing order) and its triangle ids (a fragment of another
        triangle at the same quantised depth lost ``g``'s less-than test).  Pixels outside ``where`` are not shaded
        either: the depth buffer is set to the near plane there first.  Outside ``where`` the colour is the sky's on
        background pixels and black on the others.  ``g`` drawn over by a later render is drawn again first."""
        d = g.drawn
        if not isinstance(d, _Drawn):
            raise ValueError("Renderer.shade needs a render that asked for no colour and was not supersampled")
        w, h = d.intr.width, d.intr.height
        if where is not None and np.shape(where) != (h, w):
            raise ValueError(f"shade's where must be {(h, w)}, got {np.shape(where)}")
        prog = self.shade_prog
        sg = self.upload(d.scene)
        self.bind_shading(prog, d.scene, d.t_s)  # may draw (probes relit, shadow maps) before g's buffers are used
        if d.serial != self._serial:            # g's buffers were drawn over: draw them again
            self._render(d.scene, d.t_s, d.pose, d.intr, ("depth",), d.object_ids, d.peel)
        _, _, _, ids, _, shade_fbo, depth_fbo = self._fbo(w, h)
        if where is not None and not np.all(where):
            depth_fbo.use()
            self.ctx.viewport = (0, 0, w, h)
            self._depth_near_outside(where)
            self._serial += 1                   # the depth buffer is no longer g's
        shade_fbo.use()
        self.ctx.viewport = (0, 0, w, h)
        ids.use(location=DRAWN_IDS_UNIT)
        set_uniform(prog, "u_drawn_ids", DRAWN_IDS_UNIT)
        self.ctx.depth_func = "=="
        try:
            self._draw_objects(prog, sg, d.t_s, d.pose, d.intr, d.object_ids, True)
        finally:
            self.ctx.depth_func = "<"
        return np.frombuffer(shade_fbo.read(components=3, attachment=0), np.uint8).reshape(h, w, 3)[::-1].copy()

    def _depth_near_outside(self, where: np.ndarray) -> None:
        """Set the bound framebuffer's depth buffer (it has no colour) to the near plane (0) where ``where`` is false
        (row 0 at the top), leaving the rest: an equal test drawn after it then fails early there, before any
        shading."""
        if self._where_pass is None:
            self._where_pass = FullscreenPass(self.ctx, SHADER_DIR / "depth_where.frag")
        self._where_tex = upload_image(self.ctx, np.ascontiguousarray(np.asarray(where, np.uint8)[::-1]) * np.uint8(255),
                                       self._where_tex, linear=False)
        self._where_tex.use(location=DRAWN_IDS_UNIT + 1)
        self._where_pass.prog["u_where"].value = DRAWN_IDS_UNIT + 1
        self.ctx.enable(self.ctx.DEPTH_TEST)
        self.ctx.depth_func = "1"       # always: the pass writes its depth
        try:
            self._where_pass.vao.render(mode=self.ctx.TRIANGLES, vertices=3)
        finally:
            self.ctx.depth_func = "<"


def make_pose_looking(eye: tuple[float, float, float], target: tuple[float, float, float]) -> Pose:
    return Pose(np.array(eye, float), look_at_quat(np.array(eye, float), np.array(target, float)))

