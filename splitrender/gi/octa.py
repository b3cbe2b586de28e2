"""The octahedral maps' old home: they are the renderer's DDGI probes', in :mod:`splitrender.render.octa`.

These names stay importable from here for the ``probes`` method and the tests until they import them from
``render`` (which imports nothing from this package).
"""

from __future__ import annotations

from ..render.octa import (CUBE_FACES, add_guard, cube_directions, irradiance_weights, oct_decode, oct_encode,
                           texel_directions, visibility_weights)

__all__ = ["CUBE_FACES", "add_guard", "cube_directions", "irradiance_weights", "oct_decode", "oct_encode",
           "texel_directions", "visibility_weights"]
