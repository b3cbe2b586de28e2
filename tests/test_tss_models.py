"""``tss`` against ``sas`` on real models (issue 50, part 1; ``benchmarks/bench_tss_models.py`` has the full grid).

At its defaults ``tss`` shades one sample per covered pixel (the paper's O1) while ``sas`` fills its atlas, up to 16
texels per pixel: on assimp's models that is 7-14x ``tss``'s samples, and the issue's 5-7 dB gap was mostly that
budget.  Given 4 samples per pixel (``samples_per_px = 4``) and 4:4:4 chroma, still fewer samples than ``sas``
shades, ``tss`` leads lossless and is level lossy at about ``sas``'s bits.  What was our implementation's fault: the
black texels between cells, which the codec blended into every triangle's border samples (``layout.fill_gutters``).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from splitrender.methods.tss.layout import fill_gutters

MODELS = {"duck": "/usr/share/assimp/models/Collada/duck.dae",
          "TextureTransformTest": "/usr/share/assimp/models/glTF2/textureTransform/TextureTransformTest.gltf"}
BUDGET = {"samples_per_px": 4.0, "chroma": "444"}
#: The length of the still, lossless runs: on a still view of a still model every shown frame of a lossless run is the
#: same (measured at 0.3 s and 0.1 s for each configuration below: model PSNR, DSSIM, edge PSNR and samples per update
#: equal to the last digit on every frame), so the mean over 3 shown frames is the mean over 9, at a third of the CPU.
STILL_S = 0.1


def test_fill_gutters_keeps_written_texels_and_fills_the_rest_from_neighbours() -> None:
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (37, 53, 4)).astype(np.uint8)
    written = rng.random((37, 53)) < 0.3
    a[..., 3] = np.where(written, 255, 0)
    out = fill_gutters(a, 30)
    assert out.shape == (37, 53, 3) and out.dtype == np.uint8
    assert (out[written] == a[..., :3][written]).all()
    assert (out[30:] == a[30:, :, :3]).all()                 # rows past the used ones untouched
    # a gap between two flat cells takes their colour, not black
    b = np.zeros((8, 8, 4), np.uint8)
    b[:, :3] = (200, 100, 50, 255)
    b[:, 4:] = (200, 100, 50, 255)
    assert (fill_gutters(b, 8)[:, 3] == (200, 100, 50)).all()
    assert (fill_gutters(b, 0) == b[..., :3]).all()


@pytest.mark.slow
@pytest.mark.parametrize("model,lossless_lead,lossy_lead,bits", [
    ("duck", 0.2, -1.2, 1.8),
    ("TextureTransformTest", 1.4, -1.85, 1.7),
])
def test_tss_at_sas_budget_matches_sas_on_real_models(shared_run, model: str, lossless_lead: float, lossy_lead: float,
                                                       bits: float) -> None:  # type: ignore[no-untyped-def]
    """Still camera, zero latency, 320x180, 1 s, model-region PSNR over the frames that show an update; ``sas`` at
    its defaults.  Measured (client at 30 fps), ``tss`` at 4 samples per pixel and 4:4:4 / ``sas``:

    - duck: lossless 39.71 dB from 66.7k samples / 39.10 dB from 259k (+0.61); lossy 38.29 dB at 1337 kbit/s /
      39.10 at 1288 (-0.81 dB at 1.04x the bits);
    - TextureTransformTest: lossless 44.73 from 91.2k / 41.61 from 178k (+3.12); lossy 42.22 at 1092 / 41.61 at 1345
      (+0.61 dB at 0.81x).

    ``sas`` gained 1.03 and 1.14 dB (from 38.07 at 1301 kbit/s and 40.47 at 1370) when its shading stopped growing
    a triangle across the edge it shares with its patch's other triangles (issue 49: the later triangle's
    extrapolation overwrote the earlier one's texels near their diagonal); before that ``tss`` at its defaults (one
    sample per pixel) trailed by 5.3 and 5.1 dB (lossless by 3.3 and 2.8).  ``sas``'s I-frames every 30 frames, not
    5 (bf66471), cut its still bits: at b78990c the duck's ``sas`` takes 774 kbit/s (39.35 dB) and ``tss`` 1327
    (38.22 dB, 1.72x), TextureTransformTest's 617 (41.78) and 1082 (42.20, 1.75x); lossless ``tss`` 39.64 and 44.69
    (1 s or ``STILL_S``: the same on every frame).  On TextureTransformTest ``sas`` had filtered its two scaled quads
    too finely (its gradients missed the material's uv transform, as ``tss``'s did: 3838ba7, 7f1eefb); with both
    fixed, measured: lossless ``tss`` 46.28 dB from 91.2k samples, lossy 43.03 at 983 kbit/s, ``sas`` 44.48 at 616
    (+1.80, and -1.45 dB at 1.60x the bits: the lossy lead is gone there).  Asserted: the lossless lead, the lossy lead and the bit ratio each within about 0.4 dB or 0.1x of what was measured, and
    fewer samples than ``sas``."""
    from splitrender.sim.runner import RunConfig

    path = MODELS[model]
    if not os.path.exists(path):
        pytest.skip(f"{path} absent (Debian's assimp-testmodels)")

    def still(method: str, params: dict, duration_s: float = 1.0) -> tuple[float, float, float]:
        res = shared_run(RunConfig(method=method, scene=path, trace="static", network="ideal", duration_s=duration_s, width=320,
                                   height=180, client_fps=30, flip_every=0, seed=0, method_params=params))
        shown = [f for f in res.frames if f["update_frame_id"] >= 0]
        return (float(np.mean([f["model_psnr_db"] for f in shown])), float(res.summary["steady_kbps"]),
                float(np.mean([u["srv_samples"] for u in res.updates])))

    sas, sas_kbps, sas_n = still("sas", {})
    lossy, kbps, n = still("tss", BUDGET)
    lossless, _, n_ll = still("tss", {**BUDGET, "lossless": True}, STILL_S)   # its bits are not asserted
    got = (lossless, n_ll, lossy, kbps, sas, sas_kbps, sas_n)
    assert lossless >= sas + lossless_lead and n_ll <= sas_n and n <= sas_n, got
    assert lossy >= sas + lossy_lead and kbps <= bits * sas_kbps, got


@pytest.mark.slow
def test_view_cells_sas_fixed_atlas_loses_more_than_tss_as_the_cell_grows(session_renderer, truth_cache) -> None:  # type: ignore[no-untyped-def]
    """The TSS paper's protocol (table 4; ``benchmarks/bench_tss_viewcells.py``): a PVS over a view cell, the server
    shading for the cell's centre, the client wandering within it, ``sas`` with the paper's fixed 24 Mpix atlas.  On
    the default scene (the only one of ours whose PVS outgrows ``sas``'s atlas) ``sas``'s samples stay put while
    ``tss``'s grow with the cell, and ``sas`` loses more of its model-region PSNR.  Measured at 320x180, 1 s, p0 ->
    p2: ``sas`` 500k -> 499k samples, 34.81 -> 29.15 dB; ``tss`` 86k -> 313k, 28.91 -> 27.80 dB.  Here 160x90, 0.5 s
    (measured: ``sas`` 125.1k -> 125.3k samples, 35.59 -> 29.45 dB, -6.14; ``tss`` 21.7k -> 89.5k, 30.05
    -> 28.79 dB, -1.26).  Asserted: ``sas``'s samples within 2 %, ``tss``'s at least 3x, ``sas`` losing at least
    4 dB more than ``tss``.  ``tss`` at the paper's count (``lp_own = False``; with lp_own, the default since issue
    50, its samples at p0 start higher, 32.8k, and grow 2.75x)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import bench_tss_viewcells as bench
    from splitrender.sim.runner import RunConfig, run

    def cell(name: str, method: str, params: dict) -> tuple[float, float]:
        trans, rot = bench.CELLS[name]
        with bench.view_cell(trans, rot), bench.cell_client(trans, rot):
            # not shared_run: the servers and the trace are patched for the run
            res = run(RunConfig(method=method, scene="default+nogi", trace="static", network="ideal", duration_s=0.5,
                                width=160, height=90, client_fps=30, flip_every=0, seed=0, method_params=params,
                                truth_cache=truth_cache), renderer=session_renderer)
        shown = [f for f in res.frames if f["update_frame_id"] >= 0]
        return (float(np.nanmean([f["model_psnr_db"] for f in shown])),
                float(np.mean([u["srv_samples"] for u in res.updates])))

    sas0, sas_n0 = cell("p0", "sas", bench.SAS)
    sas2, sas_n2 = cell("p2", "sas", bench.SAS)
    tss0, tss_n0 = cell("p0", "tss", {"lp_own": False})     # the paper's count
    tss2, tss_n2 = cell("p2", "tss", {"lp_own": False})
    got = (sas0, sas2, sas_n0, sas_n2, tss0, tss2, tss_n0, tss_n2)
    assert abs(sas_n2 / sas_n0 - 1.0) < 0.02 and tss_n2 > 3.0 * tss_n0, got
    assert (sas0 - sas2) - (tss0 - tss2) > 4.0, got


ENGINE = "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb"


def _lossless_still(shared_run, path: str, params: dict) -> tuple[float, float, float]:  # type: ignore[no-untyped-def]
    """Model-region PSNR, edge PSNR and samples per update of a still, zero-latency, lossless run (320x180, ``STILL_S``)."""
    from splitrender.sim.runner import RunConfig

    res = shared_run(RunConfig(method="tss", scene=path, trace="static", network="ideal", duration_s=STILL_S, width=320,
                               height=180, client_fps=30, flip_every=0, seed=0, method_params={**params, "lossless": True}))
    shown = [f for f in res.frames if f["update_frame_id"] >= 0]
    return (float(np.mean([f["model_psnr_db"] for f in shown])), float(np.mean([f["edge_psnr_db"] for f in shown])),
            float(np.mean([u["srv_samples"] for u in res.updates])))


@pytest.mark.slow
@pytest.mark.parametrize("path,spp,gain,cost", [
    (MODELS["duck"], 1.0, 0.8, 1.06),
    (MODELS["duck"], 8.0, 1.5, 1.03),
    (ENGINE, 1.0, 0.9, 1.25),
    (ENGINE, 4.0, 1.8, 1.05),
])
def test_silhouette_slivers_are_sampled_along_their_length(shared_run, path: str, spp: float, gain: float,  # type: ignore[no-untyped-def]
                                                           cost: float) -> None:
    """The per-sample floor on real models (issue 50): a model's outline is lined with triangles seen edge-on, each a
    fraction of a pixel in area and pixels long; under ``tiny_samples`` they got one texel at the centroid, one
    colour along the outline, whatever the sampling rate.  With ``sliver_px = 1`` a triangle whose longest edge spans
    a sample step is L-packed at its level (corners and centre); before, such a sliver was oversampled (its slant),
    two staircase rows of its length.  Still, lossless, 320x180, ``STILL_S``, model-region PSNR and samples per update,
    ``sliver_px`` 0 -> 1 (measured, the oversampled slivers of before in brackets): duck at 1 sample per pixel 34.72
    -> 35.80 dB, 18.2k -> 18.8k samples (35.92, 19.5k); at 8 39.71 -> 41.56, 131.1k both (41.61; ``sas``
    lossless 40.74 from 259k); 2CylinderEngine at 1 30.77 ->
    31.96, 22.6k -> 27.1k (32.19, 31.5k: 1.40x); at 4 35.50 -> 37.68, 76.7k -> 77.5k (37.84, 79.8k).  Asserted: at
    least ``gain`` dB for at most ``cost`` times the samples (the engine at 1 sample per pixel fails the cost with
    the staircases of before).  At the paper's count (``lp_own = False``; lp_own, the default since issue 50, spends
    1.42x the samples on the engine at 1 sample per pixel with slivers L-packed)."""
    if not os.path.exists(path):
        pytest.skip(f"{path} absent (Debian's assimp-testmodels)")
    old, _, n_old = _lossless_still(shared_run, path, {"samples_per_px": spp, "lp_own": False})    # the paper's count
    new, _, n_new = _lossless_still(shared_run, path, {"samples_per_px": spp, "sliver_px": 1.0, "lp_own": False})
    assert new >= old + gain and n_new <= cost * n_old, (old, n_old, new, n_new)


@pytest.mark.slow
@pytest.mark.parametrize("model,lead", [("duck", -0.1), ("TextureTransformTest", -7.3)])
def test_moving_budget_lossless_beats_sas_with_fewer_samples(shared_run, model: str, lead: float) -> None:  # type: ignore[no-untyped-def]
    """The paper's claim on real models with a budget that moves with the scene (``budget_px = 2``: up to 8 samples
    per covered pixel while the frame's samples stay within 2 per display pixel; slivers sampled): still, 320x180, ``STILL_S``, lossless
    ``tss`` against lossless ``sas`` at its defaults, model-region PSNR.  Measured: duck 40.77 dB from 111.0k samples
    (rate 6.7) against 40.74 from 259.2k; TextureTransformTest 44.72 from 110.5k (rate 4.8) against 44.58 from
    178.2k.  Before (no budget, one texel per sliver) ``tss`` at its defaults scored 34.74 and 37.66 dB from 18.2k
    and 22.7k.  Asserted: level with ``sas`` within 0.1 dB (the margins are +0.03 and +0.14 dB) from at most 0.7x
    its samples and within the budget.  On TextureTransformTest the claim does not hold since ``sas``'s gradients follow
    the material's uv transform (7f1eefb; ``tss``'s since 3838ba7): ``tss`` 47.69 dB from 110.5k against ``sas``'s
    54.63 from 178.2k (-6.94): there the test holds the gap where it is (within 0.4 dB), not the claim."""
    from splitrender.sim.runner import RunConfig

    path = MODELS[model]
    if not os.path.exists(path):
        pytest.skip(f"{path} absent (Debian's assimp-testmodels)")
    tss, _, n = _lossless_still(shared_run, path, {"budget_px": 2.0, "sliver_px": 1.0})
    res = shared_run(RunConfig(method="sas", scene=path, trace="static", network="ideal", duration_s=STILL_S, width=320,
                               height=180, client_fps=30, flip_every=0, seed=0, method_params={"lossless": True}))
    shown = [f for f in res.frames if f["update_frame_id"] >= 0]
    sas = float(np.mean([f["model_psnr_db"] for f in shown]))
    n_sas = float(np.mean([u["srv_samples"] for u in res.updates]))
    assert tss >= sas + lead and n <= 0.7 * n_sas and n <= 2.0 * 320 * 180, (tss, n, sas, n_sas)


MOVING_FLIPS = {"budget_px": 2.0, "sliver_px": 1.0, "flip_level": 8}
MATCHED = {"budget_px": 3.0, "budget_max_spp": 16.0, "sliver_px": 1.0, "flip_level": 16}


@pytest.mark.slow
@pytest.mark.parametrize("model,params,ratio,samples", [("duck", MOVING_FLIPS, 0.75, 0.7),
                                                        ("TextureTransformTest", MOVING_FLIPS, 4.6, 0.7),
                                                        ("2CylinderEngine", MATCHED, 0.93, 1.2)])
def test_the_papers_claim_in_its_measure_dssim_from_comparable_samples(shared_run, model: str, params: dict, ratio: float,  # type: ignore[no-untyped-def]
                                                                   samples: float) -> None:
    """The TSS paper's table 4 in its own measure (model-region DSSIM, ``(1 - SSIM) / 2``, lower is better; the claims
    ledger's T-T4-1) at comparable samples: ``tss`` with the moving budget (``budget_px = 2``), slivers sampled and
    the flip's triangles lifted (``flip_level = 8``), still, zero latency, lossless atlases, 320x180, ``STILL_S``, against
    lossless ``sas`` at its defaults.  Measured: duck DSSIM 0.00090 (44.84 dB) from 114.3k samples against 0.00136
    (40.74 dB) from 259.2k; TextureTransformTest 0.00102 (44.72 dB) from 110.5k against 0.00111 (44.59 dB) from
    178.2k.  Without ``flip_level`` the duck's DSSIM is 0.00191, behind ``sas`` at a level PSNR (40.77 dB): the flipped
    outline pixels are what SSIM sees.  At the old defaults (one sample per pixel) ``tss`` scored 0.0065 and 0.0038.
    Lossy at crf 23 the claim holds in no model cell (``benchmarks/bench_tss_matched.py``, 1 s: at ``budget_px = 2``
    the duck 0.00267 against 0.00222, TextureTransformTest 0.00205 against 0.00161, at 2.3x and 1.8x ``sas``'s bits;
    below, the duck and the engine come within 0.00006 and 0.00002 at 3.1x and 2.8x): the codec costs ``tss``'s atlas
    about twice the DSSIM it costs ``sas``'s (``docs/methods.md``, tss, "The paper's claim at matched samples").
    2CylinderEngine needs more: at ``budget_px = 2`` its lossless DSSIM is 0.00142 against 0.00088 (the silhouettes:
    edge DSSIM 0.00167 against 0.00013); with ``budget_px = 3``, up to 16 samples per covered pixel
    (``budget_max_spp``) and the flip's triangles at level 16 it is 0.00077 (42.82 dB) from 166.5k samples against
    0.00088 (42.37 dB) from 144.4k, 1.15x (the paper's table 4: 0.48-1.61x).  Asserted: ``tss``'s DSSIM at most
    ``ratio`` times ``sas``'s (measured 0.66x, 0.92x and 0.88x), from at most ``samples`` times its samples.  On
    TextureTransformTest the claim does not hold since ``sas``'s gradients follow the material's uv transform (7f1eefb):
    0.00043 from 110.5k samples against 0.00010 from 178.2k, 4.25x (asserted 4.6x: the gap held where it is)."""
    from splitrender.sim.runner import RunConfig

    path = ENGINE if model == "2CylinderEngine" else MODELS[model]
    if not os.path.exists(path):
        pytest.skip(f"{path} absent (Debian's assimp-testmodels)")

    def still(method: str, p: dict) -> tuple[float, float]:
        res = shared_run(RunConfig(method=method, scene=path, trace="static", network="ideal", duration_s=STILL_S, width=320,
                                   height=180, client_fps=30, flip_every=0, seed=0, method_params={**p, "lossless": True}))
        shown = [f for f in res.frames if f["update_frame_id"] >= 0]
        return float(np.mean([f["model_dssim"] for f in shown])), float(np.mean([u["srv_samples"] for u in res.updates]))

    sas, n_sas = still("sas", {})
    tss, n = still("tss", params)
    assert tss <= ratio * sas and n <= samples * n_sas, (tss, n, sas, n_sas)


def test_classify_lifts_the_triangles_given_a_least_level() -> None:
    """``flip_level``'s mechanism (:func:`~splitrender.methods.tss.server.classify`'s ``min_level``): a triangle given a
    least level is L-packed at that level or its own, whichever is higher, whatever kind it would have been (one
    texel, a sliver, an oversampled staircase); the others are untouched."""
    from splitrender.methods.tss.layout import KIND_LP, KIND_OS, KIND_SINGLE
    from splitrender.methods.tss.server import classify

    px = np.array([[[0, 0], [0.5, 0], [0, 0.5]],          # tiny: one texel
                   [[0, 0], [40, 0], [20, 0.5]],          # slanted: oversampled
                   [[0, 0], [30, 0], [0, 30]],            # large: L-packed at its own level
                   [[0, 0], [30, 0], [0, 30]]], float)
    args = (1.0, 16.0, 2.0)
    kind, level = classify(px, *args)[:2]
    assert list(kind) == [KIND_SINGLE, KIND_OS, KIND_LP, KIND_LP], kind
    kind2, level2 = classify(px, *args, min_level=np.array([8, 8, 8, 0]))[:2]
    assert list(kind2) == [KIND_LP] * 4 and list(level2[:2]) == [8, 8], (kind2, level2)
    assert level2[2] == level[2] == level2[3] > 8, level2
    # flip_cap: the lift capped at flip_cap times the samples along the longest edge (rate 1: its length in pixels),
    # at least 1; a triangle whose own level is higher keeps it
    kind3, level3 = classify(px, *args, min_level=np.array([16, 16, 16, 0]), flip_cap=1.0)[:2]
    assert list(kind3) == [KIND_LP] * 4 and list(level3[:2]) == [1, 16], (kind3, level3)
    assert level3[2] == level[2] == level3[3], level3
    assert list(classify(px, *args, min_level=np.array([16, 16, 16, 0]), flip_cap=4.0)[1][:2]) == [3, 16]   # ceil(4 * 0.71)


@pytest.mark.slow
def test_flip_level_closes_the_orbit_gap_without_latency(shared_run) -> None:  # type: ignore[no-untyped-def]
    """Issue 50 part 1: on the duck's fitted ``orbit`` ``tss`` with the moving budget trailed ``sas`` by about 3 dB
    even without latency or coding (``ideal``, lossless).  Not the motion: a one-frame harness (a fresh server half
    per pose, the client at the same pose) at 30 orbit poses gave the same gap (``tss`` 40.39 dB, ``sas`` 43.84),
    and the still view's level score was one lucky pose (a 0.9 degree turn moves ``sas`` 40.74 -> 45.40 dB, ``tss``
    40.77 -> 42.72).  The model-region PSNR is decided by a few dozen outline pixels (the top 50 carry 93-99 % of the
    error), and there the truth is discontinuous: its two-sided lighting flips the interpolated normal where it turns
    from the eye.  A silhouette triangle that the flip crosses got the few samples its area asks for (3 at its
    corners, or an oversampling staircase whose rows lie outside a triangle thinner than one sample step), so a
    pixel beside the flip read the flipped colour.  ``flip_level = 8`` L-packs those triangles at level 8 (61
    samples) or more.  320x180, 0.3 s, ``orbit``, ``ideal``, lossless, model PSNR over the frames that show an update,
    9 of them (measured at cfd47c2: ``sas`` 40.60 dB from 261k samples; the moving budget 38.12, -2.48; with
    ``flip_level = 8`` and hysteresis 0.75 41.40 from 121k, +0.80; over 0.5 s, 15 frames: 41.91 dB from 257k, 38.65,
    42.50 from 121k, the same as when first measured).  Asserted: the flips gain at least half of the 3.29 dB
    measured, and ``tss`` leads ``sas`` by at least half its measured lead from at most 0.6x its samples."""
    from splitrender.sim.runner import RunConfig

    path = MODELS["duck"]
    if not os.path.exists(path):
        pytest.skip(f"{path} absent (Debian's assimp-testmodels)")

    def orbit(method: str, params: dict) -> tuple[float, float]:
        res = shared_run(RunConfig(method=method, scene=path, trace="orbit", network="ideal", duration_s=0.3, width=320,
                                   height=180, client_fps=30, flip_every=0, seed=0, method_params={**params, "lossless": True}))
        shown = [f for f in res.frames if f["update_frame_id"] >= 0]
        return float(np.mean([f["model_psnr_db"] for f in shown])), float(np.mean([u["srv_samples"] for u in res.updates]))

    moving = {"budget_px": 2.0, "sliver_px": 1.0}
    sas, n_sas = orbit("sas", {})
    old, _ = orbit("tss", moving)
    new, n = orbit("tss", {**moving, "flip_level": 8, "hysteresis": 0.75})
    got = (sas, n_sas, old, new, n)
    assert new >= old + 1.6 and new >= sas + 0.4 and n <= 0.6 * n_sas, got


def test_moving_tells_a_still_view_from_a_moving_one() -> None:
    """``pvs_ring`` grows the PVS only while the EVS samples' views differ (:func:`~splitrender.methods.tss.server.moving`):
    a still view keeps its exact PVS and so its samples."""
    from splitrender.methods.tss.server import moving
    from splitrender.scene.pose import Pose

    a = Pose(np.array([0.0, 1.0, 3.0]))
    b = Pose(np.array([0.1, 1.0, 3.0]))
    assert not moving([(0.0, a)]) and not moving([(0.0, a), (0.03, a)])
    assert moving([(0.0, a), (0.03, b)])


@pytest.mark.slow
def test_pvs_ring_fills_the_engines_orbit_holes(shared_run) -> None:  # type: ignore[no-untyped-def]
    """Issue 50 part 1: on 2CylinderEngine's fitted ``orbit`` under ``cloud`` lossless ``tss`` (``FLIPS``) trailed
    lossless ``sas`` by 5.4 dB, not the codec: its per-triangle PVS missed the small triangles between the fins that
    the client's view turns to between the EVS samples, and the client showed the sky there (3x ``sas``'s geometric
    holes, 0.33 % of the view against 0.12 %).  ``pvs_ring = 1`` adds the PVS's neighbours (sharing a vertex) while
    the view moves, at one texel each.  320x180, 0.3 s, ``orbit``, ``cloud``, lossless, model PSNR over the frames
    that show an update, 7 of them (measured at cfd47c2: 23.34 dB with 0.99 % of the view in geometric holes; with the
    ring 28.07 dB, 0.84 %).  Over 0.5 s, 13 frames shown, the same gap was wider (26.02 dB, 0.58 %; with the ring
    31.42, 0.46 %; 5.53 dB when first measured) for 22 CPU s of runs against 12 at 0.3 s.  Asserted: the ring's gain,
    within 1 dB of the 4.72 dB measured, and at most 0.9 of the holes (0.85 measured)."""
    from splitrender.sim.runner import RunConfig

    path = "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb"
    if not os.path.exists(path):
        pytest.skip(f"{path} absent (Debian's assimp-testmodels)")

    def orbit(params: dict) -> tuple[float, float]:
        res = shared_run(RunConfig(method="tss", scene=path, trace="orbit", network="cloud", duration_s=0.3, width=320,
                                   height=180, client_fps=30, flip_every=0, seed=0, method_params={**params, "lossless": True}))
        shown = [f for f in res.frames if f["update_frame_id"] >= 0]
        return (float(np.mean([f["model_psnr_db"] for f in shown])), float(np.mean([f["hole_geom_pct"] for f in shown])))

    flips = {"budget_px": 2.0, "chroma": "444", "sliver_px": 1.0, "flip_level": 8, "hysteresis": 0.75}
    old, old_holes = orbit(flips)
    new, new_holes = orbit({**flips, "pvs_ring": 1})
    got = (old, old_holes, new, new_holes)
    assert new >= old + 3.7 and new_holes < 0.9 * old_holes, got
