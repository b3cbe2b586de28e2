"""Depth coding for the depth-image warping method (``warp``).

Depth is view-space distance along -Z in metres (``inf`` on background), as the
renderer outputs it.  It is quantised to 16-bit *inverse* depth, like a post-projection
depth buffer (precision where parallax is largest)::

    code = clamp(round(65535 * near_m / z), 1, 65535)   for finite z,  0 for background

so ``z = 65535 * near_m / code``; the relative error is at most ``0.5 / code``
(about 0.08 % at 10 m with ``near_m = 0.1``).  Depth closer than ``near_m`` clamps
to ``near_m``.

Two transports:

- **lossless**: the 16-bit codes split into a high-byte plane and a *folded* low-byte
  plane (the low byte is mirrored on odd high bytes, so a smooth ramp stays continuous
  across byte wraps instead of a saw tooth), stacked into one (2H, W) 8-bit gray
  picture for lossless HEVC (4:0:0).  Round trips bit-exactly.
- **bc4**: a BC4-like block code (the cheaper option QUASAR evaluates for MeshWarp):
  per 8x8 block two 16-bit endpoints (the block's min and max code) and a 3-bit index
  per pixel for 8 evenly spaced levels; a block that holds background uses 7 levels
  and index 7 for background, so the sky never bleeds into geometry.  The block
  stream is then zstd-compressed.  Lossy: a code is off by at most
  ``(max - min) / 14`` (levels) plus rounding.
"""

from __future__ import annotations

import struct

import numpy as np
import zstandard

from ..errors import CodecError
from .bounded import bounded_zstd_decompress

CODE_MAX = 65535
BC4_BLOCK = 8
BC4_MAGIC = b"BC4D"
BC4_VERSION = 1
_BC4_HEADER = struct.Struct("<4sBxHHH")  # magic, version, pad, block, height, width
BC4_MAX_PIXELS = 8192 * 8192


# ----------------------------------------------------------------------------- quantisation
def quantize_depth(depth_m: np.ndarray, near_m: float) -> np.ndarray:
    """(H, W) float depth in metres (``inf``/``nan``/<= 0 = background) -> (H, W) uint16 codes."""
    if not near_m > 0:
        raise CodecError(f"depth near_m must be > 0, got {near_m}")
    d = np.asarray(depth_m, dtype=np.float64)
    if d.ndim != 2:
        raise CodecError(f"depth must be a 2-D (H, W) array, got shape {d.shape}")
    bg = ~np.isfinite(d) | (d <= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.rint(CODE_MAX * near_m / np.where(bg, 1.0, d))
    c = np.clip(c, 1, CODE_MAX)
    c[bg] = 0
    return c.astype(np.uint16)


def coarsen_depth(codes: np.ndarray, bits: int) -> np.ndarray:
    """``codes`` (uint16, from :func:`quantize_depth`) keeping ``bits`` significant bits: each moved within its
    bucket of ``2**(16 - bits)`` codes to the bucket's first (less than one bucket away), background (0) kept and no
    surface moved into it.  Where the high byte
    is odd the dropped bits are ones, not zeros: :func:`pack_depth_planes` folds those low bytes (255 - lo), so the
    dropped bits are zero in the coded plane either way (a plane of zeros, not a pattern of the high byte's parity)."""
    if not 1 <= bits <= 16:
        raise CodecError(f"depth bits must be 1 to 16, got {bits}")
    if bits == 16:
        return codes
    k = 16 - bits
    step = 1 << k
    c = np.maximum(codes.astype(np.int64) >> k << k, step)     # the code's bucket of 2**k (never the background's)
    c = np.where((c >> 8) & 1, c | (step - 1) & 0xFF, c)
    return np.where(codes == 0, 0, c).astype(np.uint16)


def dequantize_depth(codes: np.ndarray, near_m: float) -> np.ndarray:
    """(H, W) uint16 codes -> (H, W) float32 depth in metres, ``inf`` on background (code 0)."""
    if not near_m > 0:
        raise CodecError(f"depth near_m must be > 0, got {near_m}")
    c = np.asarray(codes)
    if c.ndim != 2 or c.dtype != np.uint16:
        raise CodecError(f"depth codes must be a 2-D uint16 array, got {c.dtype} {c.shape}")
    with np.errstate(divide="ignore"):
        z = (CODE_MAX * near_m) / c.astype(np.float64)
    return z.astype(np.float32)


# ----------------------------------------------------------------------------- lossless planes
def pack_depth_planes(codes: np.ndarray) -> np.ndarray:
    """(H, W) uint16 codes -> (2H, W) uint8: high bytes on top, folded low bytes below."""
    c = np.asarray(codes)
    if c.ndim != 2 or c.dtype != np.uint16:
        raise CodecError(f"depth codes must be a 2-D uint16 array, got {c.dtype} {c.shape}")
    hi = (c >> 8).astype(np.uint8)
    lo = (c & 0xFF).astype(np.uint8)
    lo = np.where(hi & 1, 255 - lo, lo).astype(np.uint8)
    return np.concatenate([hi, lo], axis=0)


def unpack_depth_planes(plane: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pack_depth_planes`: (2H, W) uint8 -> (H, W) uint16."""
    p = np.asarray(plane)
    if p.ndim != 2 or p.dtype != np.uint8 or p.shape[0] % 2:
        raise CodecError(f"packed depth must be a (2H, W) uint8 plane, got {p.dtype} {p.shape}")
    h = p.shape[0] // 2
    hi = p[:h].astype(np.uint16)
    lo = p[h:].astype(np.uint16)
    lo = np.where(hi & 1, 255 - lo, lo)
    return ((hi << 8) | lo).astype(np.uint16)


# ----------------------------------------------------------------------------- BC4-like blocks
def _blocks(c: np.ndarray, b: int) -> tuple[np.ndarray, int, int]:
    h, w = c.shape
    ph, pw = -h % b, -w % b
    if ph or pw:
        c = np.pad(c, ((0, ph), (0, pw)), mode="edge")
    by, bx = c.shape[0] // b, c.shape[1] // b
    return c.reshape(by, b, bx, b).transpose(0, 2, 1, 3).reshape(by * bx, b * b), by, bx


def bc4_encode(codes: np.ndarray, level: int = 3) -> bytes:
    """(H, W) uint16 depth codes -> BC4-like 8x8 block stream, zstd-compressed."""
    c = np.asarray(codes)
    if c.ndim != 2 or c.dtype != np.uint16:
        raise CodecError(f"depth codes must be a 2-D uint16 array, got {c.dtype} {c.shape}")
    h, w = c.shape
    if h == 0 or w == 0 or h > 65535 or w > 65535:
        raise CodecError(f"bc4: unsupported size {w}x{h}")
    blk, _, _ = _blocks(c, BC4_BLOCK)
    bg = blk == 0
    has_bg = bg.any(axis=1)
    fg = np.where(bg, np.uint16(CODE_MAX), blk)
    lo = fg.min(axis=1).astype(np.int64)
    hi = np.where(bg, 0, blk).max(axis=1).astype(np.int64)
    all_bg = bg.all(axis=1)
    lo[all_bg] = 0
    hi[all_bg] = 0
    # A background block whose foreground is one value would store lo == hi, which reads as
    # the no-background mode: widen it by one code (the value stays exact, see below).
    same = has_bg & ~all_bg & (lo == hi)
    hi = np.where(same & (hi < CODE_MAX), hi + 1, hi)
    lo = np.where(same & (lo == hi), lo - 1, lo)
    levels = np.where(has_bg, 6, 7)  # number of intervals between lo and hi
    span = np.maximum(hi - lo, 1)
    idx = np.rint((blk.astype(np.int64) - lo[:, None]) * levels[:, None] / span[:, None])
    idx = np.clip(idx, 0, levels[:, None]).astype(np.uint8)
    idx[bg] = 7
    # Endpoint order tells the decoder the mode: lo <= hi without background, lo > hi with it
    # (as BC4 does with its two endpoint orders).  A background-only block is (1, 0).
    e0 = np.where(all_bg, 1, np.where(has_bg, hi, lo))
    e1 = np.where(all_bg, 0, np.where(has_bg, lo, hi))
    ends = np.stack([e0, e1], axis=1).astype("<u2")
    # pack 64 3-bit indices into 24 bytes per block
    bits = np.unpackbits(idx[:, :, None], axis=2, bitorder="little")[:, :, :3].reshape(len(idx), -1)
    packed = np.packbits(bits, axis=1, bitorder="little")
    body = ends.tobytes() + packed.tobytes()
    head = _BC4_HEADER.pack(BC4_MAGIC, BC4_VERSION, BC4_BLOCK, h, w)
    return head + zstandard.ZstdCompressor(level=level).compress(body)


def bc4_decode(data: bytes, expect_shape: tuple[int, int] | None = None) -> np.ndarray:
    """Inverse of :func:`bc4_encode` (lossy): bytes -> (H, W) uint16 codes.  With
    ``expect_shape`` (H, W) a header of another size is refused before decompressing."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise CodecError(f"bc4: expected bytes, got {type(data).__name__}")
    data = bytes(data)
    if len(data) < _BC4_HEADER.size:
        raise CodecError(f"bc4: {len(data)} bytes is shorter than the {_BC4_HEADER.size}-byte header")
    magic, ver, b, h, w = _BC4_HEADER.unpack_from(data)
    if magic != BC4_MAGIC:
        raise CodecError(f"bc4: bad magic {magic!r}")
    if ver != BC4_VERSION:
        raise CodecError(f"bc4: unsupported version {ver}")
    if b != BC4_BLOCK or h == 0 or w == 0:
        raise CodecError(f"bc4: bad header block={b} size={w}x{h}")
    if expect_shape is not None and (h, w) != tuple(expect_shape):
        raise CodecError(f"bc4: size {w}x{h} does not match the expected {expect_shape[1]}x{expect_shape[0]}")
    if h * w > BC4_MAX_PIXELS:
        raise CodecError(f"bc4: size {w}x{h} exceeds the limit of {BC4_MAX_PIXELS} pixels")
    by, bx = -(-h // b), -(-w // b)
    n = by * bx
    need = n * 4 + n * 24
    # the body size follows from the header: a frame declaring anything else is refused
    # before decompressing, and one without a declared size is capped at ``need``
    body = bounded_zstd_decompress(data[_BC4_HEADER.size:], need, "bc4", exact=need)
    ends = np.frombuffer(body[: n * 4], "<u2").reshape(n, 2).astype(np.int64)
    bits = np.unpackbits(np.frombuffer(body[n * 4:], np.uint8).reshape(n, 24), axis=1, bitorder="little").reshape(n, 64, 3)
    idx = (bits[..., 0] | (bits[..., 1] << 1) | (bits[..., 2] << 2)).astype(np.int64)
    e0, e1 = ends[:, 0], ends[:, 1]
    has_bg = e0 > e1
    lo = np.where(has_bg, e1, e0)
    hi = np.where(has_bg, e0, e1)
    levels = np.where(has_bg, 6, 7)
    val = lo[:, None] + np.rint((hi - lo)[:, None] * np.minimum(idx, levels[:, None]) / levels[:, None])
    val = np.where(has_bg[:, None] & (idx == 7), 0, val)
    val = np.where(((e0 == 1) & (e1 == 0))[:, None], 0, val)  # background-only block
    out = val.astype(np.uint16).reshape(by, bx, b, b).transpose(0, 2, 1, 3).reshape(by * b, bx * b)
    return np.ascontiguousarray(out[:h, :w])
