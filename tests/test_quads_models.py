"""``quads`` on assimp's models (issue 50, part 2): QUASAR leads warp on the model region under ``cloud``, and its
reference frames carry no background quads unless ``background_quads`` asks for them.

The numbers in the docstrings were measured on this project's 2-core machine (llvmpipe); the full comparison (three
models, 2 s orbits, MeshWarp 60/120, the error budget, before and after) is ``benchmarks/bench_quads_models.py``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from splitrender.scene.pose import CameraIntrinsics
from splitrender.sim.runner import RunConfig

ASSIMP = Path("/usr/share/assimp/models")
ENGINE = ASSIMP / "glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb"
DUCK = ASSIMP / "Collada/duck.dae"
INTR = CameraIntrinsics(320, 180)

needs_models = pytest.mark.skipif(not (ENGINE.exists() and DUCK.exists()),
                                  reason="assimp-testmodels is not installed (apt-get install assimp-testmodels)")


def _reference_frame(renderer, params: dict):  # type: ignore[no-untyped-def]
    """The first (reference) frame of QUASAR on the engine+ground at the fitted orbit's start: (server, update, spec,
    config, scene, pose)."""
    from splitrender.methods import get_method, make_config
    from splitrender.pipeline.direct import server_context
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    scene = get_scene(f"{ENGINE}+ground")
    pose = get_trace("orbit", scene=scene).pose_at(0.5)
    spec = get_method("quads")
    cfg = make_config(spec.config, {"lossless": True, **params})
    srv = spec.server_class(cfg, INTR, scene, 30, None)
    ctx = server_context(scene, renderer, INTR, pose, t_s=0.5)
    return srv, srv.produce(ctx), spec, cfg, scene, pose


@needs_models
def test_reference_frames_carry_no_background_quads_unless_asked_and_the_client_draws_the_same(renderer) -> None:  # type: ignore[no-untyped-def]
    """2CylinderEngine+ground, the orbit's pose at 0.5 s, 320x180, lossless atlas.  By default (as in QUASAR's code)
    the reference set and the wide view carry no background quads; ``background_quads=true`` puts them back.  The
    client makes the sky's quads itself over what its sets leave uncovered, so at the server's pose both draw the
    same picture, pixel for pixel, with no holes.  Counts asserted against the run's own; measured at three poses of
    the orbit (0.5, 1, 1.5 s), per reference frame: the reference set 6,261 -> 5,850 quads (411 background), the
    wide view 481 -> 272, the quads stream 85.6 -> 79.4 KB (-7 %); on the duck 682 of 3,369 (-22 % of the stream),
    on Wuson 509 of 3,747 (-15 %)."""
    from splitrender.methods import DecodedUpdate
    from splitrender.methods.quads.wire import KIND_REFERENCE, KIND_WIDE

    shown, counts = [], []
    for params in ({}, {"background_quads": True}):
        srv, upd, spec, cfg, scene, pose = _reference_frame(renderer, params)
        ref = next(s for s in srv.last_sets if s.kind == KIND_REFERENCE)
        wide = next(s for s in srv.last_sets if s.kind == KIND_WIDE)
        counts.append((len(ref.quads), int(ref.quads.background(INTR).sum()), len(wide.quads), len(upd.data["quads"])))
        cli = spec.client_class(cfg, INTR, renderer.ctx, srv.session_data())
        cli.apply(DecodedUpdate(upd.frame_id, upd.t_s, upd.pose, upd.planes, upd.meta, dict(upd.data)))
        got = cli.render(pose, 0.5)
        assert not got.holes.any(), params
        shown.append(got.color)
    (n0, bg0, w0, b0), (n1, bg1, w1, b1) = counts
    assert bg0 == 0 and bg1 > 0 and n1 - n0 == bg1, counts
    assert w1 > w0 and b1 > b0, counts
    assert (shown[0] == shown[1]).all(-1).mean() > 0.999


def _orbit_cloud(model: Path, method: str) -> RunConfig:
    """0.6 s of the fitted orbit around ``model`` on a ground, under ``cloud``, at 320x180, the client at 30 Hz."""
    return RunConfig(method=method, scene=f"{model}+ground", trace="orbit", network="cloud", duration_s=0.6, width=320,
                     height=180, client_fps=30, flip_every=0, seed=0)


@pytest.mark.slow
@needs_models
@pytest.mark.parametrize("model, margin_db", [pytest.param(m, 0.6, marks=pytest.mark.shared_runs(
    _orbit_cloud(m, "quads"), _orbit_cloud(m, "warp"))) for m in (ENGINE, DUCK)])
def test_quasar_leads_warp_on_the_model_under_cloud(shared_run, model: Path, margin_db: float) -> None:  # type: ignore[no-untyped-def]
    """``+ground``, the fitted orbit, ``cloud`` (50 +- 20 ms each way), 0.6 s, 320x180, the client at 30 Hz: the
    mean model-region PSNR over the frames with content, QUASAR (defaults) minus warp (defaults).  QUASAR's table 4
    puts QUASAR ahead of MeshWarp.  Measured here: 2CylinderEngine 20.61 against 19.49 dB (+1.12), duck 28.84
    against 27.87 (+0.97); asserted: at least 0.6 dB ahead.  Before QUASAR's colour lookup filtered across quads
    (d2ead52^): -0.09 and +0.41, so both fail it.  Over the benchmark's 2 s at 60 Hz, and against MeshWarp 60/120:
    ``benchmarks/results/bench_quads_models.json`` and docs/quasar.md.  The file takes about 20 s on 2 cores (89 s
    beside two benchmarks)."""
    def model_psnr(method: str) -> float:
        r = shared_run(_orbit_cloud(model, method))
        v = [f["model_psnr_db"] for f in r.frames if f.get("update_frame_id", -1) != -1 and not math.isnan(f["model_psnr_db"])]
        assert len(v) >= 10
        return float(np.mean(v))

    quasar, warp = model_psnr("quads"), model_psnr("warp")
    print(f"{model.name}: quasar {quasar:.2f} dB, warp {warp:.2f} dB, {quasar - warp:+.2f}")
    assert quasar >= warp + margin_db, (quasar, warp)


def test_the_clients_background_quads_are_the_servers() -> None:
    """``background_quads`` (the quadtree of the uncovered pixels) makes the quads that ``generate(...,
    background=True)`` makes of the same pixels, in the same order, with the same sizes, positions, normals and
    depths: at 320x180 and 160x90 (a wide view's size, 120 degrees), over a random blob mask, a mask with odd edges
    and a full one.  All of the client's are flat; of the server's, the full mask's 4 largest (of 114) carry
    offsets, up to 0.75 m (5.2 m at the wide view's edges) against their 98 m depth: the tilt of the 8+8-bit normal
    over a quad up to 128 pixels wide.  The colour lookup is projective, so that moves no colour (the reference-frame
    test above: the same picture pixel for pixel)."""
    from splitrender.methods.quads.config import QuadParams
    from scipy.ndimage import binary_dilation

    from splitrender.methods.quads.gen import QuadSet, generate
    from splitrender.methods.quads.mesh import background_quads

    rng = np.random.default_rng(5)
    for intr, params in ((INTR, QuadParams()), (CameraIntrinsics(160, 90, 120.0), QuadParams().relaxed(10.0, 4))):
        blobs = binary_dilation(rng.random((intr.height, intr.width)) < 0.002, iterations=9)
        for region in (blobs, ~blobs & (rng.random((intr.height, intr.width)) < 0.97), np.ones((intr.height, intr.width), bool)):
            want = generate(np.full(region.shape, np.inf), np.zeros((*region.shape, 3)), np.eye(3), intr, params,
                            emit=region, background=True)
            got = background_quads(QuadSet.empty(), intr, region)
            assert len(got) == len(want) and len(got) > 0
            for k in ("level", "x", "y", "theta", "phi", "depth"):
                assert (getattr(got, k) == getattr(want, k)).all(), k
            assert got.flat.all() and got.offsets.shape == (0, 16)
            big = np.abs(want.offsets.astype(np.float64)).max(initial=0.0)
            assert int((~want.flat).sum()) <= 4 and big < 0.06 * 0.98 * intr.far_m, (int((~want.flat).sum()), big)
