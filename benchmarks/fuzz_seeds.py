"""Fuzzing seeds captured from real sessions: one short virtual-time run per method.

:func:`capture` runs :class:`~splitrender.sim.runner.VirtualTimeRun` (160x90 by default,
``minimal`` scene; ``default+gi`` for methods that need global illumination, ``fec = True``
so every RTP stream also sends RFC 5109 parity packets) and records what crosses the
wire in both directions, by wrapping, for the length of the run, the functions the
runner calls (the package is not changed):

- ``ServerPipeline.session_frames``: the session data blob exactly as sent (msgpack +
  zstd) and its ``DataChunk`` frames;
- ``Connection.send``: every control frame either end writes, with the message (the
  server's ``Welcome``, ``DataChunk`` and ``FrameMeta``; the client's ``Hello`` and
  ``Feedback``);
- ``ClientSession.display``: every update the client half was handed, as the pipeline
  released it (the ``FrameMeta`` with its envelope blob, the decoded planes, the
  decompressed data payloads, the streams missing);
- ``ClientSession.datagrams_to_send`` / ``ServerSession.datagrams_to_send`` (its ``rtcp``): RTCP up and down;
- ``ServerSession.frame_sent``: every RTP datagram (media and FEC) per stream, in send order.

Used by ``benchmarks/fuzz_decoders.py`` and ``tests/test_fuzz_entry_points.py``.
"""

from __future__ import annotations

import copy
import functools
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

METHODS = ("video", "atw", "warp", "sas", "tss", "quads", "probes")
WIDTH, HEIGHT = 160, 90
NETWORK = "down: delay 10ms loss 4%"
"""A little downlink loss, so the client NACKs, sends PLIs and reports lost frames, and some updates arrive partial."""


@dataclass
class CapturedUpdate:
    """One update as the client half received it (``display``'s ``ReceivedFrame``)."""

    frame_id: int
    meta_blob: bytes
    """``FrameMeta.method_meta``: the zstd-packed update envelope as sent."""
    frame_meta: Any
    """The ``FrameMeta`` message."""
    update: Any
    """The ``DecodedUpdate`` handed to ``apply`` (planes decoded, data decompressed)."""


@dataclass
class MethodSeeds:
    """Everything one method's session put on the wire (see the module docstring)."""

    method: str
    scene: str
    config: Any
    """The method config (``make_config(spec.config, {})``)."""
    intrinsics: Any
    specs: list[Any]
    """The server half's stream specs (to build a ``ServerPipeline`` / ``ServerSession``)."""
    session_blob: bytes = b""
    session_chunks: list[bytes] = field(default_factory=list)
    """``DataChunk`` frames of the session data, as framed by the server's connection."""
    welcome: Any = None
    welcome_frame: bytes = b""
    server_frames: list[tuple[Any, bytes]] = field(default_factory=list)
    """(message, framed bytes) of every server control frame after the session data (DataChunk, FrameMeta)."""
    client_frames: list[tuple[Any, bytes]] = field(default_factory=list)
    """(message, framed bytes) of every client control frame (Hello, Feedback)."""
    updates: list[CapturedUpdate] = field(default_factory=list)
    rtcp_up: list[bytes] = field(default_factory=list)
    rtcp_down: list[bytes] = field(default_factory=list)
    rtp: dict[str, list[bytes]] = field(default_factory=dict)
    """Per RTP stream, its media datagrams in send order."""
    fec: dict[str, list[bytes]] = field(default_factory=dict)
    """Per RTP stream, its FEC datagrams in send order."""

    @property
    def session_data(self) -> dict[str, Any]:
        """The session data as the client half receives it (``unpack_meta`` of the blob; ``{}`` when empty)."""
        from splitrender.codecs.meta import unpack_meta

        return unpack_meta(self.session_blob) if self.session_blob else {}

    @property
    def feedback(self) -> list[Any]:
        from splitrender.protocol import Feedback

        return [m for m, _ in self.client_frames if isinstance(m, Feedback)]


def scene_for(method: str) -> str:
    from splitrender.methods.base import get_method

    return "default+gi" if get_method(method).needs_gi else "minimal"


def _patched(cls: Any, name: str, wrapper: Any, undo: list[tuple[Any, str, Any]]) -> None:
    real = cls.__dict__[name]
    undo.append((cls, name, real))
    setattr(cls, name, wrapper(real))


def capture(method: str, duration_s: float = 0.6, width: int = WIDTH, height: int = HEIGHT,
            renderer: Any = None, scene: str | None = None, network: str = NETWORK) -> MethodSeeds:
    """Run ``method`` for ``duration_s`` of virtual time and return what its session sent."""
    from splitrender.methods.base import get_method, make_config
    from splitrender.pipeline import ClientSession, ServerPipeline, ServerSession
    from splitrender.protocol import DataChunk, FrameMeta, Welcome
    from splitrender.protocol.connection import Connection, Role
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import VirtualTimeRun

    spec = get_method(method)
    scene = scene or scene_for(method)
    cfg = RunConfig(method=method, scene=scene, trace="walk", network=network, width=width, height=height,
                    duration_s=duration_s, server_fps=30, client_fps=30, metrics=False, fec=True)
    seeds = MethodSeeds(method, scene, make_config(spec.config, {}), CameraIntrinsics(width, height, cfg.fov_y_deg), [])
    state = {"session_done": False}
    undo: list[tuple[Any, str, Any]] = []

    def session_frames(real: Any) -> Any:
        @functools.wraps(real)
        def wrap(self: Any, blob: bytes, framer: Any) -> Any:
            out = real(self, blob, framer)
            seeds.session_blob = bytes(blob)
            seeds.session_chunks = [bytes(f) for _, f in out]
            seeds.specs = list(self.specs)
            state["session_done"] = True
            return out
        return wrap

    def send(real: Any) -> Any:
        @functools.wraps(real)
        def wrap(self: Any, msg: Any, *a: Any, **kw: Any) -> bytes:
            data = real(self, msg, *a, **kw)
            if self.role is Role.SERVER:
                if isinstance(msg, Welcome):
                    seeds.welcome_frame = bytes(data)
                elif state["session_done"] and isinstance(msg, (DataChunk, FrameMeta)):
                    seeds.server_frames.append((msg, bytes(data)))
            else:
                seeds.client_frames.append((msg, bytes(data)))
            return data
        return wrap

    def display(real: Any) -> Any:
        @functools.wraps(real)
        def wrap(self: Any, tick: Any, now_ms: float, *a: Any, **kw: Any) -> Any:
            out = real(self, tick, now_ms, *a, **kw)
            for rf in out[1] or ():   # the updates a display tick applies: the client core's one way out for them
                u = rf.update
                seeds.updates.append(CapturedUpdate(u.frame_id, bytes(rf.meta.method_meta), rf.meta,
                                                    copy.deepcopy(u)))
            return out
        return wrap

    def to_send(real: Any) -> Any:
        @functools.wraps(real)
        def wrap(self: Any) -> Any:
            out = real(self)
            seeds.rtcp_up.extend(bytes(d) for d in out)
            return out
        return wrap

    def server_out(real: Any) -> Any:
        @functools.wraps(real)
        def wrap(self: Any, now_ms: float) -> Any:
            out = real(self, now_ms)
            seeds.rtcp_down.extend(bytes(d.data) for d in out if d.kind == "rtcp")
            return out
        return wrap

    def frame_sent(real: Any) -> Any:
        @functools.wraps(real)
        def wrap(self: Any, frame_id: int, out: Any, *a: Any, **kw: Any) -> Any:
            for name, _, data in out.datagrams:
                seeds.rtp.setdefault(name, []).append(bytes(data))
            for name, data in out.fec:
                seeds.fec.setdefault(name, []).append(bytes(data))
            return real(self, frame_id, out, *a, **kw)
        return wrap

    try:
        _patched(ServerPipeline, "session_frames", session_frames, undo)
        _patched(Connection, "send", send, undo)
        _patched(ClientSession, "display_tick", display, undo)
        _patched(ClientSession, "datagrams_to_send", to_send, undo)
        _patched(ServerSession, "datagrams_to_send", server_out, undo)
        _patched(ServerSession, "frame_sent", frame_sent, undo)
        vt = VirtualTimeRun(cfg, renderer=renderer)
        vt.run()
    finally:
        for cls, name, real in reversed(undo):
            setattr(cls, name, real)
    seeds.welcome = vt.clients[0].welcome
    if not seeds.updates:
        raise RuntimeError(f"capture {method}: the client was handed no update in {duration_s} s")
    return seeds


def capture_all(methods: tuple[str, ...] = METHODS, **kw: Any) -> dict[str, MethodSeeds]:
    """:func:`capture` of every method, sharing one server renderer."""
    from splitrender.render.renderer import Renderer

    renderer = kw.pop("renderer", None) or Renderer()
    return {m: capture(m, renderer=renderer, **kw) for m in methods}


if __name__ == "__main__":
    import time

    for m in sys.argv[1:] or METHODS:
        t0 = time.perf_counter()
        s = capture(m)
        print(f"{m:7s} {time.perf_counter() - t0:5.2f} s  session {len(s.session_blob)} B, {len(s.updates)} updates, "
              f"{len(s.server_frames)} server frames, {len(s.feedback)} feedback, rtcp {len(s.rtcp_up)} up "
              f"{len(s.rtcp_down)} down, rtp {({k: len(v) for k, v in s.rtp.items()})}, fec "
              f"{({k: len(v) for k, v in s.fec.items()})}, data {[sorted(u.update.data) for u in s.updates][:1]}, "
              f"planes {[sorted(u.update.planes) for u in s.updates][:1]}")
