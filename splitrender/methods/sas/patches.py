"""Patches: groups of one, two or three adjacent triangles, the unit of SAS visibility
and atlas allocation (paper section 3.1 and figure 4).

Built once at load time per mesh, for static and animated objects alike (rigid
animation does not change a patch).  The heuristic:

1. candidate pairs are triangles sharing an edge (by vertex index); a pair scores
   highest when the shared edge is the longest edge of both triangles, i.e. it is the
   diagonal of a quad, which fills a rectangular block with little distortion;
2. pairs are matched greedily, best score first (two-triangle patches preferred);
3. a leftover triangle adjacent to a pair joins it as a three-triangle strip;
4. what is still left is a one-triangle patch ("used only when unavoidable").

Block layout (figure 6): every patch maps to a rectangle with block-local coordinates
``(u, v)`` in ``[0, 1]^2``; ``u`` runs along the block width, ``v`` along its height.

- one triangle ``(a, b, c)``: a (0,0), b (1,0), c (0,1) (half the block);
- two triangles ``(c, a, b)`` + ``(a, b, d)`` sharing edge ab: c (0,0), a (1,0), b (0,1), d (1,1);
- three-triangle strip ``s0 s1 s2 | s1 s2 s3 | s2 s3 s4``: s0 (0,1), s1 (0,0), s2 (.5,1), s3 (1,0), s4 (1,1).

Each patch has up to five vertex *slots*; per patch we keep the slots' mesh vertex
indices and layout coordinates, and per triangle the three slots it uses.  The layout
tables (`SLOT_LAYOUT`, `TRI_SLOTS`) are part of the wire format, in :mod:`.wire`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...scene.model import Mesh, Scene

MAX_SLOTS = 5
MAX_TRIS = 3

#: Edges parallel to the block width: (slot, slot, layout length in u).
WIDTH_EDGES: dict[int, list[tuple[int, int, float]]] = {
    1: [(0, 1, 1.0)],
    2: [(0, 1, 1.0), (2, 3, 1.0)],
    3: [(0, 2, 0.5), (2, 4, 0.5), (1, 3, 1.0)],
}
#: Edges parallel to the block height: (slot, slot, layout length in v).
HEIGHT_EDGES: dict[int, list[tuple[int, int, float]]] = {
    1: [(0, 2, 1.0)],
    2: [(0, 2, 1.0), (1, 3, 1.0)],
    3: [(0, 1, 1.0), (3, 4, 1.0)],
}


@dataclass
class MeshPatches:
    """Patches of one mesh.

    ``slots`` (P, 5) int32 mesh vertex index per slot (-1 unused); ``tris`` (P, 3) int32
    mesh triangle index per patch triangle (-1 unused); ``size`` (P,) int8 triangles per
    patch (1..3); ``tri_patch`` (T,) int32 patch of each mesh triangle.
    """

    slots: np.ndarray
    tris: np.ndarray
    size: np.ndarray
    tri_patch: np.ndarray

    @property
    def count(self) -> int:
        return int(self.size.shape[0])

    def histogram(self) -> dict[int, int]:
        """Number of patches with 1, 2 and 3 triangles."""
        return {k: int((self.size == k).sum()) for k in (1, 2, 3)}


def _edge_table(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interior edges shared by exactly two triangles: (tri_a, tri_b, edge (E, 2) vertex ids)."""
    t = idx.shape[0]
    e = np.stack([idx[:, [0, 1]], idx[:, [1, 2]], idx[:, [2, 0]]], axis=1).reshape(-1, 2)
    e.sort(axis=1)
    tri = np.repeat(np.arange(t), 3)
    key = e[:, 0].astype(np.int64) * (int(idx.max()) + 1 if t else 1) + e[:, 1]
    order = np.argsort(key, kind="stable")
    ks = key[order]
    same = ks[1:] == ks[:-1]
    # keep only keys occurring exactly twice (manifold interior edges)
    first = np.flatnonzero(same)
    ok = np.ones(first.shape, bool)
    ok &= ~np.concatenate([same[1:], [False]])[first]          # no third occurrence
    ok &= ~np.concatenate([[False], same[:-1]])[first]         # no earlier occurrence
    first = first[ok]
    a, b = tri[order[first]], tri[order[first + 1]]
    keep = a != b
    return a[keep], b[keep], e[order[first]][keep]


def build_mesh_patches(mesh: Mesh) -> MeshPatches:
    """Group the triangles of ``mesh`` into patches (see the module docstring)."""
    idx = mesh.indices.astype(np.int64)
    t = idx.shape[0]
    pos = mesh.positions.astype(np.float64)
    ta, tb, edges = _edge_table(idx)
    # score: shared edge length over the longest edge of each triangle (1 = quad diagonal)
    p = pos[idx]
    elen = np.linalg.norm(p[:, [1, 2, 0]] - p, axis=2)
    emax = elen.max(axis=1) + 1e-12
    shared = np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=1)
    score = np.minimum(shared / emax[ta], shared / emax[tb])
    order = np.argsort(-score, kind="stable")
    partner = np.full(t, -1, np.int64)
    ta_l, tb_l = ta[order].tolist(), tb[order].tolist()
    for a, b in zip(ta_l, tb_l):
        if partner[a] < 0 and partner[b] < 0:
            partner[a] = b
            partner[b] = a
    # adjacency lists for attaching leftover singles
    singles = np.flatnonzero(partner < 0)
    third = np.full(t, -1, np.int64)   # for a paired triangle: the single attached to it
    if singles.size:
        single_set = set(singles.tolist())
        neigh: dict[int, list[int]] = {}
        for a, b in zip(ta.tolist(), tb.tolist()):
            if a in single_set:
                neigh.setdefault(a, []).append(b)
            if b in single_set:
                neigh.setdefault(b, []).append(a)
        for s in singles.tolist():
            if partner[s] >= 0:
                continue
            for n in neigh.get(s, []):
                if partner[n] >= 0 and third[n] < 0 and third[partner[n]] < 0 and partner[n] != s:
                    third[n] = s
                    partner[s] = -2  # consumed
                    break
    slots, tris, size = [], [], []
    tri_patch = np.full(t, -1, np.int32)
    idx_l = idx.tolist()
    for i in range(t):
        if tri_patch[i] >= 0 or partner[i] == -2:
            continue
        pid = len(size)
        j = int(partner[i])
        if j < 0:
            a, b, c = idx_l[i]
            slots.append([a, b, c, -1, -1])
            tris.append([i, -1, -1])
            size.append(1)
            tri_patch[i] = pid
            continue
        s = int(third[i]) if third[i] >= 0 else int(third[j])
        if s < 0:
            ti, tj = idx_l[i], idx_l[j]
            c = next(v for v in ti if v not in tj)
            rest = [v for v in ti if v != c]        # shared edge a, b in i's order
            d = next(v for v in tj if v not in ti)
            slots.append([c, rest[0], rest[1], d, -1])
            tris.append([i, j, -1])
            size.append(2)
            tri_patch[[i, j]] = pid
            continue
        mid = i if third[i] >= 0 else j        # the triangle the single touches
        other = j if mid == i else i
        tm, to, ts = idx_l[mid], idx_l[other], idx_l[s]
        e1 = [v for v in tm if v in ts]        # edge shared with the single
        e3 = [v for v in tm if v in to]        # edge shared with the pair partner
        bshared = next(v for v in e1 if v in e3)
        a = next(v for v in e1 if v != bshared)
        c = next(v for v in e3 if v != bshared)
        pv = next(v for v in ts if v not in tm)
        q = next(v for v in to if v not in tm)
        slots.append([pv, a, bshared, c, q])
        tris.append([s, mid, other])
        size.append(3)
        tri_patch[[s, mid, other]] = pid
    return MeshPatches(np.array(slots, np.int32).reshape(-1, MAX_SLOTS), np.array(tris, np.int32).reshape(-1, MAX_TRIS),
                       np.array(size, np.int8), tri_patch)


@dataclass
class ScenePatches:
    """Scene-wide patch table.  Global patch ids are ``0..count-1`` in object order.

    ``object_index`` (P,) index into ``scene.objects``; ``local`` (P,) patch index inside
    its object; ``tri_to_patch`` (T_scene,) global patch of each scene-wide triangle
    (the renderer's ``tri_base`` order); ``size`` (P,) triangles per patch;
    ``slot_pos``/``slot_nrm`` (P, 5, 3), ``slot_uv`` (P, 5, 2) and ``slot_tan`` (P, 5, 4)
    object-space vertex attributes per slot (float32).
    """

    per_object: list[MeshPatches]
    object_index: np.ndarray
    local: np.ndarray
    size: np.ndarray
    tri_to_patch: np.ndarray
    slot_pos: np.ndarray
    slot_nrm: np.ndarray
    slot_uv: np.ndarray
    base: np.ndarray
    slot_tan: np.ndarray

    @property
    def count(self) -> int:
        return int(self.size.shape[0])


def build_scene_patches(scene: Scene) -> ScenePatches:
    """Patches for every object of ``scene`` (object order = renderer triangle order)."""
    per, oi, loc, sz, t2p, sp, sn, su, st, base = [], [], [], [], [], [], [], [], [], []
    pbase = 0
    for k, o in enumerate(scene.objects):
        mp = build_mesh_patches(o.mesh)
        per.append(mp)
        oi.append(np.full(mp.count, k, np.int32))
        loc.append(np.arange(mp.count, dtype=np.int32))
        sz.append(mp.size)
        t2p.append(mp.tri_patch + pbase)
        s = np.where(mp.slots < 0, 0, mp.slots)
        sp.append(o.mesh.positions[s])
        sn.append(o.mesh.normals[s])
        su.append(o.mesh.uvs[s])
        st.append(o.mesh.tangent_frame()[s])
        base.append(pbase)
        pbase += mp.count
    return ScenePatches(per, np.concatenate(oi), np.concatenate(loc), np.concatenate(sz), np.concatenate(t2p).astype(np.int32),
                        np.concatenate(sp).astype(np.float32), np.concatenate(sn).astype(np.float32),
                        np.concatenate(su).astype(np.float32), np.array(base, np.int64),
                        np.concatenate(st).astype(np.float32))
