"""QuadStream's margin over QUASAR on a thin structure (issue 50, part 2): a railing of 3 cm posts in front of a
textured wall, seen by a client that has moved inside the view cell.

QuadStream's extra views (the 8 corners of the 0.5 m view cell) see the posts' sides and the wall behind them from
where the client goes; QUASAR's single centre view does not (its hidden layer sees behind the posts from the centre,
not the posts' sides; with one layer the railing's error is the same, measured).  The numbers in the docstring were
measured on this project's 2-core machine (llvmpipe)."""

from __future__ import annotations

import numpy as np

from splitrender.scene.pose import CameraIntrinsics, Pose

INTR = CameraIntrinsics(320, 180)
CLIENT_OFFSETS = ((0.1, 0.0, 0.0), (0.25, 0.0, 0.0), (0.0, 0.0, 0.25), (0.25, 0.0, 0.25))
"""Where the client stands, metres from the server's pose (right, up, back): inside the 0.5 m view cell."""
WRONG = 24
"""A pixel is wrong where some channel is more than this many code values off the truth."""


def railing_scene():  # type: ignore[no-untyped-def]
    """Thirteen 3 cm square posts 0.2 m apart and a top bar (orange, object 1) 2 m in front of the camera, before a
    checkered wall (object 2) at 3.5 m; a sun, no ground."""
    from splitrender.scene import primitives as P
    from splitrender.scene import textures as T
    from splitrender.scene.model import DirectionalLight, Material, Scene, SceneObject, merge_meshes

    def at(x: float, y: float, z: float) -> np.ndarray:
        m = np.eye(4)
        m[:3, 3] = (x, y, z)
        return m

    posts = [P.translate(P.box((0.03, 1.2, 0.03)), (x, 0.6, 0.0)) for x in np.arange(-1.2, 1.21, 0.2)]
    bar = P.translate(P.box((2.6, 0.03, 0.03)), (0.0, 1.2, 0.0))
    return Scene("railing", [
        SceneObject("railing", merge_meshes(posts + [bar], "railing"), Material("metal", (0.9, 0.3, 0.1)), 1, at(0, 0, -2.0)),
        SceneObject("wall", P.box((6.0, 3.0, 0.1), uv_scale_m=1.0), Material("wall", (1, 1, 1), T.checker(128, 8)), 2,
                    at(0, 1.0, -3.5), backdrop=True),
    ], DirectionalLight(direction=(-0.3, -1.0, -0.5)), [])


def _moved_client(renderer, one_frame, scene, variant: str):  # type: ignore[no-untyped-def]
    """One lossless reference frame of ``variant`` made at the server's pose (0, 0.8, 0), looking down -z; per client
    offset: (PSNR over the railing's pixels, share of them wrong, share of the frame the client leaves as holes)."""
    from splitrender.methods import get_method, make_config

    pose = Pose(np.array([0.0, 0.8, 0.0]), np.array([0.0, 0.0, 0.0, 1.0]))
    spec = get_method("quads")
    cfg = make_config(spec.config, {"lossless": True, "variant": variant})
    cli = one_frame("quads", cfg, INTR, scene, pose)
    out = []
    for off in CLIENT_OFFSETS:
        moved = Pose(pose.position + np.asarray(off), pose.orientation)
        got = cli.render(moved, 0.0)
        truth = renderer.render(scene, 0.0, moved, INTR, ("color", "object_id"))
        rail = truth.object_id == 1
        diff = got.color.astype(np.int16) - truth.color.astype(np.int16)
        mse = float((diff[rail].astype(np.float64) ** 2).mean())
        out.append((10 * np.log10(255.0 ** 2 / mse), float((np.abs(diff).max(-1) > WRONG)[rail].mean()),
                    float(got.holes.mean())))
    return np.array(out)


def test_quadstream_shows_a_thin_railing_better_than_quasar_from_inside_the_view_cell(renderer, one_frame) -> None:  # type: ignore[no-untyped-def]
    """Per client offset (0.1 m right, 0.25 right, 0.25 back, 0.25 right and back), lossless atlas, measured:

    * PSNR over the railing: QUASAR 21.16 / 16.58 / 18.02 / 16.85 dB, QuadStream 30.98 / 21.66 / 25.57 / 25.85:
      a margin of +7.86 dB on average, +5.1 at least (issue 50: before QuadStream's centre view took priority over
      its later views 27.75 / 21.20 / 20.55 / 22.91, +4.95 on average, +2.5 at least; with the priority alone
      33.40 / 21.29 / 23.35 / 22.92; the centre view's lookups now also filter across quad borders along a surface);
    * railing pixels wrong: QUASAR 15.5 / 41.9 / 27.8 / 28.5 %, QuadStream 2.3 / 16.9 / 9.3 / 8.0 % (0.32x; 0.30x
      before; filtering across every quad border of the centre view, depth edges too, made it 0.61x);
    * holes: QUASAR 0 / 0.63 / 0.42 / 2.61 % of the frame (1.45 / 2.86 / 8.43 / 8.95 % before its client laid sky
      behind the model, ``tests/test_quads_sky.py``; the railing's numbers did not change), QuadStream 0.12 % at
      most.

    Bounds: the mean margin at least 3.5 dB and at every offset at least 1.5 dB; QuadStream's wrong railing
    pixels at most 0.45x QUASAR's; its holes under 0.5 % where QUASAR's average over 0.6 % (measured 0.91 %)."""
    scene = railing_scene()
    qr = _moved_client(renderer, one_frame, scene, "quasar")
    qs = _moved_client(renderer, one_frame, scene, "quadstream")
    margin = qs[:, 0] - qr[:, 0]
    assert margin.mean() > 3.5 and margin.min() > 1.5, (qr, qs)
    assert qs[:, 1].mean() < 0.45 * qr[:, 1].mean(), (qr, qs)
    assert qs[:, 2].max() < 0.005 and qr[:, 2].mean() > 0.006, (qr, qs)


def test_expand_edges_grows_every_silhouette_by_a_pixel_as_qs_simulator_does() -> None:
    """``expand_edges`` (QUASAR's ``expandEdges``, which its QuadStream uses for every view): each background pixel
    with a valid 8-neighbour takes the farthest such neighbour's depth, normal and colour; the rest stays."""
    from splitrender.methods.quads.server import QS_EXPAND_EDGES, expand_edges

    assert QS_EXPAND_EDGES is False                   # opt-in: measured on the peer benchmark only
    depth = np.full((7, 7), np.inf)
    depth[2:5, 2:5] = 2.0
    depth[2, 2] = 3.0                                 # the block's farthest pixel, top left
    color = np.zeros((7, 7, 3), np.uint8)
    color[2:5, 2:5] = 100
    color[2, 2] = 200
    normal = np.zeros((7, 7, 3))
    normal[2:5, 2:5] = (0.0, 0.0, 1.0)
    normal[2, 2] = (0.0, 1.0, 0.0)
    c, d, n = expand_edges(color, depth, normal)
    grown = np.isfinite(d)
    assert grown[1:6, 1:6].all() and grown.sum() == 25 and (d[2:5, 2:5] == depth[2:5, 2:5]).all()
    assert d[1, 1] == 3.0 and (c[1, 1] == 200).all() and (n[1, 1] == (0, 1, 0)).all()       # beside the far pixel
    assert d[5, 5] == 2.0 and (c[5, 5] == 100).all() and (n[5, 5] == (0, 0, 1)).all()
    assert (c[0] == 0).all() and np.isinf(d[0]).all()                                         # two away: background
    full = np.full((4, 4), 1.0)
    assert expand_edges(color[:4, :4], full, normal[:4, :4])[1] is full


def _disoccluded(renderer, scene, pose, moved) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """(the railing's pixels at ``moved``, those of them the server's centre view at ``pose`` does not see): a
    pixel's surface point, seen from ``pose``, lies outside its image or more than 2 % behind what it shows there."""
    from splitrender.methods.quads.gen import rays

    at = renderer.render(scene, 0.0, moved, INTR, ("depth", "object_id"))
    centre = renderer.render(scene, 0.0, pose, INTR, ("depth",)).depth
    ys, xs = np.mgrid[0:INTR.height, 0:INTR.width].astype(np.float64)
    ok = np.isfinite(at.depth)
    p = rays(INTR, xs + 0.5, ys + 0.5) * np.where(ok, at.depth, 1.0)[..., None]
    world = p @ moved.matrix()[:3, :3].T + moved.matrix()[:3, 3]
    v = world @ pose.view_matrix()[:3, :3].T + pose.view_matrix()[:3, 3]
    z = -v[..., 2]
    f = INTR.focal_px()
    u, w = v[..., 0] / z * f + INTR.width / 2, -v[..., 1] / z * f + INTR.height / 2
    inside = (z > 0) & (u >= 0) & (u < INTR.width) & (w >= 0) & (w < INTR.height)
    cz = centre[np.clip(w, 0, INTR.height - 1).astype(int), np.clip(u, 0, INTR.width - 1).astype(int)]
    seen = inside & np.isfinite(cz) & (z <= cz * 1.02)
    rail = ok & (at.object_id == 1)
    return rail, rail & ~seen


def test_quadstream_leads_quasar_where_its_extra_views_disocclude_the_railing(renderer, one_frame) -> None:  # type: ignore[no-untyped-def]
    """The paper's case for QuadStream's extra views: the railing's pixels that the client, moved inside the view
    cell, sees and the server's centre view does not (the posts' sides: 61 pixels over the four client offsets above,
    11 at the first).  Lossless, one frame at the server's pose, PSNR pooled over the four offsets.  Measured:
    QuadStream 14.01 dB there against QUASAR's 8.84 (+5.17 dB); over the railing pixels the centre view sees too,
    24.95 against 18.00 (+6.95: QUASAR's one-pixel quads of the posts leave cracks from aside as well, so the
    margin is not confined to the disoccluded pixels).  Bound: the margin on the disoccluded pixels at least 4 dB."""
    from splitrender.methods import get_method, make_config

    scene = railing_scene()
    pose = Pose(np.array([0.0, 0.8, 0.0]), np.array([0.0, 0.0, 0.0, 1.0]))
    clients = {v: one_frame("quads", make_config(get_method("quads").config, {"lossless": True, "variant": v}), INTR,
                            scene, pose) for v in ("quasar", "quadstream")}
    sse = {(v, k): 0.0 for v in clients for k in ("dis", "seen")}
    count = {"dis": 0, "seen": 0}
    for off in CLIENT_OFFSETS:
        moved = Pose(pose.position + np.asarray(off), pose.orientation)
        rail, dis = _disoccluded(renderer, scene, pose, moved)
        assert dis.sum() >= 5, (off, int(dis.sum()))
        truth = renderer.render(scene, 0.0, moved, INTR, ("color",)).color.astype(np.float64)
        count["dis"] += int(dis.sum()) * 3
        count["seen"] += int((rail & ~dis).sum()) * 3
        for v, cli in clients.items():
            err = (cli.render(moved, 0.0).color.astype(np.float64) - truth) ** 2
            sse[v, "dis"] += float(err[dis].sum())
            sse[v, "seen"] += float(err[rail & ~dis].sum())
    psnr = {key: 10 * np.log10(255.0 ** 2 * count[key[1]] / max(e, 1e-10)) for key, e in sse.items()}
    dis_margin = psnr["quadstream", "dis"] - psnr["quasar", "dis"]
    seen_margin = psnr["quadstream", "seen"] - psnr["quasar", "seen"]
    assert 40 * 3 <= count["dis"] <= 90 * 3, count      # 61 pixels measured
    assert dis_margin >= 4.0 and seen_margin > 0.0, psnr
