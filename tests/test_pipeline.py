"""Pipeline v2: typed streams, partial delivery, feedback, shared producers, many clients,
one transmission path for virtual time and live, session data, method plug-ins."""

from __future__ import annotations

import asyncio
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from splitrender.codecs.video import VideoCodecConfig
from splitrender.methods import DataStreamSpec, StreamSpec, Update, available_methods, get_method, load_methods
from splitrender.pipeline import (ClientPipeline, ServerPipeline, SessionAssembler, SessionDataError, StreamEncoder,
                                  specs_from_table)
from splitrender.protocol import PROTOCOL_VERSION, ClientConnection, Hello, ServerConnection, Welcome
from splitrender.protocol.framing import NEED_DATA
from splitrender.scene.pose import Pose
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import VirtualTimeRun

PLUGINS = Path(__file__).parent / "plugins"
LOOPBACK = "127.0.0.1"


# --------------------------------------------------------------------------- sans-IO pipeline pair


def _pair(specs: list, fec: bool = False) -> tuple[ServerPipeline, StreamEncoder, ClientPipeline, ServerConnection,  # type: ignore[type-arg]
                                                   ClientConnection]:
    tx = ServerPipeline(specs, mtu=1200, rng=np.random.default_rng(1), fec=fec)
    s, c = ServerConnection(), ClientConnection()
    s.receive_data(c.send(Hello(PROTOCOL_VERSION, "", ("x",), ("h264",), 64, 64, 30.0)))
    s.next_event()
    c.receive_data(s.send(Welcome("s", "x", tx.welcome_params(b""), tx.describe("127.0.0.1", 5000, "t"))))
    w = c.next_event()
    assert isinstance(w, Welcome)
    rx = ClientPipeline(w.streams, specs_from_table(w.method_params["streams"]), jitter_timeout_ms=50)
    return tx, StreamEncoder(specs), rx, s, c


def _deliver_control(c: ClientConnection, rx: ClientPipeline, data: bytes, now_ms: float) -> None:
    c.receive_data(data)
    while (ev := c.next_event()) is not NEED_DATA:
        rx.on_message(ev, now_ms)  # type: ignore[arg-type]


def _send(tx: ServerPipeline, encoder: StreamEncoder, s: ServerConnection, fid: int, planes: dict, data: dict):  # type: ignore[no-untyped-def,type-arg]
    upd = Update(fid, fid / 30, Pose(), planes, {"n": fid}, data=data)
    enc = encoder.encode(upd, force_idr=fid == 0)
    return tx.packetize(enc, s.send, 1_000_000 + fid, fid * 3000, 0, fid, fid / 30, {}, {})


def test_partial_delivery_names_the_missing_stream_and_keeps_the_rest() -> None:
    """A frame whose datagram stream lost a packet is released with that stream in
    ``missing`` and its video and reliable data intact; later frames are complete."""
    specs = [StreamSpec("color", VideoCodecConfig(gop=30), 64, 48), DataStreamSpec("quads", "datagram"),
             DataStreamSpec("table", "reliable")]
    tx, encoder, rx, s, c = _pair(specs)
    rng = np.random.default_rng(0)
    released = []
    for fid in range(4):
        img = np.full((48, 64, 3), 40 * fid, np.uint8)
        quads = rng.integers(0, 255, 3000, dtype=np.uint8).tobytes()  # several datagrams
        out = _send(tx, encoder, s, fid, {"color": img}, {"quads": quads, "table": bytes([fid]) * 10})
        assert set(out.wire_bytes) == {"meta", "color", "quads", "table"}
        for _, data in out.control:
            _deliver_control(c, rx, data, fid * 33.0)
        quad_packets = [d for name, _, d in out.datagrams if name == "quads"]
        assert len(quad_packets) >= 3
        for name, _, data in out.datagrams:
            if fid == 1 and name == "quads" and data is quad_packets[1]:
                continue  # lost on the way
            for w in rx.on_datagram(data, fid * 33.0 + 5):
                rx.on_decoded(w, rx.decode(w), fid * 33.0 + 6)
        released += rx.ready()
    for w in rx.poll(1000.0):
        rx.on_decoded(w, rx.decode(w), 1000.0)
    released += rx.ready()
    assert [r.update.frame_id for r in released] == [0, 1, 2, 3]
    by_id = {r.update.frame_id: r.update for r in released}
    assert by_id[1].missing == frozenset({"quads"}) and not by_id[1].complete
    assert "color" in by_id[1].planes and by_id[1].data["table"] == bytes([1]) * 10
    for fid in (0, 2, 3):
        assert by_id[fid].complete and len(by_id[fid].data["quads"]) == 3000
        assert abs(int(by_id[fid].planes["color"].mean()) - 40 * fid) <= 2
    applied, lost = rx.tracker.take()
    assert lost == {"quads": (1,)}


def test_fec_rebuilds_one_lost_packet_per_frame_on_every_stream() -> None:
    """With ``fec``, each RTP stream gets a parity stream announced in Welcome; losing one packet of every
    frame on both the video and the datagram stream still delivers every frame complete, and the parity
    packets count as their stream's wire bytes."""
    specs = [StreamSpec("color", VideoCodecConfig(gop=30), 64, 48), DataStreamSpec("quads", "datagram")]
    tx, encoder, rx, s, c = _pair(specs, fec=True)
    assert {n: (st.fec_ssrc != 0, st.fec_payload_type) for n, st in tx.streams.items()} == {"color": (True, 127),
                                                                                            "quads": (True, 126)}
    assert len(rx.by_fec_ssrc) == 2
    rng = np.random.default_rng(0)
    released = []
    for fid in range(4):
        img = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
        quads = rng.integers(0, 255, 3000, dtype=np.uint8).tobytes()
        out = _send(tx, encoder, s, fid, {"color": img}, {"quads": quads})
        assert {name for name, _ in out.fec} == {"color", "quads"}
        media = sum(28 + len(d) for n, _, d in out.datagrams if n == "quads")
        assert out.wire_bytes["quads"] == media + sum(28 + len(d) for n, d in out.fec if n == "quads")
        for _, data in out.control:
            _deliver_control(c, rx, data, fid * 33.0)
        for name in ("color", "quads"):
            pkts = [d for n, _, d in out.datagrams if n == name]
            assert len(pkts) >= 2
            for k, data in enumerate(pkts):
                if k == (fid - 1) % len(pkts):
                    continue  # lost on the way (the first frame loses its last packet: before any frame has
                              # completed, the buffer cannot tell a lost first packet from the stream's start)
                for w in rx.on_datagram(data, fid * 33.0 + 5):
                    rx.on_decoded(w, rx.decode(w), fid * 33.0 + 6)
        for name, data in out.fec:
            for w in rx.on_datagram(data, fid * 33.0 + 7):
                rx.on_decoded(w, rx.decode(w), fid * 33.0 + 8)
        released += rx.ready()
    assert [r.update.frame_id for r in released] == [0, 1, 2, 3]
    assert all(r.update.complete and len(r.update.data["quads"]) == 3000 for r in released)
    assert sum(st.jitter.fec_recovered for st in rx.streams.values() if st.jitter is not None) == 8 and rx.counters["udp_bad"] == 0


def test_session_data_is_chunked_checked_and_bounded() -> None:
    tx = ServerPipeline([], rng=np.random.default_rng(0))
    s, c = ServerConnection(), ClientConnection()
    s.receive_data(c.send(Hello(PROTOCOL_VERSION, "", ("x",), ("h264",), 64, 64, 30.0)))
    s.next_event()
    blob = np.random.default_rng(5).integers(0, 256, 512000, dtype=np.uint8).tobytes()  # two 256 KiB chunks, incompressible
    params = tx.welcome_params(blob)
    c.receive_data(s.send(Welcome("s", "x", params, ())) + b"".join(f for _, f in tx.session_frames(blob, s.send)))
    w = c.next_event()
    asm = SessionAssembler(w.method_params["session_data_bytes"], w.method_params["session_data_crc"], 1 << 20)  # type: ignore[union-attr]
    chunks = 0
    while not asm.done:
        asm.add(c.next_event())  # type: ignore[arg-type]
        chunks += 1
    assert asm.blob == blob and chunks == 2
    assert tx.bytes_sent["session"] > len(blob)  # headers counted
    with pytest.raises(SessionDataError, match=r"session data of 512000 bytes exceeds this client's limit of 1000 bytes"):
        SessionAssembler(len(blob), None, 1000)


# --------------------------------------------------------------------------- virtual time


def test_feedback_reaches_the_server_and_aims_the_prediction(renderer) -> None:  # type: ignore[no-untyped-def]
    """Under loss the client's lost frames reach the server half (``sas`` resends in
    full), and the expected latency is measured, not read from the network model."""
    # seed 0: 20 frames reported lost, 3 keyframe requests (seed 2, used before, drew the fewest losses of seeds 0-4:
    # 1 request, then none once sas's atlas frames grew with fill_atlas).  The paper's 8 Mpix atlas: with the 12 Mpix
    # default, frames of more packets wait for a lost one more often and the measured latency settles at 102-149 ms
    # (this test is about where the estimate comes from, not its value); and the paper's I-frame every 5 frames: with
    # sas's default of 30 (issue 50) seed 0 draws one frame 200 ms late among the last ten (their mean 164 ms; seeds
    # 1-4 give 66-77)
    cfg = RunConfig(method="sas", scene="minimal", trace="walk", network="delay 50ms loss 4%", width=160, height=90,
                    duration_s=1.5, client_fps=30, flip_every=0, seed=0, metrics=False,
                    method_params={"atlas_mpix_1080p": 8.0, "gop": 5})
    vt = VirtualTimeRun(cfg, renderer)
    res = vt.run()
    fb = vt.clients[0].core_s.fb
    assert fb is not None and fb.reports > 10
    assert fb._fb.lost_frames > 0 and "atlas" in fb._fb.lost, fb._fb
    assert fb._fb.applied.get("atlas", -1) > 20
    lat = [u["expected_latency_ms"] for u in res.updates]
    assert lat[0] == pytest.approx(20 + 5 + 0.5 / 30 * 1000)  # the prior, before any feedback
    # measured: 10 ms server + 50 ms + 4 ms decode + up to one display tick
    assert 60 <= np.mean(lat[-10:]) <= 100, lat[-10:]
    assert res.summary["keyframe_requests"] >= 1


def test_every_display_tick_from_zero_is_scored(renderer) -> None:  # type: ignore[no-untyped-def]
    cfg = RunConfig(method="video", scene="minimal", trace="static", network="delay 100ms", width=160, height=90,
                    duration_s=0.5, client_fps=30, flip_every=0)
    res = VirtualTimeRun(cfg, renderer).run()
    assert res.frames[0]["t_s"] == 0.0 and len(res.frames) == 16
    early = [f for f in res.frames if f["update_frame_id"] == -1]
    # nothing can arrive before 10 ms server + 100 ms network + 4 ms decode: ticks 0..3 show black
    assert len(early) == 4 and all(f["hole_pct"] == 100.0 for f in early)
    assert all(f["psnr_db"] < 15 for f in early) and res.frames[-1]["psnr_db"] > 25
    assert res.summary["frames_before_content"] == 4


def test_many_clients_share_the_scene_producer(renderer) -> None:  # type: ignore[no-untyped-def]
    cfg = RunConfig(method="sas", scene="minimal", trace="walk", client_traces=("walk", "orbit"), clients=3,
                    client_offset_s=0.2, network="lan", width=160, height=90, duration_s=0.5, client_fps=30,
                    flip_every=0, seed=1)
    vt = VirtualTimeRun(cfg, renderer)
    res = vt.run()
    assert [s["client"] for s in res.client_summaries] == [0, 1, 2]
    assert [s["client_trace"] for s in res.client_summaries] == ["walk", "orbit", "walk"]
    assert vt.pool.frames_prepared["sas"] == 16  # once per server frame, not once per client
    halves = [c.maker.half for c in vt.clients]
    assert halves[0].patches is halves[1].patches is halves[2].patches  # patches built once
    assert all(math.isfinite(s["mean_psnr_db"]) for s in res.client_summaries)
    assert len({round(s["mean_psnr_db"], 3) for s in res.client_summaries}) == 3  # own trace, offset, network draws
    assert {u["client"] for u in res.updates} == {0, 1, 2} and "shared_ms" in res.updates[0]


def test_bytes_per_stream_are_wire_bytes(renderer) -> None:  # type: ignore[no-untyped-def]
    cfg = RunConfig(method="warp", scene="minimal", trace="static", network="ideal", width=160, height=90,
                    duration_s=0.5, client_fps=30, flip_every=0, metrics=False)
    res = VirtualTimeRun(cfg, renderer).run()
    u = res.updates[0]
    assert u["bytes"] == u["bytes_meta"] + u["bytes_color0"] + u["bytes_depth0"]
    s = res.summary
    dur = 0.5 + 1 / 30
    assert all(s[f"kbps_{n}"] > 0 for n in ("meta", "color0", "depth0", "session"))
    assert s["mean_kbps"] == pytest.approx(sum(s[f"kbps_{n}"] for n in ("meta", "color0", "depth0", "session")))
    assert s["kbps_meta"] == pytest.approx(sum(r["bytes_meta"] for r in res.updates) * 8 / dur / 1000)
    assert "kbps_color0" in res.frames[-1]


# --------------------------------------------------------------------------- plug-ins


@pytest.fixture
def tiny_installed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):  # type: ignore[no-untyped-def]
    """'Install' the tiny method package (a package plus its .dist-info) on the path."""
    site = tmp_path / "site"
    shutil.copytree(PLUGINS, site)
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]))
    load_methods(rescan=True)
    yield site
    # uninstall: later tests see only the built-in methods again
    from splitrender.methods import base as methods_base

    methods_base._REGISTRY.pop("tiny", None)
    methods_base._seen_entry_points.discard("tiny=splitrender_tiny:SPEC")
    for mod in [m for m in sys.modules if m == "splitrender_tiny" or m.startswith("splitrender_tiny.")]:
        del sys.modules[mod]


def test_plugin_method_runs_through_run_sweep_and_live(tiny_installed: Path, tmp_path: Path, renderer) -> None:  # type: ignore[no-untyped-def]
    assert "tiny" in available_methods() and get_method("tiny").config.__module__ == "splitrender_tiny"
    cfg = RunConfig(method="tiny", method_params={"factor": 2}, scene="minimal", trace="static", network="lan",
                    width=160, height=90, duration_s=0.5, client_fps=30, flip_every=0)
    res = VirtualTimeRun(cfg, renderer).run()
    s = res.summary
    assert s["kbps_thumb"] > 0 and s["kbps_counter"] > 0 and "kbps_color" not in s
    assert s["mean_psnr_db"] > 15
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('[sweep]\nname = "plugin"\nscenes = ["minimal"]\ntraces = ["static"]\nnetworks = ["ideal", "lan"]\n'
                     '[base]\nwidth = 160\nheight = 90\nduration_s = 0.3\nclient_fps = 30\nflip_every = 0\n\n'
                     '[methods.tiny]\nfactor = [2]\n')
    from splitrender.experiments.store import read_csv
    from splitrender.experiments.sweep import run_sweep

    run_sweep(sweep, tmp_path / "sw", workers=2)
    rows = read_csv(tmp_path / "sw" / "runs.csv")
    assert sorted(r["network"] for r in rows) == ["ideal", "lan"] and all(r["method"] == "tiny" for r in rows)
    from splitrender.client.session import ClientConfig, LiveClient
    from splitrender.server.server import LiveServer, ServerConfig

    class KeepHalf(LiveClient):
        async def _release(self) -> None:
            self.kept = self._half
            await super()._release()

    async def live() -> tuple:  # type: ignore[type-arg]
        async with LiveServer(ServerConfig(host=LOOPBACK, port=0, udp_port=0, scene="minimal", methods=("tiny",))) as srv:
            serve = asyncio.create_task(srv.serve_forever())
            try:
                client = KeepHalf(ClientConfig(server=LOOPBACK, port=srv.tcp_address[1], methods=("tiny",), width=160,
                                                 height=90, display_hz=30, duration_s=1.5, trace="static"))
                result = await asyncio.wait_for(client.run(), 30)
                return result, client.kept
            finally:
                serve.cancel()
                await asyncio.gather(serve, return_exceptions=True)

    result, half = asyncio.run(live())
    assert result.counters["frames_complete"] >= 10, result.counters
    assert half.thumb is not None and half.counters == sorted(half.counters) and len(half.counters) >= 10


# --------------------------------------------------------------------------- never peek


@pytest.mark.parametrize("method", ["video", "atw", "warp", "sas"])
def test_client_half_imports_nothing_of_its_server_the_scene_or_the_renderer(method: str) -> None:
    spec = get_method(method)
    module = spec.client.split(":")[0] if isinstance(spec.client, str) else spec.client.__module__
    code = (f"import sys, {module}\n"
            "bad = [m for m in sys.modules if m.startswith('splitrender') and (m.endswith('.server') or "
            "m in ('splitrender.scene.model', 'splitrender.scene.loader', 'splitrender.scene.procedural', "
            "'splitrender.render.renderer'))]\nprint(','.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         cwd=Path(__file__).parent.parent)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"{module} imports {out.stdout.strip()}"
    assert module.endswith(".client"), module


# --------------------------------------------------------------------------- one path, two modes


@pytest.mark.slow
def test_same_session_counts_the_same_bytes_and_quality_in_virtual_time_and_live(tmp_path: Path, renderer) -> None:  # type: ignore[no-untyped-def]
    """``video`` on a still scene and camera at zero network delay, run both ways: bytes
    per frame of every stream within 5%, displayed quality within 0.5 dB."""
    from splitrender.client.score import read_frames, score_recording
    from splitrender.client.session import ClientConfig, LiveClient
    from splitrender.server.server import LiveServer, ServerConfig

    duration = 3.0

    async def live() -> tuple:  # type: ignore[type-arg]
        async with LiveServer(ServerConfig(host=LOOPBACK, port=0, udp_port=0, scene="minimal", methods=("video",))) as srv:
            serve = asyncio.create_task(srv.serve_forever())
            try:
                cfg = ClientConfig(server=LOOPBACK, port=srv.tcp_address[1], methods=("video",), width=160, height=90,
                                   display_hz=30, duration_s=duration, trace="static", out_dir=tmp_path, save_images=True)
                run = asyncio.create_task(asyncio.wait_for(LiveClient(cfg).run(), duration + 30))
                while not srv.sessions and not run.done():
                    await asyncio.sleep(0.01)
                session = next(iter(srv.sessions.values()))
                result = await run
                return result, list(session.update_rows)
            finally:
                serve.cancel()
                await asyncio.gather(serve, return_exceptions=True)

    result, live_updates = asyncio.run(live())
    score_recording(tmp_path, renderer=renderer, flip_every=0)
    live_rows = [r for r in read_frames(tmp_path / "frames.csv") if int(r["update_frame_id"]) >= 0]
    vt = VirtualTimeRun(RunConfig(method="video", scene="minimal", trace="static", network="ideal", width=160, height=90,
                                  duration_s=duration, client_fps=30, flip_every=0), renderer).run()
    n = min(len(live_updates), len(vt.updates))
    assert n >= 0.5 * len(vt.updates), (len(live_updates), len(vt.updates))
    for stream in ("color", "meta"):  # the same frames (same GOP positions) both ways
        per_live = sum(u[f"bytes_{stream}"] for u in live_updates[:n]) / n
        per_vt = sum(u[f"bytes_{stream}"] for u in vt.updates[:n]) / n
        assert per_live == pytest.approx(per_vt, rel=0.05), (stream, per_live, per_vt)
    vt_psnr = np.mean([f["psnr_db"] for f in vt.frames if f["update_frame_id"] >= 0])
    live_psnr = np.mean([float(r["psnr_db"]) for r in live_rows])
    assert abs(live_psnr - vt_psnr) < 0.5, (live_psnr, vt_psnr)
