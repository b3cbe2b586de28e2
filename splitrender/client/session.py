"""The live headless client: poses up, RTP/FrameMeta down, decode, display, record.

Task layout (one ``asyncio.TaskGroup`` owned by :meth:`LiveClient.run`):

* ``poses``: samples the camera trace at ``tracker_hz`` and sends ``Pose`` messages;
* ``control``: hands the control connection's bytes to the session core, which owns the connection (FrameMeta,
  kept until its planes are decoded; Stats, Bye, Error come back as its events);
* ``rtcp``: runs the session core's timer (:class:`splitrender.pipeline.ClientSession`:
  receiver reports, which bind the UDP path until the first RTP packet, generic NACKs,
  PLIs, jitter-buffer timeouts and stall detection) and sends the RTCP it queues;
* ``decode``: decodes every completed access unit in order on a decoder thread and
  matches planes to their FrameMeta by ``(stream, RTP timestamp)``;
* ``display``: the display clock at ``display_hz``; each tick applies the updates that
  became ready, renders through the method's client half on the client's GL thread
  at the trace pose of that instant, records the row (and image) and sends Feedback
  the first time an update is shown.  It ends the run after ``duration_s``.

Times on the wire are wall-clock µs (:func:`~splitrender.transport.control.wall_us`);
durations are measured with ``time.perf_counter``.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from splitrender.client.config import ClientConfig
from splitrender.errors import CodecError, PeerTimeoutError, ServerRefusedError, SplitRenderError
from splitrender.pipeline import ClientHandshake, ClientPipeline, ClientSession, ReceivedFrame, Work, black_frame, display_frame
from splitrender.pipeline.frames import decode_work
from splitrender.pipeline.session import StreamStalledError, leaving_error
from splitrender.pipeline.live import wait_for_timer
from splitrender.pipeline.recording import ClientRecording, MetricsLog, manifest, save_image
from splitrender.protocol import Bye, Welcome
from splitrender.scene.pose import Pose as ScenePose
from splitrender.scene.trace import get_trace
from splitrender.transport.control import READ_CHUNK_BYTES, ControlChannel, wall_ms, wall_us
from splitrender.transport.errors import ConnectError, describe_os_error

__all__ = ["ClientConfig", "LiveClient", "ClientResult", "ServerRefusedError", "StreamStalledError", "run_client"]

logger = logging.getLogger(__name__)

DECODE_QUEUE = 64
"""Access units waiting for the decoder; overflow flushes and asks for a keyframe."""
RTCP_TICK_S = 0.01
"""The longest the timer task sleeps between two looks at the core's deadline, s."""


@dataclass
class ClientResult:
    """What a run recorded: per displayed frame rows, and session counters."""

    rows: list[dict[str, Any]]
    counters: dict[str, Any]
    recording: dict[str, Any]
    """(The counters have the core's FrameMeta count ``frames_meta``, the first and last ids ``meta_first_id`` and
    ``meta_last_id``, and ``meta_gaps``, FrameMetas that did not follow the previous one.)"""
    out_dir: Path | None = None


class LiveClient:
    """One session against a live server; ``await LiveClient(cfg).run()``."""

    def __init__(self, config: ClientConfig) -> None:
        self.cfg = config
        self.trace = get_trace(config.trace)
        self.session_id = "?"
        self.gl_executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="sr-client-gl")
        self.decode_executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="sr-client-dec")
        self.io_executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="sr-client-io")
        self.channel: ControlChannel | None = None
        self.udp: asyncio.DatagramTransport | None = None
        self._udp_protocol: Any = None
        self.rx: ClientPipeline | None = None
        self.core: ClientSession | None = None
        """The sans-IO session core: RTCP, NACK, PLI, playout delay, stalls, feedback."""
        self.recording = ClientRecording(config.out_dir, config.rows_kept)
        """The recording folder, written as the session goes; its ``recent`` holds the newest ``rows_kept`` displayed
        rows (its ``frames.jsonl``/``frames.csv`` has them all)."""
        self._decode_q: asyncio.Queue[Work] = asyncio.Queue(DECODE_QUEUE)
        self._half: Any = None
        self._welcome: Welcome | None = None
        self._params: dict[str, Any] = {}
        self._t0_wall = 0.0
        self._counters: dict[str, Any] = {"late_ticks": 0}

    @property
    def counters(self) -> dict[str, Any]:
        """The session core's counters, with what each RTP stream's jitter buffer dropped
        (:meth:`ClientSession.all_counters`), and the driver's own (late display ticks, the timer task's lag, datagrams
        from a foreign address, the rows recorded)."""
        core = self.core.all_counters() if self.core is not None else {}
        foreign = {"udp_foreign": self._udp_protocol.foreign} if self._udp_protocol is not None else {}
        return {**core, **self._counters, **foreign, "rows_recorded": self.recording.rows}

    # ------------------------------------------------------------------ run

    async def run(self) -> ClientResult:
        """Connect, stream for ``duration_s``, say Bye, write the recording."""
        cfg = self.cfg
        try:
            try:
                reader, writer = await asyncio.wait_for(
                    asyncio.open_connection(cfg.server, cfg.port, ssl=cfg.tls_context()), cfg.connect_timeout_s)
            except (OSError, OverflowError) as exc:  # refused, unreachable, unknown host, timed out
                raise ConnectError(f"cannot connect to {cfg.server}:{cfg.port}: {describe_os_error(exc)}") from exc
            hs = ClientHandshake(cfg.methods, cfg.limits, (cfg.width, cfg.height))   # it owns the connection
            self.channel = ControlChannel(hs.conn, reader, writer, "client")
            try:
                core = await self._handshake(hs)
                await self._open_udp(core)
                self._t0_wall = time.time()
                core.start(wall_ms())   # the stall clock starts; an empty RR opens the UDP path
                self._flush_rtcp(core)
                self.recording.start(self._recording())   # the manifest, complete: false; the journal opened
                try:
                    async with asyncio.TaskGroup() as tg:
                        tg.create_task(self._pose_loop(core), name="client-poses")
                        tg.create_task(self._control_loop(core), name="client-control")
                        tg.create_task(self._rtcp_loop(core), name="client-rtcp")
                        tg.create_task(self._decode_loop(core), name="client-decode")
                        tg.create_task(self._display_loop(core), name="client-display")
                except BaseExceptionGroup as eg:
                    _, rest = eg.split(_RunDone)
                    if rest is not None:  # re-raise the first real failure as itself
                        first: BaseException = rest
                        while isinstance(first, BaseExceptionGroup):
                            first = first.exceptions[0]
                        raise first from None
                await self._say_bye(core, "duration reached")
            except Exception as exc:
                await self._say_error(exc)
                raise
            finally:
                if self.udp is not None:
                    self.udp.close()
                await self.channel.close()
        except BaseException as exc:
            await self._release()
            if self.recording.started:   # a broken session: keep what was
                # recorded, marked incomplete
                self.recording.finish(self.recording.ended(self._recording(), exc), self.counters)
                logger.error("session %s: ended early (%s); the partial recording (%d rows) is in %s", self.session_id,
                             exc, self.recording.rows, cfg.out_dir)
            raise
        await self._release()
        logger.info("session %s: client done: %d displayed rows, %s", self.session_id, self.recording.rows,
                    ", ".join(f"{k}={v}" for k, v in self.counters.items() if v))
        result = ClientResult(list(self.recording.recent), self.counters, self.recording.ended(self._recording()),
                              cfg.out_dir)
        if cfg.out_dir is not None:   # frames.csv, counters.json and the completed manifest; then the journal goes
            await asyncio.get_running_loop().run_in_executor(None, self.recording.finish, result.recording,
                                                             result.counters)
        return result

    async def _release(self) -> None:
        loop = asyncio.get_running_loop()
        half, self._half = self._half, None
        if half is not None:
            try:
                await loop.run_in_executor(self.gl_executor, lambda: None)
            except RuntimeError:
                pass
        for ex in (self.gl_executor, self.decode_executor, self.io_executor):
            ex.shutdown(wait=True)

    async def _say_error(self, exc: BaseException) -> None:
        """Tell the server why this client is leaving (best effort; the core's rule, :func:`leaving_error`)."""
        said = leaving_error(exc)
        if self.channel is not None and said is not None:
            logger.info("session %s: leaving with Error %d: %s", self.session_id, *said)
            await self.channel.send_error(*said)

    async def _say_bye(self, core: ClientSession, reason: str) -> None:
        try:
            core.send(Bye(reason))
            await asyncio.wait_for(self._flush_control(core), 1.0)
        except (ConnectionError, asyncio.TimeoutError, SplitRenderError) as exc:
            logger.debug("session %s: Bye not sent: %s", self.session_id, exc)

    # ------------------------------------------------------------------ handshake

    async def _handshake(self, hs: ClientHandshake) -> ClientSession:
        """The sans-IO handshake both modes share (it holds the config's sizes to ``cfg.limits`` before any
        allocation), driven over the control connection; then the client half and the session core (returned)."""
        cfg, ch = self.cfg, self.channel
        assert ch is not None
        await ch.write_frames([hs.hello(hs.make_hello(cfg.codecs, cfg.display_hz, cfg.token))])
        while not hs.done:   # the Welcome, then the session data in DataChunk messages (chunked, counted, bounded)
            first = hs.welcome is None
            msg = await self._next_message(hs.waiting_for)
            if first and msg is None and not cfg.tls and ch.bytes_received == 0:   # a TLS server's answer to plaintext
                raise ConnectError(f"{cfg.server}:{cfg.port} closed the connection without answering Hello: if it "
                                   "serves TLS (serve --tls-cert), connect with --tls")
            hs.receive_message(msg)   # an Error or the end: ServerRefusedError naming it
            if first:
                self._welcome, self.session_id, self._params = msg, msg.session_id, dict(msg.method_params)
        terms = hs.terms
        assert terms is not None and self._welcome is not None
        # a loaded model (the terms' subject): built-in traces go around it, as in the simulator
        self.trace = get_trace(cfg.trace, scene=terms, fov_y_deg=terms.fov_y_deg, aspect=cfg.width / cfg.height)  # type: ignore[arg-type]
        self._counters["session_bytes"] = hs.session_bytes
        # the client half in the GL thread's own context
        self._half = await asyncio.get_running_loop().run_in_executor(self.gl_executor, hs.client_half)
        self.core = hs.session(cfg.options())
        self.rx = self.core.rx
        logger.info("session %s: method %s, streams %s", self.session_id, terms.method,
                    ", ".join(f"{s.name}({s.codec}, ssrc {s.ssrc:08x})" for s in self._welcome.streams))
        return self.core

    async def _next_message(self, what: str) -> Any:
        """The server's next control message; :class:`PeerTimeoutError` naming ``what``, the server and the wait when
        none comes within ``connect_timeout_s``."""
        cfg, ch = self.cfg, self.channel
        assert ch is not None
        try:
            async with asyncio.timeout(cfg.connect_timeout_s) as deadline:
                return await ch.next_message()
        except TimeoutError:
            if not deadline.expired():   # the socket's own timeout, not our wait
                raise
            raise PeerTimeoutError(f"no {what} from {cfg.server}:{cfg.port} within connect_timeout_s "
                                   f"{cfg.connect_timeout_s:g} s") from None

    async def _open_udp(self, core: ClientSession) -> None:
        assert self._welcome is not None
        port = self.cfg.udp_port or (self._welcome.streams[0].port if self._welcome.streams else 0)
        loop = asyncio.get_running_loop()
        try:
            self.udp, self._udp_protocol = await loop.create_datagram_endpoint(
                lambda: _ClientUdp(lambda data: self._on_datagram(core, data)), remote_addr=(self.cfg.server, port))
        except (OSError, OverflowError) as exc:
            raise ConnectError(f"cannot open udp to {self.cfg.server}:{port}: {describe_os_error(exc)}") from exc

    # ------------------------------------------------------------------ poses

    async def _pose_loop(self, core: ClientSession) -> None:
        interval = 1.0 / self.cfg.tracker_hz
        loop = asyncio.get_running_loop()
        start = loop.time()
        n = int(self.cfg.duration_s * self.cfg.tracker_hz) + 1
        for seq in range(n):
            delay = start + seq * interval - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            now_us = wall_us()
            core.send_pose(now_us, seq, self._trace_pose(now_us / 1e6))
            await self._flush_control(core)
        await asyncio.Event().wait()  # the display task ends the run

    def _trace_pose(self, wall_s: float) -> ScenePose:
        return self.trace.pose_at(min(max(0.0, wall_s - self._t0_wall), self.trace.duration_s))

    # ------------------------------------------------------------------ control

    async def _control_loop(self, core: ClientSession) -> None:
        """The control connection's bytes to the core, which owns it; its events end the run where they say so."""
        assert self.channel is not None
        while True:
            data = await self.channel.reader.read(READ_CHUNK_BYTES)
            core.receive_data(data, wall_ms())  # raises RemoteProtocolError on bad input: the session ends with Error
            self._take_events()

    async def _flush_control(self, core: ClientSession) -> None:
        """Write what the core queued on the control connection (feedback, poses, Bye)."""
        assert self.channel is not None
        if data := core.data_to_send():
            await self.channel.write_frames([data])

    def _take_events(self) -> None:
        """The core's events by its one rule (:meth:`ClientSession.take_events`: what ends the session is raised); a
        released frame needs nothing here, display_tick shows it.  (It takes no core: tests override it.)"""
        assert self.core is not None
        self.core.take_events(f"session {self.session_id}")

    # ------------------------------------------------------------------ UDP in

    def _on_datagram(self, core: ClientSession, data: bytes) -> None:
        core.receive_datagram(data, wall_ms())
        self._queue_work(core)

    def _queue_work(self, core: ClientSession) -> None:
        """What the core released to decode joins the decode queue (a full queue is flushed: the core is told)."""
        for w in core.work_to_decode():
            try:
                self._decode_q.put_nowait(w)
            except asyncio.QueueFull:
                while not self._decode_q.empty():
                    self._decode_q.get_nowait()
                core.decoder_overflow()

    # ------------------------------------------------------------------ decode

    async def _decode_loop(self, core: ClientSession) -> None:
        loop = asyncio.get_running_loop()
        while True:
            w = await self._decode_q.get()
            if core.skips_decode(w, wall_ms()):
                continue
            res, decode_ms = await loop.run_in_executor(self.decode_executor, decode_work, w)
            if isinstance(res, CodecError):
                logger.info("session %s: %s decode error, waiting for a keyframe: %s", self.session_id, w.stream.name, res)
            core.on_decoded(w, res, wall_ms(), decode_ms)

    # ------------------------------------------------------------------ RTCP out

    def _flush_rtcp(self, core: ClientSession) -> None:
        """Send the compound RTCP packets the core queued."""
        for data in core.datagrams_to_send():
            if self.udp is not None and not self.udp.is_closing():
                self.udp.sendto(data)

    async def _rtcp_loop(self, core: ClientSession) -> None:
        """The core's timer: sleep to its deadline (at most :data:`RTCP_TICK_S`), run it, send what it queued."""
        metrics = MetricsLog(logger, self.session_id, self.cfg.metrics_interval_s)
        lag_sum, lag_n = 0.0, 0
        while True:
            lag = await wait_for_timer(core.get_timer() - wall_ms(), RTCP_TICK_S)   # how late the loop woke us
            lag_sum, lag_n = lag_sum + lag, lag_n + 1
            self._counters["timer_lag_ms_mean"] = round(lag_sum / lag_n, 2)
            self._counters["timer_lag_ms_max"] = round(max(self._counters.get("timer_lag_ms_max", 0.0), lag), 1)
            now_ms = wall_ms()
            if now_ms >= core.get_timer():
                core.handle_timer(now_ms)
                self._queue_work(core)
                self._flush_rtcp(core)
            self._take_events()
            if metrics.due():
                metrics.write(self.counters)

    # ------------------------------------------------------------------ display

    async def _display_loop(self, core: ClientSession) -> None:
        cfg = self.cfg
        loop = asyncio.get_running_loop()
        interval = 1.0 / cfg.display_hz
        start = loop.time()
        n = int(cfg.duration_s * cfg.display_hz)
        saves: list[asyncio.Future[None]] = []
        for tick in range(n):
            delay = start + tick * interval - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            elif delay < -interval:
                self._counters["late_ticks"] += 1
                continue  # more than a tick late: skip it rather than bunch renders up
            w = time.time()
            # the core's rule: ticks wait for the server's clock (the first FrameMeta), then show black until an
            # update shows; with a playout delay, only the updates whose turn has come are applied
            blanks, new = core.display_tick((tick, w, self._trace_pose(w)), wall_ms())
            for b_tick, b_wall, b_pose in blanks:
                self._record_blank(core, b_tick, b_wall, b_pose, saves)
            if new is not None:
                await self._show(core, new, tick, saves)
        for b_tick, b_wall, b_pose in core.held_ticks():   # the server never sent a frame: without a scene time
            self._record_blank(core, b_tick, b_wall, b_pose, None)
        await asyncio.gather(*saves)
        raise _RunDone()

    async def _show(self, core: ClientSession, new: list[ReceivedFrame], tick: int, saves: list[Any]) -> None:
        """Display tick ``tick``: apply the ``new`` updates and render the trace's pose (on the GL thread), report them
        to the core, record the row (and the image), and send the feedback of a newly shown update."""
        cfg = self.cfg
        half = self._half
        loop = asyncio.get_running_loop()
        tick_wall = time.time()
        pose = self._trace_pose(tick_wall)
        trace_t = tick_wall - self._t0_wall
        scene_t = core.scene_t(tick_wall)
        drawn = await loop.run_in_executor(self.gl_executor, display_frame, half, new, pose, scene_t,
                                           (cfg.width, cfg.height), f"session {self.session_id}")
        displayed_us = wall_us()
        # the core's rule (and the Feedback of an update shown the first time)
        shown = core.showing(new, drawn.ok, half.has_content, displayed_us / 1000)
        if shown is None:   # every update so far rejected or without content: still black
            self._record_blank(core, tick, tick_wall, pose, saves)
        else:
            row = self.recording.tick(tick, trace_t, scene_t, pose, shown, displayed_us, drawn.client_ms,
                                      **drawn.columns, **core.received_kbps(displayed_us / 1e6))
            self._save_image(saves, row["frame"], drawn.frame.color, drawn.frame.holes)
            if len(saves) > 64:
                await asyncio.gather(*saves[:32])
                del saves[:32]
        await self._flush_control(core)

    def _record_blank(self, core: ClientSession, tick: int, wall_s: float, pose: ScenePose,
                      saves: list[Any] | None) -> None:
        """Record a tick that showed the black background (its image saved when ``saves`` is given and images are
        kept; without the server clock, ``saves`` is None and the row has no scene time)."""
        row = self.recording.tick(tick, wall_s - self._t0_wall, core.scene_t(wall_s), pose, None,
                                  int(wall_s * 1e6))
        if saves is not None and self.cfg.save_images:
            black = black_frame(self.cfg.width, self.cfg.height)
            self._save_image(saves, row["frame"], black.color, black.holes)

    def _save_image(self, saves: list[Any], frame: int, color: Any, holes: Any) -> None:
        """Save a displayed image on the I/O thread where images are kept (its future joins ``saves``)."""
        cfg = self.cfg
        if cfg.save_images and cfg.out_dir is not None:
            saves.append(asyncio.get_running_loop().run_in_executor(self.io_executor, save_image, cfg.out_dir, frame,
                                                                    color, holes))

    # ------------------------------------------------------------------ recording

    def _recording(self) -> dict[str, Any]:
        cfg, w, params = self.cfg, self._welcome, self._params
        return manifest(self.session_id, w.method if w else "", params.get("config", {}), params.get("scene", "default"),
                        params.get("fov_y_deg", 60.0), params.get("server_fps", 30), cfg.trace, cfg.width, cfg.height,
                        cfg.display_hz, cfg.tracker_hz, cfg.duration_s, bool(cfg.save_images and cfg.out_dir is not None),
                        {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()})


class _RunDone(Exception):
    """The display clock reached ``duration_s``."""


class _ClientUdp(asyncio.DatagramProtocol):
    """The client's UDP socket, connected to the server's media address: a datagram from any other source (which a
    connected socket's kernel filter should already drop) is counted in ``foreign`` and never parsed."""

    def __init__(self, on_datagram: Any) -> None:
        self._on_datagram = on_datagram
        self.peer: tuple[str, int] | None = None
        self.foreign = 0

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        peer = transport.get_extra_info("peername")
        self.peer = (peer[0], peer[1]) if peer else None

    def datagram_received(self, data: bytes, addr: Any) -> None:
        if self.peer is not None and (addr[0], addr[1]) != self.peer:
            self.foreign += 1
            return
        self._on_datagram(data)

    def error_received(self, exc: Exception) -> None:
        logger.debug("client udp error: %s", exc)


async def run_client(config: ClientConfig) -> ClientResult:
    """Run one live client session (see :class:`LiveClient`)."""
    return await LiveClient(config).run()
