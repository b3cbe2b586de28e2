"""End-to-end live sessions on loopback: server, shaping relay and client in one event loop.

The slow test runs ``video`` through the relay with the ``cloud`` delay (50 ± 20 ms
uniform, each way) plus 1% loss on both directions, then scores the recording with
the virtual-time metrics and compares it with the virtual-time run of the same trace,
scene, size and network: mean PSNR within ``PSNR_TOLERANCE_DB``.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from splitrender.client.score import score_recording
from splitrender.client.session import ClientConfig, LiveClient
from splitrender.netsim import Relay, parse_path
from splitrender.pipeline import FrameReleased
from splitrender.server.server import LiveServer, ServerConfig

from _load import LoadMeter, slowdown_over

LOOPBACK = "127.0.0.1"
NETWORK = "delay 50ms 20ms distribution uniform loss 1%"
PSNR_TOLERANCE_DB = 3.0
GOP_S = 1.0  # gop 30 at 30 fps
STOP_S = 2.0
"""``serve`` exits within this long of SIGTERM on an idle machine (scaled by the measured load: :mod:`tests._load`)."""
LONG_GOP = 900  # 30 s at 30 fps: no scheduled keyframe but the first in a short run


def _server_config(**kw: object) -> ServerConfig:
    base: dict[str, object] = dict(host=LOOPBACK, port=0, udp_port=0, scene="minimal", server_fps=30)
    base.update(kw)
    return ServerConfig(**base)  # type: ignore[arg-type]


async def _run_through_relay(tmp: Path, network: str, seed: int = 3, server_kw: dict[str, object] | None = None,  # type: ignore[no-untyped-def]
                             **client_kw: object):
    async with LiveServer(_server_config(**(server_kw or {}))) as server:
        serve = asyncio.create_task(server.serve_forever())
        relay = Relay(parse_path(network), seed=seed)
        try:
            tcp = await relay.start_tcp((LOOPBACK, 0), server.tcp_address)
            udp = await relay.start_udp((LOOPBACK, 0), server.udp_address)
            cfg = ClientConfig(server=LOOPBACK, port=tcp[1], udp_port=udp[1], width=320, height=180,
                               out_dir=tmp, save_images=True, **{"trace": "walk", **client_kw})  # type: ignore[arg-type]
            run = asyncio.create_task(asyncio.wait_for(LiveClient(cfg).run(), cfg.duration_s + 20))
            while not server.sessions and not run.done():  # keep the session: it unregisters at Bye
                await asyncio.sleep(0.01)
            sessions = list(server.sessions.values())
            result = await run
            assert len(sessions) == 1, sessions
            counters = dict(sessions[0].counters)
            counters["update_rows"] = list(sessions[0].update_rows)
        finally:
            await relay.wait_tcp_idle(1.0)  # let the relay see both TCP sides close before closing it
            await relay.close()
            serve.cancel()
            await asyncio.gather(serve, return_exceptions=True)
        return result, relay.stats(), counters


def _update_gaps_s(rows: list[dict]) -> list[float]:  # type: ignore[type-arg]
    """Seconds between successive displays of a new update."""
    rows = [r for r in rows if r["update_frame_id"] != -1]  # ticks before the first update
    times = [r["displayed_us"] / 1e6 for k, r in enumerate(rows)
             if k == 0 or r["update_frame_id"] != rows[k - 1]["update_frame_id"]]
    return list(np.diff(times))


@pytest.mark.slow
async def test_video_through_lossy_cloud_relay_matches_virtual_time(tmp_path: Path, renderer) -> None:  # type: ignore[no-untyped-def]
    duration = 4.0
    result, relay_stats, sc = await _run_through_relay(tmp_path, NETWORK, duration_s=duration)
    rows = result.rows
    c = result.counters
    # frames keep being shown: most display ticks that ran (a busy machine skips late ones, counted) show something
    ran = duration * 60 - c["late_ticks"]
    assert len(rows) + c["late_ticks"] == duration * 60, (len(rows), c)
    assert sum(r["update_frame_id"] != -1 for r in rows) >= 0.5 * ran, (len(rows), c)
    # most frames the server sent complete (measured 103 of 111 and 102 of 115 at load 10: 1 % loss, NACK repairs most),
    # counted against what was sent, not the wall clock's frame rate (a busy machine sends fewer)
    assert sc["frames_sent"] >= 10 and c["frames_complete"] >= 0.7 * sc["frames_sent"], (c, sc)
    # the relay really lost packets downstream, and the stream went on
    assert relay_stats.downlink.packets_dropped > 0, relay_stats
    gaps = _update_gaps_s(rows)
    assert max(gaps) < GOP_S, (max(gaps), c)
    # no metadata lost: FrameMeta ids arrive contiguous over TCP, and every displayed
    # update's FrameMeta arrived
    first, n = result.counters["meta_first_id"], result.counters["frames_meta"]
    assert result.counters["meta_gaps"] == 0 and result.counters["meta_last_id"] == first + n - 1
    assert {int(r["update_frame_id"]) for r in rows} - {-1} <= set(range(first, first + n))  # -1: ticks before the first
    # quality close to the virtual-time run of the same trace and network
    live = await asyncio.get_running_loop().run_in_executor(None, _score_and_reference, tmp_path, duration)
    live_psnr, vt_psnr = live
    assert abs(live_psnr - vt_psnr) < PSNR_TOLERANCE_DB, (live_psnr, vt_psnr)


def _score_and_reference(out: Path, duration: float) -> tuple[float, float]:
    from splitrender.render import Renderer
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import VirtualTimeRun

    r = Renderer()  # this worker thread's own GL context
    s = score_recording(out, renderer=r, flip_every=0)
    vt = VirtualTimeRun(RunConfig(method="video", scene="minimal", trace="walk", network=NETWORK, width=320, height=180,
                                  duration_s=duration, flip_every=0, seed=3), renderer=r).run()
    return float(s["mean_psnr_db"]), float(vt.summary["mean_psnr_db"])


@pytest.mark.slow
async def test_loss_without_nack_recovers_through_pli_and_idr(tmp_path: Path) -> None:
    """NACK off and 2% loss: every broken frame must be healed by a PLI-triggered IDR.

    The GOP (``LONG_GOP`` frames) is far longer than the run, so the only scheduled
    keyframe is the first one: every later IDR answers a PLI.
    """
    result, _, server_counters = await _run_through_relay(
        tmp_path, "loss 2%", seed=5, server_kw={"method_params": {"video": {"gop": LONG_GOP}}}, duration_s=3.0,
        nack_max_tries=0, jitter_timeout_ms=60.0, pli_interval_ms=100.0)
    c = result.counters
    # the client sent PLIs, the server received them and answered with IDRs beyond the first,
    # and at least one of them reached the client after it had sent a PLI
    assert c["plis_sent"] > 0 and server_counters["plis"] > 0, (c, server_counters)
    assert server_counters["keyframes"] >= 2, server_counters
    assert c["keyframes_after_pli"] >= 1, c
    gaps = _update_gaps_s(result.rows)
    assert max(gaps) < GOP_S, (max(gaps), c)
    # most frames sent complete (measured 0.50-0.72 of them at load 10: each loss breaks the stream until the IDR it
    # asks for), counted against what the server sent, not the wall clock's frame rate
    assert server_counters["frames_sent"] >= 10 and c["frames_complete"] >= 0.4 * server_counters["frames_sent"], (
        c, server_counters)


class _RecordingClient(LiveClient):
    """Records, for every update that became complete, its planes and RTP timestamps."""

    def __init__(self, config: ClientConfig) -> None:
        super().__init__(config)
        self.completed: dict[int, tuple[dict[str, int], dict[str, tuple[tuple[int, ...], str]]]] = {}

    def _take_events(self) -> None:
        self.record_released()
        super()._take_events()

    def record_released(self) -> None:
        """The frames the core announced released for display (FrameReleased), before the driver takes its events;
        once more after the run for those it left untaken."""
        for ev in list(self.core.events) if self.core is not None else []:
            if isinstance(ev, FrameReleased) and (fr := ev.frame).update.complete:
                self.completed[fr.update.frame_id] = (dict(fr.meta.rtp_timestamps),
                                                      {n: (p.shape, str(p.dtype)) for n, p in fr.update.planes.items()})


async def test_warp_colour_and_depth_streams_are_matched_and_shown(tmp_path: Path) -> None:
    """``warp`` sends two video streams per frame (colour, lossless depth); the client pairs
    them by RTP timestamp with the FrameMeta of the same frame and shows the result."""
    duration = 2.0
    async with LiveServer(_server_config(methods=("warp",))) as server:
        serve = asyncio.create_task(server.serve_forever())
        try:
            client = _RecordingClient(ClientConfig(server=LOOPBACK, port=server.tcp_address[1], methods=("warp",),
                                                   width=160, height=90, display_hz=30, duration_s=duration,
                                                   out_dir=tmp_path))
            run = asyncio.create_task(asyncio.wait_for(client.run(), duration + 20))
            while not server.sessions and not run.done():  # keep the session: it unregisters at Bye
                await asyncio.sleep(0.01)
            sessions = list(server.sessions.values())
            result = await run
            client.record_released()
            sc = dict(sessions[0].counters)
        finally:
            serve.cancel()
            await asyncio.gather(serve, return_exceptions=True)
    streams = [s.name for s in client._welcome.streams]  # type: ignore[union-attr]
    assert [s.codec for s in client._welcome.streams] == ["h264", "hevc"]  # type: ignore[union-attr]
    assert len(streams) == 2 and streams[0].startswith("color") and streams[1].startswith("depth"), streams
    c = result.counters
    # what was completed against what was sent, not a rate (a loaded machine sends fewer frames in 2 s): no loss
    # on loopback, so every frame but those in flight at the end
    assert sc["frames_sent"] >= 10 and c["frames_complete"] >= sc["frames_sent"] - 3 and c["frames_partial"] <= 2, (c, sc)
    assert len(client.completed) == c["frames_complete"]
    for fid, (rtp_ts, planes) in client.completed.items():
        # both streams of the frame, decoded, under the one RTP timestamp of the frame
        assert set(rtp_ts) == set(streams) == set(planes), (fid, rtp_ts, planes)
        assert len(set(rtp_ts.values())) == 1, (fid, rtp_ts)
        # colour is RGB; depth is the 16-bit codes as two 8-bit halves stacked (2 x height)
        (h, w, ch), _ = planes[streams[0]]
        assert ch == 3 and planes[streams[1]][0] == (2 * h, w), (fid, planes)
    # timestamps advance with the frames: distinct frames never share one
    assert len({next(iter(ts.values())) for ts, _ in client.completed.values()}) == len(client.completed)
    shown = {int(r["update_frame_id"]) for r in result.rows} - {-1}
    # the display shows the newest complete update at each of its ticks, so it skips updates only where its ticks
    # ran late (measured at load 24: 21 and 42 shown of 28 and 56 complete, all sent)
    assert shown <= set(client.completed), (sorted(shown), sorted(client.completed))
    assert len(shown) >= 0.5 * c["frames_complete"], (len(shown), c)
    assert (tmp_path / "frames.csv").read_text().count("\n") == len(result.rows) + 1


def test_cli_serve_and_client_smoke(tmp_path: Path) -> None:
    """``splitrender serve`` and ``splitrender client`` as subprocesses, 1.5 s of video."""
    port = _free_port()
    srv = _serve(port, "video,atw")
    try:
        out = tmp_path / "rec"
        cli = subprocess.run([sys.executable, "-m", "splitrender.cli", "client", "--port", str(port), "--method", "atw",
                              "--width", "160", "--height", "90", "--duration", "1.5", "--out", str(out)],
                             capture_output=True, text=True, timeout=60)
        assert cli.returncode == 0, cli.stderr
        assert "frames displayed" in cli.stdout
        assert (out / "frames.csv").read_text().count("\n") > 10
    finally:
        srv.send_signal(2)  # SIGINT: clean shutdown
        try:
            _, err = srv.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            srv.kill()
            raise
    assert srv.returncode == 0, err
    assert "server stopped" in err
    assert "Traceback" not in err


def _sigterm_within_stop_s(srv: subprocess.Popen) -> str:  # type: ignore[type-arg]
    """SIGTERM ``srv``; it exits 0 within :data:`STOP_S` scaled by the load measured meanwhile; its stderr."""
    import signal
    import time

    with LoadMeter() as load:
        t0 = time.monotonic()
        srv.send_signal(signal.SIGTERM)
        try:
            _, err = srv.communicate(timeout=10 * STOP_S)
        except subprocess.TimeoutExpired:
            srv.kill()
            raise
        took = time.monotonic() - t0
    # the 2 s of an idle machine, in proportion to the share of a core each process gets now (3.85 s once with
    # two busy loops beside the suite, which this bound now scales for)
    assert srv.returncode == 0 and took < STOP_S * load.slowdown, (took, load.slowdown, err)
    return err


@pytest.mark.slow
def test_sigterm_stops_the_server_within_two_seconds_idle_and_while_streaming(tmp_path: Path) -> None:
    """``splitrender serve`` exits 0 within 2 s of SIGTERM with no session, and with two clients streaming;
    the clients then end with a non-zero exit and a recording that says the session broke."""
    import json
    import time

    def stop(srv: subprocess.Popen) -> None:
        err = _sigterm_within_stop_s(srv)
        assert "server stopped" in err and "Traceback" not in err, err

    stop(_serve(_free_port()))
    port = _free_port()
    srv = _serve(port)
    clients = [_client(port, tmp_path / f"c{k}") for k in range(2)]
    try:
        end = time.monotonic() + 30
        while time.monotonic() < end and not all((tmp_path / f"c{k}" / "frames.jsonl").is_file()
                                                 and (tmp_path / f"c{k}" / "frames.jsonl").stat().st_size > 0 for k in range(2)):
            time.sleep(0.1)
        assert all(c.poll() is None for c in clients), "the clients stream"
        stop(srv)
        for k, c in enumerate(clients):
            c.communicate(timeout=20)
            assert c.returncode != 0
            rec = json.loads((tmp_path / f"c{k}" / "recording.json").read_text())
            assert rec["complete"] is False and rec["error"], rec
    finally:
        for c in clients:
            if c.poll() is None:
                c.kill()
                c.communicate(timeout=5)


def _client(port: int, out: Path, duration_s: float = 20.0) -> subprocess.Popen:  # type: ignore[type-arg]
    return subprocess.Popen([sys.executable, "-m", "splitrender.cli", "client", "--port", str(port), "--width", "160",
                             "--height", "90", "--duration", str(duration_s), "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _rows(out: Path) -> int:
    journal = out / "frames.jsonl"
    return journal.read_text().count("\n") if journal.is_file() else 0


@pytest.mark.slow
def test_a_hung_render_ends_its_session_only_and_sigterm_still_stops_the_server(tmp_path: Path) -> None:
    """The ``SPLITRENDER_TEST_HANG`` hook spins the first session's render worker at frame 8, holding that
    process's interpreter lock as the Mesa stall did.  With a 1.5 s deadline the watchdog kills that worker:
    its client exits non-zero naming the deadline, the second session keeps streaming (its journal grows after
    the first client ended) and SIGTERM stops the server within 2 s.  Then, with a 60 s deadline, SIGTERM
    during the hang (the render still stuck) stops the server within 2 s too."""
    import time

    port = _free_port()
    srv = _serve(port, "video", "--render-deadline", "1.5", hang="1:8")
    first, second = tmp_path / "first", tmp_path / "second"
    clients = []
    try:
        clients.append(_client(port, first))
        _wait_rows(first / "frames.jsonl", 1, clients[0])
        clients.append(_client(port, second))
        _, err = clients[0].communicate(timeout=30)
        assert clients[0].returncode != 0, err
        assert "missed its 1.5 s deadline" in err, err
        n = _rows(second)
        end = time.monotonic() + 20
        while time.monotonic() < end and _rows(second) < n + 30:
            time.sleep(0.1)
        assert _rows(second) >= n + 30, "the second session keeps streaming"
        assert clients[1].poll() is None
        err = _sigterm_within_stop_s(srv)
        assert "missed its 1.5 s deadline" in err and "Traceback" not in err, err
        clients[1].communicate(timeout=20)

        port = _free_port()
        srv = _serve(port, "video", "--render-deadline", "60", hang="1:3")
        clients.append(_client(port, tmp_path / "third"))
        _wait_rows(tmp_path / "third" / "frames.jsonl", 1, clients[2])
        time.sleep(1.0)                      # the worker is now spinning inside frame 3
        err = _sigterm_within_stop_s(srv)
    finally:
        if srv.poll() is None:
            srv.kill()
            srv.communicate(timeout=5)
        for c in clients:
            if c.poll() is None:
                c.kill()
                c.communicate(timeout=5)


@pytest.mark.slow
def test_one_shared_worker_serves_every_session_and_is_replaced_after_a_hang(tmp_path: Path) -> None:
    """``--isolation server``: both sessions run in one render worker; when the second one's render hangs
    (its frame 3) the watchdog kills it, both sessions end with the deadline named, and the next client
    streams from a fresh worker.  (The hang was the first session's frame 12, which a loaded machine could reach
    before the second client had started, which then streamed from a fresh worker and ended well.)"""
    port = _free_port()
    srv = _serve(port, "video", "--isolation", "server", "--render-deadline", "1.5", hang="2:3")
    outs = [tmp_path / f"c{k}" for k in range(3)]
    clients = [_client(port, outs[0])]
    try:
        _wait_rows(outs[0] / "frames.jsonl", 1, clients[0])
        clients.append(_client(port, outs[1]))
        for c in clients:
            _, err = c.communicate(timeout=30)
            assert c.returncode != 0 and "missed its 1.5 s deadline" in err, err
        clients.append(_client(port, outs[2], duration_s=1.5))
        _, err = clients[2].communicate(timeout=60)
        assert clients[2].returncode == 0, err
        assert (outs[2] / "frames.csv").read_text().count("\n") > 10
    finally:
        srv.send_signal(2)
        _, err = srv.communicate(timeout=15)
        for c in clients:
            if c.poll() is None:
                c.kill()
                c.communicate(timeout=5)
    assert err.count("missed its 1.5 s deadline") >= 2, err   # the watchdog's line and each session's error
    pids = {line.split("pid ")[1].split(")")[0] for line in err.splitlines() if "render worker" in line and "pid " in line}
    assert len(pids) == 1, pids                                # one worker served both sessions


async def test_a_playout_delay_holds_every_update_until_its_turn(tmp_path: Path) -> None:
    """``playout_delay_ms``: no update reaches the screen sooner than its server time plus the delay, and the
    updates still come one after another; a delay outside [0, 2000] ms is refused by name."""
    from splitrender.errors import ConfigError

    with pytest.raises(ConfigError, match="playout_delay_ms"):
        ClientConfig(playout_delay_ms=5000.0)
    result, _, sc = await _run_through_relay(tmp_path, "delay 10ms", duration_s=1.5, display_hz=30, playout_delay_ms=120.0)
    rows = [r for r in result.rows if r["update_frame_id"] != -1]
    ages = [r["update_age_ms"] for r in rows]
    # shown against sent, not a rate (a loaded machine sends fewer frames in 1.5 s): the delay holds each update
    # back, it loses none; the display skips one only where its ticks ran late (measured at load 24: 17 and 11 shown of
    # 21 and 15 complete, of 22 and 16 sent)
    c = result.counters
    assert c["frames_complete"] >= sc["frames_sent"] - 3, (c, sc)
    assert len({r["update_frame_id"] for r in rows}) >= max(5, 0.5 * c["frames_complete"]), (len(rows), c)
    assert min(ages) >= 120.0, min(ages)


BOX_TEXTURED = Path("/usr/share/assimp/models/glTF2/BoxTextured-glTF-Binary/BoxTextured.glb")


@pytest.mark.skipif(not BOX_TEXTURED.is_file(), reason="assimp-testmodels not installed")
async def test_live_client_fits_builtin_traces_around_a_loaded_model(tmp_path: Path) -> None:
    """The server sends the model's bounds (``subject``); the client's ``orbit`` goes around the model,
    pose for pose the trace the simulator uses, not the default scene's orbit."""
    from splitrender.scene import get_scene
    from splitrender.scene.pose import Pose
    from splitrender.scene.trace import get_trace

    result, _, _ = await _run_through_relay(tmp_path, "ideal", server_kw={"scene": str(BOX_TEXTURED)}, duration_s=1.0,
                                           trace="orbit")
    scene = get_scene(str(BOX_TEXTURED))
    fitted = get_trace("orbit", scene=scene, fov_y_deg=60.0, aspect=320 / 180)
    plain = get_trace("orbit")
    rows = result.rows
    assert len(rows) > 10
    for r in rows:
        shown = Pose.from_list([r["px"], r["py"], r["pz"], r["qx"], r["qy"], r["qz"], r["qw"]])
        want = fitted.pose_at(min(r["t_s"], fitted.duration_s))
        assert np.allclose(shown.position, want.position, atol=1e-6), (r["t_s"], shown.position, want.position)
    far = max(np.linalg.norm(plain.pose_at(r["t_s"]).position - fitted.pose_at(r["t_s"]).position) for r in rows)
    assert far > 1.0  # the fitted orbit is not the default scene's: 1.25-2.06 m apart over the first 1.2 s


def _serve(port: int, methods: str = "video", *args: str, hang: str = "") -> subprocess.Popen:  # type: ignore[type-arg]
    """``splitrender serve`` on ``port`` with the minimal scene, once it listens; ``hang``: the
    ``SPLITRENDER_TEST_HANG`` hook (``"SESSION:FRAME"``)."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "SPLITRENDER_TEST_HANG"}
    if hang:
        env["SPLITRENDER_TEST_HANG"] = hang
    srv = subprocess.Popen([sys.executable, "-m", "splitrender.cli", "serve", "--port", str(port), "--udp-port", "0",
                            "--scene", "minimal", "--methods", methods, *args], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True, env=env)
    assert srv.stderr is not None
    line = srv.stderr.readline()  # "splitrender: serving on ..." once it listens
    assert "serving on" in line, line
    return srv


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        return int(s.getsockname()[1])


def _wait_rows(journal: Path, n: int, proc: subprocess.Popen, timeout_s: float = 30.0) -> None:  # type: ignore[type-arg]
    import time

    end = time.monotonic() + timeout_s
    while time.monotonic() < end and proc.poll() is None:
        if journal.exists() and journal.read_text().count("\n") >= n:
            return
        time.sleep(0.05)
    raise AssertionError(f"{journal}: fewer than {n} rows in {timeout_s} s (client rc {proc.poll()})")


@pytest.mark.slow
def test_killed_server_or_client_leaves_a_scoreable_partial_recording(tmp_path: Path) -> None:
    """``kill -9`` of the server mid-session: the client exits non-zero within 2 s and leaves frames.csv,
    counters.json and recording.json (``complete: false``, the error); ``kill -9`` of the client leaves the
    manifest and the rows appended so far (frames.jsonl).  Both score; the server serves the next client."""
    import json
    import signal
    import time

    from splitrender.client.score import score_recording

    port = _free_port()
    client_cmd = [sys.executable, "-m", "splitrender.cli", "client", "--port", str(port), "--width", "160", "--height", "90",
                  "--display-hz", "30", "--duration", "15", "--save-images"]
    srv = _serve(port)
    try:
        out = tmp_path / "server_killed"
        cli = subprocess.Popen(client_cmd + ["--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _wait_rows(out / "frames.jsonl", 20, cli)
        with LoadMeter() as load:
            srv.send_signal(signal.SIGKILL)
            t0 = time.monotonic()
            _, err = cli.communicate(timeout=30)
            exited_s = time.monotonic() - t0
    finally:
        srv.kill()
        srv.communicate()
    # the 2 s, scaled by the measured load (tests/_load.py); measured 0.14 s idle
    assert cli.returncode != 0 and exited_s < STOP_S * load.slowdown, (cli.returncode, exited_s, load.slowdown, err[-2000:])
    assert "Traceback" not in err and "error" in err.lower(), err[-2000:]
    rec = json.loads((out / "recording.json").read_text())
    assert rec["complete"] is False and rec["error"], rec
    assert (out / "counters.json").is_file() and not (out / "frames.jsonl").exists()
    s = score_recording(out, flip_every=0)
    assert s["frames"] >= 20 and s["mean_psnr_db"] > 15, s

    # kill -9 of the client: the manifest and the journal survive, and the server takes the next client
    port = _free_port()
    srv = _serve(port)
    try:
        client_cmd[client_cmd.index("--port") + 1] = str(port)
        out2 = tmp_path / "client_killed"
        cli = subprocess.Popen(client_cmd + ["--out", str(out2)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _wait_rows(out2 / "frames.jsonl", 20, cli)
        time.sleep(0.6)  # past one journal flush
        cli.send_signal(signal.SIGKILL)
        cli.communicate(timeout=10)
        rec2 = json.loads((out2 / "recording.json").read_text())
        assert rec2["complete"] is False and not (out2 / "frames.csv").exists()
        # images are written to a temporary name and renamed: every one the kill left is whole
        images = sorted((out2 / "images").glob("*.npz"))
        assert len(images) >= 20
        for path in images:
            with np.load(path) as z:
                assert z["color"].shape == (90, 160, 3), path
        # one cut short (as an older client writing in place left them) is skipped and counted
        images[0].write_bytes(images[0].read_bytes()[:100])
        s2 = score_recording(out2, flip_every=0)
        assert s2["frames"] >= 20 and s2["images_damaged"] == 1, s2
        nxt_cmd = [a if a != "15" else "1.0" for a in client_cmd] + ["--out", str(tmp_path / "next")]
        nxt = subprocess.run(nxt_cmd, capture_output=True, text=True, timeout=60)
        assert nxt.returncode == 0, nxt.stderr[-2000:]
        assert json.loads((tmp_path / "next" / "recording.json").read_text())["complete"] is True
    finally:
        srv.kill()
        srv.communicate()


async def test_client_detects_a_stalled_stream_asks_for_keyframes_and_gives_up(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The server stops sending frames after its first 12 (a test hook): the client counts a stall and
    ``stall_timeout_s`` after the stop ends the session with StreamStalledError and a partial recording.  Nothing was
    lost (the server simply stopped), so the stall asks for no keyframe (issue 37: a keyframe would not help a server
    that sends nothing, and a slow server's gaps must not each cost an IDR).  The stop follows the frames sent, not
    the wall clock: at load 18 a stop 1 s after the client started came before the session's first frame."""
    import json
    import time

    from splitrender.client.session import StreamStalledError
    from splitrender.server.session import ServerSession

    send = ServerSession._send_frame
    sent: list[int] = [0]
    t_stop: list[float] = []

    async def stalling(self) -> None:  # type: ignore[no-untyped-def]
        if sent[0] >= 12:
            if not t_stop:
                t_stop.append(time.monotonic())
            return  # frozen: the session stays up, no frame goes out
        await send(self)
        sent[0] += 1

    monkeypatch.setattr(ServerSession, "_send_frame", stalling)
    before = slowdown_over(0.5)
    async with LiveServer(_server_config()) as server:
        serve = asyncio.create_task(server.serve_forever())
        try:
            cfg = ClientConfig(server=LOOPBACK, port=server.tcp_address[1], width=160, height=90, display_hz=30,
                               duration_s=20.0, out_dir=tmp_path, stall_frames=6, stall_timeout_s=1.5)
            client = LiveClient(cfg)
            with pytest.raises(StreamStalledError, match="no frame for"):
                await asyncio.wait_for(client.run(), 30)
            t_end = time.monotonic()
        finally:
            serve.cancel()
            await asyncio.gather(serve, return_exceptions=True)
    slowdown = max(before, slowdown_over(0.5))
    c = client.counters
    assert c["stalls"] == 1 and c["stall_plis"] == 0 and c["plis_sent"] == 0, c
    assert c["frames_complete"] >= 10, c  # the frames before the stop arrived (the last may have been in flight)
    # the client gives up stall_timeout_s after its last frame, which left at most one server frame before the stop:
    # measured 1.51-1.53 s at load 12-15; the upper bound is the timeout plus a second, scaled by the load (tests/_load.py)
    took = t_end - t_stop[0]
    assert 1.5 - 0.1 < took < (1.5 + 1.0) * slowdown, (took, slowdown)
    rec = json.loads((tmp_path / "recording.json").read_text())
    assert rec["complete"] is False and "StreamStalledError" in rec["error"]
    assert (tmp_path / "frames.csv").read_text().count("\n") > 10


async def test_periodic_metrics_lines_and_drop_counters(tmp_path: Path, caplog) -> None:  # type: ignore[no-untyped-def]
    """Server and client log a ``metrics`` line every ``metrics_interval_s``; the client's counters carry each
    jitter buffer's drops (late packets, frames given up, dropped waiting for a keyframe, corrupt) and the
    measured NACK round trip that times its retries."""
    import logging

    caplog.set_level(logging.INFO)
    result, _, counters = await _run_through_relay(tmp_path, "delay 10ms loss 3%", seed=2, server_kw={"metrics_interval_s": 0.5},
                                                   duration_s=2.0, metrics_interval_s=0.5)
    server_lines = [r.getMessage() for r in caplog.records if r.name.startswith("splitrender.server")
                    and r.getMessage().startswith("metrics session=")]
    client_lines = [r.getMessage() for r in caplog.records if r.name.startswith("splitrender.client")
                    and r.getMessage().startswith("metrics session=")]
    assert len(server_lines) >= 2 and "frames_sent=" in server_lines[-1] and "server_udp_dropped=" in server_lines[-1]
    assert len(client_lines) >= 2 and "color_packets_late=" in client_lines[-1] and "nacks_sent=" in client_lines[-1]
    c = result.counters
    for k in ("packets_late", "frames_lost", "frames_dropped", "frames_corrupt"):
        assert f"color_{k}" in c, sorted(c)
    assert c["nacks_sent"] > 0, c  # the loss was seen and reported
    # NACK retries are timed from the measured round trip: 10 ms each way at least
    assert 20.0 <= c["nack_rtt_ms"] < 200.0, c


@pytest.mark.slow
async def test_quads_live_through_a_lan_relay(tmp_path: Path) -> None:
    """``quads`` (QUASAR) live on the minimal scene through ``lan``, 320x180: the atlas over RTP and the quad
    and offset streams over the control channel reach the client together and are shown.  This server makes
    about one frame a second here once the session is set up (numpy quad generation beside six llvmpipe
    G-buffers: 5-6 frames in a 6 s session with two busy processes beside it, 2 in a 4 s session under the
    whole suite's load in CI), so the client's stall detector asks for keyframes and most frames are reference
    frames.  Not every complete frame need be shown: two that complete within one display tick show as one."""
    duration = 6.0
    result, _, _ = await _run_through_relay(tmp_path, "lan", server_kw={"methods": ("quads",)}, methods=("quads",),
                                            display_hz=30, duration_s=duration)
    c = result.counters
    assert c["frames_complete"] >= 3 and c["frames_complete"] >= c["frames_meta"] - 1, c  # the last may be in flight
    assert c["decode_errors"] == 0 and c["atlas_frames_corrupt"] == 0, c
    shown = {int(r["update_frame_id"]) for r in result.rows} - {-1}
    assert len(shown) >= 3, (sorted(shown), c)


async def test_the_client_keeps_a_bounded_window_of_rows_and_records_them_all(tmp_path: Path) -> None:
    """Issue 37: the client kept every displayed row in memory (131 to 171 MB over a 5-minute soak).  It keeps the
    newest ``rows_kept`` (here 20) and appends every row to the recording as it is shown; ``frames.csv`` is made
    from that journal at the end, so it has them all, numbered in order."""
    import csv

    async with LiveServer(_server_config()) as srv:
        serve = asyncio.create_task(srv.serve_forever())
        try:
            cfg = ClientConfig(server=LOOPBACK, port=srv.tcp_address[1], methods=("video",), width=160, height=90,
                               display_hz=30, duration_s=3.0, out_dir=tmp_path, rows_kept=20)
            result = await asyncio.wait_for(LiveClient(cfg).run(), 30)
        finally:
            serve.cancel()
            await asyncio.gather(serve, return_exceptions=True)
    with open(tmp_path / "frames.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(result.rows) == 20
    # every one of the 90 ticks is recorded, or counted as skipped for running late on a busy machine
    assert len(rows) + result.counters["late_ticks"] == 90 and len(rows) >= 20, (len(rows), result.counters["late_ticks"])
    assert [int(r["frame"]) for r in rows] == list(range(len(rows)))
    assert [r["frame"] for r in rows[-20:]] == [str(r["frame"]) for r in result.rows]
    assert not (tmp_path / "frames.jsonl").exists()


async def test_an_h264_only_client_gets_warp_with_depth_it_can_decode(tmp_path: Path) -> None:
    """Issue 37: a client that decodes H.264 only was refused warp (415) although BC4 depth over a data stream
    serves it.  The server now chooses each method's streams from what the client decodes: warp's depth goes
    as BC4, the session shows frames and its SDP files name no H.265; where nothing fits (probes' 10-bit
    lossless HEVC irradiance) the 415 names the stream."""
    from splitrender.client.session import ServerRefusedError

    sdp = tmp_path / "sdp"
    async with LiveServer(_server_config(methods=("warp", "probes"), scene="minimal+gi", sdp_dir=sdp)) as srv:
        serve = asyncio.create_task(srv.serve_forever())
        try:
            cfg = ClientConfig(server=LOOPBACK, port=srv.tcp_address[1], methods=("warp",), codecs=("h264",),
                               width=160, height=90, display_hz=30, duration_s=2.0)
            client = LiveClient(cfg)
            result = await asyncio.wait_for(client.run(), 40)
            with pytest.raises(ServerRefusedError, match=r"415.*hevc"):
                await asyncio.wait_for(LiveClient(ClientConfig(
                    server=LOOPBACK, port=srv.tcp_address[1], methods=("probes",), codecs=("h264",), width=160,
                    height=90, display_hz=30, duration_s=1.0)).run(), 60)
        finally:
            serve.cancel()
            await asyncio.gather(serve, return_exceptions=True)
    assert client._welcome is not None
    assert [(s.name, s.codec) for s in client._welcome.streams] == [("color0", "h264")]   # depth in the metadata
    assert client._welcome.method_params["config"]["depth_coding"] == "bc4"
    texts = [p.read_text() for p in sdp.glob("*.sdp")]
    assert texts and all("H264/90000" in t and "H265" not in t for t in texts), texts
    c = result.counters
    assert c["frames_complete"] >= 3 and c["decode_errors"] == 0, c


async def test_a_slow_server_without_loss_gets_no_keyframe_storm(monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 37: with the server at 2-4 updates a second (a nominal 30), every gap was a stall, a PLI and a
    keyframe (85-92 % of frames keyframes with no loss).  A server that sends one tick in ten (3 a second) for
    6 s with no loss now gets at most one PLI per GOP of its own (here the GOP is 30 frames, 10 s at that rate),
    and its client stalls at most once (before the rate is measured)."""
    from splitrender.server.session import ServerSession

    send = ServerSession._send_frame
    ticks = {"n": 0}

    async def one_in_ten(self: ServerSession) -> None:
        ticks["n"] += 1
        if ticks["n"] % 10 == 1:
            await send(self)

    monkeypatch.setattr(ServerSession, "_send_frame", one_in_ten)
    async with LiveServer(_server_config()) as srv:
        serve = asyncio.create_task(srv.serve_forever())
        try:
            cfg = ClientConfig(server=LOOPBACK, port=srv.tcp_address[1], methods=("video",), width=160, height=90,
                               display_hz=30, duration_s=6.0)
            run = asyncio.create_task(asyncio.wait_for(LiveClient(cfg).run(), 40))
            while not srv.sessions and not run.done():
                await asyncio.sleep(0.01)
            session = next(iter(srv.sessions.values()))
            result = await run
            server_counters = dict(session.counters)
        finally:
            serve.cancel()
            await asyncio.gather(serve, return_exceptions=True)
    c = result.counters
    assert c["frames_complete"] >= 10, c                     # about 18 in 6 s at 3 a second
    assert c["plis_sent"] <= 1 and c["stalls"] <= 1, c
    assert server_counters["keyframes"] <= 2, server_counters   # the first, and at most one asked for


CC_NETWORK = "delay 20ms rate 1mbit"


@pytest.mark.slow
async def test_transport_wide_feedback_sees_the_same_standing_queue_live_and_in_virtual_time(tmp_path: Path) -> None:
    """``video`` at 3 Mbit/s into a 1 Mbit/s bottleneck with transport-wide feedback (issue 35's first step: the
    path is measured, nothing adapts yet): live through the relay and in virtual time, the client reports every
    packet, the server matches each report with what it sent, and both estimators see the queue grow and ask the
    encoder for less than the link carries.  Measured (2.5 s): queue at the last frame 1.12-1.36 s live, 1.53 s in
    virtual time; acknowledged rate 957-962 / 945 kbit/s; encoder rate 100 kbit/s (the floor) in both; 20 / 22
    feedback packets.  (The delay-based target fell to 0.8 Mbit/s in one live run of two and in virtual time:
    at 1 Mbit/s a 20 KB frame takes 160 ms, so its trendline's 20 frames take over 3 s.)"""
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import VirtualTimeRun

    dur = 2.5
    result, _, sc = await _run_through_relay(tmp_path, CC_NETWORK, server_kw={"transport_cc": True,
                                             "method_params": {"video": {"bitrate_kbps": 3000}}}, duration_s=dur)
    assert result.counters["twcc_feedback_sent"] >= 10 and sc["twcc_feedback"] >= 10, (result.counters, sc)
    assert sc["twcc_unknown"] == 0 and sc["twcc_stamped"] >= sc["rtp_packets"]
    live = [r for r in sc["update_rows"] if r.get("cc_queue_ms", 0) > 0]
    vt = VirtualTimeRun(RunConfig(method="video", scene="minimal", trace="walk", duration_s=dur, width=320, height=180,
                                  network=CC_NETWORK, method_params={"bitrate_kbps": 3000}, transport_cc=True,
                                  metrics=False)).run()
    rows = vt.updates
    assert vt.summary["twcc_feedback"] >= 10 and vt.summary["twcc_unknown"] == 0
    for name, r in (("live", live[-1]), ("virtual time", rows[-1])):
        assert r["cc_queue_ms"] > 500, (name, r)
        assert r["cc_encoder_kbps"] < 500 < r["cc_acked_kbps"] < 1100, (name, r)


@pytest.mark.slow
async def test_an_adapting_live_session_follows_a_narrow_link(tmp_path: Path) -> None:
    """``serve --adapt rate``: ``video`` asked for 3 Mbit/s into the 1 Mbit/s bottleneck above.  The server's
    estimator probes (the client reports the probe packets' arrivals and drops them), its encoder restarts at the
    estimated rate, and the standing queue of the test above does not form: over the last second the estimator sees
    a median under 300 ms of queue (measured 0-26 ms in two runs; without adaptation 1.1-1.4 s) and the client shows updates
    under 600 ms old (p95; measured 75-104 ms alone, 413 ms with the stress suite beside it), after 6-7 encoder restarts and 43 probe packets."""
    dur = 4.0
    result, _, sc = await _run_through_relay(tmp_path, CC_NETWORK, server_kw={
        "transport_cc": True, "adapt": "rate", "method_params": {"video": {"bitrate_kbps": 3000}}}, duration_s=dur)
    c = result.counters
    assert c["probe_packets"] > 0 and sc["probe_packets"] >= c["probe_packets"], (c, sc)
    assert sc["encoder_restarts"] >= 1 and sc["twcc_unknown"] == 0, sc
    rows = [r for r in sc["update_rows"] if "cc_queue_ms" in r]
    late = [r for r in rows if r["t_s"] >= rows[-1]["t_s"] - 1.0]
    # the queue over the last second: median under 300 ms, no sample over 700 (without adaptation 1.1-1.4 s; idle
    # 0-26 ms; with the machine loaded by a C++ build beside the suite a spike reached 321 and 387 ms)
    queue = [r["cc_queue_ms"] for r in late]
    assert float(np.median(queue)) < 300 and max(queue) < 700, [round(q) for q in queue]
    # the target follows the link: its median under the 1 Mbit/s (measured 540-620 kbit/s; a frame or two after a
    # probe's result may ask for more, 1.7 Mbit/s seen once with the suite running beside it)
    assert float(np.median([r["adapt_color_kbps"] for r in late])) < 1000, [round(r["adapt_color_kbps"]) for r in late]
    last = max(r["t_s"] for r in result.rows)
    ages = [r["update_age_ms"] for r in result.rows if r["t_s"] >= last - 1.0 and np.isfinite(r["update_age_ms"])]
    # p95 measured 75-104 ms alone, 413 ms once with the stress suite running beside it; without adaptation the
    # standing queue alone ages every update past 1.1 s
    assert ages and float(np.percentile(ages, 95)) < 600, ages


@pytest.mark.slow
async def test_a_live_session_adapting_its_operating_point_lowers_warp_s_depth_and_colour(tmp_path: Path) -> None:
    """``serve --adapt full``: ``warp`` (lossless depth, about 3 Mbit/s at 320x180 here) into the 1 Mbit/s bottleneck
    above.  The server's point controller lowers the depth's bits and samples and the colour's resolution in the
    render worker (the knob values travel with each frame's call), the client's pipeline brings the smaller colour
    pictures back to their declared size on its decoder thread, and no frame is refused for its size."""
    dur = 4.0
    result, _, sc = await _run_through_relay(tmp_path, CC_NETWORK, server_kw={
        "transport_cc": True, "adapt": "full"}, duration_s=dur, methods=("warp",))
    c = result.counters
    rows = [r for r in sc["update_rows"] if "adapt_point" in r]
    assert rows and max(r["adapt_point"] for r in rows) >= 2, [r.get("adapt_point") for r in rows]
    low = [r for r in rows if r["adapt_knob_scale"] < 1.0]
    assert low and min(r["adapt_knob_depth_bits"] for r in rows) < 16, rows[-1]
    # enough complete frames for the size check to mean something: 10, or half of what was sent where a loaded machine
    # sent fewer than 20 (the 1 Mbit/s bottleneck drops what the controller has not yet cut: measured idle 14, 22, 34
    # and 49 complete of 44-52 sent; 13 of 20 in the clean-clone CI; 11 of 12 with the machine at load 24)
    assert c.get("frames_wrong_size", 0) == 0 and sc["frames_sent"] >= 8, (c, sc)
    assert c["frames_complete"] >= min(10, sc["frames_sent"] // 2), (c, sc)
    assert sc.get("point_moves", 0) >= 1, sc


@pytest.mark.slow
async def test_a_paced_live_session_streams_and_is_reported(tmp_path: Path) -> None:
    """``serve --pacing`` (transport-wide feedback implied): the pacer task sends every frame's packets, the client
    shows the stream and reports it, and no packet is left unaccounted for."""
    result, _, sc = await _run_through_relay(tmp_path, "delay 10ms rate 4mbit", server_kw={"transport_cc": True, "pacing": True},
                                             duration_s=2.0)
    c = result.counters
    # what was shown against what was sent, not a rate: a loaded machine sends fewer frames in 2 s
    assert sc["frames_sent"] >= 8 and c["frames_complete"] >= sc["frames_sent"] - 3, (c["frames_complete"], sc["frames_sent"])
    assert sc["twcc_feedback"] >= 10 and sc["twcc_unknown"] == 0, (c, sc)
    # every media packet left stamped, or was still in the pacer's queue when the session ended (or dropped by a
    # full queue): 424 stamped of 425 once in CI, one packet queued at the end
    assert sc["twcc_stamped"] + sc["pacer_queued"] + sc["pacer_dropped"] >= sc["rtp_packets"], sc
    assert any("cc_pacer_packets" in r for r in sc["update_rows"])
