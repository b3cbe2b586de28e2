"""Headless OpenGL contexts (EGL) and shader loading from ``.glsl`` files.

One thread owns a context: :func:`get_context` hands out one context per thread.
Shaders may ``#include "file.glsl"``; includes are resolved relative to the
including file's directory, then to ``splitrender/render/shaders``.
"""

from __future__ import annotations

import logging
import re
import threading
from pathlib import Path
from typing import Any, Sequence

from ..errors import RenderError

log = logging.getLogger(__name__)

SHADER_DIR = Path(__file__).parent / "shaders"
MIN_GL_VERSION = 430
_local = threading.local()
_INCLUDE = re.compile(r'^\s*#include\s+"([^"]+)"\s*$', re.M)


def create_context() -> Any:
    """A new standalone moderngl context through EGL (OpenGL >= 4.3 core).

    Raises :class:`RenderError` with what to install when none can be made.
    """
    try:
        import moderngl
    except ImportError as exc:  # pragma: no cover - dependency missing
        raise RenderError(f"moderngl is not installed: {exc}") from exc
    try:
        ctx = moderngl.create_context(standalone=True, backend="egl", require=MIN_GL_VERSION)
    except Exception as exc:
        raise RenderError(
            "could not create a headless OpenGL 4.3 context through EGL "
            f"({type(exc).__name__}: {exc}); install libegl1, libegl-mesa0 and libgl1-mesa-dri "
            "(Mesa llvmpipe works without a GPU)"
        ) from exc
    log.debug("GL context: %s / %s", ctx.info.get("GL_RENDERER"), ctx.info.get("GL_VERSION"))
    return ctx


def make_current(ctx: Any) -> Any:
    """Make ``ctx`` the calling thread's current GL context and return it.

    moderngl sends every call to whichever context is current, so a thread that holds
    several contexts (the virtual-time runner: the server's and one per client) must
    switch before each use.  Nested ``with ctx:`` blocks do not restore the outer
    context on exit; this plain switch is what the runner uses instead.
    """
    ctx.__enter__()
    return ctx


def get_context() -> Any:
    """The calling thread's shared context, created on first use, made current."""
    ctx = getattr(_local, "ctx", None)
    if ctx is None:
        ctx = create_context()
        _local.ctx = ctx
    return make_current(ctx)


def read_shader(path: str | Path, _seen: frozenset[Path] = frozenset()) -> str:
    """Read a shader file and resolve ``#include "x.glsl"`` lines (once each, no cycles)."""
    p = Path(path)
    if not p.is_absolute() and not p.exists():
        p = SHADER_DIR / p
    p = p.resolve()
    if p in _seen:
        raise RenderError(f"shader include cycle at {p}")
    try:
        src = p.read_text()
    except OSError as exc:
        raise RenderError(f"cannot read shader {p}: {exc}") from exc

    def sub(m: re.Match[str]) -> str:
        name = m.group(1)
        cand = p.parent / name
        if not cand.exists():
            cand = SHADER_DIR / name
        return read_shader(cand, _seen | {p})

    return _INCLUDE.sub(sub, src)


def load_program(ctx: Any, vertex: str | Path, fragment: str | Path | None = None, geometry: str | Path | None = None,
                 defines: dict[str, Any] | None = None, **kw: Any) -> Any:
    """Compile a program from shader files; ``defines`` become ``#define`` lines after ``#version``."""

    def prep(path: str | Path) -> str:
        src = read_shader(path)
        if defines:
            lines = src.split("\n", 1)
            extra = "".join(f"#define {k} {v}\n" for k, v in defines.items())
            src = lines[0] + "\n" + extra + (lines[1] if len(lines) > 1 else "")
        return src

    try:
        return ctx.program(
            vertex_shader=prep(vertex),
            fragment_shader=prep(fragment) if fragment else None,
            geometry_shader=prep(geometry) if geometry else None,
            **kw,
        )
    except Exception as exc:
        raise RenderError(f"shader program {Path(str(vertex)).name}/{Path(str(fragment)).name if fragment else '-'} failed to build: {exc}") from exc


def grow_vertex_buffer(ctx: Any, prog: Any, vbo: Any, vao: Any, nbytes: int, layout: str, names: Sequence[str],
                       minimum: int = 0) -> tuple[Any, Any]:
    """A persistent vertex buffer (and its vertex array on ``prog``) of at least ``nbytes``.

    Returns ``(vbo, vao)`` unchanged while they are large enough; otherwise releases them
    and makes new ones of ``max(nbytes, minimum, twice the old size)`` bytes (doubling, so
    a growing set reallocates rarely).  ``layout``/``names`` as in
    ``ctx.vertex_array(prog, [(vbo, layout, *names)])``.
    """
    if vbo is not None and vbo.size >= nbytes:
        return vbo, vao
    old = 0
    if vbo is not None:
        old = vbo.size
        vao.release()
        vbo.release()
    vbo = ctx.buffer(reserve=max(nbytes, minimum, 2 * old, 1))
    return vbo, ctx.vertex_array(prog, [(vbo, layout, *names)])


def runs(values: Any) -> list[tuple[int, int]]:
    """``(start, end)`` of each run of equal consecutive values (e.g. the triangles of one object in a sorted list)."""
    import numpy as np

    v = np.asarray(values)
    if v.size == 0:
        return []
    b = (np.flatnonzero(v[1:] != v[:-1]) + 1).tolist()
    return list(zip([0] + b, b + [int(v.size)]))


def has_uniform(prog: Any, name: str) -> bool:
    """Whether the program uses uniform ``name`` (the GLSL compiler drops unused ones).  A lookup: moderngl's Program
    has no ``__contains__``, so ``name in prog`` walks every member (20-40 ms of CPU a frame on sas's default walk,
    where ``Renderer.bind_material`` sets about 25 uniforms per object)."""
    return prog.get(name, None) is not None


def set_uniform(prog: Any, name: str, value: Any) -> None:
    """Set a uniform if the program uses it (the GLSL compiler drops unused ones)."""
    member = prog.get(name, None)
    if member is not None:
        member.value = value


def set_reference_view(prog: Any, intrinsics: Any, pose: Any) -> None:
    """``u_view_proj`` (projection times view) and ``u_viewport`` (display pixels) of the view ``pose`` seen through
    ``intrinsics``, where the program uses them: the object-space shading stages take their texture gradients
    from it."""
    if has_uniform(prog, "u_view_proj"):
        import numpy as np

        vp = intrinsics.projection() @ pose.view_matrix()
        prog["u_view_proj"].write(np.asarray(vp, "f4").T.tobytes())
    set_uniform(prog, "u_viewport", (float(intrinsics.width), float(intrinsics.height)))
