"""A discrete-event driver for :class:`~splitrender.netsim.models.Link`: the simulated clock, its event queue, and
each link used as a sans-IO session's driver uses a socket.

The virtual-time runner (:mod:`splitrender.sim.runner`) puts its sessions' bytes on the network model through this:

- :class:`Clock`: the simulated clock and its event queue (events at one time in order of priority, then of
  scheduling), run to the end with :meth:`Clock.run`;
- :class:`Wire`: one direction of a path as a driver sends on it: every send at the clock's time, in time order;
  a datagram arrives as the link delivers it (lost, delayed, reordered, duplicated; a corrupted copy is dropped, as
  its checksum would), and a reliable byte stream (TCP) as segments, each frame delivered once all its segments
  are in and after the frames before it (head-of-line blocking);
- :class:`Timer`: the one timer a sans-IO core names (``get_timer``), armed for the earliest deadline it names;
- :func:`arrivals`: when a series of datagrams sent ahead of the run arrives (a tracker's poses).

It knows nothing of what the bytes are; the segment sizes of a stream write come from the caller.
"""

from __future__ import annotations

import heapq
import math
from typing import Any, Callable, Iterable

from splitrender.netsim.models import Delivery, Link

DELIVER, TIMER = 0, 1
"""Priorities of a delivery and of a timer (or a deferred send): deliveries at one time come first; a driver's own
events (ticks) take higher numbers."""


def arrivals(link: Link, times_s: Iterable[float], nbytes: int) -> list[tuple[float, float]]:
    """``(arrival, send time)`` of each uncorrupted copy of a datagram of ``nbytes`` sent on ``link`` at each of
    ``times_s`` (nondecreasing), in order of arrival: a series worked out before the run, since the link's model
    does not depend on what else is sent."""
    out = [(d.time_s, t) for t in times_s for d in link.send(t, nbytes) if not d.corrupted]
    out.sort()
    return out


class Clock:
    """The simulated clock (s) and its events."""

    def __init__(self) -> None:
        self.now = 0.0
        self._events: list[tuple[float, int, int, Callable[..., None], tuple[Any, ...]]] = []
        self._seq = 0

    def at(self, t: float, prio: int, fn: Callable[..., None], *args: Any) -> None:
        """Call ``fn(*args)`` at ``t`` (after the events at ``t`` of lower ``prio``, and those scheduled before)."""
        self._seq += 1
        heapq.heappush(self._events, (t, prio, self._seq, fn, args))

    def run(self) -> None:
        """Run the events in order until none is left."""
        while self._events:
            t, _, _, fn, args = heapq.heappop(self._events)
            self.now = t
            fn(*args)


class Wire:
    """One direction of a path (its :class:`Link`) on ``clock``: sends leave at the clock's time, in time order."""

    def __init__(self, clock: Clock, link: Link) -> None:
        self.clock, self.link = clock, link
        self.sent_s = -math.inf
        """The last send time (a link takes sends in time order)."""
        self.stream_free_s = -math.inf
        """When the stream's last frame arrived (a frame is delivered after the frames before it)."""

    def _send_time(self) -> float:
        self.sent_s = t = max(self.clock.now, self.sent_s)
        return t

    def datagram(self, nbytes: int, deliver: Callable[..., None], *args: Any) -> list[Delivery]:
        """Send a datagram of ``nbytes`` on the wire now; ``deliver(*args)`` runs at each uncorrupted delivery.
        Returns the link's deliveries (``[]``: lost)."""
        deliveries = self.link.send(self._send_time(), nbytes)
        for d in deliveries:
            if not d.corrupted:
                self.clock.at(d.time_s, DELIVER, deliver, *args)
        return deliveries

    def stream(self, frames: Iterable[tuple[bytes, list[int]]], deliver: Callable[..., None], *args: Any) -> None:
        """Write ``frames`` (each its bytes and the wire sizes of the TCP segments carrying it) on a reliable stream
        now; ``deliver(*args, data)`` runs when a frame's last segment is in and the frames before it are."""
        t = self._send_time()
        for data, segments in frames:
            arrive = t
            for seg in segments:
                arrive = max(arrive, self.link.send(t, seg, reliable=True)[0].time_s)
            self.stream_free_s = arrive = max(arrive, self.stream_free_s)
            self.clock.at(arrive, DELIVER, deliver, *args, data)


class Timer:
    """The one timer of a sans-IO core on ``clock``: :meth:`arm` with the deadline the core names; ``fire()`` runs at
    the earliest one armed, not past ``horizon_s``.

    ``by_deadline``: a pending event fires if its deadline is still the one armed (else only the latest arming's
    event fires); the server core's timer and the client core's have kept their own rule, so that a run's events keep
    their order."""

    def __init__(self, clock: Clock, fire: Callable[[], None], horizon_s: float, *, by_deadline: bool) -> None:
        self.clock, self.fire, self.horizon_s, self.by_deadline = clock, fire, horizon_s, by_deadline
        self.when = math.inf
        """The deadline armed (s; ``inf``: none)."""
        self._token = 0

    def arm(self, deadline_s: float) -> None:
        """Arm for ``deadline_s`` (at the earliest now), unless an earlier deadline is armed or it is past the
        horizon."""
        now = self.clock.now
        if self.by_deadline:
            deadline_s = max(deadline_s, now)
        if deadline_s < self.when and deadline_s <= self.horizon_s:
            self.when = max(deadline_s, now)
            self._token += 1
            self.clock.at(self.when, TIMER, self._due, self.when if self.by_deadline else self._token)

    def _due(self, key: float) -> None:
        if key != (self.when if self.by_deadline else self._token):   # a later arming replaced this one
            return
        self.when = math.inf
        self.fire()
