"""Client-side GL helpers: an offscreen canvas, image textures, a fullscreen pass.

Image convention: numpy images have row 0 at the top.  Textures are uploaded row by
row as they are, so texture coordinate ``v = 0`` is the image's top row; shaders that
work in pixel units use a top-left origin (``y_top = height - gl_FragCoord.y``), and
:meth:`Canvas.read` flips back, so what a shader writes at ``y_top`` lands in row
``y_top`` of the returned array.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .gl import SHADER_DIR, load_program


class Canvas:
    """An offscreen RGBA8 framebuffer with a depth buffer."""

    def __init__(self, ctx: Any, width: int, height: int) -> None:
        self.ctx, self.width, self.height = ctx, width, height
        self.color = ctx.texture((width, height), 4, dtype="f1")
        self.depth = ctx.depth_renderbuffer((width, height))
        self.fbo = ctx.framebuffer([self.color], self.depth)

    def use(self) -> None:
        self.fbo.use()
        self.ctx.viewport = (0, 0, self.width, self.height)

    def clear(self, rgba: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)) -> None:
        self.fbo.clear(*rgba, depth=1.0)

    def read_rgba(self) -> np.ndarray:
        return np.frombuffer(self.fbo.read(components=4), np.uint8).reshape(self.height, self.width, 4)[::-1].copy()

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """(colour (H, W, 3) uint8, coverage (H, W) bool from alpha > 0)."""
        rgba = self.read_rgba()
        return rgba[..., :3].copy(), rgba[..., 3] > 0

    def release(self) -> None:
        self.fbo.release()
        self.color.release()
        self.depth.release()


def upload_image(ctx: Any, img: np.ndarray, tex: Any | None = None, linear: bool = True) -> Any:
    """Upload an (H, W, 3|4) uint8 or (H, W) float32 image; reuses ``tex`` when the size matches."""
    import moderngl

    img = np.ascontiguousarray(img)
    h, w = img.shape[:2]
    comps = 1 if img.ndim == 2 else img.shape[2]
    dtype = {np.dtype(np.uint8): "f1", np.dtype(np.float32): "f4", np.dtype(np.uint16): "u2", np.dtype(np.uint32): "u4"}[img.dtype]
    if tex is None or tex.size != (w, h) or tex.components != comps or tex.dtype != dtype:
        if tex is not None:
            tex.release()
        tex = ctx.texture((w, h), comps, dtype=dtype)
    tex.write(img.tobytes())
    if dtype in ("f1", "f4") and linear:
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
    else:
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
    tex.repeat_x = tex.repeat_y = False
    return tex


class FullscreenPass:
    """Runs a fragment shader over every pixel of the bound framebuffer."""

    def __init__(self, ctx: Any, fragment: str, defines: dict[str, Any] | None = None) -> None:
        self.ctx = ctx
        self.prog = load_program(ctx, SHADER_DIR / "fullscreen.vert", fragment, defines=defines)
        self.vao = ctx.vertex_array(self.prog, [])

    def run(self) -> None:
        self.ctx.disable(self.ctx.DEPTH_TEST)
        self.vao.render(mode=self.ctx.TRIANGLES, vertices=3)
