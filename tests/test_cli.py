"""The ``splitrender`` command line: run with a config file, overrides, errors, methods."""

from __future__ import annotations

import csv
import subprocess
import sys

import pytest

from splitrender.cli import main


def _summary(path):
    return next(csv.DictReader(open(path / "summary.csv")))


def test_run_uses_the_config_file_and_only_given_options_override_it(tmp_path, capsys):
    cfg = tmp_path / "run.toml"
    cfg.write_text(
        '[run]\nmethod = "atw"\nscene = "default+nogi"\nnetwork = "lan"\ntrace = "turn"\nseed = 5\nwidth = 96\nheight = 54\n'
        "duration_s = 0.4\nflip_every = 0\n[run.method_params]\noverscan = 1.5\n"
    )
    assert main(["run", "--config", str(cfg), "--out", str(tmp_path / "a")]) == 0
    s = _summary(tmp_path / "a")
    assert (s["method"], s["network"], s["trace"], s["seed"]) == ("atw", "lan", "turn", "5")
    assert "overscan=1.5" in s["params"]
    # the written config is complete and loads back to the same run
    from splitrender.sim import RunConfig

    again = RunConfig.from_toml(tmp_path / "a" / "config.toml")
    assert again == RunConfig.from_toml(cfg)
    text = (tmp_path / "a" / "config.toml").read_text()
    assert "[resolved.method]" in text and "fill = " in text and "[resolved.network.downlink]" in text
    # a command-line option wins over the file, the rest of the file stays
    assert main(["run", "--config", str(cfg), "--network", "ideal", "--param", "overscan=1.2", "--out", str(tmp_path / "b")]) == 0
    s = _summary(tmp_path / "b")
    assert (s["method"], s["network"], s["trace"]) == ("atw", "ideal", "turn")
    assert "overscan=1.2" in s["params"]
    assert "atw on ideal" in capsys.readouterr().out


def test_run_accepts_a_network_toml_file(tmp_path):
    net = tmp_path / "net.toml"
    net.write_text("[downlink]\ndelay_ms = 40.0\n")
    assert main(["run", "--network", str(net), "--scene", "default+nogi", "--width", "64", "--height", "36", "--duration", "0.4",
                 "--flip-every", "0", "--out", str(tmp_path / "o")]) == 0
    assert float(_summary(tmp_path / "o")["mean_update_age_ms"]) > 40


@pytest.mark.parametrize(
    "args, message",
    [
        (["run", "--param", "overscan=big", "--method", "atw"], "AtwConfig.overscan: expected a number, got str 'big'"),
        (["run", "--param", "novalue"], "--param 'novalue': expected KEY=VALUE"),
        (["run", "--network", "delay fast"], "netem: 'fast' is not a time"),
        (["run", "--seed", "-1"], "run config seed: must be in"),
        (["run", "--width", "641"], "width/height: must be positive and even"),
        (["run", "--method", "teleport"], "unknown method 'teleport'"),
        (["run", "--scene", "/nonexistent/scene.glb"], "scene file not found"),
        (["run", "--trace", "moonwalk"], "unknown trace"),
        (["run", "--config", "/nonexistent/run.toml"], "config file not found"),
        (["run", "--cost-model", "measured", "--cost-scale", "0"], "run config cost_scale: must be in [0.001, 1000], got 0.0"),
        (["client", "--stall-frames", "0"], "--stall-frames: must be in [1, 1000], got 0.0"),
        (["client", "--stall-timeout", "0"], "--stall-timeout: must be in [0.1, 3600] or inf, got 0.0"),
        (["client", "--metrics-interval", "-1"], "--metrics-interval: must be in [0, 3600] s, got -1.0"),
        (["serve", "--metrics-interval", "-1"], "--metrics-interval: must be in [0, 3600] s, got -1.0"),
    ],
)
def test_bad_input_gives_one_clear_line_and_exit_2(args, message, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("splitrender: error: ") and message in err, err
    assert "Traceback" not in err


def test_methods_lists_every_registered_method_in_its_class(capsys):
    """Thin clients first; methods whose client renders the scene (probes) under their own heading."""
    from splitrender.methods import available_methods, get_method

    assert main(["methods"]) == 0
    out = capsys.readouterr().out
    for m in available_methods():
        assert out.count(f"\n  {m} ") == 1, m
    thin, scene = out.split("client renders the scene:")
    assert thin.startswith("thin clients:") and "\n  probes " in scene and "\n  sas " in thin
    assert {m for m in available_methods() if f"\n  {m} " in scene} == {m for m in available_methods()
                                                                         if get_method(m).client_draws_scene} == {"probes"}


def test_console_script_help():
    r = subprocess.run([sys.executable, "-m", "splitrender.cli", "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0
    for cmd in ("demo", "run", "sweep", "report", "stress", "serve", "client", "shape"):
        assert cmd in r.stdout
