"""One transmission path for both modes (DESIGN.md, "one pipeline").

:class:`StreamEncoder` and :class:`ServerPipeline` (encode; packetize and count: a session holds one of each) and :class:`ClientPipeline`
(reassemble, jitter buffer, decode, release in order with partial delivery) are
sans-IO: they take time and bytes in and give bytes and updates out.  The live server
and client drive them with sockets and the wall clock; the virtual-time runner drives
them with the network model on a simulated clock.  :mod:`.feedback` holds both ends
of the feedback loop, :mod:`.producers` the scene producers shared by sessions, and
:mod:`.wire` the byte-counting model and the update envelope; :mod:`.session` the sans-IO
session cores (RTCP, NACK, PLI, playout, stalls) that both drivers run, and :mod:`.frames` a server
frame's order (the core's) and its making (:func:`make_frame`, wherever the GL context lives); :mod:`.live`
the session the two live server front doors share around the core (not sans-IO: asyncio, a render worker).
"""

from .direct import StillFrame, server_context, still_frame
from .frames import FrameMaker, FrameOrder, apply_updates, black_frame, display_frame, make_frame
from .feedback import FeedbackState, FeedbackTracker, LatencyEstimator
from .producers import ProducerPool
from .receiver import ClientPipeline, ReceivedFrame, SessionAssembler, Work
from ..options import ClientOptions
from .session import (CLIENT_CODECS, Accepted, Opening, ClientHandshake, ClientSession, ControlClosed, FrameReleased, PoseInbox, Resumed, ServerMessage,
                      ServerOptions, ServerSession, SessionEvent,
                      SessionTerms, Stalled, StallTimeout, accept_hello, accept_page, check_hello, parse_welcome,
                      method_config, open_hello, open_page, session_params,
                      session_summary, shows_anything)
from .sender import EncodedUpdate, OutgoingFrame, ServerPipeline, StreamEncoder, rtp_timestamp
from .wire import (DEFAULT_MAX_SESSION_BYTES, META_STREAM, SESSION_STREAM, Envelope, EnvelopeError, SessionDataError,
                   control_wire_bytes, datagram_wire_bytes, specs_from_table, tcp_segments)

__all__ = [
    "ClientHandshake", "ClientOptions", "ClientSession", "ControlClosed", "FrameReleased", "PoseInbox", "ServerMessage", "Resumed", "ServerOptions", "ServerSession", "SessionEvent",
    "Accepted", "Opening", "accept_hello", "accept_page", "method_config", "open_hello", "open_page", "apply_updates", "CLIENT_CODECS",
    "SessionTerms", "Stalled", "StallTimeout", "check_hello", "parse_welcome", "session_params",
    "session_summary", "shows_anything",
    "StillFrame", "server_context", "still_frame",
    "FrameMaker", "FrameOrder", "black_frame", "display_frame", "make_frame", "StreamEncoder",
    "ClientPipeline", "DEFAULT_MAX_SESSION_BYTES", "EncodedUpdate", "Envelope", "EnvelopeError", "FeedbackState",
    "FeedbackTracker", "LatencyEstimator", "META_STREAM", "OutgoingFrame", "ProducerPool", "ReceivedFrame",
    "SESSION_STREAM", "ServerPipeline", "SessionAssembler", "SessionDataError", "Work", "control_wire_bytes",
    "datagram_wire_bytes", "rtp_timestamp", "specs_from_table", "tcp_segments",
]
