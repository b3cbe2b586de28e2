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

Bad requests get 400 with a JSON ``error`` naming what was wrong; a busy server 503.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import re
import time
from pathlib import Path
from typing import Any

from aiohttp import web

from ..errors import ConfigError, describe_error
from .messages import (BROWSER_METHODS, PageMessageError, browser_methods, parse_rows, parse_session_request,
                       rgba_to_rgb)
from .session import BrowserSession

__all__ = ["WebRtcFrontDoor", "STATIC", "TRACE_RATE_HZ", "restrict_ice_host"]

logger = logging.getLogger(__name__)

STATIC = Path(__file__).parent / "static"
TRACE_RATE_HZ = 120.0
"""Rate a trace is sampled at for the page (it interpolates between samples)."""
RECORDING_GRACE_S = 300.0
"""How long after a session ends its recording may still be posted."""
MAX_TRACE_S = 600.0
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
        self.max_body = max(1 << 20, cfg.max_pixels * 4 + 4096)

    @property
    def active(self) -> list[BrowserSession]:
        return [s for s in self.sessions.values() if not s.ended.is_set()]

    # ------------------------------------------------------------------ lifecycle

    async def start(self) -> None:
        from ..transport.errors import BindError, describe_os_error

        restrict_ice_host(self.server.config.host)
        app = web.Application(client_max_size=self.max_body)
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
        from ..scene.trace import BUILTIN_TRACES

        cfg = self.server.config
        return web.json_response({"scene": cfg.scene, "methods": self.offered, "method_notes": {m: BROWSER_METHODS[m]
                                                                                                 for m in self.offered},
                                  "traces": sorted(BUILTIN_TRACES), "fov_y_deg": cfg.fov_y_deg,
                                  "server_fps": cfg.server_fps, "max_pixels": cfg.max_pixels,
                                  "network": self.network_text, "recording": cfg.out_dir is not None})

    async def _clock(self, request: web.Request) -> web.Response:
        return web.json_response({"server_ms": time.time() * 1000})

    async def _trace(self, request: web.Request) -> web.Response:
        from ..scene.trace import BUILTIN_TRACES, get_trace

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
        trace = get_trace(name, duration, scene=self.server.scene, fov_y_deg=self.server.config.fov_y_deg,
                          aspect=width / height).sample(TRACE_RATE_HZ)
        return web.json_response({"name": name, "duration_s": float(trace.duration_s),
                                  "t": [round(float(t), 6) for t in trace.t_s],
                                  "p": [[round(float(v), 6) for v in p] for p in trace.positions],
                                  "q": [[round(float(v), 7) for v in o] for o in trace.orientations]})

    async def _offer(self, request: web.Request) -> web.Response:
        try:
            body = await request.json()
        except (json.JSONDecodeError, UnicodeDecodeError, ValueError) as exc:
            return _bad(f"session request: not JSON ({exc})")
        try:
            req = parse_session_request(body, self.offered, self.server.config.max_pixels)
        except PageMessageError as exc:
            return _bad(str(exc))
        busy = len(self.server.sessions) + len(self.active)
        if busy >= self.server.config.max_sessions:
            return web.json_response({"error": f"server busy: {busy} sessions already"}, status=503)
        self._expire()
        self.sessions_total += 1
        session = BrowserSession(self, req, self.sessions_total)
        self.sessions[session.id] = session
        try:
            answer = await session.open()
        except PageMessageError as exc:
            await session.close()
            return _bad(str(exc))
        except Exception as exc:  # noqa: BLE001 - a failed set-up ends this session only
            logger.exception("browser session %s: set-up failed", session.id)
            await session.close()
            return web.json_response({"error": f"session set-up failed: {describe_error(exc)}"}, status=500)
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
        from ..client.session import _save_image

        s = self._session_for_upload(request)
        try:
            frame = int(request.match_info["frame"])
        except ValueError:
            return _bad(f"recording image: frame {request.match_info['frame']!r} is not an integer")
        if not 0 <= frame < 10_000_000:
            return _bad(f"recording image: frame {frame} out of range")
        data = await request.read()
        try:
            rgb = rgba_to_rgb(data, s.req.width, s.req.height)
        except PageMessageError as exc:
            return _bad(str(exc))
        assert s.out_dir is not None
        await asyncio.get_running_loop().run_in_executor(None, _save_image, s.out_dir, frame, rgb, None)
        return web.json_response({"ok": True})

    async def _recording(self, request: web.Request) -> web.Response:
        from ..tabular import atomic_write_bytes, write_csv

        s = self._session_for_upload(request)
        try:
            body = await request.json()
        except (json.JSONDecodeError, UnicodeDecodeError, ValueError) as exc:
            return _bad(f"recording: not JSON ({exc})")
        if not isinstance(body, dict):
            return _bad("recording: expected a JSON object")
        try:
            rows = parse_rows(body.get("rows"))
        except PageMessageError as exc:
            return _bad(str(exc))
        stats = body.get("stats") if isinstance(body.get("stats"), dict) else {}
        d = s.out_dir
        assert d is not None
        d.mkdir(parents=True, exist_ok=True)
        trace = str(body.get("trace", ""))[:100]
        duration = body.get("duration_s")
        duration = float(duration) if isinstance(duration, (int, float)) and math.isfinite(duration) else math.nan
        server = s.server_counters()
        counters: dict[str, Any] = {**server, **{f"browser_{k}": v for k, v in stats.items()
                                                 if isinstance(v, (int, float)) and not isinstance(v, bool)}}
        # the keys the scorer's summary reads, as the headless client names them
        counters["rtp_bytes"] = int(server.get("rtp_payload_bytes", 0)) + 12 * int(server.get("rtp_packets", 0))
        counters["meta_bytes"] = int(server.get("frame_meta_bytes", 0)) + int(server.get("sas_slot_bytes", 0))
        counters["frames_partial"] = 0
        rec = {"session_id": s.id, "method": s.method, "params": s.params.get("config", {}), "scene": s.cfg.scene,
               "fov_y_deg": s.cfg.fov_y_deg, "server_fps": s.cfg.server_fps, "trace": trace, "width": s.req.width,
               "height": s.req.height, "display_hz": s.display_hz, "tracker_hz": s.display_hz,
               "duration_s": duration, "images": True, "complete": bool(body.get("complete", True)),
               "network": s.front.network_text or "live",
               "client": {"kind": "browser", "user_agent": str(body.get("user_agent", ""))[:300],
                          "record_every": body.get("record_every")}}
        write_csv(d / "frames.csv", rows)
        atomic_write_bytes(d / "recording.json", json.dumps(rec, indent=2, default=str).encode())
        atomic_write_bytes(d / "counters.json", json.dumps(counters, indent=2, default=str).encode())
        logger.info("browser session %s: recording of %d rows written to %s", s.id, len(rows), d)
        return web.json_response({"ok": True, "dir": str(d), "rows": len(rows)})


def _bad(text: str) -> web.Response:
    return web.json_response({"error": text}, status=400)


def check_http_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` for ``--http`` (as ``splitrender shape`` reads its addresses); raises ConfigError naming it."""
    from ..errors import NetworkConfigError
    from ..netsim.cli import parse_address

    try:
        return parse_address(text)
    except NetworkConfigError as exc:
        raise ConfigError(f"--http: {exc}") from None
