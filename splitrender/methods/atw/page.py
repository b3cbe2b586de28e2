"""``atw``'s page glue (its :attr:`~splitrender.methods.base.MethodSpec.page`): the page warps the newest frame
itself, so it needs the reference frame's field of view (the overscan) and the fill rule for what falls outside."""

from __future__ import annotations

from typing import Any

from ..base import PageGlue
from .config import overscan_intrinsics


class AtwPage(PageGlue):
    def terms(self) -> dict[str, Any]:
        return {"ref_fov_y_deg": overscan_intrinsics(self.intrinsics, float(self.config.overscan)).fov_y_deg,
                "fill": self.config.fill}
