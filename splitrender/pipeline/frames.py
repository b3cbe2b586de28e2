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

On the client, :func:`display_frame` is every front door's side of a display tick: the updates applied to the client
half and the half rendered (the core's :meth:`~.session.ClientSession.display_tick` and
:meth:`~.session.ClientSession.showing` are the tick's rule before and after it).

A :class:`FrameOrder` pickles (the live server sends it to its worker); its ``predictor`` is a copy taken then, so
a pose arriving while the worker renders does not move the frame's predictions.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from ..errors import RemoteProtocolError
from ..methods.base import ClientFeedback, ClientFrame, ServerContext
from .adapt import AdaptConfig
from .producers import ProducerPool
from .receiver import ClientPipeline
from .sender import EncodedUpdate, StreamEncoder

log = logging.getLogger(__name__)


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


class SessionFrames:
    """The frame makers a render worker holds (:mod:`splitrender.server.worker`, in its own process): scene
    ``scene_name``, its renderer (live GI relit at ``gi_hz``; its shaders compiled at once) and the scene producers,
    shared by the sessions it serves, and each session's :class:`FrameMaker`, by session id."""

    def __init__(self, scene_name: str, server_fps: int, gi_hz: float = 0.0) -> None:
        from ..render import Renderer             # GL and the scene's files: where the frames are made only
        from ..scene.loader import get_scene
        from ..scene.pose import CameraIntrinsics, Pose

        self.scene = get_scene(scene_name)
        self.server_fps = server_fps
        self.renderer = Renderer()
        self.renderer.gi_hz = gi_hz
        self.renderer.render(self.scene, 0.0, Pose(), CameraIntrinsics(64, 36), ("color",))   # compile shaders now
        self.producers = ProducerPool(self.scene, server_fps, self.renderer)
        self.makers: dict[str, FrameMaker] = {}

    def open(self, sid: str, opening: Any) -> tuple[list[Any], bytes, dict[str, Any]]:
        """Build session ``sid``'s server half of ``opening`` (:class:`~.session.Opening`) and its encoders; returns its
        stream specs, session data and the parameter sets each video encoder sends (for the SDP)."""
        maker = self.makers[sid] = FrameMaker(opening, self.producers)
        return maker.specs, maker.session_blob, maker.encoder.described_sets()

    def frame(self, sid: str, order: FrameOrder) -> tuple[EncodedUpdate, dict[str, Any], dict[str, float]]:
        """Make session ``sid``'s frame ``order`` (:meth:`FrameMaker.make`) for another process: the coded update
        without its raw planes (they stay here), the half's stats, and the frame's stages in milliseconds
        (``frame_ms`` is the whole frame in this process)."""
        enc, stats, stages = self.makers[sid].make(order)
        enc.update = replace(enc.update, planes={}, data={})
        return enc, stats, stages

    def close(self, sid: str) -> None:
        self.makers.pop(sid, None)


# ---------------------------------------------------------------------- the client's side of a display tick

def apply_updates(half: Any, frames: list[Any], log_id: str = "") -> list[bool]:
    """Apply ``frames`` (:class:`~.receiver.ReceivedFrame`) to the client half ``half`` in order (on the thread that
    owns its GL context): a malformed update is rejected (logged, prefixed ``log_id``) and the half keeps its last good
    state.  Returns which were applied, for :meth:`~.session.ClientSession.showing`."""
    ok = []
    for rf in frames:
        try:
            half.apply(rf.update)
            ok.append(True)
        except RemoteProtocolError as exc:
            ok.append(False)
            log.warning("%s: update %d rejected by the client half: %s", log_id, rf.update.frame_id, exc)
    return ok


def black_frame(width: int, height: int) -> ClientFrame:
    """The black background a display tick shows with nothing to draw, every pixel a hole."""
    return ClientFrame(np.zeros((height, width, 3), np.uint8), np.ones((height, width), bool))


def decode_work(work: Any) -> tuple[Any, float]:
    """Every client front door's decode of what its core released (:meth:`~.session.ClientSession.work_to_decode`,
    after :meth:`~.session.ClientSession.skips_decode`), where it runs it (in line, or on the live client's decoder
    thread): the pipeline's answer (:meth:`~.receiver.ClientPipeline.decode`: the plane or bytes, or the
    :class:`~splitrender.errors.CodecError`) and the milliseconds it took, for
    :meth:`~.session.ClientSession.on_decoded`."""
    w0 = time.perf_counter()
    res = ClientPipeline.decode(work)
    return res, (time.perf_counter() - w0) * 1000


class Displayed(NamedTuple):
    """A display tick's client-half side (:func:`display_frame`): the frame drawn, which updates were applied (for
    :meth:`~.session.ClientSession.showing`), and the apply and render milliseconds."""

    frame: ClientFrame
    ok: list[bool]
    apply_ms: float
    render_ms: float

    @property
    def client_ms(self) -> float:
        """The tick's client milliseconds (a frame row's ``client_ms``): applying and rendering."""
        return self.apply_ms + self.render_ms

    @property
    def columns(self) -> dict[str, Any]:
        """The client half's stats as a frame row's ``cli_<stat>`` columns (every client front door's)."""
        return {f"cli_{k}": v for k, v in self.frame.stats.items()}


def display_frame(half: Any, frames: list[Any], pose: Any, t_s: float, size: tuple[int, int],
                  log_id: str = "") -> Displayed:
    """The client half's side of a display tick, in every client front door (on the thread that owns its GL context):
    the updates the core gave the tick (``frames``: :meth:`~.session.ClientSession.display_tick`) applied
    (:func:`apply_updates`), then the half rendered at ``pose`` and scene time ``t_s``, or the black background of
    ``size`` (width, height) where it has nothing to draw.  Returns the frame, which updates were applied (for
    :meth:`~.session.ClientSession.showing`, the tick's rule), and the apply and render milliseconds."""
    w0 = time.perf_counter()
    ok = apply_updates(half, frames, log_id)
    w1 = time.perf_counter()
    frame = half.render(pose, t_s) if half.has_content else black_frame(*size)
    return Displayed(frame, ok, (w1 - w0) * 1000, (time.perf_counter() - w1) * 1000)
