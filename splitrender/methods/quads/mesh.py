"""The client's quad cache and layered mesh (QUASAR section 3.6), shared by both halves:
the server keeps the same cache to know what the client holds.

:class:`ReferenceCache` holds the quads of the newest reference frame and the updates
since, with a quad index map at the reference camera's resolution (each pixel: the
quad that covers it last); an update's quads overwrite the map where they lie, and a
cached quad no pixel names any more is freed.  :func:`build_mesh` turns sets of quads
into one indexed triangle mesh in world space, textured from the atlas; :class:`QuadMeshGL`
draws it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ...render.gl import set_uniform
from ...scene.pose import CameraIntrinsics, Pose
from .gen import (BACKGROUND_FAR, MAX_LEVEL, OUTER, QuadSet, corner_points, decode_normals, dot3, encode_normals,
                  ray_grids, rays)

SHADERS = Path(__file__).parent / "shaders"
VERTEX_FLOATS = 3 + 3 + 4 + 1
CENTRE_PRIORITY = 0.005
"""QuadStream's centre view wins over the later views (:meth:`QuadMeshGL.set_guard`) within this fraction of its depth:
a later view's fragment that the centre camera sees more than this in front of the centre view's nearest surface
around it is discarded (a quad's overhang past a silhouette: no surface a later view adds can lie in front of what
the centre view shows), and the later views' corners are drawn pushed back along their rays by
:data:`VIEW_BIAS`, so that at the centre pose every fragment left loses the depth test to the centre view's.
Measured (``tests/test_quads_thin.py``'s railing, client moved in the view cell): 0.5 % gave the railing 7.1 dB over
QUASAR, 1 and 2 % 6.9 dB, only the discard (at 0.1 % behind) 3.0 dB, neither 5.0 dB."""
VIEW_BIAS = CENTRE_PRIORITY / (1.0 - CENTRE_PRIORITY) + 1e-4
"""A later view's corners are drawn this fraction farther along their rays (the same pixels): a fragment
:data:`CENTRE_PRIORITY` in front of the centre view's surface still lies behind it."""
GUARD_REACH_PX = 0.49
"""How far (centre-view pixels) around a fragment's centre-view position the guard looks for that nearest surface: at
the centre pose a fragment lies on its pixel's centre and sees that pixel alone; elsewhere the up to four pixels
nearest it, so a surface that the centre view sees edge-on (a post's side) is kept beside the centre's silhouette."""
FAR_SCALE = 16.0
"""The mesh is drawn with the far plane this many times the camera's: background quads lie at 98 % of the far
distance along their source camera's axis, so seen from a camera turned towards its edge a wide view's (120
degrees) background lies well beyond the far plane (1.6x it for a point 75 degrees off axis, seen 9 degrees
closer) and would be clipped to a hole."""
ColourClamp = Literal["quad", "view"]
SUB_TRIANGLES = np.array([[s * 4 + a for a in tri] for s in range(4) for tri in ((0, 2, 1), (1, 2, 3))], np.uint32).ravel()
"""24 indices into a quad's 16 corners: two triangles per sub-quad (TL, BL, TR) and (TR, BL, BR)."""
FLAT_TRIANGLES = np.array([0, 10, 5, 5, 10, 15], np.uint32)
"""6 indices into a flat quad's 16 corners: its outer corners' (TL, BL, TR) and (TR, BL, BR).  Its 16 corners lie on
one plane, so two triangles draw the surface eight do; llvmpipe's cost per display frame follows the triangles
(issue 49: the default walk's mesh draw 24 -> 9 ms of CPU with flat quads as two triangles)."""
FLAT_LOCAL = np.array([0, 2, 1, 1, 2, 3], np.uint32)
""":data:`FLAT_TRIANGLES` over the four vertices :func:`build_mesh` makes for a flat quad, its :data:`~.gen.OUTER`
corners (0, 5, 10, 15 of the 16) in that order."""


def concat(sets: list[QuadSet]) -> QuadSet:
    if not sets:
        return QuadSet.empty()
    return QuadSet(*(np.concatenate([getattr(s, k) for s in sets]) for k in ("level", "x", "y", "theta", "phi", "depth", "flat")),
                   np.concatenate([s.offsets for s in sets]).reshape(-1, 16))


def select(qs: QuadSet, keep: np.ndarray) -> QuadSet:
    """The quads where ``keep``, their offsets with them."""
    nonflat_keep = keep[~qs.flat]
    return QuadSet(qs.level[keep], qs.x[keep], qs.y[keep], qs.theta[keep], qs.phi[keep], qs.depth[keep], qs.flat[keep],
                   qs.offsets[nonflat_keep])


def rasterize(index_map: np.ndarray, qs: QuadSet, first: int) -> None:
    """Write quad indices ``first + i`` over the pixels each quad covers."""
    h, w = index_map.shape
    for lv in np.unique(qs.level):
        sel = np.flatnonzero(qs.level == lv)
        s = 1 << int(lv)
        dy, dx = np.mgrid[0:s, 0:s]
        ys = qs.y[sel, None].astype(np.int64) + dy.ravel()
        xs = qs.x[sel, None].astype(np.int64) + dx.ravel()
        ok = (ys < h) & (xs < w)
        idx = np.broadcast_to((first + sel)[:, None], ys.shape)
        if index_map.flags.c_contiguous:    # by flat index (faster; the same writes)
            index_map.reshape(-1)[ys[ok] * w + xs[ok]] = idx[ok]
        else:
            index_map[ys[ok], xs[ok]] = idx[ok]


def index_map_of(qs: QuadSet, intr: CameraIntrinsics, index_map: np.ndarray | None = None) -> np.ndarray:
    """(H, W) int64: the quad of ``qs`` covering each pixel (:func:`rasterize`, -1 where none); ``index_map`` when
    given, the caller's map of the same set (:attr:`ReferenceCache.index_map` while :attr:`ReferenceCache.raster`),
    read and not changed."""
    if index_map is not None:
        if index_map.shape != (intr.height, intr.width):
            raise ValueError(f"index_map is {index_map.shape}, the view {(intr.height, intr.width)}")
        return index_map
    out = np.full((intr.height, intr.width), -1, np.int64)
    rasterize(out, qs, 0)
    return out


def background_quads(qs: QuadSet, intr: CameraIntrinsics, region: np.ndarray | None = None,
                     index_map: np.ndarray | None = None) -> QuadSet:
    """The background quads a view's set would have carried (``generate(..., background=True)``): over the pixels of
    ``region`` (all when ``None``) that no quad of ``qs`` covers.  The client makes them itself when the server sends
    none (``QuadsConfig.background_quads`` off, as QUASAR's code sends none), so its sky is drawn as before.

    Every background pixel lies on the same plane (facing the eye at :data:`~.gen.BACKGROUND_FAR` of the far
    distance, flat), so every merge of four present quads succeeds at any thresholds and the set is the quadtree of
    the pixels: at each level the 2x2 blocks whose four children are present merge, the rest stay.  (``generate``
    makes the same set, field for field, tested; this takes about 1 ms where it took 60-300 ms at 320x180.)
    ``index_map``: :func:`index_map_of`'s."""
    present = index_map_of(qs, intr, index_map) < 0
    if region is not None:
        present &= region
    return _far_quadtree(present, intr)


def _far_quadtree(present: np.ndarray, intr: CameraIntrinsics) -> QuadSet:
    """The quadtree of the ``present`` pixels as flat quads facing the eye at the background's far plane."""
    theta, phi = encode_normals(np.array([0.0, 0.0, 1.0]))
    levels, xs, ys = [], [], []
    for level in range(MAX_LEVEL + 1):
        h, w = present.shape[0] // 2, present.shape[1] // 2
        if level < MAX_LEVEL and min(present.shape) >= 2 and present.any():
            p = present[:2 * h, :2 * w]
            merged = p[0::2, 0::2] & p[0::2, 1::2] & p[1::2, 0::2] & p[1::2, 1::2]
            stay = present.copy()
            stay[:2 * h, :2 * w] &= ~np.repeat(np.repeat(merged, 2, axis=0), 2, axis=1)
        else:
            merged, stay = np.zeros((h, w), bool), present
        yy, xx = np.nonzero(stay)
        levels.append(np.full(yy.size, level, np.uint8))
        xs.append((xx << level).astype(np.uint16))
        ys.append((yy << level).astype(np.uint16))
        if not merged.any():
            break
        present = merged
    lv = np.concatenate(levels)
    n = lv.size
    return QuadSet(lv, np.concatenate(xs), np.concatenate(ys), np.full(n, theta, np.uint8), np.full(n, phi, np.uint8),
                   np.full(n, np.float32(BACKGROUND_FAR * intr.far_m), np.float32), np.ones(n, bool),
                   np.zeros((0, 16), np.float16))


HIDDEN_SKY_PX = 8
"""The reach measured for :func:`hidden_sky` (pixels, in the reference view, behind the model's silhouette against the
sky), its default; the client lays them at its config's ``hidden_sky_px`` (0, none, by default)."""


def hidden_sky(qs: QuadSet, intr: CameraIntrinsics, slot_origin: tuple[int, int],
               reach: int | None = None, index_map: np.ndarray | None = None) -> tuple[QuadSet, np.ndarray]:
    """Sky quads behind the model: the pixels that ``qs`` covers within ``reach`` pixels of one it leaves
    uncovered (the background), as flat quads on the background's far plane, each coloured by the background texel
    nearest its centre.  Returns the quads and that texel's atlas position per quad ((N, 2), for :func:`build_mesh`'s
    ``texel``).  ``reach`` defaults to :data:`HIDDEN_SKY_PX`.

    Invisible from the reference pose (the model lies in front), they show where the client's motion reveals the
    background next to a silhouette.  Without them those pixels are holes, and the hole fill (the farther of the
    first covered samples along the epipolar line) takes the model's colour wherever a sliver of it lies on the way:
    the model bled over the background (Wuson, the peer benchmark's strafe: 2/3 of our QUASAR's wrongly covered
    background pixels lay in filled holes, issue 50).  QUASAR's code draws its clear colour there, the background.
    Only near the sky: a pixel further from it (a model standing on a ground) may reveal the ground, which the hole
    fill finds.  ``index_map``: :func:`index_map_of`'s."""
    from scipy.ndimage import distance_transform_edt

    reach = HIDDEN_SKY_PX if reach is None else reach
    if reach <= 0:
        return QuadSet.empty(), np.zeros((0, 2), np.float64)
    covered = index_map_of(qs, intr, index_map) >= 0
    if covered.all() or not covered.any():
        return QuadSet.empty(), np.zeros((0, 2), np.float64)
    dist, (iy, ix) = distance_transform_edt(covered, return_indices=True)
    sky = _far_quadtree(covered & (dist <= reach), intr)
    half = (1 << sky.level.astype(np.int64)) // 2
    cy = np.minimum(sky.y.astype(np.int64) + half, intr.height - 1)
    cx = np.minimum(sky.x.astype(np.int64) + half, intr.width - 1)
    texel = np.stack([ix[cy, cx] + slot_origin[0], iy[cy, cx] + slot_origin[1]], axis=-1).astype(np.float64)
    return sky, texel


@dataclass
class ReferenceCache:
    """The cached reference quads of one camera and their quad index map."""

    pose: Pose | None = None
    intr: CameraIntrinsics | None = None
    frame_id: int = -1
    quads: QuadSet | None = None
    index_map: np.ndarray | None = None
    freed: int = 0
    raster: bool = False
    """:attr:`index_map` is :func:`rasterize`'s of :attr:`quads` (so far from a reference set alone; an update's quads
    overwrite it in their own order), for :func:`index_map_of`."""

    def set_reference(self, qs: QuadSet, pose: Pose, intr: CameraIntrinsics, frame_id: int) -> None:
        self.pose, self.intr, self.frame_id, self.quads = pose, intr, frame_id, qs
        self.index_map = np.full((intr.height, intr.width), -1, np.int64)
        rasterize(self.index_map, qs, 0)
        self.freed = 0
        self.raster = True

    def apply_update(self, qs: QuadSet) -> None:
        """Append an update's quads, overwrite the index map where they lie, free quads covered entirely."""
        assert self.quads is not None and self.index_map is not None
        n0 = len(self.quads)
        allq = concat([self.quads, qs])
        rasterize(self.index_map, qs, n0)
        named = np.zeros(len(allq), bool)
        named[self.index_map[self.index_map >= 0]] = True
        named[n0:] = True  # an update's quads are drawn even where a later one of the same update overlaps
        self.freed = int((~named[:n0]).sum())
        self.raster = False
        remap = np.cumsum(named) - 1
        self.quads = select(allq, named)
        m = self.index_map >= 0
        self.index_map[m] = remap[self.index_map[m]]

    def __len__(self) -> int:
        return 0 if self.quads is None else len(self.quads)


SURFACE_REL = 0.05
"""Two neighbouring pixels of a view lie on one surface when their depths differ by at most this fraction
(:func:`continuous_sides`)."""


def continuous_sides(qs: QuadSet, depth: np.ndarray, rel: float | None = None) -> np.ndarray:
    """(N, 4) float: half a texel on each side (left, top, right, bottom) of each quad of ``qs`` where every pixel
    along that side and its neighbour across it lie on one surface (``depth``: the view's (H, W) depth, top row
    first; within ``rel`` of each other), else 0: :func:`build_mesh`'s ``grow``, so a quad's bilinear lookup
    filters across its border where the atlas holds the view's own image beyond it (QuadStream's centre view,
    whole in its atlas) and the surface goes on, and stops at depth edges (a post before a wall stays crisp).
    ``rel`` defaults to :data:`SURFACE_REL`."""
    rel = SURFACE_REL if rel is None else rel
    if not len(qs):
        return np.zeros((len(qs), 4))
    z = np.where(np.isfinite(depth) & (depth > 0), depth, np.inf)
    return _sides_of_pairs(qs, _one_surface(z[:, :-1], z[:, 1:], rel), _one_surface(z[:-1], z[1:], rel))


def _sides_of_pairs(qs: QuadSet, across: np.ndarray, down_pairs: np.ndarray) -> np.ndarray:
    """:func:`continuous_sides` from which pairs of neighbouring pixels lie on one surface: ``across`` (H, W - 1)
    each pixel and its right neighbour, ``down_pairs`` (H - 1, W) each and its lower one."""
    h, w = down_pairs.shape[0] + 1, across.shape[1] + 1
    out = np.zeros((len(qs), 4))
    # per pixel: it and its right (below: its lower) neighbour lie on one surface, both in the view; false beyond
    # the view out to the largest quad's size, so a quad's side that leaves the view counts no pixel there
    size = 1 << qs.level.astype(np.int64)
    pad = int(size.max()) + 1
    right = np.zeros((h + pad, w + pad), bool)
    below = np.zeros((h + pad, w + pad), bool)
    right[:h, :w - 1] = across
    below[:h - 1, :w] = down_pairs
    # running counts down the columns of ``right`` and along the rows of ``below`` (a zero first row / column): a
    # quad's side is continuous where all ``size`` of its pixels' pairs across it are
    down = np.zeros((h + pad + 1, w + pad), np.int32)
    np.cumsum(right, axis=0, out=down[1:])
    along = np.zeros((h + pad, w + pad + 1), np.int32)
    np.cumsum(below, axis=1, out=along[:, 1:])
    x0, y0 = qs.x.astype(np.int64), qs.y.astype(np.int64)
    xl, yt = np.maximum(x0 - 1, 0), np.maximum(y0 - 1, 0)     # the pair's first pixel: the neighbour on the left / top
    xr, yb = x0 + size - 1, y0 + size - 1
    full = {0: (x0 > 0) & (down[y0 + size, xl] - down[y0, xl] == size),
            1: (y0 > 0) & (along[yt, x0 + size] - along[yt, x0] == size),
            2: down[y0 + size, xr] - down[y0, xr] == size,
            3: along[yb, x0 + size] - along[yb, x0] == size}
    for side, ok in full.items():
        out[:, side] = np.where(ok, 0.5, 0.0)
    return out


def _one_surface(za: np.ndarray, zb: np.ndarray, rel: float) -> np.ndarray:
    """Neighbouring depths on one surface: equal (two inf: the same background), or within ``rel`` of the nearer."""
    with np.errstate(invalid="ignore"):   # inf - inf: equal, caught by the first test
        return (za == zb) | (np.abs(za - zb) <= rel * np.minimum(za, zb))


def scene_sides(qs: QuadSet, intr: CameraIntrinsics, index_map: np.ndarray | None = None) -> np.ndarray:
    """:func:`continuous_sides` of a view's set over its own coverage: half a texel on each side whose neighbouring
    pixel is a scene pixel of the set, 0 where it is background (no quad there, or a background quad) or outside
    the view.  QUASAR's reference set (``QuadsConfig.silhouette_clamp``): its lookup filters across quad borders
    inside the model, as the view's image would, and stops at the silhouette, so an edge quad seen from another
    pose never mixes in the sky texels beside it (QUASAR's code samples its view nearest, no blend at all).
    ``index_map``: :func:`index_map_of`'s."""
    index_map = index_map_of(qs, intr, index_map)
    if not len(qs):
        return np.zeros((0, 4))
    scene = index_map >= 0
    scene[scene] = ~qs.background(intr)[index_map[scene]]
    # continuous_sides of a depth 1 at scene pixels and 1e6 elsewhere (background: one far 'surface' of its own):
    # two such depths are on one surface exactly when they are equal, so when both pixels are scene or neither is
    return _sides_of_pairs(qs, scene[:, :-1] == scene[:, 1:], scene[:-1] == scene[1:])


SEAL_PX = 0.45
"""How far past a side where the surface goes on a quad is drawn (``QuadsConfig.seal_cracks``, :func:`sealed`)."""


def quad_depth(qs: QuadSet, intr: CameraIntrinsics, index_map: np.ndarray | None = None) -> np.ndarray:
    """(H, W) view depth at each pixel's centre of the plane of the quad of ``qs`` that covers it (the last one),
    top row first, inf where none does: the view's depth as its quads give it, the same on both halves.
    ``index_map``: :func:`index_map_of`'s."""
    index_map = index_map_of(qs, intr, index_map)
    if not len(qs):
        return np.full(index_map.shape, np.inf)
    # each quad's plane once, read at its pixels (the same arithmetic per value as per pixel); row N of the planes is
    # a stand-in for the pixels no quad covers (index -1), whose depth is inf
    s = 2.0 ** qs.level.astype(np.float64)
    planes = np.zeros((len(qs) + 1, 4))
    planes[:-1, :3] = decode_normals(qs.theta, qs.phi)
    planes[:-1, 3] = dot3(planes[:-1, :3], rays(intr, qs.x + s / 2, qs.y + s / 2)) * qs.depth.astype(np.float64)
    at = planes.take(index_map, axis=0)     # (H, W, 4): the normal and -w of the plane at each pixel (take: the
    # same rows as planes[index_map], index -1 the last, several times faster)
    # a pixel centre's ray: its x is its column's, its y its row's, its z -1 (ray_grids' centres, the same values as
    # rays(intr, x + 0.5, y + 0.5)); plane_depth's dot3 from those (the same products and sums), and -w / den
    centre = ray_grids(intr)[0]
    den = at[..., 0] * centre[0, :, 0]
    den += at[..., 1] * centre[:, 0, 1, None]
    den += at[..., 2] * centre[0, 0, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        z = at[..., 3] / den
    return np.where((index_map >= 0) & (np.abs(den) > 1e-12) & (z > 0), z, np.inf)


def sealed(sides: np.ndarray) -> np.ndarray:
    """:func:`build_mesh`'s ``extend`` that seals the cracks between a view's quads: :data:`SEAL_PX` on each side
    where ``sides`` (:func:`continuous_sides` or :func:`scene_sides`: half a texel where the lookup filters across)
    is set, 0 elsewhere.  Two neighbouring quads flattened onto planes that disagree at their shared border open a
    crack there seen from another pose, and what lies behind (the sky quads, a hidden layer) showed through (issue
    50: single pixels inside the model, on the peer benchmark's Wuson and Spider).  Less than half a pixel, so that
    from the view's own pose no quad reaches another pixel's centre and the view is drawn exactly as before."""
    return np.where(np.asarray(sides) > 0, SEAL_PX, 0.0)


def sky_sides(qs: QuadSet, intr: CameraIntrinsics, px: float) -> np.ndarray:
    """(N, 4) pixels: ``px`` on each side (left, top, right, bottom) of each scene quad of ``qs`` along which every
    pixel across lies in the view and is covered by one of the set's background quads (the sky), else 0:
    :func:`build_mesh`'s ``extend``.  A view's silhouette against the sky, drawn that far out on the quad's own
    plane: the model's true outline crosses the last model pixel's neighbour anywhere up to its centre, and a quad
    stops half a pixel short of that, so seen from another pose a display pixel whose centre lies on the model in
    that sliver showed the sky (issue 50: most of QuadStream's missed model pixels on the peer benchmark).  QUASAR's
    code (``expandEdges``) adds a whole pixel, at the farthest neighbour's depth, which is its silhouettes' bleed."""
    out = np.zeros((len(qs), 4))
    if not len(qs) or px <= 0:
        return out
    h, w = intr.height, intr.width
    index_map = np.full((h, w), -1, np.int64)
    rasterize(index_map, qs, 0)
    bg = qs.background(intr)
    sky = np.zeros((h, w), bool)
    sky[index_map >= 0] = bg[index_map[index_map >= 0]]
    for lv in np.unique(qs.level):
        sel = np.flatnonzero((qs.level == lv) & ~bg)
        if not sel.size:
            continue
        size = 1 << int(lv)
        x0, y0 = qs.x[sel].astype(np.int64), qs.y[sel].astype(np.int64)
        k = np.arange(size)
        for side, (dx, dy) in enumerate(((-1, 0), (0, -1), (1, 0), (0, 1))):
            if dx:
                xb = np.broadcast_to((x0 - 1 if dx < 0 else x0 + size)[:, None], (sel.size, size))
                yb = y0[:, None] + k
            else:
                yb = np.broadcast_to((y0 - 1 if dy < 0 else y0 + size)[:, None], (sel.size, size))
                xb = x0[:, None] + k
            inside = (xb >= 0) & (xb < w) & (yb >= 0) & (yb < h)
            across = sky[np.clip(yb, 0, h - 1), np.clip(xb, 0, w - 1)] & inside
            out[sel, side] = np.where(across.all(axis=1), px, 0.0)
    return out


class MeshPart(tuple):  # type: ignore[type-arg]
    """:func:`build_mesh`'s (vertices, indices), unpacked as a pair, with :attr:`quads`, the quads it draws."""

    quads: int

    def __new__(cls, vertices: np.ndarray, indices: np.ndarray, quads: int) -> "MeshPart":
        part = super().__new__(cls, (vertices, indices))
        part.quads = int(quads)
        return part


def build_mesh(qs: QuadSet, pose: Pose, intr: CameraIntrinsics, slot_origin: tuple[int, int] | np.ndarray,
               clamp: ColourClamp = "quad", texel: np.ndarray | None = None, view: int = 0,
               grow: np.ndarray | None = None, extend: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A :class:`MeshPart`: (vertices (V, 11) float32: world xyz, homogeneous atlas pixel coordinates
    ``(u z, v z, z)`` with ``z`` the corner's depth in the source camera, atlas pixel rect, ``view``; 4 for a flat
    quad (its outer corners) and 16 for another, the flat quads' first; indices uint32, quad by quad: 24
    (:data:`SUB_TRIANGLES`) for a quad with offsets, 6 for a flat one (:data:`FLAT_TRIANGLES`)).

    ``view``: the set's view, 0 for the centre view (and all of QUASAR's sets); a later view's fragments are subject
    to the centre view's guard (:meth:`QuadMeshGL.set_guard`).

    ``slot_origin``: where the source camera's pixel (0, 0) lies in the atlas, one (x, y) for
    the whole set (a slot) or (N, 2) per quad (a packed atlas: its atlas position less its x, y).

    The atlas position of a surface point is its projection in the source camera, a
    projective function of the point: ``(u z, v z, z)`` is affine in it, so interpolated
    perspective-correctly and divided per fragment it gives the exact atlas position from
    any viewpoint (plain ``uv`` would bend across slanted quads).

    ``clamp``: the rect the fragment shader clamps its bilinear lookup to.  ``"view"`` (a slot: the quads' own
    G-buffer lies whole in the atlas) is the source view's image, so the lookup filters across quad borders as a
    mesh over the image would and never reads a neighbouring slot; ``"quad"`` (a packed atlas, whose neighbouring
    texels belong to unrelated quads) is the quad's own pixels, which makes every one-pixel quad a flat
    nearest-neighbour sample (on 2CylinderEngine+ground, orbit under cloud, 2 s, that cost QUASAR 1.1 dB on the
    model, ``benchmarks/bench_quads_models.py``).  ``texel`` ((N, 2) atlas pixels, optional): every fragment of quad
    i takes the colour of that one texel instead (:func:`hidden_sky`).  ``grow`` ((N, 4) texels, optional, with
    ``"quad"``): each quad's rect widened on its left, top, right and bottom (:func:`continuous_sides`).  ``extend``
    ((N, 4) pixels, optional): each quad's geometry drawn that far past its left, top, right and bottom side, on its
    own plane (:func:`sky_sides`, :func:`sealed`), where no corner's depth moves by more than :data:`SURFACE_REL`; its
    lookup there is clamped to the rect as anywhere else."""
    if len(qs) == 0:
        return MeshPart(np.zeros((0, VERTEX_FLOATS), np.float32), np.zeros(0, np.uint32), 0)
    # a flat quad is drawn as its outer corners' two triangles (FLAT_TRIANGLES), so only those four are made: the same
    # bits for them and the same triangles in the same order, a quarter of the vertices
    org_all = np.broadcast_to(np.asarray(slot_origin, np.float64), (len(qs), 2))
    m = pose.matrix()
    kept = np.zeros(len(qs), bool)
    verts = []
    for group, corners in ((qs.flat, OUTER), (~qs.flat, None)):
        if not group.any():
            continue
        part = qs if group.all() else select(qs, group)
        where = np.flatnonzero(group)
        pts, uv, ok = corner_points(part, intr, corners=corners)
        if extend is not None:
            # a quad seen nearly edge-on: its plane a fraction of a pixel further on may lie far off, or behind the
            # eye; such a quad is drawn as it is.  (A flat quad's depth ratio along a side lies between its
            # corners', so its outer corners decide as its 16 did.)
            # Only the quads with a side to move: another's corners moved by 0 are its own, the same bits
            ext = np.asarray(extend, np.float64)[where]
            moved = (ext != 0).any(-1)
            if moved.any():
                pe, ue, oke = corner_points(part if moved.all() else select(part, moved), intr, ext[moved], corners)
                with np.errstate(divide="ignore", invalid="ignore"):
                    use = oke & ok[moved] & (np.abs(pe[..., 2] / pts[moved][..., 2] - 1.0) <= SURFACE_REL).all(-1)
                at = np.flatnonzero(moved)[use]
                pts[at], uv[at] = pe[use], ue[use]   # (corner_points' own arrays)
        keep = where[ok]
        kept[keep] = True
        verts.append(_vertices(qs, keep, pts[ok], uv[ok], m, org_all[keep], intr, clamp, texel, view, grow))
    v = np.concatenate(verts) if len(verts) > 1 else verts[0]
    # in quad order (the depth test keeps the first of equal depths): 6 indices for a flat quad, 24 for another; a
    # flat quad's four vertices first, then the others' 16
    flat = qs.flat[kept]
    nflat = int(flat.sum())
    if flat.all():
        return MeshPart(v, (np.arange(nflat, dtype=np.uint32)[:, None] * 4 + FLAT_LOCAL[None, :]).ravel(), flat.size)
    base = np.where(flat, 4 * (np.cumsum(flat) - 1), 4 * nflat + 16 * (np.cumsum(~flat) - 1)).astype(np.uint32)
    if not flat.any():
        return MeshPart(v, (base[:, None] + SUB_TRIANGLES[None, :]).ravel(), flat.size)
    counts = np.where(flat, FLAT_LOCAL.size, SUB_TRIANGLES.size)
    start = np.cumsum(counts) - counts
    idx = np.empty(int(counts.sum()), np.uint32)
    for sel, tri in ((flat, FLAT_LOCAL), (~flat, SUB_TRIANGLES)):
        idx[(start[sel][:, None] + np.arange(tri.size)).ravel()] = (base[sel][:, None] + tri[None, :]).ravel()
    return MeshPart(v, idx, flat.size)


def _vertices(qs: QuadSet, keep: np.ndarray, pts: np.ndarray, uv: np.ndarray, m: np.ndarray, org: np.ndarray,
              intr: CameraIntrinsics, clamp: ColourClamp, texel: np.ndarray | None, view: int,
              grow: np.ndarray | None) -> np.ndarray:
    """:func:`build_mesh`'s vertices (K, C, :data:`VERTEX_FLOATS`) of quads ``keep`` of ``qs`` from their C corners'
    view-space points ``pts`` and image positions ``uv``, ``m`` the source camera's pose matrix, ``org`` their slot
    origins (K, 2), flattened to (K C, :data:`VERTEX_FLOATS`)."""
    n, c = pts.shape[:2]
    # a product per quad (numpy's own loop): one (K C, 3) product goes to OpenBLAS, whose threads took 80 ms for
    # 65k corners on this busy machine (1.5 ms this way), the same bits
    world = pts @ m[:3, :3].T + m[:3, 3]
    s = (2.0 ** qs.level[keep].astype(np.float64))
    x0 = qs.x[keep].astype(np.float64) + org[:, 0]
    y0 = qs.y[keep].astype(np.float64) + org[:, 1]
    if texel is not None:
        t = np.asarray(texel, np.float64)[keep]
        rect = np.concatenate([t, t + 1.0], axis=-1)
    elif clamp == "view":
        rect = np.stack([org[:, 0], org[:, 1], org[:, 0] + intr.width, org[:, 1] + intr.height], axis=-1)
    else:
        rect = np.stack([x0, y0, x0 + s, y0 + s], axis=-1)
        if grow is not None:
            rect += np.asarray(grow, np.float64)[keep] * np.array([-1.0, -1.0, 1.0, 1.0])
    v = np.empty((n, c, VERTEX_FLOATS), np.float32)
    v[..., 0:3] = world
    zs = -pts[..., 2]
    v[..., 3] = (uv[..., 0] + org[:, None, 0]) * zs
    v[..., 4] = (uv[..., 1] + org[:, None, 1]) * zs
    v[..., 5] = zs
    v[..., 6:10] = rect[:, None, :]
    v[..., 10] = view
    return v.reshape(-1, VERTEX_FLOATS)


def join_meshes(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    if len(parts) == 1:     # one part is its own join (no copy)
        return parts[0][0], parts[0][1].astype(np.uint32, copy=False)
    vs, ids, base = [], [], 0
    for v, i in parts:
        vs.append(v)
        ids.append(i + np.uint32(base))
        base += v.shape[0]
    if not vs:
        return np.zeros((0, VERTEX_FLOATS), np.float32), np.zeros(0, np.uint32)
    return np.concatenate(vs), np.concatenate(ids).astype(np.uint32)


class QuadMeshGL:
    """Draws a quad mesh from any pose into colour (alpha = coverage) and view depth (0 = none)."""

    def __init__(self, ctx: Any) -> None:
        import moderngl

        from ...render.gl import load_program

        self.ctx = ctx
        self._mgl = moderngl
        self.prog = load_program(ctx, SHADERS / "quads_mesh.vert", SHADERS / "quads_mesh.frag")
        self._guard_prog: Any = None
        """The program with the guard compiled in (``QUADS_GUARD``), made at the first :meth:`set_guard`; the plain
        one cannot discard, so its fragments are depth-tested before they are shaded."""
        self._guard_vao: Any = None
        self.vbo: Any = None
        self.ibo: Any = None
        self.vao: Any = None
        self.count = 0
        self.vertices = 0
        """Vertices uploaded (4 a flat quad, 16 another)."""
        self.quads = 0
        """Quads uploaded by :meth:`upload_parts` (its :class:`MeshPart` s')."""
        self._targets: dict[tuple[int, int], tuple[Any, Any, Any]] = {}
        self._guard: tuple[Any, Pose, CameraIntrinsics] | None = None
        self.guard_depth: np.ndarray | None = None
        """The centre view's depth from its camera (H, W), top row first, 0 where none (:meth:`set_guard`)."""

    def _bind(self) -> None:
        """The vertex array over :attr:`vbo` and :attr:`ibo` (after either is made anew)."""
        self.vao = self._vertex_array(self.prog)
        if self._guard_vao is not None:
            self._guard_vao.release()
        self._guard_vao = None   # made when a draw needs it

    def _vertex_array(self, prog: Any) -> Any:
        return self.ctx.vertex_array(prog, [(self.vbo, "3f 3f 4f 1f", "in_pos", "in_uvw", "in_rect", "in_view")],
                                     index_buffer=self.ibo, index_element_size=4)

    def upload(self, vertices: np.ndarray, indices: np.ndarray) -> None:
        for b in (self.vao, self._guard_vao, self.vbo, self.ibo):
            if b is not None:
                b.release()
        self.vao = self._guard_vao = self.vbo = self.ibo = None
        self.count = int(indices.size)
        self.vertices = int(vertices.shape[0])
        if self.count == 0:
            return
        # the arrays themselves (the buffer protocol), not a bytes copy of them
        self.vbo = self.ctx.buffer(np.ascontiguousarray(vertices, np.float32))
        self.ibo = self.ctx.buffer(np.ascontiguousarray(indices, np.uint32))
        self._bind()

    def upload_parts(self, parts: list[tuple[np.ndarray, np.ndarray]]) -> None:
        """``upload(*join_meshes(parts))`` without the joined copy: each part written into buffers of the whole
        mesh's size at its offset, its indices moved past the parts before it (the same bytes in the buffers)."""
        nv = sum(int(v.shape[0]) for v, _ in parts)
        ni = sum(int(i.size) for v, i in parts if v.shape[0])
        self.upload(np.zeros((0, VERTEX_FLOATS), np.float32), np.zeros(0, np.uint32))
        self.quads = sum(getattr(p, "quads", 0) for p in parts)
        if ni == 0:
            return
        self.vbo = self.ctx.buffer(reserve=nv * VERTEX_FLOATS * 4)
        self.ibo = self.ctx.buffer(reserve=ni * 4)
        self._bind()
        for v, i in parts:
            if v.shape[0]:
                self.vbo.write(np.ascontiguousarray(v, np.float32), offset=self.vertices * VERTEX_FLOATS * 4)
                self.ibo.write((np.asarray(i, np.uint32) + np.uint32(self.vertices)).astype(np.uint32),
                               offset=self.count * 4)
                self.vertices += int(v.shape[0])
                self.count += int(i.size)

    def append(self, vertices: np.ndarray, indices: np.ndarray) -> None:
        """Add a part (``indices`` counted from its own first vertex) after the mesh uploaded so far: the mesh that
        ``upload(*join_meshes(parts))`` gives, the same vertices and indices in the same order, without joining and
        uploading the earlier parts again (QuadStream's server masks each view with the views before it).  The
        buffers grow by doubling, their contents copied on the GL side."""
        v = np.ascontiguousarray(vertices, np.float32)
        if v.shape[0] == 0:
            return
        i = (np.asarray(indices, np.uint32) + np.uint32(self.vertices)).astype(np.uint32)
        vb, ib = v.shape[0] * VERTEX_FLOATS * 4, i.size * 4
        used_v, used_i = self.vertices * VERTEX_FLOATS * 4, self.count * 4
        if self.vbo is None or self.vbo.size < used_v + vb or self.ibo.size < used_i + ib:
            vbo = self.ctx.buffer(reserve=max(used_v + vb, 2 * (self.vbo.size if self.vbo is not None else 0)))
            ibo = self.ctx.buffer(reserve=max(used_i + ib, 2 * (self.ibo.size if self.ibo is not None else 0)))
            if self.vbo is not None and used_v:
                self.ctx.copy_buffer(vbo, self.vbo, used_v)
                self.ctx.copy_buffer(ibo, self.ibo, used_i)
            for b in (self.vao, self._guard_vao, self.vbo, self.ibo):
                if b is not None:
                    b.release()
            self._guard_vao = None
            self.vbo, self.ibo = vbo, ibo
            self._bind()
        self.vbo.write(v, offset=used_v)
        self.ibo.write(i, offset=used_i)
        self.vertices += v.shape[0]
        self.count += i.size

    def set_guard(self, vertices: np.ndarray, indices: np.ndarray, pose: Pose, intr: CameraIntrinsics) -> None:
        """The centre view's guard (QuadStream): the mesh ``vertices``/``indices`` (the centre view's set) drawn from
        ``pose`` (the centre camera) once, its view depth kept; from then on :meth:`draw` discards every fragment of a
        later view (``build_mesh``'s ``view`` > 0) that, seen from the centre camera, lies more than
        :data:`CENTRE_PRIORITY` in front of the centre view's nearest surface within :data:`GUARD_REACH_PX` of it, and
        pushes the rest back by :data:`VIEW_BIAS` (the same pixels, a farther depth), so the centre view wins ties.  Every surface
        a later view adds lies behind what the centre view shows, so this drops only the later views' duplicates of
        the centre view's surfaces and their quads' overhang past a silhouette (a quad fills its whole pixel
        footprint), which otherwise won the depth test over the centre view at the centre pose (issue 50: 2CylinderEngine
        20.2 dB at the server's pose with a lossless atlas, the centre view alone exact)."""
        self.clear_guard()
        keep = (self.vao, self._guard_vao, self.vbo, self.ibo, self.count, self.vertices)
        self.vao = self._guard_vao = self.vbo = self.ibo = None
        self.upload(vertices, indices)
        _, _, depth = self.draw(pose, intr, None, (1, 1))
        guard = self.ctx.texture((intr.width, intr.height), 1, dtype="f4")
        guard.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
        raw = depth.read()
        guard.write(raw)
        self.guard_depth = np.frombuffer(raw, np.float32).reshape(intr.height, intr.width)[::-1].copy()
        for b in (self.vao, self._guard_vao, self.vbo, self.ibo):
            if b is not None:
                b.release()
        self.vao, self._guard_vao, self.vbo, self.ibo, self.count, self.vertices = keep
        self._guard = (guard, pose, intr)
        if self._guard_prog is None:
            from ...render.gl import load_program

            self._guard_prog = load_program(self.ctx, SHADERS / "quads_mesh.vert", SHADERS / "quads_mesh.frag",
                                            defines={"QUADS_GUARD": 1})

    def clear_guard(self) -> None:
        if self._guard is not None:
            self._guard[0].release()
        self._guard = None

    def target(self, w: int, h: int) -> tuple[Any, Any, Any]:
        t = self._targets.get((w, h))
        if t is None:
            color = self.ctx.texture((w, h), 4, dtype="f1")
            depth = self.ctx.texture((w, h), 1, dtype="f4")
            for tex in (color, depth):
                tex.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
            fbo = self.ctx.framebuffer([color, depth], self.ctx.depth_renderbuffer((w, h)))
            t = (fbo, color, depth)
            self._targets[(w, h)] = t
        return t

    def draw(self, pose: Pose, intr: CameraIntrinsics, atlas: Any | None, atlas_size: tuple[int, int],
             atlas_alpha: bool = False) -> tuple[Any, Any, Any]:
        """Draw into the target of ``intr``'s size; returns (framebuffer, colour texture, depth texture).  The
        colour's alpha is 1 where the mesh covers, 0 elsewhere; with ``atlas_alpha`` the atlas's (filtered) alpha
        where it covers instead (the server's residual-error test carries a mask in it)."""
        fbo, color, depth = self.target(intr.width, intr.height)
        fbo.use()
        self.ctx.viewport = (0, 0, intr.width, intr.height)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        if self.vao is not None:
            prog, vao = self.prog, self.vao
            if self._guard is not None:
                if self._guard_vao is None:
                    self._guard_vao = self._vertex_array(self._guard_prog)
                prog, vao = self._guard_prog, self._guard_vao
            self.ctx.enable(self.ctx.DEPTH_TEST)
            self.ctx.disable(self.ctx.CULL_FACE | self.ctx.BLEND)
            proj = replace(intr, far_m=intr.far_m * FAR_SCALE).projection()
            prog["u_proj"].write(np.asarray(proj, "f4").T.tobytes())
            set_uniform(prog, "u_view_bias", VIEW_BIAS if self._guard is not None else 0.0)
            prog["u_view"].write(np.asarray(pose.view_matrix(), "f4").T.tobytes())
            set_uniform(prog, "u_atlas_size", (float(atlas_size[0]), float(atlas_size[1])))
            set_uniform(prog, "u_has_atlas", 0 if atlas is None else 1)
            set_uniform(prog, "u_atlas_alpha", 1 if atlas_alpha and atlas is not None else 0)
            set_uniform(prog, "u_has_guard", 0 if self._guard is None else 1)
            if self._guard is not None:
                tex, gpose, gintr = self._guard
                gvp = replace(gintr, far_m=gintr.far_m * FAR_SCALE).projection() @ gpose.view_matrix()
                prog["u_guard_vp"].write(np.asarray(gvp, "f4").T.tobytes())
                prog["u_guard_view"].write(np.asarray(gpose.view_matrix(), "f4").T.tobytes())
                set_uniform(prog, "u_guard_size", (float(gintr.width), float(gintr.height)))
                set_uniform(prog, "u_guard_front", CENTRE_PRIORITY)
                set_uniform(prog, "u_guard_reach", GUARD_REACH_PX)
                tex.use(1)
                set_uniform(prog, "u_guard", 1)
            if atlas is not None:
                atlas.use(0)
                set_uniform(prog, "u_atlas", 0)
            vao.render(mode=self._mgl.TRIANGLES, vertices=self.count)
        return fbo, color, depth

    def depth_at(self, pose: Pose, intr: CameraIntrinsics) -> np.ndarray:
        """(H, W) view depth of the mesh seen from ``pose`` (inf where it covers nothing), top row first."""
        _, _, depth = self.draw(pose, intr, None, (1, 1))
        z = np.frombuffer(depth.read(), np.float32).reshape(intr.height, intr.width)[::-1].copy()
        z[z <= 0] = np.inf
        return z
