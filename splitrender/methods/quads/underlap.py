"""QUASAR's reference set drawn a fraction of a pixel past its depth edges, behind the surface beyond them.

Seen from a pose near the reference view's, two neighbouring quads of the set whose planes meet the pixel border
between them at different depths (a fin before the cylinder behind it, a concave corner, two flattened quads whose
planes disagree) part by a sliver: what lay on that border from the reference pose now lies at two places on
screen.  Where a display pixel's centre falls in the sliver, no quad of the set covers it, and the client shows a
filled hole there.  MeshWarp's mesh stretches over the sliver instead.  On 2CylinderEngine's orbit under ``cloud``
(320x180, 1 s) those pixels were 0.9 % of QUASAR's model pixels and 8 % of its squared error on the model, against
MeshWarp 60's 0.3 % and 2 % (issue 50, part 2).

:func:`behind_sides` draws each quad up to ``px`` past every side along which its own plane, carried on to the pixel
centres beyond, lies *behind* the surface the set shows there.  From the reference pose that surface hides the
extension (which, shorter than half a pixel, reaches no other pixel's centre there either: the view is drawn exactly
as before), and from another pose it shows only where motion pulls the nearer surface away: it fills the sliver
with the farther side's colour and never draws one surface over another.  ``seal_cracks`` extends both sides of every
border where the surface goes on, in front or behind, so it fattens convex edges (the engine's fins) by nearly half a
pixel seen from any other pose: on the same orbit it cost the model 0.9 dB where this gains 0.15.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ...scene.pose import CameraIntrinsics
from .gen import QuadSet, decode_normals, dot3, ray_grids, rays
from .mesh import continuous_sides, index_map_of, quad_depth, sealed

if TYPE_CHECKING:
    from .config import QuadsConfig

UNDERLAP_MARGIN = 1e-4
"""A quad's plane counts as behind the surface beyond its side when, at every pixel centre along the side, it lies
at least this fraction of that surface's depth behind it."""

_SIDES = ((-1, 0), (0, -1), (1, 0), (0, 1))   # left, top, right, bottom


def _across(qs: QuadSet, sel: np.ndarray, size: int, side: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (x, y), each (len(sel), size), of the pixels just across ``side`` of quads ``sel``."""
    dx, dy = _SIDES[side]
    x0, y0 = qs.x[sel].astype(np.int64), qs.y[sel].astype(np.int64)
    k = np.arange(size)
    if dx:
        return np.broadcast_to((x0 - 1 if dx < 0 else x0 + size)[:, None], (sel.size, size)), y0[:, None] + k
    return x0[:, None] + k, np.broadcast_to((y0 - 1 if dy < 0 else y0 + size)[:, None], (sel.size, size))


def _by_level(qs: QuadSet, bg: np.ndarray):  # type: ignore[no-untyped-def]
    """The scene quads of ``qs`` (``bg``: its background mask) level by level: (their indices, their size in pixels)."""
    for lv in np.unique(qs.level):
        sel = np.flatnonzero((qs.level == lv) & ~bg)
        if sel.size:
            yield sel, 1 << int(lv)


def behind_sides(qs: QuadSet, intr: CameraIntrinsics, px: float, index_map: np.ndarray | None = None) -> np.ndarray:
    """(N, 4) pixels: ``px`` on each side (left, top, right, bottom) of each scene quad of ``qs`` along which every
    pixel across is covered by a scene quad of the set and the quad's own plane, carried to that pixel's centre, lies
    behind the depth the set shows there (:func:`.mesh.quad_depth`, by :data:`UNDERLAP_MARGIN`); 0 elsewhere (the
    view's border, the sky, or a side where the quad's plane would come in front): :func:`.mesh.build_mesh`'s
    ``extend``.  ``index_map``: the set's own (:func:`.mesh.index_map_of`), when the caller has it."""
    out = np.zeros((len(qs), 4))
    if not len(qs) or px <= 0:
        return out
    h, w = intr.height, intr.width
    im = index_map_of(qs, intr, index_map)
    bg = qs.background(intr)
    scene = im >= 0
    scene[scene] = ~bg[im[scene]]
    z_shown = np.where(scene, quad_depth(qs, intr, im), np.inf)
    normals = decode_normals(qs.theta, qs.phi)
    # a pixel centre's ray: x its column's, y its row's, z -1 (the same values as rays(intr, x + 0.5, y + 0.5), read
    # from ray_grids' centres), so plane_depth's dot3 is made of per-column and per-row products (the same bits)
    centre_rays = ray_grids(intr)[0]
    ray_x, ray_y, ray_z = centre_rays[0, :, 0], centre_rays[:, 0, 1], centre_rays[0, 0, 2]
    for sel, size in _by_level(qs, bg):
        n = normals.take(sel, axis=0)
        centre = rays(intr, qs.x[sel].astype(np.float64) + size / 2, qs.y[sel].astype(np.float64) + size / 2)
        neg_w = dot3(n, centre) * qs.depth[sel].astype(np.float64)   # -w of the quad's plane n . X + w = 0, view space
        nx, ny, nz = n[:, 0, None], n[:, 1, None], n[:, 2, None] * ray_z
        for side in range(4):
            xb, yb = _across(qs, sel, size, side)
            inside = (xb >= 0) & (xb < w) & (yb >= 0) & (yb < h)
            xc, yc = np.clip(xb, 0, w - 1), np.clip(yb, 0, h - 1)
            zb = np.where(inside, z_shown.reshape(-1).take(yc * w + xc), np.inf)   # (z_shown[yc, xc], faster)
            den = nx * ray_x[xc] + ny * ray_y[yc]
            den += nz
            with np.errstate(divide="ignore", invalid="ignore"):
                own = neg_w[:, None] / den
            # plane_depth's inf (parallel, or behind the eye) fails as a non-finite depth did
            behind = np.isfinite(zb) & (np.abs(den) > 1e-12) & (own > 0) & np.isfinite(own) & (own >= zb * (1.0 + UNDERLAP_MARGIN))
            out[sel, side] = np.where(behind.all(axis=1), px, 0.0)
    return out


def open_sides(qs: QuadSet, intr: CameraIntrinsics, px: float, index_map: np.ndarray | None = None) -> np.ndarray:
    """(N, 4) pixels: ``px`` on each side of each scene quad of ``qs`` along which every pixel across lies in the
    view and holds no scene quad of the set (the sky, which QUASAR's client lays there itself), else 0: the
    reference set's ``sky_edge_px`` (:func:`.mesh.sky_sides` is QuadStream's, whose views carry their sky quads)."""
    out = np.zeros((len(qs), 4))
    if not len(qs) or px <= 0:
        return out
    h, w = intr.height, intr.width
    im = index_map_of(qs, intr, index_map)
    bg = qs.background(intr)
    sky = im < 0
    sky[~sky] = bg[im[~sky]]
    for sel, size in _by_level(qs, bg):
        for side in range(4):
            xb, yb = _across(qs, sel, size, side)
            inside = (xb >= 0) & (xb < w) & (yb >= 0) & (yb < h)
            across = sky[np.clip(yb, 0, h - 1), np.clip(xb, 0, w - 1)] & inside
            out[sel, side] = np.where(across.all(axis=1), px, 0.0)
    return out


def reference_extend(qs: QuadSet, intr: CameraIntrinsics, config: "QuadsConfig",
                     index_map: np.ndarray | None = None) -> np.ndarray | None:
    """:func:`.mesh.build_mesh`'s ``extend`` for QUASAR's reference set, drawn alike by the client and by the
    server's residual-error test: on each side the largest of :func:`behind_sides` at ``underlap_px``,
    :func:`.mesh.sealed` (``seal_cracks``) and :func:`open_sides` at ``sky_edge_px``; None when all are off."""
    parts = []
    if config.underlap_px > 0:
        parts.append(behind_sides(qs, intr, config.underlap_px, index_map))
    if config.seal_cracks:
        parts.append(sealed(continuous_sides(qs, quad_depth(qs, intr, index_map))))
    if config.sky_edge_px > 0:
        parts.append(open_sides(qs, intr, config.sky_edge_px, index_map))
    if not parts:
        return None
    out = parts[0]
    for p in parts[1:]:
        out = np.maximum(out, p)
    return out
