"""The rate estimator in a closed loop over a modelled link, in virtual time (no rendering, no codec).

A sender produces a frame every ``1 / fps`` s of the size the estimator's target allows,
cuts it into packets of at most ``mtu`` bytes and queues them in the :class:`Pacer`;
probe clusters go out as the estimator asks.  Every packet crosses a
:class:`~splitrender.netsim.models.Link` (its delay, loss and bottleneck: a fixed rate or
a mahimahi capacity trace); the receiver's :class:`FeedbackRecorder` reports arrivals
every ``feedback_ms``, and the report reaches the sender one return-path delay later,
where the :class:`SendHistory` turns it into packet results for the
:class:`BandwidthEstimator`.  This is the loop a session runs, with frames of exactly
the target size: it shows the controller's own dynamics (how fast it follows a step,
how much queue it builds) apart from any encoder's.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from splitrender.netsim.models import Link, LinkSpec, load_mahimahi_trace
from splitrender.netsim.traces import rate_series
from splitrender.pipeline.gcc import BandwidthEstimator, GccConfig, Pacer
from splitrender.protocol.twcc import FeedbackRecorder, SendHistory

__all__ = ["LoopResult", "run_loop"]


@dataclass
class LoopResult:
    """Per feedback report: ``t_s``, ``target_mbps``, ``capacity_mbps`` (the link's, where it has a rate or a trace),
    ``acked_mbps``, ``sent_mbps`` and ``delay_ms`` (median one-way delay of the media packets that arrived since the
    previous report), ``loss`` and ``usage``."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    packets_sent: int = 0
    packets_lost: int = 0
    probe_bytes: int = 0
    media_bytes: int = 0

    def column(self, key: str) -> np.ndarray:
        return np.array([r[key] for r in self.rows], np.float64)


def _capacity_fn(spec: LinkSpec):  # type: ignore[no-untyped-def]
    if spec.trace_path:
        series = rate_series(load_mahimahi_trace(spec.trace_path), 100)
        period = len(series) * 0.1
        return lambda t: float(series[int((t % period) / 0.1) % len(series)])
    if spec.rate_bps:
        return lambda t: spec.rate_bps / 1e6
    return lambda t: math.nan


def run_loop(link: LinkSpec, duration_s: float, fps: float = 30.0, seed: int = 0, feedback_ms: float = 100.0,
             return_delay_ms: float | None = None, cfg: GccConfig | None = None, mtu: int = 1200,
             pacing: bool = True) -> LoopResult:
    """Run the loop for ``duration_s``; see the module docstring.  ``return_delay_ms`` defaults to the link's delay."""
    est = BandwidthEstimator(cfg)
    rng = np.random.default_rng(seed)
    down = Link(link, rng)
    hist, rec = SendHistory(window_us=10_000_000), FeedbackRecorder(ssrc=1)
    pacer: Pacer[tuple[int, int]] = Pacer(est.target_bps, pacing_factor=2.5 if pacing else 1e6)
    back_us = int((link.delay_ms if return_delay_ms is None else return_delay_ms) * 1000)
    capacity = _capacity_fn(link)
    res = LoopResult()
    events: list[tuple[int, int, str, Any]] = []
    order = 0

    def push(t: int, kind: str, data: Any = None) -> None:
        nonlocal order
        order += 1
        heapq.heappush(events, (t, order, kind, data))

    end_us = int(duration_s * 1e6)
    push(0, "frame")
    push(int(feedback_ms * 1000), "feedback")
    window: list[tuple[int, int]] = []        # (one-way delay us, bytes) of media arrivals since the last report
    sent_bytes = 0
    sent_since = 0
    next_pace: int | None = None

    def send(t: int, size: int, probe: int) -> None:
        nonlocal sent_bytes
        seq = hist.on_sent(t, size, probe)
        res.packets_sent += 1
        if probe >= 0:
            res.probe_bytes += size
        else:
            res.media_bytes += size
        sent_bytes += size
        deliveries = down.send(t / 1e6, size)
        if not deliveries:
            res.packets_lost += 1
        for d in deliveries[:1]:
            push(int(d.time_s * 1e6), "arrive", (seq, t, size, probe))

    probing: list[Any] = [None]           # the cluster being sent: media sent meanwhile belongs to it

    def pace(t: int) -> None:
        nonlocal next_pace
        cl = probing[0]
        tag = cl.cluster if cl is not None and cl.start_us <= t <= cl.end_us else -1
        for size, _ in pacer.poll(t):
            send(t, size, tag)
        nxt = pacer.next_send_us(t)
        if nxt is not None and (next_pace is None or nxt < next_pace or next_pace <= t):
            next_pace = max(nxt, t + 1)
            push(next_pace, "pace")

    while events:
        t, _, kind, data = heapq.heappop(events)
        if t > end_us:
            break
        if kind == "frame":
            size = int(est.encoder_bps() / fps / 8)
            while size > 0:
                n = min(mtu, size)
                pacer.enqueue((n, t), n, t)
                size -= n
            pace(t)
            cl = est.probe(t)
            if cl is not None:
                probing[0] = cl
                for k in range(cl.packets):
                    push(t + int(k * cl.spacing_us()), "probe", (cl.packet_bytes, cl.cluster))
            push(t + int(1e6 / fps), "frame")
        elif kind == "probe":
            send(t, data[0], data[1])
        elif kind == "pace":
            if next_pace == t:
                next_pace = None
            pace(t)
        elif kind == "arrive":
            seq, sent_us, size, probe = data
            rec.on_packet(seq, t)
            if probe < 0:
                window.append((t - sent_us, size))
        elif kind == "feedback":
            fbs = rec.feedback()
            if fbs:
                push(t + back_us, "report", fbs)
            push(t + int(feedback_ms * 1000), "feedback")
        elif kind == "report":
            results = [r for fb in data for r in hist.on_feedback(fb)]
            target = est.on_feedback(results, t)
            pacer.rate_bps = target
            lost = sum(1 for r in results if r.arrival_us is None)
            delays = sorted(d for d, _ in window)
            h = est.history[-1] if est.history else {}
            res.rows.append({
                "t_s": t / 1e6, "target_mbps": target / 1e6, "encoder_mbps": est.encoder_bps() / 1e6,
                "capacity_mbps": capacity(t / 1e6),
                "acked_mbps": h.get("acked_bps", math.nan) / 1e6, "probe_mbps": h.get("probe_bps", math.nan) / 1e6,
                "sent_mbps": sent_bytes * 8 / max(t - sent_since, 1), "delay_ms": delays[len(delays) // 2] / 1000 if delays else math.nan,
                "p95_delay_ms": delays[int(0.95 * (len(delays) - 1))] / 1000 if delays else math.nan,
                "loss": lost / len(results) if results else 0.0, "usage": h.get("usage", ""),
                "queued_ms": pacer.queue_delay_us(t) / 1000})
            window.clear()
            sent_bytes, sent_since = 0, t
    return res
