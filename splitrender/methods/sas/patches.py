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

import math
from dataclasses import dataclass, field

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
    slots: list[list[int]] = []
    tris: list[list[int]] = []
    size: list[int] = []
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
    object-space vertex attributes per slot (float32); ``meshes`` the (possibly split,
    :func:`split_mesh`) mesh of each object whose triangles the patches group;
    ``slot_vertex`` (P, 5) int64 scene-wide vertex id per slot (the objects' vertices one
    after another, -1 unused).
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
    meshes: list[Mesh] = field(default_factory=list)
    slot_vertex: np.ndarray = field(default_factory=lambda: np.zeros((0, MAX_SLOTS), np.int64))

    @property
    def count(self) -> int:
        return int(self.size.shape[0])


def build_scene_patches(scene: Scene, meshes: list[Mesh] | None = None) -> ScenePatches:
    """Patches for every object of ``scene`` (object order = renderer triangle order).

    ``meshes`` replaces the objects' meshes (one per object, e.g. from
    :func:`split_scene_meshes`); ``tri_to_patch`` then follows their triangles.
    """
    per, oi, loc, sz, t2p, sp, sn, su, st, base, sv = [], [], [], [], [], [], [], [], [], [], []
    pbase = vbase = 0
    meshes = [o.mesh for o in scene.objects] if meshes is None else meshes
    for k, mesh in enumerate(meshes):
        mp = build_mesh_patches(mesh)
        per.append(mp)
        oi.append(np.full(mp.count, k, np.int32))
        loc.append(np.arange(mp.count, dtype=np.int32))
        sz.append(mp.size)
        t2p.append(mp.tri_patch + pbase)
        s = np.where(mp.slots < 0, 0, mp.slots)
        sp.append(mesh.positions[s])
        sn.append(mesh.normals[s])
        su.append(mesh.uvs[s])
        st.append(mesh.tangent_frame()[s])
        base.append(pbase)
        sv.append(np.where(mp.slots < 0, -1, mp.slots.astype(np.int64) + vbase))
        pbase += mp.count
        vbase += mesh.vertex_count
    return ScenePatches(per, np.concatenate(oi), np.concatenate(loc), np.concatenate(sz), np.concatenate(t2p).astype(np.int32),
                        np.concatenate(sp).astype(np.float32), np.concatenate(sn).astype(np.float32),
                        np.concatenate(su).astype(np.float32), np.array(base, np.int64),
                        np.concatenate(st).astype(np.float32), list(meshes),
                        np.concatenate(sv) if sv else np.zeros((0, MAX_SLOTS), np.int64))


# ---------------------------------------------------------------------------- load-time splitting
def split_mesh(mesh: Mesh, max_edge_m: float, max_rounds: int = 8, max_triangles: int | None = None) -> Mesh:
    """``mesh`` with every edge longer than ``max_edge_m`` (metres) halved, round after round (red-green refinement).

    An edge is split at its midpoint in every triangle that uses it (edges are keyed
    by vertex index pair), so the result is conforming: no T-junctions, no cracks.  A
    triangle with three long edges becomes four, one with two becomes three, one with
    one becomes two.  Positions, normals and texture coordinates of a midpoint are the
    averages of its edge's ends (normals are *not* renormalised), so the split mesh
    interpolates every attribute exactly as the original does: it renders the same.
    At most ``max_rounds`` rounds (each at most quadruples the triangle count); no
    round starts once the mesh has more than ``max_triangles``.
    """
    pos = mesh.positions.astype(np.float64)
    nrm = mesh.normals.astype(np.float64)
    uv = mesh.uvs.astype(np.float64)
    idx = mesh.indices.astype(np.int64)
    for _ in range(max_rounds):
        if idx.shape[0] == 0 or (max_triangles is not None and idx.shape[0] > max_triangles):
            break
        a, b = idx, np.roll(idx, -1, axis=1)                        # edge k: vertex k -> k+1
        long = np.linalg.norm(pos[b] - pos[a], axis=2) > max_edge_m  # (T, 3)
        if not long.any():
            break
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        key = lo * pos.shape[0] + hi
        ukey, inv = np.unique(key[long], return_inverse=True)
        n0 = pos.shape[0]
        ea, eb = ukey // n0, ukey % n0
        pos = np.concatenate([pos, (pos[ea] + pos[eb]) / 2])
        nrm = np.concatenate([nrm, (nrm[ea] + nrm[eb]) / 2])
        uv = np.concatenate([uv, (uv[ea] + uv[eb]) / 2])
        mid = np.full(idx.shape, -1, np.int64)
        mid[long] = n0 + inv
        idx = _refine(idx, mid, long)
    return Mesh(pos.astype(np.float32), nrm.astype(np.float32), uv.astype(np.float32), idx.astype(np.uint32), mesh.name)


def _refine(idx: np.ndarray, mid: np.ndarray, long: np.ndarray) -> np.ndarray:
    """New (T', 3) triangles of red-green refinement; ``mid`` (T, 3) midpoint vertex of edge k (k -> k+1) or -1."""
    n = long.sum(axis=1)
    out = [idx[n == 0]]
    parent = [np.flatnonzero(n == 0)]
    # one long edge: rotate it to edge 0, then (v0, m0, v2) + (m0, v1, v2)
    sel = np.flatnonzero(n == 1)
    if sel.size:
        r = np.argmax(long[sel], axis=1)
        rot = (r[:, None] + np.arange(3)) % 3
        v = np.take_along_axis(idx[sel], rot, 1)
        m0 = mid[sel, r]
        out.append(np.stack([np.stack([v[:, 0], m0, v[:, 2]], 1), np.stack([m0, v[:, 1], v[:, 2]], 1)], 1).reshape(-1, 3))
        parent.append(np.repeat(sel, 2))
    # two long edges: rotate the short one to edge 2, then (m0, v1, m1) + the quad v0 m0 m1 v2 split at its diagonal
    sel = np.flatnonzero(n == 2)
    if sel.size:
        r = (np.argmin(long[sel], axis=1) + 1) % 3
        rot = (r[:, None] + np.arange(3)) % 3
        v = np.take_along_axis(idx[sel], rot, 1)
        mm = np.take_along_axis(mid[sel], rot, 1)
        m0, m1 = mm[:, 0], mm[:, 1]
        out.append(np.stack([np.stack([m0, v[:, 1], m1], 1), np.stack([v[:, 0], m0, m1], 1),
                             np.stack([v[:, 0], m1, v[:, 2]], 1)], 1).reshape(-1, 3))
        parent.append(np.repeat(sel, 3))
    # three long edges: four similar triangles
    sel = np.flatnonzero(n == 3)
    if sel.size:
        v, m = idx[sel], mid[sel]
        out.append(np.stack([np.stack([v[:, 0], m[:, 0], m[:, 2]], 1), np.stack([m[:, 0], v[:, 1], m[:, 1]], 1),
                             np.stack([m[:, 2], m[:, 1], v[:, 2]], 1), np.stack([m[:, 0], m[:, 1], m[:, 2]], 1)], 1).reshape(-1, 3))
        parent.append(np.repeat(sel, 4))
    # children stay where their parent was, so triangle order stays spatially coherent
    return np.concatenate(out)[np.argsort(np.concatenate(parent), kind="stable")]


def split_scene_meshes(scene: Scene, max_edge_m: float, max_triangles: int) -> tuple[list[Mesh], float]:
    """Every object's mesh split to edges of at most ``max_edge_m`` metres in the world (:func:`split_mesh`).

    The bound is taken into each object's own space through its placement's largest stretch
    (a model loaded at 1/40 scale splits to edges 40x longer in its own units; animations are
    taken as rigid).  Should that exceed ``max_triangles`` in all, the edge bound grows by
    sqrt(2) until it fits (never below the original meshes).  Returns the meshes and the
    (world) bound used.
    """
    if not np.isfinite(max_edge_m) or max_edge_m <= 0:
        return [o.mesh for o in scene.objects], math.inf
    limit = max(max_triangles, scene.triangle_count)
    stretch = [float(np.linalg.norm(np.asarray(o.transform, np.float64)[:3, :3], 2)) or 1.0 for o in scene.objects]
    edge = max_edge_m
    while True:
        meshes: list[Mesh] = []
        total = 0
        for o, k in zip(scene.objects, stretch):
            meshes.append(split_mesh(o.mesh, edge / k, max_triangles=limit - total))
            total += meshes[-1].triangle_count
            if total > limit:
                break
        if total <= limit:
            return meshes, edge
        edge *= math.sqrt(2.0)
