"""Client pose prediction on the server, as in QUASAR (section 4.1.4).

The server sees client poses late (uplink delay) and must render for the time the
client will display the frame.  These predictors extrapolate from the poses seen so
far with a kinematic model:

- :class:`NoPrediction`: the newest pose as is;
- :class:`ConstantVelocityPredictor`: position and orientation move on at their
  current linear / angular velocity;
- :class:`ConstantAccelerationPredictor`: also uses linear / angular acceleration;
- :class:`PerfectPredictor`: reads the true pose from the trace (an oracle for
  "perfect prediction" experiments).

Velocities and accelerations come from a polynomial fitted to the recent history,
with time measured relative to the newest sample:

- ``smoothing="none"``: the polynomial of the model's order (1 for CV, 2 for CA)
  through the last 2 (CV) or 3 (CA) samples exactly (finite differences that also
  work for uneven sample spacing);
- ``smoothing="savgol"``: a least-squares polynomial of degree ``polyorder`` over the
  last ``window`` samples, evaluated at the newest sample: the Savitzky-Golay filter
  (end-point form).  It is computed on the samples' own timestamps, so jittered pose
  arrival times are handled, which ``scipy.signal.savgol_filter`` (uniform spacing)
  would not.

Orientation is handled in the tangent space at the newest orientation ``q_n``: each
history orientation becomes the rotation vector ``log(q_i q_n^-1)`` (radians, world
frame), the same polynomial fit gives angular velocity (rad/s) and acceleration, and
the prediction is ``exp(r(h)) q_n``.  This is exact for rotation at constant angular
velocity about a fixed axis.

Two clamps keep a bad estimate from running away: the horizon is capped at
``max_horizon_s`` (seconds) and the extrapolated rotation at ``max_angle_deg``.
Time is seconds and distances metres throughout; errors are reported in cm and
degrees as in the paper's Table 1.
"""

from __future__ import annotations

import logging
import math
from abc import ABC, abstractmethod
from collections import deque
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from splitrender.errors import ConfigError, SplitRenderError
from splitrender.scene.pose import Pose, quat_conj, quat_from_axis_angle, quat_mul, quat_normalize
from splitrender.scene.trace import CameraTrace

log = logging.getLogger(__name__)

Smoothing = Literal["none", "savgol"]

DEFAULT_MAX_HORIZON_S = 0.5
"""Longest extrapolation, seconds; predictions further ahead are held at this horizon."""

DEFAULT_MAX_ANGLE_DEG = 90.0
"""Largest extrapolated rotation from the newest orientation, degrees."""

DEFAULT_SAVGOL_WINDOW = 9
"""Savitzky-Golay window, samples (9 samples = 67 ms at 120 Hz; the paper uses ~50 ms)."""

DEFAULT_SAVGOL_POLYORDER = 2


class NoObservationError(SplitRenderError, RuntimeError):
    """``predict`` was called before any pose was observed."""


# ---------------------------------------------------------------------------------
# Quaternion log / exp (rotation vectors)
# ---------------------------------------------------------------------------------


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle, radians, angle in [0, pi]) of a unit quaternion."""
    q = quat_normalize(q)
    if q[3] < 0:
        q = -q
    s = float(np.linalg.norm(q[:3]))
    if s < 1e-12:
        return 2.0 * q[:3]
    angle = 2.0 * math.atan2(s, float(q[3]))
    return q[:3] / s * angle


def rotvec_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation vector (radians)."""
    r = np.asarray(r, dtype=np.float64)
    angle = float(np.linalg.norm(r))
    if angle < 1e-12:
        return quat_normalize(np.array([0.5 * r[0], 0.5 * r[1], 0.5 * r[2], 1.0]))
    return quat_from_axis_angle(r / angle, angle)


# ---------------------------------------------------------------------------------
# Errors and logging
# ---------------------------------------------------------------------------------


def prediction_error(predicted: Pose, actual: Pose) -> tuple[float, float]:
    """Position error (cm) and rotation error (degrees) of a predicted pose."""
    return predicted.distance_m(actual) * 100.0, predicted.angle_deg(actual)


@dataclass(frozen=True)
class PredictionRecord:
    """One frame's prediction: when it was for (s), how far ahead (ms), its error (cm, deg)."""

    t_s: float
    horizon_ms: float
    err_cm: float
    err_deg: float


@dataclass(frozen=True)
class ErrorSummary:
    """Mean ± std / max of position (cm) and rotation (deg) errors, as in QUASAR Table 1."""

    count: int
    mean_cm: float
    std_cm: float
    max_cm: float
    mean_deg: float
    std_deg: float
    max_deg: float

    def __str__(self) -> str:
        return (
            f"{self.mean_cm:.2f} ± {self.std_cm:.2f} / {self.max_cm:.2f} cm, "
            f"{self.mean_deg:.2f} ± {self.std_deg:.2f} / {self.max_deg:.2f} deg (n={self.count})"
        )


class PredictionLog:
    """Per-frame prediction errors, for the runner's ``frames.csv``.

    Columns (:attr:`COLUMNS`): ``t_s`` (time predicted for, seconds), ``horizon_ms``
    (how far ahead of the newest observed pose), ``err_cm``, ``err_deg``.
    """

    COLUMNS = ("t_s", "horizon_ms", "err_cm", "err_deg")

    def __init__(self) -> None:
        self._records: list[PredictionRecord] = []

    def record(self, t_s: float, horizon_ms: float, predicted: Pose, actual: Pose) -> PredictionRecord:
        """Add one frame: the predicted and the true pose at ``t_s``."""
        err_cm, err_deg = prediction_error(predicted, actual)
        rec = PredictionRecord(float(t_s), float(horizon_ms), err_cm, err_deg)
        self._records.append(rec)
        return rec

    def add(self, rec: PredictionRecord) -> None:
        self._records.append(rec)

    def __len__(self) -> int:
        return len(self._records)

    @property
    def records(self) -> tuple[PredictionRecord, ...]:
        return tuple(self._records)

    def rows(self) -> list[tuple[float, float, float, float]]:
        """One tuple per frame in :attr:`COLUMNS` order."""
        return [(r.t_s, r.horizon_ms, r.err_cm, r.err_deg) for r in self._records]

    def columns(self) -> dict[str, np.ndarray]:
        """The log as arrays keyed by :attr:`COLUMNS`."""
        a = np.array(self.rows(), dtype=np.float64).reshape(-1, 4)
        return {name: a[:, i] for i, name in enumerate(self.COLUMNS)}

    def summary(self) -> ErrorSummary:
        """Mean, standard deviation and maximum of both errors (NaN when empty)."""
        c = self.columns()
        if len(self) == 0:
            nan = float("nan")
            return ErrorSummary(0, nan, nan, nan, nan, nan, nan)
        cm, deg = c["err_cm"], c["err_deg"]
        return ErrorSummary(
            len(self), float(cm.mean()), float(cm.std()), float(cm.max()), float(deg.mean()), float(deg.std()), float(deg.max())
        )


# ---------------------------------------------------------------------------------
# Predictors
# ---------------------------------------------------------------------------------


class PosePredictor(ABC):
    """Predicts a future pose from poses observed so far.

    ``observe`` takes poses in time order; a sample not newer than the newest one
    (duplicate or out of order) is ignored.  ``predict(t_s)`` returns the pose
    expected at ``t_s`` seconds (same clock as ``observe``).
    """

    name: str = "predictor"

    @abstractmethod
    def observe(self, t_s: float, pose: Pose) -> None:
        """Add the client's pose measured at ``t_s`` seconds."""

    @abstractmethod
    def predict(self, t_s: float) -> Pose:
        """The pose expected at ``t_s`` seconds; raises :class:`NoObservationError` before any observation."""

    def reset(self) -> None:
        """Forget all observations."""

    @property
    def last_t_s(self) -> float | None:
        """Time of the newest accepted observation, seconds (None before any)."""
        return None


class _HistoryPredictor(PosePredictor):
    """Keeps the newest ``history`` observations, dropping stale ones."""

    def __init__(self, history: int) -> None:
        self._hist: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=max(1, history))
        self.ignored = 0

    def observe(self, t_s: float, pose: Pose) -> None:
        t = float(t_s)
        if not math.isfinite(t):
            log.debug("%s: ignored pose with non-finite time %r", self.name, t_s)
            self.ignored += 1
            return
        if self._hist and t <= self._hist[-1][0]:
            log.debug("%s: ignored stale pose t=%.6f s (newest %.6f s)", self.name, t, self._hist[-1][0])
            self.ignored += 1
            return
        q = quat_normalize(pose.orientation)
        if self._hist and float(np.dot(q, self._hist[-1][2])) < 0:
            q = -q
        self._hist.append((t, np.array(pose.position, dtype=np.float64), q))

    def reset(self) -> None:
        self._hist.clear()
        self.ignored = 0

    @property
    def last_t_s(self) -> float | None:
        return self._hist[-1][0] if self._hist else None

    def _newest(self) -> tuple[float, np.ndarray, np.ndarray]:
        if not self._hist:
            raise NoObservationError(f"{self.name}: predict() called before any pose was observed")
        return self._hist[-1]


class NoPrediction(_HistoryPredictor):
    """The newest observed pose, whatever the time asked for."""

    name = "none"

    def __init__(self) -> None:
        super().__init__(history=1)

    def predict(self, t_s: float) -> Pose:
        _, p, q = self._newest()
        return Pose(p.copy(), q.copy())


def _local_fit(tau: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    """Value and derivatives at tau=0 of a degree-``degree`` least-squares polynomial.

    ``tau`` (K,) seconds relative to the newest sample, ``y`` (K, D).  Returns
    (degree+1, D): row k is the k-th derivative at 0 (units of y per s^k).
    """
    degree = min(degree, tau.shape[0] - 1)
    scale = max(float(np.max(np.abs(tau))), 1e-9)  # condition the Vandermonde matrix
    s = tau / scale
    v = np.vander(s, degree + 1, increasing=True)
    coef, *_ = np.linalg.lstsq(v, y, rcond=None)
    out = np.zeros((degree + 1, y.shape[1]))
    for k in range(degree + 1):
        out[k] = coef[k] * math.factorial(k) / scale**k
    return out


class _KinematicPredictor(_HistoryPredictor):
    """Taylor extrapolation of order ``order`` from a local polynomial fit of the history."""

    order = 1

    def __init__(
        self,
        smoothing: Smoothing = "none",
        window: int = DEFAULT_SAVGOL_WINDOW,
        polyorder: int = DEFAULT_SAVGOL_POLYORDER,
        max_horizon_s: float = DEFAULT_MAX_HORIZON_S,
        max_angle_deg: float = DEFAULT_MAX_ANGLE_DEG,
    ) -> None:
        if smoothing not in ("none", "savgol"):
            raise ConfigError(f"{self.name}: smoothing must be 'none' or 'savgol', got {smoothing!r}")
        if smoothing == "savgol":
            if int(window) < 2:
                raise ConfigError(f"{self.name}: savgol window must be >= 2 samples, got {window!r}")
            if not (0 <= int(polyorder) < int(window)):
                raise ConfigError(f"{self.name}: savgol polyorder must be in [0, window), got {polyorder!r}")
            if int(polyorder) < self.order:
                raise ConfigError(f"{self.name}: savgol polyorder must be >= {self.order} for this model, got {polyorder!r}")
        if not (max_horizon_s >= 0 and math.isfinite(max_horizon_s)):
            raise ConfigError(f"{self.name}: max_horizon_s must be a finite number >= 0, got {max_horizon_s!r}")
        if not (max_angle_deg >= 0):
            raise ConfigError(f"{self.name}: max_angle_deg must be >= 0, got {max_angle_deg!r}")
        self.smoothing: Smoothing = smoothing
        self.window = int(window)
        self.polyorder = int(polyorder)
        self.max_horizon_s = float(max_horizon_s)
        self.max_angle_rad = math.radians(float(max_angle_deg))
        super().__init__(history=self.window if smoothing == "savgol" else self.order + 1)

    def state(self) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """``(t_newest_s, derivs_position, derivs_rotvec, q_newest)`` from the current history.

        Row k of the derivative arrays is the k-th time derivative at the newest
        sample (m/s^k and rad/s^k, world frame), up to the model's order.
        """
        t_n, _, q_n = self._newest()
        hist = list(self._hist)
        ts = np.array([h[0] for h in hist]) - t_n
        ps = np.array([h[1] for h in hist])
        q_inv = quat_conj(q_n)
        rs = np.array([quat_to_rotvec(quat_mul(h[2], q_inv)) for h in hist])
        degree = self.polyorder if self.smoothing == "savgol" else self.order
        dp = _local_fit(ts, ps, degree)
        dr = _local_fit(ts, rs, degree)
        k = min(self.order, dp.shape[0] - 1)
        return t_n, dp[: k + 1], dr[: k + 1], q_n

    def predict(self, t_s: float) -> Pose:
        t_n, dp, dr, q_n = self.state()
        h = min(max(float(t_s) - t_n, 0.0), self.max_horizon_s)
        pos = np.zeros(3)
        rv = np.zeros(3)
        for k in range(dp.shape[0]):
            c = h**k / math.factorial(k)
            pos += c * dp[k]
            rv += c * dr[k]
        ang = float(np.linalg.norm(rv))
        if ang > self.max_angle_rad:
            rv *= self.max_angle_rad / ang
        return Pose(pos, quat_mul(rotvec_to_quat(rv), q_n))


class ConstantVelocityPredictor(_KinematicPredictor):
    """Position and orientation continue at their current linear (m/s) and angular (rad/s) velocity."""

    name = "cv"
    order = 1


class ConstantAccelerationPredictor(_KinematicPredictor):
    """Like :class:`ConstantVelocityPredictor` plus linear (m/s²) and angular (rad/s²) acceleration."""

    name = "ca"
    order = 2


class PerfectPredictor(PosePredictor):
    """Oracle: the true pose of ``trace`` at the asked time (observations are ignored)."""

    name = "perfect"

    def __init__(self, trace: CameraTrace) -> None:
        self.trace = trace
        self._last: float | None = None

    def observe(self, t_s: float, pose: Pose) -> None:
        if self._last is None or t_s > self._last:
            self._last = float(t_s)

    def predict(self, t_s: float) -> Pose:
        return self.trace.pose_at(t_s)

    def reset(self) -> None:
        self._last = None

    @property
    def last_t_s(self) -> float | None:
        return self._last


PREDICTOR_NAMES = ("none", "cv", "ca", "cv_savgol", "ca_savgol", "perfect")


def make_predictor(name: str, **kw: Any) -> PosePredictor:
    """A predictor by name: ``none``, ``cv``, ``ca``, ``cv_savgol``, ``ca_savgol``, ``perfect``.

    Keyword arguments go to the constructor (``window``, ``polyorder``,
    ``max_horizon_s``, ``max_angle_deg``; ``perfect`` needs ``trace=``).  Unknown
    names or arguments raise :class:`ConfigError`.
    """
    try:
        if name == "none":
            return NoPrediction(**kw)
        if name == "perfect":
            return PerfectPredictor(**kw)
        base, _, smooth = name.partition("_")
        cls = {"cv": ConstantVelocityPredictor, "ca": ConstantAccelerationPredictor}.get(base)
        if cls is not None and smooth in ("", "savgol"):
            if "smoothing" in kw:
                raise ConfigError(f"predictor {name!r}: smoothing is given by the name, not an argument")
            return cls(smoothing="savgol" if smooth else "none", **kw)
    except TypeError as exc:
        raise ConfigError(f"predictor {name!r}: bad arguments: {exc}") from None
    raise ConfigError(f"unknown predictor {name!r}; valid names: {', '.join(PREDICTOR_NAMES)}")


def evaluate_predictor(
    predictor: PosePredictor,
    trace: CameraTrace,
    horizon_s: float,
    rate_hz: float | None = None,
    warmup_s: float = 0.1,
    noise_cm: float = 0.0,
    noise_deg: float = 0.0,
    seed: int = 0,
) -> PredictionLog:
    """Replay ``trace`` into ``predictor`` and score predictions ``horizon_s`` ahead.

    Poses are observed at the trace's own samples (or resampled at ``rate_hz``); after
    each observation at time t past ``warmup_s`` the pose at ``t + horizon_s`` is
    predicted and compared with the trace, while ``t + horizon_s`` is inside it.
    ``noise_cm`` / ``noise_deg`` add Gaussian tracker noise (standard deviation per
    axis, seeded by ``seed``) to the observed poses, not to the truth.
    """
    rng = np.random.default_rng(seed)
    src = trace if rate_hz is None else trace.sample(rate_hz)
    log_ = PredictionLog()
    predictor.reset()
    for i, t in enumerate(src.t_s):
        t = float(t)
        pose = src.pose(i)
        if noise_cm > 0 or noise_deg > 0:
            dq = rotvec_to_quat(rng.normal(0.0, math.radians(noise_deg), 3))
            pose = Pose(pose.position + rng.normal(0.0, noise_cm / 100.0, 3), quat_mul(dq, pose.orientation))
        predictor.observe(t, pose)
        target = t + horizon_s
        if t < warmup_s or target > trace.duration_s:
            continue
        log_.record(target, horizon_s * 1000.0, predictor.predict(target), trace.pose_at(target))
    return log_


__all__ = [
    "ConstantAccelerationPredictor",
    "ConstantVelocityPredictor",
    "ErrorSummary",
    "NoObservationError",
    "NoPrediction",
    "PREDICTOR_NAMES",
    "PerfectPredictor",
    "PosePredictor",
    "PredictionLog",
    "PredictionRecord",
    "evaluate_predictor",
    "make_predictor",
    "prediction_error",
    "quat_to_rotvec",
    "rotvec_to_quat",
]
