"""``warp``'s wire format, shared by both halves: the reference frame a client half rebuilds from an update."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...codecs.depth import bc4_decode, dequantize_depth, unpack_depth_planes
from ...errors import CodecError, RemoteProtocolError
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


def _show(v: Any) -> str:
    """A short description of a peer value for an error message."""
    if isinstance(v, np.ndarray):
        return f"array {v.dtype} {v.shape}"
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


def _real(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_)) and math.isfinite(v)


def _positive(m: dict[Any, Any], key: str, where: str) -> float:
    v = m.get(key)
    if not _real(v) or not 0 < v <= MAX_COORD_M:
        raise WarpMetaError(f"warp metadata {where}: {key} must be a number in (0, {MAX_COORD_M:g}], got {_show(v)}")
    return float(v)


def _pose(v: Any, where: str, field: str) -> Pose:
    """A pose sent as ``[x, y, z, qx, qy, qz, qw]`` (metres, unit quaternion)."""
    x = v.tolist() if isinstance(v, np.ndarray) and v.ndim == 1 else v
    if not isinstance(x, (list, tuple)) or len(x) != 7 or not all(_real(e) and abs(e) <= MAX_COORD_M for e in x):
        raise WarpMetaError(f"warp metadata {where}: {field} must be 7 numbers [x, y, z, qx, qy, qz, qw] within "
                            f"+-{MAX_COORD_M:g}, got {_show(v)}")
    with np.errstate(over="ignore"):   # a peer's 1e300 overflows to inf, which the range check rejects
        qn = float(np.linalg.norm(np.asarray(x[3:], np.float64)))
    if not 0.5 < qn < 2.0:
        raise WarpMetaError(f"warp metadata {where}: {field} orientation is not a unit quaternion: {_show(v)}")
    return Pose.from_list(x)


def _ids(m: dict[Any, Any], key: str, where: str) -> np.ndarray:
    a = m.get(key)
    if not isinstance(a, np.ndarray) or a.ndim != 1 or a.dtype.kind not in "ui":
        raise WarpMetaError(f"warp metadata {where}: {key} must be a 1-D integer array, got {_show(a)}")
    if a.size and not (1 <= int(a.min()) and int(a.max()) <= MAX_OBJECT_ID):
        raise WarpMetaError(f"warp metadata {where}: {key} must be object ids in [1, {MAX_OBJECT_ID}], "
                            f"got {int(a.min())}..{int(a.max())}")
    return a


def _matrices(m: dict[Any, Any], key: str, n: int, where: str) -> np.ndarray:
    """``n`` affine 4x4 model matrices with an invertible 3x3 part (warping inverts them)."""
    a = m.get(key)
    if not isinstance(a, np.ndarray) or a.dtype.kind != "f" or a.shape != (n, 4, 4):
        raise WarpMetaError(f"warp metadata {where}: {key} must be a ({n}, 4, 4) float array, got {_show(a)}")
    a = a.astype(np.float64)
    if not (np.abs(a) <= MAX_COORD_M).all():
        raise WarpMetaError(f"warp metadata {where}: {key} has entries that are not finite or beyond +-{MAX_COORD_M:g}")
    if n and (not np.allclose(a[:, 3], (0.0, 0.0, 0.0, 1.0)) or (np.abs(np.linalg.det(a[:, :3, :3])) < 1e-9).any()):
        raise WarpMetaError(f"warp metadata {where}: {key} holds a matrix that is not an invertible affine transform")
    return a


def parse_update(update: DecodedUpdate, cfg: WarpConfig, ref: CameraIntrinsics) -> ReferenceFrame:
    """Check and decode one update's planes and metadata; anything malformed raises
    :class:`WarpMetaError` naming the frame and the field."""
    m = update.meta
    where = f"frame {update.frame_id}"
    if not isinstance(m, dict):
        raise WarpMetaError(f"warp metadata {where}: expected a map, got {type(m).__name__}")
    if not (isinstance(m.get("v"), int) and not isinstance(m.get("v"), bool) and m.get("v") == META_VERSION):
        raise WarpMetaError(f"warp metadata {where}: v: missing or unsupported version {_show(m.get('v'))}")
    coding = m.get("depth_coding")
    if not isinstance(coding, str) or coding not in ("lossless", "bc4"):
        raise WarpMetaError(f"warp metadata {where}: depth_coding: unknown coding {_show(coding)}")
    near = _positive(m, "depth_near_m", where)
    r = m.get("ref")
    if (not isinstance(r, (list, tuple)) or len(r) != 3 or not all(_real(x) for x in r)
            or (r[0], r[1]) != (ref.width, ref.height) or abs(r[2] - ref.fov_y_deg) > 1e-6):
        raise WarpMetaError(f"warp metadata {where}: ref: reference camera {_show(r)} does not match "
                            f"[{ref.width}, {ref.height}, {ref.fov_y_deg:.6g}]")
    views_m = m.get("views")
    if not isinstance(views_m, list) or not 1 <= len(views_m) <= 2:
        raise WarpMetaError(f"warp metadata {where}: views must be a list of 1 or 2 views, got {_show(views_m)}")
    shape = (ref.height, ref.width)
    views = []
    for v, vm in enumerate(views_m):
        if not isinstance(vm, dict):
            raise WarpMetaError(f"warp metadata {where}: views[{v}] must be a map, got {type(vm).__name__}")
        pose = _pose(vm.get("pose"), where, f"views[{v}].pose")
        color = update.planes.get(f"color{v}")
        if not isinstance(color, np.ndarray) or color.shape != (*shape, 3) or color.dtype != np.uint8:
            raise WarpMetaError(f"warp {where}: plane color{v} must be {shape + (3,)} uint8, got {_show(color)}")
        ids = vm.get("ids")
        if not isinstance(ids, np.ndarray) or ids.shape != shape or ids.dtype not in (np.uint8, np.uint16):
            raise WarpMetaError(f"warp metadata {where}: views[{v}].ids must be a {shape} uint8/uint16 array, got {_show(ids)}")
        if coding == "lossless":
            plane = update.planes.get(f"depth{v}")
            if not isinstance(plane, np.ndarray) or plane.shape != (2 * shape[0], shape[1]) or plane.dtype != np.uint8:
                raise WarpMetaError(f"warp {where}: plane depth{v} must be {(2 * shape[0], shape[1])} uint8, got {_show(plane)}")
            codes = unpack_depth_planes(plane)
        else:
            try:
                codes = bc4_decode(vm.get("bc4"), expect_shape=shape)
            except CodecError as exc:
                raise WarpMetaError(f"warp metadata {where}: views[{v}].bc4: {exc}") from exc
        depth = dequantize_depth(codes, near)
        depth[~np.isfinite(depth)] = 0.0
        views.append(ReferenceView(pose, color, depth, ids.astype(np.uint16)))
    obj_ids = _ids(m, "obj_ids", where)
    dyn_ids = _ids(m, "dyn_ids", where)
    model = _matrices(m, "obj_model", len(obj_ids), where)
    dyn_prev = _matrices(m, "dyn_prev", len(dyn_ids), where)
    dt = _positive(m, "dt_s", where)
    return ReferenceFrame(update.t_s, views, {int(i): model[k] for k, i in enumerate(obj_ids)},
                          {int(i): dyn_prev[k] for k, i in enumerate(dyn_ids)}, dt)
