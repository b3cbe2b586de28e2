"""The rate estimator's pieces sans-IO on synthetic arrivals, the pacer's spacing, capacity traces, and the closed
loop over a step trace (issue 35)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from splitrender.errors import ConfigError, NetworkConfigError
from splitrender.netsim.models import LinkSpec, load_mahimahi_trace
from splitrender.netsim.traces import cellular_trace, rate_series, step_trace, trace_stats, write_mahimahi
from splitrender.pipeline.gcc import (AimdRateControl, BandwidthEstimator, GccConfig, InterArrival, Pacer, Trendline,
                                      Usage)
from splitrender.protocol.twcc import PacketResult


def _groups(n: int, queue_step_us: int, noise_us: int = 0, seed: int = 0) -> list[tuple[int, int, int]]:
    """(send delta, arrival delta, arrival time) per frame group 33 ms apart, each arriving ``queue_step_us`` later
    than the last relative to its send time (a queue that grows, or drains when negative)."""
    rng = np.random.default_rng(seed)
    out, t = [], 1_000_000
    for _ in range(n):
        d = 33_333 + queue_step_us + int(rng.integers(-noise_us, noise_us + 1)) if noise_us else 33_333 + queue_step_us
        t += d
        out.append((33_333, d, t))
    return out


def _usages(groups: list[tuple[int, int, int]]) -> list[str]:
    tl = Trendline(GccConfig())
    return [tl.update(s, a, t) for s, a, t in groups]


def test_over_use_is_detected_on_a_growing_queue_and_only_there() -> None:
    """A queue growing 2 ms a frame is over-use within a second of frames; +-1 ms of jitter on a steady queue
    never is (300 frames); a draining queue is under-use."""
    grow = _usages(_groups(60, 2_000))
    first = grow.index(Usage.OVERUSE)
    assert 19 <= first <= 34, first              # 31: the 20-point window, then the smoothed slope's rise
    steady = _usages(_groups(300, 0, noise_us=1_000, seed=1))
    assert Usage.OVERUSE not in steady and Usage.UNDERUSE not in steady
    assert _usages(_groups(60, -2_000))[-1] == Usage.UNDERUSE


def test_the_threshold_adapts_towards_the_trend() -> None:
    """The threshold falls from 12.5 to its floor of 6 while nothing happens (k_down), climbs towards a persistent
    trend (k_up: a queue growing 2 ms a frame, modified trend 13.6) and falls back when the trend goes."""
    tl = Trendline(GccConfig())
    groups = _groups(200, 2_000)
    for s, a, t in _groups(40, 0):
        tl.update(s, a, t)
    assert tl.threshold == 6.0
    t0 = groups[0][2]
    for s, a, t in groups:
        tl.update(s, a, t + 40 * 33_333)
    assert tl.threshold == pytest.approx(tl.trend, rel=0.05) and tl.threshold > 12
    high, t1 = tl.threshold, groups[-1][2] + 40 * 33_333
    for i in range(1, 200):
        tl.update(33_333, 33_333, t1 + i * 33_333)
    assert tl.threshold < high / 2 and t0 > 0


def test_inter_arrival_groups_bursts() -> None:
    ia = InterArrival(5_000)
    got = []
    for frame in range(3):
        for k in range(4):                       # four packets 1 ms apart: one group
            r = ia.add(frame * 33_000 + k * 1_000, 50_000 + frame * 40_000 + k * 1_000, 1000)
            if r:
                got.append(r)
    assert got == [(33_000, 40_000, 0)]          # groups 0 and 1 compared when group 2 starts


def test_aimd_decreases_to_beta_of_the_acked_rate_and_increases_slowly() -> None:
    cfg = GccConfig(start_bps=5e6)
    a = AimdRateControl(cfg)
    assert a.update(Usage.OVERUSE, 4e6, 0) == pytest.approx(0.85 * 4e6)
    assert a.state == "hold"
    r1 = a.update(Usage.NORMAL, 3.4e6, 100_000)
    r2 = a.update(Usage.NORMAL, 3.4e6, 1_100_000)
    assert 3.4e6 <= r1 <= r2 <= 3.4e6 * 1.09      # additive near the capacity just seen: slow
    assert a.update(Usage.UNDERUSE, 3.4e6, 1_200_000) == r2
    far = AimdRateControl(GccConfig(start_bps=1e6))
    far.update(Usage.NORMAL, None, 0)
    assert far.update(Usage.NORMAL, None, 1_000_000) == pytest.approx(1.08e6)   # multiplicative, 8 % a second


def test_pacer_spaces_packets_at_the_paced_rate() -> None:
    """1 Mbit/s, pacing factor 1, no burst: 1250-byte packets leave 10 ms apart however they were queued."""
    p: Pacer[int] = Pacer(1e6, pacing_factor=1.0, burst_us=0)
    for i in range(10):
        p.enqueue(i, 1250, 0)
    sent: list[tuple[int, int]] = []
    now = 0
    while p.queued:
        sent += [(now, i) for i in p.poll(now)]
        nxt = p.next_send_us(now)
        now = nxt if nxt is not None and nxt > now else now + 1
    assert [i for _, i in sent] == list(range(10))
    assert [t for t, _ in sent] == [k * 10_000 for k in range(10)]


def test_pacer_drains_a_queue_that_would_wait_too_long() -> None:
    p: Pacer[int] = Pacer(1e6, pacing_factor=1.0, burst_us=0, max_queue_us=200_000)
    for i in range(100):                          # 1 Mbit: 1 s at the paced rate
        p.enqueue(i, 1250, 0)
    assert p.pace_bps(0) == pytest.approx(100 * 1250 * 8 / 0.2)
    with pytest.raises(ConfigError, match="rate_bps and pacing_factor must be > 0"):
        Pacer(0.0)


def test_a_probe_measures_what_the_link_delivers() -> None:
    """A cluster sent at 12 Mbit/s through a 6 Mbit/s bottleneck reads as 6 and raises a 2 Mbit/s estimate."""
    est = BandwidthEstimator(GccConfig(start_bps=2e6))
    cl = est.probe(0)
    assert cl is not None and cl.rate_bps == pytest.approx(6e6)       # the first probe: 3x the start rate
    est.probes._sent.clear()
    est.probes._pending.clear()
    est.probes._last_probe_us = -10**9
    est.probes._last_decrease_us = -10**9
    cl = est.probes.next_cluster(6e6, 10_000_000)                    # a periodic probe: 2x the estimate
    assert cl is not None and cl.rate_bps == pytest.approx(12e6)
    results, t_free = [], 10_020_000
    for k in range(cl.packets):
        send = cl.start_us + int(k * cl.spacing_us())
        t_free = max(t_free, send + 20_000) + int(cl.packet_bytes * 8e6 / 6e6)
        results.append(PacketResult(k, send, cl.packet_bytes, t_free, cl.cluster))
    results.append(PacketResult(cl.packets, cl.end_us + 1, 1000, t_free + 5_000))   # a later media packet
    est.on_feedback(results, 10_200_000)
    assert est.probes.found[-1][1] == pytest.approx(6e6, rel=0.02)
    assert est.target_bps == pytest.approx(0.9 * 6e6, rel=0.03)


def _probe_beside_media(cfg: GccConfig) -> BandwidthEstimator:
    """A periodic probe (2x a 6 Mbit/s estimate) through a 7 Mbit/s FIFO bottleneck while media goes out at 3.5
    Mbit/s, 1,000-byte packets: the estimator after the feedback that covers it."""
    est = BandwidthEstimator(cfg)
    est.probes._pending.clear()
    est.aimd.set_estimate(6e6)
    cl = est.probes.next_cluster(6e6, 10_000_000)
    assert cl is not None and cl.rate_bps == pytest.approx(12e6)
    sent = [(cl.start_us + int(k * cl.spacing_us()), cl.packet_bytes, cl.cluster) for k in range(cl.packets)]
    sent += [(9_990_000 + k * 2_286, 1000, -1) for k in range(40)]          # 1,000 bytes every 2.29 ms: 3.5 Mbit/s
    results, t_free = [], 0
    for seq, (send, size, probe) in enumerate(sorted(sent)):
        t_free = max(t_free, send + 20_000) + int(size * 8e6 / 7e6)
        results.append(PacketResult(seq, send, size, t_free, probe))
    est.on_feedback(results, 10_200_000)
    return est


def test_a_probe_beside_media_measures_the_link_with_probe_media() -> None:
    """Padding alone, a probe sent while media shares the link reads the link less the media's rate (5.5 of 7
    Mbit/s here, under the 6 Mbit/s estimate: nothing found); with ``probe_media`` the media sent within its span
    counts too and it reads the link, raising the estimate to 0.9 of it."""
    alone = _probe_beside_media(GccConfig())
    assert alone.probes.found[-1][1] < 0.8 * 7e6
    assert alone.target_bps < 6.1e6
    both = _probe_beside_media(GccConfig(probe_media=True))
    assert both.probes.found[-1][1] == pytest.approx(7e6, rel=0.05)
    assert both.target_bps == pytest.approx(0.9 * 7e6, rel=0.05)


def _start_clusters(cfg: GccConfig) -> list[tuple[float, int, int]]:
    """(rate, start us, end us) of the clusters the estimator sends before any feedback, polled every ms for 0.2 s."""
    est, out = BandwidthEstimator(cfg), []
    for now in range(0, 200_000, 1_000):
        cl = est.probe(now)
        if cl is not None:
            out.append((cl.rate_bps, cl.start_us, cl.end_us))
    return out


def test_the_start_up_probes_go_back_to_back_at_their_multiples() -> None:
    """GCC's own: 3x and 6x the start rate, the second as the first ends, then nothing until feedback; a config's
    ``start_probes`` (a queue-tolerant method's, issue 48) sends its multiples the same way."""
    own = _start_clusters(GccConfig())
    assert [r for r, _, _ in own] == pytest.approx([0.9e6, 1.8e6])
    more = _start_clusters(GccConfig(start_probes=(3.0, 6.0, 12.0, 24.0)))
    assert [r for r, _, _ in more] == pytest.approx([0.9e6, 1.8e6, 3.6e6, 7.2e6])
    assert more[:2] == own                                  # the first two as GCC's, to the microsecond
    assert all(0 <= b[1] - a[2] < 1_000 for a, b in zip(more, more[1:]))   # each within a poll of the last's end


def test_the_acknowledged_cap_bounds_an_increase() -> None:
    """An increase never takes the rate past ``acked_cap`` times the acknowledged rate plus 10 kbit/s (1.5 by
    default), however long since the last update."""
    for cap in (1.5, 2.0):
        aimd = AimdRateControl(GccConfig(start_bps=3e6, acked_cap=cap))
        aimd.update(Usage.NORMAL, 1e6, 0)
        assert aimd.rate_bps == 3e6                         # no increase: the start stays where it is
        aimd.rate_bps = 1e6
        for k in range(1, 200):
            aimd.update(Usage.NORMAL, 1e6, k * 1_000_000)
        assert aimd.rate_bps == pytest.approx(cap * 1e6 + 10_000)


def test_config_is_validated() -> None:
    with pytest.raises(ConfigError, match="need 0 < min_bps <= start_bps <= max_bps"):
        GccConfig(start_bps=1.0)
    with pytest.raises(ConfigError, match="beta: must be in"):
        GccConfig(beta=1.5)
    with pytest.raises(ConfigError, match=r"start_probes: one or more, each in \[1, 100\], got \(\)"):
        GccConfig(start_probes=())
    with pytest.raises(ConfigError, match="start_probes: one or more"):
        GccConfig(start_probes=(3.0, 0.5))
    with pytest.raises(ConfigError, match=r"acked_cap: must be in \[1, 10\], got 0.9"):
        GccConfig(acked_cap=0.9)


# --------------------------------------------------------------------------- capacity traces


def test_step_trace_rates_and_round_trip(tmp_path) -> None:  # type: ignore[no-untyped-def]
    st = step_trace([(1.0, 12.0), (1.0, 2.4)])
    r = rate_series(st, 100)
    assert r[:10] == pytest.approx([12.0] * 10, rel=0.02) and r[10:] == pytest.approx([2.4] * 10, rel=0.06)
    back = load_mahimahi_trace(write_mahimahi(st, tmp_path / "s.mm"))
    assert (back == st).all() and back[-1] == 2000
    for bad, msg in (([], "no steps"), ([(0.0, 5.0)], "lasts 0.0 s"), ([(1.0, -1.0)], "rate -1.0"), ([(1.0, 0.0)], "delivers nothing")):
        with pytest.raises(NetworkConfigError, match=msg):
            step_trace(bad)


def test_trace_statistics_take_a_trace_that_starts_at_zero() -> None:
    """mahimahi's public traces begin with opportunities at 0 ms (several on one millisecond); the statistics
    crashed on them (a slot index of -1) and now count them in the first slot."""
    st = np.array([0, 0, 0, 40, 60, 100], np.int64)
    r = rate_series(st, 50)
    assert r.tolist() == pytest.approx([4 * 1500 * 8 / 0.05 / 1e6, 2 * 1500 * 8 / 0.05 / 1e6])
    assert trace_stats(st, 50)["mean_mbps"] == pytest.approx(6 * 1500 * 8 / 0.1 / 1e6)


def test_cellular_trace_has_its_stated_statistics() -> None:
    """Over 10 minutes the generator's mean (outages included), variation, outage share and correlation are what
    was asked, within sampling error; the same seed gives the same trace."""
    st = cellular_trace(600, mean_mbps=8.0, cv=0.5, corr_time_s=1.0, outage_share=0.02, outage_mean_s=0.3, seed=3)
    s = trace_stats(st, 50)
    assert s["mean_mbps"] == pytest.approx(8.0 * 0.98, rel=0.08)
    assert s["cv"] == pytest.approx(0.5, rel=0.15)
    assert s["outage_share"] == pytest.approx(0.02, abs=0.008)
    assert s["lag1_corr"] > 0.85                      # e^(-50 ms / 1 s) = 0.95 for the log-rate; outages lower it
    assert (cellular_trace(5, seed=3) == cellular_trace(5, seed=3)).all()
    with pytest.raises(NetworkConfigError, match="cv = -1"):
        cellular_trace(5, cv=-1)


# --------------------------------------------------------------------------- the closed loop


@pytest.fixture(scope="module")
def step_loop(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    from splitrender.sim.cc_loop import run_loop

    path = write_mahimahi(step_trace([(5, 20), (5, 2), (10, 20)]), tmp_path_factory.mktemp("cc") / "step.mm")
    return run_loop(LinkSpec(delay_ms=20, trace_path=str(path), limit_packets=300), 20.0)


def test_the_loop_follows_a_step_down_and_up(step_loop) -> None:  # type: ignore[no-untyped-def]
    """20 -> 2 -> 20 Mbit/s, 20 ms each way: the encoder rate is under 1.2x the new capacity 0.32 s after the drop
    (the queue it measures), the delay-based target 1.12 s after (its trendline window); after the rise a probe
    finds the capacity and the target passes 14 Mbit/s 1.9 s later, where multiplicative increase alone would
    take half a minute; 86 % of the capacity is used over the steady parts."""
    t, enc, tgt = step_loop.column("t_s"), step_loop.column("encoder_mbps"), step_loop.column("target_mbps")
    assert t[(t > 5) & (enc <= 2.4)][0] - 5 < 0.5
    assert t[(t > 5) & (tgt <= 2.4)][0] - 5 < 1.3
    assert t[(t > 10) & (tgt >= 14)][0] - 10 < 2.5
    sent, cap = step_loop.column("sent_mbps"), step_loop.column("capacity_mbps")
    steady = ((t > 2) & (t < 5)) | ((t > 7) & (t < 10)) | ((t > 13) & (t < 20))
    assert sent[steady].sum() / cap[steady].sum() > 0.8
    d = step_loop.column("delay_ms")
    assert np.nanpercentile(d[steady], 95) < 60                         # 52 ms: 20 ms path, frame bursts queue
    assert step_loop.probe_bytes < 0.05 * step_loop.media_bytes          # probing costs 3.4 %
    assert math.isfinite(float(np.nanmax(d)))


def test_capacity_trace_stats_reads_any_trace_and_the_link_study_takes_a_users(tmp_path, capsys, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``capacity-trace stats FILE...`` prints each trace's statistics (a public trace as it is downloaded: starting
    at 0 ms, several opportunities a millisecond); ``SPLITRENDER_LINK_TRACES`` adds a user's traces to the link
    study, each checked first and named when it cannot be read."""
    from splitrender.cli import main
    from splitrender.experiments.studies import link

    pub = tmp_path / "public.down"
    pub.write_text("0\n0\n0\n" + "".join(f"{t}\n" for t in range(1, 1001)))
    gen = write_mahimahi(step_trace([(1.0, 12.0)]), tmp_path / "gen.trace")
    assert main(["capacity-trace", "stats", str(pub), str(gen)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "trace,mean_mbps,cv,outage_pct,lag1_corr,period_s"
    assert lines[1].startswith(f"{pub},12.04,") and lines[2].startswith(f"{gen},12.00,0.00,0.0,")
    monkeypatch.setenv(link.TRACES_ENV, f"{pub}, {gen}")
    assert [(p, len(st)) for p, st in link.extra_traces()] == [(str(pub), 1003), (str(gen), len(load_mahimahi_trace(gen)))]
    monkeypatch.setenv(link.TRACES_ENV, str(tmp_path / "missing.down"))
    with pytest.raises(NetworkConfigError, match=r"mahimahi trace '.*missing.down': cannot read"):
        link.extra_traces()
