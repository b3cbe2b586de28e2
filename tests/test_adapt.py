"""Rate adaptation (issue 35, step 3): the controller sans-IO, encoder restarts in the pipeline, probes, and
sessions over a changing link in virtual time."""

from __future__ import annotations

import numpy as np
import pytest

from splitrender.errors import ConfigError
from splitrender.pipeline.adapt import DIP_FRAMES, AdaptConfig, CappedCrf, RateController, retarget


def test_targets_follow_the_estimate_after_paying_for_what_is_not_controlled() -> None:
    """A 30 frame/s session with a colour stream and 2 KB of reliable data a frame (480 kbit/s): the colour target
    is 90 % of the estimate less that, and falls with the estimate."""
    rc = RateController(("color",), 30.0, AdaptConfig(smoothing=1.0, calibrate_frames=0))
    rc.on_frame_sent({"color": 5000, "meta": 1500, "geo": 500})
    got = [rc.targets_kbps(bps)["color"] for bps in (4e6, 2e6, 1e6)]
    assert got == pytest.approx([0.9 * 4000 - 480, 0.9 * 2000 - 480, 0.9 * 1000 - 480])
    assert rc.targets_kbps(1e5)["color"] == AdaptConfig().min_kbps           # never below the floor
    assert rc.state()["adapt_overhead_kbps"] == pytest.approx(480)


def test_a_burst_of_data_beyond_the_estimate_is_paid_once() -> None:
    """A session's first frame carries 50 kB of data (12 Mbit/s in a frame's terms) at a 300 kbit/s estimate, then
    300 B a frame (72 kbit/s) as the estimate climbs to 2 Mbit/s.  The encoders are left the estimate less the data
    counted at no more than the estimate a frame: 9 frames on, about 1.64 Mbit/s for colour (counted whole, the
    average still held 4.6 Mbit/s of data and colour sat at its 50 kbit/s floor, as sas's atlas did for its first
    0.6 s on an 8 Mbit/s link); what the operating point learns of the data is the whole average."""
    rc = RateController(("color",), 30.0, AdaptConfig(calibrate_frames=0))
    rc.targets_kbps(3e5)
    rc.on_frame_sent({"color": 500, "meta": 50_000})
    for _ in range(9):
        rc.targets_kbps(2e6)
        rc.on_frame_sent({"color": 500, "meta": 300})
    assert rc.targets_kbps(2e6)["color"] == pytest.approx(0.9 * 2000 - 300 * 0.9 ** 9 - 72 * (1 - 0.9 ** 9), rel=1e-6)
    assert rc.overhead_bps > 4.5e6                      # 12 Mbit/s * 0.9^9 + 72 kbit/s * (1 - 0.9^9): 4.69 Mbit/s


def test_a_calibrating_ceiling_is_held_through_a_blip_of_queue() -> None:
    """A calibrating stream's ceiling that falls under ``urgent_ratio`` (0.7) of the one before (which restarts its
    encoder at once with an I-frame, and its rise back another) is held just over that for DIP_FRAMES - 1 frames: a
    0.1 s blip costs no I-frame; a fall that lasts passes on the fourth frame."""
    rc = RateController(("color",), 30.0, AdaptConfig(smoothing=1.0, headroom=1.0))
    assert rc.targets_kbps(4e6)["color"] == pytest.approx(4000)
    held = [rc.targets_kbps(2e6)["color"] for _ in range(DIP_FRAMES - 1)]
    assert all(isinstance(v, CappedCrf) for v in held) and held == pytest.approx([1.001 * 0.7 * 4000] * 3)
    assert rc.targets_kbps(4e6)["color"] == pytest.approx(4000)            # the blip is over: no restart at all
    got = [rc.targets_kbps(2e6)["color"] for _ in range(DIP_FRAMES)]
    assert got[-1] == pytest.approx(2000)                                  # a fall that lasts


def test_a_queue_tolerant_start_is_not_squeezed_by_its_first_fill_before_any_measurement() -> None:
    """Before the estimator's first measurement (its encoder rate still the first it gave, GCC's 300 kbit/s guess) a
    calibrating stream of a method that tolerates a queue keeps the start's share of it (START_HOLD): tss's first
    frame carries 17 kB of geometry, which, paid first against the guess, left its atlas the 50 kbit/s floor at
    0.13 s and an IDR coded at it.  Once the estimate moves the overhead is paid as before; without a buffer (video,
    atw) nothing changes."""
    for buffer_ms, first in ((100.0, 270.0), (None, 50.0)):
        rc = RateController(("atlas",), 30.0)
        rc.buffer_ms = buffer_ms
        assert rc.targets_kbps(3e5)["atlas"] == pytest.approx(270.0)
        for _ in range(DIP_FRAMES + 1):
            rc.on_frame_sent({"atlas": 1000, "geo": 17_000})
            got = rc.targets_kbps(3e5)["atlas"]
        assert got == pytest.approx(first)
        got = [rc.targets_kbps(3.1e5)["atlas"] for _ in range(DIP_FRAMES)]
        assert got[-1] == pytest.approx(50.0)            # measured: the overhead is paid first (after a blip's hold)


def test_a_calibrated_ceiling_falls_at_once_and_a_point_move_is_no_blip() -> None:
    """Only a calibrating ceiling is held through a blip (DIP_FRAMES): a queue-tolerant method's calibrated one (its
    crf under a ceiling, BURST_CAP) falls at once (held, quads on the step trace queued through the 2 Mbit/s span's
    falls: 0.33 dB under), and so does a calibrating one where the operating point moved (the controller's decision)."""
    rc = RateController(("atlas",), 30.0, AdaptConfig(smoothing=1.0, headroom=1.0, calibrate_frames=2))
    rc.buffer_ms = 100.0
    rc.targets_kbps(6e6)
    for idr in (("atlas",), ()):
        rc.on_frame_sent({"atlas": 20_000}, {"atlas": CappedCrf(12_000.0, 100.0)}, idr)
    assert rc.calibrated and "atlas" not in rc._provisional        # its own rate: 4.8 Mbit/s
    assert rc.targets_kbps(6e6)["atlas"] == pytest.approx(4800.0)
    assert rc.targets_kbps(3e6)["atlas"] == pytest.approx(3000.0)   # at once
    rc = RateController(("color",), 30.0, AdaptConfig(smoothing=1.0, headroom=1.0))
    assert rc.targets_kbps(4e6)["color"] == pytest.approx(4000)
    assert rc.targets_kbps(2e6)["color"] == pytest.approx(1.001 * 0.7 * 4000)   # a blip: held
    assert rc.targets_kbps(4e6)["color"] == pytest.approx(4000)
    rc.factor = 0.5                                                 # the point moved down: not held
    assert rc.targets_kbps(2e6)["color"] == pytest.approx(2000)


def test_streams_share_by_what_they_took_and_an_encoder_s_miss_is_learnt() -> None:
    rc = RateController(("color", "depth"), 30.0, AdaptConfig(smoothing=1.0, headroom=1.0, calibrate_frames=0))
    assert rc.targets_kbps(2e6) == pytest.approx({"color": 1000, "depth": 1000})   # equal before any frame
    rc.on_frame_sent({"color": 3000, "depth": 1000})
    assert rc.targets_kbps(2e6) == pytest.approx({"color": 1500, "depth": 500})
    # color sent 1.5x what it was given (3000 B a frame at 30/s is 720 kbit/s against 480): its next target shrinks
    rc.on_frame_sent({"color": 3000, "depth": 1000}, {"color": 480.0})
    t = rc.targets_kbps(2e6)
    assert t["color"] == pytest.approx(1500 / 1.5) and t["depth"] == pytest.approx(500)


def test_a_stream_first_runs_at_the_method_s_own_rate_under_a_ceiling_and_is_capped_by_it() -> None:
    """Calibration: a stream first keeps the method's crf under a ceiling at its share of the estimate (a
    :class:`CappedCrf`, not a target).  3 frames of 4000 B at 30 frame/s (960 kbit/s) under a 20 Mbit/s ceiling were
    the crf's own: its target is capped at 1.5x that (1440); a link whose share is 1.5x the cap or more gives the
    method its crf back (under a ceiling at the share, :data:`WIDE`).  Under a 500 kbit/s ceiling the
    P-frames took half of it or more: the ceiling shaped them, so the cap they give (480) is provisional: it caps
    nothing, the estimator may probe past it, and once the stream's share is 1.5x it the stream calibrates again.
    A window opens at an IDR (one per GOP, as the stream sends them), and an IDR, however large, never counts as
    shaped."""
    cfg = AdaptConfig(smoothing=1.0, headroom=1.0, calibrate_frames=3, ceiling=1.5)   # the default ceiling is 1
    rc = RateController(("color",), 30.0, cfg)
    got = rc.targets_kbps(20e6)
    assert got == {"color": pytest.approx(20000)} and isinstance(got["color"], CappedCrf)
    assert not rc.calibrated and rc.wanted_bps() is None
    for k in range(3):
        rc.on_frame_sent({"color": 4000}, {"color": CappedCrf(20000.0)}, idr_streams=("color",) if k == 0 else ())
    got = rc.targets_kbps(2e6)                       # a share under 1.5x the cap: a target, at the cap
    assert got == {"color": pytest.approx(1440)} and not isinstance(got["color"], CappedCrf)
    assert rc.state()["adapt_color_cap_kbps"] == pytest.approx(1440) and rc.wanted_bps() == pytest.approx(1.5 * 1440e3)
    assert rc.targets_kbps(1e6) == {"color": pytest.approx(1000)}

    narrow = RateController(("color",), 30.0, AdaptConfig(smoothing=1.0, headroom=1.0, calibrate_frames=3))
    narrow.on_frame_sent({"color": 20000}, {"color": CappedCrf(500.0)}, idr_streams=("color",))      # the IDR: not shaped
    for _ in range(2):
        narrow.on_frame_sent({"color": 2000}, {"color": CappedCrf(500.0)})                  # 480 kbit/s under 500
    assert narrow.calibrated and narrow.state()["adapt_color_cap_kbps"] == pytest.approx((20000 + 4000) / 3 * 0.24)
    assert narrow.wanted_bps() is None                                       # provisional: the probes may go on
    cap = narrow.state()["adapt_color_cap_kbps"]
    got = narrow.targets_kbps(1.2 * cap * 1e3)
    assert got == {"color": pytest.approx(1.2 * cap)} and not isinstance(got["color"], CappedCrf)   # no cap
    got = narrow.targets_kbps(20e6)                                          # 1.5x the cap or more: calibrate again
    assert isinstance(got["color"], CappedCrf) and narrow.calibrated         # the provisional cap stands meanwhile
    narrow.on_frame_sent({"color": 9000}, {"color": CappedCrf(20000.0)}, idr_streams=())   # no IDR yet: not counted
    for k in range(3):                                                      # a window opens at an IDR
        narrow.on_frame_sent({"color": 3000}, {"color": CappedCrf(20000.0)}, idr_streams=("color",) if k == 0 else ())
    assert narrow.wanted_bps() == pytest.approx(1.5 * 720e3)                 # its own cap now: 720 kbit/s
    assert narrow.targets_kbps(1e6) == {"color": pytest.approx(720)}           # a target at it, under 1.5x of it

    shaped = RateController(("color",), 30.0, AdaptConfig(smoothing=1.0, headroom=1.0, calibrate_frames=3))
    for k in range(3):   # 960 kbit/s P-frames under a 1000 kbit/s ceiling: shaped
        shaped.on_frame_sent({"color": 4000}, {"color": CappedCrf(1000.0)}, idr_streams=("color",) if k == 0 else ())
    assert shaped.wanted_bps() is None


def test_a_link_well_wider_than_the_cap_gives_the_stream_its_crf_back() -> None:
    """Once calibrated (960 kbit/s at its crf), a stream whose share of the estimate reaches ``WIDE`` (1.5) times its
    cap runs at its crf under a ceiling at that share, not at a target at the cap (a target spends the cap evenly:
    it squeezes each I-frame into two mean frames, measured on sas over the 8 Mbit/s cellular-like trace: I-frames of
    14-16 kB against the crf's 42-106 kB).  It stays there while the share covers the cap, and takes a target again
    below it.  At a coarser operating point the cap is the point's (``factor``)."""
    rc = RateController(("color",), 30.0, AdaptConfig(smoothing=1.0, headroom=1.0, calibrate_frames=3))
    for k in range(3):
        rc.on_frame_sent({"color": 4000}, {"color": CappedCrf(20000.0)}, idr_streams=("color",) if k == 0 else ())
    assert rc.calibrated and rc.state()["adapt_color_cap_kbps"] == pytest.approx(960)
    seq = [(1.3e6, 960.0, False), (1.5e6, 1500.0, True), (1.1e6, 1100.0, True), (0.9e6, 900.0, False),
           (1.4e6, 960.0, False), (20e6, 20000.0, True)]
    for bps, want, crf in seq:
        got = rc.targets_kbps(bps)["color"]
        assert (got, isinstance(got, CappedCrf)) == (pytest.approx(want), crf), (bps, got)
    rc.factor = 0.5                                  # a coarser point: its cap is half, wide from 1.5x that
    assert rc.targets_kbps(0.4e6)["color"] == pytest.approx(400) and rc.targets_kbps(0.6e6)["color"] == pytest.approx(480)
    got = rc.targets_kbps(0.75e6)["color"]
    assert isinstance(got, CappedCrf) and got == pytest.approx(750)


def test_when_an_encoder_restarts() -> None:
    cfg = AdaptConfig(change_ratio=0.15, urgent_ratio=0.7)
    assert retarget(None, 800, False, cfg) == (True, False)          # not under rate control yet
    assert retarget(1000, 1100, True, cfg) == (False, False)         # within 15 %: left alone
    assert retarget(1000, 1500, False, cfg) == (False, False)        # a rise waits for the IDR that is due anyway
    assert retarget(1000, 1500, True, cfg) == (True, False)
    assert retarget(1000, 800, False, cfg) == (False, False)         # a small fall waits too
    assert retarget(1000, 600, False, cfg) == (True, True)           # a steep one restarts now, with an IDR


def test_config_errors_name_what_is_wrong() -> None:
    from splitrender.sim.config import RunConfig

    with pytest.raises(ConfigError, match="run config adapt: must be one of off, rate, full, got .fast."):
        RunConfig(adapt="fast", transport_cc=True)
    with pytest.raises(ConfigError, match="run config adapt: rate follows the estimated rate, so it needs transport_cc"):
        RunConfig(adapt="rate")
    with pytest.raises(ConfigError, match="smoothing"):
        AdaptConfig(smoothing=0)
    from splitrender.pipeline.session import ServerOptions
    from splitrender.server.server import ServerConfig

    with pytest.raises(ConfigError, match="server adapt: must be one of off, rate, full, got 'fast'"):
        ServerConfig(adapt="fast", transport_cc=True)
    with pytest.raises(ConfigError, match="server adapt rate: follows the estimated rate, so it needs transport_cc"):
        ServerConfig(adapt="rate")
    with pytest.raises(ConfigError, match="server adapt: must be one of off, rate, full, got 'on'"):
        ServerOptions(adapt="on")


def _noise(rng: np.random.Generator) -> np.ndarray:
    return (rng.random((90, 160, 3)) * 255).astype(np.uint8)


def test_the_pipeline_restarts_an_encoder_at_a_new_rate() -> None:
    """Noise at 160x90 (every frame costs what the rate allows): 1500 kbit/s, then a fall to 300 restarts the
    encoder at once with an IDR, and the frames after it are about 5x smaller; a rise waits for the GOP's IDR."""
    from splitrender.codecs.video import VideoCodecConfig
    from splitrender.methods.base import StreamSpec, Update
    from splitrender.pipeline.sender import StreamEncoder
    from splitrender.scene.pose import Pose

    tx = StreamEncoder([StreamSpec("color", VideoCodecConfig(gop=30), 160, 90)])
    rng = np.random.default_rng(1)

    def frame(i: int, kbps: float):  # type: ignore[no-untyped-def]
        return tx.encode(Update(i, i / 30, Pose(), {"color": _noise(rng)}, {}), rates_kbps={"color": kbps})

    first = frame(0, 1500)
    assert first.keyframe and first.restarts == 0 and first.rates_kbps == {"color": 1500}   # a fresh encoder
    high = [len(frame(i, 1500).video["color"].data) for i in range(1, 12)]
    drop = frame(12, 300)
    assert drop.restarts == 1 and drop.keyframe and drop.rates_kbps == {"color": 300}
    low = [len(frame(i, 300).video["color"].data) for i in range(13, 24)]
    assert np.mean(high[3:]) > 3.5 * np.mean(low[3:]), (np.mean(high), np.mean(low))
    rise = [frame(i, 1500) for i in range(24, 43)]   # the new encoder's GOP began at frame 12: its IDR is frame 42
    assert [e.restarts for e in rise] == [0] * 18 + [1] and rise[-1].keyframe and not any(e.keyframe for e in rise[:-1])


def test_adaptation_needs_the_feedback_and_probes_only_where_it_adapts() -> None:
    from splitrender.codecs.video import VideoCodecConfig
    from splitrender.methods.base import StreamSpec
    from splitrender.pipeline.sender import ServerPipeline
    from splitrender.pipeline.session import ServerOptions, ServerSession

    specs = [StreamSpec("color", VideoCodecConfig(), 160, 90)]
    with pytest.raises(ConfigError, match="server adapt rate: .* needs transport-wide feedback"):
        ServerSession(ServerPipeline(specs), 30.0, ServerOptions(adapt="rate"))
    from splitrender.pipeline import OutgoingFrame

    def probes(core: ServerSession) -> list[tuple[float, bytes]]:
        """A first frame's worth of sending, followed through the core's timer: the probe packets and their times."""
        core.frame_sent(0, OutgoingFrame(0, keyframe=True, wire_bytes={"color": 1000}), 0.0, 0)
        out, now = [], 0.0
        while now < 1000.0:
            out += [(now, d.data) for d in core.datagrams_to_send(now) if d.kind == "probe"]
            now = core.get_timer()
        return out

    measured = ServerSession(ServerPipeline(specs, transport_cc_id=5), 30.0, ServerOptions())
    assert probes(measured) == [] and measured.encoder_rates() is None
    adapting = ServerSession(ServerPipeline(specs, transport_cc_id=5), 30.0, ServerOptions(adapt="rate"))
    probe = probes(adapting)     # the start-up probe: 3x the start rate
    assert len(probe) >= 12 and all(b[8:12] == adapting.tx.probe_ssrc.to_bytes(4, "big") for _, b in probe)
    times = [t for t, _ in probe]
    assert times == sorted(times) and times[-1] > times[0]
    rates = adapting.encoder_rates()             # calibrating: the method's crf under a ceiling at its share of the
    assert rates == {"color": pytest.approx(270.0)} and isinstance(rates["color"], CappedCrf)   # start rate (0.9x)



@pytest.mark.parametrize("method", ["video", "atw", "warp", "sas", "tss", "quads"])
def test_the_estimator_is_the_methods_own_only_where_it_adapts_its_point(method: str) -> None:
    """A method's quality model may set its adapting session's estimator (``QualityModel.estimator``, issue 48): sas
    and tss (they redraw geometry at the display pose) start with bigger probes, video and atw keep GCC's own (and
    quads and warp, which hold their targets with it); the fields reach the estimator with ``adapt = "full"`` only,
    and an unknown field is a config error."""
    import dataclasses

    from splitrender.codecs.video import VideoCodecConfig
    from splitrender.methods import get_method
    from splitrender.methods.base import StreamSpec, with_model
    from splitrender.pipeline.gcc import GccConfig
    from splitrender.pipeline.sender import ServerPipeline
    from splitrender.pipeline.session import UNADAPTED_START_BPS, ServerOptions, ServerSession

    knobs = get_method(method).config().adapt_knobs()
    model = next(k.model for k in knobs if k.model is not None)
    tolerant = method in ("sas", "tss")
    assert bool(model.estimator) == tolerant
    specs = [StreamSpec("color", VideoCodecConfig(), 160, 90)]

    def estimator_cfg(adapt: str, knobs: tuple = knobs) -> GccConfig:
        core = ServerSession(ServerPipeline(specs, transport_cc_id=5), 30.0, ServerOptions(adapt=adapt), knobs=knobs)
        return core.estimator.cfg

    own = dict(model.estimator)
    assert estimator_cfg("full") == dataclasses.replace(GccConfig(), **own)
    assert estimator_cfg("rate") == GccConfig()
    assert estimator_cfg("off") == GccConfig(start_bps=UNADAPTED_START_BPS)
    if tolerant:
        assert len(own["start_probes"]) > len(GccConfig().start_probes)
    bad = with_model(knobs, dataclasses.replace(model, estimator=(("start_rate", 1e6),)))
    with pytest.raises(ConfigError, match="quality model estimator: .*start_rate"):
        estimator_cfg("full", bad)


def test_the_webrtc_profile_follows_the_receivers_estimate() -> None:
    """The browser front door's core (aiortc owns RTP: no transport-wide feedback) adapts to the estimate the page's
    browser reports (RTCP REMB, :meth:`ServerSession.receive_estimate`): the encoder's rate follows it down and up,
    clamped to the estimator's bounds, and a session that does not adapt, or one on RTP, only counts it."""
    from splitrender.codecs.video import VideoCodecConfig
    from splitrender.methods.base import StreamSpec
    from splitrender.pipeline import OutgoingFrame
    from splitrender.pipeline.sender import ServerPipeline
    from splitrender.pipeline.session import ServerOptions, ServerSession

    specs = [StreamSpec("color", VideoCodecConfig(), 160, 90)]
    core = ServerSession(ServerPipeline(specs), 30.0, ServerOptions(adapt="rate", pacing=False), transport="webrtc")
    assert core.encoder_rates() == {"color": pytest.approx(270.0)}     # GCC's start, 300 kbit/s, at its 0.9 share
    assert core.congestion()["cc_target_kbps"] == pytest.approx(300.0)

    def follow(bps: float, t_ms: float) -> float:
        core.receive_estimate(bps, t_ms)
        for k in range(30):     # a second of frames at what the encoder was told (the controller learns its cost)
            rates = core.encoder_rates()
            assert rates is not None
            size = int(rates["color"] * 1000 / 8 / 30)
            core.frame_sent(k, OutgoingFrame(k, keyframe=k == 0, wire_bytes={"color": size}), t_ms + k * 33.3, 0, rates)
        return core.encoder_rates()["color"]  # type: ignore[index]

    low = follow(150_000.0, 1000.0)
    assert core.congestion()["cc_target_kbps"] == pytest.approx(150.0) and low <= 150.0, low
    high = follow(2_000_000.0, 3000.0)
    assert core.congestion()["cc_target_kbps"] == pytest.approx(2000.0) and high > 5 * low, (low, high)
    follow(1.0, 5000.0)                                                  # below the floor: clamped to min_bps
    assert core.congestion()["cc_target_kbps"] == pytest.approx(100.0)
    follow(float("nan"), 6000.0)                                         # nonsense: ignored
    assert core.congestion()["cc_target_kbps"] == pytest.approx(100.0) and core.counters["estimates_received"] == 4
    plain = ServerSession(ServerPipeline(specs), 30.0, ServerOptions(), transport="webrtc")
    plain.receive_estimate(150_000.0, 0.0)
    assert plain.encoder_rates() is None and plain.congestion() == {} and plain.counters["estimates_received"] == 1


STEP = ((1.5, 3.0), (3.5, 0.6))


@pytest.fixture(scope="module")
def step_trace_path(tmp_path_factory):  # type: ignore[no-untyped-def]
    from splitrender.netsim.traces import step_trace, write_mahimahi

    return write_mahimahi(step_trace(list(STEP)), tmp_path_factory.mktemp("adapt") / "step.trace")


def _ages(res, a: float, b: float) -> np.ndarray:  # type: ignore[no-untyped-def]
    return np.array([f["update_age_ms"] for f in res.frames if a <= f["t_s"] < b and np.isfinite(f["update_age_ms"])])


@pytest.mark.slow
def test_a_step_down_is_followed_within_the_recovery_bound(step_trace_path) -> None:  # type: ignore[no-untyped-def]
    """``video`` on ``minimal``, 320x180, ``walk``, 20 ms each way over a capacity of 3 Mbit/s falling to 0.6 at
    1.5 s (4 s).  Adaptation off (crf 23, about 1.5 Mbit/s here) builds a queue that only grows: the last second's
    updates are 1.2-1.6 s old.  With ``adapt rate`` the encoders follow the estimate down; the recovery bound:
    from 1.5 s after the drop, p95 update age under 150 ms (measured: off 1570 ms, rate 100 ms; in between the
    queue the drop caught ages updates to 370 ms at most)."""
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import VirtualTimeRun

    res = {}
    for adapt in ("off", "rate"):
        res[adapt] = VirtualTimeRun(RunConfig(method="video", scene="minimal", trace="walk", duration_s=4.0, width=320,
                                              height=180, network=f"delay 20ms trace {step_trace_path}",
                                              transport_cc=True, adapt=adapt, metrics=False, seed=0)).run()
    off, rate = (float(np.percentile(_ages(res[a], 3.0, 4.0), 95)) for a in ("off", "rate"))
    assert rate < 150 and off > 1300, (off, rate)
    s = res["rate"].summary
    assert s["encoder_restarts"] >= 1 and s["probe_clusters"] >= 1, s
    # what went out after the drop fits the new 600 kbit/s with room to drain (measured 323 kbit/s over 2.5-4 s; 377
    # before the stream calibrated under a ceiling, when the encoder's learnt miss was older).  Its target is no
    # measure of it: the learnt miss lifts the target over what the encoder then sends (up to 430 kbit/s measured)
    sent = sum(u["bytes"] for u in res["rate"].updates if u["t_s"] >= 2.5) * 8 / 1.5 / 1000
    assert sent < 450, sent


def _adapt_run(path, method: str):  # type: ignore[no-untyped-def]
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import VirtualTimeRun

    return VirtualTimeRun(RunConfig(method=method, scene="minimal", trace="walk", duration_s=5.0, width=160, height=90,
                                    network=f"delay 20ms trace {path}", transport_cc=True, adapt="rate", metrics=False,
                                    seed=0)).run()


@pytest.mark.slow
def test_an_atlas_with_geometry_beside_it_follows_the_link(step_trace_path) -> None:  # type: ignore[no-untyped-def]
    """The same step (160x90, 5 s) for ``sas``, whose reliable geometry and metadata the controller pays for first
    and whose atlas repacks bring frequent I-frames: the atlas falls from the 714 kbit/s it took at its own crf to
    a 204 kbit/s target and the update age recovers (p95 from 2.5 s after the drop: 117 ms measured; at most 300
    ms in between)."""
    res = _adapt_run(step_trace_path, "sas")
    before = np.mean([u["bytes_atlas"] for u in res.updates if 0.5 <= u["t_s"] < 1.5]) * 8 * 30 / 1000   # kbit/s
    after = np.mean([u["adapt_atlas_kbps"] for u in res.updates if u["t_s"] >= 2.5])
    # measured 810 -> 198 kbit/s (0.244) since the start's first fill is paid once (fewer bytes before 1.5 s: 816 at
    # 508f5b7) and a calibrating ceiling is held through a blip (DIP_FRAMES); before those,
    # 924 -> 205 kbit/s (0.222), the same every run since encoders under a VBV run one thread (x264's sliced
    # threads coded it differently each run: 158-200 kbit/s in five runs before, docs/experiments.md); 932 -> 186 before
    # sas's metadata carried its shading-reuse counters (1b9e9a3: 13-16 bytes a frame, which the controller pays first)
    # 714 -> 204 kbit/s (0.285) since sas's reshade_eye_deg is on by default (a0efa28: fewer atlas bits at its crf)
    assert after < 0.31 * before and after < 215, (before, after)
    assert float(np.percentile(_ages(res, 4.0, 5.0), 95)) < 150            # measured 117 ms


@pytest.mark.slow
def test_rate_alone_cannot_save_a_lossless_depth_stream(step_trace_path) -> None:  # type: ignore[no-untyped-def]
    """``warp``'s depth is lossless HEVC (16-bit): the controller pays for it first and takes the colour down to its
    floor, but the depth alone (1.3-2.2 Mbit/s here) outweighs a 0.6 Mbit/s link, so the queue and the update age
    keep growing (measured 2.5 s at the end).  Depth precision is a knob for a per-method operating-point
    controller (issue 35, not built yet), not for the encoder rate."""
    res = _adapt_run(step_trace_path, "warp")
    assert "adapt_depth0_kbps" not in res.updates[-1]                      # not controlled: paid for
    late = [u for u in res.updates if u["t_s"] >= 2.5]
    assert all(u["adapt_color0_kbps"] == AdaptConfig().min_kbps for u in late)
    assert min(u["adapt_overhead_kbps"] for u in late) > 1000               # measured 1276 kbit/s at least
    assert float(np.percentile(_ages(res, 4.0, 5.0), 95)) > 2000            # measured 2518 ms


def test_run_adapt_rate_turns_the_feedback_on_and_is_written_with_the_run(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """``splitrender run --adapt rate``: the written config has both, and its summary the adaptation's counters."""
    import csv

    from splitrender.cli import main
    from splitrender.sim.config import RunConfig

    out = tmp_path / "run"
    assert main(["run", "--method", "video", "--scene", "minimal", "--width", "64", "--height", "36", "--duration", "0.4",
                 "--adapt", "rate", "--out", str(out)]) == 0
    cfg = RunConfig.from_toml(out / "config.toml")
    assert cfg.adapt == "rate" and cfg.transport_cc
    s = next(csv.DictReader(open(out / "summary.csv")))
    assert "encoder_restarts" in s and "probe_clusters" in s and int(s["twcc_feedback"]) >= 1, s
    assert RunConfig(adapt="rate", transport_cc=True).key() != RunConfig(transport_cc=True).key()


def test_capacity_trace_writes_a_trace_the_links_read(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    from splitrender.cli import main
    from splitrender.netsim.models import load_mahimahi_trace
    from splitrender.netsim.traces import trace_stats

    out = tmp_path / "step.trace"
    assert main(["capacity-trace", "step", "1:20,2:2", str(out)]) == 0
    stamps = load_mahimahi_trace(out)
    assert stamps[-1] == 3000 and trace_stats(stamps)["mean_mbps"] == pytest.approx((20 + 2 * 2) / 3, rel=0.02)
    assert f'trace {out}' in capsys.readouterr().out
    assert main(["capacity-trace", "cellular", "4", str(tmp_path / "cell.trace"), "--mean", "6", "--seed", "3"]) == 0
    assert main(["capacity-trace", "step", "1-20", str(out)]) == 2
    assert "capacity-trace step: '1-20' is not seconds:Mbit/s (e.g. 5:20)" in capsys.readouterr().err


def test_a_welcome_with_a_bad_probe_ssrc_is_refused_by_name() -> None:
    """``Welcome.method_params.probe_ssrc`` must be an SSRC no stream of the session uses."""
    from splitrender.codecs.video import VideoCodecConfig
    from splitrender.methods.base import StreamSpec
    from splitrender.pipeline import ClientOptions, ClientSession, EnvelopeError, ServerPipeline
    from splitrender.protocol import Welcome

    tx = ServerPipeline([StreamSpec("color", VideoCodecConfig(), 160, 90)], transport_cc_id=5)
    good = tx.welcome_params(b"")
    streams = tx.describe("127.0.0.1", 5000, "t")
    assert ClientSession.from_welcome(Welcome("s", "video", good, streams), ClientOptions()).probe_ssrc == tx.probe_ssrc
    for bad in ("1234", -1, 1 << 32, True, streams[0].ssrc):
        with pytest.raises(EnvelopeError, match="Welcome.method_params.probe_ssrc: expected an SSRC no stream uses, got"):
            ClientSession.from_welcome(Welcome("s", "video", {**good, "probe_ssrc": bad}, streams), ClientOptions())


def test_a_latency_tolerant_method_gives_its_capped_encoders_a_longer_buffer() -> None:
    """With ``sas``'s quality model (tolerance 300 ms) the point controller sets the rate controller's VBV buffer to
    half of what that tolerance leaves past video's 100 ms budget; a ceiling carries it, scaled or not, into the
    encoder's config, where it lets an IDR take more of its crf's bits: 8.0 kB against 4.5 kB under a 1 Mbit/s cap
    with two frames' buffer (measured, 320x176; the crf alone: 32.4 kB).  ``video`` (100 ms) keeps two frames."""
    from splitrender.codecs.video import VideoCodecConfig, VideoEncoder
    from splitrender.methods.base import SCALE_KNOB
    from splitrender.methods.sas.config import QUALITY as SAS
    from splitrender.methods.video import QUALITY as VIDEO
    from splitrender.pipeline.adapt import BURST_SHARE, PointController, scale_rate

    import dataclasses

    for model, want in ((SAS, BURST_SHARE * (300.0 - 100.0)), (VIDEO, None)):
        rc = RateController(("atlas",), 30.0)
        PointController((dataclasses.replace(SCALE_KNOB, model=model),), rc)
        assert rc.buffer_ms == want
        ceiling = rc.targets_kbps(2e6)["atlas"]
        assert isinstance(ceiling, CappedCrf) and ceiling.buffer_ms == want
        assert scale_rate(ceiling, 2).buffer_ms == want and float(scale_rate(ceiling, 2)) == 2 * float(ceiling)
    rng = np.random.default_rng(0)
    base = (rng.random((22, 40, 3)) * 255).astype(np.uint8).repeat(8, 0).repeat(8, 1)
    img = np.clip(base.astype(int) + rng.integers(-20, 20, base.shape), 0, 255).astype(np.uint8)
    idr = {b: VideoEncoder(VideoCodecConfig(crf=23.0, cap_kbps=1000.0, cap_buffer_ms=b), 320, 176).encode(img, True).nbytes
           for b in (None, 200.0)}
    assert idr[200.0] > 1.5 * idr[None], idr
    with pytest.raises(ConfigError, match="cap_buffer_ms"):
        VideoCodecConfig(cap_kbps=1000.0, cap_buffer_ms=-1.0)


def test_the_start_up_probes_go_out_back_to_back_and_climb_faster_until_an_overuse() -> None:
    """The 3x and 6x start-up clusters: the second once the first has been sent, before any result; a probe that
    finds what it was sent at is followed by one at ``start_climb`` (3) times the estimate until the first over-use,
    at 2x after it."""
    from splitrender.pipeline.gcc import GccConfig, ProbeController
    from splitrender.protocol.twcc import PacketResult

    pc = ProbeController(GccConfig())
    a = pc.next_cluster(3e5, 0)
    assert a is not None and a.rate_bps == pytest.approx(9e5)
    assert pc.next_cluster(3e5, a.end_us - 1) is None                    # the first still going out
    b = pc.next_cluster(3e5, a.end_us)
    assert b is not None and b.rate_bps == pytest.approx(1.8e6)
    assert pc.next_cluster(3e5, b.end_us + 1) is None                    # then one at a time, after its result

    def deliver(cl) -> None:                                             # type: ignore[no-untyped-def]
        for k in range(cl.packets):
            send = cl.start_us + int(k * cl.spacing_us())
            pc.on_result(PacketResult(k, send, cl.packet_bytes, send + 20_000, cl.cluster))

    deliver(a)
    deliver(b)
    assert pc.evaluate(b.end_us + 1) == pytest.approx(1.8e6, rel=0.15)
    c = pc.next_cluster(1.6e6, 300_000)
    assert c is not None and c.rate_bps == pytest.approx(3 * 1.6e6)
    deliver(c)
    pc.on_decrease(400_000)
    pc.evaluate(c.end_us + 1)
    assert pc.next_cluster(4e6, 450_000).rate_bps == pytest.approx(2 * 4e6)  # type: ignore[union-attr]
    with pytest.raises(ConfigError, match="start_climb"):
        GccConfig(start_climb=1.0)


def test_a_method_whose_estimator_probes_high_at_start_codes_its_first_frames_under_that_probe() -> None:
    """START_BOOST: tss's estimator sends start-up probes to 24x the 300 kbit/s guess at 0 s; until the first
    measurement its calibrating streams keep their share of that (0.9 x 7.2 Mbit/s), not of the guess (tss coded its
    first atlas IDR in 2.9 kB under 270 kbit/s); once the estimate moves, its own share (no blip hold from the
    boosted ceiling).  sas (the same probes, its model's ``start_boost`` off) and quads (GCC's probes) keep the
    guess's share."""
    import dataclasses

    from splitrender.methods.base import SCALE_KNOB
    from splitrender.methods.quads.config import QUALITY as QUADS
    from splitrender.methods.sas.config import QUALITY as SAS
    from splitrender.methods.tss.config import QUALITY as TSS
    from splitrender.pipeline.adapt import PointController

    for model, boost in ((TSS, 24.0), (SAS, 1.0), (QUADS, 1.0)):
        rc = RateController(("atlas",), 30.0)
        PointController((dataclasses.replace(SCALE_KNOB, model=model),), rc)
        assert rc.start_boost == boost
        assert rc.targets_kbps(3e5)["atlas"] == pytest.approx(270.0 * boost)
        assert rc.targets_kbps(1e6)["atlas"] == pytest.approx(900.0)      # measured: the estimate's share
