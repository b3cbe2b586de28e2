"""Loading scenes from glTF/GLB/OBJ/PLY/Collada files through trimesh."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SceneError
from . import primitives, textures
from .model import MAX_POINT_LIGHTS, DirectionalLight, Material, Mesh, PointLight, Scene, SceneObject, Schedule
from .procedural import BUILTIN_GI, BUILTIN_SCENES

log = logging.getLogger(__name__)

SUPPORTED_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".dae", ".stl", ".off")


def _image(img: Any, name: str, what: str) -> np.ndarray | None:
    """An embedded image as (H, W, 3) uint8, or None (a broken image should not stop the scene)."""
    if img is None:
        return None
    try:
        return np.asarray(img.convert("RGB"), dtype=np.uint8)
    except Exception as exc:
        log.warning("scene %s: ignoring unreadable %s texture: %s", name, what, exc)
        return None


def _factor(v: Any, default: float) -> float:
    return default if v is None else float(np.asarray(v, np.float64).ravel()[0])


def _pbr_fields(mat: Any, name: str) -> dict[str, Any]:
    """glTF metallic-roughness fields of a trimesh ``PBRMaterial`` (glTF defaults where absent:
    metallic 1, roughness 1, no emission).  trimesh (5.x) exposes neither the normal map's scale,
    the occlusion strength nor ``KHR_texture_transform``, so those stay 1, 1 and identity."""
    if not hasattr(mat, "metallicRoughnessTexture"):
        return {}
    em = getattr(mat, "emissiveFactor", None)
    emissive = (0.0, 0.0, 0.0) if em is None else tuple(float(c) for c in np.asarray(em, np.float64).ravel()[:3])
    return {
        "metallic": _factor(getattr(mat, "metallicFactor", None), 1.0),
        "roughness": _factor(getattr(mat, "roughnessFactor", None), 1.0),
        "metallic_roughness_texture": _image(getattr(mat, "metallicRoughnessTexture", None), name, "metallic-roughness"),
        "normal_texture": _image(getattr(mat, "normalTexture", None), name, "normal"),
        "occlusion_texture": _image(getattr(mat, "occlusionTexture", None), name, "occlusion"),
        "emissive": emissive,
        "emissive_texture": _image(getattr(mat, "emissiveTexture", None), name, "emissive"),
    }


def texture_transform_matrix(ext: dict[str, Any]) -> np.ndarray:
    """3x3 UV matrix of a ``KHR_texture_transform`` (translation * rotation * scale, glTF's order)."""
    ox, oy = (float(v) for v in ext.get("offset", (0.0, 0.0)))
    sx, sy = (float(v) for v in ext.get("scale", (1.0, 1.0)))
    r = float(ext.get("rotation", 0.0))
    c, s = np.cos(r), np.sin(r)
    t = np.array([[1.0, 0.0, ox], [0.0, 1.0, oy], [0.0, 0.0, 1.0]])
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return t @ rot @ np.diag([sx, sy, 1.0])


def _gltf_json(p: Path) -> dict[str, Any] | None:
    """The JSON of a .gltf or .glb file, or None when it cannot be read."""
    import json
    import struct

    try:
        data = p.read_bytes()
        if p.suffix.lower() == ".glb":
            if len(data) < 20 or data[:4] != b"glTF":
                return None
            n, kind = struct.unpack_from("<II", data, 12)
            if kind != 0x4E4F534A:  # "JSON"
                return None
            data = data[20:20 + n]
        doc = json.loads(data)
        return doc if isinstance(doc, dict) else None
    except (OSError, ValueError):
        return None


def gltf_texture_transforms(p: Path) -> dict[str, np.ndarray]:
    """Material name -> UV matrix of its base-colour texture's ``KHR_texture_transform`` (trimesh
    does not expose the extension, so it is read from the file's JSON; one matrix serves every
    map of the material)."""
    doc = _gltf_json(p) if p.suffix.lower() in (".gltf", ".glb") else None
    out: dict[str, np.ndarray] = {}
    for m in (doc or {}).get("materials", []) if isinstance((doc or {}).get("materials"), list) else []:
        try:
            ext = m["pbrMetallicRoughness"]["baseColorTexture"]["extensions"]["KHR_texture_transform"]
            out[str(m["name"])] = texture_transform_matrix(ext)
        except (KeyError, TypeError, ValueError):
            continue
    return out


def _node_matrix(node: dict[str, Any]) -> np.ndarray:
    """A glTF node's local 4x4 matrix (``matrix``, column-major, or translation/rotation/scale)."""
    if "matrix" in node:
        return np.asarray(node["matrix"], np.float64).reshape(4, 4).T
    t = np.asarray(node.get("translation", [0.0, 0.0, 0.0]), np.float64)
    x, y, z, w = (float(v) for v in node.get("rotation", [0.0, 0.0, 0.0, 1.0]))
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = r * np.asarray(node.get("scale", [1.0, 1.0, 1.0]), np.float64)[None, :]
    m[:3, 3] = t
    return m


GLTF_POINT_INTENSITY_SCALE = 4.0 * np.pi / 100.0
"""Renderer point-light intensity per glTF candela (the renderer's units are relative: its default
point light is 5; a 40 cd bulb, about a 500 lm lamp, maps to about 5)."""
GLTF_SUN_INTENSITY_SCALE = 2.5 / 3.0
"""Renderer sun intensity per glTF lux unit as exporters write it (Blender writes its
'strength', typically 1-5; the renderer's default sun is 2.5)."""


def gltf_punctual_lights(p: Path) -> tuple[list[tuple[np.ndarray, tuple[float, float, float], float, float]],
                                           list[tuple[np.ndarray, tuple[float, float, float], float]]]:
    """``KHR_lights_punctual`` lights of a glTF/GLB file, placed by the default scene's node graph.

    Returns (point lights: world position, colour, intensity in renderer units, range in
    metres (10 when the file gives none)), (directional lights: world direction of travel,
    colour, intensity).  Spot lights are taken as point lights (their cone is not modelled).
    Photometric units are mapped with :data:`GLTF_POINT_INTENSITY_SCALE` and
    :data:`GLTF_SUN_INTENSITY_SCALE`.  Read from the JSON: trimesh does not expose the extension.
    """
    doc = _gltf_json(p) if p.suffix.lower() in (".gltf", ".glb") else None
    points: list[tuple[np.ndarray, tuple[float, float, float], float, float]] = []
    suns: list[tuple[np.ndarray, tuple[float, float, float], float]] = []
    try:
        lights = (doc or {}).get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
        nodes = (doc or {}).get("nodes", [])
        scenes = (doc or {}).get("scenes", [])
        roots = scenes[int((doc or {}).get("scene", 0))].get("nodes", []) if scenes else list(range(len(nodes)))
        stack = [(int(i), np.eye(4)) for i in roots]
        seen = 0
        while stack and seen < 100_000:
            seen += 1
            i, parent = stack.pop()
            node = nodes[i]
            world = parent @ _node_matrix(node)
            ref = node.get("extensions", {}).get("KHR_lights_punctual", {}).get("light")
            if ref is not None:
                light = lights[int(ref)]
                color = tuple(float(c) for c in light.get("color", [1.0, 1.0, 1.0]))[:3]
                inten = float(light.get("intensity", 1.0))
                if light.get("type") == "directional":
                    d = world[:3, :3] @ np.array([0.0, 0.0, -1.0])
                    suns.append((d / max(float(np.linalg.norm(d)), 1e-12), color, inten * GLTF_SUN_INTENSITY_SCALE))  # type: ignore[arg-type]
                else:
                    points.append((world[:3, 3].copy(), color, inten * GLTF_POINT_INTENSITY_SCALE,  # type: ignore[arg-type]
                                   float(light.get("range", 10.0))))
            stack.extend((int(c), world) for c in node.get("children", []))
    except (KeyError, IndexError, TypeError, ValueError, AttributeError) as exc:
        log.warning("scene file %s: KHR_lights_punctual ignored: %s", p, exc)
        return [], []
    return points, suns


def _material_from_visual(visual, name: str) -> Material:
    base = (0.8, 0.8, 0.8)
    tex = None
    pbr: dict[str, Any] = {}
    mat = getattr(visual, "material", None)
    if mat is not None:
        pbr = _pbr_fields(mat, name)
        col = getattr(mat, "baseColorFactor", None)
        if col is None:
            col = getattr(mat, "main_color", None)
        if col is not None:
            c = np.asarray(col, dtype=np.float64).ravel()[:3]
            if c.max() > 1.0:
                c = c / 255.0
            base = tuple(float(v) for v in c)
        img = getattr(mat, "baseColorTexture", None)
        if img is None:
            img = getattr(mat, "image", None)
        tex = _image(img, name, "base colour")
    elif getattr(visual, "kind", None) == "vertex" or hasattr(visual, "vertex_colors"):
        try:
            vc = np.asarray(visual.vertex_colors)[:, :3].mean(axis=0) / 255.0
            base = tuple(float(v) for v in vc)
        except Exception:
            pass
    return Material(name, base, tex, **pbr)


def _texture_refs(p: Path) -> list[str]:
    """External texture files a glTF/GLB/OBJ file refers to (relative paths as written)."""
    import json
    import struct

    refs: list[str] = []
    try:
        suffix = p.suffix.lower()
        if suffix in (".gltf", ".glb"):
            if suffix == ".glb":
                raw = p.read_bytes()
                length, kind = struct.unpack_from("<II", raw, 12)  # first chunk: JSON
                doc = json.loads(raw[20:20 + length]) if kind == 0x4E4F534A else {}
            else:
                doc = json.loads(p.read_text())
            for img in doc.get("images", []) or []:
                uri = img.get("uri") if isinstance(img, dict) else None
                if isinstance(uri, str) and not uri.startswith("data:"):
                    refs.append(uri)
        elif suffix == ".obj":
            for line in p.read_text(errors="replace").splitlines():
                if line.startswith("mtllib "):
                    mtl = p.parent / line.split(None, 1)[1].strip()
                    if mtl.exists():
                        for ml in mtl.read_text(errors="replace").splitlines():
                            parts = ml.split()
                            if parts and parts[0].lower() in ("map_kd", "map_ka") and len(parts) > 1:
                                refs.append(parts[-1])
    except (OSError, ValueError, struct.error):
        return []  # the loader proper reports unreadable files
    return refs


def _warn_missing_textures(p: Path) -> list[str]:
    """Log a warning for each texture file ``p`` refers to that is not there; returns them."""
    from urllib.parse import unquote

    missing = [r for r in _texture_refs(p) if not (p.parent / unquote(r)).exists()]
    for r in missing:
        log.warning("scene file %s: texture %s is missing; its material uses its base colour", p, r)
    return missing


def _node_geometries(p: Path, loaded) -> list[tuple[str, object]]:  # type: ignore[no-untyped-def]
    """One (name, mesh in world coordinates) per mesh node of the file's scene graph."""
    out = []
    try:
        for node in loaded.graph.nodes_geometry:
            m, gname = loaded.graph[node]
            g = loaded.geometry[gname].copy()
            g.apply_transform(m)
            out.append((str(node), g))
    except Exception as exc:
        raise SceneError(f"scene file {p} is corrupt or unreadable: {type(exc).__name__}: {exc}") from exc
    return out


GROUND_SIZE_MIN_M = 20.0
"""Side of the optional ground plane: at least this, or 5x the model's footprint (metres)."""


_GLTF1 = "glTF 1 is not supported: convert it to glTF 2 (e.g. with the Khronos glTF 1-to-2 converter or Blender)"


def _check_header(p: Path) -> None:
    """What can be told before parsing: an empty file, and glTF 1 (a .glb's header version, or a .gltf's
    ``asset.version``, or glTF 1's objects keyed by id where glTF 2 has lists)."""
    try:
        size = p.stat().st_size
        head = p.read_bytes()[:12] if size else b""
    except OSError as exc:
        raise SceneError(f"scene file {p} is unreadable: {exc}") from exc
    if size == 0:
        raise SceneError(f"scene file {p} is empty (0 bytes)")
    suffix = p.suffix.lower()
    if suffix == ".glb":
        if len(head) < 12 or head[:4] != b"glTF":
            raise SceneError(f"scene file {p} is not a binary glTF file (no 'glTF' magic in its 12-byte header)")
        version = int.from_bytes(head[4:8], "little")
        if version == 1:
            raise SceneError(f"scene file {p}: {_GLTF1}")
        if version != 2:
            raise SceneError(f"scene file {p}: binary glTF version {version} is not supported (only glTF 2)")
    elif suffix == ".gltf":
        import json

        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise SceneError(f"scene file {p} is not valid glTF JSON: {exc}") from exc
        if not isinstance(doc, dict):
            raise SceneError(f"scene file {p} is not a glTF document (a JSON {type(doc).__name__}, expected an object)")
        asset = doc.get("asset")
        version = str(asset.get("version", "")) if isinstance(asset, dict) else ""
        if version.startswith("1") or (not version.startswith("2") and isinstance(doc.get("meshes"), dict)):
            raise SceneError(f"scene file {p}: {_GLTF1}")


def load_scene_file(path: str | os.PathLike, target_size_m: float | None = None, ground: bool = False) -> Scene:
    """Load a mesh file into a static :class:`Scene` with a default sun.

    Every mesh node of the file becomes its own object (its own object id, material and
    texture).  A texture the file names but that is missing is logged as a warning and
    that material falls back to its base colour; textures that are present are used.
    Raises :class:`SceneError` naming the file when it is missing, unreadable,
    unsupported or has no triangles.  ``target_size_m`` rescales the scene so its
    largest extent has that size, centred on (0, y, -4) and resting on y=0.
    ``ground`` adds a checkered ground plane under it (object id after the model's).
    The model's world bounds are kept as :attr:`Scene.subject`, so built-in traces can
    frame it (:func:`splitrender.scene.trace.get_trace`).
    """
    import trimesh

    p = Path(path)
    if not p.exists():
        raise SceneError(f"scene file not found: {p}")
    if p.suffix.lower() not in SUPPORTED_SUFFIXES:
        raise SceneError(f"scene file {p}: unsupported format {p.suffix!r} (supported: {', '.join(SUPPORTED_SUFFIXES)})")
    _check_header(p)
    try:
        loaded = trimesh.load(str(p), force="scene")
    except Exception as exc:
        raise SceneError(f"scene file {p} is corrupt or unreadable: {type(exc).__name__}: {exc}") from exc
    _warn_missing_textures(p)
    objects: list[SceneObject] = []
    uv_transforms = gltf_texture_transforms(p)
    for i, (node, g) in enumerate(_node_geometries(p, loaded)):
        if not hasattr(g, "faces") or len(getattr(g, "faces", [])) == 0:
            continue
        verts = np.asarray(g.vertices, dtype=np.float64)
        faces = np.asarray(g.faces, dtype=np.int64)
        if not np.isfinite(verts).all():
            raise SceneError(f"scene file {p}: mesh {i} has non-finite vertex positions")
        if verts.ndim != 2 or verts.shape[1] != 3:
            raise SceneError(f"scene file {p}: mesh {i} has vertices of shape {verts.shape}, expected (N, 3)")
        if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= len(verts):
            raise SceneError(f"scene file {p}: mesh {i} has face indices out of range or not triangles")
        try:
            normals = np.asarray(g.vertex_normals, dtype=np.float64)
        except Exception:
            normals = np.tile([0.0, 1.0, 0.0], (len(verts), 1))
        uv = getattr(g.visual, "uv", None)
        uvs = np.asarray(uv, dtype=np.float64) if uv is not None and len(uv) == len(verts) else np.zeros((len(verts), 2))
        uvs = np.stack([uvs[:, 0], 1.0 - uvs[:, 1]], 1) if uv is not None else uvs  # trimesh flips v
        name = f"{p.stem}_{i}"
        mesh = Mesh(verts, normals, uvs, faces, name)
        material = _material_from_visual(g.visual, name)
        src = getattr(getattr(g.visual, "material", None), "name", None)
        if src in uv_transforms:
            material.uv_transform = uv_transforms[src]
        objects.append(SceneObject(name, mesh, material, len(objects) + 1))
    if not objects:
        raise SceneError(f"scene file {p} contains no triangle meshes")
    if not any(float(o.mesh.triangle_areas().sum()) > 0 for o in objects):
        raise SceneError(f"scene file {p}: every triangle is degenerate (zero area)")
    t = np.eye(4)
    if target_size_m is not None:
        lo = np.min([o.mesh.positions.min(0) for o in objects], axis=0)
        hi = np.max([o.mesh.positions.max(0) for o in objects], axis=0)
        s = target_size_m / max(float((hi - lo).max()), 1e-9)
        centre = (lo + hi) / 2
        t[:3, :3] *= s
        t[:3, 3] = -np.array([centre[0], lo[1], centre[2]]) * s + np.array([0.0, 0.0, -4.0])
        for o in objects:
            o.transform = t.copy()
    points, suns = gltf_punctual_lights(p)
    sun = DirectionalLight()
    if suns:  # the file's first directional light replaces the default sun
        d, col, inten = suns[0]
        sun = DirectionalLight(tuple(float(v) for v in d), col, Schedule.constant(inten))  # type: ignore[arg-type]
    scale = float(t[0, 0])
    point_lights = [PointLight(tuple(float(v) for v in (t @ np.append(pos, 1.0))[:3]), col, Schedule.constant(inten),  # type: ignore[arg-type]
                               rng * scale) for pos, col, inten, rng in points[:MAX_POINT_LIGHTS]]
    if len(points) > MAX_POINT_LIGHTS:
        log.warning("scene file %s: %d point lights, only the first %d are used", p, len(points), MAX_POINT_LIGHTS)
    scene = Scene(p.stem, objects, sun, point_lights)
    lo, hi = scene.bounds()
    scene.subject = (lo, hi)
    if ground:
        size = max(GROUND_SIZE_MIN_M, 5.0 * float(max(hi[0] - lo[0], hi[2] - lo[2])))
        t = np.eye(4)
        t[:3, 3] = [(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2]
        plane = primitives.grid_plane(size, size, 16, 16, uv_scale_m=2.0, name="ground")
        scene.objects.append(SceneObject("ground", plane, Material("ground", (0.9, 0.9, 0.9), textures.checker(256, 8)),
                                         len(objects) + 1, t, backdrop=True))
    return scene


GROUND_OPTION = "+ground"
"""Suffix of a scene file path that adds the ground plane: ``model.glb+ground``."""
GI_OPTION = "+gi"
"""Suffix of any scene that turns on DDGI global illumination: ``minimal+gi``, ``model.glb+gi``."""
NOGI_OPTION = "+nogi"
"""Suffix of any scene that turns global illumination off: ``default+nogi`` (the default scene has GI)."""
NOSUN_OPTION = "+nosun"
"""Suffix of any scene that turns its sun (the directional light and its shadows) off: ambient, point lights and
GI stay (``model.glb+nosun``: lit as QUASAR's llvmpipe build lights it, see ``docs/quasar.md``)."""
STILL_OPTION = "+still"
"""Suffix of any scene that stops its moving objects where they are at t = 0 (the lights keep their schedules)."""


def _with_gi(scene: Scene) -> None:
    scene.gi = "ddgi"


def _without_gi(scene: Scene) -> None:
    scene.gi = "none"


def _without_sun(scene: Scene) -> None:
    scene.sun = None


def _still(scene: Scene) -> None:
    for o in scene.objects:
        if o.animation is not None:
            o.transform, o.animation = np.asarray(o.model_matrix(0.0), np.float64).copy(), None


SCENE_OPTIONS = ((GI_OPTION, _with_gi), (NOGI_OPTION, _without_gi), (STILL_OPTION, _still), (NOSUN_OPTION, _without_sun))
"""The trailing options of a scene name, each with what it does to the scene (:func:`get_scene`)."""


def with_gi_spec(name_or_path: str) -> str:
    """``name_or_path`` with global illumination on, its path and other options kept: a trailing ``+nogi``
    becomes ``+gi``, otherwise ``+gi`` is appended (``duck.dae+ground`` -> ``duck.dae+ground+gi``)."""
    if name_or_path.endswith(NOGI_OPTION):
        return name_or_path[: -len(NOGI_OPTION)] + GI_OPTION
    return name_or_path + GI_OPTION


def scene_has_gi(name_or_path: str) -> bool:
    """Whether :func:`get_scene` gives scene ``name_or_path`` global illumination, from its name alone (no file is
    read): the last of ``+gi`` / ``+nogi`` wins, else a built-in scene's own setting (files have none)."""
    name = name_or_path
    while True:
        opt = next((o for o, _ in SCENE_OPTIONS if name.endswith(o)), None)
        if opt is None:
            return name in BUILTIN_GI
        if opt in (GI_OPTION, NOGI_OPTION):
            return opt == GI_OPTION
        name = name[: -len(opt)]


def get_scene(name_or_path: str) -> Scene:
    """A built-in scene by name (``default``, ``minimal``) or a scene file by path.

    A file is rescaled to 4 m (largest extent); ``path+ground`` adds a ground plane.
    Trailing options, in any order: ``+gi`` (``minimal+gi``) turns on DDGI global
    illumination (``Scene.gi``), ``+nogi`` turns it off (``default+nogi``: the default
    scene has it); ``+still`` stops every moving object at its t = 0 place (the lights
    still change: a light change with nothing else moving); ``+nosun`` turns the sun off.
    """
    for opt, apply in SCENE_OPTIONS:
        if name_or_path.endswith(opt):
            scene = get_scene(name_or_path[: -len(opt)])
            apply(scene)
            scene.name += opt
            scene.spec = name_or_path
            return scene
    if name_or_path in BUILTIN_SCENES:
        scene = BUILTIN_SCENES[name_or_path]()
        scene.spec = name_or_path
        return scene
    ground = name_or_path.endswith(GROUND_OPTION)
    path = name_or_path[: -len(GROUND_OPTION)] if ground else name_or_path
    if any(path.lower().endswith(s) for s in SUPPORTED_SUFFIXES) or os.sep in path:
        scene = load_scene_file(path, target_size_m=4.0, ground=ground)
        scene.spec = name_or_path
        return scene
    raise SceneError(f"unknown scene {name_or_path!r}: use one of {sorted(BUILTIN_SCENES)} or a path to a {'/'.join(SUPPORTED_SUFFIXES)} file")
