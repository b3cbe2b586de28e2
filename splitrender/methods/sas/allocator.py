"""Shading-atlas memory management (paper section 4.2), vectorised with numpy.

The atlas (``width`` x ``height`` texels) is a grid of square :class:`Superblock` s of
``superblock_px`` texels.  A block has power-of-two sides ``2^lw x 2^lh`` (its *level*
``(lw, lh)``, landscape: ``lh <= lw``).

Strategy S0 (the paper's): a superblock is claimed by one *column width* ``2^lw`` and
split into columns of that width; blocks of any height ``2^lh <= 2^lw`` are stacked in
the columns.  Per column width the superblocks form one linear "column space"
(column after column, superblock after superblock); blocks are provisioned in
decreasing height so every block lands on a multiple of its height and never
straddles a column.  After a frame, the fill pointer is aligned up to the column
width by pushing the leftover pieces onto the block stacks (figure 8 (e)).

Each frame runs the three phases on arrays of patches:

- **request**: blocks of patches that left the PVS (or change level) go onto the
  block stack of their level; patches that need a block draw a *slot* per level
  (their rank in the level's request group);
- **provisioning**: per column width, in decreasing height, the block stack serves
  the first requests; the rest (the *required* blocks) come from the fill pointer of
  the current superblock, drawing new superblocks from the superblock stack;
- **assignment**: a slot below the stack count takes a stacked block, otherwise its
  block is at ``offset + (slot - stacked) * height`` in the column space.

Simpler strategies for the fragmentation comparison (section 5.4):
S1 no columns (a superblock holds a grid of one level only), S2 also no block stacks
(freed blocks stay inaccessible until their whole superblock is free), S3 also no
atlas reset.  A superblock whose last live block is freed returns to the superblock
stack (its stacked blocks are dropped).  An atlas reset frees everything and
allocates the whole PVS again, compactly.

All positions are texel coordinates of the block's top-left corner, ``x`` along the
atlas width and ``y`` along its rows (row 0 = first row of the atlas image).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ...errors import ConfigError

Strategy = Literal["S0", "S1", "S2", "S3"]
STRATEGIES: tuple[Strategy, ...] = ("S0", "S1", "S2", "S3")


@dataclass(frozen=True)
class AtlasLayout:
    """Atlas geometry: ``width``/``height`` texels (multiples of ``superblock_px``, a power of two)."""

    width: int
    height: int
    superblock_px: int = 32
    min_level: int = 1

    def __post_init__(self) -> None:
        s = self.superblock_px
        if s < 2 or s & (s - 1):
            raise ConfigError(f"AtlasLayout.superblock_px: must be a power of two >= 2, got {s}")
        if self.width % s or self.height % s or self.width <= 0 or self.height <= 0:
            raise ConfigError(f"AtlasLayout: atlas {self.width}x{self.height} must be a positive multiple of superblock_px={s}")
        if not 0 <= self.min_level <= self.max_level:
            raise ConfigError(f"AtlasLayout.min_level: must be in [0, {self.max_level}], got {self.min_level}")

    @property
    def max_level(self) -> int:
        return int(self.superblock_px).bit_length() - 1

    @property
    def sb_cols(self) -> int:
        return self.width // self.superblock_px

    @property
    def n_superblocks(self) -> int:
        return self.sb_cols * (self.height // self.superblock_px)

    @property
    def area(self) -> int:
        return self.width * self.height


@dataclass
class AllocResult:
    """One frame's allocation: patch ids (sorted int64 arrays)."""

    placed: np.ndarray      #: got a new block this frame (entered, moved level, or reset)
    released: np.ndarray    #: lost their block (left the PVS)
    failed: np.ndarray      #: visible but no block (out of memory)
    reset: bool = False


@dataclass
class MemoryBreakdown:
    """Atlas area in texels by state (figure 11); the five fields sum to the atlas area."""

    allocated: int = 0
    superblock_tail: int = 0
    block_stacks: int = 0
    inaccessible: int = 0
    free_superblocks: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass
class _Key:
    """Fill state of one column width (S0) or one level (S1-S3)."""

    lw: int
    lh_fixed: int | None
    sb: int = -1          # current superblock (-1: none)
    ptr: int = 0          # fill pointer in the current superblock's column space, texels of height


class PatchAllocator:
    """Assigns atlas blocks to visible patches, frame by frame (see module docstring).

    ``n_patches`` is the scene-wide patch count; state arrays are indexed by patch id.
    """

    def __init__(self, n_patches: int, layout: AtlasLayout, strategy: Strategy = "S0") -> None:
        if strategy not in STRATEGIES:
            raise ConfigError(f"PatchAllocator.strategy: {strategy!r} is not one of {list(STRATEGIES)}")
        self.layout = layout
        self.strategy = strategy
        self.n_patches = n_patches
        self.level_w = np.full(n_patches, -1, np.int8)
        self.level_h = np.full(n_patches, -1, np.int8)
        self.bx = np.zeros(n_patches, np.int32)
        self.by = np.zeros(n_patches, np.int32)
        self.resets = 0
        self._clear()

    # ------------------------------------------------------------------ state
    def _clear(self) -> None:
        lay = self.layout
        self.level_w[:] = -1
        self.level_h[:] = -1
        self.sb_live = np.zeros(lay.n_superblocks, np.int64)          # live blocks per superblock
        self.sb_key = np.full(lay.n_superblocks, -1, np.int64)         # owning key, -1 free
        self.sb_dead_area = np.zeros(lay.n_superblocks, np.int64)      # S2/S3: freed, inaccessible texels
        self.free_sbs = np.arange(lay.n_superblocks, dtype=np.int64)   # superblock stack (lowest id first)
        self.stacks: dict[int, np.ndarray] = {}                         # level code -> (K, 2) int32 block positions
        self.keys: dict[int, _Key] = {}

    @property
    def has_columns(self) -> bool:
        return self.strategy == "S0"

    @property
    def has_stacks(self) -> bool:
        return self.strategy in ("S0", "S1")

    @property
    def can_reset(self) -> bool:
        return self.strategy != "S3"

    def allocated(self) -> np.ndarray:
        """Patch ids that currently hold a block."""
        return np.flatnonzero(self.level_w >= 0)

    def memory_load(self) -> float:
        """Fraction of superblocks claimed (0..1): what the high-water mark is compared with."""
        return 1.0 - self.free_sbs.size / self.layout.n_superblocks

    # ------------------------------------------------------------------ helpers
    def _key_of(self, lw: np.ndarray, lh: np.ndarray) -> np.ndarray:
        return lw.astype(np.int64) if self.has_columns else lw.astype(np.int64) * 16 + lh

    def _capacity(self, key: _Key) -> int:
        """Column-space length of one superblock for ``key``, in texels of height."""
        s = self.layout.superblock_px
        return s * (s >> key.lw)

    def _to_xy(self, key: _Key, sb: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Superblock id + column-space offset (texels of height) -> block top-left texel."""
        s = self.layout.superblock_px
        col, y = np.divmod(q, s)
        sx, sy = np.divmod(sb, self.layout.sb_cols)[::-1]
        return (sx * s + col * (1 << key.lw)).astype(np.int32), (sy * s + y).astype(np.int32)

    def _sb_of(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        s = self.layout.superblock_px
        return (y // s).astype(np.int64) * self.layout.sb_cols + x // s

    def _push(self, code: int, xy: np.ndarray) -> None:
        if xy.size == 0:
            return
        st = self.stacks.get(code)
        self.stacks[code] = xy.astype(np.int32) if st is None or st.size == 0 else np.concatenate([st, xy.astype(np.int32)])

    def _pop(self, code: int, n: int) -> np.ndarray:
        st = self.stacks.get(code)
        if st is None or n <= 0:
            return np.zeros((0, 2), np.int32)
        take = st[st.shape[0] - n:][::-1]
        self.stacks[code] = st[: st.shape[0] - n]
        return take

    def _draw_superblocks(self, n: int) -> np.ndarray:
        take = self.free_sbs[:n]
        self.free_sbs = self.free_sbs[n:]
        return take

    # ------------------------------------------------------------------ phases
    def _release(self, ids: np.ndarray) -> None:
        """Request phase, deallocation half: blocks of ``ids`` go to their level's stack."""
        if ids.size == 0:
            return
        lw, lh = self.level_w[ids].astype(np.int64), self.level_h[ids].astype(np.int64)
        x, y = self.bx[ids], self.by[ids]
        sb = self._sb_of(x, y)
        self.sb_live -= np.bincount(sb, minlength=self.sb_live.size)
        code = lw * 16 + lh
        if self.has_stacks:
            order = np.argsort(code, kind="stable")
            cs = code[order]
            cuts = np.flatnonzero(np.diff(cs)) + 1
            for grp in np.split(order, cuts):
                self._push(int(code[grp[0]]), np.stack([x[grp], y[grp]], axis=1))
        else:
            self.sb_dead_area += np.bincount(sb, weights=(1 << lw) * (1 << lh), minlength=self.sb_live.size).astype(np.int64)
        self.level_w[ids] = -1
        self.level_h[ids] = -1
        # superblocks with no live block left return to the superblock stack
        current = {k.sb for k in self.keys.values()}
        empty = np.flatnonzero((self.sb_live == 0) & (self.sb_key >= 0))
        empty = np.array([s for s in empty.tolist() if s not in current], np.int64)
        if empty.size:
            self.sb_key[empty] = -1
            self.sb_dead_area[empty] = 0
            if self.has_stacks:
                for code_, st in self.stacks.items():
                    if st.size:
                        keep = ~np.isin(self._sb_of(st[:, 0], st[:, 1]), empty)
                        self.stacks[code_] = st[keep]
            self.free_sbs = np.sort(np.concatenate([self.free_sbs, empty]))

    def _request(self, ids: np.ndarray, lw: np.ndarray, lh: np.ndarray) -> np.ndarray:
        """Request, provisioning and assignment phases for ``ids``; returns the ids that failed."""
        if ids.size == 0:
            return ids
        lw = lw.astype(np.int64)
        lh = lh.astype(np.int64)
        key = self._key_of(lw, lh)
        # slot = rank in the (key, decreasing height) group; sort once
        order = np.lexsort((ids, -lh, key))
        ids, lw, lh, key = ids[order], lw[order], lh[order], key[order]
        ok = np.zeros(ids.size, bool)
        gx = np.zeros(ids.size, np.int32)
        gy = np.zeros(ids.size, np.int32)
        bounds = np.flatnonzero(np.diff(key * 64 + (63 - lh))) + 1
        starts = np.concatenate([[0], bounds])
        ends = np.concatenate([bounds, [ids.size]])
        for a, b in zip(starts.tolist(), ends.tolist()):
            kcode = int(key[a])
            k = self.keys.get(kcode)
            if k is None:
                k = self.keys[kcode] = _Key(int(lw[a]), None if self.has_columns else int(lh[a]))
            h = 1 << int(lh[a])
            code = int(lw[a]) * 16 + int(lh[a])
            n = b - a
            # block stack first
            n_stack = 0
            if self.has_stacks:
                st = self.stacks.get(code)
                n_stack = min(n, 0 if st is None else st.shape[0])
                if n_stack:
                    xy = self._pop(code, n_stack)
                    gx[a:a + n_stack], gy[a:a + n_stack] = xy[:, 0], xy[:, 1]
                    ok[a:a + n_stack] = True
            req = n - n_stack
            if req == 0:
                continue
            cap = self._capacity(k)
            # offsets in a virtual column space: current superblock, then new ones
            sbs = [k.sb] if k.sb >= 0 else []
            start = k.ptr if k.sb >= 0 else 0
            if k.sb < 0:
                start = 0
            have = (len(sbs) * cap - start) // h
            need_sb = 0 if req <= have else -(-(req - have) * h // cap)
            new = self._draw_superblocks(need_sb)
            if new.size:
                self.sb_key[new] = kcode
            sbs_arr = np.array(sbs + new.tolist(), np.int64)
            fit = min(req, (sbs_arr.size * cap - start) // h) if sbs_arr.size else 0
            if fit:
                q = start + np.arange(fit, dtype=np.int64) * h
                which, local = np.divmod(q, cap)
                x, y = self._to_xy(k, sbs_arr[which], local)
                s0 = a + n_stack
                gx[s0:s0 + fit], gy[s0:s0 + fit] = x, y
                ok[s0:s0 + fit] = True
                end = start + fit * h
                last, ptr = divmod(end, cap)
                if ptr == 0:
                    k.sb, k.ptr = -1, 0
                else:
                    k.sb, k.ptr = int(sbs_arr[last]), int(ptr)
            # superblocks drawn but unused (out of memory mid-way cannot happen; all are used)
        # assignment: write back
        got = ids[ok]
        self.level_w[got] = lw[ok]
        self.level_h[got] = lh[ok]
        self.bx[got] = gx[ok]
        self.by[got] = gy[ok]
        sb = self._sb_of(gx[ok], gy[ok])
        self.sb_live += np.bincount(sb, minlength=self.sb_live.size)
        self._align()
        return np.sort(ids[~ok])

    def _align(self) -> None:
        """End of provisioning: align every S0 fill pointer to its column width (figure 8 (e))."""
        if not self.has_columns:
            return
        for k in self.keys.values():
            if k.sb < 0:
                continue
            cw = 1 << k.lw
            cap = self._capacity(k)
            while k.ptr % cw:
                piece = k.ptr & -k.ptr
                x, y = self._to_xy(k, np.array([k.sb]), np.array([k.ptr]))
                self._push(k.lw * 16 + piece.bit_length() - 1, np.stack([x, y], axis=1))
                k.ptr += piece
            if k.ptr >= cap:
                k.sb, k.ptr = -1, 0

    # ------------------------------------------------------------------ frame
    def update(self, visible: np.ndarray, lw: np.ndarray, lh: np.ndarray, reset: bool = False) -> AllocResult:
        """Allocate blocks for the PVS ``visible`` (unique patch ids) with levels ``lw``/``lh``.

        Patches that keep their level keep their block; ``reset`` repacks everything
        (ignored for S3).
        """
        visible = np.asarray(visible, np.int64)
        lw = np.asarray(lw, np.int64)
        lh = np.asarray(lh, np.int64)
        if not (visible.shape == lw.shape == lh.shape):
            raise ConfigError(f"PatchAllocator.update: visible {visible.shape}, lw {lw.shape}, lh {lh.shape} differ")
        lay = self.layout
        if lw.size and (lw.min() < lay.min_level or lh.min() < lay.min_level or lw.max() > lay.max_level or (lh > lw).any()):
            raise ConfigError(f"PatchAllocator.update: levels must satisfy {lay.min_level} <= lh <= lw <= {lay.max_level}")
        reset = reset and self.can_reset
        was = self.allocated()
        if reset:
            self.resets += 1
            self._clear()
            released = np.setdiff1d(was, visible)
            failed = self._request(visible, lw, lh)
            placed = np.setdiff1d(visible, failed)
            return AllocResult(placed, released, failed, True)
        vis_mask = np.zeros(self.n_patches, bool)
        vis_mask[visible] = True
        left = was[~vis_mask[was]]
        cur_w, cur_h = self.level_w[visible], self.level_h[visible]
        has = cur_w >= 0
        relevel = has & ((cur_w != lw) | (cur_h != lh))
        need = ~has | relevel
        self._release(np.concatenate([left, visible[relevel]]))
        failed = self._request(visible[need], lw[need], lh[need])
        placed = np.setdiff1d(visible[need], failed)
        return AllocResult(placed, np.sort(left), failed, False)

    # ------------------------------------------------------------------ accounting
    def memory(self) -> MemoryBreakdown:
        """Where the atlas texels are (allocated, superblock tails, stacks, inaccessible, free)."""
        lay = self.layout
        m = MemoryBreakdown()
        a = self.allocated()
        m.allocated = int(((1 << self.level_w[a].astype(np.int64)) * (1 << self.level_h[a].astype(np.int64))).sum())
        for code, st in self.stacks.items():
            m.block_stacks += int(st.shape[0]) * (1 << (code // 16)) * (1 << (code % 16))
        for k in self.keys.values():
            if k.sb >= 0:
                m.superblock_tail += (self._capacity(k) - k.ptr) * (1 << k.lw)
        m.inaccessible = int(self.sb_dead_area.sum())
        m.free_superblocks = int(self.free_sbs.size) * lay.superblock_px ** 2
        # S1-S3 grids can leave an unusable remainder (none for power-of-two sizes)
        return m

    def blocks(self, ids: np.ndarray | None = None) -> np.ndarray:
        """(N, 4) int32 ``x, y, w, h`` texel rectangles of ``ids`` (default: all allocated)."""
        ids = self.allocated() if ids is None else np.asarray(ids, np.int64)
        w = (1 << self.level_w[ids].astype(np.int32))
        h = (1 << self.level_h[ids].astype(np.int32))
        return np.stack([self.bx[ids], self.by[ids], w, h], axis=1).astype(np.int32)


@dataclass
class BaselineAllocator:
    """A per-patch Python loop allocator (the "simple CPU baseline" of the benchmark).

    Same S0 layout rules, one block at a time: a block comes from its level's free
    list if one is there, else from the next free position in a superblock owned by
    its column width.  No vectorisation.
    """

    layout: AtlasLayout
    free: dict[tuple[int, int], list[tuple[int, int]]] = field(default_factory=dict)
    fill: dict[int, tuple[int, int]] = field(default_factory=dict)
    next_sb: int = 0
    where: dict[int, tuple[int, int, int, int]] = field(default_factory=dict)

    def update(self, visible: np.ndarray, lw: np.ndarray, lh: np.ndarray) -> int:
        s = self.layout.superblock_px
        vis = {int(p): (int(a), int(b)) for p, a, b in zip(visible.tolist(), lw.tolist(), lh.tolist())}
        for p in list(self.where):
            x, y, a, b = self.where[p]
            if vis.get(p) != (a, b):
                self.free.setdefault((a, b), []).append((x, y))
                del self.where[p]
        failed = 0
        for p, (a, b) in vis.items():
            if p in self.where:
                continue
            fl = self.free.get((a, b))
            if fl:
                x, y = fl.pop()
            else:
                sb, ptr = self.fill.get(a, (-1, 0))
                cap = s * (s >> a)
                ptr = -(-ptr >> b) << b           # align to the block height
                if sb < 0 or ptr + (1 << b) > cap:
                    if self.next_sb >= self.layout.n_superblocks:
                        failed += 1
                        continue
                    sb, ptr = self.next_sb, 0
                    self.next_sb += 1
                col, yy = divmod(ptr, s)
                x = (sb % self.layout.sb_cols) * s + col * (1 << a)
                y = (sb // self.layout.sb_cols) * s + yy
                self.fill[a] = (sb, ptr + (1 << b))
            self.where[p] = (x, y, a, b)
        return failed
