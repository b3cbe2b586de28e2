"""Camera traces: timed head poses, their files, and generators of human-like motion.

A :class:`CameraTrace` is a sequence of samples ``(t_s, position, orientation)`` with
times in seconds starting at exactly 0 and strictly increasing, positions in metres
(world space, +Y up) and unit quaternions ``(x, y, z, w)`` (see :mod:`.pose` for the
conventions: the camera looks down its local -Z, yaw 0 looks down world -Z).

Trace file format (``.csv``, version 1)
---------------------------------------
UTF-8 text, one record per line, ``\\n`` line ends::

    # splitrender-trace v1
    t_s,px,py,pz,qx,qy,qz,qw
    0,0,1.6,2.5,0,0,0,1
    0.008333333333333333,0,1.6,2.4883,0,0.0012,0,0.99999928

- Line 1 is exactly ``# splitrender-trace v1`` (the version number is checked).
- Line 2 is exactly the header ``t_s,px,py,pz,qx,qy,qz,qw``.
- Every further line is one sample: 8 comma-separated decimal numbers, time in
  seconds, position in metres, orientation quaternion (need not be exactly unit
  length; it is normalised on load, but must not be zero).  Blank lines and lines
  starting with ``#`` are ignored.
- Times must be finite and strictly increasing; at least 2 samples.  A trace whose
  first time is not 0 is rebased so that it starts at 0.
- Numbers are written with ``repr`` (17 significant digits), so a save/load round
  trip is bit-exact.

Any violation raises :class:`~splitrender.errors.TraceError` naming the file and
line (``path:line: what was wrong``).

QUASAR camera paths (``.txt`` / ``.path``)
------------------------------------------
The QUASAR project's path files have one frame per line,
``px py pz rx ry rz t_ms``, whitespace separated, angles in degrees, time in
milliseconds.  QUASAR's ``CameraAnimator`` makes the camera-to-world rotation
``glm::quat(radians(vec3(rx, ry, rz)))``, R = Rz(rz) Ry(ry) Rx(rx) (:func:`quat_from_glm_euler_deg`):
rx is the pitch and ry the yaw, as in :func:`~splitrender.scene.pose.quat_from_euler_deg`, but roll is about +Z
and applied last (ours: about -Z and first); the two agree without roll.  :func:`load_quasar_path`
reads them (time rebased to 0); :func:`save_quasar_path` writes them (:func:`glm_euler_deg`).
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterable, Sequence

import numpy as np

from splitrender.errors import TraceError

if TYPE_CHECKING:
    from splitrender.scene.model import Scene
from splitrender.scene.pose import (
    Pose,
    look_at_quat,
    quat_angle_rad,
    quat_from_axis_angle,
    quat_from_euler_deg,
    quat_mul,
    quat_normalize,
    quat_slerp,
    quat_to_matrix3,
)

log = logging.getLogger(__name__)

TRACE_MAGIC = "# splitrender-trace v1"
TRACE_MAGIC_PREFIX = "# splitrender-trace v"
TRACE_VERSION = 1
TRACE_HEADER = "t_s,px,py,pz,qx,qy,qz,qw"
TRACE_COLUMNS = 8
QUASAR_COLUMNS = 7

TRACKER_RATE_HZ = 120.0
"""Sample rate of the generated traces (a typical head-tracker rate), Hz."""

DEFAULT_START = (0.0, 1.6, 2.5)
"""Default eye position of the built-in traces, metres (the default scene's entrance)."""

DEFAULT_BOX_XZ = ((-3.0, 3.0), (-4.0, 3.0))
"""Region of the default scene the built-in traces stay in: ((x_min, x_max), (z_min, z_max)), metres."""


# ---------------------------------------------------------------------------------
# The trace itself
# ---------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class CameraTrace:
    """Timed camera poses.

    ``t_s`` (N,) seconds, starting at 0, strictly increasing; ``positions`` (N, 3)
    metres; ``orientations`` (N, 4) unit quaternions (x, y, z, w).  Orientations are
    normalised and sign-aligned so neighbouring samples lie in the same hemisphere
    (the same rotations; this keeps finite differences and filters well behaved).
    Invalid arrays raise :class:`TraceError`.
    """

    t_s: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    name: str = "trace"

    def __post_init__(self) -> None:
        t = np.array(self.t_s, dtype=np.float64).reshape(-1)
        p = np.array(self.positions, dtype=np.float64)
        q = np.array(self.orientations, dtype=np.float64)
        n = t.shape[0]
        if n < 2:
            raise TraceError(f"trace {self.name!r}: needs at least 2 samples, got {n}")
        if p.shape != (n, 3):
            raise TraceError(f"trace {self.name!r}: positions must have shape ({n}, 3), got {p.shape}")
        if q.shape != (n, 4):
            raise TraceError(f"trace {self.name!r}: orientations must have shape ({n}, 4), got {q.shape}")
        for label, arr in (("t_s", t), ("positions", p), ("orientations", q)):
            if not np.all(np.isfinite(arr)):
                raise TraceError(f"trace {self.name!r}: {label} contains NaN or infinity")
        if t[0] != 0.0:
            raise TraceError(f"trace {self.name!r}: t_s must start at 0, starts at {t[0]!r}")
        bad = np.nonzero(np.diff(t) <= 0)[0]
        if bad.size:
            i = int(bad[0]) + 1
            raise TraceError(f"trace {self.name!r}: t_s not strictly increasing at sample {i} ({t[i - 1]!r} -> {t[i]!r})")
        norms = np.linalg.norm(q, axis=1)
        if np.any(norms < 1e-12):
            i = int(np.nonzero(norms < 1e-12)[0][0])
            raise TraceError(f"trace {self.name!r}: zero-length quaternion at sample {i}")
        renorm = np.abs(norms - 1.0) > 1e-12
        q[renorm] /= norms[renorm, None]
        # Hemisphere continuity: q and -q are the same rotation.
        for i in range(1, n):
            if float(np.dot(q[i], q[i - 1])) < 0.0:
                q[i] = -q[i]
        for arr in (t, p, q):
            arr.setflags(write=False)
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "positions", p)
        object.__setattr__(self, "orientations", q)

    # -- basic properties -----------------------------------------------------------

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def duration_s(self) -> float:
        """Time of the last sample, seconds."""
        return float(self.t_s[-1])

    def __repr__(self) -> str:
        return f"CameraTrace(name={self.name!r}, samples={len(self)}, duration_s={self.duration_s:.3f})"

    # -- interpolation --------------------------------------------------------------

    def pose_at(self, t_s: float) -> Pose:
        """Pose at time ``t_s`` (seconds): linear position, slerped orientation.

        Clamped to the first / last sample outside ``[0, duration_s]``.
        """
        t = float(t_s)
        if not math.isfinite(t):
            raise TraceError(f"trace {self.name!r}: pose_at({t_s!r}) needs a finite time")
        if t <= self.t_s[0]:
            return Pose(self.positions[0].copy(), self.orientations[0].copy())
        if t >= self.t_s[-1]:
            return Pose(self.positions[-1].copy(), self.orientations[-1].copy())
        i = int(np.searchsorted(self.t_s, t, side="right")) - 1
        t0, t1 = float(self.t_s[i]), float(self.t_s[i + 1])
        u = (t - t0) / (t1 - t0)
        pos = self.positions[i] + u * (self.positions[i + 1] - self.positions[i])
        return Pose(pos, quat_slerp(self.orientations[i], self.orientations[i + 1], u))

    def poses_at(self, ts: Iterable[float]) -> list[Pose]:
        """:meth:`pose_at` for each time in ``ts`` (seconds)."""
        return [self.pose_at(t) for t in ts]

    def pose(self, i: int) -> Pose:
        """The ``i``-th sample as a :class:`Pose`."""
        return Pose(self.positions[i].copy(), self.orientations[i].copy())

    def sample(self, rate_hz: float) -> "CameraTrace":
        """The trace resampled at ``rate_hz`` (Hz), from 0 up to ``duration_s`` inclusive."""
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise TraceError(f"trace {self.name!r}: sample rate must be positive, got {rate_hz!r}")
        dt = 1.0 / rate_hz
        n = max(2, int(math.floor(self.duration_s * rate_hz + 1e-9)) + 1)
        ts = np.arange(n) * dt
        poses = self.poses_at(ts)
        return CameraTrace(
            ts,
            np.array([p.position for p in poses]),
            np.array([p.orientation for p in poses]),
            name=self.name,
        )

    # -- kinematics for reports -----------------------------------------------------

    def velocity_at(self, t_s: float, h_s: float = 0.005) -> np.ndarray:
        """Linear velocity (m/s, world, shape (3,)) by a central difference of ±``h_s`` seconds."""
        a, b = self._diff_window(t_s, h_s)
        return (self.pose_at(b).position - self.pose_at(a).position) / (b - a)

    def angular_speed_deg_s_at(self, t_s: float, h_s: float = 0.005) -> float:
        """Angular speed (degrees/s) by a central difference of ±``h_s`` seconds."""
        a, b = self._diff_window(t_s, h_s)
        ang = quat_angle_rad(self.pose_at(a).orientation, self.pose_at(b).orientation)
        return math.degrees(ang) / (b - a)

    def _diff_window(self, t_s: float, h_s: float) -> tuple[float, float]:
        a = max(0.0, float(t_s) - h_s)
        b = min(self.duration_s, float(t_s) + h_s)
        if b <= a:
            a, b = max(0.0, b - h_s), b
        return a, b

    def sample_speeds(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-interval linear speed (m/s) and angular speed (deg/s) between samples, (N-1,) each."""
        dt = np.diff(self.t_s)
        lin = np.linalg.norm(np.diff(self.positions, axis=0), axis=1) / dt
        d = np.abs(np.sum(self.orientations[1:] * self.orientations[:-1], axis=1))
        ang = np.degrees(2.0 * np.arccos(np.clip(d, 0.0, 1.0))) / dt
        return lin, ang

    # -- files ----------------------------------------------------------------------

    def to_text(self) -> str:
        """The trace in the v1 CSV format (see the module docstring)."""
        lines = [TRACE_MAGIC, TRACE_HEADER]
        for t, p, q in zip(self.t_s, self.positions, self.orientations):
            lines.append(",".join(repr(float(v)) for v in (t, *p, *q)))
        return "\n".join(lines) + "\n"

    def save(self, path: "str | os.PathLike[str]") -> None:
        """Write the trace as a v1 CSV file (bit-exact floats)."""
        Path(path).write_text(self.to_text(), encoding="utf-8")
        log.debug("saved trace %s (%d samples) to %s", self.name, len(self), path)

    @staticmethod
    def load(path: "str | os.PathLike[str]") -> "CameraTrace":
        """Read a v1 CSV trace file; raises :class:`TraceError` naming the file and line."""
        text = _read_text(path)
        return parse_trace_text(text, source=str(path), name=Path(path).stem)


def _read_text(path: "str | os.PathLike[str]") -> str:
    try:
        return Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise TraceError(f"{path}: trace file not found") from None
    except UnicodeDecodeError as exc:
        raise TraceError(f"{path}: trace file is not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise TraceError(f"{path}: cannot read trace file: {exc.strerror or exc}") from None


def _parse_number(tok: str, source: str, lineno: int, col: str) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise TraceError(f"{source}:{lineno}: column {col}: not a number: {tok.strip()[:40]!r}") from None
    if not math.isfinite(v):
        raise TraceError(f"{source}:{lineno}: column {col}: value must be finite, got {tok.strip()[:40]!r}")
    return v


def _build(
    rows: list[list[float]], linenos: list[int], source: str, name: str, pos_q: Callable[[list[float]], tuple[Sequence[float], np.ndarray]]
) -> CameraTrace:
    if len(rows) < 2:
        raise TraceError(f"{source}:{linenos[-1] if linenos else 1}: trace needs at least 2 samples, found {len(rows)}")
    return CameraTrace(*_arrays(rows, linenos, source, pos_q), name=name)


def _arrays(
    rows: list[list[float]], linenos: list[int], source: str, pos_q: Callable[[list[float]], tuple[Sequence[float], np.ndarray]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ts = np.empty(len(rows))
    ps = np.empty((len(rows), 3))
    qs = np.empty((len(rows), 4))
    for k, (row, ln) in enumerate(zip(rows, linenos)):
        t, p, q = row[0], *pos_q(row)
        if k and t <= ts[k - 1]:
            raise TraceError(f"{source}:{ln}: time {t!r} is not after the previous sample's {ts[k - 1]!r}")
        if float(np.linalg.norm(q)) < 1e-12:
            raise TraceError(f"{source}:{ln}: zero-length quaternion")
        ts[k], ps[k], qs[k] = t, p, q
    return ts - ts[0], ps, qs


def parse_trace_text(text: str, source: str = "<string>", name: str = "trace") -> CameraTrace:
    """Parse v1 CSV trace text (see the module docstring).

    ``source`` names the file in error messages.  Raises :class:`TraceError` and
    nothing else for malformed input.
    """
    lines = text.split("\n")
    first = lines[0].rstrip("\r").strip() if lines else ""
    if first != TRACE_MAGIC:
        if first.startswith(TRACE_MAGIC_PREFIX):
            raise TraceError(f"{source}:1: unsupported trace version {first[len(TRACE_MAGIC_PREFIX):]!r}, expected {TRACE_VERSION}")
        raise TraceError(f"{source}:1: expected {TRACE_MAGIC!r}, got {first[:60]!r}")
    header = lines[1].rstrip("\r").strip() if len(lines) > 1 else ""
    if header.replace(" ", "") != TRACE_HEADER:
        raise TraceError(f"{source}:2: expected header {TRACE_HEADER!r}, got {header[:60]!r}")
    cols = TRACE_HEADER.split(",")
    rows: list[list[float]] = []
    linenos: list[int] = []
    for lineno, raw in enumerate(lines[2:], start=3):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        toks = line.split(",")
        if len(toks) != TRACE_COLUMNS:
            raise TraceError(f"{source}:{lineno}: expected {TRACE_COLUMNS} columns, got {len(toks)}")
        rows.append([_parse_number(tok, source, lineno, c) for tok, c in zip(toks, cols)])
        linenos.append(lineno)
    return _build(rows, linenos, source, name, lambda r: (r[1:4], np.array(r[4:8])))


# ---------------------------------------------------------------------------------
# QUASAR camera paths
# ---------------------------------------------------------------------------------


def quat_to_euler_deg(q: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`quat_from_euler_deg`: ``(pitch, yaw, roll)`` in degrees.

    Pitch is in [-90, 90]; at exactly ±90° pitch (gimbal lock) roll is reported as 0.
    """
    m = quat_to_matrix3(q)
    # R = Ry(yaw) Rx(pitch) Rz(-roll): m[1,2] = -sin(pitch), m[0,2]/m[2,2] give yaw,
    # m[1,0]/m[1,1] give -roll.
    sp = -float(m[1, 2])
    pitch = math.asin(max(-1.0, min(1.0, sp)))
    if abs(sp) < 1.0 - 1e-12:
        yaw = math.atan2(float(m[0, 2]), float(m[2, 2]))
        roll = -math.atan2(float(m[1, 0]), float(m[1, 1]))
    else:
        yaw = math.atan2(-float(m[2, 0]), float(m[0, 0]))
        roll = 0.0
    return math.degrees(pitch), math.degrees(yaw), math.degrees(roll)


def quat_from_glm_euler_deg(rx: float, ry: float, rz: float) -> np.ndarray:
    """The rotation glm makes of Euler angles (``glm::quat(vec3)``, degrees here): R = Rz(rz) Ry(ry) Rx(rx)."""
    qx = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(rx))
    qy = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), math.radians(ry))
    qz = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), math.radians(rz))
    return quat_normalize(quat_mul(qz, quat_mul(qy, qx)))


def glm_euler_deg(q: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`quat_from_glm_euler_deg`: ``(rx, ry, rz)`` in degrees, ry in [-90, 90]; where ry is +-90
    (gimbal lock: a camera yawed a quarter turn) rz is 0 and rx carries the rest."""
    m = quat_to_matrix3(q)
    cy = math.hypot(float(m[0, 0]), float(m[1, 0]))
    ry = math.atan2(-float(m[2, 0]), cy)            # stable at the poles, where asin loses half its digits
    if cy > 1e-6:
        rx = math.atan2(float(m[2, 1]), float(m[2, 2]))
        rz = math.atan2(float(m[1, 0]), float(m[0, 0]))
    else:
        rx, rz = math.atan2(-float(m[1, 2]), float(m[1, 1])), 0.0
    return math.degrees(rx), math.degrees(ry), math.degrees(rz)


def parse_quasar_path_text(text: str, source: str = "<string>", name: str = "quasar_path") -> CameraTrace:
    """Parse QUASAR path text ``px py pz rx ry rz t_ms`` per line (see module docstring)."""
    cols = ("px", "py", "pz", "rx", "ry", "rz", "t_ms")
    rows: list[list[float]] = []
    linenos: list[int] = []
    for lineno, raw in enumerate(text.split("\n"), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        toks = line.split()
        if len(toks) != QUASAR_COLUMNS:
            raise TraceError(f"{source}:{lineno}: expected {QUASAR_COLUMNS} columns (px py pz rx ry rz t_ms), got {len(toks)}")
        v = [_parse_number(tok, source, lineno, c) for tok, c in zip(toks, cols)]
        rows.append([v[6] / 1000.0, *v[:6]])
        linenos.append(lineno)
    return _build(rows, linenos, source, name, lambda r: (r[1:4], quat_from_glm_euler_deg(r[4], r[5], r[6])))


def load_quasar_path(path: "str | os.PathLike[str]") -> CameraTrace:
    """Read a QUASAR camera path file; raises :class:`TraceError` naming the file and line."""
    return parse_quasar_path_text(_read_text(path), source=str(path), name=Path(path).stem)


def quasar_path_text(trace: CameraTrace, header: bool = True) -> str:
    """The trace as QUASAR path text (``px py pz rx ry rz t_ms``, glm's Euler angles, repr floats).  ``header``: a first comment line
    naming the columns; QUASAR's own reader (``CameraAnimator.cpp``: ``ss >> px >> ... >> timestampMillis``) takes
    no comments, so write without it for QUASAR's simulators.  (That reader also truncates each time to a whole
    millisecond: a 60 Hz path's 16.67 ms is read as 16.)"""
    lines = [f"# {trace.name}: px py pz rx_deg ry_deg rz_deg t_ms (written by splitrender)"] if header else []
    for t, p, q in zip(trace.t_s, trace.positions, trace.orientations):
        rx, ry, rz = glm_euler_deg(q)
        lines.append(" ".join(repr(float(v)) for v in (*p, rx, ry, rz, t * 1000.0)))
    return "\n".join(lines) + "\n"


def save_quasar_path(trace: CameraTrace, path: "str | os.PathLike[str]", header: bool = True) -> None:
    """Write ``trace`` as a QUASAR camera path file (``header``: see :func:`quasar_path_text`)."""
    Path(path).write_text(quasar_path_text(trace, header), encoding="utf-8")
    log.debug("saved QUASAR path %s (%d samples) to %s", trace.name, len(trace), path)


# ---------------------------------------------------------------------------------
# Generators of head motion
# ---------------------------------------------------------------------------------


def _times(duration_s: float, rate_hz: float) -> np.ndarray:
    if not (duration_s > 0 and math.isfinite(duration_s)):
        raise TraceError(f"trace duration must be positive, got {duration_s!r}")
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise TraceError(f"trace rate must be positive, got {rate_hz!r}")
    n = max(2, int(math.floor(duration_s * rate_hz + 1e-9)) + 1)
    return np.arange(n) / rate_hz


def _from_euler(name: str, t: np.ndarray, pos: np.ndarray, pitch: np.ndarray, yaw: np.ndarray, roll: np.ndarray) -> CameraTrace:
    q = np.array([quat_from_euler_deg(float(a), float(b), float(c)) for a, b, c in zip(pitch, yaw, roll)])
    return CameraTrace(t, pos, q, name=name)


def _min_jerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk profile 0→1 for s in [0, 1]; peak rate 1.875 at s=0.5."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


def _sway(rng: np.random.Generator, t: np.ndarray, amp: float, freqs_hz: Sequence[float]) -> np.ndarray:
    """Sum of sinusoids with random phases, peak roughly ``amp``."""
    out = np.zeros_like(t)
    for f in freqs_hz:
        out += np.sin(2 * math.pi * f * t + rng.uniform(0, 2 * math.pi))
    return amp * out / max(1, len(freqs_hz)) * 1.4


def _head_turn_offsets(
    rng: np.random.Generator,
    t: np.ndarray,
    rate_per_s: float,
    amp_deg: tuple[float, float],
    peak_deg_s: tuple[float, float],
    hold_s: tuple[float, float],
    start_s: float = 0.5,
) -> np.ndarray:
    """Occasional saccade-like head turns away and back (min-jerk), degrees of yaw offset."""
    out = np.zeros_like(t)
    if rate_per_s <= 0:
        return out
    tc = start_s + rng.exponential(1.0 / rate_per_s)
    end = float(t[-1])
    while tc < end:
        amp = rng.uniform(*amp_deg) * rng.choice([-1.0, 1.0])
        dur = 1.875 * abs(amp) / rng.uniform(*peak_deg_s)
        dur_back = 1.875 * abs(amp) / rng.uniform(*peak_deg_s)
        hold = rng.uniform(*hold_s)
        go = _min_jerk((t - tc) / dur)
        back = _min_jerk((t - (tc + dur + hold)) / dur_back)
        out += amp * (go - back)
        tc += dur + hold + dur_back + rng.exponential(1.0 / rate_per_s)
    return out


def walk_trace(
    duration_s: float = 10.0,
    speed_mps: float = 1.4,
    seed: int = 0,
    start: Sequence[float] = DEFAULT_START,
    heading_deg: float = 0.0,
    turn_rate_deg_s: float = 25.0,
    head_yaw_amp_deg: float = 4.0,
    head_turn_rate_per_s: float = 0.25,
    head_turn_amp_deg: tuple[float, float] = (20.0, 60.0),
    head_turn_peak_deg_s: tuple[float, float] = (100.0, 200.0),
    bob_amp_m: float = 0.015,
    box_xz: tuple[tuple[float, float], tuple[float, float]] = DEFAULT_BOX_XZ,
    rate_hz: float = TRACKER_RATE_HZ,
    name: str = "walk",
) -> CameraTrace:
    """A person walking at ``speed_mps`` (m/s, 1-4) on a smooth wandering path.

    The path heading (degrees, 0 = towards -Z, positive = left) wanders at up to
    ``turn_rate_deg_s`` and steers back towards the middle of ``box_xz`` near its
    walls (turning harder and slowing down when needed), so the path stays inside the
    box.  On top: vertical gait bob of ``bob_amp_m`` at the step frequency (~2 Hz at
    1.4 m/s), lateral sway at half that, small head yaw/pitch sway
    (``head_yaw_amp_deg``) and occasional saccade-like head turns of
    ``head_turn_amp_deg`` at peak ``head_turn_peak_deg_s``.  Deterministic for a seed.
    """
    if not (0.2 <= speed_mps <= 6.0):
        raise TraceError(f"walk speed must be in [0.2, 6] m/s, got {speed_mps!r}")
    rng = np.random.default_rng(seed)
    t = _times(duration_s, rate_hz)
    dt = 1.0 / rate_hz
    (x0, x1), (z0, z1) = box_xz
    margin = 0.6
    cx, cz = 0.5 * (x0 + x1), 0.5 * (z0 + z1)
    n = t.shape[0]
    pos = np.zeros((n, 3))
    heading = np.zeros(n)
    speed = np.zeros(n)
    x, z = float(start[0]), float(start[2])
    h = math.radians(heading_deg)
    omega = 0.0  # rad/s, low-pass filtered heading rate
    wander = 0.0
    v = speed_mps  # already walking when the trace starts
    tau = 0.25  # s, heading-rate smoothing
    max_wander = math.radians(turn_rate_deg_s)
    for i in range(n):
        pos[i, 0], pos[i, 2] = x, z
        heading[i], speed[i] = h, v
        # Wandering heading rate (Ornstein-Uhlenbeck).
        wander += -wander * dt / 1.5 + max_wander * math.sqrt(2 * dt / 1.5) * rng.standard_normal()
        target_omega = max(-max_wander, min(max_wander, wander))
        # Steer towards the middle when the point 2 m (more when fast) ahead is near a wall.
        look = max(2.0, 1.0 + 0.8 * speed_mps)
        fx, fz = x - math.sin(h) * look, z - math.cos(h) * look
        inside = x0 + margin < fx < x1 - margin and z0 + margin < fz < z1 - margin
        urgency = 0.0
        if not inside:
            want = math.atan2(-(cx - x), -(cz - z))  # heading that points to the middle
            err = (want - h + math.pi) % (2 * math.pi) - math.pi
            omega_max = max(max_wander, speed_mps / 1.2)  # turning radius >= ~1.2 m
            target_omega = max(-omega_max, min(omega_max, 3.0 * err))
            urgency = min(1.0, abs(err) / math.pi * 2.0)
        omega += (target_omega - omega) * min(1.0, dt / tau)
        # Slow down a little in sharp turns, as people do.
        v_target = speed_mps * (1.0 - 0.1 * urgency)
        v += (v_target - v) * min(1.0, dt / 0.4)
        h += omega * dt
        x -= math.sin(h) * v * dt
        z -= math.cos(h) * v * dt
    # Hard safety: never leave the box even in pathological settings.
    pos[:, 0] = np.clip(pos[:, 0], x0, x1)
    pos[:, 2] = np.clip(pos[:, 2], z0, z1)
    # Gait: step frequency rises with speed; vertical bob at step rate, lateral sway at half.
    f_step = float(np.clip(1.5 + 0.35 * speed_mps, 1.6, 3.0))
    phase = 2 * math.pi * np.cumsum(f_step * np.clip(speed / max(speed_mps, 1e-9), 0.0, 1.0)) * dt
    ramp = np.clip(speed / max(speed_mps, 1e-9), 0.0, 1.0)
    bob = bob_amp_m * ramp * np.cos(phase)
    lateral = 0.012 * ramp * np.sin(0.5 * phase)
    pos[:, 1] = float(start[1]) + bob
    pos[:, 0] += lateral * np.cos(heading)
    pos[:, 2] += -lateral * np.sin(heading)
    pos[:, 0] = np.clip(pos[:, 0], x0, x1)
    pos[:, 2] = np.clip(pos[:, 2], z0, z1)
    # Head orientation: path heading + sway + occasional turns.
    yaw = np.degrees(heading)
    yaw += _sway(rng, t, head_yaw_amp_deg, (0.13, 0.31, 0.57))
    yaw += _head_turn_offsets(rng, t, head_turn_rate_per_s, head_turn_amp_deg, head_turn_peak_deg_s, (0.4, 1.5))
    pitch = -4.0 + _sway(rng, t, 0.5 * head_yaw_amp_deg, (0.11, 0.23, 0.41)) + 0.6 * ramp * np.sin(phase)
    roll = _sway(rng, t, 0.8, (0.17, 0.37)) + 0.5 * ramp * np.sin(0.5 * phase)
    yaw -= yaw[0] - (heading_deg + 0.0)  # start looking exactly along the start heading
    return _from_euler(name, t, pos, pitch, yaw, roll)


def head_turn_trace(
    duration_s: float = 10.0,
    seed: int = 0,
    position: Sequence[float] = DEFAULT_START,
    peak_deg_s: tuple[float, float] = (320.0, 420.0),
    amp_deg: tuple[float, float] = (60.0, 110.0),
    pause_s: tuple[float, float] = (0.3, 0.9),
    pitch_amp_deg: float = 15.0,
    rate_hz: float = TRACKER_RATE_HZ,
    name: str = "turn",
    base_pitch_deg: float = 0.0,
) -> CameraTrace:
    """Standing still, turning the head fast left and right (stress trace).

    Each turn is a minimum-jerk yaw move of ``amp_deg`` with peak speed drawn from
    ``peak_deg_s`` (degrees/s, default ≥ 320: beyond what 100 ms of overscan covers),
    alternating sides around yaw 0, with some pitch and a little body sway (cm).
    """
    rng = np.random.default_rng(seed)
    t = _times(duration_s, rate_hz)
    yaw = np.zeros_like(t)
    pitch = np.zeros_like(t)
    cur_yaw, cur_pitch = 0.0, 0.0
    side = rng.choice([-1.0, 1.0])
    tc = 0.3
    while tc < t[-1]:
        target = side * rng.uniform(*amp_deg) * 0.5 + rng.uniform(-10, 10)
        target_pitch = rng.uniform(-pitch_amp_deg, pitch_amp_deg * 0.5)
        amp = abs(target - cur_yaw)
        dur = max(0.05, 1.875 * amp / rng.uniform(*peak_deg_s))
        s = _min_jerk((t - tc) / dur)
        yaw += (target - cur_yaw) * s
        pitch += (target_pitch - cur_pitch) * s
        cur_yaw, cur_pitch = target, target_pitch
        side = -side
        tc += dur + rng.uniform(*pause_s)
    pos = np.tile(np.asarray(position, dtype=np.float64), (t.shape[0], 1))
    pos[:, 0] += _sway(rng, t, 0.01, (0.2, 0.45))
    pos[:, 1] += _sway(rng, t, 0.005, (0.3, 0.7))
    pos[:, 2] += _sway(rng, t, 0.01, (0.15, 0.5))
    roll = _sway(rng, t, 1.0, (0.2, 0.5))
    if base_pitch_deg:
        pitch = pitch + base_pitch_deg
    return _from_euler(name, t, pos, pitch, yaw, roll)


def strafe_trace(
    duration_s: float = 10.0,
    seed: int = 0,
    start: Sequence[float] = DEFAULT_START,
    step_m: tuple[float, float] = (0.35, 0.6),
    step_s: float = 0.6,
    pause_s: tuple[float, float] = (0.05, 0.35),
    x_limit_m: float = 2.5,
    rate_hz: float = TRACKER_RATE_HZ,
    name: str = "strafe",
    base_pitch_deg: float = 0.0,
) -> CameraTrace:
    """Side-stepping along X while looking towards -Z (disocclusion stress).

    Steps of ``step_m`` metres taking ``step_s`` seconds each (min-jerk) with short
    pauses; the direction reverses near ``|x - start_x| = x_limit_m``.  A small bob
    per step and head sway are added.
    """
    rng = np.random.default_rng(seed)
    t = _times(duration_s, rate_hz)
    x = np.zeros_like(t)
    bob = np.zeros_like(t)
    cur = 0.0
    direction = 1.0 if rng.random() < 0.5 else -1.0
    tc = 0.2
    while tc < t[-1]:
        d = rng.uniform(*step_m)
        if abs(cur + direction * d) > x_limit_m:
            direction = -direction
        s = (t - tc) / step_s
        x += direction * d * _min_jerk(s)
        inside = (s > 0) & (s < 1)
        bob[inside] += 0.015 * np.sin(math.pi * s[inside])
        cur += direction * d
        tc += step_s + rng.uniform(*pause_s)
    pos = np.tile(np.asarray(start, dtype=np.float64), (t.shape[0], 1))
    pos[:, 0] += x
    pos[:, 1] += bob
    pos[:, 2] += _sway(rng, t, 0.03, (0.1, 0.25))
    yaw = _sway(rng, t, 6.0, (0.12, 0.29, 0.5))
    pitch = -3.0 + _sway(rng, t, 2.0, (0.1, 0.33))
    if base_pitch_deg:
        pitch = pitch + 3.0 + base_pitch_deg
    roll = _sway(rng, t, 1.0, (0.2, 0.4))
    return _from_euler(name, t, pos, pitch, yaw, roll)


def orbit_trace(
    duration_s: float = 10.0,
    seed: int = 0,
    center: Sequence[float] = (0.0, 1.2, -0.5),
    radius_m: float = 2.5,
    eye_height_m: float = 1.6,
    angular_speed_deg_s: float = 30.0,
    arc_deg: float = 120.0,
    rate_hz: float = TRACKER_RATE_HZ,
    name: str = "orbit",
) -> CameraTrace:
    """Walking on a circle of ``radius_m`` around ``center`` while looking at it.

    Starts at the +Z side of the circle (default (0, 1.6, 2.0), looking towards -Z)
    and swings back and forth over ``arc_deg`` degrees at up to
    ``angular_speed_deg_s``.  ``seed`` perturbs the look target slightly.
    """
    rng = np.random.default_rng(seed)
    t = _times(duration_s, rate_hz)
    c = np.asarray(center, dtype=np.float64)
    half = math.radians(arc_deg) / 2.0
    w = math.radians(angular_speed_deg_s)
    # Sinusoidal swing with peak angular speed w: phi = half * sin(w t / half).
    phi = half * np.sin(w * t / half) if half > 0 else np.zeros_like(t)
    pos = np.stack([c[0] + radius_m * np.sin(phi), np.full_like(t, eye_height_m), c[2] + radius_m * np.cos(phi)], axis=1)
    jitter = np.stack([_sway(rng, t, 0.05, (0.2, 0.37)), _sway(rng, t, 0.03, (0.25,)), np.zeros_like(t)], axis=1)
    q = np.array([look_at_quat(p, c + j) for p, j in zip(pos, jitter)])
    return CameraTrace(t, pos, q, name=name)


def static_trace(
    duration_s: float = 10.0,
    position: Sequence[float] = DEFAULT_START,
    yaw_deg: float = 0.0,
    pitch_deg: float = 0.0,
    rate_hz: float = TRACKER_RATE_HZ,
    name: str = "static",
) -> CameraTrace:
    """A camera that does not move at all (exactly constant pose)."""
    t = _times(duration_s, rate_hz)
    pos = np.tile(np.asarray(position, dtype=np.float64), (t.shape[0], 1))
    q = np.tile(quat_from_euler_deg(pitch_deg, yaw_deg, 0.0), (t.shape[0], 1))
    return CameraTrace(t, pos, q, name=name)


# ---------------------------------------------------------------------------------
# Traces fitted to a loaded model
# ---------------------------------------------------------------------------------

FIT_FILL = 0.8
"""Share of the frame's width and height that a loaded model's bounds span on the fitted traces.

The camera stays at the distance where a horizontal circle around the model's
bounding box (its footprint's half diagonal) spans ``FIT_FILL`` of the frame width
and the box's half height spans ``FIT_FILL`` of the half frame height, whichever is
further (seen from the circle's centre), so the model fits from every side."""

EYE_HEIGHT_M = 1.6
"""Eye height above the model's lowest point on the fitted traces, metres."""


@dataclass(frozen=True)
class TraceFrame:
    """Where the fitted traces stand: look target, eye height, distance (metres)."""

    center: np.ndarray
    eye_y: float
    distance_m: float     # eye to ``center``
    radius_xz_m: float    # the same, projected on the ground plane
    footprint_m: float    # half diagonal of the model's footprint

    @property
    def home(self) -> np.ndarray:
        """The standing point of ``static``, ``turn`` and ``strafe``: on the +Z side, looking towards -Z."""
        return np.array([self.center[0], self.eye_y, self.center[2] + self.radius_xz_m])

    @property
    def home_pitch_deg(self) -> float:
        return math.degrees(math.atan2(self.center[1] - self.eye_y, self.radius_xz_m))


def frame_subject(lo: Sequence[float], hi: Sequence[float], fov_y_deg: float = 60.0, aspect: float = 16 / 9) -> TraceFrame:
    """Place the fitted traces around a model with world bounds ``lo``..``hi`` (metres)."""
    lo_a, hi_a = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    c = (lo_a + hi_a) / 2
    r_xz = 0.5 * math.hypot(hi_a[0] - lo_a[0], hi_a[2] - lo_a[2])
    half_h = 0.5 * (hi_a[1] - lo_a[1])
    tan_v = math.tan(math.radians(fov_y_deg) / 2)
    tan_h = tan_v * aspect
    d = max(r_xz / math.sin(math.atan(FIT_FILL * tan_h)), half_h / math.sin(math.atan(FIT_FILL * tan_v)), 0.5)
    eye_y = float(lo_a[1]) + EYE_HEIGHT_M
    dy = float(c[1]) - eye_y
    d = max(d, abs(dy) + 0.5)
    return TraceFrame(c, eye_y, d, math.sqrt(d * d - dy * dy), r_xz)


def _looking_at(name: str, t: np.ndarray, pos: np.ndarray, target: np.ndarray, yaw_off: np.ndarray, pitch_off: np.ndarray,
                roll: np.ndarray) -> CameraTrace:
    d = target[None, :] - pos
    yaw = np.degrees(np.unwrap(np.arctan2(-d[:, 0], -d[:, 2])))
    pitch = np.degrees(np.arctan2(d[:, 1], np.hypot(d[:, 0], d[:, 2])))
    return _from_euler(name, t, pos, pitch + pitch_off, yaw + yaw_off, roll)


def walk_around_trace(frame: TraceFrame, duration_s: float = 10.0, speed_mps: float = 1.4, seed: int = 0,
                      rate_hz: float = TRACKER_RATE_HZ, name: str = "walk") -> CameraTrace:
    """Walking around the model at eye height, mostly looking at it.

    The path is a circle of ``frame.radius_xz_m`` (radius wandering by 10 %) at
    ``speed_mps``; gait bob as in :func:`walk_trace`; the gaze is on the model's centre
    plus head sway and occasional head turns of 10-25 degrees.
    """
    rng = np.random.default_rng(seed)
    t = _times(duration_s, rate_hz)
    r0 = frame.radius_xz_m
    direction = rng.choice([-1.0, 1.0])
    r = r0 * (1.0 + _sway(rng, t, 0.1, (0.05, 0.11)))
    phi = direction * np.cumsum(np.full_like(t, speed_mps / rate_hz) / r)
    phi -= phi[0]
    f_step = float(np.clip(1.5 + 0.35 * speed_mps, 1.6, 3.0))
    pos = np.stack([frame.center[0] + r * np.sin(phi), frame.eye_y + 0.015 * np.cos(2 * math.pi * f_step * t),
                    frame.center[2] + r * np.cos(phi)], axis=1)
    yaw_off = _sway(rng, t, 4.0, (0.13, 0.31, 0.57)) + _head_turn_offsets(rng, t, 0.25, (10.0, 25.0), (100.0, 200.0), (0.4, 1.5))
    pitch_off = _sway(rng, t, 2.0, (0.11, 0.23, 0.41))
    roll = _sway(rng, t, 0.8, (0.17, 0.37))
    return _looking_at(name, t, pos, frame.center, yaw_off, pitch_off, roll)


def fitted_trace(name: str, frame: TraceFrame, duration_s: float = 10.0) -> CameraTrace:
    """The built-in trace ``name`` placed around a loaded model (see :data:`FIT_FILL`)."""
    home = frame.home
    if name == "walk":
        return walk_around_trace(frame, duration_s, 1.4, seed=1, name=name)
    if name == "walk_fast":
        return walk_around_trace(frame, duration_s, 3.0, seed=2, name=name)
    if name == "orbit":
        return orbit_trace(duration_s, seed=5, center=frame.center, radius_m=frame.radius_xz_m, eye_height_m=frame.eye_y, name=name)
    if name == "static":
        return static_trace(duration_s, position=home, pitch_deg=frame.home_pitch_deg, name=name)
    if name == "turn":
        return head_turn_trace(duration_s, seed=3, position=home, amp_deg=(30.0, 60.0), pitch_amp_deg=8.0, name=name,
                               base_pitch_deg=frame.home_pitch_deg)
    if name == "strafe":
        return strafe_trace(duration_s, seed=4, start=home, x_limit_m=max(0.3, min(2.5, frame.footprint_m)), name=name,
                            base_pitch_deg=frame.home_pitch_deg)
    raise TraceError(f"no fitted version of trace {name!r}")


# ---------------------------------------------------------------------------------
# Built-in traces
# ---------------------------------------------------------------------------------

DEFAULT_TRACE = "walk"
DEFAULT_DURATION_S = 10.0

BUILTIN_TRACES: dict[str, Callable[[float], CameraTrace]] = {
    "walk": lambda d: walk_trace(d, speed_mps=1.4, seed=1, name="walk"),
    "walk_fast": lambda d: walk_trace(d, speed_mps=3.0, seed=2, name="walk_fast"),
    "turn": lambda d: head_turn_trace(d, seed=3, name="turn"),
    "strafe": lambda d: strafe_trace(d, seed=4, name="strafe"),
    "static": lambda d: static_trace(d, name="static"),
    "orbit": lambda d: orbit_trace(d, seed=5, name="orbit"),
}
"""Named traces for the default scene: name -> factory(duration_s)."""


def get_trace(name: str, duration_s: float | None = None, scene: "Scene | None" = None, fov_y_deg: float = 60.0,
              aspect: float = 16 / 9) -> CameraTrace:
    """A built-in trace by name, or a trace file by path.

    Paths ending ``.csv`` load the v1 format; ``.txt`` / ``.path`` load QUASAR paths.
    ``duration_s`` (seconds, default 10) applies to built-in traces; a file is cut to
    it when given.  Unknown names raise :class:`TraceError` listing the valid ones.
    With a ``scene`` that has a :attr:`~splitrender.scene.model.Scene.subject` (a
    loaded model), built-in traces are placed around it (:func:`fitted_trace`, for a
    camera of ``fov_y_deg`` and ``aspect`` = width / height); the built-in scenes keep
    the fixed traces.  Trace files are never moved.
    """
    lower = name.lower()
    subject = getattr(scene, "subject", None)
    if subject is not None and name in BUILTIN_TRACES and not lower.endswith((".csv", ".txt", ".path")):
        frame = frame_subject(subject[0], subject[1], fov_y_deg, aspect)
        return fitted_trace(name, frame, DEFAULT_DURATION_S if duration_s is None else float(duration_s))
    if lower.endswith(".csv"):
        trace = CameraTrace.load(name)
    elif lower.endswith((".txt", ".path")):
        trace = load_quasar_path(name)
    elif name in BUILTIN_TRACES:
        return BUILTIN_TRACES[name](DEFAULT_DURATION_S if duration_s is None else float(duration_s))
    else:
        valid = ", ".join(sorted(BUILTIN_TRACES))
        raise TraceError(f"unknown trace {name!r}; valid names: {valid} (or a .csv / .txt / .path file)")
    if duration_s is not None and duration_s < trace.duration_s:
        keep = trace.t_s <= duration_s
        if int(keep.sum()) < 2:
            raise TraceError(f"{name}: duration_s={duration_s!r} leaves fewer than 2 samples")
        trace = CameraTrace(trace.t_s[keep], trace.positions[keep], trace.orientations[keep], name=trace.name)
    return trace


__all__ = [
    "BUILTIN_TRACES",
    "CameraTrace",
    "DEFAULT_BOX_XZ",
    "DEFAULT_START",
    "DEFAULT_TRACE",
    "FIT_FILL",
    "TraceFrame",
    "fitted_trace",
    "frame_subject",
    "walk_around_trace",
    "TRACE_HEADER",
    "TRACE_MAGIC",
    "TRACKER_RATE_HZ",
    "get_trace",
    "head_turn_trace",
    "load_quasar_path",
    "orbit_trace",
    "parse_quasar_path_text",
    "parse_trace_text",
    "quasar_path_text",
    "quat_to_euler_deg",
    "quat_from_glm_euler_deg",
    "glm_euler_deg",
    "save_quasar_path",
    "static_trace",
    "strafe_trace",
    "walk_trace",
]
