"""One live server session: handshake, frame clock, RTP/RTCP, feedback.

Task layout (all in one ``asyncio.TaskGroup`` owned by :meth:`ServerSession.run`, the live session's
(:class:`~splitrender.pipeline.live.LiveSession`, which the browser's session shares)):

* ``control``: hands the client's control bytes to the session core, which takes Pose, Feedback and KeyframeRequest
  and gives back the rest (:meth:`~splitrender.pipeline.ServerSession.next_event`); a Bye, an Error or EOF ends the
  session, a protocol error sends ``Error`` and ends it;
* ``frames``: the frame clock at ``server_fps`` (the live session's); each tick has the session's render
  worker (:mod:`splitrender.server.worker`, another process) render and encode, then
  sends FrameMeta over TCP and the planes as RTP over UDP.  A frame that misses the
  worker's deadline ends the session with an error (the worker is killed).
  A tick that comes while the previous frame's metadata is still queued in the TCP
  send buffer, or that was missed because rendering overran, is skipped: stale frames
  are dropped, never queued;
* ``timer``: the session core's one timer (:meth:`~splitrender.pipeline.ServerSession.get_timer`):
  sender reports (every ``sr_interval_s`` on average, randomised), the pacer's sends and the
  estimator's probe packets, each when the core says.  Everything the core sends leaves through
  :meth:`ServerSession._flush` (its ``datagrams_to_send``), after each input and at that timer.

RTCP from the client (receiver reports, generic NACKs, PLIs) arrives through the
server's shared UDP socket and goes to the session core in :meth:`on_datagram`,
parsed only once its source is the session's client; the
retransmissions it answers with leave through the same flush.  Everything the protocol decides
(feedback, keyframe requests, NACK answers, sender reports) is the sans-IO core's
(:class:`splitrender.pipeline.ServerSession`); this module only moves bytes and time.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from typing import Any

from splitrender.errors import LocalProtocolError, RemoteProtocolError
from splitrender.methods.base import StreamSpec
from splitrender.pipeline.live import (Address, LiveServer, LiveSession, MadeFrame, SessionEnded, busy_refusal,
                                       wait_for_timer)
from splitrender.pipeline.recording import ROWS_KEPT
from splitrender.pipeline import Accepted, ServerPipeline, accept_hello, open_hello
from splitrender.pipeline.sender import FIRST_PAYLOAD_TYPE
from splitrender.protocol import Bye, Error, ErrorCode, Hello, ServerConnection, State
from splitrender.transport.control import READ_CHUNK_BYTES, ControlChannel, wall_ms

__all__ = ["ServerSession", "FIRST_PAYLOAD_TYPE", "ROWS_KEPT"]

logger = logging.getLogger(__name__)


class ServerSession(LiveSession):
    """One client: its own method halves, encoders, predictor and RTP state (the live session's life, frame clock
    and end: :class:`~splitrender.pipeline.live.LiveSession`)."""

    def __init__(self, server: LiveServer, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                 ordinal: int = 0) -> None:
        super().__init__(server, ordinal)
        peer = writer.get_extra_info("peername")
        self.peer = f"{peer[0]}:{peer[1]}" if peer else "?"
        self.channel = ControlChannel(ServerConnection(self.cfg.token), reader, writer, f"session {self.id}")
        self.mirrors: dict[str, Address] = {}
        """Where a copy of each video stream's RTP goes (``sdp_dir`` with mirror ports: its SDP file names it)."""
        self.tx: ServerPipeline | None = None
        self._timer_wake = asyncio.Event()
        self._counters.update({"session_bytes": 0, "client_errors": 0})
        self.client_error: tuple[int, str] | None = None
        """The client's ``Error`` (code, reason) when it left with one."""

    def server_counters(self) -> dict[str, Any]:
        rtt_ms = self.core.rtt_ms if self.core is not None else None
        return dict(super().server_counters(), rtt_ms=rtt_ms or math.nan, server_udp_dropped=self.server.udp_dropped)

    # ------------------------------------------------------------------ lifecycle

    def _loops(self) -> tuple[Any, ...]:
        return self._control_loop(), self._timer_loop()

    async def _send_error(self, exc: RemoteProtocolError | int, text: str = "") -> None:
        await self.channel.send_error(exc, text)

    async def _teardown(self) -> None:
        self.server.unregister(self)
        if self.client_error is not None:
            self.end_reason = f"client error {self.client_error[0]}: {self.client_error[1]}"
        await self.channel.close()

    def _say_bye(self, reason: str) -> None:
        """Best-effort Bye without waiting (used while being cancelled)."""
        try:
            data = self.channel.conn.send(Bye(reason))
            if not self.channel.writer.is_closing():
                self.channel.writer.write(data)
        except (LocalProtocolError, ConnectionError, RuntimeError):
            pass

    # ------------------------------------------------------------------ handshake

    async def _start(self) -> bool:
        """The handshake: the Hello within ``hello_timeout_s`` (else an Error naming the wait), the session's set-up,
        the Welcome and the session data.  False where the session ends there: the server was busy, the client left
        before its Hello, or our side failed to set it up (an Error ``session setup failed: ...``, logged:
        :meth:`~splitrender.pipeline.live.LiveSession.set_up`).  The client's protocol errors and a lost connection
        leave to :meth:`run`."""
        logger.info("session %s: connection from %s", self.id, self.peer)
        if (busy := busy_refusal(len(self.server.sessions), self.cfg.max_sessions)) is not None:
            await self.channel.send_error(503, busy)
            return False
        try:
            msg = await asyncio.wait_for(self.channel.next_message(), self.cfg.hello_timeout_s)
        except asyncio.TimeoutError:
            raise RemoteProtocolError(f"no Hello within {self.cfg.hello_timeout_s:g} s", ErrorCode.BAD_MESSAGE) from None
        if msg is None:
            logger.info("session %s: %s closed before Hello", self.id, self.peer)
            return False
        assert isinstance(msg, Hello)  # the state machine allows nothing else here
        acc = await self.set_up(self._setup(msg))
        if acc is None:   # our fault (a method, encoder or GL failure): the client told, others still served
            return False
        await self.channel.write_frames(acc.core.data_to_send(wall_ms()))     # the Welcome, then the session data
        self._counters["session_bytes"] = acc.session_bytes
        logger.info("session %s: %s streaming %s %dx%d @ %g Hz to %s", self.id, self.peer, self.method,
                    msg.width, msg.height, msg.display_hz, ", ".join(s.name for s in acc.welcome.streams))
        return True

    async def _setup(self, hello: Hello) -> Accepted:
        """Open the session (:func:`~splitrender.pipeline.open_hello`: method and codec), build the half and
        encoders (in the render worker) and the session's core; returns the accepted session (its Welcome and the
        control frames to send first).  Raises RemoteProtocolError."""
        cfg, server = self.cfg, self.server
        opening = open_hello(hello, server.methods, cfg)
        # the method half and its encoders live in the worker
        specs, session_blob, sets = await self._open_worker(opening, test_hang=True)
        host, port = server.udp_address
        acc = accept_hello(hello, self.id, opening, specs, session_blob, self.channel.conn, cfg, cfg.session_options(),
                           address=(host if host != "0.0.0.0" else "127.0.0.1", port),
                           subject=getattr(server.scene, "subject", None), parameter_sets=sets,
                           ssrc_taken=server.ssrc_taken, rtp_origin_ms=server.epoch_wall_s * 1000)
        self.core, self.tx = acc.core, acc.core.tx
        self.core.start(wall_ms())
        for st in self.tx.rtp_streams:
            if isinstance(st.spec, StreamSpec) and self.cfg.sdp_dir is not None:
                self._write_sdp(st.spec.name)
        server.register(self, [st.ssrc for st in self.tx.rtp_streams])
        return acc

    def _write_sdp(self, name: str) -> None:
        """Stream ``name``'s SDP in ``sdp_dir``, naming its mirror port where the server has one (else its own)."""
        assert self.tx is not None and self.cfg.sdp_dir is not None
        mirror = self.server.next_mirror_port()
        port = mirror if mirror is not None else self.server.udp_address[1]
        if mirror is not None:
            self.mirrors[name] = ("127.0.0.1", mirror)
        path = self.cfg.sdp_dir / f"{self.id}_{name}.sdp"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.tx.sdp(name, port, f"splitrender {self.id}"))
        logger.info("session %s: wrote %s (stream %s on udp port %d)", self.id, path, name, port)

    # ------------------------------------------------------------------ control

    async def _control_loop(self) -> None:
        """The control connection's bytes to the core, which reads them on the handshake's connection (what came with
        the Hello first); its rows are written as they come, its events taken by its rule
        (:meth:`~splitrender.pipeline.ServerSession.take_events`: Stats logged; a Bye, an Error or the end of the
        stream ends the session, the client's Error counted in ``client_errors`` and kept)."""
        core = self.core
        assert core is not None
        while (left := core.take_events(f"session {self.id}", wall_ms())) is None:   # a message cut by the end raises
            self._logs.write(core.rows_to_write())
            data = await self.channel.reader.read(READ_CHUNK_BYTES)
            self.channel.bytes_received += len(data)
            core.receive_data(data)
        if isinstance(left, Error):
            self._counters["client_errors"] += 1
            self.client_error = (left.code, left.text)
        raise SessionEnded()

    # ------------------------------------------------------------------ frames

    def _tick(self) -> tuple[bool, bool]:
        """A tick of the frame clock: the core's rule makes no frame before the client's address and a pose, nor
        while the last frame's metadata waits in the TCP send buffer."""
        return True, self.channel.write_buffer_bytes > self.cfg.max_meta_backlog_bytes

    async def _deliver(self, made: MadeFrame) -> None:
        assert self.core is not None
        if self.channel.conn.state is not State.STREAMING:
            # the peer said Bye (or the connection closed) while the worker rendered: the control
            # task is ending the session in this same loop turn; this frame has nowhere to go
            raise SessionEnded()
        c1 = time.perf_counter()
        _out, row = self.core.frame_from_worker(*made, wall_ms())
        # the core's one way out: metadata and reliable data first (TCP), then the RTP packets
        await self.channel.write_frames(self.core.data_to_send(wall_ms()), drain=False)
        self._flush()
        row["send_ms"] = (time.perf_counter() - c1) * 1e3    # packetizing and sending here

    # ------------------------------------------------------------------ RTCP

    async def _timer_loop(self) -> None:
        """Flushes the core (its control frames, then its datagrams) when its one timer comes (woken early when an
        input may have moved it)."""
        assert self.core is not None
        while True:
            await wait_for_timer(self.core.get_timer() - wall_ms(), 1.0, self._timer_wake)
            if frames := self.core.data_to_send(wall_ms()):   # (a frame's are written as it is sent)
                await self.channel.write_frames(frames, drain=False)
            self._flush(wake=False)

    def on_datagram(self, data: bytes, addr: Address) -> None:
        """A compound RTCP datagram from ``addr`` that names one of this session's streams, for the core: the first
        that parses binds the client's address, and a datagram from any other is then counted (``rtcp_foreign``) and
        dropped unparsed (malformed ones are counted in ``rtcp_bad``)."""
        if self.core is None:
            return
        bound = self.core.peer
        self.core.receive_datagram(data, wall_ms(), addr)
        if bound is None and self.core.peer is not None:
            logger.info("session %s: client RTP address is %s:%d (learned from RTCP)", self.id, *addr)
        self._flush()

    def _flush(self, wake: bool = True) -> None:
        """Send what the core lets go now (its one way out): RTP and sender reports to the client, each stream's RTP to
        its mirror as well; before the client's address (learned from its RTCP: the core's
        :attr:`~splitrender.pipeline.ServerSession.peer`) is known they are dropped.  After an input (``wake``) the
        timer task is woken, since the core's next deadline may have moved."""
        if self.core is None:
            return
        for d in self.core.datagrams_to_send(wall_ms()):
            if self.core.peer is None:
                continue
            self.server.send_datagram(d.data, self.core.peer)
            mirror = self.mirrors.get(d.stream) if d.kind == "rtp" and d.stream is not None else None
            if mirror is not None:
                self.server.send_datagram(d.data, mirror)
        if wake:
            self._timer_wake.set()
