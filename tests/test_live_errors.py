"""Startup and connection failures of ``splitrender serve`` / ``splitrender client``:
a clear ``splitrender: error: ...`` line and exit status 2, never a traceback; and
the --sdp-dir hint."""

from __future__ import annotations

import logging
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from splitrender.cli import main
from splitrender.client.session import ClientConfig, LiveClient
from splitrender.errors import ConfigError
from splitrender.server.server import LiveServer, ServerConfig
from splitrender.transport import BindError, ConnectError

LOOPBACK = "127.0.0.1"
BAD_HOST = "999.1.1.1"


def _unresolvable() -> str:
    """What this platform's resolver says about ``BAD_HOST``."""
    try:
        socket.getaddrinfo(BAD_HOST, 1)
    except socket.gaierror as exc:
        return f"cannot resolve host ({exc.strerror})"
    raise AssertionError(f"{BAD_HOST} resolved")


@pytest.fixture
def busy_port() -> Iterator[int]:
    """A loopback TCP port that is bound and listening (so nobody else can have it)."""
    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        s.listen()
        yield s.getsockname()[1]


@pytest.fixture
def closed_port() -> int:
    """A loopback TCP port with nothing listening (connecting is refused)."""
    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize(("argv", "message"), [
    (["serve", "--param", "atw.nosuch=1"],
     "--param atw.*: AtwConfig: unknown parameter 'nosuch' (valid: bitrate_kbps, chroma, codec, crf, fill, gop, lossless, overscan, "
     "preset)"),
    (["serve", "--param", "atw.overscan=abc"], "--param atw.*: AtwConfig.overscan: expected a number, got str 'abc'"),
    (["serve", "--param", "video.gop=0"], "--param video.*: VideoConfig.gop: must be >= 1, got 0"),
    (["serve", "--param", "nosuch.x=1"], "--param nosuch.*: unknown method 'nosuch'; available: video, atw, warp, sas, tss, quads, probes"),
    (["serve", "--methods", "video", "--param", "atw.overscan=1.4"],
     "--param atw.*: method 'atw' is not offered (offered: video)"),
    (["serve", "--port", "70000"], "--port: must be in [0, 65535], got 70000"),
    (["serve", "--udp-port", "-1"], "--udp-port: must be in [0, 65535], got -1"),
    (["client", "--port", "70000"], "--port: must be in [1, 65535], got 70000"),
    (["client", "--playout-delay", "-5"], "--playout-delay: must be in [0, 2000], got -5.0"),
    (["client", "--jitter-timeout", "0.5"], "--jitter-timeout: must be in [1, 10000], got 0.5"),
    (["client", "--nack-tries", "99"], "--nack-tries: must be in [0, 20], got 99"),
    (["serve", "--render-deadline", "0"], "--render-deadline: must be in [0.05, 3600] s, got 0.0"),
    (["serve", "--gi-hz", "-1"], "--gi-hz: must be 0 (every frame) or in [0.1, 240], got -1"),
    (["serve", "--gi-hz", "0.05"], "--gi-hz: must be 0 (every frame) or in [0.1, 240], got 0.05"),
    (["client", "--rows-kept", "0"], "--rows-kept: must be in [1, 10000000], got 0"),
    (["client", "--connect-timeout", "0"], "--connect-timeout: must be in (0, 3600] s, got 0.0"),
])
def test_bad_arguments_are_refused_at_startup(argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    if argv[0] == "serve":  # should a check regress, the server fails to bind instead of serving forever
        argv = [*argv, "--host", BAD_HOST]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err == f"splitrender: error: {message}\n"


def test_client_connect_timeout_reaches_its_config() -> None:
    """``client --connect-timeout`` sets how long the client waits for its Welcome (5 s unless given: a loaded
    machine's sas set-up took longer, so the live-rate benchmark asks for 60)."""
    import argparse

    from splitrender.client.cli import add_client_arguments, config_from_args

    p = argparse.ArgumentParser()
    add_client_arguments(p)
    assert config_from_args(p.parse_args([])).connect_timeout_s == 5.0   # type: ignore[attr-defined]
    assert config_from_args(p.parse_args(["--connect-timeout", "60"])).connect_timeout_s == 60.0   # type: ignore[attr-defined]


def test_live_server_checks_method_params_before_starting() -> None:
    with pytest.raises(ConfigError, match=r"^--param atw\.\*: AtwConfig: unknown parameter 'nosuch'"):
        LiveServer(ServerConfig(method_params={"atw": {"nosuch": 1}}))


@pytest.mark.parametrize(("host", "which", "reason"), [
    (LOOPBACK, "tcp", "address already in use"),
    (BAD_HOST, "udp", None),
    (LOOPBACK, "port", "port must be in [0, 65535]"),
])
async def test_live_server_bind_errors(host: str, which: str, reason: str | None, busy_port: int) -> None:
    port = 70000 if which == "port" else busy_port
    udp = 0 if which == "tcp" else port
    cfg = ServerConfig(host=host, port=port, udp_port=udp, scene="minimal")
    where = f"tcp {host}:{port}" if which == "tcp" else f"udp {host}:{udp}"
    with pytest.raises(BindError) as info:
        async with LiveServer(cfg):
            pass
    assert str(info.value) == f"cannot listen on {where}: {reason or _unresolvable()}"
    assert isinstance(info.value, OSError)


@pytest.mark.parametrize(("host", "reason"), [
    (LOOPBACK, "connection refused"),
    (BAD_HOST, None),
])
async def test_live_client_connect_errors(host: str, reason: str | None, closed_port: int) -> None:
    with pytest.raises(ConnectError) as info:
        await LiveClient(ClientConfig(server=host, port=closed_port, duration_s=0.5)).run()
    assert str(info.value) == f"cannot connect to {host}:{closed_port}: {reason or _unresolvable()}"
    assert isinstance(info.value, ConnectionError)


def test_cli_port_in_use_and_refused_connection_exit_2(busy_port: int, closed_port: int) -> None:
    """The real processes: one clean line on stderr, exit status 2, no traceback."""
    cmd = [sys.executable, "-m", "splitrender.cli"]
    procs = [
        subprocess.Popen(cmd + ["serve", "--port", str(busy_port), "--udp-port", "0", "--scene", "minimal"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True),
        subprocess.Popen(cmd + ["client", "--port", str(closed_port), "--duration", "1"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True),
    ]
    expected = [f"splitrender: error: cannot listen on tcp {LOOPBACK}:{busy_port}: address already in use\n",
                f"splitrender: error: cannot connect to {LOOPBACK}:{closed_port}: connection refused\n"]
    for proc, want in zip(procs, expected):
        try:
            _, err = proc.communicate(timeout=60)
        finally:
            if proc.returncode is None:
                proc.kill()
        assert (proc.returncode, err) == (2, want)


async def test_sdp_dir_without_mirror_port_logs_a_hint(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="splitrender.server.server")
    for mirror in (None, 5004):
        caplog.clear()
        cfg = ServerConfig(host=LOOPBACK, port=0, udp_port=0, scene="minimal", sdp_dir=tmp_path, mirror_port=mirror)
        async with LiveServer(cfg):
            pass
        hints = [r.getMessage() for r in caplog.records if "--mirror-port" in r.getMessage()]
        if mirror is None:
            assert len(hints) == 1 and "ffplay on this host cannot bind" in hints[0], hints
        else:
            assert hints == []


@pytest.mark.parametrize("bad", [[[0, 0, 0]], [[0, 0, "x"], [1, 1, 1]], [[0, 0, 0], [1, float("nan"), 1]], [[2, 0, 0], [1, 1, 1]], 7])
def test_malformed_subject_bounds_name_the_field(bad) -> None:  # type: ignore[no-untyped-def]
    from splitrender.pipeline.session import parse_subject as _parse_subject
    from splitrender.pipeline import EnvelopeError

    with pytest.raises(EnvelopeError, match="Welcome.method_params.subject"):
        _parse_subject(bad)
