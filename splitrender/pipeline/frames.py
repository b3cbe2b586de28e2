"""One frame, ordered and made: the server core's :class:`FrameOrder` and the one :func:`make_frame`.

Every front door makes a server frame in the same two steps:

1. the session core decides what the frame must be (:meth:`.session.ServerSession.order_frame`): whether it is a
   keyframe, the operating point and encoder rates rate adaptation chose, the latency it is expected to reach the
   display with, and from that the pose and time to render for; the answer is a :class:`FrameOrder` (or ``None``
   where the operating point leaves the tick out);
2. :func:`make_frame` runs the order where the GL context lives (the virtual-time runner's thread, the live
   server's render worker): the method's shared work for the tick (:class:`~.producers.ProducerPool`), the server
   half's :meth:`~splitrender.methods.base.ServerHalf.produce` and the encoders (:class:`~.sender.StreamEncoder`).
   :class:`FrameMaker` holds a session's half and encoders there, opened together, and makes its frames.

A :class:`FrameOrder` pickles (the live server sends it to its worker); its ``predictor`` is a copy taken then, so
a pose arriving while the worker renders does not move the frame's predictions.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from ..methods.base import ClientFeedback, ServerContext
from .adapt import AdaptConfig
from .sender import EncodedUpdate, StreamEncoder


@dataclass
class FrameOrder:
    """What the session core orders for one server frame.

    Times: ``t_s`` is the frame's scene time; ``latest_pose_t_s`` and ``target_t_s`` are on the scene clock too
    (the driver's clock less ``epoch_s``, the driver time of scene time 0), while ``predictor`` runs on the driver's
    clock (:meth:`predict` converts)."""

    frame_id: int
    tick: int
    """The server tick on the shared grid (the key of the producers' shared work)."""
    t_s: float
    keyframe: bool
    expected_latency_s: float
    latest_pose: Any
    latest_pose_t_s: float
    pose_us: int
    """The client's timestamp (µs) and sequence number of the latest pose, as ``FrameMeta.pose`` echoes them."""
    pose_seq: int
    target_pose: Any
    target_t_s: float
    predictor: Any
    epoch_s: float = 0.0
    feedback: ClientFeedback = field(default_factory=ClientFeedback)
    point: dict[str, Any] | None = None
    """The operating point ``adapt = "full"`` chose (the half's knobs and ``scale``), or None."""
    rates_kbps: dict[str, float] | None = None
    """Each lossy video stream's encoder rate (``adapt = "rate"`` or ``"full"``), or None."""
    adapt: AdaptConfig | None = None
    client: int = 0

    @property
    def scale(self) -> float | None:
        return self.point.get("scale") if self.point else None

    def predict(self, t_s: float) -> Any:
        """The client's pose predicted for scene time ``t_s``."""
        return self.predictor.predict(t_s + self.epoch_s)

    def context(self, scene: Any, renderer: Any, intrinsics: Any, shared: Any = None) -> ServerContext:
        """The server half's :class:`~splitrender.methods.base.ServerContext` for this order."""
        return ServerContext(frame_id=self.frame_id, t_s=self.t_s, scene=scene, renderer=renderer, intrinsics=intrinsics,
                             latest_pose=self.latest_pose, latest_pose_t_s=self.latest_pose_t_s,
                             target_pose=self.target_pose, target_t_s=self.target_t_s, predict=self.predict,
                             expected_latency_s=self.expected_latency_s, keyframe_requested=self.keyframe,
                             feedback=self.feedback, shared=shared, client=self.client)


def make_frame(order: FrameOrder, half: Any, encoder: StreamEncoder, scene: Any, renderer: Any, intrinsics: Any,
               pool: Any = None, method: str = "") -> tuple[EncodedUpdate, dict[str, Any], dict[str, float]]:
    """Render and encode ``order``: the method's shared work for its tick (``pool``'s, once per tick for every
    session of ``method``), the half's own (with the operating point's knobs set first), the encoders'.  Call on the
    thread that owns ``renderer``'s GL context.

    Returns the coded update, the half's stats, and the stages in milliseconds: ``shared_ms`` (this call's share of
    the tick's shared work: 0 where another session paid for it), ``produce_ms``, ``gi_ms`` (the probes' relighting
    within those two), ``encode_ms`` and ``frame_ms`` (the whole call)."""
    gi0 = getattr(renderer, "gi_ms", 0.0)
    w0 = time.perf_counter()
    shared = pool.prepare(method, order.tick, order.t_s) if pool is not None else None
    w1 = time.perf_counter()
    if order.point is not None:
        half.set_knobs(order.point)
    upd = half.produce(order.context(scene, renderer, intrinsics, shared))
    w2 = time.perf_counter()
    enc = encoder.encode(upd, bool(upd.force_idr or order.keyframe), order.rates_kbps, order.adapt, order.scale)
    w3 = time.perf_counter()
    stages = {"shared_ms": (w1 - w0) * 1e3, "produce_ms": (w2 - w1) * 1e3,
              "gi_ms": getattr(renderer, "gi_ms", 0.0) - gi0, "encode_ms": enc.encode_ms, "frame_ms": (w3 - w0) * 1e3}
    return enc, half.stats(), stages


class FrameMaker:
    """One session's frame producer where the GL context lives (the runner's thread, a render worker): the server
    half of ``opening`` (:class:`~.session.Opening`) built with ``pool``'s shared producer, and the encoders of the
    streams it declares, opened now so that their parameter sets are known for the SDP.  The session core holds the
    other half of the sending side (:class:`~.sender.ServerPipeline`: packetizing)."""

    def __init__(self, opening: Any, pool: Any) -> None:
        self.method = opening.method
        self.intrinsics = opening.intrinsics
        self.pool = pool
        self.half, self.specs, self.session_blob = pool.server_half(opening)
        self.encoder = StreamEncoder(self.specs)
        self.encoder.open()

    def make(self, order: FrameOrder) -> tuple[EncodedUpdate, dict[str, Any], dict[str, float]]:
        """Make and encode ``order`` (:func:`make_frame`)."""
        return make_frame(order, self.half, self.encoder, self.pool.scene, self.pool.renderer, self.intrinsics,
                          self.pool, self.method)
