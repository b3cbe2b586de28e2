"""``video``: plain remote rendering.  The server renders a colour frame at the predicted
pose; the client shows the newest decoded frame whatever its pose (the baseline every
paper compares against)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene.pose import Pose
from .base import ClientFrame, ClientHalf, DecodedUpdate, MethodConfig, MethodSpec, ServerContext, ServerHalf, StreamSpec, Update, register_method


@dataclass(frozen=True)
class VideoConfig(MethodConfig):
    """Plain streaming: only the common codec settings."""


class VideoServer(ServerHalf):
    def streams(self) -> list[StreamSpec]:
        i = self.intrinsics
        return [StreamSpec("color", self.config.video(self.server_fps), i.width, i.height)]

    def produce(self, ctx: ServerContext) -> Update:
        out = ctx.renderer.render(ctx.scene, ctx.t_s, ctx.target_pose, self.intrinsics, ("color",))
        return Update(ctx.frame_id, ctx.t_s, ctx.target_pose, {"color": out.color}, {}, ctx.keyframe_requested)


class VideoClient(ClientHalf):
    def __init__(self, *a, **kw) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*a, **kw)
        self._frame: np.ndarray | None = None

    def apply(self, update: DecodedUpdate) -> None:
        if "color" in update.planes:
            self._frame = update.planes["color"]
            self._has_content = True

    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        i = self.intrinsics
        if self._frame is None:
            return ClientFrame(np.zeros((i.height, i.width, 3), np.uint8), np.ones((i.height, i.width), bool))
        return ClientFrame(self._frame, np.zeros((i.height, i.width), bool))


SPEC = register_method(MethodSpec("video", VideoServer, VideoClient, VideoConfig, "plain video of the predicted view"))
