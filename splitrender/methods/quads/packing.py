"""QuadStream's packed texture atlas: every quad's own texels, packed square by square.

QuadStream (Hladky et al. 2022) bins its quads' texels into one atlas and sends each quad's
atlas position with it (24 bits a quad; 103 bits a quad in all, against QUASAR's 80, whose
atlas holds whole views side by side and derives a quad's texels from its x and y).  The
QUASAR paper (section 3.4.1, figure 7) measures its linear packing at 1.5-2x fewer video
bits than this binning.

The centre view lies whole at the atlas's top left (in the tiles of :func:`whole_tiles`; it covers every pixel of
its view, so as many texels as its quads would take), where the client filters across its quad borders as over an
image, as QUASAR's slots and QUASAR's own QuadStream simulator (each view's colour buffer whole) do; the later views'
quads are binned around it.

Our binning: quads are power-of-two squares, so sorted by size (largest first) and laid
along a Z-order curve in square tiles of side :func:`tile_side` they pack without a gap: each
square starts at a multiple of its own area along the curve, which is an aligned cell of
its size in one tile.  Squares of one size go in view order and, within a view, along the
Z-order curve of their own place in it (:func:`source_order`), so neighbours in a view stay
neighbours in the atlas: in gathering order (row by row) a view's one-pixel quads became a
mosaic the codec coded worse (issue 50: 2CylinderEngine's still frame through the default
codec, one intra frame, 36.07 -> 36.73 dB on the model, 25 -> 24 kB; QUASAR's slots 36.99).
The layout is a pure function of the frame's quads (no state, no reuse across frames:
QuadStream tries to keep a quad's patch from frame to frame, which this does not, so its
atlas codes with less temporal locality than the original's).
"""

from __future__ import annotations

import math

import numpy as np

from ...errors import ConfigError

POS_BITS = 12
"""Bits of each atlas coordinate on the wire (atlases up to 4096 texels a side)."""


def tile_side(slot_w: int, slot_h: int) -> int:
    """The largest power of two within a view: no quad is larger (a quad lies inside its view)."""
    return 1 << int(math.floor(math.log2(max(1, min(slot_w, slot_h)))))


def whole_tiles(slot_w: int, slot_h: int) -> tuple[int, int]:
    """(columns, rows) of tiles at the atlas's top left that hold the centre view whole."""
    t = tile_side(slot_w, slot_h)
    return -(-slot_w // t), -(-slot_h // t)


def packed_size(slot_w: int, slot_h: int, max_texels: int, width_hint: int) -> tuple[int, int]:
    """(width, height) of an atlas of whole tiles about ``width_hint`` wide holding ``max_texels``
    (the most texels a frame's quads can cover: every view's pixels, the first view whole in the tiles of
    :func:`whole_tiles`), at most 4096 a side (the wire's 12 bits, the papers' 4096x4096 atlases): from about
    1280x720 up a frame's quads could cover more than that, and what does not fit is left out (:func:`fitting`)."""
    t = tile_side(slot_w, slot_h)
    side = (1 << POS_BITS) // t
    if side < 1:
        raise ConfigError(f"quads packed atlas: a {slot_w}x{slot_h} view's quads can be {t} texels wide, more than "
                          f"the wire's {1 << POS_BITS}; use atlas = 'slots'")
    rx, ry = whole_tiles(slot_w, slot_h)
    tiles = rx * ry + max(0, -(-(max_texels - slot_w * slot_h) // (t * t)))
    tx = max(1, rx, min(tiles, width_hint // t, side))
    return tx * t, min(side, max(ry, -(-tiles // tx))) * t


def fitting(sizes: np.ndarray, capacity: int) -> int:
    """How many of the squares of ``sizes``, taken in order, fit ``capacity`` texels (they pack without a gap)."""
    area = np.cumsum(np.asarray(sizes, np.int64) ** 2)
    return int(np.searchsorted(area, capacity, side="right"))


def morton_decode(code: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of Z-order indices: x from the even bits, y from the odd ones."""
    c = code.astype(np.int64)
    x = np.zeros_like(c)
    y = np.zeros_like(c)
    for b in range(POS_BITS):
        x |= ((c >> (2 * b)) & 1) << b
        y |= ((c >> (2 * b + 1)) & 1) << b
    return x, y


def morton_encode(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Z-order indices of (x, y) (each under ``2**POS_BITS``): x in the even bits, y in the odd ones."""
    x, y = np.asarray(x, np.int64), np.asarray(y, np.int64)
    code = np.zeros(np.broadcast(x, y).shape, np.int64)
    for b in range(POS_BITS):
        code |= ((x >> b) & 1) << (2 * b)
        code |= ((y >> b) & 1) << (2 * b + 1)
    return code


def source_order(view: np.ndarray, level: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A tie key for :func:`pack_squares`: quads of one size in view order, within a view along the Z-order curve
    of their positions in units of their size.  Same-size neighbours in a view then lie side by side in the atlas
    (an aligned 2x2 block of them lands on an aligned 2x2 block), so the codec sees the view's own texture there
    instead of a mosaic of unrelated texels."""
    lv = np.asarray(level, np.int64)
    return (np.asarray(view, np.int64) << (2 * POS_BITS)) | morton_encode(np.asarray(x, np.int64) >> lv,
                                                                          np.asarray(y, np.int64) >> lv)


def pack_squares(sizes: np.ndarray, tile: int, atlas_w: int, atlas_h: int, key: np.ndarray | None = None,
                 reserved: tuple[int, int] = (0, 0)) -> tuple[np.ndarray, np.ndarray]:
    """Atlas positions (x, y) of squares of power-of-two ``sizes`` (each at most ``tile``), packed
    without overlap: largest first (ties by ``key``, else in the given order) along a Z-order curve tile by tile,
    leaving out the ``reserved`` (columns, rows) of tiles at the top left (the centre view's, whole).
    Raises ``ValueError`` when they do not fit (they cover more than the atlas)."""
    sizes = np.asarray(sizes, np.int64)
    n = sizes.size
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if int(sizes.max()) > tile or (sizes & (sizes - 1)).any() or int(sizes.min()) < 1:
        raise ValueError(f"square sizes must be powers of two up to the tile's {tile}")
    order = np.argsort(-sizes, kind="stable") if key is None else np.lexsort((np.asarray(key, np.int64), -sizes))
    area = sizes[order] ** 2
    start = np.cumsum(area) - area                     # a multiple of each square's own area
    tiles_x, tiles_y = atlas_w // tile, atlas_h // tile
    free = np.array([k for k in range(tiles_x * tiles_y) if not (k % tiles_x < reserved[0] and k // tiles_x < reserved[1])],
                    np.int64)
    if int(start[-1] + area[-1]) > free.size * tile * tile:
        raise ValueError(f"{int(area.sum())} texels of quads do not fit a {atlas_w}x{atlas_h} atlas")
    t_idx, within = np.divmod(start, tile * tile)
    t_idx = free[t_idx]
    cx, cy = morton_decode(within // area)
    s = sizes[order]
    x = np.empty(n, np.int64)
    y = np.empty(n, np.int64)
    x[order] = (t_idx % tiles_x) * tile + cx * s
    y[order] = (t_idx // tiles_x) * tile + cy * s
    return x, y


def copy_texels(atlas: np.ndarray, image: np.ndarray, level: np.ndarray, qx: np.ndarray, qy: np.ndarray,
                ax: np.ndarray, ay: np.ndarray) -> None:
    """Copy each quad's square of ``image`` (at ``qx, qy``, side ``2**level``) to the atlas at ``ax, ay``."""
    for lv in np.unique(level):
        sel = np.flatnonzero(level == lv)
        s = 1 << int(lv)
        dy, dx = np.mgrid[0:s, 0:s]
        atlas[ay[sel, None, None] + dy, ax[sel, None, None] + dx] = \
            image[qy[sel, None, None].astype(np.int64) + dy, qx[sel, None, None].astype(np.int64) + dx]
