"""The SAS client's state without GL (:class:`PatchSlots`), shared by the client half and the browser front door's
page glue (:mod:`.page`), which runs in the server process and so must not import the client half."""

from __future__ import annotations

from typing import Any

import numpy as np

from .wire import SLOT_LAYOUT, TRI_SLOTS, FrameMeta, block_clamp_rect, block_layout_xy, dequantize_slots


class PatchSlots:
    """The SAS client's state without GL: PVS patches (object slot, triangle count, object-space positions),
    their atlas rectangles, and one vertex slot of three triangles per drawn patch.

    :meth:`apply` takes a frame's validated metadata; :meth:`rebuild` recomputes the slots of the patches that
    changed (freed slots are zeroed and reused) and returns their indices.  :attr:`rows` ``[:high]`` is the
    vertex data: per slot (3 triangles, 3 vertices, 10 floats) object-space position, normalised atlas uv,
    object slot and the block's normalised texel-centre clamp rectangle; unused triangles are zero.  The
    browser front door keeps one for a page (:mod:`.page`) and sends it the changed slots.
    """

    def __init__(self, session: Any) -> None:
        self.session = session
        self.atlas_size = session.atlas_size
        self.geo: dict[int, tuple[int, int, np.ndarray]] = {}      # id -> (object slot, triangles, (5, 3) positions)
        self.rect: dict[int, np.ndarray] = {}                      # id -> (x, y, lw, lh, transposed)
        self._changed: set[int] = set()
        self._slot: dict[int, int] = {}
        self._free: list[int] = []
        self.rows = np.zeros((0, 3, 3, 10), np.float32)
        self._slot_tris = np.zeros(0, np.int64)
        self.high = 0
        self.n_tri = 0

    @property
    def dirty(self) -> bool:
        return bool(self._changed)

    def apply(self, m: FrameMeta) -> None:
        if m.full:
            self._changed.update(self.geo)
            self._changed.update(self.rect)
            self.geo.clear()
            self.rect.clear()
        self._changed.update(m.drop.tolist())
        self._changed.update(m.geo_id.tolist())
        self._changed.update(m.uv_id.tolist())
        for pid in m.drop.tolist():
            self.geo.pop(pid, None)
            self.rect.pop(pid, None)
        gpos = dequantize_slots(m.geo_pos, m.geo_size, self.session.obj_box[m.geo_obj])
        for pid, o, s, p in zip(m.geo_id.tolist(), m.geo_obj.tolist(), m.geo_size.tolist(), gpos):
            self.geo[pid] = (o, s, p)
        for pid, r in zip(m.uv_id.tolist(), m.uv_rect):
            self.rect[pid] = r
        if m.pvs is not None:
            keep = set(m.pvs.tolist())
            for d in (self.geo, self.rect):
                for pid in [k for k in d if k not in keep]:
                    del d[pid]
                    self._changed.add(pid)

    def _patch_rows(self, ids: list[int]) -> np.ndarray:
        """(N, 3, 3, 10) float32 vertex rows of patches ``ids`` (unused triangles zero): object-space
        position, normalised atlas uv, object slot, the block's normalised texel-centre clamp rectangle."""
        out = np.zeros((len(ids), 3, 3, 10), np.float32)
        obj = np.array([self.geo[p][0] for p in ids], np.float32)
        size = np.array([self.geo[p][1] for p in ids], np.int64)
        pos = np.stack([self.geo[p][2] for p in ids]).astype(np.float32)
        rr = np.stack([self.rect[p] for p in ids]).astype(np.int64)
        rect = np.stack([rr[:, 0], rr[:, 1], 1 << rr[:, 2], 1 << rr[:, 3]], axis=1).astype(np.float64)
        wh = np.array(self.atlas_size, np.float64)
        for k in (1, 2, 3):
            sel = np.flatnonzero(size == k)
            if sel.size == 0:
                continue
            xy = block_layout_xy(np.broadcast_to(SLOT_LAYOUT[k], (sel.size, 5, 2)), rect[sel], rr[sel, 4] != 0,
                                 self.session.inset) / wh
            o = np.broadcast_to(obj[sel][:, None, None], (sel.size, 3, 1))
            clamp = block_clamp_rect(rect[sel]) / np.tile(wh, 2)
            c4 = np.broadcast_to(clamp[:, None, :], (sel.size, 3, 4))
            for t, tri in enumerate(TRI_SLOTS[k]):
                if tri[0] < 0:
                    continue
                out[sel, t] = np.concatenate([pos[sel][:, tri], xy[:, tri], o, c4], axis=2)
        return out

    def rebuild(self) -> np.ndarray:
        """Recompute the slots of the patches that changed since the last call; returns the slot indices
        written (patches drawn anew or moved, and slots freed), ascending."""
        written: set[int] = set()
        drawn = [p for p in self._changed if p in self.geo and p in self.rect]
        for pid in self._changed:
            if pid in self._slot and not (pid in self.geo and pid in self.rect):
                k = self._slot.pop(pid)
                self.rows[k] = 0.0
                self._slot_tris[k] = 0
                self._free.append(k)
                written.add(k)
        for pid in drawn:
            if pid not in self._slot:
                if not self._free:
                    grow = max(64, self.rows.shape[0])
                    self._free = list(range(self.rows.shape[0] + grow - 1, self.rows.shape[0] - 1, -1))
                    self.rows = np.concatenate([self.rows, np.zeros((grow, 3, 3, 10), np.float32)])
                    self._slot_tris = np.concatenate([self._slot_tris, np.zeros(grow, np.int64)])
                self._slot[pid] = self._free.pop()
        if drawn:
            slots = np.array([self._slot[p] for p in drawn], np.int64)
            self.rows[slots] = self._patch_rows(drawn)
            self._slot_tris[slots] = [self.geo[p][1] for p in drawn]
            written.update(slots.tolist())
        self._changed.clear()
        self.high = max(self._slot.values()) + 1 if self._slot else 0
        self.n_tri = int(self._slot_tris[:self.high].sum())
        return np.array(sorted(written), np.int64)
