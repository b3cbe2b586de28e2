"""``splitrender serve``: argument definitions and the entry point."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from pathlib import Path
from typing import Any

from splitrender.errors import ConfigError
from splitrender.options import ServerProtocolOptions, add_option_arguments, options_from_args

__all__ = ["add_serve_arguments", "main_serve", "config_from_args"]

logger = logging.getLogger(__name__)


def add_serve_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``splitrender serve``."""
    from splitrender.server.server import DEFAULT_GI_HZ, DEFAULT_PORT, DEFAULT_UDP_PORT

    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1; 0.0.0.0 for all)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"TCP control port (default {DEFAULT_PORT})")
    p.add_argument("--udp-port", type=int, default=DEFAULT_UDP_PORT,
                   help=f"UDP port for RTP/RTCP, shared by all sessions (default {DEFAULT_UDP_PORT}; 0 = any)")
    p.add_argument("--token", default=None, help="shared secret clients must present in Hello")
    p.add_argument("--methods", default=None, help="comma-separated methods to offer (default: all)")
    p.add_argument("--param", action="append", default=[], metavar="METHOD.KEY=VALUE",
                   help="method parameter (TOML value), repeatable, e.g. --param atw.overscan=1.4")
    p.add_argument("--scene", default="default", help="built-in scene or a scene file")
    p.add_argument("--server-fps", type=int, default=30, help="frame clock, frames per second")
    p.add_argument("--fov", type=float, default=60.0, help="vertical field of view, degrees")
    p.add_argument("--predictor", default="cv", help="pose predictor: none, cv, ca, cv_savgol, ca_savgol")
    p.add_argument("--max-sessions", type=int, default=8)
    p.add_argument("--sdp-dir", type=Path, default=None, help="write one SDP file per stream here")
    p.add_argument("--mirror-port", type=int, default=None,
                   help="with --sdp-dir: also send each stream to 127.0.0.1:PORT+2k for ffplay")
    p.add_argument("--out", type=Path, default=None, help="write per-session feedback.csv (latency per frame) here")
    p.add_argument("--fec", action="store_true",
                   help="forward error correction: an RFC 5109 parity packet per group of up to 16 RTP packets")
    p.add_argument("--transport-cc", action="store_true",
                   help="transport-wide congestion control feedback: each session estimates its path's rate "
                        "(updates.csv cc_* columns with --out)")
    p.add_argument("--pacing", action="store_true",
                   help="RTP leaves through a pacer at 2.5x each session's estimated rate (implies --transport-cc)")
    p.add_argument("--adapt", choices=("off", "rate", "full"), default="off",
                   help="rate: each session's lossy video encoders follow its estimated rate, and the estimator probes "
                        "for capacity (implies --transport-cc); full: that, and each method's own knobs choose its "
                        "operating point; off (default): fixed operating points.  Browser sessions (--webrtc) follow the "
                        "page's REMB estimate instead")
    p.add_argument("--isolation", choices=("session", "server"), default="session",
                   help="render workers: one process per session (a hung render ends that session only; default) "
                        "or one for the server (scene producers shared by every session)")
    p.add_argument("--gi-hz", type=float, default=None,
                   help="relight the scene's global illumination (DDGI probes) this many times a second, whatever "
                        "the frame rate (0: every frame, as the ground truth does; default "
                        f"{DEFAULT_GI_HZ:g})")
    p.add_argument("--render-deadline", type=float, default=10.0,
                   help="watchdog: seconds a frame's render and encode may take before its worker is killed and "
                        "its session ends with an error (default 10)")
    p.add_argument("--webrtc", action="store_true",
                   help="also serve browsers: the page and WebRTC sessions (video, atw, sas) on --http")
    p.add_argument("--http", default="127.0.0.1:8080", metavar="HOST:PORT",
                   help="with --webrtc: the page's HTTP address (default 127.0.0.1:8080; port 0 = any)")
    p.add_argument("--webrtc-network", default=None, metavar="PATH",
                   help="with --webrtc: shape each browser session's media through an in-process relay (a profile "
                        "name, a netem string such as 'delay 50ms', or a .toml file)")
    p.add_argument("--metrics-interval", type=float, default=5.0,
                   help="seconds between each session's `metrics` log line (counters; 0 = never; default 5)")
    p.add_argument("--tls-cert", type=Path, default=None, metavar="PATH",
                   help="serve the TCP control channel (and, with --webrtc, the page: https) under TLS with this PEM "
                        "certificate (chain); needs --tls-key; clients connect with --tls")
    p.add_argument("--tls-key", type=Path, default=None, metavar="PATH",
                   help="the unencrypted PEM private key of --tls-cert")
    add_option_arguments(p, ServerProtocolOptions)


def _parse_value(text: str) -> Any:
    import tomllib

    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def config_from_args(ns: argparse.Namespace) -> Any:
    """A :class:`ServerConfig` from parsed arguments."""
    from splitrender.methods import available_methods, get_method
    from splitrender.server.server import DEFAULT_GI_HZ, ServerConfig, check_method_params

    params: dict[str, dict[str, Any]] = {}
    for kv in ns.param:
        key, sep, value = kv.partition("=")
        method, dot, name = key.partition(".")
        if not sep or not dot or not method or not name:
            raise ConfigError(f"--param {kv!r}: expected METHOD.KEY=VALUE")
        params.setdefault(method.strip(), {})[name.strip()] = _parse_value(value.strip())
    methods = tuple(m.strip() for m in ns.methods.split(",") if m.strip()) if ns.methods else None
    for m in methods or ():
        get_method(m)  # unknown names fail here, by name
    # every offered method's config is built once now, so a bad --param fails here
    check_method_params(methods or tuple(available_methods()), params)
    if ns.server_fps < 1 or ns.server_fps > 240:
        raise ConfigError(f"--server-fps: must be in [1, 240], got {ns.server_fps}")
    for opt, port, low in (("--port", ns.port, 0), ("--udp-port", ns.udp_port, 0),
                           ("--mirror-port", ns.mirror_port, 1)):
        if port is not None and not low <= port <= 65535:
            raise ConfigError(f"{opt}: must be in [{low}, 65535], got {port}")
    if not 0.05 <= ns.render_deadline <= 3600:
        raise ConfigError(f"--render-deadline: must be in [0.05, 3600] s, got {ns.render_deadline}")
    gi_hz = DEFAULT_GI_HZ if ns.gi_hz is None else ns.gi_hz
    if not (gi_hz == 0 or 0.1 <= gi_hz <= 240):
        raise ConfigError(f"--gi-hz: must be 0 (every frame) or in [0.1, 240], got {gi_hz:g}")
    if not 0 <= ns.metrics_interval <= 3600:
        raise ConfigError(f"--metrics-interval: must be in [0, 3600] s, got {ns.metrics_interval}")
    webrtc_http = None
    if ns.webrtc:
        from splitrender.webrtc.app import check_http_address

        webrtc_http = check_http_address(ns.http)
        if ns.webrtc_network:
            from splitrender.netsim.config import parse_path

            try:
                parse_path(ns.webrtc_network)
            except Exception as exc:   # noqa: BLE001 - named below
                raise ConfigError(f"--webrtc-network: {exc}") from None
    elif ns.webrtc_network:
        raise ConfigError("--webrtc-network: shapes browser sessions, so it needs --webrtc")
    return ServerConfig(tls_cert=ns.tls_cert, tls_key=ns.tls_key, webrtc_http=webrtc_http, webrtc_network=ns.webrtc_network or None, host=ns.host, port=ns.port, udp_port=ns.udp_port, token=ns.token, methods=methods,
                        method_params=params, scene=ns.scene, server_fps=ns.server_fps, fov_y_deg=ns.fov,
                        predictor=ns.predictor, max_sessions=ns.max_sessions, sdp_dir=ns.sdp_dir,
                        mirror_port=ns.mirror_port, out_dir=ns.out, metrics_interval_s=ns.metrics_interval,
                        fec=ns.fec, transport_cc=ns.transport_cc or ns.pacing or ns.adapt != "off", pacing=ns.pacing, adapt=ns.adapt, isolation=ns.isolation, render_deadline_s=ns.render_deadline, gi_hz=gi_hz,
                        **options_from_args(ns, ServerProtocolOptions))


async def _serve_until_signal(cfg: Any) -> None:
    from splitrender.server.server import serve

    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    assert task is not None
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, stop.set)
        except (NotImplementedError, RuntimeError):  # pragma: no cover - non-Unix
            pass

    def ready(server: Any) -> None:
        host, port = server.tcp_address
        tls = " (TLS)" if server.tls is not None else ""
        print(f"splitrender: serving on tcp {host}:{port}{tls}, udp {server.udp_address[0]}:{server.udp_address[1]}",
              file=sys.stderr, flush=True)
        if server.front is not None:
            scheme = "https" if server.tls is not None else "http"
            print(f"splitrender: browsers: {scheme}://{server.front.address[0]}:{server.front.address[1]}/",
                  file=sys.stderr, flush=True)

    serve_task = asyncio.create_task(serve(cfg, ready))
    stop_task = asyncio.create_task(stop.wait())
    try:
        await asyncio.wait({serve_task, stop_task}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for t in (serve_task, stop_task):
            t.cancel()
        results = await asyncio.gather(serve_task, stop_task, return_exceptions=True)
    err = results[0]
    if isinstance(err, BaseException) and not isinstance(err, asyncio.CancelledError):
        raise err


def main_serve(ns: argparse.Namespace) -> int:
    """Entry point of ``splitrender serve``; returns the exit status."""
    cfg = config_from_args(ns)
    asyncio.run(_serve_until_signal(cfg))
    print("splitrender: server stopped", file=sys.stderr)
    return 0
