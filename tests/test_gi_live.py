"""Live probes (``render.ddgi.RELIGHT_HALVES``): a recurrent update (``Renderer.gi_hz`` > 0) whose lights are as the
last one's relights the probes of one half of the atlas's rows, the halves alternately; a light's change, the first
update and virtual time relight every probe."""

from __future__ import annotations

import numpy as np

from splitrender.render.renderer import Renderer
from splitrender.scene.loader import get_scene


def _changed(vol, t: float) -> np.ndarray:  # type: ignore[no-untyped-def]
    before = (vol.irradiance.copy(), vol.moments.copy())
    assert vol.update(t)
    return (vol.irradiance != before[0]).any(axis=(1, 2)) | (vol.moments != before[1]).any(axis=(1, 2))


def test_live_updates_relight_the_halves_alternately_and_a_light_change_all() -> None:
    """Default scene (the sun dims from 4 to 5 s): live, after the first update, each update at the same lights
    changes only probes of one half (rows of the atlas of one parity), most of them (measured: every active one),
    the next the other half; an update across the sun's dimming changes probes of both halves; virtual time
    (``gi_hz`` 0) changes probes of both halves at every update."""
    r = Renderer()
    r.gi_hz = 5.0
    scene = get_scene("default")
    vol = r.gi_volume(scene)
    vol.recurrent = True
    row = (np.arange(vol.count) // vol.cols) % 2
    assert vol.update(1.0)
    seen = []
    for t in (1.4, 1.8, 2.2):
        ch = _changed(vol, t)
        halves = np.unique(row[ch])
        assert halves.size == 1, (t, halves)
        assert ch.sum() >= 0.5 * (row == halves[0]).sum(), (t, int(ch.sum()))
        seen.append(int(halves[0]))
    assert seen in ([0, 1, 0], [1, 0, 1]), seen
    ch = _changed(vol, 4.4)                              # the sun at 1.92 against 2.6
    assert set(np.unique(row[ch]).tolist()) == {0, 1}
    r0 = Renderer()                                      # virtual time: every update relights everything
    v0 = r0.gi_volume(get_scene("default"))
    assert not v0.recurrent and v0.update(1.0)
    for t in (1.4, 1.8):
        assert set(np.unique(row[_changed(v0, t)]).tolist()) == {0, 1}
