"""``quads``' bytes counted as QUASAR's simulators count them (issue 38), against hand computations."""

from __future__ import annotations

import struct

import numpy as np
import pytest
import zstandard

from splitrender.methods.quads.accounting import QUADSTREAM_FACTOR, quasar_frame_bytes, quasar_quads_buffer
from splitrender.methods.quads.gen import QuadSet
from splitrender.methods.quads.wire import KIND_HIDDEN, KIND_REFERENCE, KIND_REVEALED, KIND_UPDATE, KIND_VIEW, KIND_WIDE, WireSet


def _set(n: int, nonflat: int, seed: int) -> QuadSet:
    rng = np.random.default_rng(seed)
    flat = np.ones(n, bool)
    flat[:nonflat] = False
    return QuadSet(rng.integers(0, 4, n).astype(np.uint8), rng.integers(0, 300, n).astype(np.uint16),
                   rng.integers(0, 170, n).astype(np.uint16), rng.integers(0, 256, n).astype(np.uint8),
                   rng.integers(0, 256, n).astype(np.uint8), rng.uniform(0.5, 30, n).astype(np.float32), flat,
                   rng.normal(0, 0.01, (nonflat, 16)).astype(np.float16))


def _z(b: bytes) -> int:
    return len(zstandard.ZstdCompressor(level=3).compress(b))


def _by_hand(q: QuadSet) -> float:
    """QUASAR's QuadMapDataPacked written out field by field with struct, then zstd(quads) + zstd(offsets) // 8."""
    n = len(q)
    normals = b"".join(struct.pack("<I", int(t) | int(p) << 8) for t, p in zip(q.theta, q.phi))
    depths = b"".join(struct.pack("<f", float(d)) for d in q.depth)
    osf = b"".join(struct.pack("<I", int(x) << 20 | int(y) << 8 | (int(lv) + 1) << 1 | int(f))
                   for x, y, lv, f in zip(q.x, q.y, q.level, q.flat))
    quads = struct.pack("<I", n) + normals + depths + osf
    offsets = b"".join(struct.pack("<e", float(v)) for v in q.offsets.reshape(-1))
    return _z(quads) + _z(offsets) // 8


def test_a_quad_is_twelve_bytes_in_quasar_s_layout() -> None:
    q = _set(5, 2, 0)
    buf = quasar_quads_buffer(q)
    assert len(buf) == 4 + 12 * 5
    assert struct.unpack_from("<I", buf, 0)[0] == 5
    osf = struct.unpack_from("<I", buf, 4 + 8 * 5)[0]        # the first quad's offsetSizeFlattened
    assert (osf >> 20, (osf >> 8) & 0xFFF, (osf >> 1) & 0x7F, osf & 1) == (q.x[0], q.y[0], q.level[0] + 1, 0)


def test_quasar_counts_every_layer_on_reference_frames_and_only_the_residual_on_others() -> None:
    ref, hidden, wide = _set(40, 12, 1), _set(25, 6, 2), _set(30, 4, 3)
    upd, rev = _set(8, 3, 4), _set(6, 2, 5)
    reference = [WireSet(KIND_REFERENCE, 0, 1, ref), WireSet(KIND_HIDDEN, 2, 0, hidden), WireSet(KIND_WIDE, 3, 2, wide)]
    qb = quasar_frame_bytes(reference, reference=True)
    assert qb.bytes == pytest.approx(_by_hand(ref) + _by_hand(hidden) + _by_hand(wide))
    assert qb.proxies == 40                                  # "Num Proxies": the visible layer only
    residual = [WireSet(KIND_UPDATE, 0, 1, upd), WireSet(KIND_REVEALED, 1, 0, rev), WireSet(KIND_HIDDEN, 2, 0, hidden),
                WireSet(KIND_WIDE, 3, 2, wide)]
    qb = quasar_frame_bytes(residual, reference=False)
    assert qb.bytes == pytest.approx(_by_hand(upd) + _by_hand(rev))   # hidden layers and wide view made, not counted
    assert qb.proxies == 14


def test_quadstream_s_per_view_factor_compounds_as_in_its_simulator() -> None:
    views = [_set(20 + k, 3, 10 + k) for k in range(3)]
    sets = [WireSet(KIND_VIEW, k, k, q) for k, q in enumerate(views)]
    total = 0.0
    for q in views:            # QSSimulator.h: total += view; total *= 103 / 96, inside the loop
        total = (total + _by_hand(q)) * 103 / 96
    qb = quasar_frame_bytes(sets, reference=False)
    assert qb.bytes == pytest.approx(total) and QUADSTREAM_FACTOR == pytest.approx(103 / 96)
    assert qb.proxies == sum(len(q) for q in views)


@pytest.mark.slow
def test_a_recorded_update_is_counted_as_by_hand() -> None:
    """The quads server half on the default walk: a reference frame, then a residual one; its ``quasar_bytes`` stat
    equals the hand computation over the sets it sent, and the residual frame's leaves its hidden layer out."""
    from splitrender.methods import get_method, make_config
    from splitrender.pipeline.direct import server_context
    from splitrender.render.renderer import Renderer
    from splitrender.scene.loader import get_scene
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.trace import get_trace

    spec = get_method("quads")
    scene = get_scene("default+nogi")
    intr = CameraIntrinsics(160, 90, 60.0, 0.05, 200.0)
    trace = get_trace("walk", scene=scene)
    srv = spec.server_class(make_config(spec.config, {"reference_error_db": 0.0}), intr, scene, 30)   # a residual frame as such
    r = Renderer()
    seen = {}
    for f in (0, 1):
        t = f / 30
        pose = trace.pose_at(t)
        srv.produce(server_context(scene, r, intr, pose, t_s=t, frame_id=f))
        st = srv.stats()
        kinds = {s.kind for s in srv.last_sets}
        counted = srv.last_sets if st["reference"] else [s for s in srv.last_sets if s.kind in (KIND_UPDATE, KIND_REVEALED)]
        assert st["quasar_bytes"] == pytest.approx(sum(_by_hand(s.quads) for s in counted))
        seen[f] = (st["reference"], kinds)
    assert seen[0][0] == 1.0 and seen[1][0] == 0.0
    assert KIND_HIDDEN in seen[1][1]                       # made on the residual frame, not counted there
