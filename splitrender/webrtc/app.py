"""The front door's HTTP side (aiohttp): the page, traces, offer/answer, and the recording posted back.

Routes:

* ``GET /``: the page (``static/index.html``); ``GET /static/NAME``: its modules;
* ``GET /api/info``: scene, the methods the page can draw, traces, field of view, frame rate;
* ``GET /api/clock``: the server's wall clock (ms), for the page's offset estimate;
* ``GET /api/trace?name=&duration_s=&width=&height=``: a built-in trace sampled at 120 Hz, as JSON (fitted
  around a loaded model as the headless client fits it);
* ``POST /api/session``: the page's offer and terms (:func:`~.messages.parse_session_request`); answers with
  the SDP answer and the session's terms;
* ``POST /api/session/ID/image/FRAME``: one canvas read-back (RGBA, ``width x height x 4`` bytes);
* ``POST /api/session/ID/recording``: the rows (JSON) and the browser's own statistics.  The server writes
  the headless client's recording (``recording.json``, ``counters.json``, ``frames.csv``, ``images/``) under
  ``--out``/ID, which :func:`splitrender.client.score.score_recording` scores as it scores any other.

With ``serve --token``, every ``/api/`` route needs the token, as ``Authorization: Bearer TOKEN`` or
``X-Splitrender-Token: TOKEN`` (compared in constant time): without it 401, a wrong one 403.  The page and its
modules are served without it; the page takes the token from its URL (``#token=...``) or asks for it.

Every request is bounded before it costs anything (the numbers below, ``docs/protocol.md`` section 11): the
body's bytes per route, JSON's values and depth (:func:`~.messages.decode_json`), the images a session may
post, the sessions per client address and in all; a trace is made in a thread of its own, one at a time.
Bad requests get a 4xx with a JSON ``error`` naming what was wrong (400 malformed, 401/403 token, 404 no such
session, 409 no recordings, 413 too large, 429 too many sessions from one address); a busy server 503.
"""

from __future__ import annotations

import asyncio
import hmac
import json
import logging
import re
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from aiohttp import web

from ..errors import ConfigError, NetworkConfigError, RemoteProtocolError
from ..pipeline.live import busy_refusal
from ..pipeline.recording import ClientRecording, manifest, save_image
from ..scene.trace import BUILTIN_TRACES, get_trace
from ..transport.errors import BindError, describe_os_error
from .messages import (BROWSER_METHODS, MAX_ROWS, MAX_STATS, PageMessageError, Recording, browser_methods,
                       decode_json, parse_recording, parse_session_request, rgba_to_rgb)
from .session import BrowserSession

__all__ = ["WebRtcFrontDoor", "STATIC", "TRACE_RATE_HZ", "restrict_ice_host", "TOKEN_HEADER", "MAX_TRACE_S",
           "MAX_TRACE_JOBS", "MAX_TRACE_WAITING", "MAX_SESSION_BODY", "MAX_SESSION_VALUES", "MAX_RECORDING_BODY",
           "MAX_RECORDING_VALUES", "MAX_IMAGES_PER_SESSION", "MAX_IMAGE_BYTES_PER_SESSION",
           "MAX_SESSIONS_PER_ADDRESS"]

logger = logging.getLogger(__name__)

STATIC = Path(__file__).parent / "static"
TRACE_RATE_HZ = 120.0
"""Rate a trace is sampled at for the page (it interpolates between samples)."""
RECORDING_GRACE_S = 300.0
"""How long after a session ends its recording may still be posted."""
MAX_TRACE_S = 120.0
"""Longest trace the page may ask for (s).  A trace costs about 10 ms of CPU per second of it (600 s took 6 s)."""
MAX_TRACE_JOBS = 1
"""Traces made at once, each in the front door's own thread (never on the event loop, which ticks every session)."""
MAX_TRACE_WAITING = 4
"""Trace requests that may wait for :data:`MAX_TRACE_JOBS`; more are answered 503 (busy) at once."""
TRACE_CACHE = 8
"""Traces kept, encoded, after they are made (a page's reload, or the next session on the same trace, is free)."""
MAX_SESSION_BODY = 128 * 1024
"""Largest ``POST /api/session`` body (bytes): the SDP offer (at most 64 KiB) and the page's terms."""
MAX_SESSION_VALUES = 256
"""Most JSON values in a session request (it has 6)."""
MAX_RECORDING_BODY = 8 * 1024 * 1024
"""Largest ``POST .../recording`` body (bytes): about 18,000 rows as the page writes them (decoding one this
large peaks at about 70 MB)."""
MAX_RECORDING_VALUES = 20 * MAX_ROWS + 4 * MAX_STATS + 64
"""Most JSON values in a recording: :data:`~.messages.MAX_ROWS` rows of 17 columns, the statistics, the notes."""
MAX_IMAGES_PER_SESSION = 2000
"""Most read-backs one session may post (a 10 s session reading back every 4th frame at 60 Hz posts 150)."""
MAX_IMAGE_BYTES_PER_SESSION = 1 << 30
"""Most read-back bytes (RGBA, as posted) one session may post: 1 GiB (128 frames at 1920x1080)."""
MAX_SESSIONS_PER_ADDRESS = 4
"""Most browser sessions running at once from one client address (all sessions are capped by --max-sessions)."""
TOKEN_HEADER = "X-Splitrender-Token"
"""The header the page sends ``serve --token``'s token in (``Authorization: Bearer TOKEN`` is taken too)."""
_STATIC_NAME = re.compile(r"^[a-z][a-z0-9_]*\.(js|html|css)$")
_CONTENT_TYPES = {"js": "text/javascript", "html": "text/html", "css": "text/css"}


def restrict_ice_host(host: str) -> None:
    """Make aiortc (aioice) gather host candidates on ``host`` only: the server's ``--host``.  aioice leaves
    loopback out by default and offers every other interface; a server bound to one address offers that one."""
    import aioice.ice

    if host in ("0.0.0.0", "", "::"):
        return
    aioice.ice.get_host_addresses = lambda use_ipv4, use_ipv6: [host]   # type: ignore[assignment]


class WebRtcFrontDoor:
    """The HTTP server and the browser sessions of one :class:`~splitrender.server.server.LiveServer`."""

    def __init__(self, server: Any, address: tuple[str, int], network: str | None = None) -> None:
        self.server = server
        self.requested = address
        self.address: tuple[str, int] = address
        self.network_text = network
        self.network: Any = None
        if network:
            from ..netsim.config import parse_path

            self.network = parse_path(network)
        self.ice_host = server.config.host if server.config.host not in ("0.0.0.0", "") else "127.0.0.1"
        self.sessions: dict[str, BrowserSession] = {}
        self.sessions_total = 0
        self._runner: web.AppRunner | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self.offered = browser_methods(list(server.methods))
        cfg = server.config
        self.token: str | None = cfg.token or None
        self.max_body = max(MAX_RECORDING_BODY, cfg.max_pixels * 4)
        """The app's own bound on a body (aiohttp's ``client_max_size``); each route reads less (:meth:`_body`)."""
        self._trace_pool: ThreadPoolExecutor | None = None
        self._trace_pending = 0
        self._trace_cache: OrderedDict[tuple[str, float, int, int], bytes] = OrderedDict()
        self.refused: dict[int, int] = {}
        """Requests refused, by HTTP status (400, 401, 403, 413, 429, 503 ...)."""

    @property
    def active(self) -> list[BrowserSession]:
        return [s for s in self.sessions.values() if not s.ended.is_set()]

    # ------------------------------------------------------------------ lifecycle

    async def start(self) -> None:
        restrict_ice_host(self.server.config.host)
        app = web.Application(client_max_size=self.max_body, middlewares=[self._guard])
        self._trace_pool = ThreadPoolExecutor(MAX_TRACE_JOBS, thread_name_prefix="splitrender-trace")
        app.add_routes([
            web.get("/", self._index), web.get("/static/{name}", self._static), web.get("/api/info", self._info),
            web.get("/api/clock", self._clock), web.get("/api/trace", self._trace),
            web.post("/api/session", self._offer), web.post("/api/session/{sid}/image/{frame}", self._image),
            web.post("/api/session/{sid}/recording", self._recording),
        ])
        self._runner = web.AppRunner(app, access_log=None)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.requested[0], self.requested[1],
                           ssl_context=getattr(self.server, "tls", None))   # https with serve --tls-cert
        try:
            await site.start()
        except (OSError, OverflowError) as exc:
            await self._runner.cleanup()
            raise BindError(f"cannot listen on http {self.requested[0]}:{self.requested[1]}: "
                            f"{describe_os_error(exc)}") from exc
        sock = site._server.sockets[0].getsockname()   # type: ignore[union-attr]
        self.address = (sock[0], sock[1])
        logger.info("browser front door on http://%s:%d/ (methods %s%s)", *self.address, ",".join(self.offered),
                    f"; sessions shaped by {self.network_text}" if self.network_text else "")

    async def close(self) -> None:
        tasks = list(self._tasks)
        for t in tasks:
            t.cancel()
        if tasks:
            await asyncio.gather(*tasks, return_exceptions=True)
        if self._runner is not None:
            await self._runner.cleanup()
        if self._trace_pool is not None:
            self._trace_pool.shutdown(wait=False, cancel_futures=True)

    # ------------------------------------------------------------------ the token and the bounds

    @web.middleware
    async def _guard(self, request: web.Request,
                     handler: Callable[[web.Request], Awaitable[web.StreamResponse]]) -> web.StreamResponse:
        """``--token`` on every ``/api/`` route (401 without it, 403 wrong); :class:`_Refused` as its answer; every
        refusal counted by status."""
        if self.token is not None and request.path.startswith("/api/"):
            presented = _presented_token(request)
            if presented is None:
                return self._refuse(401, "this server needs its token (serve --token): send it as 'Authorization: "
                                    f"Bearer TOKEN' or '{TOKEN_HEADER}: TOKEN' (the page takes it from its URL, "
                                    "#token=TOKEN)", {"WWW-Authenticate": 'Bearer realm="splitrender"'})
            if not hmac.compare_digest(presented.encode("utf-8", "surrogateescape"),
                                       self.token.encode("utf-8", "surrogateescape")):
                return self._refuse(403, "wrong token")
        try:
            response = await handler(request)
        except _Refused as exc:
            return self._refuse(exc.status, exc.text)
        except web.HTTPException as exc:
            self.refused[exc.status] = self.refused.get(exc.status, 0) + 1
            raise
        if response.status >= 400:
            self.refused[response.status] = self.refused.get(response.status, 0) + 1
        return response

    def _refuse(self, status: int, text: str, headers: dict[str, str] | None = None) -> web.Response:
        self.refused[status] = self.refused.get(status, 0) + 1
        return web.json_response({"error": text}, status=status, headers=headers)

    async def _body(self, request: web.Request, limit: int, where: str) -> bytes:
        """The request's body, read no further than ``limit`` bytes (413 naming it past that)."""
        n = request.content_length
        if n is not None and n > limit:
            raise _Refused(413, f"{where}: {n} bytes, more than the {limit} allowed")
        data = bytearray()
        async for chunk in request.content.iter_chunked(1 << 16):
            data += chunk
            if len(data) > limit:
                raise _Refused(413, f"{where}: more than the {limit} bytes allowed")
        return bytes(data)

    # ------------------------------------------------------------------ handlers

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html", headers={"Content-Type": "text/html", "Cache-Control": "no-store"})

    async def _static(self, request: web.Request) -> web.StreamResponse:
        name = request.match_info["name"]
        path = STATIC / name
        if not _STATIC_NAME.match(name) or not path.is_file():
            raise web.HTTPNotFound(text=f"no such file: {name}")
        return web.FileResponse(path, headers={"Content-Type": _CONTENT_TYPES[name.rsplit(".", 1)[1]],
                                               "Cache-Control": "no-store"})

    async def _info(self, request: web.Request) -> web.Response:
        cfg = self.server.config
        return web.json_response({"scene": cfg.scene, "methods": self.offered, "method_notes": {m: BROWSER_METHODS[m]
                                                                                                 for m in self.offered},
                                  "traces": sorted(BUILTIN_TRACES), "fov_y_deg": cfg.fov_y_deg,
                                  "server_fps": cfg.server_fps, "max_pixels": cfg.max_pixels,
                                  "network": self.network_text, "recording": cfg.out_dir is not None})

    async def _clock(self, request: web.Request) -> web.Response:
        return web.json_response({"server_ms": time.time() * 1000})

    async def _trace(self, request: web.Request) -> web.Response:
        q = request.query
        name = q.get("name", "walk")
        if name not in BUILTIN_TRACES:
            return _bad(f"trace: {name!r} is not a built-in trace ({', '.join(sorted(BUILTIN_TRACES))})")
        try:
            duration = float(q.get("duration_s", "10"))
            width, height = int(q.get("width", "320")), int(q.get("height", "180"))
        except ValueError as exc:
            return _bad(f"trace: {exc}")
        if not (0.5 <= duration <= MAX_TRACE_S) or not (16 <= width <= 7680 and 16 <= height <= 4320):
            return _bad(f"trace: duration_s must be in [0.5, {MAX_TRACE_S:g}] and the size within 16..7680 x 16..4320")
        key = (name, round(duration, 3), width, height)
        body = self._trace_cache.get(key)
        if body is None:
            if self._trace_pending >= MAX_TRACE_JOBS + MAX_TRACE_WAITING:
                raise _Refused(503, f"trace: busy ({self._trace_pending} traces being made or waiting); try again")
            assert self._trace_pool is not None
            self._trace_pending += 1
            job = asyncio.get_running_loop().run_in_executor(self._trace_pool, self._make_trace, *key)
            job.add_done_callback(self._trace_done)      # when the thread is done, even if the page is gone
            body = await asyncio.shield(job)
            self._trace_cache[key] = body
            while len(self._trace_cache) > TRACE_CACHE:
                self._trace_cache.popitem(last=False)
        return web.Response(body=body, content_type="application/json")

    def _trace_done(self, _job: Any) -> None:
        self._trace_pending -= 1

    def _make_trace(self, name: str, duration: float, width: int, height: int) -> bytes:
        """A built-in trace sampled at :data:`TRACE_RATE_HZ`, as the JSON the page reads (in the trace thread)."""
        trace = get_trace(name, duration, scene=self.server.scene, fov_y_deg=self.server.config.fov_y_deg,
                          aspect=width / height).sample(TRACE_RATE_HZ)
        return json.dumps({"name": name, "duration_s": float(trace.duration_s),
                           "t": [round(float(t), 6) for t in trace.t_s],
                           "p": [[round(float(v), 6) for v in p] for p in trace.positions],
                           "q": [[round(float(v), 7) for v in o] for o in trace.orientations]}).encode()

    async def _offer(self, request: web.Request) -> web.Response:
        raw = await self._body(request, MAX_SESSION_BODY, "session request")
        try:
            body = decode_json(raw, "session request", MAX_SESSION_BODY, MAX_SESSION_VALUES)
            req = parse_session_request(body, self.offered, self.server.config.max_pixels)
        except PageMessageError as exc:
            return _bad(str(exc))
        busy = busy_refusal(len(self.server.sessions) + len(self.active), self.server.config.max_sessions)
        if busy is not None:
            return web.json_response({"error": busy}, status=503)
        remote = request.remote or "?"
        mine = sum(1 for s in self.active if s.remote == remote)
        if mine >= MAX_SESSIONS_PER_ADDRESS:
            raise _Refused(429, f"session request: {mine} sessions from {remote} already, the most one address may "
                                "run at once")
        self._expire()
        self.sessions_total += 1
        session = BrowserSession(self, req, self.sessions_total)
        session.remote = remote
        session.peer = remote     # as the logs name it
        self.sessions[session.id] = session
        try:   # a failed set-up (logged, the session ended with its error) ends this session only
            answer = await session.set_up(session.open())
        except RemoteProtocolError as exc:     # the page's request or offer (PageMessageError) or its method's streams
            await session.close()
            return _bad(str(exc))
        if answer is None:
            await session.close()
            return web.json_response({"error": session.end_reason}, status=500)
        task = asyncio.ensure_future(session.run())
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return web.json_response(answer)

    def _expire(self) -> None:
        now = time.time()
        for sid, s in list(self.sessions.items()):
            if s.ended_at is not None and now - s.ended_at > RECORDING_GRACE_S:
                del self.sessions[sid]

    def _session_for_upload(self, request: web.Request) -> BrowserSession:
        sid = request.match_info["sid"]
        s = self.sessions.get(sid)
        if s is None:
            raise web.HTTPNotFound(text=json.dumps({"error": f"no session {sid!r} (or its recording time is over)"}),
                                   content_type="application/json")
        if s.out_dir is None:
            raise web.HTTPConflict(text=json.dumps({"error": "this server keeps no recordings (start it with --out DIR)"}),
                                   content_type="application/json")
        return s

    async def _image(self, request: web.Request) -> web.Response:
        s = self._session_for_upload(request)
        try:
            frame = int(request.match_info["frame"])
        except ValueError:
            return _bad(f"recording image: frame {request.match_info['frame']!r} is not an integer")
        if not 0 <= frame < 10_000_000:
            return _bad(f"recording image: frame {frame} out of range")
        size = s.req.width * s.req.height * 4
        c = s.counters
        if c["images_received"] >= MAX_IMAGES_PER_SESSION:
            raise _Refused(413, f"recording image: this session has posted {c['images_received']} images, the most "
                                "one session may")
        if c["image_bytes_received"] + size > MAX_IMAGE_BYTES_PER_SESSION:
            raise _Refused(413, f"recording image: this session has posted {c['image_bytes_received']} bytes of "
                                f"images; {size} more is past the {MAX_IMAGE_BYTES_PER_SESSION} one session may")
        data = await self._body(request, size, "recording image")
        try:
            rgb = rgba_to_rgb(data, s.req.width, s.req.height)
        except PageMessageError as exc:
            return _bad(str(exc))
        assert s.out_dir is not None
        s.count("images_received")
        s.count("image_bytes_received", size)
        await asyncio.get_running_loop().run_in_executor(None, save_image, s.out_dir, frame, rgb, None)
        return web.json_response({"ok": True})

    async def _recording(self, request: web.Request) -> web.Response:
        s = self._session_for_upload(request)
        raw = await self._body(request, MAX_RECORDING_BODY, "recording")
        loop = asyncio.get_running_loop()
        try:        # decoding 8 MiB of rows takes a quarter of a CPU second: not on the event loop
            rec = await loop.run_in_executor(None, _decode_recording, raw)
        except PageMessageError as exc:
            return _bad(str(exc))
        await s.read_sender_stats()
        d = await loop.run_in_executor(None, self._write_recording, s, rec)
        logger.info("browser session %s: recording of %d rows written to %s", s.id, len(rec.rows), d)
        return web.json_response({"ok": True, "dir": str(d), "rows": len(rec.rows)})

    @staticmethod
    def _write_recording(s: BrowserSession, body: Recording) -> Path:
        """The headless client's recording files for ``s`` under its ``--out`` folder (in an executor thread)."""
        d = s.out_dir
        assert d is not None
        # the session's counters under the headless client's names where they count the same, and the page's own
        counters: dict[str, Any] = {**s.server_counters(), **{f"browser_{k}": v for k, v in body.stats.items()}}
        rec = manifest(s.id, s.method, s.params.get("config", {}), s.cfg.scene, s.cfg.fov_y_deg, s.cfg.server_fps,
                       body.trace, s.req.width, s.req.height, s.display_hz, s.display_hz, body.duration_s, True,
                       {"kind": "browser", "user_agent": body.user_agent, "record_every": body.record_every},
                       complete=body.complete, network=s.front.network_text or "live")
        ClientRecording(d).finish(rec, counters, body.rows)
        return d


class _Refused(Exception):
    """A request refused with ``status`` (4xx, or 503 busy); ``text`` names what was wrong."""

    def __init__(self, status: int, text: str) -> None:
        super().__init__(text)
        self.status = status
        self.text = text


def _decode_recording(raw: bytes) -> Recording:
    return parse_recording(decode_json(raw, "recording", MAX_RECORDING_BODY, MAX_RECORDING_VALUES))


def _presented_token(request: web.Request) -> str | None:
    """The token a request carries (``Authorization: Bearer`` or :data:`TOKEN_HEADER`), or ``None``."""
    auth = request.headers.get("Authorization", "")
    if auth[:7].lower() == "bearer ":
        return auth[7:].strip()
    return request.headers.get(TOKEN_HEADER)


def _bad(text: str) -> web.Response:
    return web.json_response({"error": text}, status=400)


def check_http_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` for ``--http`` (as ``splitrender shape`` reads its addresses); raises ConfigError naming it."""
    from ..netsim.cli import parse_address

    try:
        return parse_address(text)
    except NetworkConfigError as exc:
        raise ConfigError(f"--http: {exc}") from None
