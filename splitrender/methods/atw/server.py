"""``atw``, server half."""

from __future__ import annotations

from ..base import ServerContext, ServerHalf, StreamSpec, Update
from .config import AtwConfig, overscan_intrinsics


class AtwServer(ServerHalf):
    config: AtwConfig

    def __init__(self, *a, **kw) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*a, **kw)
        self.ref_intr = overscan_intrinsics(self.intrinsics, self.config.overscan)

    def streams(self) -> list[StreamSpec]:
        r = self.ref_intr
        return [StreamSpec("color", self.config.video(self.server_fps), r.width, r.height, scalable=True)]

    def produce(self, ctx: ServerContext) -> Update:
        out = ctx.renderer.render(ctx.scene, ctx.t_s, ctx.target_pose, self.ref_intr, ("color",))
        meta = {"fov_y_deg": self.ref_intr.fov_y_deg}
        return Update(ctx.frame_id, ctx.t_s, ctx.target_pose, {"color": out.color}, meta, ctx.keyframe_requested)
