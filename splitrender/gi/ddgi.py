"""The DDGI probes' old home: they are the renderer's, in :mod:`splitrender.render.ddgi`.

Every :class:`~splitrender.render.renderer.Renderer` shades a scene that sets ``gi = "ddgi"`` with them,
so they sit in ``render`` beside their shaders, and ``render`` imports nothing from this package (no
package-level import circle).  These names stay importable from here for the ``probes`` method and the
tests until they import them from ``render``.
"""

from __future__ import annotations

from ..render.ddgi import (BACKFACE_INACTIVE, BITS_PER_TEXEL, GI_UNITS, IRR_CORE, IRR_TILE, MOVING_MIN_RAYS, NEAR_M,
                           SHARPNESS, VIS_CORE, VIS_TILE, DdgiSettings, DdgiVolume, ProbeCopy, ProbeStates, atlas_tiles,
                           bind_probes, face_projection, face_view, gi_time, irradiance_atlas, probe_atlas, probe_grid,
                           slot_grid)

__all__ = ["BACKFACE_INACTIVE", "BITS_PER_TEXEL", "GI_UNITS", "IRR_CORE", "IRR_TILE", "MOVING_MIN_RAYS", "NEAR_M",
           "SHARPNESS", "VIS_CORE", "VIS_TILE", "DdgiSettings", "DdgiVolume", "ProbeCopy", "ProbeStates", "atlas_tiles",
           "bind_probes", "face_projection", "face_view", "gi_time", "irradiance_atlas", "probe_atlas", "probe_grid",
           "slot_grid"]
