"""``sas``: shading atlas streaming (Mueller et al. 2018).

The server shades the potentially visible patches into a temporally coherent atlas
and streams it as video with geometry and atlas coordinates as metadata; the client
draws the PVS geometry textured from the atlas at its own pose.  Modules, in paper
order: :mod:`.patches` (section 3.1, fig. 4), :mod:`.pvs` (3.1, 5.1),
:mod:`.levels` (4.3, eq. 1-3), :mod:`.allocator` (4.1-4.2, 5.4),
:mod:`.server` (with the scene-level :class:`~.server.SasProducer` shared by every
session) and :mod:`.client`, which share only :mod:`.wire` and :mod:`.config`.
The halves are loaded on first use: importing the client never imports the server.
"""

from __future__ import annotations

from ..base import MethodSpec, register_method
from .allocator import AtlasLayout, PatchAllocator
from .config import SasConfig

SPEC = register_method(MethodSpec("sas", "splitrender.methods.sas.server:SasServer", "splitrender.methods.sas.client:SasClient",
                                  SasConfig, "shading atlas streaming: shaded PVS patches in a video atlas",
                                  producer="splitrender.methods.sas.server:SasProducer", page="splitrender.methods.sas.page:SasPage"))


def __getattr__(attr: str) -> object:
    """The halves, loaded on first use."""
    if attr in ("SasServer", "SasProducer"):
        from . import server

        return getattr(server, attr)
    if attr == "SasClient":
        from .client import SasClient

        return SasClient
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")


__all__ = ["AtlasLayout", "PatchAllocator", "SasClient", "SasConfig", "SasProducer", "SasServer", "SPEC"]
