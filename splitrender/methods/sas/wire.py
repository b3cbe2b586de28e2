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
- ``xf_obj`` uint16 (X,), ``xf`` float32 (X, 4, 4) object-to-world matrices.

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

META_VERSION = 4
MAX_INSET = 4096
MAX_LEVEL = 15
_F32_MAX = float(np.finfo(np.float32).max)
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
    flat = slot_vertex[used].astype(np.int64)
    uniq, first, inv = np.unique(flat, return_index=True, return_inverse=True)
    by_first = np.argsort(first, kind="stable")
    rank = np.empty_like(by_first)
    rank[by_first] = np.arange(by_first.size)
    idx = rank[inv.reshape(-1)]
    is_new = np.zeros(flat.size, np.int64)
    is_new[first] = 1
    new_before = np.cumsum(is_new) - is_new
    code = new_before - idx
    q = vertex_q[uniq[by_first]].astype(np.int64)
    dq = np.diff(q, axis=0, prepend=np.zeros((1, 3), np.int64)) % 65536
    return {"geo_id": encode_ids(ids), "geo_size": size.astype(np.uint8), "geo_vtx": dq.astype(np.uint16),
            "geo_idx": code.astype(np.uint16 if code.size == 0 or code.max() < 65536 else np.uint32)}


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


def _is_version(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v == META_VERSION


def _count(sd: dict[str, Any], key: str, lo: int, hi: int) -> int:
    v = sd.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= int(v) <= hi:
        raise SasMetaError(f"sas session data: {key!r} must be an integer in {lo}..{hi}, got {v!r}")
    return int(v)


def parse_session(sd: Any) -> SessionInfo:
    """Validate the server's session data; raises :class:`SasMetaError` naming the field."""
    if not isinstance(sd, dict):
        raise SasMetaError(f"sas session data: expected a map, got {type(sd).__name__}")
    if not _is_version(sd.get("v")):
        raise SasMetaError(f"sas session data: version {sd.get('v')!r}, expected {META_VERSION}")
    atlas = sd.get("atlas")
    if not isinstance(atlas, (list, tuple)) or len(atlas) != 2:
        raise SasMetaError(f"sas session data: 'atlas' must be [width, height], got {atlas!r}")
    size = _count({"atlas": atlas[0]}, "atlas", 1, 1 << MAX_LEVEL), _count({"atlas": atlas[1]}, "atlas", 1, 1 << MAX_LEVEL)
    n_obj = _count(sd, "n_objects", 0, 65535)
    n_patches = _count(sd, "n_patches", 0, 2**31 - 1)
    sky = sd.get("sky", [0.0, 0.0, 0.0])
    if (not isinstance(sky, (list, tuple)) or len(sky) != 3
            or not all(isinstance(c, (int, float)) and not isinstance(c, bool) and abs(c) <= _F32_MAX for c in sky)):
        raise SasMetaError(f"sas session data: 'sky' must be three finite numbers, got {sky!r}"[:200])
    box = sd.get("obj_box")
    if not isinstance(box, np.ndarray) or box.shape != (n_obj, 2, 3) or box.dtype.kind != "f":
        raise SasMetaError(f"sas session data: 'obj_box' must be a finite float array of shape ({n_obj}, 2, 3)")
    with np.errstate(over="ignore"):
        box32 = box.astype(np.float32)
    if not np.isfinite(box32).all():  # checked as float32, the dtype used: 1e39 is finite only in float64
        raise SasMetaError(f"sas session data: 'obj_box' must be a finite float array of shape ({n_obj}, 2, 3)")
    base = sd.get("patch_base")
    if (not isinstance(base, np.ndarray) or base.shape != (n_obj,) or base.dtype.kind not in "iu"
            or (n_obj and (int(base[0]) != 0 or (np.diff(base.astype(np.int64)) < 0).any() or int(base[-1]) > n_patches))):
        raise SasMetaError(f"sas session data: 'patch_base' must be {n_obj} non-decreasing integers from 0 to at most n_patches")
    if n_patches and not n_obj:
        raise SasMetaError("sas session data: patches without objects")
    inset = _count(sd, "inset", 0, MAX_INSET) if "inset" in sd else 0     # absent: every side spanned
    return SessionInfo(size, n_obj, n_patches, (float(sky[0]), float(sky[1]), float(sky[2])), box32,
                       base.astype(np.int64), inset)


def _arr(meta: dict[str, Any], key: str, kind: str, shape_tail: tuple[int, ...], n: int | None = None) -> np.ndarray:
    """Field ``key`` as an int64 (``kind="i"``) or float32 (``"f"``) array of shape (N, *shape_tail); absent = empty."""
    v = meta.get(key)
    out_dtype = np.int64 if kind == "i" else np.float32
    if v is None:
        if n:
            raise SasMetaError(f"sas metadata: {key!r} is missing, expected {n} rows")
        return np.zeros((0,) + shape_tail, out_dtype)
    if not isinstance(v, np.ndarray):
        raise SasMetaError(f"sas metadata: {key!r} must be an array, got {type(v).__name__}")
    if v.ndim != 1 + len(shape_tail) or v.shape[1:] != shape_tail:
        raise SasMetaError(f"sas metadata: {key!r} has shape {v.shape}, expected (N, {', '.join(map(str, shape_tail))})".replace(", )", ")"))
    if n is not None and v.shape[0] != n:
        raise SasMetaError(f"sas metadata: {key!r} has {v.shape[0]} rows, expected {n}")
    if (kind == "i" and v.dtype.kind not in "iu") or (kind == "f" and v.dtype.kind != "f"):
        raise SasMetaError(f"sas metadata: {key!r} has dtype {v.dtype}, expected {'integers' if kind == 'i' else 'floats'}")
    if kind == "i" and v.dtype.kind == "u" and v.dtype.itemsize >= 8 and v.size and int(v.max()) >= 2**63:
        raise SasMetaError(f"sas metadata: {key!r} has values beyond int64")
    with np.errstate(over="ignore"):
        out = v.astype(out_dtype)
    if kind == "f" and not np.isfinite(out).all():  # after the cast: 1e39 overflows float32
        raise SasMetaError(f"sas metadata: {key!r} has values that are not finite in float32")
    return out


def _in_range(key: str, v: np.ndarray, lo: int, hi: int) -> None:
    """Every value of field ``key`` in ``lo..hi`` (inclusive)."""
    if v.size and (int(v.min()) < lo or int(v.max()) > hi):
        raise SasMetaError(f"sas metadata: {key!r} must be in {lo}..{hi}, got {int(v.min())}..{int(v.max())}")


def encode_ids(ids: np.ndarray) -> np.ndarray:
    """Sorted distinct patch ids as the wire's delta code: uint32, the first id, then differences >= 1."""
    return np.diff(np.asarray(ids, np.int64), prepend=0).astype(np.uint32)


def _ids(meta: dict[str, Any], key: str, last_id: int) -> np.ndarray:
    """Decode the delta-coded id list ``key`` (:func:`encode_ids`): strictly increasing int64 ids in ``0..last_id``."""
    d = _arr(meta, key, "i", ())
    _in_range(key, d, 0, last_id)
    if d.size > 1 and (d[1:] < 1).any():
        raise SasMetaError(f"sas metadata: {key!r} differences must be >= 1 (strictly increasing ids)")
    ids = np.cumsum(d)
    _in_range(key, ids, 0, last_id)
    return ids


def parse_frame_meta(meta: Any, session: SessionInfo) -> FrameMeta:
    """Validate one frame's metadata against ``session``; raises :class:`SasMetaError` naming the field.

    Nothing is applied here, so a client can reject a frame without touching its state.
    """
    if not isinstance(meta, dict):
        raise SasMetaError(f"sas metadata: expected a map, got {type(meta).__name__}")
    if not _is_version(meta.get("v")):
        raise SasMetaError(f"sas metadata: version {meta.get('v')!r}, expected {META_VERSION}")
    full = meta.get("full", False)
    if not isinstance(full, bool):
        raise SasMetaError(f"sas metadata: 'full' must be a bool, got {type(full).__name__}")
    last_id, last_obj = session.n_patches - 1, session.n_objects - 1
    pvs = _ids(meta, "pvs", last_id) if "pvs" in meta else None
    drop = _ids(meta, "drop", last_id)
    gid = _ids(meta, "geo_id", last_id)
    gsz = _arr(meta, "geo_size", "i", (), gid.size)
    _in_range("geo_size", gsz, 1, 3)
    dvtx = _arr(meta, "geo_vtx", "i", (3,))
    _in_range("geo_vtx", dvtx, 0, 65535)
    code = _arr(meta, "geo_idx", "i", (), int((gsz + 2).sum()))
    is_new = (code == 0).astype(np.int64)
    new_before = np.cumsum(is_new) - is_new
    if code.size and ((code < 0).any() or (code > new_before).any()):
        raise SasMetaError("sas metadata: 'geo_idx' refers to a vertex not yet introduced")
    if int(is_new.sum()) != dvtx.shape[0]:
        raise SasMetaError(f"sas metadata: 'geo_idx' introduces {int(is_new.sum())} vertices, 'geo_vtx' has {dvtx.shape[0]}")
    gq = decode_geometry_slots(dvtx, code)
    gobj = session.object_of(gid)
    uid = np.concatenate([gid, _ids(meta, "uv_id", last_id)])   # rect rows: the new patches', then uv_id's
    urect = _arr(meta, "uv_rect", "i", (5,), uid.size)
    if uid.size:
        w, h = session.atlas_size
        x, y, lw, lh, t = urect.T
        if (x < 0).any() or (y < 0).any():
            raise SasMetaError("sas metadata: 'uv_rect' has a negative block x or y")
        if (lw < 0).any() or (lh < 0).any() or (lw > MAX_LEVEL).any() or (lh > MAX_LEVEL).any():
            raise SasMetaError(f"sas metadata: 'uv_rect' levels must be in 0..{MAX_LEVEL}")
        if ((t != 0) & (t != 1)).any():
            raise SasMetaError("sas metadata: 'uv_rect' transposed flag must be 0 or 1")
        # levels are in 0..MAX_LEVEL here, so 1 << level and the atlas size minus it
        # fit easily; comparing x against that (not x + width) cannot wrap int64
        if (x > w - (1 << lw)).any() or (y > h - (1 << lh)).any():
            raise SasMetaError("sas metadata: 'uv_rect' has a block outside the atlas")
    xo = _arr(meta, "xf_obj", "i", ())
    xf = _arr(meta, "xf", "f", (4, 4), xo.size)
    _in_range("xf_obj", xo, 0, last_obj)
    return FrameMeta(full, pvs, drop, gid, gobj, gsz, gq.astype(np.uint16), uid, urect, xo, xf)
