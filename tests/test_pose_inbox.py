"""The server's one pose rule (``PoseInbox``), which the runner, the live server and the browser session share."""

from __future__ import annotations

import inspect

import numpy as np

from splitrender.pipeline import PoseInbox
from splitrender.scene.pose import Pose
from splitrender.scene.predict import make_predictor


def _pose(x: float) -> Pose:
    return Pose(np.array([x, 0.0, 0.0]), np.array([1.0, 0.0, 0.0, 0.0]))


def test_newer_samples_are_taken_duplicates_and_reordered_ones_counted() -> None:
    inbox = PoseInbox(make_predictor("cv"))
    assert inbox.latest is None and inbox.newer(0.0)
    assert inbox.offer(0.0, _pose(0.0), 0, 1)
    assert not inbox.offer(0.0, _pose(5.0), 0, 2)          # a duplicate time: dropped, even with another pose
    assert inbox.offer(0.1, _pose(1.0), 100_000, 3)
    assert not inbox.offer(0.05, _pose(9.0), 50_000, 4)    # reordered: older than the newest taken
    assert inbox.latest is not None and inbox.latest[0] == 0.1 and inbox.latest[2:] == (100_000, 3)
    assert (inbox.received, inbox.stale) == (4, 2)
    assert inbox.counters() == {"poses_received": 2, "poses_stale": 2}   # what the live and browser sessions report
    # the predictor saw only the two taken samples: it extrapolates 10 m/s from them
    assert np.allclose(inbox.predictor.predict(0.2).position, [2.0, 0.0, 0.0])


def test_every_front_door_uses_it_through_the_core() -> None:
    """The rule was written three times and the copies disagreed (issue 47): the runner took ``ts >= latest``.  Now
    each front door hands its samples to the server core (``ServerSession.receive_pose``, whose PoseInbox applies the
    rule; the live ones the samples as they come: the live server's control bytes to the core, which reads each
    ``Pose`` on its connection (``receive_data``, ``next_message``), the page's through ``receive_pose_sample``) and keeps no inbox or predictor of its own,
    nor a frame clock (the live ones share one, their base's ``LiveSession._make_frame``: the core's ``order_at``, its
    grid tick at the wall clock, made in the worker); the client drivers ask the client core for the
    display rules (``display_tick``: what to apply; ``showing``: the update shown or the black background, and its
    Feedback) and the keyframe-skip rule instead of writing them, and apply and render through ``display_frame``.
    Every server front door makes its frames with a ``FrameMaker`` (the runner's; the render worker's, in its
    ``SessionFrames``) and the core packetizes; the live ones hand the made frame to the core's
    ``frame_from_worker``."""
    from splitrender.client import session as client
    from splitrender.pipeline.live import LiveSession
    from splitrender.server import session as live, worker
    from splitrender.sim import runner
    from splitrender.webrtc import session as browser

    assert ".order_at(" in inspect.getsource(LiveSession._make_frame)   # the live frame tick, written once
    assert issubclass(live.ServerSession, LiveSession) and issubclass(browser.BrowserSession, LiveSession)
    for mod, pose, order in ((runner, ".receive_pose(", ".order_frame("), (live, ".next_message(", "(LiveSession)"),
                             (browser, ".receive_pose_sample(", "(LiveSession)")):
        src = inspect.getsource(mod)
        assert pose in src and order in src and "_last_tick" not in src and "ScenePose(" not in src, mod.__name__
        assert "PoseInbox(" not in src and ".offer(" not in src and ".predict(" not in src, mod.__name__
        assert "ServerContext(" not in src and "KeyframeRateLimiter" not in src, mod.__name__
        # one frame producer (FrameMaker: the half and its encoders; the core packetizes), and the live doors' made
        # frame reported, stamped and rowed by the core
        assert "make_frame(" not in src and "StreamEncoder(" not in src and ".packetize(" not in src, mod.__name__
        assert (".frame_from_worker(" in src) == (mod is not runner), mod.__name__
    from splitrender.pipeline.frames import SessionFrames

    assert "FrameMaker(" in inspect.getsource(runner) and "(SessionFrames)" in inspect.getsource(worker)
    assert "FrameMaker(" in inspect.getsource(SessionFrames)    # the render worker's makers, one per session
    for mod in (runner, client):
        src = inspect.getsource(mod)
        assert ".display_tick(" in src and ".showing(" in src and ".skips_decode(" in src, mod.__name__
        assert ".blank(" not in src and ".feedback(" not in src and ".broken" not in src, mod.__name__
        # the client half's side of a tick is one call (apply, then render or the black background)
        assert "display_frame" in src and "apply_updates" not in src and "half.render(" not in src, mod.__name__


def test_the_server_core_takes_a_pose_message_by_the_rule() -> None:
    """``ServerSession.receive_message`` takes a ``Pose`` as ``receive_pose_sample`` does (the live server hands it
    every control message the core keeps): a reordered or repeated one is counted stale and not observed."""
    from splitrender.codecs.video import VideoCodecConfig
    from splitrender.methods.base import StreamSpec
    from splitrender.pipeline import ServerPipeline, ServerSession
    from splitrender.protocol import Pose as PoseMessage

    tx = ServerPipeline([StreamSpec("color", VideoCodecConfig("h264", gop=300), 64, 36)], rng=np.random.default_rng(1))
    core = ServerSession(tx, 60.0, predictor=make_predictor("cv"))
    for us, seq in ((100_000, 1), (50_000, 2), (100_000, 3), (200_000, 4)):
        assert core.receive_message(PoseMessage(us, seq, (us / 1e5, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), 0.0) is None
    assert core.poses.counters() == {"poses_received": 2, "poses_stale": 2}
    assert core.poses.latest is not None and core.poses.latest[2:] == (200_000, 4)
