"""The scene model: meshes, materials, rigid objects animated over time, lights.

Everything is plain numpy so that the server's renderer, the method halves that
need geometry (SAS, TSS, probes) and tests can share it.  Units: metres, seconds,
radians; matrices are 4x4 float64 (column vectors), object-to-world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .pose import quat_from_axis_angle, quat_to_matrix3


@dataclass(frozen=True)
class Schedule:
    """A piecewise-linear scalar over time: ``value(t)`` interpolates ``(times_s, values)``.

    Outside the keyframes the ends are held.  A single value is a constant.
    """

    times_s: tuple[float, ...] = (0.0,)
    values: tuple[float, ...] = (1.0,)

    def value(self, t_s: float) -> float:
        if len(self.values) == 1:
            return float(self.values[0])
        return float(np.interp(t_s, self.times_s, self.values))

    @staticmethod
    def constant(v: float) -> "Schedule":
        return Schedule((0.0,), (float(v),))


SHADING_MODELS = ("pbr", "phong")


@dataclass
class Material:
    """A glTF 2.0 metallic-roughness material (also read by the older Blinn-Phong model).

    Colours are linear RGB in 0..1.  Textures are (H, W, 3) uint8 with row 0 at ``uv.y = 0``
    (glTF's top-left origin): ``texture`` (base colour) and ``emissive_texture`` are sRGB;
    ``metallic_roughness_texture`` (G = roughness, B = metallic), ``normal_texture``
    (tangent space, +Y towards decreasing ``v``) and ``occlusion_texture`` (R) are linear.
    ``uv_transform`` is a 3x3 matrix applied to the texture coordinates of every map
    (``KHR_texture_transform``; identity when the file has none).  ``specular`` and
    ``shininess`` are the Blinn-Phong model's (``Scene.shading = "phong"``), which ignores
    everything but the base colour.
    """

    name: str = "default"
    base_color: tuple[float, float, float] = (0.8, 0.8, 0.8)
    texture: np.ndarray | None = None
    specular: float = 0.2
    shininess: float = 32.0
    metallic: float = 0.0
    roughness: float = 0.6
    metallic_roughness_texture: np.ndarray | None = None
    normal_texture: np.ndarray | None = None
    normal_scale: float = 1.0
    occlusion_texture: np.ndarray | None = None
    occlusion_strength: float = 1.0
    emissive: tuple[float, float, float] = (0.0, 0.0, 0.0)
    emissive_texture: np.ndarray | None = None
    uv_transform: np.ndarray | None = None


@dataclass
class Mesh:
    """Indexed triangle mesh.  ``positions``/``normals`` (N,3) float32, ``uvs`` (N,2), ``indices`` (M,3) uint32."""

    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    indices: np.ndarray
    name: str = "mesh"
    tangents: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.positions = np.ascontiguousarray(self.positions, dtype=np.float32).reshape(-1, 3)
        self.normals = np.ascontiguousarray(self.normals, dtype=np.float32).reshape(-1, 3)
        self.uvs = np.ascontiguousarray(self.uvs, dtype=np.float32).reshape(-1, 2)
        self.indices = np.ascontiguousarray(self.indices, dtype=np.uint32).reshape(-1, 3)
        if self.tangents is not None:
            self.tangents = np.ascontiguousarray(self.tangents, dtype=np.float32).reshape(-1, 4)

    def tangent_frame(self) -> np.ndarray:
        """(N, 4) float32 tangents (xyz, handedness w = +-1): the file's, else generated from
        the UVs (:func:`generate_tangents`, computed once)."""
        if self.tangents is None or len(self.tangents) != self.vertex_count:
            self.tangents = generate_tangents(self.positions, self.normals, self.uvs, self.indices)
        return self.tangents

    @property
    def triangle_count(self) -> int:
        return int(self.indices.shape[0])

    @property
    def vertex_count(self) -> int:
        return int(self.positions.shape[0])

    def triangle_areas(self) -> np.ndarray:
        """Object-space area of each triangle, m^2."""
        p = self.positions[self.indices]
        return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.positions.min(axis=0), self.positions.max(axis=0)


class Animation:
    """A rigid motion: ``matrix(t_s)`` is applied after the object's rest transform."""

    def matrix(self, t_s: float) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError


@dataclass(frozen=True)
class Spin(Animation):
    """Rotation about ``axis`` through ``center`` at ``rate_rad_s``."""

    axis: tuple[float, float, float] = (0.0, 1.0, 0.0)
    rate_rad_s: float = 1.0
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def matrix(self, t_s: float) -> np.ndarray:
        m = np.eye(4)
        r = quat_to_matrix3(quat_from_axis_angle(np.array(self.axis), self.rate_rad_s * t_s))
        c = np.array(self.center)
        m[:3, :3] = r
        m[:3, 3] = c - r @ c
        return m


@dataclass(frozen=True)
class Oscillate(Animation):
    """Translation ``amplitude_m * sin(2 pi t / period_s + phase)`` along ``direction``."""

    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    amplitude_m: float = 1.0
    period_s: float = 4.0
    phase_rad: float = 0.0

    def matrix(self, t_s: float) -> np.ndarray:
        m = np.eye(4)
        d = np.array(self.direction, dtype=np.float64)
        d /= np.linalg.norm(d)
        m[:3, 3] = d * self.amplitude_m * math.sin(2 * math.pi * t_s / self.period_s + self.phase_rad)
        return m


@dataclass(frozen=True)
class Patrol(Animation):
    """Back-and-forth linear motion between ``start`` and ``end`` at ``speed_mps`` (triangle wave)."""

    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    end: tuple[float, float, float] = (1.0, 0.0, 0.0)
    speed_mps: float = 1.0

    def matrix(self, t_s: float) -> np.ndarray:
        a, b = np.array(self.start), np.array(self.end)
        length = float(np.linalg.norm(b - a))
        m = np.eye(4)
        if length == 0:
            m[:3, 3] = a
            return m
        s = (self.speed_mps * t_s) % (2 * length)
        u = s / length if s <= length else 2 - s / length
        m[:3, 3] = a + u * (b - a)
        return m


@dataclass(frozen=True)
class Delayed(Animation):
    """``inner`` run ``offset_s`` seconds ahead: ``matrix(t) = inner.matrix(t + offset_s)``."""

    inner: Animation
    offset_s: float

    def matrix(self, t_s: float) -> np.ndarray:
        return self.inner.matrix(t_s + self.offset_s)


@dataclass
class SceneObject:
    """A mesh with a material placed in the world; ``object_id`` >= 1 (0 is background).

    ``backdrop``: the object sets the stage rather than being what a test looks at (a floor, an added
    ground plane); region scores (:meth:`Scene.model_ids`) leave it out of the ``model`` region.
    """

    name: str
    mesh: Mesh
    material: Material
    object_id: int
    transform: np.ndarray = field(default_factory=lambda: np.eye(4))
    animation: Animation | None = None
    backdrop: bool = False

    @property
    def dynamic(self) -> bool:
        return self.animation is not None

    def model_matrix(self, t_s: float) -> np.ndarray:
        """Object-to-world at time ``t_s``."""
        if self.animation is None:
            return self.transform
        return self.animation.matrix(t_s) @ self.transform


@dataclass
class DirectionalLight:
    """Sun-like light travelling along ``direction`` (world), casting a shadow map."""

    direction: tuple[float, float, float] = (-0.4, -1.0, -0.3)
    color: tuple[float, float, float] = (1.0, 0.97, 0.9)
    intensity: Schedule = field(default_factory=lambda: Schedule.constant(2.5))
    shadow_map_size: int = 2048
    shadow_extent_m: float = 14.0


@dataclass
class PointLight:
    position: tuple[float, float, float] = (0.0, 3.0, 0.0)
    color: tuple[float, float, float] = (1.0, 0.8, 0.6)
    intensity: Schedule = field(default_factory=lambda: Schedule.constant(5.0))
    range_m: float = 10.0


MAX_POINT_LIGHTS = 8
GI_MODES = ("none", "ddgi")


@dataclass
class Scene:
    """A complete scene.  ``version`` changes whenever geometry is edited (GPU caches key on it).

    ``subject``: world bounds (lo, hi) in metres of a loaded model, which the built-in
    traces frame; None for the built-in scenes (their traces are fixed).
    ``gi``: ``none`` (the constant ``ambient`` on a hemisphere gradient) or ``ddgi``
    (light probes over the scene's bounds, ``gi_probes`` along x, y, z, whose
    irradiance replaces the ambient term in every method's shading; the sky's radiance
    is ``ambient``; :mod:`splitrender.render.ddgi`).
    """

    name: str
    objects: list[SceneObject]
    sun: DirectionalLight | None = field(default_factory=DirectionalLight)
    point_lights: list[PointLight] = field(default_factory=list)
    ambient: tuple[float, float, float] = (0.18, 0.2, 0.24)
    sky_color: tuple[float, float, float] = (0.55, 0.7, 0.9)
    version: int = 0
    shading: str = "pbr"
    subject: tuple[np.ndarray, np.ndarray] | None = None
    gi: str = "none"
    gi_probes: tuple[int, int, int] = (8, 4, 8)
    spec: str | None = None
    """What the scene was loaded from (``get_scene``'s argument: a name or a path with its options), for messages."""

    def __post_init__(self) -> None:
        if self.shading not in SHADING_MODELS:
            raise ValueError(f"scene {self.name}: shading {self.shading!r} is not one of {list(SHADING_MODELS)}")
        if self.gi not in GI_MODES:
            raise ValueError(f"scene {self.name}: gi {self.gi!r} is not one of {list(GI_MODES)}")
        ids = [o.object_id for o in self.objects]
        if len(set(ids)) != len(ids) or any(i <= 0 for i in ids):
            raise ValueError("scene object ids must be unique and >= 1")
        if len(self.point_lights) > MAX_POINT_LIGHTS:
            raise ValueError(f"at most {MAX_POINT_LIGHTS} point lights are supported")

    @property
    def triangle_count(self) -> int:
        return sum(o.mesh.triangle_count for o in self.objects)

    def model_matrices(self, t_s: float) -> dict[int, np.ndarray]:
        """Object id -> object-to-world matrix at ``t_s``."""
        return {o.object_id: o.model_matrix(t_s) for o in self.objects}

    def model_ids(self) -> np.ndarray:
        """Object ids of the scene's model (every object but its backdrop: a loaded file's model without the
        ``+ground`` plane; a built-in scene less its floor), sorted, for the ``model`` scoring region."""
        return np.array(sorted(o.object_id for o in self.objects if not o.backdrop), np.int64)

    def model_mask(self, object_id: np.ndarray) -> np.ndarray:
        """Where an object-id image (0 = background) shows the scene's model (bool, same shape)."""
        return np.isin(object_id, self.model_ids())

    def dynamic_ids(self) -> list[int]:
        return [o.object_id for o in self.objects if o.dynamic]

    def light_intensities(self) -> list[Schedule]:
        """The lights' intensity schedules: the sun's first, if any, then the point lights' in order."""
        return ([self.sun.intensity] if self.sun is not None else []) + [pl.intensity for pl in self.point_lights]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for o in self.objects:
            p = (o.transform[:3, :3] @ o.mesh.positions.T.astype(np.float64)).T + o.transform[:3, 3]
            lo = np.minimum(lo, p.min(axis=0))
            hi = np.maximum(hi, p.max(axis=0))
        return lo, hi


def merge_meshes(meshes: Sequence[Mesh], name: str = "merged") -> Mesh:
    """Concatenate meshes into one (indices offset)."""
    pos, nor, uv, idx = [], [], [], []
    base = 0
    for m in meshes:
        pos.append(m.positions)
        nor.append(m.normals)
        uv.append(m.uvs)
        idx.append(m.indices + base)
        base += m.vertex_count
    return Mesh(np.concatenate(pos), np.concatenate(nor), np.concatenate(uv), np.concatenate(idx), name)


def generate_tangents(positions: np.ndarray, normals: np.ndarray, uvs: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Per-vertex tangents (N, 4) float32 for normal mapping, from the UV layout (Lengyel's method):
    ``xyz`` is dP/du summed over the vertex's triangles and made orthogonal to the normal; ``w`` is
    +1 when ``cross(normal, xyz)`` points towards decreasing ``v`` (glTF's bitangent, the normal
    map's +Y), else -1.  Vertices without a usable UV gradient get any unit vector orthogonal to
    the normal."""
    p = np.asarray(positions, np.float64)
    n = np.asarray(normals, np.float64)
    uv = np.asarray(uvs, np.float64)
    tri = np.asarray(indices, np.int64).reshape(-1, 3)
    e1, e2 = p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]]
    d1, d2 = uv[tri[:, 1]] - uv[tri[:, 0]], uv[tri[:, 2]] - uv[tri[:, 0]]
    r = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(r) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, r, 1.0), 0.0)[:, None]
    sdir = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inv       # dP/du
    tdir = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inv       # dP/dv
    ts = np.zeros_like(p)
    tt = np.zeros_like(p)
    for k in range(3):
        np.add.at(ts, tri[:, k], sdir)
        np.add.at(tt, tri[:, k], tdir)
    t = ts - n * np.sum(n * ts, axis=1, keepdims=True)
    ln = np.linalg.norm(t, axis=1)
    bad = ln < 1e-12
    if bad.any():  # any perpendicular: cross with the axis least aligned with the normal
        axis = np.eye(3)[np.argmin(np.abs(n[bad]), axis=1)]
        t[bad] = np.cross(n[bad], axis)
        ln[bad] = np.maximum(np.linalg.norm(t[bad], axis=1), 1e-12)
    t /= ln[:, None]
    w = np.where(np.sum(np.cross(n, t) * -tt, axis=1) < 0.0, -1.0, 1.0)
    return np.concatenate([t, w[:, None]], axis=1).astype(np.float32)


def shift_time(scene: Scene, offset_s: float) -> Scene:
    """``scene`` with its clock ``offset_s`` seconds ahead: animations and light schedules at time ``t``
    show what the original shows at ``t + offset_s`` (e.g. start a short run just before the sun dims).

    Meshes and materials are shared with ``scene``; the result is a new :class:`Scene` object.
    """
    if offset_s == 0:
        return scene
    import dataclasses

    def sched(s: Schedule) -> Schedule:
        return Schedule(tuple(t - offset_s for t in s.times_s), s.values) if len(s.values) > 1 else s

    objs = [dataclasses.replace(o, animation=Delayed(o.animation, offset_s)) if o.animation is not None else o
            for o in scene.objects]
    sun = dataclasses.replace(scene.sun, intensity=sched(scene.sun.intensity)) if scene.sun is not None else None
    lamps = [dataclasses.replace(pl, intensity=sched(pl.intensity)) for pl in scene.point_lights]
    return dataclasses.replace(scene, objects=objs, sun=sun, point_lights=lamps)
