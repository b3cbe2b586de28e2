"""Hostile peers round 3 (issue 32, items 2 and 3): what a server sends a method's client half.

Each finding of the mutation campaign, replayed on real session data and metadata (a
server half on ``default`` at 160x90, through msgpack + zstd): the method's client half
raises its documented :class:`~splitrender.errors.RemoteProtocolError` subclass with a
message naming the field, never a ``ValueError`` from an array's truth value, a
``LinAlgError`` at render or an ``OverflowError`` from ``int(inf)`` (the live client
catches only ``RemoteProtocolError``).  Memory is the ``tracemalloc`` peak of the call
(numpy and Python allocations; GL objects are not traced).  After a rejected update a
client applies the next valid one and draws exactly what a client that never saw the bad
one draws: bad state never enters the cache.
"""

from __future__ import annotations

import time
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pytest

from splitrender.codecs.meta import pack_meta, unpack_meta
from splitrender.errors import RemoteProtocolError
from splitrender.gi.stream import ProbeStreamError
from splitrender.limits import ClientLimits
from splitrender.methods import DecodedUpdate, get_method, make_config
from splitrender.methods.quads.wire import QuadsWireError
from splitrender.methods.sas.wire import SasMetaError
from splitrender.methods.tss.wire import WIRE_VERSION as TSS_WIRE_VERSION, TssWireError
from splitrender.methods.warp.wire import WarpMetaError
from splitrender.pipeline.direct import server_context
from splitrender.scene.loader import get_scene
from splitrender.scene.pose import CameraIntrinsics
from splitrender.scene.trace import get_trace
from splitrender.scene.wire import SceneWireError

KB = 1024
MB = 1024 * 1024
INTR = CameraIntrinsics(160, 90, 60.0)
METHODS: dict[str, tuple[str, dict[str, Any], type[RemoteProtocolError], int]] = {
    # method: (scene, parameters, its error class, its metadata version)
    "sas": ("default+nogi", {"lossless": True}, SasMetaError, 4),
    "tss": ("default+nogi", {"lossless": True}, TssWireError, TSS_WIRE_VERSION),
    "warp": ("default+nogi", {}, WarpMetaError, 1),
    "quads": ("default+nogi", {"lossless": True, "reference_every": 1}, QuadsWireError, 1),
    "probes": ("default", {}, ProbeStreamError, 2),
}


def _peak(fn: Callable[[], Any]) -> tuple[BaseException | None, int]:
    """(exception raised or None, tracemalloc peak in bytes above the start)."""
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        err: BaseException | None = None
        try:
            fn()
        except BaseException as exc:  # noqa: BLE001 - the test inspects it
            err = exc
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    return err, peak


@dataclass
class Pair:
    """A method's valid session data and two valid updates (frames 0 and 1), as a client receives them."""

    name: str
    client_class: Any
    cfg: Any
    session: dict[str, Any]
    updates: list[DecodedUpdate]
    renderer: Any

    def client(self, session: dict[str, Any] | None = None, limits: ClientLimits | None = None) -> Any:
        return self.client_class(self.cfg, INTR, self.renderer.ctx, self.session if session is None else session,
                                      limits)

    def with_meta(self, k: int = 1, **fields: Any) -> DecodedUpdate:
        u = self.updates[k]
        return replace(u, meta={**u.meta, **fields})


_PAIRS: dict[str, Pair] = {}


@pytest.fixture
def pair(request: Any, renderer: Any) -> Pair:
    """The method named by the test's ``method`` parameter (built once per module run, about 1 s each)."""
    name = request.node.callspec.params["method"]
    if name not in _PAIRS:
        scene_name, params, _, _ = METHODS[name]
        scene = get_scene(scene_name)
        spec = get_method(name)
        cfg = make_config(spec.config, params)
        prod = spec.producer_class(cfg, scene, 30, renderer) if spec.producer_class else None
        srv = spec.server_class(cfg, INTR, scene, 30, prod)
        trace = get_trace("walk", scene=scene)
        updates = []
        for f in range(2):
            t = 0.5 + f / 30
            pose = trace.pose_at(t)
            ctx = server_context(scene, renderer, INTR, pose, t_s=t, frame_id=f, predict=trace.pose_at,
                                 shared=prod.prepare(f, t) if prod else None)
            u = srv.produce(ctx)
            updates.append(DecodedUpdate(u.frame_id, t, pose, u.planes, unpack_meta(pack_meta(u.meta)), dict(u.data)))
        _PAIRS[name] = Pair(name, spec.client_class, cfg, unpack_meta(pack_meta(srv.session_data())), updates, renderer)
    return _PAIRS[name]


def _assert_rejected(err: BaseException | None, cls: type[RemoteProtocolError], text: str) -> None:
    assert type(err) is cls, repr(err)          # the method's own class: not a bare ValueError, LinAlgError, OverflowError
    assert str(err) == text, str(err)


def _where(name: str, frame: int | None) -> str:
    if name in ("warp", "quads") and frame is not None:
        return f"{name} metadata frame {frame}"
    return f"{name} {'session data' if frame is None else 'metadata'}"


# ------------------------------------------------------------------ 1. array-valued fields
@pytest.mark.parametrize("method", ["sas", "tss", "quads", "probes"])
def test_array_valued_version_in_session_data(pair: Pair, method: str) -> None:
    """``v`` as an array of two: ``sd.get("v") != 3`` raised ValueError (ambiguous truth value)."""
    _, _, cls, version = METHODS[method]
    err, peak = _peak(lambda: pair.client({**pair.session, "v": np.array([version, version])}))
    _assert_rejected(err, cls, f"{method} session data: v: version array int64 (2,), this client speaks {version}")
    assert peak < 64 * KB, peak                 # measured 3.6-3.8 KB


@pytest.mark.parametrize("method", ["sas", "tss", "warp", "quads", "probes"])
def test_array_valued_version_in_frame_metadata(pair: Pair, method: str) -> None:
    _, _, cls, version = METHODS[method]
    cli = pair.client()
    cli.apply(pair.updates[0])
    bad = pair.with_meta(1, v=np.array([version, version]))
    err, peak = _peak(lambda: cli.apply(bad))
    _assert_rejected(err, cls, f"{_where(method, 1)}: v: version array int64 (2,), this client speaks {version}")
    assert peak < 64 * KB, peak                 # measured 2.9-3.4 KB


@pytest.mark.parametrize("method", ["probes"])
def test_array_valued_fields_in_the_scene(pair: Pair, method: str) -> None:
    scene = pair.session["scene"]
    cases = [({**scene, "v": np.array([1, 1])}, "scene: v: version array int64 (2,), this client speaks 1"),
             ({**scene, "shading": np.array([1, 2])}, "scene: shading: expected one of ['pbr', 'phong'], got array int64 (2,)"),
             ({**scene, "sky": np.array([0.5, 0.5, 0.5])}, "scene: sky: expected a list of 3, got array float64 (3,)")]
    for data, text in cases:
        err, peak = _peak(lambda: pair.client({**pair.session, "scene": data}))   # noqa: B023
        _assert_rejected(err, SceneWireError, text)
        assert peak < 256 * KB, peak            # measured 4.5 KB (v), 24 KB (the objects are checked before shading)


# ------------------------------------------------------------------ 2. singular and huge transforms
def _poked(xf: np.ndarray, how: str) -> np.ndarray:
    out = np.array(xf, np.float64 if how == "1e300" else xf.dtype)
    if how == "zero":
        out[0] = 0.0                             # the campaign's all-zero matrix
    elif how == "singular":
        out[0, :3, :3] = 0.0                     # affine, but nothing to invert
    elif how == "1e300":
        out[0, 0, 0] = 1e300                     # float32 inf
    elif how == "3e38":
        out[0, 0, 3] = 3e38                      # finite in float32; extrapolated to inf
    return out


TRANSFORM_TEXT = {"zero": "xf[0]: last row [0.0, 0.0, 0.0, 0.0] is not (0, 0, 0, 1)",
                  "singular": "xf[0]: singular transform (|det| 0 < 1e-12)",
                  "1e300": "xf[0]: not finite in float32",
                  "3e38": "xf[0]: entry 3e+38 beyond +-1e+06"}


@pytest.mark.parametrize("how", ["zero", "singular", "1e300", "3e38"])
@pytest.mark.parametrize("method", ["sas", "tss", "probes"])
def test_bad_transforms_are_refused_on_receipt_and_rendering_goes_on(pair: Pair, method: str, how: str) -> None:
    """Before: sas and tss took an all-zero transform and ``extrapolate_transforms`` raised LinAlgError at every
    later render; probes raised in ``render/renderer.py``; sas took a 3e38 m translation and drew inf; tss
    ``parse_transforms`` turned 1e300 into float32 inf."""
    cls = METHODS[method][2]
    cli = pair.client()
    cli.apply(pair.updates[0])
    u = pair.updates[1]
    bad = pair.with_meta(1, xf=_poked(u.meta["xf"], how))
    err, peak = _peak(lambda: cli.apply(bad))
    _assert_rejected(err, cls, f"{method} metadata: {TRANSFORM_TEXT[how]}")
    # sas validates the frame's geometry (its slot codes cast to int64) before its transforms: measured 111 KB;
    # tss 4.9-6.3 KB, probes 3.9-4.3 KB
    assert peak < (1 * MB if method == "sas" else 64 * KB), peak
    frame = cli.render(u.pose, u.t_s + 0.1)          # extrapolates from the transforms it holds: all valid
    assert frame.color.shape == (INTR.height, INTR.width, 3)


@pytest.mark.parametrize("method", ["warp"])
def test_warp_model_matrices_are_refused_the_same_way(pair: Pair, method: str) -> None:
    cli = pair.client()
    m = pair.updates[1].meta["obj_model"]
    for how, text in (("singular", "obj_model[0]: singular transform (|det| 0 < 1e-09)"),
                      ("1e300", "obj_model[0]: entry 1e+300 beyond +-1e+06"),
                      ("3e38", "obj_model[0]: entry 3e+38 beyond +-1e+06")):
        bad = pair.with_meta(1, obj_model=_poked(m, how).astype(np.float64))
        err, peak = _peak(lambda: cli.apply(bad))  # noqa: B023
        _assert_rejected(err, WarpMetaError, f"warp metadata frame 1: {text}")
        assert peak < 64 * KB, peak             # measured 6.6-7.7 KB


@pytest.mark.parametrize("method", ["probes"])
def test_a_singular_rest_transform_in_the_scene_is_refused(pair: Pair, method: str) -> None:
    """The client inverts each moving object's rest transform per update; a singular one passed the scene's checks."""
    scene = pair.session["scene"]
    k = next(i for i, o in enumerate(scene["objects"]) if o["dynamic"])
    objs = list(scene["objects"])
    for tf, text in ((np.diag([1.0, 0.0, 1.0, 1.0]).astype(np.float32), "singular transform (|det| 0 < 1e-12)"),
                     (np.full((4, 4), np.inf, np.float32), "not finite"),
                     (np.diag([1e7, 1.0, 1.0, 1.0]).astype(np.float32), "entry 1e+07 beyond +-1e+06")):
        objs[k] = {**scene["objects"][k], "transform": tf}
        err, peak = _peak(lambda: pair.client({**pair.session, "scene": {**scene, "objects": objs}}))  # noqa: B023
        _assert_rejected(err, SceneWireError, f"scene: objects[{k}].transform: {text}")
        assert peak < 256 * KB, peak            # measured 22-23 KB (the objects before it are checked first)


@pytest.mark.parametrize("method", ["sas"])
def test_sas_object_boxes_are_bounded(pair: Pair, method: str) -> None:
    """Patch vertices are dequantised inside their object's box: a 3e38 m box (finite in float32) made them inf."""
    box = np.array(pair.session["obj_box"])
    box[0, 1, 0] = 3e38
    err, peak = _peak(lambda: pair.client({**pair.session, "obj_box": box}))
    _assert_rejected(err, SasMetaError, "sas session data: obj_box: values must be in -1e+06..1e+06, got -8..3e+38")
    assert peak < 64 * KB, peak                 # measured 3.7 KB


def test_extrapolation_never_draws_inf_and_never_raises() -> None:
    """A transform valid on its own can still extrapolate past float32 (here 3e38 m moving 3e38 m per 0.1 s, which
    the wire now refuses anyway); the client shows the newest sample instead.  A singular previous sample (never
    accepted either) keeps the newest sample too, where ``np.linalg.inv`` raised."""
    from splitrender.methods.sas.client import extrapolate_transforms

    eye = np.eye(4, dtype=np.float32)[None]
    far = eye.copy()
    far[0, 0, 3] = 3e38
    with np.errstate(all="raise"):                      # no floating-point warning escapes either
        got = extrapolate_transforms(eye, np.array([0.0]), far, np.array([0.1]), 0.2)
        assert np.isfinite(got).all() and np.array_equal(got, far)
        zero = np.zeros_like(eye)
        moved = eye.copy()
        moved[0, 2, 3] = 1.0
        got = extrapolate_transforms(zero, np.array([0.0]), moved, np.array([0.1]), 0.2)
        assert np.array_equal(got, moved)
        got = extrapolate_transforms(eye, np.array([0.0]), moved, np.array([0.1]), float("nan"))
        assert np.array_equal(got, moved)
    # a valid pair still extrapolates: 1 m per 0.1 s, shown 0.1 s later
    got = extrapolate_transforms(eye, np.array([0.0]), moved, np.array([0.1]), 0.2)
    assert abs(float(got[0, 2, 3]) - 2.0) < 1e-6


@pytest.mark.parametrize("method", ["probes"])
def test_the_renderer_skips_an_object_it_cannot_draw(pair: Pair, method: str) -> None:
    """``render/renderer.py`` inverted each model matrix for its normal matrix and raised LinAlgError on a singular
    one; it now leaves that object out (nothing else changes)."""
    from splitrender.render.renderer import normal_matrix

    assert normal_matrix(np.zeros((4, 4))) is None and normal_matrix(np.full((4, 4), np.nan)) is None
    nm = normal_matrix(np.diag([2.0, 2.0, 2.0, 1.0]))
    assert nm is not None and np.allclose(nm, np.eye(3) / 2.0)
    cli = pair.client()
    u = pair.updates[0]
    cli.apply(u)
    before = cli.render(u.pose, u.t_s).color
    holder = next(iter(cli._moving.values()))
    holder.m = np.zeros((4, 4))
    after = cli.render(u.pose, u.t_s).color
    assert after.shape == before.shape and not np.array_equal(after, before)


# ------------------------------------------------------------------ 3. int(inf) and NaN in session data
INT_INF = [
    ("tss", "n_objects", "tss session data: n_objects: expected an integer in 0..65535, got inf"),
    ("tss", "atlas", "tss session data: atlas[0]: expected an integer in 2..16384, got inf"),
    ("quads", "slots", "quads session data: slots: expected an integer in 1..64, got inf"),
    ("quads", "slot_size", "quads session data: slot_size[0]: expected an integer in 1..4096, got inf"),
    ("probes", "counts", "probes session data: counts[0]: expected an integer in 2..64, got inf"),
]


@pytest.mark.parametrize(("method", "key", "text"), INT_INF, ids=[f"{m}-{k}" for m, k, _ in INT_INF])
def test_float_inf_where_an_integer_is_expected(pair: Pair, method: str, key: str, text: str) -> None:
    """``int(float("inf"))`` raised OverflowError in session parsing."""
    v = pair.session[key]
    bad = [float("inf"), *v[1:]] if isinstance(v, list) else float("inf")
    err, peak = _peak(lambda: pair.client({**pair.session, key: bad}))
    _assert_rejected(err, METHODS[method][2], text)
    assert peak < 64 * KB, peak                 # measured 3.4-4.1 KB


@pytest.mark.parametrize("method", ["tss"])
def test_a_nan_sky_colour_is_refused(pair: Pair, method: str) -> None:
    """tss took ``float("nan")`` as the clear colour of every frame it draws: silent wrong output."""
    err, peak = _peak(lambda: pair.client({**pair.session, "sky": [0.5, float("nan"), 0.5]}))
    _assert_rejected(err, TssWireError, "tss session data: sky[1]: expected a finite number in [-1e+06, 1e+06], got nan")
    assert peak < 64 * KB, peak                 # measured 4.6 KB


# ------------------------------------------------------------------ 4. sizes the server declares
@pytest.mark.parametrize("method", ["probes"])
def test_a_huge_probe_grid_is_refused_before_anything_is_allocated(pair: Pair, method: str) -> None:
    """``counts = [64, 64, 64]`` (262144 probes) passed every check and cost 3 GB and 12 s; the default limit is
    ``ClientLimits.max_probes`` = 32768."""
    sd = {**pair.session, "counts": [64, 64, 64]}
    t0 = time.perf_counter()
    err, peak = _peak(lambda: pair.client(sd))
    dt = time.perf_counter() - t0
    _assert_rejected(err, ProbeStreamError, "probes session data: counts: 64x64x64 = 262144 probes, over this client's "
                                            "limit of 32768 (ClientLimits.max_probes)")
    assert peak < 64 * KB, peak                 # measured 2.4 KB
    assert dt < 0.5, dt                         # the check alone: 7 µs


@pytest.mark.parametrize("method", ["probes"])
def test_the_probe_limit_is_the_clients_to_raise(pair: Pair, method: str) -> None:
    scene = {**pair.session["scene"], "gi_probes": [4, 4, 4]}
    sd = {**pair.session, "counts": [4, 4, 4], "scene": scene}
    with pytest.raises(ProbeStreamError, match=r"^probes session data: counts: 4x4x4 = 64 probes, over this client's "
                                               r"limit of 32 \(ClientLimits.max_probes\)$"):
        pair.client(sd, ClientLimits(max_probes=32))
    cli = pair.client(sd, ClientLimits(max_probes=64))
    assert cli.count == 64
    # the scene's own grid is held to the same limit
    with pytest.raises(SceneWireError, match=r"^scene: gi_probes: 8x4x8 = 256 probes, over this client's limit of 64"):
        pair.client({**sd, "scene": pair.session["scene"]}, ClientLimits(max_probes=64))


@pytest.mark.parametrize("method", ["probes"])
def test_scene_size_limits(pair: Pair, method: str) -> None:
    scene = pair.session["scene"]
    tris = sum(int(o["indices"].shape[0]) for o in scene["objects"])
    n = len(scene["objects"])
    with pytest.raises(SceneWireError, match=rf"^scene: objects: {tris} triangles, over this client's limit of "
                                             rf"{tris - 1} \(ClientLimits.max_scene_triangles\)$"):
        pair.client(limits=ClientLimits(max_scene_triangles=tris - 1))
    with pytest.raises(SceneWireError, match=rf"^scene: objects: expected a list of 1 to {n - 1}, got list of {n}$"):
        pair.client(limits=ClientLimits(max_scene_objects=n - 1))
    assert pair.client(limits=ClientLimits(max_scene_triangles=tris, max_scene_objects=n)).scene.objects


# ------------------------------------------------------------------ 5. bad state does not persist
BAD_UPDATES: dict[str, list[dict[str, Any]]] = {
    "sas": [{"v": np.array([4, 4])}, {"xf": "zero"}, {"xf": "3e38"}, {"full": np.array([True, False])}],
    "tss": [{"v": np.array([3, 3])}, {"xf": "zero"}, {"xf": "1e300"}],
    "warp": [{"v": np.array([1, 1])}, {"obj_model": "singular"}, {"dt_s": float("inf")}],
    "quads": [{"v": np.array([1, 1])}, {"ref_frame": float("inf")}, {"cameras": [[0.0] * 10]}],
    "probes": [{"v": np.array([2, 2])}, {"xf": "zero"}, {"sun": float("nan")}, {"lights": np.array([1.0])}],
}


@pytest.mark.parametrize("method", ["sas", "tss", "warp", "quads", "probes"])
def test_after_rejected_updates_the_next_valid_one_draws_what_it_should(pair: Pair, method: str) -> None:
    """Client A: frame 0, every bad update (each rejected with the method's error, each followed by a render that
    must not raise), frame 1.  Client B: frames 0 and 1.  Both draw the same pixels at frame 1's pose."""
    cls = METHODS[method][2]
    a, b = pair.client(), pair.client()
    u0, u1 = pair.updates
    a.apply(u0)
    b.apply(u0)
    for fields in BAD_UPDATES[method]:
        fields = {k: _poked(u1.meta[k], v) if isinstance(v, str) and k in ("xf", "obj_model") else v for k, v in fields.items()}
        with pytest.raises(cls):
            a.apply(pair.with_meta(1, **fields))
        # at frame 0's time: probes' renderer keeps the moving objects' shadow map per display time, so a render at
        # frame 1's time before frame 1 arrives would leave a stale shadow map behind (11 pixels; not this issue's)
        assert a.render(u1.pose, u0.t_s).color.dtype == np.uint8
    a.apply(u1)
    b.apply(u1)
    for dt in (0.0, 0.05):                      # at the frame's time, and extrapolated
        fa, fb = a.render(u1.pose, u1.t_s + dt), b.render(u1.pose, u1.t_s + dt)
        assert np.array_equal(fa.color, fb.color), f"{method}: {int((fa.color != fb.color).any(-1).sum())} pixels differ"
    assert fa.color.std() > 5.0, "the frame shows the scene, not a cleared background"


def test_probes_wire_version_is_the_servers() -> None:
    """``probes``' client reads its versions from ``probes/wire.py`` (not from the server half)."""
    from splitrender.methods.probes import server, wire

    assert wire.META_VERSION == server.META_VERSION


@pytest.mark.parametrize("method", ["probes"])
def test_an_object_without_triangles_in_the_scene_is_refused(pair: Pair, method: str) -> None:
    """The long fuzz run's find: a probes scene whose object has an empty index array passed the checks and
    the first render raised moderngl's "the buffer cannot be empty".  An object draws at least one triangle."""
    scene = pair.session["scene"]
    objects = [dict(o) for o in scene["objects"]]
    objects[-1]["indices"] = np.zeros((0, 3), np.uint32)
    err, peak = _peak(lambda: pair.client({**pair.session, "scene": {**scene, "objects": objects}}))
    _assert_rejected(err, SceneWireError, f"scene: objects[{len(objects) - 1}].indices: shape (0, 3): a dimension of 0 is "
                                          "not in 1..16777216")
    assert peak < 256 * KB, peak
