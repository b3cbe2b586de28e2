"""``atw``: asynchronous time warp.  The server renders the predicted view with overscan
(a larger field of view at the same pixel density); the client re-projects the newest
frame rotationally to its current orientation with a homography, in a shader.  Position
changes are ignored (that is what ATW cannot fix); pixels the overscan does not cover
are holes, filled with the nearest edge texel or black."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ..errors import ConfigError
from ..render.canvas import Canvas, FullscreenPass, upload_image
from ..scene.pose import CameraIntrinsics, Pose, quat_to_matrix3
from .base import ClientFrame, ClientHalf, DecodedUpdate, MethodConfig, MethodSpec, ServerContext, ServerHalf, StreamSpec, Update, register_method

SHADERS = Path(__file__).parent / "shaders"


@dataclass(frozen=True)
class AtwConfig(MethodConfig):
    """``overscan``: image-plane scale of the server frame (1.3 = 30% wider and taller)."""

    overscan: float = 1.3
    fill: Literal["edge", "black"] = "edge"

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 1.0 <= self.overscan <= 3.0:
            raise ConfigError(f"AtwConfig.overscan: must be in [1, 3], got {self.overscan}")
        if self.fill not in ("edge", "black"):
            raise ConfigError(f"AtwConfig.fill: {self.fill!r} is not one of ['edge', 'black']")


def overscan_intrinsics(intr: CameraIntrinsics, overscan: float) -> CameraIntrinsics:
    return intr.enlarged(overscan, keep_pixel_density=True)


def pixel_projection(intr: CameraIntrinsics) -> np.ndarray:
    """3x3 map from a camera-space direction to homogeneous top-left pixel coordinates."""
    f = intr.focal_px()
    return np.array([[f, 0.0, -intr.width / 2.0], [0.0, -f, -intr.height / 2.0], [0.0, 0.0, -1.0]])


def rotation_homography(ref: CameraIntrinsics, ref_q: np.ndarray, cur: CameraIntrinsics, cur_q: np.ndarray) -> np.ndarray:
    """Display pixel of the current camera -> pixel of the reference image (rotation only)."""
    r_ref = quat_to_matrix3(ref_q)
    r_cur = quat_to_matrix3(cur_q)
    return pixel_projection(ref) @ r_ref.T @ r_cur @ np.linalg.inv(pixel_projection(cur))


class AtwServer(ServerHalf):
    config: AtwConfig

    def __init__(self, *a, **kw) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*a, **kw)
        self.ref_intr = overscan_intrinsics(self.intrinsics, self.config.overscan)

    def streams(self) -> list[StreamSpec]:
        r = self.ref_intr
        return [StreamSpec("color", self.config.video(self.server_fps), r.width, r.height)]

    def produce(self, ctx: ServerContext) -> Update:
        out = ctx.renderer.render(ctx.scene, ctx.t_s, ctx.target_pose, self.ref_intr, ("color",))
        meta = {"fov_y_deg": self.ref_intr.fov_y_deg}
        return Update(ctx.frame_id, ctx.t_s, ctx.target_pose, {"color": out.color}, meta, ctx.keyframe_requested)


class AtwClient(ClientHalf):
    config: AtwConfig

    def __init__(self, *a, **kw) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*a, **kw)
        self.ref_intr = overscan_intrinsics(self.intrinsics, self.config.overscan)
        self.canvas = Canvas(self.gl, self.intrinsics.width, self.intrinsics.height)
        self.warp = FullscreenPass(self.gl, SHADERS / "atw.frag")
        self._tex = None
        self._ref_q: np.ndarray | None = None

    def apply(self, update: DecodedUpdate) -> None:
        img = update.planes.get("color")
        if img is None:
            return
        self._tex = upload_image(self.gl, img, self._tex)
        self._ref_q = update.pose.orientation
        self._has_content = True

    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        i = self.intrinsics
        if self._tex is None or self._ref_q is None:
            return ClientFrame(np.zeros((i.height, i.width, 3), np.uint8), np.ones((i.height, i.width), bool))
        h = rotation_homography(self.ref_intr, self._ref_q, i, pose.orientation)
        p = self.warp.prog
        p["u_H"].write(np.asarray(h, "f4").T.tobytes())
        p["u_ref_size"].value = (float(self.ref_intr.width), float(self.ref_intr.height))
        p["u_out_size"].value = (float(i.width), float(i.height))
        p["u_fill_edge"].value = 1 if self.config.fill == "edge" else 0
        self._tex.use(location=0)
        p["u_ref"].value = 0
        self.canvas.use()
        self.canvas.clear()
        self.warp.run()
        color, covered = self.canvas.read()
        return ClientFrame(color, ~covered)


SPEC = register_method(MethodSpec("atw", AtwServer, AtwClient, AtwConfig, "rotational time warp of an overscanned frame"))
