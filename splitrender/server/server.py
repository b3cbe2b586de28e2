"""The live asyncio server: TCP control sessions plus one shared UDP socket for RTP/RTCP.

Architecture (one process):

* :class:`LiveServer` owns the listening TCP socket, one UDP socket shared by all
  sessions (RTP out, RTCP in; RTCP is demultiplexed to a session by the media SSRCs it
  names), the scene clock (``scene time = wall clock − epoch``) and the render workers
  (:mod:`splitrender.server.worker`): child processes that hold the renderer, the method
  halves and the encoders, each request under a watchdog deadline.  The event loop's
  process never runs GL or a codec, so a stuck render cannot stall the other sessions,
  the sockets or the signal handlers.
* Each accepted connection runs one :class:`~splitrender.server.session.ServerSession`
  in the connection's task; the session owns its sub-tasks in an ``asyncio.TaskGroup``
  (control reader, frame clock, RTCP sender).
* ``close()`` (or cancelling :func:`serve`) stops accepting, cancels every session task
  and waits for them, closes the sockets and stops the workers (SIGKILL after 0.5 s).

The client's UDP address is learned from its first RTCP packet naming one of the
session's SSRCs (see ``docs/protocol.md``, "Live sessions").
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import ssl
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from splitrender.errors import ConfigError
from splitrender.options import ServerProtocolOptions, option_fields, options_of
from splitrender.pipeline import ServerOptions
from splitrender.protocol import RtcpError
from splitrender.protocol.rtcp import rtcp_route_ssrc
from splitrender.server.session import ServerSession
from splitrender.server.worker import RenderWorker
from splitrender.transport.errors import BindError, describe_os_error

__all__ = ["ServerConfig", "LiveServer", "serve", "check_method_params", "sdp_hint", "DEFAULT_PORT",
           "DEFAULT_UDP_PORT"]

logger = logging.getLogger(__name__)

DEFAULT_PORT = 9100
"""TCP control port."""
DEFAULT_UDP_PORT = 6004
"""UDP port for RTP (out) and RTCP (in), shared by all sessions."""
DEFAULT_GI_HZ = 5.0
"""Live servers relight the scene's DDGI probes at this rate (0: every frame)."""

Address = tuple[str, int]


def parse_test_hang(text: str) -> tuple[int, int] | None:
    """``"SESSION:FRAME"`` (the ``SPLITRENDER_TEST_HANG`` test hook): the server's SESSION-th session (1-based)
    hangs while rendering frame FRAME; ``""`` = never.  Raises ``ValueError`` naming the fault."""
    if not text:
        return None
    a, sep, b = text.partition(":")
    try:
        s, f = int(a), int(b)
    except ValueError:
        s = f = -1
    if not sep or s < 1 or f < 0:
        raise ValueError(f"SPLITRENDER_TEST_HANG: expected SESSION:FRAME (e.g. 1:5), got {text!r}")
    return s, f


@dataclass(frozen=True)
@option_fields(ServerProtocolOptions)
class ServerConfig:
    """Settings of a live server.

    The session options (:class:`~splitrender.options.ServerProtocolOptions`: NACK history and bounds, keyframe and
    sender-report intervals) are fields too, from their one declaration (:mod:`splitrender.options`).

    ``methods``: method ids offered, in the server's order (``None`` = all registered).
    ``method_params``: per method id, parameters for its config dataclass.
    ``udp_port`` 0 picks a free port. ``max_pixels`` bounds the display size a client
    may ask for. ``sdp_dir``: write one SDP file per stream there; with
    ``mirror_port`` each stream is also copied to ``127.0.0.1:mirror_port + 2k`` so
    ``ffplay -protocol_whitelist file,udp,rtp -i <sdp>`` can watch it.
    ``out_dir``: write each session's Feedback rows (per-frame latency) there.
    ``max_session_bytes``: a method whose session data is larger fails that session
    with an error naming the limit.  ``fec``: protect every RTP stream with RFC 5109
    parity packets on a separate SSRC (announced in ``Welcome``, not mirrored).
    """

    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    udp_port: int = DEFAULT_UDP_PORT
    token: str | None = None
    methods: tuple[str, ...] | None = None
    method_params: dict[str, dict[str, Any]] = field(default_factory=dict)
    scene: str = "default"
    server_fps: int = 30
    fov_y_deg: float = 60.0
    predictor: str = "cv"
    max_sessions: int = 8
    max_pixels: int = 1920 * 1080
    hello_timeout_s: float = 5.0
    mtu_bytes: int = 1200
    max_meta_backlog_bytes: int = 512 * 1024
    sdp_dir: Path | None = None
    mirror_port: int | None = None
    out_dir: Path | None = None
    max_session_bytes: int = 256 * 1024 * 1024
    fec: bool = False
    transport_cc: bool = False
    """Transport-wide congestion control feedback (``serve --transport-cc``): sessions' RTP packets carry transport
    sequence numbers, clients report arrivals, each session's estimator follows its path (updates.csv ``cc_*``)."""
    pacing: bool = False
    """With ``transport_cc``: RTP leaves through a pacer at 2.5x the estimated rate (``serve --pacing``)."""
    adapt: str = "off"
    """``rate``, with ``transport_cc``: each session's lossy video encoders follow its estimated rate, and the
    estimator probes for capacity (``serve --adapt rate``; :mod:`splitrender.pipeline.adapt`)."""
    metrics_interval_s: float = 5.0
    """Each session logs a ``metrics`` line (its counters, the server's dropped datagrams) this often; 0 = never."""
    isolation: str = "session"
    """``"session"``: a render worker process per session (a hung render ends that session only);
    ``"server"``: one worker for every session, sharing the scene producers' per-frame work (a hung render
    ends every session, and the next session gets a fresh worker)."""
    gi_hz: float = DEFAULT_GI_HZ
    """The rate the scene's DDGI probes are relit at in the render workers (0: for every frame, as the virtual-time
    runner and the ground truth do); see ``Renderer.gi_hz``."""
    render_deadline_s: float = 10.0
    """Watchdog: a frame's render and encode must finish within this, or its worker is killed and its
    session(s) end with an error."""
    setup_deadline_s: float = 60.0
    """Watchdog for a worker's start and a session's set-up (scene loading, method half, encoders)."""
    webrtc_http: tuple[str, int] | None = None
    """``serve --webrtc``: the browser front door's HTTP address (the page, offer/answer, recordings); ``None``:
    no browser sessions (:mod:`splitrender.webrtc`)."""
    webrtc_network: str | None = None
    """``serve --webrtc-network``: shape each browser session's media through an in-process relay with this path
    (a profile name, a netem string or a .toml file); ``None``: direct."""
    tls_cert: Path | None = None
    """``serve --tls-cert``: a PEM certificate (chain); with ``tls_key`` the TCP control channel and the browser
    page are served under TLS (:mod:`splitrender.transport.tls`).  ``None``: plaintext."""
    tls_key: Path | None = None
    """``serve --tls-key``: the PEM private key of ``tls_cert`` (unencrypted)."""
    test_hang: str = dataclasses.field(default_factory=lambda: os.environ.get("SPLITRENDER_TEST_HANG", ""))
    """Test hook, ``"SESSION:FRAME"``: the SESSION-th session (1-based) hangs rendering frame FRAME (taken
    from ``$SPLITRENDER_TEST_HANG``); ``""`` = never."""

    def __post_init__(self) -> None:
        if self.isolation not in ("session", "server"):
            raise ConfigError(f"server isolation: {self.isolation!r} is not one of ['session', 'server']")
        if not (self.gi_hz == 0 or 0.1 <= self.gi_hz <= 240):
            raise ConfigError(f"server gi_hz: must be 0 (every frame) or in [0.1, 240], got {self.gi_hz}")
        for k in ("render_deadline_s", "setup_deadline_s"):
            v = getattr(self, k)
            if not 0.05 <= v <= 3600:
                raise ConfigError(f"server {k}: must be in [0.05, 3600] s, got {v}")
        self.session_options()   # a bad option or adaptation mode fails here, by name
        if self.adapt != "off" and not self.transport_cc:
            raise ConfigError(f"server adapt {self.adapt}: follows the estimated rate, so it needs transport_cc "
                              "(--transport-cc)")
        try:
            parse_test_hang(self.test_hang)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        self.tls_context()   # a missing, unreadable or mismatched certificate or key fails here, by path

    def session_options(self) -> ServerOptions:
        """Each session core's options (:mod:`splitrender.options`)."""
        return options_of(self, ServerOptions, pacing=self.pacing, adapt=self.adapt)

    def tls_context(self) -> ssl.SSLContext | None:
        """The server's TLS context from ``tls_cert`` and ``tls_key``, or ``None`` without them; raises
        ``ConfigError`` naming the file and what was wrong."""
        if (self.tls_cert is None) != (self.tls_key is None):
            given, missing = ("--tls-cert", "--tls-key") if self.tls_key is None else ("--tls-key", "--tls-cert")
            raise ConfigError(f"{given}: needs {missing} too (the certificate and its private key)")
        if self.tls_cert is None or self.tls_key is None:
            return None
        from splitrender.transport.tls import server_context

        return server_context(self.tls_cert, self.tls_key)


def check_method_params(methods: Sequence[str], params: dict[str, dict[str, Any]]) -> None:
    """Build every offered method's config from ``params`` once, so a bad parameter
    fails at startup by name instead of in every session; raises ``ConfigError``."""
    from splitrender.methods import get_method, make_config

    for name in params:
        if name not in methods:
            try:
                get_method(name)
            except ConfigError as exc:
                raise ConfigError(f"--param {name}.*: {exc}") from None
            raise ConfigError(f"--param {name}.*: method {name!r} is not offered (offered: {', '.join(methods)})")
    for name in methods:
        try:
            make_config(get_method(name).config, dict(params.get(name, {})))
        except ConfigError as exc:
            raise ConfigError(f"--param {name}.*: {exc}") from None


def sdp_hint(config: ServerConfig) -> str | None:
    """Why SDP files written without ``mirror_port`` cannot be played on this host, or ``None``."""
    if config.sdp_dir is None or config.mirror_port is not None:
        return None
    return ("--sdp-dir without --mirror-port: the SDP files name the server's own UDP port, which ffplay "
            "on this host cannot bind (the server holds it); add --mirror-port 5004 to copy each stream to "
            "127.0.0.1:5004+2k and play those SDP files with ffplay")


class _UdpProtocol(asyncio.DatagramProtocol):
    def __init__(self, on_datagram: Callable[[bytes, Address], None]) -> None:
        self._on_datagram = on_datagram

    def datagram_received(self, data: bytes, addr: Address) -> None:  # type: ignore[override]
        self._on_datagram(data, (addr[0], addr[1]))

    def error_received(self, exc: Exception) -> None:
        logger.debug("udp error: %s", exc)


class LiveServer:
    """Accepts sessions; use ``async with LiveServer(cfg) as s: await s.serve_forever()``."""

    def __init__(self, config: ServerConfig) -> None:
        from splitrender.methods import methods_for_scene

        self.config = config
        self.methods: tuple[str, ...] = config.methods or tuple(methods_for_scene(config.scene))
        check_method_params(self.methods, config.method_params)
        self.epoch_wall_s = time.time()
        """Wall-clock time (s) of scene time 0: the one scene clock all sessions share."""
        self.scene: Any = None
        """The scene, loaded here too (checked at start; a loaded model's bounds go to clients as ``subject``)."""
        self.workers: set[RenderWorker] = set()
        """Every live render worker (the spare, the shared one, each session's)."""
        self._spare: asyncio.Future[RenderWorker] | None = None
        self._shared: RenderWorker | None = None
        self._shared_lock = asyncio.Lock()
        self.test_hang = parse_test_hang(config.test_hang)
        self.sessions: dict[str, ServerSession] = {}
        self._by_ssrc: dict[int, ServerSession] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self._tcp: asyncio.Server | None = None
        self.udp: asyncio.DatagramTransport | None = None
        self.tcp_address: Address = (config.host, 0)
        self.udp_address: Address = (config.host, 0)
        self.sessions_total = 0
        self.udp_dropped = 0
        self._mirror_next = 0
        self._closed = False
        self.front: Any = None
        """The browser front door (:class:`splitrender.webrtc.app.WebRtcFrontDoor`) with ``webrtc_http``."""
        self.tls: ssl.SSLContext | None = config.tls_context()
        """TLS for the control channel and the browser page (``tls_cert``/``tls_key``), or ``None``."""

    # -- scene clock ---------------------------------------------------------------

    def tick_of(self, wall_s: float) -> int:
        """Index of the shared server frame clock at ``wall_s`` (every session ticks on this grid)."""
        return int(round((wall_s - self.epoch_wall_s) * self.config.server_fps))

    async def frame_ticks(self) -> AsyncIterator[int]:
        """The shared frame clock, for a session's frame loop: wakes at each tick of the grid (scene time
        k / server_fps, so sessions share the producers' work) and yields how many ticks were missed before it
        (rendering overran: they are skipped, not caught up in a burst)."""
        loop = asyncio.get_running_loop()
        interval = 1.0 / self.config.server_fps
        wall_now = time.time()
        next_t = loop.time() + (self.tick_of(wall_now) + 1) * interval - (wall_now - self.epoch_wall_s)
        while True:
            delay = next_t - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            next_t += interval
            skipped = 0
            behind = loop.time() - next_t
            if behind > 0:
                skipped = int(behind / interval) + 1
                next_t += skipped * interval
            yield skipped

    # -- render workers ------------------------------------------------------------

    async def _new_worker(self) -> RenderWorker:
        w = RenderWorker(self.config.scene, self.config.server_fps, self.config.gi_hz)
        self.workers.add(w)
        try:
            await w.start(self.config.setup_deadline_s)    # closes the worker itself when it fails
        finally:
            if w.dead is not None:
                self.workers.discard(w)
        return w

    def _spawn_spare(self) -> None:
        if self._closed or self.config.isolation != "session":
            return
        self._spare = asyncio.ensure_future(self._new_worker())
        self._spare.add_done_callback(lambda t: t.cancelled() or t.exception())

    async def acquire_worker(self) -> RenderWorker:
        """The worker a new session runs in: the warm spare (a new spare starts behind it) or a new one
        (``isolation = "session"``), or the shared one, replaced when it was killed (``"server"``)."""
        if self.config.isolation == "server":
            async with self._shared_lock:
                if self._shared is None or self._shared.dead is not None:
                    self._shared = await self._new_worker()
                return self._shared
        spare, self._spare = self._spare, None
        self._spawn_spare()
        if spare is not None:
            try:
                w = await spare
                if w.dead is None:
                    return w
            except Exception as exc:  # noqa: BLE001 - try once more with a fresh worker below
                logger.warning("spare render worker failed to start: %s", exc)
        return await self._new_worker()

    async def release_worker(self, worker: RenderWorker, session_id: str) -> None:
        """A session ended: drop its half from the shared worker, or stop its own worker."""
        if self.config.isolation == "server" and worker.dead is None:
            with contextlib.suppress(Exception):
                await worker.call("close", session_id, deadline_s=self.config.render_deadline_s)
            return
        try:
            await worker.close()
        finally:
            self.workers.discard(worker)

    def next_mirror_port(self) -> int | None:
        """Port to mirror the next stream to (``mirror_port + 2k``), or ``None`` (no mirror,
        or the ports ran out)."""
        if self.config.mirror_port is None:
            return None
        port = self.config.mirror_port + 2 * self._mirror_next
        if port > 65535:
            return None
        self._mirror_next += 1
        return port

    # -- lifecycle -----------------------------------------------------------------

    async def start(self) -> None:
        """Bind UDP and TCP (so a busy port fails at once), load the scene, start the first render
        worker (its renderer and shaders ready, so a GL fault fails here), then accept connections;
        raises ``BindError``."""
        from splitrender.scene.loader import get_scene

        cfg = self.config
        loop = asyncio.get_running_loop()
        try:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _UdpProtocol(self._on_datagram), local_addr=(cfg.host, cfg.udp_port)
            )
        except (OSError, OverflowError) as exc:
            raise BindError(f"cannot listen on udp {cfg.host}:{cfg.udp_port}: {describe_os_error(exc)}") from exc
        self.udp = transport
        sock = transport.get_extra_info("sockname")
        self.udp_address = (sock[0], sock[1])
        try:
            self._tcp = await asyncio.start_server(self._on_connect, cfg.host, cfg.port, start_serving=False,
                                                   ssl=self.tls, ssl_handshake_timeout=cfg.hello_timeout_s
                                                   if self.tls is not None else None)
        except (OSError, OverflowError) as exc:
            raise BindError(f"cannot listen on tcp {cfg.host}:{cfg.port}: {describe_os_error(exc)}") from exc
        sock = self._tcp.sockets[0].getsockname()
        self.tcp_address = (sock[0], sock[1])
        self.scene = get_scene(cfg.scene)
        first = await self._new_worker()
        if cfg.isolation == "server":
            self._shared = first
        else:
            self._spare = asyncio.get_running_loop().create_future()
            self._spare.set_result(first)
        if cfg.webrtc_http is not None:
            from splitrender.webrtc.app import WebRtcFrontDoor

            self.front = WebRtcFrontDoor(self, cfg.webrtc_http, cfg.webrtc_network)
            await self.front.start()
        await self._tcp.start_serving()
        logger.info("serving %s on tcp %s:%d, udp %s:%d (methods %s)", cfg.scene, *self.tcp_address,
                    *self.udp_address, ",".join(self.methods))
        hint = sdp_hint(cfg)
        if hint is not None:
            logger.warning("%s", hint)

    async def serve_forever(self) -> None:
        """Wait until cancelled (sessions run in their own connection tasks)."""
        assert self._tcp is not None, "call start() first"
        await self._tcp.serve_forever()

    async def close(self) -> None:
        """Stop accepting, end every session (cancel and wait), close sockets, stop the workers."""
        if self._closed:
            return
        self._closed = True
        if self._tcp is not None:
            self._tcp.close()
        if self.front is not None:
            await self.front.close()
        tasks = list(self._tasks)
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.gather(*tasks, return_exceptions=True)
        if self._tcp is not None:
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._tcp.wait_closed(), 2.0)
        if self.udp is not None:
            self.udp.close()
        if self._spare is not None:
            self._spare.cancel()
            with contextlib.suppress(BaseException):
                await self._spare
        workers, self.workers = list(self.workers), set()
        await asyncio.gather(*(w.close() for w in workers), return_exceptions=True)
        logger.info("server closed after %d sessions", self.sessions_total)

    async def __aenter__(self) -> LiveServer:
        try:
            await self.start()
        except BaseException:
            await self.close()
            raise
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # -- sessions ------------------------------------------------------------------

    async def _on_connect(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        if self._closed:
            writer.close()
            return
        self._tasks.add(task)  # type: ignore[arg-type]
        self.sessions_total += 1
        session = ServerSession(self, reader, writer, self.sessions_total)
        try:
            await session.run()
        except asyncio.CancelledError:
            # the server is closing: this is the connection's top-level task, and asyncio's stream
            # callback (Python 3.11) logs a cancelled handler's exception as an error with a traceback
            logger.info("session %s: closed with the server", session.id)
        finally:
            self._tasks.discard(task)  # type: ignore[arg-type]

    def register(self, session: ServerSession, ssrcs: Sequence[int]) -> None:
        """Route RTCP naming ``ssrcs`` to ``session``."""
        self.sessions[session.id] = session
        for s in ssrcs:
            self._by_ssrc[s] = session

    def unregister(self, session: ServerSession) -> None:
        self.sessions.pop(session.id, None)
        for s in [s for s, v in self._by_ssrc.items() if v is session]:
            del self._by_ssrc[s]

    def ssrc_taken(self, ssrc: int) -> bool:
        return ssrc in self._by_ssrc

    def send_datagram(self, data: bytes, addr: Address) -> None:
        if self.udp is not None and not self.udp.is_closing():
            self.udp.sendto(data, addr)

    def _on_datagram(self, data: bytes, addr: Address) -> None:
        """RTCP from clients: find the session by the media SSRC its headers name (fixed offsets, no parsing), and
        hand the datagram over; the session checks the source address before it parses anything."""
        try:
            ssrc = rtcp_route_ssrc(data)
        except RtcpError as exc:
            self.udp_dropped += 1
            logger.debug("udp from %s: %s", addr, exc)
            return
        session = self._by_ssrc.get(ssrc) if ssrc is not None else None
        if session is None:
            self.udp_dropped += 1
            return
        session.on_datagram(data, addr)


async def serve(config: ServerConfig, ready: Callable[[LiveServer], Awaitable[None] | None] | None = None) -> None:
    """Run a server until cancelled; ``ready(server)`` is called once it listens."""
    async with LiveServer(config) as server:
        if ready is not None:
            r = ready(server)
            if asyncio.iscoroutine(r):
                await r
        await server.serve_forever()
