"""Headless rendering through moderngl (EGL): contexts, shaders, the forward renderer."""

from .gl import create_context, get_context, load_program
from .renderer import ALL_OUTPUTS, Renderer, RenderOutput, light_view_projection

__all__ = ["ALL_OUTPUTS", "RenderOutput", "Renderer", "create_context", "get_context", "light_view_projection", "load_program"]
