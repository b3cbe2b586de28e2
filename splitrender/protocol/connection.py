"""Session state machine for the control channel (sans-IO).

Both ends track one shared session state.  Every legal transition is a row of
:data:`TRANSITIONS`: ``(sender role, state, message type) -> next state``.  Sending a
message not in the table raises ``LocalProtocolError``; receiving one raises
:class:`~splitrender.protocol.errors.StateError` naming the state and message type.
"""

from __future__ import annotations

import hmac
import logging
from collections.abc import Sequence
from enum import Enum

from splitrender.errors import LocalProtocolError, RemoteProtocolError
from splitrender.protocol.errors import (
    StateError,
    UnauthorizedError,
    UnsupportedMethodError,
    VersionError,
)
from splitrender.protocol.framing import (
    CONNECTION_CLOSED,
    FrameDecoder,
    Sentinel,
    encode_frame,
)
from splitrender.protocol.messages import (
    PROTOCOL_VERSION,
    Error,
    Hello,
    Message,
    MessageType,
)

__all__ = [
    "Role",
    "State",
    "TRANSITIONS",
    "Connection",
    "ClientConnection",
    "ServerConnection",
    "check_auth_token",
    "negotiate_method",
]

logger = logging.getLogger(__name__)


class Role(Enum):
    """Which end of the session."""

    CLIENT = "client"
    SERVER = "server"


class State(Enum):
    """Session states."""

    AWAIT_HELLO = "AWAIT_HELLO"
    AWAIT_WELCOME = "AWAIT_WELCOME"
    STREAMING = "STREAMING"
    CLOSED = "CLOSED"
    ERROR = "ERROR"


C, S = Role.CLIENT, Role.SERVER
T = MessageType
_OPEN = (State.AWAIT_HELLO, State.AWAIT_WELCOME, State.STREAMING)

TRANSITIONS: dict[tuple[Role, State, MessageType], State] = {
    # handshake
    (C, State.AWAIT_HELLO, T.HELLO): State.AWAIT_WELCOME,
    (S, State.AWAIT_WELCOME, T.WELCOME): State.STREAMING,
    # streaming
    (C, State.STREAMING, T.POSE): State.STREAMING,
    (C, State.STREAMING, T.FEEDBACK): State.STREAMING,
    (C, State.STREAMING, T.KEYFRAME_REQUEST): State.STREAMING,
    (C, State.STREAMING, T.STATS): State.STREAMING,
    (S, State.STREAMING, T.FRAME_META): State.STREAMING,
    (S, State.STREAMING, T.DATA_CHUNK): State.STREAMING,
    (S, State.STREAMING, T.STATS): State.STREAMING,
    # closing: Bye from either side in any open state; Error also once in ERROR
    **{(r, st, T.BYE): State.CLOSED for r in (C, S) for st in _OPEN},
    **{(r, st, T.ERROR): State.ERROR for r in (C, S) for st in (*_OPEN, State.ERROR)},
    # an Error may still answer a malformed frame that follows a Bye; the session stays CLOSED
    **{(r, State.CLOSED, T.ERROR): State.CLOSED for r in (C, S)},
}
"""The only place session transitions are defined."""


def check_auth_token(expected: str, presented: str) -> bool:
    """Constant-time comparison of auth tokens."""
    return hmac.compare_digest(expected.encode("utf-8"), presented.encode("utf-8"))


def negotiate_method(offered: Sequence[str], supported: Sequence[str]) -> str:
    """First of the client's ``offered`` methods that the server ``supported``.

    Raises :class:`UnsupportedMethodError` if there is none.
    """
    for m in offered:
        if m in supported:
            return m
    raise UnsupportedMethodError(
        f"Hello.methods: none of {list(offered)} is supported (server has {list(supported)})"
    )


class Connection:
    """One end of a control session: bytes in, messages out and vice versa."""

    def __init__(self, role: Role) -> None:
        self.role = role
        self.peer_role = Role.SERVER if role is Role.CLIENT else Role.CLIENT
        self.state = State.AWAIT_HELLO
        self._decoder = FrameDecoder()
        self._failed = False

    def _advance(self, sender: Role, msg_type: MessageType) -> State | None:
        return TRANSITIONS.get((sender, self.state, msg_type))

    def send(self, msg: Message, compress: bool | None = None) -> bytes:
        """Bytes to write for ``msg``; raises ``LocalProtocolError`` if illegal now."""
        nxt = self._advance(self.role, msg.TYPE)
        if nxt is None:
            raise LocalProtocolError(
                f"{self.role.value} cannot send {type(msg).__name__} in state {self.state.value}"
            )
        data = encode_frame(msg, compress)
        logger.debug("%s send %s: %s -> %s", self.role.value, msg.TYPE.name, self.state.value, nxt.value)
        self.state = nxt
        return data

    def send_error(self, exc: RemoteProtocolError | int, text: str = "") -> bytes:
        """Bytes of an ``Error`` message for a peer error (or a bare code)."""
        if isinstance(exc, RemoteProtocolError):
            msg = Error(code=exc.code, text=str(exc)[:1024])
        else:
            msg = Error(code=int(exc), text=text[:1024])
        return self.send(msg)

    def receive_data(self, data: bytes) -> None:
        """Feed bytes from the transport; ``b""`` means EOF."""
        self._decoder.receive_data(data)

    def next_event(self) -> Message | Sentinel:
        """Next peer message, ``NEED_DATA`` or ``CONNECTION_CLOSED``.

        Raises a ``RemoteProtocolError`` subclass on malformed or illegal input; the
        state becomes ERROR (an ``Error`` message may still be sent).
        """
        if self.state is State.ERROR and self._failed:
            raise StateError("connection is in state ERROR")
        try:
            event = self._decoder.next_event()
            if isinstance(event, Sentinel):
                if event is CONNECTION_CLOSED and self.state in _OPEN:
                    self.state = State.CLOSED
                return event
            nxt = self._advance(self.peer_role, event.TYPE)
            if nxt is None:
                raise StateError(
                    f"{self.peer_role.value} sent {type(event).__name__} in state {self.state.value}"
                )
            self._check(event)
        except RemoteProtocolError:
            self._failed = True
            if self.state is not State.CLOSED:
                self.state = State.ERROR
            raise
        logger.debug(
            "%s recv %s: %s -> %s", self.role.value, event.TYPE.name, self.state.value, nxt.value
        )
        self.state = nxt
        return event

    def _check(self, msg: Message) -> None:
        """Role-specific validation of a legal incoming message."""


class ClientConnection(Connection):
    """Client end: sends ``Hello`` first, then waits for ``Welcome``."""

    def __init__(self) -> None:
        super().__init__(Role.CLIENT)


class ServerConnection(Connection):
    """Server end: checks ``Hello`` version and (optionally) the auth token."""

    def __init__(self, auth_token: str | None = None) -> None:
        super().__init__(Role.SERVER)
        self._auth_token = auth_token

    def _check(self, msg: Message) -> None:
        if isinstance(msg, Hello):
            if msg.version != PROTOCOL_VERSION:
                raise VersionError(
                    f"Hello.version: peer speaks protocol version {msg.version}, "
                    f"this side speaks version {PROTOCOL_VERSION}"
                )
            if self._auth_token is not None and not check_auth_token(
                self._auth_token, msg.auth_token
            ):
                raise UnauthorizedError("Hello.auth_token: invalid token")

