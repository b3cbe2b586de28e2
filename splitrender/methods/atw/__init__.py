"""``atw``: asynchronous time warp.  The server renders the predicted view with overscan
(a larger field of view at the same pixel density); the client re-projects the newest
frame rotationally to its current orientation with a homography, in a shader.  Position
changes are ignored (that is what ATW cannot fix); pixels the overscan does not cover
are holes, filled with the nearest edge texel or black."""

from __future__ import annotations

from ..base import MethodSpec, register_method
from .config import SHADERS, AtwConfig, overscan_intrinsics, pixel_projection, rotation_homography

SPEC = register_method(MethodSpec("atw", "splitrender.methods.atw.server:AtwServer",
                                  "splitrender.methods.atw.client:AtwClient", AtwConfig, "rotational time warp of an overscanned frame",
                                  page="splitrender.methods.atw.page:AtwPage"))


def __getattr__(attr: str) -> object:
    """The halves, loaded on first use (importing the client never imports the server)."""
    if attr == "AtwServer":
        from .server import AtwServer

        return AtwServer
    if attr == "AtwClient":
        from .client import AtwClient

        return AtwClient
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")


__all__ = ["SHADERS", "SPEC", "AtwClient", "AtwConfig", "AtwServer", "overscan_intrinsics", "pixel_projection",
           "rotation_homography"]
