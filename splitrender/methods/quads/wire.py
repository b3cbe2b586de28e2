"""``quads``' wire format, shared by both halves.

Per frame, three streams:

- ``quads`` (reliable data, zstd): a header, then every set's quads as a structure of
  arrays, the sets one after another inside each array (paper section 3.4.2):
  ``theta`` u8[N], ``phi`` u8[N], ``packed`` u32[N] (bits 31-26 level = log2 size,
  25-14 x, 13-2 y, 1 flat, 0 alpha), ``depth`` f32[N] (the plane's view depth at the
  quad centre): 80 bits per quad before zstd.  The multi-byte arrays go as byte planes
  (byte 0 of every element, then byte 1, ...; the "shuffle" filter of Blosc and HDF5):
  the high bytes of neighbouring quads' positions and depths are nearly equal, and zstd
  finds those runs only when they are adjacent (measured on the default walk at
  320x180: 1.78x fewer ``quads`` bytes than the interleaved arrays, for 0.3 ms).
  Then, for the sets whose flags say so (QuadStream's packed atlas, :mod:`.packing`),
  every such quad's atlas position, ``x | y << 12`` in 24 bits, as three byte planes.
  Header: ``b"QD"``, version u8, set count u8, then per set kind u8, atlas slot u8,
  camera u8, flags u8 (bit 0: atlas positions follow), quads u32, non-flat quads u32
  (little-endian).
- ``offsets`` (reliable data, zstd): 16 float16 depth offsets per non-flat quad, in
  quad order, as two byte planes.
- ``atlas`` (video): the sets' colour images, one slot each, side by side; or (packed)
  each quad's own texels at its atlas position.

The frame's metadata (``v`` :data:`META_VERSION`) names the cameras (pose, size,
vertical FOV) the sets refer to and, for QUASAR, whether the frame is a reference or a
residual frame.  Session data and metadata are checked against :data:`SESSION` and
:data:`META` (:mod:`splitrender.protocol.schema`); errors name the field
(``quads metadata frame 3: cameras[0][7]: expected an integer in 1..320, got 0``).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import CodecError, RemoteProtocolError
from ...protocol.schema import Check, Float, Int, Map, Opt, Schema, Seq, Str, Tup, Version
from ...scene.pose import CameraIntrinsics, Pose
from .gen import MAX_LEVEL, MAX_OFFSET_M, QuadSet
from .packing import POS_BITS

WIRE_VERSION = 3
"""3: per-set flags, atlas positions for packed sets; 2: byte planes for the multi-byte arrays (1 sent them interleaved)."""
MAGIC = b"QD"
HEADER = struct.Struct("<2sBB")
SET_HEADER = struct.Struct("<BBBBII")
KIND_REFERENCE, KIND_UPDATE, KIND_REVEALED, KIND_HIDDEN, KIND_WIDE, KIND_VIEW = range(6)
KIND_NAMES = ("reference", "update", "revealed", "hidden", "wide", "view")
CACHED_KINDS = (KIND_REFERENCE, KIND_UPDATE)
"""Sets the client keeps across frames (QUASAR's reference frame); the others live for one frame."""
MAX_QUADS = 1 << 24
MAX_CAMERAS = 16
FLAG_TEX = 1
"""Set flag: the set's quads carry atlas positions (a packed atlas)."""
TEX_MASK = (1 << POS_BITS) - 1


class QuadsWireError(RemoteProtocolError, CodecError):
    """Malformed ``quads`` data from the server; the message names the frame, the stream and the field."""


@dataclass
class WireSet:
    """One set of quads: what it is, where its colour lies in the atlas (a slot, or with ``tex``
    each quad's own (x, y) atlas position), which camera it was made from."""

    kind: int
    slot: int
    camera: int
    quads: QuadSet
    tex: np.ndarray | None = None


def pack(level: np.ndarray, x: np.ndarray, y: np.ndarray, flat: np.ndarray, alpha: np.ndarray | None = None) -> np.ndarray:
    """The u32 of size, position, flat and alpha bits."""
    a = np.zeros(level.shape, np.uint32) if alpha is None else alpha.astype(np.uint32)
    return ((level.astype(np.uint32) & 0x3F) << 26 | (x.astype(np.uint32) & 0xFFF) << 14
            | (y.astype(np.uint32) & 0xFFF) << 2 | flat.astype(np.uint32) << 1 | a).astype(np.uint32)


def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    p = p.astype(np.uint32)
    return ((p >> 26) & 0x3F).astype(np.uint8), ((p >> 14) & 0xFFF).astype(np.uint16), ((p >> 2) & 0xFFF).astype(np.uint16), \
        ((p >> 1) & 1).astype(bool), (p & 1).astype(bool)


def byte_planes(a: np.ndarray, dtype: str) -> bytes:
    """``a`` as ``dtype`` (little-endian), its bytes regrouped by position within an element."""
    a = np.ascontiguousarray(a, dtype)
    return a.view(np.uint8).reshape(-1, a.dtype.itemsize).T.tobytes()


def from_byte_planes(buf: bytes | bytearray | memoryview, dtype: str, n: int, offset: int = 0) -> np.ndarray:
    """Inverse of :func:`byte_planes`: ``n`` elements of ``dtype`` from ``buf`` at ``offset``."""
    size = np.dtype(dtype).itemsize
    planes = np.frombuffer(buf, np.uint8, n * size, offset).reshape(size, n)
    return np.ascontiguousarray(planes.T).view(dtype).reshape(n)


def encode_sets(sets: list[WireSet]) -> tuple[bytes, bytes]:
    """(``quads`` payload, ``offsets`` payload) of a frame's sets."""
    head = [HEADER.pack(MAGIC, WIRE_VERSION, len(sets))]
    for s in sets:
        head.append(SET_HEADER.pack(s.kind, s.slot, s.camera, 0 if s.tex is None else FLAG_TEX, len(s.quads),
                                    int((~s.quads.flat).sum())))
    qs = [s.quads for s in sets]
    cat = lambda name, dt: np.concatenate([getattr(q, name) for q in qs]).astype(dt) if qs else np.zeros(0, dt)  # noqa: E731
    packed = np.concatenate([pack(q.level, q.x, q.y, q.flat) for q in qs]) if qs else np.zeros(0, np.uint32)
    body = (cat("theta", np.uint8).tobytes() + cat("phi", np.uint8).tobytes() + byte_planes(packed, "<u4")
            + byte_planes(cat("depth", np.float32), "<f4"))
    tex = [s.tex for s in sets if s.tex is not None]
    if tex:
        t = np.concatenate(tex).astype(np.uint32)
        body += byte_planes(t[:, 0] | t[:, 1] << POS_BITS, "<u4")[:3 * len(t)]   # the top byte is always zero
    offs = np.concatenate([q.offsets for q in qs]) if qs else np.zeros((0, 16), np.float16)
    return b"".join(head) + body, byte_planes(offs.reshape(-1), "<f2")


def decode_sets(quads: bytes, offsets: bytes, where: str, slot_size: tuple[int, int], n_slots: int, n_cameras: int,
                far_m: float, packed_atlas: tuple[int, int] | None = None) -> list[WireSet]:
    """Check and decode a frame's ``quads`` and ``offsets`` payloads; anything malformed raises
    :class:`QuadsWireError` naming the frame and field.  ``packed_atlas``: the (width, height)
    of the session's packed atlas, whose sets (and only those) carry atlas positions."""
    def bad(msg: str) -> QuadsWireError:
        return QuadsWireError(f"quads {where}: {msg}")

    if not isinstance(quads, (bytes, bytearray, memoryview)) or len(quads) < HEADER.size:
        raise bad(f"quads stream: {len(quads) if isinstance(quads, (bytes, bytearray)) else type(quads).__name__} bytes "
                  f"is shorter than the {HEADER.size}-byte header")
    magic, version, n_sets = HEADER.unpack_from(quads, 0)
    if magic != MAGIC:
        raise bad(f"quads stream: bad magic {magic!r} (expected {MAGIC!r})")
    if version != WIRE_VERSION:
        raise bad(f"quads stream: unsupported version {version} (this client speaks {WIRE_VERSION})")
    pos = HEADER.size
    if len(quads) < pos + n_sets * SET_HEADER.size:
        raise bad(f"quads stream: {len(quads)} bytes cannot hold {n_sets} set headers")
    heads = []
    for k in range(n_sets):
        kind, slot, cam, flags, n, nonflat = SET_HEADER.unpack_from(quads, pos)
        pos += SET_HEADER.size
        if kind >= len(KIND_NAMES):
            raise bad(f"set {k}: unknown kind {kind}")
        if slot >= n_slots:
            raise bad(f"set {k}: atlas slot {slot} beyond the session's {n_slots}")
        if cam >= n_cameras:
            raise bad(f"set {k}: camera {cam} beyond the frame's {n_cameras}")
        if n > MAX_QUADS or nonflat > n:
            raise bad(f"set {k}: {n} quads with {nonflat} non-flat is not a valid count (at most {MAX_QUADS})")
        if flags & ~FLAG_TEX:
            raise bad(f"set {k}: unknown flags 0x{flags:02x}")
        if bool(flags & FLAG_TEX) != (packed_atlas is not None):
            raise bad(f"set {k}: atlas positions {'sent' if flags & FLAG_TEX else 'missing'}, but the session's atlas is "
                      f"{'packed' if packed_atlas is not None else 'slots'}")
        heads.append((kind, slot, cam, n, nonflat))
    total = sum(h[3] for h in heads)
    n_tex = total if packed_atlas is not None else 0
    if len(quads) - pos != total * 10 + n_tex * 3:
        raise bad(f"quads stream: {len(quads) - pos} bytes of quad arrays for {total} quads (expected "
                  f"{total * 10 + n_tex * 3})")
    theta = np.frombuffer(quads, np.uint8, total, pos)
    phi = np.frombuffer(quads, np.uint8, total, pos + total)
    packed = from_byte_planes(quads, "<u4", total, pos + 2 * total)
    depth = from_byte_planes(quads, "<f4", total, pos + 6 * total).astype(np.float32)
    level, x, y, flat, alpha = unpack(packed)
    tex = None
    if n_tex:
        t = np.zeros((n_tex, 4), np.uint8)
        t[:, :3] = np.frombuffer(quads, np.uint8, 3 * n_tex, pos + 10 * total).reshape(3, n_tex).T
        tv = t.view("<u4").reshape(n_tex)
        tex = np.stack([tv & TEX_MASK, tv >> POS_BITS], axis=-1).astype(np.int64)
    n_nonflat = sum(h[4] for h in heads)
    if int((~flat).sum()) != n_nonflat:
        raise bad(f"quads stream: {int((~flat).sum())} quads say non-flat, the set headers {n_nonflat}")
    if not isinstance(offsets, (bytes, bytearray, memoryview)) or len(offsets) != n_nonflat * 32:
        raise bad(f"offsets stream: {len(offsets) if isinstance(offsets, (bytes, bytearray)) else '?'} bytes for "
                  f"{n_nonflat} non-flat quads (expected {n_nonflat * 32})")
    offs = from_byte_planes(offsets, "<f2", n_nonflat * 16).reshape(-1, 16).astype(np.float16)
    if offs.size and not (np.isfinite(offs).all() and float(np.abs(offs.astype(np.float32)).max()) <= MAX_OFFSET_M):
        raise bad(f"offsets stream: offsets must be finite and within +-{MAX_OFFSET_M:g} m")
    if total:
        if int(level.max()) > MAX_LEVEL:
            raise bad(f"quads stream: quad level {int(level.max())} beyond {MAX_LEVEL} (size {2 ** MAX_LEVEL})")
        if not (np.isfinite(depth).all() and float(depth.min()) > 0 and float(depth.max()) <= far_m * 1.01):
            raise bad(f"quads stream: plane depths must be in (0, {far_m * 1.01:g}] m")
        if alpha.any():
            raise bad("quads stream: the alpha bit is set, and this version sends no alpha atlas")
    out = []
    a = b = 0
    for k, (kind, slot, cam, n, nonflat) in enumerate(heads):
        sl = slice(a, a + n)
        s = 2 ** level[sl].astype(np.int64)
        if n and (int((x[sl] + s).max()) > slot_size[0] or int((y[sl] + s).max()) > slot_size[1]):
            raise bad(f"set {k}: a quad reaches beyond its {slot_size[0]}x{slot_size[1]} atlas slot")
        if int((s * s).sum()) > slot_size[0] * slot_size[1]:   # one G-buffer's quads never overlap
            raise bad(f"set {k}: its quads cover {int((s * s).sum())} pixels, more than the "
                      f"{slot_size[0] * slot_size[1]} of a slot")
        if int((~flat[sl]).sum()) != nonflat:
            raise bad(f"set {k}: {int((~flat[sl]).sum())} non-flat quads, the header says {nonflat}")
        q = QuadSet(level[sl].copy(), x[sl].copy(), y[sl].copy(), theta[sl].copy(), phi[sl].copy(), depth[sl].copy(),
                    flat[sl].copy(), offs[b:b + nonflat].copy())
        tq = None
        if tex is not None and packed_atlas is not None:
            tq = tex[sl].copy()
            if n and (int((tq[:, 0] + s).max()) > packed_atlas[0] or int((tq[:, 1] + s).max()) > packed_atlas[1]):
                raise bad(f"set {k}: a quad's atlas position reaches beyond the {packed_atlas[0]}x{packed_atlas[1]} "
                          "packed atlas")
        out.append(WireSet(kind, slot, cam, q, tq))
        a += n
        b += nonflat
    return out


META_VERSION = 1
"""Version of the session data and per-frame metadata maps (the byte streams carry :data:`WIRE_VERSION`)."""
MAX_SLOTS = 64
MAX_SIDE = 4096


@dataclass(frozen=True)
class Session:
    """Validated session data: ``slots`` atlas slots of ``slot_size`` (W, H) pixels in a ``cols`` x ``rows`` grid,
    the atlas (W, H) it makes, and QuadStream's ``packed`` atlas size (W, H), or ``None``."""

    slots: int
    cols: int
    rows: int
    slot_size: tuple[int, int]
    atlas_size: tuple[int, int]
    packed: tuple[int, int] | None


SESSION = Schema("quads session data", QuadsWireError, Map({
    "v": Version(META_VERSION),
    "wire": Version(WIRE_VERSION),
    "slots": Int(1, MAX_SLOTS),
    "cols": Int(1, MAX_SLOTS),
    "rows": Int(1, MAX_SLOTS),
    "slot_size": Seq(Int(1, MAX_SIDE), 2),
    "packed_atlas": Opt(Seq(Int(1, MAX_SIDE), 2), None),
}))


def parse_session(sd: Any) -> Session:
    """Validate the server's session data; raises :class:`QuadsWireError` naming the field."""
    d = SESSION.parse(sd)
    slots, cols, rows = d["slots"], d["cols"], d["rows"]
    w, h = d["slot_size"]
    if not slots <= cols * rows <= MAX_SLOTS:
        raise SESSION.error_at("slots", f"{slots} slots in a {cols}x{rows} grid of {w}x{h} is not a valid atlas "
                                        f"(at most {MAX_SLOTS} cells)")
    pa = d["packed_atlas"]
    packed = None if pa is None else (pa[0], pa[1])
    return Session(slots, cols, rows, (w, h), packed or (cols * w, rows * h), packed)


def _unit_quaternion(c: list[Any]) -> bool:
    return 0.5 < math.sqrt(sum(x * x for x in c[3:7])) < 2.0


_CAMERA = Check(Tup(*[Float(-1e6, 1e6)] * 3, *[Float(-2.0, 2.0)] * 4, Int(1, "slot_w"), Int(1, "slot_h"), Float(1.0, 179.0)),
                _unit_quaternion, "pose orientation is not a unit quaternion")
"""A camera: ``[x, y, z, qx, qy, qz, qw, width, height, fov_y_deg]`` (metres, a unit quaternion, pixels within the
slot, degrees)."""
META = Schema("quads metadata", QuadsWireError, Map({
    "v": Version(META_VERSION),
    "frame": Str(("reference", "residual")),
    "ref_frame": Int(-(2**63), 2**63 - 1),
    "cameras": Seq(_CAMERA, min_len=1, max_len=MAX_CAMERAS),
}))


@dataclass(frozen=True)
class FrameInfo:
    """A frame's validated metadata: ``kind`` (reference or residual), the reference frame it builds on, and its
    cameras (pose, intrinsics) that the sets refer to."""

    kind: str
    ref_frame: int
    cameras: list[tuple[Pose, CameraIntrinsics]]


def parse_frame_meta(meta: Any, where: str, slot_size: tuple[int, int]) -> FrameInfo:
    """Validate one frame's metadata (``where``: e.g. ``frame 3``); raises :class:`QuadsWireError` naming the field."""
    m = META.parse(meta, {"slot_w": slot_size[0], "slot_h": slot_size[1]}, f"quads metadata {where}")
    cams = [(Pose.from_list(c[:7]), CameraIntrinsics(c[7], c[8], c[9])) for c in m["cameras"]]
    return FrameInfo(m["frame"], m["ref_frame"], cams)


def encode_camera(pose: Pose, intr: CameraIntrinsics) -> list[float]:
    return [*map(float, pose.to_list()), intr.width, intr.height, float(intr.fov_y_deg)]
