"""The virtual-time runner: determinism, baselines' ordering, accounting, loss recovery, config errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from splitrender.errors import ConfigError, NetworkConfigError, TraceError
from splitrender.sim import RunConfig, run

TINY = dict(scene="default+nogi", width=160, height=90, flip_every=0)
"""The runs here are on the walk at 160x90 and 60 Hz (unless a test says otherwise): with the session's truth cache
(``truth_cache`` in conftest) each ground-truth frame is rendered once for them all."""


def test_same_seed_same_csv(tmp_path, renderer, truth_cache):
    """Two runs of one config write the same CSVs (but the wall-clock columns) and config; another seed draws
    other jitter.  Half a second under ``cloud`` (31 display ticks, 16 updates) shows it as a second did: measured
    4 of 31 update ages differ with seed 8 (9 of 61 over 1 s).  Both runs render their own ground truth."""
    cfg = RunConfig(method="atw", trace="walk", network="cloud", duration_s=0.5, seed=7, **TINY)
    a = run(cfg, tmp_path / "a", renderer=renderer)
    run(cfg, tmp_path / "b", renderer=renderer)

    def stable(path):  # wall-clock columns differ between runs; everything else must not
        import csv

        rows = list(csv.DictReader(open(path)))
        drop = {"client_ms", "decode_ms", "gt_ms", "server_ms", "encode_ms", "mean_server_ms", "mean_encode_ms",
                "mean_decode_ms", "mean_client_ms", "mean_gt_ms"}
        return [{k: v for k, v in r.items() if k not in drop} for r in rows]

    for name in ("frames.csv", "updates.csv", "summary.csv"):
        assert stable(tmp_path / "a" / name) == stable(tmp_path / "b" / name), name
    assert (tmp_path / "a" / "config.toml").read_text() == (tmp_path / "b" / "config.toml").read_text()
    other = run(cfg.replace(seed=8, truth_cache=truth_cache), renderer=renderer)
    ages_a = [f["update_age_ms"] for f in a.frames]
    ages_o = [f["update_age_ms"] for f in other.frames]
    assert ages_a != ages_o, "a different seed should draw different network jitter"
    # the decode time measured for each update (ReceivedFrame.decode_ms) reaches the tick that first shows it
    firsts = {f["update_frame_id"]: f["decode_ms"] for f in reversed(a.frames) if f["update_frame_id"] >= 0}
    # (0 for an update released with nothing decoded since the last: one of 18 at 5 % loss, before and after)
    assert len(firsts) >= 5 and all(0 <= ms < 1000 for ms in firsts.values()), firsts
    assert sum(ms > 0 for ms in firsts.values()) > len(firsts) / 2, firsts


def test_atw_beats_video_on_a_turning_trace_under_cloud(renderer, truth_cache):
    """1.5 s of head turns under ``cloud`` at 320x180, shown at 30 Hz: measured atw 4.68 dB and 0.274 SSIM ahead of
    video (at the runner's default 60 Hz 4.54 dB and 0.269, over 2.5 s 4.88 dB and 0.259; 1 s is too short for the
    margin: 3.60 dB at 30 Hz, 3.48 at 60).  One ground truth for both runs."""
    common = dict(scene="default+nogi", trace="turn", network="cloud", duration_s=1.5, width=320, height=180, client_fps=30,
                  flip_every=0, truth_cache=truth_cache)
    v = run(RunConfig(method="video", **common), renderer=renderer).summary
    a = run(RunConfig(method="atw", **common), renderer=renderer).summary
    margin = a["mean_psnr_db"] - v["mean_psnr_db"]
    assert margin > 3.5, f"atw {a['mean_psnr_db']:.2f} dB vs video {v['mean_psnr_db']:.2f} dB: margin {margin:.2f} dB <= 3.5 dB"
    assert a["mean_ssim"] > v["mean_ssim"] + 0.2, (a["mean_ssim"], v["mean_ssim"])


def test_latency_costs_quality_and_is_reported(shared_run):
    """1 s of the walk, ``video`` at ``ideal`` and under ``cloud``: measured update age 25.0 / 92.9 ms, 24.36 / 14.70 dB
    (over 1.5 s 25.0 / 92.1 ms, 24.15 / 15.00 dB).  The ``ideal`` run is the measured-cost test's ``fixed`` one."""
    common = dict(method="video", trace="walk", duration_s=1.0, **TINY)
    ideal = shared_run(RunConfig(network="ideal", **common)).summary
    cloud = shared_run(RunConfig(network="cloud", **common)).summary
    assert cloud["mean_update_age_ms"] > ideal["mean_update_age_ms"] + 40
    assert ideal["mean_psnr_db"] > cloud["mean_psnr_db"]


def _on_the_clock(res, fps: int) -> int:
    """Check the measured cost model's rule against a run's own costs (whatever the machine's load made them): each
    frame is made at the first server tick at which the one before it had been sent (its tick plus its ``cost_ms``),
    and every tick in between is skipped.  Returns the ticks skipped between the frames made."""
    made = sorted((u["frame_id"], u["cost_ms"]) for u in res.updates)
    skipped = 0
    for (f1, cost), (f2, _) in zip(made, made[1:]):
        free_s = f1 / fps + cost / 1000.0
        assert f2 / fps >= free_s - 1e-9, (f1, cost, f2)             # not made while the server was busy
        assert (f2 - 1) / fps < free_s + 1e-9 or f2 == f1 + 1, (f1, cost, f2)   # nor later than the first free tick
        skipped += f2 - f1 - 1
    assert res.summary["server_skipped"] >= skipped
    return skipped


def test_measured_cost_puts_a_slow_server_on_the_clock(renderer, shared_run, truth_cache, monkeypatch):
    """``cost_model = "measured"``: a method made 100 ms slower per frame delivers late and skips ticks.  (The ground
    truth, from the session's cache, is never on the clock.)  The base cost is wall-clock time and moves with the
    machine's load (measured idle: cost 10 / 32 / 147 / 74 ms (fixed / fast / slowed / halved), skipped 0 / 7 / 25 /
    21, update age 25 / 55 / 233 / 129 ms; fast read 56 ms in a CI run and 205 ms at load 16): so the clock's rule is
    checked against each run's own measured costs, and the slowed runs against the 100 ms the sleep guarantees."""
    import time

    from splitrender.methods.video.server import VideoServer

    common = dict(method="video", trace="walk", duration_s=1.0, truth_cache=truth_cache, **TINY)
    fixed = shared_run(RunConfig(**common)).summary
    fast = run(RunConfig(cost_model="measured", **common), renderer=renderer)
    produce = VideoServer.produce

    def slow(self, ctx):  # type: ignore[no-untyped-def]
        time.sleep(0.1)
        return produce(self, ctx)

    monkeypatch.setattr(VideoServer, "produce", slow)
    slowed = run(RunConfig(cost_model="measured", **common), renderer=renderer)
    halved = run(RunConfig(cost_model="measured", cost_scale=0.5, **common), renderer=renderer)
    fps = RunConfig(**common).server_fps
    assert fixed["server_skipped"] == 0 and fixed["mean_cost_ms"] == pytest.approx(10.0)
    for res in (fast, slowed, halved):
        _on_the_clock(res, fps)
    # the sleep puts 100 ms on every slowed frame (50 ms at cost_scale 0.5): each holds the server for three ticks of
    # 33 ms at least, so at least two are skipped after every frame made (idle: 25 of 31 ticks skipped)
    assert min(u["cost_ms"] for u in slowed.updates) >= 100.0
    assert min(u["cost_ms"] for u in halved.updates) >= 50.0
    assert _on_the_clock(slowed, fps) >= 2 * (len(slowed.updates) - 1) and slowed.summary["server_skipped"] >= 20
    assert slowed.summary["server_skipped"] > fast.summary["server_skipped"]
    # >= 100 ms more on the clock, plus about half of the 133 ms between the frames that are made
    assert slowed.summary["mean_update_age_ms"] >= fixed["mean_update_age_ms"] + 150.0, (slowed.summary, fixed)
    assert slowed.summary["mean_psnr_db"] < fixed["mean_psnr_db"]
    # the same work at half the modelled cost: cheaper on the clock, fewer ticks skipped
    assert halved.summary["mean_cost_ms"] < slowed.summary["mean_cost_ms"]
    assert halved.summary["server_skipped"] < slowed.summary["server_skipped"]


def test_bits_count_every_stream_and_metadata(shared_run):
    res = shared_run(RunConfig(method="atw", duration_s=1.0, **TINY))
    s = res.summary
    parts = sum(v for k, v in s.items() if k.startswith("kbps_"))
    assert s["kbps_meta"] > 0 and s["kbps_color"] > 0
    assert s["mean_kbps"] == pytest.approx(parts)
    for u in res.updates:
        assert u["bytes"] == u["bytes_color"] + u["bytes_meta"]


def test_loss_triggers_keyframe_requests_and_recovery(shared_run):
    """2 s at 5 % loss, seed 1, shown at 30 Hz: measured 12 lost frames, 2 keyframe requests, 4 keyframes (the bound:
    more than 3, the GOP's two and one).  Over 3 s 12 lost, 2 requests, 5 keyframes (3 s ran until issue 49: every loss
    falls in the first 2 s, and the third second cost a third of the test's CPU).  At the runner's default 60 Hz (other feedback times,
    other draws) 20 lost, 3 requests, 4 keyframes.  (Measured 2026-12-06, once the server core's datagrams left one
    way: a retransmission no longer waits behind the frame being encoded, so NACKs repair more, and seed 3, used
    before, now loses no frame: 0 against 16; over seeds 0-5, 6.5 lost frames a run against 11.2.)"""
    cfg = RunConfig(method="video", network="delay 20ms loss 5%", duration_s=2.0, seed=1, client_fps=30, **TINY)
    res = shared_run(cfg)
    s = res.summary
    assert s["lost_frames"] > 0 and s["keyframe_requests"] > 0
    assert s["keyframes"] > 1 + math.floor(cfg.duration_s * 30 / 30), "IDRs beyond the GOP schedule answer the requests"
    # after every undecodable frame a later update is shown again (the stream recovers)
    shown = sorted({f["update_frame_id"] for f in res.frames})
    lost = [u["frame_id"] for u in res.updates if not u["delivered"]]
    assert any(fid > max(lost) for fid in shown) or max(lost) >= res.updates[-1]["frame_id"] - 3


def test_nonsense_config_gives_clear_errors():
    with pytest.raises(ConfigError, match="width/height: must be positive and even"):
        RunConfig(width=641)
    with pytest.raises(ConfigError, match="unknown key 'resolution'"):
        RunConfig.from_dict({"resolution": "hd"})
    with pytest.raises(ConfigError, match="server_fps: expected an integer, got str"):
        RunConfig.from_dict({"server_fps": "thirty"})
    with pytest.raises(ConfigError, match="client_fps: must be in"):
        RunConfig(client_fps=0)
    with pytest.raises(ConfigError, match="cost_model: must be one of fixed, measured, got 'wallclock'"):
        RunConfig(cost_model="wallclock")
    with pytest.raises(ConfigError, match=r"supersample: must be in \[1, 4\], got 8"):
        RunConfig(supersample=8)
    with pytest.raises(ConfigError, match="unknown method 'teleport'"):
        run(RunConfig(method="teleport"))
    with pytest.raises(ConfigError, match="AtwConfig: unknown parameter 'overscna'"):
        run(RunConfig(method="atw", method_params={"overscna": 1.2}))
    with pytest.raises(NetworkConfigError):
        run(RunConfig(network="delay lots"))
    with pytest.raises(TraceError, match="unknown trace"):
        run(RunConfig(trace="moonwalk"))


def test_toml_config_file(tmp_path):
    p = tmp_path / "run.toml"
    p.write_text('[run]\nmethod = "atw"\nwidth = 320\nheight = 180\n[run.method_params]\noverscan = 1.5\n')
    cfg = RunConfig.from_toml(p)
    assert cfg.method == "atw" and cfg.method_params == {"overscan": 1.5}
    p.write_text("[run\nmethod=")
    with pytest.raises(ConfigError, match="not valid TOML"):
        RunConfig.from_toml(p)
    with pytest.raises(ConfigError, match="config file not found"):
        RunConfig.from_toml(tmp_path / "nope.toml")


def test_a_malformed_update_is_rejected_and_the_run_goes_on(renderer, truth_cache, monkeypatch):
    from splitrender.errors import RemoteProtocolError
    from splitrender.methods.atw import AtwClient

    real = AtwClient.apply
    calls = {"n": 0}

    def flaky(self, update):
        calls["n"] += 1
        if calls["n"] == 3:
            raise RemoteProtocolError("atw metadata: fov_y_deg missing")
        return real(self, update)

    monkeypatch.setattr(AtwClient, "apply", flaky)
    res = run(RunConfig(method="atw", duration_s=0.5, truth_cache=truth_cache, **TINY), renderer=renderer)
    assert res.summary["apply_errors"] == 1
    shown = {f["update_frame_id"] for f in res.frames}
    assert 2 not in shown and max(shown) >= 10, "the rejected update is skipped, later ones are shown"


@pytest.mark.parametrize("supersample", [1, 2])
def test_still_camera_lossless_video_reproduces_the_truth_bit_for_bit(renderer, supersample):
    """A still camera on a still scene at ``ideal`` with ``lossless = true``: every shown frame is the truth,
    supersampled or not (the server renders with the same anti-aliasing as the truth)."""
    cfg = RunConfig(method="video", scene="minimal", trace="static", network="ideal", duration_s=0.5, width=160, height=90,
                    flip_every=2, save_images_every=1, method_params={"lossless": True}, supersample=supersample)
    res = run(cfg, renderer=renderer)
    assert renderer.supersample == 1  # restored for the next user of the shared renderer
    assert len(res.images) == 31 and res.summary["frames_before_content"] == 1  # tick 0 shows the black background
    for frame, shown, truth in res.images[1:]:
        assert np.array_equal(shown, truth), f"frame {frame}: {int(np.sum(np.any(shown != truth, axis=-1)))} pixels differ"
    rows = [f for f in res.frames if f["update_frame_id"] >= 0]
    assert len(rows) == 30 and all(f["psnr_db"] == 60.0 and f["mse"] == 0.0 for f in rows)
    assert all(f["flip"] == 0.0 for f in rows if not np.isnan(f["flip"]))


def test_a_sas_runs_metadata_repeats_bit_for_bit(renderer):
    """Issue 48: two virtual-time runs of one configuration differed in their metadata bytes, because the frame
    envelope carried the server half's wall-clock stage times (sas's pvs_ms, shade_ms, ...), whose compressed size
    varies; an adapting run's controllers then learned from those bytes.  In the fixed cost model the times stay
    out of the envelope (they are still in updates.csv as ``srv_*``), so every byte count repeats.  (An adapting run
    repeats too since its encoders under a VBV run one thread: tests/test_adapt_repeat.py.)"""
    cfg = RunConfig(method="sas", scene="minimal", trace="walk", network="delay 20ms loss 2%", width=160, height=90,
                    duration_s=0.6, client_fps=30, flip_every=0, metrics=False, seed=5)
    a, b = run(cfg, renderer=renderer), run(cfg, renderer=renderer)
    keys = [k for k in a.updates[0] if k.startswith(("bytes", "keyframe", "frame_id", "delivered", "srv_pvs_patches"))]
    assert "bytes_meta" in keys and len(a.updates) == 19
    assert [[u[k] for k in keys] for u in a.updates] == [[u[k] for k in keys] for u in b.updates]
    assert all("srv_shade_ms" in u for u in a.updates)        # the stage times are still recorded


def test_the_live_servers_session_options_are_a_runs_too(renderer):
    """Issue 47: ``history_packets``, ``keyframe_min_interval_ms`` and ``sr_interval_s`` could only be set live.  A run
    takes them (TOML keys, the live server's names and ranges) into its server core, and leaves older configs' keys
    as they were."""
    from splitrender.errors import ConfigError
    from splitrender.sim.runner import VirtualTimeRun

    assert RunConfig().key() == RunConfig(history_packets=2048, sr_interval_s=1.0).key()
    assert RunConfig(sr_interval_s=0.5).key() != RunConfig().key()
    with pytest.raises(ConfigError, match=r"^run config server options: server history_packets: must be in "
                                          r"\[1, 1048576\], got 0$"):
        RunConfig(history_packets=0)
    cfg = RunConfig(method="video", scene="minimal", trace="static", width=64, height=36, duration_s=0.2, metrics=False,
                    history_packets=64, keyframe_min_interval_ms=900.0, sr_interval_s=0.05)
    vt = VirtualTimeRun(cfg, renderer)
    vt.run()
    core = vt.clients[0].core_s
    assert (core.options.history_packets, core.options.keyframe_min_interval_ms, core.options.sr_interval_s) == (64, 900.0, 0.05)
    assert core.counters["rtcp_sent"] >= 2          # sender reports every 25-75 ms over 0.2 s (1 s would send none)
