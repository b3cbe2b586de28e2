"""The TSS wire format: what the server and client halves share.

Session data (msgpack): ``v`` (:data:`WIRE_VERSION`), ``atlas`` [W, H] texels, ``strip``
(width of the atlas's shelf strips, texels, :func:`~.layout.strip_width`),
``os_grid`` (``centred`` or ``paper``: where oversampled triangles' samples sit,
:func:`~.layout.os_row_lengths`), ``block`` (optional, 1 when absent: L-packing tip blocks take
:func:`~.layout.tip_pitch` texels, ``D(L)`` rounded up to it), ``n_objects``, ``n_triangles`` (triangle ids are ``0 .. n_triangles - 1``, the split
scene's triangles in object order), ``sky`` RGB, ``tri_base`` int (n_objects,): each
object's first triangle id (non-decreasing from 0; triangle ``t`` belongs to the last
object whose base is <= ``t``), ``obj_box`` float32 (n_objects, 2, 3): per object the
lo, hi corners of its box in object space, metres, in which positions are quantised.

Per frame, two ``reliable`` data streams (zstd-compressed by the pipeline) and the
atlas video stream.  All integers little-endian.

``geo`` -- geometry of the triangles entering the client's cache (sent once per
triangle and session): ``u8 version, u32 n, u32 nv, u8 wide``, then ``n`` delta-coded
``u32`` ids (the first id, then differences >= 1), ``nv x 3`` ``u16`` positions of the
distinct vertices these triangles use, in order of first use, quantised to 16 bits in
their object's box (:func:`quantize_positions`) and delta-coded per component modulo
2^16, then ``3 n`` vertex codes (``u16``, ``u32`` when ``wide``), corner after corner:
``0`` introduces the next vertex, ``k >= 1`` reuses the ``k``-th most recently
introduced one.  The server draws the mesh snapped to the same grid, so the client
rasterises exactly the triangles the PVS pass saw.

``tris`` -- the live triangles and where their samples are: ``u8 version, u8 full,
u8 single_px`` (the side of a single texel's cell in this table, 1, 2 or 4; a delta
keeps the state's); a delta (``full = 0``: every frame but those below, I-frames included) then lists the
triangles that left, ``u32 n`` and ``n`` delta-coded ``u32`` ids, and carries only the triangles that are new or
whose descriptor or cell changed (the layout is stable, so most do not; a still view's periodic I-frame repacks to
the same cells).  A frame whose delta would be empty (no triangle left, none changed) sends no ``tris`` message:
the client draws its atlas with the table the stream built; a full table (the first frame, a keyframe request, a loss, a new single-texel cell
side) carries every live triangle.  Then ``u32 n_single, u32 n_lp, u32
n_os, u16 n_bins``; ``n_bins`` bins (those the rows use, in both kinds) ``u8 level, u16 n`` and
``n`` shelves ``u16 x, u16 y`` (first texel), each ``S`` texels wide (``S``: the
session's ``strip``; level 0 = the single-texel shelves, 16 rows each, tiles of 16 x 16
texels whose ``single_px``-square cells follow a Z-order curve, :func:`~.layout.single_origins`; cell level
``L``: shelves of ``2 P(L)`` rows, each ``S // (3 P(L))`` pair cells of two slots (``P``: ``D`` rounded up to the
session's ``block``),
holding the L-packed triangles whose level rounds up to ``L``,
:func:`~.layout.lp_cell_level`: with ``block`` > 1 every level of the same pitch); then the
ids of each kind: the single texels' and the oversampled triangles' sorted and delta-coded (``u32``), the
L-packing triangles' in slot order (by cell level, then slot) as ``u32`` zigzag-coded differences
(:func:`zigzag_deltas`; each id in ``0 .. n_triangles - 1`` and listed once), then

- the single texels' slots, as ``u32`` zigzag-coded differences (:func:`zigzag_deltas`:
  slots given in id order are mostly consecutive);
- one ``u8`` per L-packing triangle (in the same slot order): bits 0-5 level - 1, bit 6 no perspective
  correction, bit 7 0; then their slots in their cell levels' bins as ``u32`` zigzag
  differences (:func:`~.layout.lp_tip_origins`; mostly +1, in whatever order the layout placed the triangles);
- 16 B per oversampled triangle: ``u16 x, u16 y`` the rectangle's first texel,
  ``u16 width`` of the rectangle, ``u16 w1, u16 w2, u16 h`` the two staircases' bases
  and common height (samples; the rectangle has ``h`` rows on the centred grid,
  ``h + 1`` on the paper's), ``u16 a`` the height's foot on the base (fraction x
  65535), ``u8 flags`` (bit 1 no perspective correction, others 0), ``u8 base`` (the
  vertex starting the base; the client rotates its vertices so it comes first).

Version 5 (issue 50): the L-packing rows in slot order, their ids as zigzag differences, instead of in id
order with their slots as differences; a layout that places triangles by colour (``colour_order``), not by id,
then costs the table no more than one in id order.  Version 4 (issue 33, lossy atlases of fine meshes): single texels in Z-ordered tiles
of cells ``single_px`` square, compact geometry (quantised shared vertices instead of
``f32`` corners and ``u16`` objects: less than half the bytes), slots as differences
(a full table of single texels shrank fourfold after zstd), ``tri_base`` and ``obj_box``
in the session data.  Version 3 added ``os_grid``; version 2 added delta tables; version 1 sent the full
table every frame (20 KB of a 30 KB frame on the walk at 160x90).

Per-frame metadata: ``v``, ``xf`` float32 (n_objects, 4, 4) object-to-world matrices
at the frame's time (what the atlas was shaded with; the frame's pose is the
reference view of the perspective correction): affine, entries within +-1e6, the 3x3
part invertible (:class:`~splitrender.protocol.schema.Transforms`).

The client checks the session data and metadata against :data:`SESSION` and
:data:`META` (:mod:`splitrender.protocol.schema`: an error names the field, e.g.
``tss metadata: xf[3]: singular transform (|det| 0 < 1e-12)``); the binary ``geo`` and
``tris`` payloads are decoded by hand, every count and offset checked before use.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import RemoteProtocolError
from ...protocol.schema import Array, Float, Int, Map, Opt, Schema, Seq, Str, Transforms, Version
from ..sas.wire import decode_geometry_slots, encode_vertex_codes
from .layout import (KIND_LP, KIND_OS, KIND_SINGLE, MAX_LEVEL, OS_GRIDS, SINGLE_PX, SINGLE_TILE, AtlasPlan, lp_cell_level, lp_per_shelf,
                     lp_tip_origins, os_rows, os_sizes, single_origins, single_per_shelf, tip_pitch)

WIRE_VERSION = 5
OS_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("pw", "<u2"), ("w1", "<u2"), ("w2", "<u2"), ("h", "<u2"), ("a", "<u2"),
                     ("flags", "u1"), ("base", "u1")])
"""The 16-byte oversampling descriptor."""
LP_PERSP_OFF = 1 << 6
OS_PERSP_OFF = 2
MAX_OS_SIDE = 4096


class TssWireError(RemoteProtocolError):
    """Malformed TSS session data, geometry or triangle table (names the field)."""


def encode_ids(ids: np.ndarray) -> bytes:
    """Sorted distinct ids as ``u32`` deltas (the first id, then differences >= 1)."""
    return np.diff(np.asarray(ids, np.int64), prepend=0).astype("<u4").tobytes()


def zigzag_deltas(v: np.ndarray) -> bytes:
    """Integers ``v`` (each within +-2^30 of the one before, the first of 0) as ``u32`` zigzag-coded differences."""
    d: np.ndarray = np.diff(np.asarray(v, np.int64), prepend=0)
    return ((d << 1) ^ (d >> 63)).astype("<u4").tobytes()


def unzigzag_deltas(z: np.ndarray) -> np.ndarray:
    """Inverse of :func:`zigzag_deltas` (int64; the sums of hostile input stay far inside int64)."""
    z = z.astype(np.int64)
    return np.cumsum((z >> 1) ^ -(z & 1))


def decode_ids(d: np.ndarray, what: str, n_max: int) -> np.ndarray:
    """Strictly increasing ids in ``0 .. n_max - 1`` from their deltas."""
    d = d.astype(np.int64)
    if d.size > 1 and (d[1:] < 1).any():
        raise TssWireError(f"tss {what}: id differences must be >= 1 (strictly increasing ids)")
    ids = np.cumsum(d)
    if ids.size and ids[-1] >= n_max:
        raise TssWireError(f"tss {what}: id {int(ids[-1])} is not below the scene's {n_max} triangles")
    return ids


class _Reader:
    def __init__(self, buf: bytes, what: str) -> None:
        self.buf = memoryview(buf)
        self.pos = 0
        self.what = what

    def take(self, n: int, field: str) -> memoryview:
        if n < 0 or self.pos + n > len(self.buf):
            raise TssWireError(f"tss {self.what}: truncated at {field} (needs {n} bytes at offset {self.pos}, "
                               f"payload is {len(self.buf)})")
        out = self.buf[self.pos:self.pos + n]
        self.pos += n
        return out

    def array(self, dtype: Any, count: int, field: str) -> np.ndarray:
        dt = np.dtype(dtype)
        return np.frombuffer(self.take(dt.itemsize * count, field), dt).copy()

    def done(self) -> None:
        if self.pos != len(self.buf):
            raise TssWireError(f"tss {self.what}: {len(self.buf) - self.pos} bytes after the end")


# ---------------------------------------------------------------------------- geometry
GEO_HEAD = struct.Struct("<BIIB")
"""``geo`` header: version, triangles, new vertices, vertex-code width (0: u16, 1: u32)."""


def quantize_positions(pos: np.ndarray, box: np.ndarray) -> np.ndarray:
    """``pos`` (..., 3) object-space metres as uint16 in ``box`` (..., 2, 3) (lo, hi corners), rounded."""
    ext = np.maximum(box[..., 1, :] - box[..., 0, :], 1e-9)
    return np.rint((pos - box[..., 0, :]) / ext * 65535.0).clip(0, 65535).astype(np.uint16)


def dequantize_positions(q: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Inverse of :func:`quantize_positions`: float32 metres."""
    ext = np.maximum(box[..., 1, :] - box[..., 0, :], 1e-9)
    return (box[..., 0, :] + q.astype(np.float32) / 65535.0 * ext).astype(np.float32)


def encode_geometry(ids: np.ndarray, tri_vertex: np.ndarray, vertex_q: np.ndarray) -> bytes:
    """The ``geo`` payload for triangles ``ids`` (sorted, distinct): ``tri_vertex`` (T, 3) scene-wide vertex ids of
    every triangle, ``vertex_q`` (V, 3) uint16 every scene vertex quantised in its object's box."""
    ids = np.asarray(ids, np.int64)
    dq, code = encode_vertex_codes(tri_vertex[ids], vertex_q)   # code 0: the next new vertex; k: the k-th most recent
    wide = int(code.size > 0 and code.max() > 65535)
    return (GEO_HEAD.pack(WIRE_VERSION, ids.size, dq.shape[0], wide) + encode_ids(ids) + dq.astype("<u2").tobytes()
            + code.astype("<u4" if wide else "<u2").tobytes())


@dataclass
class Geometry:
    ids: np.ndarray
    obj: np.ndarray
    pos: np.ndarray


def object_of(ids: np.ndarray, tri_base: np.ndarray) -> np.ndarray:
    """The object of each triangle id: the last whose first triangle ``tri_base`` is <= the id."""
    return np.searchsorted(tri_base, ids, side="right") - 1


def decode_geometry(buf: bytes, n_triangles: int, tri_base: np.ndarray, box: np.ndarray) -> Geometry:
    """Validate and decode a ``geo`` payload: triangle ids, objects (from ``tri_base``) and (n, 3, 3) float32
    object-space corners (dequantised in their object's ``box``)."""
    r = _Reader(buf, "geo")
    v, n, nv, wide = GEO_HEAD.unpack(r.take(GEO_HEAD.size, "header"))
    if v != WIRE_VERSION:
        raise TssWireError(f"tss geo: version {v}, this client speaks {WIRE_VERSION}")
    if n > n_triangles:
        raise TssWireError(f"tss geo: {n} triangles, the scene has {n_triangles}")
    if nv > 3 * n or wide > 1:
        raise TssWireError(f"tss geo: {nv} new vertices for {n} triangles, code width {wide}")
    ids = decode_ids(r.array("<u4", n, "ids"), "geo ids", n_triangles)
    dq = r.array("<u2", 3 * nv, "vertices").astype(np.int64).reshape(nv, 3)
    code = r.array("<u4" if wide else "<u2", 3 * n, "vertex codes").astype(np.int64)
    r.done()
    is_new = (code == 0).astype(np.int64)
    new_before = np.cumsum(is_new) - is_new
    if code.size and (code > new_before).any():
        k = int(np.argmax(code > new_before))
        raise TssWireError(f"tss geo: vertex code {int(code[k])} at corner {k} refers to a vertex not yet introduced")
    if int(is_new.sum()) != nv:
        raise TssWireError(f"tss geo: the codes introduce {int(is_new.sum())} vertices, the header says {nv}")
    obj = object_of(ids, tri_base)
    pos = dequantize_positions(decode_geometry_slots(dq, code).reshape(n, 3, 3), box[obj][:, None])
    return Geometry(ids, obj, pos)


# ---------------------------------------------------------------------------- triangle table
def descriptors(plan: AtlasPlan, persp: np.ndarray, base: np.ndarray) -> np.ndarray:
    """(N, 17) uint8: each triangle's kind byte and its wire descriptor, zero-padded: byte 1 the L-packing level
    byte and bytes 2-5 the ``u32`` slot (single texels, L-packing), bytes 1-16 the oversampling record.  What a
    delta table compares and :func:`encode_table` sends."""
    out = np.zeros((plan.kind.size, 17), np.uint8)
    out[:, 0] = plan.kind
    one = plan.kind != KIND_OS
    lp = plan.kind == KIND_LP
    out[lp, 1] = (plan.level[lp] - 1) | np.where(persp[lp], 0, LP_PERSP_OFF)
    out[one, 2:6] = np.ascontiguousarray(plan.slot[one].astype("<u4")).view(np.uint8).reshape(-1, 4)
    os_ = np.flatnonzero(~one)
    rec = np.zeros(os_.size, OS_DTYPE)
    rec["x"], rec["y"], rec["pw"] = plan.origin[os_, 0, 0], plan.origin[os_, 0, 1], plan.origin[os_, 1, 0]
    rec["w1"], rec["w2"], rec["h"] = plan.w[os_], plan.w2[os_], plan.h[os_]
    rec["a"] = np.rint(plan.a[os_] * 65535.0)
    rec["flags"] = np.where(persp[os_], 0, OS_PERSP_OFF)
    rec["base"] = base[os_]
    out[os_, 1:] = rec.view(np.uint8).reshape(-1, 16)
    return out


def encode_table(ids: np.ndarray, plan: AtlasPlan, desc: np.ndarray, gone: np.ndarray | None = None,
                 changed: np.ndarray | None = None) -> bytes:
    """The ``tris`` payload of one frame for triangles ``ids`` (sorted) laid out by ``plan``, with their
    :func:`descriptors` ``desc``.  A full table without ``gone``; else a delta: the ids that left (``gone``,
    sorted) and only the rows ``changed`` (a mask over ``ids``: new triangles and those whose descriptor changed)."""
    if gone is None:
        head = struct.pack("<BBB", WIRE_VERSION, 1, plan.single_px)
        rows = np.arange(ids.size)
    else:
        head = struct.pack("<BBBI", WIRE_VERSION, 0, plan.single_px, gone.size) + encode_ids(gone)
        rows = np.flatnonzero(changed) if changed is not None else np.arange(ids.size)   # no mask: every row
    kind = plan.kind[rows]
    sel = [rows[kind == k] for k in (KIND_SINGLE, KIND_LP, KIND_OS)]
    # only the bins the rows sent use (a still view's delta sends none: the client keeps the origins it decoded)
    used = set(lp_cell_level(plan.level[sel[1]], plan.block).tolist()) | ({0} if sel[0].size else set())
    bins = {lv: sh for lv, sh in plan.bins.items() if lv in used}
    out = [head, struct.pack("<IIIH", *(s.size for s in sel), len(bins))]
    for lv, shelves in sorted(bins.items()):
        out.append(struct.pack("<BH", lv, len(shelves)) + np.asarray(shelves, "<u2").reshape(-1, 2).tobytes())
    # L-packed rows in slot order (cell level, then slot), so their slots step by +1 however the layout ordered the
    # triangles (colour_order places them by luma, not id); their ids follow as zigzag differences
    lp_slot = np.ascontiguousarray(desc[sel[1], 2:6]).view("<u4").reshape(-1).astype(np.int64)
    by_slot = np.lexsort((lp_slot, lp_cell_level(plan.level[sel[1]], plan.block)))
    sel[1], lp_slot = sel[1][by_slot], lp_slot[by_slot]
    out += [encode_ids(ids[sel[0]]), zigzag_deltas(ids[sel[1]]), encode_ids(ids[sel[2]])]
    # from the descriptors: slot deltas of single texels, L-packing level bytes and slot deltas, 16-byte records
    s0 = np.ascontiguousarray(desc[sel[0], 2:6]).view("<u4").reshape(-1).astype(np.int64)
    out += [zigzag_deltas(s0), desc[sel[1], 1].tobytes(), zigzag_deltas(lp_slot), desc[sel[2], 1:17].tobytes()]
    return b"".join(out)


@dataclass
class Table:
    """A decoded triangle table: per live triangle (sorted by kind, then id) what the client draws with.

    ``origin`` (N, 3, 2) texel origins, ``w``/``w2``/``h``/``a`` as in :class:`~.layout.AtlasPlan`.
    """

    ids: np.ndarray
    kind: np.ndarray
    level: np.ndarray
    origin: np.ndarray
    w: np.ndarray
    w2: np.ndarray
    h: np.ndarray
    a: np.ndarray
    persp: np.ndarray
    base: np.ndarray
    single_px: int = 1


def decode_table(buf: bytes, n_triangles: int, atlas: tuple[int, int], strip: int,
                 grid: str = "centred", block: int = 1) -> tuple[Table, np.ndarray | None]:
    """Validate and decode a ``tris`` payload against the session (``atlas`` = (W, H), shelf ``strip`` width, the
    oversampling ``grid``, the tip blocks' alignment ``block``, :func:`~.layout.tip_pitch`).

    Returns the table's rows (all live triangles for a full table, the changed ones for a delta) and, for a
    delta, the ids that left (``None`` for a full table).
    """
    r = _Reader(buf, "tris")
    v, full, single_px = struct.unpack("<BBB", r.take(3, "header"))
    if v != WIRE_VERSION:
        raise TssWireError(f"tss tris: version {v}, this client speaks {WIRE_VERSION}")
    if full not in (0, 1):
        raise TssWireError(f"tss tris: full flag {full} is not 0 or 1")
    if single_px not in SINGLE_PX:
        raise TssWireError(f"tss tris: single-texel cell side {single_px} is not one of {list(SINGLE_PX)}")
    gone = None
    if not full:
        (ng,) = struct.unpack("<I", r.take(4, "gone count"))
        if ng > n_triangles:
            raise TssWireError(f"tss tris: {ng} triangles gone, the scene has {n_triangles}")
        gone = decode_ids(r.array("<u4", ng, "gone ids"), "tris gone ids", n_triangles)
    return _decode_body(r, n_triangles, atlas, strip, grid, single_px, block), gone


def _decode_body(r: _Reader, n_triangles: int, atlas: tuple[int, int], strip: int, grid: str, single_px: int,
                 block: int = 1) -> Table:
    W, H = atlas
    S = strip
    n0, n1, n2, nb = struct.unpack("<IIIH", r.take(14, "counts"))
    if n0 + n1 + n2 > n_triangles:
        raise TssWireError(f"tss tris: {n0 + n1 + n2} live triangles, the scene has {n_triangles}")
    bins: dict[int, np.ndarray] = {}
    for _ in range(nb):
        lv, ns = struct.unpack("<BH", r.take(3, "bins"))
        if lv > MAX_LEVEL or lv in bins:
            raise TssWireError(f"tss tris: bin level {lv} repeated or above {MAX_LEVEL}")
        shelves = r.array("<u2", 2 * ns, "bin shelves").astype(np.int64).reshape(-1, 2)
        tall = SINGLE_TILE if lv == 0 else 2 * int(tip_pitch(lv, block))
        if shelves.size and ((shelves[:, 1] + tall > H).any() or (shelves[:, 0] + S > W).any()):
            raise TssWireError(f"tss tris: a level-{lv} shelf reaches outside the {W}x{H} atlas")
        bins[lv] = shelves
    id0 = decode_ids(r.array("<u4", n0, "single ids"), "tris single ids", n_triangles)
    id1 = unzigzag_deltas(r.array("<u4", n1, "lp ids"))   # in slot order, not sorted
    if id1.size and (id1.min() < 0 or id1.max() >= n_triangles):
        v = int(id1[(id1 < 0) | (id1 >= n_triangles)][0])
        raise TssWireError(f"tss tris lp ids: id {v} is not in 0 .. {n_triangles - 1} (the scene's triangles)")
    id2 = decode_ids(r.array("<u4", n2, "os ids"), "tris os ids", n_triangles)
    s0 = unzigzag_deltas(r.array("<u4", n0, "single slots"))
    b1 = r.array("u1", n1, "lp levels").astype(np.int64)
    slot = unzigzag_deltas(r.array("<u4", n1, "lp slots"))
    rec = r.array(OS_DTYPE, n2, "os descriptors")
    r.done()
    # the L-packed rows back in id order (the table's rows are sorted by kind, then id)
    by_id = np.argsort(id1, kind="stable")
    id1, b1, slot = id1[by_id], b1[by_id], slot[by_id]
    if id1.size > 1 and (np.diff(id1) == 0).any():
        raise TssWireError(f"tss tris lp ids: triangle {int(id1[np.flatnonzero(np.diff(id1) == 0)[0]])} listed twice")
    allids = np.concatenate([id0, id1, id2])
    if np.unique(allids).size != allids.size:
        raise TssWireError("tss tris: a triangle is listed under two kinds")
    n = allids.size
    kind = np.concatenate([np.full(n0, KIND_SINGLE), np.full(n1, KIND_LP), np.full(n2, KIND_OS)]).astype(np.int64)
    level = np.zeros(n, np.int64)
    origin = np.zeros((n, 3, 2), np.int64)
    w = np.zeros(n, np.int64)
    w2 = np.zeros(n, np.int64)
    h = np.zeros(n, np.int64)
    a = np.zeros(n, np.float64)
    persp = np.ones(n, bool)
    base = np.zeros(n, np.int64)
    if n0:
        if 0 not in bins:
            raise TssWireError("tss tris: single texels without a level-0 bin")
        sh = bins[0]
        cap = len(sh) * single_per_shelf(S, single_px)
        if (s0 < 0).any() or (s0 >= cap).any():
            v = int(s0[(s0 < 0) | (s0 >= cap)][0])
            raise TssWireError(f"tss tris: single-texel slot {v} outside its {len(sh)} shelves ({cap} slots)")
        origin[:n0, 0] = single_origins(s0, sh, S, single_px)
        level[:n0] = 1
    if n1:
        if (b1 & ~np.int64(63 | LP_PERSP_OFF)).any():
            raise TssWireError("tss tris: L-packing level byte with its reserved bit set")
        lv = (b1 & 63) + 1
        persp[n0:n0 + n1] = (b1 & LP_PERSP_OFF) == 0
        level[n0:n0 + n1] = lv
        cell = lp_cell_level(lv, block)
        for L in np.unique(cell).tolist():
            if L not in bins:
                raise TssWireError(f"tss tris: L-packed triangles of cell level {L} without a level-{L} bin")
            sh = bins[L]
            k = np.flatnonzero(cell == L)
            cap = lp_per_shelf(L, S, block) * len(sh)
            if slot[k].min() < 0 or slot[k].max() >= cap:
                v = int(slot[k][(slot[k] < 0) | (slot[k] >= cap)][0])
                raise TssWireError(f"tss tris: level-{L} slot {v} outside its bin of {len(sh)} shelves ({cap} slots)")
            origin[n0 + k] = lp_tip_origins(L, slot[k], sh, S, block)
    if n2:
        sl = slice(n0 + n1, n)
        if (rec["flags"] & ~np.uint8(OS_PERSP_OFF)).any() or (rec["base"] > 2).any():
            raise TssWireError("tss tris: oversampling descriptor with reserved flags or a base vertex above 2")
        w1, ww2, hh, pw = (rec[k].astype(np.int64) for k in ("w1", "w2", "h", "pw"))
        if (np.minimum(w1, np.minimum(ww2, hh)) < 1).any() or (np.maximum(w1, np.maximum(ww2, hh)) > MAX_OS_SIDE).any():
            raise TssWireError(f"tss tris: oversampling size outside 1..{MAX_OS_SIDE}")
        need, _ = os_sizes(w1, ww2, hh, grid)
        if (pw < need).any():
            raise TssWireError("tss tris: an oversampling rectangle is narrower than its two staircases")
        x, y = rec["x"].astype(np.int64), rec["y"].astype(np.int64)
        if (x + pw > W).any() or (y + os_rows(hh, grid) > H).any():
            raise TssWireError(f"tss tris: an oversampling rectangle reaches outside the {W}x{H} atlas")
        origin[sl, 0, 0], origin[sl, 0, 1], origin[sl, 1, 0] = x, y, pw
        w[sl], w2[sl], h[sl] = w1, ww2, hh
        a[sl] = rec["a"] / 65535.0
        persp[sl] = (rec["flags"] & OS_PERSP_OFF) == 0
        base[sl] = rec["base"]
    return Table(allids, kind, level, origin, w, w2, h, a, persp, base, single_px)


@dataclass(frozen=True)
class Session:
    atlas: tuple[int, int]
    strip: int
    os_grid: str
    n_objects: int
    n_triangles: int
    sky: tuple[float, float, float]
    tri_base: np.ndarray
    box: np.ndarray
    block: int = 1


SESSION = Schema("tss session data", TssWireError, Map({
    "v": Version(WIRE_VERSION),
    "atlas": Seq(Int(2, 16384), 2),
    "strip": Int(1, 16384),
    "os_grid": Str(tuple(OS_GRIDS)),
    "block": Opt(Int(1, 16), 1),
    "n_objects": Int(0, 65535, bind="n_objects"),
    "n_triangles": Int(0, (1 << 25) - 1, bind="n_triangles"),
    "sky": Seq(Float(-1e6, 1e6), 3),
    "tri_base": Array("iu", ("n_objects",), cast=np.int64, lo=0, hi="n_triangles"),
    # finite as float32 and within +-1e6 m, so dequantised positions stay finite
    "obj_box": Array("f", ("n_objects", 2, 3), cast=np.float32, finite=True, lo=-1e6, hi=1e6),
}))
"""The session data's fields; :func:`parse_session` adds the rules between them."""

META = Schema("tss metadata", TssWireError, Map({
    "v": Version(WIRE_VERSION),
    "xf": Transforms("n_objects"),
}))
"""Per-frame metadata: the version and every object's transform (affine, entries within +-1e6, invertible)."""


def parse_session(data: Any) -> Session:
    """Validate the session data; raises :class:`TssWireError` naming the field."""
    d = SESSION.parse(data)
    W, H = d["atlas"]
    strip = d["strip"]
    if W % 2 or H % 2:
        raise SESSION.error_at("atlas", f"{W}x{H} must be even")
    if not min(W, 128) <= strip <= W:
        raise SESSION.error_at("strip", f"{strip} must be in [min(128, W), W] for an atlas {W} wide")
    base = d["tri_base"]
    if base.size and (int(base[0]) != 0 or (np.diff(base) < 0).any()):
        raise SESSION.error_at("tri_base", "must be non-decreasing from 0")
    if d["n_triangles"] and not d["n_objects"]:
        raise SESSION.error_at("n_triangles", f"{d['n_triangles']} triangles without objects")
    sky = d["sky"]
    return Session((W, H), strip, d["os_grid"], d["n_objects"], d["n_triangles"], (sky[0], sky[1], sky[2]),
                   base, d["obj_box"], d["block"])


def parse_transforms(meta: Any, n_objects: int) -> np.ndarray:
    """The frame's (n_objects, 4, 4) float32 object transforms from the metadata; raises :class:`TssWireError`
    naming the field (and the object) when one is not finite, too large or not invertible."""
    xf: np.ndarray = META.parse(meta, {"n_objects": n_objects})["xf"]
    return xf
