"""``tss``'s colour order (``colour_order``; issue 50 part 1, the lossy target): a repack places each L-packing class's
cells in the order of their samples' mean luma, in bins, then by id.

The duck's first atlas at the claims ledger's ``TSS_MATCHED`` + ``codec_block`` 4, coded as one I-frame: with every
tip block at its own mean, the mosaic of means alone was 65 % of the bytes at crf 31 (19.3k of 29.6k), and the id
order put a mesh's lit and shadowed triangles side by side in each shelf.  Moving whole triangles into the order of
their mean luma (bins of 4 levels) took the same samples to 22.2k (0.75x) on the duck, 0.91x on TextureTransformTest,
0.85x on 2CylinderEngine and 0.89x on the default scene (``/tmp`` probes at fffb3a4, 2026-12-07).  Over 1 s at
``sas``'s bits, bins of 16: ``benchmarks/bench_tss_rd.py``, labels ``colour_still`` and ``colour_orbit``."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from splitrender.methods.tss.layout import KIND_LP, StableAtlas, lp_cell_level, lp_luma, plan_atlas, tip_dim

DUCK = "/usr/share/assimp/models/Collada/duck.dae"


def test_a_repack_orders_l_packing_cells_by_rank_then_id_and_lp_luma_reads_their_samples() -> None:
    """Six L-packed triangles of level 7: without ranks the repack hands out slots in id order, with ranks in rank
    order (ties by id); :func:`lp_luma` is the mean luma of the texels a triangle's three tip blocks hold."""
    n = 6
    ids = np.arange(n)
    kind = np.full(n, KIND_LP)
    level = np.full(n, 7)                     # D = 5 texels in a pitch of 8
    z, one = np.zeros(n, np.int64), np.ones(n, np.int64)
    atlas = StableAtlas(n, 512, 256, block=4)
    plan = plan_atlas(atlas, ids, kind, level, z, z, one, np.zeros(n), reset=True)
    assert np.array_equal(plan.slot, np.arange(n))
    atlas.rank = np.array([5, 1, 1, 0, 9, 2])
    plan = plan_atlas(atlas, ids, kind, level, z, z, one, np.zeros(n), reset=True)
    assert np.array_equal(np.argsort(plan.slot), [3, 1, 2, 5, 0, 4]), plan.slot
    # a grey level per triangle in its three D x D tip blocks; texels beside them (padding) are not read
    rgba = np.zeros((256, 512, 4), np.uint8)
    D = int(tip_dim(7))
    grey = np.array([10, 60, 61, 200, 255, 90])
    for i in range(n):
        for t in range(3):
            x, y = plan.origin[i, t]
            rgba[y:y + D, x:x + D] = (grey[i], grey[i], grey[i], 255)
            rgba[y + D, x:x + D] = (0, 0, 0, 255)          # the padding's first row: not the triangle's
    rows, luma = lp_luma(rgba, plan)
    assert np.array_equal(rows, ids)
    np.testing.assert_allclose(luma, grey, atol=0.01)


@pytest.mark.skipif(not os.path.exists(DUCK), reason=f"{DUCK} absent (Debian's assimp-testmodels)")
def test_colour_order_on_the_duck_codes_the_same_samples_in_fewer_bytes_and_keeps_a_still_views_cells(renderer) -> None:  # type: ignore[no-untyped-def]
    """The duck, still, 320x180, ``TSS_MATCHED`` + ``codec_block`` 4 at crf 31, ``colour_order`` 16: frame 0 shades
    twice (no colours known), its L-packing cells follow their luma bins; the periodic I-frame (gop 2) repacks to the
    same cells (no table sent); the client's table is the server's plan; the first atlas codes in 0.77x the bytes of
    the id order (measured 23.6k against 30.5k; in bins of 4 levels 22.8k, 0.75x), the same samples shaded.
    Lossless, the client's picture is the same to the bit."""
    from splitrender.codecs.video import VideoEncoder
    from splitrender.experiments.studies.claims import TSS_MATCHED
    from splitrender.methods import DecodedUpdate
    from test_tss import _client, _server_frame

    base = {**TSS_MATCHED, "codec_block": 4, "crf": 31.0, "gop": 2}

    def first(colour: float) -> tuple[int, int]:
        srv, ctx, *_ = _server_frame(renderer, DUCK, {**base, "colour_order": colour}, trace="static")
        u = srv.produce(ctx)
        v = srv.streams()[0]
        W, H = srv.atlas
        nb = VideoEncoder(v.codec, W, H).encode(np.ascontiguousarray(u.planes["atlas"]), force_idr=True).nbytes
        return nb, int(srv.stats()["samples"])

    (b0, s0), (b4, s4) = first(0.0), first(16.0)
    assert s0 == s4 > 100_000
    assert b4 <= 0.82 * b0, (b0, b4)

    srv, ctx, spec, cfg, scene, pose = _server_frame(renderer, DUCK, {**base, "colour_order": 16.0}, trace="static")
    cli = _client(renderer, srv, spec, cfg)
    for k in range(4):
        u = srv.produce(dataclasses.replace(ctx, frame_id=k))
        st = srv.stats()
        assert st["iframe"] == float(k in (0, 2))
        assert ("tris" in u.data) == (k == 0), (k, st["table_rows"])
        plan, ids = srv.last_plan, srv.last_ids
        lp = np.flatnonzero(plan.kind == KIND_LP)
        rank = np.floor(srv._luma[ids[lp]] / 16.0)
        assert not np.isnan(rank).any()
        cl = lp_cell_level(plan.level[lp], plan.block)
        for L in np.unique(cl):
            sel = lp[cl == L]
            r = np.floor(srv._luma[ids[sel]] / 16.0)[np.argsort(plan.slot[sel])]
            assert (np.diff(r) >= 0).all(), f"level {L}: cells out of colour order"
        cli.apply(DecodedUpdate(u.frame_id, u.t_s, u.pose, u.planes, u.meta, u.data))
        order = np.argsort(ids)
        assert np.array_equal(cli.table.ids, ids[order])
        assert np.array_equal(cli.table.origin, plan.origin[order])

    def shown(colour: float) -> np.ndarray:
        srv, ctx, spec, cfg, scene, pose = _server_frame(renderer, DUCK, {**TSS_MATCHED, "lossless": True,
                                                                         "colour_order": colour}, trace="static")
        cli = _client(renderer, srv, spec, cfg)
        u = srv.produce(ctx)
        cli.apply(DecodedUpdate(u.frame_id, u.t_s, u.pose, u.planes, u.meta, u.data))
        return np.asarray(cli.render(pose, ctx.t_s).color).copy()

    a, b = shown(0.0), shown(16.0)
    assert np.array_equal(a, b)
