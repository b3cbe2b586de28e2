"""``quads``: QUASAR and QuadStream (issue 10).

The 80-bit packing and the wire, quads against their G-buffer (exact at the server's
pose), monotone quad counts over the thresholds, effective depth peeling against a
brute-force reference, temporal compression, quality under latency beside ``warp``,
QuadStream's rate beside QUASAR's, and malformed quad data."""

from __future__ import annotations


import numpy as np
import pytest

from splitrender.methods.quads.config import QuadParams
from splitrender.methods.quads.gen import QuadSet, decode_normals, encode_normals, generate
from splitrender.methods.quads.wire import (KIND_HIDDEN, KIND_REFERENCE, QuadsWireError, WireSet, byte_planes, decode_sets,
                                            encode_sets, from_byte_planes, pack, unpack)
from splitrender.scene.pose import CameraIntrinsics, Pose
from splitrender.sim.runner import RunConfig

INTR = CameraIntrinsics(320, 180)


def _random_set(rng: np.random.Generator, n: int) -> QuadSet:
    level = rng.integers(0, 3, n).astype(np.uint8)   # at most 16 pixels a quad: 1000 quads fit one slot
    s = 2 ** level.astype(np.int64)
    x = (rng.integers(0, 320, n) // s * s).clip(0, 320 - s).astype(np.uint16)
    y = (rng.integers(0, 180, n) // s * s).clip(0, 180 - s).astype(np.uint16)
    flat = rng.random(n) < 0.7
    return QuadSet(level, x, y, rng.integers(0, 256, n).astype(np.uint8), rng.integers(0, 256, n).astype(np.uint8),
                   rng.uniform(0.1, 90, n).astype(np.float32), flat, rng.normal(0, 0.1, ((~flat).sum(), 16)).astype(np.float16))


def test_the_80_bit_packing_round_trips_exactly() -> None:
    """Every field of the u32 (level 6 bits, x and y 12, flat, alpha) and the whole wire (two sets, offsets) come back bit for bit."""
    rng = np.random.default_rng(0)
    n = 5000
    lv, x, y = rng.integers(0, 64, n), rng.integers(0, 4096, n), rng.integers(0, 4096, n)
    fl, al = rng.random(n) < 0.5, rng.random(n) < 0.5
    got = unpack(pack(lv, x, y, fl, al))
    for a, b in zip(got, (lv, x, y, fl, al)):
        assert np.array_equal(a.astype(np.int64), np.asarray(b).astype(np.int64))
    sets = [WireSet(KIND_REFERENCE, 0, 1, _random_set(rng, 700)), WireSet(KIND_HIDDEN, 2, 0, _random_set(rng, 300))]
    q, o = encode_sets(sets)
    assert len(q) == 4 + 2 * 12 + 1000 * 10, "80 bits a quad plus the header"
    # the multi-byte arrays go as byte planes: every element's byte 0, then every byte 1, ...
    assert byte_planes(np.array([0x01020304, 0x05060708]), "<u4") == bytes([4, 8, 3, 7, 2, 6, 1, 5])
    assert from_byte_planes(b"\0" + bytes([4, 8, 3, 7, 2, 6, 1, 5]), "<u4", 2, 1).tolist() == [0x01020304, 0x05060708]
    assert len(o) == 32 * sum(int((~s.quads.flat).sum()) for s in sets)
    back = decode_sets(q, o, "frame 0", (320, 180), 6, 3, 100.0)
    for a, b in zip(back, sets):
        assert (a.kind, a.slot, a.camera) == (b.kind, b.slot, b.camera)
        for k in ("level", "x", "y", "theta", "phi", "depth", "flat", "offsets"):
            assert np.array_equal(getattr(a.quads, k), getattr(b.quads, k)), k
    n3 = rng.normal(size=(1000, 3))
    n3 /= np.linalg.norm(n3, axis=1, keepdims=True)
    err = np.degrees(np.arccos(np.clip((decode_normals(*encode_normals(n3)) * n3).sum(1), -1, 1)))
    assert err.max() < 1.1, "8 + 8 bit spherical normals stay within a degree"


def _gbuffer(renderer, t: float = 0.5, trace: str = "walk"):  # type: ignore[no-untyped-def]
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    scene = get_scene("default+nogi")
    pose = get_trace(trace, scene=scene).pose_at(t)
    return scene, pose, renderer.render(scene, t, pose, INTR, ("color", "depth", "normal"))


def test_quad_count_falls_monotonically_with_the_thresholds(renderer) -> None:  # type: ignore[no-untyped-def]
    """Default view, 320x180 (57.6k pixels).  Quads against delta_sim 0 / 0.05 / 0.1 / 0.5 / 2 (no coarse
    pass): measured 57.6k, 8.92k, 8.85k, 8.63k, 6.08k; against coarse passes 0-4 at delta_sim 0.5: 8.63k, 7.95k,
    7.91k, 7.90k, 7.90k; non-flat quads against delta_flatten 0.01 / 0.05 / 0.2 / 1: 1080, 69, 23, 4.  Every
    quad set covers every pixel once."""
    _, pose, g = _gbuffer(renderer)
    rot = pose.view_matrix()[:3, :3]

    def run(**kw: float) -> QuadSet:
        q = generate(g.depth, g.normal, rot, INTR, QuadParams(**{"delta_max": 1e-4, "delta_sim": 0.5, "delta_flatten": 0.2,
                                                                 "coarse_passes": 3, **kw}), background=True)
        assert q.pixels() == INTR.width * INTR.height
        return q

    by_sim = [len(run(delta_sim=s, coarse_passes=0)) for s in (0.0, 0.05, 0.1, 0.5, 2.0)]
    by_coarse = [len(run(coarse_passes=c)) for c in range(5)]
    by_flat = [int((~run(delta_flatten=f).flat).sum()) for f in (0.01, 0.05, 0.2, 1.0)]
    for seq in (by_sim, by_coarse, by_flat):
        assert all(a >= b for a, b in zip(seq, seq[1:])), (by_sim, by_coarse, by_flat)
    assert by_sim[0] == INTR.width * INTR.height and by_sim[-1] < by_sim[0] / 8, by_sim   # measured 9.5x fewer
    assert by_coarse[-1] < by_coarse[0] and by_flat[-1] < by_flat[0], (by_coarse, by_flat)


def _frame(renderer, params: dict, t: float = 0.5, frame_id: int = 0, srv=None, pose: Pose | None = None):  # type: ignore[no-untyped-def]
    from splitrender.methods import get_method, make_config
    from splitrender.pipeline.direct import server_context
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    scene = get_scene("default+nogi")
    spec = get_method("quads")
    cfg = make_config(spec.config, {"lossless": True, **params})
    pose = pose or get_trace("walk", scene=scene).pose_at(t)
    srv = srv or spec.server_class(cfg, INTR, scene, 30, None)
    ctx = server_context(scene, renderer, INTR, pose, t_s=t, frame_id=frame_id)
    return srv, srv.produce(ctx), spec, cfg, scene, pose


def _decoded(upd):  # type: ignore[no-untyped-def]
    from splitrender.methods import DecodedUpdate

    return DecodedUpdate(upd.frame_id, upd.t_s, upd.pose, upd.planes, upd.meta, dict(upd.data))


@pytest.mark.parametrize("variant", ["quasar", "quadstream"])
def test_at_the_servers_pose_the_mesh_shows_the_truth(renderer, variant: str) -> None:  # type: ignore[no-untyped-def]
    """A lossless atlas drawn from the pose the quads were made at: QUASAR (one layer, and the defaults: a hidden layer and the wide view)
    reproduces the truth pixel for pixel (measured: every pixel equal), since every quad projects onto its own
    pixels whatever its depth.  So does QuadStream, whose centre view takes priority over its later views (issue 50;
    ``tests/test_quads_still.py``): before, its corner views' quads, not pixel-aligned with the centre view (the
    artefact the QUASAR paper's figure 6 shows), won the depth test along every edge: 26.78 dB.  20 cm to the side,
    measured: QUASAR 27.73 dB with 1.06 % holes, QuadStream 28.76 dB with 0.02 % (25.92 dB before)."""
    from splitrender.metrics.image import psnr

    for params in ([{"layers": 1, "wide_fov_deg": 0.0}, {}] if variant == "quasar" else [{"variant": "quadstream"}]):
        srv, upd, spec, cfg, scene, pose = _frame(renderer, params)
        cli = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
        cli.apply(_decoded(upd))
        truth = renderer.render(scene, 0.5, pose, INTR).color
        got = cli.render(pose, 0.5)
        assert (got.color == truth).all(-1).mean() > 0.999 and not got.holes.any(), params
    side = Pose(pose.position + pose.matrix()[:3, :3] @ np.array([0.2, 0.0, 0.0]), pose.orientation)
    moved = cli.render(side, 0.5)
    aside = psnr(moved.color, renderer.render(scene, 0.5, side, INTR).color)
    if variant == "quasar":
        assert aside > 26.5 and moved.holes.mean() < 0.015
    else:
        assert aside > 28.2 and moved.holes.mean() < 0.001


def test_a_turned_client_sees_the_wide_views_background(renderer) -> None:  # type: ignore[no-untyped-def]
    """Turned 12 degrees from the server's pose (and 8 up), the client draws the wide view's quads where the main
    view ends, sky included: measured holes 0.52 / 0.35 / 0.35 %, 21.84 / 22.88 / 22.16 dB.  Before the mesh was
    drawn with a far plane past the background quads' (98 % of far along the source axis, much further along a
    120-degree view's edge rays), the turned client clipped that sky away: 7.6 / 18.5 / 16.7 % holes, 18.2 / 12.4 /
    13.3 dB (the stress case fast_turn: 34 % of frames under 20 dB, 12 % holes in the worst)."""
    from scipy.spatial.transform import Rotation

    from splitrender.metrics.image import psnr

    srv, upd, spec, cfg, scene, pose = _frame(renderer, {})
    cli = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
    cli.apply(_decoded(upd))
    for yaw, pitch in ((-12, 0), (-12, 8), (12, 8)):
        turned = Pose(pose.position, (Rotation.from_quat(pose.orientation) * Rotation.from_euler("YX", [yaw, pitch], degrees=True)).as_quat())
        got = cli.render(turned, 0.5)
        assert got.holes.mean() < 0.01 and psnr(got.color, renderer.render(scene, 0.5, turned, INTR).color) > 21.3, (yaw, pitch)


def test_residual_frames_are_smaller_and_the_client_cache_follows_the_server(renderer) -> None:  # type: ignore[no-untyped-def]
    """The default walk at 30 Hz, frames 0-5: a reference frame, four residual frames, a reference frame.
    Measured quads payload after zstd (byte planes, wire 2, one hidden layer): 49.1 KB and 50.5 KB for the
    reference frames, 30.5-35.9 KB for the residual frames (1.37-1.61x smaller, 1.49x on average; the paper
    reports 2-3x; with two hidden layers 51.7 / 54.0 KB and 33.4-39.2 KB, 1.46x).  The
    byte planes shrank reference frames 1.78x and residual frames 1.6x (interleaved: 92 KB against 53-63 KB,
    1.5-1.7x): a dense reference layer's neighbouring quads share more high bytes than a residual frame's
    scattered ones.  The client's cached set equals the server's mirror."""
    import zstandard

    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    tr = get_trace("walk", scene=get_scene("default+nogi"))
    srv = cli = None
    sizes, kinds = [], []
    for f in range(6):
        t = 0.5 + f / 30
        # residual frames as such: the walk's cached mesh scores under reference_error_db's 30 dB (24-26 dB)
        srv, upd, spec, cfg, scene, pose = _frame(renderer, {"reference_error_db": 0.0}, t=t, frame_id=f, srv=srv,
                                                  pose=tr.pose_at(t))
        if cli is None:
            cli = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
        cli.apply(_decoded(upd))
        sizes.append(len(zstandard.ZstdCompressor(3).compress(upd.data["quads"])))
        kinds.append(upd.meta["frame"])
        assert len(cli.cache) == len(srv.cache) and np.array_equal(cli.cache.index_map, srv.cache.index_map)
    assert kinds == ["reference"] + ["residual"] * 4 + ["reference"]
    ref = min(sizes[0], sizes[5])
    assert max(sizes[1:5]) < ref / 1.3 and np.mean(sizes[1:5]) < ref / 1.45, sizes


@pytest.mark.slow
def test_effective_depth_peeling_against_brute_force(renderer) -> None:  # type: ignore[no-untyped-def]
    """Three peeled layers of the default view, view sphere of 25 cm radius; reference: what 64 eyes spread
    through the sphere see (0.3% depth tolerance).  Measured: layer 1 keeps 6.8k of 12.6k fragments, false
    negatives 9.5% (seen but dropped), false positives 25%; layers 2-3 hold few seen fragments and keep mostly
    false positives (84%, 95%).  The false negatives are seams: half lie within 1.2% of the front surface's depth
    at their pixel (where a wall meets another, a post meets the floor), a duplicate of a visible surface; among
    fragments more than 2% behind their front surface the pooled rate is 3.6%."""
    from splitrender.methods.quads.edp import brute_force_seen, edp_keep, unproject

    scene, pose, g0 = _gbuffer(renderer)
    prev = g0.depth
    layers = []
    for k in range(3):
        g = renderer.render(scene, 0.5, pose, INTR, ("depth",), peel=prev).depth
        assert (g[np.isfinite(g)] > prev[np.isfinite(g)]).all(), "a peeled layer lies behind the one before"
        layers.append(g)
        prev = g
    # the reference for the three layers at once: a point's verdict depends on that point alone, so the 64 eyes
    # are rendered once for all the layers' fragments rather than once a layer
    valid = [np.isfinite(g) for g in layers]
    world = np.concatenate([unproject(g, pose, INTR, v) for g, v in zip(layers, valid)])
    seen_all = brute_force_seen(renderer, scene, 0.5, pose, INTR, world, 0.25, eyes=64, tolerance=0.003)
    seen_by_layer = np.split(seen_all, np.cumsum([int(v.sum()) for v in valid])[:-1])
    seen_n = fn_n = deep_seen = deep_fn = 0
    kept_seen = []
    for g, v, seen in zip(layers, valid, seen_by_layer):
        keep = edp_keep(g0.depth, g, INTR, 0.25)[v]
        deep = (g > g0.depth * 1.02)[v]
        seen_n += int(seen.sum())
        fn_n += int((seen & ~keep).sum())
        deep_seen += int((seen & deep).sum())
        deep_fn += int((seen & deep & ~keep).sum())
        kept_seen.append((int(keep.sum()), int((keep & seen).sum())))
    assert seen_n > 3000 and fn_n / seen_n < 0.11, (fn_n, seen_n)
    assert deep_seen > 3000 and deep_fn / deep_seen < 0.045, (deep_fn, deep_seen)
    kept, hit = kept_seen[0]
    assert hit / kept > 0.7, "most of what layer 1 keeps is seen from somewhere in the sphere"


def _cloud_walk(method: str, params: dict) -> RunConfig:
    """0.3 s of the default walk (no GI) under ``cloud`` at 320x180, the client at 30 Hz."""
    return RunConfig(method=method, scene="default+nogi", trace="walk", network="cloud", duration_s=0.3, width=320,
                     height=180, client_fps=30, flip_every=0, seed=0, method_params=params)


CLOUD_RUNS = {"quasar": ("quads", {}), "quadstream": ("quads", {"variant": "quadstream"}), "warp": ("warp", {})}


@pytest.mark.slow
@pytest.mark.shared_runs(*(_cloud_walk(m, p) for m, p in CLOUD_RUNS.values()))
def test_quasar_beats_warp_under_cloud_and_quadstream_sends_more(shared_run) -> None:  # type: ignore[no-untyped-def]
    """``cloud`` (50 +- 20 ms each way), 0.3 s of the default walk at 320x180.  Measured: QUASAR 17.25 dB at
    10.8 Mbit/s, QuadStream 17.18 dB at 34.8 Mbit/s (3.24x QUASAR; the paper reports up to 15x at larger view
    cells), warp 16.61 dB (0.64 dB behind QUASAR).  Over 0.4 s: QUASAR 18.48 dB at 11.3 Mbit/s, QuadStream 18.38 dB
    at 35.6 Mbit/s (3.14x), warp 17.81 dB (0.67 behind).  Over 1 s: 20.95 dB at 12.9 Mbit/s against 20.70 at 38.4 (2.97x).  With a second
    hidden layer (the default until it was measured to carry 84 % false positives) QUASAR sent 12.6 Mbit/s for
    18.49 dB (2.82x), over 1 s 14.4 Mbit/s for 20.98 dB (2.67x).  QuadStream's own atlas and wide view (the packed atlas with
    24-bit positions, the wide view at 2/3 resolution) took it from 33.3 Mbit/s (2.64x) with the slot atlas.  Over 0.6 s: 19.83 dB at 13.2 Mbit/s, 19.71 dB at 34.7, warp
    19.13.  Wire 1 (interleaved arrays) sent 18.9 and 49.8 Mbit/s over 0.6 s: the byte planes took 1.43x off
    both, so the ratio stayed.  Since QUASAR sends a reference frame where a residual frame would score under 30 dB
    (``reference_error_db``, issue 50; the walk's residual frames score 24-26 dB, so most frames are reference
    frames) QuadStream sends 2.91x QUASAR's bits over 0.3 s (40.4 against 13.9 Mbit/s), 3.24x before."""
    # one ground truth for the three runs (the session's truth cache)
    quasar, qs, warp = (shared_run(_cloud_walk(*CLOUD_RUNS[k])).summary for k in ("quasar", "quadstream", "warp"))
    assert quasar["mean_psnr_db"] >= warp["mean_psnr_db"] + 0.5, (quasar["mean_psnr_db"], warp["mean_psnr_db"])
    assert qs["mean_kbps"] >= 2.6 * quasar["mean_kbps"], (qs["mean_kbps"], quasar["mean_kbps"])


def test_malformed_quad_data_gives_named_errors_and_keeps_the_last_state(renderer) -> None:  # type: ignore[no-untyped-def]
    srv, upd, spec, cfg, scene, pose = _frame(renderer, {"layers": 2})
    cli = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
    cli.apply(_decoded(upd))
    before = cli.render(pose, 0.5).color
    q, o = upd.data["quads"], upd.data["offsets"]
    n_sets = q[3]
    arrays = 4 + 12 * n_sets
    total = (len(q) - arrays) // 10
    depth_at, packed_at = arrays + 6 * total, arrays + 2 * total
    depth = from_byte_planes(q, "<f4", total, depth_at).copy()
    depth[0] = np.nan
    nan_depth = q[:depth_at] + byte_planes(depth, "<f4")
    packed = from_byte_planes(q, "<u4", total, packed_at).copy()
    packed[0] = (5 << 26) | (4000 << 14)
    big = q[:packed_at] + byte_planes(packed, "<u4") + q[depth_at:]
    cases = [
        ({"quads": q[:3]}, "shorter than"),
        ({"quads": b"XX" + q[2:]}, "bad magic"),
        ({"quads": q[:2] + bytes([9]) + q[3:]}, "unsupported version 9"),
        ({"quads": q[:-3]}, "bytes of quad arrays"),
        ({"offsets": o[:-2]}, "offsets stream"),
        ({"quads": nan_depth}, "plane depths"),
        ({"quads": bytes(big)}, "beyond its 320x180 atlas slot|non-flat"),
        ({"quads": q[:4] + bytes([7]) + q[5:]}, "unknown kind 7"),
    ]
    from splitrender.methods import DecodedUpdate

    for patch, msg in cases:
        bad = DecodedUpdate(upd.frame_id + 1, upd.t_s, upd.pose, upd.planes, upd.meta, {**upd.data, **patch})
        with pytest.raises(QuadsWireError, match=msg):
            cli.apply(bad)
        assert np.array_equal(cli.render(pose, 0.5).color, before), msg
    for meta, msg in (({**upd.meta, "v": 7}, r"^quads metadata frame 1: v: version 7, this client speaks 1$"),
                      ({**upd.meta, "frame": "x"}, r"^quads metadata frame 1: frame: 'x' is not one of"),
                      ({**upd.meta, "cameras": [[0] * 7 + [320, 180, 60.0]]},
                       r"^quads metadata frame 1: cameras\[0\]: pose orientation is not a unit quaternion$"),
                      ({**upd.meta, "cameras": [[0] * 10]}, r"^quads metadata frame 1: cameras\[0\]\[7\]: expected an integer in 1\.\.320"),
                      ({**upd.meta, "cameras": "x"}, r"^quads metadata frame 1: cameras: expected a list of 1 to 16, got 'x'$")):
        with pytest.raises(QuadsWireError, match=msg):
            cli.apply(DecodedUpdate(upd.frame_id + 1, upd.t_s, upd.pose, upd.planes, meta, dict(upd.data)))
        assert np.array_equal(cli.render(pose, 0.5).color, before), msg
    from splitrender.methods.quads.wire import KIND_UPDATE

    stacked = QuadSet(np.full(100, 5, np.uint8), np.zeros(100, np.uint16), np.zeros(100, np.uint16), np.zeros(100, np.uint8),
                      np.zeros(100, np.uint8), np.ones(100, np.float32), np.ones(100, bool), np.zeros((0, 16), np.float16))
    for sets, msg in (([WireSet(KIND_HIDDEN, 1, 0, stacked)], "cover 102400 pixels"),
                      ([WireSet(KIND_UPDATE, 0, 1, _random_set(np.random.default_rng(1), 3))],
                       "updates a reference set the client does not hold")):
        q2, o2 = encode_sets(sets)
        bad = DecodedUpdate(upd.frame_id + 1, upd.t_s, upd.pose, upd.planes, upd.meta, {"quads": q2, "offsets": o2})
        with pytest.raises(QuadsWireError, match=msg):
            spec.client_class(cfg, INTR, renderer.ctx, srv.session_data()).apply(bad)
    for sd, msg in (({**srv.session_data(), "wire": 9}, r"^quads session data: wire: version 9, this client speaks 3$"),
                    ({**srv.session_data(), "slots": 99}, r"^quads session data: slots: expected an integer in 1\.\.64, got 99$"),
                    ({**srv.session_data(), "slots": 7, "cols": 2, "rows": 2}, r"^quads session data: slots: 7 slots in a 2x2 grid"),
                    ({**srv.session_data(), "packed_atlas": [8192, 16]},
                     r"^quads session data: packed_atlas\[0\]: expected an integer in 1\.\.4096, got 8192$")):
        with pytest.raises(QuadsWireError, match=msg):
            spec.client_class(cfg, INTR, renderer.ctx, sd)
    # QuadStream's packed atlas: positions beyond it, positions a session without one did not ask for, unknown flags
    qsrv, qupd, _, qcfg, _, _ = _frame(renderer, {"variant": "quadstream"})
    qcli = spec.client_class(qcfg, INTR, renderer.ctx, qsrv.session_data())
    qcli.apply(_decoded(qupd))
    shown = qcli.render(pose, 0.5).color
    far = [WireSet(s.kind, s.slot, s.camera, s.quads, s.tex + np.array([1536, 0]) * (k == 0)) for k, s in enumerate(qsrv.last_sets)]
    q3, o3 = encode_sets(far)
    flagged = bytearray(qupd.data["quads"])
    flagged[4 + 3] = 3
    for data, client, msg in (({"quads": q3, "offsets": o3}, qcli, "beyond the 1536x384 packed atlas"),
                              ({"quads": bytes(flagged)}, qcli, "unknown flags 0x03"),
                              ({}, cli, "atlas positions sent, but the session's atlas is slots")):
        meta = qupd.meta if client is qcli else upd.meta
        planes = qupd.planes if client is qcli else upd.planes
        with pytest.raises(QuadsWireError, match=msg):
            client.apply(DecodedUpdate(qupd.frame_id + 1, qupd.t_s, qupd.pose, planes, meta, {**qupd.data, **data}))
    assert np.array_equal(qcli.render(pose, 0.5).color, shown) and np.array_equal(cli.render(pose, 0.5).color, before)


def test_packed_squares_never_overlap_and_fill_their_tiles() -> None:
    """QuadStream's packed atlas: power-of-two squares, largest first along a Z-order curve, cover each texel
    at most once and stay inside the atlas; squares whose area is exactly the atlas's tile it with no gap;
    one texel more is refused."""
    from splitrender.methods.quads.packing import pack_squares

    rng = np.random.default_rng(3)
    for trial in range(20):
        tile, tx, ty = 1 << int(rng.integers(2, 7)), int(rng.integers(1, 5)), int(rng.integers(1, 4))
        w, h = tile * tx, tile * ty
        sizes = 1 << rng.integers(0, int(np.log2(tile)) + 1, 400)
        sizes = sizes[np.cumsum(sizes ** 2) <= w * h]
        if trial % 2:   # top up with single texels to exactly the atlas's area
            sizes = np.concatenate([sizes, np.ones(w * h - int((sizes ** 2).sum()), np.int64)])
        x, y = pack_squares(sizes, tile, w, h)
        cover = np.zeros((h, w), np.int64)
        for a, b, s in zip(x, y, sizes):
            assert a % s == 0 and b % s == 0 and a + s <= w and b + s <= h, (a, b, s)
            cover[b:b + s, a:a + s] += 1
        assert cover.max() <= 1 and cover.sum() == int((sizes ** 2).sum())
        if trial % 2:
            assert (cover == 1).all(), "a full set of squares tiles the atlas"
            with pytest.raises(ValueError, match="do not fit"):
                pack_squares(np.concatenate([sizes, [1]]), tile, w, h)


def test_packing_leaves_the_centre_views_tiles_free_and_keeps_neighbours_together() -> None:
    """The packed atlas's top-left tiles hold QuadStream's centre view whole: squares packed around them never land
    there, and all of the rest fills.  Same-size squares go along the Z-order curve of their place in their view
    (``source_order``), so an aligned 2x2 block of one-pixel quads lands on an aligned 2x2 block of texels."""
    from splitrender.methods.quads.packing import pack_squares, packed_size, source_order, whole_tiles

    assert whole_tiles(320, 180) == (3, 2) and packed_size(320, 180, 9 * 320 * 180 + 212 * 120, 1600) == (1536, 384)
    tile, w, h = 8, 32, 16                             # 4x2 tiles, the top-left 2x1 reserved
    sizes = np.ones(w * h - 2 * tile * tile, np.int64)
    x, y = pack_squares(sizes, tile, w, h, reserved=(2, 1))
    cover = np.zeros((h, w), np.int64)
    np.add.at(cover, (y, x), 1)
    assert (cover[:tile, :2 * tile] == 0).all() and (cover[tile:] == 1).all() and (cover[:tile, 2 * tile:] == 1).all()
    with pytest.raises(ValueError, match="do not fit"):
        pack_squares(np.ones(sizes.size + 1, np.int64), tile, w, h, reserved=(2, 1))
    qx, qy = np.array([7, 6, 6, 7, 30]), np.array([5, 4, 5, 4, 0])     # a 2x2 block (shuffled) and a stray quad
    key = source_order(np.zeros(5), np.zeros(5), qx, qy)
    ax, ay = pack_squares(np.ones(5, np.int64), tile, w, h, key=key)
    assert {(a - 0, b - 0) for a, b in zip(ax[:4], ay[:4])} == {(0, 0), (1, 0), (0, 1), (1, 1)}
    assert all(ax[k] - qx[k] == ax[1] - 6 and ay[k] - qy[k] == ay[1] - 4 for k in range(4))


def test_quads_past_the_packed_atlas_are_left_out_and_the_rest_still_draws(renderer) -> None:  # type: ignore[no-untyped-def]
    """From about 1280x720 up a QuadStream frame's quads could cover more than a 4096x4096 atlas; what does not fit
    (the last views' quads) is left out and counted, and the client draws the rest.  Here a 512x128 atlas (65.5k
    texels) takes the centre view (57.6k) and part of the first corner view: measured 11529 of 12733 quads left
    out, 65521 texels kept, no hole at the centre pose."""
    from splitrender.methods.quads.packing import fitting
    from splitrender.pipeline.direct import server_context

    assert fitting(np.array([4, 4, 2, 1]), 36) == 3 and fitting(np.array([4, 4, 2, 1]), 32) == 2
    assert fitting(np.array([4]), 15) == 0
    srv, _, spec, cfg, scene, pose = _frame(renderer, {"variant": "quadstream"})
    srv.packed = srv.atlas_wh = (512, 128)
    ctx = server_context(scene, renderer, INTR, pose, t_s=0.5, frame_id=1)
    upd = srv.produce(ctx)
    st = srv.stats()
    assert st["atlas_dropped"] > 11000 and 65000 < sum(s.quads.pixels() for s in srv.last_sets) <= 512 * 128
    assert srv.last_sets[0].quads.pixels() == INTR.width * INTR.height, "the centre view is whole"
    cli = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
    cli.apply(_decoded(upd))
    assert cli.render(pose, 0.5).holes.mean() < 0.001


def test_quadstreams_packed_atlas_shows_what_the_slot_atlas_shows(renderer) -> None:  # type: ignore[no-untyped-def]
    """With a lossless atlas, QuadStream's packed atlas (each quad's texels at a position of its own, sent in 24
    bits: 104 bits a quad on the wire against 80) draws the same image as the slot layout, at the centre pose and
    20 cm to the side: every quad reads only its own texels, wherever they lie (measured: every pixel equal at the
    centre, 99.976 % 20 cm aside)."""
    from splitrender.methods.quads.wire import SET_HEADER

    srv_p, upd_p, spec, cfg_p, scene, pose = _frame(renderer, {"variant": "quadstream"})
    srv_s, upd_s, _, cfg_s, _, _ = _frame(renderer, {"variant": "quadstream", "atlas": "slots"})
    assert srv_p.session_data()["packed_atlas"] == [1536, 384] and "packed_atlas" not in srv_s.session_data()
    n = int(srv_p.stats()["quads"])
    head = 4 + SET_HEADER.size * len(srv_p.last_sets)
    assert len(upd_p.data["quads"]) - head == 13 * n and len(upd_s.data["quads"]) - head == 10 * n
    side = Pose(pose.position + pose.matrix()[:3, :3] @ np.array([0.2, 0.0, 0.0]), pose.orientation)
    shown = []
    for srv, upd, cfg in ((srv_p, upd_p, cfg_p), (srv_s, upd_s, cfg_s)):
        cli = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
        cli.apply(_decoded(upd))
        shown.append([cli.render(p, 0.5).color for p in (pose, side)])
    for a, b in zip(*shown):
        assert (a == b).all(-1).mean() > 0.999


@pytest.mark.parametrize("params,msg", [({"variant": "seurat"}, "variant"), ({"layers": 5}, "layers"),
                                        ({"wide_fov_deg": 30.0}, "wide_fov_deg"), ({"delta_sim": -1.0}, "delta_sim"),
                                        ({"atlas": "packed"}, "QuadStream's atlas"), ({"atlas": "bins"}, "atlas"),
                                        ({"wide_scale": 2.0}, "wide_scale"),
                                        ({"reference_distance_m": -0.1}, r"reference_distance_m: must be in \[0, 100\]"),
                                        ({"reference_angle_deg": 200.0}, r"reference_angle_deg: must be in \[0, 180\]"),
                                        ({"view_cell": 1.0}, "unknown parameter 'view_cell'")])
def test_nonsense_config_is_named(params: dict, msg: str) -> None:
    from splitrender.errors import ConfigError
    from splitrender.methods import get_method, make_config

    with pytest.raises(ConfigError, match=msg):
        make_config(get_method("quads").config, params)


def test_reference_frames_follow_the_distance_and_angle_thresholds(renderer) -> None:  # type: ignore[no-untyped-def]
    """QUASAR section 3.5.1: a reference frame "every 5 frames or based on distance and angle thresholds".  At a
    still pose neither threshold fires, so the residual frames run to ``reference_every``; 6 cm aside (past a 5 cm
    threshold) or 3 degrees turned (past 2) the next frame is a reference frame, and the one after it, back at that
    pose, is residual again.  Unset (0), the same moves give residual frames (``reference_error_db`` off: the 3 degree
    turn alone scores under its 30 dB)."""
    from splitrender.scene.pose import quat_from_euler_deg, quat_mul

    base = {"layers": 1, "wide_fov_deg": 0.0, "reference_error_db": 0.0}
    for params, moved, want in (
            ({"reference_distance_m": 0.05}, "aside", ["reference", "residual", "residual", "reference", "residual"]),
            ({"reference_angle_deg": 2.0}, "turned", ["reference", "residual", "residual", "reference", "residual"]),
            ({}, "aside", ["reference", "residual", "residual", "residual", "residual"]),
            ({}, "turned", ["reference", "residual", "residual", "residual", "residual"])):
        srv = pose0 = None
        kinds = []
        for f in range(5):
            if pose0 is not None and f >= 3:
                pose = (Pose(pose0.position + np.array([0.06, 0.0, 0.0]), pose0.orientation) if moved == "aside" else
                        Pose(pose0.position, quat_mul(pose0.orientation, quat_from_euler_deg(0.0, 3.0, 0.0))))
                assert (5.9 < 100 * pose.distance_m(pose0) < 6.1) if moved == "aside" else (2.5 < pose.angle_deg(pose0) < 3.5)
            else:
                pose = pose0
            srv, upd, *_, p = _frame(renderer, {**base, **params}, frame_id=f, srv=srv, pose=pose)
            pose0 = pose0 or p
            kinds.append(upd.meta["frame"])
        assert kinds == want, (params, moved, kinds)


def test_residual_frame_at_the_reference_pose_resends_nothing_under_quasars_mask(renderer) -> None:
    """QUASAR's residual mask (``coverage``: scene pixels the cached mesh does not cover) resends nothing when the
    camera has not moved; the old mask (``depth``: also pixels more than 2 % in front of the mesh) resent the
    pixels under flat merged quads, which may sit up to ``delta_flatten`` off the surface (issue 38: 4x
    QUASAR's residual quads on 2CylinderEngine).  Measured on the default walk at t = 0.5 s, 320x180: 0 against
    40 pixels (before the one-pixel growth)."""
    out = {}
    for mask in ("coverage", "depth"):
        params = {"residual_mask": mask, "layers": 1, "wide_fov_deg": 0.0}
        srv, _ref, *_, pose = _frame(renderer, params)
        assert srv.stats()["reference"] == 1.0
        _frame(renderer, params, frame_id=1, srv=srv, pose=pose)
        st = srv.stats()
        assert st["reference"] == 0.0
        out[mask] = st["revealed_px"]
    assert out["coverage"] == 0, out
    assert out["depth"] >= 20, out
