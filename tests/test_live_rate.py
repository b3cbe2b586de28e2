"""The live server's GI rate, the per-stage figures of a live frame, and the ``live`` study's measurement."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from splitrender.errors import ConfigError
from splitrender.experiments.live_rate import STAGES, measure, summarise_server
from splitrender.render import ddgi
from splitrender.render.ddgi import gi_time
from splitrender.metrics.image import psnr
from splitrender.render.renderer import Renderer, make_pose_looking
from splitrender.scene.loader import get_scene
from splitrender.scene.pose import CameraIntrinsics
from splitrender.server.server import DEFAULT_GI_HZ, ServerConfig


def test_gi_time_is_the_newest_tick_at_or_before() -> None:
    assert gi_time(0.19, 5.0) == 0.0 and gi_time(0.2, 5.0) == pytest.approx(0.2) and gi_time(1.0, 5.0) == 1.0
    assert gi_time(0.6, 5.0) == pytest.approx(0.6)          # 0.6 * 5 is 2.9999999999999996 in floating point
    assert gi_time(0.123, 0.0) == 0.123                      # 0: every time its own


def test_a_renderer_at_a_gi_rate_relights_once_a_period_and_differs_little() -> None:
    """The default scene's probes move with its objects, so with ``gi_hz = 0`` every new time relights them; at
    5 Hz the renders of one 200 ms period share one relight, and the image a period's last render shows (GI up to
    190 ms old) stays close to the one relit for its own time: here 2.8 % of the pixels differ, by at most 3 code
    values (63 dB; over the 10 s walk at 320x180, 5 Hz gave 59.5 dB on average and 51 dB at worst, the sun's dimming
    and the lamp switching on included)."""
    scene = get_scene("default")
    intr = CameraIntrinsics(160, 90)
    pose = make_pose_looking((0.0, 1.6, 2.0), (0.0, 1.0, -4.0))
    every, rated = Renderer(), Renderer()
    for r in (every, rated):
        r.probe_states().enabled = False      # relight for real, no reuse of a state relit before
    rated.gi_hz = 5.0
    imgs = {}
    for t in (0.0, 0.05, 0.1, 0.19):
        imgs[t] = rated.render(scene, t, pose, intr).color
    vol = rated.gi_volume(scene)
    assert vol.updates == 1
    ms_one = rated.gi_ms
    assert ms_one > 0
    rated.render(scene, 0.2, pose, intr)
    assert vol.updates == 2 and rated.gi_ms > ms_one
    for t in (0.0, 0.05, 0.1, 0.19):
        every.render(scene, t, pose, intr)
    assert every.gi_volume(scene).updates == 4
    assert np.array_equal(every.render(scene, 0.0, pose, intr).color, imgs[0.0])   # same time, same probes
    late = every.render(scene, 0.19, pose, intr).color
    diff = np.abs(late.astype(int) - imgs[0.19])
    assert diff.max() > 0                              # the probes moved with the objects in 190 ms ...
    assert psnr(late, imgs[0.19]) >= 55 and diff.max() <= 6 and (diff > 0).mean() < 0.06   # ... by little


def test_the_server_refuses_a_nonsense_gi_rate() -> None:
    """(The CLI's ``--gi-hz`` is in ``test_live_errors``' table.)"""
    assert ServerConfig().gi_hz == DEFAULT_GI_HZ > 0
    assert ServerConfig(gi_hz=0).gi_hz == 0
    with pytest.raises(ConfigError, match=r"server gi_hz: must be 0 \(every frame\) or in \[0.1, 240\], got 0.01"):
        ServerConfig(gi_hz=0.01)


def test_server_rows_summarise_into_rates_and_stages() -> None:
    """Ten frames a second after a warm-up second at two a second: the warm-up is left out, the stages are means,
    and what the stages leave of each 100 ms interval is waiting."""
    rows = [{"server_us": str(int(t * 1e6)), "gi_ms": "20", "shared_ms": "0", "server_ms": "50", "encode_ms": "5",
             "worker_rtt_ms": "1", "send_ms": "1", "keyframe": "0", "bytes": "1000"} for t in (0.0, 0.5)]
    rows += [{"server_us": str(int((1.0 + 0.1 * k) * 1e6)), "gi_ms": "10", "shared_ms": "5", "server_ms": "40",
              "encode_ms": "2", "worker_rtt_ms": "1", "send_ms": "0.5", "keyframe": str(int(k == 0)), "bytes": "1250"}
             for k in range(21)]
    s = summarise_server(rows)
    assert s["updates"] == 23 and s["updates_per_s"] == pytest.approx(10.0)
    assert (s["gi_ms"], s["method_ms"], s["encode_ms"]) == pytest.approx((10.0, 35.0, 2.0))
    assert s["wait_ms"] == pytest.approx(100 - (10 + 35 + 2 + 1 + 0.5))
    assert s["kbps"] == pytest.approx(21 * 1250 * 8 / 1000 / 2.0)
    assert s["keyframes"] == 1
    assert summarise_server([])["updates_per_s"] == 0.0


@pytest.mark.slow
def test_a_live_session_reports_its_rate_and_every_stage(tmp_path: Path) -> None:
    """One real live session (server here, ``splitrender client`` a process of its own) measured as the ``live``
    study measures every method, and its chart.  On the minimal scene at 160x90 video kept up with the 30 Hz frame
    clock here, idle and with two busy loops beside it alike (30.0 updates a second, 86-88 of 90 ticks shown)."""
    from splitrender.experiments.studies.live import chart, target_ups

    r = measure("video", seconds=3.0, scene="minimal", width=160, height=90, out=tmp_path / "s")
    assert r["client_rc"] == 0, r.get("client_error")
    assert r["updates_per_s"] > 20 and r["client_shown"] > 60, r
    for s in STAGES:
        assert math.isfinite(r[f"{s}_ms"]) and r[f"{s}_ms"] >= 0, (s, r)
    assert r["gi_ms"] == 0.0                         # the minimal scene has no GI
    assert r["method_ms"] > 0 and r["encode_ms"] > 0
    assert sum(r[f"{s}_ms"] for s in STAGES) <= r["frame_ms"] * 1.05 + 1   # the stages fit in the interval
    assert (tmp_path / "s" / "client" / "frames.csv").is_file()
    r["target_ups"] = target_ups("video")
    png = chart([r], tmp_path / "live.png")
    assert png.stat().st_size > 10_000


def test_subnormal_weights_are_flushed_without_moving_a_bit() -> None:
    """The visibility weights' cosine power leaves subnormals (2,432 of 98,304 here); the CPU multiplies them in
    microcode, 20-40x slower.  Flushed, the products with any distances come out the same bits."""
    from splitrender.render.ddgi import SHARPNESS, VIS_CORE, flush_subnormal
    from splitrender.render.octa import cube_directions, texel_directions, visibility_weights

    dirs, omega = cube_directions(8)
    w = visibility_weights(texel_directions(VIS_CORE), dirs, omega, SHARPNESS).astype(np.float32)
    sub = (w != 0) & (np.abs(w) < np.finfo(np.float32).tiny)
    assert sub.sum() > 1000
    f = flush_subnormal(w)
    assert not ((f != 0) & (np.abs(f) < np.finfo(np.float32).tiny)).any() and np.array_equal(f[~sub], w[~sub])
    d = np.random.default_rng(1).uniform(0.0, 12.0, (256, w.shape[1])).astype(np.float32)
    d[:, ::7] = 12.0                                     # rays that missed: max_distance
    for x in (d, d * d):
        assert np.array_equal(x @ w.T, x @ f.T)


def test_a_live_gi_rate_relights_one_bounce_on_the_last_probes() -> None:
    """At a GI rate (live) a relight after the first runs the last bounce only, reading the probes the one before
    left (the DDGI paper's recurrence), and keeps such states out of the shared cache; without one (virtual time,
    the ground truth) every relight runs every bounce.  The recurrent probes stay near the ones relit from scratch:
    here 1.0 % mean relative difference in irradiance after two recurrent relights (over 10 s of the walk at 10 Hz
    frames the recurrence cost 59.4 dB against two bounces at 5 Hz, 55.5 dB at the worst frame)."""
    scene = get_scene("default")
    intr = CameraIntrinsics(96, 54)
    pose = make_pose_looking((0.0, 1.6, 2.0), (0.0, 1.0, -4.0))
    rated, every = Renderer(), Renderer()
    for r in (rated, every):
        r.probe_states().enabled = False
    rated.gi_hz = 5.0
    passes = []
    vol = rated.gi_volume(scene)
    run = vol._relight.run
    vol._relight.run = lambda *a, **k: (passes.append(1), run(*a, **k))[1]
    for t in (0.0, 0.2, 0.4):
        rated.render(scene, t, pose, intr)
        every.render(scene, t, pose, intr)
    assert vol.recurrent and not every.gi_volume(scene).recurrent
    # the first relight runs every bounce; each recurrent one its last bounce only, over half the probe rows
    # (ddgi.RELIGHT_HALVES: the even rows, then the odd ones, one scissored pass per row)
    assert vol.updates == 3 and len(passes) == vol.settings.bounces + (vol.rows if ddgi.RELIGHT_HALVES else 2)
    a, b = vol.irradiance, every.gi_volume(scene).irradiance
    rel = np.abs(a - b).mean() / np.abs(b).mean()
    assert 0 < rel < 0.02, rel


def test_render_workers_start_with_one_blas_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    """The fork server (and so every render worker) starts with ``OPENBLAS_NUM_THREADS=1``; the server's own
    environment is left as it was."""
    from multiprocessing import forkserver

    from splitrender.server import worker

    seen = {}
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.setattr(forkserver, "ensure_running", lambda: seen.update(os.environ))
    worker.worker_context()
    assert seen.get("OPENBLAS_NUM_THREADS") == "1" and "OPENBLAS_NUM_THREADS" not in os.environ
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")       # one the user set is kept
    worker.worker_context()
    assert seen["OPENBLAS_NUM_THREADS"] == "3" == os.environ["OPENBLAS_NUM_THREADS"]
