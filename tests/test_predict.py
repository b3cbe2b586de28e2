"""Pose predictors: exactness on kinematic trajectories, accuracy on built-in traces."""

from __future__ import annotations

import math

import numpy as np
import pytest

from splitrender.errors import ConfigError
from splitrender.scene.pose import Pose, quat_from_axis_angle, quat_from_euler_deg
from splitrender.scene.predict import (
    PREDICTOR_NAMES,
    ConstantAccelerationPredictor,
    ConstantVelocityPredictor,
    NoObservationError,
    NoPrediction,
    PerfectPredictor,
    PredictionLog,
    evaluate_predictor,
    make_predictor,
    prediction_error,
    quat_to_rotvec,
    rotvec_to_quat,
)
from splitrender.scene.trace import get_trace

AXIS = np.array([0.3, 1.0, -0.2]) / np.linalg.norm([0.3, 1.0, -0.2])


def _linear(t: float) -> Pose:
    """1.5 m/s along a diagonal, 60 deg/s about a fixed axis."""
    return Pose(np.array([0.1, 1.6, 2.5]) + t * np.array([1.0, 0.2, -1.1]), quat_from_axis_angle(AXIS, math.radians(60.0) * t))


def _parabola(t: float) -> Pose:
    """Constant linear acceleration and constant angular acceleration about a fixed axis."""
    p = np.array([0.0, 1.6, 2.5]) + t * np.array([0.5, 0.0, -1.0]) + 0.5 * t * t * np.array([2.0, -0.3, 1.0])
    ang = math.radians(20.0 * t + 0.5 * 150.0 * t * t)
    return Pose(p, quat_from_axis_angle(AXIS, ang))


def _feed(pred, fn, ts) -> None:  # type: ignore[no-untyped-def]
    for t in ts:
        pred.observe(float(t), fn(float(t)))


# Uneven spacing on purpose (jittered arrival).
TIMES = np.cumsum([0.0, 0.008, 0.011, 0.006, 0.0083, 0.0095, 0.007, 0.012, 0.008, 0.0081, 0.009])


@pytest.mark.parametrize("name", ["cv", "cv_savgol", "ca", "ca_savgol"])
@pytest.mark.parametrize("horizon_s", [0.02, 0.05, 0.1])
def test_kinematic_predictors_exact_on_linear_motion(name: str, horizon_s: float) -> None:
    pred = make_predictor(name)
    _feed(pred, _linear, TIMES)
    t = float(TIMES[-1]) + horizon_s
    cm, deg = prediction_error(pred.predict(t), _linear(t))
    assert cm < 1e-6 and deg < 1e-4, f"{name} @ {horizon_s * 1000:.0f} ms: {cm:.3g} cm, {deg:.3g} deg"


@pytest.mark.parametrize("name", ["ca", "ca_savgol"])
@pytest.mark.parametrize("horizon_s", [0.02, 0.05, 0.1])
def test_constant_acceleration_exact_on_parabola(name: str, horizon_s: float) -> None:
    pred = make_predictor(name)
    _feed(pred, _parabola, TIMES)
    t = float(TIMES[-1]) + horizon_s
    cm, deg = prediction_error(pred.predict(t), _parabola(t))
    assert cm < 1e-6 and deg < 1e-4, f"{name} @ {horizon_s * 1000:.0f} ms: {cm:.3g} cm, {deg:.3g} deg"
    # ... where constant velocity is not.
    cv = make_predictor("cv")
    _feed(cv, _parabola, TIMES)
    cv_cm, _ = prediction_error(cv.predict(t), _parabola(t))
    assert cv_cm > 100 * max(cm, 1e-6), f"cv {cv_cm:.3g} cm vs ca {cm:.3g} cm"


def test_no_prediction_returns_last_pose_and_stale_samples_are_ignored() -> None:
    pred = NoPrediction()
    with pytest.raises(NoObservationError):
        pred.predict(0.0)
    pred.observe(0.1, _linear(0.1))
    pred.observe(0.1, _linear(5.0))  # duplicate time: ignored
    pred.observe(0.05, _linear(7.0))  # out of order: ignored
    assert pred.predict(1.0).distance_m(_linear(0.1)) == 0.0
    assert pred.last_t_s == 0.1


def test_out_of_order_samples_do_not_disturb_cv() -> None:
    pred = ConstantVelocityPredictor()
    _feed(pred, _linear, TIMES)
    pred.observe(float(TIMES[2]), Pose(np.array([9.0, 9.0, 9.0])))  # stale, wildly wrong
    t = float(TIMES[-1]) + 0.05
    assert prediction_error(pred.predict(t), _linear(t))[0] < 1e-6


def test_single_observation_falls_back_to_holding() -> None:
    for name in ("cv", "ca", "cv_savgol", "ca_savgol"):
        pred = make_predictor(name)
        pred.observe(0.0, _linear(0.0))
        assert pred.predict(0.1).distance_m(_linear(0.0)) == 0.0, name


def test_clamps_horizon_and_angle() -> None:
    pred = ConstantVelocityPredictor(max_horizon_s=0.1, max_angle_deg=5.0)
    _feed(pred, _linear, TIMES)
    far = pred.predict(float(TIMES[-1]) + 10.0)
    expect = _linear(float(TIMES[-1]) + 0.1)
    assert far.distance_m(expect) < 1e-9  # held at 100 ms
    assert far.angle_deg(_linear(float(TIMES[-1]))) == pytest.approx(5.0, abs=1e-6)  # 60 deg/s * 0.1 s capped at 5
    # Asking for the past returns the newest pose rather than rewinding.
    assert pred.predict(0.0).distance_m(_linear(float(TIMES[-1]))) < 1e-9


def test_rotvec_round_trip() -> None:
    for pitch, yaw, roll in [(0, 0, 0), (10, 170, -20), (-45, -90, 5)]:
        q = quat_from_euler_deg(pitch, yaw, roll)
        assert Pose(orientation=rotvec_to_quat(quat_to_rotvec(q))).angle_deg(Pose(orientation=q)) < 1e-6


def test_make_predictor_names_and_errors() -> None:
    assert isinstance(make_predictor("none"), NoPrediction)
    assert isinstance(make_predictor("cv"), ConstantVelocityPredictor)
    ca = make_predictor("ca_savgol", window=7, polyorder=3)
    assert isinstance(ca, ConstantAccelerationPredictor) and ca.smoothing == "savgol" and ca.window == 7
    with pytest.raises(ConfigError, match=r"unknown predictor 'kalman'; valid names: none, cv, ca, cv_savgol, ca_savgol, perfect"):
        make_predictor("kalman")
    with pytest.raises(ConfigError, match="polyorder must be >= 2"):
        make_predictor("ca_savgol", polyorder=1)
    with pytest.raises(ConfigError, match="bad arguments"):
        make_predictor("cv", windw=3)
    with pytest.raises(ConfigError, match="smoothing must be"):
        ConstantVelocityPredictor(smoothing="kalman")  # type: ignore[arg-type]
    assert set(PREDICTOR_NAMES) == {"none", "cv", "ca", "cv_savgol", "ca_savgol", "perfect"}


def test_perfect_predictor_reads_the_trace() -> None:
    tr = get_trace("turn", duration_s=2.0)
    pred = make_predictor("perfect", trace=tr)
    assert isinstance(pred, PerfectPredictor)
    pred.observe(0.5, tr.pose_at(0.5))
    assert prediction_error(pred.predict(1.234), tr.pose_at(1.234)) == (0.0, 0.0)


def test_prediction_log() -> None:
    log = PredictionLog()
    log.record(0.1, 50.0, Pose(np.array([0.0, 0.0, 0.0])), Pose(np.array([0.03, 0.04, 0.0])))
    log.record(0.2, 50.0, Pose(), Pose(orientation=quat_from_euler_deg(0, 10, 0)))
    assert log.rows()[0] == pytest.approx((0.1, 50.0, 5.0, 0.0))
    assert log.rows()[1][3] == pytest.approx(10.0)
    s = log.summary()
    assert (s.count, s.mean_cm, s.max_deg) == (2, pytest.approx(2.5), pytest.approx(10.0))
    assert list(log.columns()) == ["t_s", "horizon_ms", "err_cm", "err_deg"]


@pytest.mark.parametrize("horizon_ms", [50, 100])
def test_cv_beats_no_prediction_on_walk(horizon_ms: int) -> None:
    tr = get_trace("walk")
    none = evaluate_predictor(make_predictor("none"), tr, horizon_ms / 1000).summary()
    cv = evaluate_predictor(make_predictor("cv"), tr, horizon_ms / 1000).summary()
    msg = f"walk @ {horizon_ms} ms: none {none}; cv {cv}"
    assert cv.mean_cm < 0.5 * none.mean_cm, msg
    assert cv.mean_deg < 0.5 * none.mean_deg, msg
    # No prediction lags by speed x horizon: ~1.35 m/s x horizon.
    assert none.mean_cm == pytest.approx(1.35 * horizon_ms / 10, rel=0.1), msg


@pytest.mark.parametrize("horizon_ms", [50, 100])
def test_savgol_helps_with_tracker_noise(horizon_ms: int) -> None:
    """With 2 mm / 0.2 deg tracker noise, raw finite differences amplify it; smoothing does not."""
    tr = get_trace("walk", duration_s=4.0)
    kw = dict(noise_cm=0.2, noise_deg=0.2, seed=3)
    res = {n: evaluate_predictor(make_predictor(n), tr, horizon_ms / 1000, **kw).summary() for n in ("none", "cv", "cv_savgol", "ca", "ca_savgol")}
    msg = f"walk+noise @ {horizon_ms} ms: " + "; ".join(f"{n} {s}" for n, s in res.items())
    assert res["cv_savgol"].mean_cm < 0.6 * res["cv"].mean_cm, msg
    assert res["ca_savgol"].mean_cm < 0.5 * res["ca"].mean_cm, msg
    assert res["cv_savgol"].mean_cm < 0.5 * res["none"].mean_cm, msg


def test_turn_trace_prediction_is_hard() -> None:
    """On the fast-turn stress trace even CA leaves degrees of error at 100 ms."""
    tr = get_trace("turn")
    none = evaluate_predictor(make_predictor("none"), tr, 0.1).summary()
    ca = evaluate_predictor(make_predictor("ca"), tr, 0.1).summary()
    msg = f"turn @ 100 ms: none {none}; ca {ca}"
    assert ca.mean_deg < none.mean_deg, msg
    assert ca.max_deg > 10.0, msg
