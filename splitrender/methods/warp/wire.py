"""``warp``'s wire format, shared by both halves: the reference frame a client half rebuilds from an update.

The metadata is checked against :data:`META` (:mod:`splitrender.protocol.schema`) before
anything is decoded: an error names the frame and the field path
(``warp metadata frame 3: obj_model[0]: singular transform (|det| 0 < 1e-09)``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...codecs.depth import bc4_decode, dequantize_depth, unpack_depth_planes
from ...errors import CodecError, RemoteProtocolError
from ...protocol.schema import Array, Check, Float, Int, Map, Opt, Schema, Seq, Str, Transforms, Version, show
from ...scene.pose import CameraIntrinsics, Pose
from ..base import DecodedUpdate
from .config import MAX_COORD_M, MAX_OBJECT_ID, META_VERSION, WarpConfig

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- client: data
@dataclass
class ReferenceView:
    """One decoded reference view: camera pose, colour, depth (metres, 0 = background), ids."""

    pose: Pose
    color: np.ndarray
    depth_m: np.ndarray
    ids: np.ndarray


@dataclass
class ReferenceFrame:
    """A decoded update: its views, object poses at ``t_s`` and one server frame earlier."""

    t_s: float
    views: list[ReferenceView]
    model: dict[int, np.ndarray]
    prev: dict[int, np.ndarray]
    dt_s: float


class WarpMetaError(RemoteProtocolError, CodecError):
    """A malformed ``warp`` update from the server; the message names the frame and the field.
    Also a :class:`CodecError`, the class these checks raised before."""


def _unit_quaternion(p: list[float]) -> bool:
    return 0.5 < math.sqrt(sum(x * x for x in p[3:])) < 2.0


_POSE = Check(Seq(Float(-MAX_COORD_M, MAX_COORD_M), 7, arrays=True), _unit_quaternion, "orientation is not a unit quaternion")
"""A pose ``[x, y, z, qx, qy, qz, qw]`` (metres within +-MAX_COORD_M, a unit quaternion; a 1-D array too)."""

META = Schema("warp metadata", WarpMetaError, Map({
    "v": Version(META_VERSION),
    "depth_coding": Str(("lossless", "bc4")),
    "depth_near_m": Float(0.0, MAX_COORD_M, lo_open=True),
    "ref": Seq(Float(), 3),
    "views": Seq(Map({"pose": _POSE, "ids": Array(dtype=(np.uint8, np.uint16), shape=("H", "W")),
                      "depth_step": Opt(Int(1, 4), 1)}), min_len=1, max_len=2),
    "obj_ids": Array("iu", ("n_obj",), lo=1, hi=MAX_OBJECT_ID),
    "dyn_ids": Array("iu", ("n_dyn",), lo=1, hi=MAX_OBJECT_ID),
    # model matrices: affine, entries within +-MAX_COORD_M, an invertible 3x3 part (warping inverts them)
    "obj_model": Transforms("n_obj", max_abs=MAX_COORD_M, min_det=1e-9, dtype=np.float64),
    "dyn_prev": Transforms("n_dyn", max_abs=MAX_COORD_M, min_det=1e-9, dtype=np.float64),
    "dt_s": Float(0.0, MAX_COORD_M, lo_open=True),
}))
"""The metadata's fields (what :class:`~.server.WarpServer` sends); ``views[i].bc4`` is checked by its decoder."""


def parse_update(update: DecodedUpdate, cfg: WarpConfig, ref: CameraIntrinsics) -> ReferenceFrame:
    """Check and decode one update's planes and metadata; anything malformed raises
    :class:`WarpMetaError` naming the frame and the field."""
    where = f"warp metadata frame {update.frame_id}"
    m = META.parse(update.meta, {"H": ref.height, "W": ref.width}, where)
    r = m["ref"]
    if (r[0], r[1]) != (ref.width, ref.height) or abs(r[2] - ref.fov_y_deg) > 1e-6:
        raise META.error_at("ref", f"reference camera {show(update.meta['ref'])} does not match "
                                   f"[{ref.width}, {ref.height}, {ref.fov_y_deg:.6g}]", where)
    coding, near = m["depth_coding"], m["depth_near_m"]
    shape = (ref.height, ref.width)
    views = []
    for v, vm in enumerate(m["views"]):
        color = update.planes.get(f"color{v}")
        if not isinstance(color, np.ndarray) or color.shape != (*shape, 3) or color.dtype != np.uint8:
            raise WarpMetaError(f"warp frame {update.frame_id}: plane color{v} must be {shape + (3,)} uint8, got {show(color)}")
        if coding == "lossless":
            plane = update.planes.get(f"depth{v}")
            if not isinstance(plane, np.ndarray) or plane.shape != (2 * shape[0], shape[1]) or plane.dtype != np.uint8:
                raise WarpMetaError(f"warp frame {update.frame_id}: plane depth{v} must be {(2 * shape[0], shape[1])} uint8, "
                                    f"got {show(plane)}")
            codes = unpack_depth_planes(plane)
            s = vm["depth_step"]
            if s > 1:     # one sample in s per axis in the top-left corner: repeat each
                small = codes[:-(-shape[0] // s), :-(-shape[1] // s)]
                codes = np.repeat(np.repeat(small, s, axis=0), s, axis=1)[:shape[0], :shape[1]]
        else:
            try:
                codes = bc4_decode(update.meta["views"][v].get("bc4"), expect_shape=shape)
            except CodecError as exc:
                raise META.error_at(["views", v, "bc4"], str(exc), where) from exc
        depth = dequantize_depth(codes, near)
        depth[~np.isfinite(depth)] = 0.0
        views.append(ReferenceView(Pose.from_list(vm["pose"]), color, depth, vm["ids"].astype(np.uint16)))
    obj_ids, dyn_ids, model, dyn_prev = m["obj_ids"], m["dyn_ids"], m["obj_model"], m["dyn_prev"]
    return ReferenceFrame(update.t_s, views, {int(i): model[k] for k, i in enumerate(obj_ids)},
                          {int(i): dyn_prev[k] for k, i in enumerate(dyn_ids)}, m["dt_s"])
