"""Issue 50, part 5: the start-up ticks and the upload in the aggregates and the headline.

* Quality is aggregated twice: over all displayed frames and over the frames with content (``*_content``: from the
  first display tick that shows an update on; the black start-up ticks before it left out).  The headline shows and
  ranks by the frames with content, with the all-frames figure beside it in brackets.
* The headline's kbit/s is the steady rate: a scene upload is counted once, in kB, not again in the rate.
"""

from __future__ import annotations

import math

import pytest

from splitrender import metrics
from splitrender.experiments.headline import headline_markdown, headline_rows, headline_text
from splitrender.experiments.store import summarise
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import VirtualTimeRun


def _frame(fid: int, flip: float, model_mse: float) -> dict:
    return {"update_frame_id": fid, "flip": flip, "psnr_db": metrics.psnr_from_mse(model_mse), "mse": model_mse,
            "model_psnr_db": metrics.psnr_from_mse(model_mse), "model_mse": model_mse}


def test_six_black_start_up_ticks_make_the_all_frames_flip_and_the_content_flip_differs() -> None:
    """The issue's probes run in miniature: 6 black start-up ticks (FLIP 0.7) and 62 frames with content (FLIP
    0.0002): 0.062 over all frames, 0.0002 over the frames with content."""
    rows = [_frame(-1, 0.7, 4000.0) for _ in range(6)] + [_frame(i, 0.0002, 40.0) for i in range(62)]
    s = {**metrics.quality_summary(rows), **metrics.content_quality_summary(rows)}
    assert s["mean_flip"] == pytest.approx((6 * 0.7 + 62 * 0.0002) / 68) and round(s["mean_flip"], 3) == 0.062
    assert s["mean_flip_content"] == pytest.approx(0.0002) and s["flip_frames_content"] == 62
    assert s["content_frames"] == 62
    # MSE-PSNR: the black ticks' squared error dominates the mean MSE
    assert s["model_psnr_mse_db"] == pytest.approx(metrics.psnr_from_mse((6 * 4000.0 + 62 * 40.0) / 68))
    assert s["model_psnr_mse_db_content"] == pytest.approx(metrics.psnr_from_mse(40.0))
    assert s["model_psnr_mse_db_content"] - s["model_psnr_mse_db"] > 8.0
    # a table without the column (frames from elsewhere) is all content
    assert metrics.content_quality_summary([{"flip": 0.5}])["mean_flip_content"] == 0.5
    assert metrics.has_content({"update_frame_id": 0}) and not metrics.has_content({"update_frame_id": -1.0})


def test_a_run_reports_both_aggregates(renderer) -> None:  # type: ignore[no-untyped-def]
    """Over 100 ms one way, ticks 0-3 show black: the summary has every quality aggregate over all 16 frames and,
    with ``_content``, over the 12 with content, equal to quality_summary of those frames."""
    cfg = RunConfig(method="video", scene="minimal", trace="static", network="delay 100ms", width=160, height=90,
                    duration_s=0.5, client_fps=30, flip_every=0)
    res = VirtualTimeRun(cfg, renderer).run()
    s = res.summary
    assert s["frames"] == 16 and s["frames_before_content"] == 4 and s["content_frames"] == 12
    shown = [f for f in res.frames if f["update_frame_id"] >= 0]
    for k, v in metrics.quality_summary(shown).items():
        assert s[f"{k}_content"] == pytest.approx(v, nan_ok=True), k
    assert s["mean_psnr_db_content"] > s["mean_psnr_db"] + 3.0
    assert s["psnr_mse_db_content"] > s["psnr_mse_db"] + 3.0


def _summary_row(m: str, *, model: float, model_all: float, flip: float = 0.01, flip_all: float = 0.05,
                 client: float = 0.1, mean_kbps: float = 1000.0, steady: float = 1000.0, upload: float = 0.0) -> dict:
    return {"method": m, "network": "ideal", "trace": "walk",
            "mean_model_psnr_db_content": model, "mean_model_psnr_db": model_all,
            "mean_psnr_db_content": model + 2, "mean_psnr_db": model_all + 2,
            "mean_flip_content": flip, "mean_flip": flip_all,
            "mean_kbps": mean_kbps, "steady_kbps": steady, "session_kb": upload,
            "mean_gt_ms": 10.0, "mean_server_ms": 20.0, "mean_client_ms": client * 10.0}


def test_headline_ranks_by_the_frames_with_content_and_shows_all_frames_in_brackets() -> None:
    """a is better over all frames (a short start-up), b over the frames with content at the same client cost: the
    front puts b first; each cell shows the content figure and, in brackets, the all-frames one."""
    runs = [_summary_row("video", model=25.0, model_all=20.0, flip=0.02, flip_all=0.05),
            _summary_row("atw", model=24.0, model_all=23.5, flip=0.03, flip_all=0.03)]
    t = headline_rows(summarise(runs))["ideal"]
    assert [(x["method"], x["rank"]) for x in t] == [("video", 1), ("atw", 2)]
    assert t[0]["model_psnr_db"] == 25.0 and t[0]["model_psnr_db_all"] == 20.0
    md = headline_markdown({"ideal": t})
    assert "| 1 | video | 25.0 (20.0) | 27.0 (22.0) | 0.020 (0.050) | 1000 | - |" in md
    assert "| 2 | atw | 24.0 (23.5) | 26.0 (25.5) | 0.030 |" in md   # the same FLIP either way: one figure
    assert "over the frames with content" in md and "in brackets, where it differs, over all displayed frames" in md
    assert "25.0 (20.0)" in headline_text({"ideal": t})


def test_headline_counts_the_scene_upload_once() -> None:
    """probes: 500 kB uploaded once over a 1 s run is 4000 kbit/s of mean_kbps on top of its 1000 kbit/s steady rate;
    the headline's kbit/s is the steady 1000 and the upload is its kB alone (it was 5000 kbit/s and 500 kB)."""
    runs = [_summary_row("probes", model=55.0, model_all=50.0, client=1.5, mean_kbps=5000.0, steady=1000.0, upload=500.0),
            _summary_row("video", model=30.0, model_all=29.0)]
    t = {x["method"]: x for x in headline_rows(summarise(runs))["ideal"]}
    assert t["probes"]["kbps"] == 1000.0 and t["probes"]["session_kb"] == 500.0
    md = headline_markdown({"ideal": list(t.values())})
    assert "| 1000 | 500 |" in md and "5000" not in md
    assert "kbit/s: the steady rate, every stream but the one-off upload" in md
    # results from before steady_kbps: mean_kbps is all there is
    old = {k: v for k, v in _summary_row("video", model=30.0, model_all=29.0, mean_kbps=1234.0).items() if k != "steady_kbps"}
    assert headline_rows(summarise([old]))["ideal"][0]["kbps"] == 1234.0


def test_results_from_before_the_split_show_the_all_frames_figure_alone() -> None:
    old = {"method": "video", "network": "ideal", "trace": "walk", "mean_model_psnr_db": 30.0, "mean_psnr_db": 36.0,
           "mean_flip": 0.1, "mean_kbps": 1000.0, "session_kb": 0.0, "mean_gt_ms": 10.0, "mean_server_ms": 20.0,
           "mean_client_ms": 1.0}
    t = headline_rows(summarise([old]))["ideal"]
    assert math.isnan(t[0]["model_psnr_db"]) and t[0]["rank"] == 1
    assert "| 1 | video | 30.0 | 36.0 | 0.100 | 1000 | - |" in headline_markdown({"ideal": t})


def test_summarise_carries_the_content_aggregates() -> None:
    runs = [{**_summary_row("video", model=25.0, model_all=20.0), "content_frames": 50, "frames_before_content": 10},
            {**_summary_row("video", model=27.0, model_all=22.0), "trace": "turn", "content_frames": 54, "frames_before_content": 6}]
    s = summarise(runs)[0]
    assert s["mean_model_psnr_db_content"] == 26.0 and s["mean_model_psnr_db"] == 21.0
    assert s["content_frames"] == 52 and s["frames_before_content"] == 8
