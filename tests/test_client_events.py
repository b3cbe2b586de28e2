"""The client core's one rule for its events and for what a leaving client tells the server
(:meth:`ClientSession.take_events`, :func:`leaving_error`), which the live client and the virtual-time runner both
follow."""

from __future__ import annotations

import asyncio
import logging
from types import SimpleNamespace

import pytest

from splitrender.errors import PeerTimeoutError, RemoteProtocolError, ServerRefusedError
from splitrender.pipeline import ClientOptions, ClientPipeline, ClientSession
from splitrender.pipeline.session import (ControlClosed, FrameReleased, Resumed, ServerMessage, Stalled, StallTimeout,
                                          StreamStalledError, leaving_error)
from splitrender.protocol import Bye, Error, ErrorCode, Stats


def _core(**opts: object) -> ClientSession:
    return ClientSession(ClientPipeline([], [], 100.0), ClientOptions(**opts), 30.0)  # type: ignore[arg-type]


def test_released_frames_come_back_in_order_and_stalls_are_logged(caplog: pytest.LogCaptureFixture) -> None:
    core = _core(stall_frames=6.0)
    a, b = SimpleNamespace(name="a"), SimpleNamespace(name="b")
    core.events += [FrameReleased(1.0, a), Stalled(2.0, 250.0), Resumed(3.0, 400.0),   # type: ignore[arg-type]
                    FrameReleased(4.0, b), ServerMessage(5.0, Stats({"x": 1}))]        # type: ignore[arg-type]
    with caplog.at_level(logging.DEBUG, logger="splitrender.pipeline.session"):
        assert core.take_events("session s1") == [a, b]
    levels = {r.getMessage().split(":")[1].strip().split(" ")[0]: r.levelno for r in caplog.records}
    assert levels == {"stalled": logging.WARNING, "frames": logging.INFO, "server": logging.DEBUG}, levels
    assert all(r.getMessage().startswith("session s1: ") for r in caplog.records)
    assert "(6 of the server's frame intervals)" in caplog.records[0].getMessage()
    assert core.next_event() is None
    # virtual time: a stall and its end at debug, and a stall timeout ends nothing (a run ends by its duration)
    caplog.clear()
    core.events += [Stalled(2.0, 250.0), StallTimeout(2.5, 5000.0), Resumed(3.0, 400.0), FrameReleased(4.0, a)]
    with caplog.at_level(logging.DEBUG, logger="splitrender.pipeline.session"):
        assert core.take_events("run video client 0", virtual=True) == [a]   # type: ignore[arg-type]
    assert [r.levelno for r in caplog.records] == [logging.DEBUG, logging.DEBUG]


@pytest.mark.parametrize("event,error,text", [
    (StallTimeout(9000.0, 5200.0), StreamStalledError,
     "session s1: no frame for 5.2 s (stall_timeout_s 5 s): the server stopped streaming"),
    (ServerMessage(1.0, Bye("shutting down")), ServerRefusedError, "server ended the session: shutting down"),
    (ServerMessage(1.0, Error(503, "busy")), ServerRefusedError, "server error 503: busy"),
    (ControlClosed(1.0), ConnectionResetError, "server closed the control connection"),
])
def test_what_ends_the_session_is_raised_after_the_events_before_it(event, error, text) -> None:
    core = _core()
    core.events += [FrameReleased(0.0, SimpleNamespace()), event, Resumed(2.0, 1.0)]   # type: ignore[arg-type]
    with pytest.raises(error) as err:
        core.take_events("session s1")
    assert str(err.value) == text
    assert isinstance(core.next_event(), Resumed)   # what came after is left


def test_a_leaving_client_says_why_by_one_rule() -> None:
    assert leaving_error(RemoteProtocolError("bad FrameMeta", 415)) == (415, "client: bad FrameMeta")
    assert leaving_error(StreamStalledError("no frame")) == (int(ErrorCode.TIMEOUT), "client: no frame")
    assert leaving_error(PeerTimeoutError("no Welcome")) == (int(ErrorCode.TIMEOUT), "client: no Welcome")
    code, text = leaving_error(ValueError("oops"))   # type: ignore[misc]
    assert code == int(ErrorCode.INTERNAL) and text.startswith("client failed: ") and "oops" in text
    # no one to tell: the server ended or refused the session, or the connection is gone
    for exc in (ServerRefusedError("bye"), ConnectionResetError(), asyncio.IncompleteReadError(b"", 4)):
        assert leaving_error(exc) is None
