"""QUASAR's residual-error test decided from part of the reference view (issue 49 item 3, ``server.PARTIAL_TEST``),
or from its estimate alone (``server.ESTIMATE_MARGIN_DB``).

The test's squared error only grows with the pixels counted, so the server shades the reference view first only in
the blocks where the cached mesh, drawn in the last colour sent at the reference pose, errs most, and stops when the
pixels drawn from shaded texels alone put the frame under ``reference_error_db``.  It must send the same bytes as
the whole test: the same verdicts, and on a residual frame the reference view's colour shaded in two parts equal to
one pass.  Default scene without GI (not timeless, so the reference view is drawn again every frame), 160x90."""

from __future__ import annotations

import hashlib

import numpy as np

from splitrender.scene.pose import CameraIntrinsics, Pose

INTR = CameraIntrinsics(160, 90)


def _frames(renderer, poses: list[tuple[float, Pose]]) -> list[tuple[str, dict, str]]:  # type: ignore[no-untyped-def]
    """Each frame's kind, server stats and a digest of what it sends (atlas, quads, offsets)."""
    from splitrender.methods import get_method, make_config
    from splitrender.pipeline.direct import server_context
    from splitrender.scene.loader import get_scene

    scene = get_scene("default+nogi")
    spec = get_method("quads")
    srv = spec.server_class(make_config(spec.config, {}), INTR, scene, 30, None)
    out = []
    for fid, (t, pose) in enumerate(poses):
        upd = srv.produce(server_context(scene, renderer, INTR, pose, t_s=t, frame_id=fid))
        d = hashlib.sha256(np.ascontiguousarray(upd.planes["atlas"]).tobytes())
        d.update(upd.data["quads"])
        d.update(upd.data["offsets"])
        out.append((upd.meta["frame"], srv.stats(), d.hexdigest()))
    return out


def _walk(n: int) -> list[tuple[float, Pose]]:
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    tr = get_trace("walk", scene=get_scene("default+nogi"), aspect=INTR.width / INTR.height)
    return [(0.5 + f / 30, tr.pose_at(0.5 + f / 30)) for f in range(n)]


def _both(renderer, monkeypatch, poses):  # type: ignore[no-untyped-def]
    """The whole test's frames and the partial test's (the estimate deciding alone off in both)."""
    import splitrender.methods.quads.server as srv_mod

    monkeypatch.setattr(srv_mod, "ESTIMATE_MARGIN_DB", 0.0)
    monkeypatch.setattr(srv_mod, "PARTIAL_TEST", False)
    whole = _frames(renderer, poses)
    monkeypatch.setattr(srv_mod, "PARTIAL_TEST", True)
    return whole, _frames(renderer, poses)


def test_a_partial_verdict_sends_the_same_bytes(renderer, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The walk: every frame after the first is a reference frame by the test (the whole test scores 24-25 dB at
    320x180), and the partial test stops early on each of them with a bound of its PSNR at or over the whole
    test's figure and under 30 dB; the bytes sent are the same."""
    whole, part = _both(renderer, monkeypatch, _walk(5))
    assert [k for k, _, _ in part] == [k for k, _, _ in whole] == ["reference"] * 5
    assert [d for _, _, d in part] == [d for _, _, d in whole]
    for (_, sw, _), (_, sp, _) in zip(whole[1:], part[1:]):
        assert "residual_psnr_partial" in sp and "residual_psnr_partial" not in sw, sp
        assert sw["residual_psnr_db"] - 1e-9 <= sp["residual_psnr_db"] < 30.0, (sw, sp)


def test_an_undecided_partial_test_shades_the_rest(renderer, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """With the first part too small to decide (``PARTIAL_TARGET`` 0.05), the rest is shaded and the whole test
    runs: the same verdicts, PSNR and bytes.  The pixels counted as exact (the mask drawn in the colour's alpha, over
    128) are the whole colour's own there, and the part covers the same pixels as the whole."""
    import splitrender.methods.quads.server as srv_mod

    monkeypatch.setattr(srv_mod, "PARTIAL_TARGET", 0.05)
    draws: list[np.ndarray] = []
    rgba = srv_mod.QuadsServer._mesh_rgba

    def keep(self, ctx, pose, img):  # type: ignore[no-untyped-def]
        got = rgba(self, ctx, pose, img)
        draws.append(got.copy())
        return got

    monkeypatch.setattr(srv_mod.QuadsServer, "_mesh_rgba", keep)
    whole, part = _both(renderer, monkeypatch, _walk(4))
    assert [(k, s["residual_psnr_db"] if "residual_psnr_db" in s else None, d) for k, s, d in part] == \
        [(k, s["residual_psnr_db"] if "residual_psnr_db" in s else None, d) for k, s, d in whole]
    assert not any("residual_psnr_partial" in s for _, s, _ in part)
    # the whole run drew once a test frame; the partial one three times (estimate, part with its mask, whole)
    n = len(whole) - 1
    assert len(draws) == n + 3 * n
    for f in range(n):
        _, got, full = draws[n + 3 * f: n + 3 * f + 3]     # the estimate (half the size), the part, the whole
        at = got[..., 3] > 128
        assert np.array_equal(got[..., 3] > 0, full[..., 3] > 0)
        assert at.sum() > 0.01 * at.size
        assert np.array_equal(got[..., :3][at], full[..., :3][at])


def test_residual_frames_send_the_same_bytes(renderer, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A camera creeping 2 mm a frame (and the scene's objects moving): residual frames, the test over 30 dB, the
    reference view shaded whole; the same bytes."""
    start = _walk(1)[0][1]
    poses = [(0.5 + f / 30, Pose(start.position + np.array([0.002 * f, 0.0, 0.0]), start.orientation))
             for f in range(4)]
    whole, part = _both(renderer, monkeypatch, poses)
    assert [k for k, _, _ in whole] == ["reference"] + ["residual"] * 3
    assert [(k, s.get("residual_psnr_db"), d) for k, s, d in part] == \
        [(k, s.get("residual_psnr_db"), d) for k, s, d in whole]


def _estimated(renderer, monkeypatch, poses):  # type: ignore[no-untyped-def]
    """The frames with the estimate deciding alone (the default) and with the whole test (every verdict exact)."""
    import splitrender.methods.quads.server as srv_mod

    assert srv_mod.ESTIMATE_MARGIN_DB > 0
    est = _frames(renderer, poses)
    monkeypatch.setattr(srv_mod, "ESTIMATE_MARGIN_DB", 0.0)
    monkeypatch.setattr(srv_mod, "PARTIAL_TEST", False)
    return est, _frames(renderer, poses)


def test_the_estimate_decides_the_walk_alone(renderer, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The walk: the estimate (the cached mesh in the last colour sent at the reference pose) puts every frame after
    the first more than ESTIMATE_MARGIN_DB under 30 dB, so the reference view is not drawn; the verdicts and bytes are
    those of the exact test, and the estimate lies within 1 dB of the exact figure (0.3 dB measured at 320x180)."""
    import splitrender.methods.quads.server as srv_mod

    views: list[int] = []
    rv = srv_mod.QuadsServer._reference_view

    def count(self, *a, **k):  # type: ignore[no-untyped-def]
        views.append(1)
        return rv(self, *a, **k)

    monkeypatch.setattr(srv_mod.QuadsServer, "_reference_view", count)
    est, exact = _estimated(renderer, monkeypatch, _walk(5))
    assert len(views) == 4      # the exact run's four tests; the estimate's run drew none
    assert [k for k, _, _ in est] == [k for k, _, _ in exact] == ["reference"] * 5
    assert [d for _, _, d in est] == [d for _, _, d in exact]
    for (_, se, _), (_, sx, _) in zip(est[1:], exact[1:]):
        assert se.get("residual_psnr_estimate") == 1.0 and "residual_psnr_estimate" not in sx, se
        assert se["residual_psnr_db"] < 30.0 - srv_mod.ESTIMATE_MARGIN_DB
        assert abs(se["residual_psnr_db"] - sx["residual_psnr_db"]) < 1.0, (se, sx)


def test_residual_frames_are_not_decided_by_the_estimate(renderer, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The creeping camera of the test above: its estimate is over the margin, the exact test runs; the same
    verdicts, PSNR and bytes as without the estimate."""
    start = _walk(1)[0][1]
    poses = [(0.5 + f / 30, Pose(start.position + np.array([0.002 * f, 0.0, 0.0]), start.orientation))
             for f in range(4)]
    est, exact = _estimated(renderer, monkeypatch, poses)
    assert [k for k, _, _ in est] == ["reference"] + ["residual"] * 3
    assert not any("residual_psnr_estimate" in s for _, s, _ in est)
    assert [(k, s.get("residual_psnr_db"), d) for k, s, d in est] == \
        [(k, s.get("residual_psnr_db"), d) for k, s, d in exact]


def test_a_light_change_leaves_the_verdict_to_the_exact_test(renderer, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The walk while the default scene's sun dims (4-5 s of scene time): the last colour sent was drawn under
    another light, so the estimate decides nothing alone; the same verdicts and bytes as the exact test."""
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    tr = get_trace("walk", scene=get_scene("default+nogi"), aspect=INTR.width / INTR.height)
    poses = [(4.2 + f / 30, tr.pose_at(0.5 + f / 30)) for f in range(3)]
    est, exact = _estimated(renderer, monkeypatch, poses)
    assert [k for k, _, _ in est] == ["reference"] * 3
    assert not any("residual_psnr_estimate" in s for _, s, _ in est)
    assert [d for _, _, d in est] == [d for _, _, d in exact]
