"""``warp``: client/server depth-image warping (Smit et al., "An image-warping
architecture for VR"), which is also the MeshWarp (MW) baseline of SAS and QUASAR.

Server half: renders colour, depth and per-pixel object IDs for one or two
**reference views** per frame (the second placed by ``second_view``: a wider
stereo-like pair, a step back, or a step along the predicted motion), with an
enlarged field of view (``fov_scale``, image-plane scale as ``atw``'s overscan)
and a resolution scale.  Colour goes as lossy video; depth as 16-bit inverse-depth
codes (``splitrender.codecs.depth``), either lossless (two 8-bit planes in one
lossless HEVC 4:0:0 picture) or BC4-like 8x8 blocks + zstd in the metadata.  The
per-pixel object IDs and the model matrices of the visible objects (at the frame's
time and one server frame earlier, for motion extrapolation) go in the metadata.

Client half: per object one 4x4 warp matrix
``M_i = P_cur V_cur O_i(t) O_i(ref)^-1 V_ref^-1`` (the paper's chain; the reference
projection's inverse is applied analytically in the shader because depth arrives in
metres); ``O_i(t)`` is extrapolated from the two model matrices (slerp on rotation,
linear on translation).  The grid of reference pixels is drawn as Jacobian-sized point
splats, Jacobian quad splats (geometry shader), or a grid mesh (its outer vertices on the
image border, so it spans the whole reference image) cut at depth and
moving-object discontinuities.  The view nearest the display pose is drawn first; a
second view only fills the pixels it left uncovered (``view_merge``; the paper's plain
depth test is ``"depth"``).  Pixels no warped fragment reaches are holes; they are
filled by scanning along the epipolar direction both ways and taking the farther
sample, and the hole mask (before filling) is returned for the metrics.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..codecs.depth import bc4_decode, bc4_encode, dequantize_depth, pack_depth_planes, quantize_depth, unpack_depth_planes
from ..codecs.video import VideoCodecConfig
from ..errors import CodecError, ConfigError, RemoteProtocolError
from ..render.canvas import FullscreenPass, upload_image
from ..render.gl import load_program
from ..scene.pose import CameraIntrinsics, Pose, quat_from_matrix3, quat_slerp, quat_to_matrix3
from .base import ClientFrame, ClientHalf, DecodedUpdate, MethodConfig, MethodSpec, ServerContext, ServerHalf, StreamSpec, Update, register_method

log = logging.getLogger(__name__)

SHADERS = Path(__file__).parent / "shaders"
META_VERSION = 1
MAX_OBJECT_ID = 65535
MAX_COORD_M = 1e6  # largest pose coordinate, matrix entry, near distance or dt accepted from the server (float32 on the GPU)
Reconstruction = Literal["points", "quads", "mesh"]
SecondView = Literal["stereo", "back", "motion"]
ViewMerge = Literal["holes", "depth"]
DepthCoding = Literal["lossless", "bc4"]


@dataclass(frozen=True)
class WarpConfig(MethodConfig):
    """Settings of the ``warp`` method.

    - ``views``: reference views per frame (1 or 2);
    - ``second_view``: where view 2 goes; view 1 is always the predicted pose (moving it
      off the prediction costs more than view 2 gains): ``stereo`` (view 2 ``baseline_m``
      to the right along the camera's x axis, the paper's widened eye separation),
      ``back`` (``baseline_m`` behind), ``motion`` (``baseline_m`` further along the
      predicted motion; to the right when still);
    - ``view_merge``: how the other views join the one nearest the display pose:
      ``holes`` (they only fill pixels the nearest view left uncovered) or ``depth``
      (the paper's plain depth test; their pixel-phase-shifted silhouettes then widen
      every foreground edge and thin structure, which costs more PSNR than the filled
      disocclusions gain);
    - ``fov_scale``: image-plane scale of the reference views (1 = display FOV;
      3.0 turns a 60 degree display into about 120 degrees, "MW 120");
    - ``resolution_scale``: reference pixels per display pixel along each axis at equal
      pixel density (1 keeps the density; the reference is ``fov_scale *
      resolution_scale`` times the display size);
    - ``reconstruction``: ``points``, ``quads`` or ``mesh``;
    - ``depth_coding``: ``lossless`` (HEVC, bit-exact 16-bit codes) or ``bc4``;
    - ``depth_near_m``: the depth quantiser's near distance (metres);
    - ``depth_discontinuity``: relative depth step that cuts mesh triangles and
      one-sides the Jacobian;
    - ``hole_fill``: epipolar hole filling on/off; ``max_scan_px``: scan length;
    - ``extrapolate``: extrapolate object motion between updates (else objects jump);
      ``max_extrapolation_s`` caps it;
    - ``max_splat_px``: largest point/quad splat;
    - ``splat_slack_px``: point size is ``ceil(S - slack)``; 0 is the paper's strict
      ``ceil`` (every magnification above 1 doubles the splat and thickens edges by half a
      pixel); the default lets near-1 magnifications keep 1-pixel splats and leaves the
      rare crack to hole filling.
    """

    views: int = 1
    second_view: SecondView = "stereo"
    view_merge: ViewMerge = "holes"
    baseline_m: float = 0.3
    fov_scale: float = 1.3
    resolution_scale: float = 1.0
    reconstruction: Reconstruction = "points"
    depth_coding: DepthCoding = "lossless"
    depth_near_m: float = 0.1
    depth_discontinuity: float = 0.15
    hole_fill: bool = True
    max_scan_px: int = 64
    extrapolate: bool = True
    max_extrapolation_s: float = 0.5
    max_splat_px: float = 8.0
    splat_slack_px: float = 0.25

    def __post_init__(self) -> None:
        super().__post_init__()
        n = type(self).__name__
        if self.views not in (1, 2):
            raise ConfigError(f"{n}.views: must be 1 or 2, got {self.views}")
        if self.second_view not in ("stereo", "back", "motion"):
            raise ConfigError(f"{n}.second_view: {self.second_view!r} is not one of ['stereo', 'back', 'motion']")
        if self.view_merge not in ("holes", "depth"):
            raise ConfigError(f"{n}.view_merge: {self.view_merge!r} is not one of ['holes', 'depth']")
        if self.reconstruction not in ("points", "quads", "mesh"):
            raise ConfigError(f"{n}.reconstruction: {self.reconstruction!r} is not one of ['points', 'quads', 'mesh']")
        if self.depth_coding not in ("lossless", "bc4"):
            raise ConfigError(f"{n}.depth_coding: {self.depth_coding!r} is not one of ['lossless', 'bc4']")
        if not 0.0 <= self.baseline_m <= 5.0:
            raise ConfigError(f"{n}.baseline_m: must be in [0, 5] metres, got {self.baseline_m}")
        if not 1.0 <= self.fov_scale <= 6.0:
            raise ConfigError(f"{n}.fov_scale: must be in [1, 6], got {self.fov_scale}")
        if not 0.1 <= self.resolution_scale <= 4.0:
            raise ConfigError(f"{n}.resolution_scale: must be in [0.1, 4], got {self.resolution_scale}")
        if not self.depth_near_m > 0:
            raise ConfigError(f"{n}.depth_near_m: must be > 0, got {self.depth_near_m}")
        if not self.depth_discontinuity > 0:
            raise ConfigError(f"{n}.depth_discontinuity: must be > 0, got {self.depth_discontinuity}")
        if self.max_scan_px < 1:
            raise ConfigError(f"{n}.max_scan_px: must be >= 1, got {self.max_scan_px}")
        if not 1.0 <= self.max_splat_px <= 64.0:
            raise ConfigError(f"{n}.max_splat_px: must be in [1, 64], got {self.max_splat_px}")
        if not 0.0 <= self.splat_slack_px < 1.0:
            raise ConfigError(f"{n}.splat_slack_px: must be in [0, 1), got {self.splat_slack_px}")
        if self.max_extrapolation_s < 0:
            raise ConfigError(f"{n}.max_extrapolation_s: must be >= 0, got {self.max_extrapolation_s}")


def fov_scale_for(display: CameraIntrinsics, fov_y_deg: float) -> float:
    """The ``fov_scale`` that gives reference views a vertical FOV of ``fov_y_deg``."""
    return math.tan(math.radians(fov_y_deg) / 2) / math.tan(math.radians(display.fov_y_deg) / 2)


def reference_intrinsics(display: CameraIntrinsics, fov_scale: float, resolution_scale: float) -> CameraIntrinsics:
    """Reference-view camera: display FOV enlarged by ``fov_scale``, even pixel size."""
    big = display.enlarged(fov_scale, keep_pixel_density=False)
    w = max(2, int(round(display.width * fov_scale * resolution_scale / 2)) * 2)
    h = max(2, int(round(display.height * fov_scale * resolution_scale / 2)) * 2)
    return CameraIntrinsics(w, h, big.fov_y_deg, display.near_m, display.far_m)


def reference_poses(cfg: WarpConfig, target: Pose, motion_dir: np.ndarray | None) -> list[Pose]:
    """The reference view poses for one frame (view 0 first; see ``WarpConfig.second_view``)."""
    if cfg.views == 1:
        return [target]
    r = quat_to_matrix3(target.orientation)
    right, back = r[:, 0], r[:, 2]
    b = cfg.baseline_m
    if cfg.second_view == "stereo":
        return [target, Pose(target.position + right * b, target.orientation)]
    if cfg.second_view == "back":
        return [target, Pose(target.position + back * b, target.orientation)]
    d = motion_dir if motion_dir is not None and np.linalg.norm(motion_dir) > 1e-9 else right
    return [target, Pose(target.position + d / np.linalg.norm(d) * b, target.orientation)]


# ----------------------------------------------------------------------------- server
class WarpServer(ServerHalf):
    """Renders colour, depth and object IDs of the reference views and packs them."""

    config: WarpConfig

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        self.ref_intr = reference_intrinsics(self.intrinsics, self.config.fov_scale, self.config.resolution_scale)
        self._stats: dict[str, float] = {}

    def depth_codec(self) -> VideoCodecConfig:
        """Lossless HEVC 4:0:0, 8-bit: the two byte planes of the depth codes stacked."""
        return VideoCodecConfig(codec="hevc", pix_fmt="gray", input_format="gray", lossless=True, crf=None,
                                gop=self.config.gop, preset=self.config.preset, fps=self.server_fps)

    def streams(self) -> list[StreamSpec]:
        r = self.ref_intr
        share = 1.0 / self.config.views
        out = []
        for v in range(self.config.views):
            out.append(StreamSpec(f"color{v}", self.config.video(self.server_fps, share), r.width, r.height))
            if self.config.depth_coding == "lossless":
                out.append(StreamSpec(f"depth{v}", self.depth_codec(), r.width, 2 * r.height))
        return out

    def produce(self, ctx: ServerContext) -> Update:
        cfg = self.config
        dt = 1.0 / self.server_fps
        motion = ctx.predict(ctx.target_t_s + dt).position - ctx.target_pose.position if cfg.second_view == "motion" else None
        poses = reference_poses(cfg, ctx.target_pose, motion)
        planes: dict[str, np.ndarray] = {}
        views: list[dict[str, Any]] = []
        seen: set[int] = set()
        bc4_bytes = 0
        for v, pose in enumerate(poses):
            out = ctx.renderer.render(ctx.scene, ctx.t_s, pose, self.ref_intr, ("color", "depth", "object_id"))
            codes = quantize_depth(out.depth, cfg.depth_near_m)
            ids = out.object_id
            if ids.max(initial=0) > MAX_OBJECT_ID:
                raise ConfigError(f"warp: object id {int(ids.max())} exceeds {MAX_OBJECT_ID}")
            ids = ids.astype(np.uint8 if ids.max(initial=0) < 256 else np.uint16)
            seen.update(int(i) for i in np.unique(ids) if i)
            planes[f"color{v}"] = out.color
            view: dict[str, Any] = {"pose": pose.to_list(), "ids": ids}
            if cfg.depth_coding == "lossless":
                planes[f"depth{v}"] = pack_depth_planes(codes)
            else:
                view["bc4"] = bc4_encode(codes)
                bc4_bytes += len(view["bc4"])
            views.append(view)
        mats = ctx.scene.model_matrices(ctx.t_s)
        prev = ctx.scene.model_matrices(ctx.t_s - dt)
        dyn = set(ctx.scene.dynamic_ids())
        obj_ids = sorted(seen)
        dyn_ids = [i for i in obj_ids if i in dyn]
        meta = {
            "v": META_VERSION,
            "depth_coding": cfg.depth_coding,
            "depth_near_m": cfg.depth_near_m,
            "ref": [self.ref_intr.width, self.ref_intr.height, self.ref_intr.fov_y_deg],
            "views": views,
            "obj_ids": np.array(obj_ids, np.uint16),
            "obj_model": np.array([mats[i] for i in obj_ids], np.float64).reshape(-1, 4, 4),
            "dyn_ids": np.array(dyn_ids, np.uint16),
            "dyn_prev": np.array([prev[i] for i in dyn_ids], np.float64).reshape(-1, 4, 4),
            "dt_s": dt,
        }
        self._stats = {"views": float(len(poses)), "objects": float(len(obj_ids)), "bc4_bytes": float(bc4_bytes)}
        return Update(ctx.frame_id, ctx.t_s, ctx.target_pose, planes, meta, ctx.keyframe_requested)

    def stats(self) -> dict[str, float]:
        return dict(self._stats)


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
    if not 0.5 < float(np.linalg.norm(np.asarray(x[3:], np.float64))) < 2.0:
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


def extrapolate_model(prev: np.ndarray, cur: np.ndarray, u: float) -> np.ndarray:
    """Model matrix ``u`` steps past ``cur`` (``u`` in units of the prev->cur interval):
    slerp on the rotation, linear on the translation, scale kept from ``cur``."""
    sp = np.linalg.norm(prev[:3, :3], axis=0)
    sc = np.linalg.norm(cur[:3, :3], axis=0)
    qp = quat_from_matrix3(prev[:3, :3] / sp)
    qc = quat_from_matrix3(cur[:3, :3] / sc)
    out = np.eye(4)
    out[:3, :3] = quat_to_matrix3(quat_slerp(qp, qc, 1.0 + u)) * sc
    out[:3, 3] = cur[:3, 3] + u * (cur[:3, 3] - prev[:3, 3])
    return out


def warp_matrices(frame: ReferenceFrame, view: ReferenceView, ref: CameraIntrinsics, pose: Pose, intr: CameraIntrinsics,
                  t_s: float, extrapolate: bool, max_extrapolation_s: float, n_ids: int) -> np.ndarray:
    """(n_ids, 5, 4) float32 texture rows: the columns of each object's warp matrix
    ``P_cur V_cur O_i(t) O_i(ref)^-1 V_ref^-1`` and a (dynamic, 0, 0, 0) flag texel."""
    base = intr.projection() @ pose.view_matrix()
    ref_inv = view.pose.matrix()
    out = np.zeros((n_ids, 5, 4), np.float32)
    static = base @ ref_inv
    out[:, :4, :] = static.T.astype(np.float32)
    h = float(np.clip(t_s - frame.t_s, 0.0, max_extrapolation_s))
    for i, cur in frame.model.items():
        if i >= n_ids:
            continue
        prev = frame.prev.get(i)
        now = cur
        if prev is not None:  # a dynamic object: cut mesh triangles at its border, extrapolate its motion
            out[i, 4, 0] = 1.0
            if extrapolate:
                now = extrapolate_model(prev, cur, h / frame.dt_s)
        m = base @ now @ np.linalg.inv(cur) @ ref_inv
        out[i, :4, :] = m.T.astype(np.float32)
    return out


# ----------------------------------------------------------------------------- client: GL
def mesh_grid_indices(width: int, height: int) -> np.ndarray:
    """Triangle indices (flat uint32) of the mesh reconstruction's grid for a ``width`` x ``height``
    reference image: ``(width + 2) x (height + 2)`` vertices, row-major from the top, whose inner
    ``width x height`` are the pixel centres and whose outer ring lies on the image border
    (``warp_mesh.vert``), so the mesh spans the whole image."""
    gw, gh = width + 2, height + 2
    idx = np.arange(gw * gh, dtype=np.uint32).reshape(gh, gw)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    return np.stack([a, c, b, b, c, d], axis=-1).reshape(-1).astype(np.uint32)


class _ViewGPU:
    """Textures of one reference view."""

    def __init__(self) -> None:
        self.color: Any = None
        self.depth: Any = None
        self.ids: Any = None
        self.mats: Any = None


class WarpClient(ClientHalf):
    """Warps the newest reference frame to the display pose, in shaders."""

    config: WarpConfig

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        import moderngl

        self._mgl = moderngl
        cfg = self.config
        i = self.intrinsics
        self.ref_intr = reference_intrinsics(i, cfg.fov_scale, cfg.resolution_scale)
        ctx = self.gl
        w, h = i.width, i.height
        self._warped = ctx.texture((w, h), 4, dtype="f1")
        self._wdepth = ctx.texture((w, h), 1, dtype="f4")
        self._zbuf = ctx.depth_renderbuffer((w, h))
        self._fbo = ctx.framebuffer([self._warped, self._wdepth], self._zbuf)
        self._cover = ctx.texture((w, h), 4, dtype="f1")  # the nearest view's coverage (alpha), for view_merge="holes"
        self._out = ctx.texture((w, h), 4, dtype="f1")
        self._out_fbo = ctx.framebuffer([self._out])
        for t in (self._warped, self._wdepth, self._cover):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        rec = cfg.reconstruction
        if rec == "points":
            self.prog = load_program(ctx, SHADERS / "warp_points.vert", SHADERS / "warp_points.frag")
        elif rec == "quads":
            self.prog = load_program(ctx, SHADERS / "warp_quads.vert", SHADERS / "warp_splat.frag", SHADERS / "warp_quads.geom")
        else:
            self.prog = load_program(ctx, SHADERS / "warp_mesh.vert", SHADERS / "warp_mesh.frag", SHADERS / "warp_mesh.geom")
        rw, rh = self.ref_intr.width, self.ref_intr.height
        if rec == "mesh":
            tris = mesh_grid_indices(rw, rh)
            self._ibo = ctx.buffer(tris.astype("u4").tobytes())
            self.vao = ctx.vertex_array(self.prog, [], index_buffer=self._ibo, index_element_size=4)
            self._mode = moderngl.TRIANGLES
            self._count = len(tris)
            # pixels next to a cut (thin railings, silhouettes) are drawn as point splats too
            self.edge_prog = load_program(ctx, SHADERS / "warp_points.vert", SHADERS / "warp_points.frag")
            self.edge_vao = ctx.vertex_array(self.edge_prog, [])
        else:
            self.vao = ctx.vertex_array(self.prog, [])
            self._mode = moderngl.POINTS
            self._count = rw * rh
        self.fill = FullscreenPass(ctx, SHADERS / "warp_holefill.frag")
        self._views: list[_ViewGPU] = []
        self._frame: ReferenceFrame | None = None
        self._n_ids = 1
        self._max_ids = int(ctx.info["GL_MAX_TEXTURE_SIZE"])

    # ------------------------------------------------------------------ cache
    def apply(self, update: DecodedUpdate) -> None:
        if update.missing:  # a reference view without its colour or depth cannot be warped: keep the last one
            return
        frame = parse_update(update, self.config, self.ref_intr)
        n_ids = 1 + max([int(v.ids.max(initial=0)) for v in frame.views] + list(frame.model) + [0])
        if n_ids > self._max_ids:  # the warp matrices are one texture row per id
            raise WarpMetaError(f"warp metadata frame {update.frame_id}: object id {n_ids - 1} exceeds this client's "
                                f"limit of {self._max_ids - 1} (GL_MAX_TEXTURE_SIZE)")
        while len(self._views) < len(frame.views):
            self._views.append(_ViewGPU())
        for g, v in zip(self._views, frame.views):
            g.color = upload_image(self.gl, v.color, g.color, linear=False)
            g.depth = upload_image(self.gl, v.depth_m.astype(np.float32), g.depth, linear=False)
            g.ids = upload_image(self.gl, v.ids, g.ids, linear=False)
        self._frame = frame
        self._n_ids = n_ids
        self._has_content = True

    # ------------------------------------------------------------------ render
    def _view_order(self, pose: Pose) -> list[int]:
        assert self._frame is not None
        d = [v.pose.distance_m(pose) + 0.01 * v.pose.angle_deg(pose) for v in self._frame.views]
        return sorted(range(len(d)), key=lambda k: d[k])

    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        i = self.intrinsics
        if self._frame is None:
            return ClientFrame(np.zeros((i.height, i.width, 3), np.uint8), np.ones((i.height, i.width), bool))
        t0 = time.perf_counter()
        cfg, ctx, prog, frame, ref = self.config, self.gl, self.prog, self._frame, self.ref_intr
        proj = i.projection()
        self._fbo.use()
        ctx.viewport = (0, 0, i.width, i.height)
        self._fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self._wdepth.write(np.zeros((i.height, i.width), np.float32).tobytes())
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.CULL_FACE | ctx.BLEND)
        ctx.enable(ctx.PROGRAM_POINT_SIZE)
        tan_y = math.tan(math.radians(ref.fov_y_deg) / 2)
        progs = [prog] + ([self.edge_prog] if cfg.reconstruction == "mesh" else [])
        for p in progs:
            self._set(p, "u_ref_size", (ref.width, ref.height))
            self._set(p, "u_tan_half", (tan_y * ref.aspect, tan_y))
            self._set(p, "u_out_size", (float(i.width), float(i.height)))
            self._set(p, "u_proj_zz", (float(proj[2, 2]), float(proj[2, 3])))
            self._set(p, "u_disc", float(cfg.depth_discontinuity))
            self._set(p, "u_max_splat", float(cfg.max_splat_px))
            self._set(p, "u_splat_slack", float(cfg.splat_slack_px))
            self._set(p, "u_edge_only", 0 if p is prog else 1)
            for unit, name in enumerate(("u_color", "u_depth", "u_ids", "u_mats", "u_cover")):
                self._set(p, name, unit)
        order = self._view_order(pose)
        for rank, k in enumerate(order):
            g, view = self._views[k], frame.views[k]
            mats = warp_matrices(frame, view, ref, pose, i, t_s, cfg.extrapolate, cfg.max_extrapolation_s, self._n_ids)
            self._upload_mats(g, mats)
            g.color.use(0)
            g.depth.use(1)
            g.ids.use(2)
            g.mats.use(3)
            holes_only = rank > 0 and cfg.view_merge == "holes"
            if holes_only and rank == 1:
                ctx.copy_framebuffer(self._cover, self._fbo)
                self._fbo.use()
            self._cover.use(4)
            for p in progs:
                self._set(p, "u_bias_rel", 0.0 if rank == 0 else 0.01 * rank)
                self._set(p, "u_holes_only", 1 if holes_only else 0)
            self.vao.render(mode=self._mode, vertices=self._count)
            if cfg.reconstruction == "mesh":
                self.edge_vao.render(mode=self._mgl.POINTS, vertices=ref.width * ref.height)
        # hole filling into the output target; alpha keeps the coverage
        ctx.disable(ctx.DEPTH_TEST)
        self._out_fbo.use()
        ctx.viewport = (0, 0, i.width, i.height)
        primary = frame.views[order[0]]
        e = proj @ pose.view_matrix() @ np.append(primary.pose.position, 1.0)
        ep = np.array([(e[0] + e[3]) * 0.5 * i.width, (e[1] + e[3]) * 0.5 * i.height, e[3]])
        fp = self.fill.prog
        self._warped.use(0)
        self._wdepth.use(1)
        self._set(fp, "u_warped", 0)
        self._set(fp, "u_wdepth", 1)
        self._set(fp, "u_out_size", (float(i.width), float(i.height)))
        self._set(fp, "u_epipole", tuple(float(x) for x in ep))
        self._set(fp, "u_max_scan", int(cfg.max_scan_px))
        self._set(fp, "u_fill", 1 if cfg.hole_fill else 0)
        self.fill.run()
        rgba = np.frombuffer(self._out_fbo.read(components=4), np.uint8).reshape(i.height, i.width, 4)[::-1]
        color = np.ascontiguousarray(rgba[..., :3])
        holes = rgba[..., 3] == 0
        ms = (time.perf_counter() - t0) * 1e3
        return ClientFrame(color, holes, {"warp_ms": ms, "views": float(len(order))})

    def _upload_mats(self, g: _ViewGPU, mats: np.ndarray) -> Any:
        n = mats.shape[0]
        data = np.ascontiguousarray(mats.reshape(n, 5 * 4), np.float32)
        if g.mats is None or g.mats.size != (5, n):
            if g.mats is not None:
                g.mats.release()
            g.mats = self.gl.texture((5, n), 4, dtype="f4")
            g.mats.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
        g.mats.write(data.tobytes())
        return g.mats

    @staticmethod
    def _set(prog: Any, name: str, value: Any) -> None:
        if name in prog:
            prog[name].value = value


SPEC = register_method(MethodSpec("warp", WarpServer, WarpClient, WarpConfig, "depth-image warping (MeshWarp): points, quads or mesh"))
