"""DDGI light probes (Majercik et al. 2019): a grid of probes that hold irradiance and distance moments.

The scene-level global illumination every method's shading shares when a scene sets
``gi = "ddgi"`` (``render/shaders/ddgi.glsl`` reads the probes in place of the constant
ambient term).  Everything here is deterministic: a still scene gives bit-identical
probes at every update.

**Tracing by rasterisation.**  A GPU ray tracer is not available on llvmpipe; each probe
sees the scene instead through a cube of six ``face_res`` x ``face_res`` faces, whose
pixel centres are its fixed ray set (6 x 8^2 = 384 rays by default; the paper uses 256
random rays per update).  6 x 16^2 = 1536 rays cost twice the run time with GI on the
default walk (13.4 s against 7.5 s for 1 s of ``video``; 3.8 s without GI) and change
the ground truth by little: 50.5-54.1 dB between the two on the walk, where GI itself
moves the image by 32-39 dB.  The cube faces of every probe are rasterised once per scene into a
G-buffer atlas (what each ray hits: position, normal, back-face flag, diffuse colour,
emission).  An update relights that atlas in one full-screen pass: the sun with the
scene's shadow maps at the update's time, the point lights, and the previous bounce's
probes; rays that miss see the sky, whose radiance is the scene's ``ambient`` colour (so
an open surface facing up receives the same light as without GI).  ``bounces`` passes
give that many bounces of indirect light.  The radiance then becomes

- irradiance ``E(n) = sum max(0, n . w) L(w) dOmega`` in an 8 x 8 octahedral map, and
- the mean distance and mean squared distance to what the rays hit, weighted by
  ``max(0, n . w)^50`` as DDGI does, in a 16 x 16 map,

each with a one-texel guard band (10 x 10 and 18 x 18 tiles; paper: 3.125 kbit and
10.125 kbit per probe at 32 bits a texel).

**Moving objects.**  The static objects are captured once; the moving ones are redrawn
at each update's time into a G-buffer of their own, only into the probe faces their
bounding spheres reach and only for probes near enough to see them across a ray's
spacing or more (:data:`MOVING_MIN_RAYS`), and merged over the static one ray by ray
(the nearer hit wins).  So they bounce light and block the probes' view where they are, and the
visibility moments (and which probes are active) follow them.  Probes with more than a
quarter of their rays on back faces sit inside geometry and are inactive (DDGI's
classification).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..scene.digest import scene_digest
from .canvas import FullscreenPass
from .gl import SHADER_DIR, load_program, set_uniform
from .octa import CUBE_FACES, add_guard, cube_directions, irradiance_weights, texel_directions, visibility_weights

IRR_CORE = 8
VIS_CORE = 16
IRR_TILE = IRR_CORE + 2
VIS_TILE = VIS_CORE + 2
BITS_PER_TEXEL = 32
"""The paper's texel formats: A2RGB10 irradiance, RG16F visibility."""
GI_UNITS = (12, 13)
"""Texture units of the irradiance and visibility atlases in every program that includes ``shading.glsl``."""
NEAR_M = 0.02
SHARPNESS = 50.0
BACKFACE_INACTIVE = 0.25
GL_CLIP_DISTANCE0 = 0x3000
VIS_WEIGHT_FLOOR = float(np.finfo(np.float32).tiny) * 2.0 ** 24
"""Visibility weights below this (2e-31; 5,680 of the 43,024 non-zero ones at the default 8 x 8 faces, each row
summing to 1) are dropped: a weight just above float32's smallest normal times a ray's distance (0.004-1 m near
a probe) or its square made subnormal products, whose microcode assists took the moments of the default scene's
256 probes 30.9 ms of CPU an update where they take 12.6 without.  What they add (< 1e-28 m^2 a texel) is below
half an ulp of the moments: the same bits (``tests/test_gi_weights.py``)."""
RELIGHT_HALVES = True
"""A recurrent update (live: ``Renderer.gi_hz`` > 0) whose lights are as the last update's relights the probes of
every second row of the probe atlas (spread over the whole volume), the even rows and the odd ones alternately:
each probe is relit, its moving objects redrawn and its visibility derived every second update, at that update's
time (late, not wrong: a live server relights at its own rate, ``Renderer.gi_hz``).  A change of a light's
intensity, colour or direction, the first update and virtual time (not recurrent) relight them all."""
MOVING_MIN_RAYS = 2.0
"""A moving object is redrawn only for the probes that see its bounding sphere at least this many ray spacings
across: farther probes would see it in a ray or two at most, and drawing it for them is most of the cost
(measured on the default scene: 157 ms a update for every probe, 71 ms with this bound)."""


@dataclass(frozen=True)
class DdgiSettings:
    """``counts`` probes along x, y, z over the scene's bounds (paper: 16x8x16 and up);
    ``face_res`` cube-face pixels (rays: ``6 face_res^2``; 8 by default, see the module
    docstring); ``bounces`` of indirect light;
    ``bias`` metres along the normal and the view before the lookup."""

    counts: tuple[int, int, int] = (8, 4, 8)
    face_res: int = 8
    bounces: int = 2
    bias: float = 0.1

    def __post_init__(self) -> None:
        if len(self.counts) != 3 or not all(2 <= int(c) <= 64 for c in self.counts):
            raise ValueError(f"ddgi counts: each of the three must be in [2, 64], got {self.counts}")
        if not 4 <= self.face_res <= 64:
            raise ValueError(f"ddgi face_res: must be in [4, 64], got {self.face_res}")
        if not 1 <= self.bounces <= 8:
            raise ValueError(f"ddgi bounces: must be in [1, 8], got {self.bounces}")


class ProbeStates:
    """Relit probe states shared by every volume of one renderer, keyed by the scene's content and the state.

    A demo or a sweep builds its scene anew for every run, and every run relights the
    probes at the same server and display times: what a volume relit for one scene
    object serves every volume built alike.  A state is what the shading and the
    ``probes`` server read: the irradiance, the distance moments and the active flags
    (float32, bit for bit what relighting gives: the probes are deterministic).  At most
    ``capacity`` states are kept, the least recently used dropped (about 0.7 MB each for
    the default 8x4x8 probes).  ``enabled = False`` relights every state anew: the
    virtual-time runner turns reuse off under ``cost_model = "measured"``, where the
    server's wall-clock milliseconds go on the simulated clock and must not depend on
    what an earlier run left here.
    """

    def __init__(self, capacity: int = 64) -> None:
        self.capacity = int(capacity)
        self.enabled = True
        self.hits = 0
        self.misses = 0
        self._states: OrderedDict[Any, tuple[np.ndarray, np.ndarray, np.ndarray]] = OrderedDict()

    def get(self, key: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        if not self.enabled:
            return None
        state = self._states.get(key)
        if state is None:
            self.misses += 1
            return None
        self._states.move_to_end(key)
        self.hits += 1
        return state

    def put(self, key: Any, irradiance: np.ndarray, moments: np.ndarray, active: np.ndarray) -> None:
        if not self.enabled or self.capacity <= 0:
            return
        arrays = tuple(np.array(a, copy=True) for a in (irradiance, moments, active))
        for a in arrays:
            a.flags.writeable = False
        self._states[key] = arrays  # type: ignore[assignment]
        self._states.move_to_end(key)
        while len(self._states) > self.capacity:
            self._states.popitem(last=False)

    def __len__(self) -> int:
        return len(self._states)


def gi_time(t_s: float, hz: float) -> float:
    """The newest probe update time at or before ``t_s`` on the ``hz`` grid (``hz`` <= 0: ``t_s`` itself)."""
    if hz <= 0:
        return t_s
    return math.floor(t_s * hz + 1e-9) / hz


def flush_subnormal(w: np.ndarray, floor: float | None = None) -> np.ndarray:
    """``w`` with its entries below ``floor`` in magnitude (default: float32's smallest normal) set to 0.  The
    visibility weights' cosine power leaves a few per cent of them below float32's smallest normal; the CPU
    multiplies those through microcode assists, so the 256 x 384 x 256 visibility product took 38 ms where it
    takes 1.8 flushed (one BLAS thread, x86-64).  Their products (< 1e-37 each) are below half an ulp of any sum
    of the normal ones: the probes come out the same bits (hashed over 8 relights of the default scene, and a
    walk's video, sas and tss runs the same).  A normal weight times a distance under a metre can still make a
    subnormal product: :data:`VIS_WEIGHT_FLOOR`."""
    w = np.array(w, copy=True)
    w[np.abs(w) < (np.finfo(w.dtype).tiny if floor is None else floor)] = 0
    return w


def probe_grid(lo: np.ndarray, hi: np.ndarray, counts: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(origin, spacing): probe ``(i, j, k)`` sits at ``origin + (i, j, k) * spacing``, the centres of a
    ``counts`` grid of cells over the box ``lo``..``hi``."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    spacing = np.maximum(hi - lo, 1e-3) / np.asarray(counts, np.float64)
    return lo + spacing / 2.0, spacing


def face_view(eye: np.ndarray, face: int) -> np.ndarray:
    """4x4 view matrix of cube face ``face`` (:data:`~.octa.CUBE_FACES`) of a probe at ``eye``."""
    f, up = (np.asarray(v, np.float64) for v in CUBE_FACES[face])
    r = np.cross(f, up)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = r, up, -f
    m[:3, 3] = -m[:3, :3] @ np.asarray(eye, np.float64)
    return m


def face_projection(far: float) -> np.ndarray:
    """90-degree square perspective from :data:`NEAR_M` to ``far``."""
    n = NEAR_M
    p = np.zeros((4, 4))
    p[0, 0] = p[1, 1] = 1.0
    p[2, 2] = -(far + n) / (far - n)
    p[2, 3] = -2.0 * far * n / (far - n)
    p[3, 2] = -1.0
    return p


def bind_probes(prog: Any, irr_tex: Any, vis_tex: Any, origin: np.ndarray, spacing: np.ndarray,
                counts: tuple[int, int, int], cols: int, bias: float) -> None:
    """Set the probe uniforms and textures of ``ddgi.glsl`` on ``prog`` (``u_gi`` is left to the caller)."""
    irr_tex.use(location=GI_UNITS[0])
    vis_tex.use(location=GI_UNITS[1])
    set_uniform(prog, "u_gi_irr", GI_UNITS[0])
    set_uniform(prog, "u_gi_vis", GI_UNITS[1])
    set_uniform(prog, "u_gi_origin", tuple(float(x) for x in origin))
    set_uniform(prog, "u_gi_spacing", tuple(float(x) for x in spacing))
    set_uniform(prog, "u_gi_counts", tuple(int(c) for c in counts))
    set_uniform(prog, "u_gi_cols", int(cols))
    set_uniform(prog, "u_gi_irr_core", IRR_CORE)
    set_uniform(prog, "u_gi_vis_core", VIS_CORE)
    set_uniform(prog, "u_gi_bias", float(bias))


def slot_grid(count: int) -> tuple[int, int]:
    """(cols, rows) of the slot grid that holds ``count`` probes' tiles, row-major (as square as it gets)."""
    cols = int(math.ceil(math.sqrt(count)))
    return cols, int(math.ceil(count / cols))


def probe_atlas(tiles: np.ndarray, size: int) -> np.ndarray:
    """(rows * size, cols * size, C) picture of per-probe tiles (count, size, size, C) in their slots
    (:func:`slot_grid`), in the tiles' dtype."""
    count, C = tiles.shape[0], tiles.shape[-1]
    cols, rows = slot_grid(count)
    out = np.zeros((rows * cols, size, size, C), tiles.dtype)
    out[:count] = tiles
    return out.reshape(rows, cols, size, size, C).transpose(0, 2, 1, 3, 4).reshape(rows * size, cols * size, C)


def atlas_tiles(img: np.ndarray, count: int, size: int) -> np.ndarray:
    """Inverse of :func:`probe_atlas`: (count, size, size, C) tiles of a picture."""
    cols, rows = slot_grid(count)
    C = img.shape[-1]
    return img.reshape(rows, size, cols, size, C).transpose(0, 2, 1, 3, 4).reshape(rows * cols, size, size, C)[:count]


def irradiance_atlas(irradiance: np.ndarray, active: np.ndarray) -> np.ndarray:
    """The float32 irradiance texture: each probe's (8 x 8) RGB, alpha 1 where the probe is active, guard bands."""
    n = active.size
    alpha = np.broadcast_to(active.astype(np.float32)[:, None, None, None], (n, IRR_CORE, IRR_CORE, 1))
    core = np.concatenate([np.asarray(irradiance, np.float32).reshape(n, IRR_CORE, IRR_CORE, 3), alpha], -1)
    return probe_atlas(add_guard(core), IRR_TILE)


class ProbeCopy:
    """A client's copy of the probes: what it received, with the guard bands rebuilt, in the textures the shading
    reads (register it in ``Renderer.gi_sources`` for its scene).  A probe never received is inactive."""

    def __init__(self, ctx: Any, origin: np.ndarray, spacing: np.ndarray, counts: tuple[int, int, int], bias: float) -> None:
        self.origin, self.spacing = np.asarray(origin, np.float64), np.asarray(spacing, np.float64)
        self.counts = tuple(int(c) for c in counts)
        self.count = int(np.prod(self.counts))
        self.cols, self.rows = slot_grid(self.count)
        self.bias = float(bias)
        self.irradiance = np.zeros((self.count, IRR_CORE, IRR_CORE, 3), np.float32)
        self.moments = np.zeros((self.count, VIS_CORE, VIS_CORE, 2), np.float32)
        self.received = np.zeros(self.count, bool)
        self.irr_tex = ctx.texture((self.cols * IRR_TILE, self.rows * IRR_TILE), 4, dtype="f4")
        self.vis_tex = ctx.texture((self.cols * VIS_TILE, self.rows * VIS_TILE), 2, dtype="f4")
        self._upload()

    def scatter(self, ids: np.ndarray, irradiance: np.ndarray | None, moments: np.ndarray | None) -> None:
        """Take probes ``ids``' core texels (n, 8, 8, 3) and (n, 16, 16, 2) and rebuild the textures (None: that
        half of those probes is unchanged)."""
        if irradiance is not None:
            self.irradiance[ids] = irradiance
            self.received[ids] = True
        if moments is not None:
            self.moments[ids] = moments
        self._upload()

    def _upload(self) -> None:
        self.irr_tex.write(irradiance_atlas(self.irradiance, self.received).tobytes())
        self.vis_tex.write(probe_atlas(add_guard(self.moments), VIS_TILE).tobytes())

    def bind(self, prog: Any) -> None:
        bind_probes(prog, self.irr_tex, self.vis_tex, self.origin, self.spacing, self.counts, self.cols, self.bias)  # type: ignore[arg-type]


class DdgiVolume:
    """The probes of one scene on one renderer: static geometry captured once, moving objects redrawn and
    everything relit per update."""

    def __init__(self, renderer: Any, scene: Any, settings: DdgiSettings | None = None,
                 states: ProbeStates | None = None) -> None:
        self.renderer, self.scene = renderer, scene
        self.settings = s = settings or DdgiSettings()
        self.states = states
        self._content = (scene_digest(scene), s) if states is not None else None
        lo, hi = (np.asarray(v, np.float64) for v in scene.bounds())
        self.origin, self.spacing = probe_grid(lo, hi, s.counts)
        cx, cy, cz = s.counts
        self.count = cx * cy * cz
        k, j, i = np.meshgrid(np.arange(cz), np.arange(cy), np.arange(cx), indexing="ij")
        self.positions = self.origin + np.stack([i, j, k], -1).reshape(-1, 3) * self.spacing   # probe = i + cx (j + cy k)
        self.cols, self.rows = slot_grid(self.count)
        F = s.face_res
        self.tile = (6 * F, F)
        self.far = float(np.linalg.norm(hi - lo)) * 1.5 + 1.0
        self.max_distance = float(np.linalg.norm(self.spacing)) * 2.0
        dirs, omega = cube_directions(F)
        self._w_irr = flush_subnormal(irradiance_weights(texel_directions(IRR_CORE), dirs, omega).astype(np.float32))
        self._w_vis = flush_subnormal(visibility_weights(texel_directions(VIS_CORE), dirs, omega, SHARPNESS).astype(np.float32),
                                      VIS_WEIGHT_FLOOR)
        ctx = renderer.ctx
        self.ctx = ctx
        W, H = self.cols * self.tile[0], self.rows * self.tile[1]
        self._cap = [ctx.texture((W, H), 4, dtype=dt) for dt in ("f4", "f2", "f2", "f2")]
        for t in self._cap:
            t.filter = (ctx.NEAREST, ctx.NEAREST)
        self._rad = ctx.texture((W, H), 4, dtype="f4")
        self._rad_fbo = ctx.framebuffer([self._rad])
        self.irr_tex = ctx.texture((self.cols * IRR_TILE, self.rows * IRR_TILE), 4, dtype="f4")
        self.vis_tex = ctx.texture((self.cols * VIS_TILE, self.rows * VIS_TILE), 2, dtype="f4")
        self.active = np.ones(self.count, bool)
        self.irradiance = np.zeros((self.count, IRR_CORE * IRR_CORE, 3), np.float32)
        self.moments = np.zeros((self.count, VIS_CORE * VIS_CORE, 2), np.float32)
        self.updates = 0
        self.reused = 0
        self.updating = False
        self.recurrent = False
        """One bounce per update, reading the probes the update before left (the DDGI paper's recurrence: the
        bounces accumulate over updates), instead of every bounce from scratch.  A live server relighting at a GI rate
        sets it (``Renderer.gi_hz`` > 0: half the relight passes); virtual time and the ground truth never do."""
        self._key: Any = None
        self._half = 0
        self._capture()
        self._relight = FullscreenPass(ctx, SHADER_DIR / "gi_relight.frag")

    # ------------------------------------------------------------------ capture
    def _per_ray(self, img: np.ndarray, probes: np.ndarray | None = None) -> np.ndarray:
        """(count, 6 F^2, C) per-probe rays of an atlas image (H, W, C) laid out as the capture tiles; with ``probes``
        (indices), only theirs."""
        F = self.settings.face_res
        C = img.shape[-1]
        t = img.reshape(self.rows, F, self.cols, 6, F, C).transpose(0, 2, 3, 1, 4, 5)   # (row, col, face, y, x, C)
        if probes is not None:
            r, c = np.divmod(np.asarray(probes, np.int64), self.cols)
            return t[r, c].reshape(r.size, 6 * F * F, C)
        return t.reshape(self.rows * self.cols, 6 * F * F, C)[: self.count]

    def _capture(self) -> None:
        """The static objects' G-buffer, once; with moving objects, also kept in numpy for :meth:`_capture_moving`."""
        r, ctx, scene = self.renderer, self.ctx, self.scene
        sg = r.upload(scene)
        self._prog = prog = load_program(ctx, SHADER_DIR / "gi_capture.vert", SHADER_DIR / "gi_capture.frag")
        r.bind_shading(prog, scene, 0.0)          # (renders the shadow maps: before our framebuffer is bound)
        F = self.settings.face_res
        W, H = self._cap[0].size
        prog["u_proj"].write(np.asarray(face_projection(self.far), "f4").T.tobytes())
        prog["u_face_rot"].write(np.stack([face_view(np.zeros(3), f)[:3, :3].T for f in range(6)]).astype("f4").tobytes())
        set_uniform(prog, "u_face_res", F)
        set_uniform(prog, "u_cols", self.cols)
        set_uniform(prog, "u_atlas", (float(W), float(H)))
        planes = []                                         # (6, 4, 3) inward side-plane normals per face
        for f, up in CUBE_FACES:
            f_, u_ = np.asarray(f, np.float64), np.asarray(up, np.float64)
            r_ = np.cross(f_, u_)
            planes.append([(f_ + r_), (f_ - r_), (f_ + u_), (f_ - u_)])
        self._planes = np.asarray(planes) / math.sqrt(2.0)
        inst = np.zeros(self.count * 6, [("eye", "<f4", 3), ("pf", "<i4")])
        inst["eye"] = np.repeat(self.positions, 6, axis=0)
        inst["pf"] = np.arange(self.count * 6)
        self._inst_all = inst
        self._inst = ctx.buffer(reserve=inst.nbytes)
        self._vaos = {og.obj.object_id: ctx.vertex_array(prog, [(og.vbo, "3f 3f 2f", "in_position", "in_normal", "in_uv"),
                                                                (og.tbo, "4f", "in_tangent"), (self._inst, "3f 1i/i", "i_eye", "i_pf")],
                                                         og.ibo, skip_errors=True)
                      for og in sg.objects}
        self._moving = [og for og in sg.objects if og.obj.dynamic]
        zbuf = ctx.depth_renderbuffer(self._cap[0].size)
        fbo = ctx.framebuffer(self._cap, zbuf)
        self._draw([og for og in sg.objects if not og.obj.dynamic], 0.0, fbo)
        self._static = self._read(self._cap)
        if self._moving:                              # a G-buffer of its own for the moving objects, redrawn per update
            W, H = self._cap[0].size
            self._mov = [ctx.texture((W, H), 4, dtype=dt) for dt in ("f4", "f2", "f2", "f2")]
            self._mov_fbo = ctx.framebuffer(self._mov, ctx.depth_renderbuffer((W, H)))
            eye = np.repeat(self.positions, 6 * F * F, axis=0).reshape(self.count, 6, F, F, 3)
            pad = np.zeros((self.rows * self.cols - self.count, 6, F, F, 3))
            self._eye = np.concatenate([eye, pad]).reshape(self.rows, self.cols, 6, F, F, 3).transpose(0, 3, 1, 2, 4, 5) \
                .reshape(H, W, 3).astype(np.float32)                                  # each texel's probe
            self._d_static = np.where(self._static[0][..., 3] > 0.5,
                                      np.linalg.norm(self._static[0][..., :3] - self._eye, axis=-1), np.inf)
        else:
            self._static = None            # nothing to merge: drop the copy
        self._derive(*self._read(self._cap)[:2])
        self._rad_fbo.use()                      # not the framebuffer about to be released
        fbo.release()
        zbuf.release()

    def _draw(self, objects: list[Any], t_s: float, fbo: Any, min_rays: float = 0.0, probes: np.ndarray | None = None) -> None:
        """Draw ``objects`` at ``t_s`` into every probe face of ``fbo`` that their bounding spheres reach and, with
        ``min_rays`` > 0, only for probes that see the sphere at least that many ray spacings across; with ``probes``
        ((count,) bool), only for those."""
        r, ctx, prog = self.renderer, self.ctx, self._prog
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.CULL_FACE)
        ctx.viewport = (0, 0, *fbo.size)
        ctx.enable_direct(GL_CLIP_DISTANCE0)
        for k in range(1, 4):
            ctx.enable_direct(GL_CLIP_DISTANCE0 + k)
        try:
            # object by object (one material binding, one instanced draw each): every probe face that the object's
            # bounding sphere reaches (the four side planes of the 90-degree face frustum); depth sorts out the rest
            for og in objects:
                model = og.obj.model_matrix(t_s)
                wp = og.obj.mesh.positions.astype(np.float64) @ model[:3, :3].T + model[:3, 3]
                centre = (wp.min(axis=0) + wp.max(axis=0)) / 2.0
                radius = float(np.linalg.norm(wp.max(axis=0) - wp.min(axis=0))) / 2.0 + 1e-3
                rel = centre[None, :] - self.positions                                            # (count, 3)
                dist = np.einsum("pc,fkc->pfk", rel, self._planes)                                  # (count, 6, 4)
                near = np.linalg.norm(rel, axis=1)
                seen = (dist >= -radius).all(axis=2) | (near <= radius)[:, None]
                if min_rays > 0:        # the sphere's diameter spans min_rays ray spacings ((pi / 2) / face_res) or more
                    seen &= (2.0 * radius * self.settings.face_res >= near * min_rays * (math.pi / 2.0))[:, None]
                if probes is not None:
                    seen &= probes[:, None]
                inst = self._inst_all[seen.reshape(-1)]
                if not inst.size:
                    continue
                prog["u_model"].write(np.asarray(model, "f4").T.tobytes())
                prog["u_normal_matrix"].write(np.asarray(np.linalg.inv(model[:3, :3]).T, "f4").T.tobytes())
                r.bind_material(prog, og)
                self._inst.write(inst.tobytes())
                self._vaos[og.obj.object_id].render(instances=int(inst.size))
        finally:
            for k in range(4):
                ctx.disable_direct(GL_CLIP_DISTANCE0 + k)

    def _read(self, textures: list[Any]) -> list[np.ndarray]:
        W, H = textures[0].size
        return [np.frombuffer(t.read(), np.float32 if i == 0 else np.float16).reshape(H, W, 4) for i, t in enumerate(textures)]

    def _capture_moving(self, t_s: float, half: int | None = None) -> None:
        """Redraw the moving objects at ``t_s`` and merge them over the static G-buffer (nearer hit wins): their
        bounce and their occlusion reach the probes, and the visibility moments follow them.  ``half``
        (:data:`RELIGHT_HALVES`): only for the probes of that half; the others keep their active flags and moments
        (their G-buffer rows are left static, which only their own relight reads)."""
        assert self._static is not None
        ids = self._half_ids(half) if half is not None else None
        mask = None
        if ids is not None:
            mask = np.zeros(self.count, bool)
            mask[ids] = True
        self._draw(self._moving, t_s, self._mov_fbo, min_rays=MOVING_MIN_RAYS, probes=mask)
        mov = self._read(self._mov)
        hit = np.nonzero(mov[0][..., 3] > 0.5)
        d = np.linalg.norm(mov[0][hit][:, :3] - self._eye[hit], axis=-1)
        near = d < self._d_static[hit]
        take = (hit[0][near], hit[1][near])
        merged = []
        for m, st in zip(mov, self._static):
            a = st.copy()
            a[take] = m[take]
            merged.append(a)
        for tex, a in zip(self._cap, merged):
            tex.write(np.ascontiguousarray(a).tobytes())
        self._derive(merged[0], merged[1], ids)

    def _half_ids(self, half: int) -> np.ndarray:
        """The probes of half ``half`` (0 or 1) of :data:`RELIGHT_HALVES`: those in the even or odd rows of the atlas."""
        return np.flatnonzero((np.arange(self.count) // self.cols) % 2 == half)

    def _derive(self, pos: np.ndarray, nrm: np.ndarray, ids: np.ndarray | None = None) -> None:
        """Active flags and visibility moments from the G-buffer's positions and normals; with ``ids``, of those probes
        only (:data:`RELIGHT_HALVES`: the same steps on their rows), the others' flags and moments as they are."""
        sel = slice(None) if ids is None else ids
        hit = self._per_ray(pos[..., 3:4], ids)[..., 0] > 0.5
        back = self._per_ray(nrm[..., 3:4], ids)[..., 0] > 0.5
        active = (back & hit).mean(axis=1) <= BACKFACE_INACTIVE
        dist = np.linalg.norm(self._per_ray(pos[..., :3], ids) - self.positions[sel][:, None, :], axis=-1)
        dist = np.where(hit, np.minimum(dist, self.max_distance), self.max_distance)
        dist = np.where(back & hit, dist * 0.2, dist)          # DDGI: back faces pull the distance in
        d = dist.astype(np.float32)
        moments = np.stack([d @ self._w_vis.T, (d * d) @ self._w_vis.T], axis=-1).astype(np.float32)   # (n, VIS^2, 2)
        if ids is None:
            self.active, self.moments = active, moments
        else:       # new arrays: the old ones may be held by the shared state cache
            self.active, self.moments = self.active.copy(), np.array(self.moments, copy=True)
            self.active[ids], self.moments[ids] = active, moments
        self._write_visibility()

    def _write_visibility(self) -> None:
        vis = add_guard(self.moments.reshape(self.count, VIS_CORE, VIS_CORE, 2))
        self.vis_tex.write(probe_atlas(vis, VIS_TILE).tobytes())

    # ------------------------------------------------------------------ relight (per update)
    def bind(self, prog: Any) -> None:
        """Set the probe uniforms and textures of ``ddgi.glsl`` on ``prog`` (``u_gi`` left to the caller)."""
        bind_probes(prog, self.irr_tex, self.vis_tex, self.origin, self.spacing, self.settings.counts, self.cols,
                    self.settings.bias)

    def state_key(self, t_s: float) -> tuple[Any, ...]:
        """What the probes at ``t_s`` depend on: the lights and the sky and, with moving objects, the time."""
        sc = self.scene
        sun = (float(sc.sun.intensity.value(t_s)), tuple(sc.sun.direction), tuple(sc.sun.color)) if sc.sun is not None else None
        pts = tuple((float(pl.intensity.value(t_s)), tuple(pl.position), tuple(pl.color), pl.range_m) for pl in sc.point_lights)
        return (sun, pts, tuple(sc.ambient), float(t_s) if sc.dynamic_ids() else None)

    def update(self, t_s: float) -> bool:
        """Relight the probes for time ``t_s`` unless they already hold that state; True when they were relit."""
        key = self.state_key(t_s)
        if key == self._key:
            return False
        shared = self.states.get((self._content, key)) if self.states is not None else None
        if shared is not None:       # relit before, for this volume or another built alike
            self.irradiance, self.moments, self.active = shared
            self.irr_tex.write(irradiance_atlas(self.irradiance, self.active).tobytes())
            self._write_visibility()
            self._key = key
            self.reused += 1
            return True
        prev_fbo, prev_viewport = self.ctx.fbo, self.ctx.viewport
        self.updating = True
        try:
            recurrent = self.recurrent and self._key is not None
            # a live update whose lights are as the last one's relights half the probes (their atlas rows alternately)
            half = self._half if RELIGHT_HALVES and recurrent and key[:3] == self._key[:3] else None
            if self._moving:
                self._capture_moving(t_s, half)
            self._relight_all(t_s, recurrent, half)
            self._half = 1 - self._half if half is not None else self._half
        finally:
            self.updating = False
            prev_fbo.use()
            self.ctx.viewport = prev_viewport
        recurred = self.recurrent and self._key is not None
        self._key = key
        self.updates += 1
        if self.states is not None and not recurred:    # a recurrent state is not the key's from scratch
            self.states.put((self._content, key), self.irradiance, self.moments, self.active)
        return True

    def _relight_all(self, t_s: float, recurrent: bool = False, half: int | None = None) -> None:
        """Relight the probes: ``bounces`` passes, each later bounce reading the textures the one before wrote
        (``recurrent``: only the last bounce, reading what the last update left).  ``half`` (0 or 1; recurrent only):
        only the probes in the even or odd rows of the atlas (:data:`RELIGHT_HALVES`), the others keep their
        irradiance."""
        r, ctx = self.renderer, self.ctx
        prog = self._relight.prog
        r.bind_shading(prog, self.scene, t_s)
        self.bind(prog)
        set_uniform(prog, "u_gi", 1)
        for unit, (name, tex) in enumerate(zip(("u_cap_pos", "u_cap_nrm", "u_cap_diff", "u_cap_emit"), self._cap), start=8):
            tex.use(location=unit)
            set_uniform(prog, name, unit)
        set_uniform(prog, "u_tile", self.tile)
        set_uniform(prog, "u_tiles_per_row", self.cols)
        set_uniform(prog, "u_sky", tuple(float(c) for c in self.scene.ambient))
        self._rad_fbo.use()
        ctx.viewport = (0, 0, *self._rad.size)
        W, H = self._rad.size
        F = self.settings.face_res
        for b in ([self.settings.bounces - 1] if recurrent else range(self.settings.bounces)):
            set_uniform(prog, "u_bounce", b)
            if half is None:
                self._relight.run()
                rad = np.frombuffer(self._rad.read(), np.float32).reshape(H, W, 4)[..., :3]
                L = np.ascontiguousarray(self._per_ray(rad))                          # (count, rays, 3)
                self.irradiance = np.ascontiguousarray(np.matmul(self._w_irr, L))           # (count, texels, 3), BLAS
            else:
                for row in range(half, self.rows, 2):
                    ctx.scissor = (0, row * F, W, F)
                    self._relight.run()
                ctx.scissor = None
                rad = np.frombuffer(self._rad.read(), np.float32).reshape(H, W, 4)[..., :3]
                ids = self._half_ids(half)
                irr = np.array(self.irradiance, copy=True)
                irr[ids] = np.matmul(self._w_irr, self._per_ray(rad, ids))
                self.irradiance = irr
            self.irradiance[~self.active] = 0.0
            self.irr_tex.write(irradiance_atlas(self.irradiance, self.active).tobytes())

    def textures(self) -> tuple[np.ndarray, np.ndarray]:
        """The irradiance (RGB + active) and visibility atlases as the shaders read them, float32."""
        W, H = self.irr_tex.size
        irr = np.frombuffer(self.irr_tex.read(), np.float32).reshape(H, W, 4)
        W2, H2 = self.vis_tex.size
        vis = np.frombuffer(self.vis_tex.read(), np.float32).reshape(H2, W2, 2)
        return irr, vis
