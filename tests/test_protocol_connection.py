"""Session state machine: handshake, illegal transitions both ways, auth, version."""

from __future__ import annotations

import msgpack
import pytest

from splitrender.errors import LocalProtocolError, RemoteProtocolError
from splitrender.protocol import (
    CONNECTION_CLOSED,
    NEED_DATA,
    TRANSITIONS,
    Bye,
    ClientConnection,
    Error,
    ErrorCode,
    Feedback,
    FrameMeta,
    Hello,
    KeyframeRequest,
    Pose,
    Role,
    ServerConnection,
    State,
    StateError,
    Stats,
    UnauthorizedError,
    UnsupportedMethodError,
    VersionError,
    Welcome,
    check_auth_token,
    negotiate_method,
)
from splitrender.protocol.framing import HEADER
from splitrender.protocol.messages import PROTOCOL_VERSION

HELLO = Hello(PROTOCOL_VERSION, "tok", ("sas", "video"), ("h264",), 1280, 720, 90.0)
WELCOME = Welcome("s1", "video", {}, ())
POSE = Pose(5, 1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
META = FrameMeta(1, 10, {"color": 0}, POSE, b"", True)


def _pump(src: ClientConnection | ServerConnection, dst: ClientConnection | ServerConnection, msg):
    dst.receive_data(src.send(msg))
    ev = dst.next_event()
    assert dst.next_event() is NEED_DATA
    return ev


def _streaming() -> tuple[ClientConnection, ServerConnection]:
    c, s = ClientConnection(), ServerConnection(auth_token="tok")
    assert _pump(c, s, HELLO) == HELLO
    assert c.state is s.state is State.AWAIT_WELCOME
    assert _pump(s, c, WELCOME) == WELCOME
    assert c.state is s.state is State.STREAMING
    return c, s


def test_full_session() -> None:
    c, s = _streaming()
    assert _pump(c, s, POSE) == POSE
    assert _pump(s, c, META) == META
    fb = Feedback(1, 2, 3, 4, 0, 5, {"render": 1})
    assert _pump(c, s, fb) == fb
    assert _pump(c, s, KeyframeRequest("color", "loss")).stream == "color"
    assert _pump(s, c, Stats({"fps": 60.0})) == Stats({"fps": 60.0})
    assert _pump(c, s, Bye("bye")) == Bye("bye")
    assert c.state is s.state is State.CLOSED
    with pytest.raises(LocalProtocolError, match=r"^client cannot send Pose in state CLOSED$"):
        c.send(POSE)
    s.receive_data(b"")
    assert s.next_event() is CONNECTION_CLOSED


def test_transition_table_is_the_only_source() -> None:
    assert TRANSITIONS[(Role.CLIENT, State.AWAIT_HELLO, HELLO.TYPE)] is State.AWAIT_WELCOME
    assert (Role.SERVER, State.STREAMING, POSE.TYPE) not in TRANSITIONS
    assert (Role.CLIENT, State.STREAMING, META.TYPE) not in TRANSITIONS


@pytest.mark.parametrize(
    ("who", "msg", "text"),
    [
        ("client", POSE, r"^client cannot send Pose in state AWAIT_HELLO$"),
        ("client", WELCOME, r"^client cannot send Welcome in state AWAIT_HELLO$"),
        ("server", WELCOME, r"^server cannot send Welcome in state AWAIT_HELLO$"),
        ("server", META, r"^server cannot send FrameMeta in state AWAIT_HELLO$"),
    ],
)
def test_illegal_local_sends(who: str, msg, text: str) -> None:
    conn = ClientConnection() if who == "client" else ServerConnection()
    with pytest.raises(LocalProtocolError, match=text):
        conn.send(msg)
    assert conn.state is State.AWAIT_HELLO


def test_illegal_local_sends_while_streaming() -> None:
    c, s = _streaming()
    with pytest.raises(LocalProtocolError, match=r"^client cannot send FrameMeta in state STREAMING$"):
        c.send(META)
    with pytest.raises(LocalProtocolError, match=r"^server cannot send Pose in state STREAMING$"):
        s.send(POSE)
    with pytest.raises(LocalProtocolError, match=r"^client cannot send Hello in state STREAMING$"):
        c.send(HELLO)


def _raw(msg) -> bytes:
    from splitrender.protocol import encode_frame

    return encode_frame(msg)


def test_illegal_peer_messages() -> None:
    s = ServerConnection()
    s.receive_data(_raw(POSE))
    with pytest.raises(StateError, match=r"^client sent Pose in state AWAIT_HELLO$") as info:
        s.next_event()
    assert info.value.code == ErrorCode.ILLEGAL_STATE
    assert s.state is State.ERROR
    # the offending session may still be told why
    err = s.send_error(info.value)
    c = ClientConnection()
    c.state = State.AWAIT_WELCOME
    c.receive_data(err)
    assert c.next_event() == Error(409, "client sent Pose in state AWAIT_HELLO")
    assert c.state is State.ERROR

    c, s = _streaming()
    c.receive_data(_raw(HELLO))
    with pytest.raises(StateError, match=r"^server sent Hello in state STREAMING$"):
        c.next_event()
    with pytest.raises(StateError):
        c.next_event()  # sticky
    c, s = _streaming()
    s.receive_data(_raw(META))
    with pytest.raises(StateError, match=r"^client sent FrameMeta in state STREAMING$"):
        s.next_event()


def test_wrong_version_in_hello() -> None:
    s = ServerConnection()
    s.receive_data(_raw(Hello(1, "", ("video",), ("h264",), 64, 64, 60.0)))
    with pytest.raises(
        VersionError,
        match=r"^Hello\.version: peer speaks protocol version 1, this side speaks version 2$",
    ) as info:
        s.next_event()
    assert info.value.code == 505
    s = ServerConnection()
    s.receive_data(HEADER.pack(b"SR", 3, 1, 0, 0))
    with pytest.raises(VersionError, match=r"^peer speaks protocol version 3, this side speaks version 2$"):
        s.next_event()


def test_auth() -> None:
    s = ServerConnection(auth_token="right")
    s.receive_data(_raw(HELLO))
    with pytest.raises(UnauthorizedError, match=r"^Hello\.auth_token: invalid token$") as info:
        s.next_event()
    assert info.value.code == ErrorCode.UNAUTHORIZED == 401
    assert isinstance(info.value, RemoteProtocolError)
    assert check_auth_token("abc", "abc") and not check_auth_token("abc", "abd")
    assert not check_auth_token("abc", "")


def test_negotiate_method() -> None:
    assert negotiate_method(["sas", "video"], ["video", "atw"]) == "video"
    with pytest.raises(UnsupportedMethodError, match=r"^Hello\.methods: none of \['x'\] is supported") as info:
        negotiate_method(["x"], ["video"])
    assert info.value.code == ErrorCode.UNSUPPORTED_METHOD


def test_error_reply_during_handshake_and_garbage() -> None:
    c = ClientConnection()
    s = ServerConnection()
    s.receive_data(c.send(HELLO))
    s.next_event()
    c.receive_data(s.send(Error(ErrorCode.UNSUPPORTED_METHOD, "no")))
    assert c.next_event() == Error(415, "no")
    assert c.state is State.ERROR
    s = ServerConnection()
    s.receive_data(b"GET / HTTP/1.1\r\n\r\n")
    with pytest.raises(RemoteProtocolError, match="bad frame magic"):
        s.next_event()
    assert s.state is State.ERROR
    s.receive_data(b"")


def test_eof_closes_and_bad_body_in_hello() -> None:
    s = ServerConnection()
    s.receive_data(b"")
    assert s.next_event() is CONNECTION_CLOSED
    assert s.state is State.CLOSED
    body = msgpack.packb({"version": 1})
    s = ServerConnection()
    s.receive_data(HEADER.pack(b"SR", PROTOCOL_VERSION, 1, 0, len(body)) + body)
    with pytest.raises(RemoteProtocolError, match=r"^Hello: missing field 'auth_token'$"):
        s.next_event()


def test_one_byte_at_a_time_session() -> None:
    c = ClientConnection()
    data = c.send(HELLO)
    s = ServerConnection()
    events = []
    for i in range(len(data)):
        s.receive_data(data[i : i + 1])
        ev = s.next_event()
        if ev is not NEED_DATA:
            events.append(ev)
    assert events == [HELLO] and s.state is State.AWAIT_WELCOME
