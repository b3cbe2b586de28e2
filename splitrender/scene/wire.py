"""A scene as session data: what a client that renders the scene itself receives once (``probes``).

:func:`scene_to_data` gives a msgpack-able map (numpy arrays ride as the metadata's
array extension): objects (name, id, mesh arrays, material fields and textures, rest
transform, whether it moves), the sun, the point lights, ``ambient``, ``sky``,
``shading``, ``gi_probes``.  Animations and light schedules are not sent: the server
sends each frame's object transforms and light intensities instead, so the client shows
the scene as of its newest update.  :func:`scene_from_data` checks everything against
:data:`SCENE` (:mod:`splitrender.protocol.schema`) and the client's
:class:`~splitrender.limits.ClientLimits` (objects, triangles, probes) and raises
:class:`SceneWireError` naming the field (``scene: objects[0].transform: singular
transform (|det| 0 < 1e-12)``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import RemoteProtocolError
from ..limits import DEFAULT_CLIENT_LIMITS, ClientLimits
from ..protocol.schema import Array, Bool, Check, Dim, Float, Int, Invalid, Map, Nullable, Opt, Schema, Seq, Str, Transforms, Version
from .model import (DirectionalLight, GI_MODES, MAX_POINT_LIGHTS, SHADING_MODELS, Material, Mesh, PointLight, Scene,
                    SceneObject, Schedule)

WIRE_VERSION = 1
MAX_OBJECTS = 4096
MAX_VERTICES = 1 << 24
MAX_TEXTURE_SIDE = 8192
TEXTURES = ("texture", "metallic_roughness_texture", "normal_texture", "occlusion_texture", "emissive_texture")
FLOATS = ("specular", "shininess", "metallic", "roughness", "normal_scale", "occlusion_strength")


class SceneWireError(RemoteProtocolError):
    """Malformed scene session data; the message names the object and field."""


class _Fixed:
    """An animation standing for "the transform the server sent last" (set per update by the client)."""

    def __init__(self) -> None:
        self.m = np.eye(4)

    def matrix(self, t_s: float) -> np.ndarray:
        return self.m


def scene_to_data(scene: Scene) -> dict[str, Any]:
    """The scene as session data (see the module docstring)."""
    objs = []
    for o in scene.objects:
        m, mat = o.mesh, o.material
        md: dict[str, Any] = {"name": mat.name, "base_color": list(map(float, mat.base_color)),
                              "emissive": list(map(float, mat.emissive)),
                              **{k: float(getattr(mat, k)) for k in FLOATS}}
        for k in TEXTURES:
            t = getattr(mat, k)
            if t is not None:
                md[k] = np.ascontiguousarray(np.asarray(t)[..., :3], np.uint8)
        if mat.uv_transform is not None:
            md["uv_transform"] = np.asarray(mat.uv_transform, np.float32)
        objs.append({"name": o.name, "id": int(o.object_id), "dynamic": bool(o.dynamic),
                     "transform": np.asarray(o.transform, np.float32),
                     "positions": m.positions, "normals": m.normals, "uvs": m.uvs, "indices": m.indices,
                     "tangents": m.tangent_frame(), "material": md})
    sun = None
    if scene.sun is not None:
        s = scene.sun
        sun = {"direction": list(map(float, s.direction)), "color": list(map(float, s.color)),
               "intensity": float(s.intensity.value(0.0)), "shadow_map_size": int(s.shadow_map_size),
               "shadow_extent_m": float(s.shadow_extent_m)}
    lights = [{"position": list(map(float, p.position)), "color": list(map(float, p.color)),
               "intensity": float(p.intensity.value(0.0)), "range_m": float(p.range_m)} for p in scene.point_lights]
    return {"v": WIRE_VERSION, "name": scene.name, "objects": objs, "sun": sun, "lights": lights,
            "ambient": list(map(float, scene.ambient)), "sky": list(map(float, scene.sky_color)),
            "shading": scene.shading, "gi": scene.gi, "gi_probes": list(map(int, scene.gi_probes))}


MAX_COORD_M = 1e6
"""Largest position, direction or colour component accepted (metres for positions)."""


class _Indices(Array):
    """An object's (T, 3) uint32 triangle indices, each below its vertex count ``V`` (bound by ``positions``)."""

    def __init__(self) -> None:
        super().__init__(dtype=np.uint32, shape=(Dim("T", 1, MAX_VERTICES), 3))   # an object draws at least one triangle

    def check(self, v: Any, ctx: dict[str, Any]) -> np.ndarray:
        out = super().check(v, ctx)
        if out.size and int(out.max()) >= ctx["V"]:
            raise Invalid(f"index {int(out.max())} beyond the {ctx['V']} vertices")
        return out


_V3 = Seq(Float(-MAX_COORD_M, MAX_COORD_M), 3)
_NAME = Opt(Nullable(Str()), None)
_TEXTURE = Opt(Nullable(Array(dtype=np.uint8, shape=(Dim(None, 1, MAX_TEXTURE_SIDE), Dim(None, 1, MAX_TEXTURE_SIDE), 3))))
_MATERIAL = Map({"name": _NAME, "base_color": _V3, "emissive": _V3, **{k: Float(0.0, 1e4) for k in FLOATS},
                 **{k: _TEXTURE for k in TEXTURES}, "uv_transform": Opt(Nullable(Array("f", (3, 3), finite=True)))})
_OBJECT = Map({
    "positions": Array(dtype=np.float32, shape=(Dim("V", 0, MAX_VERTICES), 3), finite=True),
    "normals": Array(dtype=np.float32, shape=("V", 3), finite=True),
    "uvs": Array(dtype=np.float32, shape=("V", 2), finite=True),
    "tangents": Array(dtype=np.float32, shape=("V", 4), finite=True),
    "indices": _Indices(),
    "id": Int(1, 1 << 24),
    "transform": Transforms(),                   # the rest transform: affine, within +-1e6, invertible (the client inverts it)
    "material": _MATERIAL,
    "name": _NAME,
    "dynamic": Opt(Bool(), False),
}, scope=True)                                   # V and T per object
_SUN = Map({"direction": Check(_V3, lambda d: sum(x * x for x in d) > 1e-12, "must not be zero"), "color": _V3,
            "intensity": Float(0.0, 1e6), "shadow_map_size": Int(16, 8192), "shadow_extent_m": Float(0.01, 1e5)})
_LIGHT = Map({"position": _V3, "color": _V3, "intensity": Float(0.0, 1e6), "range_m": Float(0.0, 1e5)})

SCENE = Schema("scene", SceneWireError, Map({
    "v": Version(WIRE_VERSION),
    "gi_probes": Seq(Int(2, 64), 3),
    "objects": Seq(_OBJECT, min_len=1, max_len="max_objects"),
    "sun": Opt(Nullable(_SUN)),
    "lights": Seq(_LIGHT, max_len=MAX_POINT_LIGHTS),
    "shading": Str(SHADING_MODELS),
    "gi": Str(GI_MODES),
    "ambient": _V3,
    "sky": _V3,
    "name": _NAME,
}))
"""The scene's fields (:func:`scene_to_data`); :func:`scene_from_data` adds the client's limits."""


def _name(v: str | None, default: str) -> str:
    return default if v is None else v[:256]


def scene_from_data(data: Any, limits: ClientLimits = DEFAULT_CLIENT_LIMITS) -> tuple[Scene, dict[int, _Fixed]]:
    """A client-side :class:`Scene` from :func:`scene_to_data`'s map, and the per-object transform holders of its
    moving objects (set them from each update's transforms).  Raises :class:`SceneWireError` naming the field, also
    when the scene has more objects, triangles or probes than ``limits`` allow."""
    d = SCENE.parse(data, {"max_objects": min(MAX_OBJECTS, limits.max_scene_objects)})
    cx, cy, cz = d["gi_probes"]
    if cx * cy * cz > limits.max_probes:
        raise SCENE.error_at("gi_probes", f"{cx}x{cy}x{cz} = {cx * cy * cz} probes, over this client's limit of "
                                          f"{limits.max_probes} (ClientLimits.max_probes)")
    tris = sum(int(od["indices"].shape[0]) for od in d["objects"])
    if tris > limits.max_scene_triangles:
        raise SCENE.error_at("objects", f"{tris} triangles, over this client's limit of {limits.max_scene_triangles} "
                                        "(ClientLimits.max_scene_triangles)")
    objects, holders = [], {}
    for od in d["objects"]:
        md = od["material"]
        mat = Material(name=_name(md["name"], "default"), base_color=tuple(md["base_color"]),
                       emissive=tuple(md["emissive"]), uv_transform=md["uv_transform"],
                       **{key: md[key] for key in FLOATS + TEXTURES})
        name = _name(od["name"], "object")
        mesh = Mesh(od["positions"], od["normals"], od["uvs"], od["indices"], _name(od["name"], "mesh"), od["tangents"])
        fixed = _Fixed() if od["dynamic"] else None
        if fixed is not None:
            holders[od["id"]] = fixed
        objects.append(SceneObject(name, mesh, mat, od["id"], od["transform"].astype(np.float64), fixed))  # type: ignore[arg-type]
    sun = None
    if d["sun"] is not None:
        sd = d["sun"]
        sun = DirectionalLight(tuple(sd["direction"]), tuple(sd["color"]), Schedule.constant(sd["intensity"]),
                               sd["shadow_map_size"], sd["shadow_extent_m"])
    lights = [PointLight(tuple(ld["position"]), tuple(ld["color"]), Schedule.constant(ld["intensity"]),
                         ld["range_m"]) for ld in d["lights"]]
    try:
        scene = Scene(_name(d["name"], "scene"), objects, sun, lights, tuple(d["ambient"]), tuple(d["sky"]),
                      shading=d["shading"], gi=d["gi"], gi_probes=(cx, cy, cz))
    except ValueError as exc:
        raise SceneWireError(f"scene: {exc}") from None
    return scene, holders
