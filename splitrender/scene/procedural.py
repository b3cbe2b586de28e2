"""Procedural scenes.

``default_scene()`` is small (about 20k triangles) but built to exercise what split
rendering methods fail on:

- occluders at several depths (pillars and crates at 2.5 to 9 m): disocclusions;
- a thin railing (2 cm posts and bars) right in front of the camera: thin structures;
- a slanted ramp and a tilted sign panel: slanted surfaces, anisotropic sampling;
- brick, checker, noise-stripe and glyph textures: codec stress;
- three moving objects: a spinning torus, a sphere crossing the view at 2.5 m/s,
  and a bobbing crate;
- a light change: the sun dims from t=4 s to 5 s and recovers at 8 s; a point light
  switches on at t=6 s;
- global illumination: DDGI light probes (``Scene.gi = "ddgi"``) whose bounce light
  follows the moving objects and the light change; ``default+nogi`` (``default_scene(gi=False)``)
  is the same scene with the constant ambient term, for what does not need GI.

The camera's walkable box is x in [-3, 3], z in [-4, 3] at eye height 1.6 m, looking
towards -Z (see ``splitrender.scene.trace``).  ``minimal_scene()`` is one textured
plane and one box, for tests that need no more; ``default_phong`` is the default scene with
the older Blinn-Phong shading (``Scene.shading = "phong"``) and no GI, for comparison.
"""

from __future__ import annotations

import math

import numpy as np

from . import primitives as P
from . import textures as T
from .model import DirectionalLight, Material, Mesh, Oscillate, Patrol, PointLight, Scene, SceneObject, Schedule, Spin, merge_meshes
from .pose import quat_from_axis_angle, quat_to_matrix3


def _tr(x: float, y: float, z: float, rot_axis=None, rot_deg: float = 0.0) -> np.ndarray:
    m = np.eye(4)
    if rot_axis is not None:
        m[:3, :3] = quat_to_matrix3(quat_from_axis_angle(np.array(rot_axis, float), math.radians(rot_deg)))
    m[:3, 3] = (x, y, z)
    return m


def default_scene(gi: bool = True) -> Scene:
    """The default scene, with DDGI global illumination unless ``gi`` is False (``--scene default+nogi``)."""
    sign = T.text_panel(256, seed=3)
    mats = {  # (Blinn-Phong specular and shininess for shading = "phong"; metallic-roughness for "pbr")
        "floor": Material("floor", (0.9, 0.9, 0.9), T.checker(256, 8), roughness=0.35),   # glossy tiles
        "brick": Material("brick", (1.0, 1.0, 1.0), T.bricks(256, 8, seed=1), roughness=0.85),
        "stripes": Material("stripes", (1.0, 1.0, 1.0), T.noise_stripes(256, seed=2), roughness=0.6),
        "sign": Material("sign", (1.0, 1.0, 1.0), sign, specular=0.05, roughness=0.4,           # a lit display
                         emissive=(0.8, 0.8, 0.8), emissive_texture=sign),
        "concrete": Material("concrete", (0.62, 0.6, 0.58), None, specular=0.1, roughness=0.9),
        "metal": Material("metal", (0.75, 0.76, 0.8), None, specular=0.8, shininess=64.0, metallic=1.0, roughness=0.3),
        "red": Material("red", (0.8, 0.12, 0.1), None, specular=0.5, roughness=0.15),          # glossy plastic
        "gold": Material("gold", (0.9, 0.7, 0.2), None, specular=0.9, shininess=64.0, metallic=1.0, roughness=0.25),
    }
    objs: list[SceneObject] = []

    def add(name: str, mesh: Mesh, mat: str, transform: np.ndarray | None = None, animation=None) -> None:
        objs.append(SceneObject(name, mesh, mats[mat], len(objs) + 1, np.eye(4) if transform is None else transform, animation,
                                backdrop=name == "floor"))

    add("floor", P.grid_plane(16.0, 16.0, 64, 64, uv_scale_m=2.0), "floor", _tr(0, 0, -4))
    add("back_wall", P.box((16.0, 5.0, 0.3), uv_scale_m=2.0, subdiv=8), "brick", _tr(0, 2.5, -12))
    add("left_wall", P.box((0.3, 5.0, 16.0), uv_scale_m=2.0, subdiv=8), "brick", _tr(-8, 2.5, -4))
    add("right_wall", P.box((0.3, 5.0, 16.0), uv_scale_m=1.5, subdiv=8), "stripes", _tr(8, 2.5, -4))
    # occluders at several depths
    for i, (x, z) in enumerate([(-1.5, -3.0), (1.8, -5.5), (-3.0, -8.0), (0.6, -9.5)]):
        add(f"pillar{i}", P.box((0.6, 3.2, 0.6), uv_scale_m=1.0, subdiv=4), "concrete" if i % 2 else "brick", _tr(x, 1.6, z))
    add("crate0", P.box((1.0, 1.0, 1.0), uv_scale_m=1.0, subdiv=4), "stripes", _tr(2.6, 0.5, -2.6, (0, 1, 0), 20))
    add("crate1", P.box((1.2, 1.2, 1.2), uv_scale_m=1.2, subdiv=4), "stripes", _tr(-2.6, 0.6, -6.2, (0, 1, 0), -35))
    # slanted surfaces
    add("ramp", P.box((2.0, 0.1, 4.0), uv_scale_m=1.0, subdiv=8), "floor", _tr(4.5, 0.9, -7.0, (1, 0, 0), 25))
    add("sign", P.box((2.4, 1.4, 0.05), uv_scale_m=2.4, subdiv=6), "sign", _tr(-4.2, 2.2, -4.5, (0, 1, 0), 55))
    # thin railing in front of the camera
    posts = [P.translate(P.cylinder(0.02, 1.0, 12, caps=False), (x, 0.5, 0.0)) for x in np.arange(-3.0, 3.01, 0.5)]
    bars = [P.translate(P.cylinder(0.015, 6.0, 10, caps=False, axis="x"), (0.0, y, 0.0)) for y in (0.5, 1.0)]
    add("railing", merge_meshes(posts + bars, "railing"), "metal", _tr(0, 0, -1.3))
    # moving objects
    add("torus", P.torus(0.45, 0.15, 48, 16), "gold", _tr(-0.6, 1.4, -4.6, (1, 0, 0), 70), Spin((0.3, 1.0, 0.2), 1.6, (-0.6, 1.4, -4.6)))
    add("ball", P.uv_sphere(0.35, 24, 48), "red", _tr(0, 0.9, -3.6), Patrol((-4.0, 0.0, 0.0), (4.0, 0.0, 0.0), 2.5))
    add("bobber", P.box((0.7, 0.7, 0.7), uv_scale_m=0.7, subdiv=4), "stripes", _tr(3.2, 1.0, -8.5), Oscillate((0, 1, 0), 0.5, 3.0))
    sun = DirectionalLight(
        direction=(-0.35, -1.0, -0.45),
        intensity=Schedule((0.0, 4.0, 5.0, 8.0, 9.0), (2.6, 2.6, 0.9, 0.9, 2.6)),
    )
    lamp = PointLight(position=(0.5, 2.6, -6.5), color=(1.0, 0.75, 0.45), intensity=Schedule((0.0, 6.0, 6.2), (0.0, 0.0, 6.0)), range_m=9.0)
    return Scene("default", objs, sun, [lamp], gi="ddgi" if gi else "none")


def minimal_scene() -> Scene:
    """A textured floor and one box: the least a renderer or codec test needs."""
    floor = SceneObject("floor", P.grid_plane(10.0, 10.0, 4, 4, 1.0), Material("floor", (1, 1, 1), T.checker(128, 8)), 1, _tr(0, 0, -3),
                        backdrop=True)
    cube = SceneObject("cube", P.box((1.0, 1.0, 1.0)), Material("cube", (0.8, 0.2, 0.2)), 2, _tr(0, 0.5, -3))
    return Scene("minimal", [floor, cube], DirectionalLight(shadow_map_size=1024, shadow_extent_m=8.0), [])


def shed_scene() -> Scene:
    """A closed shed (4 x 3 x 4 m, walls 10 cm thick) on a sunlit 8 m floor under a blue sky: the light-leak case
    of DDGI's visibility test.  With ``+gi`` the default probe grid is 4 x 2 x 4, so the shed's walls run between
    the probes inside it and those outside; a point inside by a wall takes light from both unless the
    visibility (Chebyshev) test rejects the ones beyond the wall."""
    mat = Material("plaster", (0.7, 0.7, 0.7), None, roughness=1.0)
    objs = [SceneObject("floor", P.grid_plane(8.0, 8.0, 8, 8), mat, 1, backdrop=True)]
    t, h, w = 0.1, 3.0, 4.0
    parts = [((t, h, w + t), (-w / 2, h / 2, 0.0)), ((t, h, w + t), (w / 2, h / 2, 0.0)), ((w + t, h, t), (0.0, h / 2, -w / 2)),
             ((w + t, h, t), (0.0, h / 2, w / 2)), ((w + t, t, w + t), (0.0, h, 0.0))]
    for i, (size, pos) in enumerate(parts):
        objs.append(SceneObject(("wall_w", "wall_e", "wall_n", "wall_s", "roof")[i], P.box(size), mat, i + 2, _tr(*pos)))
    return Scene("shed", objs, DirectionalLight(direction=(-0.3, -1.0, -0.2)), [], ambient=(0.6, 0.7, 0.9), gi_probes=(4, 2, 4))


def default_phong_scene() -> Scene:
    """The default scene shaded with the older Blinn-Phong model (base colour only), for comparison."""
    sc = default_scene(gi=False)
    sc.name, sc.shading = "default_phong", "phong"
    return sc


BUILTIN_SCENES = {"default": default_scene, "default_phong": default_phong_scene, "minimal": minimal_scene, "shed": shed_scene}
BUILTIN_GI = frozenset({"default"})
"""The built-in scenes that have global illumination unless ``+nogi`` is given (what their builders set)."""
