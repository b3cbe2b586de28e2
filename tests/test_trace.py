"""Camera traces: file formats, interpolation, generators, built-in registry."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from splitrender.errors import TraceError
from splitrender.scene.pose import Pose, quat_from_euler_deg
from splitrender.scene.trace import (
    BUILTIN_TRACES,
    DEFAULT_BOX_XZ,
    TRACE_HEADER,
    TRACE_MAGIC,
    CameraTrace,
    get_trace,
    head_turn_trace,
    load_quasar_path,
    parse_quasar_path_text,
    parse_trace_text,
    quat_to_euler_deg,
    save_quasar_path,
    static_trace,
    walk_trace,
)


def _yaw_trace() -> CameraTrace:
    q0 = quat_from_euler_deg(0, 0, 0)
    q1 = quat_from_euler_deg(0, 90, 0)
    return CameraTrace(np.array([0.0, 1.0]), np.array([[0, 1.6, 0], [2, 1.6, 0]]), np.array([q0, q1]), name="yaw")


# -- file round trips -------------------------------------------------------------


def test_save_load_round_trip_bit_exact(tmp_path: Path) -> None:
    tr = get_trace("walk", duration_s=2.0)
    path = tmp_path / "walk.csv"
    tr.save(path)
    text = path.read_text()
    assert text.splitlines()[:2] == [TRACE_MAGIC, TRACE_HEADER]
    back = CameraTrace.load(path)
    assert len(back) == len(tr) == 241
    assert np.max(np.abs(back.t_s - tr.t_s)) <= 1e-9
    assert np.max(np.abs(back.positions - tr.positions)) <= 1e-9
    assert np.max(np.abs(back.orientations - tr.orientations)) <= 1e-9
    assert np.array_equal(back.positions, tr.positions)  # repr floats: exactly equal
    assert back.name == "walk"


def test_load_rebases_time_and_normalises_quaternions(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    path.write_text(f"{TRACE_MAGIC}\n{TRACE_HEADER}\n5,0,0,0,0,0,0,2\n\n# comment\n5.5,1,0,0,0,0,0,1\n")
    tr = CameraTrace.load(path)
    assert tr.t_s.tolist() == [0.0, 0.5]
    assert tr.orientations[0].tolist() == [0.0, 0.0, 0.0, 1.0]


def test_quasar_path_round_trip(tmp_path: Path) -> None:
    tr = get_trace("turn", duration_s=2.0)
    path = tmp_path / "turn.txt"
    save_quasar_path(tr, path)
    first_data = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")][0]
    assert len(first_data.split()) == 7
    back = load_quasar_path(path)
    assert len(back) == len(tr)
    assert np.max(np.abs(back.t_s - tr.t_s)) <= 1e-9
    assert np.max(np.abs(back.positions - tr.positions)) <= 1e-9
    # Compare quaternions directly (acos-based angles have a ~1e-6 deg floor); q == -q.
    qa, qb = back.orientations, tr.orientations
    worst = float(np.max(np.minimum(np.abs(qa - qb).max(axis=1), np.abs(qa + qb).max(axis=1))))
    assert worst <= 1e-9, f"orientation round trip error {worst:.3g}"


def test_quasar_path_for_quasar_s_own_reader_has_no_header_and_round_trips(tmp_path: Path) -> None:
    """What QUASAR's simulators read (issue 38): seven numbers a line, no comment line; our trace to that format and
    back keeps every pose to 1e-6 (metres, and quaternion components)."""
    tr = get_trace("walk", duration_s=2.0)
    path = tmp_path / "walk_path.txt"
    save_quasar_path(tr, path, header=False)
    lines = path.read_text().splitlines()
    assert len(lines) == len(tr) and all(len(ln.split()) == 7 and not ln.startswith("#") for ln in lines)
    assert all(float(v) == float(v) for ln in lines for v in ln.split())     # every token a number
    back = load_quasar_path(path)
    assert np.max(np.abs(back.positions - tr.positions)) <= 1e-6 and np.max(np.abs(back.t_s - tr.t_s)) <= 1e-9
    qa, qb = back.orientations, tr.orientations
    assert float(np.max(np.minimum(np.abs(qa - qb).max(axis=1), np.abs(qa + qb).max(axis=1)))) <= 1e-6


def test_quasar_path_angles_are_read_as_glm_makes_them() -> None:
    """QUASAR's CameraAnimator: ``glm::quat(radians(vec3(rx, ry, rz)))``, R = Rz Ry Rx, as the camera-to-world
    rotation; glm's own component formula written out here (not our axis-angle products) for a line with roll."""
    from splitrender.scene.trace import glm_euler_deg, quat_from_glm_euler_deg

    rx, ry, rz = 20.0, 30.0, 40.0
    cx, cy, cz = (math.cos(math.radians(a) / 2) for a in (rx, ry, rz))
    sx, sy, sz = (math.sin(math.radians(a) / 2) for a in (rx, ry, rz))
    glm = np.array([sx * cy * cz - cx * sy * sz, cx * sy * cz + sx * cy * sz, cx * cy * sz - sx * sy * cz,
                    cx * cy * cz + sx * sy * sz])                     # glm's (x, y, z, w)
    tr = parse_quasar_path_text(f"1 2 3 {rx} {ry} {rz} 0\n1 2 3 0 90 5 10\n", source="p.txt")
    assert np.allclose(tr.orientations[0], glm, atol=1e-12) or np.allclose(tr.orientations[0], -glm, atol=1e-12)
    for q in tr.orientations:       # the writer's angles give the same rotation back, the gimbal lock at ry 90 too
        back = quat_from_glm_euler_deg(*glm_euler_deg(q))
        assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9


def test_quasar_path_parses_peer_format() -> None:
    # The QUASAR repository's paths: "px py pz rx ry rz t_ms" per frame (rx pitch, ry yaw).
    text = "# a comment\n0.0 3.0 10.0 0.0 0.0 0.0 16.6667\n\n0.0 3.0 10.0 10.0 90.0 0.0 33.3333  # inline\n"
    tr = parse_quasar_path_text(text, source="p.txt")
    assert tr.t_s[0] == 0.0 and tr.t_s[1] == pytest.approx(0.0166666, abs=1e-9)
    assert tr.positions[1].tolist() == [0.0, 3.0, 10.0]
    # yaw +90 turns left: the camera looks down -X.
    assert np.allclose(tr.pose(1).forward(), [-math.cos(math.radians(10)), math.sin(math.radians(10)), 0.0], atol=1e-12)


@pytest.mark.parametrize("pitch,yaw,roll", [(0, 0, 0), (10, 45, -5), (-80, 170, 30), (30, -120, 179), (89.9, 10, 0)])
def test_quat_to_euler_inverts_quat_from_euler(pitch: float, yaw: float, roll: float) -> None:
    p, y, r = quat_to_euler_deg(quat_from_euler_deg(pitch, yaw, roll))
    assert (p, y, r) == pytest.approx((pitch, yaw, roll), abs=1e-6)


# -- malformed files ----------------------------------------------------------------

GOOD = f"{TRACE_MAGIC}\n{TRACE_HEADER}\n0,0,1.6,2.5,0,0,0,1\n0.1,0,1.6,2.4,0,0,0,1\n"

MALFORMED = {
    "version": (GOOD.replace("v1", "v2"), 1, "unsupported trace version"),
    "magic": ("hello\n" + GOOD.split("\n", 1)[1], 1, "expected '# splitrender-trace v1'"),
    "header": (GOOD.replace(TRACE_HEADER, "t,x,y,z,qx,qy,qz,qw"), 2, "expected header"),
    "columns": (GOOD.replace("0.1,0,1.6,2.4,0,0,0,1", "0.1,0,1.6,2.4,0,0,1"), 4, "expected 8 columns, got 7"),
    "not_a_number": (GOOD.replace("0.1,0,1.6,2.4", "0.1,zero,1.6,2.4"), 4, "column px: not a number: 'zero'"),
    "nan": (GOOD.replace("0.1,0,1.6,2.4", "0.1,0,nan,2.4"), 4, "column py: value must be finite"),
    "time_order": (GOOD.replace("0.1,0,1.6,2.4", "0,0,1.6,2.4"), 4, "is not after the previous sample"),
    "zero_quat": (GOOD.replace("0.1,0,1.6,2.4,0,0,0,1", "0.1,0,1.6,2.4,0,0,0,0"), 4, "zero-length quaternion"),
    "one_sample": (f"{TRACE_MAGIC}\n{TRACE_HEADER}\n0,0,1.6,2.5,0,0,0,1\n", 3, "at least 2 samples, found 1"),
    "empty": ("", 1, "expected '# splitrender-trace v1'"),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_csv_names_file_and_line(tmp_path: Path, case: str) -> None:
    text, line, what = MALFORMED[case]
    path = tmp_path / f"{case}.csv"
    path.write_text(text)
    with pytest.raises(TraceError) as exc:
        CameraTrace.load(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}:{line}: "), msg
    assert what in msg


QUASAR_MALFORMED = {
    "columns": ("0 1 2 0 0 0 0\n0 1 2 0 0 0\n", 2, "expected 7 columns"),
    "number": ("0 1 2 0 0 0 0\n0 1 x 0 0 0 10\n", 2, "column pz: not a number"),
    "inf": ("0 1 2 0 0 0 0\n0 1 2 inf 0 0 10\n", 2, "column rx: value must be finite"),
    "time": ("0 1 2 0 0 0 10\n0 1 2 0 0 0 10\n", 2, "is not after"),
    "one": ("# only\n0 1 2 0 0 0 10\n", 2, "at least 2 samples"),
}


@pytest.mark.parametrize("case", sorted(QUASAR_MALFORMED))
def test_malformed_quasar_path_names_file_and_line(tmp_path: Path, case: str) -> None:
    text, line, what = QUASAR_MALFORMED[case]
    path = tmp_path / f"{case}.txt"
    path.write_text(text)
    with pytest.raises(TraceError) as exc:
        load_quasar_path(path)
    assert str(exc.value).startswith(f"{path}:{line}: "), str(exc.value)
    assert what in str(exc.value)


def test_missing_and_binary_files(tmp_path: Path) -> None:
    missing = tmp_path / "nope.csv"
    with pytest.raises(TraceError, match="nope.csv: trace file not found"):
        CameraTrace.load(missing)
    with pytest.raises(TraceError, match="nope.txt: trace file not found"):
        load_quasar_path(tmp_path / "nope.txt")
    binary = tmp_path / "bin.csv"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(TraceError, match="bin.csv: trace file is not UTF-8"):
        CameraTrace.load(binary)


_line = st.one_of(
    st.text(max_size=40),
    st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.text(max_size=5)), max_size=9).map(",".join),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_line, max_size=6), st.booleans())
def test_fuzz_load_parses_or_raises_trace_error(lines: list[str], with_header: bool) -> None:
    text = "\n".join(([TRACE_MAGIC, TRACE_HEADER] if with_header else []) + lines)
    try:
        tr = parse_trace_text(text, source="fuzz.csv")
    except TraceError as exc:
        assert str(exc).startswith("fuzz.csv:") or str(exc).startswith("trace ")
        return
    assert len(tr) >= 2 and tr.t_s[0] == 0.0 and np.all(np.diff(tr.t_s) > 0)
    assert np.allclose(np.linalg.norm(tr.orientations, axis=1), 1.0)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.text(max_size=40), max_size=6))
def test_fuzz_quasar_parses_or_raises_trace_error(lines: list[str]) -> None:
    try:
        parse_quasar_path_text("\n".join(lines), source="fuzz.txt")
    except TraceError:
        pass


def test_constructor_validates() -> None:
    q = np.array([[0, 0, 0, 1.0]] * 2)
    p = np.zeros((2, 3))
    with pytest.raises(TraceError, match="must start at 0"):
        CameraTrace(np.array([0.5, 1.0]), p, q)
    with pytest.raises(TraceError, match="not strictly increasing"):
        CameraTrace(np.array([0.0, 0.0]), p, q)
    with pytest.raises(TraceError, match="shape"):
        CameraTrace(np.array([0.0, 1.0]), np.zeros((2, 2)), q)


# -- interpolation ------------------------------------------------------------------


def test_midpoint_of_90_degree_yaw_is_45() -> None:
    tr = _yaw_trace()
    mid = tr.pose_at(0.5)
    assert mid.angle_deg(Pose(orientation=quat_from_euler_deg(0, 45, 0))) < 1e-9
    assert mid.position.tolist() == pytest.approx([1.0, 1.6, 0.0])
    # clamped at the ends
    assert tr.pose_at(-1.0).angle_deg(tr.pose(0)) == 0.0
    assert tr.pose_at(7.0).distance_m(tr.pose(1)) == 0.0
    assert tr.angular_speed_deg_s_at(0.5) == pytest.approx(90.0, rel=1e-6)
    assert tr.velocity_at(0.5).tolist() == pytest.approx([2.0, 0.0, 0.0])


def test_sample_resamples() -> None:
    tr = _yaw_trace().sample(10.0)
    assert len(tr) == 11 and tr.t_s[-1] == pytest.approx(1.0)
    assert tr.pose(5).angle_deg(Pose(orientation=quat_from_euler_deg(0, 45, 0))) < 1e-9


# -- generators -----------------------------------------------------------------------


def _in_box(tr: CameraTrace) -> tuple[bool, str]:
    (x0, x1), (z0, z1) = DEFAULT_BOX_XZ
    p = tr.positions
    desc = f"x [{p[:, 0].min():.2f}, {p[:, 0].max():.2f}] z [{p[:, 2].min():.2f}, {p[:, 2].max():.2f}] y [{p[:, 1].min():.3f}, {p[:, 1].max():.3f}]"
    ok = x0 <= p[:, 0].min() and p[:, 0].max() <= x1 and z0 <= p[:, 2].min() and p[:, 2].max() <= z1
    ok = ok and 1.5 <= p[:, 1].min() and p[:, 1].max() <= 1.8
    return ok, desc


@pytest.mark.parametrize("name", sorted(BUILTIN_TRACES))
def test_builtin_traces_stay_in_the_scene_box(name: str) -> None:
    tr = get_trace(name)
    assert tr.name == name and tr.duration_s == pytest.approx(10.0)
    ok, desc = _in_box(tr)
    assert ok, f"{name}: {desc}"


@pytest.mark.parametrize("name,lo,hi", [("walk", 1.2, 1.5), ("walk_fast", 2.5, 3.1)])
def test_walk_speed(name: str, lo: float, hi: float) -> None:
    tr = get_trace(name)
    lin, ang = tr.sample_speeds()
    mean = float(lin.mean())
    assert 1.0 <= mean <= 4.0 and lo <= mean <= hi, f"{name}: mean speed {mean:.2f} m/s"
    start = tr.pose(0)
    assert start.position.tolist() == pytest.approx([0.0, 1.6, 2.5], abs=0.03)
    assert abs(math.degrees(math.atan2(-start.forward()[0], -start.forward()[2]))) < 1e-6  # yaw 0


def test_walk_gait_bob() -> None:
    tr = get_trace("walk")
    y = tr.positions[:, 1] - tr.positions[:, 1].mean()
    spectrum = np.abs(np.fft.rfft(y))
    freqs = np.fft.rfftfreq(len(y), d=1 / 120)
    peak_hz = float(freqs[np.argmax(spectrum[1:]) + 1])
    amp_cm = float((y.max() - y.min()) / 2 * 100)
    assert 1.6 <= peak_hz <= 2.4, f"bob at {peak_hz:.2f} Hz"
    assert 1.0 <= amp_cm <= 2.0, f"bob amplitude {amp_cm:.2f} cm"


@pytest.mark.parametrize("speed", [1.0, 2.0, 4.0])
@pytest.mark.parametrize("seed", range(4))
def test_walk_stays_in_box_for_many_seeds(speed: float, seed: int) -> None:
    tr = walk_trace(12.0, speed_mps=speed, seed=seed)
    ok, desc = _in_box(tr)
    assert ok, f"speed {speed} seed {seed}: {desc}"
    assert 0.9 * speed <= float(tr.sample_speeds()[0].mean()) <= 1.1 * speed


def test_turn_trace_peak_angular_speed() -> None:
    tr = get_trace("turn")
    lin, ang = tr.sample_speeds()
    assert float(ang.max()) >= 300.0, f"peak {ang.max():.0f} deg/s"
    assert float(lin.max()) < 0.2, "standing: body barely moves"
    walk_peak = float(get_trace("walk").sample_speeds()[1].max())
    assert 100.0 <= walk_peak <= 260.0, f"walk head turns peak {walk_peak:.0f} deg/s"


def test_generators_are_deterministic_for_a_seed() -> None:
    a, b = walk_trace(3.0, seed=7), walk_trace(3.0, seed=7)
    c = walk_trace(3.0, seed=8)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.orientations, b.orientations)
    assert not np.array_equal(a.positions, c.positions)
    assert np.array_equal(head_turn_trace(3.0, seed=1).orientations, head_turn_trace(3.0, seed=1).orientations)
    assert np.array_equal(get_trace("strafe").positions, get_trace("strafe").positions)


def test_static_trace_does_not_move() -> None:
    lin, ang = static_trace(2.0).sample_speeds()
    assert lin.max() == 0.0 and ang.max() == 0.0


def test_strafe_moves_sideways() -> None:
    tr = get_trace("strafe")
    span = tr.positions.max(axis=0) - tr.positions.min(axis=0)
    assert span[0] > 1.5 and span[2] < 0.2, f"span {span}"


# -- registry -----------------------------------------------------------------------------


def test_get_trace_unknown_lists_names() -> None:
    with pytest.raises(TraceError) as exc:
        get_trace("jog")
    msg = str(exc.value)
    assert "unknown trace 'jog'" in msg
    for name in ("walk", "walk_fast", "turn", "strafe", "static", "orbit"):
        assert name in msg


def test_get_trace_duration_and_files(tmp_path: Path) -> None:
    assert get_trace("walk", duration_s=2.0).duration_s == pytest.approx(2.0)
    tr = get_trace("orbit", duration_s=3.0)
    tr.save(tmp_path / "o.csv")
    save_quasar_path(tr, tmp_path / "o.path")
    assert len(get_trace(str(tmp_path / "o.csv"))) == len(tr)
    assert len(get_trace(str(tmp_path / "o.path"))) == len(tr)
    assert get_trace(str(tmp_path / "o.csv"), duration_s=1.0).duration_s <= 1.0
