"""``tss``: tessellated shading streaming (Hladky, Seidel and Steinberger 2019).

The server shades each potentially visible triangle in the tessellation stage, writing
its samples straight into a per-triangle atlas layout (L-packing for ordinary
triangles, oversampling for slanted ones) with no rasteriser; the client draws the
PVS triangles and finds each fragment's sample from the triangle's layout.  Modules:
:mod:`.layout` (sample patterns and atlas layout, sections 3.1-3.3, in numpy),
:mod:`.server` (PVS, split, layout, gathering; shaders in ``shaders/``),
:mod:`.client`, sharing :mod:`.wire` and :mod:`.config`.  The PVS pass is ``sas``'s
at triangle granularity.  The halves load on first use.
"""

from __future__ import annotations

from ..base import MethodSpec, register_method
from .config import TssConfig

SPEC = register_method(MethodSpec("tss", "splitrender.methods.tss.server:TssServer", "splitrender.methods.tss.client:TssClient",
                                  TssConfig, "tessellated shading streaming: per-triangle samples gathered in the tessellator",
                                  producer="splitrender.methods.tss.server:TssProducer"))


def __getattr__(attr: str) -> object:
    """The halves, loaded on first use."""
    if attr in ("TssServer", "TssProducer"):
        from . import server

        return getattr(server, attr)
    if attr == "TssClient":
        from .client import TssClient

        return TssClient
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")


__all__ = ["SPEC", "TssClient", "TssConfig", "TssProducer", "TssServer"]
