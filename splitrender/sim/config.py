"""Typed run configuration, loadable from TOML or a dict, written next to results."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..coerce import coerce_value
from ..errors import ConfigError
from ..options import (ClientOptions, ServerProtocolOptions, old_keys, option_defaults, option_fields, options_from_args,
                       options_of)
from ..pipeline.adapt import check_adapt_mode
from ..pipeline.session import ServerOptions


_KEYED_ALWAYS = frozenset({"nack_max_tries", "pli_interval_ms", "jitter_timeout_ms", "playout_delay_ms",
                           "stall_frames"})
"""Session options that were RunConfig fields before the options were declared once: :meth:`RunConfig.key` hashes
them always (as it did), the others only where they differ from their default."""
_OLD_KEYS = old_keys(ClientOptions, ServerProtocolOptions)
"""RunConfig's names of two options before they were declared once (``nack_tries``: ``nack_max_tries``,
``keyframe_request_interval_ms``: ``pli_interval_ms``): :meth:`RunConfig.key` hashes the options under them, so every
stored run keeps its key, and :meth:`RunConfig.from_dict` (TOML: stored runs' config.toml) reads them as the live
names."""

COST_MODELS = ("fixed", "measured")
"""Where processing time on the simulated clock comes from (see :class:`RunConfig`)."""


@dataclass(frozen=True)
@option_fields(ClientOptions, ServerProtocolOptions, virtual=True)
class RunConfig:
    """One virtual-time run: a method on a scene, a trace and a network.

    Times in seconds unless the name says ms; sizes in pixels.
    ``server_latency_ms`` and ``decode_latency_ms`` are *modelled* processing delays
    (render+encode, decode) on the simulated clock, so results do not depend on this
    machine's speed; the measured wall-clock costs are recorded separately.
    ``flip_every``: score FLIP on every n-th displayed frame (0 = never).

    Many clients: ``clients`` sessions share one server (its scene producer runs once
    per frame for all of them); client ``i`` follows ``client_traces[i % len]`` (or
    ``trace``), starting ``i * client_offset_s`` seconds into it, with its own network
    links seeded from ``seed``.  ``jitter_timeout_ms``: how long the client's jitter
    buffer waits for a frame's missing packets; ``pli_interval_ms``: the
    least time between two keyframe requests of a client; ``max_session_bytes``:
    limit on the method's session data.

    ``cost_model``: ``"fixed"`` puts the modelled ``server_latency_ms`` and
    ``decode_latency_ms`` on the clock; ``"measured"`` puts this machine's measured
    milliseconds there instead, times ``cost_scale`` (e.g. 0.1 to project onto a machine
    ten times faster): a frame leaves after the shared scene work, its own server work
    and its encoding (sessions served one after another), is released
    its measured decode time after it arrives, and a server tick that finds the server
    still busy is skipped (``server_skipped``), as a frame loop that renders the latest
    pose when it is free would.

    ``supersample``: the ground truth and the servers' renders through the shared
    renderer are drawn at ``supersample`` times the size and box-filtered down
    (anti-aliasing; 1 = off).  The clients render without it.

    ``ssim_sigma``: the SSIM Gaussian window in pixels (1.5, Wang et al.; the SAS paper uses 2).
    ``truth_cache``: where ground-truth frames are cached (:mod:`splitrender.sim.truth`):
    ``""`` renders every one, ``"default"`` uses ``$SPLITRENDER_TRUTH_CACHE`` or
    ``~/.cache/splitrender/truth``, anything else is a folder.  It cannot change a
    result, so it is not part of :meth:`key`.

    ``scene_time_offset_s``: the scene's clock runs this far ahead of the run's (its
    animations and light schedules at run time ``t`` are those at ``t + offset``), so a
    short run can start just before an event such as the default scene's sun dimming at 4 s.
    ``fec``: protect every RTP stream with RFC 5109 parity packets (:mod:`splitrender.protocol.fec`).

    The session options (the cores' loss recovery, reports and NACK bounds) are fields too, added from their one
    declaration (:mod:`splitrender.options`) under the same names as live, with virtual time's defaults
    (``jitter_timeout_ms`` 100, ``stall_timeout_s`` inf).  ``nack_max_tries`` and ``pli_interval_ms`` were
    ``nack_tries`` and ``keyframe_request_interval_ms`` here once: :meth:`key` hashes them under those names
    (:data:`_OLD_KEYS`), and :meth:`from_dict` reads those names too.
    """

    method: str = "video"
    method_params: dict[str, Any] = field(default_factory=dict)
    scene: str = "default"
    trace: str = "walk"
    network: str = "ideal"
    duration_s: float | None = None
    width: int = 640
    height: int = 360
    fov_y_deg: float = 60.0
    server_fps: int = 30
    client_fps: int = 60
    tracker_hz: int = 120
    predictor: str = "cv"
    seed: int = 0
    server_latency_ms: float = 10.0
    decode_latency_ms: float = 4.0
    cost_model: str = "fixed"
    cost_scale: float = 1.0
    supersample: int = 1
    mtu_bytes: int = 1200
    flip_every: int = 4
    metrics: bool = True
    save_images_every: int = 0
    clients: int = 1
    client_traces: tuple[str, ...] = ()
    client_offset_s: float = 0.0
    max_session_bytes: int = 256 * 1024 * 1024
    ssim_sigma: float = 1.5
    truth_cache: str = ""
    scene_time_offset_s: float = 0.0
    fec: bool = False
    transport_cc: bool = False
    """Transport-wide congestion control feedback: every RTP packet carries a transport sequence number, the client
    reports arrivals every 100 ms, the server's estimator follows the path's rate (written to updates.csv as
    ``cc_*``; with ``adapt`` the encoders follow it)."""
    pacing: bool = False
    """With ``transport_cc``: RTP leaves through a pacer at 2.5x the estimated rate instead of in a burst."""
    adapt: str = "off"
    """``rate``, with ``transport_cc``: every lossy video stream's encoder rate follows the estimate
    (:mod:`splitrender.pipeline.adapt`)."""

    def __post_init__(self) -> None:
        def bad(key: str, msg: str) -> ConfigError:
            return ConfigError(f"run config {key}: {msg}")

        if self.width <= 0 or self.height <= 0 or self.width % 2 or self.height % 2:
            raise bad("width/height", f"must be positive and even, got {self.width}x{self.height}")
        if self.pacing and not self.transport_cc:
            raise bad("pacing", "paces at the estimated rate, so it needs transport_cc (--transport-cc)")
        check_adapt_mode(self.adapt, "run config")
        if self.adapt != "off" and not self.transport_cc:
            raise bad("adapt", f"{self.adapt} follows the estimated rate, so it needs transport_cc (--transport-cc)")
        if self.width * self.height > 3840 * 2160:
            raise bad("width/height", f"{self.width}x{self.height} is larger than 3840x2160")
        if not 10.0 <= self.fov_y_deg <= 150.0:
            raise bad("fov_y_deg", f"must be in [10, 150], got {self.fov_y_deg}")
        for k in ("server_fps", "client_fps", "tracker_hz"):
            v = getattr(self, k)
            if not 1 <= v <= 1000:
                raise bad(k, f"must be in [1, 1000], got {v}")
        if self.duration_s is not None and not 0 < self.duration_s <= 3600:
            raise bad("duration_s", f"must be in (0, 3600], got {self.duration_s}")
        for k in ("server_latency_ms", "decode_latency_ms"):
            if not 0 <= getattr(self, k) <= 10_000:
                raise bad(k, f"must be in [0, 10000], got {getattr(self, k)}")
        if not 1 <= self.supersample <= 4:
            raise bad("supersample", f"must be in [1, 4], got {self.supersample}")
        if self.cost_model not in COST_MODELS:
            raise bad("cost_model", f"must be one of {', '.join(COST_MODELS)}, got {self.cost_model!r}")
        if not 0.001 <= self.cost_scale <= 1000:
            raise bad("cost_scale", f"must be in [0.001, 1000], got {self.cost_scale}")
        if not 200 <= self.mtu_bytes <= 9000:
            raise bad("mtu_bytes", f"must be in [200, 9000], got {self.mtu_bytes}")
        if not 0.5 <= self.ssim_sigma <= 10.0:
            raise bad("ssim_sigma", f"must be in [0.5, 10], got {self.ssim_sigma}")
        if self.flip_every < 0 or self.save_images_every < 0:
            raise bad("flip_every/save_images_every", "must be >= 0")
        if not 0 <= self.seed < 2**63:
            raise bad("seed", f"must be in [0, 2**63), got {self.seed}")
        if not 1 <= self.clients <= 64:
            raise bad("clients", f"must be in [1, 64], got {self.clients}")
        if not 0 <= self.client_offset_s <= 3600:
            raise bad("client_offset_s", f"must be in [0, 3600], got {self.client_offset_s}")
        try:
            self.client_options()
        except ConfigError as exc:
            raise bad("client options", str(exc)) from None
        try:
            self.server_options()
        except ConfigError as exc:
            raise bad("server options", str(exc)) from None
        if not 1024 <= self.max_session_bytes <= 1 << 34:
            raise bad("max_session_bytes", f"must be in [1024, 2**34], got {self.max_session_bytes}")
        if not 0 <= self.scene_time_offset_s <= 3600:
            raise bad("scene_time_offset_s", f"must be in [0, 3600], got {self.scene_time_offset_s}")
        if not isinstance(self.method_params, dict):
            raise bad("method_params", f"must be a table, got {type(self.method_params).__name__}")

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "RunConfig":
        """Build from a dict (e.g. parsed TOML), naming unknown keys and wrong types.  The two options' old names
        (:data:`_OLD_KEYS`, as in stored runs' config.toml) are read as their live names (silently; both names at once
        is an error)."""
        if not isinstance(d, dict):
            raise ConfigError(f"run config: expected a table, got {type(d).__name__}")
        import typing

        hints = typing.get_type_hints(RunConfig)
        names = {f.name for f in dataclasses.fields(RunConfig)}
        kw: dict[str, Any] = {}
        for k, v in d.items():
            if k in _OLD_KEYS:
                if _OLD_KEYS[k] in d:
                    raise ConfigError(f"run config: {k!r} is the old name of {_OLD_KEYS[k]!r}: give one of them")
                k = _OLD_KEYS[k]
            if k not in names:
                raise ConfigError(f"run config: unknown key {k!r} (valid: {', '.join(sorted(names))})")
            kw[k] = v if k == "method_params" else coerce_value("run config", k, hints[k], v)
        return RunConfig(**kw)

    @staticmethod
    def from_toml(path: str | Path) -> "RunConfig":
        data = load_toml(path, "config")
        return RunConfig.from_dict(data.get("run", data))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def toml(self, resolved: dict[str, Any] | None = None) -> str:
        """A run's ``config.toml``: ``[run]``, this config, and ``[resolved]`` where given (every method parameter,
        defaults included, and both network directions)."""
        text = "[run]\n" + to_toml(self.to_dict(), "run.")
        return text + ("\n[resolved]\n" + to_toml(resolved, "resolved.") if resolved else "")

    def key(self) -> str:
        """A stable hash of the resolved config (for result caching); two options under their old names
        (:data:`_OLD_KEYS`), so stored runs keep their keys."""
        d = self.to_dict()
        d.pop("truth_cache")  # where the ground truth is cached does not change the result
        added = {**option_defaults(ClientOptions, ServerProtocolOptions, virtual=True),
                 "cost_model": "fixed", "cost_scale": 1.0, "supersample": 1, "scene_time_offset_s": 0.0,
                 "fec": False, "transport_cc": False, "pacing": False, "adapt": "off"}
        for k, default in added.items():
            if k not in _KEYED_ALWAYS and d[k] == default:  # keys of configs from before these options stay valid
                del d[k]
        for old, name in _OLD_KEYS.items():
            d[old] = d.pop(name)
        blob = json.dumps(d, sort_keys=True, default=str)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def client_options(self) -> ClientOptions:
        """The session core's client options of this run (:mod:`splitrender.options`)."""
        return options_of(self, ClientOptions)

    def server_options(self) -> ServerOptions:
        """The session core's server options of this run: the same keys and ranges as the live server's."""
        return options_of(self, ServerOptions, pacing=self.pacing, adapt=self.adapt)

    def replace(self, **kw: Any) -> "RunConfig":
        return dataclasses.replace(self, **kw)


def session_options(ns: Any) -> dict[str, Any]:
    """The RunConfig keys of the session options given on the command line (``add_option_arguments``'s group,
    and ``--fec``), from an argparse namespace."""
    out = options_from_args(ns, ClientOptions, ServerProtocolOptions)
    if getattr(ns, "fec", None) is not None:
        out["fec"] = ns.fec
    return out


def load_toml(path: str | Path, kind: str) -> dict[str, Any]:
    """Parse a TOML file; a missing or malformed file is a :class:`ConfigError` naming ``kind`` and the path."""
    p = Path(path)
    try:
        return tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{kind} file not found: {p}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{kind} file {p} cannot be read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{kind} file {p} is not valid TOML: {exc}") from exc


def to_toml(d: dict[str, Any], _prefix: str = "") -> str:
    """A small TOML writer for the value types configs use."""
    simple, tables = [], []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v))
        elif v is None:
            simple.append(f"# {k} = (unset)")
        else:
            simple.append(f"{k} = {_toml_value(v)}")
    out = "\n".join(simple)
    for k, v in tables:
        name = f"{_prefix}{k}"
        out += f"\n\n[{name}]\n" + to_toml(v, name + ".")
    return out.strip() + "\n"


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return json.dumps(str(v))
