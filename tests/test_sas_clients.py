"""Several ``sas`` sessions on one server (issue 49, item 2): they share the scene producer (patches, the patch-id
pass, the shading programs, each frame's :class:`~splitrender.methods.sas.server.SasFrame`) and one renderer (its
shadow maps, GI probes and GL state), and each client's atlas and metadata are still the bytes it gets alone."""

from __future__ import annotations

import numpy as np
import pytest

import splitrender.methods.sas.server as sas_server
from splitrender.codecs.meta import pack_meta
from splitrender.methods.sas import SasConfig, SasServer
from splitrender.methods.sas.server import SasProducer
from splitrender.pipeline.direct import server_context
from splitrender.render.renderer import Renderer
from splitrender.scene.loader import get_scene
from splitrender.scene.pose import CameraIntrinsics
from splitrender.scene.trace import get_trace

INTR = CameraIntrinsics(160, 90)
OFFSETS = (0.0, 0.5, 1.0)
"""Each client's lead along the walk (seconds): three different views of the same scene time."""


def _updates(scene_name: str, clients: list[int], frames: int, r: Renderer) -> dict[int, list[bytes]]:
    """Per client of ``clients`` (indices into :data:`OFFSETS`), its updates' bytes (atlas and packed metadata), frame
    by frame, with those clients' sessions on one server: one producer, one renderer, produced in turn as the
    runner's server tick does."""
    scene = get_scene(scene_name)
    tr = get_trace("walk", scene=scene, aspect=INTR.width / INTR.height)
    prod = SasProducer(SasConfig(), scene, 30)
    halves = {c: SasServer(SasConfig(), INTR, scene, 30, producer=prod) for c in clients}
    out: dict[int, list[bytes]] = {c: [] for c in clients}
    for f in range(frames):
        t = 0.5 + f / 30
        shared = prod.prepare(f, t)
        for i, c in enumerate(clients):
            def at(s: float, c: int = c) -> object:
                return tr.pose_at(s + OFFSETS[c])
            pose = at(t)
            ctx = server_context(scene, r, INTR, pose, t_s=t, frame_id=f, predict=at, shared=shared, client=i)
            upd = halves[c].produce(ctx)
            out[c].append(np.ascontiguousarray(upd.planes["atlas"]).tobytes() + pack_meta(upd.meta))
    return out


@pytest.mark.parametrize("scene", ["default+nogi", "default"])
def test_clients_get_their_atlases_as_alone(scene: str) -> None:
    """Three clients at different points of the walk on one server: each one's updates are bit for bit those it gets
    alone on a server of its own (with GI, the probes relit once a frame for every session)."""
    r = Renderer()
    together = _updates(scene, [0, 1, 2], 3, r)
    for c in range(3):
        alone = _updates(scene, [c], 3, Renderer())
        assert together[c] == alone[c], c
    assert together[0] != together[1] and together[1] != together[2]   # three views, three atlases


def test_a_leaked_eye_would_show(monkeypatch: pytest.MonkeyPatch) -> None:
    """The sessions share one shading program, so a frame uniform a session failed to set would carry the previous
    session's: with ``u_eye`` set only once in the process (the first session's first frame), the second client's
    atlas is not the one it gets alone (where its own eye was the first), so the test above can fail."""
    real = sas_server.has_uniform
    asked: list[int] = []

    def eye_once(prog: object, name: str) -> bool:
        if name == "u_eye":
            asked.append(1)
            return len(asked) == 1 and real(prog, name)
        return real(prog, name)

    monkeypatch.setattr(sas_server, "has_uniform", eye_once)
    together = _updates("default+nogi", [0, 1], 2, Renderer())
    asked.clear()
    alone = _updates("default+nogi", [1], 2, Renderer())
    assert together[1][0] != alone[1][0]


def test_id_pass_places_each_time_once() -> None:
    """The patch-id pass places the animated objects once per scene time for every session and sample
    (``PatchIdPass.placement``): the EVS areas are those of a pass placing them afresh each time, and the kept times
    stay bounded."""
    from splitrender.methods.sas.pvs import PLACEMENT_TIMES, PatchIdPass

    r = Renderer()
    scene = get_scene("default+nogi")
    prod = SasProducer(SasConfig(), scene, 30)
    ids = prod.id_pass(r, prod.patches_for(INTR))
    assert isinstance(ids, PatchIdPass) and ids._animated.any()
    tr = get_trace("walk", scene=scene, aspect=INTR.width / INTR.height)
    times = [0.5 + k / 30 for k in range(20)]
    kept = [ids.evs_area(tr.pose_at(t + dt), INTR, t) for t in times for dt in (0.0, 0.5)]
    assert len(ids._placed) == PLACEMENT_TIMES
    fresh = []
    for t in times:
        for dt in (0.0, 0.5):
            ids._placed.clear()
            fresh.append(ids.evs_area(tr.pose_at(t + dt), INTR, t))
    assert all(np.array_equal(a, b) for a, b in zip(kept, fresh))
    assert len({a.tobytes() for a in kept}) > 20   # the views differ
