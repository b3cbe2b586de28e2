"""``sas`` at a low bitrate on a still camera (issue 50, claim S-F15-1): the atlas does not change, so P-frames
refine it and the view converges as video does; the paper's I-frame every 5 frames kept it from converging."""

from __future__ import annotations

import os

import numpy as np
import pytest

from splitrender.sim.runner import RunConfig

DUCK = "/usr/share/assimp/models/Collada/duck.dae"


def _duck(params: dict) -> RunConfig:
    """The claims ledger's cell: the duck, ``static``, ``ideal``, 320x180, server 30 Hz, client 60 Hz, 1 s."""
    return RunConfig(method="sas", scene=DUCK, trace="static", network="ideal", duration_s=1.0, width=320, height=180,
                     server_fps=30, client_fps=60, flip_every=0, seed=0, method_params={"bitrate_kbps": 500, **params})


DEFAULT, PAPER_GOP = _duck({}), _duck({"gop": 5})


@pytest.mark.skipif(not os.path.exists(DUCK), reason="assimp-testmodels not installed")
@pytest.mark.shared_runs(DEFAULT, PAPER_GOP)
def test_a_still_view_converges_at_500_kbit_s(shared_run) -> None:  # type: ignore[no-untyped-def]
    """Measured (``benchmarks/bench_sas_lowrate.py``): model PSNR 35.02 dB over the frames with content, 39.13 dB on
    the last frame (a lossless atlas: 40.74), one I-frame in the second; with the paper's I-frame every 5 frames
    (the default before), 30.59 dB, each GOP climbing from about 29.5 to 34 dB and falling back.  Since an encoder
    under a VBV runs one thread (its sliced threads overshot the VBV, differently each run: docs/experiments.md)
    32.59 dB, 38.61 on the last frame, 28.75 with the paper's I-frames."""
    res = shared_run(DEFAULT)
    paper = shared_run(PAPER_GOP)
    psnr = [f["model_psnr_db"] for f in res.frames if f["update_frame_id"] >= 0]
    mean = res.summary["mean_model_psnr_db_content"]
    assert mean >= 31.9, f"sas at 500 kbit/s, still duck: model PSNR {mean:.2f} dB"
    assert psnr[-1] >= 38.0, f"the last frame reached {psnr[-1]:.2f} dB"
    # converging: the second half never falls back (an I-frame at this rate loses 3-4 dB)
    late = np.array(psnr[len(psnr) // 2:])
    assert np.all(np.diff(late) >= -0.3), f"model PSNR fell back in the second half: {np.round(late, 2).tolist()}"
    iframes = [u["frame_id"] for u in res.updates if u["keyframe"]]
    assert iframes == [0, 30][:len(iframes)] and len(iframes) <= 2, f"I-frames at {iframes}"
    assert mean >= paper.summary["mean_model_psnr_db_content"] + 3.5, (mean, paper.summary["mean_model_psnr_db_content"])
