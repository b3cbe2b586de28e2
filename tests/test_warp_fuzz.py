"""Fuzzing the ``warp`` client with mutated metadata: every update either applies (and then renders)
or raises :class:`WarpMetaError`, a ``RemoteProtocolError``; nothing else escapes."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from splitrender.codecs.meta import pack_meta, unpack_meta
from splitrender.errors import RemoteProtocolError
from splitrender.methods.base import DecodedUpdate
from splitrender.methods.warp import WarpClient, WarpConfig, WarpMetaError, WarpServer
from splitrender.pipeline.direct import server_context
from splitrender.scene.pose import CameraIntrinsics, Pose
from splitrender.scene.procedural import default_scene

INTR = CameraIntrinsics(64, 36, 60.0)
START = Pose(np.array([0.0, 1.6, 2.5]))
T_REF = 1.4  # the ball is in view and moving, so dyn_ids / dyn_prev are not empty
TOP_KEYS = ("v", "depth_coding", "depth_near_m", "ref", "views", "obj_ids", "obj_model", "dyn_ids", "dyn_prev", "dt_s")
VIEW_KEYS = ("pose", "ids", "bc4")
WIRE_DTYPES = ("u1", "i1", "<u2", "<i2", "<u4", "<i4", "<u8", "<i8", "<f2", "<f4", "<f8", "b1")


@pytest.fixture(scope="module", params=["lossless", "bc4"])
def fuzz_pair(request: Any, renderer: Any) -> tuple[WarpClient, DecodedUpdate]:
    """A two-view client and one good update (raw planes, metadata through the wire codec)."""
    scene = default_scene(gi=False)
    cfg = WarpConfig(views=2, depth_coding=request.param, reconstruction="mesh")
    srv = WarpServer(cfg, INTR, scene, 30)
    ctx = server_context(scene, renderer, INTR, START, t_s=T_REF)
    u = srv.produce(ctx)
    good = DecodedUpdate(0, u.t_s, u.pose, u.planes, unpack_meta(pack_meta(u.meta)))
    cli = WarpClient(cfg, INTR, renderer.ctx, srv.session_data())
    cli.apply(good)
    assert good.meta["dyn_ids"].size and good.meta["obj_ids"].size
    return cli, good


scalars = st.one_of(st.none(), st.booleans(), st.integers(-(2**63), 2**64 - 1), st.floats(), st.text(max_size=8),
                    st.binary(max_size=40))
arrays = hnp.arrays(st.sampled_from(WIRE_DTYPES), hnp.array_shapes(min_dims=0, max_dims=3, max_side=5))  # NaN, inf included
junk = st.recursive(st.one_of(scalars, arrays), lambda inner: st.one_of(st.lists(inner, max_size=8),
                                                                        st.dictionaries(st.text(max_size=6), inner, max_size=4)),
                    max_leaves=12)


@st.composite
def near_miss(draw: Any, good: Any) -> Any:
    """``good`` with one entry changed: a value the field's shape checks alone would let through."""
    special = st.sampled_from([0, -1, 1, 65535, 65536, 2**40, 0.0, -0.0, 1e-300, 1e300,
                               float("nan"), float("inf"), -float("inf")])
    if isinstance(good, np.ndarray) and good.size:
        a = good.copy()
        idx = tuple(draw(st.integers(0, n - 1)) for n in a.shape)
        v = draw(special)
        try:
            with np.errstate(all="ignore"):
                a[idx] = v
        except (OverflowError, ValueError):
            a = a.astype(np.float64)
            a[idx] = v
        return a
    if isinstance(good, list) and good:
        out = list(good)
        out[draw(st.integers(0, len(out) - 1))] = draw(st.one_of(special, scalars))
        return out[: draw(st.integers(0, len(out)))] if draw(st.booleans()) else out
    if isinstance(good, bytes) and good:
        b = bytearray(good)
        b[draw(st.integers(0, len(b) - 1))] ^= 1 << draw(st.integers(0, 7))
        return bytes(b[: draw(st.integers(0, len(b)))]) if draw(st.booleans()) else bytes(b)
    return draw(special)


@st.composite
def mutated_meta(draw: Any, good: dict[str, Any]) -> dict[str, Any]:
    """1-3 edits of the good metadata: a field replaced by junk or a near miss, deleted, or a view dropped/duplicated."""
    meta = {**good, "views": [dict(v) for v in good["views"]]}
    for _ in range(draw(st.integers(1, 3))):
        views = meta.get("views")  # may itself have been replaced by junk (e.g. an array)
        in_view = draw(st.booleans()) and isinstance(views, list) and len(views) > 0 \
            and all(isinstance(v, dict) for v in views)
        target = meta["views"][draw(st.integers(0, len(meta["views"]) - 1))] if in_view else meta
        key = draw(st.sampled_from(VIEW_KEYS if in_view else TOP_KEYS))
        op = draw(st.sampled_from(["junk", "near", "near", "delete", "views"]))
        if op == "delete":
            target.pop(key, None)
        elif op == "views" and isinstance(meta.get("views"), list) and meta["views"]:
            meta["views"] = draw(st.sampled_from([meta["views"][:1], meta["views"] * 2, meta["views"][::-1], []]))
        elif op == "near" and key in target:
            target[key] = draw(near_miss(target[key]))
        else:
            target[key] = draw(junk)
    return meta


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_apply_mutated_metadata_applies_or_raises_warp_meta_error(fuzz_pair: tuple[WarpClient, DecodedUpdate], data: Any) -> None:
    cli, good = fuzz_pair
    meta = data.draw(mutated_meta(good.meta))
    meta = unpack_meta(pack_meta(meta))  # only what the wire can carry (tuples become lists, etc.)
    update = dataclasses.replace(good, meta=meta)
    try:
        cli.apply(update)
    except WarpMetaError as exc:
        assert isinstance(exc, RemoteProtocolError)
        assert str(exc).startswith(("warp metadata frame 0: ", "warp frame 0: ")), str(exc)
        event(f"raised: {str(exc).split(': ')[1].split(' ')[0]}")
        return
    event("applied")
    frame = cli.render(START, T_REF + 0.05)
    assert frame.color.shape == (INTR.height, INTR.width, 3) and frame.holes.shape == (INTR.height, INTR.width)
