"""``sas``'s page glue (its :attr:`~splitrender.methods.base.MethodSpec.page`): the shading atlas as the browser's
video track, PVS geometry as vertex slots on a data channel.

The page does not parse SAS's own metadata (msgpack + zstd, quantised slot positions, block
rectangles): a browser has neither codec to hand.  Instead the session keeps, for its page, the
SAS client's GL-free state (:class:`~.slots.PatchSlots`: the PVS patches,
their atlas rectangles, one vertex slot of three triangles per patch) and sends, per frame, the
slots that changed and the object transforms.  Slots whose rows did not change are not sent again (an I-frame of SAS's
restates every patch).  The page keeps the same vertex buffer, applies a
frame's slots when the atlas frame of that id is decoded, and draws it with the SAS client's
shaders ported to GLSL ES 3.00.  The bytes are counted as they go (``sas_slot_bytes``): float32
rows are larger than SAS's quantised wire form, which the session counts beside them
(``sas_meta_bytes``, the metadata as the RTP front door would send it).

One binary message per frame, split into parts of at most :data:`MAX_SLOTS_PER_PART` slots,
each zlib-compressed, little-endian inside, on the ``meta`` channel (reliable, ordered)::

    "SRSA"  u32 frame_id  u32 part  u32 last (0/1)  u32 high  u32 n_slots  u32 n_xf  u32 reserved
    u32 slot[n_slots]  f32 rows[n_slots][90]  u32 object[n_xf]  f32 transform[n_xf][16] (row-major)

``high`` is the number of slots the page draws (slots at and past it are unused); a row is 3
triangles x 3 vertices x (object-space position 3, atlas uv 2, object 1, clamp rectangle 4).
"""

from __future__ import annotations

import struct
import zlib
from typing import Any

import numpy as np

from ...codecs.meta import pack_meta, unpack_meta
from ..base import PageGlue
from .slots import PatchSlots
from .wire import parse_frame_meta, parse_session

__all__ = ["SasPage", "MAGIC", "MAX_SLOTS_PER_PART", "parse_slot_message"]

MAGIC = b"SRSA"
MAX_SLOTS_PER_PART = 160
"""Slots per message: 160 x 360 bytes keeps a message under 64 KiB, which every SCTP stack takes."""
ZLIB_LEVEL = 3
"""Each message is zlib-compressed (the page inflates it with ``DecompressionStream("deflate")``): about 9x
smaller on the ``minimal`` scene (a 30 fps turn: 28-103 KB raw per frame, 3.3-11.9 KB compressed, against SAS's
own 0.9-2.2 KB of metadata)."""
_HEAD = struct.Struct("<4s7I")


class SasPage(PageGlue):
    """A page's SAS state in the session: the session data's terms, and per frame the slot messages."""

    def __init__(self, config: Any, intrinsics: Any, session_blob: bytes) -> None:
        self.info = parse_session(unpack_meta(session_blob))
        self.slots = PatchSlots(self.info)
        self._sent = np.zeros((0, 3, 3, 10), np.float32)
        """The rows the page has, per slot (zeros: unused)."""
        self.n_objects = self.info.n_objects
        self.slot_bytes = 0
        self.meta_bytes = 0

    def terms(self) -> dict[str, Any]:
        """What the page needs at the start: atlas size, object count, the sky (clear) colour."""
        return {"atlas_width": self.info.atlas_size[0], "atlas_height": self.info.atlas_size[1],
                "n_objects": self.n_objects, "sky": list(map(float, self.info.sky))}

    def counters(self) -> dict[str, int]:
        """``sas_slot_bytes`` sent to the page, and ``sas_meta_bytes``: SAS's own metadata for the same frames."""
        return {"sas_slot_bytes": self.slot_bytes, "sas_meta_bytes": self.meta_bytes}

    def frame(self, frame_id: int, meta: Any) -> list[bytes]:
        """The messages of one frame (its metadata validated as the SAS client validates it)."""
        m = parse_frame_meta(meta, self.info)
        self.meta_bytes += len(pack_meta(meta))
        self.slots.apply(m)
        written = self.slots.rebuild()
        # only the slots whose rows differ from what the page has (an I-frame rewrites every slot, mostly alike)
        rows_all = self.slots.rows
        if self._sent.shape[0] < rows_all.shape[0]:
            self._sent = np.concatenate([self._sent, np.zeros((rows_all.shape[0] - self._sent.shape[0], 3, 3, 10),
                                                              np.float32)])
        if len(written):
            differ = (rows_all[written] != self._sent[written]).reshape(len(written), -1).any(axis=1)
            written = written[differ]
            self._sent[written] = rows_all[written]
        rows = rows_all[written].reshape(len(written), 90).astype("<f4")
        xf_obj = m.xf_obj.astype("<u4")
        xf = np.asarray(m.xf, "<f4").reshape(len(xf_obj), 16)
        parts = max(1, -(-len(written) // MAX_SLOTS_PER_PART))
        out = []
        for k in range(parts):
            sl = slice(k * MAX_SLOTS_PER_PART, (k + 1) * MAX_SLOTS_PER_PART)
            last = k == parts - 1
            objs, mats = (xf_obj, xf) if last else (xf_obj[:0], xf[:0])
            idx = written[sl].astype("<u4")
            msg = b"".join([_HEAD.pack(MAGIC, frame_id, k, int(last), self.slots.high, len(idx), len(objs), 0),
                            idx.tobytes(), rows[sl].tobytes(), objs.tobytes(), mats.tobytes()])
            out.append(zlib.compress(msg, ZLIB_LEVEL))
        self.slot_bytes += sum(len(x) for x in out)
        return out


def parse_slot_message(data: bytes) -> dict[str, Any]:
    """One message back into its fields (the page's reading, in Python, for tests)."""
    data = zlib.decompress(data)
    magic, frame_id, part, last, high, n, n_xf, _ = _HEAD.unpack_from(data)
    if magic != MAGIC:
        raise ValueError(f"slot message: magic {magic!r}, expected {MAGIC!r}")
    o = _HEAD.size
    slots = np.frombuffer(data, "<u4", n, o)
    o += 4 * n
    rows = np.frombuffer(data, "<f4", 90 * n, o).reshape(n, 3, 3, 10)
    o += 360 * n
    objs = np.frombuffer(data, "<u4", n_xf, o)
    o += 4 * n_xf
    xf = np.frombuffer(data, "<f4", 16 * n_xf, o).reshape(n_xf, 4, 4)
    o += 64 * n_xf
    if o != len(data):
        raise ValueError(f"slot message: {len(data)} bytes, its counts say {o}")
    return {"frame_id": frame_id, "part": part, "last": bool(last), "high": high, "slots": slots, "rows": rows,
            "objects": objs, "transforms": xf}
