"""``sas``: shading atlas streaming (Mueller et al. 2018).

The server shades the potentially visible patches into a temporally coherent atlas
and streams it as video with geometry and atlas coordinates as metadata; the client
draws the PVS geometry textured from the atlas at its own pose.  Modules, in paper
order: :mod:`.patches` (section 3.1, fig. 4), :mod:`.pvs` (3.1, 5.1),
:mod:`.levels` (4.3, eq. 1-3), :mod:`.allocator` (4.1-4.2, 5.4),
:mod:`.server` and :mod:`.client`, which share only :mod:`.wire`.
"""

from __future__ import annotations

from ..base import MethodSpec, register_method
from .allocator import AtlasLayout, PatchAllocator
from .client import SasClient
from .server import SasConfig, SasProducer, SasServer

SPEC = register_method(MethodSpec("sas", SasServer, SasClient, SasConfig, "shading atlas streaming: shaded PVS patches in a video atlas",
                                  producer=SasProducer))

__all__ = ["AtlasLayout", "PatchAllocator", "SasClient", "SasConfig", "SasServer", "SPEC"]
