"""Octahedral maps and cube-map capture directions for light probes, in numpy.

The shaders (``render/shaders/ddgi.glsl``) mirror :func:`oct_encode`; everything else here
runs once per probe volume (fixed direction sets and weight matrices) or per update (a
matrix product and the guard bands).

**Octahedral map** (Cigolle et al. 2014, as DDGI uses it): a direction ``d`` maps to
``p = d.xz / (|x| + |y| + |z|)`` folded over the diagonals for ``y < 0``, in
``[-1, 1]^2``; a probe's ``n x n`` core texels cover that square, texel ``(i, j)`` at
``((i + 1/2) / n, (j + 1/2) / n) * 2 - 1``.  With one guard texel on every side
(:func:`add_guard`) a bilinear tap anywhere in the core reads the right neighbours
across the map's folded edges.

**Capture directions**: each probe sees the scene through a cube of six ``F x F``
faces; the pixel centres are the probe's fixed ray set (``6 F^2`` rays, no random
rotation, so a still scene gives the same probes every update).
"""

from __future__ import annotations

import numpy as np

CUBE_FACES = (
    # (forward, up) of each cube face camera, in the order they are captured
    ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    ((-1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    ((0.0, 1.0, 0.0), (0.0, 0.0, -1.0)),
    ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
)


def oct_encode(d: np.ndarray) -> np.ndarray:
    """(..., 2) octahedral coordinates in [-1, 1] of directions ``d`` (..., 3), not necessarily unit."""
    d = np.asarray(d, np.float64)
    n = d / np.maximum(np.abs(d).sum(axis=-1, keepdims=True), 1e-300)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    px, pz = x.copy(), z.copy()
    neg = y < 0
    px[neg] = (1.0 - np.abs(z[neg])) * np.where(x[neg] >= 0, 1.0, -1.0)
    pz[neg] = (1.0 - np.abs(x[neg])) * np.where(z[neg] >= 0, 1.0, -1.0)
    return np.stack([px, pz], axis=-1)


def oct_decode(p: np.ndarray) -> np.ndarray:
    """(..., 3) unit directions of octahedral coordinates ``p`` (..., 2)."""
    p = np.asarray(p, np.float64)
    x, z = p[..., 0], p[..., 1]
    y = 1.0 - np.abs(x) - np.abs(z)
    neg = y < 0
    xx = np.where(neg, (1.0 - np.abs(z)) * np.where(x >= 0, 1.0, -1.0), x)
    zz = np.where(neg, (1.0 - np.abs(x)) * np.where(z >= 0, 1.0, -1.0), z)
    d = np.stack([xx, y, zz], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def texel_directions(n: int) -> np.ndarray:
    """(n * n, 3) unit directions of an ``n x n`` octahedral core's texel centres, row-major (j, i)."""
    c = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    px, pz = np.meshgrid(c, c)                       # [j, i]: i along x, j along z
    return oct_decode(np.stack([px, pz], axis=-1)).reshape(-1, 3)


def add_guard(core: np.ndarray) -> np.ndarray:
    """(..., n + 2, n + 2, C) tiles: ``core`` (..., n, n, C) with DDGI's one-texel octahedral guard band.

    The map's edges fold onto themselves mirrored: the top guard row is core row 0
    reversed, the bottom row core row ``n - 1`` reversed, the left and right columns the
    core's first and last columns reversed; each corner takes the diagonally opposite
    core corner."""
    n = core.shape[-2]
    out = np.zeros(core.shape[:-3] + (n + 2, n + 2, core.shape[-1]), core.dtype)
    out[..., 1:-1, 1:-1, :] = core
    out[..., 0, 1:-1, :] = core[..., 0, ::-1, :]
    out[..., -1, 1:-1, :] = core[..., -1, ::-1, :]
    out[..., 1:-1, 0, :] = core[..., ::-1, 0, :]
    out[..., 1:-1, -1, :] = core[..., ::-1, -1, :]
    out[..., 0, 0, :] = core[..., -1, -1, :]
    out[..., 0, -1, :] = core[..., -1, 0, :]
    out[..., -1, 0, :] = core[..., 0, -1, :]
    out[..., -1, -1, :] = core[..., 0, 0, :]
    return out


def cube_directions(face_res: int) -> tuple[np.ndarray, np.ndarray]:
    """(6 F^2, 3) unit directions of every cube-face pixel centre (faces in :data:`CUBE_FACES` order, each
    face's rows from the bottom as GL stores them) and (6 F^2,) their solid angles, scaled to sum to 4 pi.

    A face camera looks along ``forward`` with ``up`` up and ``right = forward x up``
    (90 degrees, square)."""
    F = face_res
    c = (np.arange(F) + 0.5) / F * 2.0 - 1.0
    u, v = np.meshgrid(c, c)                         # [row, column]: rows bottom to top
    dirs, omega = [], []
    for fwd, up in CUBE_FACES:
        f, upv = np.asarray(fwd), np.asarray(up)
        right = np.cross(f, upv)
        d = f[None, None] + u[..., None] * right[None, None] + v[..., None] * upv[None, None]
        r2 = (d * d).sum(-1)
        dirs.append((d / np.sqrt(r2)[..., None]).reshape(-1, 3))
        omega.append(((2.0 / F) ** 2 / r2 ** 1.5).reshape(-1))
    om = np.concatenate(omega)
    return np.concatenate(dirs), om * (4.0 * np.pi / om.sum())


def irradiance_weights(texel_dirs: np.ndarray, ray_dirs: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """(T, R) weights turning ray radiance into irradiance at each texel direction: ``max(0, n . w) dOmega``
    (the cosine integral; radiance L everywhere gives pi L)."""
    return np.maximum(texel_dirs @ ray_dirs.T, 0.0) * omega[None, :]


def visibility_weights(texel_dirs: np.ndarray, ray_dirs: np.ndarray, omega: np.ndarray, sharpness: float) -> np.ndarray:
    """(T, R) weights of the distance moments: ``max(0, n . w)^sharpness dOmega``, normalised per texel."""
    w = np.maximum(texel_dirs @ ray_dirs.T, 0.0) ** sharpness * omega[None, :]
    return w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300)
