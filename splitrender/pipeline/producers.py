"""Scene producers shared by every session of a method on one server.

:class:`ProducerPool` holds one :class:`~splitrender.methods.base.SceneProducer` per
method and runs its per-frame work once per server frame: the first session to ask
for frame ``k`` pays for it, the others reuse the result.  Costs are kept apart from
the per-client costs (``shared_ms``).
"""

from __future__ import annotations

import time
from typing import Any

from ..codecs.meta import pack_meta
from ..methods.base import MethodConfig, MethodSpec, SceneProducer, get_method


class ProducerPool:
    """Producers by method name, with the newest frame's shared result memoised."""

    def __init__(self, scene: Any, server_fps: int, renderer: Any = None) -> None:
        self.scene = scene
        self.server_fps = server_fps
        self.renderer = renderer
        self._producers: dict[str, SceneProducer] = {}
        self._frames: dict[str, tuple[int, Any]] = {}
        self.shared_ms: dict[str, float] = {}
        """Milliseconds of shared work spent on the newest frame, per method."""
        self.build_ms: dict[str, float] = {}
        self.frames_prepared: dict[str, int] = {}

    def producer(self, spec: MethodSpec, config: MethodConfig) -> SceneProducer | None:
        """The method's producer (built on first use, on the caller's GL thread), or ``None``."""
        cls = spec.producer_class
        if cls is None:
            return None
        p = self._producers.get(spec.name)
        if p is None:
            w0 = time.perf_counter()
            p = self._producers[spec.name] = cls(config, self.scene, self.server_fps, self.renderer)
            self.build_ms[spec.name] = (time.perf_counter() - w0) * 1000
        return p

    def server_half(self, opening: Any) -> tuple[Any, list[Any], bytes]:
        """The server half of a session's ``opening`` (:class:`~.session.Opening`), built on the caller's GL thread
        with the method's shared producer, for every front door's handshake (:func:`~.session.accept_hello`): the
        half, the streams it declares and its packed session data."""
        spec, config = get_method(opening.method), opening.config
        half = spec.server_class(config, opening.intrinsics, self.scene, self.server_fps,
                                 producer=self.producer(spec, config))
        return half, half.streams(), pack_meta(half.session_data())

    def stats(self, name: str) -> dict[str, Any]:
        """Method ``name``'s producer's statistics for its newest frame (empty without a producer)."""
        p = self._producers.get(name)
        return p.stats() if p is not None else {}

    def prepare(self, name: str, frame_id: int, t_s: float) -> Any:
        """Shared state of frame ``frame_id`` for method ``name`` (computed once per frame)."""
        p = self._producers.get(name)
        if p is None:
            return None
        cached = self._frames.get(name)
        if cached is not None and cached[0] == frame_id:
            return cached[1]
        w0 = time.perf_counter()
        out = p.prepare(frame_id, t_s)
        self.shared_ms[name] = (time.perf_counter() - w0) * 1000
        self.frames_prepared[name] = self.frames_prepared.get(name, 0) + 1
        self._frames[name] = (frame_id, out)
        return out
