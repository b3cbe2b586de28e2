"""``splitrender client``: argument definitions and the entry point."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path

from splitrender.errors import ConfigError, SplitRenderError
from splitrender.options import ClientOptions, add_option_arguments, options_from_args
from splitrender.transport.errors import ConnectError, describe_os_error

__all__ = ["add_client_arguments", "main_client", "config_from_args"]


def add_client_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``splitrender client``."""
    p.add_argument("--server", default="127.0.0.1", help="server host (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=9100, help="server TCP port (default 9100)")
    p.add_argument("--udp-port", type=int, default=None,
                   help="send RTCP to this UDP port instead of the one in Welcome (e.g. a relay's)")
    p.add_argument("--token", default="", help="shared secret for the server")
    p.add_argument("--tls", action="store_true",
                   help="connect over TLS (a server run with --tls-cert), verifying its certificate and that it "
                        "names --server, against --tls-ca or the system's trusted CAs")
    p.add_argument("--tls-ca", type=Path, default=None, metavar="PATH",
                   help="PEM CA certificate(s) to verify the server by (e.g. a self-signed one's); implies --tls")
    p.add_argument("--method", default="video", help="method, or comma-separated methods in preference order")
    p.add_argument("--codec", default="h264,hevc", help="codecs accepted, comma-separated")
    p.add_argument("--trace", default="walk", help="camera trace: built-in name or file")
    p.add_argument("--duration", type=float, default=10.0, help="seconds to run")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=360)
    p.add_argument("--display-hz", type=float, default=60.0, help="display refresh rate, Hz")
    p.add_argument("--tracker-hz", type=float, default=120.0, help="pose sampling rate, Hz")
    p.add_argument("--out", type=Path, default=Path("out/live"), help="recording folder (default out/live)")
    p.add_argument("--save-images", action="store_true", help="keep every displayed image (needed to score)")
    p.add_argument("--score", action="store_true", help="score the recording afterwards (implies --save-images)")
    p.add_argument("--metrics-interval", type=float, default=5.0,
                   help="seconds between `metrics` log lines (counters, drops included; 0 = never; default 5)")
    p.add_argument("--limit", action="append", default=[], metavar="KEY=N",
                   help="what this client accepts from a server (repeatable), e.g. --limit max_probes=65536; keys: "
                        "max_stream_bytes, max_session_bytes, max_pending_frames, max_pending_bytes, max_video_pixels, "
                        "max_probes, max_scene_triangles, max_scene_objects, max_reference_pixels, max_atlas_pixels, "
                        "max_mesh_vertices (docs/protocol.md, Limits)")
    p.add_argument("--connect-timeout", type=float, default=5.0, metavar="S",
                   help="seconds to wait for the connection and the server's Welcome (default 5)")
    p.add_argument("--rows-kept", type=int, default=4096, metavar="N",
                   help="displayed-frame rows kept in memory (every row goes to the recording as it is shown; "
                        "default 4096)")
    add_option_arguments(p, ClientOptions)


def config_from_args(ns: argparse.Namespace) -> object:
    """A :class:`ClientConfig` from parsed arguments."""
    from splitrender.client.config import ClientConfig

    if ns.duration <= 0 or ns.duration > 3600:
        raise ConfigError(f"--duration: must be in (0, 3600], got {ns.duration}")
    if ns.width <= 0 or ns.height <= 0 or ns.width % 2 or ns.height % 2:
        raise ConfigError(f"--width/--height: must be positive and even, got {ns.width}x{ns.height}")
    for opt, port in (("--port", ns.port), ("--udp-port", ns.udp_port)):
        if port is not None and not 1 <= port <= 65535:
            raise ConfigError(f"{opt}: must be in [1, 65535], got {port}")
    if not 0 <= ns.metrics_interval <= 3600:
        raise ConfigError(f"--metrics-interval: must be in [0, 3600] s, got {ns.metrics_interval}")
    if not 0 < ns.connect_timeout <= 3600:
        raise ConfigError(f"--connect-timeout: must be in (0, 3600] s, got {ns.connect_timeout}")
    if not 1 <= ns.rows_kept <= 10_000_000:
        raise ConfigError(f"--rows-kept: must be in [1, 10000000], got {ns.rows_kept}")
    given = options_from_args(ns, ClientOptions)   # a session option out of range fails here, by its flag
    limits: dict[str, int] = {}
    for item in getattr(ns, "limit", []) or []:
        key, sep, value = item.partition("=")
        try:
            limits[key.strip()] = int(value) if sep else int("")
        except ValueError:
            raise ConfigError(f"--limit: expected KEY=N with an integer N, got {item!r}") from None
    from splitrender.limits import ClientLimits

    client_limits = ClientLimits.from_dict(limits)
    methods = tuple(m.strip() for m in ns.method.split(",") if m.strip())
    codecs = tuple(c.strip() for c in ns.codec.split(",") if c.strip())
    return ClientConfig(server=ns.server, port=ns.port, udp_port=ns.udp_port, token=ns.token, methods=methods,
                        tls=ns.tls or ns.tls_ca is not None, tls_ca=ns.tls_ca,
                        codecs=codecs, width=ns.width, height=ns.height, display_hz=ns.display_hz,
                        tracker_hz=ns.tracker_hz, trace=ns.trace, duration_s=ns.duration, out_dir=ns.out,
                        save_images=ns.save_images or ns.score, metrics_interval_s=ns.metrics_interval,
                        limits=client_limits, rows_kept=ns.rows_kept, connect_timeout_s=ns.connect_timeout,
                        **given)


def main_client(ns: argparse.Namespace) -> int:
    """Entry point of ``splitrender client``; returns the exit status."""
    from splitrender.client.session import run_client

    cfg = config_from_args(ns)
    try:
        result = asyncio.run(run_client(cfg))  # type: ignore[arg-type]
    except KeyboardInterrupt:
        return 130
    except SplitRenderError:
        raise
    except OSError as exc:  # the connection broke or timed out mid-session
        raise ConnectError(f"session with {ns.server}:{ns.port} failed: {describe_os_error(exc)}") from exc
    c = result.counters
    print(f"splitrender client: {c.get('rows_recorded', len(result.rows))} frames displayed, {c['frames_complete']} updates, "
          f"{c['rtp_packets']} RTP packets, {c['nacked_packets']} NACKed, {c['plis_sent']} PLIs -> {ns.out}")
    if ns.score:
        from splitrender.client.score import score_recording

        s = score_recording(ns.out)
        print(f"score: PSNR {s['mean_psnr_db']:.2f} dB, SSIM {s['mean_ssim']:.4f}, "
              f"motion-to-photon {s['mean_motion_to_photon_ms']:.1f} ms, update age {s['mean_update_age_ms']:.1f} ms")
    return 0
