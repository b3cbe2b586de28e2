"""Procedural meshes with UVs in metres (one texture repeat per ``uv_scale_m``)."""

from __future__ import annotations

import math

import numpy as np

from .model import Mesh


def grid_plane(size_x: float, size_z: float, nx: int, nz: int, uv_scale_m: float = 1.0, name: str = "plane") -> Mesh:
    """A plane in XZ centred at the origin, normal +Y, subdivided into ``nx`` x ``nz`` quads."""
    xs = np.linspace(-size_x / 2, size_x / 2, nx + 1)
    zs = np.linspace(-size_z / 2, size_z / 2, nz + 1)
    gx, gz = np.meshgrid(xs, zs)
    pos = np.stack([gx.ravel(), np.zeros(gx.size), gz.ravel()], axis=1)
    nor = np.tile([0.0, 1.0, 0.0], (pos.shape[0], 1))
    uv = np.stack([gx.ravel(), -gz.ravel()], axis=1) / uv_scale_m
    i = np.arange(nz)[:, None] * (nx + 1) + np.arange(nx)[None, :]
    i = i.ravel()
    a, b, c, d = i, i + 1, i + nx + 1, i + nx + 2
    idx = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    # interleave so that the two triangles of a quad are adjacent in index order
    idx = idx.reshape(2, -1, 3).transpose(1, 0, 2).reshape(-1, 3)
    return Mesh(pos, nor, uv, idx, name)


def box(size: tuple[float, float, float], uv_scale_m: float = 1.0, subdiv: int = 1, name: str = "box") -> Mesh:
    """Axis-aligned box centred at the origin with flat normals; each face ``subdiv`` x ``subdiv`` quads."""
    sx, sy, sz = (s / 2 for s in size)
    faces = [  # normal, u axis, v axis, half extents along (n, u, v)
        ((1, 0, 0), (0, 0, -1), (0, 1, 0), (sx, sz, sy)),
        ((-1, 0, 0), (0, 0, 1), (0, 1, 0), (sx, sz, sy)),
        ((0, 1, 0), (1, 0, 0), (0, 0, -1), (sy, sx, sz)),
        ((0, -1, 0), (1, 0, 0), (0, 0, 1), (sy, sx, sz)),
        ((0, 0, 1), (1, 0, 0), (0, 1, 0), (sz, sx, sy)),
        ((0, 0, -1), (-1, 0, 0), (0, 1, 0), (sz, sx, sy)),
    ]
    pos, nor, uv, idx = [], [], [], []
    base = 0
    n = subdiv
    for normal, uax, vax, (hn, hu, hv) in faces:
        nv, uv_, vv = np.array(normal, float), np.array(uax, float), np.array(vax, float)
        us = np.linspace(-hu, hu, n + 1)
        vs = np.linspace(-hv, hv, n + 1)
        gu, gv = np.meshgrid(us, vs)
        p = nv * hn + gu.ravel()[:, None] * uv_ + gv.ravel()[:, None] * vv
        pos.append(p)
        nor.append(np.tile(nv, (p.shape[0], 1)))
        uv.append(np.stack([gu.ravel(), gv.ravel()], 1) / uv_scale_m)
        i = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
        a, b, c, d = i, i + 1, i + n + 1, i + n + 2
        q = np.stack([np.stack([a, b, c], 1), np.stack([b, d, c], 1)], 1).reshape(-1, 3)
        idx.append(q + base)
        base += p.shape[0]
    return Mesh(np.concatenate(pos), np.concatenate(nor), np.concatenate(uv), np.concatenate(idx), name)


def cylinder(radius: float, height: float, segments: int = 16, caps: bool = True, name: str = "cylinder", axis: str = "y") -> Mesh:
    """Cylinder centred at the origin along ``axis`` with smooth side normals."""
    ang = np.linspace(0, 2 * math.pi, segments + 1)
    c, s = np.cos(ang), np.sin(ang)
    ring = np.stack([c * radius, np.zeros_like(c), s * radius], 1)
    bot = ring + [0, -height / 2, 0]
    top = ring + [0, height / 2, 0]
    pos = np.concatenate([bot, top])
    nor = np.concatenate([np.stack([c, 0 * c, s], 1)] * 2)
    u = ang / (2 * math.pi) * 2 * math.pi * radius
    uv = np.concatenate([np.stack([u, np.zeros_like(u)], 1), np.stack([u, np.full_like(u, height)], 1)])
    k = segments + 1
    i = np.arange(segments)
    idx = np.concatenate([np.stack([i, i + k, i + 1], 1), np.stack([i + 1, i + k, i + k + 1], 1)])
    idx = idx.reshape(2, -1, 3).transpose(1, 0, 2).reshape(-1, 3)
    parts = [(pos, nor, uv, idx)]
    if caps:
        for y, ny in ((-height / 2, -1.0), (height / 2, 1.0)):
            centre = np.array([[0, y, 0]])
            rp = np.concatenate([centre, ring[:-1] + [0, y, 0]])
            rn = np.tile([0, ny, 0], (rp.shape[0], 1))
            ruv = rp[:, [0, 2]]
            j = np.arange(1, segments + 1)
            jn = np.where(j == segments, 1, j + 1)
            tri = np.stack([np.zeros_like(j), jn, j], 1) if ny < 0 else np.stack([np.zeros_like(j), j, jn], 1)
            parts.append((rp, rn, ruv, tri))
    m = _concat(parts, name)
    if axis == "x":
        return _rotate(m, np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], float))
    if axis == "z":
        return _rotate(m, np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float))
    return m


def uv_sphere(radius: float, rings: int = 16, segments: int = 32, name: str = "sphere") -> Mesh:
    th = np.linspace(0, math.pi, rings + 1)
    ph = np.linspace(0, 2 * math.pi, segments + 1)
    gt, gp = np.meshgrid(th, ph, indexing="ij")
    n = np.stack([np.sin(gt) * np.cos(gp), np.cos(gt), np.sin(gt) * np.sin(gp)], -1).reshape(-1, 3)
    uv = np.stack([gp.ravel() / (2 * math.pi) * 4, gt.ravel() / math.pi * 2], 1)
    k = segments + 1
    i = (np.arange(rings)[:, None] * k + np.arange(segments)[None, :]).ravel()
    idx = np.stack([np.stack([i, i + 1, i + k], 1), np.stack([i + 1, i + k + 1, i + k], 1)], 1).reshape(-1, 3)
    # drop degenerate triangles at the poles
    p = n * radius
    a = np.linalg.norm(np.cross(p[idx[:, 1]] - p[idx[:, 0]], p[idx[:, 2]] - p[idx[:, 0]]), axis=1)
    return Mesh(p, n, uv, idx[a > 1e-10], name)


def torus(major: float, minor: float, major_segments: int = 32, minor_segments: int = 12, name: str = "torus") -> Mesh:
    u = np.linspace(0, 2 * math.pi, major_segments + 1)
    v = np.linspace(0, 2 * math.pi, minor_segments + 1)
    gu, gv = np.meshgrid(u, v, indexing="ij")
    cx, cz = np.cos(gu), np.sin(gu)
    pos = np.stack([(major + minor * np.cos(gv)) * cx, minor * np.sin(gv), (major + minor * np.cos(gv)) * cz], -1).reshape(-1, 3)
    nor = np.stack([np.cos(gv) * cx, np.sin(gv), np.cos(gv) * cz], -1).reshape(-1, 3)
    uv = np.stack([gu.ravel() * major, gv.ravel() * minor], 1)
    k = minor_segments + 1
    i = (np.arange(major_segments)[:, None] * k + np.arange(minor_segments)[None, :]).ravel()
    idx = np.stack([np.stack([i, i + 1, i + k], 1), np.stack([i + 1, i + k + 1, i + k], 1)], 1).reshape(-1, 3)
    return Mesh(pos, nor, uv, idx, name)


def _concat(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]], name: str) -> Mesh:
    pos, nor, uv, idx = [], [], [], []
    base = 0
    for p, n, t, i in parts:
        pos.append(p)
        nor.append(n)
        uv.append(t)
        idx.append(i + base)
        base += p.shape[0]
    return Mesh(np.concatenate(pos), np.concatenate(nor), np.concatenate(uv), np.concatenate(idx), name)


def _rotate(m: Mesh, r: np.ndarray) -> Mesh:
    return Mesh(m.positions @ r.T, m.normals @ r.T, m.uvs, m.indices, m.name)


def translate(m: Mesh, offset: tuple[float, float, float]) -> Mesh:
    return Mesh(m.positions + np.asarray(offset, np.float32), m.normals, m.uvs, m.indices, m.name)
