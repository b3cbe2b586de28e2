"""Statistics of the seeded link model (fixed seeds, stated tolerances)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from splitrender.errors import NetworkConfigError
from splitrender.netsim import (
    Delivery,
    GilbertElliott,
    Link,
    LinkSpec,
    PathSpec,
    corrupt,
    get_profile,
    load_mahimahi_trace,
)


def rng(seed: int = 1) -> np.random.Generator:
    return np.random.default_rng(seed)


def one_way_delays_ms(spec: LinkSpec, n: int, spacing_s: float = 0.2, seed: int = 1) -> np.ndarray:
    link = Link(spec, rng(seed))
    out = []
    for i in range(n):
        now = i * spacing_s
        (d,) = link.send(now, 1000)
        out.append((d.time_s - now) * 1000.0)
    return np.asarray(out)


# -- delay distributions -------------------------------------------------------------


def test_uniform_jitter_mean_and_range_cloud() -> None:
    d = one_way_delays_ms(get_profile("cloud").downlink, 20_000)
    assert d.min() >= 30.0 and d.max() <= 70.0
    assert d.min() < 30.1 and d.max() > 69.9  # the whole +-20 ms range is used
    assert abs(d.mean() - 50.0) < 0.3
    assert abs(d.std() - 20.0 / math.sqrt(3.0)) < 0.2  # uniform std = half-width / sqrt(3)


def test_lan_profile_range() -> None:
    d = one_way_delays_ms(get_profile("lan").uplink, 5_000)
    assert 10.0 <= d.min() and d.max() <= 30.0 and abs(d.mean() - 20.0) < 0.4


def test_normal_shape() -> None:
    d = one_way_delays_ms(LinkSpec(delay_ms=100, jitter_ms=10, distribution="normal"), 20_000)
    assert abs(d.mean() - 100.0) < 0.3
    assert abs(d.std() - 10.0) < 0.3
    # about 68.3 % within one sigma, 95.4 % within two
    assert abs(np.mean(np.abs(d - 100) < 10) - 0.683) < 0.015
    assert abs(np.mean(np.abs(d - 100) < 20) - 0.954) < 0.008


def test_pareto_shape_heavy_right_tail() -> None:
    d = one_way_delays_ms(LinkSpec(delay_ms=100, jitter_ms=10, distribution="pareto"), 20_000)
    assert abs(np.median(d) - 100.0) > 2.0  # skewed: median below the mean
    assert np.median(d) < d.mean()
    assert abs(d.mean() - 100.0) < 1.0
    # bounded below at mean - sqrt(3) sigma (alpha = 3), long tail above
    assert d.min() >= 100 - math.sqrt(3) * 10 - 1e-9
    assert d.max() > 100 + 5 * 10


def test_paretonormal_between_normal_and_pareto() -> None:
    d = one_way_delays_ms(LinkSpec(delay_ms=100, jitter_ms=10, distribution="paretonormal"), 20_000)
    assert abs(d.mean() - 100.0) < 0.5
    assert abs(d.std() - 10.0) < 1.0
    dp = one_way_delays_ms(LinkSpec(delay_ms=100, jitter_ms=10, distribution="pareto"), 20_000)

    def skew(x: np.ndarray) -> float:
        return float(np.mean(((x - x.mean()) / x.std()) ** 3))

    assert 0.3 < skew(d) < skew(dp)  # right-skewed, but less than pure pareto


def test_delay_correlation_makes_successive_samples_correlated() -> None:
    d0 = one_way_delays_ms(LinkSpec(delay_ms=50, jitter_ms=20), 5_000)
    d9 = one_way_delays_ms(LinkSpec(delay_ms=50, jitter_ms=20, delay_correlation_pct=90), 5_000)
    r0 = np.corrcoef(d0[:-1], d0[1:])[0, 1]
    r9 = np.corrcoef(d9[:-1], d9[1:])[0, 1]
    assert abs(r0) < 0.05 and r9 > 0.8


def test_keep_order_never_reorders_but_netem_mode_does() -> None:
    spec = get_profile("cloud").downlink
    for keep, expect_reorder in ((True, False), (False, True)):
        link = Link(LinkSpec(delay_ms=50, jitter_ms=20, keep_order=keep), rng())
        times = [link.send(i * 0.001, 200)[0].time_s for i in range(2_000)]
        reordered = any(b < a for a, b in zip(times, times[1:]))
        assert reordered is expect_reorder
        assert min(t - i * 0.001 for i, t in enumerate(times)) >= 0.030 - 1e-12
    assert spec.keep_order is True


# -- loss ------------------------------------------------------------------------------


def deliveries(spec: LinkSpec, n: int, seed: int = 1, size: int = 1000,
               spacing_s: float = 0.001) -> list[list[Delivery]]:
    link = Link(spec, rng(seed))
    return [link.send(i * spacing_s, size) for i in range(n)]


def test_random_loss_rate() -> None:
    out = deliveries(LinkSpec(loss_pct=5.0), 20_000)
    rate = sum(1 for d in out if not d) / len(out)
    # binomial std = sqrt(.05 * .95 / 20000) = 0.0015; allow ~4 sigma
    assert abs(rate - 0.05) < 0.006


def test_no_loss_is_lossless_and_full_loss_drops_all() -> None:
    assert all(len(d) == 1 for d in deliveries(LinkSpec(), 1_000))
    assert not any(deliveries(LinkSpec(loss_pct=100.0), 1_000))


def burst_lengths(lost: list[bool]) -> list[int]:
    bursts, run = [], 0
    for x in lost:
        if x:
            run += 1
        elif run:
            bursts.append(run)
            run = 0
    return bursts


def test_gilbert_elliott_bursts() -> None:
    ge = GilbertElliott(p_pct=2.0, r_pct=25.0)
    lost = [not d for d in deliveries(LinkSpec(gemodel=ge), 20_000, seed=3)]
    bursts = burst_lengths(lost)
    assert abs(np.mean(bursts) - 1 / 0.25) < 0.5  # mean burst = 1/r packets
    # stationary loss = p / (p + r) = 0.02 / 0.27
    assert abs(np.mean(lost) - 0.02 / 0.27) < 0.015
    # random loss of the same rate has mean bursts near 1/(1-0.074)
    rnd = [not d for d in deliveries(LinkSpec(loss_pct=7.4), 20_000, seed=3)]
    assert np.mean(burst_lengths(rnd)) < 1.2


def test_gilbert_elliott_good_and_bad_state_loss() -> None:
    # never leaves the good state; 1-k = 10 % loss there
    ge = GilbertElliott(p_pct=0.0, r_pct=100.0, bad_loss_pct=100.0, good_loss_pct=10.0)
    lost = [not d for d in deliveries(LinkSpec(gemodel=ge), 20_000)]
    assert abs(np.mean(lost) - 0.10) < 0.01


# -- rate, queue, serialisation --------------------------------------------------------


def test_serialisation_delay_exact() -> None:
    link = Link(LinkSpec(delay_ms=10.0, rate_bps=12e6), rng())
    # 1500 B at 12 Mbit/s = 1 ms; queue empty -> 1 ms + 10 ms
    assert link.send(0.0, 1500) == [Delivery(0.011)]
    # back to back: the second waits for the first
    assert link.send(0.0, 1500) == [Delivery(0.012)]
    # 100 B at 12 Mbit/s = 66.67 us, after the queue drained
    (d,) = link.send(1.0, 100)
    assert d.time_s == pytest.approx(1.0 + 100 * 8 / 12e6 + 0.010, abs=1e-12)


def test_rate_limiter_throughput_and_drop_tail() -> None:
    rate, limit, size = 8e6, 50, 1000  # 1 ms per packet
    link = Link(LinkSpec(rate_bps=rate, limit_packets=limit), rng())
    # offer 4x the rate for 1 s: 4000 packets, 1 every 0.25 ms
    out = [link.send(i * 0.00025, size) for i in range(4000)]
    delivered = [d[0].time_s for d in out if d]
    # throughput equals the rate: ~1000 packets in the first second (+ the queue)
    assert 1000 <= len(delivered) <= 1000 + limit + 1
    gaps = np.diff(sorted(delivered))
    assert np.allclose(gaps[gaps > 0], size * 8 / rate)
    # the queue never exceeds the limit: the worst queueing delay is limit * 1 ms
    worst = max(d[0].time_s - i * 0.00025 for i, d in enumerate(out) if d)
    assert worst <= limit * size * 8 / rate + 1e-9
    assert link.queue_length <= limit


def test_drop_tail_exact_at_limit() -> None:
    link = Link(LinkSpec(rate_bps=8e3, limit_packets=3), rng())  # 1 s per 1000 B
    results = [link.send(0.0, 1000) for _ in range(5)]
    assert [len(r) for r in results] == [1, 1, 1, 0, 0]
    assert [r[0].time_s for r in results[:3]] == [1.0, 2.0, 3.0]
    assert link.send(1.0, 1000) == [Delivery(4.0)]  # one left at t = 1 s


def test_mahimahi_trace_throughput(tmp_path: Path) -> None:
    # 12 opportunities per 10 ms period -> 12 * 1500 B / 10 ms = 14.4 Mbit/s
    trace = tmp_path / "t.mahi"
    trace.write_text("\n".join(str(t) for t in [1, 2, 2, 3, 4, 5, 5, 6, 7, 8, 9, 10]) + "\n")
    assert list(load_mahimahi_trace(trace))[:3] == [1, 2, 2]
    link = Link(LinkSpec(trace_path=str(trace), limit_packets=100_000), rng())
    times = [link.send(0.0, 1500)[0].time_s for _ in range(1200)]
    assert times[:3] == [0.001, 0.002, 0.002]
    assert times[-1] == pytest.approx(1.0)  # 1200 packets = 100 periods of 10 ms
    # 500 B packets share one opportunity three at a time
    link = Link(LinkSpec(trace_path=str(trace)), rng())
    assert [link.send(0.0, 500)[0].time_s for _ in range(4)] == [0.001] * 3 + [0.002]


def test_mahimahi_trace_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad"
    bad.write_text("1\nx\n")
    with pytest.raises(NetworkConfigError, match="line 2: 'x' is not a millisecond timestamp"):
        Link(LinkSpec(trace_path=str(bad)), rng())
    with pytest.raises(NetworkConfigError, match="cannot read"):
        Link(LinkSpec(trace_path=str(tmp_path / "missing")), rng())


# -- duplicate, corrupt, reorder ---------------------------------------------------------


def test_duplicate_and_corrupt_rates() -> None:
    out = deliveries(LinkSpec(duplicate_pct=10.0, corrupt_pct=5.0), 20_000)
    assert abs(np.mean([len(d) == 2 for d in out]) - 0.10) < 0.007
    assert abs(np.mean([d[0].corrupted for d in out]) - 0.05) < 0.005
    assert not any(d[1].corrupted for d in out if len(d) == 2)  # the clone is intact


def test_reorder_rate_and_gap() -> None:
    spec = LinkSpec(delay_ms=10.0, reorder_pct=25.0)
    out = deliveries(spec, 20_000, spacing_s=0.001)
    early = np.mean([d[0].time_s < i * 0.001 + 0.005 for i, d in enumerate(out)])
    assert abs(early - 0.25) < 0.012
    # gap 5: only every 5th packet may go early, with prob 100 %
    out = deliveries(LinkSpec(delay_ms=10.0, reorder_pct=100.0, reorder_gap=5), 100)
    early_idx = [i for i, d in enumerate(out) if d[0].time_s == pytest.approx(i * 0.001)]
    assert early_idx == list(range(4, 100, 5))


def test_corrupt_flips_one_bit() -> None:
    data = bytes(range(256)) * 4
    g = rng()
    for _ in range(100):
        c = corrupt(data, g)
        diff = np.unpackbits(np.frombuffer(bytes(a ^ b for a, b in zip(data, c)), np.uint8))
        assert len(c) == len(data) and int(diff.sum()) == 1
    assert corrupt(b"", g) == b""


# -- reliable (TCP) mode -----------------------------------------------------------------


def test_reliable_mode_turns_loss_into_rto_delay() -> None:
    link = Link(LinkSpec(delay_ms=10.0, loss_pct=50.0, duplicate_pct=50.0), rng(), rto_s=0.2)
    out = [link.send(i * 1.0, 100, reliable=True) for i in range(200)]
    assert all(len(d) == 1 and not d[0].corrupted for d in out)
    extra = [round(d[0].time_s - i * 1.0, 9) for i, d in enumerate(out)]
    assert set(extra) == {0.01, 0.21}
    assert 70 < extra.count(0.21) < 130


# -- determinism and API contract -------------------------------------------------------


def test_same_seed_same_deliveries() -> None:
    spec = LinkSpec(delay_ms=30, jitter_ms=10, loss_pct=3, duplicate_pct=2, corrupt_pct=1,
                    rate_bps=20e6, limit_packets=20)
    a = deliveries(spec, 3_000, seed=42, spacing_s=0.0002)
    b = deliveries(spec, 3_000, seed=42, spacing_s=0.0002)
    c = deliveries(spec, 3_000, seed=43, spacing_s=0.0002)
    assert a == b and a != c


def test_time_must_not_go_backwards() -> None:
    link = Link(LinkSpec(), rng())
    link.send(1.0, 10)
    link.send(1.0, 10)
    with pytest.raises(ValueError, match=r"now_s=0.5 s is before the previous call's 1.0 s"):
        link.send(0.5, 10)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"delay_ms": -1}, "delay_ms must be >= 0, got -1"),
        ({"loss_pct": 101}, r"loss_pct must be within 0..100 \(percent\), got 101"),
        ({"rate_bps": 0}, "rate_bps must be > 0, got 0"),
        ({"limit_packets": 0}, "limit_packets must be >= 1, got 0"),
        ({"distribution": "cauchy", "jitter_ms": 1}, "distribution must be one of"),
        ({"distribution": "normal"}, "distribution 'normal' needs jitter_ms > 0"),
        ({"reorder_pct": 5}, r"reorder_pct needs delay_ms > 0"),
        ({"loss_pct": 1, "gemodel": GilbertElliott(1)}, "loss_pct and gemodel are exclusive"),
        ({"rate_bps": 1e6, "trace_path": "x"}, "rate_bps and trace_path are exclusive"),
        ({"jitter_ms": float("nan")}, "jitter_ms must be finite"),
    ],
)
def test_linkspec_validation(kwargs: dict, message: str) -> None:
    with pytest.raises(NetworkConfigError, match=message):
        LinkSpec(**kwargs)


def test_profiles() -> None:
    assert get_profile("ideal") == PathSpec()
    assert get_profile("lan").downlink == LinkSpec(delay_ms=20, jitter_ms=10)
    assert get_profile("cloud").uplink == LinkSpec(delay_ms=50, jitter_ms=20)
    assert get_profile("ideal").uplink.is_ideal
    with pytest.raises(NetworkConfigError) as exc:
        get_profile("moon")
    assert str(exc.value) == (
        "unknown network profile 'moon' (valid: cloud, ideal, lan, lte, wifi)"
    )


def test_latency_spike_delays_only_packets_sent_inside_the_window():
    from splitrender.netsim import parse_netem, to_netem

    spec = parse_netem("delay 50ms spike 250ms 1s 1s")
    assert (spec.spike_ms, spec.spike_start_s, spec.spike_duration_s) == (250.0, 1.0, 1.0)
    link = Link(spec, np.random.default_rng(0))
    delays = {t: link.send(t, 1000)[0].time_s - t for t in (0.5, 1.0, 1.5, 1.99, 2.5)}
    assert delays[0.5] == pytest.approx(0.050) and delays[2.5] == pytest.approx(0.050)
    for t in (1.0, 1.5, 1.99):
        assert delays[t] == pytest.approx(0.300), (t, delays[t])
    with pytest.raises(NetworkConfigError, match="cannot be expressed in one tc command"):
        to_netem(spec)
    with pytest.raises(NetworkConfigError, match="'soon' is not a time"):
        parse_netem("spike 250ms soon 1s")


def test_a_lost_tcp_segment_delays_its_own_stream_not_the_datagrams_behind_it() -> None:
    """One path carries the control channel (reliable) and RTP (datagrams): a segment lost and resent after
    the RTO delays the segments after it (TCP is in order) but not a datagram sent after it."""
    import numpy as np

    from splitrender.netsim.models import Link, LinkSpec

    spec = LinkSpec(delay_ms=20.0, loss_pct=100.0)     # every segment is "lost" once: each pays one RTO
    link = Link(spec, np.random.default_rng(0), rto_s=0.2)
    (seg,) = link.send(0.0, 1440, reliable=True)
    (seg2,) = link.send(0.001, 1440, reliable=True)
    assert seg.time_s == pytest.approx(0.22) and seg2.time_s >= seg.time_s
    link2 = Link(LinkSpec(delay_ms=20.0), np.random.default_rng(0), rto_s=0.2)
    link2._lost = lambda: True  # type: ignore[method-assign]  # the segment is lost; the datagram below is not
    (seg,) = link2.send(0.0, 1440, reliable=True)
    link2._lost = lambda: False  # type: ignore[method-assign]
    (dgram,) = link2.send(0.001, 300)
    assert seg.time_s == pytest.approx(0.22) and dgram.time_s == pytest.approx(0.021)
