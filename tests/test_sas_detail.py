"""``sas`` detail and compactness (issue 15): load-time splitting of large patches,
level selection that gives a patch as many texels as it covers pixels, the still-camera
comparison with ``video`` at zero latency, and the compact geometry of wire format v3."""

from __future__ import annotations

import numpy as np
import pytest

from splitrender.scene.pose import CameraIntrinsics
from splitrender.sim.runner import RunConfig

INTR = CameraIntrinsics(320, 180)
BOX_TEXTURED = "/usr/share/assimp/models/glTF2/BoxTextured-glTF-Binary/BoxTextured.glb"


def test_split_mesh_is_conforming_and_renders_the_same() -> None:
    """Red-green refinement: every edge within the bound, no cracks (the split floor renders as the original)."""
    from splitrender.methods.sas.patches import split_mesh, split_scene_meshes
    from splitrender.metrics.image import psnr
    from splitrender.render.renderer import Renderer
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    scene = get_scene("minimal")
    floor = scene.objects[0].mesh
    m = split_mesh(floor, 0.3)
    p = m.positions[m.indices]
    edges = np.linalg.norm(p[:, [1, 2, 0]] - p, axis=2)
    assert edges.max() <= 0.3 and m.triangle_count > 16 * floor.triangle_count, (edges.max(), m.triangle_count)
    assert np.isclose(m.triangle_areas().sum(), floor.triangle_areas().sum(), rtol=1e-5), "the split covers the same area"
    # every interior edge is shared by exactly two triangles, boundary edges lie on the original boundary
    e = np.sort(np.stack([m.indices[:, [0, 1]], m.indices[:, [1, 2]], m.indices[:, [2, 0]]], 1).reshape(-1, 2), 1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert counts.max() == 2, "an edge is used by more than two triangles"
    r = Renderer()
    pose = get_trace("static").pose_at(0.5)
    before = r.render(scene, 0.5, pose, INTR, ("color",)).color
    meshes, bound = split_scene_meshes(scene, 0.15, 10**6)
    assert bound == 0.15
    split = get_scene("minimal")
    for o, mesh in zip(split.objects, meshes):
        o.mesh = mesh
    after = r.render(split, 0.5, pose, INTR, ("color",)).color
    assert psnr(after, before) >= 60.0, f"split scene renders differently: {psnr(after, before):.1f} dB"
    # the triangle cap: the bound grows until the split fits
    meshes, bound = split_scene_meshes(scene, 0.15, 2000)
    assert sum(x.triangle_count for x in meshes) <= 2000 and bound > 0.15


def test_the_split_bound_is_in_world_metres_whatever_an_object_s_scale() -> None:
    """A model placed at 1/4 scale with its vertices 4x further out is the same object in the world: it splits to
    the same triangles (the bound used to be compared with object-space edges: 16x more triangles here)."""
    from splitrender.methods.sas.patches import split_scene_meshes
    from splitrender.scene.loader import get_scene

    plain = get_scene("minimal")
    scaled = get_scene("minimal")
    for o in scaled.objects:
        o.mesh.positions = o.mesh.positions * 4.0
        o.transform = o.transform @ np.diag([0.25, 0.25, 0.25, 1.0])
    a, _ = split_scene_meshes(plain, 0.3, 10**6)
    b, _ = split_scene_meshes(scaled, 0.3, 10**6)
    assert [m.triangle_count for m in b] == [m.triangle_count for m in a], ([m.triangle_count for m in a], [m.triangle_count for m in b])
    assert sum(m.triangle_count for m in a) > 2 * plain.triangle_count     # the bound did split something


@pytest.fixture(scope="module")
def renderer():  # type: ignore[no-untyped-def]
    from splitrender.render.renderer import Renderer

    return Renderer()


def _still_cfg(scene: str, method: str, params: dict | None = None) -> RunConfig:
    """0.3 s of a still camera at zero latency (``static``, ``ideal``), 320x180."""
    return RunConfig(method=method, scene=scene, trace="static", network="ideal", duration_s=0.3, width=320, height=180,
                     client_fps=30, flip_every=0, seed=0, method_params=params or {})


def _still(shared_run, scene: str, method: str, params: dict | None = None) -> float:  # type: ignore[no-untyped-def]
    """Mean PSNR of :func:`_still_cfg`'s run (the session's ``shared_run``: the minimal scene's sas run serves two
    tests)."""
    res = shared_run(_still_cfg(scene, method, params))
    return float(np.mean([f["psnr_db"] for f in res.frames if f["update_frame_id"] >= 0]))  # the start-up tick is black


# (scene, least sas PSNR in dB, largest gap to video in dB): measured at 320x180 (sas / video), over the ticks
# that show an update (tick 0 shows the black background since runs are scored from t = 0).
# History: before issue 15, BoxTextured 26.0 / 37.6, minimal 21.2, default 24.2; with trilinear ground truth
# and one texture level per patch (from its largest extent): BoxTextured 38.99 / 40.72, minimal 27.79 / 42.07,
# default 28.81 / 32.16.  Every atlas texel then took the texture gradients a forward render at the reference
# view takes per display pixel (atlas_shade.frag), which removed the aliasing of far floor texels in large
# patches seen in perspective: BoxTextured 40.23 / 40.72, minimal 30.46 / 42.07, default 30.67 / 32.16.  Eq. 3's
# bias both ways (``fill_atlas``: the levels rise until the blocks fill the budget): minimal 38.22, default
# 32.84 in the paper's 8 Mpix atlas.  What was left was resampling (a texture filtered into the atlas, the atlas
# filtered onto the screen): a Catmull-Rom lookup (``atlas_filter = "bicubic"``) gives minimal 39.22, and the
# 12 Mpix default atlas BoxTextured 40.71 / 40.72, minimal 41.69 / 42.07, default 34.54 / 32.16; with
# untextured patches held to 2 texels per pixel per side (``fill_max_density_plain``) minimal's cube leaves room to the
# floor: 41.85; with long block sides inset by half a texel (wire v4, ``inset_min_texels``): BoxTextured 40.83,
# minimal 43.15, default 34.55.  Load-time splitting then took the bound into each object's own units (issue 33:
# BoxTextured is placed at 4x, and its box split to 384 triangles instead of 6144): BoxTextured 47.29.  Video's
# default became 4:4:4 in issue 33 (BoxTextured 44.17, minimal 43.60, default 34.23; in 4:2:0 40.72 / 42.07 /
# 32.16); the bar holds against it.
STILL = [(BOX_TEXTURED, 47.0), ("minimal", 42.8), ("default+nogi", 34.3)]


def _still_runs(scene: str) -> list[RunConfig]:
    return [_still_cfg(scene, "sas"), _still_cfg(scene, "video")] + ([] if scene == BOX_TEXTURED else
                                                                      [_still_cfg(scene, "sas", {"fill_atlas": False})])


@pytest.mark.parametrize("scene,least_db", [pytest.param(sc, db, marks=pytest.mark.shared_runs(*_still_runs(sc)))
                                            for sc, db in STILL], ids=["BoxTextured", "minimal", "default"])
def test_still_camera_zero_latency_detail_against_video(shared_run, scene: str, least_db: float) -> None:  # type: ignore[no-untyped-def]
    """The issue's bar: with a still camera at zero latency, sas within 1 dB of video."""
    sas = _still(shared_run, scene, "sas")
    video = _still(shared_run, scene, "video")
    assert sas >= least_db and video - sas <= 1.0, f"{scene}: sas {sas:.2f} dB, video {video:.2f} dB (gap {video - sas:.2f} dB)"
    if scene != BOX_TEXTURED:    # without the fill, the ideal levels leave the atlas mostly empty and the detail with it
        ideal = _still(shared_run, scene, "sas", {"fill_atlas": False})
        # measured: minimal 31.20 (+11.95 dB), default 30.87 (+3.68)
        assert sas >= ideal + (11.5 if scene == "minimal" else 3.3), (sas, ideal)


BICUBIC_PARAMS = [None, {"atlas_filter": "bilinear"}, {"atlas_mpix_1080p": 8.0}, {"inset_min_texels": 0}]


@pytest.mark.shared_runs(*(_still_cfg("minimal", "sas", p) for p in BICUBIC_PARAMS))
def test_bicubic_lookup_atlas_size_and_inset_on_the_minimal_scene(shared_run) -> None:  # type: ignore[no-untyped-def]
    """What each part of the detail step gives on ``minimal`` (still camera, zero latency), measured at 43.15 dB with
    all three: the Catmull-Rom lookup against one bilinear tap (41.61 dB), the default 12 Mpix atlas against the
    paper's 8 (40.04 dB: the budget is full and detail follows the texels), and long block sides inset by half a
    texel against every side spanned (41.85 dB: lookups by a patch's border repeated its border texels)."""
    sas, bilinear, paper, spanned = (_still(shared_run, "minimal", "sas", p) for p in BICUBIC_PARAMS)
    assert sas >= bilinear + 1.2, (sas, bilinear)
    assert sas >= paper + 2.7 and paper >= 39.7, (sas, paper)
    assert sas >= spanned + 1.0, (sas, spanned)


def test_geometry_bytes_per_new_patch_on_walk() -> None:
    """Wire v3 geometry (``geo_id``/``geo_size``/``geo_vtx``/``geo_idx`` after msgpack + zstd) per new patch.

    Default scene, ``walk`` at zero latency, 8 server frames.  Measured: 3.4 bytes per
    patch on the first frame (8,405 patches; version 2's per-slot positions: 10.2) and
    12.6 bytes per patch over the next seven (version 2: 16-18.5; fewer shared
    vertices among scattered new patches).  Round trip: the decoded slots equal the
    patches' quantised positions.
    """
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_sas import _loopback  # type: ignore[import-not-found]

    from splitrender.codecs.meta import pack_meta
    from splitrender.methods.sas.wire import decode_geometry_slots, quantize_slots

    rows: list[tuple[int, int, int]] = []

    def on(srv, u) -> None:  # type: ignore[no-untyped-def]
        m = u.meta
        if "geo_id" not in m:
            return
        ids = np.cumsum(m["geo_id"].astype(np.int64))
        P = srv.patches
        v2_pos = quantize_slots(P.slot_pos[ids], P.size[ids], srv.obj_box[P.object_index[ids]])
        assert np.array_equal(decode_geometry_slots(m["geo_vtx"], m["geo_idx"].astype(np.int64)), v2_pos)
        v3 = len(pack_meta({k: m[k] for k in ("geo_id", "geo_size", "geo_vtx", "geo_idx")}))
        v2 = len(pack_meta({"geo_id": ids.astype(np.int32), "geo_obj": P.object_index[ids].astype(np.uint16),
                            "geo_size": P.size[ids].astype(np.uint8), "geo_pos": v2_pos}))
        rows.append((ids.size, v3, v2))

    _loopback(8, {}, t0=1.0, on_frame=on, truth=False)    # nothing here is scored against the ground truth
    a = np.array(rows, np.float64)
    first, later = a[0, 1] / a[0, 0], a[1:, 1].sum() / a[1:, 0].sum()
    assert first <= 4.0 and a[0, 1] <= 0.4 * a[0, 2], f"first frame: {first:.2f} bytes per patch, {a[0, 1] / a[0, 2]:.2f} of v2"
    assert later <= 14.0 and a[1:, 1].sum() <= 0.85 * a[1:, 2].sum(), f"later frames: {later:.2f} bytes per new patch"


def test_moving_object_is_drawn_at_the_display_time() -> None:
    """The ``ball`` (pure green, patrolling at 2.5 m/s) shown 100 ms after each server frame.

    With transforms extrapolated from the two newest updates its centroid must be
    within 2 px of the ground truth at the display time; drawn with the server
    frame's transform (as before issue 15) it would lag by more than 8 px.
    """
    from dataclasses import replace

    from splitrender.codecs.meta import pack_meta, unpack_meta
    from splitrender.methods.base import DecodedUpdate
    from splitrender.pipeline.direct import server_context
    from splitrender.methods.sas import SasClient, SasConfig, SasServer
    from splitrender.methods.sas.client import extrapolate_transforms
    from splitrender.render.renderer import Renderer
    from splitrender.scene.procedural import default_scene
    from splitrender.scene.trace import get_trace

    r = Renderer()
    scene = default_scene(gi=False)
    ball = next(o for o in scene.objects if o.name == "ball")
    ball.material = replace(ball.material, base_color=(0.05, 0.9, 0.05), texture=None)
    trace = get_trace("walk")
    cfg = SasConfig(lossless=True)
    srv = SasServer(cfg, INTR, scene, 30)
    cli = SasClient(cfg, INTR, r.ctx, unpack_meta(pack_meta(srv.session_data())))
    late, lag = 0.1, []
    for f in range(6):
        t = 1.3 + f / 30
        pose = trace.pose_at(t + late)
        ctx = server_context(scene, r, INTR, pose, t_s=t, frame_id=f, predict=trace.pose_at, latency_s=late)
        u = srv.produce(ctx)
        cli.apply(DecodedUpdate(u.frame_id, t, pose, {"atlas": u.planes["atlas"]}, unpack_meta(pack_meta(u.meta))))
        if f < 2:
            continue   # two updates before an object has a velocity
        frame = cli.render(pose, t + late)
        truth = r.render(scene, t + late, pose, INTR, ("object_id",)).object_id == ball.object_id
        c = frame.color.astype(np.int32)
        seen = (c[..., 1] > c[..., 0] + 40) & (c[..., 1] > c[..., 2] + 40) & ~frame.holes
        assert truth.sum() >= 200 and seen.sum() >= 100, f"frame {f}: ball {truth.sum()} px in the truth, {seen.sum()} on the client"
        err = float(np.abs(np.argwhere(seen).mean(0) - np.argwhere(truth).mean(0)).max())
        # where the server frame's transform would put it
        stale = r.render(scene, t, pose, INTR, ("object_id",)).object_id == ball.object_id
        lag.append(float(np.abs(np.argwhere(stale).mean(0) - np.argwhere(truth).mean(0)).max()))
        assert err <= 2.0, f"frame {f}: ball centroid {err:.1f} px from the truth at the display time"
    assert min(lag) > 8.0, f"the server frame's transform must lag visibly, so the test can fail: {lag}"
    # the extrapolation itself: a pure rotation about z at 1 rad/s plus a translation
    def m(a: float, x: float) -> np.ndarray:
        out = np.eye(4, dtype=np.float32)
        out[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        out[0, 3] = x
        return out
    got = extrapolate_transforms(m(0.0, 0.0)[None], np.array([0.0]), m(0.1, 0.2)[None], np.array([0.1]), 0.2)
    assert np.allclose(got[0], m(0.2, 0.4), atol=1e-5)


def test_allocator_s0_uses_columns() -> None:
    """S0 stacks blocks of different heights in columns of one width inside a superblock; S1 (no columns) cannot.

    Blocks 8 texels wide and 2, 4 or 8 high: under S0 they share superblocks (fewer
    claimed), under S1 each height claims its own, so a strategy that silently lost its
    columns fails here.
    """
    from splitrender.methods.sas.allocator import AtlasLayout, PatchAllocator

    lay = AtlasLayout(256, 128, 32, 1)
    n = 60
    lw = np.full(n, 3)
    lh = np.array([1, 2, 3] * (n // 3))
    mixed, used = {}, {}
    for strategy in ("S0", "S1"):
        al = PatchAllocator(n, lay, strategy)  # type: ignore[arg-type]
        al.update(np.arange(n), lw, lh)
        rects = al.blocks(np.arange(n))
        sb = (rects[:, 1] // 32) * lay.sb_cols + rects[:, 0] // 32
        mixed[strategy] = max(len(set(rects[sb == s, 3].tolist())) for s in np.unique(sb))
        used[strategy] = int(np.unique(sb).size)
    # 20 blocks each of 8x2, 8x4, 8x8: 280 texel rows of width 8 = 2.2 superblocks of 4 columns under S0
    assert mixed["S0"] >= 2 and mixed["S1"] == 1, f"distinct block heights in one superblock: {mixed}"
    assert used["S0"] == 3 and used["S1"] >= 4, f"superblocks claimed: {used}"


def test_gpu_visibility_counts_equal_the_read_back_counts_on_walk() -> None:
    """PVS areas counted on the GPU (compute pass, atomic counters, max over samples) equal the
    ID-buffer read-back path's, over server windows on the default ``walk``; frustum culling per
    object and cluster leaves out part of the scene and, looking away, nearly all of it."""
    from splitrender.methods.sas import SasConfig, SasServer
    from splitrender.methods.sas.pvs import PatchIdPass
    from splitrender.render.renderer import Renderer
    from splitrender.scene.pose import Pose, look_at_quat
    from splitrender.scene.procedural import default_scene
    from splitrender.scene.trace import get_trace

    r = Renderer()
    scene = default_scene(gi=False)
    trace = get_trace("walk")
    srv = SasServer(SasConfig(), INTR, scene, 30)
    ids = PatchIdPass(r, scene, srv.patches)
    assert ids.gpu_count, "llvmpipe runs compute shaders"
    big = INTR.enlarged(1.2)
    total = sum(m.triangle_count for m in srv.patches.meshes)
    drawn = []
    for t in np.linspace(0.5, trace.duration_s - 0.5, 6):
        samples = [(float(s), trace.pose_at(float(s))) for s in (t, t + 0.033, t + 0.066)]
        gpu = ids.pvs_area(samples, big, gpu=True)
        drawn.append(ids.drawn_triangles)
        cpu = ids.pvs_area(samples, big, gpu=False)
        assert np.array_equal(gpu, cpu), f"t={t:.2f}: {int((gpu != cpu).sum())} patches differ"
        assert (gpu > 0).sum() > 100
    assert max(drawn) < total, f"culling drew {drawn} of {total} triangles"
    eye = np.array([0.0, 1.6, 30.0])
    away = Pose(eye, look_at_quat(eye, eye + np.array([0.0, 0.0, 1.0])))   # away from the room, behind the camera
    ids.pvs_area([(1.0, away)], INTR)
    assert ids.drawn_triangles == 0, f"looking away drew {ids.drawn_triangles} of {total} triangles"


def test_objects_culled_all_at_once_draw_what_a_test_per_object_draws() -> None:
    """The ID pass tests every object's sphere against the frustum in one array operation (the still
    objects' spheres placed once, the animated ones' at each sample's time); it draws the same triangles as
    placing and testing each object's sphere and clusters one by one, on the default scene's ``walk`` and
    with the moving objects at different times."""
    from splitrender.methods.sas import SasConfig, SasServer
    from splitrender.methods.sas.pvs import CLUSTER_TRIANGLES, PatchIdPass, frustum_planes, spheres_visible
    from splitrender.render.renderer import Renderer
    from splitrender.scene.procedural import default_scene
    from splitrender.scene.trace import get_trace

    scene = default_scene(gi=False)
    assert any(o.animation is not None for o in scene.objects) and any(o.animation is None for o in scene.objects)
    srv = SasServer(SasConfig(), INTR, scene, 30)
    ids = PatchIdPass(Renderer(), scene, srv.patches)
    cl = ids.clusters
    trace = get_trace("walk")
    seen = set()
    for t in np.linspace(0.2, trace.duration_s - 0.2, 9):
        pose = trace.pose_at(float(t))
        planes = frustum_planes(INTR.projection() @ pose.view_matrix())
        want = 0
        for k, o in enumerate(scene.objects):
            n_tri = cl.indices[k].shape[0]
            model = np.asarray(o.model_matrix(float(t)), np.float64)
            if n_tri == 0 or not spheres_visible(planes, model, cl.sphere[k][None, :3], cl.sphere[k][3:4])[0]:
                continue
            vis = spheres_visible(planes, model, cl.centers[k], cl.radii[k])
            first = np.flatnonzero(vis) * CLUSTER_TRIANGLES
            want += int(np.minimum(first + CLUSTER_TRIANGLES, n_tri).sum() - first.sum())
            if o.animation is not None:
                seen.add(k)
        ids.render_ids(pose, INTR, float(t))
        assert ids.drawn_triangles == want, f"t={t:.2f}: drew {ids.drawn_triangles} triangles, per object {want}"
    assert seen, "no moving object was in view on the walk"


WUSON = "/usr/share/assimp/models/PLY/Wuson.ply"


WUSON_2S = RunConfig(method="sas", scene=WUSON, trace="walk", network="ideal", duration_s=2.0, width=320, height=180,
                     client_fps=30, flip_every=0, seed=0)


@pytest.mark.skipif(not __import__("os").path.exists(WUSON), reason="assimp-testmodels not installed")
@pytest.mark.shared_runs(WUSON_2S)
def test_metadata_is_at_most_a_third_of_the_bits_on_a_real_model(shared_run) -> None:  # type: ignore[no-untyped-def]
    """Issue 15's target on an untextured real model (assimp ``Wuson.ply``, 3.7k triangles), ``walk``, ``ideal``.

    After the first second: measured 32.8 % of ``sas``'s bytes are metadata (wire v3,
    8-frame PVS linger; about 66 % before issue 15, 36 % with v3 and a 4-frame linger).
    """
    res = shared_run(WUSON_2S)
    late = [u for u in res.updates if u["t_s"] >= 1.0]
    share = sum(u["bytes_meta"] for u in late) / sum(u["bytes"] for u in late)
    assert share <= 1 / 3, f"metadata is {share:.1%} of sas's bytes after the first second"
    assert res.summary["mean_psnr_db"] >= 50.0, f"quality {res.summary['mean_psnr_db']:.2f} dB"


def test_only_maps_that_vary_are_texture_detail() -> None:
    from splitrender.methods.sas.server import has_texture_detail
    from splitrender.scene.model import Material
    from splitrender.scene.textures import checker

    assert has_texture_detail(Material("c", (1, 1, 1), checker(64, 8)))
    assert not has_texture_detail(Material("grey", (1, 1, 1), np.full((2, 2, 3), 100, np.uint8)))   # a loader's placeholder
    assert not has_texture_detail(Material("plain", (0.8, 0.2, 0.2)))


def _wuson_1s(params: dict) -> RunConfig:
    return RunConfig(method="sas", scene=WUSON, trace="walk", network="ideal", duration_s=1.0, width=320, height=180,
                     client_fps=30, flip_every=0, seed=0, metrics=True, method_params=params)


SMOOTH = {"capped": {}, "filled": {"fill_max_density_plain": 64.0}}


@pytest.mark.skipif(not __import__("os").path.exists(WUSON), reason="assimp-testmodels not installed")
@pytest.mark.shared_runs(*(_wuson_1s(p) for p in SMOOTH.values()))
def test_a_smooth_model_does_not_fill_the_atlas(shared_run) -> None:  # type: ignore[no-untyped-def]
    """``Wuson.ply`` has no texture detail: its patches rise at most 2x their ideal texels per pixel per side
    (``fill_max_density_plain``), for about half the bits of filling the atlas and no less quality.  Measured
    (``walk``, ``ideal``, 1 s, 320x180): 52.13 dB at 2.01 Mbit/s against 51.09 dB at 3.83 Mbit/s uncapped (52.50 dB at
    1.12 Mbit/s at the ideal levels), with an I-frame every 5 frames; with one every 30 (issue 50), 52.19 dB at
    1.25 Mbit/s against 51.99 dB at 2.19 Mbit/s: the P-frames keep more of the uncapped atlas's detail, and the cap
    saves as many bits for a smaller gain."""
    out = {}
    for name, params in SMOOTH.items():
        res = shared_run(_wuson_1s(params))
        out[name] = (res.summary["mean_psnr_db"], res.summary["mean_kbps"])
    (q_cap, kb_cap), (q_fill, kb_fill) = out["capped"], out["filled"]
    assert kb_cap <= 0.6 * kb_fill and q_cap >= q_fill + 0.1, out       # measured 0.57x the bits, +0.20 dB


def test_long_block_sides_inset_the_patch_by_half_a_texel() -> None:
    """Wire v4 layout: along a side of at least ``inset`` texels the patch's corners lie on the border texels'
    centres (the paper's figure 6), along a shorter side on the block's edges; transposed blocks swap the axes."""
    from splitrender.methods.sas.wire import SLOT_LAYOUT, block_layout_xy

    rect = np.array([[64, 32, 16, 4], [0, 0, 16, 4]], np.float64)     # 16 wide (inset), 4 high (spanned)
    xy = block_layout_xy(np.broadcast_to(SLOT_LAYOUT[2], (2, 5, 2)), rect, np.array([False, True]), 8)
    assert xy[0, :4].tolist() == [[64.5, 32.0], [79.5, 32.0], [64.5, 36.0], [79.5, 36.0]]
    assert xy[1, :4].tolist() == [[0.5, 0.0], [0.5, 4.0], [15.5, 0.0], [15.5, 4.0]]    # transposed: u along y
    spanned = block_layout_xy(np.broadcast_to(SLOT_LAYOUT[2], (2, 5, 2)), rect, np.array([False, True]), 0)
    assert spanned[0, :4].tolist() == [[64.0, 32.0], [80.0, 32.0], [64.0, 36.0], [80.0, 36.0]]


def test_nonsense_atlas_settings_are_named() -> None:
    from splitrender.errors import ConfigError
    from splitrender.methods.sas import SasConfig

    with pytest.raises(ConfigError, match=r"SasConfig.atlas_filter: 'lanczos' is not one of"):
        SasConfig(atlas_filter="lanczos")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"SasConfig.atlas_mpix_1080p: must be > 0"):
        SasConfig(atlas_mpix_1080p=0.0)
    with pytest.raises(ConfigError, match=r"SasConfig.fill_max_density_plain: must be in \[1, 64\], got 0.5"):
        SasConfig(fill_max_density_plain=0.5)


def test_shading_draws_each_block_texel_once_and_misses_none(renderer) -> None:  # type: ignore[no-untyped-def]
    """Issue 49: the shading stage grows a triangle across an edge another triangle of its patch shares by a
    thirty-second of a texel only (grown by 1.5 texels as the outer edges, the default view drew 1.65 times the
    blocks' texels, and shading cost followed the fragments): at most 1.1 fragments per block texel, and no texel
    of a live block left as it was before the pass (a crack along a block's diagonal, whose texel centres lie on it)."""
    from splitrender.pipeline.direct import server_context
    from splitrender.methods.sas import SasConfig, SasServer
    from splitrender.scene.procedural import default_scene
    from splitrender.scene.trace import get_trace

    scene = default_scene(gi=False)
    srv = SasServer(SasConfig(shade_changed_only=False), INTR, scene, 30)   # the pass again draws every block
    got: dict[str, object] = {}
    shade = srv._shade

    def spy(ctx, live, frame, foot, clear):  # type: ignore[no-untyped-def]
        got.update(args=(ctx, live, frame, foot))
        return shade(ctx, live, frame, foot, clear)

    srv._shade = spy  # type: ignore[method-assign]
    pose = get_trace("static").pose_at(0.5)
    srv.produce(server_context(scene, renderer, INTR, pose, t_s=0.5))
    ctx, live, frame, foot = got["args"]  # type: ignore[misc]
    srv._fbo.use()
    srv._fbo.clear(1.0, 0.0, 1.0, 1.0)               # magenta: no shaded texel of the default scene is
    q = renderer.ctx.query(samples=True)
    with q:
        shade(ctx, live, frame, foot, False)
    atlas = np.frombuffer(srv._fbo.read(components=3, alignment=1), np.uint8).reshape(srv.layout.height, srv.layout.width, 3)
    inside = np.zeros(atlas.shape[:2], bool)
    for x, y, w, h in srv.allocator.blocks(live).tolist():
        inside[y:y + h, x:x + w] = True
    texels = int(inside.sum())
    assert texels > 100_000
    assert q.samples <= 1.1 * texels, f"{q.samples} fragments for {texels} block texels"    # measured 1.06
    missed = inside & (atlas == (255, 0, 255)).all(-1)
    assert not missed.any(), f"{int(missed.sum())} block texels not shaded"


def test_pvs_leaves_out_a_sample_next_to_the_window_s_end() -> None:
    """The default step (33.3 ms) over a 30 fps frame's window put a third sample 0.03 ms before the end (a third
    of the frame's ID passes for the same pose); a sample within 5 % of a step of the end is left out."""
    from splitrender.methods.sas.pvs import sample_times

    assert sample_times(0.5, 0.5 + 1 / 30, 0.0333) == [0.5, 0.5 + 1 / 30]
    assert sample_times(0.0, 0.1, 0.0333) == [0.0, 0.0333, 0.0666, 0.1]
    assert sample_times(0.0, 0.001, 0.0333) == [0.0, 0.001]
    assert sample_times(0.0, 0.0684, 0.0333) == [0.0, 0.0333, 0.0666, 0.0684]   # 0.054 steps from the end: kept



def test_a_long_window_takes_at_most_max_samples_evenly_spaced() -> None:
    """A live server making a frame in 0.6 s expects that much latency: 33.3 ms steps over its window took 22 ID
    passes (issue 49).  ``max_samples`` spreads a longer window over that many times, ends kept; a window that fits
    is sampled as without it (the cap of 8 leaves every virtual-time network profile's 3-7 samples alone)."""
    from splitrender.methods.sas import SasConfig
    from splitrender.methods.sas.pvs import sample_times
    from splitrender.errors import ConfigError

    long = sample_times(0.0, 0.7, 0.0333)
    assert len(long) == 22
    capped = sample_times(0.0, 0.7, 0.0333, 8)
    assert len(capped) == 8 and capped[0] == 0.0 and capped[-1] == 0.7
    assert np.allclose(np.diff(capped), 0.1)
    for window in (1 / 30, 0.1, 0.2, 0.2331):   # up to 8 samples: the same times with the cap
        assert sample_times(0.5, 0.5 + window, 0.0333, 8) == sample_times(0.5, 0.5 + window, 0.0333)
    assert len(sample_times(0.5, 0.5 + 0.2331, 0.0333)) == 8
    assert SasConfig().pvs_max_samples == 8
    with pytest.raises(ConfigError, match="pvs_max_samples"):
        SasConfig(pvs_max_samples=1)


def test_each_id_pass_starts_from_a_cleared_id_buffer() -> None:
    """The ID buffer is cleared with a GL clear (not an upload of zeros): a pass that draws nothing after one that
    drew the room reads back background only, and a pass after others equals a fresh pass's at the same pose."""
    from splitrender.methods.sas import SasConfig, SasServer
    from splitrender.methods.sas.pvs import PatchIdPass
    from splitrender.render.renderer import Renderer
    from splitrender.scene.pose import Pose, look_at_quat
    from splitrender.scene.procedural import default_scene
    from splitrender.scene.trace import get_trace

    r = Renderer()
    scene = default_scene(gi=False)
    trace = get_trace("walk")
    srv = SasServer(SasConfig(), INTR, scene, 30)
    ids = PatchIdPass(r, scene, srv.patches)
    big = INTR.enlarged(1.2)
    seen = ids.id_buffer(trace.pose_at(1.0), big, 1.0)
    assert (seen > 0).mean() > 0.5
    eye = np.array([0.0, 1.6, 30.0])
    away = Pose(eye, look_at_quat(eye, eye + np.array([0.0, 0.0, 1.0])))   # away from the room
    assert not ids.id_buffer(away, big, 1.0).any()
    fresh = PatchIdPass(r, scene, srv.patches)
    for t in (2.0, 3.5):
        ids.id_buffer(trace.pose_at(t - 1.0), big, t - 1.0)
        got = ids.id_buffer(trace.pose_at(t), big, t)
        assert np.array_equal(got, fresh.id_buffer(trace.pose_at(t), big, t))


def test_live_pvs_lingers_for_the_time_its_frames_take() -> None:
    """``pvs_linger_frames`` (8) keeps a patch 8 frames after its last EVS sample: in virtual time 8 frames; live
    (the renderer relights the probes at a rate) the frames within 8 / 30 s, at least one, so a live server making
    a frame in 0.6 s no longer keeps (and refreshes) patches seen 4.8 s ago, and one at 30 fps keeps 8 as before."""
    from types import SimpleNamespace

    from splitrender.methods.sas import SasConfig, SasServer
    from splitrender.scene.procedural import default_scene

    srv = SasServer(SasConfig(), INTR, default_scene(gi=False), 30)
    live, virtual = SimpleNamespace(gi_hz=5.0), SimpleNamespace(gi_hz=0.0)

    def linger(renderer: object, times: list[float], t: float) -> int:
        srv._frame_t = list(times)
        return srv._linger_frames(SimpleNamespace(renderer=renderer, t_s=t))  # type: ignore[arg-type]

    fast = [1.0 + k / 30 for k in range(8)]
    slow = [1.0 + 0.6 * k for k in range(8)]
    assert linger(live, fast, 1.0 + 8 / 30) == 8 and linger(virtual, fast, 1.0 + 8 / 30) == 8
    assert linger(live, slow, 1.0 + 0.6 * 8) == 1 and linger(virtual, slow, 1.0 + 0.6 * 8) == 8
    assert linger(live, [1.0 + 0.1 * k for k in range(8)], 1.8) == 2    # frames 0.1 s apart: 0.2 s within 0.267
    assert linger(live, [], 1.0) == 1
    assert SasServer(SasConfig(pvs_linger_frames=0), INTR, srv.scene, 30)._linger_frames(
        SimpleNamespace(renderer=live, t_s=1.0)) == 0  # type: ignore[arg-type]

TTT = "/usr/share/assimp/models/glTF2/textureTransform/TextureTransformTest.gltf"


@pytest.mark.skipif(not __import__("os").path.exists(TTT), reason="assimp-testmodels not installed")
def test_atlas_texture_gradients_follow_the_materials_uv_transform(renderer) -> None:  # type: ignore[no-untyped-def]
    """``shade()`` reads the maps at ``u_uv_transform * uv`` (KHR_texture_transform); atlas_shade.frag took the display
    footprint's gradients on the untransformed uv, so TextureTransformTest's two quads scaled by 1.5 were filtered at too
    fine a mip level and aliased (tss had the same, 3838ba7).  One still frame, the atlas as shaded (no codec), PSNR on
    each quad: measured quad 0 40.26 -> 55.84 dB, quad 2 39.30 -> 51.22; the others (no scale) the same either way
    (quad 5, rotated: 53.97)."""
    from splitrender.methods import get_method, make_config
    from splitrender.pipeline.direct import still_frame
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    scene = get_scene(TTT)
    spec = get_method("sas")
    cfg = make_config(spec.config, {})
    pose = get_trace("static", scene=scene).pose_at(0.5)
    still = still_frame(spec, cfg, INTR, scene, renderer, pose, 0.5)
    truth = renderer.render(scene, 0.5, pose, INTR, ("color", "object_id"))
    got = still.frame.color.astype(np.float64)   # type: ignore[union-attr]
    db = {}
    for name in ("TextureTransformTest_0", "TextureTransformTest_2", "TextureTransformTest_5"):
        m = truth.object_id == next(o.object_id for o in scene.objects if o.name == name)
        assert m.sum() > 1000, f"{name} is in view"
        db[name] = 10.0 * np.log10(255.0 ** 2 / np.mean((got[m] - truth.color[m].astype(np.float64)) ** 2))
    assert min(db.values()) >= 50.0, db
