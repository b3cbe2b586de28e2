"""``tiny``, server half."""

from __future__ import annotations

import numpy as np

from splitrender.methods import DataStreamSpec, ServerContext, ServerHalf, Update


class TinyServer(ServerHalf):
    def streams(self) -> list[DataStreamSpec]:
        return [DataStreamSpec("thumb", delivery="datagram", max_bytes=1 << 22), DataStreamSpec("counter")]

    def session_data(self) -> dict[str, int]:
        f = self.config.factor  # type: ignore[attr-defined]
        return {"w": self.intrinsics.width // f, "h": self.intrinsics.height // f}

    def produce(self, ctx: ServerContext) -> Update:
        f = self.config.factor  # type: ignore[attr-defined]
        img = ctx.renderer.render(ctx.scene, ctx.t_s, ctx.target_pose, self.intrinsics, ("color",)).color
        thumb = np.ascontiguousarray(img[f // 2::f, f // 2::f][: self.intrinsics.height // f, : self.intrinsics.width // f])
        return Update(ctx.frame_id, ctx.t_s, ctx.target_pose, {}, {"fb_lost": sum(len(v) for v in ctx.feedback.lost.values())},
                      data={"thumb": thumb.tobytes(), "counter": ctx.frame_id.to_bytes(8, "little")})
