"""Demo smoke test on a tiny config, and the study runner's isolation (errors, timeouts)."""

from __future__ import annotations

import csv
import re
import textwrap
from pathlib import Path

import pytest

from splitrender.errors import ConfigError
from splitrender.experiments.demo import demo_configs, discover_studies, run_demo, run_study
from splitrender.experiments.store import read_csv


def test_demo_tiny(tmp_path: Path) -> None:
    # one worker: the four runs in this process (run_configs' serial path).  The pool's two spawned workers cost more
    # than the runs (measured at d80c9ae: 24.9 CPU s with workers=2, 17.8 with 1); the pool itself is test_sweep's
    res = run_demo(tmp_path, quick=True, methods=["video", "atw"], networks=["ideal", "cloud"], duration_s=0.5, size=(160, 90),
                   studies=False, workers=1)
    assert not res.failures
    for name in ("frames.csv", "summary.csv", "runs.csv", "report.html", "report_meta.json"):
        assert (tmp_path / name).is_file(), name
    with open(tmp_path / "summary.csv") as f:
        header = next(csv.reader(f))
    for col in ("method", "network", "mean_psnr_db", "mean_ssim", "mean_flip", "mean_kbps", "client_over_gt"):
        assert col in header, col
    summ = read_csv(tmp_path / "summary.csv")
    assert sorted((r["method"], r["network"]) for r in summ) == sorted(
        (m, n) for m in ("video", "atw") for n in ("ideal", "cloud"))
    by = {(r["method"], r["network"]): r for r in summ}
    for r in summ:
        assert 10 < r["mean_psnr_db"] < 60 and 0 < r["mean_ssim"] <= 1 and r["mean_kbps"] > 0
        assert 10 < r["mean_model_psnr_db"] < 60 and 0 < r["mean_model_pct"] < 100  # the default scene less its floor
        assert 0 < r["mean_flip"] < 1  # FLIP sampled every 6th frame
    # latency costs quality for plain video; ATW recovers part of it
    assert by[("video", "cloud")]["mean_psnr_db"] < by[("video", "ideal")]["mean_psnr_db"]
    assert by[("atw", "cloud")]["mean_psnr_db"] > by[("video", "cloud")]["mean_psnr_db"]
    frames = read_csv(tmp_path / "frames.csv")
    assert {"method", "network", "run", "psnr_db", "t_s"} <= set(frames[0])
    runs = read_csv(tmp_path / "runs.csv")
    assert len(runs) == 4 and len(frames) == sum(r["frames"] for r in runs)
    for r in runs:
        d = tmp_path / "runs" / r["run"]
        assert (d / "config.toml").is_file() and (d / "frames.csv").is_file() and (d / "updates.csv").is_file()
        assert r["width"] == 160 and r["height"] == 90
    for name in ("quality_vs_latency", "psnr_timeline", "bitrate_by_stream", "client_cost"):
        assert (tmp_path / "figures" / f"{name}.png").is_file() and (tmp_path / "figures" / f"{name}.svg").is_file()
    html = (tmp_path / "report.html").read_text()
    # the answer first: the headline table per network, then speed against accuracy, then how it was scored
    assert html.index("id='answer'") < html.index('id="speed_vs_accuracy"') < html.index("What ran")
    assert re.search(r"<h3>cloud</h3><table><tr><th>front</th><th>method</th><th>model PSNR dB</th>", html)
    assert len(re.findall(r'src="data:image/png;base64,', html)) >= 6
    for needle in ('id="quality_vs_latency"', 'id="psnr_timeline"', 'id="bitrate_by_stream"', 'id="client_cost"',
                   "flip_every = 6", "50 ms +- 20 ms", "Quality over time (cloud)"):
        assert needle in html, needle
    # the report can be rebuilt from the folder alone (what `splitrender report DIR` does)
    from splitrender.experiments.report import build_report

    again = build_report(tmp_path).read_text()
    assert "flip_every = 6" in again and "splitrender demo (quick)" in again


def test_demo_configs() -> None:
    q = demo_configs(True, ["video", "atw"])
    assert len(q) == 6 and {c.network for c in q} == {"ideal", "lan", "cloud"}
    assert all((c.width, c.height, c.client_fps, c.flip_every) == (320, 180, 30, 6) for c in q)
    full = demo_configs(False, ["video"])
    assert {c.trace for c in full} == {"walk", "turn"} and all(c.width == 640 and c.duration_s is None for c in full)
    with pytest.raises(ConfigError, match="demo --methods: unknown method 'nosuch'"):
        demo_configs(True, ["nosuch"])


def test_studies_are_discovered() -> None:
    names = discover_studies()
    assert all(not n.startswith("_") for n in names)


@pytest.fixture()
def fake_studies(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    pkg = tmp_path / "fakestudies"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "ok.py").write_text(textwrap.dedent("""
        from splitrender.experiments.sections import Section
        def run(out_dir, quick):
            (out_dir / "t.csv").write_text("a\\n1\\n")
            return Section("Study: ok", f"quick={quick}", [], [out_dir / "t.csv"])
    """))
    (pkg / "boom.py").write_text("def run(out_dir, quick):\n    raise RuntimeError('study exploded')\n")
    (pkg / "hang.py").write_text("import time\ndef run(out_dir, quick):\n    time.sleep(60)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    return "fakestudies"


def test_study_runner_isolates_errors_and_timeouts(tmp_path: Path, fake_studies: str) -> None:
    ok = run_study(f"{fake_studies}.ok", tmp_path / "ok", True, 60)
    assert ok.title == "Study: ok" and ok.text_md == "quick=True" and ok.tables[0].is_file()
    boom = run_study(f"{fake_studies}.boom", tmp_path / "boom", True, 60)
    assert boom.title.endswith("(failed)") and "study exploded" in boom.text_md
    hang = run_study(f"{fake_studies}.hang", tmp_path / "hang", True, 3)
    assert hang.title.endswith("(not completed)") and "stopped after" in hang.text_md


def test_the_study_command_adds_studies_to_a_folders_report(tmp_path: Path, fake_studies: str,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """``splitrender study NAME|all --out DIR``: each study in its own process into ``DIR/studies/NAME`` with its
    ``section.json`` (the section and its time); the report of DIR lists each with its time; a failing study is
    reported, not raised, and makes the exit status 1; an unknown name is a ConfigError listing the studies."""
    import argparse

    from splitrender.experiments import demo

    names = [f"{fake_studies}.ok", f"{fake_studies}.boom"]
    monkeypatch.setattr(demo, "discover_studies", lambda: names)
    ns = argparse.Namespace(names="all", out=tmp_path / "d", quick=True, timeout=60.0)
    assert demo.main_study(ns) == 1                           # boom failed
    for n in names:
        assert (tmp_path / "d" / "studies" / n / "section.json").is_file()
    html = (tmp_path / "d" / "report.html").read_text()
    assert "Study: ok" in html and "study time:" in html and "study exploded" in html
    assert re.search(r"<li>Study: ok \(\d+ s\)</li>", html)
    ns.names = f"{fake_studies}.ok"
    assert demo.main_study(ns) == 0
    with pytest.raises(ConfigError, match=r"study: unknown study nope; available: all, fakestudies.ok"):
        demo.main_study(argparse.Namespace(names="nope", out=tmp_path / "d", quick=True, timeout=60.0))


def test_headline_ranks_by_model_psnr_and_lists_scene_rendering_clients_apart() -> None:
    """Thin clients ranked among themselves on (client cost, model PSNR); probes below its own heading, with its
    scene upload beside the score, even though its PSNR beats every thin client's."""
    from splitrender.experiments.headline import headline_markdown, headline_rows, headline_text

    def row(m: str, model: float, whole: float, client: float, upload: float = 0.0) -> dict:
        return {"method": m, "network": "ideal", "mean_model_psnr_db": model, "mean_psnr_db": whole, "mean_flip": 0.1,
                "mean_kbps": 1000.0, "session_kb": upload, "mean_gt_ms": 10.0, "mean_server_ms": 20.0, "client_over_gt": client}

    summ = [row("video", 30.0, 36.0, 0.1), row("probes", 55.0, 58.0, 1.5, 600.0), row("sas", 33.0, 34.0, 0.1),
            row("atw", 31.0, 37.0, 0.05)]
    t = headline_rows(summ)["ideal"]
    # whole-frame PSNR would put video on the front beside atw; over the model sas dominates it
    assert [(x["method"], x["rank"]) for x in t] == [("sas", 1), ("atw", 1), ("video", 2), ("probes", 1)]
    md = headline_markdown({"ideal": t})
    assert md.index("| 2 | video |") < md.index("*client renders the scene:*") < md.index("| 1 | probes * | 55.0 | 58.0 |")
    assert "| 1 | probes * | 55.0 | 58.0 | 0.100 | 1000 | 600 |" in md and "| 1 | sas | 33.0 | 34.0 | 0.100 | 1000 | - |" in md
    assert "client renders the scene:" in headline_text({"ideal": t})


def test_front_ranks_are_non_dominated_layers() -> None:
    from splitrender.experiments.headline import front_ranks

    # (client cost, PSNR): a and b on the front, c dominated by a, d dominated by c (and a), e unranked
    pts = [(1.0, 30.0), (0.1, 20.0), (2.0, 25.0), (3.0, 24.0), (float("nan"), 40.0)]
    assert front_ranks(pts) == [1, 1, 2, 3, 0]


def test_a_study_that_measures_speed_runs_alone_after_the_others(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The ``live`` study measures wall-clock rates: it starts only once every other study has ended."""
    import splitrender.experiments.demo as demo

    pkg = tmp_path / "timedstudies"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    body = textwrap.dedent("""
        import time
        from splitrender.experiments.sections import Section
        def run(out_dir, quick):
            t0 = time.time()
            time.sleep({sleep})
            return Section("{name}", f"{{t0}} {{time.time()}}")
    """)
    for name, sleep in (("slow", 3.0), ("quick", 2.5), ("alone", 0.2)):   # long enough to overlap on a busy machine
        (pkg / f"{name}.py").write_text(body.format(name=name, sleep=sleep))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(demo, "EXCLUSIVE_STUDIES", ("timedstudies.alone",))
    names = ["timedstudies.alone", "timedstudies.slow", "timedstudies.quick"]
    secs, notes = demo.StudyRunner(tmp_path / "out", True, names=names).start().collect(None)
    spans = {s.title: tuple(map(float, s.text_md.split())) for s in secs}
    assert [s.title for s in secs] == ["alone", "slow", "quick"]          # reported in the order asked for
    assert spans["alone"][0] >= max(spans["slow"][1], spans["quick"][1])   # started after both had ended
    assert spans["slow"][0] < spans["quick"][1] and spans["quick"][0] < spans["slow"][1]   # those two together
