"""The headless renderer: a known plane's depth and colour, ids, shading parity, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from splitrender.errors import RenderError
from splitrender.render.gl import read_shader
from splitrender.scene.model import Material, Scene, SceneObject
from splitrender.scene.pose import CameraIntrinsics, Pose, quat_from_euler_deg
from splitrender.scene.primitives import grid_plane


def _wall_scene(color=(0.5, 0.5, 0.5), distance=4.0) -> Scene:
    """A large plane facing +Z at z = -distance, lit only by ambient light."""
    plane = grid_plane(40.0, 40.0, 2, 2)
    m = np.eye(4)
    m[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # rotate +Y normal to +Z
    m[:3, 3] = (0, 0, -distance)
    obj = SceneObject("wall", plane, Material("grey", color, None, specular=0.0), 1, m)
    return Scene("wall", [obj], sun=None, point_lights=[], ambient=(1.0, 1.0, 1.0))


def test_plane_depth_is_exact(renderer):
    intr = CameraIntrinsics(160, 90, 60.0)
    out = renderer.render(_wall_scene(distance=4.0), 0.0, Pose(), intr, ("color", "depth", "object_id", "triangle_id", "normal"))
    assert out.depth is not None and out.object_id is not None
    # view-space depth of a fronto-parallel plane is its distance everywhere
    assert np.allclose(out.depth, 4.0, atol=1e-3), f"depth range {out.depth.min()}..{out.depth.max()}"
    assert (out.object_id == 1).all()
    assert out.triangle_id.min() >= 1 and out.triangle_id.max() <= 8
    assert np.allclose(out.normal, [0, 0, 1], atol=1e-2)


def test_plane_colour_matches_pbr_model(renderer):
    """Metallic-roughness, ambient only, at the centre pixel (n = v = +Z, reflection horizontal):
    diffuse albedo 0.5 * 0.75 plus the environment BRDF (Karis' fit, f0 0.04, roughness 0.6, n.v 1)
    times the environment, the ambient mixed towards the sky by smoothstep(-0.2, 0.4, 0) * (1 - 0.7 * 0.6)."""
    intr = CameraIntrinsics(160, 90, 60.0)
    scene = _wall_scene((0.5, 0.5, 0.5))
    assert scene.shading == "pbr"
    out = renderer.render(scene, 0.0, Pose(), intr)
    rough, ndv, f0 = 0.6, 1.0, 0.04
    r = rough * np.array([-1.0, -0.0275, -0.572, 0.022]) + np.array([1.0, 0.0425, 1.04, -0.04])
    a004 = min(r[0] * r[0], 2 ** (-9.28 * ndv)) * r[0] + r[1]
    env_brdf = f0 * (-1.04 * a004 + r[2]) + (1.04 * a004 + r[3])
    s = 1 / 3
    w = (3 * s * s - 2 * s ** 3) * (1 - 0.7 * rough)
    env = (1 - w) * 1.0 + w * np.array(scene.sky_color) ** 2.2
    c = 0.5 * 0.75 + env_brdf * env
    c = c / (1 + 0.15 * c)
    expect = 255 * c ** (1 / 2.2)
    got = out.color[44:46, 79:81].reshape(-1, 3).mean(axis=0)
    assert np.allclose(got, expect, atol=1.5), f"got {got}, expected {expect}"


def test_plane_colour_matches_shading_model(renderer):
    # Blinn-Phong: ambient (1,1,1) * albedo 0.5 * (0.75 + 0.25 * n.y=0) -> 0.375 linear, tone mapped c/(1+0.15c), sRGB 2.2 gamma
    intr = CameraIntrinsics(160, 90, 60.0)
    scene = _wall_scene((0.5, 0.5, 0.5))
    scene.shading = "phong"
    out = renderer.render(scene, 0.0, Pose(), intr)
    c = 0.5 * 0.75
    c = c / (1 + 0.15 * c)
    expect = 255 * c ** (1 / 2.2)
    got = out.color.reshape(-1, 3).mean(axis=0)
    assert np.allclose(got, expect, atol=1.5), f"got {got}, expected {expect:.1f}"


def test_background_and_orientation(renderer):
    # A camera looking away from the wall (+Z) sees only sky: depth inf and object id 0.
    scene = _wall_scene()
    intr = CameraIntrinsics(64, 36, 60.0)
    up = Pose(np.zeros(3), quat_from_euler_deg(0.0, 180.0, 0.0))
    out = renderer.render(scene, 0.0, up, intr, ("color", "depth", "object_id"))
    assert np.isinf(out.depth).all() and (out.object_id == 0).all()
    sky = np.round(255 * np.array(scene.sky_color))
    assert np.abs(out.color.astype(float) - sky).max() <= 1


def test_image_rows_start_at_the_top(renderer):
    # A camera above the default floor pitched down 20 degrees: floor fills the bottom rows, sky the top ones.
    from splitrender.scene.procedural import minimal_scene

    intr = CameraIntrinsics(64, 36, 60.0)
    pose = Pose(np.array([0.0, 1.0, 2.0]), quat_from_euler_deg(-5.0, 0.0, 0.0))
    out = renderer.render(minimal_scene(), 0.0, pose, intr, ("object_id",))
    assert (out.object_id[-1] > 0).all(), "bottom row should be floor"
    assert (out.object_id[0] == 0).all(), "top row should be sky"


def test_depth_matches_projection_for_a_tilted_view(renderer):
    # floor at y=0 seen from height h, pitched down: depth along -Z of the centre pixel = h / sin(pitch) * 1
    intr = CameraIntrinsics(64, 36, 60.0)
    h, pitch = 1.5, 30.0
    pose = Pose(np.array([0.0, h, 0.0]), quat_from_euler_deg(-pitch, 0.0, 0.0))
    floor = SceneObject("floor", grid_plane(40.0, 40.0, 2, 2), Material(), 1)
    out = renderer.render(Scene("floor", [floor], sun=None), 0.0, pose, intr, ("depth",))
    centre = float(out.depth[17:19, 31:33].mean())
    expect = h / math.sin(math.radians(pitch))
    assert abs(centre - expect) < 0.05, f"centre depth {centre:.3f} m, expected {expect:.3f} m"


def test_moving_objects_move(renderer):
    from splitrender.scene.procedural import default_scene

    scene = default_scene()
    intr = CameraIntrinsics(160, 90, 60.0)
    pose = Pose(np.array([0.0, 1.6, 2.5]))
    a = renderer.render(scene, 0.0, pose, intr, ("object_id",)).object_id
    b = renderer.render(scene, 0.5, pose, intr, ("object_id",)).object_id
    ball = scene.objects[[o.name for o in scene.objects].index("ball")].object_id
    ya, xa = np.nonzero(a == ball)
    yb, xb = np.nonzero(b == ball)
    assert xa.size and xb.size
    assert abs(xb.mean() - xa.mean()) > 5, "the patrolling ball should move across the view in 0.5 s"


def test_light_change_changes_the_image(renderer):
    from splitrender.scene.procedural import default_scene

    scene = default_scene()
    intr = CameraIntrinsics(160, 90, 60.0)
    pose = Pose(np.array([0.0, 1.6, 2.5]))
    bright = renderer.render(scene, 1.0, pose, intr).color.astype(float).mean()
    dim = renderer.render(scene, 5.5, pose, intr).color.astype(float).mean()
    assert bright - dim > 10, f"sun dims between 4 and 5 s: mean {bright:.1f} -> {dim:.1f}"


def test_unknown_output_and_shader_errors(renderer, tmp_path):
    with pytest.raises(ValueError, match="unknown render output 'albedo'"):
        renderer.render(_wall_scene(), 0.0, Pose(), CameraIntrinsics(32, 18), ("albedo",))
    a = tmp_path / "a.glsl"
    a.write_text('#include "a.glsl"\n')
    with pytest.raises(RenderError, match="include cycle"):
        read_shader(a)


def test_no_egl_gives_a_clear_error(monkeypatch):
    import moderngl

    from splitrender.render import gl

    def boom(*a, **kw):
        raise Exception("eglGetDisplay failed")

    monkeypatch.setattr(moderngl, "create_context", boom)
    with pytest.raises(RenderError, match="OpenGL 4.3 context through EGL.*libegl1"):
        gl.create_context()


def test_sun_casts_shadows_from_static_and_moving_casters(renderer):
    from splitrender.scene.model import DirectionalLight, Oscillate
    from splitrender.scene.primitives import box

    # A floor, two 1 m slabs 1 m above it, a sun travelling along (1, -1, 0): each slab's
    # shadow falls 1 m to its +x side.  A camera 8 m above looks straight down (+x right, -z up).
    floor = SceneObject("floor", grid_plane(20.0, 20.0, 2, 2), Material("floor", (0.8, 0.8, 0.8), None, specular=0.0), 1)
    m = np.eye(4)
    m[:3, 3] = (-1.5, 1.0, -4.0)
    still = SceneObject("still", box((1.0, 0.2, 1.0)), Material(), 2, m.copy())
    m[:3, 3] = (1.5, 1.0, -4.0)
    moving = SceneObject("moving", box((1.0, 0.2, 1.0)), Material(), 3, m.copy(), Oscillate((0, 0, 1), 1.5, 4.0))
    sun = DirectionalLight(direction=(1.0, -1.0, 0.0), shadow_map_size=1024, shadow_extent_m=10.0)
    scene = Scene("shadows", [floor, still, moving], sun=sun, ambient=(0.2, 0.2, 0.2))
    intr = CameraIntrinsics(96, 96, 60.0)
    top = Pose(np.array([0.0, 8.0, -4.0]), quat_from_euler_deg(-90.0, 0.0, 0.0))

    def floor_at(t, x):
        out = renderer.render(scene, t, top, intr, ("color", "object_id"))
        col = int(round(48 + x * intr.focal_px() / 8.0))
        ids = out.object_id[47:50, col - 1 : col + 2]
        assert (ids == 1).all(), f"expected to see the floor at x={x} m, t={t} s: {ids}"
        return float(out.color[47:50, col - 1 : col + 2].astype(float).mean())

    lit = floor_at(0.0, -3.5)
    shaded = floor_at(0.0, -0.5)
    assert lit - shaded > 30, f"static caster: lit {lit:.0f} vs shadowed {shaded:.0f}"
    # the moving slab leaves z = -4 (it is at z = -2.5 at t = 1 s): its shadow goes with it
    before = floor_at(0.0, 2.5)
    after = floor_at(1.0, 2.5)
    assert after - before > 30, f"moving caster's shadow should leave (2.5, -4): {before:.0f} -> {after:.0f}"
    assert abs(after - lit) < 5, f"once the shadow left, the floor is lit again: {after:.0f} vs {lit:.0f}"


def test_supersampling_averages_blocks_and_keeps_ids_at_pixel_centres(renderer):
    """``supersample = 2``: colour is the rounded mean of each 2x2 block of a render at twice the size;
    depth and ids come from one sample per block; edges get intermediate colours (anti-aliasing)."""
    from splitrender.scene import default_scene
    from splitrender.scene.trace import get_trace

    scene, intr = default_scene(), CameraIntrinsics(160, 90, 60.0)
    pose = get_trace("walk", 1.0).pose_at(0.5)
    outs = ("color", "depth", "object_id")
    big = renderer.render(scene, 0.5, pose, CameraIntrinsics(320, 180, 60.0), outs)
    one = renderer.render(scene, 0.5, pose, intr, outs)
    renderer.supersample = 2
    try:
        two = renderer.render(scene, 0.5, pose, intr, outs)
    finally:
        renderer.supersample = 1
    blocks = big.color.reshape(90, 2, 160, 2, 3)
    mean = (blocks.astype(np.uint32).sum(axis=(1, 3)) + 2) // 4
    assert two.color.shape == (90, 160, 3) and np.array_equal(two.color, mean.astype(np.uint8))
    assert np.array_equal(two.object_id, big.object_id[1::2, 1::2]) and np.array_equal(two.depth, big.depth[1::2, 1::2])
    # anti-aliasing changes pixels along edges much more than the interiors (a finer mip level moves those a little)
    d = np.abs(two.color.astype(int) - one.color.astype(int)).max(axis=-1)
    assert np.median(d) <= 2 and 0.04 < (d > 24).mean() < 0.15, ((d > 24).mean(), np.median(d))  # measured: 1, 8.3%


def test_shade_gives_the_one_pass_colour_of_a_gbuffer_drawn_without_it(renderer):
    """``Renderer.shade``: a G-buffer drawn without colour (no shading at all) and then shaded over its own depths and
    triangle ids gives one pass's colour to the bit, its depth, normals and ids the same too; with ``where`` only
    those pixels are shaded (sky on the background elsewhere, black on surfaces).  Also for a depth-peeled layer and
    after another render drew over the G-buffer (it is drawn again)."""
    from splitrender.scene import default_scene
    from splitrender.scene.trace import get_trace

    scene, intr = default_scene(), CameraIntrinsics(160, 90, 60.0)
    tr = get_trace("walk", 2.0)
    outs = ("depth", "normal", "object_id", "triangle_id")
    for t in (0.3, 1.4):
        pose = tr.pose_at(t)
        one = renderer.render(scene, t, pose, intr, ("color", *outs))
        g = renderer.render(scene, t, pose, intr, outs)
        assert g.color.size == 0
        for k in outs:
            assert np.array_equal(getattr(g, k), getattr(one, k)), k
        assert np.array_equal(renderer.shade(g), one.color)
        peel_one = renderer.render(scene, t, pose, intr, ("color", "depth"), peel=one.depth)
        peel = renderer.render(scene, t, pose, intr, ("depth",), peel=one.depth)
        assert np.array_equal(peel.depth, peel_one.depth, equal_nan=True)
        where = np.zeros((90, 160), bool)
        where[20:60, 30:110] = True
        c = renderer.shade(peel, where)
        assert np.array_equal(c[where], peel_one.color[where])
        sky = np.round(np.asarray(scene.sky_color) * 255)
        bg, fg = ~where & ~np.isfinite(peel.depth), ~where & np.isfinite(peel.depth)
        assert bg.any() and fg.any() and (np.abs(c[bg] - sky) <= 1).all() and (c[fg] == 0).all()
        # the masked shading moved g's depth buffer and the peel render drew over it: both drawn again
        assert np.array_equal(renderer.shade(peel), peel_one.color)
        assert np.array_equal(renderer.shade(g), one.color)
    with pytest.raises(ValueError, match="no colour"):
        renderer.shade(one)
    with pytest.raises(ValueError, match="where must be"):
        renderer.shade(g, np.ones((10, 10), bool))
