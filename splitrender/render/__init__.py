"""Headless rendering through moderngl (EGL): contexts, shaders, the forward renderer.

Names are loaded on first use, so that a client half importing :mod:`.gl` or
:mod:`.canvas` does not import the ground-truth renderer.
"""

from __future__ import annotations

import importlib
from typing import Any

_WHERE = {"create_context": "gl", "get_context": "gl", "load_program": "gl", "make_current": "gl",
          "ALL_OUTPUTS": "renderer", "RenderOutput": "renderer", "Renderer": "renderer", "light_view_projection": "renderer"}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    mod = _WHERE.get(name)
    if mod is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{mod}"), name)
