"""``tss``'s atlas aligned to the video codec's blocks (``codec_block``; issue 50 part 1, the lossy half of T-T4-1).

``benchmarks/bench_tss_codec.py`` coded ``tss``'s first still atlas (the claims ledger's ``TSS_MATCHED``, the duck)
once as an I-frame: L-packing tip blocks of 3-8 texels, packed edge to edge, put two to four triangles into most of
H.264's 4 x 4 transform blocks, and the texels on a tip block's border took 59 % of the error (MSE 8.5 against 5.9
inside).  With every tip block starting on a multiple of 4 texels and padded to one (filled from its own texels), the
same samples code in 25 % fewer bytes at 3.2 dB less error."""

from __future__ import annotations

import os

import numpy as np
import pytest

from splitrender.methods.tss.layout import (KIND_LP, KIND_OS, KIND_SINGLE, StableAtlas, fill_gutters, pitch_level, plan_atlas,
                                            tip_dim, tip_pitch)

DUCK = "/usr/share/assimp/models/Collada/duck.dae"


def test_tip_pitch_rounds_the_tip_block_up_to_the_codec_block_and_pitch_level_fills_it() -> None:
    lv = np.arange(1, 65)
    assert (tip_pitch(lv, 1) == tip_dim(lv)).all()
    for b in (2, 4, 8):
        p = tip_pitch(lv, b)
        assert (p % np.minimum(p, b) == 0).all() and (p >= tip_dim(lv)).all() and (p - tip_dim(lv) < b).all()
        assert (p[tip_dim(lv) >= b] % b == 0).all() and (p[tip_dim(lv) < b] < 2 * tip_dim(lv)[tip_dim(lv) < b]).all()
        top = pitch_level(lv, b)
        assert (top >= lv).all() and (tip_pitch(top, b) == p).all()
        assert ((top == 64) | (tip_pitch(np.minimum(top + 1, 64), b) > p)).all()    # the highest of its pitch
    assert pitch_level(7, 4) == 14 and pitch_level(3, 4) == 6     # D 5 -> 8 texels: level 14 fills them


@pytest.mark.parametrize("block", [4, 8])
def test_aligned_layout_puts_every_tip_block_and_rectangle_on_the_codec_grid_and_the_wire_agrees(block: int) -> None:
    from splitrender.methods.tss.wire import decode_table, descriptors, encode_table

    rng = np.random.default_rng(3)
    n = 90
    ids = np.sort(rng.choice(400, n, replace=False))
    kind = np.array([KIND_SINGLE, KIND_LP, KIND_LP, KIND_OS, KIND_LP, KIND_LP] * (n // 6))
    level = rng.integers(1, 30, n)
    w1, w2, h = rng.integers(1, 9, n), rng.integers(1, 9, n), rng.integers(1, 7, n)
    store = StableAtlas(400, 1152, 576, single_px=2, block=block)
    plan = plan_atlas(store, ids, kind, level, w1, w2, h, rng.uniform(0, 1, n))
    assert not plan.overflow
    lp, os_ = kind == KIND_LP, kind == KIND_OS
    pitch = tip_pitch(plan.level, block)
    assert (plan.origin[lp] % np.minimum(pitch[lp], block)[:, None, None] == 0).all()
    assert (plan.origin[lp & (pitch >= block)] % block == 0).all()
    assert (plan.origin[os_, 0, 1] % block == 0).all() and (plan.origin[os_, 0, 0] % block == 0).all()
    # no two triangles' tip blocks (padded) overlap
    own = np.full((576, 1152), -1)
    for i in np.flatnonzero(lp):
        P = int(tip_pitch(int(plan.level[i]), block))
        for t in range(3):
            x, y = plan.origin[i, t]
            assert (own[y:y + P, x:x + P] == -1).all()
            own[y:y + P, x:x + P] = i
    tris = encode_table(ids, plan, descriptors(plan, np.ones(n, bool), np.zeros(n, np.int64)))
    table, _ = decode_table(tris, 400, (1152, 576), store.strip, "paper", block)
    order = np.argsort(table.ids)
    assert (table.ids[order] == ids).all()
    assert (table.origin[order][lp] == plan.origin[lp]).all()


def test_block_fill_extends_each_block_from_its_own_texels_only() -> None:
    a = np.zeros((8, 8, 4), np.uint8)
    a[0:3, 0:3] = (200, 100, 50, 255)          # a 3 x 3 tip block padded to 4
    a[0:4, 4:8] = (10, 20, 30, 255)            # its neighbour, full
    out = fill_gutters(a, 8, block=4)
    assert (out[0:4, 0:4] == (200, 100, 50)).all()            # the padding takes the block's colour, not the neighbour's
    assert (out[0:4, 4:8] == (10, 20, 30)).all()
    assert (out[4:8] > 0).all()                               # empty blocks: the push-pull fill
    b = a.copy()
    b[0:3, 0:3, :3] = np.arange(9, dtype=np.uint8).reshape(3, 3, 1) * 20     # a ramp: the padding continues its edge
    out = fill_gutters(b, 8, block=4)
    assert (out[0:3, 3] == out[0:3, 2]).all() and (out[3, 0:3] == out[2, 0:3]).all()


@pytest.mark.slow
def test_codec_block_cuts_the_codecs_error_and_bits_on_the_duck(shared_run) -> None:  # type: ignore[no-untyped-def]
    """Still camera, zero latency, 320x180, 0.3 s, the claims ledger's ``TSS_MATCHED`` (crf 23, 4:4:4) on the duck,
    model region over the frames that show an update, against the ground truth.  Measured: ``codec_block`` 1 -> 4
    DSSIM 0.00312 -> 0.00231 (0.74x), PSNR 41.44 -> 42.91 dB, the atlas's bytes 120.7k -> 86.3k (0.72x); over 1 s
    ``bench_tss_matched.py`` has every model.  Lossless runs
    keep block 1 (no padding to pay for)."""
    from splitrender.experiments.studies.claims import TSS_MATCHED
    from splitrender.sim.runner import RunConfig

    if not os.path.exists(DUCK):
        pytest.skip(f"{DUCK} absent (Debian's assimp-testmodels)")

    def still(block: int) -> tuple[float, float, float]:
        res = shared_run(RunConfig(method="tss", scene=DUCK, trace="static", network="ideal", duration_s=0.3, width=320,
                                   height=180, client_fps=30, flip_every=0, seed=0,
                                   method_params={**TSS_MATCHED, "codec_block": block}))
        shown = [f for f in res.frames if f["update_frame_id"] >= 0]
        return (float(np.mean([f["model_dssim"] for f in shown])), float(np.mean([f["model_psnr_db"] for f in shown])),
                float(sum(u["bytes_atlas"] for u in res.updates)))

    d1, p1, b1 = still(1)
    d4, p4, b4 = still(4)
    assert d4 <= 0.8 * d1 and p4 >= p1 + 1.2 and b4 <= 0.76 * b1, (d1, p1, b1, d4, p4, b4)


def test_a_still_views_periodic_iframes_send_no_table_rows(renderer) -> None:  # type: ignore[no-untyped-def]
    """The tris stream is reliable, so an I-frame whose repack keeps every cell (a still view: an empty atlas is
    packed in the repack's (class, id) order) sends no table (a delta with no rows is not sent); the first frame
    and a keyframe request send the full table.  The client's table is the server's plan every frame.  Measured
    (the duck still at ``TSS_MATCHED`` + ``codec_block`` 4, 320x180, 1 s): frame 30's table 4995 -> 113 bytes,
    1772 -> 1730 kbit/s; then no message for the empty deltas (113 bytes a frame each), 1185 -> 1158 kbit/s at crf 31."""
    import dataclasses

    from splitrender.methods import DecodedUpdate
    from splitrender.methods.tss.wire import decode_table
    from test_tss import _client, _server_frame

    srv, ctx, spec, cfg, scene, pose = _server_frame(renderer, params={"gop": 2, "codec_block": 4})
    cli = _client(renderer, srv, spec, cfg)
    s = srv.session_data()
    for k in range(5):
        c = dataclasses.replace(ctx, frame_id=k, keyframe_requested=(k == 4))
        u = srv.produce(c)
        st = srv.stats()
        assert st["iframe"] == float(k in (0, 2, 4)), (k, st["iframe"])
        if k in (0, 4):
            rows, gone = decode_table(u.data["tris"], s["n_triangles"], tuple(s["atlas"]), s["strip"], s["os_grid"],
                                      s["block"])
            assert gone is None and rows.ids.size == st["pvs_triangles"] > 1000, "a full table"
        else:
            assert "tris" not in u.data and st["table_rows"] == 0, (k, st["table_rows"])
        cli.apply(DecodedUpdate(u.frame_id, u.t_s, u.pose, u.planes, u.meta, u.data))
        order = np.argsort(srv.last_ids)
        assert np.array_equal(cli.table.ids, srv.last_ids[order])
        assert np.array_equal(cli.table.origin, srv.last_plan.origin[order])
