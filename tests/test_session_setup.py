"""Both live front doors refuse a session the same way (issue 47): a busy server's words
(:func:`~splitrender.pipeline.live.busy_refusal`) and the set-up's failures
(:meth:`~splitrender.pipeline.live.LiveSession.set_up`: the peer's protocol error leaves as itself, our own failure is
logged, told to the peer as ``session setup failed: ...`` and ends that session only)."""

from __future__ import annotations

import logging
from types import SimpleNamespace
from typing import Any

import pytest

from splitrender.errors import RemoteProtocolError
from splitrender.pipeline.live import LiveSession, busy_refusal
from splitrender.server.server import ServerConfig
from splitrender.webrtc.session import BrowserSession


class _Told(LiveSession):
    """A session whose door only keeps what it told its peer."""

    def __init__(self) -> None:
        super().__init__(SimpleNamespace(config=ServerConfig()), 1)  # type: ignore[arg-type]
        self.told: list[tuple[Any, str]] = []

    async def _send_error(self, exc: RemoteProtocolError | int, text: str = "") -> None:
        self.told.append((exc, text))


def test_a_busy_server_says_how_many_sessions_it_runs() -> None:
    assert busy_refusal(0, 1) is None and busy_refusal(3, 4) is None
    assert busy_refusal(4, 4) == "server busy: 4 sessions already"
    assert busy_refusal(5, 4) == "server busy: 5 sessions already"   # the browser's count adds its active pages


async def test_set_up_answers_our_failure_and_passes_the_peers_protocol_error(caplog: pytest.LogCaptureFixture) -> None:
    async def made() -> str:
        return "accepted"

    async def ours() -> str:
        raise RuntimeError("no encoder today")

    async def theirs() -> str:
        raise RemoteProtocolError("bad Hello")

    s = _Told()
    assert await s.set_up(made()) == "accepted" and s.told == []
    with caplog.at_level(logging.ERROR):
        assert await s.set_up(ours()) is None
    assert s.told == [(500, "session setup failed: RuntimeError: no encoder today")]
    assert [r.exc_info is not None for r in caplog.records if f"session {s.id}: setup for" in r.getMessage()] == [True]
    with pytest.raises(RemoteProtocolError, match="bad Hello"):
        await s.set_up(theirs())
    assert len(s.told) == 1


async def test_a_browser_session_whose_set_up_failed_ends_with_the_error() -> None:
    """The browser's front door answers a failed set-up with the session's end reason (a 500 naming it)."""
    front = SimpleNamespace(server=SimpleNamespace(config=ServerConfig()))
    s = BrowserSession(front, SimpleNamespace(method="video", display_hz=60.0), 1)  # type: ignore[arg-type]

    async def ours() -> None:
        raise ValueError("no GL")

    assert await s.set_up(ours()) is None
    assert s.ended.is_set() and s.end_reason == "session setup failed: ValueError: no GL"
