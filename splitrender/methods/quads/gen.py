"""Quad proxies from a G-buffer (QUASAR section 3.2), in numpy.

A quad proxy covers an ``S x S`` block of pixels (``S = 2**level``) of one G-buffer. It is
the plane through the view-space point at the block's centre (``depth`` metres along
-Z) with normal ``n`` (view space, facing the camera), cut by the block's pixel frustum.
It is split into four sub-quads (its quadrants, order TL, TR, BL, BR with y down); each
sub-quad has four corners (the same order), and every corner may move along its ray
by a **depth offset** (metres along the ray, negative towards the eye).  A quad whose 16
offsets are all below ``delta_flatten`` is **flat** and sends none.

1. **Initial quads**: one per pixel.  The nine points of the pixel's 3x3 corner lattice
   lie on its own plane, except that a pixel corner (edge midpoint) whose three (one)
   neighbouring planes pass within ``delta_max`` of it along its ray moves to the mean
   of those planes and its own: surfaces close up across pixels, and depth
   discontinuities stay open.  The public code averages the neighbouring pixels' centre
   depths here; averaging the planes at the corner is exact for planar surfaces.
2. **Merging**: pass ``p`` combines 2x2 quads of level ``p`` into one of level ``p + 1``
   when the four normalised plane equations ``(n, w)`` lie pairwise within ``delta_sim``
   (the first ``coarse_passes`` passes also when their centre depths differ by less than
   ``delta_max`` in NDC).  The merged plane has the mean normal and the mean centre depth;
   its sub-quad ``k`` is child ``k`` and takes the child's four outer corners, whose
   offsets are recomputed against the merged plane.  So a quad always carries 16 offsets,
   where the public code keeps a texture of offsets at twice the G-buffer's resolution.
3. **Gathering**: every quad left on any level.

Normals are quantised to the wire's 8 + 8 bit spherical angles before any plane is
built, so the client's planes are the server's.  Normals closer than 2.5 degrees to
edge-on (the public code's ``angleThreshold`` 87.5) are turned towards the eye until they
are not, so no plane runs along its own rays.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ...scene.pose import CameraIntrinsics
from .config import QuadParams

COS_EDGE_ON = math.cos(math.radians(87.5))
MAX_LEVEL = 11
"""Largest quad: 2**11 = 2048 pixels (QUASAR's limit; the wire's size field has 6 bits)."""
MAX_OFFSET_M = 1000.0
"""Largest depth offset a quad may carry (metres along its ray); the client rejects larger ones."""
BACKGROUND_FAR = 0.98
"""Background pixels of a visible layer become quads on a plane facing the eye at this fraction of the far distance."""
SUB_CORNERS = np.array([(s % 2 + c % 2, s // 2 + c // 2) for s in range(4) for c in range(4)])
"""(i, j) half-steps from a quad's top-left corner of corner ``c`` of sub-quad ``s`` (index ``4 s + c``)."""
OUTER = np.array([5 * c for c in range(4)])
"""Index ``4 c + c``: outer corner ``c`` of a quad (corner ``c`` of its sub-quad ``c``)."""


@dataclass
class QuadSet:
    """The quads of one G-buffer, in gathering order (level, then row-major position).

    ``level`` (N,) uint8 log2 size; ``x``, ``y`` (N,) uint16 top-left pixel; ``theta``,
    ``phi`` (N,) uint8 the normal's spherical angles; ``depth`` (N,) float32 the plane's
    view depth at the quad centre; ``flat`` (N,) bool; ``offsets`` (M, 16) float16 for the
    M non-flat quads, in order.
    """

    level: np.ndarray
    x: np.ndarray
    y: np.ndarray
    theta: np.ndarray
    phi: np.ndarray
    depth: np.ndarray
    flat: np.ndarray
    offsets: np.ndarray
    stats: dict[str, float] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.level.size)

    @staticmethod
    def empty() -> "QuadSet":
        z = np.zeros(0, np.uint8)
        return QuadSet(z, np.zeros(0, np.uint16), np.zeros(0, np.uint16), z, z, np.zeros(0, np.float32), np.zeros(0, bool),
                       np.zeros((0, 16), np.float16))

    def pixels(self) -> int:
        """Pixels covered (sum of S**2)."""
        return int((4 ** self.level.astype(np.int64)).sum())

    def background(self, intr: CameraIntrinsics) -> np.ndarray:
        """(N,) bool: the quads a visible layer made of its background (on the plane at :data:`BACKGROUND_FAR`
        of the far distance; their merges keep that depth, and no geometry lies there)."""
        return np.isclose(self.depth, np.float32(BACKGROUND_FAR * intr.far_m), rtol=1e-5, atol=0.0)


# ----------------------------------------------------------------------------- geometry helpers
def dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(a * b).sum(-1)`` over a last axis of 3, without numpy's slow reduction over a short axis
    (the same additions in the same order, so the same bits)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def norm3(a: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(a, axis=-1)`` over a last axis of 3: the square root of the same sum in the same order
    (``((x x + y y) + z z)``, numpy's order for so short an axis), so the same bits, without the slow reduction."""
    return np.sqrt(dot3(a, a))


def rays(intr: CameraIntrinsics, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """View-space ray directions (z = -1) through image points ``(u, v)`` (pixels, top-left origin)."""
    f = intr.focal_px()
    return np.stack([(u - intr.width / 2) / f, -(v - intr.height / 2) / f, -np.ones_like(u, dtype=np.float64)], axis=-1)


def encode_normals(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals → (theta, phi) uint8: polar angle from +y over [0, pi], azimuth atan2(z, x) over [-pi, pi]."""
    theta = np.arccos(np.clip(n[..., 1], -1.0, 1.0))
    phi = np.arctan2(n[..., 2], n[..., 0])
    return (np.rint(theta / math.pi * 255).astype(np.uint8), np.rint((phi + math.pi) / (2 * math.pi) * 255).astype(np.uint8))


def decode_normals(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit normals (..., 3) of 8-bit angles (:func:`encode_normals`); uint8 codes are read from a table of all
    256 x 256 made once by the same arithmetic (the same bits, tested over every code; the client decodes every
    quad of a reference frame, issue 49)."""
    global _NORMALS
    if isinstance(theta, np.ndarray) and isinstance(phi, np.ndarray) and theta.dtype == phi.dtype == np.uint8:
        if _NORMALS is None:
            codes = np.arange(256, dtype=np.uint8)
            _NORMALS = _decode_normals(codes[:, None], codes[None, :]).reshape(-1, 3)
        # one flat index into the table's rows: the same rows as indexing it by (theta, phi), over 10x faster
        at = theta.astype(np.intp)
        at <<= 8
        at += phi
        return _NORMALS.take(at, axis=0)
    return _decode_normals(theta, phi)


_NORMALS: np.ndarray | None = None
"""(256 * 256, 3): :func:`decode_normals` of every (theta, phi) code, row ``256 theta + phi``."""


def _decode_normals(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    t = np.asarray(theta).astype(np.float64) / 255 * math.pi
    p = np.asarray(phi).astype(np.float64) / 255 * 2 * math.pi - math.pi
    st = np.sin(t)
    return np.stack(np.broadcast_arrays(st * np.cos(p), np.cos(t), st * np.sin(p)), axis=-1)


def ndc_depth(z: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:
    n, f = intr.near_m, intr.far_m
    return (f + n) / (f - n) - 2 * f * n / ((f - n) * np.maximum(z, 1e-9))


def window_depth(z: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:
    """Depth-buffer value in [0, 1] of view depth ``z`` clamped to [near, far] (the public code's ``normalizeDepth``)."""
    return ndc_depth(np.clip(z, intr.near_m, intr.far_m), intr) * 0.5 + 0.5


def orient(n: np.ndarray, d: np.ndarray, a: np.ndarray | None = None) -> np.ndarray:
    """Normals ``n`` turned to face the eye along rays ``d``, and at least 2.5 degrees from edge-on.  ``a``: the
    unit vectors towards the eye, ``-d / |d|``, when the caller has them (:func:`toward_eye`)."""
    if a is None:
        a = -d / norm3(d)[..., None]
    dot = dot3(n, a)[..., None]
    n = np.where(dot < 0, -n, n)
    dot = np.abs(dot)
    low = dot[..., 0] < COS_EDGE_ON
    if low.any():
        p = n[low] - dot[low] * a[low]
        pn = np.linalg.norm(p, axis=-1, keepdims=True)
        p = np.where(pn > 1e-12, p / np.maximum(pn, 1e-12), 0.0)
        n = n.copy()
        n[low] = p * math.sqrt(1 - COS_EDGE_ON ** 2) + a[low] * COS_EDGE_ON
    return n


def quantize(n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(theta, phi, decoded normal): the normal the client will see."""
    t, p = encode_normals(n)
    return t, p, decode_normals(t, p)


def plane_depth(n: np.ndarray, w: np.ndarray, d: np.ndarray) -> np.ndarray:
    """View depth where rays ``d`` (z = -1) meet planes ``n . X + w = 0`` (inf where parallel or behind)."""
    den = dot3(n, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = -w / den
    return np.where((np.abs(den) > 1e-12) & (z > 0), z, np.inf)


# ----------------------------------------------------------------------------- generation
_GRIDS: dict[tuple[int, int, float], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}


def ray_grids(intr: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The camera's rays, computed once per camera: through every pixel centre (H, W, 3), through every point of
    the half-pixel lattice ((2H + 1, 2W + 1, 3): pixel corners, edge midpoints and centres) and those rays'
    lengths.  The same arithmetic on the same coordinates as :func:`rays` on the points one at a time (the
    coordinates are halves of integers, exact in float64), so the same bits."""
    key = (intr.width, intr.height, intr.focal_px())
    got = _GRIDS.get(key)
    if got is None:
        h, w = intr.height, intr.width
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
        centre = rays(intr, xs + 0.5, ys + 0.5)
        lat_v, lat_u = np.mgrid[0:2 * h + 1, 0:2 * w + 1].astype(np.float64) / 2
        lattice = rays(intr, lat_u, lat_v)
        got = (centre, lattice, np.linalg.norm(lattice, axis=-1))
        for a in got:
            a.flags.writeable = False
        if len(_GRIDS) > 8:
            _GRIDS.clear()
        _GRIDS[key] = got
    return got


_TOWARD: dict[tuple[int, int, float], np.ndarray] = {}


def toward_eye(intr: CameraIntrinsics) -> np.ndarray:
    """(H, W, 3): :func:`orient`'s unit vectors towards the eye at every pixel centre, computed once per camera (the
    same arithmetic on :func:`ray_grids`' centre rays, so the same bits)."""
    key = (intr.width, intr.height, intr.focal_px())
    got = _TOWARD.get(key)
    if got is None:
        centre = ray_grids(intr)[0]
        got = -centre / norm3(centre)[..., None]
        got.flags.writeable = False
        if len(_TOWARD) > 8:
            _TOWARD.clear()
        _TOWARD[key] = got
    return got


LATTICE = [(j, i) for j in (0, 1, 2) for i in (0, 1, 2) if (j, i) != (1, 1)]
"""A pixel's 3x3 corner lattice less its centre: (j, i) half-steps down and right of its top-left corner."""


def _lattice_neighbours() -> tuple[list[tuple[int, int, int, int, int]], list[list[int]]]:
    """Per lattice point of :data:`LATTICE` the neighbouring pixels whose planes meet there: (dx, dy, the point's
    (j, i) in that neighbour's lattice, its index in :data:`LATTICE`) rows, and each point's rows."""
    rows: list[tuple[int, int, int, int, int]] = []
    per: list[list[int]] = []
    for m, (j, i) in enumerate(LATTICE):
        dx = -1 if i == 0 else (1 if i == 2 else 0)
        dy = -1 if j == 0 else (1 if j == 2 else 0)
        nbs = [(dx, 0), (0, dy), (dx, dy)] if dx and dy else [(dx, dy)]
        per.append([])
        for a, b in nbs:
            per[-1].append(len(rows))
            rows.append((a, b, j - 2 * b, i - 2 * a, m))
    return rows, per


NEIGHBOUR_ROWS, POINT_ROWS = _lattice_neighbours()


def _close_up(own: np.ndarray, dl_len: np.ndarray, zz: np.ndarray, has: np.ndarray, intr: CameraIntrinsics,
              params: QuadParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 16 corners' depths and offsets of pixels whose own lattice depths are ``own`` (..., 3, 3) (ray lengths
    ``dl_len``), given their neighbours' depths ``zz`` (..., len(NEIGHBOUR_ROWS)) at the shared lattice points and
    whether each neighbour has a plane (``has``); and which pixels make a quad.

    A neighbour is close where both depths are finite and their distance along the ray, as a window depth, is
    below ``delta_max``: the distance is compared with :func:`close_limit` (the same verdicts, without the window
    depth of every distance); where it is not close its depth is not read."""
    with np.errstate(invalid="ignore", over="ignore"):
        return _close_up_at(own, dl_len, zz, has, intr, params)


def _close_up_at(own: np.ndarray, dl_len: np.ndarray, zz: np.ndarray, has: np.ndarray, intr: CameraIntrinsics,
                 params: QuadParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    own_r = own[..., _PJ, _PI]
    dist = np.abs(zz - own_r)
    dist *= dl_len[..., _PJ, _PI]
    limit = close_limit(intr, params.delta_max)
    if limit < np.inf:  # a non-finite depth gives an infinite or NaN distance, which is not below the limit
        close_r = has & (dist < limit)
    else:
        close_r = has & np.isfinite(zz) & np.isfinite(own_r)
    lat = own.copy()
    for m, (j, i) in enumerate(LATTICE):
        rs = POINT_ROWS[m]
        close = close_r[..., rs[0]]
        acc = zz[..., rs[0]]
        for r in rs[1:]:
            close = close & close_r[..., r]
            acc = acc + zz[..., r]
        mean = (own[..., j, i] + acc) / (1 + len(rs))
        lat[..., j, i] = np.where(close, mean, own[..., j, i])
    corners = lat[..., _IDX_J, _IDX_I]                                          # (..., 16) actual depths
    offs = corners - own[..., _IDX_J, _IDX_I]
    offs *= dl_len[..., _IDX_J, _IDX_I]
    # |offset| <= MAX_OFFSET_M holds only for finite offsets, and a finite offset has finite depths on both sides
    good = (np.abs(offs) <= MAX_OFFSET_M).all(-1)
    return corners, offs, good


_PJ = np.array([LATTICE[m][0] for *_, m in NEIGHBOUR_ROWS])
_PI = np.array([LATTICE[m][1] for *_, m in NEIGHBOUR_ROWS])
"""Each of :data:`NEIGHBOUR_ROWS`'s lattice point in the pixel's own lattice."""
_IDX_J, _IDX_I = SUB_CORNERS[:, 1], SUB_CORNERS[:, 0]
_LIMITS: dict[tuple[float, float, float], float] = {}


def close_limit(intr: CameraIntrinsics, delta_max: float) -> float:
    """The least distance ``d`` >= 0 whose :func:`window_depth` is not below ``delta_max``: for every ``d`` >= 0,
    ``window_depth(d) < delta_max`` exactly when ``d < close_limit`` (each floating-point step of
    :func:`window_depth` is monotone, so the verdict flips once; found by bisection over the float64 values)."""
    key = (intr.near_m, intr.far_m, float(delta_max))
    got = _LIMITS.get(key)
    if got is None:
        below = lambda d: bool(window_depth(np.array([d]), intr)[0] < delta_max)  # noqa: E731
        if not below(0.0):
            got = 0.0
        elif below(np.inf):
            got = np.inf
        else:
            lo, hi = 0, int(np.array(np.inf).view(np.int64))     # below(lo), not below(hi): bits of non-negatives
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if below(float(np.array(mid, np.int64).view(np.float64))):
                    lo = mid
                else:
                    hi = mid
            got = float(np.array(hi, np.int64).view(np.float64))
        _LIMITS[key] = got
    return got


BAND_ROWS = 32
"""Rows of pixels :func:`_lattice_dense` works on at a time: each step's arrays then stay in the processor's cache."""
_POINTS = [(j, i) for j in (0, 1, 2) for i in (0, 1, 2)]
"""The 3x3 lattice's points; :data:`SUB_CORNERS`'s 16 corners are these nine, some more than once."""
_CORNER_POINT = [_POINTS.index((int(j), int(i))) for i, j in SUB_CORNERS]
"""Each of the 16 corners' index in :data:`_POINTS`."""
_CENTRE = _POINTS.index((1, 1))


def _lattice_dense(n: np.ndarray, wq: np.ndarray, valid: np.ndarray, need: np.ndarray, grid: np.ndarray,
                   grid_len: np.ndarray, intr: CameraIntrinsics, params: QuadParams
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_close_up` for every pixel, one lattice point at a time over a band of :data:`BAND_ROWS` rows: each
    plane is cut with the rays of one of its nine lattice points at once (a strided view of the camera's half-pixel
    grid), and a neighbour's depth at a shared point is a shifted slice of those.  The same arithmetic per value as
    :func:`_close_up` (the same additions in the same order), so the same bits.  Returns the level-0 maps'
    ``present`` (``need`` where the quad is good), ``corners``, ``offs`` (0 where no quad is) and ``flat``."""
    h, w = valid.shape
    own = np.zeros((3, 3, h + 2, w + 2))     # each pixel's plane at its lattice point (j, i); a zero border
    lens = [[grid_len[j:j + 2 * h:2, i:i + 2 * w:2] for i in range(3)] for j in range(3)]
    vpad = np.zeros((h + 2, w + 2), bool)
    vpad[1:-1, 1:-1] = valid
    present = np.zeros((h, w), bool)
    # the depths and offsets at the nine lattice points, each an (H, W) plane (the 16 corners are these nine, some
    # more than once: :class:`_QuadMaps` spreads them when asked)
    lat9 = np.empty((9, h, w))
    off9 = np.empty((9, h, w))
    flat = np.empty((h, w), bool)
    limit = close_limit(intr, params.delta_max)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # plane_depth at lattice point (j, i): a lattice ray's x depends on its column alone, its y on its row
        # alone and its z is -1, so dot3(n, d) = (n_x d_x + n_y d_y) + n_z d_z from products made once per column
        # and per row of the lattice (the same products and sums, so the same bits)
        nx = [n[..., 0] * grid[0, i:i + 2 * w:2, 0] for i in range(3)]
        ny = [n[..., 1] * grid[j:j + 2 * h:2, 0, 1][:, None] for j in range(3)]
        nz = n[..., 2] * grid[0, 0, 2]
        neg_w = -wq
        for j in range(3):
            for i in range(3):
                den = nx[i] + ny[j]
                den += nz
                z = neg_w / den
                own[j, i, 1:-1, 1:-1] = np.where((np.abs(den) > 1e-12) & (z > 0), z, np.inf)
        for r0 in range(0, h, BAND_ROWS):
            r1 = min(h, r0 + BAND_ROWS)
            mine = own[:, :, 1 + r0:1 + r1, 1:-1]
            ln = [[lens[j][i][r0:r1] for i in range(3)] for j in range(3)]
            close_r, zz = [], []
            for dx, dy, nj, ni, m in NEIGHBOUR_ROWS:
                j, i = LATTICE[m]
                z = own[nj, ni, 1 + r0 + dy:1 + r1 + dy, 1 + dx:1 + dx + w]
                dist = np.abs(z - mine[j, i])
                dist *= ln[j][i]
                has = vpad[1 + r0 + dy:1 + r1 + dy, 1 + dx:1 + dx + w]
                if limit < np.inf:
                    close_r.append(has & (dist < limit))
                else:
                    close_r.append(has & np.isfinite(z) & np.isfinite(mine[j, i]))
                zz.append(z)
            lat = [mine[j, i] for j, i in _POINTS]
            for m, (j, i) in enumerate(LATTICE):
                rs = POINT_ROWS[m]
                close = close_r[rs[0]]
                acc = zz[rs[0]]
                for r in rs[1:]:
                    close = close & close_r[r]
                    acc = acc + zz[r]
                mean = (mine[j, i] + acc) / (1 + len(rs))
                lat[_POINTS.index((j, i))] = np.where(close, mean, mine[j, i])
            offs = []
            ok = need[r0:r1] & np.isfinite(mine[1, 1])
            fl = np.full((r1 - r0, w), True)
            for p, (j, i) in enumerate(_POINTS):
                if p == _CENTRE:    # the centre's own depth: its offset (x - x) * len is +0 where x is finite, and
                    offs.append(None)   # NaN (not a quad) where it is not; 0 is below any positive delta_flatten
                    if not 0.0 < params.delta_flatten:
                        fl &= False
                    continue
                o = lat[p] - mine[j, i]
                o *= ln[j][i]
                a = np.abs(o)
                ok &= a <= MAX_OFFSET_M    # only a finite offset passes: finite depths on both sides
                fl &= a < params.delta_flatten
                offs.append(o)
            present[r0:r1] = ok
            flat[r0:r1] = np.where(ok, fl, 0.0 < params.delta_flatten)
            # every plane written whole, then 0 where no quad is (few pixels: the same values as zeroing each plane)
            for p in range(9):
                lat9[p, r0:r1] = lat[p]
                off9[p, r0:r1] = 0.0 if offs[p] is None else offs[p]
            if not ok.all():
                bad = ~ok
                lat9[:, r0:r1][:, bad] = 0.0
                off9[:, r0:r1][:, bad] = 0.0
    return present, lat9, off9, flat


def _lattice_sparse(n: np.ndarray, wq: np.ndarray, valid: np.ndarray, need: np.ndarray, cut: np.ndarray,
                    grid: np.ndarray, grid_len: np.ndarray, intr: CameraIntrinsics, params: QuadParams
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_close_up` at the pixels of ``need`` only (rows, columns, (k, 16) corners and offsets, (k,) quads);
    the planes of ``cut`` (``need`` and its neighbours) are cut with their own lattice rays."""
    h, w = valid.shape
    cy, cx = np.nonzero(cut)
    jj, ii = np.mgrid[0:3, 0:3]
    # plane_depth at each plane's own lattice: a lattice ray's x is its column's, its y its row's, its z -1, so the
    # products are read from one row and one column of the lattice (the same values and sums, so the same bits;
    # :func:`_lattice_dense` does the same)
    nc, neg_w = n[cy, cx], -wq[cy, cx]
    den = nc[:, 0, None, None] * grid[0, 2 * cx[:, None, None] + ii, 0] + nc[:, 1, None, None] * grid[2 * cy[:, None, None] + jj, 0, 1]
    den += nc[:, 2, None, None] * grid[0, 0, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        zc = neg_w[:, None, None] / den
    own_cut = np.zeros((cy.size + 1, 3, 3))    # the planes of cut, then a zero row (no plane)
    own_cut[:-1] = np.where((np.abs(den) > 1e-12) & (zc > 0), zc, np.inf)
    wp = w + 2                                  # index maps with a border of one pixel (outside: no plane)
    at = np.full((h + 2) * wp, cy.size, np.int64)
    at[(cy + 1) * wp + cx + 1] = np.arange(cy.size)
    vpad = np.zeros((h + 2) * wp, bool)
    vpad.reshape(h + 2, wp)[1:-1, 1:-1] = valid
    py, px = np.nonzero(need)
    base = (py + 1) * wp + px + 1
    own = own_cut[at[base]]                                                     # (k, 3, 3)
    dl_len = grid_len[2 * py[:, None, None] + jj, 2 * px[:, None, None] + ii]   # (k, 3, 3)
    nr = len(NEIGHBOUR_ROWS)
    zz = np.empty((py.size, nr))
    has = np.empty((py.size, nr), bool)
    flat_own = own_cut.reshape(-1)
    for r, (dx, dy, nj, ni, _) in enumerate(NEIGHBOUR_ROWS):
        nb = base + (dy * wp + dx)
        has[:, r] = vpad[nb]
        zz[:, r] = flat_own[9 * at[nb] + (3 * nj + ni)]
    corners, offs, ok = _close_up(own, dl_len, zz, has, intr, params)
    return py, px, corners, offs, ok


def initial_quads(depth: np.ndarray, normal_view: np.ndarray, valid: np.ndarray, intr: CameraIntrinsics,
                  params: QuadParams, emit: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Level-0 quad map: per pixel its plane, centre depth, 16 corner depths, offsets and flatness.

    Planes are built for every valid pixel (neighbours need them); the corner lattice only
    for the pixels that ``emit`` quads and their 8 neighbours.

    A neighbour's plane meets a lattice point of a pixel where the point lies on the neighbour's own lattice (a
    shared corner or edge midpoint, the same ray), so the depth there is the neighbour's own lattice depth: each
    plane is cut with the rays of its own lattice once, and the neighbours' depths are read from those."""
    h, w = depth.shape
    z = np.where(valid, depth, 1.0)
    need = valid if emit is None else valid & emit
    centre, grid, grid_len = ray_grids(intr)
    # the whole image at once where most pixels emit (the same arithmetic per pixel, so the same bits)
    dense = emit is None or 3 * int(np.count_nonzero(need)) > h * w
    if dense:
        dc = centre
        n = orient(np.where(valid[..., None], normal_view, (0.0, 0.0, 1.0)), dc, toward_eye(intr))
        th, ph, n = quantize(n)
        wq = -dot3(n, dc) * z
        cut = valid
    else:
        # planes only where an emitting pixel or one of its 8 neighbours reads them (the same per-pixel arithmetic,
        # so the same bits there; a residual frame's sets emit from a few per cent of the pixels)
        near = need.copy()
        near[1:] |= need[:-1]
        near[:-1] |= need[1:]
        near[:, 1:] |= near[:, :-1].copy()
        near[:, :-1] |= near[:, 1:].copy()
        cut = near & valid
        sy, sx = np.nonzero(cut)
        dcs = centre[sy, sx]
        ths, phs, ns = quantize(orient(normal_view[sy, sx], dcs, toward_eye(intr)[sy, sx]))
        n, th, ph, wq = np.zeros((h, w, 3)), np.zeros((h, w), np.uint8), np.zeros((h, w), np.uint8), np.zeros((h, w))
        n[sy, sx], th[sy, sx], ph[sy, sx] = ns, ths, phs
        wq[sy, sx] = -dot3(ns, dcs) * z[sy, sx]
    if dense:
        present, lat9, off9, flat = _lattice_dense(n, wq, valid, need, grid, grid_len, intr, params)
        return _QuadMaps({"present": present, "n": n, "theta": th, "phi": ph, "zc": z, "w": wq, "flat": flat,
                           "lat9": lat9, "off9": off9})
    py, px, corners, offs, ok = _lattice_sparse(n, wq, valid, need, cut, grid, grid_len, intr, params)
    present = np.zeros((h, w), bool)
    present[py[ok], px[ok]] = True
    flat = np.full((h, w), 0.0 < params.delta_flatten)      # offsets 0 where no quad is
    flat[py[ok], px[ok]] = (np.abs(offs[ok]) < params.delta_flatten).all(-1)
    return _QuadMaps({"present": present, "n": n, "theta": th, "phi": ph, "zc": z, "w": wq, "flat": flat,
                       "at": py[ok] * w + px[ok], "c16": corners[ok], "o16": offs[ok]})


class _QuadMaps(dict):  # type: ignore[type-arg]
    """:func:`initial_quads`' and :func:`merge_pass`' maps, whose ``corners`` and ``offs`` ((H, W, 16): the 16 corners' depths and offsets, 0
    where no quad is) are spread out only when read: merging reads the four outer corners (:meth:`outer`), gathering
    the offsets of the quads that carry them (:meth:`offsets_at`).  Made whole (:func:`_lattice_dense`) they are
    kept as the nine lattice points' planes (``lat9``, ``off9``: (9, H, W), :data:`_POINTS`' order); made at some
    pixels (:func:`_lattice_sparse`) or merged, as those quads' rows (``at``: flat pixel index, row-major; ``c16``,
    ``o16``)."""

    def __missing__(self, key: str) -> np.ndarray:
        if key not in ("corners", "offs"):
            raise KeyError(key)
        if "lat9" in self:
            got = self["lat9" if key == "corners" else "off9"][_CORNER_POINT].transpose(1, 2, 0)
        else:
            h, w = self["present"].shape
            got = np.zeros((h * w, 16))
            got[self["at"]] = self["c16" if key == "corners" else "o16"]
            got = got.reshape(h, w, 16)
        self[key] = got
        return got

    def outer(self) -> list[np.ndarray]:
        """The four outer corners' depths (:data:`OUTER`), each a flat (H W) array."""
        if "lat9" in self:
            return [self["lat9"][_CORNER_POINT[k]].reshape(-1) for k in OUTER]
        out = []
        for k in OUTER:
            plane = np.zeros(self["present"].size)
            plane[self["at"]] = self["c16"][:, k]
            out.append(plane)
        return out

    def offsets_at(self, at: np.ndarray) -> np.ndarray:
        """(K, 16) offsets of the quads at flat pixel indices ``at`` (each one a quad's)."""
        if "lat9" in self:
            return self["off9"].reshape(9, -1)[:, at][_CORNER_POINT].T
        return self["o16"][np.searchsorted(self["at"], at)]


def merge_pass(child: dict[str, np.ndarray], level: int, intr: CameraIntrinsics, params: QuadParams, coarse: bool
               ) -> dict[str, np.ndarray]:
    """One merge pass: level ``level`` quads (``child``, cleared where merged) into level ``level + 1``.

    Only cells whose four children are all present are examined (sparse layers cost little)."""
    h, w = child["present"].shape[0] // 2, child["present"].shape[1] // 2
    out = _QuadMaps({"present": np.zeros((h, w), bool), "n": np.zeros((h, w, 3)), "theta": np.zeros((h, w), np.uint8),
                      "phi": np.zeros((h, w), np.uint8), "zc": np.ones((h, w)), "w": np.zeros((h, w)),
                      "flat": np.zeros((h, w), bool)})
    rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []     # the merged quads' (at, corners, offsets)
    cp = child["present"]
    pres = cp[0:2 * h:2, 0:2 * w:2] & cp[0:2 * h:2, 1:2 * w:2] & cp[1:2 * h:2, 0:2 * w:2] & cp[1:2 * h:2, 1:2 * w:2]
    cy_all, cx_all = np.nonzero(pres)
    if cy_all.size:
        # the children's outer corners (the only corners a merge reads), each one contiguous (H, W) plane read by
        # flat index: the same values as reading them from the (H, W, 16) map, whose level-0 form is a transposed view
        if isinstance(child, _QuadMaps):     # not its 16 corners spread out
            outer = child.outer()
        else:
            cs = child["corners"]
            outer = [np.ascontiguousarray(cs[..., k]).reshape(-1) for k in OUTER]
    for c0 in range(0, cy_all.size, MERGE_CHUNK):   # in chunks whose arrays stay in the processor's cache
        rows.append(_merge_cells(child, out, cy_all[c0:c0 + MERGE_CHUNK], cx_all[c0:c0 + MERGE_CHUNK], level, intr,
                                 params, coarse, outer))
    out["at"] = np.concatenate([r[0] for r in rows]) if rows else np.zeros(0, np.int64)
    out["c16"] = np.concatenate([r[1] for r in rows]) if rows else np.zeros((0, 16))
    out["o16"] = np.concatenate([r[2] for r in rows]) if rows else np.zeros((0, 16))
    return out


MERGE_CHUNK = 2048
"""Cells :func:`merge_pass` examines at a time."""


def _merge_cells(child: dict[str, np.ndarray], out: dict[str, np.ndarray], cy: np.ndarray, cx: np.ndarray, level: int,
                 intr: CameraIntrinsics, params: QuadParams, coarse: bool, outer: list[np.ndarray]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`merge_pass` for the cells (``cy``, ``cx``) whose four children are present: merged ones go to
    ``out`` and leave ``child``; returns their flat indices in ``out``, corners and offsets (K, 16).

    Every ray below meets the image at a multiple of half a pixel, so it is read from the camera's lattice of rays;
    a lattice ray's x depends on its column alone, its y on its row alone and its z is -1, so a plane meets it at
    ``(n_x d_x + n_y d_y) + n_z d_z`` (:func:`dot3`'s sum) with ``d_x`` and ``d_y`` read from one row and one
    column of the lattice: the same values, so the same bits as reading the whole rays."""
    size = 2 ** (level + 1)
    subs = [(0, 0), (0, 1), (1, 0), (1, 1)]
    cw = child["present"].shape[1]
    kid_yx = [(2 * cy + sy, 2 * cx + sx) for sy, sx in subs]
    kids = [ky * cw + kx for ky, kx in kid_yx]     # the children's flat indices
    _, grid, grid_len = ray_grids(intr)
    ray_x, ray_y, ray_z = grid[0, :, 0], grid[:, 0, 1], grid[0, 0, 2]
    gx, gy = 2 * size * cx, 2 * size * cy
    child_n = child["n"].reshape(-1, 3)
    ns = [child_n.take(k, axis=0) for k in kids]
    zs = [child["zc"].ravel()[k] for k in kids]
    # each child's plane n . X + w = 0: its w as made with it (-dot3(n, its centre ray) * its centre depth, in
    # initial_quads or the merge that made it; the same bits as making it again here)
    ws = [child["w"].ravel()[k] for k in kids]
    eqs = [np.concatenate([ns[s], ws[s][:, None]], axis=-1) for s in range(4)]
    ok = np.ones(cy.size, bool)
    for a in range(4):
        for b in range(a + 1, 4):
            e = eqs[a] - eqs[b]
            ok &= np.sqrt(((e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1]) + e[:, 2] * e[:, 2]) + e[:, 3] * e[:, 3]) < params.delta_sim
    if coarse:
        ndc = [ndc_depth(z, intr) for z in zs]
        cont = np.ones(cy.size, bool)
        for a in range(4):
            for b in range(a + 1, 4):
                cont &= np.abs(ndc[a] - ndc[b]) < params.delta_max
        ok |= cont
    dcen = grid[gy + size, gx + size]
    nsum = sum(ns)
    nn = nsum / np.maximum(norm3(nsum), 1e-12)[:, None]
    th, ph, nq = quantize(orient(nn, dcen))
    zc = sum(zs) / 4.0
    wq = -dot3(nq, dcen) * zc
    # sub-quad s takes child s's four outer corners
    corners = np.empty((cy.size, 16))
    for s, k in enumerate(kids):
        for c in range(4):
            corners[:, 4 * s + c] = outer[c][k]
    iu = gx[:, None] + SUB_CORNERS[:, 0] * size
    iv = gy[:, None] + SUB_CORNERS[:, 1] * size
    den = (nq[:, 0:1] * ray_x[iu] + nq[:, 1:2] * ray_y[iv]) + nq[:, 2:3] * ray_z     # plane_depth's, at the 16 corners
    with np.errstate(divide="ignore", invalid="ignore"):
        z16 = -wq[:, None] / den
        plane16 = np.where((np.abs(den) > 1e-12) & (z16 > 0), z16, np.inf)
        offs = corners - plane16
        offs *= grid_len.reshape(-1).take(iv * grid_len.shape[1] + iu)
    # |offset| <= MAX_OFFSET_M only for a finite offset: none non-finite, none too large (a plane near edge-on over a
    # large quad)
    ok &= (np.abs(offs) <= MAX_OFFSET_M).all(-1)
    sel = np.flatnonzero(ok)
    at = cy[sel] * out["present"].shape[1] + cx[sel]
    out["present"].ravel()[at] = True
    out["n"].reshape(-1, 3)[at] = nq[sel]
    out["theta"].ravel()[at] = th[sel]
    out["phi"].ravel()[at] = ph[sel]
    out["zc"].ravel()[at] = zc[sel]
    out["w"].ravel()[at] = wq[sel]
    o = offs[sel]
    out["flat"].ravel()[at] = (np.abs(o) < params.delta_flatten).all(-1)
    cpres = child["present"].ravel()
    for k in kids:  # merged children leave their map
        cpres[k[sel]] = False
    return at, corners[sel], o


def generate(depth: np.ndarray, normal_world: np.ndarray, view_rot: np.ndarray, intr: CameraIntrinsics,
             params: QuadParams, emit: np.ndarray | None = None, background: bool = False) -> QuadSet:
    """The quads of one G-buffer: ``depth`` (H, W) view depth (inf: background), ``normal_world``
    (H, W, 3), ``view_rot`` the world-to-view rotation; quads only where ``emit`` (all
    pixels with geometry when ``None``); ``background`` turns background pixels into quads
    on a far plane facing the eye (the visible layer's sky)."""
    t0 = time.perf_counter()
    h, w = depth.shape
    valid = np.isfinite(depth) & (depth > 0)
    depth = depth.astype(np.float64)
    nview = normal_world.astype(np.float64) @ np.asarray(view_rot, np.float64).T
    if background:
        bg = ~valid
        depth = np.where(bg, BACKGROUND_FAR * intr.far_m, depth)
        nview = np.where(bg[..., None], (0.0, 0.0, 1.0), nview)
        valid = np.ones_like(valid)
    m0 = initial_quads(np.where(valid, depth, 1.0), nview, valid, intr, params, emit)
    t1 = time.perf_counter()
    maps = [m0]
    level = 0
    while level < MAX_LEVEL and min(maps[-1]["present"].shape) >= 2:
        nxt = merge_pass(maps[-1], level, intr, params, coarse=level < params.coarse_passes)
        maps.append(nxt)
        level += 1
        if not nxt["present"].any():
            break
    t2 = time.perf_counter()
    out = gather(maps)
    out.stats = {"gen_ms": (t1 - t0) * 1e3, "merge_ms": (t2 - t1) * 1e3, "quads": float(len(out)),
                 "flat": float(out.flat.sum()), "pixels": float(out.pixels())}
    return out


def gather(maps: list[dict[str, np.ndarray]]) -> QuadSet:
    """Every quad left on any level, level by level, row-major."""
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("level", "x", "y", "theta", "phi", "depth", "flat", "offs")}
    for lv, m in enumerate(maps):
        at = np.flatnonzero(m["present"])      # row-major, as np.nonzero's (y, x) pairs
        yy, xx = np.divmod(at, m["present"].shape[1])
        s = 2 ** lv
        parts["level"].append(np.full(yy.size, lv, np.uint8))
        parts["x"].append((xx * s).astype(np.uint16))
        parts["y"].append((yy * s).astype(np.uint16))
        parts["theta"].append(m["theta"].reshape(-1).take(at))
        parts["phi"].append(m["phi"].reshape(-1).take(at))
        parts["depth"].append(m["zc"].reshape(-1).take(at).astype(np.float32))
        fl = m["flat"].reshape(-1).take(at)
        parts["flat"].append(fl)
        # only the quads with offsets send them (read from level 0's lattice planes when it has them)
        if isinstance(m, _QuadMaps):
            parts["offs"].append(m.offsets_at(at[~fl]))
        else:
            parts["offs"].append(m["offs"][yy[~fl], xx[~fl]])
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}
    flat = cat["flat"].astype(bool)
    return QuadSet(cat["level"].astype(np.uint8), cat["x"].astype(np.uint16), cat["y"].astype(np.uint16),
                   cat["theta"].astype(np.uint8), cat["phi"].astype(np.uint8), cat["depth"].astype(np.float32), flat,
                   cat["offs"].reshape(-1, 16).astype(np.float16))


# ----------------------------------------------------------------------------- reconstruction
def corner_points(qs: QuadSet, intr: CameraIntrinsics, extend: np.ndarray | None = None,
                  corners: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """View-space points (N, 16, 3) of every quad's sub-quad corners, their image positions (N, 16, 2),
    and which quads are drawable (N,) (finite corners in front of the eye).  ``extend`` ((N, 4) pixels, optional):
    each planar quad's (flat, or all its offsets 0) corners on its left, top, right and bottom side moved out by that
    much, on the quad's own plane
    (``mesh.sky_sides``, ``mesh.sealed``).  ``corners`` (K indices into the 16, optional): only those corners, (N, K, 3)
    and (N, K, 2), each the same bits as in the full arrays (``mesh.build_mesh`` takes a flat quad's :data:`OUTER`
    four; drawable then means those K are)."""
    sub = SUB_CORNERS if corners is None else SUB_CORNERS[np.asarray(corners)]
    n = decode_normals(qs.theta, qs.phi)
    s = (2.0 ** qs.level.astype(np.float64))
    x0 = qs.x.astype(np.float64)
    y0 = qs.y.astype(np.float64)
    dcen = rays(intr, x0 + s / 2, y0 + s / 2)
    wv = -dot3(n, dcen) * qs.depth.astype(np.float64)
    u = x0[:, None] + sub[None, :, 0] * s[:, None] / 2
    v = y0[:, None] + sub[None, :, 1] * s[:, None] / 2
    if extend is not None:   # planar quads only: moving a quad's outer corners and not its inner ones would bend the
        # surface its depth offsets give between them, and so its depth at its own pixels
        planar = qs.flat.copy()
        planar[~qs.flat] = (np.asarray(qs.offsets) == 0).all(-1)
        e = np.where(planar[:, None], np.asarray(extend, np.float64), 0.0)
        u = u - (sub[None, :, 0] == 0) * e[:, 0:1] + (sub[None, :, 0] == 2) * e[:, 2:3]
        v = v - (sub[None, :, 1] == 0) * e[:, 1:2] + (sub[None, :, 1] == 2) * e[:, 3:4]
    d = rays(intr, u, v)
    z = plane_depth(n[:, None, :], wv[:, None], d)
    if not qs.flat.all():   # (a flat set's offsets are 0: z + 0 is z, plane_depth's z being positive or inf)
        offs = np.zeros((len(qs), 16))
        offs[~qs.flat] = qs.offsets.astype(np.float64)
        if corners is not None:
            offs = offs[:, np.asarray(corners)]
        with np.errstate(invalid="ignore"):
            z = z + offs / norm3(d)
    ok = np.isfinite(z).all(-1) & (z > 0).all(-1)
    z = np.where(ok[:, None], z, 1.0)
    return d * z[..., None], np.stack([u, v], axis=-1), ok
