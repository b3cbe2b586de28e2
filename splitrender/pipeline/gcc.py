"""A delay- and loss-based send-rate estimator and a pacer (sans-IO), after Google Congestion Control.

The structure of draft-ietf-rmcat-gcc-02 as libwebrtc implements it, fed by
transport-wide feedback (:mod:`splitrender.protocol.twcc`):

1. **Arrival groups** (:class:`InterArrival`): packets sent within ``burst_us`` (5 ms)
   of a group's first form one group (a frame's burst); consecutive completed groups
   give a send-time delta, an arrival-time delta and their difference, the one-way
   delay variation.
2. **Trendline filter** (:class:`Trendline`): the variations are accumulated (the
   queueing delay up to a constant), smoothed (``smoothing`` 0.9), and a least-squares
   line is fitted over the last ``window`` (20) points against arrival time; its slope,
   times ``min(deltas, 60)`` and ``threshold_gain`` (4), is the *modified trend*.
3. **Over-use detector** (same class): over-use when the modified trend stays above an
   adaptive threshold (initially 12.5, gains ``k_up`` 0.0087 / ``k_down`` 0.039 per ms,
   clamped to [6, 600]) for ``overuse_time_ms`` (10 ms) over more than one group and is
   not falling; under-use below minus the threshold; normal otherwise.
4. **AIMD rate control** (:class:`AimdRateControl`): over-use sets the rate to ``beta``
   (0.85) of the acknowledged rate and holds; normal increases it, multiplicatively (8 %
   a second) far from the link capacity seen at earlier decreases, additively (about one
   packet per response time) near it; under-use holds.  The rate never exceeds 1.5x the
   acknowledged rate plus 10 kbit/s.
5. **Loss-based bound** (:class:`LossBound`): over each feedback interval, more than 10 %
   lost multiplies it by ``1 - 0.5 p``, under 2 % by 1.05; the target is the smaller of
   the two rates.
6. **Probing** (:class:`ProbeController`): multiplicative increase alone takes half a
   minute to climb from 2 to 20 Mbit/s (8 % a second), and the estimate starts low (300 kbit/s, as WebRTC), so, as libwebrtc does, the sender
   sends short clusters of padding at a multiple of the estimate (``start_probes``: 3x and 6x the start rate, back
   to back; 2x the estimate every ``probe_interval_s`` while nothing is over-used; and again while a
   probe finds more, at ``start_climb`` (3x) the new estimate until the first over-use and 2x
   after it); a cluster's rate as delivered (bytes after its
   first arrival over its arrival span, no more than the rate it was sent at) replaces a
   lower estimate.

:class:`BandwidthEstimator` puts them together: feed it the :class:`PacketResult` lists
the sender's :class:`~splitrender.protocol.twcc.SendHistory` makes of each feedback, read
``target_bps``.  :class:`Pacer` spreads queued packets at a rate instead of sending a
frame's packets in one burst.  Every time is in microseconds on the caller's clock;
arrival times only ever enter as differences, so the receiver's clock may have any
offset.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

from splitrender.errors import ConfigError
from splitrender.protocol.twcc import PacketResult

__all__ = ["AimdRateControl", "BandwidthEstimator", "GccConfig", "InterArrival", "LossBound", "Pacer", "ProbeCluster",
           "ProbeController", "Trendline", "Usage"]


class Usage:
    NORMAL = "normal"
    OVERUSE = "overuse"
    UNDERUSE = "underuse"


@dataclass(frozen=True)
class GccConfig:
    """The estimator's constants (libwebrtc's defaults) and rate bounds in bit/s.

    ``start_bps``: the estimate before any feedback, 300 kbit/s as WebRTC starts; the start-up probes (3x and 6x it)
    find a wider link within the first round trips.  Starting above the link instead fills its queue before the
    first over-use is seen: from 2 Mbit/s, a 1 Mbit/s link's updates were 550-670 ms old (p95) for two seconds."""

    start_bps: float = 300_000.0
    min_bps: float = 100_000.0
    max_bps: float = 50_000_000.0
    burst_us: int = 5_000
    window: int = 20
    smoothing: float = 0.9
    threshold_gain: float = 4.0
    initial_threshold: float = 12.5
    k_up: float = 0.0087
    k_down: float = 0.039
    overuse_time_ms: float = 10.0
    beta: float = 0.85
    acked_window_us: int = 500_000
    loss_high: float = 0.10
    loss_low: float = 0.02
    base_delay_window_us: int = 10_000_000
    queue_target_ms: float = 40.0
    drain_ms: float = 500.0
    probe: bool = True
    probe_interval_s: float = 2.0
    probe_packets: int = 12
    probe_min_bytes: int = 6000
    start_climb: float = 3.0
    """Until the first over-use, a probe that found more is followed by one at this multiple of the new estimate
    (2 after it, as libwebrtc's further probing), and the start-up probes (3x and 6x ``start_bps``) go out back to
    back rather than each after the last one's feedback: at 2x a step, each a feedback interval and a round trip, sas
    over the 8 Mbit/s cellular-like trace reached 5.4 Mbit/s at 0.59 s, its atlas under the start's ceilings all the
    while."""
    start_probes: tuple[float, ...] = (3.0, 6.0)
    """The start-up probes' rates, multiples of ``start_bps``, sent back to back before any feedback (libwebrtc's 3x
    and 6x).  A method that redraws geometry at the display pose may take more (its quality model's ``estimator``:
    3x to 24x, 20 kB more, 0.16 s more of queue on a 1 Mbit/s link): video's step-down test failed with them."""
    acked_cap: float = 1.5
    """A delay-based increase never takes the estimate over this many times the acknowledged rate (plus 10 kbit/s):
    no large increase without evidence the link takes it (libwebrtc's 1.5)."""
    probe_media: bool = False
    """A probe cluster measures the media packets sent within its span beside its padding (libwebrtc's pacer probes
    with media where it has some): on a link the media already half fills, padding alone is delivered at the link's
    rate less the media's, under the estimate it was to raise (a 12 Mbit/s probe through 7 Mbit/s beside 3.5 Mbit/s of
    media read 5.5, padding alone, and 7.0 with the media: ``tests/test_gcc.py``).  Off (False): padding alone, as
    before (GCC's own estimator, video's and atw's); a method's quality model may set it (its ``estimator``)."""
    stale_overuse_ms: float = 5.0
    drained_ms: float = 100.0
    stale_window_ms: float = 1000.0
    """An over-use while the measured queue (:meth:`BandwidthEstimator.queue_ms`) is under ``stale_overuse_ms``, where
    it was ``drained_ms`` or more within the trendline's window and that window spans over ``stale_window_ms``, is
    acted on as normal: the window remembers a queue that has drained.  With few arrival groups a second (probes at
    its coarsest point: 6 frames a second) the 20 points span 3 s, and after a 2 s queue drained it read over-use for
    2.5 s more, cutting the estimate at each feedback to 0.85 of an application-limited acknowledged rate (1.6 Mbit/s
    to 230 kbit/s on a 20 Mbit/s link).  A small queue alone is not enough (near capacity the over-use comes while
    the queue is still a few ms: the step loop's p95 delay rose from 52 to 82 ms), nor a drained one where the window
    is short (30 groups a second: it soon forgets; sas on a 0.6 Mbit/s step took 271 kbit/s of atlas, not 186)."""

    def __post_init__(self) -> None:
        if not 0 < self.min_bps <= self.start_bps <= self.max_bps:
            raise ConfigError(f"GccConfig: need 0 < min_bps <= start_bps <= max_bps, got {self.min_bps:g}, "
                              f"{self.start_bps:g}, {self.max_bps:g}")
        if not 1 < self.start_climb <= 10:
            raise ConfigError(f"GccConfig.start_climb: must be in (1, 10], got {self.start_climb}")
        if not self.start_probes or not all(1 <= m <= 100 for m in self.start_probes):
            raise ConfigError(f"GccConfig.start_probes: one or more, each in [1, 100], got {self.start_probes}")
        if not 1 <= self.acked_cap <= 10:
            raise ConfigError(f"GccConfig.acked_cap: must be in [1, 10], got {self.acked_cap}")
        if not 0 < self.beta < 1:
            raise ConfigError(f"GccConfig.beta: must be in (0, 1), got {self.beta}")
        if self.window < 2:
            raise ConfigError(f"GccConfig.window: must be >= 2, got {self.window}")
        for name in ("stale_overuse_ms", "drained_ms", "stale_window_ms"):
            if not 0 <= getattr(self, name) < math.inf:
                raise ConfigError(f"GccConfig.{name}: must be a finite number of ms >= 0, got {getattr(self, name)}")


class ReceiverEstimate:
    """The path's rate as the receiver estimates it (RTCP REMB, RFC draft-alvestrand-rmcat-remb), for a session whose
    transport is a WebRTC stack's: the browser front door, where aiortc owns RTP and the page's browser reports what
    it measures.  The same face as :class:`BandwidthEstimator` to the rate and operating-point controllers, with
    nothing of its own to measure: no queue, no acknowledged rate, no probes (the receiver's estimate rises as its
    arrivals do).  Before the first report the target is ``start_bps``, as GCC's."""

    def __init__(self, cfg: GccConfig | None = None) -> None:
        self.cfg = cfg or GccConfig()
        self.target_bps = self.cfg.start_bps

    def on_report(self, bps: float, now_us: int) -> float:
        """A receiver's estimate (bit/s) came at ``now_us``: the target, clamped to the configured bounds."""
        if not math.isfinite(bps) or bps < 0:
            return self.target_bps
        self.target_bps = min(max(float(bps), self.cfg.min_bps), self.cfg.max_bps)
        return self.target_bps

    def encoder_bps(self) -> float:
        return self.target_bps

    def queue_ms(self) -> float:
        return 0.0

    def acked_bps(self) -> float | None:
        return None

    def probe(self, now_us: int) -> ProbeCluster | None:
        return None

    def set_rtt(self, rtt_us: int) -> None:
        pass


@dataclass
class _Group:
    first_send: int
    last_send: int
    last_arrival: int
    size: int


class InterArrival:
    """Groups packets by send time and returns, per completed pair of groups, (send delta, arrival delta, size delta)
    in microseconds and bytes.  Packets must come in send order; a packet sent before the current group is dropped,
    as is a group whose arrival went backwards (reordering)."""

    def __init__(self, burst_us: int = 5_000) -> None:
        self.burst_us = burst_us
        self._prev: _Group | None = None
        self._cur: _Group | None = None

    def add(self, send_us: int, arrival_us: int, size: int) -> tuple[int, int, int] | None:
        cur = self._cur
        if cur is None:
            self._cur = _Group(send_us, send_us, arrival_us, size)
            return None
        if send_us < cur.first_send:
            return None
        if send_us - cur.first_send <= self.burst_us:
            cur.last_send = max(cur.last_send, send_us)
            cur.last_arrival = max(cur.last_arrival, arrival_us)
            cur.size += size
            return None
        out = None
        prev = self._prev
        if prev is not None:
            send_d = cur.last_send - prev.last_send
            arr_d = cur.last_arrival - prev.last_arrival
            if arr_d >= 0:
                out = (send_d, arr_d, cur.size - prev.size)
        self._prev = cur
        self._cur = _Group(send_us, send_us, arrival_us, size)
        return out


class Trendline:
    """The trendline filter and the over-use detector with its adaptive threshold (module docstring, 2-3)."""

    def __init__(self, cfg: GccConfig) -> None:
        self.cfg = cfg
        self.threshold = cfg.initial_threshold
        self.usage = Usage.NORMAL
        self.trend = 0.0             # the modified trend last compared with the threshold
        self._acc = 0.0
        self._smoothed = 0.0
        self._points: collections.deque[tuple[float, float]] = collections.deque(maxlen=cfg.window)
        self._first_arrival_ms: float | None = None
        self._arrival_ms = 0.0
        self._deltas = 0
        self._prev_trend = 0.0
        self._over_ms = -1.0
        self._over_count = 0
        self._last_update_ms: float | None = None

    def update(self, send_delta_us: int, arrival_delta_us: int, arrival_us: int) -> str:
        ms = arrival_us / 1000.0
        if self._first_arrival_ms is None:
            self._first_arrival_ms = ms
        self._deltas = min(self._deltas + 1, 1000)
        self._acc += (arrival_delta_us - send_delta_us) / 1000.0
        a = self.cfg.smoothing
        self._smoothed = a * self._smoothed + (1 - a) * self._acc
        self._points.append((ms - self._first_arrival_ms, self._smoothed))
        slope = self._prev_trend
        if len(self._points) == self._points.maxlen:
            slope = _slope(self._points)
        self._detect(slope, send_delta_us / 1000.0, ms)
        self._prev_trend = slope
        return self.usage

    def window_start_us(self) -> float:
        """The arrival time (us) of the window's oldest point (``inf`` before the first)."""
        if self._first_arrival_ms is None or not self._points:
            return math.inf
        return (self._first_arrival_ms + self._points[0][0]) * 1000.0

    def _detect(self, slope: float, send_delta_ms: float, now_ms: float) -> None:
        cfg = self.cfg
        trend = min(self._deltas, 60) * slope * cfg.threshold_gain
        if trend > self.threshold:
            self._over_ms = send_delta_ms / 2 if self._over_ms < 0 else self._over_ms + send_delta_ms
            self._over_count += 1
            if self._over_ms > cfg.overuse_time_ms and self._over_count > 1 and slope >= self._prev_trend:
                self._over_ms, self._over_count = 0.0, 0
                self.usage = Usage.OVERUSE
        elif trend < -self.threshold:
            self._over_ms, self._over_count = -1.0, 0
            self.usage = Usage.UNDERUSE
        else:
            self._over_ms, self._over_count = -1.0, 0
            self.usage = Usage.NORMAL
        self.trend = trend
        self._adapt_threshold(trend, now_ms)

    def _adapt_threshold(self, trend: float, now_ms: float) -> None:
        if self._last_update_ms is None:
            self._last_update_ms = now_ms
        if abs(trend) > self.threshold + 15.0:   # a spike (a route change): do not chase it
            self._last_update_ms = now_ms
            return
        k = self.cfg.k_down if abs(trend) < self.threshold else self.cfg.k_up
        dt = min(now_ms - self._last_update_ms, 100.0)
        self.threshold = min(max(self.threshold + k * (abs(trend) - self.threshold) * dt, 6.0), 600.0)
        self._last_update_ms = now_ms


def _slope(points: collections.deque[tuple[float, float]]) -> float:
    n = len(points)
    mx = sum(p[0] for p in points) / n
    my = sum(p[1] for p in points) / n
    num = sum((x - mx) * (y - my) for x, y in points)
    den = sum((x - mx) ** 2 for x, _ in points)
    return num / den if den > 0 else 0.0


class AimdRateControl:
    """Additive-increase, multiplicative-decrease on the detector's signal (module docstring, 4)."""

    def __init__(self, cfg: GccConfig) -> None:
        self.cfg = cfg
        self.rate_bps = cfg.start_bps
        self.state = "increase"
        self._last_us: int | None = None
        self._cap_mean: float | None = None     # link capacity seen at decreases, kbit/s (exponential mean)
        self._cap_var = 0.4
        self.rtt_us = 100_000

    def update(self, usage: str, acked_bps: float | None, now_us: int) -> float:
        cfg = self.cfg
        if usage == Usage.OVERUSE:
            self.state = "decrease"
        elif usage == Usage.UNDERUSE:
            self.state = "hold"
        elif self.state == "hold" or self.state == "decrease":
            self.state = "increase"
        dt_s = 0.0 if self._last_us is None else min(max(now_us - self._last_us, 0) / 1e6, 1.0)
        self._last_us = now_us
        before = self.rate_bps
        if self.state == "increase":
            if acked_bps is not None and self._cap_mean is not None:
                std = math.sqrt(self._cap_var * self._cap_mean)
                if acked_bps / 1000 > self._cap_mean + 3 * std:   # capacity moved up: forget it
                    self._cap_mean = None
            if self._cap_mean is not None:                       # near convergence: about a packet per response time
                response_s = (self.rtt_us + 100_000) / 1e6
                packets_per_s = max(self.rate_bps / 30 / (1200 * 8), 1.0)   # ~30 frames/s of 1200-byte packets
                bits_per_packet = self.rate_bps / 30 / packets_per_s
                self.rate_bps += max(4000.0, bits_per_packet / response_s) * dt_s
            else:
                self.rate_bps *= 1.08 ** dt_s
        elif self.state == "decrease":
            base = acked_bps if acked_bps is not None else self.rate_bps
            new = cfg.beta * base
            if new < self.rate_bps:
                self.rate_bps = new
            if acked_bps is not None:
                k = acked_bps / 1000
                if self._cap_mean is not None and abs(k - self._cap_mean) > 3 * math.sqrt(self._cap_var * self._cap_mean):
                    self._cap_mean = None
                self._cap_mean = k if self._cap_mean is None else 0.95 * self._cap_mean + 0.05 * k
                norm = max(self._cap_mean, 1.0)
                self._cap_var = min(max(0.95 * self._cap_var + 0.05 * (self._cap_mean - k) ** 2 / norm, 0.4), 2.5)
            self.state = "hold"
        if acked_bps is not None and self.rate_bps > before:    # no large increase without evidence the link takes it
            self.rate_bps = max(before, min(self.rate_bps, cfg.acked_cap * acked_bps + 10_000))
        self.rate_bps = min(max(self.rate_bps, cfg.min_bps), cfg.max_bps)
        return self.rate_bps

    def set_estimate(self, bps: float) -> None:
        """A measured rate (a probe's) replaces the estimate; the capacity seen at decreases is forgotten."""
        self.rate_bps = min(max(bps, self.cfg.min_bps), self.cfg.max_bps)
        self._cap_mean = None


class LossBound:
    """The loss-based rate (module docstring, 5): updated once per feedback batch from its loss fraction."""

    def __init__(self, cfg: GccConfig) -> None:
        self.cfg = cfg
        self.rate_bps = cfg.max_bps
        self.loss = 0.0

    def update(self, lost: int, total: int, delay_bps: float) -> float:
        if total <= 0:
            return self.rate_bps
        p = lost / total
        self.loss = p
        cfg = self.cfg
        if self.rate_bps >= cfg.max_bps:
            self.rate_bps = delay_bps                # start from the delay-based rate at the first report
        if p > cfg.loss_high:
            self.rate_bps *= 1 - 0.5 * p
        elif p < cfg.loss_low:
            self.rate_bps *= 1.05
        self.rate_bps = min(max(self.rate_bps, cfg.min_bps), max(cfg.max_bps, cfg.min_bps))
        return self.rate_bps


@dataclass(frozen=True)
class ProbeCluster:
    """Send ``packets`` padding packets of ``packet_bytes`` each at ``rate_bps`` (spaced ``packet_bytes * 8 /
    rate_bps`` apart) from now until ``end_us``, every one marked with ``cluster`` in the send history, and so is
    every media packet sent meanwhile (the probe measures what the link delivers of all of it, as libwebrtc's pacer
    probes with media where it has some)."""

    cluster: int
    rate_bps: float
    packets: int
    packet_bytes: int
    start_us: int = 0

    @property
    def end_us(self) -> int:
        return self.start_us + int(self.packets * self.spacing_us())

    def spacing_us(self) -> float:
        return self.packet_bytes * 8e6 / self.rate_bps


class ProbeController:
    """When to probe and what a probe found (module docstring, 6)."""

    def __init__(self, cfg: GccConfig) -> None:
        self.cfg = cfg
        self._next_id = 0
        self._start = len(cfg.start_probes)
        self._pending: list[float] = list(cfg.start_probes) if cfg.probe else []   # multiples of the start rate
        self._sent: dict[int, tuple[float, int, int]] = {}              # cluster -> (rate, start us, end us)
        self._results: dict[int, list[PacketResult]] = {}
        self._last_probe_us: int | None = None
        self._last_decrease_us = -(1 << 62)
        self.found: list[tuple[int, float]] = []                        # (cluster, rate found)

    def on_decrease(self, now_us: int) -> None:
        self._last_decrease_us = now_us

    def next_cluster(self, estimate_bps: float, now_us: int) -> ProbeCluster | None:
        cfg = self.cfg
        for cid in [c for c, (_, t, _) in self._sent.items() if now_us - t > 5_000_000]:   # never fully reported
            self._sent.pop(cid)
            self._results.pop(cid, None)
        if not cfg.probe:
            return None
        if self._sent and not (self._next_id < self._start and self._pending
                               and all(e <= now_us for _, _, e in self._sent.values())):
            return None      # one cluster at a time, but for the start-up ones (back to back)
        if self._pending:
            rate = self._pending.pop(0) * (cfg.start_bps if self._next_id < self._start else estimate_bps)
        elif (self._last_probe_us is None or now_us - self._last_probe_us >= cfg.probe_interval_s * 1e6) \
                and now_us - self._last_decrease_us >= cfg.probe_interval_s * 1e6 and estimate_bps < cfg.max_bps:
            rate = 2.0 * estimate_bps
        else:
            return None
        rate = min(rate, cfg.max_bps)
        cid = self._next_id
        self._next_id += 1
        self._last_probe_us = now_us
        nbytes = max(cfg.probe_min_bytes, int(rate * 0.015 / 8))   # 15 ms at the probe's rate
        packets = max(cfg.probe_packets, math.ceil(nbytes / 1200))
        cl = ProbeCluster(cid, rate, packets, max(100, nbytes // packets), now_us)
        self._sent[cid] = (rate, now_us, cl.end_us)
        return cl

    def on_result(self, r: PacketResult) -> None:
        """Collect a result of a packet sent in a cluster (with ``probe_media``, a media packet sent within a
        cluster's span counts in it too)."""
        if r.probe in self._sent:
            self._results.setdefault(r.probe, []).append(r)
        elif r.probe < 0 and self.cfg.probe_media:
            for cid, (_, start, end) in self._sent.items():
                if start <= r.send_us <= end:
                    self._results.setdefault(cid, []).append(r)
                    break

    def evaluate(self, reported_to_us: int) -> float | None:
        """The delivered rate of every cluster whose packets were all sent before ``reported_to_us`` (the newest
        send time the feedback so far covers); the highest found, or None."""
        best = None
        for cid in [c for c, (_, _, end) in self._sent.items() if end < reported_to_us]:
            rate, _, _ = self._sent.pop(cid)
            res = sorted(self._results.pop(cid, []), key=lambda x: x.send_us)
            arrived = sorted((x for x in res if x.arrival_us is not None), key=lambda x: x.arrival_us or 0)
            if len(res) < 3 or len(arrived) < max(3, int(0.8 * len(res))):
                continue
            send_span = max(res[-1].send_us - res[0].send_us, 1)
            recv_span = max((arrived[-1].arrival_us or 0) - (arrived[0].arrival_us or 0), 1)
            send_rate = sum(x.size for x in res[:-1]) * 8e6 / send_span
            recv_rate = sum(x.size for x in arrived[1:]) * 8e6 / recv_span
            found = min(send_rate, recv_rate)
            self.found.append((cid, found))
            if found > 0.7 * rate and found * 2 < self.cfg.max_bps and not self._pending:   # it found more: climb
                self._pending.append(2.0 if self._last_decrease_us > -(1 << 62) else self.cfg.start_climb)
            best = found if best is None else max(best, found)
        return best


class BandwidthEstimator:
    """Transport-wide feedback in (:meth:`on_feedback`), a target send rate out (:attr:`target_bps`).

    ``history`` keeps a record per feedback (time, target, delay-based and loss-based rates, acknowledged rate,
    trend, threshold, usage, loss) for charts, the last ``history_max`` of them."""

    def __init__(self, cfg: GccConfig | None = None, history_max: int = 10_000) -> None:
        self.cfg = cfg or GccConfig()
        self.inter = InterArrival(self.cfg.burst_us)
        self.trendline = Trendline(self.cfg)
        self.aimd = AimdRateControl(self.cfg)
        self.loss = LossBound(self.cfg)
        self.probes = ProbeController(self.cfg)
        self._acked: collections.deque[tuple[int, int]] = collections.deque()   # (arrival us, bytes)
        self.history: collections.deque[dict[str, Any]] = collections.deque(maxlen=history_max)
        self._owd: collections.deque[tuple[int, int]] = collections.deque()    # (arrival us, one-way delay + offset)
        self.target_bps = self.cfg.start_bps
        self._probe_at: tuple[int, float] | None = None
        self.overuses = 0

    def probe(self, now_us: int) -> ProbeCluster | None:
        """A probe cluster to send now, if one is due (mark its packets with its ``cluster`` in the send history)."""
        return self.probes.next_cluster(self.target_bps, now_us)

    def _drained(self) -> bool:
        """The measured queue is under ``stale_overuse_ms``, was ``drained_ms`` or more within the trendline's window,
        and that window spans over ``stale_window_ms`` (see :class:`GccConfig`)."""
        if not self._owd or self.queue_ms() >= self.cfg.stale_overuse_ms:
            return False
        start_us = self.trendline.window_start_us()
        if self._owd[-1][0] - start_us <= self.cfg.stale_window_ms * 1000:
            return False
        base = min(d for _, d in self._owd)
        peak = max((d for a, d in self._owd if a >= start_us), default=base)
        return (peak - base) / 1000.0 >= self.cfg.drained_ms

    def queue_ms(self) -> float:
        """The media's queueing delay now: the newest one-way delays over the lowest of the last
        ``base_delay_window_us`` (the clocks' offset cancels)."""
        if not self._owd:
            return 0.0
        base = min(d for _, d in self._owd)
        recent = [d for a, d in self._owd if a >= self._owd[-1][0] - 50_000]
        return (min(recent) - base) / 1000.0

    def encoder_bps(self) -> float:
        """The rate to encode at: the target, less what drains the measured queue within ``drain_ms`` once it is
        over ``queue_target_ms`` (an over-use decrease alone leaves a standing queue: at 0.85 of the capacity a
        second of queue takes almost seven seconds to drain)."""
        q = self.queue_ms()
        if q <= self.cfg.queue_target_ms:
            return self.target_bps
        rate = self.delivered_bps(200_000) or self.acked_bps() or self.target_bps   # what the link delivers now
        drain = rate * (q - self.cfg.queue_target_ms) / self.cfg.drain_ms
        return max(self.cfg.min_bps, min(self.target_bps, rate - drain))

    def delivered_bps(self, window_us: int) -> float | None:
        """Bytes that arrived in the newest ``window_us`` of arrivals, as bit/s (None with fewer than two)."""
        if len(self._acked) < 2:
            return None
        newest = self._acked[-1][0]
        recent = [(a, b) for a, b in self._acked if a >= newest - window_us]
        if len(recent) < 2:
            return None
        return sum(b for _, b in recent[1:]) * 8e6 / max(recent[-1][0] - recent[0][0], 1)

    def set_rtt(self, rtt_us: int) -> None:
        self.aimd.rtt_us = max(int(rtt_us), 1)

    def acked_bps(self) -> float | None:
        """Bytes received over the last ``acked_window_us`` of arrivals, as bit/s (None until the window fills)."""
        if len(self._acked) < 2 or self._acked[-1][0] - self._acked[0][0] < self.cfg.acked_window_us // 2:
            return None
        span = max(self._acked[-1][0] - self._acked[0][0], 1)
        return sum(b for _, b in self._acked) * 8 * 1e6 / span

    def on_feedback(self, results: list[PacketResult], now_us: int) -> float:
        """Update from one feedback's packet results (in sequence order); returns the new target rate."""
        if not results:
            return self.target_bps
        lost = 0
        prev_usage = self.trendline.usage
        for r in sorted(results, key=lambda r: r.send_us):
            if r.probe >= 0 or self.cfg.probe_media:
                self.probes.on_result(r)
            if r.arrival_us is None:
                lost += 1
                continue
            self._acked.append((r.arrival_us, r.size))
            if r.probe >= 0:       # a probe measures capacity; its own burst is not the media's queue
                continue
            owd = r.arrival_us - r.send_us        # one-way delay up to the clocks' offset
            self._owd.append((r.arrival_us, owd))
            d = self.inter.add(r.send_us, r.arrival_us, r.size)
            if d is not None:
                self.trendline.update(d[0], d[1], r.arrival_us)
        newest = max((a for a, _ in self._acked), default=0)
        while self._acked and self._acked[0][0] < newest - self.cfg.acked_window_us:
            self._acked.popleft()
        while self._owd and self._owd[0][0] < newest - self.cfg.base_delay_window_us:
            self._owd.popleft()
        probe_bps = self.probes.evaluate(max(r.send_us for r in results))
        usage = self.trendline.usage
        if usage == Usage.OVERUSE and self._drained():
            usage = Usage.NORMAL                # the over-use is the window's memory of a queue that has drained
        if usage == Usage.OVERUSE and prev_usage != Usage.OVERUSE:
            self.overuses += 1
            self.probes.on_decrease(now_us)
        acked = self.acked_bps()
        if probe_bps is not None and usage != Usage.OVERUSE and 0.9 * probe_bps > self.aimd.rate_bps:
            self.aimd.set_estimate(0.9 * probe_bps)        # a little under what the link delivered: room for bursts
            self.loss.rate_bps = max(self.loss.rate_bps, probe_bps)
            self._probe_at = (now_us, probe_bps)
        if self._probe_at is not None and now_us - self._probe_at[0] < self.cfg.acked_window_us * 2 and acked is not None:
            acked = max(acked, 0.9 * self._probe_at[1])   # the acked window still averages the rate before the probe
        delay_bps = self.aimd.update(usage, acked, now_us)
        loss_bps = self.loss.update(lost, len(results), delay_bps)
        self.target_bps = min(delay_bps, loss_bps)
        self.history.append({"t_us": now_us, "target_bps": self.target_bps, "delay_bps": delay_bps, "loss_bps": loss_bps,
                             "encoder_bps": self.encoder_bps(), "queue_ms": self.queue_ms(),
                             "probe_bps": probe_bps if probe_bps is not None else math.nan,
                             "acked_bps": acked if acked is not None else math.nan, "trend": self.trendline.trend,
                             "threshold": self.trendline.threshold, "usage": usage, "loss": self.loss.loss})
        return self.target_bps


T = TypeVar("T")


@dataclass
class _Queued(Generic[T]):
    item: T
    size: int
    enqueued_us: int


@dataclass
class Pacer(Generic[T]):
    """A leaky-bucket pacer: queued packets leave at ``rate_bps`` times ``pacing_factor`` (libwebrtc's 2.5: headroom
    so the encoder's frame-size variation does not build a queue), with bursts of at most ``burst_us`` worth of
    budget.  :meth:`poll` returns what may go now; :meth:`next_send_us` when to poll again.  When the oldest packet
    has waited ``max_queue_us``, the pace rises so the queue drains within that time (the sender's queue must not
    become the bottleneck's)."""

    rate_bps: float
    pacing_factor: float = 2.5
    burst_us: int = 5_000
    max_queue_us: int = 2_000_000
    max_packets: int = 10_000
    _queue: collections.deque[_Queued[T]] = field(default_factory=collections.deque)
    _budget: float = 0.0        # bytes that may go now (may run negative after a large packet)
    _last_us: int | None = None
    _bytes_queued: int = 0
    dropped: int = 0

    def __post_init__(self) -> None:
        if not self.rate_bps > 0 or not self.pacing_factor > 0:
            raise ConfigError(f"Pacer: rate_bps and pacing_factor must be > 0, got {self.rate_bps}, {self.pacing_factor}")

    def enqueue(self, item: T, size: int, now_us: int) -> None:
        if len(self._queue) >= self.max_packets:
            old = self._queue.popleft()
            self._bytes_queued -= old.size
            self.dropped += 1
        self._queue.append(_Queued(item, int(size), int(now_us)))
        self._bytes_queued += int(size)

    def pace_bps(self, now_us: int) -> float:
        """The rate the queue drains at now: the paced rate, or faster when the oldest packet would wait too long."""
        pace = self.rate_bps * self.pacing_factor
        if self._queue:
            left_us = self.max_queue_us - (now_us - self._queue[0].enqueued_us)
            need = self._bytes_queued * 8 * 1e6 / max(left_us, 1_000)
            pace = max(pace, need)
        return pace

    def _refill(self, now_us: int) -> float:
        pace = self.pace_bps(now_us)
        if self._last_us is not None:
            cap = pace * self.burst_us / 8e6
            self._budget = min(self._budget + pace * max(now_us - self._last_us, 0) / 8e6, max(cap, 0.0))
        self._last_us = now_us
        return pace

    def poll(self, now_us: int) -> list[T]:
        if not self._queue:
            self._refill(now_us)
            self._budget = max(self._budget, 0.0)
            return []
        self._refill(now_us)
        out: list[T] = []
        while self._queue and self._budget >= 0:
            q = self._queue.popleft()
            self._bytes_queued -= q.size
            self._budget -= q.size
            out.append(q.item)
        return out

    def next_send_us(self, now_us: int) -> int | None:
        """When the next queued packet may go (None when the queue is empty)."""
        if not self._queue:
            return None
        if self._budget >= 0:
            return now_us
        return now_us + int(math.ceil(-self._budget * 8e6 / self.pace_bps(now_us)))

    @property
    def queued(self) -> int:
        return len(self._queue)

    def queue_delay_us(self, now_us: int) -> int:
        return now_us - self._queue[0].enqueued_us if self._queue else 0
