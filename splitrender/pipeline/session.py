"""Sans-IO session cores: everything a session decides, for both clocks (the aioquic shape).

:class:`ServerSession` and :class:`ClientSession` wrap the transmission path
(:class:`~.sender.ServerPipeline`, :class:`~.receiver.ClientPipeline`) with the
protocol around it: feedback, keyframe requests, RTCP sender and receiver reports at
randomised intervals (RFC 3550 6.2), generic NACKs and their retransmission from a
bounded history (RFC 4585), picture loss indications, the playout delay, stall
detection, and the "does this update show anything" rule.  The server core also owns the
session around its transport: the handshake (:func:`accept_hello`), the pose rule
(:meth:`ServerSession.receive_pose`) and each frame's order (:meth:`ServerSession.order_frame`,
made by :func:`~.frames.make_frame`); the client core the blank-frame and keyframe-skip rules
(:meth:`ClientSession.blank`, :meth:`ClientSession.skips_decode`).  Three front doors drive
them: virtual time, the live server and client, and the browser session (the server core in
its ``webrtc`` transport profile).  They never read a clock
and never touch a socket: time comes in as ``now_ms`` on the driver's clock, bytes come
in as arguments.  Everything the server core sends leaves one way,
:meth:`ServerSession.datagrams_to_send`, called after each input and when its one timer
(:meth:`ServerSession.get_timer`) comes: media, FEC, retransmissions, probes and sender reports,
each tagged with its kind (the pacer and the probe clusters sit behind that timer).  The client
core owns its control connection (the :class:`ClientHandshake`'s): the control bytes go in by
:meth:`ClientSession.receive_data` and out by :meth:`ClientSession.data_to_send` (feedback, poses,
Bye); its RTCP comes out of :meth:`ClientSession.datagrams_to_send`, its events (stalls, the
server's Stats, Bye and Error, the connection's end) out of :meth:`ClientSession.next_event`, the
decode work out of :meth:`ClientSession.work_to_decode`, the updates to apply out of
:meth:`ClientSession.display_tick` and what a tick shows out of :meth:`ClientSession.showing`, and :meth:`ClientSession.get_timer`
says when to call its ``handle_timer``.  The server core keeps the handshake's ``ServerConnection``
(:func:`accept_hello`): it frames the Welcome and each frame's FrameMeta and reliable data on it, the
drivers hand it the client's control bytes (:meth:`ServerSession.receive_data`) and take its events from
:meth:`ServerSession.next_event`, the core having taken Pose, Feedback and KeyframeRequest (the client's Stats, Bye and
Error, and the connection's end, are the driver's to act on).  The rows a server session records (a ``feedback`` row
per Feedback, an ``updates`` row per frame a live front door sent) leave by :meth:`ServerSession.rows_to_write`, for
the one writer every front door uses (:class:`~.recording.SessionLogs`).

Two drivers run them: the virtual-time runner (:mod:`splitrender.sim.runner`) with the
network model on a simulated clock, and the live server and client
(:mod:`splitrender.server.session`, :mod:`splitrender.client.session`) with sockets and
the wall clock.  ``clock_offset_us`` turns the driver's clock into the protocol's
wall-clock µs (the live drivers run on the wall clock and pass 0; virtual time passes
its simulated epoch), so the same session sends the same timestamps either way.

Control-channel framing stays in :class:`~splitrender.protocol.Connection` (sans-IO as
well), which each core holds.
"""

from __future__ import annotations

import dataclasses
import heapq
import logging
import math
import secrets
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import numpy as np

from ..codecs.meta import unpack_meta
from ..errors import (CodecError, ConfigError, PeerTimeoutError, RemoteProtocolError, ServerRefusedError,
                      SplitRenderError, describe_error)
from ..limits import DEFAULT_CLIENT_LIMITS, ClientLimits, check_client_sizes
from ..protocol import (CONNECTION_CLOSED, NEED_DATA, Bye, ClientConnection, Error, ErrorCode, Feedback, FrameMeta, DataChunk,
                        FullIntraRequest, GenericNack, Hello, KeyframeRateLimiter, KeyframeRequest, Message, MessageError, Pose,
                        PROTOCOL_VERSION, ServerConnection, negotiate_method,
                        State, Stats, PictureLossIndication, ReceiverReport, ReportBlock, RetransmissionHistory,
                        RtcpPacket, RtpPacket, SenderReport, Welcome, is_rtcp, ntp_from_seconds, ntp_middle32, parse_rtcp,
                        serialize_rtcp)
from ..protocol.errors import RtcpError
from ..protocol.rtcp import SDES_CNAME, SdesChunk, SourceDescription, compound_feedback
from ..protocol.rtp import RTP_CLOCK_HZ
from ..methods.base import SCALE_KNOB, StreamSpec, get_method, make_config
from ..render.gl import get_context, make_current
from ..scene.pose import CameraIntrinsics, Pose as ScenePose
from ..scene.predict import make_predictor
from ..protocol.twcc import (DEFAULT_EXTENSION_ID, FeedbackRecorder, SendHistory, TransportFeedback, one_byte_extension, read_transport_seq,
                             write_transport_seq)
from .adapt import (AdaptConfig, PointController, RateController, check_adapt_mode, controlled_streams, knobs_model, scale_rate,
                    stream_fps)
from .feedback import FeedbackState
from .gcc import BandwidthEstimator, GccConfig, Pacer, ReceiverEstimate
from .receiver import ClientPipeline, ReceivedFrame, SessionAssembler, Work
from .frames import FrameOrder
from .rows import feedback_row, mean_of, session_summary, update_row
from ..options import NACK_RATE_WINDOW_MS, ClientOptions, ServerProtocolOptions
from .sender import EncodedUpdate, OutgoingFrame, ServerPipeline, rtp_timestamp
from .wire import EnvelopeError, SessionDataError, control_wire_bytes, specs_from_table

log = logging.getLogger(__name__)

__all__ = ["Accepted", "CLIENT_CODECS", "Opening", "accept_hello", "accept_page", "method_config", "open_hello", "open_page", "page_knobs", "page_terms", "ClientHandshake", "ClientSession", "ControlClosed", "FrameReleased", "PoseInbox",
           "ClientMessage", "ServerMessage", "ServerOptions", "ServerSession", "SessionEvent", "SessionTerms", "Stalled", "Resumed", "StallTimeout", "StreamStalledError", "check_hello", "leaving_error", "parse_welcome",
           "read_hello", "session_params", "session_summary", "shows_anything"]

TIMER_TICK_MS = 10.0
"""While packets or frames are outstanding the client core wants its timer this often (ms)."""
BIND_INTERVAL_MS = 100.0
"""Until the first RTP packet the client repeats an empty receiver report this often (it opens the UDP path)."""
NACK_RETRY_MIN_MS = 30.0
NACK_RETRY_MAX_MS = 500.0
TIME_EPS_MS = 1e-6
"""A deadline this close is due: a driver whose clock counts in other units (the runner's seconds) hands back a
deadline it was given with rounding (``t / 1000 * 1000 != t``), and must not wait for it again forever."""
MAX_READY_UPDATES = 16
"""Released updates waiting for their display turn before the oldest is applied unseen."""


class PoseInbox:
    """The server's one rule for the client's pose samples, in every front door (virtual time, live, browser).

    A sample is taken when it is newer than the newest taken (the first always): the predictor observes it and it
    becomes :attr:`latest` = (client seconds, pose, client µs, seq).  A duplicate or a reordered sample (the
    browser's unordered channel, a resend) is dropped and counted in :attr:`stale`."""

    def __init__(self, predictor: Any) -> None:
        self.predictor = predictor
        self.latest: tuple[float, Any, int, int] | None = None
        self.received = 0
        self.stale = 0

    @property
    def latest_t_s(self) -> float | None:
        return None if self.latest is None else self.latest[0]

    def newer(self, t_s: float) -> bool:
        """Whether a sample measured at ``t_s`` would be taken."""
        return self.latest is None or t_s > self.latest[0]

    def counters(self) -> dict[str, int]:
        """``poses_received`` (taken) and ``poses_stale`` (dropped), as the live and browser sessions report them."""
        return {"poses_received": self.received - self.stale, "poses_stale": self.stale}

    def offer(self, t_s: float, pose: Any, client_us: int = 0, seq: int = 0) -> bool:
        """Take the sample if it is newer than the newest; returns whether it was taken."""
        self.received += 1
        if not self.newer(t_s):
            self.stale += 1
            return False
        if self.predictor is not None:
            self.predictor.observe(t_s, pose)
        self.latest = (t_s, pose, client_us, seq)
        return True


def shows_anything(rf: ReceivedFrame) -> bool:
    """Whether an update can change the picture: complete, or at least one stream of it arrived."""
    u = rf.update
    return bool(u.complete or u.planes or u.data)


def _rtcp_interval_ms(mean_s: float, rand: Any) -> float:
    """RFC 3550 6.3.1: the report interval times a uniform factor in [0.5, 1.5], so reports do not synchronise."""
    return mean_s * 1000.0 * (0.5 + float(rand()))


def _uniform(rng: Any) -> Any:
    """A ``() -> [0, 1)`` draw from a numpy Generator, or from the OS when ``rng`` is None."""
    if rng is None:
        return lambda: secrets.randbits(53) / (1 << 53)
    return lambda: float(rng.random())


def session_params(method: str, config: Any, fov_y_deg: float, server_fps: int, scene: str,
                   tx: ServerPipeline, session_blob: bytes, subject: Any = None) -> dict[str, Any]:
    """The ``Welcome.method_params`` map of a session, in both modes (documented in docs/protocol.md).

    ``subject``: a loaded model's world bounds (lo, hi), sent as ``subject`` so that the
    client places its built-in traces around the model."""
    cfg = {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(config).items()}
    out = {"config": cfg, "fov_y_deg": float(fov_y_deg), "server_fps": int(server_fps), "scene": scene,
           **tx.welcome_params(session_blob)}
    if subject is not None:
        out["subject"] = [[float(v) for v in subject[0]], [float(v) for v in subject[1]]]
    return out


CLIENT_CODECS: tuple[str, ...] = ("h264", "hevc")
"""The video codecs a splitrender client decodes, in its default order of preference (``Hello.codecs``)."""


def check_hello(hello: Hello, max_pixels: int) -> None:
    """What a server asks of every ``Hello`` before it opens a session, in both modes; :class:`MessageError` naming
    the field otherwise."""
    if hello.width % 2 or hello.height % 2:
        raise MessageError(f"Hello.width/height: {hello.width}x{hello.height} must be even")
    if hello.width * hello.height > max_pixels:
        raise MessageError(f"Hello.width/height: {hello.width}x{hello.height} exceeds this server's "
                           f"limit of {max_pixels} pixels")
    if not hello.codecs:
        raise MessageError("Hello.codecs: empty")


@dataclass(frozen=True)
class Opening:
    """A session a server is opening, before its method's server half is built (in a render worker, or the runner's
    producer pool: :meth:`~.producers.ProducerPool.server_half`): the method, its config and the client's camera.
    Every server front door makes one (:func:`open_hello`, :func:`open_page`, the runner from its run config)."""

    method: str
    config: Any
    intrinsics: CameraIntrinsics


def method_config(method: str, params: Mapping[str, Any], codecs: Iterable[str] | None = None) -> Any:
    """``method``'s config from ``params`` (a ``ConfigError`` naming a bad one), fitted to the video codecs the
    client decodes (its ``Hello.codecs``) where it named them."""
    config = make_config(get_method(method).config, dict(params))
    return config if codecs is None else config.for_codecs(tuple(codecs))


def open_hello(hello: Hello, methods: Iterable[str], server: Any) -> Opening:
    """The opening of the session that said ``hello`` to a server of ``methods`` with config ``server`` (its
    ``max_pixels``, ``method_params`` and ``fov_y_deg``): the Hello checked (:func:`check_hello`), the method
    negotiated and its config fitted to the client's codecs.  Raises ``RemoteProtocolError`` naming what it refused."""
    check_hello(hello, server.max_pixels)
    method = negotiate_method(hello.methods, tuple(methods))
    return Opening(method, method_config(method, server.method_params.get(method, {}), hello.codecs),
                   CameraIntrinsics(hello.width, hello.height, server.fov_y_deg))


def open_page(method: str, width: int, height: int, server: Any, overrides: Mapping[str, Any]) -> Opening:
    """The opening of a browser session (:func:`accept_page`): ``method``'s config from ``server``'s parameters for
    it with ``overrides`` (the codec every browser decodes), the page's camera."""
    params = {**server.method_params.get(method, {}), **overrides}
    return Opening(method, method_config(method, params), CameraIntrinsics(width, height, server.fov_y_deg))


@dataclass(frozen=True)
class SessionTerms:
    """What a ``Welcome`` settles, checked (:func:`parse_welcome`)."""

    session_id: str
    method: str
    spec: Any
    """The method's registered ``MethodSpec``."""
    config: Any
    """The method's config (its ``MethodConfig``), from ``method_params.config``."""
    fov_y_deg: float
    server_fps: float
    subject: tuple[np.ndarray, np.ndarray] | None
    """A loaded model's world bounds (lo, hi): built-in traces go around it."""


def _finite_param(params: Any, key: str, default: float, lo: float, hi: float) -> float:
    v = params.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo < v <= hi:
        raise EnvelopeError(f"Welcome.method_params.{key}: expected a number in ({lo:g}, {hi:g}], got {v!r:.80}")
    return float(v)


def parse_subject(v: Any) -> tuple[np.ndarray, np.ndarray]:
    """``Welcome.method_params.subject``: [[x, y, z], [x, y, z]], finite, lo <= hi."""
    try:
        lo, hi = (np.asarray(b, np.float64).reshape(3) for b in v)
    except (TypeError, ValueError):
        raise EnvelopeError(f"Welcome.method_params.subject: expected [[x, y, z], [x, y, z]], got {v!r:.80}") from None
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
        raise EnvelopeError(f"Welcome.method_params.subject: bounds must be finite with lo <= hi, got {v!r:.80}")
    return lo, hi


def parse_welcome(welcome: Welcome, offered: Any = None, limits: ClientLimits = DEFAULT_CLIENT_LIMITS,
                  display: tuple[int, int] | None = None) -> SessionTerms:
    """The terms of ``welcome``, every field a client builds on checked: the method is one the client offered
    (``offered``: its ``Hello.methods``; any registered one when None) and its config is valid for it, the field of
    view and server rate are finite and in range, the subject's bounds are finite.  :class:`EnvelopeError` (400)
    naming the field otherwise; a server's word is never a ``ConfigError`` of the client's.

    With ``display`` (the client's ``Hello.width``, ``Hello.height``) what the config makes the client hold
    (:meth:`~splitrender.methods.base.MethodConfig.client_sizes`: reference images, atlases, meshes) is held to
    ``limits`` too, before anything is allocated: :class:`~splitrender.limits.ClientLimitError` (413) naming the
    config field."""
    params = welcome.method_params
    if offered is not None and welcome.method not in offered:
        raise EnvelopeError(f"Welcome.method: {welcome.method!r:.80} is not one this client offered ({list(offered)})")
    try:
        spec = get_method(welcome.method)
    except ConfigError as exc:
        raise EnvelopeError(f"Welcome.method: {exc}") from None
    raw = params.get("config", {})
    if not isinstance(raw, Mapping) or not all(isinstance(k, str) for k in raw):
        raise EnvelopeError(f"Welcome.method_params.config: expected a map of parameter names, got {type(raw).__name__}")
    try:
        config = make_config(spec.config, dict(raw))
    except (ConfigError, TypeError, ValueError, OverflowError) as exc:
        raise EnvelopeError(f"Welcome.method_params.config: {exc}") from None
    fov = _finite_param(params, "fov_y_deg", 60.0, 0.0, 179.0)
    fps = _finite_param(params, "server_fps", 30.0, 0.0, 1000.0)
    if display is not None:
        try:
            sizes = config.client_sizes(CameraIntrinsics(display[0], display[1], fov))
        except (ConfigError, TypeError, ValueError, OverflowError) as exc:   # a plug-in's sizing of a config it took
            raise EnvelopeError(f"Welcome.method_params.config: {exc}") from None
        check_client_sizes(sizes, limits)
    subject = params.get("subject")
    return SessionTerms(welcome.session_id, welcome.method, spec, config, fov, fps,
                        parse_subject(subject) if subject is not None else None)


class ClientHandshake:
    """The client's side of the handshake, sans-IO, in both modes: a ``Welcome`` (its terms checked by
    :func:`parse_welcome`, and with ``display``, the client's (width, height), what its config makes the client hold
    against ``limits``), then the session data in ``DataChunk`` messages, bounded by ``limits``.

    It owns the client's control :class:`~splitrender.protocol.Connection` (:attr:`conn`), which the session it
    makes (:meth:`session`) takes over.  :meth:`hello` gives the ``Hello``'s bytes; feed the server's bytes to
    :meth:`receive_data` (or, where the driver parses them, every message after ``Hello`` to
    :meth:`receive_message`) until it returns True; then :attr:`terms`, :attr:`session_data` and :meth:`session`
    give what the session is built from.  Raises ``RemoteProtocolError`` naming what was wrong; an ``Error`` or a
    closed connection is the driver's to report."""

    def __init__(self, offered: Any = None, limits: ClientLimits = DEFAULT_CLIENT_LIMITS,
                 display: tuple[int, int] | None = None) -> None:
        self.conn = ClientConnection()
        """The control connection (sans-IO framing and state), the session's once the handshake is done."""
        self.offered = tuple(offered) if offered is not None else None
        self.limits = limits
        self.display = display
        self.welcome: Welcome | None = None
        self.terms: SessionTerms | None = None
        self._asm: SessionAssembler | None = None
        self.session_data: dict[str, Any] = {}
        self.session_bytes = 0
        self.done = False

    @property
    def session_progress(self) -> tuple[int, int]:
        """Session data bytes received so far and announced in the Welcome ((0, 0) before it)."""
        if self._asm is None:
            return 0, 0
        return self._asm.received, self._asm.total

    def make_hello(self, codecs: Iterable[str], display_hz: float, token: str = "") -> Hello:
        """The ``Hello`` this client sends: the methods it offers, the ``codecs`` it decodes (in order of preference),
        its display's size and rate, and the server's ``token``."""
        assert self.offered is not None and self.display is not None
        return Hello(PROTOCOL_VERSION, token, self.offered, tuple(codecs), *self.display, float(display_hz))

    def hello(self, hello: Hello) -> bytes:
        """The ``Hello``'s bytes (:meth:`make_hello`), the first the client sends."""
        return self.conn.send(hello)

    def receive_data(self, data: bytes) -> bool:
        """Bytes from the server; True once the session data is complete (bytes after it stay in :attr:`conn`, for
        the session)."""
        self.conn.receive_data(data)
        while not self.done and isinstance(msg := self.conn.next_event(), Message):
            self.receive_message(msg)
        return self.done

    @property
    def waiting_for(self) -> str:
        """What the handshake waits for next (the Welcome, or the session data and how much of it came), for a
        driver's timeout to name."""
        got, total = self.session_progress
        return "Welcome" if self.welcome is None else f"session data ({got} of {total} bytes received)"

    def receive_message(self, msg: Message | None) -> bool:
        """One message from the server (None: it closed the connection); True once the session data is complete.
        An ``Error`` or the connection's end raises :class:`~splitrender.errors.ServerRefusedError` naming it."""
        if isinstance(msg, Error):
            raise ServerRefusedError(f"server refused the session: {msg.code}: {msg.text}")
        if msg is None:
            raise ServerRefusedError("server closed the connection " + ("instead of answering Hello" if self.welcome
                                                                        is None else "during the session data"))
        if self.done:
            raise EnvelopeError(f"handshake: {type(msg).__name__} after the session data was complete")
        if self.welcome is None:
            if not isinstance(msg, Welcome):
                raise EnvelopeError(f"handshake: expected Welcome, got {type(msg).__name__}")
            self.terms = parse_welcome(msg, self.offered, self.limits, self.display)
            params = msg.method_params
            self._asm = SessionAssembler(params.get("session_data_bytes", 0), params.get("session_data_crc"),
                                         self.limits.max_session_bytes)
            self.welcome = msg
        else:
            if not isinstance(msg, DataChunk):
                raise EnvelopeError(f"handshake: expected session data after Welcome, got {type(msg).__name__}")
            assert self._asm is not None
            self._asm.add(msg)
        assert self._asm is not None
        if self._asm.done:
            self.session_bytes = self._asm.total
            try:
                self.session_data = unpack_meta(self._asm.blob) if self._asm.total else {}
            except CodecError as exc:   # the peer's bytes: a protocol error, not our crash
                raise EnvelopeError(f"session data: {exc}") from None
            if not isinstance(self.session_data, dict):
                raise EnvelopeError(f"session data: expected a map, got {type(self.session_data).__name__}")
            self.done = True
        return self.done

    def client_half(self, gl: Any = None) -> Any:
        """The method's client half the terms name, in GL context ``gl`` (made current here; call on the thread that
        owns it), or by default in the calling thread's own (:func:`~splitrender.render.gl.get_context`: a live
        client's GL thread): at the display's size and the Welcome's field of view, built from the session data, held
        to ``limits``."""
        t = self.terms
        assert t is not None and self.done and self.display is not None
        if gl is None:
            gl = get_context()
        else:
            make_current(gl)
        intr = CameraIntrinsics(self.display[0], self.display[1], t.fov_y_deg)
        return t.spec.client_class(t.config, intr, gl, self.session_data, limits=self.limits)

    def session(self, options: ClientOptions, clock_offset_us: int = 0, rng: Any = None) -> ClientSession:
        """The client session core the Welcome describes (:meth:`ClientSession.from_welcome`); it takes over the
        control connection."""
        assert self.welcome is not None and self.done
        return ClientSession.from_welcome(self.welcome, options, clock_offset_us, rng, conn=self.conn)


# --------------------------------------------------------------------------- events


@dataclass(frozen=True)
class SessionEvent:
    now_ms: float


@dataclass(frozen=True)
class Stalled(SessionEvent):
    """No frame with content for ``idle_ms`` (``stall_frames`` server intervals): keyframes are asked for."""

    idle_ms: float

    def __str__(self) -> str:   # what every client driver logs
        return f"stalled at {self.now_ms / 1000:.3f} s: no new frame for {self.idle_ms:.0f} ms"


@dataclass(frozen=True)
class Resumed(SessionEvent):
    """Frames flow again after a stall of ``stall_ms``."""

    stall_ms: float

    def __str__(self) -> str:
        return f"frames resumed after {self.stall_ms:.0f} ms"


@dataclass(frozen=True)
class StallTimeout(SessionEvent):
    """No frame for ``stall_timeout_s``: the live client ends the session."""

    idle_ms: float


@dataclass(frozen=True)
class ServerMessage(SessionEvent):
    """A control message the core leaves to the driver: ``Stats``, ``Bye`` or ``Error``."""

    message: Message


@dataclass(frozen=True)
class ClientMessage(SessionEvent):
    """A control message the server core leaves to the driver (:meth:`ServerSession.next_event`): ``Stats``, ``Bye``
    or ``Error``."""

    message: Message


@dataclass(frozen=True)
class ControlClosed(SessionEvent):
    """The peer closed the control connection (the server, to the client core; the client, to the server core)."""


@dataclass(frozen=True)
class FrameReleased(SessionEvent):
    """A frame left the receive path for the display queue, whole or with ``frame.update.missing`` streams lost
    (for the driver's records: it is applied only as :meth:`ClientSession.display_tick` gives it out)."""

    frame: ReceivedFrame


# --------------------------------------------------------------------------- client


class StreamStalledError(SplitRenderError):
    """No frame arrived for ``stall_timeout_s``: the server stopped streaming (:meth:`ClientSession.take_events`)."""


def leaving_error(exc: BaseException) -> tuple[int, str] | None:
    """What a client leaving the session on ``exc`` tells the server, as its ``Error``'s code and text: the peer
    error's own code for bad input from the server, 408 for a stream that stalled or a server that did not answer in
    time, 500 for a failure of its own; None where there is no one to tell (the server ended or refused the session,
    or the connection is gone)."""
    if isinstance(exc, (ServerRefusedError, ConnectionError, EOFError)):
        return None
    if isinstance(exc, RemoteProtocolError):
        return int(exc.code), f"client: {exc}"
    if isinstance(exc, (StreamStalledError, PeerTimeoutError)):
        return int(ErrorCode.TIMEOUT), f"client: {exc}"
    return int(ErrorCode.INTERNAL), f"client failed: {describe_error(exc)}"


STALL_MAX_INTERVAL_MS = 500.0
"""The longest achieved frame interval a stall is measured in (a floor of 2 frames a second): ``stall_frames``
of them stays well under ``stall_timeout_s``."""


def _losses(rx: Any) -> int:
    """What a video stream has lost so far: packets, frames given up or corrupt (its jitter buffer's counts)."""
    j = rx.jitter
    return int(j.packets_lost + j.frames_lost + j.frames_corrupt) if j is not None else 0


@dataclass
class _Ready:
    release_ms: float
    frame: ReceivedFrame


class ClientSession:
    """The client side of one session (see the module docstring).

    It owns the control connection (``conn``: the handshake's; a fresh one past the handshake where None).  Call
    :meth:`start` once the streams are known, then feed the control connection's bytes (:meth:`receive_data`),
    datagrams (:meth:`receive_datagram`) and timer expiries (:meth:`handle_timer`).  Decoding is the driver's (it
    may run on another thread): after each of those calls the ``Work`` items :meth:`work_to_decode` gives go to
    :meth:`ClientPipeline.decode` (unless :meth:`skips_decode`), their results to :meth:`on_decoded`.  The frames
    each input completes join the display queue there and then (each announced by a :class:`FrameReleased` event);
    they leave it one way: at each display tick :meth:`display_tick` gives the updates to apply in order, the
    driver applies them and renders (:func:`~.frames.display_frame`), and :meth:`showing` takes the outcome and says
    what the tick shows (sending a new update's Feedback).  What the core sends leaves by
    :meth:`datagrams_to_send` (RTCP) and :meth:`data_to_send` (the control connection: feedback, and what the driver
    :meth:`send`), its events by :meth:`next_event`, and :meth:`get_timer` says when to call :meth:`handle_timer`.
    """

    def __init__(self, rx: ClientPipeline, options: ClientOptions, server_fps: float, clock_offset_us: int = 0,
                 rng: Any = None, transport_cc_id: int | None = None, probe_ssrc: int | None = None,
                 conn: ClientConnection | None = None) -> None:
        if conn is None:   # a session made without a handshake (tests, tools): its connection starts past it
            conn = ClientConnection()
            conn.state = State.STREAMING
        self.conn = conn
        """The control connection (sans-IO): :meth:`receive_data` in, :meth:`data_to_send` out."""
        self._control_out: list[bytes] = []
        self.scene_epoch_ms: float | None = None
        """Driver time of the server's scene time 0 (ms), from the newest ``FrameMeta``: its server time and its
        envelope's scene time were stamped at one instant; None before the first."""
        self.rx = rx
        self.opts = options
        self.server_fps = max(1.0, float(server_fps))
        self.clock_offset_us = int(clock_offset_us)
        self._rand = _uniform(rng)
        media = {s.ssrc for s in rx.streams.values()}
        ssrc = 0
        while ssrc == 0 or ssrc in media:
            ssrc = int(self._rand() * (1 << 32)) & 0xFFFFFFFF
        self.ssrc = ssrc
        """This receiver's RTCP SSRC (random per session)."""
        self.cname = f"splitrender-client-{int(self._rand() * (1 << 48)):012x}".encode("ascii")
        self.transport_cc_id = transport_cc_id
        """The Welcome's transport sequence extension id: arrivals are reported with transport-wide feedback."""
        self._twcc = FeedbackRecorder(self.ssrc, min(media) if media else 0) if transport_cc_id is not None else None
        self._next_twcc_ms = math.inf
        self.probe_ssrc = probe_ssrc
        """The server's probe packets (padding for its rate estimator): their arrivals are reported, then dropped."""
        self._out: list[bytes] = []
        self._work: list[Work] = []
        """Frames released to decode since the last :meth:`work_to_decode`, in order."""
        self.events: list[SessionEvent] = []
        self._holes: dict[str, dict[int, tuple[float, float, int]]] = {}  # stream -> seq -> first seen, last nack, tries
        self.nack_rtt_ms: float | None = None
        """Smoothed time from a NACK to its retransmission's arrival (RFC 6298's 1/8 gain), ms."""
        self._last_pli_ms: dict[str, float] = {}
        self._first_packet_ms: dict[str, float] = {}
        self.rtp_seen = False
        self._started = False
        self._last_frame_ms = 0.0
        self._stalled = False
        self._arrivals: deque[float] = deque()
        """When frames with content arrived over the last second (the achieved server rate)."""
        self._achieved_ms = 1000.0 / self.server_fps
        """The server's achieved frame interval (ms): over the last second, within [nominal, STALL_MAX_INTERVAL_MS]."""
        self._loss_mark: dict[str, int] = {}
        """Per video stream, its loss count when the last frame arrived (a stall asks for a keyframe only past it)."""
        self._next_rr_ms = math.inf
        self._next_bind_ms = math.inf
        self._last_timer_ms = -math.inf
        self._ready: deque[_Ready] = deque()
        self.release_delay_ms: Callable[[ReceivedFrame], float] | None = None
        """How long after its release a frame is displayable (virtual time's model of decoding; the live drivers
        decode before the release: None, at once)."""
        self._decode_ms = 0.0
        """Decoding time reported since the last release (:meth:`on_decoded`), ms."""
        self._pending_apply: list[ReceivedFrame] = []
        self._held_ticks: list[Any] = []
        """Display ticks held until the server's scene clock is known (:meth:`display_tick`)."""
        self.shown: ReceivedFrame | None = None
        """The update on screen (the newest applied one that showed anything)."""
        self._fed_back = -1
        self._last_release_ms = -math.inf
        self._rate_window: deque[tuple[float, dict[str, int]]] = deque()   # (s, bytes received so far), a second's
        self.counters: dict[str, Any] = {
            "rtp_packets": 0, "rtp_bytes": 0, "rtcp_sent": 0, "rtcp_bytes_sent": 0, "rtcp_received": 0,
            "nacks_sent": 0, "nacked_packets": 0, "plis_sent": 0, "stall_plis": 0, "stalls": 0, "longest_stall_ms": 0.0,
            "frames_meta": 0, "frames_complete": 0, "frames_partial": 0, "frames_displayed_updates": 0,
            "updates_dropped_ready": 0, "keyframes_after_pli": 0, "udp_bad": 0, "decode_overflows": 0,
            "meta_bytes": 0, "apply_errors": 0, "twcc_feedback_sent": 0, "probe_packets": 0, "probe_bytes": 0,
            "meta_gaps": 0, "control_bytes_received": 0,
        }

    @classmethod
    def from_welcome(cls, welcome: Welcome, options: ClientOptions, clock_offset_us: int = 0,
                     rng: Any = None, conn: ClientConnection | None = None) -> ClientSession:
        """The client session a ``Welcome`` describes: its streams' receive path (jitter buffers, decoders) with
        ``options``' timeouts.  Raises ``RemoteProtocolError`` for a malformed stream table."""
        params = welcome.method_params
        rx = ClientPipeline(welcome.streams, specs_from_table(params.get("streams")), options.jitter_timeout_ms,
                            resolve_timeout_ms=options.resolve_timeout_ms, limits=options.limits)
        cc = params.get("transport_cc")
        if cc is not None and (isinstance(cc, bool) or not isinstance(cc, int) or not 1 <= cc <= 14):
            raise EnvelopeError(f"Welcome.method_params.transport_cc: expected a header extension id in 1..14, got {cc!r:.80}")
        probe = params.get("probe_ssrc")
        if probe is not None and (isinstance(probe, bool) or not isinstance(probe, int) or not 0 <= probe < 1 << 32
                                  or probe in rx.by_ssrc):
            raise EnvelopeError(f"Welcome.method_params.probe_ssrc: expected an SSRC no stream uses, got {probe!r:.80}")
        return cls(rx, options, _finite_param(params, "server_fps", 30.0, 0.0, 1000.0), clock_offset_us, rng, cc,
                   probe if cc is not None else None, conn)

    # ------------------------------------------------------------------ clock

    def scene_t(self, now_s: float) -> float:
        """The server's scene time at driver time ``now_s`` (s; NaN before the first FrameMeta set its clock)."""
        return math.nan if self.scene_epoch_ms is None else now_s - self.scene_epoch_ms / 1000

    def protocol_us(self, now_ms: float) -> int:
        """The protocol's wall-clock µs at driver time ``now_ms``."""
        return self.clock_offset_us + int(round(now_ms * 1000))

    # ------------------------------------------------------------------ input

    def start(self, now_ms: float) -> None:
        """The session streams from ``now_ms``: the stall clock starts; an empty RR opens the UDP path; control
        messages that came with the handshake's last bytes are taken."""
        self._started = True
        self._last_frame_ms = now_ms
        self._next_bind_ms = now_ms + BIND_INTERVAL_MS
        self._next_rr_ms = now_ms + _rtcp_interval_ms(self.opts.rr_interval_s, self._rand)
        self._queue_rtcp([self._empty_rr()])
        self._take_control(now_ms)

    def receive_data(self, data: bytes, now_ms: float) -> None:
        """Bytes from the control connection (``b""``: it closed).  ``FrameMeta`` and ``DataChunk`` go to the
        pipeline; ``Stats``, ``Bye`` and ``Error`` leave as :class:`ServerMessage` events, the end of the connection
        as :class:`ControlClosed`.  Raises ``RemoteProtocolError`` on bad input (the driver answers with ``Error``)."""
        self.counters["control_bytes_received"] += len(data)
        self.conn.receive_data(data)
        self._take_control(now_ms)

    def _take_control(self, now_ms: float) -> None:
        while (ev := self.conn.next_event()) is not NEED_DATA:
            if ev is CONNECTION_CLOSED:
                self.events.append(ControlClosed(now_ms))
                return
            if isinstance(ev, (FrameMeta, DataChunk)):
                self.receive_message(ev, now_ms)
            else:
                self.events.append(ServerMessage(now_ms, ev))   # type: ignore[arg-type]

    def receive_message(self, msg: Message, now_ms: float) -> None:
        """A ``FrameMeta`` or ``DataChunk`` from the control channel; raises ``RemoteProtocolError`` on bad input."""
        if isinstance(msg, FrameMeta):
            c = self.counters
            c["frames_meta"] += 1
            if isinstance(msg.method_meta, bytes):
                c["meta_bytes"] += len(msg.method_meta)
            c["meta_gaps"] += "meta_last_id" in c and msg.frame_id != c["meta_last_id"] + 1
            c.setdefault("meta_first_id", msg.frame_id)
            c["meta_last_id"] = msg.frame_id
        if isinstance(msg, (FrameMeta, DataChunk)):
            self.rx.on_message(msg, now_ms)
        env = self.rx.last_envelope
        if isinstance(msg, FrameMeta) and env is not None:
            self.scene_epoch_ms = (msg.server_time_us - self.clock_offset_us) / 1000 - env.t_s * 1000
        self._release(now_ms)

    def send(self, msg: Message) -> None:
        """Send ``msg`` on the control connection (a ``Pose``, ``Stats``, ``Bye``): its bytes join
        :meth:`data_to_send`.  Raises ``LocalProtocolError`` where the connection's state forbids it."""
        self._control_out.append(self.conn.send(msg))

    def send_pose(self, client_time_us: int, seq: int, pose: ScenePose) -> None:
        """Send the tracker's ``pose`` sampled at ``client_time_us`` (wall-clock µs) as the ``seq``-th ``Pose``
        (numbered modulo 2^32, as the message carries it)."""
        position, orientation = (tuple(float(v) for v in a) for a in (pose.position, pose.orientation))
        self.send(Pose(client_time_us, seq & 0xFFFFFFFF, position, orientation))  # type: ignore[arg-type]

    def data_to_send(self) -> bytes:
        """The control connection's bytes queued since the last call (feedback, what was :meth:`send`), in order."""
        out, self._control_out = b"".join(self._control_out), []
        return out

    def receive_datagram(self, data: bytes, now_ms: float) -> None:
        """An RTP or RTCP datagram; the frames it makes ready to decode join :meth:`work_to_decode`."""
        rx = self.rx
        if is_rtcp(data):
            try:
                packets = parse_rtcp(data)
            except RtcpError:
                self.counters["udp_bad"] += 1
                return
            self.counters["rtcp_received"] += 1
            for p in packets:
                if isinstance(p, SenderReport) and p.ssrc in rx.by_ssrc:
                    st = rx.by_ssrc[p.ssrc].stats
                    if st is not None:
                        st.on_sender_report(p, now_ms)
            return
        if self.probe_ssrc is not None and len(data) >= 12 and int.from_bytes(data[8:12], "big") == self.probe_ssrc:
            self.counters["probe_packets"] += 1
            self.counters["probe_bytes"] += len(data)
            self._record_transport_seq(data, now_ms)
            return
        before = rx.counters["udp_bad"]
        works = rx.on_datagram(data, now_ms)
        if rx.counters["udp_bad"] != before:
            self.counters["udp_bad"] += 1
            return
        self.rtp_seen = True
        self.counters["rtp_packets"] += 1
        self.counters["rtp_bytes"] += len(data)
        self._record_transport_seq(data, now_ms)
        ssrc = int.from_bytes(data[8:12], "big")
        stream = rx.by_ssrc.get(ssrc)
        if stream is not None:
            self._first_packet_ms.setdefault(stream.name, now_ms)
            hole = self._holes.get(stream.name, {}).get(int.from_bytes(data[2:4], "big"))
            if hole is not None and hole[2] > 0:   # a NACKed packet: time its round trip
                sample = now_ms - hole[1]
                self.nack_rtt_ms = sample if self.nack_rtt_ms is None else 0.875 * self.nack_rtt_ms + 0.125 * sample
                self.counters["nack_rtt_ms"] = round(self.nack_rtt_ms, 1)
        self._work += self._count_keyframes(works)
        self._release(now_ms)

    def _record_transport_seq(self, data: bytes, now_ms: float) -> None:
        if self._twcc is not None and self.transport_cc_id is not None:
            tseq = read_transport_seq(data, self.transport_cc_id)
            if tseq is not None:
                self._twcc.on_packet(tseq, self.protocol_us(now_ms))
                if not math.isfinite(self._next_twcc_ms):
                    self._next_twcc_ms = now_ms + self.opts.twcc_interval_ms

    def _count_keyframes(self, works: list[Work]) -> list[Work]:
        """Keyframes that came after a PLI (the pipeline counts every keyframe received)."""
        if self.counters["plis_sent"]:
            self.counters["keyframes_after_pli"] += sum(1 for w in works if w.unit.keyframe and w.stream.kind == "video")
        return works

    def work_to_decode(self) -> list[Work]:
        """The frames released to decode (by :meth:`receive_datagram` and :meth:`handle_timer`) since the last call, in
        order: the driver decodes each (:meth:`ClientPipeline.decode`) unless :meth:`skips_decode` says not."""
        out, self._work = self._work, []
        return out

    def on_decoded(self, work: Work, result: Any, now_ms: float, decode_ms: float = 0.0) -> None:
        """The result of decoding ``work`` (the decoded plane or bytes, or the ``CodecError``), and how long decoding
        it took (ms; charged to the next frame released: its :attr:`~.receiver.ReceivedFrame.decode_ms`)."""
        self._decode_ms += decode_ms
        self.rx.on_decoded(work, result, now_ms)
        self._release(now_ms)

    def skips_decode(self, work: Work, now_ms: float) -> bool:
        """The keyframe-skip rule of every driver, asked before decoding ``work``: a frame of a video stream that
        broke (a decode error) after ``work`` was released is not decoded but counted lost, until the stream's
        next keyframe.  Returns whether ``work`` was skipped (and reported as such)."""
        if work.stream.kind == "video" and work.stream.broken and not work.unit.keyframe:
            self.on_decoded(work, CodecError("skipped: waiting for a keyframe"), now_ms)
            return True
        return False

    def decoder_overflow(self) -> None:
        """The driver's decode queue overflowed and was flushed: every video stream waits for a keyframe."""
        self.counters["decode_overflows"] += 1
        for s in self.rx.streams.values():
            if s.kind == "video":
                s.broken = True

    def _release(self, now_ms: float) -> None:
        """Move the frames the pipeline released to the display queue (after each input: the one way frames reach
        :meth:`display_tick`), each announced by a :class:`FrameReleased` event; a frame is displayable
        :attr:`release_delay_ms` after ``now_ms``, and releases stay in frame order."""
        for rf in self.rx.ready():
            rf.decode_ms, self._decode_ms = self._decode_ms, 0.0
            release = now_ms + (float(self.release_delay_ms(rf)) if self.release_delay_ms is not None else 0.0)
            release = max(release, self._last_release_ms)
            self._last_release_ms = release
            if shows_anything(rf):
                self._frame_arrived(now_ms)
            self.counters["frames_partial" if rf.update.missing else "frames_complete"] += 1
            self._ready.append(_Ready(release, rf))
            while len(self._ready) > MAX_READY_UPDATES + int(self.opts.playout_delay_ms / 10):
                self.counters["updates_dropped_ready"] += 1
                self._pending_apply.append(self._ready.popleft().frame)  # applied unseen: the half's state stays in order
            self.events.append(FrameReleased(now_ms, rf))

    def _frame_arrived(self, now_ms: float) -> None:
        if self._stalled:
            ms = now_ms - self._last_frame_ms
            self.counters["longest_stall_ms"] = max(self.counters["longest_stall_ms"], round(ms, 1))
            self.events.append(Resumed(now_ms, ms))
            self._stalled = False
        # the achieved rate: the mean interval between the frames that arrived over the last second
        arr = self._arrivals
        arr.append(now_ms)
        while arr[0] < now_ms - 1000.0:
            arr.popleft()
        if len(arr) >= 2:
            interval = (arr[-1] - arr[0]) / (len(arr) - 1)
            self._achieved_ms = min(max(interval, 1000.0 / self.server_fps), STALL_MAX_INTERVAL_MS)
        self._last_frame_ms = now_ms
        self._loss_mark = {rx.name: _losses(rx) for rx in self.rx.streams.values() if rx.kind == "video"}

    # ------------------------------------------------------------------ timers

    def handle_timer(self, now_ms: float) -> None:
        """Jitter-buffer and resolution timeouts, receiver reports, NACKs, PLIs and stall detection at ``now_ms``.

        Frames it makes ready to decode join :meth:`work_to_decode`; RTCP goes to :meth:`datagrams_to_send`, stalls to
        :attr:`events`."""
        self._timer(now_ms)
        self._release(now_ms)

    def _timer(self, now_ms: float) -> None:
        self._last_timer_ms = now_ms
        self._work += self._count_keyframes(self.rx.poll(now_ms))
        if not self._started:
            return
        if not self.rtp_seen:
            if now_ms >= self._next_bind_ms:
                self._next_bind_ms = now_ms + BIND_INTERVAL_MS
                self._queue_rtcp([self._empty_rr()])
            idle = now_ms - self._last_frame_ms
            if idle >= self.opts.stall_timeout_s * 1000:
                self.events.append(StallTimeout(now_ms, idle))
            return
        out: list[RtcpPacket] = []
        if now_ms >= self._next_rr_ms:
            self._next_rr_ms = now_ms + _rtcp_interval_ms(self.opts.rr_interval_s, self._rand)
            out.append(ReceiverReport(self.ssrc, tuple(
                s.stats.report_block(now_ms) for s in self.rx.streams.values() if s.stats is not None)))
        for rx in self.rx.streams.values():
            if rx.jitter is None:
                continue
            nack = self._nack_list(rx, now_ms)
            if nack:
                out.append(GenericNack(self.ssrc, rx.ssrc, tuple(nack)))
                self.counters["nacks_sent"] += 1
                self.counters["nacked_packets"] += len(nack)
            first = self._first_packet_ms.get(rx.name)
            started = first is not None and now_ms - first >= self.opts.pli_interval_ms
            if (rx.wants_keyframe or (rx.needs_keyframe and started)) and (pli := self._pli(rx, now_ms)):
                out.append(pli)
        out.extend(self._check_stall(now_ms))
        if self._twcc is not None and now_ms >= self._next_twcc_ms:
            fbs = self._twcc.feedback()
            self.counters["twcc_feedback_sent"] += len(fbs)
            self.counters["twcc_late"] = self._twcc.late
            out.extend(fbs)
            self._next_twcc_ms = math.inf   # armed again by the next arrival
        if out:
            self._queue_rtcp(out)

    def get_timer(self) -> float:
        """When :meth:`handle_timer` wants to run next (driver ms; ``inf`` before :meth:`start`)."""
        if not self._started:
            return math.inf
        t = self._next_bind_ms if not self.rtp_seen else self._next_rr_ms
        if not self.rtp_seen:
            t = min(t, self._last_frame_ms + self.opts.stall_timeout_s * 1000)
        elif self._busy():
            t = -math.inf   # the next tick
        elif not self._stalled:
            t = min(t, self._last_frame_ms + self._stall_after_ms())
        t = min(t, self._next_twcc_ms)
        # never sooner than one tick after the last run: a deadline already passed waits for the next tick
        after = (math.floor(self._last_timer_ms / TIMER_TICK_MS + 1e-6) + 1) * TIMER_TICK_MS \
            if math.isfinite(self._last_timer_ms) else -math.inf
        return max(t, after)

    def _busy(self) -> bool:
        """Packets missing, frames outstanding or a stream waiting for a keyframe: poll every tick."""
        if self.rx.pending_frames or self._stalled:
            return True
        for s in self.rx.streams.values():
            if s.jitter is not None and (len(s.jitter) or s.needs_keyframe):
                return True
        return False

    def _nack_list(self, rx: Any, now_ms: float) -> list[int]:
        o = self.opts
        missing = set(rx.jitter.missing()) if o.nack_max_tries > 0 else set()
        holes = self._holes.setdefault(rx.name, {})
        for seq in [s for s in holes if s not in missing]:
            del holes[seq]
        out = []
        retry = o.nack_retry_ms if self.nack_rtt_ms is None else \
            min(NACK_RETRY_MAX_MS, max(NACK_RETRY_MIN_MS, 1.5 * self.nack_rtt_ms + 10.0))
        for seq in sorted(missing):
            first, last, tries = holes.get(seq, (now_ms, -math.inf, 0))
            if tries < o.nack_max_tries and now_ms - first >= o.nack_delay_ms and now_ms - last >= retry:
                out.append(seq)
                holes[seq] = (first, now_ms, tries + 1)
            else:
                holes.setdefault(seq, (first, last, tries))
        return out

    def _pli(self, rx: Any, now_ms: float) -> PictureLossIndication | None:
        """A PLI for stream ``rx`` unless one went out less than ``pli_interval_ms`` ago (counted)."""
        if now_ms - self._last_pli_ms.get(rx.name, -math.inf) < self.opts.pli_interval_ms:
            return None
        self._last_pli_ms[rx.name] = now_ms
        self.counters["plis_sent"] += 1
        return PictureLossIndication(self.ssrc, rx.ssrc)

    def _stall_after_ms(self) -> float:
        """``stall_frames`` of the server's achieved frame intervals (never fewer than nominal ones)."""
        return self.opts.stall_frames * self._achieved_ms

    def _check_stall(self, now_ms: float) -> list[RtcpPacket]:
        """A stall once no frame arrived for ``stall_frames`` achieved intervals; PLIs then for the video streams
        that lost packets or frames since the last frame arrived (a slow server's gaps ask for no keyframe)."""
        idle = now_ms - self._last_frame_ms
        if idle < self._stall_after_ms():
            return []
        if idle >= self.opts.stall_timeout_s * 1000:
            self.events.append(StallTimeout(now_ms, idle))
        if not self._stalled:
            self._stalled = True
            self.counters["stalls"] += 1
            self.events.append(Stalled(now_ms, idle))
        out: list[RtcpPacket] = [p for rx in self.rx.streams.values()
                                 if rx.kind == "video" and (rx.needs_keyframe or _losses(rx) > self._loss_mark.get(rx.name, 0))
                                 and (p := self._pli(rx, now_ms))]
        self.counters["stall_plis"] += len(out)
        return out

    # ------------------------------------------------------------------ RTCP out

    def _empty_rr(self) -> ReceiverReport:
        blocks = tuple(ReportBlock(s.ssrc, 0, 0, 0, 0) for s in self.rx.streams.values() if s.ssrc)
        return ReceiverReport(self.ssrc, blocks)

    def _queue_rtcp(self, packets: list[Any]) -> None:
        """``packets`` as one compound RTCP packet: a report first (an RR with no blocks when none is
        due), the SDES CNAME, then NACKs and PLIs (RFC 3550 6.1, RFC 4585 3.1)."""
        data = serialize_rtcp(compound_feedback(self.ssrc, self.cname, packets))
        self._out.append(data)
        self.counters["rtcp_sent"] += 1
        self.counters["rtcp_bytes_sent"] += len(data)

    def datagrams_to_send(self) -> list[bytes]:
        """RTCP datagrams queued since the last call, in order."""
        out, self._out = self._out, []
        return out

    def next_event(self) -> SessionEvent | None:
        """The oldest event not yet taken (a stall, its end, a stall timeout), or None."""
        return self.events.pop(0) if self.events else None

    def take_events(self, label: str, virtual: bool = False) -> list[ReceivedFrame]:
        """Every event not yet taken, by the one rule of every client driver: the frames released (returned in order,
        for the driver's records); a stall logged (a warning, its end info), the server's Stats at debug, ``label``
        naming the session; what ends the session raised: a stall timeout (:class:`StreamStalledError`), the server's
        Bye or Error (:class:`~splitrender.errors.ServerRefusedError`), the control connection's end
        (``ConnectionResetError``).  ``virtual``: virtual time's rule, where a run ends by its duration (a stall timeout
        ends nothing) and its many runs log a stall and its end at debug."""
        released = []
        while (ev := self.next_event()) is not None:
            msg = ev.message if isinstance(ev, ServerMessage) else None
            if isinstance(ev, FrameReleased):
                released.append(ev.frame)
            elif isinstance(ev, StallTimeout) and not virtual:
                raise StreamStalledError(f"{label}: no frame for {ev.idle_ms / 1000:.1f} s (stall_timeout_s "
                                         f"{self.opts.stall_timeout_s:g} s): the server stopped streaming")
            elif isinstance(ev, Stalled):
                log.log(logging.DEBUG if virtual else logging.WARNING, "%s: %s (%g of the server's frame intervals); a "
                        "keyframe is asked for where packets were lost", label, ev, self.opts.stall_frames)
            elif isinstance(ev, Resumed):
                log.log(logging.DEBUG if virtual else logging.INFO, "%s: %s", label, ev)
            elif isinstance(ev, ControlClosed):
                raise ConnectionResetError("server closed the control connection")
            elif isinstance(msg, Bye):
                raise ServerRefusedError(f"server ended the session: {msg.reason}")
            elif isinstance(msg, Error):
                raise ServerRefusedError(f"server error {msg.code}: {msg.text}")
            elif isinstance(msg, Stats):
                log.debug("%s: server stats %s", label, dict(msg.counters))
        return released

    # ------------------------------------------------------------------ display

    def _display(self, now_ms: float) -> list[ReceivedFrame]:
        """The updates to apply at display time ``now_ms``, in frame order: every released one whose
        decode is done and, with a playout delay, whose server time + the delay has come.  Until an update has
        been shown, updates that show nothing (:func:`shows_anything`) wait for the first that does: the tick shows
        the black background (:meth:`blank`) with nothing to apply or render."""
        new = list(self._pending_apply)
        self._pending_apply.clear()
        playout_us = self.opts.playout_delay_ms * 1000
        while self._ready and self._ready[0].release_ms <= now_ms:
            meta = self._ready[0].frame.meta
            if playout_us > 0 and meta.server_time_us - self.clock_offset_us + playout_us > now_ms * 1000:
                break
            new.append(self._ready.popleft().frame)
        if self.shown is None and not any(shows_anything(f) for f in new):
            self._pending_apply = new
            return []
        return new

    def display_tick(self, tick: Any, now_ms: float, hold: bool = True) -> tuple[list[Any], list[ReceivedFrame] | None]:
        """Display tick ``tick`` (the driver's token for it) at ``now_ms``, by the rule of every client driver: the
        ticks now known to show the black background (blank: their rows name no update, nothing is applied or
        rendered for them), in order, and the updates to apply at this one (:meth:`_display`), or None when it is one
        of those or held.  With ``hold`` (a live client, whose rows carry the scene time) ticks are held while the
        server's scene clock is unknown (no FrameMeta yet, and so no update either) and come out blank with the first
        tick after it is (or from :meth:`held_ticks`).  A tick with no update shown and none to apply is blank; after
        applying, :meth:`blank` says whether a tick shows anything."""
        if hold and self.scene_epoch_ms is None:
            self._held_ticks.append(tick)
            return [], None
        blanks, self._held_ticks = self._held_ticks, []
        new = self._display(now_ms)
        if self.shown is None and not new:
            return [*blanks, tick], None
        return blanks, new

    def held_ticks(self) -> list[Any]:
        """The ticks still held (:meth:`display_tick`) when the session ends: the server's clock never came."""
        held, self._held_ticks = self._held_ticks, []
        return held

    def applied(self, rf: ReceivedFrame) -> None:
        """The client half applied ``rf`` (it rejected none of it): it becomes the shown update if it
        shows anything."""
        u = rf.update
        self.rx.tracker.on_applied(u.frame_id, [*u.planes, *u.data])
        if shows_anything(rf) and (self.shown is None or u.frame_id != self.shown.update.frame_id):
            self.shown = rf

    def apply_failed(self, rf: ReceivedFrame) -> None:
        self.counters["apply_errors"] += 1

    def report_applied(self, frames: list[ReceivedFrame], ok: list[bool]) -> None:
        """What :func:`~.frames.apply_updates` made of ``frames`` (:meth:`applied` or :meth:`apply_failed` each)."""
        for rf, good in zip(frames, ok):
            self.applied(rf) if good else self.apply_failed(rf)

    def blank(self, has_content: bool) -> bool:
        """The blank-frame rule of every driver: a display tick shows the black background (and its row names no
        update) while no update has been shown, or while the client half has nothing to draw (``has_content``
        false: every update so far lost its content)."""
        return self.shown is None or not has_content

    def showing(self, frames: list[ReceivedFrame], ok: list[bool], has_content: bool,
                now_ms: float) -> ReceivedFrame | None:
        """What a display tick shows, by the one rule of every client driver, once the updates :meth:`display_tick`
        gave it (``frames``) were applied (``ok``: :func:`~.frames.apply_updates`'s answer for each, reported here)
        and the client half says whether it has anything to draw (``has_content``): the update shown, or None where
        the tick shows the black background (:meth:`blank`; its row names no update).  The shown update's Feedback is sent
        the first time it is displayed (at ``now_ms``: :meth:`feedback`)."""
        self.report_applied(frames, ok)
        shown = None if self.blank(has_content) else self.shown
        self.feedback(now_ms)
        return shown

    def feedback(self, displayed_ms: float) -> Feedback | None:
        """The ``Feedback`` for the shown update the first time it is displayed (at ``displayed_ms``), sent (its bytes
        join :meth:`data_to_send`) and returned to look at; else None."""
        rf = self.shown
        if rf is None or rf.update.frame_id == self._fed_back:
            return None
        self._fed_back = rf.update.frame_id
        self.counters["frames_displayed_updates"] += 1
        applied, lost = self.rx.tracker.take()
        timing = {k: int(v) for k, v in rf.env.timing_us.items() if k in ("render", "encode", "encoded_at")}
        fb = Feedback(rf.update.frame_id, self.protocol_us(rf.received_ms), self.protocol_us(rf.decoded_ms),
                      self.protocol_us(displayed_ms), 0, rf.meta.pose.client_time_us, timing, applied, lost)
        self.send(fb)
        return fb

    # ------------------------------------------------------------------ counters

    def received_kbps(self, now_s: float) -> dict[str, float]:
        """What arrived over the last second before ``now_s`` (the driver's clock, s; call once a display tick), kbit/s:
        ``kbps_<stream>`` for each RTP stream (wire bytes) and ``kbps_control`` for the control channel (bytes read,
        with the TCP/IP header model): the bytes since the oldest call within the last second, over the time between
        (0 with no earlier call in it)."""
        snap = dict(self.rx.wire_bytes)
        snap["control"] = control_wire_bytes(self.counters["control_bytes_received"])
        w = self._rate_window
        w.append((now_s, snap))
        while len(w) > 1 and w[0][0] < now_s - 1.0:
            w.popleft()
        t0, old = w[0]
        span = max(now_s - t0, 1e-3) if len(w) > 1 else 1.0
        return {f"kbps_{k}": (v - old.get(k, 0)) * 8 / span / 1000.0 for k, v in snap.items()}

    def all_counters(self) -> dict[str, Any]:
        """The session counters plus, per RTP stream, what its jitter buffer dropped: late packets,
        frames given up (timeout or overflow), frames dropped waiting for a keyframe, corrupt frames;
        with FEC, the parity packets received, the packets they rebuilt and the malformed ones."""
        out = dict(self.counters)
        out["decode_errors"] = self.rx.counters["decode_errors"]
        out["keyframes_received"] = self.rx.counters["keyframes_received"]
        for rx in self.rx.streams.values():
            j = rx.jitter
            if j is not None:
                out.update({f"{rx.name}_packets_late": j.packets_late, f"{rx.name}_frames_lost": j.frames_lost,
                            f"{rx.name}_frames_dropped": j.frames_dropped, f"{rx.name}_frames_corrupt": j.frames_corrupt})
                if j.fec_packets:
                    out.update({f"{rx.name}_fec_packets": j.fec_packets, f"{rx.name}_fec_recovered": j.fec_recovered,
                                f"{rx.name}_fec_bad": j.fec_bad})
        return out


# --------------------------------------------------------------------------- server


@dataclass
class Accepted:
    """A session the server accepted (:func:`accept_hello`): its core, whose :meth:`~ServerSession.data_to_send`
    gives what goes on the control connection first (the Welcome, then the session data's ``DataChunk`` messages),
    the ``Welcome``, and the session data's framed bytes (``session_bytes``, the DataChunks')."""

    core: ServerSession
    welcome: Welcome
    session_bytes: int


def read_hello(data: bytes, token: str = "") -> ServerConnection:
    """The server's end of a control connection that has read a client's ``Hello`` (``data``: its bytes, from
    :meth:`ClientHandshake.hello`), for :func:`accept_hello`: an in-process handshake's (the virtual-time runner's;
    the live server's reads it from its socket)."""
    conn = ServerConnection(token)
    conn.receive_data(data)
    while conn.next_event() is not NEED_DATA:
        pass
    return conn


def accept_hello(hello: Hello, session_id: str, opening: Opening, specs: list[Any], session_blob: bytes, conn: Any,
                 server: Any, options: ServerOptions, *, address: tuple[str, int] = ("127.0.0.1", 6004),
                 subject: Any = None, parameter_sets: Mapping[str, tuple[bytes, ...]] | None = None,
                 ssrc_taken: Callable[[int], bool] | None = None, rng: Any = None, core_rng: Any = None,
                 clock_offset_us: int = 0, rtp_origin_ms: float = 0.0, predictor: Any = None) -> Accepted:
    """The server's side of the handshake after :func:`open_hello`, in every front door that speaks the protocol.

    ``opening``'s server half and encoders (the caller's :class:`~.frames.FrameMaker`: in this process, or in a
    render worker) declared ``specs``, ``session_blob`` and ``parameter_sets``; this checks them against the
    server's limit and the client's codecs (a :class:`~.wire.SessionDataError` or ``RemoteProtocolError`` naming
    what is wrong), builds the session's :class:`~.sender.ServerPipeline` (its SDP naming the encoders' parameter
    sets) and its core, which keeps ``conn`` (the handshake's ``ServerConnection``: its
    :attr:`~ServerSession.conn`), and frames the ``Welcome`` and the session data on it (the core's
    :meth:`~ServerSession.data_to_send` gives them).  ``server`` is the
    server's config (a run's or a live server's: ``scene``, ``fov_y_deg``, ``server_fps``, ``max_session_bytes``,
    ``mtu_bytes``, ``fec``, ``transport_cc`` and, without ``predictor``, ``predictor`` by name).
    ``rng`` draws the SSRCs and sequence origins, ``core_rng`` the core's RTCP intervals (seeded runs; the system's
    randomness where None)."""
    method, config = opening.method, opening.config
    if len(session_blob) > server.max_session_bytes:
        raise SessionDataError(f"method {method}: session data of {len(session_blob)} bytes exceeds this server's "
                               f"limit of {server.max_session_bytes} bytes (max_session_bytes)")
    for spec in specs:
        codec = getattr(getattr(spec, "codec", None), "codec", None)
        if codec is not None and codec not in hello.codecs:
            raise RemoteProtocolError(f"method {method}: stream {spec.name} is {codec}, which the client does not "
                                      f"accept (Hello.codecs {list(hello.codecs)})", ErrorCode.UNSUPPORTED_METHOD)
    tx = ServerPipeline(specs, server.mtu_bytes, ssrc_taken=ssrc_taken, rng=rng, fec=server.fec,
                        transport_cc_id=DEFAULT_EXTENSION_ID if server.transport_cc else None)
    tx.described_sets.update(parameter_sets or {})   # the SDP names the sets the session's encoders will send
    core = ServerSession(tx, hello.display_hz, options, clock_offset_us, rtp_origin_ms, core_rng,
                         knobs=config.adapt_knobs(), predictor=make_predictor(server.predictor) if predictor is None else predictor,
                         conn=conn)
    host, port = address
    welcome = Welcome(session_id, method, session_params(method, config, server.fov_y_deg, server.server_fps,
                                                         server.scene, tx, session_blob, subject),
                      tx.describe(host, port, f"splitrender {session_id}"))
    core.queue_control(conn.send(welcome))
    chunks = [f for _, f in tx.session_frames(session_blob, conn.send)]
    for f in chunks:
        core.queue_control(f)
    return Accepted(core, welcome, sum(len(f) for f in chunks))


def accept_page(opening: Opening, specs: list[Any], display_hz: float, server: Any,
                session_blob: bytes = b"") -> ServerSession:
    """The server's side of a browser session (its WebRTC profile): ``opening``'s server half declared ``specs``
    and ``session_blob``, which a page takes only as one video stream (else a ``RemoteProtocolError`` naming them);
    the core, on the ``"webrtc"`` transport with ``server``'s session options and predictor (the WebRTC stack
    packetizes and paces: ``pacing`` is left off) and, for ``adapt = "full"``, the knobs the page can follow
    (:func:`page_knobs`)."""
    if len(specs) != 1 or not isinstance(specs[0], StreamSpec):
        raise RemoteProtocolError(f"method {opening.method}: streams {[s.name for s in specs]} cannot go to a page "
                                  "(it takes one video stream)", ErrorCode.UNSUPPORTED_METHOD)
    options = dataclasses.replace(server.session_options(), pacing=False)
    return ServerSession(ServerPipeline(specs), display_hz, options, predictor=make_predictor(server.predictor),
                         knobs=page_knobs(opening, session_blob) if options.adapt == "full" else (), transport="webrtc")


def page_terms(session_id: str, opening: Opening, spec: Any, page: Any, server: Any, **driver: Any) -> dict[str, Any]:
    """The session terms a browser page takes with the answer (its ``Welcome``; docs/browser.md): what
    :func:`session_params` tells a protocol client (the session and method, the scene, field of view and server
    rate from ``server``'s config), the display's size and the video stream's (``spec``), the method's page glue's
    own (``page``: :meth:`~splitrender.methods.base.PageGlue.terms`), and the front door's ``driver`` entries (its
    clock, the frame channel's lifetime, whether it records)."""
    display = opening.intrinsics
    return {"session_id": session_id, "method": opening.method, "scene": server.scene, "fov_y_deg": server.fov_y_deg,
            "server_fps": server.server_fps, "width": display.width, "height": display.height,
            "stream_width": spec.width, "stream_height": spec.height, **driver, **page.terms()}


def page_knobs(opening: Opening, session_blob: bytes) -> tuple[Any, ...]:
    """The method's operating-point knobs (:meth:`~splitrender.methods.base.MethodConfig.adapt_knobs`) that a browser
    page can follow.  The page takes its terms once, with the answer (its method's
    :meth:`~splitrender.methods.base.PageGlue.terms`, made from the config and the session data: atw's reference
    field of view and fill, sas's atlas), and its frames' own messages every frame; so a knob that sets a config
    field is kept only where none of its levels changes those terms.  The pipeline's knobs (no config field:
    ``scale``, whose smaller video the page's decoder takes as any resolution change, and ``frame_div``: the page
    draws the newest frame it has at every display tick) are kept."""
    config, page = opening.config, get_method(opening.method).page_class
    fields = {f.name for f in dataclasses.fields(config)}
    terms = page(config, opening.intrinsics, session_blob).terms()

    def follows(knob: Any) -> bool:
        return knob.name not in fields or all(
            page(dataclasses.replace(config, **{knob.name: v}), opening.intrinsics, session_blob).terms() == terms
            for v in knob.levels)
    return tuple(k for k in config.adapt_knobs() if follows(k))


class Datagram(NamedTuple):
    """A datagram the server core lets go (:meth:`ServerSession.datagrams_to_send`): its bytes, its ``kind``
    (``"rtp"`` media of ``stream``, ``"fec"``, ``"resend"``, ``"probe"``: the media path; ``"rtcp"``: a sender
    report) and the stream it belongs to (media only)."""

    data: bytes
    kind: str
    stream: str | None = None


@dataclass(frozen=True)
class ServerOptions(ServerProtocolOptions):
    """A server session's options: the protocol's (:class:`~splitrender.options.ServerProtocolOptions`, declared
    once with the client's), its estimator's settings, pacing and the adaptation mode."""

    gcc: GccConfig = field(default_factory=GccConfig)
    """The send-rate estimator's settings (sessions with transport-wide feedback)."""
    pacing: bool = False
    """With transport-wide feedback: RTP packets leave through a pacer at 2.5x the estimated rate
    (:class:`~.gcc.Pacer`) instead of in one burst per frame."""
    adapt: str = "off"
    """``"rate"``, with transport-wide feedback: every lossy video stream's encoder follows the estimate
    (:class:`~.adapt.RateController`; :meth:`ServerSession.encoder_rates`); ``"full"``: that, and the method's
    operating point too (:class:`~.adapt.PointController`; :meth:`ServerSession.operating_point`)."""
    adapt_cfg: AdaptConfig = field(default_factory=AdaptConfig)

    def __post_init__(self) -> None:
        super().__post_init__()
        check_adapt_mode(self.adapt, "server")


class _ByteWindow:
    """Bytes counted over the last ``span_ms`` (a sliding window; times never go backwards)."""

    def __init__(self, span_ms: float) -> None:
        self.span_ms = span_ms
        self._entries: deque[tuple[float, int]] = deque()
        self._sum = 0

    def add(self, now_ms: float, n: int) -> None:
        self._entries.append((now_ms, n))
        self._sum += n

    def total(self, now_ms: float) -> int:
        """Bytes added in (now_ms - span_ms, now_ms]."""
        q = self._entries
        while q and q[0][0] <= now_ms - self.span_ms:
            self._sum -= q.popleft()[1]
        return self._sum


@dataclass
class _TxState:
    name: str
    ssrc: int
    history: RetransmissionHistory
    packetizer: Any
    media: _ByteWindow = field(default_factory=lambda: _ByteWindow(NACK_RATE_WINDOW_MS))
    """Media bytes sent in the last second, for the resend rate cap."""
    resent: _ByteWindow = field(default_factory=lambda: _ByteWindow(NACK_RATE_WINDOW_MS))
    """Bytes resent in the last second."""


UNADAPTED_START_BPS = 2_000_000.0
"""The estimator's start in a session that measures the path but does not adapt (``transport_cc``, ``pacing``,
``adapt = "off"``): its encoders send at the method's own rate from the first frame, so a start as low as an adapting
session's (:attr:`~.gcc.GccConfig.start_bps`, 300 kbit/s) would only hold its pacer back (a 2 s paced session at
320x180 completed 9 frames of 60); 2 Mbit/s, the estimator's start before issue 48."""


@dataclass
class ServerSession:
    """The server side of one session (see the module docstring).

    ``tx`` is the session's transmission path; ``rtp_origin_ms`` is the driver time of
    scene time 0 (the RTP clock's origin, for sender reports).  Per frame the driver takes
    :meth:`order_frame`, makes and packetizes the update, and reports it with :meth:`frame_sent`;
    control messages go to :meth:`receive_message`, RTCP datagrams to :meth:`receive_datagram`.
    Everything the core sends leaves one way: after each of those calls, and when :meth:`get_timer`
    comes, the driver calls :meth:`datagrams_to_send` and sends what it gives (media, FEC,
    retransmissions, probes and sender reports, each tagged with its kind), in order.  The pacer,
    the probe clusters and the report schedule sit behind that one timer.
    """

    tx: ServerPipeline
    display_hz: float
    options: ServerOptions = field(default_factory=ServerOptions)
    clock_offset_us: int = 0
    rtp_origin_ms: float = 0.0
    rng: Any = None
    knobs: tuple[Any, ...] = ()
    """The method's operating-point knobs (its config's :meth:`~splitrender.methods.base.MethodConfig.adapt_knobs`),
    for ``adapt = "full"``; the resolution scale is added where a stream is scalable."""
    predictor: Any = None
    """The client's pose predictor (:mod:`splitrender.scene.predict`), on the driver's clock: the session's
    :attr:`poses` feed it, and :meth:`order_frame` asks it for the pose to render."""
    transport: str = "rtp"
    """``"rtp"``: the core owns the RTP transport (history and NACK answers, RTCP reports, transport-wide feedback,
    pacing); ``"webrtc"``: a WebRTC stack's does (the browser front door), and the core keeps the session's poses,
    feedback, keyframes and frame orders only."""
    conn: Any = None
    """The session's control ``ServerConnection`` (the handshake's, from :func:`accept_hello`): :meth:`frame_encoded`
    frames a frame's FrameMeta and reliable data on it, :meth:`receive_data` reads the client's bytes with it; what
    it frames leaves by :meth:`data_to_send`."""
    record_rows: bool = True
    """Whether the core records rows for :meth:`rows_to_write` (a driver that never takes them sets False: virtual
    time, which keeps its own tables)."""

    def __post_init__(self) -> None:
        self._control: deque[tuple[float, bytes]] = deque()
        """(driver ms from which it may leave, one framed message) for :meth:`data_to_send`, in order."""
        self._rows_out: list[tuple[str, dict[str, Any]]] = []
        self._rand = _uniform(self.rng)
        self.poses = PoseInbox(self.predictor)
        """The pose rule of every front door (:meth:`receive_pose`)."""
        self.fb = FeedbackState(self.display_hz, streams=self.tx.streams)
        self._kf = KeyframeRateLimiter(self.options.keyframe_min_interval_ms)
        self._kf_wanted = False
        self._last_tick = -1
        if self.transport not in ("rtp", "webrtc"):
            raise ConfigError(f"server transport: must be rtp or webrtc, got {self.transport!r}")
        self.streams: dict[str, _TxState] = {}
        for st in (self.tx.rtp_streams if self.transport == "rtp" else ()):
            self.streams[st.spec.name] = _TxState(st.spec.name, st.ssrc, RetransmissionHistory(self.options.history_packets),
                                                  st.packetizer)
        self._by_ssrc = {s.ssrc: s for s in self.streams.values()}
        self._fir_seq: dict[int, int] = {}
        self.peer: Any = None
        """The client's RTCP source address (:meth:`receive_datagram`'s ``addr``): None until the first datagram
        that parses, and in virtual time."""
        first = min(self._by_ssrc) if self._by_ssrc else 0
        self.cname = f"splitrender-server-{first:08x}".encode("ascii")
        """The session's RTCP CNAME (from its SSRCs, which are random: no draw of its own, so seeded runs keep theirs)."""
        self._next_sr_ms = math.inf
        self.rtt_ms: float | None = None
        cc = self.tx.transport_cc_id is not None
        self.send_history = SendHistory(window_us=5_000_000) if cc else None
        """Transport sequence numbers sent, for the client's transport-wide feedback (sessions with it only)."""
        gcc = self.options.gcc
        if self.options.adapt == "off" and gcc.start_bps < UNADAPTED_START_BPS <= gcc.max_bps:
            gcc = dataclasses.replace(gcc, start_bps=UNADAPTED_START_BPS)
        model = knobs_model(self.knobs)
        if self.options.adapt == "full" and model is not None and model.estimator:   # the method's own (QualityModel)
            try:
                gcc = dataclasses.replace(gcc, **dict(model.estimator))
            except TypeError as e:
                raise ConfigError(f"quality model estimator: {e}") from None
        self.estimator: BandwidthEstimator | ReceiverEstimate | None = BandwidthEstimator(gcc) if cc else None
        """The path's send-rate estimate from that feedback (:mod:`.gcc`); on the WebRTC transport with adaptation,
        the receiver's own estimate (REMB, :meth:`receive_estimate`)."""
        if self.transport == "webrtc" and self.options.adapt != "off":
            self.estimator = ReceiverEstimate(gcc)
        self.pacer: Pacer[tuple[Any, bytes]] | None = \
            Pacer(self.estimator.target_bps) if self.estimator is not None and self.options.pacing else None
        if self.options.adapt != "off" and self.estimator is None:
            raise ConfigError(f"server adapt {self.options.adapt}: follows the estimated rate, so it needs transport-wide "
                              "feedback (transport_cc) or, on the WebRTC transport, the receiver's estimate")
        self.rate: RateController | None = \
            RateController(controlled_streams(self.tx.specs), stream_fps(self.tx.specs), self.options.adapt_cfg) \
            if self.options.adapt in ("rate", "full") else None
        """Each lossy video stream's encoder rate from the estimate (``adapt = "rate"`` or ``"full"``)."""
        self.point: PointController | None = None
        """The method's operating point from the estimate (``adapt = "full"``, when the session has knobs)."""
        if self.options.adapt == "full" and self.rate is not None:
            knobs = tuple(self.knobs) + ((SCALE_KNOB,) if any(isinstance(s, StreamSpec) and s.scalable
                                                              for s in self.tx.specs) else ())
            if knobs:
                self.point = PointController(knobs, self.rate, self.options.adapt_cfg)
        self._base_fps = self.rate.fps if self.rate is not None else 0.0
        self._probe_seq = 0
        self._ready: deque[tuple[str, str | None, bytes, int]] = deque()
        """(kind, stream, datagram, probe cluster) to leave at the next :meth:`datagrams_to_send`, in order."""
        self._later: list[tuple[float, int, str, str | None, bytes, int]] = []
        """A heap of (time, order, kind, stream, datagram, probe cluster) that leave at their time: a frame's
        datagrams sent after its encoding (``frame_sent``'s ``send_ms``), a probe cluster's packets at its pace."""
        self._later_seq = 0
        self._pace_ms = math.inf
        """When the pacer lets its next datagram go (as of the last :meth:`datagrams_to_send`)."""
        self.counters: dict[str, int] = {
            "frames_sent": 0, "keyframes": 0, "keyframe_requests": 0, "plis": 0, "firs": 0, "nacks": 0, "retransmitted": 0,
            "rtp_packets": 0, "rtp_bytes": 0, "fec_packets": 0, "fec_bytes": 0, "feedback": 0, "lost_reported": 0,
            "rtcp_received": 0, "rtcp_sent": 0, "rtcp_bytes_sent": 0, "retransmitted_bytes": 0, "twcc_feedback": 0,
            "twcc_unknown": 0, "twcc_stamped": 0, "nack_duplicates": 0, "nack_datagram_capped": 0, "nack_rate_limited": 0,
            "rtcp_foreign": 0, "frames_skipped_late": 0, "frames_skipped_backlog": 0,
        }

    def owns_ssrc(self, ssrc: int) -> bool:
        return ssrc in self._by_ssrc

    # ------------------------------------------------------------------ input

    def start(self, now_ms: float) -> None:
        """Streaming starts at ``now_ms``: sender reports are due from then on."""
        self._next_sr_ms = now_ms + _rtcp_interval_ms(self.options.sr_interval_s, self._rand)

    def queue_control(self, frame: bytes, at_ms: float = -math.inf) -> None:
        """One message framed on :attr:`conn` for :meth:`data_to_send`, to leave from ``at_ms`` (default: at once)."""
        self._control.append((at_ms, frame))

    def data_to_send(self, now_ms: float) -> list[bytes]:
        """The control connection's output due at ``now_ms``, in order, one framed message each: the Welcome and the
        session data (:func:`accept_hello`), each frame's FrameMeta and reliable data from when its datagrams leave
        (:meth:`frame_sent`'s ``send_ms``).  Every front door on the RTP transport writes
        them to the client's TCP connection as they come (virtual time models each message as one write).  Call
        before :meth:`datagrams_to_send`, after each input; a driver that defers a frame's sending (virtual time's
        modelled encoding: ``send_ms``) calls it at that time too, which :meth:`get_timer` does not name (a frame's
        control frames are due from exactly ``send_ms``, so that they leave as they did when the runner wrote them
        itself: before the frame's datagrams or after, as the clocks' rounding fell)."""
        out = []
        while self._control and self._control[0][0] <= now_ms:
            out.append(self._control.popleft()[1])
        return out

    def receive_data(self, data: bytes) -> None:
        """Control bytes from the client (``b""``: the connection closed), for :attr:`conn`; what they say comes out
        of :meth:`next_event`."""
        self.conn.receive_data(data)

    def next_event(self, now_ms: float) -> SessionEvent | None:
        """What the driver must act on in the client's control bytes (:meth:`receive_data`), one at a time: the
        client's Stats, Bye or Error (:class:`ClientMessage`), or :class:`ControlClosed` once it closed the connection;
        None while more bytes are needed.  Every Pose, Feedback and KeyframeRequest before it is the core's
        (:meth:`receive_message`).  Raises ``RemoteProtocolError`` on malformed or illegal input (a message cut by
        the end of the stream among them)."""
        while True:
            msg = self.conn.next_event()
            if msg is CONNECTION_CLOSED:
                return ControlClosed(now_ms)
            if not isinstance(msg, Message):
                return None
            if not isinstance(msg, (Pose, Feedback, KeyframeRequest)):
                return ClientMessage(now_ms, msg)
            self.receive_message(msg, now_ms)

    def take_events(self, label: str, now_ms: float) -> Message | ControlClosed | None:
        """Every event in the client's control bytes so far (:meth:`next_event`), by the one rule of every server
        driver: the client's Stats logged at debug (``label`` naming the session); what ends the session logged and
        returned: its Bye or Error, or :class:`ControlClosed`; None while the session goes on."""
        while (ev := self.next_event(now_ms)) is not None:
            msg = ev.message if isinstance(ev, ClientMessage) else None
            if isinstance(msg, Stats):
                log.debug("%s: client stats %s", label, dict(msg.counters))
                continue
            if isinstance(msg, Bye):
                log.info("%s: client says bye: %s", label, msg.reason)
            elif isinstance(msg, Error):
                log.warning("%s: client left with Error %d: %s", label, msg.code, msg.text)
            else:
                log.info("%s: client closed the connection", label)
            return msg if msg is not None else ev
        return None

    def rows_to_write(self) -> list[tuple[str, dict[str, Any]]]:
        """The rows recorded since the last call, in order, as (kind, row): ``feedback`` (one per Feedback taken:
        :func:`~.rows.feedback_row`) and ``updates`` (one per frame a live front door sent: :meth:`frame_from_worker`'s,
        to which the driver may add its own columns before it calls this)."""
        out, self._rows_out = self._rows_out, []
        return out

    def _record(self, kind: str, row: dict[str, Any]) -> None:
        if self.record_rows:
            self._rows_out.append((kind, row))

    def receive_message(self, msg: Message, now_ms: float) -> float | None:
        """A ``Pose`` (:meth:`receive_pose_sample`), ``Feedback`` or ``KeyframeRequest`` from the control channel,
        in every front door that has one; the others (Stats, Bye, Error) are the driver's.  Returns the latency a
        Feedback measured (s), if any, and records the Feedback's row (:meth:`rows_to_write`); raises ``MessageError``
        for a request naming no stream of ours."""
        if isinstance(msg, Pose):
            self.receive_pose_sample(msg)
            return None
        if isinstance(msg, Feedback):
            self.counters["feedback"] += 1
            self.counters["lost_reported"] += sum(len(v) for v in msg.lost.values())
            latency = self.fb.on_feedback(msg)
            self._record("feedback", feedback_row(msg, self.fb.server_time_us(msg.frame_id)))
            return latency
        if isinstance(msg, KeyframeRequest):
            if msg.stream not in self.tx.streams:
                raise MessageError(f"KeyframeRequest.stream: unknown stream {msg.stream!r}")
            self.counters["keyframe_requests"] += 1
            self.request_keyframe(now_ms)
        return None

    def receive_pose_sample(self, msg: Any) -> bool:
        """A pose sample as the client sends it (a ``Pose`` message, or the page's sample: ``client_time_us``,
        ``seq``, ``position``, ``orientation``; measured on the protocol's clock), by the one rule of
        :meth:`receive_pose`.  Returns whether it was taken."""
        pose = ScenePose(np.array(msg.position), np.array(msg.orientation))
        return self.receive_pose(msg.client_time_us / 1e6, pose, msg.client_time_us, msg.seq)

    def receive_pose(self, t_s: float, pose: Any, client_us: int = 0, seq: int = 0) -> bool:
        """A pose sample measured at ``t_s`` (the driver's clock); taken when newer than the newest
        (:class:`PoseInbox`).  Returns whether it was taken."""
        return self.poses.offer(t_s, pose, client_us, seq)

    def _receive_rtcp(self, packets: list[RtcpPacket], now_ms: float) -> None:
        """A compound RTCP packet from the client (parsed by :meth:`receive_datagram`, the one RTCP entry).  The RTP packets it resends (NACKs, within the bounds of
        :meth:`_answer_nack`) leave by :meth:`datagrams_to_send`, of kind ``resend``, like everything it sends."""
        self.counters["rtcp_received"] += 1
        resend: list[bytes] = []
        refused: dict[int, str] = {}   # media SSRC: the counter of why its later requests here go unread
        for p in packets:
            if isinstance(p, GenericNack):
                st = self._by_ssrc.get(p.media_ssrc)
                if st is None:
                    continue
                self.counters["nacks"] += 1
                why = refused.get(p.media_ssrc) or \
                    ("nack_datagram_capped" if len(resend) >= self.options.nack_max_per_datagram else None)
                if why is None:
                    why = self._answer_nack(st, p, now_ms, resend)
                    if why is not None:
                        refused[p.media_ssrc] = why
                else:
                    self.counters[why] += len(p.lost)
            elif isinstance(p, PictureLossIndication):
                if p.media_ssrc in self._by_ssrc:
                    self.receive_picture_loss(now_ms)
            elif isinstance(p, FullIntraRequest):   # RFC 5104 4.3.1.2: a repeated sequence number is the same request
                for media, seq in p.requests:
                    if media in self._by_ssrc and self._fir_seq.get(media) != seq:
                        self._fir_seq[media] = seq
                        self.counters["firs"] += 1
                        self.request_keyframe(now_ms)
            elif isinstance(p, ReceiverReport):
                for b in p.reports:
                    if b.ssrc in self._by_ssrc and b.lsr:
                        now_mid = ntp_middle32(ntp_from_seconds(self._protocol_s(now_ms)))
                        rtt = ((now_mid - b.lsr - b.dlsr) & 0xFFFFFFFF) / 65536 * 1000
                        if rtt < 10_000:
                            self.rtt_ms = rtt
                            if self.estimator is not None:
                                self.estimator.set_rtt(int(rtt * 1000))
            elif isinstance(p, TransportFeedback) and isinstance(self.estimator, BandwidthEstimator) and self.send_history is not None:
                self.counters["twcc_feedback"] += 1
                before = self.send_history.unknown
                results = self.send_history.on_feedback(p)
                self.counters["twcc_unknown"] += self.send_history.unknown - before
                self.estimator.on_feedback(results, int(round(now_ms * 1000)))
        self._queue([("resend", None, d) for d in resend], now_ms)

    def _answer_nack(self, st: _TxState, nack: GenericNack, now_ms: float, resend: list[bytes]) -> str | None:
        """Append to ``resend`` (this datagram's answers so far) the kept packets ``nack`` asks for, as libwebrtc
        would: a packet resent less than max(RTT, ``nack_min_resend_ms``) ago is not resent again
        (``nack_duplicates``); at ``nack_max_per_datagram`` answers in the datagram its remaining requests are
        refused unread (``nack_datagram_capped``); and a stream resends in any second at most ``nack_rate_share`` of
        the media bytes it sent in that second plus ``nack_rate_floor_bytes``: the first packet over that refuses the
        stream's remaining requests in the datagram unread (``nack_rate_limited``).  Sequence numbers no longer kept
        are passed over.  Returns the counter of the refusal that ends the datagram's answers (for the stream, or
        for all with the cap), or None."""
        o = self.options
        lost = nack.lost
        hold_ms = max(o.nack_min_resend_ms, self.rtt_ms or 0.0)
        allowance = o.nack_rate_share * st.media.total(now_ms) + o.nack_rate_floor_bytes - st.resent.total(now_ms)
        sent = 0
        why: str | None = None
        for i, seq in enumerate(lost):
            pkt = st.history.get(seq)
            if pkt is None:
                continue
            last = st.history.resent_ms(seq)
            if last is not None and now_ms < last + hold_ms:
                self.counters["nack_duplicates"] += 1
                continue
            if len(resend) >= o.nack_max_per_datagram:
                why = "nack_datagram_capped"
            elif len(data := bytes(pkt)) > allowance:
                why = "nack_rate_limited"
            if why is not None:
                self.counters[why] += len(lost) - i
                break
            allowance -= len(data)
            sent += len(data)
            st.history.mark_resent(seq, now_ms)
            resend.append(data)
            self.counters["retransmitted"] += 1
            self.counters["retransmitted_bytes"] += len(data)
        if sent:
            st.resent.add(now_ms, sent)
        return why

    def _stamp(self, data: bytes, now_ms: float, probe: int = -1) -> bytes:
        """An RTP datagram as it leaves now: with transport-wide feedback on, its next transport sequence number
        written in and its send time and size remembered (media, retransmissions and probes, ``probe`` naming a
        probe's cluster; FEC carries none)."""
        if self.send_history is None or self.tx.transport_cc_id is None:
            return data
        if read_transport_seq(data, self.tx.transport_cc_id) is None:
            return data
        seq = self.send_history.on_sent(int(round(now_ms * 1000)), len(data), probe)
        self.counters["twcc_stamped"] += 1
        return write_transport_seq(data, self.tx.transport_cc_id, seq)

    def _queue(self, items: list[tuple[str, str | None, bytes]], now_ms: float) -> None:
        """RTP datagrams ``(kind, stream, bytes)`` to send from ``now_ms``: through the pacer where there is one, else
        at the next :meth:`datagrams_to_send`."""
        if self.pacer is None:
            self._ready.extend((kind, stream, d, -1) for kind, stream, d in items)
            return
        us = int(round(now_ms * 1000))
        for item in items:
            self.pacer.enqueue(item, len(item[2]), us)

    def _later_push(self, at_ms: float, kind: str, stream: str | None, data: bytes, cluster: int = -1) -> None:
        heapq.heappush(self._later, (at_ms, self._later_seq, kind, stream, data, cluster))
        self._later_seq += 1

    def datagrams_to_send(self, now_ms: float) -> list[Datagram]:
        """Every datagram due to leave at ``now_ms``, stamped as it leaves, in sending order: what the pacer lets go
        (media, FEC, retransmissions), a frame's datagrams without a pacer, probe packets whose time has come, and
        the sender reports when due.  Call after every input and when :meth:`get_timer` comes."""
        while self._later and self._later[0][0] <= now_ms + TIME_EPS_MS:
            at_ms, _, kind, stream, data, cluster = heapq.heappop(self._later)
            if kind == "probe":       # a probe sets its own pace, beside the pacer
                self._ready.append((kind, stream, data, cluster))
            else:
                self._queue([(kind, stream, data)], at_ms)
        out: list[Datagram] = []
        if self.pacer is not None and self.estimator is not None:
            self.pacer.rate_bps = self.estimator.target_bps
            out += [Datagram(self._stamp(d, now_ms), kind, stream) for kind, stream, d in self.pacer.poll(int(round(now_ms * 1000)))]
            t = self.pacer.next_send_us(int(round(now_ms * 1000)))
            self._pace_ms = math.inf if t is None else t / 1000.0
        while self._ready:
            kind, stream, d, cluster = self._ready.popleft()
            out.append(Datagram(self._stamp(d, now_ms, cluster), kind, stream))
        out += [Datagram(d, "rtcp", None) for d in self._sender_reports(now_ms)]
        return out

    def get_timer(self) -> float:
        """When :meth:`datagrams_to_send` has something next (driver ms; ``inf``: nothing until an input): the next
        sender report, paced datagram, probe packet or frame sent after its encoding."""
        t = min(self._next_sr_ms if self.streams else math.inf, self._pace_ms)
        return min(t, self._later[0][0]) if self._later else t

    def _plan_probe(self, now_ms: float) -> None:
        """The probe cluster the estimator wants sent from ``now_ms`` (sessions that adapt; nothing otherwise): its
        padding packets join the datagrams to send, each at its time, spaced at the probe's rate, bypassing the
        pacer (the probe sets its own pace).  A probe packet is an RTP packet of the session's probe SSRC
        (``Welcome.method_params.probe_ssrc``) whose payload is zeros."""
        if self.estimator is None or self.rate is None or self.tx.probe_ssrc is None or self.tx.transport_cc_id is None:
            return
        wanted = self.rate.wanted_bps()
        if wanted is not None and self.point is not None and self.point.index > 0:
            # at a coarser point: what the richest point would send is what there is to find
            wanted = max(wanted, self.point.cost_bps(0) / self.options.adapt_cfg.headroom)
        if wanted is not None and self.estimator.target_bps >= wanted:
            return           # the estimate already carries all the session would send: nothing to find
        cl = self.estimator.probe(int(round(now_ms * 1000)))
        if cl is None:
            return
        if wanted is not None and cl.rate_bps > 1.5 * wanted:   # no faster than 1.5x what the session could use
            cl = dataclasses.replace(cl, rate_bps=1.5 * wanted)
        profile, body = one_byte_extension({self.tx.transport_cc_id: b"\0\0"})
        out = []
        for k in range(cl.packets):
            header = 12 + 4 + len(body)
            pkt = RtpPacket(self.tx.probe_payload_type, self._probe_seq & 0xFFFF, 0, self.tx.probe_ssrc,
                            bytes(max(0, cl.packet_bytes - header)), extension_profile=profile, extension_data=body)
            self._probe_seq += 1
            out.append((now_ms + k * cl.spacing_us() / 1000, bytes(pkt)))
        self.counters["probe_clusters"] = self.counters.get("probe_clusters", 0) + 1
        self.counters["probe_packets"] = self.counters.get("probe_packets", 0) + len(out)
        self.counters["probe_bytes"] = self.counters.get("probe_bytes", 0) + sum(len(d) for _, d in out)
        for at_ms, data in out:
            self._later_push(at_ms, "probe", None, data, cl.cluster)

    def receive_estimate(self, bps: float, now_ms: float) -> None:
        """The receiver's estimate of the path's rate (bit/s; RTCP REMB, which a WebRTC stack passes on): the
        rate and operating-point controllers follow it.  Only the WebRTC transport takes it (with RTP the core
        estimates from transport-wide feedback itself); elsewhere it is counted and ignored."""
        self.counters["estimates_received"] = self.counters.get("estimates_received", 0) + 1
        if isinstance(self.estimator, ReceiverEstimate):
            self.estimator.on_report(bps, int(round(now_ms * 1000)))

    def operating_point(self, now_ms: float) -> dict[str, Any] | None:
        """The knob values the next frame should be made with (``adapt = "full"``): the method's own for its server
        half (:meth:`~splitrender.methods.base.ServerHalf.set_knobs`) and ``scale`` for
        :meth:`~.sender.StreamEncoder.encode`; None without.  Call before :meth:`encoder_rates`."""
        if self.point is None or self.estimator is None:
            return None
        est = self.estimator      # the path's rate and queue, and the encoders' (draining) rate: the point decides
        if self.point.update(now_ms / 1000, est.target_bps, est.queue_ms(), est.encoder_bps()):
            self.counters["point_moves"] = self.point.moves
            assert self.rate is not None        # its rates are per second of the frames sent
            self.rate.fps = self._base_fps / self.point.frame_div
        return self.point.values()

    def skips(self, tick: int) -> bool:
        """Whether the operating point leaves server tick ``tick`` out (``frame_div``; call after
        :meth:`operating_point`)."""
        return self.point is not None and tick % self.point.frame_div != 0

    def encoder_rates(self) -> dict[str, float] | None:
        """The bit rate (kbit/s) each lossy video stream should encode the next frame at (``adapt = "rate"``), for
        :meth:`~.sender.StreamEncoder.encode`; None without rate adaptation."""
        if self.rate is None or self.estimator is None:
            return None
        div = self.point.frame_div if self.point is not None else 1   # an encoder takes its rate per frame at its fps
        return {n: scale_rate(v, div) for n, v in self.rate.targets_kbps(self.estimator.encoder_bps()).items()}

    def congestion(self) -> dict[str, float]:
        """The estimator's view now (empty without transport-wide feedback): ``cc_target_kbps`` (delay and loss
        based), ``cc_encoder_kbps`` (that less what drains a standing queue), ``cc_acked_kbps``, ``cc_queue_ms``."""
        est = self.estimator
        if est is None:
            return {}
        acked = est.acked_bps()
        out = {"cc_target_kbps": est.target_bps / 1000, "cc_encoder_kbps": est.encoder_bps() / 1000,
               "cc_acked_kbps": acked / 1000 if acked is not None else math.nan, "cc_queue_ms": est.queue_ms()}
        if self.pacer is not None:
            out["cc_pacer_packets"] = self.pacer.queued
        if self.rate is not None:
            out.update(self.rate.state())
        if self.point is not None:
            out.update(self.point.state())
        return out

    def summary(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        """A session's summary columns of what this core's controllers did, as the session had them: the estimator
        (the mean ``cc_target_kbps`` of its update rows ``rows``, transport-wide feedback taken and packets it could not
        match, overuses), rate adaptation (encoder restarts, probe clusters and packets) and the operating point (its
        moves, and the lowest point: the largest index the rows name)."""
        s: dict[str, Any] = {}
        if self.estimator is not None:
            s.update({"mean_cc_target_kbps": mean_of(rows, "cc_target_kbps"), "twcc_feedback": self.counters["twcc_feedback"],
                      "twcc_unknown": self.counters["twcc_unknown"],
                      "cc_overuses": getattr(self.estimator, "overuses", 0)})   # a receiver's estimate has none
        if self.rate is not None:
            s.update({k: self.counters.get(k, 0) for k in ("encoder_restarts", "probe_clusters", "probe_packets")})
        if self.point is not None:
            pts = [u["adapt_point"] for u in rows if "adapt_point" in u]
            s.update({"point_moves": self.point.moves, "lowest_point": int(max(pts)) if pts else 0})
        return s

    def receive_datagram(self, data: bytes, now_ms: float, addr: Any = None) -> None:
        """A compound RTCP datagram from the client (the one RTCP entry of both clocks); malformed RTCP is counted (``rtcp_bad``) and
        ignored.  ``addr``, where the driver has one (a live socket): the datagram's source.  The first datagram that
        parses binds :attr:`peer`; one from any other source is then counted (``rtcp_foreign``) and dropped
        unparsed."""
        if self.peer is not None and addr != self.peer:
            self.counters["rtcp_foreign"] += 1
            return
        try:
            packets = parse_rtcp(data)
        except RtcpError:
            self.counters["rtcp_bad"] = self.counters.get("rtcp_bad", 0) + 1
            return
        self.peer = addr
        self._receive_rtcp(packets, now_ms)

    def receive_picture_loss(self, now_ms: float) -> None:
        """A PLI naming one of our streams (from :meth:`receive_datagram`, or passed on by a WebRTC stack): counted
        (``plis``), and an IDR requested."""
        self.counters["plis"] += 1
        self.request_keyframe(now_ms)

    def all_counters(self) -> dict[str, Any]:
        """The core's counters, with its pose rule's (``poses_received``, ``poses_stale``) and, with a pacer, the
        packets still queued or dropped by a full queue (a frame's packets are counted when it is sent): what every
        server front door reports, beside its own."""
        pacer = {} if self.pacer is None else {"pacer_queued": self.pacer.queued, "pacer_dropped": self.pacer.dropped}
        return {**self.counters, **self.poses.counters(), **pacer}

    def request_keyframe(self, now_ms: float) -> None:
        """Ask for an IDR on every stream (rate-limited; a suppressed request is kept)."""
        if self._kf.request(now_ms):
            self._kf_wanted = True

    # ------------------------------------------------------------------ frames

    def keyframe_due(self, now_ms: float) -> bool:
        """Whether the next frame must be a keyframe (a request was granted); consumes it."""
        kf = self._kf_wanted or self._kf.poll(now_ms)
        self._kf_wanted = False
        return kf

    def order_tick(self, tick: int, fps: float, now_ms: float, epoch_s: float = 0.0) -> FrameOrder | None:
        """The live front doors' frame clock: :meth:`order_frame` for the next frame (numbered by the frames sent so
        far) on tick ``tick`` of the shared grid at ``fps`` (scene time ``tick / fps``), or on the tick after the last
        one ordered, so that no two frames share a tick."""
        tick = max(tick, self._last_tick + 1)
        self._last_tick = tick
        return self.order_frame(self.counters["frames_sent"], tick, tick / fps, now_ms, epoch_s)

    def live_tick(self, skipped: int = 0, ready: bool = True, backlog: bool = False) -> bool:
        """Whether a tick of a live front door's frame clock, after ``skipped`` ticks it missed (rendering overran:
        counted in ``frames_skipped_late``), may make a frame (:meth:`order_at`).  None is made before the path is
        ``ready`` (the driver's: the page connected), on the RTP transport before the client's address is known
        (:attr:`peer`), or before a pose; nor while the last frames have not left (``backlog``: counted in
        ``frames_skipped_backlog``; stale frames are dropped, not queued)."""
        self.counters["frames_skipped_late"] += skipped
        if not ready or (self.transport == "rtp" and self.peer is None) or self.poses.latest is None:
            return False
        if backlog:
            self.counters["frames_skipped_backlog"] += 1
        return not backlog

    def order_at(self, now_ms: float, fps: float, epoch_s: float) -> FrameOrder | None:
        """:meth:`order_tick` on the tick of the shared grid at ``fps`` at driver time ``now_ms`` (the wall clock,
        whose ``epoch_s`` is the grid's scene time 0)."""
        return self.order_tick(int(round((now_ms / 1000 - epoch_s) * fps)), fps, now_ms, epoch_s)

    def update_row(self, order: FrameOrder, out: OutgoingFrame, enc: EncodedUpdate, stages: dict[str, float],
                   streams: Iterable[str]) -> dict[str, Any]:
        """The row of frame ``order`` that every front door writes (:func:`~.rows.update_row`: ``out`` on the wire,
        the stages of making ``enc``, the wire bytes of ``streams``), with the estimator's state now."""
        return update_row(order.frame_id, order.t_s, out, enc, order, stages, streams, self.congestion())

    def order_frame(self, frame_id: int, tick: int, t_s: float, now_ms: float, epoch_s: float = 0.0,
                    client: int = 0) -> FrameOrder | None:
        """What server frame ``frame_id`` (tick ``tick`` of the shared grid, scene time ``t_s``) must be, decided at
        driver time ``now_ms``: None where the operating point leaves the tick out (counted) or no pose has come yet;
        else the order :func:`~.frames.make_frame` makes.  ``epoch_s``: the driver time of scene time 0 (the
        predictor runs on the driver's clock, the order's times on the scene's).  Consumes a due keyframe."""
        latest = self.poses.latest
        if latest is None:
            return None
        point = self.operating_point(now_ms)
        if self.skips(tick):
            self.counters["frames_skipped_adapt"] = self.counters.get("frames_skipped_adapt", 0) + 1
            return None
        kf = self.keyframe_due(now_ms)
        expected = self.fb.latency.value_s
        pose_t, pose, pose_us, seq = latest
        target_clock = now_ms / 1000 + expected
        return FrameOrder(frame_id, tick, t_s, kf, expected, pose, pose_t - epoch_s, pose_us, seq,
                          self.predictor.predict(target_clock), target_clock - epoch_s, self.predictor, epoch_s,
                          self.fb.snapshot(kf), point, self.encoder_rates(), self.options.adapt_cfg, client)

    def frame_encoded(self, order: FrameOrder, enc: EncodedUpdate, now_ms: float, server_time_us: int,
                      timing: dict[str, int] | None = None, stats: dict[str, Any] | None = None,
                      send_ms: float | None = None) -> OutgoingFrame:
        """``order``'s frame came back made (``enc``: :func:`~.frames.make_frame`'s coded update) at ``now_ms``, at
        ``server_time_us`` on the protocol's clock, in every front door.  On the RTP transport it is packetized (its
        FrameMeta and reliable data framed on :attr:`conn`, stamped with ``timing`` and ``stats``) and reported
        (:meth:`frame_sent`, ``send_ms`` as there): its control frames leave by :meth:`data_to_send`, its datagrams
        by :meth:`datagrams_to_send`.  On the WebRTC transport the stack packetizes: the frame is counted from its
        coded streams.  Returns what the frame puts on the wire."""
        if self.transport == "rtp":
            out = self.tx.packetize(enc, self.conn.send, server_time_us, rtp_timestamp(order.t_s), order.pose_us,
                                    order.pose_seq, order.target_t_s, timing or {}, stats or {})
        else:
            out = OutgoingFrame(order.frame_id, keyframe=enc.keyframe, wire_bytes={n: len(f.data) for n, f in enc.video.items()},
                                idr_streams=tuple(n for n, f in enc.video.items() if f.keyframe))
        self.frame_sent(order.frame_id, out, now_ms, server_time_us, enc.rates_kbps, enc.restarts, send_ms)
        return out

    def frame_from_worker(self, order: FrameOrder, enc: EncodedUpdate, stats: dict[str, Any], stages: dict[str, float],
                          wall_s: float, now_ms: float) -> tuple[OutgoingFrame, dict[str, Any]]:
        """A live front door's frame ``order``, ordered at wall-clock ``wall_s`` (its server time) and back from the
        render worker at ``now_ms`` (the wall clock too) with its stages (:meth:`~.live.LiveSession._make_frame`'s,
        ``worker_rtt_ms`` among them): reported (:meth:`frame_encoded`, the FrameMeta stamped with the worker's
        ``render``, ``encode`` and ``shared`` times and when it was encoded), with its update row (:meth:`update_row`
        over the session's streams, and the server time, the probes' relighting and the worker round trip), which
        :meth:`rows_to_write` gives.  On the RTP transport it counts the FrameMeta's payload (``meta_bytes``) and the
        wire bytes of the frame's data streams (``data_bytes``).  Returns what the frame puts on the wire, and the
        row."""
        t_us = int(wall_s * 1e6)
        timing = {"render": int(stages["produce_ms"] * 1000), "encode": int(enc.encode_ms * 1000),
                  "encoded_at": int(now_ms * 1000), "shared": int(stages["shared_ms"] * 1000)}
        out = self.frame_encoded(order, enc, now_ms, t_us, timing, stats)
        streams = self.tx.bytes_sent if self.transport == "rtp" else [s.name for s in self.tx.specs]
        row = {**self.update_row(order, out, enc, stages, streams), "server_us": t_us, "gi_ms": stages["gi_ms"],
               "worker_rtt_ms": stages["worker_rtt_ms"]}
        if self.transport == "rtp":
            for key, n in (("meta_bytes", out.payload_bytes.get("meta", 0)),
                           ("data_bytes", sum(v for k, v in out.wire_bytes.items() if k != "meta" and k not in self.streams))):
                self.counters[key] = self.counters.get(key, 0) + n
        self._record("updates", row)
        return out, row

    def frame_sent(self, frame_id: int, out: OutgoingFrame, now_ms: float, server_time_us: int,
                   rates_kbps: dict[str, float] | None = None, restarts: int = 0, send_ms: float | None = None) -> None:
        """Frame ``frame_id`` was made at ``now_ms``: its RTP packets join the retransmission history; its
        FrameMeta and reliable data leave by :meth:`data_to_send`, then they and its FEC by :meth:`datagrams_to_send`,
        from ``send_ms`` (default ``now_ms``; virtual time's modelled encoding ends later), when the estimator also
        probes.  ``rates_kbps`` and ``restarts``: the
        encoder rates it was coded at and the encoders restarted for it (its :class:`~.sender.EncodedUpdate`'s),
        for the rate controller."""
        self.fb.frame_sent(frame_id, server_time_us)
        if out.keyframe:
            self.counters["keyframes"] += 1
            self._kf.keyframe_sent(now_ms)
        media: dict[str, int] = {}
        for name, pkt, data in out.datagrams:
            self.streams[name].history.store(pkt)
            media[name] = media.get(name, 0) + len(data)
            self.counters["rtp_packets"] += 1
            self.counters["rtp_bytes"] += len(data)
        for name, n in media.items():
            self.streams[name].media.add(now_ms, n)
        for _, data in out.fec:
            self.counters["fec_packets"] += 1
            self.counters["fec_bytes"] += len(data)
        self.counters["frames_sent"] += 1
        if self.rate is not None:
            div = self.point.frame_div if self.point is not None else 1
            self.rate.on_frame_sent(out.wire_bytes, {n: scale_rate(v, 1 / div) for n, v in rates_kbps.items()} if rates_kbps else None,
                                    idr_streams=out.idr_streams)
            if self.point is not None:
                self.point.on_frame_sent()
            self.counters["encoder_restarts"] = self.counters.get("encoder_restarts", 0) + restarts
        if self.transport == "rtp":
            at = now_ms if send_ms is None else send_ms
            for _, frame in out.control:     # its FrameMeta and reliable data leave first, by data_to_send
                self.queue_control(frame, at)
            items = [("rtp", name, data) for name, _, data in out.datagrams] + [("fec", None, d) for _, d in out.fec]
            if at <= now_ms:
                self._queue(items, at)
            else:
                for kind, stream, data in items:
                    self._later_push(at, kind, stream, data)
            self._plan_probe(at)

    # ------------------------------------------------------------------ timers

    def _protocol_s(self, now_ms: float) -> float:
        return (self.clock_offset_us + now_ms * 1000) / 1e6

    def _sender_reports(self, now_ms: float) -> list[bytes]:
        """Sender reports, one compound packet for every RTP stream, when due."""
        if now_ms + TIME_EPS_MS < self._next_sr_ms or not self.streams:
            return []
        self._next_sr_ms = now_ms + _rtcp_interval_ms(self.options.sr_interval_s, self._rand)
        ntp = ntp_from_seconds(self._protocol_s(now_ms))
        rtp_now = int(round((now_ms - self.rtp_origin_ms) / 1000 * RTP_CLOCK_HZ)) & 0xFFFFFFFF
        reports: list[RtcpPacket] = [SenderReport(st.ssrc, ntp, rtp_now, st.packetizer.packets_sent & 0xFFFFFFFF,
                                                  st.packetizer.octets_sent & 0xFFFFFFFF) for st in self.streams.values()]
        # every compound packet carries SDES CNAME (RFC 3550 6.1): one name for all the session's streams, so a
        # receiver knows to synchronise them
        cname = self.cname
        reports.append(SourceDescription(tuple(SdesChunk(st.ssrc, ((SDES_CNAME, cname),)) for st in self.streams.values())))
        data = serialize_rtcp(reports)
        self.counters["rtcp_sent"] += 1
        self.counters["rtcp_bytes_sent"] += len(data)
        return [data]
