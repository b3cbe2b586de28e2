"""Feedback, both ends (sans-IO): what the client applied and lost, and the latency estimate.

The client's :class:`FeedbackTracker` records, per stream, the newest frame the client
half applied and the frames that will never arrive; each ``Feedback`` message carries
what changed since the previous one.  The server's :class:`FeedbackState` merges every
``Feedback`` that has reached it and hands the server half a
:class:`~splitrender.methods.base.ClientFeedback` before each update; its
:class:`LatencyEstimator` turns (server time, display time) pairs into the expected
latency that aims the pose prediction.  The virtual-time runner and the live server
use these same classes, so both aim their predictions from what they measure.

The server's state is bounded whatever a client sends: a ``Feedback`` naming a stream the
session did not declare is the client's protocol error (:class:`MessageError` naming the
stream), and per stream at most ``4 x MAX_FRAMES_REMEMBERED`` lost frame ids are kept
(and as many reported to the server half between two updates).
"""

from __future__ import annotations

from collections.abc import Collection

from ..methods.base import ClientFeedback
from ..protocol import Feedback
from ..protocol.errors import MessageError

DEFAULT_DECODE_MS = 5.0
"""Client decode time assumed before feedback arrives, ms."""
LATENCY_EMA = 0.1
"""Weight of each new sample in the expected-latency estimate (the first sample is taken whole)."""
MAX_EXPECTED_LATENCY_S = 1.0
INITIAL_NETWORK_S = 0.02
"""One-way network delay assumed before any feedback, s."""
MAX_FRAMES_REMEMBERED = 512
"""Frames whose send time the server keeps (for latency); lost ids kept per stream: four times as many."""


class LatencyEstimator:
    """Expected time from the start of a server frame to its display, s (EMA of measurements)."""

    def __init__(self, display_hz: float) -> None:
        self.value_s = INITIAL_NETWORK_S + DEFAULT_DECODE_MS / 1000 + 0.5 / display_hz
        self.samples = 0

    def observe(self, latency_s: float) -> None:
        if not 0.0 <= latency_s <= MAX_EXPECTED_LATENCY_S:
            return
        if self.samples == 0:
            self.value_s = latency_s
        else:
            self.value_s += LATENCY_EMA * (latency_s - self.value_s)
        self.samples += 1


class FeedbackState:
    """The server's merged view of a client's feedback; see the module docstring."""

    def __init__(self, display_hz: float, streams: Collection[str] | None = None) -> None:
        self.latency = LatencyEstimator(display_hz)
        self.streams = frozenset(streams) if streams is not None else None
        """The session's stream names (None: any, for a bare state in tests); Feedback naming others is refused."""
        self._fb = ClientFeedback()
        self._lost_since: dict[str, list[int]] = {}
        self._sent_us: dict[int, int] = {}
        self.reports = 0

    def frame_sent(self, frame_id: int, server_time_us: int) -> None:
        """Remember when frame ``frame_id`` started, for the latency measurement."""
        self._sent_us[frame_id] = server_time_us
        if len(self._sent_us) > MAX_FRAMES_REMEMBERED:
            for k in list(self._sent_us)[: len(self._sent_us) - MAX_FRAMES_REMEMBERED]:
                del self._sent_us[k]

    def server_time_us(self, frame_id: int) -> int | None:
        return self._sent_us.get(frame_id)

    def on_feedback(self, fb: Feedback) -> float | None:
        """Merge one ``Feedback``; returns the measured latency (s) when the frame is known."""
        if self.streams is not None:
            for where, names in (("applied", fb.applied), ("lost", fb.lost)):
                for name in names:
                    if name not in self.streams:
                        raise MessageError(f"Feedback.{where}: stream {name!r} is not one of this session's "
                                           f"{sorted(self.streams)}")
        self.reports += 1
        f = self._fb
        for name, fid in fb.applied.items():
            if fid > f.applied.get(name, -1):
                f.applied[name] = fid
            f.last_applied_frame = max(f.last_applied_frame, fid)
        f.last_applied_frame = max(f.last_applied_frame, fb.frame_id)
        frames_lost: set[int] = set()
        for name, ids in fb.lost.items():
            seen = f.lost.setdefault(name, set())
            new = [i for i in ids if i not in seen]
            seen.update(new)
            if len(seen) > 4 * MAX_FRAMES_REMEMBERED:
                for old in sorted(seen)[: len(seen) - 4 * MAX_FRAMES_REMEMBERED]:
                    seen.discard(old)
            since = self._lost_since.setdefault(name, [])
            since.extend(new)
            if len(since) > 4 * MAX_FRAMES_REMEMBERED:
                del since[: len(since) - 4 * MAX_FRAMES_REMEMBERED]
            frames_lost.update(new)
        f.lost_frames += len(frames_lost)
        t_us = self._sent_us.get(fb.frame_id)
        if t_us is None:
            return None
        lat = (fb.displayed_us - t_us) / 1e6
        self.latency.observe(lat)
        return lat

    def snapshot(self, keyframe_requested: bool) -> ClientFeedback:
        """The feedback a server half sees for its next update; clears ``lost_since``."""
        f = self._fb
        out = ClientFeedback(f.last_applied_frame, keyframe_requested, f.lost_frames, dict(f.applied),
                             {k: set(v) for k, v in f.lost.items()},
                             {k: tuple(v) for k, v in self._lost_since.items() if v})
        self._lost_since.clear()
        return out


class FeedbackTracker:
    """The client's side: applied and lost frames per stream since the last report."""

    def __init__(self) -> None:
        self.applied: dict[str, int] = {}
        self._lost: dict[str, list[int]] = {}
        self.lost_total = 0

    def on_applied(self, frame_id: int, present: list[str]) -> None:
        for name in present:
            self.applied[name] = max(self.applied.get(name, -1), frame_id)

    def on_lost(self, frame_id: int, streams: list[str]) -> None:
        for name in streams:
            self._lost.setdefault(name, []).append(frame_id)
        self.lost_total += 1

    def take(self) -> tuple[dict[str, int], dict[str, tuple[int, ...]]]:
        """(applied, lost since the previous call) for the next ``Feedback``."""
        from ..protocol.messages import MAX_LOST_REPORTED

        lost = {k: tuple(v[-MAX_LOST_REPORTED:]) for k, v in self._lost.items() if v}
        self._lost.clear()
        return dict(self.applied), lost
