"""The ``splitrender shape`` sub-command: argument parser builder and entry point.

The main CLI only wires it::

    sub = subparsers.add_parser("shape", help="run the shaping relay")
    add_shape_arguments(sub)
    sub.set_defaults(func=main_shape)
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys

from splitrender.errors import NetworkConfigError
from splitrender.netsim.config import get_profile, parse_path, profile_names
from splitrender.netsim.models import PathSpec, path_from_toml
from splitrender.netsim.relay import Address, RelayStats, is_loopback_host, serve_relay

logger = logging.getLogger(__name__)


def parse_address(text: str) -> Address:
    """``HOST:PORT`` or ``[V6]:PORT`` -> (host, port)."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or int(port) > 65535:
        raise NetworkConfigError(f"{text!r} is not HOST:PORT (e.g. 127.0.0.1:9000)")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    return host, int(port)


def _address_arg(text: str) -> Address:
    try:
        return parse_address(text)
    except NetworkConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _udp_pair(text: str) -> tuple[Address, Address]:
    listen, sep, target = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not LISTEN=TARGET (e.g. 127.0.0.1:5004=127.0.0.1:6004)"
        )
    return _address_arg(listen), _address_arg(target)


def add_shape_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``shape`` options to ``parser`` and return it."""
    parser.add_argument("--listen-tcp", type=_address_arg, metavar="HOST:PORT",
                        help="accept TCP (metadata) connections here")
    parser.add_argument("--to-tcp", type=_address_arg, metavar="HOST:PORT",
                        help="forward accepted TCP connections to this server address")
    parser.add_argument("--udp", type=_udp_pair, action="append", default=[],
                        metavar="LISTEN=TARGET",
                        help="relay UDP (RTP) from LISTEN to TARGET; repeatable")
    shaping = parser.add_mutually_exclusive_group()
    shaping.add_argument("--profile", default=None,
                         help=f"named network profile: {', '.join(profile_names())}")
    shaping.add_argument("--netem", default=None, metavar="ARGS",
                         help='netem arguments for both directions, or "up: ...; down: ..."')
    shaping.add_argument("--path-toml", default=None, metavar="FILE",
                         help="TOML file with [uplink] and [downlink] tables")
    parser.add_argument("--seed", type=int, default=0, help="seed of the impairment model")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after S seconds (default: run until interrupted)")
    parser.add_argument("--stats-interval", type=float, default=None, metavar="S",
                        help="print counters every S seconds")
    parser.add_argument("--allow-remote", action="store_true",
                        help="permit non-loopback listen/target addresses")
    return parser


def resolve_path(ns: argparse.Namespace) -> PathSpec:
    """The :class:`PathSpec` chosen by ``--profile``/``--netem``/``--path-toml`` (ideal)."""
    if ns.profile is not None:
        return get_profile(ns.profile)
    if ns.netem is not None:
        return parse_path(ns.netem)
    if ns.path_toml is not None:
        return path_from_toml(ns.path_toml)
    return get_profile("ideal")


def _format_stats(stats: RelayStats) -> str:
    u, d = stats.uplink, stats.downlink
    return (
        f"up: in {u.packets_in} out {u.packets_out} dropped {u.packets_dropped} "
        f"undeliverable {u.packets_undeliverable} ({u.bytes_out} B) | down: in {d.packets_in} out {d.packets_out} "
        f"dropped {d.packets_dropped} undeliverable {d.packets_undeliverable} ({d.bytes_out} B) "
        f"| tcp open {stats.tcp_connections_open}"
    )


def main_shape(ns: argparse.Namespace) -> int:
    """Run the relay from parsed ``shape`` arguments; returns the exit status."""
    try:
        path = resolve_path(ns)
        if (ns.listen_tcp is None) != (ns.to_tcp is None):
            raise NetworkConfigError("--listen-tcp and --to-tcp must be given together")
        tcp = [(ns.listen_tcp, ns.to_tcp)] if ns.listen_tcp is not None else []
        udp = list(ns.udp)
        if not tcp and not udp:
            raise NetworkConfigError("nothing to relay: give --listen-tcp/--to-tcp and/or --udp")
        if not ns.allow_remote:
            for listen, target in tcp + udp:
                for addr in (listen, target):
                    if not is_loopback_host(addr[0]):
                        raise NetworkConfigError(
                            f"{addr[0]!r} is not a loopback address (use --allow-remote)"
                        )
    except NetworkConfigError as exc:
        print(f"splitrender shape: error: {exc}", file=sys.stderr)
        return 2

    def on_stats(stats: RelayStats) -> None:
        print(_format_stats(stats), flush=True)

    try:
        stats = asyncio.run(
            serve_relay(path, ns.seed, tcp=tcp, udp=udp, allow_remote=ns.allow_remote,
                        duration_s=ns.duration, stats_interval_s=ns.stats_interval,
                        on_stats=on_stats)
        )
    except KeyboardInterrupt:
        return 130
    except OSError as exc:
        print(f"splitrender shape: error: {exc}", file=sys.stderr)
        return 1
    print(_format_stats(stats), flush=True)
    return 0


def add_trace_arguments(p: argparse.ArgumentParser) -> None:
    """``splitrender capacity-trace``: write a generated mahimahi capacity trace (:mod:`splitrender.netsim.traces`)."""
    kind = p.add_subparsers(dest="kind", required=True)
    s = kind.add_parser("step", help="piecewise-constant capacity")
    s.add_argument("steps", help="seconds:Mbit/s pairs, comma-separated, e.g. 5:20,5:2,10:20")
    s.add_argument("out", help="the trace file to write")
    c = kind.add_parser("cellular", help="cellular-like capacity with stated statistics")
    c.add_argument("duration", type=float, help="seconds")
    c.add_argument("out", help="the trace file to write")
    c.add_argument("--mean", type=float, default=8.0, help="mean Mbit/s outside outages (default 8)")
    c.add_argument("--cv", type=float, default=0.5, help="coefficient of variation of the rate (default 0.5)")
    c.add_argument("--corr-time", type=float, default=1.0, help="e-folding time of the log-rate, seconds (default 1)")
    c.add_argument("--outage-share", type=float, default=0.02, help="share of time in outages (default 0.02)")
    c.add_argument("--outage-mean", type=float, default=0.3, help="mean outage length, seconds (default 0.3)")
    c.add_argument("--seed", type=int, default=0)
    t = kind.add_parser("stats", help="the statistics of mahimahi trace files (generated or public), one line each")
    t.add_argument("traces", nargs="+", help="trace files (e.g. mahimahi's traces/*.down)")
    t.add_argument("--slot", type=int, default=50, help="slot length in ms (default 50)")


def main_trace(ns: argparse.Namespace) -> int:
    from splitrender.netsim.traces import cellular_trace, step_trace, trace_stats, write_mahimahi

    if ns.kind == "stats":
        from splitrender.netsim.models import load_mahimahi_trace

        if not 1 <= ns.slot <= 10_000:
            raise NetworkConfigError(f"capacity-trace stats --slot: must be in [1, 10000] ms, got {ns.slot}")
        print("trace,mean_mbps,cv,outage_pct,lag1_corr,period_s")
        for name in ns.traces:
            st = trace_stats(load_mahimahi_trace(name), ns.slot)
            print(f"{name},{st['mean_mbps']:.2f},{st['cv']:.2f},{100 * st['outage_share']:.1f},{st['lag1_corr']:.2f},"
                  f"{st['period_s']:.0f}")
        return 0
    if ns.kind == "step":
        steps = []
        for item in ns.steps.split(","):
            dur, sep, mbps = item.partition(":")
            try:
                if not sep:
                    raise ValueError
                steps.append((float(dur), float(mbps)))
            except ValueError:
                raise NetworkConfigError(f"capacity-trace step: {item!r} is not seconds:Mbit/s (e.g. 5:20)") from None
        stamps = step_trace(steps)
    else:
        stamps = cellular_trace(ns.duration, ns.mean, ns.cv, ns.corr_time, ns.outage_share, ns.outage_mean, seed=ns.seed)
    path = write_mahimahi(stamps, ns.out)
    st = trace_stats(stamps)
    print(f"{path}: {len(stamps)} delivery opportunities over {stamps[-1] / 1000:.1f} s, mean "
          f"{st.get('mean_mbps', float('nan')):.2f} Mbit/s; use it as --network \"delay 20ms trace {path}\"")
    return 0
