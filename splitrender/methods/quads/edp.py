"""Effective depth peeling (QUASAR section 3.3, after Kim and Lee 2023): which hidden fragments
an eye inside the view cell could see.

The server peels layers with the renderer's depth peeling; this module decides which
fragments of a hidden layer to keep.  **Parallax test**: an eye moved by up to ``r``
metres (the view sphere's radius) shifts a point at depth ``z`` and image offset ``rho``
pixels from the principal point by at most ``r (f + rho) / z`` pixels, so a hidden
fragment at depth ``z_h`` behind a front surface at ``z_f`` moves against it by at most
``R = r (f + rho) (1 / z_f - 1 / z_h)`` pixels.  It can show only if some pixel within
``R`` of it has a front surface at least as far as ``z_h`` (the occluder's edge lies
within reach).  Kept: ``R >= 0.5`` and the largest front depth in the square of radius
``R`` (rounded up to the next of 1, 2, 3, 4, 6, 8, ... 128) reaches ``z_h (1 - tolerance)``.

:func:`brute_force_seen` is the reference it is measured against: the fragments that
any of ``n`` eyes spread through the sphere sees.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import maximum_filter

from ...scene.pose import CameraIntrinsics, Pose
from .gen import rays

RADII = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128)
FAR_STANDIN = 1e9


def parallax_px(front: np.ndarray, hidden: np.ndarray, intr: CameraIntrinsics, radius_m: float) -> np.ndarray:
    """``R``: the largest shift (pixels) of each hidden fragment against the front surface over the view sphere."""
    h, w = front.shape
    ys, xs = np.mgrid[0:h, 0:w]
    rho = np.hypot(xs + 0.5 - w / 2, ys + 0.5 - h / 2)
    f = intr.focal_px()
    zf = np.where(np.isfinite(front), front, FAR_STANDIN)
    zh = np.where(np.isfinite(hidden), hidden, FAR_STANDIN)
    return np.maximum(radius_m * (f + rho) * (1.0 / zf - 1.0 / zh), 0.0)


def edp_keep(front: np.ndarray, hidden: np.ndarray, intr: CameraIntrinsics, radius_m: float, tolerance: float = 0.01) -> np.ndarray:
    """(H, W) bool: the hidden layer's fragments the parallax test keeps."""
    valid = np.isfinite(hidden)
    if not valid.any() or radius_m <= 0:
        return np.zeros_like(valid)
    r = parallax_px(front, hidden, intr, radius_m)
    zf = np.where(np.isfinite(front), front, FAR_STANDIN).astype(np.float32)
    keep = np.zeros_like(valid)
    need = valid & (r >= 0.5)
    lower = 0.0
    for k, rad in enumerate(RADII):
        band = need & (r > lower) & ((r <= rad) | (k == len(RADII) - 1))
        lower = rad
        if not band.any():
            continue
        m = maximum_filter(zf, size=2 * rad + 1, mode="constant", cval=FAR_STANDIN)
        keep |= band & (m >= hidden * (1.0 - tolerance))
    return keep


def sphere_eyes(n: int, radius_m: float) -> np.ndarray:
    """``n`` deterministic offsets filling a ball of ``radius_m`` evenly (a Fibonacci spiral over shells), the centre first."""
    out = [np.zeros(3)]
    golden = math.pi * (3 - math.sqrt(5))
    for k in range(1, n):
        rr = radius_m * (k / (n - 1)) ** (1 / 3)
        y = 1 - 2 * ((k * 0.618034) % 1.0)
        s = math.sqrt(max(0.0, 1 - y * y))
        a = golden * k
        out.append(rr * np.array([s * math.cos(a), y, s * math.sin(a)]))
    return np.array(out)


def brute_force_seen(renderer: object, scene: object, t_s: float, pose: Pose, intr: CameraIntrinsics, world: np.ndarray,
                     radius_m: float, eyes: int = 64, tolerance: float = 0.01) -> np.ndarray:
    """(N,) bool: which of the world points (fragments of hidden layers) any of ``eyes`` eyes in the
    view sphere around ``pose`` sees (same orientation, a 1.5x wider view so the frustum cuts nothing):
    the point projects in front of, or within ``tolerance`` (relative) of, that eye's nearest surface
    at its pixel or a 4-neighbour."""
    big = intr.enlarged(1.5, keep_pixel_density=True)
    seen = np.zeros(len(world), bool)
    rot = pose.matrix()[:3, :3]
    proj = big.projection()
    for off in sphere_eyes(eyes, radius_m):
        eye = Pose(pose.position + rot @ off, pose.orientation)
        depth = renderer.render(scene, t_s, eye, big, ("depth",)).depth  # type: ignore[attr-defined]
        v = world @ eye.view_matrix()[:3, :3].T + eye.view_matrix()[:3, 3]
        z = -v[:, 2]
        c = np.c_[v, np.ones(len(v))] @ proj.T
        with np.errstate(divide="ignore", invalid="ignore"):
            px = (c[:, 0] / c[:, 3] * 0.5 + 0.5) * big.width
            py = (0.5 - c[:, 1] / c[:, 3] * 0.5) * big.height
        ok = (z > 0) & (px >= 0) & (px < big.width) & (py >= 0) & (py < big.height)
        xi = np.clip(px.astype(np.int64), 0, big.width - 1)
        yi = np.clip(py.astype(np.int64), 0, big.height - 1)
        best = np.full(len(world), np.inf)
        for dx, dy in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)):
            zz = depth[np.clip(yi + dy, 0, big.height - 1), np.clip(xi + dx, 0, big.width - 1)]
            best = np.minimum(best, np.abs(zz - z) / np.maximum(z, 1e-6))
        front = depth[yi, xi] >= z * (1 - tolerance)
        seen |= ok & ((best < tolerance) | front)
    return seen


def unproject(depth: np.ndarray, pose: Pose, intr: CameraIntrinsics, mask: np.ndarray) -> np.ndarray:
    """World points (N, 3) of the pixels in ``mask`` at their view depths."""
    ys, xs = np.nonzero(mask)
    d = rays(intr, xs + 0.5, ys + 0.5) * depth[ys, xs][:, None]
    m = pose.matrix()
    return d @ m[:3, :3].T + m[:3, 3]
