"""Poses, quaternions and camera intrinsics.

Conventions (used everywhere in splitrender):

- World space is right-handed, metres, +Y up.
- A camera looks down its local -Z axis with +Y up and +X right (OpenGL).
- Quaternions are stored ``(x, y, z, w)`` (glTF / scipy order) and are unit length.
- ``Pose.matrix()`` is camera-to-world; ``Pose.view_matrix()`` is world-to-camera.
- Matrices are 4x4 float64 numpy arrays acting on column vectors.
- Yaw is a rotation about +Y, pitch about the camera's +X, roll about its -Z view axis;
  all in radians unless a name ends in ``_deg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


def quat_normalize(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    return q / np.where(n == 0, 1.0, n)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (apply b first, then a)."""
    ax, ay, az, aw = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    bx, by, bz, bw = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def quat_conj(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def quat_from_axis_angle(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    s = math.sin(angle_rad / 2.0)
    return np.array([axis[0] * s, axis[1] * s, axis[2] * s, math.cos(angle_rad / 2.0)])


def quat_to_matrix3(q: np.ndarray) -> np.ndarray:
    x, y, z, w = quat_normalize(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_from_matrix3(m: np.ndarray) -> np.ndarray:
    """Rotation matrix (3x3, orthonormal) to unit quaternion (x, y, z, w), w >= 0."""
    m = np.asarray(m, dtype=np.float64)
    t = m[0, 0] + m[1, 1] + m[2, 2]
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    qa = quat_normalize(np.array(q))
    return qa if qa[3] >= 0 else -qa


def quat_slerp(a: np.ndarray, b: np.ndarray, u: float) -> np.ndarray:
    """Spherical interpolation from a (u=0) to b (u=1); u may extrapolate beyond [0, 1]."""
    a = quat_normalize(a)
    b = quat_normalize(b)
    d = float(np.dot(a, b))
    if d < 0:
        b, d = -b, -d
    if d > 0.9995:
        return quat_normalize(a + u * (b - a))
    theta = math.acos(min(1.0, d))
    # Extrapolation works by rotating further along the same great circle.
    rel = quat_mul(b, quat_conj(a))
    axis = rel[:3]
    n = np.linalg.norm(axis)
    if n < 1e-12:
        return a
    ang = 2 * math.atan2(n, rel[3])
    return quat_normalize(quat_mul(quat_from_axis_angle(axis / n, ang * u), a)) if abs(theta) > 0 else a


def quat_angle_rad(a: np.ndarray, b: np.ndarray) -> float:
    """Rotation angle between two orientations, radians in [0, pi]."""
    d = abs(float(np.dot(quat_normalize(a), quat_normalize(b))))
    return 2.0 * math.acos(min(1.0, d))


def quat_from_euler_deg(pitch_deg: float, yaw_deg: float, roll_deg: float) -> np.ndarray:
    """Orientation from yaw (about +Y), then pitch (about +X), then roll (about -Z view).

    The composed rotation is ``R = R_yaw * R_pitch * R_roll`` (roll applied first in
    camera space).  Yaw 0 looks down -Z; positive yaw turns left (towards -X).
    """
    qy = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), math.radians(yaw_deg))
    qp = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(pitch_deg))
    qr = quat_from_axis_angle(np.array([0.0, 0.0, -1.0]), math.radians(roll_deg))
    return quat_normalize(quat_mul(qy, quat_mul(qp, qr)))


def look_at_quat(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 1.0, 0.0])) -> np.ndarray:
    """Orientation of a camera at ``eye`` looking at ``target`` (no roll)."""
    f = np.asarray(target, dtype=np.float64) - np.asarray(eye, dtype=np.float64)
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    if np.linalg.norm(r) < 1e-9:
        r = np.array([1.0, 0.0, 0.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    m = np.stack([r, u, -f], axis=1)
    return quat_from_matrix3(m)


@dataclass(frozen=True)
class Pose:
    """A rigid pose: position (metres, world) and orientation (unit quaternion x,y,z,w)."""

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    orientation: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", np.asarray(self.position, dtype=np.float64).reshape(3))
        object.__setattr__(self, "orientation", quat_normalize(np.asarray(self.orientation, dtype=np.float64).reshape(4)))

    def matrix(self) -> np.ndarray:
        """Local-to-world 4x4 (camera-to-world for a camera)."""
        m = np.eye(4)
        m[:3, :3] = quat_to_matrix3(self.orientation)
        m[:3, 3] = self.position
        return m

    def view_matrix(self) -> np.ndarray:
        """World-to-camera 4x4."""
        r = quat_to_matrix3(self.orientation)
        m = np.eye(4)
        m[:3, :3] = r.T
        m[:3, 3] = -r.T @ self.position
        return m

    def forward(self) -> np.ndarray:
        return quat_to_matrix3(self.orientation) @ np.array([0.0, 0.0, -1.0])

    def to_list(self) -> list[float]:
        return [*map(float, self.position), *map(float, self.orientation)]

    @staticmethod
    def from_list(v: "list[float] | np.ndarray") -> "Pose":
        v = list(v)
        return Pose(np.array(v[:3]), np.array(v[3:7]))

    def distance_m(self, other: "Pose") -> float:
        return float(np.linalg.norm(self.position - other.position))

    def angle_deg(self, other: "Pose") -> float:
        return math.degrees(quat_angle_rad(self.orientation, other.orientation))


@dataclass(frozen=True)
class CameraIntrinsics:
    """A symmetric perspective camera.  ``fov_y_deg`` is the full vertical field of view."""

    width: int = 640
    height: int = 360
    fov_y_deg: float = 60.0
    near_m: float = 0.05
    far_m: float = 100.0

    @property
    def aspect(self) -> float:
        return self.width / self.height

    @property
    def fov_x_deg(self) -> float:
        return math.degrees(2 * math.atan(math.tan(math.radians(self.fov_y_deg) / 2) * self.aspect))

    def projection(self) -> np.ndarray:
        """OpenGL projection matrix (clip z in [-1, 1])."""
        f = 1.0 / math.tan(math.radians(self.fov_y_deg) / 2.0)
        n, fa = self.near_m, self.far_m
        p = np.zeros((4, 4))
        p[0, 0] = f / self.aspect
        p[1, 1] = f
        p[2, 2] = (fa + n) / (n - fa)
        p[2, 3] = 2 * fa * n / (n - fa)
        p[3, 2] = -1.0
        return p

    def focal_px(self) -> float:
        """Focal length in pixels (square pixels)."""
        return self.height / 2.0 / math.tan(math.radians(self.fov_y_deg) / 2.0)

    def enlarged(self, factor: float, keep_pixel_density: bool = True) -> "CameraIntrinsics":
        """The same camera with its image plane extent scaled by ``factor`` (overscan).

        With ``keep_pixel_density`` the resolution grows too so pixels keep their size.
        """
        half = math.tan(math.radians(self.fov_y_deg) / 2.0) * factor
        fov = math.degrees(2 * math.atan(half))
        if keep_pixel_density:
            w = int(round(self.width * factor / 2)) * 2
            h = int(round(self.height * factor / 2)) * 2
        else:
            w, h = self.width, self.height
        return CameraIntrinsics(w, h, fov, self.near_m, self.far_m)
