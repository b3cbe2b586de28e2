"""Rate adaptation: each video stream's encoder rate from the path estimate (sans-IO; issue 35, step 3).

With ``adapt = "rate"`` (``run --adapt rate``, ``serve --adapt rate``) the server core's
:class:`RateController` turns the send-rate estimator's encoder rate
(:meth:`~.gcc.BandwidthEstimator.encoder_bps`: the delay- and loss-based target, less what
drains a standing queue) into a bit rate for every lossy video stream of the session:

1. **What is not under control is paid first.**  Reliable data (metadata, geometry,
   tables), datagram data and lossless video are sent as the method makes them; the
   controller keeps an exponential average of their bits per second (from each frame's
   wire bytes, :meth:`RateController.on_frame_sent`) and leaves the rest to the encoders.
2. **The rest is split by what each stream took.**  A stream's share is the average of its
   own bits over all controlled streams' bits (equal shares until the first frames), so a
   method's atlas and its depth keep the proportion their content gives them.
3. **Each encoder's miss is learnt.**  x264 and x265 under VBV land near, not at, their
   target (a still scene undershoots, a fast one overshoots); the controller averages
   each stream's sent bits over its target and divides the next target by it (held in
   0.5-2), so the session's total follows the estimate rather than the encoders' habits.

4. **No more than the method's own operating point needs.**  For its first
   ``calibrate_frames`` a stream keeps the method's configured rate control (its crf)
   unless the estimate is already below what it sends; what it took then, times
   ``ceiling`` (1 by default), caps its target from then on: adaptation degrades a
   method's operating point where the link cannot carry it, and gives it back when it
   can.  Beyond it, bits buy little (the quality of crf 23 or so) and cost the queue a
   sudden drop in capacity catches: uncapped, a session that probed its way to 15 Mbit/s
   on a 20 Mbit/s link at 320x180 and met a drop to 2 held a 2 s queue (1.5x its own
   rate: 0.9 s; ``benchmarks/bench_adapt.py``).  (libwebrtc caps by resolution, 600 kbit/s up to 320x240; a per-stream
   measure suits atlases, whose size is no measure of their content.)

Targets are per second of the streams' own frame rate.  The encoder side
(:meth:`~.sender.ServerPipeline.encode` with ``rates_kbps``) restarts a stream's encoder
at the new rate when the target moves by more than ``change_ratio``: at the stream's next
IDR when it rises or falls a little (that IDR was due anyway), at once with an IDR when
it falls below ``urgent_ratio`` of the rate the encoder runs at (a queue builds with every
frame sent too fast, and an IDR at the new rate costs less than the queue).

PyAV cannot change a libx264 encoder's rate in place (setting ``bit_rate`` after opening
changes nothing: measured, 2 -> 0.2 Mbit/s left the output at 1.7), hence the restarts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Literal

from ..errors import ConfigError

AdaptMode = Literal["off", "rate"]
ADAPT_MODES: tuple[str, ...] = ("off", "rate")


@dataclass(frozen=True)
class AdaptConfig:
    """The rate controller's settings.

    ``min_kbps`` / ``max_kbps``: bounds of one stream's target; ``smoothing``: weight of the
    newest frame in the averages (overhead, shares, misses); ``change_ratio``: how far a
    target must move from the encoder's rate before the encoder is restarted;
    ``urgent_ratio``: a target under this fraction of the encoder's rate restarts it at once
    (with an IDR) instead of at its next IDR; ``headroom``: the fraction of the estimate the
    session aims to use (what is left absorbs the encoders' frame-to-frame variation);
    ``calibrate_frames``, ``ceiling``: a stream first runs at the method's own rate control
    for this many frames, and its target never exceeds ``ceiling`` times what it took then
    (0 frames: no calibration, no cap but ``max_kbps``).
    """

    min_kbps: float = 50.0
    max_kbps: float = 50_000.0
    smoothing: float = 0.1
    change_ratio: float = 0.15
    urgent_ratio: float = 0.7
    headroom: float = 0.9
    calibrate_frames: int = 30
    ceiling: float = 1.0

    def __post_init__(self) -> None:
        if not 0 < self.min_kbps <= self.max_kbps:
            raise ConfigError(f"AdaptConfig: need 0 < min_kbps <= max_kbps, got {self.min_kbps:g}, {self.max_kbps:g}")
        if not 0 < self.smoothing <= 1:
            raise ConfigError(f"AdaptConfig.smoothing: must be in (0, 1], got {self.smoothing}")
        if not 0 <= self.change_ratio < 1:
            raise ConfigError(f"AdaptConfig.change_ratio: must be in [0, 1), got {self.change_ratio}")
        if not 0 < self.urgent_ratio <= 1:
            raise ConfigError(f"AdaptConfig.urgent_ratio: must be in (0, 1], got {self.urgent_ratio}")
        if not 0 < self.headroom <= 1:
            raise ConfigError(f"AdaptConfig.headroom: must be in (0, 1], got {self.headroom}")
        if not 0 <= self.calibrate_frames <= 10_000:
            raise ConfigError(f"AdaptConfig.calibrate_frames: must be in [0, 10000], got {self.calibrate_frames}")
        if not 1 <= self.ceiling <= 100:
            raise ConfigError(f"AdaptConfig.ceiling: must be in [1, 100], got {self.ceiling}")


def check_adapt_mode(mode: str, where: str) -> str:
    """``mode`` when it names an adaptation mode, else a :class:`ConfigError` naming ``where``."""
    if mode not in ADAPT_MODES:
        raise ConfigError(f"{where} adapt: must be one of {', '.join(ADAPT_MODES)}, got {mode!r:.40}")
    return mode


def retarget(current_kbps: float | None, target_kbps: float, idr_due: bool, cfg: AdaptConfig) -> tuple[bool, bool]:
    """Whether an encoder running at ``current_kbps`` (None: not under rate control yet) should restart at
    ``target_kbps``, and whether that restart must be now with an IDR of its own: ``(restart, urgent)``.
    ``idr_due``: the stream's next frame is an IDR anyway (its GOP ends, or one was asked for)."""
    if current_kbps is None:
        return True, False
    if abs(target_kbps / current_kbps - 1.0) <= cfg.change_ratio:
        return False, False
    if target_kbps < cfg.urgent_ratio * current_kbps:
        return True, True
    return idr_due, False


@dataclass
class RateController:
    """Per-stream encoder targets from the estimator's rate (see the module docstring).

    ``video``: the names of the session's lossy video streams (the controlled ones);
    ``fps``: the server's frame rate (bits per frame to bits per second).
    """

    video: tuple[str, ...]
    fps: float
    cfg: AdaptConfig = field(default_factory=AdaptConfig)

    def __post_init__(self) -> None:
        self.video = tuple(self.video)
        self._overhead_bps: float | None = None
        self._share: dict[str, float] = {n: 1.0 / len(self.video) for n in self.video} if self.video else {}
        self._miss: dict[str, float] = {n: 1.0 for n in self.video}
        self._target: dict[str, float] = {}
        self._seen: dict[str, list[int]] = {n: [] for n in self.video}     # calibration: bytes per frame at the method's own
        self._cap: dict[str, float] = {}                                     # kbit/s, once calibrated
        self._controlled: set[str] = set()
        self.frames = 0

    def _avg(self, old: float | None, new: float) -> float:
        return new if old is None else old + self.cfg.smoothing * (new - old)

    def on_frame_sent(self, wire_bytes: dict[str, int], given_kbps: dict[str, float] | None = None) -> None:
        """One server frame's bytes on the wire per stream (headers included), and the targets its encoders ran at
        (``given_kbps``, the streams under rate control; their misses are learnt from it)."""
        self.frames += 1
        other = sum(b for n, b in wire_bytes.items() if n not in self._share)
        self._overhead_bps = self._avg(self._overhead_bps, other * 8 * self.fps)
        ours = {n: wire_bytes.get(n, 0) for n in self.video}
        for n, b in ours.items():
            seen = self._seen[n]
            if n not in self._cap and self.cfg.calibrate_frames:
                if n in self._controlled:      # the link forced control before calibration ended: cap from what was seen
                    self._cap[n] = self.cfg.ceiling * self._rate_kbps(seen) if seen else self.cfg.max_kbps
                else:
                    seen.append(b)
                    if len(seen) >= self.cfg.calibrate_frames:
                        self._cap[n] = self.cfg.ceiling * self._rate_kbps(seen)
        total = sum(ours.values())
        if total > 0:
            for n, b in ours.items():
                self._share[n] = self._avg(self._share[n], b / total)
        for n, kbps in (given_kbps or {}).items():
            if n in self._miss and kbps > 0:
                sent_kbps = ours.get(n, 0) * 8 * self.fps / 1000
                ratio = min(2.0, max(0.5, sent_kbps / kbps))
                self._miss[n] = self._avg(self._miss[n], ratio)

    def _rate_kbps(self, per_frame: list[int]) -> float:
        return float(sum(per_frame)) / len(per_frame) * 8 * self.fps / 1000

    def targets_kbps(self, encoder_bps: float) -> dict[str, float]:
        """Each controlled stream's encoder target (kbit/s) for an estimated encoder rate of ``encoder_bps``; a stream
        still calibrating is left out (it keeps the method's own rate control) unless the estimate is below what it
        has been sending."""
        if not self.video or not math.isfinite(encoder_bps):
            return {}
        budget = self.cfg.headroom * encoder_bps - (self._overhead_bps or 0.0)
        out = {}
        for n in self.video:
            kbps = min(self.cfg.max_kbps, max(self.cfg.min_kbps, budget * self._share[n] / self._miss[n] / 1000))
            if self.cfg.calibrate_frames and n not in self._cap and n not in self._controlled:
                seen = self._seen[n]
                if len(seen) < min(self.cfg.calibrate_frames, 10) or kbps >= self._rate_kbps(seen):
                    continue       # calibrating, and the link carries what the method sends (or too few frames to tell:
                    #                the first is an IDR, and the estimate starts from a guess)
                self._controlled.add(n)
            self._controlled.add(n)
            out[n] = min(kbps, self._cap.get(n, self.cfg.max_kbps))
        self._target = out
        return dict(out)

    def wanted_bps(self) -> float | None:
        """The most this session would send (every stream at its cap, the overhead beside them, over ``headroom``),
        once every stream is calibrated; None before.  The estimator need not probe past it."""
        if not self.cfg.calibrate_frames or any(n not in self._cap for n in self.video):
            return None
        return (sum(self._cap.values()) * 1000 + (self._overhead_bps or 0.0)) / self.cfg.headroom

    def state(self) -> dict[str, float]:
        """For updates.csv: the overhead the controller pays first and each stream's latest target and learnt miss."""
        out = {"adapt_overhead_kbps": (self._overhead_bps or 0.0) / 1000}
        for n in self.video:     # every key from the first frame (NaN until known): row logs fix their columns then
            out[f"adapt_{n}_kbps"] = self._target.get(n, math.nan)
            out[f"adapt_{n}_cap_kbps"] = self._cap.get(n, math.nan)
            out[f"adapt_{n}_miss"] = self._miss[n]
        return out


def controlled_streams(specs: Iterable[object]) -> tuple[str, ...]:
    """The lossy video streams of a session's stream specs (those with a coded rate to set)."""
    from ..methods.base import StreamSpec

    return tuple(s.name for s in specs if isinstance(s, StreamSpec) and not s.codec.lossless)


def stream_fps(specs: Iterable[object]) -> float:
    """The frame rate the session's video streams are coded at (their codec's ``fps``; 30 without video)."""
    from ..methods.base import StreamSpec

    rates = [float(s.codec.fps) for s in specs if isinstance(s, StreamSpec)]
    return max(rates) if rates else 30.0
