"""Sans-IO network link models shared by the virtual-time simulator and the live relay.

A :class:`LinkSpec` describes one direction of a path with netem's vocabulary (delay,
jitter, distribution, correlation, loss, Gilbert-Elliott loss, duplicate, corrupt,
reorder, rate, limit) plus a mahimahi-style delivery trace.  A :class:`Link` turns a
spec and a seeded :class:`numpy.random.Generator` into a deterministic function from
"a packet of ``size_bytes`` was sent at ``now_s``" to the list of its deliveries.

Model, in the order a packet meets it (mirrors ``netem_enqueue``):

1. *duplicate*: with ``duplicate_pct`` a second copy is made;
2. *loss*: random (``loss_pct``) or Gilbert-Elliott (``gemodel``); a loss removes one
   copy, so a duplicated-and-lost packet still arrives once (as in netem);
3. *corrupt*: with ``corrupt_pct`` the first copy is marked corrupted (the duplicate is
   cloned before corruption, as in netem);
4. *bottleneck queue*: if ``rate_bps`` or ``trace_path`` is set, the copy enters a
   drop-tail FIFO of ``limit_packets`` packets that drains at the rate (serialisation
   delay = size * 8 / rate_bps seconds) or at the trace's delivery opportunities;
   unlike netem, ``limit_packets`` bounds only this bottleneck queue, not the delay
   line (a real router queue is in front of the propagation delay);
5. *propagation*: ``delay_ms`` plus a jitter sample from ``distribution``; with
   ``keep_order`` (default) a packet never overtakes the previous one on the same link
   (a single path queue is FIFO: a sample that would overtake is held back), without
   it jitter larger than the packet spacing reorders packets exactly as netem does;
6. *reorder*: with ``reorder_pct`` every ``reorder_gap``-th packet skips the
   propagation delay (netem's "sent immediately"), so it overtakes the others.

All times are in seconds on the caller's clock (``now_s``); spec values use ms,
percent (0..100) and bits per second as their names say.

The dict/TOML form of a spec (:func:`link_from_dict`, :func:`path_from_dict`,
:func:`path_from_toml`, :func:`link_to_dict`) is here too, so that :class:`PathSpec`'s
constructors need nothing above this module; :mod:`.config` re-exports it.
"""

from __future__ import annotations

import bisect
import collections
import dataclasses
import logging
import math
import statistics
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np

from splitrender.errors import NetworkConfigError

logger = logging.getLogger(__name__)

Distribution = Literal["uniform", "normal", "pareto", "paretonormal"]
DISTRIBUTIONS: tuple[str, ...] = get_args(Distribution)

#: Bytes delivered by one line (one delivery opportunity) of a mahimahi trace.
MAHIMAHI_MTU_BYTES = 1500
#: Default extra delay for a lost segment on a reliable (TCP) stream: one minimum RTO.
DEFAULT_RTO_S = 0.200
#: netem's default queue limit in packets.
DEFAULT_LIMIT_PACKETS = 1000

_PARETO_ALPHA = 3.0  # shape of iproute2's pareto table
_PARETO_MEAN = _PARETO_ALPHA / (_PARETO_ALPHA - 1.0)  # x_m = 1
_PARETO_STD = math.sqrt(_PARETO_ALPHA / ((_PARETO_ALPHA - 1.0) ** 2 * (_PARETO_ALPHA - 2.0)))
_STD_NORMAL = statistics.NormalDist()


@dataclass(frozen=True)
class GilbertElliott:
    """netem's ``loss gemodel p [r [1-h [1-k]]]``, all in percent (0..100).

    ``p_pct``: probability of moving good -> bad per packet; ``r_pct``: bad -> good;
    ``bad_loss_pct`` (1-h): loss probability in the bad state; ``good_loss_pct``
    (1-k): loss probability in the good state.  Defaults follow iproute2: r = 100 %,
    1-h = 100 %, 1-k = 0 %.  With the defaults a loss burst lasts 1/r packets on mean.
    """

    p_pct: float
    r_pct: float = 100.0
    bad_loss_pct: float = 100.0
    good_loss_pct: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            _check_percent(f"gemodel.{f.name}", getattr(self, f.name))


@dataclass(frozen=True)
class LinkSpec:
    """One direction of a network path, netem semantics (see module docstring).

    Times in ms, probabilities in percent (0..100), rate in bits per second.
    ``correlation`` fields are netem's (deprecated but supported) correlation between
    successive random draws, in percent.  ``rate_bps=None`` and ``trace_path=None``
    mean an unlimited link; both at once is an error.  ``keep_order=True`` (default)
    models a single FIFO path where jitter never reorders packets; ``False`` gives
    netem's behaviour where jitter larger than the spacing reorders them.  Note that
    with ``keep_order`` and packets spaced closer than the jitter range (a burst of RTP
    packets of one frame), each packet waits for the slowest before it, so a burst
    arrives near ``delay_ms + jitter_ms`` rather than spread over the range.
    """

    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    delay_correlation_pct: float = 0.0
    distribution: Distribution = "uniform"
    loss_pct: float = 0.0
    loss_correlation_pct: float = 0.0
    gemodel: GilbertElliott | None = None
    duplicate_pct: float = 0.0
    duplicate_correlation_pct: float = 0.0
    corrupt_pct: float = 0.0
    corrupt_correlation_pct: float = 0.0
    reorder_pct: float = 0.0
    reorder_correlation_pct: float = 0.0
    reorder_gap: int = 1
    rate_bps: float | None = None
    limit_packets: int = DEFAULT_LIMIT_PACKETS
    trace_path: str | None = None
    keep_order: bool = True
    spike_ms: float = 0.0
    spike_start_s: float = 0.0
    spike_duration_s: float = 0.0

    def __post_init__(self) -> None:
        _check_nonneg("delay_ms", self.delay_ms)
        for name in ("spike_ms", "spike_start_s", "spike_duration_s"):
            _check_nonneg(name, getattr(self, name))
        _check_nonneg("jitter_ms", self.jitter_ms)
        for name in (
            "delay_correlation_pct",
            "loss_pct",
            "loss_correlation_pct",
            "duplicate_pct",
            "duplicate_correlation_pct",
            "corrupt_pct",
            "corrupt_correlation_pct",
            "reorder_pct",
            "reorder_correlation_pct",
        ):
            _check_percent(name, getattr(self, name))
        if self.distribution not in DISTRIBUTIONS:
            raise NetworkConfigError(
                f"distribution must be one of {', '.join(sorted(DISTRIBUTIONS))}, "
                f"got {self.distribution!r}"
            )
        if self.distribution != "uniform" and self.jitter_ms == 0:
            raise NetworkConfigError(
                f"distribution {self.distribution!r} needs jitter_ms > 0 (as in tc)"
            )
        if self.gemodel is not None and not isinstance(self.gemodel, GilbertElliott):
            raise NetworkConfigError(f"gemodel must be a GilbertElliott, got {self.gemodel!r}")
        if self.gemodel is not None and self.loss_pct > 0:
            raise NetworkConfigError("loss_pct and gemodel are exclusive (one loss model)")
        if not isinstance(self.reorder_gap, int) or isinstance(self.reorder_gap, bool):
            raise NetworkConfigError(f"reorder_gap must be an integer, got {self.reorder_gap!r}")
        if self.reorder_gap < 1:
            raise NetworkConfigError(f"reorder_gap must be >= 1, got {self.reorder_gap}")
        if self.reorder_pct > 0 and self.delay_ms <= 0:
            raise NetworkConfigError("reorder_pct needs delay_ms > 0 (as in netem)")
        if self.rate_bps is not None:
            _check_nonneg("rate_bps", self.rate_bps)
            if self.rate_bps <= 0:
                raise NetworkConfigError(f"rate_bps must be > 0, got {self.rate_bps!r}")
        if not isinstance(self.limit_packets, int) or isinstance(self.limit_packets, bool):
            raise NetworkConfigError(
                f"limit_packets must be an integer, got {self.limit_packets!r}"
            )
        if self.limit_packets < 1:
            raise NetworkConfigError(f"limit_packets must be >= 1, got {self.limit_packets}")
        if self.trace_path is not None:
            if not isinstance(self.trace_path, str) or not self.trace_path:
                raise NetworkConfigError(
                    f"trace_path must be a non-empty string, got {self.trace_path!r}"
                )
            if self.rate_bps is not None:
                raise NetworkConfigError("rate_bps and trace_path are exclusive")
        if not isinstance(self.keep_order, bool):
            raise NetworkConfigError(f"keep_order must be true or false, got {self.keep_order!r}")

    @property
    def is_ideal(self) -> bool:
        """True when the link neither delays, limits nor impairs anything."""
        return self == LinkSpec(keep_order=self.keep_order)


@dataclass(frozen=True)
class Delivery:
    """One arrival of a sent packet: at ``time_s`` (caller's clock, s), maybe corrupted."""

    time_s: float
    corrupted: bool = False


def _check_number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise NetworkConfigError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise NetworkConfigError(f"{name} must be finite, got {value!r}")
    return float(value)


def _check_nonneg(name: str, value: Any) -> None:
    if _check_number(name, value) < 0:
        raise NetworkConfigError(f"{name} must be >= 0, got {value!r}")


def _check_percent(name: str, value: Any) -> None:
    v = _check_number(name, value)
    if not 0.0 <= v <= 100.0:
        raise NetworkConfigError(f"{name} must be within 0..100 (percent), got {value!r}")


class _CorrelatedUniform:
    """netem's ``get_crandom``: u_n = (1 - rho) * U + rho * u_{n-1}, in [0, 1)."""

    __slots__ = ("_rho", "_last", "_rng")

    def __init__(self, correlation_pct: float, rng: np.random.Generator) -> None:
        self._rho = correlation_pct / 100.0
        self._rng = rng
        self._last = 0.0

    def __call__(self) -> float:
        u = float(self._rng.random())
        if self._rho == 0.0:
            return u
        self._last = (1.0 - self._rho) * u + self._rho * self._last
        return self._last


def load_mahimahi_trace(path: str | Path) -> np.ndarray:
    """Read a mahimahi trace: one integer millisecond timestamp per line, nondecreasing.

    Each line is one delivery opportunity of :data:`MAHIMAHI_MTU_BYTES` bytes; the
    trace repeats with a period equal to its last timestamp (ms), which must be > 0.
    Returns the timestamps as an int64 array.  Blank lines and ``#`` comments are
    skipped.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError) as exc:
        raise NetworkConfigError(f"mahimahi trace {str(p)!r}: cannot read: {exc}") from exc
    stamps: list[int] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if not line.isdigit():
            raise NetworkConfigError(
                f"mahimahi trace {str(p)!r} line {lineno}: {line!r} is not a millisecond timestamp"
            )
        value = int(line)
        if stamps and value < stamps[-1]:
            raise NetworkConfigError(
                f"mahimahi trace {str(p)!r} line {lineno}: {value} ms is before {stamps[-1]} ms"
            )
        stamps.append(value)
    if not stamps or stamps[-1] <= 0:
        raise NetworkConfigError(
            f"mahimahi trace {str(p)!r}: needs at least one timestamp and a last timestamp > 0 ms"
        )
    return np.asarray(stamps, dtype=np.int64)


class _TraceServer:
    """Serves a FIFO byte queue at a mahimahi trace's delivery opportunities."""

    def __init__(self, stamps_ms: np.ndarray) -> None:
        self._stamps = [int(s) for s in stamps_ms]
        self._period_ms = self._stamps[-1]
        self._n = len(self._stamps)
        # The opportunity in use when the queue last emptied, and the bytes left in it.
        self._opp_index = -1  # global index: cycle * n + i
        self._opp_left = 0

    def _time_of(self, k: int) -> float:
        cycle, i = divmod(k, self._n)
        return (cycle * self._period_ms + self._stamps[i]) / 1000.0

    def _first_at_or_after(self, t_s: float) -> int:
        t_ms = t_s * 1000.0
        cycle = int(t_ms // self._period_ms)
        i = bisect.bisect_left(self._stamps, t_ms - cycle * self._period_ms)
        return cycle * self._n + i

    def serve(self, start_s: float, size_bytes: int) -> float:
        """Serve ``size_bytes`` from ``start_s`` on (queue empty of earlier packets)."""
        remaining = size_bytes
        k = self._opp_index
        if k >= 0 and self._opp_left > 0 and self._time_of(k) >= start_s:
            left = self._opp_left  # finish the opportunity the previous packet started
        else:
            # An opportunity serves one packet start at most once: never go back to k.
            k = max(self._first_at_or_after(start_s), k + 1)
            left = MAHIMAHI_MTU_BYTES
        while True:
            used = min(left, remaining)
            remaining -= used
            left -= used
            if remaining == 0:
                self._opp_index, self._opp_left = k, left
                return self._time_of(k)
            k += 1
            left = MAHIMAHI_MTU_BYTES


class Link:
    """A stateful, deterministic model of one direction of a path (see module docstring).

    ``send`` must be called with nondecreasing ``now_s``.  The link keeps the
    bottleneck queue (departure times of queued packets), the Gilbert-Elliott state,
    the correlated random state and the last delivery time (for ``keep_order``).
    ``rto_s`` is the extra delay a *reliable* send adds for a lost segment.
    """

    def __init__(
        self,
        spec: LinkSpec,
        rng: np.random.Generator,
        *,
        rto_s: float = DEFAULT_RTO_S,
    ) -> None:
        self.spec = spec
        self.rto_s = rto_s
        self._rng = rng
        self._u_delay = _CorrelatedUniform(spec.delay_correlation_pct, rng)
        self._u_loss = _CorrelatedUniform(spec.loss_correlation_pct, rng)
        self._u_dup = _CorrelatedUniform(spec.duplicate_correlation_pct, rng)
        self._u_corrupt = _CorrelatedUniform(spec.corrupt_correlation_pct, rng)
        self._u_reorder = _CorrelatedUniform(spec.reorder_correlation_pct, rng)
        self._ge_bad = False
        self._reorder_counter = 0
        self._last_now = -math.inf
        self._last_delivery = -math.inf
        self._last_reliable = -math.inf
        """When the last reliable (TCP) segment is delivered: TCP's own order, retransmission timeouts included."""
        self._queue: collections.deque[float] = collections.deque()  # departure times
        self._busy_until = -math.inf
        self._trace = (
            _TraceServer(load_mahimahi_trace(spec.trace_path)) if spec.trace_path else None
        )
        self._bits_per_s = spec.rate_bps

    # -- random decisions ---------------------------------------------------------

    def _chance(self, pct: float, draw: _CorrelatedUniform) -> bool:
        if pct <= 0.0:
            return False
        if pct >= 100.0:
            return True
        return draw() * 100.0 < pct

    def _lost(self) -> bool:
        ge = self.spec.gemodel
        if ge is None:
            return self._chance(self.spec.loss_pct, self._u_loss)
        # Loss is decided in the current state, then the state moves (as in netem).
        if self._ge_bad:
            lost = self._chance(ge.bad_loss_pct, self._u_loss)
            if self._rng.random() * 100.0 < ge.r_pct:
                self._ge_bad = False
        else:
            lost = self._chance(ge.good_loss_pct, self._u_loss)
            if self._rng.random() * 100.0 < ge.p_pct:
                self._ge_bad = True
        return lost

    def _propagation_s(self) -> float:
        """One propagation delay sample in s (>= 0)."""
        spec = self.spec
        if spec.jitter_ms == 0.0:
            return spec.delay_ms / 1000.0
        u = self._u_delay()
        if spec.distribution == "uniform":
            z = 2.0 * u - 1.0  # delay +- jitter, uniformly
        else:
            u = min(max(u, 1e-12), 1.0 - 1e-12)
            if spec.distribution == "normal":
                z = _STD_NORMAL.inv_cdf(u)
            else:
                pareto = ((1.0 - u) ** (-1.0 / _PARETO_ALPHA) - _PARETO_MEAN) / _PARETO_STD
                if spec.distribution == "pareto":
                    z = pareto
                else:  # paretonormal: 25 % normal + 75 % pareto, rescaled to unit std
                    u2 = min(max(float(self._rng.random()), 1e-12), 1.0 - 1e-12)
                    z = (0.25 * _STD_NORMAL.inv_cdf(u2) + 0.75 * pareto) / math.sqrt(
                        0.25**2 + 0.75**2
                    )
        return max(0.0, (spec.delay_ms + z * spec.jitter_ms) / 1000.0)

    # -- queue --------------------------------------------------------------------

    @property
    def queue_length(self) -> int:
        """Packets in the bottleneck queue (waiting or being serialised) at the last send."""
        return len(self._queue)

    def _depart(self, now_s: float, size_bytes: int) -> float:
        """Departure time from the bottleneck (end of serialisation), in s."""
        start = max(now_s, self._busy_until)
        if self._trace is not None:
            done = self._trace.serve(start, size_bytes)
        elif self._bits_per_s is not None:
            done = start + size_bytes * 8.0 / self._bits_per_s
        else:
            return now_s
        self._busy_until = done
        self._queue.append(done)
        return done

    def _transmit(self, now_s: float, size_bytes: int, corrupted: bool, penalty_s: float,
                  reliable: bool) -> Delivery | None:
        limited = self._trace is not None or self._bits_per_s is not None
        if limited and len(self._queue) >= self.spec.limit_packets:
            if not reliable:
                return None  # drop-tail
            penalty_s += self.rto_s
        depart = self._depart(now_s, size_bytes)
        spec = self.spec
        if not reliable and spec.reorder_pct > 0.0:
            if self._reorder_counter < spec.reorder_gap - 1 or not self._chance(
                spec.reorder_pct, self._u_reorder
            ):
                self._reorder_counter += 1
            else:
                self._reorder_counter = 0
                return Delivery(depart + penalty_s, corrupted)  # sent immediately
        t = depart + self._propagation_s()
        if spec.spike_ms and spec.spike_start_s <= depart < spec.spike_start_s + spec.spike_duration_s:
            t += spec.spike_ms / 1000.0
        if spec.keep_order or reliable:
            t = max(t, self._last_delivery)
        self._last_delivery = max(self._last_delivery, t)
        if reliable:
            # a lost segment's retransmission timeout holds back its own stream (TCP is in order), never the
            # datagrams behind it on the path: other flows do not wait for one flow's retransmission
            t = max(t + penalty_s, self._last_reliable)
            self._last_reliable = t
        return Delivery(t, corrupted)

    # -- public -------------------------------------------------------------------

    def send(self, now_s: float, size_bytes: int, *, reliable: bool = False) -> list[Delivery]:
        """Offer a packet of ``size_bytes`` at ``now_s`` (s); return its deliveries.

        ``[]`` means lost, two entries mean duplicated.  With ``reliable=True`` (a TCP
        segment) nothing is dropped, duplicated, corrupted or reordered: a loss (or a
        full queue) instead delays the segment by ``rto_s``, and order is kept.
        Raises :class:`ValueError` when ``now_s`` goes backwards.
        """
        if not now_s >= self._last_now:
            raise ValueError(
                f"Link.send: now_s={now_s!r} s is before the previous call's {self._last_now!r} s"
            )
        if size_bytes < 0:
            raise ValueError(f"Link.send: size_bytes must be >= 0, got {size_bytes}")
        self._last_now = now_s
        queue = self._queue
        while queue and queue[0] <= now_s:
            queue.popleft()
        if reliable:
            penalty = self.rto_s if self._lost() else 0.0
            d = self._transmit(now_s, size_bytes, False, penalty, True)
            assert d is not None
            return [d]
        spec = self.spec
        copies = 2 if self._chance(spec.duplicate_pct, self._u_dup) else 1
        if self._lost():
            copies -= 1
        if copies == 0:
            return []
        corrupted = self._chance(spec.corrupt_pct, self._u_corrupt)
        out: list[Delivery] = []
        for i in range(copies):
            d = self._transmit(now_s, size_bytes, corrupted and i == 0, 0.0, False)
            if d is not None:
                out.append(d)
        return out


def corrupt(payload: bytes, rng: np.random.Generator) -> bytes:
    """Return ``payload`` with one uniformly chosen bit flipped (empty stays empty)."""
    if not payload:
        return payload
    bit = int(rng.integers(len(payload) * 8))
    out = bytearray(payload)
    out[bit // 8] ^= 1 << (bit % 8)
    return bytes(out)


@dataclass(frozen=True)
class PathSpec:
    """Both directions of a path: ``uplink`` client -> server, ``downlink`` server -> client."""

    uplink: LinkSpec = LinkSpec()
    downlink: LinkSpec = LinkSpec()

    @classmethod
    def symmetric(cls, link: LinkSpec) -> PathSpec:
        """The same spec in both directions."""
        return cls(uplink=link, downlink=link)

    @classmethod
    def from_dict(cls, data: Any) -> PathSpec:
        """Build from ``{"uplink": {...}, "downlink": {...}}`` (keys as in LinkSpec).

        A missing direction is ideal; unknown keys and bad values raise
        :class:`NetworkConfigError` naming the key.
        """
        return path_from_dict(data)

    @classmethod
    def from_toml(cls, path: str | Path, table: str | None = None) -> PathSpec:
        """Load from a TOML file (optionally from the dotted ``table`` inside it)."""
        return path_from_toml(path, table)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """The inverse of :meth:`from_dict` (only non-default keys)."""
        return {"uplink": link_to_dict(self.uplink), "downlink": link_to_dict(self.downlink)}


# -- dict / TOML form ---------------------------------------------------------------

_LINK_FIELDS = {f.name: f for f in dataclasses.fields(LinkSpec)}
_GE_FIELDS = {f.name for f in dataclasses.fields(GilbertElliott)}
_INT_KEYS = {"reorder_gap", "limit_packets"}
_STR_KEYS = {"distribution", "trace_path"}


def _check_type(where: str, key: str, value: Any) -> None:
    if key == "keep_order":
        ok = isinstance(value, bool)
        want = "true or false"
    elif key in _INT_KEYS:
        ok = isinstance(value, int) and not isinstance(value, bool)
        want = "an integer"
    elif key in _STR_KEYS:
        ok = isinstance(value, str)
        want = "a string"
    elif key == "gemodel":
        ok = isinstance(value, dict)
        want = "a table with " + ", ".join(sorted(_GE_FIELDS))
    else:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        want = "a number"
    if not ok:
        raise NetworkConfigError(f"{where}.{key} must be {want}, got {value!r}")


def link_from_dict(data: Any, where: str = "link") -> LinkSpec:
    """Build a :class:`LinkSpec` from a dict of its field names (``gemodel`` a sub-dict)."""
    if not isinstance(data, dict):
        raise NetworkConfigError(f"{where} must be a table/dict, got {type(data).__name__}")
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key not in _LINK_FIELDS:
            raise NetworkConfigError(
                f"{where}: unknown key {key!r} (valid: {', '.join(sorted(_LINK_FIELDS))})"
            )
        if key in ("rate_bps", "trace_path") and value is None:
            kwargs[key] = None
            continue
        _check_type(where, key, value)
        if key == "gemodel":
            for gk, gv in value.items():
                if gk not in _GE_FIELDS:
                    raise NetworkConfigError(
                        f"{where}.gemodel: unknown key {gk!r} (valid: {', '.join(sorted(_GE_FIELDS))})"
                    )
                _check_type(f"{where}.gemodel", gk, gv)
            if "p_pct" not in value:
                raise NetworkConfigError(f"{where}.gemodel: missing key 'p_pct'")
            try:
                value = GilbertElliott(**value)
            except NetworkConfigError as exc:
                raise NetworkConfigError(f"{where}.{exc}") from None
        kwargs[key] = value
    try:
        return LinkSpec(**kwargs)
    except NetworkConfigError as exc:
        raise NetworkConfigError(f"{where}.{exc}") from None


def link_to_dict(spec: LinkSpec) -> dict[str, Any]:
    """The non-default fields of ``spec`` as a dict (``link_from_dict`` inverts it)."""
    default = LinkSpec()
    out: dict[str, Any] = {}
    for name in _LINK_FIELDS:
        value = getattr(spec, name)
        if value != getattr(default, name):
            out[name] = dataclasses.asdict(value) if isinstance(value, GilbertElliott) else value
    return out


def path_from_dict(data: Any) -> PathSpec:
    """``{"uplink": {...}, "downlink": {...}}`` -> :class:`PathSpec`; missing side = ideal."""
    if not isinstance(data, dict):
        raise NetworkConfigError(f"network path must be a table/dict, got {type(data).__name__}")
    for key in data:
        if key not in ("uplink", "downlink"):
            raise NetworkConfigError(
                f"network path: unknown key {key!r} (valid: downlink, uplink)"
            )
    return PathSpec(
        uplink=link_from_dict(data.get("uplink", {}), "uplink"),
        downlink=link_from_dict(data.get("downlink", {}), "downlink"),
    )


def path_from_toml(path: str | Path, table: str | None = None) -> PathSpec:
    """Load a :class:`PathSpec` from a TOML file, optionally from a dotted ``table``."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            data: Any = tomllib.load(fh)
    except OSError as exc:
        raise NetworkConfigError(f"{str(p)!r}: cannot read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise NetworkConfigError(f"{str(p)!r}: invalid TOML: {exc}") from exc
    if table:
        for part in table.split("."):
            if not isinstance(data, dict) or part not in data:
                raise NetworkConfigError(f"{str(p)!r}: no table [{table}]")
            data = data[part]
    try:
        return path_from_dict(data)
    except NetworkConfigError as exc:
        raise NetworkConfigError(f"{str(p)!r}: {exc}") from None
