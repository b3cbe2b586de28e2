"""``--adapt full``: each method's operating point from the estimate (issue 35, step 4).

Sans-IO: the ladder, the point controller under a falling and a rising budget, each method's knobs moving the right
way.  With the codecs: resampled colour round trips, depth precision and depth step through the wire, a smaller
picture brought back to the declared size by the client's pipeline.  In virtual time: a lossless-depth method that
rate adaptation alone cannot save recovers over a step trace.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from splitrender.methods.base import SCALE_KNOB, Knob
from splitrender.pipeline.adapt import AdaptConfig, PointController, RateController, build_ladder


def test_the_ladder_lowers_each_knob_in_turn() -> None:
    a = Knob("a", (3, 2, 1), (1.0, 0.5, 0.25))
    b = Knob("b", (1.0, 0.5), (1.0, 0.4), "data")
    assert build_ladder((a, b)) == [(0, 0), (1, 0), (1, 1), (2, 1)]
    assert build_ladder((a,)) == [(0,), (1,), (2,)]
    late = Knob("c", (1, 2), (1.0, 0.5), "both", order=1)      # lowered once the others are spent
    assert build_ladder((late, b)) == [(0, 0), (0, 1), (1, 1)]


def test_a_knob_s_costs_must_start_at_one_and_fall() -> None:
    from splitrender.errors import ConfigError

    with pytest.raises(ConfigError, match="knob x: costs must start at 1 and fall"):
        Knob("x", (1, 2), (1.0, 1.2))
    with pytest.raises(ConfigError, match="knob x: needs two or more levels"):
        Knob("x", (1,), (1.0,))


def _calibrated(video_kbps: float, overhead_kbps: float, cfg: AdaptConfig) -> RateController:
    """A rate controller that has seen 30 frames: one stream at ``video_kbps``, ``overhead_kbps`` of data beside."""
    rate = RateController(("color",), 30.0, cfg)
    for _ in range(cfg.calibrate_frames):
        rate.on_frame_sent({"color": int(video_kbps * 1000 / 8 / 30), "meta": int(overhead_kbps * 1000 / 8 / 30)})
    assert rate.calibrated
    return rate


@pytest.mark.parametrize("halved_first", [False, True])
def test_a_calibration_across_two_frame_rates_gives_the_own_point_s_rate(halved_first: bool) -> None:
    """Half the window at the method's own point (2 kB a frame at 30 fps: 480 kbit/s), half at one frame in 2
    (the point's prior 0.67: 2.68 kB a frame at 15 fps); the cap is the own point's 480 kbit/s either way.  Counted
    as bytes per frame at the last frame rate it came out 1.49x or 0.75x of it."""
    cfg = AdaptConfig()
    rate = RateController(("color",), 30.0, cfg)
    spans = [(30.0, 1.0, 2000), (15.0, 0.67, 2680)]
    for fps, factor, size in (spans[::-1] if halved_first else spans):
        rate.fps, rate.factor = fps, factor
        for _ in range(cfg.calibrate_frames // 2):
            rate.on_frame_sent({"color": size})
    assert rate.calibrated
    assert rate.natural_video_bps() == pytest.approx(480e3, rel=0.01)


def test_the_point_goes_down_at_once_and_back_up_after_a_hold() -> None:
    cfg = AdaptConfig(up_hold_s=1.0, down_hold_s=0.5)
    rate = _calibrated(2000.0, 200.0, cfg)
    pc = PointController((SCALE_KNOB,), rate, cfg)
    assert pc.update(0.0, 10e6) is False and pc.index == 0      # room: the method's own point
    # 1 Mbit/s: 0.9 Mbit/s to spend; scale 0.75 costs 200 + 2000 * 0.55 / 1.5 = 933 kbit/s: too much; 0.5 fits
    assert pc.update(1.0, 1e6) and pc.values() == {"scale": 0.5}
    assert rate.factor == pytest.approx(SCALE_KNOB.cost[2])      # the encoders' caps follow the point
    assert pc.update(1.2, 0.1e6) is False                         # nothing lower to go to
    # 1.25 Mbit/s: 1125 kbit/s to spend; scale 0.75's 933 fits within the up margin (0.85 * 1125 = 956), 1's 1533 not
    assert pc.update(2.0, 1.25e6) is False                        # fits: the hold starts
    assert pc.update(2.5, 1.25e6) is False
    assert pc.update(3.05, 1.25e6) and pc.values() == {"scale": 0.75}     # after up_hold_s, one point up
    # capacity back: after the hold, up to the richest point that fits with room to spare, in one move
    pc2 = PointController((Knob("a", (1, 2, 3), (1.0, 0.6, 0.3)), SCALE_KNOB), _calibrated(2000.0, 200.0, cfg), cfg)
    pc2.update(0.0, 0.3e6)
    assert pc2.index == len(pc2.ladder) - 1
    assert pc2.update(1.0, 10e6) is False and pc2.update(2.1, 10e6) and pc2.index == 0
    # a queue past the motion-to-photon budget and still growing is a point that does not fit, whatever the costs say
    assert pc2.update(3.0, 10e6, queue_ms=120.0) and pc2.index == 1
    assert pc2.update(3.6, 10e6, queue_ms=110.0) is False         # draining: the estimate takes care of it


def test_the_point_waits_for_the_encoders_to_be_calibrated() -> None:
    cfg = AdaptConfig()
    rate = RateController(("color",), 30.0, cfg)
    pc = PointController((SCALE_KNOB,), rate, cfg)
    assert pc.update(0.0, 1e3) is False and pc.index == 0


def test_data_costs_are_learnt_at_each_point() -> None:
    """The data rate a point sends is measured once the session has been there ``settle_frames``; points not visited
    are the nearest learnt one scaled by the priors."""
    cfg = AdaptConfig(settle_frames=5)
    rate = _calibrated(500.0, 3000.0, cfg)
    depth = Knob("depth_bits", (16, 8), (1.0, 0.3), "data")
    pc = PointController((depth,), rate, cfg)
    assert pc.data_bps(1) == pytest.approx(0.3 * pc.data_bps(0))
    for _ in range(5):
        pc.on_frame_sent()
    learnt = pc.data_bps(0)
    pc.update(0.0, 1.5e6)                   # 3 Mbit/s of data does not fit 1.35: down to 8 bits
    assert pc.index == 1
    for _ in range(30):   # what 8 bits really send: 200 kbit/s (a sixth, not the prior's 0.3)
        rate.on_frame_sent({"color": 2000, "meta": int(200 * 1000 / 8 / 30)})
        pc.on_frame_sent()
    assert pc.data_bps(1) < 0.2 * learnt and pc.data_bps(0) == learnt


def _knobs(method: str) -> tuple[Knob, ...]:
    from splitrender.methods import get_method, make_config

    knobs = make_config(get_method(method).config, {}).adapt_knobs()
    return knobs + ((SCALE_KNOB,) if method in ("video", "atw", "warp") else ())


@pytest.mark.parametrize("model", [False, True])
@pytest.mark.parametrize("method", ["video", "atw", "warp", "sas", "tss", "quads", "probes"])
def test_each_method_s_knobs_move_the_right_way_under_a_falling_target(method: str, model: bool) -> None:
    """Under a budget falling from 20 to 0.2 Mbit/s every knob only ever moves to a cheaper level, the expected cost
    falls with it, and the coarsest point is reached; each method has at least one knob.  With the method's quality
    model (``tests/test_adapt_quality.py``) the last point is the one the model rates best at 0.2 Mbit/s, which may
    squeeze the encoders rather than lose the coarsest point's detail, and the point has moved."""
    import dataclasses

    knobs = _knobs(method)
    assert knobs, method
    if not model:
        knobs = tuple(dataclasses.replace(k, model=None) for k in knobs)
    cfg = AdaptConfig(down_hold_s=0.0)
    rate = _calibrated(2000.0, 500.0, cfg)
    pc = PointController(knobs, rate, cfg)
    seen, costs = [pc.ladder[0]], [pc.cost_bps(0)]
    for k, budget in enumerate(np.geomspace(20e6, 0.2e6, 40)):
        pc.update(float(k), float(budget))
        if pc.ladder[pc.index] != seen[-1]:
            assert all(b >= a for a, b in zip(seen[-1], pc.ladder[pc.index])), (method, seen[-1], pc.ladder[pc.index])
            seen.append(pc.ladder[pc.index])
            costs.append(pc.cost_bps(pc.index))
    if model:
        assert pc.model is not None and pc.index > 0
        scores = [pc.expected_db(i, cfg.headroom * 0.2e6) for i in range(len(pc.ladder))]
        assert scores[pc.index] == max(scores), (method, scores)
    else:
        assert pc.model is None and pc.index == len(pc.ladder) - 1, method
    assert all(b < a for a, b in zip(costs, costs[1:])), (method, costs)
    cheaper = {k.name: (k.levels[0], k.levels[-1]) for k in knobs}
    for name, (first, last) in cheaper.items():   # the direction of each knob: what it sends falls
        if name in ("depth_step", "frame_div", "probe_div"):
            assert last > first
        else:
            assert last < first, name


def test_resampling_keeps_flat_colour_and_round_trips_smooth_pictures() -> None:
    from splitrender.codecs.resize import is_scaled, resize, scaled_size

    assert scaled_size(320, 180, 0.75) == (240, 136) and scaled_size(320, 180, 0.5) == (160, 90)
    flat = np.full((180, 320, 3), 77, np.uint8)
    assert np.all(resize(resize(flat, 160, 90), 320, 180) == 77)
    y, x = np.mgrid[0:180, 0:320]
    smooth = np.stack([x * 255 // 319, y * 255 // 179, (x + y) * 255 // 498], -1).astype(np.uint8)
    back = resize(resize(smooth, 240, 136), 320, 180).astype(int)
    assert np.abs(back - smooth)[2:-2, 2:-2].max() <= 2          # a ramp survives down and up
    assert is_scaled(160, 90, 320, 180) and is_scaled(240, 136, 320, 180)
    assert not is_scaled(320, 90, 320, 180) and not is_scaled(40, 22, 320, 180) and not is_scaled(322, 180, 320, 180)


def test_a_scaled_stream_is_coded_small_and_decoded_at_the_declared_size() -> None:
    """The server codes a scalable stream at the scale asked (a new encoder, an IDR); the client's pipeline brings the
    picture back to the declared size; a stream not declared scalable keeps its size."""
    from splitrender.codecs.video import VideoCodecConfig, VideoDecoder
    from splitrender.methods.base import StreamSpec, Update
    from splitrender.pipeline.receiver import ClientPipeline, RxStream, Work
    from splitrender.pipeline.sender import StreamEncoder
    from splitrender.protocol import AccessUnit
    from splitrender.scene.pose import Pose

    codec = VideoCodecConfig(codec="h264", crf=23.0, gop=30, preset="ultrafast", pix_fmt="yuv444p", fps=30)
    tx = StreamEncoder([StreamSpec("color", codec, 128, 72, scalable=True), StreamSpec("other", codec, 128, 72)])
    y, x = np.mgrid[0:72, 0:128]
    img = np.stack([x * 2, y * 3, (x * 7 ^ y * 13) & 255], -1).astype(np.uint8)     # ramps, and detail in blue
    full = tx.encode(Update(0, 0.0, Pose(), {"color": img, "other": img}))
    half = tx.encode(Update(1, 1 / 30, Pose(), {"color": img, "other": img}), scale=0.5)
    assert half.video["color"].keyframe and not half.video["other"].keyframe and half.restarts == 1
    assert len(half.video["color"].data) < 0.6 * len(full.video["color"].data)
    rx = RxStream("color", "video", "h264", decoder=VideoDecoder("h264"), size=(72, 128))
    plane = ClientPipeline.decode(Work(rx, AccessUnit(half.video["color"].data, 0, 0, 0, 0.0, 0.0, True, 1), 0.0))
    assert plane.shape == (72, 128, 3)
    assert np.abs(plane.astype(int) - img)[..., :2].mean() < 3.0          # the ramps come back


def test_depth_precision_zeroes_what_the_coded_plane_carries() -> None:
    from splitrender.codecs.depth import coarsen_depth, pack_depth_planes, unpack_depth_planes

    codes = np.random.default_rng(0).integers(1, 65535, (16, 16)).astype(np.uint16)
    codes[0, 0] = 0
    for bits in (12, 10, 8):
        c = coarsen_depth(codes, bits)
        step = 1 << (16 - bits)
        assert c[0, 0] == 0 and np.all(c[1:, :] > 0)                                 # background stays, surfaces too
        big = codes >= step                                  # (codes under one step, the farthest, go to the first bucket)
        assert np.abs(c.astype(int) - codes)[big].max() < step and np.all(c[~big & (codes > 0)] >= step)
        packed = pack_depth_planes(c)
        assert np.all(packed[16:].astype(int) % step == 0)                         # dropped bits zero once folded
        assert np.array_equal(unpack_depth_planes(packed), c)


def test_warp_s_depth_step_goes_through_the_wire() -> None:
    """A warp server at ``depth_step`` 2 keeps one depth sample in four, top left; the client's parser repeats each
    one back over the view (a surface's depth is the same where it is, within one sample)."""
    from splitrender.methods import get_method, make_config
    from splitrender.methods.base import DecodedUpdate
    from splitrender.pipeline.direct import server_context
    from splitrender.methods.warp.wire import parse_update
    from splitrender.render.renderer import Renderer
    from splitrender.scene.loader import get_scene
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.trace import get_trace

    spec = get_method("warp")
    scene = get_scene("minimal")
    intr = CameraIntrinsics(64, 36, 60.0, 0.05, 200.0)
    pose = get_trace("walk", scene=scene).pose_at(0.5)
    r = Renderer()
    out = {}
    for step in (1, 2):
        cfg = make_config(spec.config, {"depth_step": step})
        srv = spec.server_class(cfg, intr, scene, 30)
        ctx = server_context(scene, r, intr, pose, t_s=0.5)
        upd = srv.produce(ctx)
        dec = DecodedUpdate(0, 0.5, pose, upd.planes, upd.meta)
        out[step] = parse_update(dec, cfg, srv.ref_intr).views[0].depth_m
        if step == 2:
            assert upd.meta["views"][0]["depth_step"] == 2
            d = upd.planes["depth0"]
            h = d.shape[0] // 2
            assert not d[:h][-(-h // 2):].any()            # the lower half of the high bytes is zero
    a, b = out[1], out[2]
    assert a.shape == b.shape
    assert np.array_equal(a[::2, ::2], b[::2, ::2])      # the kept samples are exact
    near = np.isclose(a, b, rtol=0.05) | ((a == 0) == (b == 0)) & (a == 0)
    assert near.mean() > 0.8, near.mean()


@pytest.mark.slow
def test_full_adaptation_saves_a_lossless_depth_stream(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The step of ``test_adapt.py`` (3 -> 0.6 Mbit/s at 1.5 s; minimal, 160x90, 5 s) for ``warp``: with ``rate``
    alone its lossless depth outweighs the link and updates age past 2 s.  With ``full`` the controller lowers the
    depth's bits and samples and the colour's resolution, and the update age recovers: p95 over the last second
    under 200 ms (measured 117 ms; 750-817 ms at most in between)."""
    from splitrender.netsim.traces import step_trace, write_mahimahi
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import VirtualTimeRun

    path = write_mahimahi(step_trace([(1.5, 3.0), (3.5, 0.6)]), tmp_path / "step.trace")
    res = VirtualTimeRun(RunConfig(method="warp", scene="minimal", trace="walk", duration_s=5.0, width=160, height=90,
                                   network=f"delay 20ms trace {path}", transport_cc=True, adapt="full", metrics=False,
                                   seed=0)).run()
    late = [u for u in res.updates if u["t_s"] >= 2.5]
    assert all(u["adapt_knob_depth_bits"] == 8 and u["adapt_knob_depth_step"] == 2 and u["adapt_knob_scale"] == 0.5
               for u in late)
    ages = [f["update_age_ms"] for f in res.frames if f["t_s"] >= 4.0 and np.isfinite(f["update_age_ms"])]
    assert float(np.percentile(ages, 95)) < 200, np.percentile(ages, 95)
    assert res.summary["point_moves"] >= 1 and res.summary["lowest_point"] == 6


def test_the_knobs_settings_out_of_range_are_refused_by_name() -> None:
    from splitrender.errors import ConfigError
    from splitrender.methods import get_method, make_config

    for method, params, field in (("warp", {"depth_bits": 7}, "depth_bits"), ("warp", {"depth_step": 5}, "depth_step"),
                                  ("quads", {"merge_scale": 0.0}, "merge_scale"),
                                  ("probes", {"probe_div": 0}, "probe_div"), ("probes", {"probe_div": 31}, "probe_div"),
                                  ("probes", {"probe_bits": 3}, "probe_bits"), ("probes", {"vis_bits": 11}, "vis_bits"),
                                  ("sas", {"reset_period": 0}, "reset_period"), ("tss", {"pvs_ring": 9}, "pvs_ring"),
                                  ("tss", {"pvs_ring": -1}, "pvs_ring"),
                                  ("tss", {"budget_max_spp": 16.5}, "budget_max_spp")):
        with pytest.raises(ConfigError, match=field):
            make_config(get_method(method).config, params)
    for kw in ({"stretch": 0.5}, {"up_margin": 0.0}, {"up_hold_s": -1.0}, {"mtp_budget_ms": 0.0}, {"settle_frames": 0}):
        with pytest.raises(ConfigError, match=f"AdaptConfig.{next(iter(kw))}"):
            AdaptConfig(**kw)
    from splitrender.pipeline.gcc import GccConfig

    for kw in ({"stale_overuse_ms": -1.0}, {"drained_ms": math.nan}, {"stale_window_ms": math.inf}):
        with pytest.raises(ConfigError, match=f"GccConfig.{next(iter(kw))}"):
            GccConfig(**kw)


def test_a_warp_view_with_a_depth_step_out_of_range_is_refused_by_name() -> None:
    from splitrender.methods import get_method, make_config
    from splitrender.methods.base import DecodedUpdate
    from splitrender.methods.warp.config import reference_intrinsics
    from splitrender.methods.warp.wire import WarpMetaError, parse_update
    from splitrender.scene.pose import CameraIntrinsics, Pose

    cfg = make_config(get_method("warp").config, {})
    ref = reference_intrinsics(CameraIntrinsics(32, 18, 60.0, 0.05, 200.0), cfg.fov_scale, cfg.resolution_scale)
    h, w = ref.height, ref.width
    meta = {"v": 1, "depth_coding": "lossless", "depth_near_m": 0.1, "ref": [w, h, ref.fov_y_deg],
            "views": [{"pose": Pose().to_list(), "ids": np.zeros((h, w), np.uint8), "depth_step": 9}],
            "obj_ids": np.zeros(0, np.uint16), "dyn_ids": np.zeros(0, np.uint16), "obj_model": np.zeros((0, 4, 4)),
            "dyn_prev": np.zeros((0, 4, 4)), "dt_s": 1 / 30}
    planes = {"color0": np.zeros((h, w, 3), np.uint8), "depth0": np.zeros((2 * h, w), np.uint8)}
    with pytest.raises(WarpMetaError, match="depth_step"):
        parse_update(DecodedUpdate(3, 0.1, Pose(), planes, meta), cfg, ref)
