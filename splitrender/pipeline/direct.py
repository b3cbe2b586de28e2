"""Driving a method's halves directly, without a session: benchmarks, studies and tests.

A session makes its frames through its core (:class:`~.frames.FrameOrder`, :func:`~.frames.make_frame`); a
benchmark, a study or a test that calls a server half itself builds the same
:class:`~splitrender.methods.base.ServerContext` here, and nowhere else:

- :func:`server_context`: the context of one server frame for a client whose pose is held (``pose``) or follows a
  trace or predictor (``predict``: a trace's ``pose_at``, a predictor's ``predict``), with the latency the frame is
  expected to reach the display with, the frame's id and time, and the keyframe request, feedback, shared work and
  client number a session would give it;
- :func:`still_frame`: a still frame through both halves: a fresh server half produces one update, optionally
  through the streams' real codecs (:class:`~.sender.StreamEncoder`, then the decoders and decompression a client
  runs), a fresh client half applies it and renders it at a pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from ..codecs.meta import pack_meta, unpack_meta
from ..codecs.video import VideoDecoder
from ..methods.base import ClientFeedback, ClientFrame, DecodedUpdate, ServerContext, Update, get_method
from .sender import StreamEncoder
from .wire import decompress_data


def server_context(scene: Any, renderer: Any, intrinsics: Any, pose: Any = None, *, t_s: float = 0.0, frame_id: int = 0,
                   predict: Callable[[float], Any] | None = None, latency_s: float = 0.0, keyframe: bool = False,
                   feedback: ClientFeedback | None = None, shared: Any = None, client: int = 0) -> ServerContext:
    """The :class:`~splitrender.methods.base.ServerContext` of server frame ``frame_id`` at scene time ``t_s``.

    The client's latest pose is ``pose`` (default: ``predict(t_s)``), taken at ``t_s``.  ``predict`` extrapolates
    the client's pose to any time (default: held at ``pose``).  The frame is expected to reach the display
    ``latency_s`` later: its target is the pose predicted for ``t_s + latency_s`` (``pose`` itself at zero latency).
    ``keyframe``, ``feedback``, ``shared`` (the method's shared work for the frame) and ``client`` are passed on."""
    if pose is None and predict is None:
        raise ValueError("server_context: give the client's pose, or predict to take it from (predict(t_s))")
    if not latency_s >= 0.0:
        raise ValueError(f"server_context: latency_s must be >= 0, got {latency_s!r}")
    if pose is None:
        pose = predict(t_s)   # type: ignore[misc]
    held = pose
    at = predict if predict is not None else (lambda _t: held)
    target = pose if latency_s == 0.0 else at(t_s + latency_s)
    return ServerContext(frame_id=frame_id, t_s=t_s, scene=scene, renderer=renderer, intrinsics=intrinsics,
                         latest_pose=pose, latest_pose_t_s=t_s, target_pose=target, target_t_s=t_s + latency_s,
                         predict=at, expected_latency_s=latency_s, keyframe_requested=keyframe,
                         feedback=feedback if feedback is not None else ClientFeedback(), shared=shared, client=client)


@dataclass
class StillFrame:
    """What :func:`still_frame` made: both halves (to read their stats or render again), the update as produced
    and as the client half applied it, and the client's render."""

    server: Any
    update: Update
    decoded: DecodedUpdate
    client: Any
    frame: ClientFrame | None
    """The client half's render at the view pose (None with ``render=False``)."""
    coded_bytes: dict[str, int] = field(default_factory=dict)
    """Bytes per stream after coding (video access units, compressed data); empty without ``codec``."""


def decoded_through_codecs(server: Any, update: Update) -> tuple[DecodedUpdate, dict[str, int]]:
    """``update`` as a client receives it: every plane through its stream's real encoder (an IDR, fresh encoders)
    and decoder, every data payload compressed and decompressed, the metadata packed and unpacked.  Returns it
    with the coded bytes per stream."""
    specs = server.streams()
    enc = StreamEncoder(specs).encode(update, force_idr=True)
    by_name = {s.name: s for s in specs}
    planes = {}
    for name, ef in enc.video.items():
        codec = by_name[name].codec   # type: ignore[union-attr]
        planes[name] = VideoDecoder(codec.codec, codec.input_format).decode(ef.data)
    data = {name: decompress_data(by_name[name], blob) for name, blob in enc.data.items()}   # type: ignore[arg-type]
    sizes = {**{n: len(ef.data) for n, ef in enc.video.items()}, **{n: len(b) for n, b in enc.data.items()}}
    return DecodedUpdate(update.frame_id, update.t_s, update.pose, planes, unpack_meta(pack_meta(update.meta)), data), sizes


def still_frame(method: Any, cfg: Any, intrinsics: Any, scene: Any, renderer: Any, pose: Any, t_s: float = 0.0, *,
                view: Any = None, codec: bool = False, render: bool = True, producer: Any = None, fps: int = 30,
                frame_id: int = 0) -> StillFrame:
    """One still frame of ``method`` (a name or a :class:`~splitrender.methods.base.MethodSpec`) through both halves.

    A fresh server half (``cfg``, ``intrinsics``, ``scene``, ``fps``; with ``producer``, the method's scene
    producer, whose shared work for the frame it is given) produces frame ``frame_id`` for a client held at
    ``pose`` at ``t_s`` (:func:`server_context`).  With ``codec`` the update goes through the real codecs
    (:func:`decoded_through_codecs`); without, the client half gets the planes, metadata and data as produced (the
    atlas as shaded).  A fresh client half applies it and, with ``render``, draws it at ``view`` (default ``pose``)
    and ``t_s``."""
    spec = get_method(method) if isinstance(method, str) else method
    server = spec.server_class(cfg, intrinsics, scene, fps, producer)
    shared = producer.prepare(frame_id, t_s) if producer is not None else None
    update = server.produce(server_context(scene, renderer, intrinsics, pose, t_s=t_s, frame_id=frame_id, shared=shared))
    if codec:
        decoded, sizes = decoded_through_codecs(server, update)
    else:
        decoded, sizes = DecodedUpdate(update.frame_id, update.t_s, update.pose, update.planes, update.meta,
                                       dict(update.data)), {}
    client = spec.client_class(cfg, intrinsics, renderer.ctx, server.session_data())
    client.apply(decoded)
    frame = client.render(view if view is not None else pose, t_s) if render else None
    return StillFrame(server, update, decoded, client, frame, sizes)


__all__ = ["StillFrame", "decoded_through_codecs", "server_context", "still_frame"]
