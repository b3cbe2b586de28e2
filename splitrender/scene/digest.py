"""Content digests: SHA-256 of everything in a scene that can change a rendered pixel.

The ground-truth cache (:mod:`splitrender.sim.truth`) keys frames on them, and the
renderer's DDGI probes (:mod:`splitrender.render.ddgi`) key relit probe states on them, so
two scene objects built alike (one per run) share what was computed for either.

- every mesh array, material (texture pixels included), transform, animation
  parameter, light and colour of the :class:`~splitrender.scene.model.Scene`;
- a plain function inside a scene counts by its qualified name only.
"""

from __future__ import annotations

import dataclasses
import hashlib
from typing import Any

import numpy as np

from .model import Scene


def feed(h: Any, obj: Any, depth: int = 0) -> None:
    """Feed ``obj`` (arrays, numbers, strings, containers, dataclasses, objects) into the hash ``h``."""
    if depth > 32:
        raise ValueError("content digest: object nesting too deep to hash")
    if obj is None:
        h.update(b"N")
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(b"A" + str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    elif isinstance(obj, (bool, int, float, str, bytes)):
        h.update(type(obj).__name__.encode() + b":" + repr(obj).encode() + b";")
    elif isinstance(obj, (np.integer, np.floating)):
        feed(h, obj.item(), depth + 1)
    elif isinstance(obj, (list, tuple)):
        h.update(b"L%d" % len(obj))
        for x in obj:
            feed(h, x, depth + 1)
    elif isinstance(obj, dict):
        h.update(b"D%d" % len(obj))
        for k in sorted(obj, key=repr):
            feed(h, k, depth + 1)
            feed(h, obj[k], depth + 1)
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        h.update(b"C" + type(obj).__qualname__.encode())
        for f in dataclasses.fields(obj):
            h.update(f.name.encode())
            feed(h, getattr(obj, f.name), depth + 1)
    elif callable(obj):
        h.update(b"F" + getattr(obj, "__module__", "?").encode() + getattr(obj, "__qualname__", repr(type(obj))).encode())
    elif hasattr(obj, "__dict__"):
        h.update(b"O" + type(obj).__qualname__.encode())
        feed(h, vars(obj), depth + 1)
    else:
        h.update(b"R" + repr(obj).encode())


def scene_digest(scene: Scene) -> str:
    """SHA-256 of everything in ``scene`` that can change a rendered pixel."""
    h = hashlib.sha256()
    feed(h, scene)
    return h.hexdigest()
