"""Probe streaming formats (light probe streaming paper, sections 3.2-3.4): what a ``probes`` server sends.

The wire layer of the ``probes`` method (:mod:`splitrender.methods.probes`), which
streams :mod:`~splitrender.render.ddgi` probes to thin clients.  Everything here is exact: a decoded update
equals, bit for bit, what the server packed.

**Update textures** hold the probes' core texels without guard bands (the client
rebuilds them, :func:`~splitrender.render.octa.add_guard`): 8 x 8 colour texels and 16 x 16 visibility
texels per probe, each probe a self-contained block in a stable slot (slot = probe
index, blocks row-major, ``cols`` per row), so an unchanged probe leaves its block as it
was and the codec's P-frames skip it.  Dropping the guard bands saves 36 % of the colour
and 21 % of the visibility texels (paper: -36 % / -21 %).

**Colour** (:func:`encode_irradiance`): 10-bit codes in a ``gbrp10le`` picture for
lossless HEVC (4:4:4, no chroma subsampling; the paper's hardware path uses
``yuv444p10le`` the same way).  The paper normalises small floats into [0, 1]; our
irradiance is HDR, so the codes are logarithmic in ``x = E / pi``: 0 is zero, 1..1023
span ``2^-10`` to ``2^8`` evenly in ``log2 x`` (about 0.6 % relative error at most, and
values outside that range clamp to its ends).

**Visibility** (:func:`visibility_frame`): the mean and mean squared distance as float16
(RG16F) split into bytes, little-endian, and the bytes of each texel row laid
consecutively over the three 8-bit channels of a ``gbrp`` picture: three RG16F texels
make four pixels (paper, figure 4: YUVY, UVYU, VYUV), the row padded to an even width.

**Index list** (:func:`encode_index_list`): which slots an update carries, as a data
stream: ``u16 n``, then ``n`` u16 probe indices delta-coded (the first index, then
differences >= 1).
"""

from __future__ import annotations

import math
import struct

import numpy as np

from ..errors import RemoteProtocolError
from ..render.ddgi import IRR_CORE, IRR_TILE, VIS_CORE, VIS_TILE, atlas_tiles, probe_atlas, slot_grid

COLOR_BITS = 10
COLOR_MAX_CODE = (1 << COLOR_BITS) - 1
LOG2_LO, LOG2_HI = -10.0, 8.0
"""``log2(E / pi)`` of colour codes 1 and 1023."""
MAX_PROBES = 65535


class ProbeStreamError(RemoteProtocolError):
    """A malformed probe update (index list or texture); the message names the field."""


def guard_band_savings() -> tuple[float, float]:
    """Fractions of the colour and visibility texels that dropping the guard bands saves."""
    return 1.0 - IRR_CORE ** 2 / IRR_TILE ** 2, 1.0 - VIS_CORE ** 2 / VIS_TILE ** 2


def encode_irradiance(e: np.ndarray) -> np.ndarray:
    """uint16 10-bit codes of irradiance ``e`` (any shape; zero and below give code 0)."""
    x = np.asarray(e, np.float64) / math.pi
    pos = x > 0
    l2 = np.log2(np.where(pos, x, 1.0))
    q = 1.0 + (np.clip(l2, LOG2_LO, LOG2_HI) - LOG2_LO) / (LOG2_HI - LOG2_LO) * (COLOR_MAX_CODE - 1)
    return np.where(pos, np.rint(q), 0).astype(np.uint16)


def decode_irradiance(q: np.ndarray) -> np.ndarray:
    """float32 irradiance of 10-bit codes ``q`` (the inverse of :func:`encode_irradiance` up to its rounding)."""
    q = np.asarray(q, np.float64)
    l2 = LOG2_LO + (q - 1.0) / (COLOR_MAX_CODE - 1) * (LOG2_HI - LOG2_LO)
    return np.where(q > 0, math.pi * np.exp2(l2), 0.0).astype(np.float32)


def grid_shape(count: int) -> tuple[int, int]:
    """(cols, rows) of the slot grid for ``count`` probes (:func:`~splitrender.render.ddgi.slot_grid`;
    the index list's u16 bounds it)."""
    if not 1 <= count <= MAX_PROBES:
        raise ValueError(f"probe count must be in [1, {MAX_PROBES}], got {count}")
    return slot_grid(count)


def color_frame(codes: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint16 ``gbrp10le`` picture of every probe's (count, 8, 8, 3) colour codes in its slot."""
    codes = np.asarray(codes)
    if codes.ndim != 4 or codes.shape[1:] != (IRR_CORE, IRR_CORE, 3):
        raise ValueError(f"colour codes must be (count, {IRR_CORE}, {IRR_CORE}, 3), got {codes.shape}")
    grid_shape(codes.shape[0])
    return probe_atlas(codes.astype(np.uint16), IRR_CORE)


def color_from_frame(img: np.ndarray, count: int) -> np.ndarray:
    """(count, 8, 8, 3) uint16 codes from a decoded colour picture."""
    cols, rows = grid_shape(count)
    if img.shape != (rows * IRR_CORE, cols * IRR_CORE, 3):
        raise ProbeStreamError(f"probe colour picture: {img.shape}, expected {(rows * IRR_CORE, cols * IRR_CORE, 3)} "
                               f"for {count} probes")
    if int(img.max(initial=0)) > COLOR_MAX_CODE:
        raise ProbeStreamError(f"probe colour picture: code {int(img.max())} above {COLOR_MAX_CODE}")
    return atlas_tiles(img, count, IRR_CORE)


def visibility_width(count: int) -> int:
    """Pixels per row of the visibility picture: ``4/3`` of the texels per row, rounded up to even."""
    cols, _ = grid_shape(count)
    w = -(-4 * cols * VIS_CORE // 3)
    return w + (w % 2)


def visibility_frame(moments: np.ndarray) -> np.ndarray:
    """(H, W', 3) uint8 ``gbrp`` picture of every probe's (count, 16, 16, 2) distance moments as float16 bytes."""
    m = np.asarray(moments)
    if m.ndim != 4 or m.shape[1:] != (VIS_CORE, VIS_CORE, 2):
        raise ValueError(f"moments must be (count, {VIS_CORE}, {VIS_CORE}, 2), got {m.shape}")
    count = m.shape[0]
    tex = probe_atlas(m.astype("<f2"), VIS_CORE)                   # (H, C, 2) float16
    rows = tex.view(np.uint8).reshape(tex.shape[0], -1)                # 4 bytes a texel
    w = visibility_width(count)
    out = np.zeros((rows.shape[0], w * 3), np.uint8)
    out[:, : rows.shape[1]] = rows
    return out.reshape(rows.shape[0], w, 3)


def visibility_from_frame(img: np.ndarray, count: int) -> np.ndarray:
    """(count, 16, 16, 2) float16 moments from a decoded visibility picture."""
    cols, rows = grid_shape(count)
    w = visibility_width(count)
    if img.shape != (rows * VIS_CORE, w, 3) or img.dtype != np.uint8:
        raise ProbeStreamError(f"probe visibility picture: {img.shape} {img.dtype}, expected {(rows * VIS_CORE, w, 3)} "
                               f"uint8 for {count} probes")
    nbytes = cols * VIS_CORE * 4
    flat = np.ascontiguousarray(img.reshape(img.shape[0], -1)[:, :nbytes])
    tex = flat.view("<f2").reshape(img.shape[0], cols * VIS_CORE, 2)
    return atlas_tiles(tex, count, VIS_CORE)


def encode_index_list(ids: np.ndarray) -> bytes:
    """The ``index`` data stream of probe indices ``ids`` (strictly increasing, < 65536)."""
    ids = np.asarray(ids, np.int64)
    if ids.size > MAX_PROBES or (ids.size and (ids.min() < 0 or ids.max() > MAX_PROBES - 1 or (np.diff(ids) < 1).any())):
        raise ValueError("probe indices must be strictly increasing in [0, 65534]")
    deltas = np.diff(ids, prepend=0) if ids.size else ids
    return struct.pack("<H", ids.size) + deltas.astype("<u2").tobytes()


def decode_index_list(buf: bytes, count: int) -> np.ndarray:
    """Probe indices from an ``index`` stream for a volume of ``count`` probes; malformed lists raise
    :class:`ProbeStreamError` naming what is wrong."""
    if len(buf) < 2:
        raise ProbeStreamError(f"probe index list: {len(buf)} bytes, shorter than its 2-byte count")
    (n,) = struct.unpack_from("<H", buf, 0)
    if len(buf) != 2 + 2 * n:
        raise ProbeStreamError(f"probe index list: {len(buf)} bytes for {n} indices (expected {2 + 2 * n})")
    if n > count:
        raise ProbeStreamError(f"probe index list: {n} indices for a volume of {count} probes")
    d = np.frombuffer(buf, "<u2", n, 2).astype(np.int64)
    if n > 1 and (d[1:] < 1).any():
        raise ProbeStreamError(f"probe index list: delta {int(d[1:].min())} at position {int(np.argmin(d[1:])) + 1}; "
                               "indices must strictly increase")
    ids = np.cumsum(d)
    if n and ids[-1] >= count:
        raise ProbeStreamError(f"probe index list: index {int(ids[-1])} beyond the volume's {count} probes")
    return ids
