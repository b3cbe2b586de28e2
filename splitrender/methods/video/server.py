"""``video``, server half."""

from __future__ import annotations

from ..base import ServerContext, ServerHalf, StreamSpec, Update


class VideoServer(ServerHalf):
    def streams(self) -> list[StreamSpec]:
        i = self.intrinsics
        return [StreamSpec("color", self.config.video(self.server_fps), i.width, i.height, scalable=True)]

    def produce(self, ctx: ServerContext) -> Update:
        out = ctx.renderer.render(ctx.scene, ctx.t_s, ctx.target_pose, self.intrinsics, ("color",))
        return Update(ctx.frame_id, ctx.t_s, ctx.target_pose, {"color": out.color}, {}, ctx.keyframe_requested)
