"""The browser front door without a browser: the page's messages, SDP edits, the relay's late target, and
the HTTP endpoints refusing bad requests by name while the server keeps serving."""

from __future__ import annotations

import asyncio
import json
import math

import numpy as np
import pytest

from splitrender.errors import ConfigError
from splitrender.webrtc.messages import (PageFeedback, PageMessageError, PoseSample, parse_channel_message, parse_rows,
                                         parse_session_request, rgba_to_rgb)
from splitrender.webrtc.sdp import replace_candidates, udp_candidate_ports

OFFER = "\r\n".join([
    "v=0", "o=- 1 2 IN IP4 127.0.0.1", "s=-", "t=0 0", "a=group:BUNDLE 0 1",
    "m=video 9 UDP/TLS/RTP/SAVPF 102", "c=IN IP4 0.0.0.0", "a=mid:0",
    "a=candidate:1 1 udp 2113937151 127.0.0.1 50000 typ host generation 0",
    "a=candidate:2 1 tcp 1518280447 127.0.0.1 9 typ host tcptype active",
    "a=candidate:3 1 udp 2113939711 ::1 50001 typ host", "a=end-of-candidates",
    "m=application 9 UDP/DTLS/SCTP webrtc-datachannel", "c=IN IP4 0.0.0.0", "a=mid:1",
    "a=candidate:1 1 udp 2113937151 127.0.0.1 50000 typ host", "",
])


def _request(**kw):
    body = {"type": "offer", "sdp": OFFER, "method": "atw", "width": 320, "height": 180, "display_hz": 60}
    body.update(kw)
    return body


def test_session_request_is_checked_by_name():
    req = parse_session_request(_request(), ["video", "atw"], 1920 * 1080)
    assert (req.method, req.width, req.height, req.display_hz) == ("atw", 320, 180, 60.0)
    cases = [
        ({"type": "answer"}, "type: expected 'offer'"),
        ({"sdp": "hello"}, "sdp: expected an SDP offer"),
        ({"sdp": "v=0" + "x" * 70000}, "more than the 65536 allowed"),
        ({"method": "quads"}, "method: 'quads' is not one this server offers the page (video, atw)"),
        ({"width": 321}, "must be even"),
        ({"width": "320"}, "width: expected a finite number"),
        ({"height": 10}, "height: 10 is out of range"),
        ({"width": 4000, "height": 4000}, "more than this server's 2073600 pixels"),
        ({"display_hz": 0}, "display_hz: 0 is out of range"),
    ]
    for kw, text in cases:
        with pytest.raises(PageMessageError, match=text.replace("(", r"\(").replace(")", r"\)")):
            parse_session_request(_request(**kw), ["video", "atw"], 1920 * 1080)
    with pytest.raises(PageMessageError, match="expected a JSON object, got list"):
        parse_session_request([1], ["video"], 100)


def test_channel_messages_parse_and_refuse_by_name():
    pose = parse_channel_message(json.dumps({"type": "pose", "seq": 3, "t_us": 1_700_000_000_000_000,
                                             "p": [0, 1.6, 2], "q": [0, 0, 0, 1]}))
    assert pose == PoseSample(3, 1_700_000_000_000_000, (0.0, 1.6, 2.0), (0.0, 0.0, 0.0, 1.0))
    fb = parse_channel_message('{"type": "feedback", "frame_id": 7, "displayed_us": 5, "received_us": 4}')
    assert fb == PageFeedback(7, 5, 4)
    assert parse_channel_message('{"type": "bye"}') == "bye"
    bad = [
        ("{", "not JSON"),
        ("[1, 2]", "expected a JSON object, got list"),
        (b"\x00\x01", "expected JSON text, got 2 binary bytes"),
        ('{"type": "pose", "seq": 1, "t_us": 5, "p": [0, 0, 0], "q": [0, 0, 0, 1.9]}', "q: not a unit quaternion"),
        ('{"type": "pose", "seq": 1, "t_us": 5, "p": [0, NaN, 0], "q": [0, 0, 0, 1]}', r"p\[1\]: expected a finite"),
        ('{"type": "pose", "seq": 1, "t_us": 5, "p": [0, 0], "q": [0, 0, 0, 1]}', "p: expected a list of 3 numbers"),
        ('{"type": "pose", "seq": -1, "t_us": 5, "p": [0, 0, 0], "q": [0, 0, 0, 1]}', "seq: -1 is out of range"),
        ('{"type": "feedback", "frame_id": 1.5, "displayed_us": 5, "received_us": 4}', "frame_id: expected an integer"),
        ('{"type": "hello"}', "'hello' is not one of 'pose', 'feedback', 'bye'"),
        ('{"type": "bye", "pad": "' + "x" * 5000 + '"}', "more than the 4096 allowed"),
    ]
    for text, match in bad:
        with pytest.raises(PageMessageError, match=match):
            parse_channel_message(text)


def test_recording_rows_and_images():
    row = {"frame": 0, "t_s": 0.0, "scene_t_s": 1.0, "px": 0, "py": 1, "pz": 2, "qx": 0, "qy": 0, "qz": 0, "qw": 1,
           "update_frame_id": -1, "update_age_ms": None}
    out = parse_rows([row])
    assert out[0]["py"] == 1.0 and math.isnan(out[0]["update_age_ms"]) and math.isnan(out[0]["rtp_timestamp"])
    with pytest.raises(PageMessageError, match=r"rows\[0\].px: expected a number or null"):
        parse_rows([{**row, "px": "left"}])
    with pytest.raises(PageMessageError, match=r"rows\[0\].qw: missing or not finite"):
        parse_rows([{**row, "qw": None}])
    with pytest.raises(PageMessageError, match="expected a list, got dict"):
        parse_rows({"rows": 1})
    # readPixels gives RGBA rows bottom up: the image comes back top down, alpha dropped
    h, w = 3, 2
    rgba = np.zeros((h, w, 4), np.uint8)
    rgba[0, :, 0] = 255             # the bottom row as GL reads it
    img = rgba_to_rgb(rgba.tobytes(), w, h)
    assert img.shape == (3, 2, 3) and img[2, 0, 0] == 255 and img[0, 0, 0] == 0
    with pytest.raises(PageMessageError, match="23 bytes, expected 2x3x4 = 24"):
        rgba_to_rgb(b"x" * 23, w, h)


def test_candidates_are_replaced_in_every_media_section():
    assert udp_candidate_ports(OFFER) == [50000, 50001, 50000]
    assert udp_candidate_ports(OFFER, "127.0.0.1") == [50000, 50000]
    out = replace_candidates(OFFER, "127.0.0.1", 40000)
    assert udp_candidate_ports(out) == [40000, 40000]
    assert out.count("a=end-of-candidates") == 2 and "tcptype" not in out and "::1" not in out
    lines = out.split("\r\n")
    # each section's candidate follows its c= line, inside the section
    for mid in ("a=mid:0", "a=mid:1"):
        i = lines.index(mid)
        assert lines[i - 2].startswith("a=candidate:1 1 udp 2130706431 127.0.0.1 40000 typ host")


async def test_relay_with_a_target_named_later():
    from splitrender.netsim.models import PathSpec
    from splitrender.netsim.relay import Relay

    loop = asyncio.get_running_loop()
    got: list[tuple[bytes, tuple[str, int]]] = []

    class Sink(asyncio.DatagramProtocol):
        def __init__(self, box: list) -> None:
            self.box = box

        def datagram_received(self, data: bytes, addr) -> None:   # type: ignore[override]
            self.box.append((data, addr[:2]))

    server_t, _ = await loop.create_datagram_endpoint(lambda: Sink(got), local_addr=("127.0.0.1", 0))
    client_got: list = []
    client_t, _ = await loop.create_datagram_endpoint(lambda: Sink(client_got), local_addr=("127.0.0.1", 0))
    relay = Relay(PathSpec())
    try:
        listen, inner, set_target = await relay.start_udp_unbound(("127.0.0.1", 0))
        client_t.sendto(b"early", listen)
        await asyncio.sleep(0.05)
        assert got == [] and relay.stats().uplink.packets_undeliverable == 1
        set_target(server_t.get_extra_info("sockname")[:2])
        client_t.sendto(b"late", listen)
        await asyncio.sleep(0.05)
        assert got == [(b"late", inner)]        # the server sees the relay's inner socket
        server_t.sendto(b"reply", inner)
        stranger, _ = await loop.create_datagram_endpoint(asyncio.DatagramProtocol, local_addr=("127.0.0.1", 0))
        stranger.sendto(b"spoof", inner)        # not the target: dropped
        await asyncio.sleep(0.05)
        stranger.close()
        assert [d for d, _ in client_got] == [b"reply"]
        assert relay.stats().udp_foreign_dropped == 1
        with pytest.raises(Exception, match="not loopback"):
            set_target(("8.8.8.8", 53))
    finally:
        await relay.close()
        server_t.close()
        client_t.close()


def test_serve_options_are_checked():
    from splitrender.cli import build_parser
    from splitrender.server.cli import config_from_args

    ap = build_parser()
    cfg = config_from_args(ap.parse_args(["serve", "--webrtc", "--http", "127.0.0.1:0", "--webrtc-network", "delay 50ms"]))
    assert cfg.webrtc_http == ("127.0.0.1", 0) and cfg.webrtc_network == "delay 50ms"
    with pytest.raises(ConfigError, match="--http: '8080' is not HOST:PORT"):
        config_from_args(ap.parse_args(["serve", "--webrtc", "--http", "8080"]))
    with pytest.raises(ConfigError, match="--webrtc-network: shapes browser sessions, so it needs --webrtc"):
        config_from_args(ap.parse_args(["serve", "--webrtc-network", "delay 5ms"]))
    with pytest.raises(ConfigError, match="--webrtc-network"):
        config_from_args(ap.parse_args(["serve", "--webrtc", "--webrtc-network", "delay fast"]))


@pytest.mark.slow
async def test_front_door_refuses_bad_requests_and_keeps_serving(tmp_path):
    import aiohttp

    from splitrender.server.server import LiveServer, ServerConfig

    cfg = ServerConfig(port=0, udp_port=0, scene="minimal", webrtc_http=("127.0.0.1", 0), out_dir=tmp_path,
                       methods=("video", "atw", "warp"))
    async with LiveServer(cfg) as server:
        base = "http://%s:%d" % server.front.address
        async with aiohttp.ClientSession() as http:
            async with http.get(base + "/api/info") as r:
                info = await r.json()
            assert info["methods"] == ["video", "atw"] and info["scene"] == "minimal" and info["recording"]
            async with http.get(base + "/") as r:
                assert r.status == 200 and "main.js" in await r.text()
            async with http.get(base + "/static/main.js") as r:
                assert r.status == 200 and r.headers["Content-Type"].startswith("text/javascript")
            for path in ("/static/..%2Fapp.py", "/static/app.py", "/static/nothing.js"):
                async with http.get(base + path) as r:
                    assert r.status == 404, path
            async with http.get(base + "/api/trace?name=turn&duration_s=2&width=320&height=180") as r:
                tr = await r.json()
            assert len(tr["t"]) == len(tr["p"]) == len(tr["q"]) == 241 and tr["duration_s"] == pytest.approx(2.0)
            for query, text in (("name=/etc/passwd", "is not a built-in trace"), ("name=walk&duration_s=1e9", "duration_s must be"),
                                ("name=walk&width=x", "invalid literal")):
                async with http.get(base + "/api/trace?" + query) as r:
                    assert r.status == 400 and text in (await r.json())["error"], query
            for body, text in ((b"{", "session request: not JSON"),
                               (json.dumps(_request(method="warp")).encode(), "'warp' is not one this server offers"),
                               (json.dumps(_request(width=3)).encode(), "width: 3 is out of range"),
                               (json.dumps(_request(sdp="v=0\r\nm=video 9 nonsense\r\n")).encode(),
                                "session request.sdp: not an offer this server can take")):
                async with http.post(base + "/api/session", data=body) as r:
                    assert r.status == 400 and text in (await r.json())["error"], body[:40]
            async with http.post(base + "/api/session/nosuch/image/0", data=b"x") as r:
                assert r.status == 404 and "no session 'nosuch'" in (await r.json())["error"]
            async with http.post(base + "/api/session/nosuch/recording", json={"rows": []}) as r:
                assert r.status == 404
            async with http.get(base + "/api/clock") as r:
                assert abs((await r.json())["server_ms"] - __import__("time").time() * 1000) < 5000
        # only the bad SDP got as far as a session (and its render worker): it ended and gave the worker back
        assert server.front.sessions_total == 1 and server.front.active == []
        assert all(s.worker is None for s in server.front.sessions.values())


def test_sas_slot_messages_rebuild_the_sas_clients_vertex_buffer():
    """What the page keeps for ``sas`` (slot rows applied in order, transforms) equals the SAS client's own
    vertex buffer after every frame, whatever the PVS did; parts stay under 64 KiB."""
    from splitrender.codecs.meta import pack_meta, unpack_meta
    from splitrender.pipeline.direct import server_context
    from splitrender.methods.sas import SasConfig, SasServer
    from splitrender.methods.sas.slots import PatchSlots
    from splitrender.methods.sas.wire import parse_frame_meta, parse_session
    from splitrender.render.renderer import Renderer
    from splitrender.scene.loader import get_scene
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.trace import get_trace
    from splitrender.methods.sas.page import MAX_SLOTS_PER_PART, SasPage, parse_slot_message

    r = Renderer()
    scene = get_scene("minimal")
    intr = CameraIntrinsics(320, 180, 60.0)
    trace = get_trace("turn", 2.0)
    srv = SasServer(SasConfig(chroma="420"), intr, scene, 30)
    blob = pack_meta(srv.session_data())
    bridge = SasPage(SasConfig(chroma="420"), intr, blob)
    info = parse_session(unpack_meta(blob))
    reference = PatchSlots(info)
    rows = np.zeros((0, 90), np.float32)
    xf = np.tile(np.eye(4, dtype=np.float32), (info.n_objects, 1, 1))
    high = 0
    assert bridge.terms()["n_objects"] == info.n_objects == 2
    sizes = []
    for f in range(8):
        t = f * 0.2
        pose = trace.pose_at(t)
        u = srv.produce(server_context(scene, r, intr, pose, t_s=t, frame_id=f, predict=trace.pose_at))
        meta = unpack_meta(pack_meta(u.meta))
        msgs = bridge.frame(f, meta)
        for msg in msgs:                      # the page's reading
            sizes.append(len(msg))
            m = parse_slot_message(msg)
            assert m["frame_id"] == f and len(m["slots"]) <= MAX_SLOTS_PER_PART
            need = max([m["high"], *(int(s) + 1 for s in m["slots"])])
            if need > rows.shape[0]:
                rows = np.concatenate([rows, np.zeros((need - rows.shape[0], 90), np.float32)])
            rows[m["slots"]] = m["rows"].reshape(-1, 90)
            xf[m["objects"]] = m["transforms"]
            if m["last"]:
                high = m["high"]
        assert [parse_slot_message(x)["last"] for x in msgs] == [False] * (len(msgs) - 1) + [True]
        reference.apply(parse_frame_meta(meta, info))
        reference.rebuild()
        assert high == reference.high > 0
        np.testing.assert_array_equal(rows[:high], reference.rows[:high].reshape(high, 90))
        assert reference.n_tri > 0
    assert max(sizes) < 65536 and bridge.slot_bytes == sum(sizes) and bridge.meta_bytes > 0
    with pytest.raises(ValueError, match="magic"):
        parse_slot_message(__import__("zlib").compress(b"XXXX" + bytes(28)))


@pytest.mark.slow
async def test_a_page_that_never_connects_ends_its_session(tmp_path, monkeypatch):
    """An offer whose page never completes ICE (here: it never takes the answer) holds a render worker only until
    the connect timeout; the server stays up for the next one."""
    import aiohttp
    from aiortc import RTCConfiguration, RTCPeerConnection

    import splitrender.webrtc.session as bs
    from splitrender.server.server import LiveServer, ServerConfig

    monkeypatch.setattr(bs, "CONNECT_TIMEOUT_S", 1.0)
    cfg = ServerConfig(port=0, udp_port=0, scene="minimal", webrtc_http=("127.0.0.1", 0), methods=("video",))
    async with LiveServer(cfg) as server:
        base = "http://%s:%d" % server.front.address
        pc = RTCPeerConnection(RTCConfiguration(iceServers=[]))
        pc.addTransceiver("video", direction="recvonly")
        pc.createDataChannel("pose")
        await pc.setLocalDescription(await pc.createOffer())
        try:
            async with aiohttp.ClientSession() as http:
                async with http.post(base + "/api/session", json=_request(sdp=pc.localDescription.sdp, method="video")) as r:
                    answer = await r.json()
            assert r.status == 200 and answer["type"] == "answer" and "H264" in answer["sdp"], answer
            session = server.front.sessions[answer["session_id"]]
            await asyncio.wait_for(session.ended.wait(), 10.0)
            assert "did not connect and send a pose within 1 s" in session.end_reason
            for _ in range(100):
                if session.worker is None:
                    break
                await asyncio.sleep(0.05)
            assert session.worker is None and server.front.active == []
        finally:
            await pc.close()


def test_page_glue_is_the_methods_and_the_server_process_imports_no_client_half() -> None:
    """Method-specific page glue sits behind ``MethodSpec.page`` (issue 47): the browser session has no
    ``if method == ...`` of its own, and building every method's glue in a fresh interpreter, as the server process
    does, imports no client half."""
    import inspect
    import subprocess
    import sys

    from splitrender.methods.atw import AtwConfig
    from splitrender.methods.base import PageGlue, get_method
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.webrtc import session

    src = inspect.getsource(session)
    assert 'method == "' not in src and "methods.sas" not in src and "methods.atw" not in src
    intr = CameraIntrinsics(320, 180, 60.0)
    terms = get_method("atw").page_class(AtwConfig(overscan=1.3, fill="black"), intr, b"").terms()
    assert terms["fill"] == "black" and terms["ref_fov_y_deg"] == pytest.approx(intr.enlarged(1.3, True).fov_y_deg)
    assert terms["ref_fov_y_deg"] > 60.0
    assert get_method("video").page_class is PageGlue
    code = ("import sys, splitrender.webrtc.session, splitrender.server.session\n"
            "from splitrender.methods.base import available_methods, get_method\n"
            "for m in available_methods(): get_method(m).page_class\n"
            "print(sorted(k for k in sys.modules if k.startswith('splitrender.methods.') and k.endswith('.client')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stderr + out.stdout


async def test_the_senders_rtcp_reaches_the_session_core_through_one_adapter():
    """``webrtc.track.hook_sender_rtcp`` (issue 47): the page's PLI and FIR become the core's ``receive_picture_loss``
    (counted ``plis``, an IDR ordered), its REMB the core's ``receive_estimate``, a NACK is counted here and left to
    aiortc; every packet still reaches aiortc's own handler.  The core's counters are the session's: it keeps no
    copy of frames, keyframes, poses or PLIs."""
    from types import SimpleNamespace

    from aiortc.rtp import RtcpPsfbPacket, RtcpRtpfbPacket, pack_remb_fci

    from splitrender.codecs.video import VideoCodecConfig
    from splitrender.methods.base import StreamSpec
    from splitrender.pipeline import ServerPipeline, ServerSession
    from splitrender.scene.predict import make_predictor
    from splitrender.webrtc.session import BrowserSession
    from splitrender.webrtc.track import hook_sender_rtcp

    tx = ServerPipeline([StreamSpec("color", VideoCodecConfig("h264", gop=300), 64, 36)], rng=np.random.default_rng(1))
    core = ServerSession(tx, 60.0, predictor=make_predictor("cv"), transport="webrtc")
    seen: list[object] = []

    async def aiortc_handler(packet):
        seen.append(packet)

    sender = SimpleNamespace(_handle_rtcp_packet=aiortc_handler)
    session = BrowserSession.__new__(BrowserSession)
    session.core = core
    session._counters = {"nacks_received": 0, "nacked_packets": 0}
    session.track = session.page = session.relay = None
    session._sender_sent, session.method = None, "video"
    hook_sender_rtcp(sender, core, session._counters)
    packets = [RtcpPsfbPacket(1, 1, 2), RtcpPsfbPacket(4, 1, 2), RtcpRtpfbPacket(1, 1, 2, [5, 6, 7]),
               RtcpPsfbPacket(15, 1, 0, pack_remb_fci(400_000, [2])), RtcpPsfbPacket(15, 1, 0, b"not a remb")]
    for p in packets:
        await sender._handle_rtcp_packet(p)
    assert seen == packets
    c = session.server_counters()
    assert (c["plis"], c["estimates_received"], c["nacks_received"], c["nacked_packets"]) == (2, 1, 1, 3), c
    assert core.keyframe_due(1e12) and c["frames_sent"] == 0 and c["poses_received"] == 0
    with pytest.raises(RuntimeError, match="_handle_rtcp_packet"):
        hook_sender_rtcp(SimpleNamespace(), core, session._counters)
