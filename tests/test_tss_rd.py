"""``tss`` against ``sas`` at ``sas``'s bits on a real model (issue 50 part 1, the lossy target; ``benchmarks/bench_tss_rd.py``).

The issue asks for lossy ``tss`` within 1 dB of ``sas`` (model-region PSNR) at no more than ``sas``'s bits.  Over a
crf ladder ``tss`` (the claims ledger's ``TSS_MATCHED`` with ``codec_block = 4``) comes within 1 dB at about 1.3x
``sas``'s bits on the duck and trails by about 3-4 dB at ``sas``'s own bits: its atlas codes a tile per triangle,
and its side data (geometry, tables, metadata) is 0.39x ``sas``'s whole stream there (0.44x before 8674690 sent no
empty table deltas and packed tables and geometry at zstd level 19).  The test pins that relation
against the ground truth, so a change that moves it (either way) has to say so in ``docs/methods.md``.  With
``colour_order = 16`` and a load-time split made for 16 m instead of 2 m (fewer triangles, so fewer tiles and less
geometry) the target holds on the duck and TextureTransformTest (the second test).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

DUCK = "/usr/share/assimp/models/Collada/duck.dae"


@pytest.mark.slow
def test_tss_within_1db_of_sas_needs_more_than_sas_bits_on_the_duck(shared_run) -> None:  # type: ignore[no-untyped-def]
    """Still camera, ``ideal``, 320x180, 1 s (server and client 30 Hz), model-region PSNR over the frames that show
    an update, against the ground truth; ``sas`` at its defaults.  The client shows each update once at 30 Hz, twice at
    60: on the still camera every figure below is the same to the last digit either way (measured at f77d872), and
    the ``sas`` runs are ``test_tss_models``'s (``shared_run``), so the client at 30 Hz saves them and half the
    display ticks.  Measured (``bench_tss_rd.py``, label
    ``sidedata_still``, at 8674690): ``sas`` 39.35 dB at 779.6 kbit/s; ``tss`` at crf 31 39.91 dB at 1142.8 kbit/s
    (+0.56 dB at 1.47x; 1185 before 8674690); at crf 39 36.16 dB (label ``after_still``, the same pixels) at about
    787 kbit/s (-3.19 dB at 1.01x: crf 39's atlas, 484.3 kbit/s, with the tables, geometry and metadata measured at
    crf 31 and 41, 32.8 + 110.1 + 159.6; 829 before)."""
    from splitrender.experiments.studies.claims import TSS_MATCHED
    from splitrender.sim.runner import RunConfig

    if not os.path.exists(DUCK):
        pytest.skip(f"{DUCK} absent (Debian's assimp-testmodels)")

    def still(method: str, params: dict) -> tuple[float, float]:
        res = shared_run(RunConfig(method=method, scene=DUCK, trace="static", network="ideal", duration_s=1.0, width=320,
                                   height=180, server_fps=30, client_fps=30, flip_every=0, seed=0, method_params=params))
        shown = [f for f in res.frames if f["update_frame_id"] >= 0]
        return float(np.mean([f["model_psnr_db"] for f in shown])), float(res.summary["steady_kbps"])

    sas_db, sas_kbps = still("sas", {})
    db31, kb31 = still("tss", {**TSS_MATCHED, "codec_block": 4, "crf": 31.0})
    db39, kb39 = still("tss", {**TSS_MATCHED, "codec_block": 4, "crf": 39.0})
    # within 1 dB of sas takes about 1.5x its bits at crf 31 (the ladder puts the crossing near 1.26x) ...
    assert db31 >= sas_db - 1.0 and kb31 <= 1.55 * sas_kbps, (sas_db, sas_kbps, db31, kb31)
    # ... and at about sas's bits tss trails by about 3 dB
    assert kb39 <= 1.08 * sas_kbps and -4.0 <= db39 - sas_db <= -2.4, (sas_db, sas_kbps, db39, kb39)


TTT = "/usr/share/assimp/models/glTF2/textureTransform/TextureTransformTest.gltf"


@pytest.mark.slow
def test_tss_split_for_the_view_is_within_1db_of_sas_at_sas_bits(shared_run) -> None:  # type: ignore[no-untyped-def]
    """The issue's lossy target, met on two models once the load-time split stops cutting the model into more
    triangles than the view needs (helper-49, ``bench_tss_rd.py`` labels ``h49_still`` and ``h49_ttt16``):
    ``TSS_MATCHED`` with ``codec_block = 4``, ``colour_order = 16`` and ``split_near_m = 16`` (the load-time
    split guarantees level <= 64 seen from 16 m instead of 2 m: each extra triangle is another tile in the atlas and
    more geometry; the fitted camera is 3.3-4.4 m from the models' centres, so the largest triangles are capped at
    ``v(64)`` samples).  Same setting as the test above.  Measured: the duck at crf 33
    39.15 dB at 761.2 kbit/s (``sas`` 39.35 at 779.6: -0.20 dB at 0.98x; its mesh is not split at all there, the
    same run as ``split_near_m = 8``), TextureTransformTest at crf 28 41.36 dB at 499.0 kbit/s (``sas`` 41.78 at
    622.3: -0.42 dB at 0.80x, from 82k samples against ``sas``'s 178k).  On TextureTransformTest the target holds no
    more since ``sas``'s gradients follow the material's uv transform (7f1eefb): ``tss`` 41.92 dB at 488.1 kbit/s
    against ``sas``'s 44.48 at 615.7 (-2.56 dB at 0.79x): asserted there within 0.35 dB of that gap."""
    from splitrender.experiments.studies.claims import TSS_MATCHED
    from splitrender.sim.runner import RunConfig

    for path in (DUCK, TTT):
        if not os.path.exists(path):
            pytest.skip(f"{path} absent (Debian's assimp-testmodels)")

    def still(scene: str, method: str, params: dict) -> tuple[float, float]:
        res = shared_run(RunConfig(method=method, scene=scene, trace="static", network="ideal", duration_s=1.0, width=320,
                                   height=180, server_fps=30, client_fps=30, flip_every=0, seed=0, method_params=params))
        shown = [f for f in res.frames if f["update_frame_id"] >= 0]
        return float(np.mean([f["model_psnr_db"] for f in shown])), float(res.summary["steady_kbps"])

    split = {**TSS_MATCHED, "codec_block": 4, "colour_order": 16.0, "split_near_m": 16.0}
    for scene, crf, most, behind in ((DUCK, 33.0, 1.0, 1.0), (TTT, 28.0, 0.85, 2.9)):
        sas_db, sas_kbps = still(scene, "sas", {})
        db, kbps = still(scene, "tss", {**split, "crf": crf})
        assert kbps <= most * sas_kbps and db >= sas_db - behind, (scene, sas_db, sas_kbps, db, kbps)
