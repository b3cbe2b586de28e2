"""The QUASAR client's sky behind the model's silhouette (issue 50, part 2: bleed on the peer benchmark).

Without sky quads there, the background a moving client reveals next to a silhouette was a hole, and the hole fill
took the model's colour wherever a sliver of it lay on the epipolar line: the model bled over the background."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from splitrender.scene.pose import CameraIntrinsics, Pose

INTR = CameraIntrinsics(320, 180)


def test_hidden_sky_lies_behind_the_model_near_the_sky_and_takes_the_nearest_sky_texel() -> None:
    """A 100x60 block of model pixels in a 320x180 view of sky: the hidden sky covers the block's pixels within the
    reach of the sky (a ring 8 pixels wide: 100*60 - 84*44 = 2,304 pixels), each quad on the far plane, coloured
    by the sky texel nearest its centre (outside the block, within one quad's size of it, in the slot); none with
    reach 0 or when the set covers the whole view."""
    from splitrender.methods.quads.config import QuadParams
    from splitrender.methods.quads.gen import BACKGROUND_FAR, generate
    from splitrender.methods.quads.mesh import HIDDEN_SKY_PX, hidden_sky, rasterize

    assert HIDDEN_SKY_PX == 8
    depth = np.full((INTR.height, INTR.width), np.inf)
    depth[60:120, 100:200] = 3.0
    normal = np.zeros((INTR.height, INTR.width, 3))
    normal[..., 2] = 1.0
    model = generate(depth, normal, np.eye(3), INTR, QuadParams())
    origin = (320, 0)                                                      # the set's slot in the atlas
    sky, texel = hidden_sky(model, INTR, origin)
    cover = np.full((INTR.height, INTR.width), -1, np.int64)
    rasterize(cover, sky, 0)
    ring = np.zeros_like(depth, bool)
    ring[60:120, 100:200] = True
    ring[68:112, 108:192] = False
    assert ((cover >= 0) == ring).all() and sky.pixels() == 2304
    assert sky.flat.all() and np.allclose(sky.depth, BACKGROUND_FAR * INTR.far_m)
    tx, ty = texel[:, 0] - origin[0], texel[:, 1] - origin[1]
    inside = (ty >= 60) & (ty < 120) & (tx >= 100) & (tx < 200)
    assert not inside.any()
    size = 1 << sky.level.astype(np.int64)
    cx, cy = sky.x + size // 2, sky.y + size // 2
    assert (np.hypot(tx - cx, ty - cy) <= 8 + size).all()
    assert len(hidden_sky(model, INTR, origin, reach=0)[0]) == 0
    full = generate(np.full_like(depth, 3.0), normal, np.eye(3), INTR, QuadParams())
    assert len(hidden_sky(full, INTR, origin)[0]) == 0


def test_a_strafing_client_shows_the_sky_it_reveals_beside_a_silhouette(renderer, one_frame) -> None:  # type: ignore[no-untyped-def]
    """A grey ball 1.2 m across, 3 m away, before the sky; a QUASAR reference frame (lossless) at the origin, the
    client 0.15 m to the side.  Holes measured: 4 with the hidden sky, 519 without it (reach 0, as before: the
    revealed strip, which the hole fill paints with the sky here, as no sliver of the ball lies on its scan lines:
    bleed 0 either way; on a real model it does not, next test).  At the server's pose both draw the same picture."""
    from splitrender.methods import get_method, make_config
    from splitrender.methods.quads import mesh as quads_mesh
    from splitrender.scene import primitives as P
    from splitrender.scene.model import DirectionalLight, Material, Scene, SceneObject

    at = np.eye(4)
    at[:3, 3] = (0.0, 0.0, -3.0)
    scene = Scene("box", [SceneObject("ball", P.uv_sphere(0.6, 24, 48), Material("grey", (0.4, 0.4, 0.4)), 1, at)],
                  DirectionalLight(direction=(-0.3, -1.0, -0.5)), [])
    pose = Pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
    side = Pose(np.array([0.15, 0.0, 0.0]), pose.orientation)
    spec = get_method("quads")
    truth = renderer.render(scene, 0.0, side, INTR, ("color", "object_id"))
    sky = truth.object_id == 0
    sky_colour = np.median(truth.color[sky], axis=0)
    got = {}
    keep = quads_mesh.HIDDEN_SKY_PX
    for reach in (keep, 0):
        cfg = make_config(spec.config, {"lossless": True, "hidden_sky_px": reach})
        cli = one_frame("quads", cfg, INTR, scene, pose)
        moved = cli.render(side, 0.0)
        bleed = sky & (np.abs(moved.color.astype(np.int16) - sky_colour).max(-1) > 6)
        got[reach] = (int(bleed.sum()), int(moved.holes.sum()), cli.render(pose, 0.0).color)
    (b1, h1, at1), (b0, h0, at0) = got[keep], got[0]
    assert b1 == 0 and b0 == 0 and h1 <= 40 and h0 >= 400, (b1, h1, b0, h0)
    assert (at1 == at0).all()


WUSON = Path("/usr/share/assimp/models/PLY/Wuson.ply")


@pytest.mark.skipif(not WUSON.exists(), reason="assimp-testmodels is not installed")
def test_the_model_bleeds_less_over_the_sky_it_reveals(renderer, one_frame) -> None:  # type: ignore[no-untyped-def]
    """assimp's Wuson unlit (``+nosun``, no ground), the peer benchmark's fitted strafe; QUASAR reference frames
    (lossless) at 1, 2, 3 and 4 s, the client 0.1 and 0.15 s further on.  Background pixels drawn as something else
    than the sky, over the model's pixels, measured: 4.0 % with the hidden sky, 11.2 % without it (reach 0, as
    before); model pixels drawn as sky 1.27 % against 0.73 % (the sky now also shows where the model reveals more
    of itself near its silhouette, as QUASAR's code shows its background there).  Bounds: with it at most half the
    bleed without it, and the missed pixels under 1.5 %."""
    from splitrender.methods import get_method, make_config
    from splitrender.methods.quads import mesh as quads_mesh
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    scene = get_scene(f"{WUSON}+nosun")
    trace = get_trace("strafe", duration_s=5.0, scene=scene, fov_y_deg=60, aspect=320 / 180)
    spec = get_method("quads")
    keep = quads_mesh.HIDDEN_SKY_PX
    got = {}
    for reach in (keep, 0):
        cfg = make_config(spec.config, {"lossless": True, "hidden_sky_px": reach})
        tot = np.zeros(3)
        for t0 in (1.0, 2.0, 3.0, 4.0):
            pose = trace.pose_at(t0)
            cli = one_frame("quads", cfg, INTR, scene, pose, t0)
            for dt in (0.1, 0.15):
                p = trace.pose_at(t0 + dt)
                shown = cli.render(p, t0 + dt).color
                truth = renderer.render(scene, t0 + dt, p, INTR, ("color", "object_id"))
                model = truth.object_id > 0
                drawn = np.abs(shown.astype(np.int16) - np.median(truth.color[~model], axis=0)).max(-1) > 6
                tot += (model.sum(), (model & ~drawn).sum(), (~model & drawn).sum())
        got[reach] = (100 * tot[1] / tot[0], 100 * tot[2] / tot[0])
    (m1, b1), (_, b0) = got[keep], got[0]
    assert b1 < 0.5 * b0 and m1 < 1.5, got


def test_the_reference_sets_lookup_stops_at_the_silhouette_against_the_sky() -> None:
    """``scene_sides`` (``silhouette_clamp``, issue 50): a 100x60 block of model pixels in a 320x180 view of sky.  A
    quad's lookup may filter half a texel across each side whose neighbouring pixel is the model, none across a side
    that borders the sky (or the view's edge), so an edge quad seen from another pose never blends in the sky texels
    beside it.  Counted exactly: every side of every quad, against the block's outline; the same with the sky sent
    as quads (``background_quads``), where the sky's own quads keep their blend among themselves."""
    from splitrender.methods.quads.config import QuadParams
    from splitrender.methods.quads.gen import generate
    from splitrender.methods.quads.mesh import scene_sides

    depth = np.full((INTR.height, INTR.width), np.inf)
    depth[60:120, 100:200] = 3.0
    normal = np.zeros((INTR.height, INTR.width, 3))
    normal[..., 2] = 1.0
    block = np.isfinite(depth)
    for background in (False, True):
        qs = generate(depth, normal, np.eye(3), INTR, QuadParams(), background=background)
        grow = scene_sides(qs, INTR)
        assert grow.shape == (len(qs), 4) and set(np.unique(grow)) <= {0.0, 0.5}
        model = ~qs.background(INTR)
        assert model.sum() > 0 and (background == bool((~model).any()))
        for i in range(len(qs)):
            x, y, s = int(qs.x[i]), int(qs.y[i]), 1 << int(qs.level[i])
            inside = block[y, x]
            # left, top, right, bottom: the pixels just across each side, all inside the view and of the same kind
            across = [(y, y + s, x - 1, x), (y - 1, y, x, x + s), (y, y + s, x + s, x + s + 1), (y + s, y + s + 1, x, x + s)]
            for side, (y0, y1, x0, x1) in enumerate(across):
                in_view = y0 >= 0 and x0 >= 0 and y1 <= INTR.height and x1 <= INTR.width
                same = in_view and bool((block[y0:y1, x0:x1] == inside).all())
                assert grow[i, side] == (0.5 if same else 0.0), (background, i, side)
