"""Level selection (paper section 4.3): the block size of each visible patch.

- eq. 1: the screen-space length of an edge is ``s = r / f * acos(v1.v2 / |v1||v2|)``
  pixels, with ``r / f`` the display's pixels per radian (width over horizontal field
  of view) and ``v1, v2`` the vectors from the eye to the edge's vertices (a curved
  image plane, so independent of the view direction);
- eq. 2: from the edge lengths, the patch's block area (Heron's formula) and aspect
  ratio (longest width edge over longest height edge in the block layout) give
  ``A = log2(area)`` and ``a = log2(aspect)``, rounded (``a`` to the parity of ``A``)
  and clamped; the level is ``(lw, lh) = ((A + a) / 2, (A - a) / 2)``;
- eq. 3: under memory pressure a bias ``b = log2((I - d) / (S - d))`` is subtracted
  from ``A``: ``I`` is the ideal total block area, ``S`` the atlas space budget and
  ``d`` the area of blocks already at the smallest level.  The paper's ``b`` is negative
  when the atlas has room (``I < S``): the levels go up until the blocks fill it.  With
  ``fill`` (``SasConfig.fill_atlas``, the default) that is what happens: ``b`` is the
  smallest bias, negative or positive, for which the blocks, each rounded up from
  ``A - b``, fit in ``S`` (found by bisection, so the rounding cannot overshoot); so a
  patch never gets fewer texels than it covers pixels while there is room, and the
  sampling density then follows the atlas size, as in the paper's figure 13.  Without
  ``fill`` a patch keeps its ideal level (``A`` rounded up) unless the atlas is short,
  and a positive ``b`` is rounded to nearest.

Blocks are landscape (``lh <= lw``); a patch that is taller than wide is laid out
transposed (its block-local ``u, v`` swapped), flagged per patch.  A hysteresis keeps
a patch's current level while the ideal one is within ``hysteresis`` (log2 units) of
it, so blocks do not move for small changes of distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .allocator import AtlasLayout
from .patches import HEIGHT_EDGES, WIDTH_EDGES, ScenePatches
from .wire import TRI_SLOTS


@dataclass
class LevelChoice:
    """Chosen levels for a list of patches (aligned arrays) and the eq. 3 bias (log2 units)."""

    lw: np.ndarray
    lh: np.ndarray
    transposed: np.ndarray
    bias: float
    ideal_area: float


def patch_world_slots(patches: ScenePatches, ids: np.ndarray, model: np.ndarray) -> np.ndarray:
    """(N, 5, 3) world positions of the slots of patches ``ids``; ``model`` (n_objects, 4, 4)."""
    m = model[patches.object_index[ids]]                     # (N, 4, 4)
    p = patches.slot_pos[ids].astype(np.float64)             # (N, 5, 3)
    return np.einsum("nij,nsj->nsi", m[:, :3, :3], p) + m[:, None, :3, 3]


def edge_px(a: np.ndarray, b: np.ndarray, eye: np.ndarray, px_per_rad: float) -> np.ndarray:
    """Eq. 1: screen-space length in pixels of edges ``a``-``b`` (..., 3) seen from ``eye``."""
    v1, v2 = a - eye, b - eye
    return _rays_px(v1, np.linalg.norm(v1, axis=-1), v2, np.linalg.norm(v2, axis=-1), px_per_rad)


def _rays_px(v1: np.ndarray, n1: np.ndarray, v2: np.ndarray, n2: np.ndarray, px_per_rad: float) -> np.ndarray:
    """:func:`edge_px` from the eye's rays to the two ends and their lengths."""
    c = (v1 * v2).sum(-1) / np.maximum(n1 * n2, 1e-12)
    return px_per_rad * np.arccos(np.clip(c, -1.0, 1.0))


def _heron(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    s = (a + b + c) / 2
    return np.sqrt(np.maximum(s * (s - a) * (s - b) * (s - c), 0.0))


@dataclass
class PatchExtent:
    """Screen-space size of patches (eq. 1), pixels: along the block width ``u`` and height ``v``, and area."""

    width: np.ndarray
    height: np.ndarray
    area: np.ndarray


def patch_extent_px(patches: ScenePatches, ids: np.ndarray, world: np.ndarray, eye: np.ndarray,
                    px_per_rad: float) -> PatchExtent:
    """Eq. 1 per patch: extent along ``u`` and ``v`` (longest edge over its layout length) and area, in pixels."""
    n = ids.size
    width = np.zeros(n)
    height = np.zeros(n)
    area = np.zeros(n)
    size = patches.size[ids]
    for k in (1, 2, 3):
        sel = np.flatnonzero(size == k)
        if sel.size == 0:
            continue
        w = world[sel]
        rays: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        done: dict[tuple[int, int], np.ndarray] = {}

        def ray(slot: int) -> tuple[np.ndarray, np.ndarray]:
            got = rays.get(slot)
            if got is None:
                v = w[:, slot] - eye
                got = rays[slot] = (v, np.linalg.norm(v, axis=-1))
            return got

        def edge(s0: int, s1: int) -> np.ndarray:
            """:func:`edge_px` of slots ``s0``-``s1`` (the same numbers), each pair and each slot's ray once (a
            two-triangle patch's 4 sides and 6 triangle edges are 5 pairs)."""
            key = (min(int(s0), int(s1)), max(int(s0), int(s1)))
            got = done.get(key)
            if got is None:
                got = done[key] = _rays_px(*ray(key[0]), *ray(key[1]), px_per_rad)
            return got

        for s0, s1, du in WIDTH_EDGES[k]:
            width[sel] = np.maximum(width[sel], edge(s0, s1) / du)
        for s0, s1, dv in HEIGHT_EDGES[k]:
            height[sel] = np.maximum(height[sel], edge(s0, s1) / dv)
        tri_area = np.zeros(sel.size)
        for t in TRI_SLOTS[k]:
            if t[0] < 0:
                continue
            tri_area += _heron(edge(t[0], t[1]), edge(t[1], t[2]), edge(t[2], t[0]))
        # a single triangle fills half its block
        area[sel] = tri_area * (2.0 if k == 1 else 1.0)
    return PatchExtent(width, height, area)


def log_size(ext: PatchExtent, texels_per_px: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Continuous ``(A, a)`` per patch from its extent: log2 block area (texels) and log2 aspect (width / height)."""
    area = np.maximum(ext.area * texels_per_px ** 2, 1e-6)
    # the block must also hold the longest edges (slivers have tiny area but long sides)
    area = np.maximum(area, 0.25 * ext.width * ext.height * texels_per_px ** 2)
    a = np.log2(np.maximum(ext.width, 1e-6) / np.maximum(ext.height, 1e-6))
    return np.log2(area), a


def ideal_log_size(patches: ScenePatches, ids: np.ndarray, world: np.ndarray, eye: np.ndarray,
                   px_per_rad: float, texels_per_px: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Continuous ``(A, a)`` per patch: log2 block area (texels) and log2 aspect (width / height)."""
    return log_size(patch_extent_px(patches, ids, world, eye, px_per_rad), texels_per_px)


def footprint(ext: PatchExtent, lw: np.ndarray, lh: np.ndarray, transposed: np.ndarray) -> np.ndarray:
    """(N, 2) block texels per display pixel along atlas x and y (at least 1) for blocks ``2^lw x 2^lh``.

    The block width (atlas x) holds the patch's ``u`` extent, or its ``v`` extent when
    the patch is laid out transposed.
    """
    along_x = np.where(transposed, ext.height, ext.width)
    along_y = np.where(transposed, ext.width, ext.height)
    fx = np.maximum(1.0, 2.0 ** lw.astype(np.float64) / np.maximum(along_x, 1e-6))
    fy = np.maximum(1.0, 2.0 ** lh.astype(np.float64) / np.maximum(along_y, 1e-6))
    return np.stack([fx, fy], 1)


def fill_bias(A: np.ndarray, amin: int, amax: int, budget_texels: float, steps: int = 16,
              min_bias: float | np.ndarray = -math.inf) -> float:
    """The smallest bias ``b`` (log2 units, either sign) for which the blocks ``2^clip(ceil(A - max(b, min_bias)))``
    fit in ``budget_texels``; ``min_bias`` (one, or one per patch) bounds how far a patch's level rises; the
    largest level span when even the smallest blocks do not fit."""
    floor = np.minimum(np.asarray(min_bias, np.float64), 0.0)

    def total(b: float) -> float:
        return float((2.0 ** np.clip(np.ceil(A - np.maximum(b, floor) - 0.01), amin, amax)).sum())

    lo_b, hi_b = max(-float(amax - amin), float(np.min(floor)) if floor.size else 0.0), float(amax - amin)
    if total(lo_b) <= budget_texels:
        return lo_b
    if total(hi_b) > budget_texels:
        return hi_b
    for _ in range(steps):                     # total(lo_b) > budget >= total(hi_b)
        mid = (lo_b + hi_b) / 2
        if total(mid) <= budget_texels:
            hi_b = mid
        else:
            lo_b = mid
    return hi_b


def select_levels(A: np.ndarray, a: np.ndarray, layout: AtlasLayout, budget_texels: float,
                  cur_lw: np.ndarray | None = None, cur_lh: np.ndarray | None = None, cur_t: np.ndarray | None = None,
                  hysteresis: float = 0.75, max_aspect_log: int = 3, fill: bool = False,
                  fill_max_density: float | np.ndarray = math.inf) -> LevelChoice:
    """Eq. 2 and 3: integer levels from continuous ``(A, a)``; ``cur_*`` (-1 = none) enable hysteresis; ``fill``:
    eq. 3's bias in both directions (see the module docstring), up to ``fill_max_density`` (one, or one per
    patch) times a patch's ideal texels per display pixel along each side: a patch's bias is at least
    ``-2 log2`` of it."""
    lo, hi = layout.min_level, layout.max_level
    amin, amax = 2 * lo, 2 * hi
    # without pressure a patch gets at least as many texels as it covers pixels (A rounded up)
    ideal = np.clip(2.0 ** np.ceil(A - 0.01), 2.0 ** amin, 2.0 ** amax)
    at_min = A <= amin
    d = float(at_min.sum()) * 2.0 ** amin
    total = float(ideal.sum())
    bias = 0.0
    if fill:
        min_bias = np.broadcast_to(-2.0 * np.log2(np.asarray(fill_max_density, np.float64)), A.shape)
        bias = fill_bias(A, amin, amax, budget_texels, min_bias=min_bias) if A.size else 0.0
    elif total > budget_texels and budget_texels > d:
        bias = max(0.0, math.log2((total - d) / max(budget_texels - d, 1.0)))
    elif total > budget_texels:
        bias = float(amax)
    Ab = A - (np.maximum(bias, min_bias) if fill else bias)
    transposed = a < 0
    aa = np.abs(a)
    if fill:
        Ar = np.clip(np.ceil(Ab - 0.01), amin, amax).astype(np.int64)
    else:
        Ar = np.clip(np.ceil(A - 0.01) if bias == 0.0 else np.rint(Ab), amin, amax).astype(np.int64)
    ar = np.rint(aa).astype(np.int64)
    odd = (Ar - ar) % 2 == 1
    up = aa > ar
    ar = np.where(odd, np.where(up, ar + 1, ar - 1), ar)
    ar = np.clip(ar, 0, np.minimum(np.minimum(amax - Ar, Ar - amin), 2 * (max_aspect_log // 2) + (Ar % 2)))
    ar = np.where((Ar - ar) % 2 == 1, ar + 1, ar)     # parity after the clamp at 0
    ar = np.minimum(ar, np.minimum(amax - Ar, Ar - amin))
    lw = ((Ar + ar) // 2).astype(np.int8)
    lh = ((Ar - ar) // 2).astype(np.int8)
    if cur_lw is not None and cur_lh is not None:
        has = cur_lw >= 0
        cur_A = cur_lw.astype(np.float64) + cur_lh
        cur_a = cur_lw.astype(np.float64) - cur_lh
        same_orient = (cur_t == transposed) | (cur_lw == cur_lh) | (np.abs(aa) < 0.5) if cur_t is not None else True
        keep = has & (np.abs(np.clip(Ab, amin, amax) - cur_A) <= hysteresis + 0.5) & (np.abs(aa - cur_a) <= hysteresis + 0.5) & same_orient
        lw = np.where(keep, cur_lw, lw).astype(np.int8)
        lh = np.where(keep, cur_lh, lh).astype(np.int8)
        if cur_t is not None:
            transposed = np.where(keep, cur_t, transposed)
    return LevelChoice(lw, lh, np.asarray(transposed, bool), bias, total)
