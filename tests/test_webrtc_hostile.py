"""The browser front door against a hostile page (issue 46, findings 5, 6 and 7): the token on the page's API,
bounded bodies, JSON, traces, images and sessions per address; integers past float range and deep JSON; offers
aiortc fails on.  Every bad request is a 4xx naming what was wrong, never a 500; garbage on a data channel is
counted and answered, and the peer connection stays up.  Then hypothesis fuzzing of the page's messages, the HTTP
handlers and offers through aiortc (rule: an answer below 500; an answer or :class:`PageMessageError`)."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from contextlib import asynccontextmanager
from typing import Any

import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

import splitrender.webrtc.app as app
from splitrender.webrtc.messages import (PageMessageError, decode_json, parse_channel_message, parse_recording,
                                         parse_session_request)
from splitrender.webrtc.sdp import SdpOfferError, check_offer
from splitrender.webrtc.session import try_offer

TOKEN = "s3cret-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
HUGE = int("1" + "0" * 400)          # past float range: float(HUGE) raises OverflowError


async def _offer(video: bool = True) -> tuple[Any, dict[str, Any]]:
    """An aiortc peer connection set up as the page sets up its own, and its offer."""
    from aiortc import RTCConfiguration, RTCPeerConnection

    from splitrender.webrtc.app import restrict_ice_host

    restrict_ice_host("127.0.0.1")   # gather on loopback only, whether or not a front door started first
    pc = RTCPeerConnection(RTCConfiguration(iceServers=[]))
    if video:
        pc.addTransceiver("video", direction="recvonly")
    chans = {"meta": pc.createDataChannel("meta"),
             "frame": pc.createDataChannel("frame", ordered=False, maxPacketLifeTime=250),
             "pose": pc.createDataChannel("pose", ordered=False, maxRetransmits=0)}
    await pc.setLocalDescription(await pc.createOffer())
    return pc, chans


def _request(sdp: str, **kw: Any) -> dict[str, Any]:
    return {"type": "offer", "sdp": sdp, "method": "video", "width": 320, "height": 180, "display_hz": 60, **kw}


@asynccontextmanager
async def _door(tmp_path, token: str | None = TOKEN, **kw: Any):   # type: ignore[no-untyped-def]
    """A live server with its browser front door on loopback, and an HTTP client; yields (server, base, http)."""
    import aiohttp

    from splitrender.server.server import LiveServer, ServerConfig

    cfg = ServerConfig(port=0, udp_port=0, scene="minimal", webrtc_http=("127.0.0.1", 0), out_dir=tmp_path,
                       methods=("video", "atw"), token=token, **kw)
    async with LiveServer(cfg) as server:
        base = "http://%s:%d" % server.front.address
        async with aiohttp.ClientSession() as http:
            yield server, base, http


async def _status(http, method: str, url: str, **kw: Any) -> tuple[int, Any]:   # type: ignore[no-untyped-def]
    async with http.request(method, url, **kw) as r:
        text = await r.text()
    try:
        return r.status, json.loads(text)
    except ValueError:
        return r.status, text


async def _start_session(base: str, http) -> tuple[Any, dict[str, Any], dict[str, Any]]:   # type: ignore[no-untyped-def]
    pc, chans = await _offer()
    status, answer = await _status(http, "POST", base + "/api/session", json=_request(pc.localDescription.sdp),
                                   headers=AUTH)
    assert status == 200 and answer["type"] == "answer", answer
    return pc, chans, answer


# ----------------------------------------------------------------------------- finding 5: the token


@pytest.mark.slow
async def test_the_token_guards_the_pages_api_and_not_its_files(tmp_path):
    async with _door(tmp_path) as (server, base, http):
        for path in ("/", "/static/main.js"):
            assert (await _status(http, "GET", base + path))[0] == 200, path
        pc, _ = await _offer()
        body = _request(pc.localDescription.sdp)
        try:
            for method, path, kw in (("GET", "/api/info", {}), ("GET", "/api/clock", {}),
                                     ("GET", "/api/trace?name=turn&duration_s=1", {}),
                                     ("POST", "/api/session", {"json": body}),
                                     ("POST", "/api/session/x/image/0", {"data": b"x"}),
                                     ("POST", "/api/session/x/recording", {"json": {"rows": []}})):
                status, err = await _status(http, method, base + path, **kw)
                assert status == 401 and "needs its token" in err["error"], (path, status, err)
                for bad in ({"Authorization": "Bearer wrong"}, {"X-Splitrender-Token": TOKEN + "x"},
                            {"Authorization": "Bearer \u00e9"}):
                    status, err = await _status(http, method, base + path, headers=bad, **kw)
                    assert status == 403 and err == {"error": "wrong token"}, (path, bad, status, err)
            assert server.front.sessions_total == 0          # nothing was started without the token
            for headers in (AUTH, {"X-Splitrender-Token": TOKEN}):
                status, info = await _status(http, "GET", base + "/api/info", headers=headers)
                assert status == 200 and info["methods"] == ["video", "atw"]
            status, answer = await _status(http, "POST", base + "/api/session", json=body, headers=AUTH)
            assert status == 200 and answer["type"] == "answer" and "H264" in answer["sdp"], answer
            assert server.front.refused[401] == 6 and server.front.refused[403] == 18
        finally:
            await pc.close()


# ----------------------------------------------------------------------------- finding 5: bounds


@pytest.mark.slow
async def test_traces_are_bounded_and_made_off_the_event_loop(tmp_path):
    """A 600 s trace took 6 CPU s on the event loop; now it is refused, a long one is made in the trace thread
    (the loop keeps ticking), and requests past the trace queue are answered busy at once."""
    async with _door(tmp_path, token=None) as (server, base, http):
        status, err = await _status(http, "GET", base + "/api/trace?name=walk&duration_s=600")
        assert status == 400 and "duration_s must be in [0.5, 120]" in err["error"]
        gaps: list[float] = []

        async def ticker() -> None:
            last = time.perf_counter()
            while True:
                await asyncio.sleep(0.005)
                now = time.perf_counter()
                gaps.append(now - last - 0.005)
                last = now

        tick = asyncio.create_task(ticker())
        t0, w0 = time.process_time(), time.perf_counter()
        status, tr = await _status(http, "GET", base + "/api/trace?name=walk&duration_s=60&width=320&height=180")
        cpu, wall = time.process_time() - t0, time.perf_counter() - w0
        tick.cancel()
        assert status == 200 and len(tr["t"]) == 60 * 120 + 1
        # measured: 0.5-1.1 CPU s for the 60 s trace, the loop's longest gap 10-30 ms idle and 280 ms in CI beside the
        # background runs (made on the loop, the gap was the whole trace, 600 ms): the loop never waits for most of it.
        # The gap is held against the request's wall time, which a loaded machine stretches as it stretches the gaps
        # (with two busy loops beside the suite: a 459 ms gap against 857 ms of CPU failed a bound of half the CPU)
        assert cpu > 0.2 and max(gaps) < 0.5 * wall, (cpu, wall, max(gaps))
        made: list[tuple[Any, ...]] = []
        make = server.front._make_trace
        server.front._make_trace = lambda *key: made.append(key) or make(*key)
        again = await _status(http, "GET", base + "/api/trace?name=walk&duration_s=60&width=320&height=180")
        assert again[0] == 200 and again[1] == tr and made == []   # the same trace again: from the cache, not made
        # eight at once: one is made, four wait, the others are told the server is busy
        got = await asyncio.gather(*[_status(http, "GET", base + f"/api/trace?name=turn&duration_s={20 + i}")
                                     for i in range(8)])
        busy = [e for s, e in got if s == 503]
        assert sorted(s for s, _ in got) == [200] * 5 + [503] * 3, [s for s, _ in got]
        assert all("trace: busy" in e["error"] for e in busy)


@pytest.mark.slow
async def test_bodies_and_json_are_bounded_by_route(tmp_path):
    """The 8.3 MB body of ``[{},{},...]`` cost +191 MB before its 400; deep JSON raised RecursionError (500)."""
    async with _door(tmp_path) as (server, base, http):
        big = b"[" + b"{},{}," * (8_290_000 // 6) + b"{}]"
        status, err = await _status(http, "POST", base + "/api/session", data=big, headers=AUTH)
        assert status == 413 and err["error"] == "session request: 8290000 bytes, more than the 131072 allowed"

        async def chunks():   # no Content-Length: refused as it passes the bound
            for _ in range(100):
                yield b"[{}," * 16384

        status, err = await _status(http, "POST", base + "/api/session", data=chunks(), headers=AUTH)
        assert status == 413 and err["error"] == "session request: more than the 131072 bytes allowed"
        for body, text in ((b"[" * 200 + b"]" * 200, "session request: JSON nested 200 deep, more than the 8 allowed"),
                           (b"[" + b"1," * 1000 + b"1]", "session request: about 1001 JSON values, more than the 256"),
                           (b"\xff{}", "session request: not UTF-8")):
            status, err = await _status(http, "POST", base + "/api/session", data=body, headers=AUTH)
            assert status == 400 and err["error"].startswith(text), (status, err)
        pc, _, answer = await _start_session(base, http)
        try:
            url = f"{base}/api/session/{answer['session_id']}/recording"
            status, err = await _status(http, "POST", url, data=b'{"rows": ' + b"[" * 5000 + b"]" * 5000 + b"}",
                                        headers=AUTH)
            assert status == 400 and "recording: JSON nested 5001 deep" in err["error"], err
            status, err = await _status(http, "POST", url, data=b"x" * (app.MAX_RECORDING_BODY + 1), headers=AUTH)
            assert status == 413 and "more than the 8388608 allowed" in err["error"]
        finally:
            await pc.close()


@pytest.mark.slow
async def test_images_and_sessions_per_address_are_capped(tmp_path, monkeypatch):
    monkeypatch.setattr(app, "MAX_IMAGES_PER_SESSION", 3)
    monkeypatch.setattr(app, "MAX_SESSIONS_PER_ADDRESS", 1)
    async with _door(tmp_path) as (server, base, http):
        pc, _, answer = await _start_session(base, http)
        try:
            sid = answer["session_id"]
            img = bytes(320 * 180 * 4)
            for frame in range(3):
                status, ok = await _status(http, "POST", f"{base}/api/session/{sid}/image/{frame}", data=img, headers=AUTH)
                assert status == 200 and ok == {"ok": True}
            status, err = await _status(http, "POST", f"{base}/api/session/{sid}/image/3", data=img, headers=AUTH)
            assert status == 413 and "has posted 3 images, the most one session may" in err["error"]
            assert len(list((tmp_path / sid / "images").iterdir())) == 3
            session = server.front.sessions[sid]
            assert session.counters["images_received"] == 3 and session.counters["image_bytes_received"] == 3 * len(img)
            monkeypatch.setattr(app, "MAX_IMAGES_PER_SESSION", 100)
            monkeypatch.setattr(app, "MAX_IMAGE_BYTES_PER_SESSION", 4 * len(img))
            assert (await _status(http, "POST", f"{base}/api/session/{sid}/image/3", data=img, headers=AUTH))[0] == 200
            status, err = await _status(http, "POST", f"{base}/api/session/{sid}/image/4", data=img, headers=AUTH)
            assert status == 413 and "past the 921600 one session may" in err["error"], err
            status, err = await _status(http, "POST", f"{base}/api/session/{sid}/image/4", data=img + b"x", headers=AUTH)
            assert status == 413      # the bytes cap comes first; a body past the image's size is refused too
            # a second session from the same address
            pc2, _ = await _offer()
            try:
                status, err = await _status(http, "POST", base + "/api/session", json=_request(pc2.localDescription.sdp),
                                            headers=AUTH)
                assert status == 429 and "1 sessions from 127.0.0.1 already" in err["error"], err
            finally:
                await pc2.close()
        finally:
            await pc.close()


# ----------------------------------------------------------------------------- finding 6


def test_integers_past_float_range_are_refused_by_name():
    """``math.isfinite(10**400)`` and ``float(10**400)`` raise OverflowError: they were reached at three sites in
    messages.py and one in app.py."""
    sdp = "v=0\r\n"
    with pytest.raises(PageMessageError, match=r"session request.width: an integer of 401 digits is out of range"):
        parse_session_request(_request(sdp, width=HUGE), ["video"], 1 << 30)
    with pytest.raises(PageMessageError, match=r"pose message.t_us: an integer of 401 digits is out of range"):
        parse_channel_message(json.dumps({"type": "pose", "seq": 1, "t_us": HUGE, "p": [0, 0, 0], "q": [0, 0, 0, 1]}))
    with pytest.raises(PageMessageError, match=r"pose message.p\[1\]: expected a finite number within ±1e\+06, got an"):
        parse_channel_message(json.dumps({"type": "pose", "seq": 1, "t_us": 1, "p": [0, HUGE, 0], "q": [0, 0, 0, 1]}))
    row = {"frame": 0, "px": 0, "py": 0, "pz": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 1, "scene_t_s": 0}
    with pytest.raises(PageMessageError, match=r"recording.rows\[0\].t_s: an integer of 401 digits is out of range"):
        parse_recording({"rows": [{**row, "t_s": HUGE}]})
    rec = parse_recording({"rows": [row], "duration_s": HUGE, "stats": {"nackCount": HUGE, "framesDecoded": 3}})
    assert rec.stats == {"framesDecoded": 3} and rec.duration_s != rec.duration_s     # NaN: left out
    with pytest.raises(PageMessageError, match="JSON nested 9 deep, more than the 8 allowed"):
        parse_channel_message("[" * 9 + "]" * 9)


@pytest.mark.slow
async def test_http_answers_integers_and_deep_json_with_400(tmp_path):
    async with _door(tmp_path) as (server, base, http):
        pc, _, answer = await _start_session(base, http)
        try:
            body = json.dumps(_request(pc.localDescription.sdp, height=HUGE))
            status, err = await _status(http, "POST", base + "/api/session", data=body, headers=AUTH)
            assert status == 400 and "session request.height: an integer of 401 digits" in err["error"], err
            url = f"{base}/api/session/{answer['session_id']}/recording"
            row = {"frame": 0, "px": 0, "py": 0, "pz": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 1, "scene_t_s": 0}
            status, ok = await _status(http, "POST", url, data=json.dumps({"rows": [row], "duration_s": HUGE}),
                                       headers=AUTH)
            assert status == 200 and ok["rows"] == 1, ok
            rec = json.loads((tmp_path / answer["session_id"] / "recording.json").read_text())
            assert rec["duration_s"] != rec["duration_s"] or rec["duration_s"] == "NaN"
            status, err = await _status(http, "POST", url, data=json.dumps({"rows": [{**row, "px": HUGE}]}),
                                        headers=AUTH)
            assert status == 400 and "recording.rows[0].px: an integer of 401 digits" in err["error"]
            status, err = await _status(http, "POST", url, data="[" * 100_000 + "]" * 100_000, headers=AUTH)
            assert status == 400 and "JSON nested" in err["error"]
        finally:
            await pc.close()


@pytest.mark.slow
async def test_garbage_on_the_pose_channel_is_counted_and_answered_and_the_connection_stays(tmp_path):
    """An integer past float range in a pose raised OverflowError into aiortc, which closed the peer connection
    with nothing counted or sent.  Now each refused message is counted and answered on ``meta``; the connection
    stays up and poses keep coming, until the 16th refusal ends the session."""
    from aiortc import RTCSessionDescription

    from splitrender.webrtc.session import MAX_PAGE_ERRORS

    async with _door(tmp_path) as (server, base, http):
        pc, chans, answer = await _start_session(base, http)
        try:
            await pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], "answer"))
            session = server.front.sessions[answer["session_id"]]
            errors: asyncio.Queue[str] = asyncio.Queue()
            chans["meta"].on("message", lambda m: errors.put_nowait(m) if isinstance(m, str) and '"error"' in m else None)
            for _ in range(200):
                if chans["pose"].readyState == "open" and "pose" in session.channels and "meta" in session.channels:
                    break
                await asyncio.sleep(0.05)
            assert chans["pose"].readyState == "open", session.channels
            chans["pose"].send(json.dumps({"type": "pose", "seq": 1, "t_us": HUGE, "p": [0, 1.6, 0], "q": [0, 0, 0, 1]}))
            err = json.loads(await asyncio.wait_for(errors.get(), 10))
            assert err["text"].startswith("pose message.t_us: an integer of 401 digits is out of range"), err
            assert session.counters["page_errors"] == 1 and not session.ended.is_set()
            chans["pose"].send(json.dumps({"type": "pose", "seq": 2, "t_us": int(time.time() * 1e6),
                                           "p": [0, 1.6, 0], "q": [0, 0, 0, 1]}))
            for _ in range(100):
                if session.server_counters()["poses_received"]:
                    break
                await asyncio.sleep(0.05)
            assert session.server_counters()["poses_received"] == 1 and pc.connectionState == "connected"
            for i in range(MAX_PAGE_ERRORS - 1):
                chans["pose"].send("[" * 20 + "]" * 20)
            await asyncio.wait_for(session.ended.wait(), 10)
            assert session.counters["page_errors"] == MAX_PAGE_ERRORS
            assert session.end_reason.startswith("page error: 16 messages refused, the last: page message: JSON nested")
        finally:
            await pc.close()


# ----------------------------------------------------------------------------- finding 7


REMOVALS = ("a=rtpmap:99 H264/90000", "a=recvonly", "a=mid:0")


@pytest.mark.slow
async def test_offers_aiortc_fails_on_are_answered_400_naming_the_sdp(tmp_path):
    """Without ``a=rtpmap:99 H264/90000``, ``a=recvonly`` or ``a=mid:0`` aiortc raised RuntimeError, ValueError or
    AttributeError: 500.  They are refused by name before a render worker is taken."""
    async with _door(tmp_path) as (server, base, http):
        pc, _ = await _offer()
        try:
            lines = pc.localDescription.sdp.split("\r\n")
            assert all(r in lines for r in REMOVALS)
            texts = []
            for removed in REMOVALS:
                sdp = "\r\n".join(ln for ln in lines if ln != removed)
                status, err = await _status(http, "POST", base + "/api/session", json=_request(sdp), headers=AUTH)
                assert status == 400 and err["error"].startswith("session request.sdp: not an offer this server can "
                                                                 "take (media section 0 (line "), (removed, err)
                texts.append(err["error"].split("): ", 1)[1])
            assert texts == ["'a=rtcp-fb:99 nack' comes before (or without) a=rtpmap:99)",
                             "no direction attributes (a=recvonly, a=sendrecv, ...), expected one)",
                             "no a=mid lines, expected one)"]
            assert all(s.worker is None for s in server.front.sessions.values())
        finally:
            await pc.close()


async def test_what_the_offer_check_cannot_foresee_is_still_the_pages_error():
    """aiortc's own exceptions on an offer that passes :func:`check_offer` are a PageMessageError (400), not a 500:
    here an ``a=sctp-port`` that is not a number (ValueError inside aiortc)."""
    pc, _ = await _offer()
    try:
        sdp = pc.localDescription.sdp.replace("a=sctp-port:5000", "a=sctp-port:x")
        check_offer(sdp)
        with pytest.raises(PageMessageError, match=r"session request.sdp: not an offer this server can take \(ValueError"):
            await try_offer(sdp)
        assert "H264" in await try_offer(pc.localDescription.sdp)
    finally:
        await pc.close()


# ----------------------------------------------------------------------------- the page in a browser, with the token


@pytest.mark.slow
def test_a_page_with_the_token_in_its_url_streams_and_one_without_is_refused():
    from splitrender.webrtc.driver import PageDriver, ServerProcess, browser_missing

    if browser_missing() is not None:
        pytest.skip(str(browser_missing()))
    with ServerProcess(["--scene", "minimal", "--methods", "video", "--token", TOKEN]) as server, PageDriver() as d:
        res = d.session(server.url, "video", trace="turn", duration_s=3.0, record_every=0, token=TOKEN)
        # it streams: the page decodes what reached it (against what arrived, not a rate: 21-25 decoded in 3 s at
        # load 26-30, where this asked for more than 30; 74 of 86 received in a clean-clone CI run beside the stress
        # suite, where a slowed decoder still holds the last frames when the session ends)
        st = res["stats"] if res["ok"] else {}
        assert res["ok"] and st["framesDecoded"] >= max(5, 0.75 * st["framesReceived"]), (res, list(d.console), list(server.log)[-20:])
        res = d.session(server.url, "video", trace="turn", duration_s=3.0, record_every=0, timeout_s=30)
        assert not res["ok"] and "/api/info: this server needs its token" in res["error"], res
        res = d.session(server.url, "video", trace="turn", duration_s=3.0, record_every=0, timeout_s=30, token="nope")
        assert not res["ok"] and "/api/info: wrong token" in res["error"], res


# ----------------------------------------------------------------------------- fuzzing

_json = st.recursive(st.none() | st.booleans() | st.integers(min_value=-HUGE, max_value=HUGE) |
                     st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=20),
                     lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=12), inner, max_size=6),
                     max_leaves=30)
_keys = st.sampled_from(["type", "seq", "t_us", "p", "q", "frame_id", "displayed_us", "received_us", "sdp", "method",
                         "width", "height", "display_hz", "rows", "stats", "duration_s", "trace", "record_every"])
_values = st.sampled_from(["pose", "feedback", "bye", "offer", 0, 1, -1, 2**53, HUGE, 1.5, [0, 0, 0], [0, 0, 0, 1],
                           [0, 0, 0, HUGE], None, "v=0", 320, 180, 60])
_messages = st.one_of(_json, st.dictionaries(_keys, _values | _json, max_size=8))


@settings(max_examples=400)
@given(_messages, st.integers(0, 3))
def test_fuzz_page_messages_parse_or_raise_page_message_error(value, nest):
    text = "[" * nest + json.dumps(value) + "]" * nest
    for parse in (parse_channel_message,
                  lambda t: parse_session_request(decode_json(t, "session request", 1 << 17, 256), ["video"], 1 << 21),
                  lambda t: parse_recording(decode_json(t, "recording", 1 << 20, 1 << 16))):
        try:
            parse(text)
        except PageMessageError:
            pass


@settings(max_examples=300)
@given(st.binary(max_size=300) | st.text(max_size=300).map(str.encode))
def test_fuzz_bounded_json_decodes_or_raises_page_message_error(data):
    try:
        decode_json(data, "fuzz", 256, 64, max_depth=4)
    except PageMessageError:
        pass


class _Door:
    """A live server with a browser front door, running on its own thread's event loop, for sync hypothesis
    tests: ``call(coro)`` runs a coroutine there."""

    def __enter__(self) -> _Door:
        import tempfile

        self.loop = asyncio.new_event_loop()
        self.tmp = tempfile.TemporaryDirectory()
        self.ready = threading.Event()
        self.stop: asyncio.Event | None = None
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.ctx = _door(__import__("pathlib").Path(self.tmp.name))
        self.server, self.base, self.http = self.call(self.ctx.__aenter__())
        self.pc, _, answer = self.call(_start_session(self.base, self.http))
        self.sid = answer["session_id"]
        return self

    def call(self, coro: Any, timeout: float = 60.0) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def __exit__(self, *exc: Any) -> None:
        try:
            self.call(self.pc.close())
            self.call(self.ctx.__aexit__(None, None, None))
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self.thread.join(10)
            self.loop.close()
            self.tmp.cleanup()


@pytest.fixture(scope="module")
def door():  # type: ignore[no-untyped-def]
    with _Door() as d:
        yield d


_paths = st.sampled_from(["/api/session", "/api/session/{sid}/recording", "/api/session/{sid}/image/0",
                          "/api/session/{sid}/image/-1", "/api/session/nosuch/recording", "/api/trace", "/api/info"])
_query = st.dictionaries(st.sampled_from(["name", "duration_s", "width", "height"]),
                         st.sampled_from(["walk", "turn", "static", "0", "-1", "1e400", "nan", "inf", "2", "16", "99999",
                                          "1" + "0" * 5000, "x", ""]) | st.text(max_size=8), max_size=4)
_headers = st.sampled_from([AUTH, {"X-Splitrender-Token": TOKEN}, {}, {"Authorization": "Bearer"},
                            {"Authorization": "Basic " + TOKEN}])


@pytest.mark.slow
@settings(max_examples=150)
@given(path=_paths, body=_messages, raw=st.booleans(), headers=_headers)
def test_fuzz_http_handlers_never_answer_500(door, path, body, raw, headers):
    data = json.dumps(body).encode()
    if raw:
        data = data[: len(data) // 2]            # cut JSON
    status, err = door.call(_status(door.http, "POST", door.base + path.format(sid=door.sid), data=data,
                                    headers=headers))
    assert status < 500, (path, status, err)
    if status >= 400 and isinstance(err, dict):
        assert err["error"], err


@pytest.mark.slow
@settings(max_examples=60)
@given(query=_query, headers=_headers)
def test_fuzz_trace_requests_never_answer_500(door, query, headers):
    status, err = door.call(_status(door.http, "GET", door.base + "/api/trace", params=query, headers=headers))
    assert status < 500, (query, status, err)


_OFFER: list[str] = []


def _real_offer() -> list[str]:
    if not _OFFER:
        async def make() -> str:
            pc, _ = await _offer()
            try:
                return str(pc.localDescription.sdp)
            finally:
                await pc.close()

        _OFFER.extend(asyncio.run(make()).split("\r\n"))
    return list(_OFFER)


@st.composite
def _mutated_offer(draw: Any) -> str:
    lines = _real_offer()
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, len(lines) - 1))
        op = draw(st.sampled_from(["drop", "dup", "cut", "swap", "digit", "text"]))
        if op == "drop":
            del lines[i]
        elif op == "dup":
            lines.insert(i, lines[i])
        elif op == "cut":
            lines[i] = lines[i][: draw(st.integers(0, max(0, len(lines[i]) - 1)))]
        elif op == "swap":
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        elif op == "digit":
            lines[i] = "".join(draw(st.sampled_from("0123456789x-")) if c.isdigit() else c for c in lines[i])
        else:
            lines[i] = lines[i][:2] + draw(st.text(max_size=20))
        if not lines:
            lines = ["v=0"]
    return "\r\n".join(lines)


@pytest.mark.slow
@settings(max_examples=200)
@given(_mutated_offer())
def test_fuzz_offers_through_aiortc_answer_or_raise_page_message_error(sdp):
    """The front door's offer path (:func:`check_offer`, then aiortc): an answer, or a PageMessageError (400)."""
    try:
        answer = asyncio.run(asyncio.wait_for(try_offer(sdp), 20))
    except PageMessageError as exc:
        assert str(exc).startswith("session request.sdp: not an offer this server can take ("), exc
        event("refused by check_offer" if isinstance(exc, SdpOfferError) else "refused by aiortc")
    else:
        event("answered")
        assert answer.startswith("v=0")
