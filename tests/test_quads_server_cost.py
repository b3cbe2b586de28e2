"""QUASAR's residual-error test decided from part of the reference view (issue 49 item 3, ``server.PARTIAL_TEST``).

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
    import splitrender.methods.quads.server as srv_mod

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
