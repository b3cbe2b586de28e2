"""A ``quads`` frame's bytes counted as QUASAR's own simulators count them (issue 38), beside ours.

Ours (``bytes_*`` in ``updates.csv``) is every stream on the wire: the colour atlas (video), the quads and offsets
(reliable data, zstd) and the metadata.  QUASAR's simulators (quasar-gfx/QUASAR, ``FrameGenerator.cpp``,
``QRSimulator.h``, ``QSSimulator.h``) count geometry only, per view:

    zstd(quads) + zstd(depth offsets) / 8

- ``quads``: their ``QuadMapDataPacked``, 12 bytes a quad (``normalSpherical`` u32: theta and phi as snorm8, the
  upper 16 bits zero; ``depth`` f32; ``offsetSizeFlattened`` u32: x << 20 | y << 8 | size << 1 | flattened, size
  the log2 side in surfels, two per pixel), serialised as a u32 count and then each field's array
  (structure of arrays), compressed by zstd at level 3 (``ZSTD_dfast``).
- ``depth offsets``: half floats, compressed by zstd and the compressed size divided by 8 (an undocumented factor;
  it dates from when the offsets were not compressed).  They compress their whole 2W x 2H RGBA16F image, zeros
  where proxies are flat or absent; we compress the non-flat quads' 16 offsets each as a packed list, the same
  non-zero content for one-pixel proxies (QUASAR stores S x S x 4 for a proxy of S surfels a side).
- The colour atlas is never counted.
- **QUASAR** (``qr_simulator``): a reference frame counts every view (visible layer, hidden layers, wide view);
  a residual frame counts only the visible layer's residual output (the updated reference and the mask frame),
  although the hidden layers and the wide view are made again every frame.  ``Num Proxies`` counts the visible
  layer only.
- **QuadStream** (``qs_simulator``): every frame counts every view, and after adding each view the running total
  is multiplied by 103/96 ("QS has data structures that are 103 bits"), so the factor compounds (the first of 10
  views ends up 2.02x).  :func:`quasar_frame_bytes` does the same, to reproduce their ratio.

Where our sets map to theirs: ``reference`` is their layer 0 on a reference frame, ``update`` and ``revealed`` their
residual frame's updated reference and mask, ``hidden`` and ``wide`` their other layers, ``view`` and ``wide``
QuadStream's views.  Our plane depth is the view depth in metres where theirs is window depth; both are one f32.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gen import QuadSet
from .wire import KIND_REFERENCE, KIND_REVEALED, KIND_UPDATE, KIND_VIEW, WireSet

QUASAR_ZSTD_LEVEL = 3
"""``ZSTDCodec``'s default level (``ZSTD_CLEVEL_DEFAULT``)."""
QUASAR_OFFSET_DIVISOR = 8
QUADSTREAM_FACTOR = 103.0 / 96.0
"""``qs_simulator``'s per-view factor: 103 bits a quad over the 96 of ``QuadMapDataPacked``."""
LAYER0_KINDS = (KIND_REFERENCE, KIND_UPDATE, KIND_REVEALED)


def quasar_quads_buffer(q: QuadSet) -> bytes:
    """``q`` serialised as QUASAR serialises a view's quads: u32 count, then the arrays of ``normalSpherical``,
    ``depth`` and ``offsetSizeFlattened`` (12 bytes a quad)."""
    n = len(q)
    normal = (q.theta.astype(np.uint32) | q.phi.astype(np.uint32) << 8).astype("<u4")
    size = q.level.astype(np.uint32) + 1                     # log2 side in surfels (two per pixel)
    osf = ((q.x.astype(np.uint32) & 0xFFF) << 20 | (q.y.astype(np.uint32) & 0xFFF) << 8 | (size & 0x7F) << 1
           | q.flat.astype(np.uint32)).astype("<u4")
    return np.uint32(n).astype("<u4").tobytes() + normal.tobytes() + q.depth.astype("<f4").tobytes() + osf.tobytes()


def quasar_offsets_buffer(q: QuadSet) -> bytes:
    """The non-flat quads' depth offsets as half floats, quad by quad (16 each)."""
    return np.ascontiguousarray(q.offsets, "<f2").tobytes()


@dataclass
class QuasarBytes:
    """One frame as QUASAR counts it: ``bytes`` in all (their ``Frame Size``), its ``quads`` part, its offsets part
    after the division (``offsets``), and ``proxies`` (their ``Num Proxies``)."""

    bytes: float
    quads: int
    offsets: int
    proxies: int


def _zstd_len(data: bytes, level: int) -> int:
    import zstandard

    return len(zstandard.ZstdCompressor(level=level).compress(data))


def quasar_frame_bytes(sets: list[WireSet], reference: bool, level: int = QUASAR_ZSTD_LEVEL) -> QuasarBytes:
    """A frame's geometry bytes as QUASAR's simulators count them (module docstring).  ``reference``: a QUASAR
    reference frame (QuadStream frames, whose sets are views, always count every set)."""
    quadstream = any(s.kind == KIND_VIEW for s in sets)
    if quadstream or reference:
        counted = list(sets)
    else:
        counted = [s for s in sets if s.kind in (KIND_UPDATE, KIND_REVEALED)]
    total = 0.0
    quads = offsets = 0
    for s in counted:
        qb = _zstd_len(quasar_quads_buffer(s.quads), level)
        ob = _zstd_len(quasar_offsets_buffer(s.quads), level) // QUASAR_OFFSET_DIVISOR    # C++ unsigned division
        quads += qb
        offsets += ob
        total += qb + ob
        if quadstream:
            total *= QUADSTREAM_FACTOR
    proxies = sum(len(s.quads) for s in counted if quadstream or s.kind in LAYER0_KINDS)
    return QuasarBytes(total, quads, offsets, proxies)


__all__ = ["QUADSTREAM_FACTOR", "QUASAR_OFFSET_DIVISOR", "QUASAR_ZSTD_LEVEL", "QuasarBytes",
           "quasar_frame_bytes", "quasar_offsets_buffer", "quasar_quads_buffer"]
