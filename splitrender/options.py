"""Session options, declared once: each option's name, default, range, flag and help.

:class:`ClientOptions` and :class:`ServerProtocolOptions` (under :class:`splitrender.pipeline.ServerOptions`) are
what the session cores take.  Each option field
carries its declaration (:func:`option`: range, command-line flag, help, and where virtual time's default
or key differs), and everything else is made from it:

* the range checks, in the two dataclasses (:func:`check_options`);
* the fields of the front doors' configs (:func:`option_fields`: ``RunConfig``, the live ``ClientConfig``
  and ``ServerConfig``), hence their TOML keys;
* the argparse groups of ``run`` and ``demo`` (both sides), ``serve`` (server) and ``client`` (client)
  (:func:`add_option_arguments`, read back by :func:`options_from_args`);
* the cores' options from a front door's config (:func:`options_of`).

So every option is settable in both modes, under one name and one range.  Two options had another name in
``RunConfig`` before they were declared once (``nack_tries``, ``keyframe_request_interval_ms``; :attr:`Option.old_key`):
``RunConfig.key`` still hashes them under it, so stored runs keep their keys, and a run config's TOML may still use it
(read as the live name).  Two have another default in virtual time (``jitter_timeout_ms`` 100 ms; ``stall_timeout_s`` never, since
a run must end by its duration, not by an error).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Iterator

from .errors import ConfigError
from .limits import DEFAULT_CLIENT_LIMITS, ClientLimits


__all__ = ["ClientOptions", "ServerProtocolOptions", "Option", "add_option_arguments", "check_options", "declared", "option",
           "old_keys", "option_defaults", "option_fields", "options_from_args", "options_of", "options_table"]

NACK_MIN_RESEND_MS = 20.0
"""A packet resent at t is not resent again for a NACK arriving before t + max(RTT, this) (ms; the RTT is the
sender's from receiver reports, so until the first one this floor alone).  libwebrtc's ``RtpPacketHistory`` holds
a resent packet for one RTT (plus 5 ms) the same way.  Below the client's shortest retry (``NACK_RETRY_MIN_MS``, and
its retries after that come 1.5 RTT + 10 ms apart), so a receiver's honest retry is never refused."""
NACK_MAX_PER_DATAGRAM = 256
"""Most packets resent for one RTCP datagram, all its NACKs together (the requests beyond are refused unread)."""
NACK_RATE_WINDOW_MS = 1000.0
"""The sliding window over which resent bytes are held to a share of the media bytes (ms)."""
NACK_RATE_SHARE = 0.5
"""Resent bytes of a stream in the window at most this share of its media bytes in the window, plus the floor."""
NACK_RATE_FLOOR_BYTES = 16_000
"""What a stream may resend in any window whatever its media rate (bytes: 13 full 1,200-byte packets), so a quiet
stream can still repair a keyframe."""

_SAME = object()


def _num(x: float) -> str:
    """A bound or default as the messages write it: whole numbers in full (1048576, not 1.04858e+06)."""
    return str(int(x)) if x == int(x) and abs(x) < 1e15 else f"{x:g}"


@dataclass(frozen=True)
class Option:
    """One option's declaration (the metadata of its field): range ``[lo, hi]`` (``inf_ok``: or infinity),
    command-line ``flag`` and ``help``; ``old_key``: the name ``RunConfig`` gave it before the options were
    declared once, under which ``RunConfig.key`` hashes it (stored runs' keys) and a run config's TOML may still
    give it; ``virtual``: its default in virtual time where that differs."""

    lo: float
    hi: float
    flag: str
    help: str
    metavar: str | None = None
    old_key: str | None = None
    virtual: Any = _SAME
    inf_ok: bool = False

    def check(self, value: Any, label: str) -> None:
        """Raise a :class:`ConfigError` naming ``label`` when ``value`` is not a number in range."""
        if self.inf_ok and value == math.inf:
            return
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not self.lo <= value <= self.hi:
            extra = " or inf" if self.inf_ok else ""
            raise ConfigError(f"{label}: must be in [{_num(self.lo)}, {_num(self.hi)}]{extra}, got {value!r:.40}")


def option(default: Any, lo: float, hi: float, flag: str, help: str, **kw: Any) -> Any:
    """A dataclass field declaring a session option (see :class:`Option`)."""
    return field(default=default, metadata={"option": Option(lo, hi, flag, help, **kw)})


@dataclass(frozen=True)
class ClientOptions:
    """A client's loss-recovery and display options, the same for ``run``, sweeps, the demo and ``client``.

    A NACK's retry wait holds until a retransmission's round trip is measured; then it is 1.5x the smoothed round
    trip + 10 ms within [30, 500] ms.  Receiver reports are randomised by 0.5-1.5x.  A stall is counted, and asks
    for a keyframe on every video stream; the live client exits on :class:`StallTimeout`.
    """

    nack_max_tries: int = option(3, 0, 20, "--nack-tries", "NACKs per lost RTP packet (0 = NACK off)",
                                 old_key="nack_tries")
    nack_delay_ms: float = option(20.0, 0.0, 2000.0, "--nack-delay", "how long a hole waits before its first NACK "
                                  "(reordering)", metavar="MS")
    nack_retry_ms: float = option(120.0, 1.0, 5000.0, "--nack-retry", "the wait between two NACKs of a hole until "
                                  "a retransmission's round trip is measured", metavar="MS")
    pli_interval_ms: float = option(250.0, 1.0, 10_000.0, "--pli-interval", "the least time between two keyframe "
                                    "requests (PLIs) of a stream", metavar="MS", old_key="keyframe_request_interval_ms")
    rr_interval_s: float = option(0.5, 0.01, 60.0, "--rr-interval", "mean interval between receiver reports",
                                  metavar="S")
    jitter_timeout_ms: float = option(300.0, 1.0, 10_000.0, "--jitter-timeout", "how long a jitter buffer waits "
                                      "for a frame's missing packets (then it waits for a keyframe)", metavar="MS",
                                      virtual=100.0)
    playout_delay_ms: float = option(0.0, 0.0, 2000.0, "--playout-delay", "show each update no earlier than its "
                                     "server time + MS: frames held behind a retransmission are then shown in turn "
                                     "instead of skipped (0: as soon as ready)", metavar="MS")
    stall_frames: float = option(6.0, 1.0, 1000.0, "--stall-frames", "no new frame for this many server frame "
                                 "intervals is a stall: counted, and PLIs on every video stream")
    stall_timeout_s: float = option(5.0, 0.1, 3600.0, "--stall-timeout", "a stall this long ends the session with "
                                    "an error (inf: never)", metavar="S", virtual=math.inf, inf_ok=True)
    twcc_interval_ms: float = option(100.0, 10.0, 1000.0, "--twcc-interval", "how often transport-wide feedback "
                                     "goes out while arrivals wait to be reported", metavar="MS")
    limits: ClientLimits = DEFAULT_CLIENT_LIMITS
    """What the client accepts from the server (:mod:`splitrender.limits`)."""

    def __post_init__(self) -> None:
        check_options(self, "client")

    @property
    def resolve_timeout_ms(self) -> float:
        """How long a frame whose FrameMeta arrived may wait for its other streams."""
        return max(500.0, 2 * self.jitter_timeout_ms)


@dataclass(frozen=True)
class ServerProtocolOptions:
    """A server session's protocol options: NACK history and bounds, keyframe and sender-report intervals.
    :class:`splitrender.pipeline.ServerOptions` adds the estimator's settings and the adaptation mode (this module
    sits below the pipeline, like :mod:`splitrender.limits`, so the command lines declare the options without
    loading it)."""

    history_packets: int = option(2048, 1, 1 << 20, "--history-packets", "RTP packets kept per stream to answer "
                                  "NACKs", metavar="N")
    keyframe_min_interval_ms: float = option(200.0, 0.0, 60_000.0, "--keyframe-min-interval", "the least time "
                                             "between two keyframes granted to a client's requests", metavar="MS")
    sr_interval_s: float = option(1.0, 0.01, 60.0, "--sr-interval", "mean interval between sender reports "
                                  "(randomised by 0.5-1.5x)", metavar="S")
    nack_min_resend_ms: float = option(NACK_MIN_RESEND_MS, 0.0, 10_000.0, "--nack-min-resend", "a packet resent at "
                                       "t is not resent for a NACK before t + max(RTT, this)", metavar="MS")
    nack_max_per_datagram: int = option(NACK_MAX_PER_DATAGRAM, 0, 1 << 16, "--nack-max-per-datagram", "most packets "
                                        "resent for one RTCP datagram", metavar="N")
    nack_rate_share: float = option(NACK_RATE_SHARE, 0.0, 10.0, "--nack-rate-share", "resent bytes per stream in "
                                    "any second at most this share of its media bytes, plus --nack-rate-floor")
    nack_rate_floor_bytes: int = option(NACK_RATE_FLOOR_BYTES, 0, 1 << 30, "--nack-rate-floor", "resent bytes per "
                                        "stream allowed in any second whatever its media rate", metavar="BYTES")

    def __post_init__(self) -> None:
        check_options(self, "server")


OPTION_CLASSES = (ClientOptions, ServerProtocolOptions)


def declared(cls: type) -> Iterator[tuple[dataclasses.Field, Option]]:
    """The option fields of ``cls`` (one of :data:`OPTION_CLASSES`) with their declarations."""
    for f in dataclasses.fields(cls):
        o = f.metadata.get("option")
        if o is not None:
            yield f, o


def check_options(obj: Any, side: str) -> None:
    """Check every option of ``obj`` (a :class:`ClientOptions` or :class:`ServerProtocolOptions`) against its range, and
    an option declared ``int`` for being an integer."""
    for f, o in declared(type(obj)):
        v = getattr(obj, f.name)
        if _is_int(f) and (not isinstance(v, int) or isinstance(v, bool)):
            raise ConfigError(f"{side} {f.name}: must be an integer, got {v!r:.40}")
        o.check(v, f"{side} {f.name}")


def _is_int(f: dataclasses.Field) -> bool:
    return f.type in ("int", int)


def _default(f: dataclasses.Field, o: Option, virtual: bool) -> Any:
    return f.default if not virtual or o.virtual is _SAME else o.virtual


def option_defaults(*classes: type, virtual: bool = False) -> dict[str, Any]:
    """Each option's name and its default in the mode (``virtual``)."""
    return {f.name: _default(f, o, virtual) for cls in classes for f, o in declared(cls)}


def old_keys(*classes: type) -> dict[str, str]:
    """The options of ``classes`` that ``RunConfig`` once named otherwise: old key -> name (:attr:`Option.old_key`)."""
    return {o.old_key: f.name for cls in classes for f, o in declared(cls) if o.old_key}


def option_fields(*classes: type, virtual: bool = False) -> Any:
    """A class decorator, applied under ``@dataclass``: adds every option of ``classes`` to the class as a field
    (under its name, with the mode's default), so a front door's config (and its TOML
    keys) carries the options without declaring them again."""
    def add(cls: type) -> type:
        ann = dict(cls.__dict__.get("__annotations__", {}))
        for c in classes:
            for f, o in declared(c):
                key = f.name
                if key in ann:
                    raise TypeError(f"{cls.__name__}.{key} is declared by {c.__name__} already")
                ann[key] = f.type
                setattr(cls, key, _default(f, o, virtual))
        cls.__annotations__ = ann
        return cls
    return add


def options_of(config: Any, cls: type, **extra: Any) -> Any:
    """The core's options (``cls``) from a front door's config that carries them (:func:`option_fields`)."""
    return cls(**{f.name: getattr(config, f.name) for f, o in declared(cls)}, **extra)


def _dest(o: Option) -> str:
    return o.flag.lstrip("-").replace("-", "_")


def add_option_arguments(parser: argparse.ArgumentParser, *classes: type, virtual: bool = False) -> None:
    """An argparse group with every option of ``classes``; each defaults to ``None`` (not given), and its help
    names the mode's default and range."""
    g = parser.add_argument_group("session options", "the session cores' options, the same in virtual time and "
                                  "live (docs/protocol.md)")
    for cls in classes:
        for f, o in declared(cls):
            d = _default(f, o, virtual)
            kind = int if _is_int(f) else float
            g.add_argument(o.flag, type=kind, default=None, metavar=o.metavar, dest=_dest(o),
                           help=f"{o.help} (default {d:g}; range {_num(o.lo)}-{_num(o.hi)}{' or inf' if o.inf_ok else ''})")


def options_from_args(ns: argparse.Namespace, *classes: type) -> dict[str, Any]:
    """The options given on the command line (:func:`add_option_arguments`), by name, each checked against its range under its flag's name."""
    out: dict[str, Any] = {}
    for cls in classes:
        for f, o in declared(cls):
            v = getattr(ns, _dest(o), None)
            if v is not None:
                o.check(v, o.flag)
                out[f.name] = v
    return out


def options_table() -> str:
    """The options as a Markdown table (``docs/protocol.md``, "Session options"; a test keeps the two equal)."""
    rows = ["| side | option (config key) | flag | live default | virtual time | range | what it does |",
            "|---|---|---|---|---|---|---|"]
    for cls, side in ((ClientOptions, "client"), (ServerProtocolOptions, "server")):
        for f, o in declared(cls):
            key = f"`{f.name}`" + (f" (stored runs: `{o.old_key}`)" if o.old_key else "")
            virtual = _default(f, o, True)
            rng = f"{_num(o.lo)}-{_num(o.hi)}" + (" or inf" if o.inf_ok else "")
            rows.append(f"| {side} | {key} | `{o.flag}` | {f.default:g} | {virtual:g} | {rng} | {o.help} |")
    return "\n".join(rows) + "\n"
