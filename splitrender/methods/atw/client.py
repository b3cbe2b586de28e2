"""``atw``, client half: sees only what arrived."""

from __future__ import annotations

import numpy as np

from ...render.canvas import Canvas, FullscreenPass, upload_image
from ...scene.pose import Pose
from ..base import ClientFrame, ClientHalf, DecodedUpdate
from .config import SHADERS, AtwConfig, overscan_intrinsics, rotation_homography


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
        self.has_content = True

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
