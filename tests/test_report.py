"""Report and charts on synthetic results (no rendering): structure, numbers, exact errors."""

from __future__ import annotations

import base64
import math
import re
from pathlib import Path

import pytest

from splitrender.errors import ConfigError
from splitrender.experiments.charts import failure_mask, method_order, pareto_front
from splitrender.experiments.report import build_report, markdown_to_html, worst_run
from splitrender.experiments.sections import Section
from splitrender.experiments.store import ResultStore, network_columns, read_csv, write_csv

METHODS = ("warp", "video", "atw")
NETS = ("ideal", "lan", "cloud")


def _synthetic(root: Path, ratios: bool = False) -> list[dict]:
    """runs.csv / frames.csv / per-run updates for 3 methods x 3 networks x 2 bitrates."""
    runs, frames = [], []
    store = ResultStore(root)
    i = 0
    for m in METHODS:
        for net in NETS:
            for br in (1000, 3000):
                i += 1
                key = f"k{i:02d}"
                d = network_columns(net)["net_delay_ms"]
                psnr = {"video": 30, "atw": 32, "warp": 34}[m] - d / 10 + br / 1000
                runs.append({"run": key, "method": m, "params": f"bitrate_kbps={br}", "network": net, "trace": "walk", "seed": 0,
                             "server_fps": 30 if not ratios else (30 if i % 2 else 15), "client_fps": 30,
                             "frame_ratio": 1.0 if not ratios else (1.0 if i % 2 else 0.5),
                             "frames": 10, "mean_psnr_db": psnr, "mean_ssim": 0.9 - d / 1000, "mean_flip": 0.1 + d / 1000,
                             "mean_kbps": br * 1.1, "kbps_color": br, "kbps_meta": br * 0.1,
                             "kbps_depth": br * 0.5 if m == "warp" else math.nan, "mean_server_ms": 10 + i,
                             "mean_client_ms": {"video": 0.1, "atw": 2, "warp": 40}[m], "mean_gt_ms": 50,
                             **network_columns(net)})
                for k in range(10):
                    frames.append({"run": key, "method": m, "network": net, "trace": "walk", "frame": k, "t_s": k / 30,
                                    "psnr_db": psnr - (20 if k == 5 and key == "k01" else 0), "ssim": 0.9,
                                    "hole_pct": 6.0 if k == 7 else 0.0, "update_age_ms": 30 + d})
                store.run_dir(key).mkdir(parents=True)
                write_csv(store.run_dir(key) / "updates.csv",
                          [{"frame_id": k, "t_s": k / 30, "bytes": 4000, "delivered": int(k != 3)} for k in range(10)])
                (store.run_dir(key) / "config.toml").write_text(f'[run]\nmethod = "{m}"\n')
    write_csv(root / "runs.csv", runs)
    write_csv(root / "frames.csv", frames)
    return runs


def test_report_is_self_contained_with_every_chart(tmp_path: Path) -> None:
    runs = _synthetic(tmp_path)
    sec_png = tmp_path / "study.png"
    import matplotlib.pyplot as plt

    plt.figure().savefig(sec_png)
    sec_csv = write_csv(tmp_path / "study.csv", [{"a": 1, "b": 2.5}])
    p = build_report(tmp_path, sections=[Section("Study: x", "Some **bold** text\n\n- item", [sec_png], [sec_csv])])
    html = p.read_text()
    for name in ("quality_vs_latency", "psnr_timeline", "bitrate_by_stream", "client_cost", "rate_distortion",
                 "speed_vs_accuracy", "run_timeline"):
        assert (tmp_path / "figures" / f"{name}.png").stat().st_size > 1000, name
        assert (tmp_path / "figures" / f"{name}.svg").read_text().lstrip().startswith("<?xml"), name
        assert f'id="{name}"' in html
    # no frame-ratio chart when the ratio does not vary
    assert not (tmp_path / "figures" / "quality_vs_frame_ratio.png").exists()
    imgs = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html)
    assert len(imgs) == 8  # 7 charts + the study's figure
    assert all(base64.b64decode(b)[:8] == b"\x89PNG\r\n\x1a\n" for b in imgs)
    assert 'src="figures/' not in html and "<b>bold</b>" in html and "<li>item</li>" in html
    assert "Study: x" in html and "<td>2.5</td>" in html
    # every chart names the baselines
    assert html.count("baselines: video, atw") == 1
    # the worst-PSNR run is the default timeline run
    assert worst_run(runs) == "k11" and "worst-PSNR run k11" in html  # video on cloud at 1000 kbit/s
    # data behind the charts: client cost ratio per method, baselines first
    cc = read_csv(tmp_path / "figures" / "client_cost.csv")
    assert [r["method"] for r in cc] == ["video", "atw", "warp"]
    assert cc[2]["client_over_gt"] == pytest.approx(0.8)
    bs = read_csv(tmp_path / "figures" / "bitrate_by_stream.csv")
    assert bs[2]["kbps_depth"] == pytest.approx(1000) and bs[0]["kbps_depth"] == 0
    assert bs[0]["total_kbps"] == pytest.approx(2000 + 200)
    ql = read_csv(tmp_path / "figures" / "quality_vs_latency.csv")
    assert [(r["method"], r["net_delay_ms"]) for r in ql][:3] == [("video", 0), ("video", 20), ("video", 50)]
    assert ql[2]["mean_psnr_db"] == pytest.approx(30 - 5 + 2)


def test_report_chosen_run_and_failures(tmp_path: Path) -> None:
    _synthetic(tmp_path, ratios=True)
    html = build_report(tmp_path, run_key="k01").read_text()
    assert "chosen run k01" in html
    tl = read_csv(tmp_path / "figures" / "run_timeline.csv")
    assert [r["failure"] for r in tl] == [0, 0, 0, 0, 0, 1, 0, 1, 0, 0]
    assert (tmp_path / "figures" / "quality_vs_frame_ratio.png").is_file()
    with pytest.raises(ConfigError, match="report --run nope: no such run"):
        build_report(tmp_path, run_key="nope")


def test_report_without_results(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="has neither runs.csv nor summary.csv"):
        build_report(tmp_path)


def test_missing_baselines_are_flagged(tmp_path: Path) -> None:
    _synthetic(tmp_path)
    rows = [r for r in read_csv(tmp_path / "runs.csv") if r["method"] == "warp"]
    write_csv(tmp_path / "runs.csv", rows)
    html = build_report(tmp_path).read_text()
    assert "lack the baseline(s) video, atw" in html


def test_pareto_front() -> None:
    pts = [(10, 30), (5, 25), (20, 29), (7, 31), (3, 20), (7, 28), (float("nan"), 50)]
    assert pareto_front(pts) == [(3, 20), (5, 25), (7, 31)]
    assert pareto_front([]) == []


def test_failure_mask_and_order() -> None:
    fr = [{"psnr_db": 25, "hole_pct": 0}, {"psnr_db": 19.9, "hole_pct": 0}, {"psnr_db": 30, "hole_pct": 5.1}, {"psnr_db": 20}]
    assert failure_mask(fr) == [False, True, True, False]
    assert method_order(["sas", "warp", "atw", "video", "sas"]) == ["video", "atw", "sas", "warp"]


def test_markdown_subset() -> None:
    h = markdown_to_html("# Title\n\ntext `a<b>` and *em*\n\n- x\n- y\n\n```\n<code>\n```")
    assert h == ("<h3>Title</h3>\n<p>text <code>a&lt;b&gt;</code> and <i>em</i></p>\n<ul>\n<li>x</li>\n<li>y</li>\n</ul>\n"
                 "<pre>\n&lt;code&gt;\n</pre>")


def test_charts_keep_the_scene_upload_out_of_the_rate_and_the_front(tmp_path: Path) -> None:
    """The probes client renders the scene: its one-off upload is written above its bar in kB, not averaged into a
    rate or the rate-distortion x axis, and its runs are drawn but left off the thin clients' Pareto front."""
    from splitrender.experiments.charts import bitrate_stacked, rate_distortion, speed_accuracy

    base = {"network": "ideal", "trace": "walk", "params": "", "mean_ssim": 0.9, "mean_flip": 0.1, "mean_gt_ms": 50}
    runs = [{**base, "run": "a", "method": "video", "mean_kbps": 1100, "steady_kbps": 1100, "session_kb": 0.1,
             "kbps_color": 1000, "kbps_meta": 100, "kbps_session": 0.2, "mean_psnr_db": 30, "mean_model_psnr_db": 28,
             "mean_server_ms": 10, "mean_client_ms": 1},
            {**base, "run": "b", "method": "probes", "mean_kbps": 5000, "steady_kbps": 1000, "session_kb": 500,
             "kbps_color": 900, "kbps_meta": 100, "kbps_session": 4000, "mean_psnr_db": 55, "mean_model_psnr_db": 54,
             "mean_server_ms": 10, "mean_client_ms": 2}]
    bitrate_stacked(runs, tmp_path)
    bs = {r["method"]: r for r in read_csv(tmp_path / "bitrate_by_stream.csv")}
    assert "kbps_session" not in bs["probes"] and bs["probes"]["total_kbps"] == pytest.approx(1000)
    assert bs["probes"]["session_kb"] == pytest.approx(500) and bs["video"]["session_kb"] == 0
    rate_distortion(runs, tmp_path)
    rd = {r["method"]: r for r in read_csv(tmp_path / "rate_distortion.csv")}
    assert rd["probes"]["mean_kbps"] == pytest.approx(1000)
    speed_accuracy(runs, tmp_path)
    sa = read_csv(tmp_path / "speed_vs_accuracy.csv")
    front = [r for r in sa if r["axis"] == "mean_client_ms"]
    assert [(r["x_ms"], r["model_psnr_db"]) for r in front] == [(1, 28)]  # probes (2 ms, 54 dB) is not on it
