"""TSS sample patterns and atlas layout (Hladky et al. 2019, sections 3.1-3.3), in numpy.

Everything here is shared by the server half (which mirrors it in GLSL, ``shaders/``),
the client half and the tests; none of it touches GL.

**Tessellation pattern.**  A triangle patch with all four tessellation factors equal
to ``l`` (1..64, equal spacing) spawns :func:`v_count` ``v(l)`` vertices (eq. 1) on
concentric rings: ring ``k`` (0 = the outer edge) holds the points whose smallest
barycentric coordinate is ``k * i(l)`` (``i(l) = 2 / (3 l)``, eq. 3), ``3 (l - 2k)``
of them (the centre alone when ``l`` is even).  :func:`tess_coords` generates them;
a test checks them against this machine's GL.

**L-packing** (eq. 3-4).  A sample with barycentrics ``B`` belongs to the *tip* of
its largest coordinate; within a tip (vertex ``t``, the others ``a = t+1``, ``b =
t+2``) it has a row ``r = lambda_min / i(l)`` (its ring) and a column ``c =
(lambda_med + lambda_min / 2) / o(l)`` (``o(l) = 1 / l``).  The side where
``lambda_a >= lambda_b`` keeps ``(x, y) = (c, r)`` (on or above the block's diagonal,
``r <= c``); the other side is flipped under it, ``(x, y) = (r, c)``.  Each tip fills
a square block of :func:`tip_dim` ``D(l)`` texels: ``ceil((l + 1) / 2)`` for even
levels, one more for odd ones, whose extra column duplicates the first samples of
the neighbouring tip (the paper duplicates one cut row instead; ours makes every
block self-contained, so a bilinear tap never reads a neighbour's block).  Samples
on the borders between tips (edge midpoints, the centre) are written to every block
they border.  Three blocks make an L; two Ls, the second turned by 180 degrees,
interlock into a ``3D x 2D`` pair cell.

**Oversampling** (section 3.3, figure 8).  A slanted triangle (vertex 0 -> 1 its
longest edge, the base; vertex 2 the apex) is split at the foot of its height, at the
fraction ``a`` of the base (eq. 12), into two right triangles with the height ``H``
(samples ~ projected pixels) in common and bases ``w1 ~ a W``, ``w2 ~ (1 - a) W``.
Each is sampled on an orthogonal grid, ``x`` along the base from the foot and ``y``
up the height, one sample per pixel; row ``y = j`` keeps :func:`os_row_lengths`
samples, exactly those a bilinear tap inside the right triangle reads (a staircase;
the samples past its hypotenuse are the paper's conservative extras).  The second
staircase, turned by 180 degrees, interlocks with the first in one rectangle of
:func:`os_sizes` width by ``H + 1`` texels.

That lattice costs two extra samples a row, which is most of a small triangle's
samples: at 640x360 on the default scene the oversampled triangles are 1-4 rows
high and their staircases hold 3.4 samples per covered pixel.  The ``centred`` grid
(ours, ``os_grid = "centred"``; the paper's lattice stays the default) puts the
samples at cell centres, ``h`` rows of ``ceil(w (h - j) / h)``, and the client clamps
each tap to its row's samples (four fetches, :func:`os_centred_taps`) instead of
reading past the hypotenuse: 1.8 samples per covered pixel there, and 8.7% overhead at
1080p against the lattice's 30.5%.

**Atlas layout** (:class:`StableAtlas`, :func:`plan_atlas`): shelves per class (single
texels, each L-packing level's pair cells, oversampling rectangles by height and rounded
width); a triangle keeps its cell while it stays visible in the same class, so the
atlas changes little between frames (P-frames stay cheap).  Single texels, most of a
fine mesh's triangles, sit in cells of ``single_px`` texels square along a Z-order curve
in 16 x 16 tiles aligned to the codec's macroblocks (:func:`single_origins`): slots given
out in id order (mesh neighbours, :func:`morton_order`) share chroma samples and
transform blocks, and a 2 x 2 cell is a chroma sample of its own.  A repack (on overflow,
or every frame in the ``prefix`` mode) places every triangle in (class, id) order: a
deterministic prefix sum, not the paper's atomic binning.  With the server's colour order
(``TssConfig.colour_order``, :attr:`StableAtlas.rank`) an L-packing class is placed in the order of its
triangles' mean luma (:func:`lp_luma`), in bins, then id: cells side by side then share their means, which
the codec's intra prediction and 4 x 4 DC transform pay for when they differ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_LEVEL = 64
"""Largest tessellation factor (GL_MAX_TESS_GEN_LEVEL on every GL 4 implementation)."""

EPS = 1e-4
"""Tolerance of barycentric comparisons (GL's tessellation coordinates are float32)."""

KIND_SINGLE, KIND_LP, KIND_OS = 0, 1, 2
"""Triangle kinds: one texel (tiny), L-packing, oversampling."""


def v_count(level: np.ndarray | int) -> np.ndarray:
    """Vertices (shading samples) a triangle patch with all factors ``level`` spawns (paper eq. 1)."""
    lv = np.asarray(level, np.int64)
    h = lv // 2
    return 3 * (h + 1) * (h + lv % 2) + (lv + 1) % 2


V_TABLE = v_count(np.arange(MAX_LEVEL + 1))
PITCH_LEVEL: dict[int, np.ndarray] = {}
"""Per block (2, 4, 8, 16), :func:`pitch_level` of levels 0..64 (filled after :func:`tip_pitch`)."""
"""``v(l)`` for ``l = 0..64`` (``v(0)`` unused)."""


def level_for(samples: np.ndarray) -> np.ndarray:
    """Smallest level ``l`` in 1..64 whose ``v(l)`` covers ``samples`` (capped at 64)."""
    s = np.asarray(samples, np.float64)
    lv = np.searchsorted(V_TABLE[1:], np.ceil(s), side="left") + 1
    return np.clip(lv, 1, MAX_LEVEL).astype(np.int64)


def own_count(level: np.ndarray | int) -> np.ndarray:
    """The samples a level-``l`` patch holds for itself, its neighbours' shared ones counted once: ``v(l)`` less half
    of the ``3 l`` on its outer ring and a further third of each corner (a mesh vertex is shared by about six
    triangles, an edge sample by two).  ``own_count(1)`` = 0.5 (three corners), ``own_count(2)`` = 3, ``own_count(10)`` = 75
    of 91 (``TssConfig.lp_own``)."""
    lv = np.asarray(level, np.int64)
    return v_count(lv) - 1.5 * lv - 1.0


OWN_TABLE = own_count(np.arange(1, MAX_LEVEL + 1))


def level_for_own(samples: np.ndarray) -> np.ndarray:
    """Smallest level ``l`` in 1..64 whose :func:`own_count` covers ``samples`` (capped at 64)."""
    s = np.asarray(samples, np.float64)
    lv = np.searchsorted(OWN_TABLE, s, side="left") + 1
    return np.clip(lv, 1, MAX_LEVEL).astype(np.int64)


def tip_dim(level: np.ndarray | int) -> np.ndarray:
    """Side ``D(l)`` of one tip block in texels: ``ceil((l + 1) / 2)``, plus one for odd ``l``."""
    lv = np.asarray(level, np.int64)
    return (lv + 2) // 2 + lv % 2


def tip_pitch(level: np.ndarray | int, block: int = 1) -> np.ndarray:
    """Side of the square a tip block takes in the atlas: :func:`tip_dim` rounded up to a multiple of ``block`` texels
    (the codec's transform blocks, ``TssConfig.codec_block``; 1: ``D(l)`` itself), a tip smaller than ``block`` to a
    power of two (1, 2: four of them share a transform block).  The texels past ``D(l)`` hold no sample (the
    gutter fill extends the block's own colours into them, :func:`fill_gutters`)."""
    return _pitch(tip_dim(level), block)


def _pitch(d: np.ndarray, block: int) -> np.ndarray:
    """Tip side ``d`` rounded up to a multiple of ``block``, or below ``block`` to a power of two (a level-2 tip of
    2 x 2 texels padded to 4 x 4 would take four times its texels: the default scene's slivers overflowed the atlas)."""
    d = np.asarray(d, np.int64)
    pow2 = np.left_shift(1, np.ceil(np.log2(np.maximum(d, 1))).astype(np.int64))
    return np.where(d < block, np.minimum(pow2, block), -(-d // block) * block)


def pitch_level(level: np.ndarray | int, block: int) -> np.ndarray:
    """The highest level (up to :data:`MAX_LEVEL`) whose tip block takes the same :func:`tip_pitch` as ``level``'s:
    its samples fill the texels the padding to ``block`` would leave empty (``TssConfig.fill_pitch``)."""
    lv = np.asarray(level, np.int64)
    if block <= 1:
        return lv
    return PITCH_LEVEL[block][np.clip(lv, 0, MAX_LEVEL)]


def max_ring(level: np.ndarray | int) -> np.ndarray:
    """Index of the innermost ring (the centre for even ``l``)."""
    return np.asarray(level, np.int64) // 2


def tess_coords(level: int) -> np.ndarray:
    """(v(l), 3) float64 barycentrics of the tessellator's vertices for all factors ``level``.

    Ring ``k`` is the triangle with corners ``(1 - 2d, d, d)`` (and rotations), ``d =
    k i(l)``; its edge from corner ``e`` to corner ``e + 1`` holds ``l - 2k`` equally
    spaced points, corner ``e`` included.
    """
    pts: list[np.ndarray] = []
    for k in range(level // 2 + 1):
        n = level - 2 * k
        d = 2.0 * k / (3.0 * level)
        if n == 0:
            pts.append(np.array([[1 / 3, 1 / 3, 1 / 3]]))
            continue
        corners = np.array([[1 - 2 * d, d, d], [d, 1 - 2 * d, d], [d, d, 1 - 2 * d]])
        j = np.arange(n)[:, None] / n
        for e in range(3):
            pts.append(corners[e] + j * (corners[(e + 1) % 3] - corners[e]))
    return np.concatenate(pts)


def lp_positions(bary: np.ndarray, level: int) -> list[tuple[int, int, int, int]]:
    """Every ``(sample, tip, x, y)`` an L-packing writes for samples ``bary`` (N, 3) at ``level``.

    The reference for the GLSL in ``shaders/tss_shade.tese``: a sample lands in every
    tip block whose region it lies in or borders (within the block's ``D`` columns).
    """
    D = int(tip_dim(level))
    out = []
    b = np.asarray(bary, np.float64)
    for t in range(3):
        a, q = (t + 1) % 3, (t + 2) % 3
        for s, m, flip in ((a, q, False), (q, a, True)):
            r = np.rint(b[:, m] * 1.5 * level).astype(np.int64)
            c = np.rint((b[:, s] + b[:, m] / 2) * level).astype(np.int64)
            # on ring r: lambda_m is the smallest coordinate (strictly below lambda_s on the flipped side)
            ok = (b[:, m] < b[:, s] - EPS) if flip else (b[:, m] <= b[:, s] + EPS)
            ok &= (c <= D - 1) & (b[:, m] <= b[:, t] + EPS)
            for i in np.flatnonzero(ok):
                x, y = (int(r[i]), int(c[i])) if flip else (int(c[i]), int(r[i]))
                out.append((int(i), t, x, y))
    return out


def lp_lookup(bary: np.ndarray, level: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tip and continuous block position ``(x, y)`` (texel units, sample centres at integers)
    of points ``bary`` (N, 3): the client's decode (``shaders/client.frag``)."""
    b = np.asarray(bary, np.float64)
    t = np.argmax(b, axis=1)
    a, q = (t + 1) % 3, (t + 2) % 3
    ba, bq = b[np.arange(len(b)), a], b[np.arange(len(b)), q]
    side_a = ba >= bq
    s_val = np.where(side_a, ba, bq)
    m_val = np.where(side_a, bq, ba)
    r = np.minimum(m_val * 1.5 * level, float(max_ring(level)))
    c = (s_val + m_val / 2) * level
    x = np.where(side_a, c, r)
    y = np.where(side_a, r, c)
    return t, x, y


def lp_inset_offset(level: np.ndarray | int, inset: float) -> np.ndarray:
    """The smallest barycentric ``d0`` of an inset L-packing lattice (``inset`` > 0; 0: the paper's, on the edges):
    ``inset / (3 (l + 1))``.  At ``inset`` 1 the outer ring sits half a ring spacing inside the triangle (``d0 = (1 -
    3 d0) i(l) / 2``), so no sample lies on an edge or a corner: none is one a neighbouring triangle shades again, and
    the same ``v(l)`` samples cover the triangle ``(l + 1) / l`` times more densely along each side than the paper's
    lattice, whose ``3 l`` outer samples (``3 l / v(l)``, 14 % of a level-13 patch) are shared.  Level 1's three
    samples are then ``(2/3, 1/6, 1/6)`` and its rotations.  The client extrapolates past the outer ring
    (:func:`lp_reconstruct`), exact for linear shading."""
    return float(inset) / (3.0 * (np.asarray(level, np.float64) + 1.0))


def lp_inset_coords(bary: np.ndarray, level: int, inset: float) -> np.ndarray:
    """Where the sample of the lattice point ``bary`` (N, 3) is shaded with the lattice inset (:func:`lp_inset_offset`):
    ``d0 + (1 - 3 d0) bary``; it is stored where :func:`lp_positions` puts ``bary`` (``shaders/tss_shade.tese``)."""
    d0 = float(lp_inset_offset(level, inset))
    return d0 + (1.0 - 3.0 * d0) * np.asarray(bary, np.float64)


def lp_reconstruct(blocks: np.ndarray, bary: np.ndarray, level: int, inset: float = 0.0) -> np.ndarray:
    """The client's L-packing reconstruction (``shaders/client.frag``) at points ``bary`` (N, 3) from the three tip
    blocks ``blocks`` (3, D, D, ...) of one triangle at ``level``: (N, ...) values.

    Each side of a tip block's diagonal is an affine lattice of its own (its rows are ring edges), so a bilinear tap
    is exact for linear shading except on a diagonal cell, whose fourth texel holds the mirrored side's sample, a
    third of a sample step from where the tap takes it to be, and in the innermost ring of an odd level, which has no
    row of its own.  There the point is interpolated linearly on the three samples around it: on a diagonal cell the
    two diagonal texels and the one on the point's side, in the innermost ring its three corners (texels ``(k, k)``,
    ``(k + 1, k)`` and ``(k, k + 1)`` of the block, ``k = level // 2``).  Exact for linear shading at every level.

    ``inset`` > 0 (:func:`lp_inset_offset`): the point is first moved into the inset lattice's coordinates, ``(bary -
    d0) / (1 - 3 d0)``, whose smallest coordinate is down to ``-1 / (3 l)`` (half a ring) near the edges; there the
    block's edge cell is extrapolated (bilinear, or the diagonal cell's three samples), still exact for linear
    shading."""
    b = np.asarray(bary, np.float64)
    if inset > 0:
        d0 = float(lp_inset_offset(level, inset))
        b = (b - d0) / (1.0 - 3.0 * d0)
    n = np.arange(len(b))
    D = int(tip_dim(level))
    k = int(max_ring(level))
    t, x, y = lp_lookup(b, level)
    a, q = (t + 1) % 3, (t + 2) % 3
    m_val = np.minimum(b[n, a], b[n, q])
    lo, hi = (0, max(D - 2, 0)) if inset > 0 else (None, D - 1)
    x0 = np.clip(np.floor(x).astype(np.int64), lo, hi)
    y0 = np.clip(np.floor(y).astype(np.int64), lo, hi)
    fx, fy = x - x0, y - y0
    x1, y1 = np.minimum(x0 + 1, D - 1), np.minimum(y0 + 1, D - 1)
    ex = (slice(None),) + (None,) * (blocks.ndim - 3)
    T = (lambda xx, yy: blocks[t, yy, xx])
    fx_, fy_ = fx[ex], fy[ex]
    out = (T(x0, y0) * (1 - fx_) * (1 - fy_) + T(x1, y0) * fx_ * (1 - fy_) + T(x0, y1) * (1 - fx_) * fy_
           + T(x1, y1) * fx_ * fy_)
    lower = (fx >= fy)[ex]
    tri = np.where(lower, (1 - fx_) * T(x0, y0) + (fx_ - fy_) * T(x1, y0) + fy_ * T(x1, y1),
                   (1 - fy_) * T(x0, y0) + (fy_ - fx_) * T(x0, y1) + fx_ * T(x1, y1))
    out = np.where((x0 == y0)[ex], tri, out)
    if level % 2:
        d = 2.0 * k / (3.0 * level)
        w = [((b[n, j] - d) / (1.0 - 3.0 * d))[ex] for j in (t, a, q)]
        kk = np.full(len(b), k)
        centre = w[0] * T(kk, kk) + w[1] * T(kk + 1, kk) + w[2] * T(kk, kk + 1)
        # level 1 inset: its three samples everywhere (its block's fourth texel is no sample to extrapolate with)
        out = np.where((m_val * 1.5 * level > k)[ex] | (inset > 0 and level == 1), centre, out)
    return out


def os_linear_id(bary: np.ndarray, level: int) -> np.ndarray:
    """(N,) consecutive thread ids ``0 .. v(l) - 1`` of tessellator vertices ``bary`` (N, 3) at ``level``.

    Ring ``k`` starts at ``3 k (l - k + 1)``; on it, the vertex on edge ``e`` (corner
    ``e`` included, corner ``e + 1`` not) ``j`` steps from corner ``e`` is ``e (l - 2k) + j``.
    Mirrors the oversampling threads of ``shaders/tss_shade.tese`` (our derivation of
    the paper's eq. 6-8 for the ring pattern of :func:`tess_coords`).
    """
    b = np.asarray(bary, np.float64)
    k = np.rint(b.min(axis=1) * 1.5 * level).astype(np.int64)
    n = level - 2 * k
    out = 3 * k * (level - k + 1)
    d = k * 2.0 / (3.0 * level)
    found = n == 0
    for e in range(3):
        j = np.rint((b[:, (e + 1) % 3] - d) * level).astype(np.int64)
        hit = ~found & (np.abs(b[:, (e + 2) % 3] - d) < 1.0 / (6.0 * level)) & (j >= 0) & (j < n)
        out = np.where(hit, out + e * n + j, out)
        found |= hit
    return np.where(found, out, -1)


OS_GRIDS = ("centred", "paper")
"""Oversampling grids: ``paper`` (samples on the integer lattice, each row long enough for a bilinear tap,
figure 8) and ``centred`` (samples at cell centres, one row per unit of height, taps clamped to each row)."""


def os_rows(h: np.ndarray | int, grid: str = "paper") -> np.ndarray:
    """Rows of an oversampled staircase of height ``h``: ``h + 1`` on the paper's lattice, ``h`` centred."""
    return np.asarray(h, np.int64) + (1 if grid == "paper" else 0)


def os_row_lengths(w: int, h: int, grid: str = "paper") -> np.ndarray:
    """Samples in each row of an oversampled staircase of base ``w`` and height ``h``.

    ``paper`` (``h + 1`` rows): row ``j`` holds ``x = 0 .. floor(w (1 - max(j - 1, 0) / h)) + 1``,
    every sample a bilinear tap at a point of the triangle (``x / w + y / h <= 1``) reads.
    ``centred`` (``h`` rows): row ``j`` holds the cell centres ``x + 1/2`` of the band
    ``j <= y <= j + 1``, ``ceil(w (h - j) / h)`` of them (at least one); a tap beyond a
    row's last centre takes that sample.
    """
    if grid == "paper":
        j = np.arange(h + 1)
        return (w * (h - np.maximum(j - 1, 0))) // h + 2      # integer arithmetic, as the shader
    j = np.arange(h)
    return np.maximum((w * (h - j) + h - 1) // h, 1)


def os_sizes(w1: np.ndarray, w2: np.ndarray, h: np.ndarray, grid: str = "paper") -> tuple[np.ndarray, np.ndarray]:
    """Per triangle, the width of the rectangle holding its two staircases (the second turned by 180 degrees,
    interlocked with the first) and their samples in all (:func:`os_row_lengths` per row)."""
    pw = np.zeros(h.size, np.int64)
    ns = np.zeros(h.size, np.int64)
    for hh in np.unique(h).tolist():
        k = np.flatnonzero(h == hh)
        if grid == "paper":
            rows = hh - np.maximum(np.arange(hh + 1) - 1, 0)              # (hh + 1,)
            l1 = (w1[k, None] * rows) // hh + 2
            l2 = (w2[k, None] * rows) // hh + 2
        else:
            rows = hh - np.arange(hh)                                     # (hh,)
            l1 = np.maximum((w1[k, None] * rows + hh - 1) // hh, 1)
            l2 = np.maximum((w2[k, None] * rows + hh - 1) // hh, 1)
        pw[k] = (l1 + l2[:, ::-1]).max(axis=1)
        ns[k] = l1.sum(axis=1) + l2.sum(axis=1)
    return pw, ns


@dataclass
class AtlasPlan:
    """Where every live triangle's samples go.  Arrays are per triangle in ``ids`` order.

    ``kind`` (N,) :data:`KIND_SINGLE` / :data:`KIND_LP` / :data:`KIND_OS`; ``level``
    (N,) tessellation level (LP) or the level spawning both staircases (OS); ``slot``
    (N,) index within the triangle's bin (single texels, LP levels); ``origin`` (N, 3, 2)
    int64 texel origin of each tip block (LP), of the rectangle (OS, first row; its
    width in ``origin[:, 1, 0]``) or the texel (single); ``w``/``w2``/``h`` (N,) OS
    staircase bases and height, ``a`` (N,) the split fraction; ``samples`` (N,)
    samples shaded;
    ``bins`` {level: shelves (x, y)} (0 = the single-texel rows); ``height`` texel rows
    used; ``overflow`` True when it did not fit the atlas; ``repacked`` when every
    triangle was (re)placed.
    """

    kind: np.ndarray
    level: np.ndarray
    slot: np.ndarray
    origin: np.ndarray
    w: np.ndarray
    w2: np.ndarray
    h: np.ndarray
    a: np.ndarray
    samples: np.ndarray
    bins: dict[int, list[tuple[int, int]]]
    height: int
    overflow: bool
    repacked: bool = True
    single_px: int = 1
    block: int = 1


for _b in (2, 4, 8, 16):
    _p = _pitch((np.arange(MAX_LEVEL + 1) + 2) // 2 + np.arange(MAX_LEVEL + 1) % 2, _b)
    PITCH_LEVEL[_b] = np.array([max(m for m in range(1, MAX_LEVEL + 1) if _p[m] == _p[max(lv, 1)]) for lv in range(MAX_LEVEL + 1)],
                               np.int64)


def lp_per_shelf(level: int, strip: int, block: int = 1) -> int:
    """L-packing slots (half pair cells) on one shelf of ``2 P`` rows and ``strip`` texels (``P``: :func:`tip_pitch`)."""
    return 2 * max(1, strip // (3 * int(tip_pitch(level, block))))


def lp_tip_origins(level: int, slot: np.ndarray, shelves: np.ndarray, strip: int, block: int = 1) -> np.ndarray:
    """(N, 3, 2) tip-block origins of L-packing slots ``slot`` of ``level``, whose bin's shelves start at texels
    ``shelves`` (S, 2) (x, y), each ``strip`` texels wide; tip blocks ``block``-aligned (:func:`tip_pitch`)."""
    D = int(tip_pitch(level, block))
    per = lp_per_shelf(level, strip, block) // 2
    pair, half = slot // 2, slot % 2
    sh = np.asarray(shelves, np.int64).reshape(-1, 2)[pair // per]
    X = sh[:, 0] + (pair % per) * 3 * D
    Y = sh[:, 1]
    o = np.zeros((slot.size, 3, 2), np.int64)
    up = half == 0
    o[:, 0] = np.where(up[:, None], np.stack([X, Y], 1), np.stack([X + 2 * D, Y + D], 1))
    o[:, 1] = np.where(up[:, None], np.stack([X + D, Y], 1), np.stack([X + D, Y + D], 1))
    o[:, 2] = np.where(up[:, None], np.stack([X, Y + D], 1), np.stack([X + 2 * D, Y], 1))
    return o


LADDER = np.array([1, 2, 3, 4, 5, 6, 8, 10, 12, 14, 16, 20, 24, 28, 32, 40, 48, 56, 64, 80, 96, 112, 128, 160, 192, 224, 256,
                   320, 384, 448, 512, 640, 768, 896, 1024, 1280, 1536, 1792, 2048, 2560, 3072, 3584, 4096], np.int64)
"""Cell sizes of the stable layout: L-packing levels and oversampling heights are rounded up to this ladder,
oversampling widths to 8 times it, so a few dozen classes share the shelves (at most 25% of a cell is slack)."""


def ladder(v: np.ndarray | int) -> np.ndarray:
    """``v`` rounded up to :data:`LADDER`."""
    return LADDER[np.minimum(np.searchsorted(LADDER, np.asarray(v, np.int64), side="left"), LADDER.size - 1)]


def lp_cell_level(level: np.ndarray | int, block: int = 1) -> np.ndarray:
    """The level whose pair cells hold L-packed triangles of ``level``: the ladder's next step, or with ``block`` > 1
    (``codec_block``) the highest level of the same :func:`tip_pitch` (every level whose tip blocks take the same
    texels shares the cells, so a triangle whose level moves within its pitch keeps its cell)."""
    return ladder(level) if block <= 1 else pitch_level(level, block)


def strip_width(width: int) -> int:
    """Width of the atlas's shelf strips: the width cut into as many strips of at least 128 texels as fit (an
    L-packed pair at level 64 is 99 wide), rounded down to whole :data:`SINGLE_TILE` tiles when that leaves 128."""
    s = width // max(1, width // 128)
    return s - s % SINGLE_TILE if s - s % SINGLE_TILE >= 128 else s


SINGLE_TILE = 16
"""Single texels live in tiles of this many texels square (a codec macroblock), on shelves of one tile row whose
first row is a multiple of it; within a tile the cells follow a Z-order curve."""
SINGLE_PX = (1, 2, 4)
"""Sides (texels) a single texel's cell may have: a cell of 2 x 2 on even texels is one 4:2:0 chroma sample."""


def morton_decode2(k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of Z-order index ``k`` (even bits x, odd bits y)."""
    k = np.asarray(k, np.int64)
    x = np.zeros_like(k)
    y = np.zeros_like(k)
    for b in range(16):
        x |= ((k >> (2 * b)) & 1) << b
        y |= ((k >> (2 * b + 1)) & 1) << b
    return x, y


def morton_order(points: np.ndarray) -> np.ndarray:
    """Indices sorting ``points`` (N, 3) along a 3D Z-order curve over their bounding box (10 bits per axis,
    ties by index): mesh neighbours end up near each other in the order."""
    p = np.asarray(points, np.float64)
    if p.shape[0] == 0:
        return np.zeros(0, np.int64)
    lo, hi = p.min(axis=0), p.max(axis=0)
    q = np.clip(((p - lo) / np.maximum(hi - lo, 1e-12) * 1023.0).astype(np.int64), 0, 1023)
    code = np.zeros(p.shape[0], np.int64)
    for b in range(10):
        for a in range(3):
            code |= ((q[:, a] >> b) & 1) << (3 * b + a)
    return np.lexsort((np.arange(p.shape[0]), code))


def single_per_shelf(strip: int, px: int) -> int:
    """Single-texel cells (``px`` texels square) on one shelf: a row of :data:`SINGLE_TILE` tiles ``strip`` wide."""
    return max(1, strip // SINGLE_TILE) * (SINGLE_TILE // px) ** 2


def single_origins(slot: np.ndarray, shelves: np.ndarray, strip: int, px: int) -> np.ndarray:
    """(N, 2) first texel of single-texel cells ``slot`` (``px`` texels square) on shelves ``shelves`` (S, 2):
    shelf ``slot // per_shelf``, tile after tile along it, each tile's cells in Z order."""
    slot = np.asarray(slot, np.int64)
    per_tile = (SINGLE_TILE // px) ** 2
    k = slot % single_per_shelf(strip, px)
    sh = np.asarray(shelves, np.int64).reshape(-1, 2)[slot // single_per_shelf(strip, px)]
    u, v = morton_decode2(k % per_tile)
    return np.stack([sh[:, 0] + (k // per_tile) * SINGLE_TILE + u * px, sh[:, 1] + v * px], 1)


APPEND_BELOW = 0.8
"""Below this load (:meth:`StableAtlas.load`) new triangles take new shelves rather than cells others left (default
scene, 1 s walk, 320x180: at 0.5 it took 3 % more bits at 1 sample per pixel; with no limit the atlas overflowed at 3
samples per pixel, repacking mid-GOP, 43 % more bits)."""


class StableAtlas:
    """Atlas memory in which a triangle keeps its place while it stays visible (the codec-friendly layout).

    The atlas is cut into vertical strips of :func:`strip_width`; space is handed out in
    shelves (one strip wide, or the whole width for cells wider than a strip) per
    *class*: single texels (shelves of one row of 16 x 16 tiles, starting on a multiple
    of 16 rows, cells ``single_px`` square, :func:`single_origins`), L-packing pair cells per cell level
    (:func:`lp_cell_level`; shelves of ``2 D`` rows), oversampling rectangles per
    rounded rows and width (:data:`LADDER`; shelves of that many rows).  A triangle whose class is unchanged keeps its cell; one that leaves or
    changes class frees it, and new ones take the lowest cell of their class unused since
    the last repack, or one on a new shelf in the least filled strip while the atlas is less
    than :data:`APPEND_BELOW` full; past that, or when no shelf fits, a cell that another
    triangle left (:meth:`_alloc`).  :meth:`place` with ``reset`` (or when space
    runs out) repacks every live triangle compactly in (class, id) order: the
    prefix-sum layout, which is deterministic; the server then sends an I-frame.
    """

    def __init__(self, n_triangles: int, width: int, height: int, single_px: int = 1, block: int = 1) -> None:
        self.width, self.height = width, height
        self.strip = strip_width(width)
        self.single_px = single_px
        self.block = block
        """Codec block alignment (``TssConfig.codec_block``): L-packing tip blocks take :func:`tip_pitch` texels, and
        L-packing and oversampling shelves start on rows (and oversampling cells span rows) in multiples of it."""
        self.cls = np.full(n_triangles, -1, np.int64)      # class index per triangle (-1: none)
        self.cell = np.full(n_triangles, -1, np.int64)
        self.rank: np.ndarray | None = None
        """Per triangle id, where a repack puts it within its L-packing class, before its id (None: id order alone):
        the server's colour order (``TssConfig.colour_order``, :func:`lp_luma`)."""
        self._reset_state()

    def _reset_state(self) -> None:
        self.keys: list[tuple[int, ...]] = []
        self.index: dict[tuple[int, ...], int] = {}
        self.shelves: list[list[tuple[int, int]]] = []    # per class: (x, y) of its shelves
        self.free: list[list[int]] = []                   # per class: free cells (sorted descending; pop() takes the lowest)
        self.fresh: list[list[int]] = []                  # per class: cells never used since the last repack (descending)
        self.cursor = np.zeros(max(1, self.width // self.strip), np.int64)   # first free row per strip
        self._load = 0.0                                  # load(), kept as the cursor moves (_alloc asks per cell)
        self.cls[:] = -1
        self.cell[:] = -1

    @property
    def rows(self) -> int:
        """Rows in use (the deepest strip)."""
        return int(self.cursor.max())

    def cell_size(self, key: tuple[int, ...]) -> tuple[int, int, int]:
        """(cell width, shelf height, cells per shelf) of class ``key``."""
        if key[0] == KIND_SINGLE:
            return self.single_px, SINGLE_TILE, single_per_shelf(self.strip, self.single_px)
        if key[0] == KIND_LP:
            D = int(tip_pitch(key[1], self.block))
            return 3 * D, 2 * D, lp_per_shelf(key[1], self.strip, self.block)
        cw = min(key[2], self.width)
        return cw, key[1], max(1, (self.strip if cw <= self.strip else self.width) // cw)   # key: (OS, rows, width)

    def _class(self, key: tuple[int, ...]) -> int:
        c = self.index.get(key)
        if c is None:
            c = self.index[key] = len(self.keys)
            self.keys.append(key)
            self.shelves.append([])
            self.free.append([])
            self.fresh.append([])
        return c

    def _shelf(self, cw: int, sh: int, align: int = 1) -> tuple[int, int] | None:
        if cw > self.strip:                                # a full-width shelf below every strip
            y = -(-int(self.cursor.max()) // align) * align
            if y + sh > self.height:
                return None
            self.cursor[:] = y + sh
            self._load = float(self.cursor.mean()) / self.height
            return 0, y
        s = int(np.argmin(self.cursor))
        y = -(-int(self.cursor[s]) // align) * align
        if y + sh > self.height:
            return None
        self.cursor[s] = y + sh
        self._load = float(self.cursor.mean()) / self.height
        return s * self.strip, y

    def _alloc(self, c: int) -> int:
        """A cell of class ``c``: the lowest never used since the last repack (on a new shelf if need be, while the
        atlas is less than :data:`APPEND_BELOW` full), else the lowest one a triangle left (-1 when there is none).
        Between repacks new triangles thus gather at their shelves' ends and the cells left behind keep their old
        texels: a P-frame codes a few compact regions, not scattered cells."""
        if not self.fresh[c] and (not self.free[c] or self.load() < APPEND_BELOW):
            cw, sh, per = self.cell_size(self.keys[c])
            at = self._shelf(cw, sh, SINGLE_TILE if self.keys[c][0] == KIND_SINGLE else self.block)
            if at is not None:
                base = len(self.shelves[c]) * per
                self.shelves[c].append(at)
                self.fresh[c] = list(range(base + per - 1, base - 1, -1))
        if self.fresh[c]:
            return self.fresh[c].pop()
        return self.free[c].pop() if self.free[c] else -1

    def load(self) -> float:
        """Mean rows in use per strip over the atlas height."""
        return self._load

    def place(self, ids: np.ndarray, keys: list[tuple[int, ...]], reset: bool = False) -> tuple[bool, bool]:
        """Give every live triangle ``ids`` (sorted) of class ``keys`` a cell; returns ``(fits, repacked)``."""
        live = np.zeros(self.cls.size, bool)
        live[ids] = True
        repacked = reset
        if not reset:
            for k in dict.fromkeys(keys):        # new classes in order of first use, as one lookup per key made them
                self._class(k)
            want = np.fromiter(map(self.index.__getitem__, keys), np.int64, len(keys))
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
            t_new, c_new = ids[new], want[new]
            cells = []
            for c in c_new.tolist():
                k = self._alloc(c)
                if k < 0:
                    repacked = True         # everything is placed again below
                    break
                cells.append(k)
            if not repacked:
                self.cls[t_new], self.cell[t_new] = c_new, cells
        if repacked:
            self._reset_state()
            rank = (self.rank[ids] if self.rank is not None else np.zeros(ids.size, np.int64)).tolist()
            order = sorted(range(len(keys)),
                           key=lambda i: (keys[i], rank[i] if keys[i][0] == KIND_LP else 0, int(ids[i])))
            cls, cells = [], []
            for i in order:
                c = self._class(keys[i])
                k = self._alloc(c)
                if k < 0:
                    break
                cls.append(c)
                cells.append(k)
            at = ids[np.asarray(order[:len(cells)], np.int64)]
            self.cls[at], self.cell[at] = cls, cells      # those placed before a failure keep their cells, as before
            if len(cells) < len(order):
                return False, True
        return True, repacked

    def origins(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) first texel of each triangle's cell and (N,) its slot within its class (single texels, L-packing)."""
        out = np.zeros((ids.size, 2), np.int64)
        slot = self.cell[ids].copy()
        for c, key in enumerate(self.keys):
            sel = np.flatnonzero(self.cls[ids] == c)
            if sel.size == 0:
                continue
            cw, sh, per = self.cell_size(key)
            k = self.cell[ids[sel]]
            if key[0] == KIND_SINGLE:
                out[sel] = single_origins(k, np.asarray(self.shelves[c]), self.strip, self.single_px)
                continue
            if key[0] == KIND_LP:
                k = k // 2
                per //= 2
            at = np.asarray(self.shelves[c], np.int64).reshape(-1, 2)[k // per]
            out[sel, 0] = at[:, 0] + (k % per) * cw
            out[sel, 1] = at[:, 1]
        return out, slot

    def bins(self) -> dict[int, list[tuple[int, int]]]:
        """Shelves per single-texel (0) and L-packing level class: what the client needs to find a slot."""
        return {(0 if k[0] == KIND_SINGLE else k[1]): list(self.shelves[c]) for c, k in enumerate(self.keys)
                if k[0] in (KIND_SINGLE, KIND_LP) and self.shelves[c]}


def lp_luma(rgba: np.ndarray, plan: AtlasPlan) -> tuple[np.ndarray, np.ndarray]:
    """The mean luma (Rec. 601 weights, 8-bit levels) of the samples each L-packed triangle of ``plan`` wrote into the
    atlas ``rgba`` (H, W, 4) uint8 (texels of alpha > 127 in its three ``D(l)``-square tip blocks): (M,) indices into
    the plan's rows and (M,) lumas (NaN where no texel was written).  The server's colour order
    (``TssConfig.colour_order``) ranks a repack's cells by it."""
    lp = np.flatnonzero(plan.kind == KIND_LP)
    out = np.full(lp.size, np.nan)
    D = tip_dim(plan.level[lp])
    wts = np.array([0.299, 0.587, 0.114], np.float32)
    for d in np.unique(D).tolist():
        sel = np.flatnonzero(D == d)
        o = plan.origin[lp[sel]]                                                      # (n, 3, 2)
        yy = o[:, :, 1, None, None] + np.arange(d)[None, None, :, None]
        xx = o[:, :, 0, None, None] + np.arange(d)[None, None, None, :]
        px = rgba[yy, xx]                                                             # (n, 3, d, d, 4)
        w = px[..., 3] > 127
        y = px[..., :3].astype(np.float32) @ wts
        n = w.sum(axis=(1, 2, 3))
        out[sel] = np.where(n > 0, (y * w).sum(axis=(1, 2, 3)) / np.maximum(n, 1), np.nan)
    return lp, out


def plan_atlas(atlas: StableAtlas, ids: np.ndarray, kind: np.ndarray, level: np.ndarray, w: np.ndarray, w2: np.ndarray,
               h: np.ndarray, a: np.ndarray, reset: bool = False, grid: str = "paper") -> AtlasPlan:
    """Lay out triangles ``ids`` (sorted) in ``atlas``: keep places where the class is unchanged (or repack all with
    ``reset``); ``plan.overflow`` when they do not fit even repacked, ``plan.repacked`` when they were repacked.
    ``grid``: the oversampling grid (:data:`OS_GRIDS`)."""
    n = ids.size
    pw, ns = os_sizes(w, w2, h, grid)
    samples = np.where(kind == KIND_SINGLE, 1, np.where(kind == KIND_LP, v_count(level), ns)).astype(np.int64)
    lvl = np.where(kind == KIND_OS, level_for(samples), level).astype(np.int64)
    cw = 8 * ladder(-(-pw // 8))
    ch = ladder(os_rows(h, grid))
    ch = -(-ch // atlas.block) * atlas.block
    cl = lp_cell_level(np.maximum(level, 1), atlas.block)
    keys = [(KIND_SINGLE,) if k == KIND_SINGLE else (KIND_LP, int(lv)) if k == KIND_LP else (KIND_OS, int(hh), int(c))
            for k, lv, hh, c in zip(kind.tolist(), cl.tolist(), ch.tolist(), cw.tolist())]
    fits, repacked = atlas.place(ids, keys, reset)
    origin = np.zeros((n, 3, 2), np.int64)
    slot = np.zeros(n, np.int64)
    bins = atlas.bins() if fits else {}
    if fits:
        o, slot = atlas.origins(ids)
        origin[:, 0] = o
        lp = kind == KIND_LP
        for lv in np.unique(cl[lp]).tolist():
            sel = np.flatnonzero(lp & (cl == lv))
            origin[sel] = lp_tip_origins(lv, slot[sel], np.asarray(bins[lv]), atlas.strip, atlas.block)
        origin[kind == KIND_OS, 1, 0] = pw[kind == KIND_OS]
    return AtlasPlan(kind, lvl, slot, origin, w, w2, h, a, samples, bins, atlas.rows, not fits, repacked, atlas.single_px,
                     atlas.block)


def os_sample_bary(x: np.ndarray, y: np.ndarray, half: np.ndarray, w: np.ndarray, w2: np.ndarray, h: np.ndarray,
                   a: np.ndarray, grid: str = "paper") -> np.ndarray:
    """(N, 3) screen-space barycentrics (base start, base end, apex) of staircase samples ``(x, y)`` of ``half`` 0/1
    (the sample's column and row; ``centred`` samples sit half a step further along both)."""
    if grid != "paper":
        x, y = x + 0.5, y + 0.5
    foot = np.stack([1 - a, a, np.zeros_like(a)], -1)
    up = np.stack([-(1 - a), -a, np.ones_like(a)], -1)
    along = np.where((half == 0)[:, None], np.stack([a, -a, np.zeros_like(a)], -1) / np.maximum(w, 1)[:, None],
                     np.stack([-(1 - a), 1 - a, np.zeros_like(a)], -1) / np.maximum(w2, 1)[:, None])
    return foot + x[:, None] * along + (y / h)[:, None] * up


def os_lookup(bary: np.ndarray, w: np.ndarray, w2: np.ndarray, h: np.ndarray, a: np.ndarray, pw: np.ndarray) -> np.ndarray:
    """(N, 2) continuous texel offsets from the rectangle's origin of points ``bary`` (the client's decode)."""
    b = np.asarray(bary, np.float64)
    y = b[:, 2] * h
    s = b[:, 1] + b[:, 2] * a
    first = s <= a
    x1 = np.where(a > 0, (a - s) / np.where(a > 0, a, 1) * w, 0.0)
    x2 = np.where(a < 1, (s - a) / np.where(a < 1, 1 - a, 1) * w2, 0.0)
    return np.where(first[:, None], np.stack([x1, y], -1), np.stack([pw - 1 - x2, h - y], -1))


def os_centred_taps(bary: np.ndarray, w: np.ndarray, w2: np.ndarray, h: np.ndarray, a: np.ndarray,
                    pw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The client's decode on the ``centred`` grid: for points ``bary`` (N, 3), four texels (N, 4, 2) (x, y from the
    rectangle's origin) and their weights (N, 4): two rows, in each the two samples around the point's column,
    clamped to the row's samples; mirrors ``shaders/client.frag``."""
    b = np.asarray(bary, np.float64)
    h = np.asarray(h, np.int64)
    s = b[:, 1] + b[:, 2] * a
    first = s <= a
    x = np.where(first, np.where(a > 0, (a - s) / np.where(a > 0, a, 1) * w, 0.0),
                 np.where(a < 1, (s - a) / np.where(a < 1, 1 - a, 1) * w2, 0.0))
    W = np.where(first, w, w2).astype(np.int64)
    yc = np.clip(b[:, 2] * h - 0.5, 0.0, np.maximum(h - 1, 0).astype(np.float64))
    j0 = np.floor(yc).astype(np.int64)
    j1 = np.minimum(j0 + 1, h - 1)
    fy = yc - j0
    texels = np.zeros((b.shape[0], 4, 2), np.int64)
    weights = np.zeros((b.shape[0], 4))
    for r, (j, wy) in enumerate(((j0, 1.0 - fy), (j1, fy))):
        n = np.maximum((W * (h - j) + h - 1) // np.maximum(h, 1), 1)
        xc = np.clip(x - 0.5, 0.0, (n - 1).astype(np.float64))
        i0 = np.floor(xc).astype(np.int64)
        i1 = np.minimum(i0 + 1, n - 1)
        fx = xc - i0
        for c, (i, wx) in enumerate(((i0, 1.0 - fx), (i1, fx))):
            texels[:, 2 * r + c] = np.where(first[:, None], np.stack([i, j], -1), np.stack([pw - 1 - i, h - 1 - j], -1))
            weights[:, 2 * r + c] = wx * wy
    return texels, weights


def layout_attributes(kind: np.ndarray, origin: np.ndarray, w: np.ndarray, w2: np.ndarray, h: np.ndarray, a: np.ndarray,
                      samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two vec4 layout attributes per triangle both halves' shaders read (``in_o0``, ``in_o1``).

    L-packing: tip 0 xy, tip 1 xy | tip 2 xy, 0, 0.  Oversampling: rectangle xy, its
    width, ``a`` | ``w1``, ``w2``, ``h``, samples.  Single texel: texel xy, ...
    """
    n = kind.size
    o = origin.astype(np.float64)
    os_ = (kind == KIND_OS)[:, None]
    o0 = np.where(os_, np.stack([o[:, 0, 0], o[:, 0, 1], o[:, 1, 0], a], 1), np.concatenate([o[:, 0], o[:, 1]], 1))
    o1 = np.where(os_, np.stack([w, w2, h, samples], 1).astype(np.float64), np.concatenate([o[:, 2], np.zeros((n, 2))], 1))
    return o0, o1


def dilate_in_blocks(col: np.ndarray, w: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray]:
    """Texels of ``col`` (H, W, 3) float with ``w`` (H, W) False take the mean of their written 4-neighbours in the
    same ``block``-aligned square, step after step (``2 (block - 1)`` steps: a block with any written texel ends up
    full).  A tip block padded to the codec's transform block (:func:`tip_pitch`) is then extended by its own edge
    colours, not by a fill across the transform's border.  Returns the new colours and the new written mask."""
    col, w = col.copy(), w.copy()
    H, W = w.shape
    for _ in range(2 * (block - 1)):
        acc = np.zeros_like(col)
        cnt = np.zeros((H, W), np.float32)
        for axis in (0, 1):
            n = (H, W)[axis]
            same = (np.arange(n - 1) + 1) % block != 0          # i and i + 1 in the same block
            sl_lo = (slice(0, n - 1), slice(None)) if axis == 0 else (slice(None), slice(0, n - 1))
            sl_hi = (slice(1, n), slice(None)) if axis == 0 else (slice(None), slice(1, n))
            m = same[:, None] if axis == 0 else same[None, :]
            # from i + 1 into i, and from i into i + 1
            for dst, src in ((sl_lo, sl_hi), (sl_hi, sl_lo)):
                take = w[src] & m
                acc[dst] += np.where(take[..., None], col[src], 0.0)
                cnt[dst] += take
        new = ~w & (cnt > 0)
        if not new.any():
            break
        col[new] = acc[new] / cnt[new][:, None]
        w = w | new
    return col, w


def _push_pull(c: np.ndarray, w: np.ndarray, finest: int) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """Push-pull over colour sums ``c`` (h, w, 3) float32 with weights ``w`` (h, w): push builds the pyramid of
    levels (each padded to even sides, then 2x2 sums turned into means of weight 1 where any weight lies), pull
    comes back down, each level's own mean where it has weight, else the coarser level's colour.  The pull stops at
    level ``finest`` (0: the input's); returns that level's colours and the pyramid (level k's (c, w) at index k)."""
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
        c = np.where(ok[..., None], c / np.maximum(w, 1e-9)[..., None], 0.0)   # each coarser level: means, weight 1
        w = ok.astype(np.float32)
    col = c
    for c_k, w_k in reversed(pyramid[finest:]):
        up = np.repeat(np.repeat(col, 2, axis=0), 2, axis=1)[: c_k.shape[0], : c_k.shape[1]]
        col = np.where((w_k > 0)[..., None], c_k / np.maximum(w_k, 1e-9)[..., None], up)
    return col, pyramid


def _fill_holes(rgba: np.ndarray, rows: int, out: np.ndarray) -> np.ndarray:
    """:func:`fill_gutters` without blocks, from the second level: its 2x2 sums of the written texels' 8-bit colours are
    integers, exact in float32 whichever way they are added, so they are summed as integers (no float32 copy of the
    atlas); an unwritten texel of the first level has no weight and takes the second level's colour."""
    m = rgba[:rows, :, 3] > 127
    ci = rgba[:rows, :, :3].astype(np.uint16)
    ci *= m[..., None]
    mi = m.astype(np.uint16)
    ph, pw = ci.shape[0] % 2, ci.shape[1] % 2
    if ph or pw:
        ci = np.pad(ci, ((0, ph), (0, pw), (0, 0)))
        mi = np.pad(mi, ((0, ph), (0, pw)))
    ci, mi = ci[0::2] + ci[1::2], mi[0::2] + mi[1::2]            # row pairs, then column pairs
    c = (ci[:, 0::2] + ci[:, 1::2]).astype(np.float32)
    w = (mi[:, 0::2] + mi[:, 1::2]).astype(np.float32)
    ok = w > 0
    c = np.where(ok[..., None], c / np.maximum(w, 1e-9)[..., None], 0.0)
    w = ok.astype(np.float32)
    col, _ = _push_pull(c, w, 0)
    hy, hx = np.nonzero(~m)
    out = out.copy()
    out[hy, hx] = np.clip(np.rint(col[hy >> 1, hx >> 1]), 0, 255).astype(np.uint8)
    return out


def fill_gutters(rgba: np.ndarray, rows: int, block: int = 1) -> np.ndarray:
    """The atlas ``rgba`` (H, W, 4) uint8 as RGB with every texel no sample wrote (alpha 0) in its first ``rows``
    rows filled by push-pull: the alpha-weighted mean of the written texels in the smallest enclosing 2^k block.

    The gaps between cells (and the corners odd L-packing levels leave) were black: a lossy codec's transforms and
    4:2:0 chroma blend that black into each cell's border samples, which the client reads along every triangle's
    edges (dark seams).  Filled with their neighbours' colours, the borders code like the inside of the cells; the
    texels a sample wrote are left exactly as they are.  Rows from ``rows`` on are returned unchanged.  With ``block``
    > 1 (``TssConfig.codec_block``) the texels of a ``block``-aligned square with any written texel are first filled
    from that square's own texels (:func:`dilate_in_blocks`), the push-pull fills the empty squares."""
    out = np.ascontiguousarray(rgba[..., :3])
    rows = int(min(max(rows, 0), rgba.shape[0]))
    if rows == 0:
        return out
    w = (rgba[:rows, :, 3] > 127).astype(np.float32)
    if w.all() or not w.any():
        return out
    if block == 1:
        return _fill_holes(rgba, rows, out)
    c = rgba[:rows, :, :3].astype(np.float32) * w[..., None]
    if block > 1:
        c, wb = dilate_in_blocks(c, w > 0, block)
        w = wb.astype(np.float32)
        if w.all():
            hole = rgba[:rows, :, 3] <= 127
            out = out.copy()
            out[:rows][hole] = np.clip(np.rint(c[hole]), 0, 255).astype(np.uint8)
            return out
    col, pyramid = _push_pull(c, w, 1)
    # the finest level only where no sample wrote (the others keep their texels): the same per-texel steps, without
    # the full-size upsampled copy (a fifth of this function's time on a 320x180 walk's atlas, 82 % written)
    c0, w0 = pyramid[0]
    hy, hx = np.nonzero(rgba[:rows, :, 3] <= 127)
    wh = w0[hy, hx]
    val = np.where((wh > 0)[:, None], c0[hy, hx] / np.maximum(wh, 1e-9)[:, None], col[hy >> 1, hx >> 1])
    out = out.copy()
    out[hy, hx] = np.clip(np.rint(val), 0, 255).astype(np.uint8)
    return out
