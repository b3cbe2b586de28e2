"""The stability suite as tests: every available method through every stress case its scene allows at
96x54 and 1.25 s (one suite run shared by the tests, about 200 CPU seconds; the test session starts it in
the background beside the deterministic tests, see ``conftest.py``: ``STRESS_SIZE``), with a stated bound per case.
The values below are the 96x54 suite's, window 0.4-0.7 s (measured at c8cc006; in brackets the 160x90 suite's of
``splitrender stress --quick``, which took 1.40x the CPU: 275 against 197 CPU s of runs; before that the 1.5 s
suite, 24 % more again, and 1.8 s):

- every case, every method: no exception, no crash, no hang (120 CPU s per run, or 480 s of wall time; 240 and 960
  where the suite runs niced beside the tests, ``SR_STRESS_NICE``, ``conftest.STRESS_TIMEOUT_S``),
  and frames keep being shown: at least 60% of the display ticks show a frame (a
  lost first frame delays the start by the same 13-14 ticks at either size: under 3% Gilbert-Elliott
  loss warp shows 61 %, 23 of 38 ticks, tss and quads 63 %, sas 76 % [tss and sas 66 %, warp and quads 68 %])
  and no displayed update is older than 1 s;
- baselines (video, atw): share of frames below 20 dB at most ``baseline_floor_pct``
  of the case (see :data:`splitrender.experiments.stress.CASES`, the 160x90 suite's), and where the 96x54 suite
  measures far less, at most :data:`FLOOR_PCT_96`;
- fast_turn: ATW's rotational reprojection keeps fewer frames below the floor than video (2.8 % against 33.3);
- windowed cases (latency_spike, bandwidth_drop): the disturbance is visible for video
  (mean PSNR inside the window at least 1 dB below the pre-window median: 4.3 and 6.1 dB [4.1, 6.3]);
- ball_crossing: every method stays above 15 dB on its worst frame (22.2 the lowest, sas and tss [21.9 warp]);
- capacity_drop (20 -> 2 Mbit/s inside the window, ``--adapt full``): a recovery bound per method on the oldest
  update shown, at measured plus a quarter at 160x90, kept where 96x54 measures within them: video 133 ms, atw 167,
  warp 233, quads 200, sas and tss 333 [video 167, warp 233, atw, sas, tss and quads 300 at cfd47c2; over 1.5 s at
  cc91518 video 333, atw, sas and tss 67, warp 400, quads 433, against bounds of 375-500 ms];
- light_change (the sun dims over the run): generic bounds; video at most 40% below
  the floor (36.1% measured [58.3%, bound 62; 54.5% over 1.5 s; 47% over 1.8 s, whose last 0.3 s come after the
  dimming]);
- fine_texture (backing away from the glyph sign, 1.5 m to 7 m over the run): video at most
  20% below the floor (13.9% measured [36.1%, bound 42; 29.5% over 1.5 s with a bound of 35; 19% over 1.8 s]: the
  shorter run backs away faster);
- atlas_overflow (sas and tss, an atlas of 1 Mpix at 1080p on the fast turns, 64x32 texels at 96x54): tss at
  19 dB or more on the mean and 14.5 on its worst frame (20.3 and 15.3 measured [21.3 and 15.6, bounds 20 and 14.5;
  21.41 and 15.65 over 1.5 s]: it lowers its rate, then leaves the smallest triangles out; it raised an error before);
  sas has the generic bounds (10.5 dB mean [12.4]: its allocations fail and what is not placed is a hole);
- with GI (``probes``, whose probes do not depend on the display's size; measured with 384 rays per probe over 1.25 s
  at 96x54; then at 160x90, over 1.5 s, over 1.8 s, and with 1536 rays over 1.8 s): gi_light_change at 45 dB or more
  on the mean (47.9; 47.9; 47.2; 49.0; 49.3; atw in light_change 21.9) and 34 dB or more on its worst frame (38.1;
  38.0; 37.5; 37.5; 37.4); gi_fast_moves at 55 dB or more (60, capped: nothing but the camera moves, and every probe
  the walk needs was sent in the first update); gi_moving_geometry at 30 dB or more on its worst frame (32.7; 33.6;
  33.0; 33.0; 33.1); gi_lossy_visibility (the ablation) at 22 dB or less on the mean: the leak must show (17.3; 17.2;
  17.2; 17.2; 18.7); gi_loss has the generic bounds: the visibility pictures rarely arrive whole under
  Gilbert-Elliott loss and the client draws direct light only (29.9 dB mean, 24.1 worst; at 160x90 29.9 and 24.0;
  over 1.5 s 35.8 and 24.0, over 1.8 s 40.2 and 24.0).
"""

from __future__ import annotations

import math

import pytest

from splitrender.experiments.stress import CASES, QUICK, STRESS_SCENE, get_case, recovery_time_s

pytestmark = pytest.mark.slow


#: The baselines' share of frames below the floor where the test session's 96x54 suite (``conftest.STRESS_SIZE``)
#: measures far below ``CASES``' ``baseline_floor_pct`` (the 160x90 suite's): measured at c8cc006 plus the margin the
#: 160x90 bound had over its measurement (light_change 36.1 % + 3.7, fine_texture 13.9 % + 5.9).
FLOOR_PCT_96 = {"light_change": 40.0, "fine_texture": 20.0}


@pytest.fixture(scope="module")
def suite(background_stress) -> dict[tuple[str, str], dict]:  # type: ignore[no-untyped-def]
    """The quick suite's rows, from the run the session started in the background (``conftest.py``)."""
    out, rows = background_stress
    assert (out / "stress.csv").is_file() and (out / "stress.html").is_file()
    return {(r["case"], r["method"]): r for r in rows}


@pytest.mark.parametrize("case", [c.name for c in CASES])
def test_stress_case(suite: dict, case: str) -> None:
    from splitrender.methods import methods_for_scene

    c = get_case(case)
    rows = {m: suite[(case, m)] for m in methods_for_scene(c.scene) if c.runs(m)}
    assert rows, case
    for m, r in rows.items():
        assert r["status"] == "ok", f"{case}/{m}: {r['status']} {r.get('error')}"
        assert r["frames_shown"] >= 0.6 * r["display_ticks"], f"{case}/{m}: only {r['frames_shown']} of {r['display_ticks']} shown"
        assert r["longest_stale_ms"] < 1000.0, f"{case}/{m}: an update {r['longest_stale_ms']:.0f} ms old was shown"
        assert r["worst_psnr_db"] > 5.0, f"{case}/{m}: worst frame {r['worst_psnr_db']:.1f} dB (blank?)"
    for m in [b for b in ("video", "atw") if b in rows] if c.scene == STRESS_SCENE else ():
        most = min(c.baseline_floor_pct, FLOOR_PCT_96.get(case, 100.0))
        assert rows[m]["below_floor_pct"] <= most, f"{case}/{m}: {rows[m]['below_floor_pct']:.1f}% below floor"
    if case == "fast_turn":
        assert rows["atw"]["below_floor_pct"] < rows["video"]["below_floor_pct"]
    if c.windowed and case != "capacity_drop":
        assert rows["video"]["window_drop_db"] >= 1.0, rows["video"]
    # capacity_drop adapts from the session's start, and adaptation starts low (300 kbit/s, issue 48): in the quick
    # suite the pre-window baseline (0.2-0.5 s) is the ramp from that start, so the window's cost shows in the oldest
    # update shown (the bounds below), not against that baseline (video measured 1.9 dB better in the window)
    # oldest update shown, measured over 1.25 s (window 0.4-0.7 s, at cfd47c2): 167 ms (video), 233 (warp), 300 (atw,
    # sas, tss, quads): the window now comes while the start's ramp is still on, and holds the methods that tolerate a
    # queue (1b30113's 100 ms encoder buffer) a tick or two longer than the 1.5 s suite's later window did (video 333,
    # atw, sas and tss 67, warp 400, quads 433 ms at cc91518).  Bounds: measured plus a quarter.  At 96x54 (c8cc006):
    # video 133, atw 167, warp 233, quads 200, sas and tss 333 ms, each within its bound by at least a tick (33 ms).
    if case == "capacity_drop":
        bound = {"video": 210.0, "atw": 375.0, "sas": 375.0, "quads": 375.0, "tss": 375.0, "warp": 292.0}
        for m, r in rows.items():
            assert r["longest_stale_ms"] <= bound.get(m, 1000.0), (m, r["longest_stale_ms"])
    if case == "ball_crossing":
        assert all(r["worst_psnr_db"] > 15.0 for r in rows.values())
    # atlas_overflow: measured 20.3 dB mean, 15.3 worst (sas 10.5, 10.3); at 160x90 21.3 and 15.6 (bounds 20 and 14.5)
    if case == "atlas_overflow":
        assert rows["tss"]["mean_psnr_db"] >= 19.0 and rows["tss"]["worst_psnr_db"] >= 14.5, rows["tss"]
    if case == "gi_light_change":   # the client relights its own scene: 47.9 dB mean (light_change: atw 21.9)
        assert rows["probes"]["mean_psnr_db"] >= 45.0, rows["probes"]
    if case == "gi_lossy_visibility":   # the ablation's light leak shows on every frame (17.2 dB measured)
        assert rows["probes"]["mean_psnr_db"] <= 22.0, rows["probes"]
    worst = {"gi_light_change": 34.0, "gi_fast_moves": 55.0, "gi_moving_geometry": 30.0}   # measured 38.1, 60, 32.7
    if case in worst:
        assert rows["probes"]["worst_psnr_db"] >= worst[case], rows["probes"]


def test_recovery_time() -> None:
    import numpy as np

    t = np.arange(0, 2.0, 0.05)
    p = np.where((t >= 0.5) & (t < 1.0), 10.0, 30.0)
    p[(t >= 1.0) & (t < 1.2)] = 25.0  # still degraded for 0.2 s after the window
    assert recovery_time_s(t, p, 0.5, 1.0) == pytest.approx(0.2)
    assert math.isnan(recovery_time_s(t, np.where(t >= 0.5, 10.0, 30.0), 0.5, 1.0))
    assert QUICK.t1_s + 0.5 < QUICK.duration_s  # recovery is measurable in the quick suite


def test_a_run_is_timed_by_its_workers_cpu_time_with_a_wall_clock_backstop() -> None:
    """A run's limit counts its worker's CPU seconds, so a loaded machine does not make a slow run a hang; a hang that
    burns nothing is still stopped at WALL_BACKSTOP times the limit; without /proc, wall time alone."""
    import os
    import time

    from splitrender.experiments.stress import WALL_BACKSTOP, _Job, _process_cpu_s, _timed_out

    before = time.process_time()
    cpu = _process_cpu_s(os.getpid())
    assert cpu is not None and abs(cpu - before) < 0.5, (cpu, before)   # this process's threads, from /proc
    assert _process_cpu_s(None) is None
    now = time.monotonic()
    job = _Job(case=None, method="video", cfg=None, t0=now - 30.0, cpu0=cpu)   # type: ignore[arg-type]
    assert not _timed_out(job, os.getpid(), limit=10.0)          # 30 s of wall, next to no CPU: waiting, not stuck
    job.cpu0 = cpu - 11.0
    assert _timed_out(job, os.getpid(), limit=10.0)              # 11 CPU s spent on it
    job.cpu0, job.t0 = cpu, now - WALL_BACKSTOP * 10.0 - 1.0
    assert _timed_out(job, os.getpid(), limit=10.0)              # a hang that burns nothing
    job.t0 = now - 11.0
    assert _timed_out(job, None, limit=10.0)                     # no CPU figure: wall time
