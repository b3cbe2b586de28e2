"""``quads``: the work saved on its server and client (issue 49, item 3) changes no byte.

- a set that emits quads from few pixels builds its planes only around them, and gets the planes, corners,
  offsets and flatness the whole image's planes give;
- a residual frame at the reference pose takes the reference view's G-buffer from the frame's own (one render
  fewer), and sends the same update;
- the client keeps the reference set's mesh (and its sky's) while neither changes, and draws the same.

``benchmarks/bench_quads_server.py`` measures what this saves against the ground truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from splitrender.scene.pose import CameraIntrinsics

INTR = CameraIntrinsics(320, 180)


def _setup(trace: str = "walk"):  # type: ignore[no-untyped-def]
    from splitrender.methods import get_method, make_config
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    scene = get_scene("default+nogi")
    spec = get_method("quads")
    cfg = make_config(spec.config, {"lossless": True, "reference_error_db": 0.0})   # the walk's residual frames as such
    return scene, get_trace(trace, scene=scene), spec, cfg


def _ctx(renderer, scene, tr, f: int):  # type: ignore[no-untyped-def]
    from splitrender.pipeline.direct import server_context

    t = 0.5 + f / 30
    pose = tr.pose_at(t)
    return server_context(scene, renderer, INTR, pose, t_s=t, frame_id=f)


def test_sparse_planes_are_the_whole_images(renderer) -> None:  # type: ignore[no-untyped-def]
    """``initial_quads`` with an ``emit`` mask (planes only at the emitting pixels and their 8 neighbours) against
    the same G-buffer with planes everywhere: at every emitting pixel the same quad, bit for bit (present, normal,
    its 8-bit angles, 16 corner depths, offsets, flatness).  The mask is scattered pixels, a block and the image's
    border, so the neighbours a pixel reads cross every edge."""
    from splitrender.methods.quads.gen import initial_quads

    scene, tr, _, cfg = _setup()
    pose = tr.pose_at(0.5)
    g = renderer.render(scene, 0.5, pose, INTR, ("color", "depth", "normal"))
    valid = np.isfinite(g.depth) & (g.depth > 0)
    nview = g.normal.astype(np.float64) @ pose.view_matrix()[:3, :3].T
    depth = np.where(valid, g.depth.astype(np.float64), 1.0)
    rng = np.random.default_rng(3)
    emit = rng.random(valid.shape) < 0.03
    emit[60:90, 100:160] = True
    emit[0, :] = emit[:, -1] = True
    dense = initial_quads(depth, nview, valid, INTR, cfg.params)
    sparse = initial_quads(depth, nview, valid, INTR, cfg.params, emit)
    at = valid & emit
    assert at.sum() > 3000 and (dense["present"] & at).sum() > 0.9 * at.sum()
    assert np.array_equal(sparse["present"], dense["present"] & at)
    for k in ("n", "theta", "phi", "zc", "corners", "offs", "flat"):
        assert np.array_equal(sparse[k][at], dense[k][at]), k


def test_every_levels_maps_spread_what_gather_sends(renderer, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The maps keep a level's corners and offsets as lattice planes or rows and spread ``corners`` / ``offs``
    ((H, W, 16)) only when read (issue 49, h95): on a whole frame (dense level 0) and on a few pixels (sparse), at
    every level the spread offsets of the quads with offsets are what ``gather`` sends (to float16, in order), and each
    merged quad's corners are its children's outer corners."""
    from splitrender.methods.quads import gen

    scene, tr, _, cfg = _setup()
    pose = tr.pose_at(0.5)
    g = renderer.render(scene, 0.5, pose, INTR, ("color", "depth", "normal"))
    rot = pose.view_matrix()[:3, :3]
    emit = np.zeros(g.depth.shape, bool)
    emit[40:120, 60:260:3] = True
    emit[100:140, 100:180] = True
    seen: list[list[dict[str, np.ndarray]]] = []
    orig = gen.gather
    monkeypatch.setattr(gen, "gather", lambda maps: seen.append(maps) or orig(maps))
    params = dataclasses.replace(cfg.params, delta_flatten=1e-4)    # quads with offsets at every level, level 0 too
    for kw in ({}, {"emit": emit}):
        q = gen.generate(g.depth, g.normal, rot, INTR, params, **kw)
        maps = seen[-1]
        assert len(maps) >= 3 and ((~q.flat) & (q.level == 0)).sum() > 100 and ((~q.flat) & (q.level > 0)).sum() > 10
        sent = []
        for lv, m in enumerate(maps):
            sel = m["present"] & ~m["flat"]
            sent.append(m["offs"][sel])
            if lv:      # a merged quad's sub-quad s takes child s's four outer corners
                yy, xx = np.nonzero(m["present"])
                kids = [maps[lv - 1]["corners"][2 * yy + sy, 2 * xx + sx][:, gen.OUTER] for sy in (0, 1) for sx in (0, 1)]
                assert np.array_equal(m["corners"][yy, xx], np.concatenate(kids, axis=-1))
        assert np.array_equal(np.concatenate(sent).astype(np.float16), q.offsets)


def test_a_still_camera_draws_the_reference_view_once(renderer, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """On the still camera a residual frame is at the reference pose: the G-buffer there at this time is the frame's
    own, so it renders three G-buffers (visible, hidden layer, wide view), not four, and sends the same bytes as
    rendering the reference view again (the scene's objects move, so the update has quads)."""
    import splitrender.methods.quads.server as srv_mod

    scene, tr, spec, cfg = _setup("static")
    sent = {}
    for reuse in (True, False):
        if not reuse:
            monkeypatch.setattr(srv_mod, "same_pose", lambda a, b: False)
        srv = spec.server_class(cfg, INTR, scene, 30, None)
        renders = []
        orig = renderer.render
        monkeypatch.setattr(renderer, "render", lambda *a, **k: renders.append(1) or orig(*a, **k))
        ups = [srv.produce(_ctx(renderer, scene, tr, f)) for f in range(3)]
        monkeypatch.setattr(renderer, "render", orig)
        assert [u.meta["frame"] for u in ups] == ["reference", "residual", "residual"]
        assert srv.stats()["quads_update"] > 0
        sent[reuse] = ([(u.planes["atlas"].tobytes(), u.data["quads"], u.data["offsets"]) for u in ups], len(renders))
    assert sent[True][0] == sent[False][0]
    assert (sent[True][1], sent[False][1]) == (3 + 3 + 3, 3 + 4 + 4)


@pytest.mark.parametrize("trace", ["walk", "static"])
def test_the_client_keeps_the_reference_mesh(renderer, trace: str) -> None:  # type: ignore[no-untyped-def]
    """Two clients take the same updates (a reference frame, then residual frames; one update with its update
    quads removed, so the cached quads stay as they are); one rebuilds every mesh part each time (as before): the
    same vertices and indices, the same frames.  The other kept its reference set's parts through the frame
    without update quads."""
    from splitrender.methods import DecodedUpdate
    from splitrender.methods.quads.wire import KIND_UPDATE, decode_sets, encode_sets

    scene, tr, spec, cfg = _setup(trace)
    srv = spec.server_class(cfg, INTR, scene, 30, None)
    a = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
    b = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
    kept = []
    for f in range(4):
        u = srv.produce(_ctx(renderer, scene, tr, f))
        data = dict(u.data)
        if f == 3:   # the update set emptied: the cache does not change
            sets = decode_sets(data["quads"], data["offsets"], "t", (INTR.width, INTR.height), srv.slots,
                               len(u.meta["cameras"]), INTR.far_m, None)
            upd = next(s for s in sets if s.kind == KIND_UPDATE)
            upd.quads = upd.quads.__class__.empty()
            data["quads"], data["offsets"] = encode_sets(sets)
        parts = a._cached_parts
        d = DecodedUpdate(u.frame_id, u.t_s, u.pose, u.planes, u.meta, data)
        a.apply(d)
        kept.append(parts is not None and a._cached_parts is parts)
        b._cached_parts = None
        b.apply(d)
        assert a._mesh.vbo.read() == b._mesh.vbo.read() and a._mesh.ibo.read() == b._mesh.ibo.read(), f
        p = tr.pose_at(0.52 + f / 30)
        assert np.array_equal(a.render(p, 0.5).color, b.render(p, 0.5).color), f
    assert kept == [False, False, False, True]


def _all_offset(qs):  # type: ignore[no-untyped-def]
    """``qs`` with every quad carrying 16 offsets (0 for a flat one): drawn as eight triangles, as before issue 49."""
    from splitrender.methods.quads.gen import QuadSet

    offs = np.zeros((len(qs), 16), np.float16)
    offs[~qs.flat] = qs.offsets
    return QuadSet(qs.level, qs.x, qs.y, qs.theta, qs.phi, qs.depth, np.zeros(len(qs), bool), offs)


def test_flat_quads_drawn_as_two_triangles_show_the_same(renderer, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A flat quad is drawn as its outer corners' two triangles, not eight: on the default walk (8 updates, two
    display frames each, 0.5 and 1.5 server frames after the update) a client drawing every quad as eight triangles
    (the same corners) and one drawing flat quads as two.  Measured: ~4x fewer indices, 0.10-0.40 % of the pixels
    differ (ties between layers at equal depth, rounding), each frame's PSNR against the ground truth within 0.016 dB
    either way, hole pixels within 7 (default scene without GI, lossless atlas)."""
    import splitrender.methods.quads.client as cli_mod
    from splitrender.methods import DecodedUpdate
    from splitrender.metrics.image import psnr

    scene, tr, spec, cfg = _setup()
    srv = spec.server_class(cfg, INTR, scene, 30, None)
    new = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
    old = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
    build = cli_mod.build_mesh
    differ, dpsnr, dholes = [], [], []
    for f in range(8):
        u = srv.produce(_ctx(renderer, scene, tr, f))
        d = DecodedUpdate(u.frame_id, u.t_s, u.pose, u.planes, u.meta, dict(u.data))
        new.apply(d)
        monkeypatch.setattr(cli_mod, "build_mesh", lambda qs, *a, **k: build(_all_offset(qs), *a, **k))
        old.apply(d)
        monkeypatch.setattr(cli_mod, "build_mesh", build)
        assert old._mesh.quads == new._mesh.quads and new._mesh.count * 3.5 < old._mesh.count
        for dt in (0.5 / 30, 1.5 / 30):
            t = 0.5 + f / 30 + dt
            p = tr.pose_at(t)
            a, b = new.render(p, t), old.render(p, t)
            truth = renderer.render(scene, t, p, INTR).color
            differ.append(float((a.color != b.color).any(-1).mean()))
            dpsnr.append(psnr(a.color, truth) - psnr(b.color, truth))
            dholes.append(int(a.holes.sum()) - int(b.holes.sum()))
    assert max(differ) < 0.006 and max(np.abs(dpsnr)) < 0.03 and max(np.abs(dholes)) < 15, (differ, dpsnr, dholes)
    assert abs(np.mean(dpsnr)) < 0.01, dpsnr


def _sixteen_corner_mesh(build):  # type: ignore[no-untyped-def]
    """``build_mesh`` as 55abe70 made it: 16 vertices for every quad, a flat one's 6 indices into its own 16
    (:data:`FLAT_TRIANGLES`): the mesh built with every quad given zero offsets, its flat quads' indices rewritten."""
    from splitrender.methods.quads.mesh import FLAT_TRIANGLES, SUB_TRIANGLES

    def old(qs, *a, **k):  # type: ignore[no-untyped-def]
        v, i = build(_all_offset(qs), *a, **k)
        assert v.shape[0] == 16 * len(qs)   # every quad drawable here (else the flat flags below would shift)
        base = np.arange(len(qs), dtype=np.uint32) * 16
        idx = [base[q] + (FLAT_TRIANGLES if qs.flat[q] else SUB_TRIANGLES) for q in range(len(qs))]
        return v, (np.concatenate(idx) if idx else i).astype(np.uint32)
    return old


@pytest.mark.parametrize("variant, options", [("quasar", {}), ("quasar", {"seal_cracks": True, "hidden_sky_px": 8}),
                                              ("quadstream", {"sky_edge_px": 0.25, "seal_cracks": True})])
def test_flat_quads_from_four_corners_draw_the_same_pixels(renderer, monkeypatch, variant: str,
                                                           options: dict) -> None:  # type: ignore[no-untyped-def]
    """``build_mesh`` makes a flat quad's four outer corners, not its 16 (issue 49: the client's apply on the
    default walk without GI ~30 -> ~18 ms): a client with it and one building 16 corners for every quad (55abe70's
    mesh) take the same updates (three reference frames: a reference set, its sky, the wide view; with the
    options that move corners: ``seal_cracks``'s extend, ``hidden_sky_px``'s texel lookups, QuadStream's
    ``sky_edge_px`` and guard) and draw the same bytes from two poses after each, with 3.5x or more fewer
    vertices.  Its outer corners' vertices are the 16-corner mesh's own, bit for bit."""
    import splitrender.methods.quads.client as cli_mod
    from splitrender.methods import DecodedUpdate, make_config
    from splitrender.methods.quads.gen import OUTER
    from splitrender.methods.quads.mesh import sealed
    from splitrender.methods.quads.wire import decode_sets

    scene, tr, spec, _ = _setup()
    cfg = make_config(spec.config, {"variant": variant, "lossless": True, **options})
    srv = spec.server_class(cfg, INTR, scene, 30, None)
    new = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
    old = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
    build = cli_mod.build_mesh
    sixteen = _sixteen_corner_mesh(build)
    for f in range(3):
        u = srv.produce(_ctx(renderer, scene, tr, f))
        d = DecodedUpdate(u.frame_id, u.t_s, u.pose, u.planes, u.meta, dict(u.data))
        new.apply(d)
        monkeypatch.setattr(cli_mod, "build_mesh", sixteen)
        old.apply(d)
        monkeypatch.setattr(cli_mod, "build_mesh", build)
        assert new._mesh.count == old._mesh.count and new._mesh.vertices * 3.5 < old._mesh.vertices
        for dt in (0.5 / 30, 1.5 / 30):
            t = 0.5 + f / 30 + dt
            p = tr.pose_at(t)
            a, b = new.render(p, t), old.render(p, t)
            assert np.array_equal(a.color, b.color) and np.array_equal(a.holes, b.holes), (f, dt)
    # the vertices themselves: the last update's first set's flat quads' four, against the 16-corner mesh's outer
    # corners, with a corner-moving extend
    qs = decode_sets(d.data["quads"], d.data["offsets"], "t", (INTR.width, INTR.height), srv.slots,
                     len(u.meta["cameras"]), INTR.far_m, srv.packed)[0].quads
    assert qs.flat.mean() > 0.9 and (~qs.flat).sum() > 10
    ext = sealed(np.ones((len(qs), 4)))
    v4, i4 = build(qs, u.pose, INTR, (0, 0), "quad", extend=ext)
    v16, _ = build(_all_offset(qs), u.pose, INTR, (0, 0), "quad", extend=ext)
    nf = int(qs.flat.sum())
    assert np.array_equal(v4[:4 * nf].reshape(nf, 4, -1), v16.reshape(len(qs), 16, -1)[qs.flat][:, OUTER])
    assert np.array_equal(v4[4 * nf:].reshape(-1, 16, v4.shape[1]), v16.reshape(len(qs), 16, -1)[~qs.flat])
    assert i4.size == 6 * nf + 24 * (len(qs) - nf)


def test_continuous_sides_as_each_sides_pixels_say() -> None:
    """``continuous_sides`` (running counts over the view, issue 49) against each quad's side read pixel by pixel: half
    a texel where every pixel along the side and its neighbour across lie in the view on one surface (depths within
    ``SURFACE_REL``, two infs equal), else 0; quads of every size up to 16 px, sides on the view's border and past
    it.  ``scene_sides`` with the set's index map handed in gives what it gives making its own."""
    from splitrender.methods.quads.mesh import SURFACE_REL, _far_quadtree, continuous_sides, index_map_of, scene_sides

    intr = CameraIntrinsics(61, 37)
    rng = np.random.default_rng(5)
    qs = _far_quadtree(rng.random((37, 61)) < 0.97, intr)
    assert len(qs) > 300 and qs.level.max() >= 3
    depth = rng.choice([1.0, 1.01, 1.3, np.inf, 0.0, np.nan], size=(37, 61), p=[0.55, 0.2, 0.1, 0.05, 0.05, 0.05])
    depth[5:30, 10:50] = 2.0   # a wide surface, so that large quads' sides go on
    z = np.where(np.isfinite(depth) & (depth > 0), depth, np.inf)

    def one_surface(ya: int, xa: int, yb: int, xb: int) -> bool:
        if not (0 <= ya < 37 and 0 <= xa < 61 and 0 <= yb < 37 and 0 <= xb < 61):
            return False
        a, b = z[ya, xa], z[yb, xb]
        return bool(a == b or abs(a - b) <= SURFACE_REL * min(a, b))

    want = np.zeros((len(qs), 4))
    for q in range(len(qs)):
        x0, y0, n = int(qs.x[q]), int(qs.y[q]), 1 << int(qs.level[q])
        pairs = [[(y, x0, y, x0 - 1) for y in range(y0, y0 + n)], [(y0, x, y0 - 1, x) for x in range(x0, x0 + n)],
                 [(y, x0 + n - 1, y, x0 + n) for y in range(y0, y0 + n)],
                 [(y0 + n - 1, x, y0 + n, x) for x in range(x0, x0 + n)]]
        for side, ps in enumerate(pairs):
            want[q, side] = 0.5 if all(one_surface(*p) for p in ps) else 0.0
    got = continuous_sides(qs, depth)
    assert np.array_equal(got, want) and 0.2 < (got > 0).mean() < 0.9
    assert np.array_equal(scene_sides(qs, intr, index_map_of(qs, intr)), scene_sides(qs, intr))


def test_decoded_normals_from_the_table_are_the_formulas() -> None:
    """``decode_normals`` reads uint8 codes from a table (issue 49): for every one of the 256 x 256 codes, in arrays
    of several shapes and as other integer types (the formula itself), the bits of the spherical formula."""
    import math

    from splitrender.methods.quads.gen import decode_normals

    codes = np.arange(256, dtype=np.uint8)
    theta, phi = (x.ravel() for x in np.meshgrid(codes, codes, indexing="ij"))
    t = theta.astype(np.float64) / 255 * math.pi
    p = phi.astype(np.float64) / 255 * 2 * math.pi - math.pi
    want = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], axis=-1)
    assert np.array_equal(decode_normals(theta, phi), want)
    assert np.array_equal(decode_normals(theta.astype(np.int64), phi.astype(np.int64)), want)
    assert np.array_equal(decode_normals(theta.reshape(256, 256), phi.reshape(256, 256)), want.reshape(256, 256, 3))
    assert np.allclose(np.linalg.norm(want, axis=-1), 1.0)


def test_extend_moves_only_the_quads_it_names() -> None:
    """``build_mesh`` computes moved corners only for the quads whose ``extend`` has a side to move (issue 49): a
    quad with a zero row is built as without ``extend``, one with a side to move as in a set of only such quads."""
    from splitrender.methods.quads.mesh import _far_quadtree, build_mesh, sealed, select
    from splitrender.scene.pose import Pose

    rng = np.random.default_rng(2)
    qs = _far_quadtree(rng.random((INTR.height, INTR.width)) < 0.9, INTR)
    ext = sealed(rng.random((len(qs), 4)) < 0.2)
    moved = (ext != 0).any(-1)
    assert 0.3 < moved.mean() < 0.8
    pose = Pose(np.array([0.3, 1.2, 2.0]), np.array([0.96, 0.05, 0.27, 0.0]) / np.linalg.norm([0.96, 0.05, 0.27, 0.0]))
    full, idx = build_mesh(qs, pose, INTR, (0, 0), "quad", extend=ext)
    plain, idx0 = build_mesh(qs, pose, INTR, (0, 0), "quad")
    only, _ = build_mesh(select(qs, moved), pose, INTR, (0, 0), "quad", extend=ext[moved])
    full, plain = full.reshape(len(qs), 4, -1), plain.reshape(len(qs), 4, -1)
    assert np.array_equal(idx, idx0) and np.array_equal(full[~moved], plain[~moved])
    assert np.array_equal(full[moved], only.reshape(-1, 4, full.shape[-1]))
    assert (full[moved] != plain[moved]).any(-1).any(-1).mean() > 0.9


@pytest.mark.parametrize("near_far,delta_max", [((0.05, 200.0), 1e-4), ((0.1, 50.0), 1e-3), ((0.05, 200.0), 0.0),
                                                ((0.05, 200.0), 2.0)])
def test_close_limit_gives_the_window_depths_verdicts(near_far: tuple[float, float], delta_max: float) -> None:
    """A lattice neighbour is close when its distance along the ray, as a window depth, is below ``delta_max``; the
    quad generation compares the distance with ``close_limit`` instead: the same verdict for every distance, at the
    limit and the float64 values either side of it included, and for NaN and inf."""
    from splitrender.methods.quads.gen import close_limit, window_depth

    intr = CameraIntrinsics(320, 180, near_m=near_far[0], far_m=near_far[1])
    limit = close_limit(intr, delta_max)
    rng = np.random.default_rng(5)
    d = np.concatenate([rng.random(20000) * 10 ** rng.uniform(-6, 3, 20000), [0.0, np.inf, np.nan, near_far[0],
                                                                             near_far[1]]])
    if 0 < limit < np.inf:
        d = np.concatenate([d, [limit, np.nextafter(limit, 0), np.nextafter(limit, np.inf)],
                            limit * (1 + rng.uniform(-1e-9, 1e-9, 1000))])
    with np.errstate(invalid="ignore"):
        truth = window_depth(d, intr) < delta_max
    if limit < np.inf:
        assert np.array_equal(d < limit, truth)
    else:   # every finite distance is close
        assert truth[np.isfinite(d)].all()
    assert truth.any() == (limit > 0)
