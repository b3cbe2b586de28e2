"""``tss``'s live frame cuts (issue 49 item 5) give what the plain steps gave, to the bit.

A profile of the live walk (320x180, default scene, probes at 5 Hz) put three numpy stages in every frame beside the
shading: :meth:`~splitrender.methods.tss.layout.StableAtlas.place` (a numpy mean per cell it handed out, a class
lookup per triangle), :func:`~splitrender.methods.tss.layout.fill_gutters` (a full-size upsampled copy of the
finest push-pull level, read only where no sample wrote) and ``visible_area``'s clipping (every plane's loop over
every polygon that crossed any plane).  Each now does less work for the same numbers; the references below are the
steps as they were before (74f1ab6's parent), run on random inputs beside the library's."""

from __future__ import annotations

import numpy as np
import pytest

from splitrender.methods.tss import server as tss_server
from splitrender.methods.tss.layout import KIND_LP, KIND_OS, KIND_SINGLE, StableAtlas, dilate_in_blocks, fill_gutters, plan_atlas
from splitrender.scene.pose import CameraIntrinsics, Pose


# ------------------------------------------------------------------ the references (the previous steps)

def fill_gutters_before(rgba: np.ndarray, rows: int, block: int = 1) -> np.ndarray:
    out = np.ascontiguousarray(rgba[..., :3])
    rows = int(min(max(rows, 0), rgba.shape[0]))
    if rows == 0:
        return out
    w = (rgba[:rows, :, 3] > 127).astype(np.float32)
    if w.all() or not w.any():
        return out
    c = rgba[:rows, :, :3].astype(np.float32) * w[..., None]
    if block > 1:
        c, wb = dilate_in_blocks(c, w > 0, block)
        w = wb.astype(np.float32)
        if w.all():
            hole = rgba[:rows, :, 3] <= 127
            out = out.copy()
            out[:rows][hole] = np.clip(np.rint(c[hole]), 0, 255).astype(np.uint8)
            return out
    pyramid = []
    while c.shape[0] > 1 or c.shape[1] > 1:
        ph, pw = c.shape[0] % 2, c.shape[1] % 2
        if ph or pw:
            c = np.pad(c, ((0, ph), (0, pw), (0, 0)))
            w = np.pad(w, ((0, ph), (0, pw)))
        pyramid.append((c, w))
        c = c[0::2, 0::2] + c[1::2, 0::2] + c[0::2, 1::2] + c[1::2, 1::2]
        w = w[0::2, 0::2] + w[1::2, 0::2] + w[0::2, 1::2] + w[1::2, 1::2]
        ok = w > 0
        c = np.where(ok[..., None], c / np.maximum(w, 1e-9)[..., None], 0.0)
        w = ok.astype(np.float32)
    col = c
    for c_k, w_k in reversed(pyramid):
        up = np.repeat(np.repeat(col, 2, axis=0), 2, axis=1)[: c_k.shape[0], : c_k.shape[1]]
        col = np.where((w_k > 0)[..., None], c_k / np.maximum(w_k, 1e-9)[..., None], up)
    col = col[:rows, : rgba.shape[1]]
    hole = rgba[:rows, :, 3] <= 127
    out = out.copy()
    out[:rows][hole] = np.clip(np.rint(col[hole]), 0, 255).astype(np.uint8)
    return out


def clip_before(poly: np.ndarray, cnt: np.ndarray, planes: list) -> tuple[np.ndarray, np.ndarray]:
    n = poly.shape[0]
    rows = np.arange(n)
    for a, b in planes:
        d = poly @ np.asarray(a) + b
        out = np.zeros_like(poly)
        pos = np.zeros(n, np.int64)
        for i in range(8):
            valid = i < cnt
            j = np.where(cnt > 0, (i + 1) % np.maximum(cnt, 1), 0)
            di, dj = d[:, i], d[rows, j]
            pi, pj = poly[:, i], poly[rows, j]
            e1 = valid & (di >= 0)
            out[rows[e1], np.minimum(pos[e1], 7)] = pi[e1]
            pos += e1
            e2 = valid & ((di >= 0) != (dj >= 0))
            t = di / np.where(e2, di - dj, 1.0)
            x = pi + t[:, None] * (pj - pi)
            out[rows[e2], np.minimum(pos[e2], 7)] = x[e2]
            pos += e2
        poly, cnt = out, np.minimum(pos, 8)
    return poly, cnt


class AtlasBefore(StableAtlas):
    """The allocator as it was: a numpy mean per :meth:`load`, a class lookup per key, a cell assigned at a time."""

    def load(self) -> float:
        return float(self.cursor.mean()) / self.height

    def place(self, ids: np.ndarray, keys: list, reset: bool = False) -> tuple[bool, bool]:
        live = np.zeros(self.cls.size, bool)
        live[ids] = True
        repacked = reset
        if not reset:
            want = np.array([self._class(k) for k in keys], np.int64)
            gone = np.flatnonzero((self.cls >= 0) & ~live)
            moved = ids[(self.cls[ids] >= 0) & (self.cls[ids] != want)]
            out = np.concatenate([gone, moved])
            touched = set()
            for c, k in zip(self.cls[out].tolist(), self.cell[out].tolist()):
                self.free[c].append(k)
                touched.add(c)
            for c in touched:
                self.free[c].sort(reverse=True)
            self.cls[out] = -1
            self.cell[out] = -1
            new = self.cls[ids] < 0
            for t, c in zip(ids[new].tolist(), want[new].tolist()):
                k = self._alloc(c)
                if k < 0:
                    repacked = True
                    break
                self.cls[t], self.cell[t] = c, k
        if repacked:
            self._reset_state()
            rank = (self.rank[ids] if self.rank is not None else np.zeros(ids.size, np.int64)).tolist()
            order = sorted(range(len(keys)), key=lambda i: (keys[i], rank[i] if keys[i][0] == KIND_LP else 0, int(ids[i])))
            for i in order:
                c = self._class(keys[i])
                k = self._alloc(c)
                if k < 0:
                    return False, True
                self.cls[ids[i]], self.cell[ids[i]] = c, k
        return True, repacked


# ------------------------------------------------------------------ the tests

def _atlas(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    rgba = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
    # written cells in rectangles, as an atlas holds them, and some scattered texels
    rgba[..., 3] = 0
    for _ in range(int(rng.integers(0, 12))):
        y, x = rng.integers(0, h), rng.integers(0, w)
        rgba[y: y + int(rng.integers(1, 9)), x: x + int(rng.integers(1, 17)), 3] = 255
    rgba[..., 3] |= np.where(rng.random((h, w)) < rng.random() * 0.5, 255, 0).astype(np.uint8)
    return rgba


@pytest.mark.parametrize("block", [1, 2, 4, 8])
def test_fill_gutters_fills_as_the_full_size_push_pull_did(block: int) -> None:
    """Odd and even sizes, used rows short of the height, blocks 1 to 8: the same bytes as the full-size pyramid
    (and the written texels untouched)."""
    rng = np.random.default_rng(block)
    differed = 0
    for trial in range(30):
        h, w = (int(x) for x in rng.integers(1, 70, 2))
        rgba = _atlas(rng, h, w)
        rows = int(rng.integers(0, h + 3))
        got, want = fill_gutters(rgba, rows, block), fill_gutters_before(rgba, rows, block)
        assert got.dtype == np.uint8 and got.shape == (h, w, 3)
        assert np.array_equal(got, want), (trial, h, w, rows, block)
        written = rgba[..., 3] > 127
        assert np.array_equal(got[written], rgba[..., :3][written])
        differed += int((got != rgba[..., :3]).any())
    assert differed > 10          # the cases filled something


def test_visible_area_clips_as_every_plane_over_every_crossing_polygon_did(monkeypatch: pytest.MonkeyPatch) -> None:
    """Triangles around and behind random cameras (near-plane and side crossings, degenerate ones): the same areas
    as with each plane's loop run over every polygon that crossed any plane."""
    rng = np.random.default_rng(7)
    intr = CameraIntrinsics(320, 180)
    cases = []
    for trial in range(40):
        n = int(rng.integers(1, 300))
        world = rng.normal(0.0, 1.0, (n, 3, 3)) * float(rng.choice([0.3, 2.0, 10.0])) + rng.normal(0.0, 3.0, (1, 1, 3))
        if trial % 3 == 0:
            world[: n // 2, 1] = world[: n // 2, 0]
        q = np.r_[1.0, rng.normal(0.0, 0.3, 3)]
        cases.append((world, Pose(position=tuple(rng.normal(0.0, 1.0, 3)), orientation=tuple(q / np.linalg.norm(q)))))
    got = [tss_server.visible_area(wd, p, intr, m) for wd, p in cases for m in (0.0, 0.1)]
    monkeypatch.setattr(tss_server, "_clip", clip_before)
    want = [tss_server.visible_area(wd, p, intr, m) for wd, p in cases for m in (0.0, 0.1)]
    clipped = 0
    for g, wv in zip(got, want):
        assert np.array_equal(g, wv)
        clipped += int((wv > 0).any() and (wv == 0).any())
    assert clipped > 5            # some views cut some triangles away


@pytest.mark.parametrize("block", [1, 4])
def test_stable_atlas_places_every_frame_as_it_did(block: int) -> None:
    """A random walk of frames (triangles entering, leaving and changing class, a repack now and then and a forced
    one when the atlas runs out) through both allocators: the same cells, shelves, load and plans every frame."""
    rng = np.random.default_rng(11 + block)
    n_tris = 600
    a, b = StableAtlas(n_tris, 256, 160, block=block), AtlasBefore(n_tris, 256, 160, block=block)
    kind = rng.choice([KIND_SINGLE, KIND_LP, KIND_OS], n_tris)
    level = rng.integers(1, 12, n_tris)
    w1, w2, h = rng.integers(1, 10, n_tris), rng.integers(0, 8, n_tris), rng.integers(1, 8, n_tris)
    alpha = rng.random(n_tris)
    live = rng.random(n_tris) < 0.4
    repacks = overflows = 0
    for frame in range(40):
        live ^= rng.random(n_tris) < 0.08
        change = rng.random(n_tris) < 0.1
        kind[change] = rng.choice([KIND_SINGLE, KIND_LP, KIND_OS], int(change.sum()))
        level[change] = rng.integers(1, 14 if frame < 30 else 24, int(change.sum()))
        ids = np.flatnonzero(live)
        reset = frame % 13 == 0
        pa = plan_atlas(a, ids, kind[ids], level[ids], w1[ids], w2[ids], h[ids], alpha[ids], reset=reset)
        pb = plan_atlas(b, ids, kind[ids], level[ids], w1[ids], w2[ids], h[ids], alpha[ids], reset=reset)
        assert (pa.overflow, pa.repacked, pa.height) == (pb.overflow, pb.repacked, pb.height)
        assert np.array_equal(a.cls, b.cls) and np.array_equal(a.cell, b.cell)
        assert a.shelves == b.shelves and a.keys == b.keys and a.free == b.free and a.fresh == b.fresh
        assert a.load() == b.load() == float(a.cursor.mean()) / a.height
        if not pa.overflow:
            assert np.array_equal(pa.origin, pb.origin) and np.array_equal(pa.slot, pb.slot) and pa.bins == pb.bins
        repacks += int(pa.repacked and not reset)
        overflows += int(pa.overflow)
    assert repacks >= 1           # the walk ran the atlas out of cells at least once
    assert KIND_OS in kind


def test_a_live_window_takes_at_most_pvs_max_samples_id_passes() -> None:
    """tss takes its PVS as sas does, capped alike (``TssConfig.pvs_max_samples``, 8): a live server expecting 0.65 s
    of latency takes 8 patch-id passes where 33.3 ms steps took 22; a virtual-time window (cloud: 50 ms and a frame)
    keeps its own samples, and a config asking for more is honoured."""
    from types import SimpleNamespace

    from splitrender.errors import ConfigError
    from splitrender.methods.tss import TssConfig
    from splitrender.pipeline.direct import server_context
    from splitrender.scene.trace import get_trace

    walk = get_trace("walk")
    intr = CameraIntrinsics(160, 90, 60.0)

    def passes(latency_s: float, cfg: TssConfig) -> int:
        ctx = server_context(None, None, intr, t_s=2.0, predict=walk.pose_at, latency_s=latency_s)
        return len(tss_server.TssServer.pvs_samples(SimpleNamespace(config=cfg, server_fps=30), ctx))

    assert passes(0.65, TssConfig()) == 8
    assert passes(0.65, TssConfig(pvs_max_samples=1000)) == 22
    assert passes(0.05, TssConfig()) == passes(0.05, TssConfig(pvs_max_samples=1000)) < 8
    with pytest.raises(ConfigError, match="pvs_max_samples"):
        TssConfig(pvs_max_samples=1)
