"""``video``, client half: sees only what arrived."""

from __future__ import annotations

import numpy as np

from ...errors import RemoteProtocolError
from ...scene.pose import Pose
from ..base import ClientFrame, ClientHalf, DecodedUpdate


class VideoFrameError(RemoteProtocolError):
    """A decoded colour frame that is not the size of this client's display."""


class VideoClient(ClientHalf):
    def __init__(self, *a, **kw) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*a, **kw)
        self._frame: np.ndarray | None = None

    def apply(self, update: DecodedUpdate) -> None:
        if "color" in update.planes:
            frame = update.planes["color"]
            i = self.intrinsics
            if getattr(frame, "shape", None) != (i.height, i.width, 3):
                raise VideoFrameError(f"video: frame {update.frame_id}: colour plane of shape {getattr(frame, 'shape', None)}, "
                                      f"this client displays {i.width}x{i.height} (expected ({i.height}, {i.width}, 3))")
            self._frame = frame
            self.has_content = True

    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        i = self.intrinsics
        if self._frame is None:
            return ClientFrame(np.zeros((i.height, i.width, 3), np.uint8), np.ones((i.height, i.width), bool))
        return ClientFrame(self._frame, np.zeros((i.height, i.width), bool))
