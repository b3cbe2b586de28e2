"""What the two live front doors share around the server core: :class:`LiveSession`, the base of the live server's
session (:class:`splitrender.server.session.ServerSession`: the protocol over TCP, RTP/RTCP over UDP) and of the
browser's (:class:`splitrender.webrtc.session.BrowserSession`: a WebRTC peer connection).

Both run one session against a render worker (another process, :mod:`splitrender.server.worker`) on the server's
shared frame grid: the method's server half and encoders are opened there (:meth:`LiveSession._open_worker`); each tick
the core's rule (:meth:`~.session.ServerSession.live_tick`) says whether a frame may be made, the core orders it, the
worker makes and encodes it (:meth:`LiveSession._make_frame`) and the door sends it its own way
(:meth:`LiveSession._deliver`); the core's rows are written as they come.  The session's tasks run in one task group,
and what ends it (its peer leaving, a protocol error, a lost connection, our own failure, the server's shutdown) is
handled here once, each door saying how it tells its peer (:meth:`LiveSession._send_error`,
:meth:`LiveSession._say_bye`).  At the end the worker is handed back and the core's last rows and the session's
counters are written (:meth:`LiveSession.close`).

The base lives here, below both doors, because the server package imports the browser's (the server starts the
browser front door) and the browser's uses the server's render workers: in either package it would close an import
circle.  It imports neither, and names what it uses of the server instead (:class:`LiveServer`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from collections.abc import AsyncIterator, Awaitable, Coroutine
from pathlib import Path
from typing import Any, Protocol, TypeVar

from ..errors import (PeerTimeoutError, RemoteProtocolError, WorkerDied, WorkerError, WorkerTimeout,
                      describe_error)
from ..protocol import ErrorCode
from .frames import FrameOrder
from .recording import MetricsLog, SessionLogs
from .sender import EncodedUpdate
from .session import ServerSession

__all__ = ["LiveServer", "LiveSession", "MadeFrame", "SessionEnded", "busy_refusal", "wait_for_timer"]

Address = tuple[str, int]
T = TypeVar("T")

MadeFrame = tuple[FrameOrder, EncodedUpdate, dict[str, Any], dict[str, float], float]
"""A frame back from the render worker (:meth:`LiveSession._make_frame`): its order, its coded update, the method
half's stats, its stages (ms) and the wall clock it was ordered at (s)."""


async def wait_for_timer(delay_ms: float, cap_s: float, wake: asyncio.Event | None = None) -> float:
    """A live front door's wait for its core's one timer, due in ``delay_ms`` (:meth:`~.session.ServerSession.get_timer`
    less the wall clock; at once where it is past), at most ``cap_s``, or until ``wake`` is set (an input may have moved
    the deadline; it is cleared).  Returns how much later than asked the event loop woke it (ms; GL or decode work
    holding the interpreter lock)."""
    wait = max(0.0, min(cap_s, delay_ms / 1000))
    w0 = time.monotonic()
    if wake is None:
        await asyncio.sleep(wait)
    else:
        # asyncio.timeout, not wait_for: 3.11's wait_for can swallow the task's cancellation when the wake-up comes at
        # the same moment, and the session's task group then never ends
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(wait):
                await wake.wait()
        wake.clear()
    return (time.monotonic() - w0 - wait) * 1000


def busy_refusal(sessions: int, most: int) -> str | None:
    """What a server running ``sessions`` sessions, at most ``most`` (``max_sessions``), refuses a new one with
    (both front doors: the RTP door's Error 503, the browser's 503 answer); None while there is room."""
    return f"server busy: {sessions} sessions already" if sessions >= most else None


class LiveServer(Protocol):
    """What a live session uses of its server (:class:`splitrender.server.server.LiveServer`, which imports the
    doors: a session names the server's interface instead of importing it back)."""

    config: Any
    epoch_wall_s: float
    methods: Any
    scene: Any
    sessions: dict[str, Any]
    test_hang: tuple[int, int] | None
    udp_address: Address
    udp_dropped: int

    async def acquire_worker(self) -> Any: ...
    async def release_worker(self, worker: Any, session_id: str) -> None: ...
    def next_mirror_port(self) -> int | None: ...
    def register(self, session: Any, ssrcs: list[int]) -> None: ...
    def unregister(self, session: Any) -> None: ...
    def send_datagram(self, data: bytes, addr: Address) -> None: ...
    def ssrc_taken(self, ssrc: int) -> bool: ...
    def frame_ticks(self) -> AsyncIterator[int]: ...


class SessionEnded(Exception):
    """A session's task saw its end (its peer's Bye or the end of its connection): the task group ends quietly."""


class LiveSession:
    """One live session of either front door (see the module docstring).  A door provides :meth:`_start` (its
    handshake; False where the session was refused), :meth:`_loops` (its tasks beside the frame clock's),
    :meth:`_tick` (whether its path is ready and whether frames still wait to leave), :meth:`_deliver` (a made frame
    to its peer), :meth:`_send_error`, :meth:`_say_bye` and :meth:`_teardown` (its own transport's end)."""

    kind = "session"
    """How the logs name this door's sessions."""

    def __init__(self, server: LiveServer, ordinal: int) -> None:
        self.server = server
        self.cfg = server.config
        self.ordinal = ordinal
        """This session's number on the server (1-based; the ``test_hang`` hook names sessions by it)."""
        self.id = secrets.token_hex(6)
        self.log = logging.getLogger(type(self).__module__)
        """The door's logger (its module's): what the base logs of a session is logged as the door's."""
        self.peer = "?"
        self.method = ""
        self.worker: Any = None
        """The session's render worker (:class:`~splitrender.server.worker.RenderWorker`) from :meth:`_open_worker`
        until :meth:`close` hands it back."""
        self.core: ServerSession | None = None
        """The sans-IO session core (poses, feedback, keyframes, frame orders; on the RTP transport its NACK answers
        and sender reports too)."""
        self.end_reason = ""
        """Why the session ended (the closing log line's), where the door knows."""
        self.ended = asyncio.Event()
        """Set by :meth:`end`: the session's tasks end (a door's peer events, which come outside them, end it so)."""
        self.ended_at: float | None = None
        self.out_dir = None if self.cfg.out_dir is None else Path(self.cfg.out_dir) / self.id
        """Where this session's records go (``out_dir``/the session id), or None."""
        self._logs = SessionLogs(self.out_dir)
        """``feedback.csv`` and ``updates.csv`` (the core's rows, as they come) and ``counters.csv``, with ``out_dir``."""
        self._counters: dict[str, int] = {"render_timeouts": 0}
        """What the door counts itself, beside its core (:attr:`counters`; :meth:`count` adds to it)."""
        self._metrics = MetricsLog(self.log, self.id, self.cfg.metrics_interval_s)

    @property
    def counters(self) -> dict[str, Any]:
        """This session's counters: its core's (frames, keyframes, poses, feedback, PLIs, NACKs, ...) and the
        door's own."""
        return {**(self.core.all_counters() if self.core is not None else {}), **self._counters}

    def count(self, name: str, n: int = 1) -> None:
        """Add ``n`` to the door's own counter ``name`` (one the core does not keep)."""
        self._counters[name] = self._counters.get(name, 0) + n

    @property
    def frames_sent(self) -> int:
        return self.core.counters["frames_sent"] if self.core is not None else 0

    def server_counters(self) -> dict[str, Any]:
        """The session's counters: its core's (frames, keyframes, poses, feedback, PLIs, ...), the door's own, and
        its method; what ``counters.csv`` gets and the closing log line names."""
        return {**self.counters, "method": self.method}

    def log_metrics(self) -> None:
        """One ``metrics`` log line: the session's counters (:meth:`server_counters`)."""
        self._metrics.write(self.server_counters())

    @property
    def feedback_rows(self) -> Any:
        """The newest :data:`~.recording.ROWS_KEPT` Feedback rows (``feedback.csv`` has them all)."""
        return self._logs.recent["feedback"]

    @property
    def update_rows(self) -> Any:
        """The newest :data:`~.recording.ROWS_KEPT` rows of frames sent (``updates.csv`` has them all)."""
        return self._logs.recent["updates"]

    # ------------------------------------------------------------------ the session's life

    def end(self, reason: str) -> None:
        """End the session for ``reason`` (the first reason given stands)."""
        if not self.ended.is_set():
            self.end_reason = reason
            self.ended_at = time.time()
            self.ended.set()

    async def _until_ended(self) -> None:
        await self.ended.wait()
        raise SessionEnded()

    async def run(self) -> None:
        """The door's opening (:meth:`_start`), then the session's tasks until one ends it or the server is shut
        down; then :meth:`close`.  A protocol error from the peer is answered with an ``Error`` naming it, our own
        failure with ``server error: ...`` (and logged), a lost connection only logged."""
        try:
            await self._serve()
        except asyncio.CancelledError:
            self._say_bye("server shutting down")
            raise
        finally:
            await self.close()

    async def _serve(self) -> None:
        try:
            if not await self._start():
                return
            async with asyncio.TaskGroup() as tg:
                for coro in (self._frame_loop(), self._until_ended(), *self._loops()):
                    tg.create_task(coro, name=f"{self.kind}-{self.id}-{coro.__name__.strip('_')}")
        except* SessionEnded:
            pass
        except* RemoteProtocolError as eg:
            exc = eg.exceptions[0]
            assert isinstance(exc, RemoteProtocolError)
            self.log.warning("%s %s: protocol error from %s: %s", self.kind, self.id, self.peer, exc)
            await self._send_error(exc)
        except* (ConnectionError, asyncio.IncompleteReadError) as eg:
            self.log.info("%s %s: connection lost: %s", self.kind, self.id, eg.exceptions[0])
        except* Exception as eg:  # noqa: BLE001 - a failing session must not take the server down
            err = eg.exceptions[0]
            if isinstance(err, (WorkerTimeout, WorkerDied, WorkerError, PeerTimeoutError)):   # said in full by the message
                self.log.error("%s %s: failed: %s", self.kind, self.id, describe_error(err))
            else:
                self.log.error("%s %s: failed", self.kind, self.id, exc_info=err)
            await self._send_error(ErrorCode.INTERNAL, f"server error: {describe_error(err)}")

    async def close(self) -> None:
        """The door's own end (:meth:`_teardown`), the worker handed back, the core's last rows written, the row
        logs closed with ``counters.csv`` (nothing without ``out_dir`` or frames), and one log line.  Safe to call
        twice."""
        await self._teardown()
        if self.worker is not None:
            worker, self.worker = self.worker, None
            await self.server.release_worker(worker, self.id)
        self._logs.write(self.core.rows_to_write() if self.core is not None else ())
        counters = self.server_counters()
        self._logs.close(counters)
        self.log.info("%s %s: closed (%s)%s", self.kind, self.id,
                    ", ".join(f"{k}={v}" for k, v in counters.items() if v), f"; {self.end_reason}" if self.end_reason else "")

    async def set_up(self, step: Awaitable[T]) -> T | None:
        """The door's set-up ``step`` (its half, encoders and core), awaited: the peer's protocol error leaves as
        itself; any other failure is ours (a method, encoder or GL failure), which ends this session only: logged,
        told to the peer (:meth:`_send_error`, ``session setup failed: ...``), and None."""
        try:
            return await step
        except RemoteProtocolError:
            raise
        except Exception as exc:  # noqa: BLE001 - any setup failure ends this session only
            self.log.exception("%s %s: setup for %s failed", self.kind, self.id, self.peer)
            await self._send_error(ErrorCode.INTERNAL, f"session setup failed: {describe_error(exc)}")
            return None

    async def _open_worker(self, opening: Any, test_hang: bool = False) -> tuple[list[Any], bytes, dict[str, Any]]:
        """Take a render worker and build ``opening``'s server half and encoders in it
        (:class:`~splitrender.pipeline.Opening`, whose method the session's becomes; with ``test_hang``, the worker
        hangs at the frame the server's ``test_hang`` hook names for this session's ordinal); returns the streams, the
        session data and the parameter sets each video encoder will send (for the SDP)."""
        self.method = opening.method
        hang = self.server.test_hang
        hang_frame = hang[1] if test_hang and hang and hang[0] == self.ordinal else -1
        self.worker = await self.server.acquire_worker()
        return await self.worker.call("open", self.id, opening, hang_frame, deadline_s=self.cfg.setup_deadline_s)

    # ------------------------------------------------------------------ frames

    async def _frame_loop(self) -> None:
        """The frame clock: the server's shared frame grid at ``server_fps`` (each tick with the ticks missed
        before it while a frame was made); a frame is made on each tick the core's rule lets through.  Every
        ``metrics_interval_s`` (0: never) a tick logs the ``metrics`` line first."""
        assert self.core is not None
        async for skipped in self.server.frame_ticks():
            if self._metrics.due():
                self.log_metrics()
            ready, backlog = self._tick()
            if self.core.live_tick(skipped, ready, backlog=backlog):
                await self._send_frame()

    async def _send_frame(self) -> None:
        """One frame: the core's order made by the worker, sent by the door, and the core's rows written."""
        assert self.core is not None
        made = await self._make_frame()
        if made is not None:
            await self._deliver(made)
            self._logs.write(self.core.rows_to_write())

    async def _make_frame(self) -> MadeFrame | None:
        """The core's order on the tick of the server's frame grid at the wall clock
        (:meth:`~.session.ServerSession.order_at`; None where it orders none: the operating point sends one tick in
        ``frame_div``), made and encoded by the render worker (its process's ``frame``) within
        ``render_deadline_s``.  Returns the order, its update, the half's stats, the stages with ``worker_rtt_ms``
        (the round trip beyond the worker's own time: pickling, the pipe, this loop's latency) and the wall clock it
        was ordered at (s).  A missed deadline is counted in ``render_timeouts`` before
        :class:`~splitrender.errors.WorkerTimeout` leaves."""
        assert self.core is not None and self.worker is not None
        wall = time.time()
        order = self.core.order_at(wall * 1000, self.cfg.server_fps, self.server.epoch_wall_s)
        if order is None:
            return None
        c0 = time.perf_counter()
        try:
            enc, stats, stages = await self.worker.call("frame", self.id, order, deadline_s=self.cfg.render_deadline_s)
        except WorkerTimeout:
            self._counters["render_timeouts"] += 1
            raise
        stages["worker_rtt_ms"] = max(0.0, (time.perf_counter() - c0) * 1e3 - stages["frame_ms"])
        return order, enc, stats, stages, wall

    # ------------------------------------------------------------------ what each door provides

    async def _start(self) -> bool:
        """The door's opening once :meth:`run` starts; False where the session ends there."""
        return True

    def _loops(self) -> tuple[Coroutine[Any, Any, None], ...]:
        """The door's tasks beside the frame clock; one that raises :class:`SessionEnded` ends the session."""
        return ()

    def _tick(self) -> tuple[bool, bool]:
        """At a tick of the frame clock: whether the door's path is ready for a frame, and whether the last frames
        have yet to leave (a backlog: the tick makes none)."""
        return True, False

    async def _deliver(self, made: MadeFrame) -> None:
        """A frame made (:meth:`_make_frame`) to the peer, reported to the core (its ``frame_from_worker``)."""
        raise NotImplementedError

    async def _send_error(self, exc: RemoteProtocolError | int, text: str = "") -> None:
        """Tell the peer the session ends with an error (a protocol error it made, or a code and text)."""
        raise NotImplementedError

    def _say_bye(self, reason: str) -> None:
        """Best-effort goodbye without waiting (the session is being cancelled)."""

    async def _teardown(self) -> None:
        """The door's own transport's end (first in :meth:`close`)."""
