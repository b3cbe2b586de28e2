"""The virtual-time link driver (splitrender.netsim.driver): event order, sends in time order, a TCP stream's
head-of-line blocking, and the two timer rules."""

import math

import numpy as np
import pytest

from splitrender.netsim import Link, LinkSpec
from splitrender.netsim.driver import DELIVER, TIMER, Clock, Timer, Wire


def test_clock_runs_events_by_time_then_priority_then_scheduling():
    clock, seen = Clock(), []
    clock.at(1.0, TIMER, seen.append, "t1-timer")
    clock.at(1.0, DELIVER, seen.append, "t1-deliver-a")
    clock.at(0.5, 3, seen.append, "t0.5")
    clock.at(1.0, DELIVER, seen.append, "t1-deliver-b")
    clock.run()
    assert seen == ["t0.5", "t1-deliver-a", "t1-deliver-b", "t1-timer"]
    assert clock.now == 1.0


def test_datagrams_arrive_after_the_delay_and_a_lost_one_is_not_delivered():
    clock, got = Clock(), []
    wire = Wire(clock, Link(LinkSpec(delay_ms=20.0), np.random.default_rng(1)))
    assert len(wire.datagram(100, lambda: got.append(clock.now))) == 1
    clock.run()
    assert got == [pytest.approx(0.020)]
    lossy = Wire(clock, Link(LinkSpec(loss_pct=100.0), np.random.default_rng(1)))
    assert lossy.datagram(100, got.append, "never") == []
    clock.run()
    assert got == [pytest.approx(0.020)]


def test_a_stream_delivers_each_frame_whole_and_in_order():
    """1 Mbit/s: a 10-segment frame takes 10 x 1500 B x 8 / 1e6 = 120 ms; the 1-segment frame after it arrives after
    it, not before (head-of-line blocking), each once its last segment is in."""
    clock, got = Clock(), []
    wire = Wire(clock, Link(LinkSpec(rate_bps=1e6), np.random.default_rng(1)))
    wire.stream([(b"big", [1500] * 10), (b"small", [100])], lambda data: got.append((data, clock.now)))
    clock.run()
    assert [d for d, _ in got] == [b"big", b"small"]
    assert got[0][1] == pytest.approx(0.120)
    assert got[1][1] >= got[0][1]


def test_sends_keep_time_order_on_the_link():
    """A send scheduled at an earlier time than the wire's last one leaves at the last one (Link.send refuses to go
    back in time)."""
    clock = Clock()
    wire = Wire(clock, Link(LinkSpec(delay_ms=5.0), np.random.default_rng(1)))
    clock.now = 1.0
    wire.datagram(10, lambda: None)
    clock.now = 0.5
    (d,) = wire.datagram(10, lambda: None)
    assert wire.sent_s == 1.0 and d.time_s == pytest.approx(1.005)


@pytest.mark.parametrize("by_deadline", [True, False])
def test_timer_fires_once_at_the_earliest_deadline_within_the_horizon(by_deadline):
    clock, fired = Clock(), []
    timer = Timer(clock, lambda: fired.append(clock.now), horizon_s=2.0, by_deadline=by_deadline)
    timer.arm(1.0)
    timer.arm(0.5)      # earlier: replaces it
    timer.arm(0.8)      # later than the one armed: ignored
    timer.arm(3.0)      # past the horizon
    clock.run()
    assert fired == [0.5] and timer.when == math.inf
    now = clock.now     # 1.0: the replaced arming's event ran the clock on, and did not fire
    timer.arm(-1.0)     # a deadline already past fires now
    clock.run()
    assert fired == [0.5, now] and now == 1.0


def test_the_runner_puts_its_bytes_on_the_links_through_the_driver():
    """Issue 47: the link simulation is netsim's; the virtual-time front door keeps no event heap, no per-link send
    times and no timer slots of its own, and calls no Link.send itself."""
    import inspect

    from splitrender.sim import runner

    src = inspect.getsource(runner)
    assert "heapq" not in src and ".send(" not in src and "sent_s" not in src and "timer_token" not in src
    assert "Wire(" in src and "Timer(" in src and "arrivals(" in src and ".clock.run()" in src
