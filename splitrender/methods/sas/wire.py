"""The SAS wire format: what the server and client halves share, and nothing else.

Session data: ``v``, ``atlas`` [W, H] texels, ``n_objects``, ``n_patches`` (patch ids
are ``0 .. n_patches - 1``), ``patch_base`` int64 (n_objects,): the first patch id of
each object (non-decreasing from 0; patch ``p`` belongs to the last object whose base
is <= ``p``), ``sky`` RGB, ``obj_box`` float32 (n_objects, 2, 3): per object the lo, hi
corners of its bounding box in object space, metres; ``inset`` (0..4096 texels; absent
= 0): a block side at least this long holds the patch inset by half a texel (0 = never;
see :func:`block_layout_xy`).

Per-frame metadata (``v = META_VERSION``), all arrays little-endian; an absent array
is empty and an absent flag false (the server leaves them out):

- ``iframe``, ``reset``, ``full`` bools;
Every id list (``pvs``, ``drop``, ``geo_id``, ``uv_id``) is sorted, distinct and
delta-coded (:func:`encode_ids`: uint32, the first id, then differences >= 1).

- ``pvs`` (N,) (resets and full resends only): the complete PVS; the client drops the rest;
- ``drop`` (K,): patches that left the PVS;
- geometry of the G patches entering the PVS (:func:`encode_geometry`), compact:
  ``geo_id`` uint32 (G,) strictly increasing patch ids, delta-coded (the first id,
  then differences >= 1); ``geo_size`` uint8 (G,) triangles (1-3); ``geo_vtx``
  uint16 (V, 3) the distinct vertices these patches use, in order of first use,
  quantised to 16 bits in their object's bounding box (:func:`quantize_slots`) and
  delta-coded per component modulo 2^16; ``geo_idx`` uint16 or uint32
  (sum(geo_size + 2),) per used slot (slot layout :data:`SLOT_LAYOUT`, patch after
  patch) its vertex as ``new_before - index`` (``new_before``: vertices first used
  before this slot), so 0 introduces the next vertex and ``k >= 1`` reuses the
  ``k``-th most recently introduced one.  A shared vertex is sent once per frame
  and quantises identically in every frame, so no cracks; the objects of the patches
  follow from ``patch_base``;
- ``uv_id`` (U,) patches other than the new ones whose block moved, ``uv_rect``
  uint16 (G + U, 5), the new patches' rows first, then ``uv_id``'s: block x, y (texels, top-left),
  lw, lh (log2 width and height), transposed flag; the patch spans its whole block,
  inset by half a texel along sides of at least ``inset`` texels (:func:`block_layout_xy`),
  and lookups are clamped to the block's texel centres (:func:`block_clamp_rect`);
- ``xf_obj`` uint16 (X,), ``xf`` float32 (X, 4, 4) object-to-world matrices (affine,
  entries within +-1e6, the 3x3 part invertible: :class:`~splitrender.protocol.schema.Transforms`).

The client validates each map against :data:`SESSION` / :data:`FRAME`
(:mod:`splitrender.protocol.schema`), then the rules between fields, before anything is
applied; an error names the field (``sas metadata: xf[0]: singular transform ...``).

Version 2: the patch spans its whole block (version 1 inset it by half a texel) and
the session data carries ``n_patches``.  Version 3: compact geometry (``geo_vtx`` +
``geo_idx`` shared-vertex indices replace ``geo_pos`` and ``geo_obj``), delta-coded
id lists, block rectangles of new patches without their ids, empty fields and false
flags left out (and no ``atlas`` per frame), and ``patch_base`` in the session data.
Version 4: ``inset`` in the session data (long block sides inset the patch again, as
version 1 did for every side and the paper's figure 6 does).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import RemoteProtocolError
from ...protocol.schema import Array, Bool, Float, Int, Invalid, Map, Opt, Schema, Seq, Transforms, Version

META_VERSION = 4
MAX_INSET = 4096
MAX_LEVEL = 15
"""Largest block level (log2 texels) a client accepts."""

#: Layout coordinates of the slots per patch size (index = triangles in the patch):
#: one triangle ``(a, b, c)``: a (0,0), b (1,0), c (0,1) (half the block); two
#: triangles ``(c, a, b)`` + ``(a, b, d)``: c (0,0), a (1,0), b (0,1), d (1,1); three
#: (strip ``s0 s1 s2 | s1 s2 s3 | s2 s3 s4``): s0 (0,1), s1 (0,0), s2 (.5,1), s3 (1,0), s4 (1,1).
SLOT_LAYOUT: dict[int, np.ndarray] = {
    1: np.array([[0, 0], [1, 0], [0, 1], [0, 0], [0, 0]], np.float32),
    2: np.array([[0, 0], [1, 0], [0, 1], [1, 1], [0, 0]], np.float32),
    3: np.array([[0, 1], [0, 0], [0.5, 1], [1, 0], [1, 1]], np.float32),
}
#: Triangles as slot triples per patch size.
TRI_SLOTS: dict[int, np.ndarray] = {
    1: np.array([[0, 1, 2], [-1, -1, -1], [-1, -1, -1]], np.int8),
    2: np.array([[0, 1, 2], [1, 2, 3], [-1, -1, -1]], np.int8),
    3: np.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]], np.int8),
}


class SasMetaError(RemoteProtocolError):
    """Malformed SAS session data or metadata from the server (names the field)."""


def quantize_slots(pos: np.ndarray, size: np.ndarray, box: np.ndarray) -> np.ndarray:
    """(sum(size + 2), 3) uint16 used-slot positions of ``pos`` (G, 5, 3) in boxes ``box`` (G, 2, 3)."""
    ext = np.maximum(box[:, 1] - box[:, 0], 1e-9)[:, None]
    q = np.rint((pos - box[:, None, 0]) / ext * 65535.0).clip(0, 65535).astype(np.uint16)
    return q[np.arange(5)[None, :] < (size.astype(np.int64) + 2)[:, None]]


def dequantize_slots(q: np.ndarray, size: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Inverse of :func:`quantize_slots`: (G, 5, 3) float32 with unused slots zero."""
    used = np.arange(5)[None, :] < (size.astype(np.int64) + 2)[:, None]
    out = np.zeros(size.shape + (5, 3), np.float32)
    lo = np.broadcast_to(box[:, None, 0], out.shape)[used]
    ext = np.broadcast_to(np.maximum(box[:, 1] - box[:, 0], 1e-9)[:, None], out.shape)[used]
    out[used] = lo + q.astype(np.float32) / 65535.0 * ext
    return out


def encode_geometry(ids: np.ndarray, size: np.ndarray, slot_vertex: np.ndarray, vertex_q: np.ndarray) -> dict[str, np.ndarray]:
    """Wire fields ``geo_id``, ``geo_size``, ``geo_vtx``, ``geo_idx`` for patches ``ids`` (sorted, distinct).

    ``size`` (G,) triangles per patch, ``slot_vertex`` (G, 5) scene-wide vertex id per
    slot (unused slots ignored), ``vertex_q`` (V_scene, 3) uint16 every scene vertex
    quantised in its object's box.
    """
    ids = np.asarray(ids, np.int64)
    used = np.arange(5)[None, :] < (size.astype(np.int64) + 2)[:, None]
    dq, code = encode_vertex_codes(slot_vertex[used], vertex_q)
    return {"geo_id": encode_ids(ids), "geo_size": size.astype(np.uint8), "geo_vtx": dq.astype(np.uint16),
            "geo_idx": code.astype(np.uint16 if code.size == 0 or code.max() < 65536 else np.uint32)}


def encode_vertex_codes(flat: np.ndarray, vertex_q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertex coding of ``sas`` and ``tss`` geometry: for scene-wide vertex ids ``flat`` (one per corner, in
    order) and ``vertex_q`` (V_scene, 3) uint16 quantised positions, the distinct vertices' positions in order of
    first use as deltas modulo 2^16 ((V, 3) int64 in 0..65535), and per corner its code (int64): 0 introduces the
    next new vertex, ``k`` >= 1 reuses the ``k``-th most recently introduced one.  :func:`decode_geometry_slots`
    inverts it."""
    flat = np.asarray(flat, np.int64).reshape(-1)
    uniq, first, inv = np.unique(flat, return_index=True, return_inverse=True)
    by_first = np.argsort(first, kind="stable")
    rank = np.empty_like(by_first)
    rank[by_first] = np.arange(by_first.size)
    idx = rank[inv.reshape(-1)]
    is_new = np.zeros(flat.size, np.int64)
    is_new[first] = 1
    code = np.cumsum(is_new) - is_new - idx
    q = vertex_q[uniq[by_first]].astype(np.int64)
    return np.diff(q, axis=0, prepend=np.zeros((1, 3), np.int64)) % 65536, code


def decode_geometry_slots(dvtx: np.ndarray, code: np.ndarray) -> np.ndarray:
    """(S, 3) uint16 quantised slot positions from ``geo_vtx`` deltas (V, 3) and ``geo_idx`` codes (S,) (validated)."""
    q = (np.cumsum(dvtx.astype(np.int64), axis=0) % 65536).astype(np.uint16)
    is_new = (code == 0).astype(np.int64)
    idx = np.cumsum(is_new) - is_new - code
    return q[idx] if idx.size else np.zeros((0, 3), np.uint16)


def block_inset(rect: np.ndarray, inset: int) -> np.ndarray:
    """(N, 2) half-texel insets (0 or 0.5) along atlas x and y of blocks ``rect`` (N, 4: x, y, width, height):
    0.5 where the side is at least ``inset`` texels (``inset`` > 0)."""
    if inset <= 0:
        return np.zeros((rect.shape[0], 2))
    return np.where(rect[:, 2:4] >= inset, 0.5, 0.0)


def block_layout_xy(layout_uv: np.ndarray, rect: np.ndarray, transposed: np.ndarray, inset: int = 0) -> np.ndarray:
    """Atlas texel positions (..., 2) of block-local ``layout_uv`` (N, ..., 2): the patch spans the whole block.

    ``rect`` (N, 4) is x, y, width, height in texels.  Along a short side texel centres
    lie inside the patch (a 2x2 block samples it at 1/4 and 3/4 of each side, not on its
    edges, where the texture filter would mix in the neighbouring surface), so a block of
    ``2^l`` texels holds ``2^l`` samples per side.  Along a side of at least ``inset``
    texels the patch is inset by half a texel (the paper's figure 6): its edges run
    through the border texels' centres, so a lookup inside the patch only interpolates,
    where the spanning layout repeats the border texel for the outer half texel (on the
    `minimal` checker that cost 1.3 dB at 320x180).  The client clamps its lookups to the
    block's texel-centre rectangle (:func:`block_clamp_rect`).
    """
    uv = np.where(transposed.reshape((-1,) + (1,) * (layout_uv.ndim - 1)), layout_uv[..., ::-1], layout_uv)
    shape = (-1,) + (1,) * (layout_uv.ndim - 2)
    ins = block_inset(rect, inset)
    ix, iy = ins[:, 0].reshape(shape), ins[:, 1].reshape(shape)
    x = rect[:, 0].reshape(shape) + ix + uv[..., 0] * (rect[:, 2].reshape(shape) - 2 * ix)
    y = rect[:, 1].reshape(shape) + iy + uv[..., 1] * (rect[:, 3].reshape(shape) - 2 * iy)
    return np.stack([x, y], axis=-1)


def block_clamp_rect(rect: np.ndarray) -> np.ndarray:
    """(N, 4) texel-centre rectangles x0, y0, x1, y1 (texels) of blocks ``rect`` (N, 4: x, y, width, height).

    Bilinear lookups clamped to it never read a texel of another block.
    """
    return np.concatenate([rect[:, :2] + 0.5, rect[:, :2] + rect[:, 2:4] - 0.5], axis=1)


# ---------------------------------------------------------------------------- decoding
@dataclass(frozen=True)
class SessionInfo:
    """Validated session data: atlas size (W, H) texels, counts, sky RGB, ``obj_box`` (n_objects, 2, 3) metres."""

    atlas_size: tuple[int, int]
    n_objects: int
    n_patches: int
    sky: tuple[float, float, float]
    obj_box: np.ndarray
    patch_base: np.ndarray
    inset: int = 0

    def object_of(self, ids: np.ndarray) -> np.ndarray:
        """Object index of patches ``ids`` (validated ids)."""
        return np.searchsorted(self.patch_base, ids, side="right") - 1


@dataclass(frozen=True)
class FrameMeta:
    """One frame's validated metadata (int64 ids, see the module docstring for the fields)."""

    full: bool
    pvs: np.ndarray | None
    drop: np.ndarray
    geo_id: np.ndarray
    geo_obj: np.ndarray
    geo_size: np.ndarray
    geo_pos: np.ndarray
    uv_id: np.ndarray
    uv_rect: np.ndarray
    xf_obj: np.ndarray
    xf: np.ndarray


def encode_ids(ids: np.ndarray) -> np.ndarray:
    """Sorted distinct patch ids as the wire's delta code: uint32, the first id, then differences >= 1."""
    return np.diff(np.asarray(ids, np.int64), prepend=0).astype(np.uint32)


class DeltaIds(Array):
    """A delta-coded id list (:func:`encode_ids`) decoded: strictly increasing int64 ids in ``0..last_id``;
    absent is empty.  ``dim`` names the number of ids for the fields after it."""

    def __init__(self, dim: str | None = None) -> None:
        super().__init__("iu", (dim,), cast=np.int64, lo=0, hi="last_id", empty_if_absent=True)

    def check(self, v: Any, ctx: dict[str, Any]) -> np.ndarray:
        d = super().check(v, ctx)
        if d.size > 1 and (d[1:] < 1).any():
            raise Invalid("differences must be >= 1 (strictly increasing ids)")
        ids = np.cumsum(d)
        if ids.size and int(ids[-1]) > ctx["last_id"]:
            raise Invalid(f"decoded ids must be in 0..{ctx['last_id']}, got up to {int(ids[-1])}")
        return ids


SESSION = Schema("sas session data", SasMetaError, Map({
    "v": Version(META_VERSION),
    "atlas": Seq(Int(1, 1 << MAX_LEVEL), 2),
    "n_objects": Int(0, 65535, bind="n_objects"),
    "n_patches": Int(0, 2**31 - 1, bind="n_patches"),
    "sky": Opt(Seq(Float(-1e6, 1e6), 3), (0.0, 0.0, 0.0)),
    # finite as float32 (the dtype used) and within +-1e6 m, so dequantised positions stay finite
    "obj_box": Array("f", ("n_objects", 2, 3), cast=np.float32, finite=True, lo=-1e6, hi=1e6),
    "patch_base": Array("iu", ("n_objects",), cast=np.int64, lo=0, hi="n_patches"),
    "inset": Opt(Int(0, MAX_INSET), 0),                                          # absent: every side spanned
}))
"""The session data's fields (see the module docstring); :func:`parse_session` adds the rules between them."""

FRAME = Schema("sas metadata", SasMetaError, Map({
    "v": Version(META_VERSION),
    "full": Opt(Bool(), False),
    "pvs": Opt(DeltaIds(), None),
    "drop": DeltaIds(),
    "geo_id": DeltaIds("G"),
    "geo_size": Array("iu", ("G",), cast=np.int64, lo=1, hi=3, empty_if_absent=True),
    "geo_vtx": Array("iu", (None, 3), cast=np.int64, lo=0, hi=65535, empty_if_absent=True),
    "geo_idx": Array("iu", (None,), cast=np.int64, empty_if_absent=True),
    "uv_id": DeltaIds(),
    "uv_rect": Array("iu", (None, 5), cast=np.int64, empty_if_absent=True),
    "xf_obj": Array("iu", ("X",), cast=np.int64, lo=0, hi="last_obj", empty_if_absent=True),
    "xf": Transforms("X", empty_if_absent=True),
}))
"""One frame's metadata fields; :func:`parse_frame_meta` adds the rules between them and the session."""


def parse_session(sd: Any) -> SessionInfo:
    """Validate the server's session data; raises :class:`SasMetaError` naming the field."""
    d = SESSION.parse(sd)
    n_obj, n_patches, base = d["n_objects"], d["n_patches"], d["patch_base"]
    if n_obj and (int(base[0]) != 0 or (np.diff(base) < 0).any()):
        raise SESSION.error_at("patch_base", "must be non-decreasing from 0")
    if n_patches and not n_obj:
        raise SESSION.error_at("n_patches", f"{n_patches} patches without objects")
    sky = d["sky"]
    return SessionInfo((d["atlas"][0], d["atlas"][1]), n_obj, n_patches, (sky[0], sky[1], sky[2]), d["obj_box"], base,
                       d["inset"])


def parse_frame_meta(meta: Any, session: SessionInfo) -> FrameMeta:
    """Validate one frame's metadata against ``session``; raises :class:`SasMetaError` naming the field.

    Nothing is applied here, so a client can reject a frame without touching its state.
    """
    m = FRAME.parse(meta, {"last_id": session.n_patches - 1, "last_obj": session.n_objects - 1})
    gid, gsz, dvtx, code = m["geo_id"], m["geo_size"], m["geo_vtx"], m["geo_idx"]
    want = int((gsz + 2).sum())
    if code.size != want:
        raise FRAME.error_at("geo_idx", f"{code.size} entries, expected {want} (the used slots of geo_size)")
    is_new = (code == 0).astype(np.int64)
    new_before = np.cumsum(is_new) - is_new
    if code.size and ((code < 0).any() or (code > new_before).any()):
        raise FRAME.error_at("geo_idx", "refers to a vertex not yet introduced")
    if int(is_new.sum()) != dvtx.shape[0]:
        raise FRAME.error_at("geo_idx", f"introduces {int(is_new.sum())} vertices, geo_vtx has {dvtx.shape[0]}")
    gq = decode_geometry_slots(dvtx, code)
    gobj = session.object_of(gid)
    uid = np.concatenate([gid, m["uv_id"]])   # rect rows: the new patches', then uv_id's
    urect = m["uv_rect"]
    if urect.shape[0] != uid.size:
        raise FRAME.error_at("uv_rect", f"{urect.shape[0]} rows, expected {uid.size} (geo_id, then uv_id)")
    if uid.size:
        w, h = session.atlas_size
        x, y, lw, lh, t = urect.T
        if (x < 0).any() or (y < 0).any():
            raise FRAME.error_at("uv_rect", "a block has a negative x or y")
        if (lw < 0).any() or (lh < 0).any() or (lw > MAX_LEVEL).any() or (lh > MAX_LEVEL).any():
            raise FRAME.error_at("uv_rect", f"levels must be in 0..{MAX_LEVEL}")
        if ((t != 0) & (t != 1)).any():
            raise FRAME.error_at("uv_rect", "transposed flag must be 0 or 1")
        # levels are in 0..MAX_LEVEL here, so 1 << level and the atlas size minus it
        # fit easily; comparing x against that (not x + width) cannot wrap int64
        if (x > w - (1 << lw)).any() or (y > h - (1 << lh)).any():
            raise FRAME.error_at("uv_rect", "a block lies outside the atlas")
    return FrameMeta(m["full"], m["pvs"], m["drop"], gid, gobj, gsz, gq.astype(np.uint16), uid, urect, m["xf_obj"], m["xf"])
