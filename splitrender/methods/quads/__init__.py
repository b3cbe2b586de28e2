"""``quads``: quad streaming, QUASAR (Zhang et al.) and its QuadStream baseline (Hladky et al. 2022).

The server turns G-buffers into quad proxies, planes cut by pixel-block frustums with
depth offsets (:mod:`.gen`), merged bottom-up; QUASAR adds hidden layers by effective
depth peeling (:mod:`.edp`), a wide view and temporal compression (reference and
residual frames), QuadStream samples a cube view cell with ten views.  Quads go as
structure-of-arrays data streams (80 bits a quad before zstd, :mod:`.wire`), colour as
one video atlas with the layers side by side.  The client caches the reference quads
(:mod:`.mesh`) and draws the layered mesh at its own rate (:mod:`.client`).
"""

from __future__ import annotations

from ..base import MethodSpec, register_method
from .config import QuadParams, QuadsConfig

SPEC = register_method(MethodSpec("quads", "splitrender.methods.quads.server:QuadsServer",
                                  "splitrender.methods.quads.client:QuadsClient", QuadsConfig,
                                  "quad streaming: QUASAR (depth peeling, residual frames) or QuadStream (10 views)"))


def __getattr__(attr: str) -> object:
    if attr == "QuadsServer":
        from .server import QuadsServer

        return QuadsServer
    if attr == "QuadsClient":
        from .client import QuadsClient

        return QuadsClient
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")


__all__ = ["QuadParams", "QuadsClient", "QuadsConfig", "QuadsServer", "SPEC"]
