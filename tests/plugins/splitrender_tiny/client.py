"""``tiny``, client half: only what arrived."""

from __future__ import annotations

import numpy as np

from splitrender.methods import ClientFrame, ClientHalf, DecodedUpdate
from splitrender.scene.pose import Pose


class TinyClient(ClientHalf):
    def __init__(self, *a, **kw) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*a, **kw)
        self.thumb: np.ndarray | None = None
        self.counters: list[int] = []
        self.missing_seen = 0

    def apply(self, update: DecodedUpdate) -> None:
        if "counter" in update.data:
            self.counters.append(int.from_bytes(update.data["counter"], "little"))
        if "thumb" not in update.data:
            self.missing_seen += 1
            return
        w, h = int(self.session_data["w"]), int(self.session_data["h"])
        raw = update.data["thumb"]
        if len(raw) != w * h * 3:
            from splitrender.errors import RemoteProtocolError

            raise RemoteProtocolError(f"tiny thumb: {len(raw)} bytes, expected {w * h * 3}")
        self.thumb = np.frombuffer(raw, np.uint8).reshape(h, w, 3)
        self.has_content = True

    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        i = self.intrinsics
        if self.thumb is None:
            return ClientFrame(np.zeros((i.height, i.width, 3), np.uint8), np.ones((i.height, i.width), bool))
        f = self.config.factor  # type: ignore[attr-defined]
        big = np.repeat(np.repeat(self.thumb, f, axis=0), f, axis=1)
        out = np.zeros((i.height, i.width, 3), np.uint8)
        out[: big.shape[0], : big.shape[1]] = big[: i.height, : i.width]
        return ClientFrame(out, np.zeros((i.height, i.width), bool))
