"""The DDGI visibility weights' floor (``render.ddgi.VIS_WEIGHT_FLOOR``): dropping the weights below it leaves the
probes' moments the same bits and takes the subnormal products out of their matrix product (what made it slow)."""

from __future__ import annotations

import numpy as np

from splitrender.render.ddgi import SHARPNESS, VIS_CORE, VIS_WEIGHT_FLOOR, flush_subnormal
from splitrender.render.octa import cube_directions, texel_directions, visibility_weights
from splitrender.render.renderer import Renderer
from splitrender.scene.loader import get_scene

TIMES = (0.0, 2.6, 4.4, 6.1, 7.7)
"""Scene times on the default walk's span: the moving objects elsewhere, the sun dimming (4-5 s), the lamp on (6 s)."""


def test_the_visibility_floor_keeps_the_moments_bits_and_no_product_is_subnormal() -> None:
    """The moments derived with every normal weight (the floor at float32's smallest normal, as before) and with
    the weights under :data:`VIS_WEIGHT_FLOOR` dropped are equal bit for bit at each time, and with the floor no
    weight times a ray's distance or its square is subnormal (without it 5,680 weights can make one)."""
    vol = Renderer().gi_volume(get_scene("default"))        # a renderer of its own: the test rewrites its G-buffer
    assert vol is not None and vol._moving
    tiny = float(np.finfo(np.float32).tiny)
    w_floor = vol._w_vis
    dirs, omega = cube_directions(vol.settings.face_res)
    w_normal = flush_subnormal(visibility_weights(texel_directions(VIS_CORE), dirs, omega, SHARPNESS).astype(np.float32))
    dropped = (w_normal != 0) & (w_floor == 0)
    assert dropped.sum() > 1000 and np.array_equal(w_floor[~dropped], w_normal[~dropped])
    smallest = float(np.abs(w_floor[w_floor != 0]).min())
    for t in TIMES:
        vol._w_vis = w_normal
        vol._capture_moving(t)
        before = (vol.active.copy(), vol.moments.copy())
        vol._w_vis = w_floor
        vol._capture_moving(t)
        assert np.array_equal(before[0], vol.active) and np.array_equal(before[1], vol.moments), t
        pos = vol._per_ray(vol._read(vol._cap)[0])
        d = np.linalg.norm(pos[..., :3] - vol.positions[:, None, :], axis=-1)
        near = float(d[(pos[..., 3] > 0.5) & (d > 0)].min()) * 0.2    # back faces pull a distance in to a fifth
        assert smallest * min(near, near * near) >= tiny, (t, smallest, near)
    assert VIS_WEIGHT_FLOOR > tiny
