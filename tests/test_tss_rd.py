"""``tss`` against ``sas`` at ``sas``'s bits on a real model (issue 50 part 1, the lossy target; ``benchmarks/bench_tss_rd.py``).

The issue asks for lossy ``tss`` within 1 dB of ``sas`` (model-region PSNR) at no more than ``sas``'s bits.  Over a
crf ladder ``tss`` (the claims ledger's ``TSS_MATCHED`` with ``codec_block = 4``) comes within 1 dB at about 1.3x
``sas``'s bits on the duck and trails by about 3-4 dB at ``sas``'s own bits: its atlas codes a tile per triangle,
and its side data (geometry, tables, metadata) is 0.39x ``sas``'s whole stream there (0.44x before 8674690 sent no
empty table deltas and packed tables and geometry at zstd level 19).  The test pins that relation
against the ground truth, so a change that moves it (either way) has to say so in ``docs/methods.md``.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

DUCK = "/usr/share/assimp/models/Collada/duck.dae"


@pytest.mark.slow
def test_tss_within_1db_of_sas_needs_more_than_sas_bits_on_the_duck(shared_run) -> None:  # type: ignore[no-untyped-def]
    """Still camera, ``ideal``, 320x180, 1 s (server 30 Hz, client 60 Hz), model-region PSNR over the frames that show
    an update, against the ground truth; ``sas`` at its defaults.  Measured (``bench_tss_rd.py``, label
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
                                   height=180, server_fps=30, client_fps=60, flip_every=0, seed=0, method_params=params))
        shown = [f for f in res.frames if f["update_frame_id"] >= 0]
        return float(np.mean([f["model_psnr_db"] for f in shown])), float(res.summary["steady_kbps"])

    sas_db, sas_kbps = still("sas", {})
    db31, kb31 = still("tss", {**TSS_MATCHED, "codec_block": 4, "crf": 31.0})
    db39, kb39 = still("tss", {**TSS_MATCHED, "codec_block": 4, "crf": 39.0})
    # within 1 dB of sas takes about 1.5x its bits at crf 31 (the ladder puts the crossing near 1.26x) ...
    assert db31 >= sas_db - 1.0 and kb31 <= 1.55 * sas_kbps, (sas_db, sas_kbps, db31, kb31)
    # ... and at about sas's bits tss trails by about 3 dB
    assert kb39 <= 1.08 * sas_kbps and -4.0 <= db39 - sas_db <= -2.4, (sas_db, sas_kbps, db39, kb39)
