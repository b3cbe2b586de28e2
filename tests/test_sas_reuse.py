"""``sas`` shades only the blocks whose texels change (issue 49, ``SasConfig.shade_changed_only``): the atlas is
bit for bit the one shading every block every frame gives, on a still camera with moving objects and their
shadows (few blocks drawn), a moving camera (every block drawn) and the default scene's GI."""

from __future__ import annotations

import numpy as np
import pytest

import splitrender.methods.sas.server as sas_server
from splitrender.methods.base import ServerContext
from splitrender.methods.sas import SasConfig, SasServer
from splitrender.render.renderer import Renderer
from splitrender.scene.loader import get_scene
from splitrender.scene.pose import CameraIntrinsics
from splitrender.scene.trace import get_trace

INTR = CameraIntrinsics(160, 90)


def _run(scene_name: str, trace: str, frames: int, t0: float = 0.5) -> tuple[list[int], list[float], list[float]]:
    """Both settings side by side: per frame the texels (atlas pixels) that differ, the share of live patches the
    reusing server drew and the live patches."""
    r = Renderer()
    scene = get_scene(scene_name)
    tr = get_trace(trace)
    srvs = [SasServer(SasConfig(shade_changed_only=on), INTR, scene, 30) for on in (False, True)]
    diff, share, live = [], [], []
    for f in range(frames):
        t = t0 + f / 30
        pose = tr.pose_at(t)
        atl = []
        for srv in srvs:
            ctx = ServerContext(f, t, scene, r, INTR, pose, t, pose, t, tr.pose_at, 0.0)
            atl.append(srv.produce(ctx).planes["atlas"])
        diff.append(int((atl[0] != atl[1]).any(axis=2).sum()))
        st = srvs[1].stats()
        n = int(srvs[1]._texels_ok.sum())   # the live patches
        share.append(st["shaded_patches"] / max(n, 1))
        live.append(float(n))
    return diff, share, live


def test_still_camera_reuses_blocks_bit_for_bit() -> None:
    """Still camera on the default scene (moving torus, ball and bobber casting shadows): identical atlases; after
    the I-frame a P-frame draws a small share of the blocks (measured 0.10-0.15 at 160x90: the moving objects and
    the still patches under their shadows' light-space boxes)."""
    diff, share, _ = _run("default+nogi", "static", 6)
    assert diff == [0] * 6, diff
    assert share[0] == 1.0
    assert max(share[1:]) < 0.2, share


def test_moving_shadows_are_redrawn(monkeypatch: pytest.MonkeyPatch) -> None:
    """The shadow-caster test is what keeps the still patches under the moving objects' shadows right: without it
    texels differ (34-74 a frame measured), so the test above would see a missed block."""
    monkeypatch.setattr(sas_server, "rects_overlap", lambda a, b: np.zeros(a.shape[0], bool))
    diff, _, _ = _run("default+nogi", "static", 3)
    assert diff[0] == 0 and min(diff[1:]) > 10, diff


@pytest.mark.slow
def test_moving_camera_and_gi_draw_every_block() -> None:
    """A moving eye changes every view-dependent texel (specular, texture filtering), and relit probes every texel:
    every live block is drawn and the atlases are identical."""
    diff, share, _ = _run("default+nogi", "walk", 3)
    assert diff == [0] * 3 and share == [1.0] * 3, (diff, share)
    diff, share, _ = _run("default", "static", 3, t0=5.9)
    assert diff == [0] * 3 and share == [1.0] * 3, (diff, share)
