"""``tss``: tessellated shading streaming (issue 12; a fine mesh in a lossy atlas, issue 33).

The sample patterns against this machine's GL tessellator, the L-packing and
oversampling layouts as bijections with exact or bounded reconstruction, the single-texel
cells and the compact geometry, the gathering stage against its plan, quality against the
ground truth beside ``sas`` and ``atw``, and malformed wire data."""

from __future__ import annotations

import math
import os
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.methods.tss.layout import (SINGLE_TILE, lp_lookup, lp_positions, lp_reconstruct, morton_order, os_centred_taps, os_linear_id,
                                            os_lookup, os_row_lengths, os_sample_bary, os_sizes, single_origins, single_per_shelf,
                                            tess_coords, tip_dim, v_count)
from splitrender.scene.pose import CameraIntrinsics

INTR = CameraIntrinsics(320, 180)

_VS = "#version 430\nin vec3 in_p; out vec3 v_p; void main() { v_p = in_p; }"
_TCS = """#version 430
layout(vertices = 3) out; in vec3 v_p[]; out vec3 c_p[]; uniform float u_l;
void main() { c_p[gl_InvocationID] = v_p[gl_InvocationID];
  if (gl_InvocationID == 0) { gl_TessLevelOuter[0] = u_l; gl_TessLevelOuter[1] = u_l; gl_TessLevelOuter[2] = u_l;
                              gl_TessLevelInner[0] = u_l; } }"""
_TES = """#version 430
layout(triangles, equal_spacing, ccw) in; in vec3 c_p[];
layout(std430, binding = 0) buffer C { uint n; uint pad[3]; vec4 co[]; };
void main() { uint k = atomicAdd(n, 1u); if (k < 4096u) co[k] = vec4(gl_TessCoord, 0.0);
  gl_Position = vec4(c_p[0] * gl_TessCoord.x, 1.0); }"""
_FS = "#version 430\nout vec4 f; void main() { f = vec4(1.0); }"


def test_tessellation_invocations_equal_v_l_on_this_gl() -> None:
    """Paper eq. 1: all factors ``l`` spawn ``v(l)`` evaluation invocations (v(64) = 3169), one per vertex,
    at the barycentrics of the ring model :func:`tess_coords` that the layouts are built on."""
    import moderngl

    from splitrender.render.gl import get_context

    ctx = get_context()
    prog = ctx.program(vertex_shader=_VS, tess_control_shader=_TCS, tess_evaluation_shader=_TES, fragment_shader=_FS)
    vao = ctx.vertex_array(prog, [(ctx.buffer(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "f4").tobytes()), "3f", "in_p")])
    buf = ctx.buffer(reserve=16 + 16 * 4096)
    fbo = ctx.simple_framebuffer((8, 8))   # Mesa skips draws without a complete framebuffer, discard or not
    fbo.use()
    assert int(v_count(64)) == 3169
    for lv in range(1, 65):
        buf.clear()
        buf.bind_to_storage_buffer(0)
        prog["u_l"].value = float(lv)
        ctx.enable_direct(0x8C89)   # GL_RASTERIZER_DISCARD
        vao.render(mode=moderngl.PATCHES, vertices=3)
        ctx.disable_direct(0x8C89)
        n = int(np.frombuffer(buf.read(4), np.uint32)[0])
        assert n == v_count(lv), f"level {lv}: {n} invocations, v(l) = {int(v_count(lv))}"
        got = np.frombuffer(buf.read(16 * n, offset=16), np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
        model = tess_coords(lv)
        # both sets on the lattice of 1 / (6 l): GL's float32 coordinates must round to the ring model's points
        # (within 5% of the ring spacing i(l) = 2 / (3 l); measured up to 0.6% of it), one GL vertex per point
        q_gl, q_model = got * 6 * lv, model * 6 * lv
        assert np.abs(q_gl - np.rint(q_gl)).max() < 0.05 * 4, f"level {lv}: a GL vertex is off the ring model"
        key = lambda q: np.unique(np.rint(q).astype(np.int64), axis=0)  # noqa: E731
        assert key(q_gl).shape[0] == n and np.array_equal(key(q_gl), key(q_model)), f"level {lv}: GL and ring model differ"


@pytest.mark.parametrize("lv", range(1, 65))
def test_l_packing_is_a_bijection_and_decodes_its_samples(lv: int) -> None:
    """Every texel of the three ``D(l) x D(l)`` tip blocks holds exactly one sample (odd levels leave one corner
    unused), every sample lands somewhere, and the client's decode of a sample's barycentrics finds it."""
    B = tess_coords(lv)
    D = int(tip_dim(lv))
    pos = lp_positions(B, lv)
    count = np.zeros((3, D, D), int)
    for _, t, x, y in pos:
        count[t, y, x] += 1
    expect = np.ones((3, D, D), int)
    if lv % 2:
        expect[:, D - 1, D - 1] = 0
    assert (count == expect).all(), np.argwhere(count != expect)[:5]
    assert {i for i, *_ in pos} == set(range(len(B)))
    t, x, y = lp_lookup(B, lv)
    own = {(i, tt, xx, yy) for i, tt, xx, yy in pos}
    assert all((i, int(t[i]), int(round(x[i])), int(round(y[i]))) in own for i in range(len(B)))


def test_l_packing_reconstructs_linear_shading_closely() -> None:
    """Bilinear taps in the tip blocks reproduce a linear function of the barycentrics; the error falls with
    the level (measured max |error| for a function of range 3.7: 0.25 at l = 2, 0.13 at 4, 0.029 at 16, 0.0072 at 64)."""
    rng = np.random.default_rng(0)
    c = np.array([0.3, 1.7, -2.0])
    errs = {}
    for lv in (2, 4, 16, 64):
        B = tess_coords(lv)
        D = int(tip_dim(lv))
        img = np.zeros((3, D, D))
        for i, t, x, y in lp_positions(B, lv):
            img[t, y, x] = B[i] @ c
        P = rng.dirichlet([1, 1, 1], 4000)
        t, x, y = lp_lookup(P, lv)
        x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
        fx, fy = x - x0, y - y0
        x1, y1 = np.minimum(x0 + 1, D - 1), np.minimum(y0 + 1, D - 1)
        v = (img[t, y0, x0] * (1 - fx) * (1 - fy) + img[t, y0, x1] * fx * (1 - fy) + img[t, y1, x0] * (1 - fx) * fy
             + img[t, y1, x1] * fx * fy)
        errs[lv] = float(np.abs(v - P @ c).max())
    assert errs[2] < 0.3 and errs[4] < 0.15 and errs[16] < 0.035 and errs[64] < 0.009, errs
    assert errs[2] > errs[4] > errs[16] > errs[64]


@pytest.mark.parametrize("lv", [1, 2, 3, 4, 5, 8, 9, 16, 33, 63, 64])
def test_l_packing_reconstruction_is_exact_for_linear_shading(lv: int) -> None:
    """The client's L-packing decode (``layout.lp_reconstruct``, mirrored by ``shaders/client.frag``) reproduces a
    linear function of the barycentrics to rounding at every level.  One bilinear tap everywhere, as before, was off
    on every diagonal cell of a tip block (its fourth texel is the mirrored side's sample, a third of a sample step
    away) and in the innermost ring of odd levels: max error 0.25 at l = 2, 0.33 at 3, 0.062 at 8, 0.031 at 16 for a
    function of range 3.7 (measured; on the duck and the default scene lossless, still, 320x180, the rendered
    difference was within +-0.1 dB: the affected cells are smooth shading)."""
    rng = np.random.default_rng(1)
    c = np.array([0.3, 1.7, -2.0])
    B = tess_coords(lv)
    D = int(tip_dim(lv))
    img = np.full((3, D, D), np.nan)
    for i, t, x, y in lp_positions(B, lv):
        img[t, y, x] = B[i] @ c
    img = np.nan_to_num(img)      # never read with a weight (the odd levels' empty corner)
    P = np.concatenate([rng.dirichlet([1, 1, 1], 4000), B])
    err = np.abs(lp_reconstruct(img, P, lv) - P @ c)
    assert err.max() < 1e-9, (lv, err.max())
    rgb = np.repeat(img[..., None], 3, axis=3)              # trailing channels ride along
    assert np.allclose(lp_reconstruct(rgb, P[:50], lv)[:, 1], P[:50] @ c)


@pytest.mark.parametrize("lv", [1, 3, 5, 9, 33, 63])
def test_the_empty_corner_of_odd_levels_is_never_read(lv: int) -> None:
    """Odd levels leave each tip block's far corner ``(D - 1, D - 1)`` without a sample; the gathering stage copies
    its neighbour there (a black texel inside a block cost the codec bits and bled into its 4:2:0 chroma: on the
    default scene the atlas took 14% fewer bits for 0.08 dB more), which is safe only because no bilinear tap of
    the client's decode ever weighs that texel."""
    D = int(tip_dim(lv))
    P = np.random.default_rng(lv).dirichlet([1, 1, 1], 20000)
    _, x, y = lp_lookup(np.concatenate([P, tess_coords(lv)]), lv)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    weight = np.zeros(x.size)
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        weight += np.where((np.minimum(x0 + dx, D - 1) == D - 1) & (np.minimum(y0 + dy, D - 1) == D - 1), w, 0.0)
    assert weight.max() == 0.0


@pytest.mark.parametrize("px", [1, 2, 4])
def test_single_texel_cells_tile_the_shelf_in_z_order_on_the_chroma_grid(px: int) -> None:
    """Single-texel cells: every slot of two shelves gets its own ``px`` x ``px`` cell inside its shelf's tile row,
    on multiples of ``px`` (a 2 x 2 cell is one 4:2:0 chroma sample), and four consecutive slots from a multiple of
    four form a square (Z order: slots next in id order, mostly mesh neighbours, share a chroma
    block and a transform block instead of lying a strip apart)."""
    strip = 128
    shelves = np.array([[128, 32], [0, 48]])
    per = single_per_shelf(strip, px)
    assert per == (strip // SINGLE_TILE) * (SINGLE_TILE // px) ** 2
    o = single_origins(np.arange(2 * per), shelves, strip, px)
    assert np.unique(o, axis=0).shape[0] == 2 * per and (o % px == 0).all()
    sh = shelves[np.arange(2 * per) // per]
    assert ((o >= sh) & (o + px <= sh + [strip, SINGLE_TILE])).all()
    quad = o[:4 * (per // 4)].reshape(-1, 4, 2)
    assert (quad.max(axis=1) - quad.min(axis=1) == px).all()


def test_morton_order_keeps_neighbours_close() -> None:
    """Triangle ids along a 3D Z-order curve of their centroids: on a 64 x 64 grid of points, consecutive ids are
    1.64 grid steps apart on average (measured), in the shuffled order 33."""
    g = np.stack(np.meshgrid(np.arange(64.0), np.arange(64.0), [0.0]), -1).reshape(-1, 3)
    g = g[np.random.default_rng(0).permutation(g.shape[0])]
    step = lambda p: float(np.linalg.norm(np.diff(p, axis=0), axis=1).mean())  # noqa: E731
    o = morton_order(g)
    assert sorted(o.tolist()) == list(range(g.shape[0]))
    assert step(g[o]) < 1.8 and step(g) > 30.0


def test_geometry_round_trips_within_the_16_bit_grid_and_codes_are_checked() -> None:
    """The ``geo`` payload (wire version 4): shared vertices quantised to 16 bits in their object's box, each sent
    once per payload; the decode gives the snapped corners back exactly (the server draws the snapped mesh too), and
    a vertex code reaching past the vertices introduced so far is refused by name."""
    from splitrender.methods.tss.wire import TssWireError, decode_geometry, dequantize_positions, encode_geometry, quantize_positions

    rng = np.random.default_rng(1)
    box = np.array([[[-1.0, 0.0, 2.0], [3.0, 0.5, 2.25]], [[0.0, 0.0, 0.0], [10.0, 10.0, 10.0]]], np.float32)
    verts = [rng.uniform(box[k, 0], box[k, 1], (40, 3)).astype(np.float32) for k in range(2)]
    vq = np.concatenate([quantize_positions(v, box[k]) for k, v in enumerate(verts)])
    tri_vertex = np.concatenate([rng.integers(0, 40, (30, 3)), 40 + rng.integers(0, 40, (25, 3))])
    tri_base = np.array([0, 30])
    ids = np.sort(rng.choice(55, 33, replace=False))
    buf = encode_geometry(ids, tri_vertex, vq)
    g = decode_geometry(buf, 55, tri_base, box)
    obj = (ids >= 30).astype(int)
    assert np.array_equal(g.ids, ids) and np.array_equal(g.obj, obj)
    assert np.array_equal(g.pos, dequantize_positions(vq[tri_vertex[ids]], box[obj][:, None]))
    assert np.abs(g.pos - np.concatenate(verts)[tri_vertex[ids]]).max() < 10.0 / 65535
    head = 10 + 4 * ids.size + 6 * int(struct.unpack("<I", buf[5:9])[0])
    with pytest.raises(TssWireError, match=r"^tss geo: vertex code 1 at corner 0 refers to a vertex not yet introduced$"):
        decode_geometry(buf[:head] + struct.pack("<H", 1) + buf[head + 2:], 55, tri_base, box)


def _wire_payloads() -> tuple[bytes, bytes, dict]:
    """A ``tris`` table of every kind and a ``geo`` payload built without GL (synthetic triangles), and what the
    decoders need to check them."""
    from splitrender.methods.tss.layout import KIND_LP, KIND_OS, KIND_SINGLE, StableAtlas, plan_atlas
    from splitrender.methods.tss.wire import descriptors, encode_geometry, encode_table, quantize_positions

    rng = np.random.default_rng(7)
    n = 60
    ids = np.sort(rng.choice(200, n, replace=False))
    kind = np.array([KIND_SINGLE, KIND_LP, KIND_OS] * (n // 3))
    level = rng.integers(1, 12, n)
    w1, w2, h = rng.integers(1, 9, n), rng.integers(1, 9, n), rng.integers(1, 5, n)
    store = StableAtlas(200, 1152, 576, single_px=2)
    plan = plan_atlas(store, ids, kind, level, w1, w2, h, rng.uniform(0, 1, n))
    tris = encode_table(ids, plan, descriptors(plan, rng.uniform(0, 1, n) < 0.8, rng.integers(0, 3, n)))
    box = np.array([[[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]], [[-5.0, -5.0, -5.0], [5.0, 5.0, 5.0]]], np.float32)
    vq = quantize_positions(rng.uniform(0, 1, (120, 3)).astype(np.float32), box[0])
    geo = encode_geometry(ids, rng.integers(0, 120, (200, 3)), vq)
    return tris, geo, {"n": 200, "atlas": (1152, 576), "strip": store.strip, "tri_base": np.array([0, 100]), "box": box}


def _decodes_or_names_the_error(tris: bytes | None, geo: bytes | None, ctx: dict) -> None:
    from splitrender.methods.tss.wire import TssWireError, decode_geometry, decode_table

    for payload, decode in ((tris, lambda b: decode_table(b, ctx["n"], ctx["atlas"], ctx["strip"], "paper")),
                            (geo, lambda b: decode_geometry(b, ctx["n"], ctx["tri_base"], ctx["box"]))):
        if payload is None:
            continue
        try:
            decode(payload)
        except TssWireError:
            pass


def test_every_prefix_of_a_table_or_geometry_parses_or_raises_a_wire_error() -> None:
    """The h11 rule for the binary payloads: fed one byte at a time, every prefix either decodes or raises
    :class:`TssWireError` (never an IndexError or a numpy error), and the whole payloads decode."""
    from splitrender.methods.tss.wire import decode_geometry, decode_table

    tris, geo, ctx = _wire_payloads()
    assert decode_table(tris, ctx["n"], ctx["atlas"], ctx["strip"], "paper")[0].ids.size == 60
    assert decode_geometry(geo, ctx["n"], ctx["tri_base"], ctx["box"]).ids.size == 60
    for k in range(max(len(tris), len(geo))):
        _decodes_or_names_the_error(tris[:k] if k < len(tris) else None, geo[:k] if k < len(geo) else None, ctx)


@given(which=st.sampled_from(["tris", "geo"]), at=st.floats(0.0, 1.0), value=st.integers(0, 255), runs=st.integers(1, 8))
@settings(max_examples=300, deadline=None)
def test_mutated_tables_and_geometry_parse_or_raise_a_wire_error(which: str, at: float, value: int, runs: int) -> None:
    """Bytes of a valid payload overwritten (``runs`` bytes from a position): it decodes or raises TssWireError."""
    tris, geo, ctx = _wire_payloads()
    buf = bytearray(tris if which == "tris" else geo)
    i = int(at * (len(buf) - 1))
    buf[i:i + runs] = bytes([value]) * len(buf[i:i + runs])
    _decodes_or_names_the_error(bytes(buf) if which == "tris" else None, bytes(buf) if which == "geo" else None, ctx)


@pytest.mark.parametrize("lv", [1, 2, 3, 8, 33, 64])
def test_oversampling_thread_ids_are_consecutive(lv: int) -> None:
    """The linear thread id of the tessellator's vertices is a bijection onto ``0 .. v(l) - 1``."""
    ids = os_linear_id(tess_coords(lv), lv)
    assert sorted(ids.tolist()) == list(range(int(v_count(lv))))


def test_oversampling_staircases_interlock_and_reconstruct_linear_shading_exactly() -> None:
    """Two right-triangle staircases share one rectangle without overlap; every bilinear tap of a point in the
    triangle reads a written texel, and a linear function is reconstructed exactly (orthogonal grids)."""
    rng = np.random.default_rng(3)
    c = np.array([0.2, -1.1, 2.5])
    for _ in range(60):
        w1, w2, h = (int(v) for v in rng.integers(1, 30, 3))
        a = float(rng.uniform(0.0, 1.0))
        pw, ns = os_sizes(np.array([w1]), np.array([w2]), np.array([h]))
        pw, ns = int(pw[0]), int(ns[0])
        img = np.full((h + 1, pw), np.nan)
        written = 0
        for hf, w in ((0, w1), (1, w2)):
            for j, L in enumerate(os_row_lengths(w, h).tolist()):
                x = np.arange(L)
                B = os_sample_bary(x.astype(float), np.full(L, float(j)), np.full(L, hf), np.full(L, w1), np.full(L, w2),
                                   np.full(L, h), np.full(L, a))
                cols, row = (x, j) if hf == 0 else (pw - 1 - x, h - j)
                assert np.isnan(img[row, cols]).all(), "the staircases overlap"
                img[row, cols] = B @ c
                written += L
        assert written == ns
        P = rng.dirichlet([1, 1, 1], 300)
        xy = os_lookup(P, np.full(300, w1), np.full(300, w2), np.full(300, h), np.full(300, a), np.full(300, pw))
        x0, y0 = np.floor(xy[:, 0]).astype(int), np.floor(xy[:, 1]).astype(int)
        fx, fy = xy[:, 0] - x0, xy[:, 1] - y0
        tap = lambda yy, xx, wt: np.where(wt > 1e-9, img[np.clip(yy, 0, h), np.clip(xx, 0, pw - 1)], 0.0) * wt  # noqa: E731
        v = tap(y0, x0, (1 - fx) * (1 - fy)) + tap(y0, x0 + 1, fx * (1 - fy)) + tap(y0 + 1, x0, (1 - fx) * fy) + tap(y0 + 1, x0 + 1, fx * fy)
        assert not np.isnan(v).any(), f"a tap read an unwritten texel (w1={w1}, w2={w2}, h={h})"
        np.testing.assert_allclose(v, P @ c, atol=1e-9)


def test_centred_staircases_interlock_and_reconstruct_linear_shading_inside_their_samples() -> None:
    """The centred grid: two staircases share one rectangle of ``h`` rows without overlap; every tap the client
    takes reads a written texel; a linear function is reconstructed exactly between sample centres (beyond a
    row's last sample the taps clamp, holding the shading constant); and it takes fewer samples than the
    paper's lattice."""
    rng = np.random.default_rng(4)
    c = np.array([0.2, -1.1, 2.5])
    for _ in range(60):
        w1, w2, h = (int(v) for v in rng.integers(1, 30, 3))
        a = float(rng.uniform(0.05, 0.95))
        pw, ns = (int(v[0]) for v in os_sizes(np.array([w1]), np.array([w2]), np.array([h]), "centred"))
        assert ns < int(os_sizes(np.array([w1]), np.array([w2]), np.array([h]))[1][0])
        img = np.full((h, pw), np.nan)
        written = 0
        for hf, w in ((0, w1), (1, w2)):
            for j, L in enumerate(os_row_lengths(w, h, "centred").tolist()):
                x = np.arange(L)
                B = os_sample_bary(x.astype(float), np.full(L, float(j)), np.full(L, hf), np.full(L, w1), np.full(L, w2),
                                   np.full(L, h), np.full(L, a), "centred")
                cols, row = (x, j) if hf == 0 else (pw - 1 - x, h - 1 - j)
                assert np.isnan(img[row, cols]).all(), "the staircases overlap"
                img[row, cols] = B @ c
                written += L
        assert written == ns
        full = lambda P: os_centred_taps(P, np.full(len(P), w1), np.full(len(P), w2), np.full(len(P), h),  # noqa: E731
                                         np.full(len(P), a), np.full(len(P), pw))
        P = rng.dirichlet([1, 1, 1], 300)
        tx, wt = full(P)
        vals = img[tx[..., 1], tx[..., 0]]
        assert not np.isnan(vals).any(), f"a tap read an unwritten texel (w1={w1}, w2={w2}, h={h})"
        np.testing.assert_allclose(wt.sum(1), 1.0)
        if h < 2:
            continue
        # points between sample centres: rows j0 and j0 + 1, columns inside the upper (shorter) row
        for hf, w in ((0, w1), (1, w2)):
            j0 = rng.integers(0, h - 1, 200)
            y = j0 + rng.uniform(0, 1, 200)                            # row coordinate (centres at integers)
            n_up = np.maximum((w * (h - j0 - 1) + h - 1) // h, 1)
            x = rng.uniform(0, 1, 200) * (n_up - 1)
            B = os_sample_bary(x, y, np.full(200, hf), np.full(200, w1), np.full(200, w2), np.full(200, h), np.full(200, a),
                               "centred")
            tx, wt = full(B)
            np.testing.assert_allclose((img[tx[..., 1], tx[..., 0]] * wt).sum(1), B @ c, atol=1e-9)


# ---------------------------------------------------------------------------- with the renderer
@pytest.fixture(scope="module")
def renderer():  # type: ignore[no-untyped-def]
    from splitrender.render.renderer import Renderer

    return Renderer()


def _server_frame(renderer, scene_name: str = "default+nogi", params: dict | None = None, t: float = 0.5,  # type: ignore[no-untyped-def]
                  intr: CameraIntrinsics = INTR, trace: str = "walk"):
    from splitrender.methods import get_method, make_config
    from splitrender.pipeline.direct import server_context
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    scene = get_scene(scene_name)
    spec = get_method("tss")
    cfg = make_config(spec.config, params or {})
    pose = get_trace(trace, scene=scene).pose_at(t)
    srv = spec.server_class(cfg, intr, scene, 30, None)
    ctx = server_context(scene, renderer, intr, pose, t_s=t)
    return srv, ctx, spec, cfg, scene, pose


def test_gathering_shades_exactly_the_planned_samples_deterministically(renderer) -> None:  # type: ignore[no-untyped-def]
    """The GPU's shading-call counter equals the plan's samples (v(l) per L-packed triangle, both staircases per
    oversampled one, one per tiny triangle); the same frame twice gives the same atlas and table."""
    srv, ctx, *_ = _server_frame(renderer)
    a = srv.produce(ctx)
    st = srv.stats()
    assert st["shaded"] == st["samples"] > 10_000
    assert st["lp_triangles"] > 0 and st["os_triangles"] > 0 and st["single_triangles"] > 0, st
    plan = srv.last_plan
    assert plan is not None and not plan.overflow and plan.level.max() <= 64
    b = srv.produce(ctx)
    assert np.array_equal(a.planes["atlas"], b.planes["atlas"]), "the same frame shades the same atlas"
    from splitrender.methods.tss.wire import decode_table

    s = srv.session_data()
    rows, gone = decode_table(a.data["tris"], s["n_triangles"], tuple(s["atlas"]), s["strip"])
    assert gone is None and rows.ids.size == st["pvs_triangles"], "the first frame: the full table"
    assert "tris" not in b.data, "no table message when nothing in it changed (the client keeps the stream's table)"
    assert "geo" not in b.data, "geometry is sent once (no message when no triangle is new)"


@pytest.mark.parametrize("grid,low,high", [("paper", 0.25, 0.35), ("centred", 0.06, 0.12)])
def test_conservative_oversampling_samples_at_the_papers_resolution(renderer, grid: str, low: float, high: float) -> None:  # type: ignore[no-untyped-def]
    """Paper section 4: the conservative samples "stay within 25 to 35%" (client renders at 1920x1080).  We read
    it as the oversampled samples outside their triangle on top of the frame's other samples.  Default scene,
    still camera, 1920x1080, planning only, at slantedness threshold 4 (the default, 16, oversamples 3.1k
    triangles here instead of 8k+).  The paper's lattice: 30.5% measured (46% of the oversampled samples alone;
    at 320x180, where slanted triangles are 1-3 px high, 78%).  Our centred grid: 8.7%."""
    from splitrender.methods.tss.layout import KIND_OS

    srv, ctx, *_ = _server_frame(renderer, params={"os_grid": grid, "slant_threshold": 4.0}, intr=CameraIntrinsics(1920, 1080, 60.0),
                                 trace="static")
    _, _, _, _, plan, _, _, rate, _ = srv.plan_view(ctx, True)
    assert rate == 1.0 and not plan.overflow
    os_ = plan.kind == KIND_OS
    assert os_.sum() > 5000, "the frame has slanted triangles to oversample"
    inside = float(((plan.w[os_] + plan.w2[os_]) * plan.h[os_] / 2.0).sum())
    extra = float(plan.samples[os_].sum()) - inside
    overhead = extra / (float(plan.samples.sum()) - extra)
    assert low <= overhead <= high, overhead


SAS_IDEAL = {"lossless": True, "fill_atlas": False, "atlas_filter": "bilinear", "atlas_mpix_1080p": 8.0, "inset_min_texels": 0}
"""sas at its ideal levels (as many texels as a patch covers pixels; ``fill_atlas`` off, or sas spends its whole atlas
budget), looked up bilinearly as tss's client does, in the paper's 8 Mpix atlas, every block side spanned (as tss's
triangles span their samples): the tss paper's comparison, quality against the samples each shades, with the same
reconstruction."""


def _still(shared_run, scene: str, method: str, params: dict, samples: bool = False, size: tuple[int, int] = (320, 180),  # type: ignore[no-untyped-def]
           duration_s: float = 0.3):
    """Mean PSNR of a still run over the ticks that show an update (and the mean samples per update); the runs
    being deterministic, each is made once a session (``shared_run``), tss and sas on one ground truth."""
    from splitrender.sim.runner import RunConfig

    res = shared_run(RunConfig(method=method, scene=scene, trace="static", network="ideal", duration_s=duration_s, width=size[0],
                               height=size[1], client_fps=30, flip_every=0, seed=0, method_params=params))
    got = (float(np.mean([f["psnr_db"] for f in res.frames if f["update_frame_id"] >= 0])),
           float(np.mean([u["srv_samples"] for u in res.updates])))
    return got if samples else got[0]


@pytest.mark.slow
@pytest.mark.parametrize("scene,holds", [("default+nogi", False), ("minimal", True)])
def test_zero_latency_lossless_tss_beats_sas_with_fewer_samples(shared_run, scene: str, holds: bool) -> None:  # type: ignore[no-untyped-def]
    """The paper's claim, at defaults: still camera, zero latency, lossless atlases, 640x360, 0.1 s (the three
    updates shown after the start-up tick; the still view's frames are near alike).  Measured (tss / sas):
    ``minimal`` 32.56 dB from 126.4k samples / 32.25 dB from 148.4k block texels.  On the default scene it held
    (31.27 dB from 336.0k / 31.03 dB from 367.9k) until sas stopped growing a triangle across the edge it shares
    with the other triangles of its patch (issue 49): the later triangle's extrapolation overwrote the earlier
    one's texels within 1.5 texels of their diagonal, most of a small block; sas now scores 32.22 dB from the same
    367.9k texels, 0.95 dB ahead of tss, which still shades fewer samples.  Before that, over 0.3 s, it held on
    the default scene from 480x270 up (31.51 / 188.6k against 31.09 / 201.8k; at 1280x720 32.56 dB / 1.23M against
    32.33 / 1.55M), not at 320x180 (30.08 / 85.8k against 31.24 / 87.9k), where most triangles are a few pixels
    across.  With the paper-like slantedness threshold of 4 it fails on
    samples (31.98 dB from 479.7k at 640x360): the oversampled staircases spend their samples worse than
    L-packing, hence the default of 16.  At the paper's count (``lp_own = False``): ``lp_own``, the default since
    issue 50, shades more samples where triangles are small and leads ``sas`` on both scenes, but not with fewer
    samples (measured: default 33.25 dB from 432.8k against 32.22 from 367.9k; minimal 34.90 from 157.8k against
    32.25 from 148.4k)."""
    tss, n_tss = _still(shared_run, scene, "tss", {"lossless": True, "lp_own": False}, samples=True, size=(640, 360),
                        duration_s=0.1)
    sas, n_sas = _still(shared_run, scene, "sas", SAS_IDEAL, samples=True, size=(640, 360), duration_s=0.1)
    assert (tss >= sas) == holds and n_tss <= n_sas, (tss, n_tss, sas, n_sas)


DUCK = "/usr/share/assimp/models/Collada/duck.dae"


@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists(DUCK), reason=f"{DUCK} absent (Debian's assimp-testmodels)")
def test_a_fine_mesh_survives_a_lossy_atlas(shared_run) -> None:  # type: ignore[no-untyped-def]
    """Issue 33: on a fine mesh nearly every visible triangle is one texel, and 4:2:0 H.264 mixed the colours of
    unrelated neighbours.  assimp's duck split fine at load (``split_near_m = 0.0483``: 191k triangles, 14.3k in view,
    all single texels; the split every method made of the duck until the bound was taken into each object's own
    units, the duck being placed at 1/41 scale), still camera, zero latency, 320x180, 1 s: tss scored 28.43 dB at
    3504 kbit/s, 43.64 with a lossless atlas, sas 39.17 at 3110.  Single texels now fill 2 x 2 cells (one chroma
    sample each; the client reads their mean) along a Z-order curve in tiles of 16 x 16 texels, and geometry and
    slots go compactly: 42.96 dB at 1865 kbit/s over 1 s (lossless 44.12; with one texel per triangle 38.58 dB, along
    rows as before 29.93; ``benchmarks/bench_tss_fine.py``).  Here 0.3 s, the ticks showing an update (measured: tss
    43.27 dB at 4358 kbit/s, lossless 44.84, sas 39.98 at 5733; the geometry, sent once, weighs more in a short run).
    The issue's target: within 2 dB of the lossless atlas, within 1 dB of sas, at no more of sas's bits; asserted
    closer to what was measured.  Every run's summary carries the region scores (model 34.44, interior 37.20, edge
    29.58 dB for tss here).  At the duck's own scale (4.2k triangles, none split) tss gives 38.38 dB at 1167
    kbit/s, lossless 40.46, sas 43.43 at 1412: see the bench for why."""
    from splitrender.sim.runner import RunConfig

    fine = {"split_near_m": 0.0483}
    summaries = {}

    def still(method: str, params: dict) -> tuple[float, float]:
        res = shared_run(RunConfig(method=method, scene=DUCK, trace="static", network="ideal", duration_s=0.3, width=320,
                                   height=180, client_fps=30, flip_every=0, seed=0, method_params={**params, **fine}))
        summaries[(method, params.get("lossless", False))] = res.summary
        return (float(np.mean([f["psnr_db"] for f in res.frames if f["update_frame_id"] >= 0])),
                float(res.summary["mean_kbps"]))

    (lossy, kbps), (lossless, _), (sas, sas_kbps) = still("tss", {}), still("tss", {"lossless": True}), still("sas", {})
    for key, s in summaries.items():
        regions = {r: s.get(f"mean_{r}_psnr_db") for r in ("model", "interior", "edge")}
        assert all(v is not None and 20.0 < v < 60.0 for v in regions.values()), (key, regions)
        assert s["mean_interior_psnr_db"] > s["mean_edge_psnr_db"], (key, regions)   # the outline is where it goes wrong
    assert lossy >= lossless - 1.7 and lossy >= sas + 2.5 and kbps <= 0.85 * sas_kbps, (lossy, kbps, lossless, sas, sas_kbps)


@pytest.mark.slow
@pytest.mark.parametrize("scene,least,behind", [("default+nogi", 30.8, 1.1), ("minimal", 30.2, 0.3)])
def test_at_320x180_the_oversampling_mix_is_level_with_sas(shared_run, scene: str, least: float, behind: float) -> None:  # type: ignore[no-untyped-def]
    """Still camera, zero latency, lossless atlases, 320x180, slantedness threshold 4 (the paper's mix of
    L-packing and oversampling; tss / sas, dB): default 31.09 / 32.00, minimal 30.48 / 30.61.  Before sas took
    its texture gradients per atlas texel from the reference view (it used one level per patch, aliasing far
    floor texels) tss led by 1.9 and 2.6 dB; then the two were level (default 31.09 / 31.24) until sas stopped
    growing a triangle across the edge it shares with its patch's other triangles (issue 49: the later one's
    extrapolation overwrote the earlier one's texels near their diagonal), which put sas 0.91 dB ahead on the
    default scene (its curved objects; ``minimal`` is boxes); tss shades more samples here (138k against 88k
    block texels on the default scene; its oversampled staircases are mostly conservative samples at this size)."""
    mix = {"lossless": True, "slant_threshold": 4.0, "lp_own": False}     # the paper's count
    tss = _still(shared_run, scene, "tss", mix)
    sas = _still(shared_run, scene, "sas", SAS_IDEAL)
    assert tss >= sas - behind and tss >= least, (tss, sas)
    if scene == "default+nogi":
        # the centred grid shades fewer samples for a better image: the lattice at 1 sample per pixel 31.09 dB from
        # 137.9k samples, the centred grid at 1.35 samples per pixel 31.25 dB from 120.7k (at 1 per pixel 29.89 dB
        # from 91.5k); sas 32.00 dB from 87.9k block texels
        paper, n_paper = _still(shared_run, scene, "tss", mix, samples=True)
        centred, n_centred = _still(shared_run, scene, "tss", {**mix, "os_grid": "centred", "samples_per_px": 1.35},
                                    samples=True)
        assert centred >= paper + 0.05 and n_centred <= 0.9 * n_paper, (centred, n_centred, paper, n_paper)


@pytest.mark.slow
def test_l_packing_alone_beats_sas_with_fewer_samples_on_the_minimal_scene(shared_run) -> None:  # type: ignore[no-untyped-def]
    """The paper's claim holds for L-packing: still camera, zero latency, lossless, 320x180, ``minimal``, every
    triangle L-packed at 1.15 samples per pixel: 32.21 dB from 36.1k samples against sas's 30.58 dB from 39.8k
    block texels.  It does not hold for the paper-like mix (threshold 4, oversampling the slanted triangles, whose staircases
    are mostly conservative samples at this size: 30.48 dB from 54.5k), nor on the default scene (L-packing at
    85.8k samples 30.85 dB against sas's 31.19 from 87.8k)."""
    tss, n_tss = _still(shared_run, "minimal", "tss", {"lossless": True, "slant_threshold": 1000.0, "samples_per_px": 1.15,
                                                       "lp_own": False}, samples=True)     # the paper's count
    sas, n_sas = _still(shared_run, "minimal", "sas", SAS_IDEAL, samples=True)
    assert n_tss <= n_sas and tss >= sas + 1.2, (tss, n_tss, sas, n_sas)


def test_slivers_get_samples_along_their_length(renderer) -> None:  # type: ignore[no-untyped-def]
    """With ``sliver_px`` set, a triangle under ``tiny_samples`` keeps one texel only while its longest edge is
    shorter than that; the far floor's tile triangles (8 px long, a quarter pixel high at 320x180) were shown as
    one colour along their length.  Default walk frame: 888 such slivers with one texel, 6 with the option (they
    reach out of the view, and the part inside is shorter)."""
    from splitrender.methods.tss.layout import KIND_SINGLE

    counts = {}
    for sliver in (0.0, 3.0):
        srv, ctx, *_ = _server_frame(renderer, params={"sliver_px": sliver})
        pvs, _, px, _, plan, *_ = srv.plan_view(ctx, True)
        longest = np.linalg.norm(np.roll(px, -1, axis=1) - px, axis=2).max(axis=1)
        single = plan.kind == KIND_SINGLE
        counts[sliver] = int((single & (longest >= 3.0)).sum())
    assert counts[0.0] > 600 and counts[3.0] <= 10, counts


def _client(renderer, srv, spec, cfg):  # type: ignore[no-untyped-def]
    return spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())


def test_malformed_tables_and_geometry_give_named_errors_and_keep_the_shown_state(renderer) -> None:  # type: ignore[no-untyped-def]
    from splitrender.methods import DecodedUpdate
    from splitrender.methods.tss.wire import OS_DTYPE, WIRE_VERSION, TssWireError

    srv, ctx, spec, cfg, scene, pose = _server_frame(renderer)
    upd = srv.produce(ctx)
    cli = _client(renderer, srv, spec, cfg)
    good = DecodedUpdate(upd.frame_id, upd.t_s, upd.pose, upd.planes, upd.meta, upd.data)
    cli.apply(good)
    shown = cli.render(pose, ctx.t_s).color
    table = cli.table
    tris, geo = upd.data["tris"], upd.data["geo"]
    n0, n1, n2, nb = struct.unpack("<IIIH", tris[3:17])
    os_off = len(tris) - 16 * n2
    rec = np.frombuffer(tris[os_off:], OS_DTYPE).copy()
    far = rec.copy()
    far["x"][0] = 65000
    narrow = rec.copy()
    narrow["pw"][0] = 1
    flags = rec.copy()
    flags["flags"][0] = 0x80
    lp_slots = os_off - 4 * n1                            # n1 level bytes, then n1 u32 zigzag slot deltas
    lp_levels = lp_slots - n1
    lp_ids = lp_levels - 4 * (n0 + n2 + n1)                # n1 u32 L-packing ids after the single texels' ids
    assert n1 >= 2
    far_slot = struct.pack("<I", 2 * 0xFFFFF)              # the first slot far beyond its level's bin
    below = struct.pack("<I", 1)                           # the first slot -1
    gv, gn, gnv, gwide = struct.unpack("<BIIB", geo[:10])
    codes = 10 + 4 * gn + 6 * gnv                          # header, ids, vertex deltas, then the vertex codes
    assert gn >= 2 and gwide == 0
    cases = [
        ({"tris": tris[:-3]}, r"^tss tris: truncated at os descriptors"),
        ({"tris": tris + b"\0"}, r"^tss tris: 1 bytes after the end$"),
        ({"tris": b"\x07" + tris[1:]}, rf"^tss tris: version 7, this client speaks {WIRE_VERSION}$"),
        ({"tris": tris[:1] + b"\x05" + tris[2:]}, r"^tss tris: full flag 5 is not 0 or 1$"),
        ({"tris": tris[:2] + b"\x03" + tris[3:]}, r"^tss tris: single-texel cell side 3 is not one of \[1, 2, 4\]$"),
        ({"tris": struct.pack("<BBBII", WIRE_VERSION, 0, 2, 1, 0) + tris[3:]}, r"^tss tris: 1 triangles leave that were not live$"),
        ({"tris": struct.pack("<BBBI", WIRE_VERSION, 0, 1, 0) + tris[3:]},
         r"^tss tris: a delta table changes the single-texel cell side from 2 to 1$"),
        ({"tris": tris[:os_off] + far.tobytes()}, r"^tss tris: an oversampling rectangle reaches outside the \d+x\d+ atlas$"),
        ({"tris": tris[:os_off] + narrow.tobytes()}, r"^tss tris: an oversampling rectangle is narrower than its two staircases$"),
        ({"tris": tris[:os_off] + flags.tobytes()}, r"^tss tris: oversampling descriptor with reserved flags"),
        ({"tris": tris[:lp_slots] + far_slot + tris[lp_slots + 4:]},
         r"^tss tris: level-\d+ slot 1048575 outside its bin of \d+ shelves \(\d+ slots\)$"),
        ({"tris": tris[:lp_slots] + below + tris[lp_slots + 4:]}, r"^tss tris: level-\d+ slot -1 outside its bin"),
        ({"tris": tris[:lp_levels] + b"\x80" + tris[lp_levels + 1:]}, r"^tss tris: L-packing level byte with its reserved bit set$"),
        # the L-packing ids (slot order, zigzag differences): the first far beyond the scene, the second equal to the first
        ({"tris": tris[:lp_ids] + struct.pack("<I", 2 * 0x7FFFFFF) + tris[lp_ids + 4:]},
         r"^tss tris lp ids: id \d+ is not in 0 \.\. \d+ \(the scene's triangles\)$"),
        ({"tris": tris[:lp_ids + 4] + struct.pack("<I", 0) + tris[lp_ids + 8:]}, r"^tss tris lp ids: triangle \d+ listed twice$"),
        ({"tris": tris[:lp_levels - 4 * n0] + below + tris[lp_levels - 4 * n0 + 4:]},
         r"^tss tris: single-texel slot -1 outside its \d+ shelves \(\d+ slots\)$"),
        ({"geo": geo[:-1]}, r"^tss geo: truncated at vertex codes"),
        ({"geo": geo[:10 + 4] + struct.pack("<I", 0) + geo[18:]}, r"^tss geo ids: id differences must be >= 1"),
        ({"geo": geo[:codes] + struct.pack("<H", 5) + geo[codes + 2:]},
         r"^tss geo: vertex code 5 at corner 0 refers to a vertex not yet introduced$"),
        ({"geo": geo[:1] + struct.pack("<II", gn, 3 * gn + 1) + geo[9:]}, rf"^tss geo: {3 * gn + 1} new vertices for {gn} triangles"),
    ]
    for patch, msg in cases:
        bad = DecodedUpdate(upd.frame_id, upd.t_s, upd.pose, upd.planes, upd.meta, {**upd.data, **patch})
        with pytest.raises(TssWireError, match=msg):
            cli.apply(bad)
        assert cli.table is table
    # a table naming triangles whose geometry never came
    fresh = _client(renderer, srv, spec, cfg)
    with pytest.raises(TssWireError, match=r"^tss tris: \d+ live triangles have no geometry$"):
        fresh.apply(DecodedUpdate(upd.frame_id, upd.t_s, upd.pose, upd.planes, upd.meta, {"tris": tris, "geo": struct.pack("<BIIB", WIRE_VERSION, 0, 0, 0)}))
    with pytest.raises(TssWireError, match=r"^tss metadata: xf: shape \(1, 4, 4\), expected \(\d+, 4, 4\)$"):
        cli.apply(DecodedUpdate(upd.frame_id, upd.t_s, upd.pose, upd.planes, {"v": WIRE_VERSION, "xf": np.zeros((1, 4, 4), "f4")}, upd.data))
    assert np.array_equal(cli.render(pose, ctx.t_s).color, shown), "the last good state stays on screen"
    sd0 = srv.session_data()
    box_nan = np.array(sd0["obj_box"], np.float32)
    box_nan[0, 1, 2] = np.nan
    for sd, msg in (({**sd0, "os_grid": "hex"}, r"^tss session data: os_grid: 'hex' is not one of \['centred', 'paper'\]$"),
                    ({k: v for k, v in sd0.items() if k != "os_grid"}, r"^tss session data: os_grid: missing$"),
                    ({**sd0, "v": 3}, rf"^tss session data: v: version 3, this client speaks {WIRE_VERSION}$"),
                    ({**sd0, "tri_base": np.array(sd0["tri_base"])[::-1].copy()}, r"^tss session data: tri_base: must be non-decreasing from 0$"),
                    ({**sd0, "obj_box": box_nan}, r"^tss session data: obj_box: "),
                    ({**sd0, "tri_base": np.array(sd0["tri_base"])[:-1].copy()}, r"^tss session data: tri_base: ")):
        with pytest.raises(TssWireError, match=msg):
            spec.client_class(cfg, INTR, renderer.ctx, sd)


def test_a_missing_atlas_keeps_the_previous_table_and_takes_the_geometry(renderer) -> None:  # type: ignore[no-untyped-def]
    from splitrender.methods import DecodedUpdate

    srv, ctx, spec, cfg, scene, pose = _server_frame(renderer)
    upd = srv.produce(ctx)
    cli = _client(renderer, srv, spec, cfg)
    cli.apply(DecodedUpdate(upd.frame_id, upd.t_s, upd.pose, {}, upd.meta, upd.data, frozenset({"atlas"})))
    assert cli.table is None and not cli.has_content and cli.has.sum() == srv.stats()["pvs_triangles"]
    cli.apply(DecodedUpdate(upd.frame_id, upd.t_s, upd.pose, upd.planes, upd.meta, upd.data))
    assert cli.table is not None and cli.has_content


@pytest.mark.parametrize("layout", ["stable", "prefix"])
def test_delta_tables_give_the_client_the_servers_layout(renderer, layout: str) -> None:  # type: ignore[no-untyped-def]
    """Over a walk of P-frames (delta tables), the client's table equals the server's plan every frame; the
    per-frame layout moves shelves under unchanged descriptors (it showed 18.5 dB before origins were compared)."""
    import dataclasses

    from splitrender.methods import DecodedUpdate
    from splitrender.scene.trace import get_trace

    srv, ctx, spec, cfg, scene, pose = _server_frame(renderer, params={"layout": layout, "gop": 30})
    cli = _client(renderer, srv, spec, cfg)
    walk = get_trace("walk", scene=scene)
    moved, prev = 0, None
    for k in range(5):
        t = 0.5 + 0.1 * k
        p = walk.pose_at(t)
        c = dataclasses.replace(ctx, frame_id=k, t_s=t, latest_pose=p, latest_pose_t_s=t, target_pose=p, target_t_s=t,
                                predict=lambda _t, p=p: p)
        u = srv.produce(c)
        assert k == 0 or srv.stats()["iframe"] == 0.0
        cli.apply(DecodedUpdate(u.frame_id, u.t_s, u.pose, u.planes, u.meta, u.data))
        plan, ids = srv.last_plan, srv.last_ids
        order = np.argsort(ids)
        tab = cli.table
        assert np.array_equal(tab.ids, ids[order])
        assert np.array_equal(tab.origin, plan.origin[order]) and np.array_equal(tab.kind, plan.kind[order])
        if prev is not None:
            moved += int((plan.origin[order] != prev).any(axis=(1, 2)).sum()) if prev.shape == plan.origin.shape else 1
        prev = plan.origin[order]
    assert layout == "stable" or moved > 0, "the per-frame layout moves triangles"


@pytest.mark.parametrize("params,msg", [({"slant_threshold": 0.5}, "slant_threshold"), ({"samples_per_px": 0.0}, "samples_per_px"),
                                        ({"atlas_mpix_1080p": 100.0}, "atlas_mpix_1080p"), ({"tiny": 1}, "unknown parameter 'tiny'"),
                                        ({"os_grid": "hex"}, "os_grid: 'hex' is not one of"),
                                        ({"sliver_px": 0.5}, r"sliver_px: must be 0 \(off\) or in \[1, 10000\]"),
                                        ({"sliver_px": float("nan")}, "sliver_px: must be 0"),
                                        ({"os_min_rows": -1.0}, r"os_min_rows: must be in \[0, 64\]"),
                                        ({"os_min_step": float("nan")}, r"os_min_step: must be in \[0, 64\] pixels"),
                                        ({"lp_filter": "bicubic"}, "lp_filter: 'bicubic' is not one of")])
def test_nonsense_config_is_named(params: dict, msg: str) -> None:
    from splitrender.errors import ConfigError
    from splitrender.methods import get_method, make_config

    with pytest.raises(ConfigError, match=msg):
        make_config(get_method("tss").config, params)


@pytest.mark.slow
def test_tss_beats_atw_under_cloud_on_the_default_walk(shared_run) -> None:  # type: ignore[no-untyped-def]
    """Under ``cloud`` (50 +- 20 ms each way), 0.6 s of the default walk at 320x180: measured tss 23.30 dB, atw
    15.33 (7.97 dB ahead; tss 22.74 before issue 33's layout and level headroom).  Before them, over 1 s: tss 24.22
    dB from 111k samples per update (24.68 dB from 165k at slantedness threshold 4; 24.95 dB from 132k at
    threshold 16 and 1.3 samples per pixel), atw 16.86 dB, 7.36 dB ahead (sas 24.86 dB from 134k at its ideal
    levels, 25.24 dB from 153k filling its atlas); tss must keep 6 dB of that lead.
    The atw run is ``test_sas``'s on the walk, and the ground truth theirs (``shared_run``)."""
    from splitrender.sim.runner import RunConfig

    def psnr(method: str) -> float:  # noqa: F811
        res = shared_run(RunConfig(method=method, scene="default+nogi", trace="walk", network="cloud", duration_s=0.6, width=320,
                                   height=180, client_fps=30, flip_every=0, seed=0))
        return float(res.summary["mean_psnr_db"])

    tss, atw = psnr("tss"), psnr("atw")
    assert tss >= atw + 6.0, (tss, atw)


def _small_atlas_frame(renderer, mpix_1080p: float):  # type: ignore[no-untyped-def]
    """One default walk frame with an atlas of ``mpix_1080p``: the server, its stats, and the PSNR of what the
    client draws from it at the server's pose."""
    from splitrender.methods import DecodedUpdate
    from splitrender.metrics.image import psnr

    srv, ctx, spec, cfg, scene, pose = _server_frame(renderer, params={"atlas_mpix_1080p": mpix_1080p})
    upd = srv.produce(ctx)
    cli = _client(renderer, srv, spec, cfg)
    cli.apply(DecodedUpdate(upd.frame_id, upd.t_s, upd.pose, upd.planes, upd.meta, upd.data))
    truth = renderer.render(scene, ctx.t_s, pose, INTR).color
    return srv, srv.stats(), psnr(cli.render(pose, ctx.t_s).color, truth)


def test_a_visible_set_larger_than_the_atlas_lowers_the_rate_and_still_fits(renderer) -> None:  # type: ignore[no-untyped-def]
    """With an atlas a tenth of the default (2.4 MPix at 1080p, 352x176 here) the frame's sampling rate drops
    until the set fits (measured: rate 0.158, 23.09 dB against 31.99 dB with the full atlas; at the paper's count,
    ``lp_own = False``, the default until issue 50's lp_own: rate 0.249, 22.37 dB against 30.14; rate 0.269 when
    single texels took one texel instead of a 2 x 2 cell, 0.195 when the default slantedness threshold was 4 and more
    triangles were oversampled); what was planned is shaded, the client draws it."""
    srv, st, shown = _small_atlas_frame(renderer, 2.4)
    assert 0.13 < st["rate"] < 0.19 and st["shaded"] == st["samples"] and not srv.last_plan.overflow, st
    assert shown > 22.5


def test_a_visible_set_past_one_texel_each_leaves_the_smallest_triangles_out(renderer) -> None:  # type: ignore[no-untyped-def]
    """An atlas of 0.05 Mpix at 1080p (1.4k texels here) cannot hold the PVS even at one texel per triangle: the
    server raised an error (the session ended).  Now the triangles needing the most samples are kept, as many as
    fit, the rest are left out and counted, and the client draws what was sent (measured: 2048 kept, 4309 left
    out, 15.09 dB against 29.68 with the full atlas; a black frame scores 4.3 dB, the image's mean colour 11.8).
    Single texels drop from 2 x 2 cells to one texel here (with the cells, 512 kept)."""
    from splitrender.methods.tss.layout import KIND_SINGLE

    srv, st, shown = _small_atlas_frame(renderer, 0.05)
    assert 4000 < st["tris_left_out"] < 4600 and st["shaded"] == st["samples"] == st["pvs_triangles"], st
    assert (srv.last_plan.kind == KIND_SINGLE).all() and not srv.last_plan.overflow and srv.last_plan.single_px == 1
    assert shown > 14.5


def test_moving_budget_raises_the_rate_within_the_frames_samples(renderer) -> None:  # type: ignore[no-untyped-def]
    """``budget_px``: the frame's rate rises from ``samples_per_px`` while the plan's samples stay within
    ``budget_px`` per display pixel, and never falls below ``samples_per_px``; ``plan_samples`` (the bisection's
    count) is what the plan places.  Default scene, walk frame, 320x180 (measured with ``lp_own``, the default: budget
    3 -> rate 2^(2/8) = 1.19, 160.9k of 172.8k samples; budget 2 and 1 -> 1.0, whose 132.5k samples already pass
    them; at the paper's count: budget 3 -> 1.83, 165.2k; 2 -> 1.19, 107.0k; 1 -> 1.0, 85.9k)."""
    from splitrender.methods.tss.server import classify, plan_samples

    srv, ctx, *_ = _server_frame(renderer, params={"budget_px": 3.0})
    seen = {}
    budget_rate = srv.budget_rate

    def spy(px, visible):  # type: ignore[no-untyped-def]
        seen["visible"] = visible     # what the bisection counts with (lp_own's levels depend on it)
        return budget_rate(px, visible)

    srv.budget_rate = spy
    pvs, _, px, _, plan, _, _, rate, _ = srv.plan_view(ctx, True)
    assert 1.0 < rate <= 8.0 and float(plan.samples.sum()) <= 3.0 * 320 * 180, (rate, plan.samples.sum())
    c = srv.config
    k = classify(px, rate, c.slant_threshold, c.tiny_samples, seen["visible"], c.os_grid, c.sliver_px or math.inf,
                 lp_own=c.lp_own)
    assert abs(plan_samples(*k[:5], grid=c.os_grid) / float(plan.samples.sum()) - 1.0) < 0.1, "the count the bisection uses"
    srv, ctx, *_ = _server_frame(renderer, params={"budget_px": 1.0})   # the budget never lowers the rate
    assert srv.plan_view(ctx, True)[7] == 1.0
    knob = srv.config.adapt_knobs()[0]                                   # rate adaptation lowers the budget itself
    assert knob.name == "budget_px" and knob.levels == (1.0, 0.7, 0.5, 0.35), knob


def test_the_other_maps_are_filtered_for_the_display_like_the_albedo(renderer) -> None:  # type: ignore[no-untyped-def]
    """The gathering runs in tessellation and compute shaders, where ``texture()`` has no derivatives and reads a
    map's level 0: the albedo had its own gradients, but the normal, metallic-roughness, occlusion and emissive maps
    were read unfiltered.  The default scene's sign (a glyph panel, emissive) aliased: 26.4 dB on its pixels over a
    1 s still run, lossless at 2 samples per pixel, 26.2 at 6, against ``sas``'s 39.4 (helper-56, issue 50 part 1,
    ``docs/methods.md``).  They now take the albedo's gradients (``MAP_LOOKUP``).  One still frame, the atlas as shaded (no codec), 320x180, 2 samples per covered
    pixel: the sign measured 33.22 dB (25.73 before), the rest of the model 32.91 (the same)."""
    from splitrender.methods import DecodedUpdate

    srv, ctx, spec, cfg, scene, pose = _server_frame(renderer, params={"samples_per_px": 2.0}, trace="static")
    upd = srv.produce(ctx)
    cli = _client(renderer, srv, spec, cfg)
    cli.apply(DecodedUpdate(upd.frame_id, upd.t_s, upd.pose, upd.planes, upd.meta, upd.data))
    truth = renderer.render(scene, ctx.t_s, pose, INTR, ("color", "object_id"))
    got = cli.render(pose, ctx.t_s).color
    sign = truth.object_id == next(o.object_id for o in scene.objects if o.name == "sign")
    rest = (truth.object_id > 0) & ~sign
    assert sign.sum() > 1000, "the sign is in view"
    db = {k: 10.0 * np.log10(255.0 ** 2 / np.mean((got[m].astype(np.float64) - truth.color[m].astype(np.float64)) ** 2))
          for k, m in (("sign", sign), ("rest", rest))}
    assert db["sign"] >= 32.0 and db["rest"] >= 32.0, db


def _object_db(renderer, scene_name: str, params: dict, names: tuple[str, ...], min_px: int = 1000) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """One still frame (``static``, 0.5 s, 320x180), the atlas as shaded (no codec): PSNR on each named object."""
    from splitrender.methods import DecodedUpdate

    srv, ctx, spec, cfg, scene, pose = _server_frame(renderer, scene_name, params=params, trace="static")
    upd = srv.produce(ctx)
    cli = _client(renderer, srv, spec, cfg)
    cli.apply(DecodedUpdate(upd.frame_id, upd.t_s, upd.pose, upd.planes, upd.meta, upd.data))
    truth = renderer.render(scene, ctx.t_s, pose, INTR, ("color", "object_id"))
    got = cli.render(pose, ctx.t_s).color
    out = {}
    for name in names:
        m = truth.object_id == next(o.object_id for o in scene.objects if o.name == name)
        assert m.sum() > min_px, f"{name} is in view"
        out[name] = 10.0 * np.log10(255.0 ** 2 / np.mean((got[m].astype(np.float64) - truth.color[m].astype(np.float64)) ** 2))
    return out


TTT = "/usr/share/assimp/models/glTF2/textureTransform/TextureTransformTest.gltf"


@pytest.mark.skipif(not os.path.exists(TTT), reason="assimp-testmodels not installed")
def test_texture_gradients_follow_the_materials_uv_transform(renderer) -> None:  # type: ignore[no-untyped-def]
    """``shade()`` reads the maps at ``u_uv_transform * uv`` (KHR_texture_transform); the gathering's per-sample
    gradients were taken on the untransformed uv, so on TextureTransformTest's two quads scaled by 1.5 the mip level
    was 0.58 too fine and aliased.  Measured (helper-66, issue 50 part 1), one still frame, no codec, 4 samples per
    pixel: quad 0 42.89 -> 45.66 dB, quad 2 41.41 -> 45.29; the rotated quad 5 (lengths kept) 45.47 either way."""
    db = _object_db(renderer, TTT, {"samples_per_px": 4.0}, ("TextureTransformTest_0", "TextureTransformTest_2"))
    assert min(db.values()) >= 44.5, db


def test_slanted_textured_triangles_are_oversampled_where_l_packing_spaces_them_out(renderer) -> None:  # type: ignore[no-untyped-def]
    """L-packing puts ``l + 1`` samples along each edge: on a slanted triangle at its area's level they sit far apart
    along the longest edge (the default scene's brick pillars: 24 px strips at level 12, 2 px apart across the mortar
    lines, 0.25 px across the strip), and the texture aliases.  ``os_min_rows`` / ``os_min_step`` oversample a slanted
    triangle only where its height holds at least that many samples and L-packing would space them further than that
    many pixels: the thin railing (a third of a pixel high, one centred row) stays L-packed.  Measured (helper-66),
    default scene, one still frame, no codec, the moving budget at 3 per display pixel, split for 16 m: pillar0 29.92
    dB L-packed (``slant_threshold`` 1000) -> 37.65, the railing 46.75 -> 46.22 (25.91 with every slanted triangle
    oversampled on the centred grid), at 168k -> 165k samples."""
    base = {"budget_px": 3.0, "budget_max_spp": 16.0, "split_near_m": 16.0}
    db = _object_db(renderer, "default+nogi", {**base, "slant_threshold": 4.0, "os_grid": "centred", "os_min_rows": 2.0,
                                               "os_min_step": 1.5}, ("pillar0", "railing"))
    assert db["pillar0"] >= 36.5 and db["railing"] >= 45.0, db


def test_own_count_levels_give_small_triangles_their_own_samples(renderer) -> None:  # type: ignore[no-untyped-def]
    """A level-``l`` patch's outer ring (``3 l`` of its ``v(l)`` samples) lies on its edges, shared with its
    neighbours, so a mesh of 1-2 px triangles at level 1 is shaded at its vertices only (the default scene's torus:
    Gouraud on a gold specular).  ``lp_own`` chooses the level for the samples a patch holds for itself
    (:func:`~splitrender.methods.tss.layout.own_count`).  Measured (helper-74, issue 50 part 1), default scene, one
    still frame, no codec, the moving budget at 3 per display pixel, split for 16 m, slivers L-packed: torus 27.44 ->
    36.13 dB (``sas`` 36.75), back wall 36.09 either way, the model 34.67 -> 34.74 at 170k -> 162k samples (the rate
    2.38 -> 1.68: the left wall 36.74 -> 35.42)."""
    from splitrender.methods.tss.layout import level_for, level_for_own, own_count, v_count

    assert list(own_count(np.arange(1, 5))) == [0.5, 3.0, 6.5, 12.0]
    need = np.array([0.2, 1.0, 2.9, 3.0, 3.1, 74.9, 75.0, 75.1, 1e6])
    lv = level_for_own(need)
    assert (own_count(lv) >= np.minimum(need, own_count(64))).all() and (lv >= level_for(need)).all(), lv
    assert (lv == 1).sum() == 1 and lv[-1] == 64 and (own_count(np.maximum(lv - 1, 1))[1:-1] < need[1:-1]).all(), lv
    assert (v_count(lv) >= own_count(lv)).all()
    base = {"budget_px": 3.0, "budget_max_spp": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0, "sliver_px": 1.0}
    off = _object_db(renderer, "default+nogi", {**base, "lp_own": False}, ("torus", "back_wall"), min_px=300)
    on = _object_db(renderer, "default+nogi", {**base, "lp_own": True}, ("torus", "back_wall"), min_px=300)
    assert on["torus"] >= 35.0 and on["torus"] >= off["torus"] + 6.0, (off, on)
    assert on["back_wall"] >= off["back_wall"] - 0.5, (off, on)


@pytest.mark.skipif(not os.path.exists(TTT), reason="assimp-testmodels not installed")
def test_cubic_client_filter_reads_l_packed_textures_sharper(renderer) -> None:  # type: ignore[no-untyped-def]
    """Each side of a tip block's diagonal is an affine lattice, so the client can read it with a Catmull-Rom filter
    over 4x4 texels (``lp_filter = "cubic"``, each tap clamped to the block and the point's side), as ``sas``'s client
    reads its atlas, where one bilinear tap blurred the pre-filtered samples.  Measured (helper-74, issue 50 part 1),
    one still frame, no codec, 4 samples per covered pixel: TextureTransformTest's model 46.28 -> 48.19 dB (quad 0
    45.66 -> 47.35, quad 2 45.29 -> 47.62), the default scene 36.70 -> 36.84, the same samples."""
    names = ("TextureTransformTest_0", "TextureTransformTest_2", "TextureTransformTest_9")
    lin = _object_db(renderer, TTT, {"samples_per_px": 4.0}, names)
    cub = _object_db(renderer, TTT, {"samples_per_px": 4.0, "lp_filter": "cubic"}, names)
    assert all(cub[k] >= lin[k] + 1.2 for k in names) and min(cub.values()) >= 47.0, (lin, cub)
