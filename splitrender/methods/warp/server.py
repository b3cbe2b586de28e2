"""``warp``, server half: reference views with depth and object ids."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ...codecs.depth import bc4_encode, coarsen_depth, pack_depth_planes, quantize_depth
from ...codecs.video import VideoCodecConfig
from ...errors import ConfigError
from ..base import ServerContext, ServerHalf, StreamSpec, Update
from .config import MAX_OBJECT_ID, META_VERSION, WarpConfig, reference_intrinsics, reference_poses

log = logging.getLogger(__name__)


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
            out.append(StreamSpec(f"color{v}", self.config.video(self.server_fps, share), r.width, r.height,
                                  scalable=True))
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
            codes = coarsen_depth(quantize_depth(out.depth, cfg.depth_near_m), cfg.depth_bits)
            ids = out.object_id
            if ids.max(initial=0) > MAX_OBJECT_ID:
                raise ConfigError(f"warp: object id {int(ids.max())} exceeds {MAX_OBJECT_ID}")
            ids = ids.astype(np.uint8 if ids.max(initial=0) < 256 else np.uint16)
            seen.update(int(i) for i in np.unique(ids) if i)
            planes[f"color{v}"] = out.color
            view: dict[str, Any] = {"pose": pose.to_list(), "ids": ids}
            if cfg.depth_coding == "lossless":
                if cfg.depth_step > 1:       # one sample in depth_step per axis, top left; the rest zero
                    s = cfg.depth_step
                    small = codes[::s, ::s]
                    codes = np.zeros_like(codes)
                    codes[:small.shape[0], :small.shape[1]] = small
                    view["depth_step"] = s
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
