"""Rate adaptation: encoder rates and the method's operating point from the path estimate (sans-IO; issue 35).

With ``adapt = "rate"`` (``run --adapt rate``, ``serve --adapt rate``) the server core's
:class:`RateController` turns the send-rate estimator's encoder rate
(:meth:`~.gcc.BandwidthEstimator.encoder_bps`: the delay- and loss-based target, less what
drains a standing queue) into a bit rate for every lossy video stream of the session:

1. **What is not under control is paid first.**  Reliable data (metadata, geometry,
   tables), datagram data and lossless video are sent as the method makes them; the
   controller keeps an exponential average of their bits per second (from each frame's
   wire bytes, :meth:`RateController.on_frame_sent`) and leaves the rest to the encoders.
   What the encoders are left counts each frame's data at no more than the estimate: a burst
   beyond it (a session's first fill) is a queue, which the estimator's encoder rate already
   drains, and counted whole the average charges it again for as long as it remembers it (sas
   sends 53 kB of tables and geometry with its first frame, 12.8 Mbit/s in a frame's terms:
   on an 8 Mbit/s link its atlas sat at the 50 kbit/s floor for its first 0.6 s).  The
   operating point (:class:`PointController`) learns a point's data rate whole.
2. **The rest is split by what each stream took.**  A stream's share is the average of its
   own bits over all controlled streams' bits (equal shares until the first frames), so a
   method's atlas and its depth keep the proportion their content gives them.
3. **Each encoder's miss is learnt.**  x264 and x265 under VBV land near, not at, their
   target (a still scene undershoots, a fast one overshoots); the controller averages
   each stream's sent bits over its target and divides the next target by it (held in
   0.5-2), so the session's total follows the estimate rather than the encoders' habits.

4. **No more than the method's own operating point needs.**  A stream first keeps the
   method's configured rate control (its crf) under a ceiling at its share of the
   estimate (:class:`CappedCrf`: x264/x265 in crf with a VBV cap), so a start below the
   link's rate queues nothing (the estimator starts low, as WebRTC does); once it has
   sent ``calibrate_frames`` frames, what those took, times ``ceiling`` (1 by default),
   caps its target from then on.  Where their P-frames took ``BOUND`` of the ceiling or
   more, the ceiling shaped them, not the crf: the link is narrower than the method's
   rate, and the cap is provisional, dropped for a new calibration once the stream's
   share is ``RECALIBRATE`` times it: adaptation degrades a
   method's operating point where the link cannot carry it, and gives it back when it
   can.  Beyond it, bits buy little (the quality of crf 23 or so) and cost the queue a
   sudden drop in capacity catches: uncapped, a session that probed its way to 15 Mbit/s
   on a 20 Mbit/s link at 320x180 and met a drop to 2 held a 2 s queue (1.5x its own
   rate: 0.9 s; ``benchmarks/bench_adapt.py``).  (libwebrtc caps by resolution, 600 kbit/s up to 320x240; a per-stream
   measure suits atlases, whose size is no measure of their content.)  The cap is a mean, though, and a target at it
   spends it evenly: where the stream's share is ``WIDE`` times the cap or more, the stream runs at the method's crf
   again under a ceiling at its share (until the share falls under the cap), so its I-frames and a scene that grows
   past what its calibration saw get their bits, as with ``adapt = "off"``, and the link bounds only the bursts.
   A method that tolerates a queue (:attr:`RateController.buffer_ms` set) never runs at a target: under the cap its
   crf runs under a ceiling at the target (``BURST_CAP``), so the stream never changes rate mode, each change a new
   encoder and an IDR.

Targets are per second of the streams' own frame rate.  The encoder side
(:meth:`~.sender.StreamEncoder.encode` with ``rates_kbps``) restarts a stream's encoder
at the new rate when the target moves by more than ``change_ratio``: at the stream's next
IDR when it rises or falls a little (that IDR was due anyway), at once with an IDR when
it falls below ``urgent_ratio`` of the rate the encoder runs at (a queue builds with every
frame sent too fast, and an IDR at the new rate costs less than the queue), but a calibrating stream's ceiling is held
just above that threshold through a fall shorter than ``DIP_FRAMES`` (a blip of queue is not worth an IDR down and
another back up).

With ``adapt = "full"`` a :class:`PointController` chooses the method's operating point as well (its knobs: the
resolution of its scalable colour, its atlas budget, depth bits and samples, layers, the server's frame rate; see
:meth:`~splitrender.methods.base.MethodConfig.adapt_knobs`), and this controller's caps follow the point
(:attr:`RateController.factor`).

PyAV cannot change a libx264 encoder's rate in place (setting ``bit_rate`` after opening
changes nothing: measured, 2 -> 0.2 Mbit/s left the output at 1.7), hence the restarts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Collection, Iterable

from ..errors import ConfigError

ADAPT_MODES: tuple[str, ...] = ("off", "rate", "full")
BURST_CAP = True
"""A calibrated stream whose encoder has a buffer longer than two frames (:attr:`RateController.buffer_ms`: a method
that tolerates a queue) runs at the method's crf under a ceiling at its target (:class:`CappedCrf`), never at a bit
rate.  Its bit-rate mode squeezed each IDR into two frames' worth and ran at 0.7-0.85x its target after a restart,
and a stream whose cap the link had set (provisional) swapped between the two modes every 10-20 frames, each swap a
new encoder and an IDR: tss on the 8 Mbit/s cellular-like trace coded 9 atlas IDRs in its first 52 frames (2.5 s),
those in bit-rate mode 14-26 kB where its crf takes 80 kB; its atlas, still for most of its texels, kept each
IDR's picture until the next, and at 0.75-1 s it scored 24.0 dB against ``adapt = "off"``'s 28.1 while sending
4.2 Mbit/s against 3.8 (5b2d51d).  Under a ceiling the crf sends less where the picture allows, and a ceiling's
change is a restart at the next IDR (or an urgent one), not a change of mode."""
BOUND = 0.5
"""Calibrating P-frames whose rate reached this fraction of their encoders' ceilings were shaped by the ceiling, not
by the method's crf: the cap they give is provisional."""
SHAPED_FRAMES = 10
"""Frames after which a calibration whose ceiling has shaped the stream ends with a provisional cap (a whole one,
``calibrate_frames``, for a cap of the method's own)."""
CEILING_JUMP = 2.0
"""A calibrating stream's encoder restarts at once, with an IDR, when its ceiling rises this many times over (a
target's rise waits for the next IDR): at start the estimate climbs from 300 kbit/s by probing within a few round
trips, and a stream held at the start's ceiling until its GOP ends would spend its first second below its own
picture."""
WIDE = 1.5
"""A calibrated stream whose share of the estimate is this many times its cap (at the operating point) runs at the
method's own crf under a ceiling at that share (:class:`CappedCrf`) instead of a target at its cap, until the share
falls back under the cap: where the link carries well more than the method's mean rate, the content decides each
picture's bits (its I-frames several times a P-frame's), as with ``adapt = "off"``, and the link only bounds the
bursts.  A target at the calibrated mean spends the same bits evenly: it squeezes each I-frame into a VBV buffer of
two mean frames, and a scene that grows past what its calibration saw stays at the old mean."""
DIP_FRAMES = 4
"""A calibrating stream's ceiling that falls under ``urgent_ratio`` of what it was (an urgent restart, with an I-frame)
is held just above that for this many frames less one first: a blip of queue (the encoder rate drains a 51 ms one for
0.1 s) is not worth an I-frame down and another back up (CEILING_JUMP); a fall at a move of the operating point is
not held (the controller's decision).  Not for a calibrated stream (75e4ada held those too, for a queue-tolerant
method): on the step trace ``quads`` kept its ceilings through the 2 Mbit/s span's falls, queued, and its estimate came
back slower, 0.33 dB under (8 s, 13c0e9e against cc91518), with no gain for ``tss`` on ``cellular8``."""
START_HOLD = True
"""Before the estimator's first measurement (its encoder rate still the first it gave: GCC's start guess, 300 kbit/s)
a calibrating stream of a method that tolerates a queue keeps at least the start's share of it: the first frames'
data (tss's geometry, 17 kB in its first frame), paid first against a guess, left its atlas the 50 kbit/s floor at
0.13 s and cost an IDR coded at it, 0.07 s before the start probes' result lifted the ceiling six times over."""
START_BOOST = True
"""A method that tolerates a queue, whose estimator sends start-up probes past GCC's own (its quality model's
``estimator``: sas and tss, 3x to 24x the 300 kbit/s guess, back to back at 0 s) and whose model asks for it
(``start_boost``: tss; sas, unmeasured, keeps the guess's share) codes its first frames under a
ceiling at its share of the highest of them (:attr:`RateController.start_boost`), not of the guess: the probes' result
comes back only after they have all been sent (0.2-0.3 s), and tss on the 8 Mbit/s cellular-like trace coded its first
atlas IDR in 2.9 kB under a 270 kbit/s ceiling and the next at 0.2 s under 1.2 Mbit/s (model PSNR 7-14 dB for its
first 0.27 s, 17.1 dB over the first half second against ``adapt = "off"``'s 22.0)."""
UP_ROOM = True
"""The point controller takes a method's ``up_room`` (its quality model's): off, every step up waits the up hold."""
TRACK_BOUND = 0.8
"""A stream whose average rate stays under this share of its ceilings' average is at its crf's rate, not the
ceiling's (:attr:`RateController.track_cap`): tss under a 5.8 Mbit/s ceiling at one frame in 2 sent 3.0-3.8 (0.5-0.65
of it; ``BOUND``'s 0.5, calibration's test of a window's P-frames alone, read it as shaped)."""
RECALIBRATE = 1.5
"""A cap the link set (a stream whose ceiling kept binding through its calibration) is dropped, and the stream
calibrated again, once its share of the estimate is this many times the cap."""


class CappedCrf(float):
    """A calibrating stream's rate (kbit/s) as a ceiling, not a target: its encoder keeps the method's crf under a
    VBV cap at this rate (``VideoCodecConfig.cap_kbps``), with a buffer of ``buffer_ms`` of it where that is over two
    frames (``VideoCodecConfig.cap_buffer_ms``; :attr:`RateController.buffer_ms`).  The other rates a
    :class:`RateController` gives are targets (the encoder runs at that bit rate)."""

    buffer_ms: float | None

    def __new__(cls, kbps: float, buffer_ms: float | None = None) -> "CappedCrf":
        out = super().__new__(cls, kbps)
        out.buffer_ms = buffer_ms
        return out

    def scaled(self, k: float) -> "CappedCrf":
        return CappedCrf(self * k, self.buffer_ms)


def scale_rate(v: float, k: float) -> float:
    """``v * k``, a :class:`CappedCrf` staying one."""
    return v.scaled(k) if isinstance(v, CappedCrf) else v * k


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
    stretch: float = 1.5
    up_margin: float = 0.85
    up_hold_s: float = 1.0
    down_hold_s: float = 0.5
    mtp_budget_ms: float = 100.0
    settle_frames: int = 10

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
        if not 1 <= self.stretch <= 10:
            raise ConfigError(f"AdaptConfig.stretch: must be in [1, 10], got {self.stretch}")
        if not 0 < self.up_margin <= 1:
            raise ConfigError(f"AdaptConfig.up_margin: must be in (0, 1], got {self.up_margin}")
        for k in ("up_hold_s", "down_hold_s"):
            if not 0 <= getattr(self, k) <= 60:
                raise ConfigError(f"AdaptConfig.{k}: must be in [0, 60] s, got {getattr(self, k)}")
        if not 1 <= self.mtp_budget_ms <= 10_000:
            raise ConfigError(f"AdaptConfig.mtp_budget_ms: must be in [1, 10000], got {self.mtp_budget_ms}")
        if not 1 <= self.settle_frames <= 1000:
            raise ConfigError(f"AdaptConfig.settle_frames: must be in [1, 1000], got {self.settle_frames}")


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
        self._paid_bps: float | None = None     # the same, each frame counted at no more than the estimate
        self._estimate_bps: float | None = None  # the encoder rate of the latest targets_kbps
        self._share: dict[str, float] = {n: 1.0 / len(self.video) for n in self.video} if self.video else {}
        self._miss: dict[str, float] = {n: 1.0 for n in self.video}
        self._target: dict[str, float] = {}
        self._seen: dict[str, list[float]] = {n: [] for n in self.video}   # calibration: kbit/s at the method's own
        self._cap: dict[str, float] = {}                                     # kbit/s, once calibrated
        self._ceilings: dict[str, list[float]] = {n: [] for n in self.video}  # calibration: the ceiling of each frame
        self._p_frames: dict[str, list[int]] = {n: [] for n in self.video}    # calibration: bytes of its P-frames
        self._provisional: set[str] = set()                                  # caps the link set, not the method
        self._calibrating: set[str] = set(self.video) if self.cfg.calibrate_frames else set()
        self._track: dict[str, tuple[float, float]] = {}                     # track_cap: (rate, ceiling) averages
        self._wide: set[str] = set()                                         # at the crf under a ceiling (WIDE)
        self._dip: dict[str, int] = {}                                       # calibrating: frames its ceiling fell
        self._dip_ref: dict[str, float] = {}                                 # ... and the ceiling before the fall
        self._target_factor = 1.0                                            # self.factor at the latest targets
        self._first_bps: float | None = None                                 # the estimator's first encoder rate
        self._boosted = False                                                # the latest ceilings were start_boost's
        self._left_start = False                                             # ... and these are the first after them
        self.last_overhead_bps = 0.0
        """The newest frame's bits of what the encoders do not control, per second of frames (not averaged)."""
        self.factor = 1.0
        """What the operating point (:class:`PointController`) lets the encoders take, as a fraction of what they
        took at the method's own point: each calibrated cap is multiplied by it."""
        self.frames = 0
        self.start_boost = 1.0
        """Before the estimator's first measurement (``START_HOLD``), a calibrating stream of a method that tolerates a
        queue keeps at least its share of this many times the start's guess: the highest of the start-up probes its
        estimator sends at once (:attr:`~splitrender.methods.base.QualityModel.estimator`'s ``start_probes``;
        :class:`PointController` sets it), what the link is being asked to carry anyway (1: the guess alone)."""
        self.track_cap = False
        """After a stream's calibration its cap follows what it sends: an average of each frame's rate at the method's
        own point (as calibration counts it; weight 1 / ``calibrate_frames``), taken as the cap while it stays under
        ``TRACK_BOUND`` of the same average of its ceilings (the crf's rate, not the link's): what the method sends follows
        its content (tss's camera speed), and a cap measured once in one window prices its own point for the rest of
        the session (the method's quality model's ``track_cap``; :class:`PointController` sets it)."""
        self.buffer_ms: float | None = None
        """The VBV buffer (ms of the ceiling) a :class:`CappedCrf` gives its encoder, where longer than two frames
        (None: two frames): the queue a method tolerates past video's (:class:`PointController` sets it from the
        method's quality model).  A two-frame buffer squeezes each I-frame, and the start's, to two frames' worth of
        the ceiling: sas's first atlas IDRs took 1-24 kB under the start's ceilings where its crf takes 90 kB, and
        its model PSNR stayed 3-6 dB under ``adapt = "off"``'s for its first second on the 8 Mbit/s cellular-like
        trace."""

    def _avg(self, old: float | None, new: float) -> float:
        return new if old is None else old + self.cfg.smoothing * (new - old)

    def on_frame_sent(self, wire_bytes: dict[str, int], given_kbps: dict[str, float] | None = None,
                      idr_streams: Collection[str] | None = None) -> None:
        """One server frame's bytes on the wire per stream (headers included), the rates its encoders ran at
        (``given_kbps``: targets, whose misses are learnt, and :class:`CappedCrf` ceilings) and the streams that
        sent an IDR (large by nature: an IDR never counts as shaped by a ceiling, and a calibration window opens at
        one; None where the caller does not know: a window opens at any frame)."""
        self.frames += 1
        other = sum(b for n, b in wire_bytes.items() if n not in self._share)
        self.last_overhead_bps = other * 8 * self.fps
        self._overhead_bps = self._avg(self._overhead_bps, other * 8 * self.fps)
        est = self._estimate_bps
        self._paid_bps = self._avg(self._paid_bps, other * 8 * self.fps if est is None else min(other * 8 * self.fps, est))
        ours = {n: wire_bytes.get(n, 0) for n in self.video}
        for n, b in ours.items():
            seen = self._seen[n]
            keyframe = None if idr_streams is None else n in idr_streams
            if n in self._calibrating and (seen or keyframe is not False):   # a window opens at an IDR: one a GOP
                # at the method's own point: a frame sent at a coarser operating point (the point controller moves
                # once a provisional cap is known) took that point's share of it, per second of that point's frames
                # (frame_div: at one frame in 2 a frame's bytes are a 15th of a second's, and a window across two
                # points counted in one rate put tss's own point at 15 Mbit/s, 2.4x its 6.3, on cellular8)
                seen.append(b * 8 * self.fps / 1000 / max(self.factor, 1e-3))
                ceiling = (given_kbps or {}).get(n)
                if ceiling is not None:
                    self._ceilings[n].append(float(ceiling))
                if not keyframe:
                    self._p_frames[n].append(b)
                ceilings, p = self._ceilings[n], self._p_frames[n]
                # the ceiling shaped the stream, not its crf: the link is narrower than the method's own rate, and
                # what it carried is a provisional cap (calibrated again in targets_kbps once it widens), known as
                # soon as SHAPED_FRAMES show it, so the operating point need not wait for a whole calibration
                shaped = bool(ceilings and p and self._rate_kbps(p) >= BOUND * sum(ceilings) / len(ceilings))
                if len(seen) >= self.cfg.calibrate_frames or (shaped and len(seen) >= SHAPED_FRAMES):
                    self._cap[n] = self.cfg.ceiling * sum(seen) / len(seen)
                    (self._provisional.add if shaped else self._provisional.discard)(n)
                    self._track.pop(n, None)
                    self._calibrating.discard(n)
                    for buf in (seen, ceilings, p):
                        buf.clear()
            elif self.track_cap and n in self._cap and n not in self._provisional:
                ceiling = (given_kbps or {}).get(n)
                if ceiling is not None:        # both at the method's own point, as calibration counts them
                    f = max(self.factor, 1e-3)
                    r, c = b * 8 * self.fps / 1000 / f, float(ceiling) / f
                    r0, c0 = self._track.get(n, (self._cap[n], c))
                    w = 1.0 / max(self.cfg.calibrate_frames, 1)
                    self._track[n] = (r0 + w * (r - r0), c0 + w * (c - c0))
                    if self._track[n][0] < TRACK_BOUND * self._track[n][1]:   # the crf's rate, not the ceiling's
                        self._cap[n] = self._track[n][0]
        total = sum(ours.values())
        if total > 0:
            for n, b in ours.items():
                self._share[n] = self._avg(self._share[n], b / total)
        for n, kbps in (given_kbps or {}).items():
            if n in self._miss and kbps > 0 and not isinstance(kbps, CappedCrf):   # a ceiling is no target to miss
                sent_kbps = ours.get(n, 0) * 8 * self.fps / 1000
                ratio = min(2.0, max(0.5, sent_kbps / kbps))
                self._miss[n] = self._avg(self._miss[n], ratio)

    def _held(self, n: str, kbps: float) -> float:
        """Stream ``n``'s ceiling ``kbps``, held just over ``urgent_ratio`` of the one before through a fall shorter
        than ``DIP_FRAMES`` (no restart, no I-frame, for a blip)."""
        ref = self._dip_ref.get(n, self._target.get(n))
        # the operating point moved, or the start's boosted ceiling met the first measurement: a decision, not a blip
        moved = self._target_factor != self.factor or self._left_start
        if isinstance(ref, CappedCrf) and kbps < self.cfg.urgent_ratio * ref and not moved:
            self._dip[n] = self._dip.get(n, 0) + 1
            self._dip_ref[n] = ref
            if self._dip[n] < DIP_FRAMES:     # a blip: held at the restart's threshold, no I-frame for it
                return 1.001 * self.cfg.urgent_ratio * ref
        else:
            self._dip.pop(n, None)
            self._dip_ref.pop(n, None)
        return kbps

    def _rate_kbps(self, per_frame: list[float] | list[int]) -> float:
        return float(sum(per_frame)) / len(per_frame) * 8 * self.fps / 1000

    def targets_kbps(self, encoder_bps: float) -> dict[str, float]:
        """Each lossy video stream's encoder rate (kbit/s) for an estimated encoder rate of ``encoder_bps``: a target
        for a calibrated stream, a :class:`CappedCrf` ceiling for one still calibrating (the method's crf under it)."""
        if not self.video or not math.isfinite(encoder_bps):
            return {}
        self._estimate_bps = encoder_bps
        if self._first_bps is None:
            self._first_bps = encoder_bps
        budget = self.cfg.headroom * encoder_bps - (self._paid_bps or 0.0)
        tolerant = self.buffer_ms is not None          # a method that tolerates a queue
        start = START_HOLD and tolerant and encoder_bps == self._first_bps   # no measurement yet: the start's guess
        self._left_start, self._boosted = self._boosted and not start, start and self.start_boost > 1.0
        out: dict[str, float] = {}
        for n in self.video:
            kbps = min(self.cfg.max_kbps, max(self.cfg.min_kbps, budget * self._share[n] / self._miss[n] / 1000))
            wider = kbps > RECALIBRATE * self._cap.get(n, math.inf) * self.factor
            if n in self._provisional and n not in self._calibrating and wider:
                self._calibrating.add(n)   # the link now carries well more than it did: learn the method's own rate
                #                            (the provisional cap stands for the operating point meanwhile)
            if n in self._calibrating:
                if start:       # the first fill's data is not paid against a guess (START_HOLD)
                    kbps = max(kbps, self.cfg.headroom * encoder_bps * self.start_boost * self._share[n]
                               / self._miss[n] / 1000)
                out[n] = CappedCrf(self._held(n, kbps), self.buffer_ms)
                continue
            # a provisional cap is the link's, not the method's: it caps nothing
            cap = self.cfg.max_kbps if n in self._provisional else self._cap.get(n, self.cfg.max_kbps)
            if n not in self._provisional and kbps >= (1.0 if n in self._wide else WIDE) * cap * self.factor:
                self._wide.add(n)              # room to spare: the method's own crf, the link bounding its bursts
                out[n] = CappedCrf(kbps, self.buffer_ms)
                continue
            self._wide.discard(n)
            target = max(self.cfg.min_kbps, min(kbps, cap * self.factor))
            if BURST_CAP and self.buffer_ms is not None:
                # a method that tolerates a queue: its crf under a ceiling at the target (BURST_CAP), not a bit rate
                out[n] = CappedCrf(target, self.buffer_ms)
                continue
            out[n] = target
        self._target = out
        self._target_factor = self.factor
        return dict(out)

    @property
    def calibrated(self) -> bool:
        """Every controlled stream has its cap (or there is none to calibrate)."""
        return not self.cfg.calibrate_frames or all(n in self._cap for n in self.video)

    def natural_video_bps(self) -> float:
        """What the controlled streams take at the method's own operating point (their caps; 0 before calibrated)."""
        return sum(self._cap.get(n, 0.0) for n in self.video) * 1000

    @property
    def overhead_bps(self) -> float:
        """The average rate of what the encoders do not control (reliable data, geometry, lossless video)."""
        return self._overhead_bps or 0.0

    def wanted_bps(self) -> float | None:
        """The most this session would use (every stream at ``WIDE`` times its cap, where it takes its crf again, the
        overhead beside them, over ``headroom``), once every stream is calibrated by its own rate; None before, or
        while a cap is the link's (provisional).  The estimator need not probe past it."""
        if not self.cfg.calibrate_frames or not self.calibrated or self._provisional:
            return None
        return (WIDE * self.natural_video_bps() + self.overhead_bps) / self.cfg.headroom

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


def knobs_model(knobs: Iterable[Any]) -> Any:
    """The method's quality model its knobs carry (:class:`~splitrender.methods.base.QualityModel`; the first knob
    that has one), or None."""
    return next((k.model for k in knobs if getattr(k, "model", None) is not None), None)


def build_ladder(knobs: tuple[Any, ...]) -> list[tuple[int, ...]]:
    """The operating points, richest first: from every knob at its first level, each step lowers the next knob (in
    declaration order, round robin) that has a level left, so no knob is spent before the others are touched; knobs
    of a higher ``order`` only once every knob of a lower one is at its last level."""
    point = [0] * len(knobs)
    out = [tuple(point)]
    for order in sorted({getattr(k, "order", 0) for k in knobs}):
        group = [i for i, k in enumerate(knobs) if getattr(k, "order", 0) == order]
        moved = True
        while moved:
            moved = False
            for k in group:
                if point[k] + 1 < len(knobs[k].levels):
                    point[k] += 1
                    out.append(tuple(point))
                    moved = True
    return out


def quality_ladder(knobs: tuple[Any, ...], model: Any) -> list[tuple[int, ...]]:
    """The operating points, richest first, by what a quality model says each step costs: from every knob at its
    first level, each step lowers the knob whose next level loses the fewest dB per bit saved (the model's dB over
    the log of the knob's cost ratio; a level that measured better than the one before it, or than the first, loses 0;
    a knob the model
    does not know only once the known ones are spent, ties in declaration order).  Every knob only ever falls along
    the ladder, as in :func:`build_ladder`."""
    point = [0] * len(knobs)
    out = [tuple(point)]
    while True:
        best: tuple[float, int] | None = None
        for k, knob in enumerate(knobs):
            i = point[k]
            if i + 1 >= len(knob.levels):
                continue
            a, b = model.db_lost(knob.name, i), model.db_lost(knob.name, i + 1)
            saving = math.log(knob.cost[i] / knob.cost[i + 1])
            per_bit = math.inf if a is None or b is None else max(0.0, max(0.0, b) - max(0.0, a)) / saving
            if best is None or per_bit < best[0]:
                best = (per_bit, k)
        if best is None:
            return out
        point[best[1]] += 1
        out.append(tuple(point))


HORIZON_S = 1.0
"""How far ahead the quality-aware controller looks at a queue a point would build (about the estimator's reaction
time: a point that does not fit is left within it)."""
MAX_SQUEEZE = 8.0
"""The deepest the encoders are expected to go below a point's own rate before the point's data and video no longer
fit and a queue builds instead (three halvings; the rate controller's floor is ``min_kbps`` a stream)."""


GROW_MS = 20.0
GROW_WINDOW_S = 0.3
"""A queue over its lowest of the last ``GROW_WINDOW_S`` by ``GROW_MS`` is growing: the point takes the encoder rate."""
DRAIN_S = 0.5
"""Without the estimator's encoder rate, the point controller drains the part of a queue past the method's tolerance
within this (the estimator's ``drain_ms``) ..."""
MIN_DRAIN_SHARE = 0.1
"""... and leaves the point at least this share of the budget while it does."""


RISING = 1.25
"""With a quality model, an estimate over this many times its lowest of the last ``RISING_WINDOW_S`` is still rising
(the start's probing, or a link that widened): it asks for no coarser point unless a queue past the method's tolerance
grows.  At start the estimate climbs from 300 kbit/s by probing (0.3, 0.6, 1.2, 2.2 Mbit/s at 0, 0.27, 0.5 and
1 s for sas on the cellular-like trace); a point chosen for it dropped sas to its coarsest for its first 2 s."""
RISING_WINDOW_S = 0.5
RISING_QUEUE_MS = 50.0
"""... and only while the queue is under this (ms): a queue building as the estimate rises is the link binding, not
the probing (warp's lossless depth at start, held at its own point while its queue reached 325 ms, kept a 1.3 s queue
for 2 s on the cellular-like trace)."""


ALR_QUIET_S = 1.0
"""The point controller takes the session as application-limited once the estimate has not fallen and the queue has
stayed under ``ALR_QUEUE_MS`` for this long (:meth:`PointController.app_limited`; the up hold's length: a step up
under the whole budget is no sooner than one with the margin)."""
ALR_QUEUE_MS = 20.0
"""... the queue it takes as empty (``GROW_MS``: what a frame's burst leaves) ..."""
ALR_FALL = 0.99
"""... and an estimate under this share of the one before is one that fell (an over-use or loss: the delay-based
estimate only ever falls on those)."""


BURST_SHARE = 0.5
"""A method that tolerates more queueing than video's budget (``mtp_budget_ms``) lets its capped encoders' VBV buffer
hold this share of the difference (:attr:`RateController.buffer_ms`): an I-frame takes its crf's bits and queues
for no longer than that."""


class PointController:
    """The method's operating point from the estimate (``adapt = "full"``; sans-IO).

    The points form a ladder (:func:`build_ladder`) over the method's knobs (:meth:`MethodConfig.adapt_knobs`,
    plus the pipeline's resolution ``scale`` where a stream is scalable).  The cost of a point is what it sends
    per second:

    - **video**: what the encoders took at the method's own point (the rate controller's calibrated caps) times
      the product of the video knobs' cost priors;
    - **data** (what is sent as made: reliable data, geometry, lossless video): the rate the rate controller paid
      first, *learnt at every point the session has been at* (after ``settle_frames``), and for a point not yet
      visited the nearest learnt one scaled by the data knobs' priors.

    A point *fits* a budget (:meth:`budget_bps`: ``headroom`` times the estimator's target, the path's rate, or its
    encoder rate, which drains the queue, where a queue grows or passes the method's tolerance) when its data plus its
    video over
    ``stretch`` do (its encoders may run below what they would take, to 1/``stretch`` of it, before a coarser point
    is worth more than the bits it loses).  The controller goes down at once to the richest point that fits (no
    sooner than ``down_hold_s`` after its last move, unless a queue past the budget is growing: a move up just
    before the link fell must not hold the session on a point the link no longer carries), and up, once a richer
    point has fitted within ``up_margin`` of the budget for ``up_hold_s``, to the richest such point.  A queue
    longer than the motion-to-photon budget (``mtp_budget_ms``) and still growing means the present point does not
    fit, whatever its costs say (a queue that drains is the estimator's: its encoder rate already leaves room to
    drain it).  It waits for the rate controller's first cap (a provisional one will do) before its first move.  A
    session without lossy video (``probes``: nothing to calibrate, everything data) learns a point's data rate as the
    mean of its settled frames there (not the rate controller's running average, which its first fill and its
    lossless I-frames would set), and waits for ``settle_frames`` of them at the point it starts at.

    **With a quality model** (the method's :class:`~splitrender.methods.base.QualityModel`, carried by its knobs, or
    ``model``) the ladder follows the model's dB per bit (:func:`quality_ladder`) and the controller picks the point
    of the highest *expected model quality* (:meth:`expected_db`) under the budget instead of the richest that fits:
    a point loses its knobs' dB, the encoders' squeeze below its own rate (the model's dB per halving), and where its
    data and its squeezed video still exceed the budget, the queue it would build within ``HORIZON_S`` at the model's
    dB per 100 ms; a point whose queue would pass the method's latency tolerance (:attr:`tolerance_ms`, from the
    model's latency slope: methods that redraw geometry at the display pose take more queueing than video) is out.
    The growing-queue rule takes that tolerance in place of ``mtp_budget_ms``; the holds and the up margin stay; an
    estimate still rising over an empty queue (``RISING``: the start's probing) moves the point no lower.

    **Application-limited** (:meth:`app_limited`; libwebrtc's ALR): a delay-based estimate grows only with what is
    sent (no more than 1.5 times the acknowledged rate, and near the capacity seen at the last over-use by about a
    packet per round trip), so a point chosen for a dip holds the estimate near its own rate, and the up margin then
    keeps it there: tss on the 8 Mbit/s cellular-like trace went to one frame in 2 at 1.1 s, behind a 5.6 Mbit/s
    estimate the margin left 4.3 of, and stayed there until 5.1 s.  Where the estimate has not fallen and the
    queue has stayed under ``ALR_QUEUE_MS`` for ``ALR_QUIET_S``, and the present point costs no more than the up
    margin of the budget (the session sends under what the estimate allows: the estimate, not the link, is what
    binds), the point steps up to the best point under the whole budget, without the margin and with no further hold
    (the quiet time was one); the session's probes
    (2x the estimate every ``probe_interval_s``, no faster than 1.5x what the richest point would send) raise the
    estimate to the link meanwhile, as libwebrtc probes in ALR.  A step that does not fit shows as a queue or an
    over-use, and the point goes down as usual.
    """

    def __init__(self, knobs: tuple[Any, ...], rate: RateController, cfg: AdaptConfig | None = None,
                 model: Any = None) -> None:
        seen: set[str] = set()      # a method may offer the pipeline's own knob (scale) with its model: the first
        self.knobs = tuple(k for k in knobs if not (k.name in seen or seen.add(k.name)))   # of a name is kept
        self.rate = rate
        self.cfg = cfg or rate.cfg
        self.model = model if model is not None else knobs_model(self.knobs)
        """The method's quality model (None: the richest point that fits, as without one)."""
        self.ladder = quality_ladder(self.knobs, self.model) if self.model is not None else build_ladder(self.knobs)
        if self.model is not None and self.rate.buffer_ms is None and self.tolerance_ms > self.cfg.mtp_budget_ms:
            self.rate.buffer_ms = BURST_SHARE * (self.tolerance_ms - self.cfg.mtp_budget_ms)
            if START_BOOST and getattr(self.model, "start_boost", False):
                self.rate.start_boost = max(dict(self.model.estimator).get("start_probes", (1.0,)))
        if self.model is not None and getattr(self.model, "track_cap", False):
            self.rate.track_cap = True
        self.index = 0
        self.moves = 0
        self._data_bps: dict[int, float] = {}
        self._since_move = 0           # frames at this point
        self._moved_s = -math.inf
        self._fits_up_since: float | None = None
        self._queue_ms = 0.0
        self._recent: list[tuple[float, float]] = []   # (time, estimate) over the last RISING_WINDOW_S
        self._queues: list[tuple[float, float]] = []   # (time, queue ms) over the last GROW_WINDOW_S
        self._data_sum: dict[int, list[float]] = {}    # sessions without lossy video: bits/s summed, frames, per point
        self._calm_since: float | None = None           # since when the estimate has not fallen nor the queue risen
        self._last_estimate: float | None = None
        self.up_room = float(getattr(self.model, "up_room", 0.0) or 0.0) if UP_ROOM else 0.0
        """A richer point whose cost fits this many times over in the budget, with no queue, is taken without the up
        hold (the quality model's ``up_room``; 0: never)."""
        self.alr_steps = 0
        """Moves up taken under the whole budget because the session was application-limited (:meth:`app_limited`)."""

    def values(self, index: int | None = None) -> dict[str, Any]:
        """Each knob's value at point ``index`` (the present one by default)."""
        p = self.ladder[self.index if index is None else index]
        return {k.name: k.levels[i] for k, i in zip(self.knobs, p)}

    def _factor(self, index: int, affects: str) -> float:
        f = 1.0
        for k, i in zip(self.knobs, self.ladder[index]):
            if k.affects in (affects, "both"):
                f *= k.cost[i]
        return f

    @property
    def frame_div(self) -> int:
        """One server tick in this many is sent at the present point (the ``frame_div`` knob; 1 without it)."""
        return int(self.values().get("frame_div", 1))

    def video_bps(self, index: int) -> float:
        return self.rate.natural_video_bps() * self._factor(index, "video")

    def data_bps(self, index: int) -> float:
        if index in self._data_bps:
            return self._data_bps[index]
        known = self._data_bps or {self.index: self.rate.overhead_bps}
        near = min(known, key=lambda j: (abs(j - index), j))
        return known[near] * self._factor(index, "data") / self._factor(near, "data")

    def cost_bps(self, index: int) -> float:
        """What point ``index`` is expected to send per second at the method's own rate control."""
        return self.data_bps(index) + self.video_bps(index)

    def fits(self, index: int, budget_bps: float, margin: float = 1.0) -> bool:
        return self.data_bps(index) + self.video_bps(index) / self.cfg.stretch <= margin * budget_bps

    @property
    def tolerance_ms(self) -> float:
        """The queueing (ms) the method takes before it drops detail: its model's, else ``mtp_budget_ms``."""
        return float(self.model.tolerance_ms) if self.model is not None else self.cfg.mtp_budget_ms

    def knob_db(self, index: int) -> float:
        """Model PSNR (dB) point ``index``'s knobs lose against the richest point (0 without a model)."""
        if self.model is None:
            return 0.0
        # a coarser level never counts as a gain (video's smaller pictures measure better: a blur scores better than
        # a sharp picture under the misalignment latency leaves, which is no richer picture)
        return sum(max(0.0, self.model.db_lost(k.name, i) or 0.0) for k, i in zip(self.knobs, self.ladder[index]))

    def expected_db(self, index: int, budget_bps: float, queue_ms: float = 0.0) -> float:
        """Expected model PSNR of point ``index`` under ``budget_bps`` against the richest point at its own rate (dB,
        <= 0; needs a model): its knobs' loss, the encoders' squeeze to what the budget leaves its video, and the
        queue it would add within ``HORIZON_S`` where even squeezed ``MAX_SQUEEZE`` times it does not fit; ``-inf``
        where that queue, on top of ``queue_ms``, passes the method's tolerance."""
        m = self.model
        data, video = self.data_bps(index), self.video_bps(index)
        loss = self.knob_db(index)
        left = budget_bps - data
        if video <= 0:
            over = data / max(budget_bps, 1.0) - 1.0
        elif left >= video:
            return -loss
        elif left >= video / MAX_SQUEEZE:
            return -loss - m.rate_db_per_halving * math.log2(video / left)
        else:
            over = (data + video / MAX_SQUEEZE) / max(budget_bps, 1.0) - 1.0
            loss += m.rate_db_per_halving * math.log2(MAX_SQUEEZE)
        if over <= 0:
            return -loss
        grow_ms = over * HORIZON_S * 1000.0
        if queue_ms + grow_ms > self.tolerance_ms:
            return -math.inf
        return -loss - m.latency_db_per_100ms * grow_ms / 100.0

    def _best(self, budget_bps: float, queue_ms: float) -> int:
        """The point of the highest expected quality (the richest of equals; the cheapest where none is in)."""
        scores = [self.expected_db(i, budget_bps, queue_ms) for i in range(len(self.ladder))]
        top = max(scores)
        if top == -math.inf:
            return len(self.ladder) - 1
        return next(i for i, v in enumerate(scores) if v >= top - 1e-9)

    def on_frame_sent(self) -> None:
        """A frame went out at the present point (the rate controller has taken its bytes): learn its data rate."""
        self._since_move += 1
        if self._since_move >= self.cfg.settle_frames:
            if self.rate.video:
                self._data_bps[self.index] = self.rate.overhead_bps
            else:       # all data (probes): the mean of every settled frame at the point, so that neither the
                #         session's first fill nor an I-frame's decay sets a point's rate
                s = self._data_sum.setdefault(self.index, [0.0, 0.0])
                s[0] += self.rate.last_overhead_bps
                s[1] += 1
                self._data_bps[self.index] = s[0] / s[1]

    def budget_bps(self, estimate_bps: float, queue_ms: float = 0.0, encoder_bps: float | None = None) -> float:
        """What the point may cost (bit/s): ``headroom`` times the path's rate ``estimate_bps`` (the estimator's
        target) where the queue ``queue_ms`` is one the method tolerates and not growing: the encoders' rate drains
        it (the estimator's encoder rate, ``encoder_bps``), and a point chosen for that draining rate is too coarse
        once it has drained (quads, at 0.83 s on the cellular-like trace: 961 of a 3,027 kbit/s target, over a
        133 ms start-up queue, and its coarsest point).  A queue past the method's tolerance, or one grown by
        ``GROW_MS`` within ``GROW_WINDOW_S`` (the link fell: the delay-based target follows only at the over-use, a
        few hundred ms later), takes the encoder rate (without one, the part past the tolerance drains within
        ``DRAIN_S``)."""
        lowest = min((q for t, q in self._queues), default=queue_ms)
        if queue_ms <= self.tolerance_ms and queue_ms <= lowest + GROW_MS:
            return self.cfg.headroom * estimate_bps
        if encoder_bps is not None and math.isfinite(encoder_bps):
            return self.cfg.headroom * min(estimate_bps, encoder_bps)
        over = max(0.0, queue_ms - self.tolerance_ms)
        return self.cfg.headroom * estimate_bps * max(MIN_DRAIN_SHARE, 1.0 - over / (DRAIN_S * 1000.0))

    def _up(self, budget_bps: float, margin: float, queue_ms: float) -> int | None:
        """The point to go up to under ``margin`` of ``budget_bps`` (None: none richer): without a model the richest
        that fits, with one the best, where richer than here."""
        if self.model is None:
            return next((i for i in range(self.index) if self.fits(i, budget_bps, margin)), None)
        rich = self._best(margin * budget_bps, queue_ms)
        return rich if rich < self.index else None

    def app_limited(self, now_s: float, budget_bps: float) -> bool:
        """The estimate, not the link, binds: it has not fallen and the queue has stayed under ``ALR_QUEUE_MS`` for
        ``ALR_QUIET_S`` (no over-use, no queue: the link carried all that was sent), and the present point costs
        no more than ``up_margin`` of ``budget_bps`` (what is sent leaves the estimate no evidence to grow on)."""
        return (self._calm_since is not None and now_s - self._calm_since >= ALR_QUIET_S
                and self.cost_bps(self.index) <= self.cfg.up_margin * budget_bps)

    def _calm(self, now_s: float, estimate_bps: float, queue_ms: float) -> None:
        last, self._last_estimate = self._last_estimate, estimate_bps
        if self._calm_since is None or queue_ms > ALR_QUEUE_MS or (last is not None and estimate_bps < ALR_FALL * last):
            self._calm_since = now_s

    def update(self, now_s: float, estimate_bps: float, queue_ms: float = 0.0,
               encoder_bps: float | None = None) -> bool:
        """Choose the point for the next frame from the path's estimated rate ``estimate_bps`` (the estimator's
        target), the queue ``queue_ms`` and the estimator's encoder rate ``encoder_bps`` (:meth:`budget_bps` decides
        which the queue leaves it); True when it moved."""
        if not math.isfinite(estimate_bps):
            return False
        self._recent = [(t, r) for t, r in self._recent if t >= now_s - RISING_WINDOW_S] + [(now_s, estimate_bps)]
        self._calm(now_s, estimate_bps, queue_ms)
        if not self.rate.calibrated:
            return False
        if not self.rate.video and self._data_sum.get(self.index, [0.0, 0.0])[1] < self.cfg.settle_frames:
            return False     # no encoder to calibrate (probes: lossless pictures and data): what it sends, learnt first
        if not self._data_bps:          # the data rate at the point the session started from
            self._data_bps[self.index] = self.rate.overhead_bps
        budget = self.budget_bps(estimate_bps, queue_ms, encoder_bps)
        self._queues = [(t, q) for t, q in self._queues if t >= now_s - GROW_WINDOW_S] + [(now_s, queue_ms)]
        last = len(self.ladder) - 1
        growing = queue_ms > self.tolerance_ms and queue_ms > self._queue_ms
        if self.model is None:
            best = next((i for i in range(last + 1) if self.fits(i, budget)), last)
        else:
            best = self._best(budget, queue_ms)
            if estimate_bps > RISING * min(r for _, r in self._recent) and queue_ms < RISING_QUEUE_MS:
                best = min(best, self.index)       # a rising estimate is no reason to go down
        if growing and self.index < last:
            best = max(best, self.index + 1)       # a queue past the budget, still growing: what is sent does not fit
        self._queue_ms = queue_ms
        up = self._up(budget, self.cfg.up_margin, queue_ms)
        alr = False
        if self.index > 0 and self.app_limited(now_s, budget):
            # application-limited: the estimate understates the link, and the margin would hold the point here
            whole = self._up(budget, 1.0, queue_ms)
            alr = whole is not None and (up is None or whole < up)
            up = whole if alr else up
        target = self.index
        if best > self.index:
            self._fits_up_since = None
            if now_s - self._moved_s >= self.cfg.down_hold_s or growing:   # a growing queue does not wait
                target = best
        elif up is not None and alr:
            target = up                            # the quiet time (ALR_QUIET_S) was the hold
        elif up is not None and self.up_room and queue_ms < ALR_QUEUE_MS \
                and self.up_room * self.cost_bps(up) <= budget:
            target = up                            # room to spare several times over: no hold
        elif up is not None:
            if self._fits_up_since is None:
                self._fits_up_since = now_s
            elif now_s - self._fits_up_since >= self.cfg.up_hold_s:
                target = up                        # the richest point that has fitted with room to spare
        else:
            self._fits_up_since = None
        if target == self.index:
            return False
        if target > self.index:
            self._calm_since = now_s               # a move down: the link bound
        elif alr:
            self.alr_steps += 1                    # further up than the margin allowed: application-limited
        self.index = target
        self.moves += 1
        self._since_move = 0
        self._moved_s = now_s
        self._fits_up_since = None
        self.rate.factor = self._factor(target, "video")
        return True

    def state(self) -> dict[str, float]:
        """For updates.csv: the point's index on the ladder and each numeric knob's value."""
        out: dict[str, float] = {"adapt_point": float(self.index)}
        if self.model is not None:
            out["adapt_knob_db"] = -self.knob_db(self.index)
        for k, v in self.values().items():
            out[f"adapt_knob_{k}"] = float(v)
        return out
