"""``splitrender.pipeline.direct``: a method's halves driven without a session, and the only place outside the session
cores that builds a server half's context (issue 47: "no ``ServerContext`` is built outside ``pipeline/``)."""

from __future__ import annotations

import io
import tokenize
from pathlib import Path

import numpy as np
import pytest

from splitrender.methods import ClientFeedback, get_method, make_config
from splitrender.metrics.image import psnr
from splitrender.pipeline import server_context, still_frame
from splitrender.scene.pose import CameraIntrinsics, Pose

ROOT = Path(__file__).resolve().parents[1]
INTR = CameraIntrinsics(64, 36, 60.0, 0.05, 200.0)


def _builds(path: Path) -> list[int]:
    """Lines of ``path`` that call ``ServerContext`` or its former ``at_pose`` (code, not a string that names it)."""
    toks = [t for t in tokenize.generate_tokens(io.StringIO(path.read_text(encoding="utf-8")).readline)
            if t.type in (tokenize.NAME, tokenize.OP)]
    after = [t.string for t in toks[1:]] + ["", ""]
    return [t.start[0] for k, t in enumerate(toks)
            if t.string == "ServerContext" and (after[k] == "(" or after[k:k + 2] == [".", "at_pose"])]


def _walk(t: float) -> Pose:
    return Pose(np.array([t, 1.6, 2.5 - 2.0 * t]))


def test_no_server_context_is_built_outside_the_pipeline() -> None:
    """Benchmarks, studies, tests and every package but ``pipeline`` get their contexts from the session core
    (``FrameOrder.context``) or from ``pipeline.direct``; the methods' ``at_pose`` is gone with them."""
    found = []
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT)
        if not rel.parts[0].startswith(".") and rel.parts[:2] != ("splitrender", "pipeline"):
            found += [f"{rel}:{n}" for n in _builds(path)]
    assert not found, found
    assert len(_builds(ROOT / "splitrender" / "pipeline" / "direct.py")) == 1


def test_a_held_pose_is_the_latest_the_target_and_every_prediction() -> None:
    pose = Pose(np.array([1.0, 2.0, 3.0]))
    fb = ClientFeedback()
    ctx = server_context("scene", "renderer", INTR, pose, t_s=0.5, frame_id=7, keyframe=True, feedback=fb,
                         shared="work", client=2)
    assert (ctx.frame_id, ctx.t_s, ctx.scene, ctx.renderer, ctx.intrinsics) == (7, 0.5, "scene", "renderer", INTR)
    assert ctx.latest_pose is pose and ctx.target_pose is pose and ctx.predict(9.0) is pose
    assert (ctx.latest_pose_t_s, ctx.target_t_s, ctx.expected_latency_s) == (0.5, 0.5, 0.0)
    assert ctx.keyframe_requested and ctx.feedback is fb and ctx.shared == "work" and ctx.client == 2
    plain = server_context("scene", "renderer", INTR, pose)
    assert (plain.frame_id, plain.t_s, plain.keyframe_requested, plain.shared, plain.client) == (0, 0.0, False, None, 0)
    assert plain.feedback == ClientFeedback() and plain.feedback is not server_context(None, None, INTR, pose).feedback


def test_latency_targets_the_pose_predicted_for_the_display_time() -> None:
    ctx = server_context(None, None, INTR, t_s=0.5, predict=_walk, latency_s=0.1)
    assert np.allclose(ctx.latest_pose.position, _walk(0.5).position) and ctx.latest_pose_t_s == 0.5
    assert np.allclose(ctx.target_pose.position, [0.6, 1.6, 1.3]) and ctx.target_t_s == pytest.approx(0.6)
    assert ctx.predict is _walk and ctx.expected_latency_s == 0.1
    held = Pose(np.zeros(3))
    late = server_context(None, None, INTR, held, t_s=1.0, latency_s=0.2)
    assert late.target_pose is held and late.target_t_s == pytest.approx(1.2)
    given = server_context(None, None, INTR, held, t_s=0.5, predict=_walk)   # zero latency: the pose asked for
    assert given.target_pose is held and given.latest_pose is held


def test_bad_context_arguments_are_named() -> None:
    with pytest.raises(ValueError, match="pose, or predict"):
        server_context(None, None, INTR)
    with pytest.raises(ValueError, match="latency_s must be >= 0"):
        server_context(None, None, INTR, Pose(np.zeros(3)), latency_s=-0.01)
    with pytest.raises(ValueError, match="latency_s"):
        server_context(None, None, INTR, Pose(np.zeros(3)), latency_s=float("nan"))


def test_a_still_frame_through_both_halves_with_and_without_the_codecs(renderer) -> None:  # type: ignore[no-untyped-def]
    """``video`` at zero latency shows exactly the ground truth without the codecs; through its H.264 stream it
    shows it within the codec's loss (measured 40.7 dB, 1,171 bytes), and the coded bytes are counted."""
    from splitrender.scene.loader import get_scene

    scene = get_scene("minimal")
    spec = get_method("video")
    cfg = make_config(spec.config, {})
    pose = _walk(0.5)
    truth = renderer.render(scene, 0.5, pose, INTR, ("color",)).color
    raw = still_frame("video", cfg, INTR, scene, renderer, pose, 0.5)
    assert raw.coded_bytes == {} and raw.decoded.planes["color"] is raw.update.planes["color"]
    assert raw.update.frame_id == 0 and raw.update.pose is pose
    assert np.array_equal(raw.frame.color, truth)
    coded = still_frame(spec, cfg, INTR, scene, renderer, pose, 0.5, codec=True, frame_id=3)
    assert coded.decoded.frame_id == 3 and set(coded.coded_bytes) == {"color"} and coded.coded_bytes["color"] > 500
    assert coded.decoded.planes["color"].shape == truth.shape
    assert psnr(coded.frame.color, truth) > 37.0
    assert still_frame(spec, cfg, INTR, scene, renderer, pose, 0.5, render=False).frame is None
