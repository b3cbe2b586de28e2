"""A scene as session data: what a client that renders the scene itself receives once (``probes``).

:func:`scene_to_data` gives a msgpack-able map (numpy arrays ride as the metadata's
array extension): objects (name, id, mesh arrays, material fields and textures, rest
transform, whether it moves), the sun, the point lights, ``ambient``, ``sky``,
``shading``, ``gi_probes``.  Animations and light schedules are not sent: the server
sends each frame's object transforms and light intensities instead, so the client shows
the scene as of its newest update.  :func:`scene_from_data` checks everything and raises
:class:`SceneWireError` naming the field.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import RemoteProtocolError
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


def _vec(d: dict[str, Any], key: str, n: int, where: str) -> tuple[float, ...]:
    v = d.get(key)
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise SceneWireError(f"{where}.{key}: expected {n} numbers")
    try:
        out = tuple(float(x) for x in v)
    except (TypeError, ValueError):
        raise SceneWireError(f"{where}.{key}: expected {n} numbers") from None
    if not all(np.isfinite(out)):
        raise SceneWireError(f"{where}.{key}: not finite")
    return out


def _num(d: dict[str, Any], key: str, where: str, lo: float = -1e9, hi: float = 1e9) -> float:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or not lo <= v <= hi:
        raise SceneWireError(f"{where}.{key}: expected a number in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


def _array(d: dict[str, Any], key: str, where: str, dtype: Any, cols: int, max_rows: int) -> np.ndarray:
    a = d.get(key)
    if not isinstance(a, np.ndarray) or a.ndim != 2 or a.shape[1] != cols or a.shape[0] > max_rows or a.dtype != np.dtype(dtype):
        raise SceneWireError(f"{where}.{key}: expected a (N, {cols}) {np.dtype(dtype).name} array, got "
                             f"{getattr(a, 'shape', type(a).__name__)} {getattr(a, 'dtype', '')}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise SceneWireError(f"{where}.{key}: not finite")
    return a


def scene_from_data(data: Any) -> tuple[Scene, dict[int, _Fixed]]:
    """A client-side :class:`Scene` from :func:`scene_to_data`'s map, and the per-object transform holders of its
    moving objects (set them from each update's transforms)."""
    if not isinstance(data, dict) or data.get("v") != WIRE_VERSION:
        raise SceneWireError(f"scene: expected a map with v={WIRE_VERSION}")
    objs = data.get("objects")
    if not isinstance(objs, list) or not 1 <= len(objs) <= MAX_OBJECTS:
        raise SceneWireError(f"scene.objects: expected a list of 1..{MAX_OBJECTS} objects")
    objects, holders = [], {}
    for k, od in enumerate(objs):
        w = f"scene.objects[{k}]"
        if not isinstance(od, dict):
            raise SceneWireError(f"{w}: expected a map")
        pos = _array(od, "positions", w, np.float32, 3, MAX_VERTICES)
        n = pos.shape[0]
        nrm = _array(od, "normals", w, np.float32, 3, MAX_VERTICES)
        uvs = _array(od, "uvs", w, np.float32, 2, MAX_VERTICES)
        tan = _array(od, "tangents", w, np.float32, 4, MAX_VERTICES)
        idx = _array(od, "indices", w, np.uint32, 3, MAX_VERTICES)
        if not (nrm.shape[0] == uvs.shape[0] == tan.shape[0] == n):
            raise SceneWireError(f"{w}: positions, normals, uvs and tangents differ in length")
        if idx.size and int(idx.max()) >= n:
            raise SceneWireError(f"{w}.indices: index {int(idx.max())} beyond the {n} vertices")
        oid = od.get("id")
        if isinstance(oid, bool) or not isinstance(oid, int) or not 1 <= oid <= 1 << 24:
            raise SceneWireError(f"{w}.id: expected an id >= 1, got {oid!r}")
        tf = od.get("transform")
        if not isinstance(tf, np.ndarray) or tf.shape != (4, 4) or not np.isfinite(tf).all():
            raise SceneWireError(f"{w}.transform: expected a finite 4x4 array")
        md = od.get("material")
        if not isinstance(md, dict):
            raise SceneWireError(f"{w}.material: expected a map")
        mw = w + ".material"
        tex: dict[str, np.ndarray | None] = {}
        for key in TEXTURES:
            t = md.get(key)
            if t is not None and (not isinstance(t, np.ndarray) or t.dtype != np.uint8 or t.ndim != 3 or t.shape[2] != 3
                                  or not 1 <= t.shape[0] <= MAX_TEXTURE_SIDE or not 1 <= t.shape[1] <= MAX_TEXTURE_SIDE):
                raise SceneWireError(f"{mw}.{key}: expected an (H, W, 3) uint8 image up to {MAX_TEXTURE_SIDE} a side")
            tex[key] = t
        uvt = md.get("uv_transform")
        if uvt is not None and (not isinstance(uvt, np.ndarray) or uvt.shape != (3, 3) or not np.isfinite(uvt).all()):
            raise SceneWireError(f"{mw}.uv_transform: expected a finite 3x3 array")
        name = md.get("name", "default")
        mat = Material(name=str(name)[:256], base_color=_vec(md, "base_color", 3, mw), emissive=_vec(md, "emissive", 3, mw),
                       **{key: _num(md, key, mw, 0.0, 1e4) for key in FLOATS}, uv_transform=uvt,  # type: ignore[arg-type]
                       **tex)  # type: ignore[arg-type]
        mesh = Mesh(pos, nrm, uvs, idx, str(od.get("name", "mesh"))[:256], tan)
        fixed = _Fixed() if od.get("dynamic") is True else None
        if fixed is not None:
            holders[oid] = fixed
        objects.append(SceneObject(str(od.get("name", "object"))[:256], mesh, mat, oid, np.asarray(tf, np.float64),
                                   fixed))  # type: ignore[arg-type]
    sun = None
    sd = data.get("sun")
    if sd is not None:
        if not isinstance(sd, dict):
            raise SceneWireError("scene.sun: expected a map or nil")
        sun = DirectionalLight(_vec(sd, "direction", 3, "scene.sun"), _vec(sd, "color", 3, "scene.sun"),
                               Schedule.constant(_num(sd, "intensity", "scene.sun", 0.0, 1e6)),
                               int(_num(sd, "shadow_map_size", "scene.sun", 16, 8192)),
                               _num(sd, "shadow_extent_m", "scene.sun", 0.01, 1e5))
    lds = data.get("lights")
    if not isinstance(lds, list) or len(lds) > MAX_POINT_LIGHTS:
        raise SceneWireError(f"scene.lights: expected a list of at most {MAX_POINT_LIGHTS}")
    lights = []
    for i, ld in enumerate(lds):
        w = f"scene.lights[{i}]"
        if not isinstance(ld, dict):
            raise SceneWireError(f"{w}: expected a map")
        lights.append(PointLight(_vec(ld, "position", 3, w), _vec(ld, "color", 3, w),
                                 Schedule.constant(_num(ld, "intensity", w, 0.0, 1e6)), _num(ld, "range_m", w, 0.0, 1e5)))
    shading, gi = data.get("shading"), data.get("gi")
    if shading not in SHADING_MODELS or gi not in GI_MODES:
        raise SceneWireError(f"scene: shading {shading!r} / gi {gi!r} unsupported")
    probes = data.get("gi_probes")
    if not isinstance(probes, list) or len(probes) != 3 or not all(isinstance(c, int) and 2 <= c <= 64 for c in probes):
        raise SceneWireError("scene.gi_probes: expected three counts in [2, 64]")
    ambient, sky = _vec(data, "ambient", 3, "scene"), _vec(data, "sky", 3, "scene")
    try:
        scene = Scene(str(data.get("name", "scene"))[:256], objects, sun, lights, ambient, sky, shading=shading, gi=gi,
                      gi_probes=tuple(probes))  # type: ignore[arg-type]
    except ValueError as exc:
        raise SceneWireError(f"scene: {exc}") from None
    return scene, holders

