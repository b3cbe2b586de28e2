"""The sans-IO session cores alone, fed bytes and times by hand (the aioquic habit): NACK and
retransmission, PLI after a lost keyframe, stall detection, randomised RTCP intervals."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from splitrender.codecs.video import VideoCodecConfig
from splitrender.errors import ConfigError
from splitrender.methods import StreamSpec, Update
from splitrender.pipeline import (ClientOptions, Opening, method_config, ClientPipeline, ClientSession, FrameReleased, ServerOptions, ServerPipeline,
                                  ServerSession, Stalled, StallTimeout, StreamEncoder, specs_from_table)
from splitrender.protocol import (PROTOCOL_VERSION, ClientConnection, GenericNack, Hello, PictureLossIndication, serialize_rtcp,
                                  ReceiverReport, SenderReport, ServerConnection, Welcome, parse_rtcp)
from splitrender.protocol.framing import NEED_DATA
from splitrender.scene.pose import CameraIntrinsics, Pose
from splitrender.server.server import ServerConfig

W, H = 64, 48
FPS = 30.0


class Pair:
    """A server core and a client core over hand-moved bytes and time (no network, no clock)."""

    def __init__(self, transport_cc: bool = False, pacing: bool = False, **client_opts: object) -> None:
        spec = StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)
        self.tx = ServerPipeline([spec], mtu=300, rng=np.random.default_rng(1), transport_cc_id=5 if transport_cc else None)
        self.encoder = StreamEncoder([spec])
        self.sconn, self.cconn = ServerConnection(), ClientConnection()
        self.sconn.receive_data(self.cconn.send(Hello(PROTOCOL_VERSION, "", ("x",), ("h264",), W, H, FPS)))
        self.sconn.next_event()
        self.cconn.receive_data(self.sconn.send(Welcome("s", "x", self.tx.welcome_params(b""),
                                                        self.tx.describe("127.0.0.1", 5000, "t"))))
        w = self.cconn.next_event()
        assert isinstance(w, Welcome)
        opts = ClientOptions(**client_opts)  # type: ignore[arg-type]
        rx = ClientPipeline(w.streams, specs_from_table(w.method_params["streams"]), opts.jitter_timeout_ms,
                            resolve_timeout_ms=opts.resolve_timeout_ms, limits=opts.limits)
        self.client = ClientSession(rx, opts, FPS, rng=np.random.default_rng(2),
                                    transport_cc_id=w.method_params.get("transport_cc"))
        self.server = ServerSession(self.tx, 60.0, ServerOptions(keyframe_min_interval_ms=100.0, pacing=pacing),
                                    rng=np.random.default_rng(3))
        self.client.start(0.0)
        self.server.start(0.0)
        self.rng = np.random.default_rng(4)

    def frame(self, fid: int, now_ms: float) -> tuple[list[bytes], list[bytes]]:
        """Server frame ``fid`` at ``now_ms``: (control frames, RTP datagrams)."""
        kf = self.server.keyframe_due(now_ms)
        plane = (self.rng.random((H, W, 3)) * 255).astype(np.uint8)
        enc = self.encoder.encode(Update(fid, fid / FPS, Pose(), {"color": plane}, {}), force_idr=kf or fid == 0)
        out = self.tx.packetize(enc, self.sconn.send, 1_000_000 + fid, fid * 3000, 0, fid, fid / FPS, {}, {})
        self.server.frame_sent(fid, out, now_ms, 1_000_000 + fid)
        self.out = out
        # what the core lets go now (its one way out: the control frames, all the RTP datagrams without a pacer)
        control = self.server.data_to_send(now_ms)
        assert control == [d for _, d in out.control]
        return control, [d.data for d in self.server.datagrams_to_send(now_ms) if d.kind == "rtp"]

    def answer(self, rtcp: list, now_ms: float) -> list[bytes]:  # type: ignore[type-arg]
        """The server core takes the client's RTCP ``rtcp`` (packets, sent as one compound datagram) at ``now_ms``: the
        packets it resends, as they leave its one way out (of kind ``resend``)."""
        self.server.receive_datagram(serialize_rtcp(rtcp), now_ms)
        return [d.data for d in self.server.datagrams_to_send(now_ms) if d.kind == "resend"]

    def reports(self, now_ms: float) -> list[bytes]:
        """The server's sender reports due at ``now_ms`` (what its way out gives of kind ``rtcp``)."""
        return [d.data for d in self.server.datagrams_to_send(now_ms) if d.kind == "rtcp"]

    def released(self, fid: int, now_ms: float) -> list:  # type: ignore[type-arg]
        """Server frame ``fid`` delivered whole at ``now_ms``: the decode work the client core releases (undecoded)."""
        control, datagrams = self.frame(fid, now_ms)
        for data in control:
            self.cconn.receive_data(data)
            while (ev := self.cconn.next_event()) is not NEED_DATA:
                self.client.receive_message(ev, now_ms)  # type: ignore[arg-type]
        for d in datagrams:
            self.client.receive_datagram(d, now_ms)
        return self.client.work_to_decode()

    def to_client(self, control: list[bytes], datagrams: list[bytes], now_ms: float) -> None:
        for data in control:
            self.cconn.receive_data(data)
            while (ev := self.cconn.next_event()) is not NEED_DATA:
                self.client.receive_message(ev, now_ms)  # type: ignore[arg-type]
        for d in datagrams:
            self.client.receive_datagram(d, now_ms)
            self._decode(self.client.work_to_decode(), now_ms)

    def _decode(self, works: list, now_ms: float) -> None:  # type: ignore[type-arg]
        for w in works:
            self.client.on_decoded(w, ClientPipeline.decode(w), now_ms)

    def timer(self, now_ms: float) -> list[list]:  # type: ignore[type-arg]
        """Run the client's timer at ``now_ms``; the RTCP it sent, parsed."""
        self.client.handle_timer(now_ms)
        self._decode(self.client.work_to_decode(), now_ms)
        return [parse_rtcp(d) for d in self.client.datagrams_to_send()]


def _due(client: ClientSession, now_ms: float) -> list:  # type: ignore[type-arg]
    """The updates a display tick at ``now_ms`` applies (the one way frames leave the client core)."""
    return client.display_tick(None, now_ms, hold=False)[1] or []


def _releases(client: ClientSession) -> list:  # type: ignore[type-arg]
    """The frames the client core announced released since the last call (its other events dropped)."""
    return [ev.frame for ev in iter(client.next_event, None) if isinstance(ev, FrameReleased)]


def _nacks(rtcp: list[list]) -> list[GenericNack]:  # type: ignore[type-arg]
    return [p for c in rtcp for p in c if isinstance(p, GenericNack)]


def test_a_lost_packet_is_nacked_once_after_the_delay_and_the_retransmission_completes_the_frame() -> None:
    p = Pair(nack_delay_ms=20.0, nack_retry_ms=120.0)
    p.timer(0.0)
    ctrl, dgrams = p.frame(0, 0.0)
    p.to_client(ctrl, dgrams, 5.0)
    assert [f.update.frame_id for f in _due(p.client, 6.0)] == [0]
    ctrl, dgrams = p.frame(1, 33.0)
    assert len(dgrams) >= 3
    lost = dgrams[1]
    p.to_client(ctrl, dgrams[:1] + dgrams[2:], 38.0)
    assert _due(p.client, 39.0) == []              # held: a packet of frame 1 is missing
    assert _nacks(p.timer(40.0)) == []               # the timer sees the hole at 40 ms
    assert _nacks(p.timer(50.0)) == []               # 10 ms later: too early
    nacks = _nacks(p.timer(60.0))                    # 20 ms: one NACK naming the lost sequence number
    assert len(nacks) == 1 and nacks[0].lost == (int.from_bytes(lost[2:4], "big"),)
    assert _nacks(p.timer(70.0)) == [] and _nacks(p.timer(170.0)) == []   # the retry waits 120 ms
    resend = p.answer([nacks[0]], 80.0)
    assert resend == [lost] and p.server.counters["retransmitted"] == 1
    p.to_client([], resend, 95.0)
    shown = _due(p.client, 96.0)
    assert [f.update.frame_id for f in shown] == [1] and shown[0].update.complete
    assert p.client.nack_rtt_ms == pytest.approx(95.0 - 60.0)
    assert p.client.counters["nacks_sent"] == 1 and p.client.counters["plis_sent"] == 0


def test_nack_off_sends_no_nack() -> None:
    p = Pair(nack_max_tries=0)
    ctrl, dgrams = p.frame(0, 0.0)
    p.to_client(ctrl, dgrams[:1] + dgrams[2:], 5.0)
    assert all(_nacks(p.timer(t)) == [] for t in (30.0, 200.0, 400.0))


def test_a_lost_keyframe_is_answered_with_a_pli_and_the_server_sends_an_idr() -> None:
    p = Pair(jitter_timeout_ms=50.0, nack_max_tries=0, pli_interval_ms=100.0)
    ctrl, dgrams = p.frame(0, 0.0)
    p.to_client(ctrl, dgrams[1:], 5.0)               # the IDR's first packet is lost
    ctrl, dgrams = p.frame(1, 33.0)                  # a P frame: dropped while waiting for a keyframe
    p.to_client(ctrl, dgrams, 40.0)
    rtcp = p.timer(50.0)                             # frame 0 is given up: the stream needs an IDR
    rtcp += p.timer(100.0) + p.timer(140.0)          # PLIs at least 100 ms apart
    plis = [x for c in rtcp for x in c if isinstance(x, PictureLossIndication)]
    assert len(plis) == 1 and plis[0].media_ssrc == p.tx.streams["color"].ssrc
    assert [x for c in p.timer(150.0) for x in c if isinstance(x, PictureLossIndication)]   # still waiting: again
    p.server.receive_datagram(serialize_rtcp(plis), 155.0)
    ctrl, dgrams = p.frame(2, 160.0)
    assert p.server.counters["plis"] == 1 and p.server.counters["keyframes"] == 2
    p.to_client(ctrl, dgrams, 165.0)
    shown = [f for f in _due(p.client, 170.0) if f.update.planes]
    assert [f.update.frame_id for f in shown] == [2]
    assert p.client.counters["keyframes_after_pli"] == 1


def test_frames_leave_the_client_core_one_way() -> None:
    """A frame the inputs complete joins the display queue by itself (announced by FrameReleased, for the driver's
    records) and leaves only as a display tick's update, :attr:`release_delay_ms` after its release (virtual time's
    decode model); the drivers call nothing in between."""
    p = Pair()
    p.client.release_delay_ms = lambda rf: 4.0
    ctrl, dgrams = p.frame(0, 0.0)
    p.to_client(ctrl, dgrams, 5.0)
    (rf,) = _releases(p.client)
    assert rf.update.frame_id == 0 and rf.update.complete
    assert _due(p.client, 8.9) == [] and _due(p.client, 9.0) == [rf] and _due(p.client, 100.0) == []
    assert not hasattr(p.client, "collect") and not hasattr(p.client, "display")


def test_a_stall_is_reported_after_stall_frames_intervals_and_asks_for_keyframes_only_after_loss() -> None:
    p = Pair(stall_frames=6.0, stall_timeout_s=1.0, pli_interval_ms=100.0)
    ctrl, dgrams = p.frame(0, 0.0)
    p.to_client(ctrl, dgrams, 5.0)                   # the last frame arrives at 5 ms
    p.timer(100.0)
    assert [f.update.frame_id for f in _releases(p.client)] == [0]   # its release, the only event
    stall_ms = 6.0 / FPS * 1000                      # 200 ms: nothing measured yet, the nominal rate
    assert p.client.get_timer() == pytest.approx(5.0 + stall_ms)
    rtcp = p.timer(5.0 + stall_ms)
    ev = p.client.next_event()
    assert p.client.next_event() is None
    assert isinstance(ev, Stalled) and ev.idle_ms == pytest.approx(stall_ms)
    # nothing was lost: a slow server, not a broken stream, so no keyframe is asked for
    assert not any(isinstance(x, PictureLossIndication) for c in rtcp for x in c)
    assert p.client.counters["stalls"] == 1 and p.client.counters["stall_plis"] == 0
    p.timer(1004.0)
    assert p.client.next_event() is None
    p.timer(1006.0)
    assert any(isinstance(e, StallTimeout) for e in iter(p.client.next_event, None))
    # a frame loses a packet and is given up (jitter timeout): the next stall asks for a keyframe
    ctrl, dgrams = p.frame(1, 1010.0)
    p.to_client(ctrl, dgrams[:1] + dgrams[2:], 1015.0)
    p.timer(1400.0)
    rtcp = p.timer(1500.0)
    assert p.client.counters["plis_sent"] >= 1


def test_a_slow_server_is_not_a_stall_once_its_rate_is_measured() -> None:
    """The keyframe storm of issue 37: at 2-4 server updates a second every gap was a stall (six nominal 33 ms
    intervals), a PLI and a keyframe.  Stalls are now measured in the achieved interval (the last second's
    frames, at least the nominal one, at most 500 ms), and a stall without loss asks for no keyframe: a lossless
    server at 3 frames a second stalls once, at its second frame (before a rate is measured), and never asks for
    a keyframe."""
    p = Pair(stall_frames=6.0, pli_interval_ms=100.0)
    t = 0.0
    for fid in range(30):                            # 10 s at 3 frames a second, nominal 30
        ctrl, dgrams = p.frame(fid, t)
        p.to_client(ctrl, dgrams, t + 5.0)
        for k in range(1, 33):
            p.timer(t + 5.0 + 10.0 * k)
        t += 1000.0 / 3
    assert p.client.counters["stalls"] == 1 and p.client.counters["plis_sent"] == 0, p.client.counters
    assert p.client._achieved_ms == pytest.approx(1000.0 / 3, rel=0.01)


def test_rtcp_report_intervals_are_randomised_around_their_mean() -> None:
    p = Pair(rr_interval_s=0.5)
    ctrl, dgrams = p.frame(0, 0.0)
    p.to_client(ctrl, dgrams, 5.0)
    rr_times, sr_times = [], []
    for t in np.arange(10.0, 60_000.0, 10.0):
        if any(isinstance(x, ReceiverReport) and x.reports for c in p.timer(float(t)) for x in c):
            rr_times.append(float(t))
        if p.reports(float(t)):
            sr_times.append(float(t))
    for times, mean in ((rr_times, 500.0), (sr_times, 1000.0)):
        gaps = np.diff(times)
        assert len(set(gaps.round())) > 10, gaps[:20]                       # the interval varies
        assert gaps.min() >= 0.5 * mean - 10 and gaps.max() <= 1.5 * mean + 10, (gaps.min(), gaps.max())
        assert abs(gaps.mean() - mean) < 0.1 * mean, gaps.mean()
    sr = parse_rtcp(p.reports(120_000.0)[0])
    assert isinstance(sr[0], SenderReport) and sr[0].packet_count == p.tx.streams["color"].packetizer.packets_sent  # type: ignore[union-attr]


def test_playout_delay_holds_each_update_until_its_turn() -> None:
    p = Pair(playout_delay_ms=100.0)
    for fid in range(3):
        ctrl, dgrams = p.frame(fid, fid * 33.0)
        p.to_client(ctrl, dgrams, fid * 33.0 + 5.0)
    # server times are 1_000_000 + fid µs on the protocol clock (offset 0): due 100 ms after
    assert _due(p.client, 1099.9) == []
    assert [f.update.frame_id for f in _due(p.client, 1100.001)] == [0, 1]
    assert [f.update.frame_id for f in _due(p.client, 1101.0)] == [2]


def test_bad_options_are_named() -> None:
    with pytest.raises(ConfigError, match="playout_delay_ms"):
        ClientOptions(playout_delay_ms=-1)
    with pytest.raises(ConfigError, match="nack_max_tries"):
        ClientOptions(nack_max_tries=1.5)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="history_packets"):
        ServerOptions(history_packets=0)
    from splitrender.sim.config import RunConfig

    with pytest.raises(ConfigError, match="run config client options: client nack_max_tries: must be in"):
        RunConfig(nack_max_tries=-1)
    with pytest.raises(ConfigError, match="playout_delay_ms: must be in \\[0, 2000\\], got 5000"):
        RunConfig.from_dict({"playout_delay_ms": 5000})


def test_a_welcome_without_a_stream_table_is_the_peers_error() -> None:
    from splitrender.errors import RemoteProtocolError
    from splitrender.protocol import Welcome

    with pytest.raises(RemoteProtocolError, match=r"Welcome.method_params.streams: expected a list"):
        ClientSession.from_welcome(Welcome("s", "video", {}, ()), ClientOptions())


def test_a_feedback_flood_leaves_the_server_core_bounded() -> None:
    """The hostile-peer campaign's find: 3,000 valid Feedback messages (7.4 MiB) grew a server by 514 MB, because
    the server kept every stream name a client listed and every row.  Now 3,000 Feedbacks, each listing 256 new
    lost frames on the session's stream, cost the core under 1 MB (measured 0.33 MB with tracemalloc), and a
    Feedback naming a stream the session did not declare is the client's protocol error naming it."""
    import tracemalloc

    from splitrender.pipeline.feedback import MAX_FRAMES_REMEMBERED
    from splitrender.protocol import Feedback
    from splitrender.protocol.errors import MessageError

    p = Pair()
    core = p.server
    for fid in range(3):
        p.frame(fid, fid * 33.0)

    def fb(i: int, stream: str = "color") -> Feedback:
        return Feedback(i, 1, 2, 3, 0, 0, {"render": 1, "encode": 2}, {stream: i}, {stream: tuple(range(256 * i, 256 * i + 256))})

    core.receive_message(fb(0), 100.0)
    core.rows_to_write()
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    for i in range(1, 3001):
        core.receive_message(fb(i), 100.0 + i)
        assert [k for k, _ in core.rows_to_write()] == ["feedback"]   # each Feedback's row, taken as a driver does
    grown = (tracemalloc.get_traced_memory()[0] - base) / 2**20
    tracemalloc.stop()
    assert grown < 1.0, grown
    assert len(core.fb._fb.lost["color"]) <= 4 * MAX_FRAMES_REMEMBERED
    snap = core.fb.snapshot(False)
    assert len(snap.lost_since["color"]) == 4 * MAX_FRAMES_REMEMBERED
    with pytest.raises(MessageError, match=r"Feedback.lost: stream 'x0' is not one of this session's \['color'\]"):
        core.receive_message(Feedback(3001, 1, 2, 3, 0, 0, {}, {}, {"x0": (1,)}), 4000.0)
    with pytest.raises(MessageError, match=r"Feedback.applied: stream"):
        core.receive_message(Feedback(3002, 1, 2, 3, 0, 0, {}, {"nope": 1}, {}), 4000.0)


# ---------------------------------------------------------------------------- what a client accepts from a server

def test_a_client_refuses_stream_sizes_over_its_limits() -> None:
    """The campaign's find: a data stream's ``max_bytes`` up to 2 GiB was accepted from Welcome (a 24 KB DataChunk
    then decompressed to 768 MiB).  The client's limits (``ClientLimits``) refuse the session at Welcome, naming
    the stream, the field and the limit; raising the limit accepts it."""
    from splitrender.limits import ClientLimits
    from splitrender.pipeline import SessionDataError

    big = [{"name": "blob", "kind": "data", "delivery": "reliable", "compression": "zstd", "max_bytes": 2**31}]
    w = Welcome("s", "x", {"streams": big, "server_fps": 30}, ())
    with pytest.raises(SessionDataError, match=r"streams\['blob'\].max_bytes: 2147483648 bytes exceeds this client's "
                                               r"limit of 67108864 \(max_stream_bytes\)"):
        ClientSession.from_welcome(w, ClientOptions())
    ClientSession.from_welcome(w, ClientOptions(limits=ClientLimits(max_stream_bytes=2**31)))
    p = Pair()
    huge = [dict(r) for r in p.tx.welcome_params(b"")["streams"]]
    huge[0].update(width=8192, height=8192)
    w = Welcome("s", "x", {"streams": huge}, p.tx.describe("127.0.0.1", 5000, "t"))
    with pytest.raises(SessionDataError, match=r"8192x8192 video exceeds this client's limit of 16777216 pixels"):
        ClientSession.from_welcome(w, ClientOptions())


def test_frames_whose_streams_never_arrive_cannot_pin_the_clients_memory() -> None:
    """The campaign's find: 8 FrameMeta messages whose streams never arrive pinned 640 MB.  Now what frames not yet
    complete hold is capped (``max_pending_bytes``): the oldest are given up (reported lost) to stay under it, and
    a single frame over it is the server's error.  Eight frames each carrying 8 MiB of metadata under a 20 MiB cap
    hold at most two; the peak traced memory stays under 48 MiB (measured 40: two held, one arriving, its decoding;
    before, all eight: 64 MiB and more)."""
    import tracemalloc

    from splitrender.codecs.meta import pack_meta
    from splitrender.limits import ClientLimits
    from splitrender.pipeline import EnvelopeError
    from splitrender.protocol import FrameMeta, Pose as WirePose

    p = Pair(limits=ClientLimits(max_pending_bytes=20 * 2**20))
    rx = p.client.rx
    env = {"t_s": 0.0, "pose": [0.0, 1.6, 2.5, 0.0, 0.0, 0.0, 1.0], "m": {"a": np.ones(2 * 2**20, np.float32)},
           "target_t_s": 0.0, "timing_us": {}, "srv": {}}
    blob = pack_meta(env)
    wpose = WirePose(0, 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    tracemalloc.start()
    for fid in range(8):
        p.client.receive_message(FrameMeta(fid, 0, {"color": 3000 * fid}, wpose, blob, False), float(fid))
        assert rx.held_bytes() <= 20 * 2**20
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    assert rx.pending_frames == 2 and rx.counters["frames_given_up"] == 6
    assert peak < 48, peak
    one = dict(env, m={"a": np.ones(6 * 2**20, np.float32)})    # 24 MiB in one frame
    with pytest.raises(EnvelopeError, match=r"FrameMeta 8: frames not yet complete hold \d+ bytes, over this client's "
                                            r"limit of 20971520 bytes \(max_pending_bytes\)"):
        p.client.receive_message(FrameMeta(8, 0, {"color": 24000}, wpose, pack_meta(one), False), 8.0)


def test_a_decoded_frame_of_the_wrong_size_is_dropped_and_counted() -> None:
    """The campaign's find: the video client showed decoded frames of any size.  The receive path checks each
    decoded frame against the size the Welcome table declared (counted ``frames_wrong_size``, handled as a decode
    error: the stream waits for a keyframe); the video client half refuses a plane that is not its display's."""
    from splitrender.methods.base import DecodedUpdate
    from splitrender.methods.video.client import VideoClient, VideoFrameError

    p = Pair()
    ctrl, dgrams = p.frame(0, 0.0)
    for data in ctrl:
        p.cconn.receive_data(data)
        while (ev := p.cconn.next_event()) is not NEED_DATA:
            p.client.receive_message(ev, 1.0)  # type: ignore[arg-type]
    for d in dgrams:
        p.client.receive_datagram(d, 2.0)
    works = p.client.work_to_decode()
    assert len(works) == 1
    p.client.on_decoded(works[0], np.zeros((H * 2, W * 2, 3), np.uint8), 3.0)
    assert p.client.rx.counters["frames_wrong_size"] == 1 and p.client.rx.counters["decode_errors"] == 1
    assert p.client.rx.needs_keyframe() == ["color"]
    half = VideoClient(None, CameraIntrinsics(W, H, 60.0), None, {})  # type: ignore[arg-type]
    with pytest.raises(VideoFrameError, match=rf"colour plane of shape \(10, 10, 3\), this client displays {W}x{H}"):
        half.apply(DecodedUpdate(0, 0.0, Pose(), {"color": np.zeros((10, 10, 3), np.uint8)}, {}, {}, frozenset()))
    half.apply(DecodedUpdate(1, 0.0, Pose(), {"color": np.zeros((H, W, 3), np.uint8)}, {}, {}, frozenset()))
    assert half.has_content


def test_client_limits_are_configurable_from_the_command_line_and_named_when_wrong() -> None:
    import argparse

    from splitrender.client.cli import add_client_arguments, config_from_args

    p = argparse.ArgumentParser()
    add_client_arguments(p)
    cfg = config_from_args(p.parse_args(["--limit", "max_probes=4096", "--limit", "max_pending_frames=8"]))
    assert cfg.limits.max_probes == 4096 and cfg.limits.max_pending_frames == 8  # type: ignore[attr-defined]
    assert cfg.options().limits is cfg.limits  # type: ignore[attr-defined]
    with pytest.raises(ConfigError, match=r"client limits: unknown key\(s\) \['max_nothing'\]"):
        config_from_args(p.parse_args(["--limit", "max_nothing=1"]))
    with pytest.raises(ConfigError, match=r"--limit: expected KEY=N with an integer N, got 'max_probes=lots'"):
        config_from_args(p.parse_args(["--limit", "max_probes=lots"]))
    with pytest.raises(ConfigError, match=r"client limits: max_probes must be a positive integer, got 0"):
        config_from_args(p.parse_args(["--limit", "max_probes=0"]))


def test_every_sender_report_compound_carries_the_sessions_cname() -> None:
    """RFC 3550 6.1: every compound RTCP packet has an SDES CNAME; the server's SR compounds lacked it (issue 37).
    One CNAME names all the session's streams (so a receiver synchronises them), derived from its SSRCs."""
    from splitrender.protocol import SourceDescription

    p = Pair()
    p.frame(0, 0.0)
    sent = [d for t in np.arange(10.0, 3000.0, 10.0) for d in p.reports(float(t))]
    assert len(sent) >= 2
    for data in sent:
        packets = parse_rtcp(data)
        assert isinstance(packets[0], SenderReport)
        (sdes,) = [x for x in packets if isinstance(x, SourceDescription)]
        assert [c.ssrc for c in sdes.chunks] == [x.ssrc for x in packets if isinstance(x, SenderReport)]
        assert {c.cname for c in sdes.chunks} == {p.server.cname} and p.server.cname.startswith(b"splitrender-server-")


def test_the_client_handshake_core_names_what_a_welcome_got_wrong() -> None:
    """The client's handshake is one sans-IO core (``ClientHandshake``) that the live client and the runner drive.
    The fuzz harness found the live client letting a Welcome's bad fields out as its own ConfigError, ValueError
    or TypeError; each is now the peer's EnvelopeError naming the field."""
    from splitrender.codecs.meta import pack_meta
    from splitrender.pipeline import ClientHandshake, EnvelopeError
    from splitrender.protocol import DataChunk

    p = Pair()
    blob = pack_meta({"hello": 1})
    good = Welcome("s", "video", {"config": {}, "fov_y_deg": 60.0, "server_fps": 30, **p.tx.welcome_params(blob)},
                   p.tx.describe("127.0.0.1", 5000, "t"))
    cases = [
        ({"method": "nosuch"}, r"Welcome.method: 'nosuch' is not one this client offered"),
        ({"method": "atw"}, r"Welcome.method: 'atw' is not one this client offered \(\['video'\]\)"),
        ({"config": [1]}, r"Welcome.method_params.config: expected a map of parameter names, got list"),
        ({"config": {"bitrate_kbpq": 1}}, r"Welcome.method_params.config: .*unknown parameter 'bitrate_kbpq'"),
        ({"fov_y_deg": "h264"}, r"Welcome.method_params.fov_y_deg: expected a number in \(0, 179\], got 'h264'"),
        ({"server_fps": [30]}, r"Welcome.method_params.server_fps: expected a number in \(0, 1000\], got \[30\]"),
        ({"subject": [[0, 0, 0], [1, "x", 1]]}, r"Welcome.method_params.subject"),
    ]
    for change, text in cases:
        method = change.pop("method", "video")
        w = Welcome("s", method, {**good.method_params, **change}, good.streams)
        with pytest.raises(EnvelopeError, match=text):
            ClientHandshake(("video",)).receive_message(w)
    hs = ClientHandshake(("video",))
    assert not hs.receive_message(good)
    twice = ClientHandshake(("video",))
    twice.receive_message(good)
    with pytest.raises(EnvelopeError, match="handshake: expected session data after Welcome, got Welcome"):
        twice.receive_message(good)
    assert hs.receive_message(DataChunk("session", 0, 0, len(blob), blob))
    assert hs.session_data == {"hello": 1} and hs.terms is not None and hs.terms.server_fps == 30.0
    core = hs.session(ClientOptions())
    assert core.server_fps == 30.0 and set(core.rx.streams) == {"color"}


def test_a_full_intra_request_is_answered_once_per_sequence_number() -> None:
    """RFC 5104 4.3.1 (offered in the SDP as ``ccm fir``): a FIR naming one of the session's streams asks for an
    IDR; the same sequence number again is the same request resent (answered once), a new one a new request; FIRs
    for another SSRC are ignored.  The bytes round-trip through the project's parser."""
    from splitrender.protocol import FullIntraRequest
    from splitrender.protocol.rtcp import parse_rtcp, rtcp_route_ssrc

    p = Pair()
    p.frame(0, 0.0)
    (ssrc,) = [s.ssrc for s in p.server.streams.values()]
    fir = FullIntraRequest(0x1234, ((ssrc, 7),))
    data = serialize_rtcp([ReceiverReport(0x1234), fir])
    packets = parse_rtcp(data)
    assert packets[1] == fir and rtcp_route_ssrc(data) == ssrc
    p.server.receive_datagram(serialize_rtcp(packets), 1000.0)
    p.server.receive_datagram(serialize_rtcp(packets), 1010.0)                 # resent: the same request
    p.server.receive_datagram(serialize_rtcp([FullIntraRequest(0x1234, ((ssrc + 1, 8),))]), 1020.0)
    assert p.server.counters["firs"] == 1 and p.server.keyframe_due(1030.0)
    p.server.receive_datagram(serialize_rtcp([FullIntraRequest(0x1234, ((ssrc, 8),))]), 1500.0)
    assert p.server.counters["firs"] == 2


def test_transport_wide_feedback_reports_every_stamped_packet_and_a_loss() -> None:
    """With transport-wide feedback each RTP packet leaves with the next transport sequence number (a retransmission
    too); the client reports arrivals 100 ms after the first unreported one, a lost packet as not received; the
    server matches every status with what it sent and its estimator takes the results."""
    from splitrender.protocol.rtp import RtpPacket
    from splitrender.protocol.twcc import TransportFeedback, read_transport_seq

    p = Pair(transport_cc=True)
    ctrl, sent = p.frame(0, 0.0)
    made = [d for _, _, d in p.out.datagrams]
    assert len(made) >= 4 and all(read_transport_seq(d, 5) == 0 for d in made)        # reserved, written at send
    assert [read_transport_seq(d, 5) for d in sent] == list(range(len(sent)))
    assert [RtpPacket.parse(a).payload for a in sent] == [RtpPacket.parse(b).payload for b in made]
    p.to_client(ctrl, sent[:2] + sent[3:], 20.0)                                      # packet 2 lost
    assert not any(isinstance(x, TransportFeedback) for c in p.timer(60.0) for x in c)
    fbs = [x for c in p.timer(120.0) for x in c if isinstance(x, TransportFeedback)]
    assert len(fbs) == 1 and fbs[0].base_seq == 0 and len(fbs[0].arrivals) == len(sent)
    assert [a is None for a in fbs[0].arrivals] == [k == 2 for k in range(len(sent))]
    p.server.receive_datagram(serialize_rtcp(fbs), 140.0)
    assert p.server.counters["twcc_feedback"] == 1 and p.server.counters["twcc_unknown"] == 0
    assert p.server.send_history is not None and p.server.send_history.in_flight == 0
    assert p.server.estimator is not None and len(p.server.estimator.history) == 1
    assert set(p.server.congestion()) == {"cc_target_kbps", "cc_encoder_kbps", "cc_acked_kbps", "cc_queue_ms"}
    p.server.receive_datagram(serialize_rtcp([GenericNack(p.client.ssrc, p.tx.streams["color"].ssrc,
                                                          (int.from_bytes(sent[2][2:4], "big"),))]), 150.0)
    (out,) = p.server.datagrams_to_send(150.0)             # the resend leaves the one way, stamped as it leaves
    assert out.kind == "resend" and read_transport_seq(out.data, 5) == len(sent)
    assert p.client.counters["twcc_feedback_sent"] == 1


def test_without_transport_wide_feedback_packets_carry_no_extension() -> None:
    from splitrender.errors import RemoteProtocolError
    from splitrender.protocol.rtp import RtpPacket

    p = Pair()
    _, dgrams = p.frame(0, 0.0)
    assert dgrams == [d for _, _, d in p.out.datagrams]                              # left as they were made
    assert all(RtpPacket.parse(d).extension_profile is None for d in dgrams)
    assert p.server.congestion() == {} and "transport_cc" not in p.tx.welcome_params(b"")
    q = Pair(transport_cc=True)
    w = Welcome("s", "x", {**q.tx.welcome_params(b""), "transport_cc": 15}, q.tx.describe("127.0.0.1", 5000, "t"))
    with pytest.raises(RemoteProtocolError, match=r"Welcome.method_params.transport_cc: expected a header extension id in "
                                                  r"1..14, got 15"):
        ClientSession.from_welcome(w, ClientOptions())


def test_a_paced_session_spreads_a_frame_at_the_pacing_rate() -> None:
    """With pacing the core lets a frame's datagrams go at 2.5x the estimate (a session that does not adapt starts
    it at 2 Mbit/s: 5 Mbit/s), stamped in the order they leave, the first 5 ms worth at once; without it, all at
    once."""
    from splitrender.pipeline.session import UNADAPTED_START_BPS
    from splitrender.protocol.twcc import read_transport_seq

    p = Pair(transport_cc=True, pacing=True)
    _, first = p.frame(0, 0.0)
    dgrams = [d for _, _, d in p.out.datagrams]
    assert len(dgrams) >= 8
    assert 1 <= len(first) < len(dgrams)
    times, sent, now = [0.0] * len(first), list(first), 0.0
    while len(sent) < len(dgrams):
        now = p.server.get_timer()                       # the pacer's next send, behind the core's one timer
        assert now < 1000.0
        got = [d.data for d in p.server.datagrams_to_send(now) if d.kind == "rtp"]
        times += [now] * len(got)
        sent += got
    assert [d[2:4] for d in sent] == [d[2:4] for d in dgrams]                    # in order, RTP sequence numbers kept
    assert [read_transport_seq(d, 5) for d in sent] == list(range(len(dgrams)))
    span_ms = times[-1] - times[0]
    expect_ms = sum(len(d) for d in dgrams[len(first):]) * 8 / (2.5 * UNADAPTED_START_BPS) * 1000
    assert span_ms == pytest.approx(expect_ms, rel=0.35), (span_ms, expect_ms)
    assert p.server.pacer is not None and p.server.pacer.queued == 0
    assert p.server.get_timer() >= 500.0                                            # only the first sender report left
    q = Pair(transport_cc=True)
    _, dgrams = q.frame(0, 0.0)
    assert len(dgrams) == len(q.out.datagrams) and q.server.get_timer() >= 500.0


def test_pacing_needs_transport_wide_feedback() -> None:
    from splitrender.sim.config import RunConfig

    with pytest.raises(ConfigError, match="run config pacing: paces at the estimated rate, so it needs transport_cc"):
        RunConfig(pacing=True)


def test_frames_given_up_for_the_frame_bound_still_hand_over_their_reliable_data_in_order() -> None:
    """Video that does not come (a standing queue, a dead UDP path) while metadata and reliable data do: past
    ``max_pending_frames`` the oldest frames are given up, but their reliable data still reaches the half, first and
    in frame order, so a method whose data are deltas (tss's tables, sas's geometry) stays in step with its server
    (it lost them, and its client rejected every later delta: 97 updates in a 10 s tss run behind a 2 Mbit/s step)."""
    from splitrender.limits import ClientLimits
    from splitrender.methods.base import DataStreamSpec

    specs = [StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H), DataStreamSpec("tris")]
    tx = ServerPipeline(specs, mtu=300, rng=np.random.default_rng(1))
    encoder = StreamEncoder(specs)
    sconn, cconn = ServerConnection(), ClientConnection()
    sconn.receive_data(cconn.send(Hello(PROTOCOL_VERSION, "", ("x",), ("h264",), W, H, FPS)))
    sconn.next_event()
    cconn.receive_data(sconn.send(Welcome("s", "x", tx.welcome_params(b""), tx.describe("127.0.0.1", 5000, "t"))))
    w = cconn.next_event()
    opts = ClientOptions(limits=ClientLimits(max_pending_frames=4))
    rx = ClientPipeline(w.streams, specs_from_table(w.method_params["streams"]), 1e9, resolve_timeout_ms=1e9,
                        limits=opts.limits)
    client = ClientSession(rx, opts, FPS, rng=np.random.default_rng(2))
    rng = np.random.default_rng(4)
    got = []
    for fid in range(10):
        plane = (rng.random((H, W, 3)) * 255).astype(np.uint8)
        enc = encoder.encode(Update(fid, fid / FPS, Pose(), {"color": plane}, {}, data={"tris": f"delta {fid}".encode()}),
                             force_idr=fid == 0)
        out = tx.packetize(enc, sconn.send, 1_000_000 + fid, fid * 3000, 0, fid, fid / FPS, {}, {})
        for data in (d for _, d in out.control):          # the RTP datagrams never arrive
            cconn.receive_data(data)
            while (ev := cconn.next_event()) is not NEED_DATA:
                client.receive_message(ev, float(fid))  # type: ignore[arg-type]
        got += [(rf.update.frame_id, rf.update.data.get("tris"), rf.update.missing) for rf in _releases(client)]
    assert rx.counters["frames_given_up"] == 6 and rx.pending_frames == 4
    assert [(f, d) for f, d, _ in got] == [(f, f"delta {f}".encode()) for f in range(6)], got
    assert all("color" in m for _, _, m in got)                # given up without their pictures


# --------------------------------------------------------------------------- frame orders and the client's rules


def test_the_server_core_orders_each_frame_from_the_poses_it_took() -> None:
    """``order_frame`` is the one frame tick of every front door: no order before a pose, the newest pose taken
    (a stale one dropped), the target pose predicted ``expected latency`` after now on the driver's clock and
    reported on the scene's (``epoch_s`` apart), a granted keyframe request consumed by exactly one order."""
    from splitrender.scene.predict import make_predictor

    tx = ServerPipeline([StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)], rng=np.random.default_rng(1))
    core = ServerSession(tx, 60.0, ServerOptions(keyframe_min_interval_ms=100.0), predictor=make_predictor("cv"))
    epoch = 1000.0                                   # driver time of scene time 0 (a wall clock)
    assert core.order_frame(0, 0, 0.0, epoch * 1000, epoch) is None       # no pose yet
    at = lambda x: Pose(np.array([x, 0.0, 0.0]), np.array([1.0, 0.0, 0.0, 0.0]))  # noqa: E731
    assert core.receive_pose(epoch + 0.0, at(0.0), 1, 1) and core.receive_pose(epoch + 0.1, at(1.0), 2, 2)
    assert not core.receive_pose(epoch + 0.05, at(9.0), 3, 3)              # reordered: dropped
    core.request_keyframe(epoch * 1000 + 200)
    order = core.order_frame(7, 3, 0.1, epoch * 1000 + 200, epoch, client=2)
    assert order is not None and (order.frame_id, order.tick, order.t_s, order.client) == (7, 3, 0.1, 2)
    assert order.keyframe and (order.pose_us, order.pose_seq) == (2, 2)
    assert order.latest_pose_t_s == pytest.approx(0.1) and order.latest_pose.position[0] == 1.0
    lat = core.fb.latency.value_s
    assert order.expected_latency_s == lat and order.target_t_s == pytest.approx(0.2 + lat)
    # 10 m/s from the two samples taken, extrapolated to the display time, through the order's scene-clock predict
    assert order.target_pose.position[0] == pytest.approx(1.0 + 10 * (0.1 + lat))
    assert order.predict(0.3).position[0] == pytest.approx(3.0)
    ctx = order.context(None, None, None, shared="s")
    assert (ctx.frame_id, ctx.keyframe_requested, ctx.shared, ctx.client, ctx.target_t_s) == (7, True, "s", 2, order.target_t_s)
    again = core.order_frame(8, 4, 0.13, epoch * 1000 + 233, epoch)
    assert again is not None and not again.keyframe                        # the request was consumed once
    assert order.rates_kbps is None and order.point is None                # no adaptation in this session


def test_the_webrtc_profile_keeps_no_rtp_transport() -> None:
    """The browser front door's core: aiortc owns RTP and RTCP, so the core holds no retransmission history and
    sends no sender reports, while it still counts frames and keyframes and orders frames."""
    from splitrender.pipeline import OutgoingFrame
    from splitrender.scene.predict import make_predictor

    tx = ServerPipeline([StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)], rng=np.random.default_rng(1))
    core = ServerSession(tx, 60.0, predictor=make_predictor("cv"), transport="webrtc")
    core.start(0.0)
    assert core.streams == {} and core.datagrams_to_send(1e9) == [] and core.get_timer() == float("inf")
    core.receive_pose(0.0, Pose())
    assert core.order_frame(0, 0, 0.0, 0.0) is not None
    core.frame_sent(0, OutgoingFrame(0, keyframe=True, wire_bytes={"color": 100}), 0.0, 1)
    assert core.counters["frames_sent"] == 1 and core.counters["keyframes"] == 1
    # frame_encoded, every front door's report of a made frame: here the stack packetizes, so the coded streams count
    order = core.order_frame(1, 1, 1 / FPS, 33.0)
    plane = (np.random.default_rng(0).random((H, W, 3)) * 255).astype(np.uint8)
    enc = StreamEncoder(tx.specs).encode(Update(1, 1 / FPS, Pose(), {"color": plane}, {}), force_idr=True)
    sent = core.frame_encoded(order, enc, 33.0, 2)
    assert (sent.frame_id, sent.keyframe, sent.idr_streams, sent.datagrams) == (1, True, ("color",), [])
    assert sent.wire_bytes == {"color": len(enc.video["color"].data)} and sent.control == []
    assert core.counters["frames_sent"] == 2 and core.counters["keyframes"] == 2 and core.datagrams_to_send(1e9) == []
    with pytest.raises(ConfigError, match="server transport: must be rtp or webrtc, got 'quic'"):
        ServerSession(tx, 60.0, transport="quic")


def test_a_page_takes_one_video_stream_on_the_webrtc_profile() -> None:
    """``accept_page``, the browser front door's side of the handshake in the core (issue 47: the front door built
    its core and refused streams itself): one video stream gives a core on the WebRTC transport with aiortc's pacing,
    anything else is refused with the streams named."""
    from splitrender.errors import RemoteProtocolError
    from splitrender.pipeline import accept_page

    video = StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)
    page = Opening("video", method_config("video", {}), CameraIntrinsics(W, H))
    core = accept_page(page, [video], 60.0, ServerConfig(transport_cc=True, pacing=True))
    assert core.transport == "webrtc" and not core.options.pacing and core.streams == {} and core.display_hz == 60.0
    depth = StreamSpec("depth", VideoCodecConfig("h264", gop=300), W, H)
    with pytest.raises(RemoteProtocolError, match=r"method warp: streams \['color', 'depth'\] cannot go to a page "
                                                  r"\(it takes one video stream\)"):
        accept_page(dataclasses.replace(page, method="warp"), [video, depth], 60.0, ServerConfig())


def test_a_page_gets_the_method_knobs_its_terms_allow(monkeypatch: pytest.MonkeyPatch) -> None:
    """``serve --webrtc --adapt full`` (issue 47: ``accept_page`` gave the core no knobs, so a page adapted on the
    pipeline's bare resolution scale, without a quality model): the core takes the method's knobs that leave the
    page's terms as they are.  video's and atw's scale carry their quality models; sas's atlas budget and frame rate are kept (its page's terms come
    from the session data, which no knob changes); a knob of a field the page's terms are made from (atw's overscan:
    the reference field of view the page warps with) is left out, one of another field (crf) kept."""
    from splitrender.methods.atw.config import AtwConfig
    from splitrender.methods.base import SCALE_KNOB, Knob
    from splitrender.pipeline.session import accept_page, page_knobs

    video = StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H, scalable=True)
    atw = Opening("atw", method_config("atw", {}), CameraIntrinsics(W, H))
    core = accept_page(atw, [video], 60.0, ServerConfig(transport_cc=True, adapt="full"))
    assert core.point is not None and [k.name for k in core.point.knobs] == ["scale"]
    assert core.point.model is not None and core.point.model is atw.config.adapt_knobs()[0].model
    vcfg = method_config("video", {})
    plain = accept_page(Opening("video", vcfg, CameraIntrinsics(W, H)), [video], 60.0,
                        ServerConfig(transport_cc=True, adapt="full"))
    assert plain.point is not None and plain.point.model is vcfg.adapt_knobs()[0].model is not None
    sas = Opening("sas", method_config("sas", {}), CameraIntrinsics(W, H))
    monkeypatch.setattr("splitrender.methods.sas.page.SasPage.__init__", lambda self, *a: None)
    monkeypatch.setattr("splitrender.methods.sas.page.SasPage.terms", lambda self: {"atlas_width": 1024})
    assert [k.name for k in page_knobs(sas, b"")] == ["bias_fill", "frame_div"]
    overscan = Knob("overscan", (1.4, 1.2), (1.0, 0.8), "video", "reference field of view")
    crf = Knob("crf", (23, 28), (1.0, 0.6), "video", "quantiser")
    monkeypatch.setattr(AtwConfig, "adapt_knobs", lambda self: (overscan, crf, SCALE_KNOB))
    assert [k.name for k in page_knobs(atw, b"")] == ["crf", "scale"]


def test_the_live_frame_clock_is_the_core_s() -> None:
    """``order_tick``, the two live front doors' frame clock (issue 47; each kept a frame id and a last tick): a frame
    is numbered by the frames sent before it, lands on the wall clock's tick of the shared grid, or on the next one
    when that tick already had a frame (a late or skipped frame never shares a tick), at scene time tick / fps.
    Poses come as the client sends them (``receive_pose_sample``: µs on the protocol's clock), by the one rule."""
    from types import SimpleNamespace

    from splitrender.pipeline import OutgoingFrame
    from splitrender.scene.predict import make_predictor

    tx = ServerPipeline([StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)], rng=np.random.default_rng(1))
    core = ServerSession(tx, 60.0, predictor=make_predictor("cv"), transport="webrtc")
    sample = lambda us, seq: SimpleNamespace(client_time_us=us, seq=seq, position=(1.0, 2.0, 3.0),  # noqa: E731
                                             orientation=(1.0, 0.0, 0.0, 0.0))
    assert core.order_tick(3, 30.0, 0.0) is None                      # no pose yet
    assert core.receive_pose_sample(sample(2_000_000, 4)) and not core.receive_pose_sample(sample(1_999_999, 5))
    assert core.poses.latest_t_s == 2.0 and core.poses.counters() == {"poses_received": 1, "poses_stale": 1}
    ticks = []
    for wall_tick in (5, 5, 4, 9):
        order = core.order_tick(wall_tick, 30.0, 0.0)
        assert order is not None and order.t_s == order.tick / 30.0 and order.pose_seq == 4
        ticks.append((order.frame_id, order.tick))
        core.frame_sent(order.frame_id, OutgoingFrame(order.frame_id, wire_bytes={"color": 1}), 0.0, 1)
    assert ticks == [(0, 5), (1, 6), (2, 7), (3, 9)]
    assert core.order_tick(9, 30.0, 0.0).frame_id == 4                # ordered, never sent: the next takes its id
    assert core.order_tick(9, 30.0, 0.0).frame_id == 4


def test_a_live_tick_orders_a_frame_only_when_the_session_can_take_it() -> None:
    """``live_tick``, the two live front doors' gate on their frame clock (issue 47; each gated its ticks itself):
    missed ticks are counted, no frame is made before the path is ready, on the RTP transport before the client's
    RTCP names its address, or before a pose; a backlog skips the tick (counted).  ``order_at`` orders the frame on
    the wall clock's tick of the shared grid (epoch 100 s, 30 Hz: 100.5 s is tick 15)."""
    from splitrender.scene.predict import make_predictor

    tx = ServerPipeline([StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)], rng=np.random.default_rng(1))
    page = ServerSession(tx, 60.0, predictor=make_predictor("cv"), transport="webrtc")
    assert not page.live_tick(skipped=2)                              # no pose yet
    page.receive_pose(100.4, Pose())
    assert not page.live_tick(ready=False) and not page.live_tick(backlog=True)   # not connected; a backlog
    assert page.live_tick(skipped=1)
    assert (page.counters["frames_skipped_late"], page.counters["frames_skipped_backlog"]) == (3, 1)
    order = page.order_at(100_500.0, 30.0, 100.0)
    assert order is not None and (order.frame_id, order.tick, order.t_s) == (0, 15, 0.5)
    rtp = ServerSession(ServerPipeline([StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)],
                                       rng=np.random.default_rng(1)), 60.0, predictor=make_predictor("cv"))
    rtp.receive_pose(0.0, Pose())
    assert not rtp.live_tick() and rtp.peer is None                   # no RTCP from the client yet
    rtp.receive_datagram(serialize_rtcp([ReceiverReport(1234, ())]), 1000.0, ("10.0.0.1", 5000))
    assert rtp.live_tick() and rtp.order_at(1000.0, 30.0, 0.0).tick == 30


def test_the_client_core_owns_the_blank_frame_and_keyframe_skip_rules() -> None:
    """Both client drivers (virtual time, live) ask the core: a tick is blank before any update shows or while the
    half has no content; a broken video stream's non-keyframe is skipped and counted lost, a keyframe decoded."""
    p = Pair()
    assert p.client.blank(True)                                   # nothing shown yet
    works = p.released(0, 0.0)
    assert len(works) == 1 and works[0].unit.keyframe
    works[0].stream.broken = True                                 # as a decode error of an earlier frame leaves it
    assert not p.client.skips_decode(works[0], 0.0)               # a keyframe is decoded
    works[0].stream.broken = False                                # (its release mends the stream)
    p.client.on_decoded(works[0], ClientPipeline.decode(works[0]), 0.0)
    (rf,) = _releases(p.client)                                   # released by the decode result, announced
    assert p.client.data_to_send() == b""
    # what the tick shows (the one call of both drivers): the applied update, its Feedback sent the first time only
    assert p.client.showing([rf], [True], True, 10.0) is rf and p.client.shown is rf
    assert p.client.counters["frames_displayed_updates"] == 1 and p.client.data_to_send() != b""
    assert p.client.showing([], [], False, 20.0) is None         # the half lost its content: the black background
    assert p.client.showing([], [], True, 30.0) is rf and p.client.data_to_send() == b""
    assert not p.client.blank(True) and p.client.blank(False)
    works = p.released(1, 33.0)
    assert len(works) == 1 and not works[0].unit.keyframe
    errors = p.client.all_counters()["decode_errors"]
    works[0].stream.broken = True                                 # a decode error after this frame's release
    assert p.client.skips_decode(works[0], 33.0)                  # skipped, reported as a decode error
    assert p.client.all_counters()["decode_errors"] == errors + 1


def test_accept_hello_is_the_one_server_handshake() -> None:
    """Every protocol front door (the runner, the live server) accepts a Hello the same way: the session data and
    the streams' codecs are checked against the server's limit and the client's codecs, by name, and the Welcome
    and session data leave framed in order for the client's handshake core."""
    from splitrender.codecs.meta import pack_meta
    from splitrender.errors import RemoteProtocolError
    from splitrender.methods.base import get_method, make_config
    from splitrender.pipeline import ClientHandshake, SessionDataError, accept_hello
    from splitrender.protocol import ErrorCode

    mcfg = make_config(get_method("video").config, {})
    spec = StreamSpec("color", VideoCodecConfig("hevc", gop=300), W, H)
    hello = Hello(PROTOCOL_VERSION, "", ("video",), ("h264", "hevc"), W, H, FPS)
    blob = pack_meta({"pad": np.random.default_rng(0).bytes(5000)})
    n = len(blob)

    encoder = StreamEncoder([spec])
    encoder.open()

    def accept(h: Hello, limit: int = 1 << 20):  # type: ignore[no-untyped-def]
        sconn = ServerConnection()
        sconn.receive_data(ClientConnection().send(h))
        sconn.next_event()
        return accept_hello(h, "sid", Opening("video", mcfg, CameraIntrinsics(W, H)), [spec], blob, sconn,
                            ServerConfig(scene="minimal", max_session_bytes=limit), ServerOptions(),
                            parameter_sets=encoder.described_sets(), rng=np.random.default_rng(1))

    with pytest.raises(SessionDataError, match=rf"^method video: session data of {n} bytes exceeds this server's limit "
                                               rf"of {n - 1} bytes \(max_session_bytes\)$"):
        accept(hello, n - 1)
    with pytest.raises(RemoteProtocolError, match=r"stream color is hevc, which the client does not accept") as info:
        accept(dataclasses.replace(hello, codecs=("h264",)))
    assert info.value.code == ErrorCode.UNSUPPORTED_METHOD
    acc = accept(hello)
    assert acc.core.display_hz == FPS
    assert "sprop-vps=" in acc.welcome.streams[0].sdp       # the SDP names the encoder's parameter sets
    cconn = ClientConnection()
    cconn.send(hello)
    hs = ClientHandshake(hello.methods, display=(W, H))
    frames = acc.core.data_to_send(0.0)                   # the core's one way out: the Welcome, then the chunks
    assert len(frames) >= 2 and acc.session_bytes == sum(map(len, frames[1:])) and acc.core.data_to_send(0.0) == []
    cconn.receive_data(b"".join(frames))
    while (ev := cconn.next_event()) is not NEED_DATA:
        hs.receive_message(ev)  # type: ignore[arg-type]
    assert hs.done and hs.welcome == acc.welcome
    assert hs.session_data is not None and hs.session_data["pad"] == np.random.default_rng(0).bytes(5000)


def test_the_client_handshake_names_what_it_waits_for_and_a_refusal() -> None:
    """The live client's handshake text is the handshake core's (issue 47): what it waits for (for a timeout to
    name), and a server's ``Error`` or its closing the connection, before the Welcome or during the session data,
    as a ServerRefusedError naming which."""
    from splitrender.codecs.meta import pack_meta
    from splitrender.errors import ServerRefusedError
    from splitrender.pipeline import ClientHandshake, accept_hello
    from splitrender.protocol import Error

    hello = Hello(PROTOCOL_VERSION, "", ("video",), ("h264",), W, H, FPS)
    hs = ClientHandshake(hello.methods, display=(W, H))
    assert hs.waiting_for == "Welcome"
    with pytest.raises(ServerRefusedError, match=r"^server refused the session: 503: server busy$"):
        hs.receive_message(Error(503, "server busy"))
    with pytest.raises(ServerRefusedError, match=r"^server closed the connection instead of answering Hello$"):
        hs.receive_message(None)
    sconn = ServerConnection()
    sconn.receive_data(hs.hello(hello))
    sconn.next_event()
    acc = accept_hello(hello, "sid", Opening("video", method_config("video", {}), CameraIntrinsics(W, H)),
                       [StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)],
                       pack_meta({"pad": bytes(3000)}), sconn, ServerConfig(scene="minimal", max_session_bytes=1 << 20),
                       ServerOptions(), rng=np.random.default_rng(1))
    welcome, *chunks = acc.core.data_to_send(0.0)
    assert not hs.receive_data(welcome) and chunks
    assert hs.waiting_for == f"session data (0 of {hs.session_progress[1]} bytes received)" and hs.session_progress[1] > 0
    with pytest.raises(ServerRefusedError, match=r"^server closed the connection during the session data$"):
        hs.receive_message(None)


def test_everything_the_server_core_sends_leaves_one_way_at_its_one_timer() -> None:
    """Issue 47: a frame whose encoding ends later (virtual time's ``send_ms``) waits behind the core's timer,
    a NACK's answer and the sender reports leave by the same ``datagrams_to_send``, each tagged with its kind, and
    ``get_timer`` names the next of them."""
    p = Pair()
    plane = (p.rng.random((H, W, 3)) * 255).astype(np.uint8)
    enc = p.encoder.encode(Update(0, 0.0, Pose(), {"color": plane}, {}), force_idr=True)
    out = p.tx.packetize(enc, p.sconn.send, 1_000_000, 0, 0, 0, 0.0, {}, {})
    leave_ms = 29 * 0.137                             # 3.973 ms: its trip through seconds comes back a hair early
    assert leave_ms / 1000 * 1000 < leave_ms
    p.server.frame_sent(0, out, 0.0, 1_000_000, send_ms=leave_ms)
    assert p.server.datagrams_to_send(2.0) == [] and p.server.data_to_send(2.0) == []
    assert p.server.get_timer() == leave_ms
    at = p.server.get_timer() / 1000 * 1000               # the runner's clock counts in seconds
    assert p.server.data_to_send(at) == []               # its control frames: from exactly send_ms (not on the timer)
    assert p.server.data_to_send(leave_ms) == [d for _, d in out.control]
    sent = p.server.datagrams_to_send(at)
    assert [d.data for d in sent] == [d for _, _, d in out.datagrams]
    assert {(d.kind, d.stream) for d in sent} == {("rtp", "color")}
    sr_at = p.server.get_timer()
    assert 500.0 <= sr_at <= 1500.0                      # nothing else due: the first sender report (1 s +- 50 %)
    assert p.server.datagrams_to_send(leave_ms) == []    # and what was due has left: the deadline moved on
    seq = int.from_bytes(sent[1].data[2:4], "big")
    p.server.receive_datagram(serialize_rtcp([GenericNack(p.client.ssrc, p.tx.streams["color"].ssrc, (seq,))]), 20.0)
    assert [(d.kind, d.data) for d in p.server.datagrams_to_send(20.0)] == [("resend", sent[1].data)]
    assert [d.kind for d in p.server.datagrams_to_send(sr_at)] == ["rtcp"]
    assert isinstance(parse_rtcp(p.reports(1e9)[0])[0], SenderReport)


def test_the_client_core_owns_its_control_connection() -> None:
    """Issue 47: the client's one control Connection goes from its handshake to its session core.  Bytes in: a
    FrameMeta that came with the session data's last bytes is taken at ``start``, later ones as their bytes come
    (counted, a gap named, the scene epoch from the newest); Stats and Bye leave as events, the end of the stream as
    ``ControlClosed``.  Bytes out: what the driver sends, by ``data_to_send``, framed for the server's end."""
    from splitrender.codecs.meta import pack_meta
    from splitrender.pipeline import ClientHandshake, ControlClosed, ServerMessage, accept_hello
    from splitrender.protocol import Bye, Pose as PoseMessage, Stats
    from splitrender.protocol.framing import encode_frame

    hello = Hello(PROTOCOL_VERSION, "", ("video",), ("h264",), W, H, FPS)
    hs = ClientHandshake(hello.methods, display=(W, H))
    sconn = ServerConnection()
    sconn.receive_data(hs.hello(hello))
    assert sconn.next_event() == hello
    acc = accept_hello(hello, "sid", Opening("video", method_config("video", {}), CameraIntrinsics(W, H)),
                       [StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)], pack_meta({}), sconn,
                       ServerConfig(scene="minimal", max_session_bytes=1 << 20), ServerOptions(),
                       rng=np.random.default_rng(1))
    tx, encoder = acc.core.tx, StreamEncoder(acc.core.tx.specs)
    rng = np.random.default_rng(0)

    def frame(fid: int) -> bytes:
        plane = (rng.random((H, W, 3)) * 255).astype(np.uint8)
        enc = encoder.encode(Update(fid, fid / FPS, Pose(), {"color": plane}, {}), force_idr=fid == 0)
        out = tx.packetize(enc, sconn.send, 5_000_000 + fid * 33_333, fid * 3000, 0, fid, fid / FPS, {}, {})
        return b"".join(d for _, d in out.control)

    assert hs.receive_data(b"".join(acc.core.data_to_send(0.0)) + frame(0))
    core = hs.session(ClientOptions())
    assert core.conn is hs.conn and core.counters["frames_meta"] == 0 and core.scene_epoch_ms is None
    core.start(0.0)
    assert core.counters["frames_meta"] == 1 and core.counters["meta_first_id"] == 0
    assert core.scene_epoch_ms == pytest.approx(5000.0)
    frame(1)                                                        # never arrives
    two = frame(2)
    core.receive_data(two[:9], 60.0)                                # a partial frame waits for its bytes
    assert core.counters["frames_meta"] == 1
    core.receive_data(two[9:], 70.0)
    c = core.counters
    assert (c["frames_meta"], c["meta_gaps"], c["meta_first_id"], c["meta_last_id"]) == (2, 1, 0, 2)
    assert core.scene_epoch_ms == pytest.approx(5000.0 + 2 * 33.333 - 2000 / FPS)
    assert c["control_bytes_received"] == len(two)
    pose = PoseMessage(1, 7, (0.0, 1.0, 2.0), (0.0, 0.0, 0.0, 1.0))
    core.send(pose)
    assert core.data_to_send() == encode_frame(pose) and core.data_to_send() == b""
    core.receive_data(sconn.send(Stats({"x": 1})) + sconn.send(Bye("done")), 80.0)
    core.receive_data(b"", 90.0)
    events = list(iter(core.next_event, None))
    assert [type(e.message) for e in events if isinstance(e, ServerMessage)] == [Stats, Bye]
    assert isinstance(events[-1], ControlClosed) and events[-1].now_ms == 90.0


def test_the_server_core_takes_the_client_s_events_by_one_rule() -> None:
    """Issue 47: what the client says on the control connection is taken by one rule in the server core
    (``take_events``, the live server's): Stats are logged and the session goes on (None); a Bye, an Error or the end
    of the stream ends it, handed back.  The Hello is the client handshake's (``make_hello``) and the server's end
    reads it in process (``read_hello``), as the runner's."""
    from splitrender.codecs.meta import pack_meta
    from splitrender.pipeline import ClientHandshake, ControlClosed, accept_hello
    from splitrender.pipeline.session import read_hello
    from splitrender.protocol import Bye, Error, ErrorCode, Stats

    def session(seed: int) -> tuple[ClientSession, ServerSession]:
        hs = ClientHandshake(("video",), display=(W, H))
        hello = hs.make_hello(("h264", "hevc"), FPS)
        assert hello == Hello(PROTOCOL_VERSION, "", ("video",), ("h264", "hevc"), W, H, FPS)
        acc = accept_hello(hello, "sid", Opening("video", method_config("video", {}), CameraIntrinsics(W, H)),
                           [StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)], pack_meta({}),
                           read_hello(hs.hello(hello)), ServerConfig(scene="minimal"), ServerOptions(),
                           rng=np.random.default_rng(seed))
        assert hs.receive_data(b"".join(acc.core.data_to_send(0.0)))
        return hs.session(ClientOptions()), acc.core

    ends = []
    for seed, last in enumerate((Bye("done"), Error(ErrorCode.INTERNAL, "gone"), None)):
        client, server = session(seed)
        client.send(Stats({"x": 1}))
        server.receive_data(client.data_to_send())
        assert server.take_events("s", 10.0) is None
        if last is not None:
            client.send(last)
        server.receive_data(client.data_to_send() if last is not None else b"")
        ends.append(server.take_events("s", 20.0))
    assert ends[0] == Bye("done") and ends[1] == Error(ErrorCode.INTERNAL, "gone")
    assert isinstance(ends[2], ControlClosed) and ends[2].now_ms == 20.0


def test_sent_bytes_rates_the_last_second_of_frames() -> None:
    """The runner's per-stream wire bytes (``rows.SentBytes``): totals in the order the streams are named or first
    counted, and each display tick's ``kbps_<stream>`` over the frames of the last second, the session data left
    out."""
    from splitrender.pipeline.rows import SentBytes

    sent = SentBytes(["session", "meta", "color"])
    sent.add("session", 5000)
    sent.frame(0.0, {"meta": 100, "color": 1000})
    sent.frame(0.5, {"meta": 100, "color": 3000, "fec": 50})
    sent.add("probe", 10)
    assert sent.total == {"session": 5000, "meta": 200, "color": 4000, "fec": 50, "probe": 10}
    assert list(sent.total) == ["session", "meta", "color", "fec", "probe"]
    assert sent.kbps(0.9) == {"kbps_meta": 1.6, "kbps_color": 32.0, "kbps_fec": 0.4, "kbps_probe": 0.0}
    assert sent.kbps(1.0) == {"kbps_meta": 0.8, "kbps_color": 24.0, "kbps_fec": 0.4, "kbps_probe": 0.0}


def test_the_server_core_binds_its_client_s_rtcp_address() -> None:
    """The live server's address rule, in the core (issue 47): a malformed datagram binds nothing (``rtcp_bad``), the
    first that parses binds its source, and later ones from any other source are counted (``rtcp_foreign``) and
    dropped unparsed.  Virtual time passes no address and binds none."""
    p = Pair()
    rr = serialize_rtcp([ReceiverReport(p.client.ssrc, ())])
    a, b = ("10.0.0.1", 5000), ("10.0.0.2", 5000)
    p.server.receive_datagram(b"\x80\xc9\x00\x07junk", 1.0, a)
    assert p.server.peer is None and p.server.counters["rtcp_bad"] == 1
    p.server.receive_datagram(rr, 2.0, a)
    assert p.server.peer == a and p.server.counters["rtcp_received"] == 1
    p.server.receive_datagram(rr, 3.0, b)
    assert p.server.peer == a and p.server.counters["rtcp_received"] == 1 and p.server.counters["rtcp_foreign"] == 1
    p.server.receive_datagram(rr, 4.0, a)
    assert p.server.counters["rtcp_received"] == 2
    q = Pair()
    q.server.receive_datagram(rr, 1.0)
    q.server.receive_datagram(rr, 2.0)
    assert q.server.peer is None and q.server.counters["rtcp_received"] == 2 and q.server.counters["rtcp_foreign"] == 0


def test_until_an_update_shows_the_updates_that_show_nothing_wait_for_one_that_does() -> None:
    """The display rule of every client front door (issue 47: the live client held such updates back itself, the
    runner applied them at once): a frame released with nothing of it arrived is not handed to the driver while no
    update has been shown (the tick stays black, nothing to apply or render); it comes first, in frame order, with
    the first update that shows something.  Once one has been shown, every update comes at its turn."""
    p = Pair(jitter_timeout_ms=50.0, nack_max_tries=0)
    ctrl, _ = p.frame(0, 0.0)
    p.to_client(ctrl, [], 5.0)                       # frame 0's FrameMeta, none of its packets
    p.timer(510.0)                                   # given up (resolve_timeout_ms): released, everything missing
    assert p.client.counters["frames_partial"] == 1
    assert _due(p.client, 511.0) == [] and _due(p.client, 512.0) == [] and p.client.blank(False)
    p.server.request_keyframe(515.0)                 # (the lost frame was the IDR)
    ctrl, dgrams = p.frame(1, 520.0)
    p.to_client(ctrl, dgrams, 525.0)
    new = _due(p.client, 530.0)
    assert [(f.update.frame_id, bool(f.update.planes)) for f in new] == [(0, False), (1, True)]
    p.client.report_applied(new, [True, True])
    assert p.client.shown is new[1] and not p.client.blank(True)
    ctrl, _ = p.frame(2, 550.0)
    p.to_client(ctrl, [], 555.0)
    p.timer(1060.0)
    assert [f.update.frame_id for f in _due(p.client, 1061.0)] == [2]   # shown before: it comes at its turn


def test_a_display_tick_waits_for_the_server_clock_then_shows_black_until_an_update_shows() -> None:
    """``display_tick``, the display rule of every client driver (issue 47: the live client kept its own list of the
    ticks before the first frame): a live client's ticks are held while the server's scene clock is unknown and come
    out blank, in order, with the first tick after a FrameMeta; a tick with nothing shown and nothing to apply is
    blank; the ticks still held at the end come from ``held_ticks``.  Virtual time (``hold`` false) holds none."""
    p = Pair(jitter_timeout_ms=50.0, nack_max_tries=0)
    assert p.client.display_tick("a", 0.0) == ([], None) and p.client.display_tick("b", 16.0) == ([], None)
    assert p.client.display_tick("v", 16.0, hold=False) == (["a", "b", "v"], None)   # (held ones go with it)
    assert p.client.display_tick("c", 20.0) == ([], None)
    ctrl, _ = p.frame(0, 20.0)
    p.to_client(ctrl, [], 25.0)                      # frame 0's FrameMeta (the server's clock), none of its packets
    assert p.client.scene_epoch_ms is not None
    assert p.client.display_tick("d", 30.0) == (["c", "d"], None)
    p.timer(510.0)                                   # frame 0 given up, released with nothing: still black
    assert p.client.display_tick("e", 511.0) == (["e"], None)
    p.server.request_keyframe(515.0)
    ctrl, dgrams = p.frame(1, 520.0)
    p.to_client(ctrl, dgrams, 525.0)
    blanks, new = p.client.display_tick("f", 530.0)
    assert blanks == [] and new is not None and [f.update.frame_id for f in new] == [0, 1]
    q = Pair()
    q.client.display_tick("x", 0.0)
    assert q.client.held_ticks() == ["x"] and q.client.held_ticks() == []


def test_a_feedback_row_has_the_fixed_columns() -> None:
    """``feedback.csv``'s row, made once in ``pipeline.rows``: every column of FEEDBACK_COLUMNS but the timings the
    Feedback did not echo, an unknown timing left out, the lost frames per stream, "" for a frame no longer
    remembered."""
    from splitrender.pipeline.rows import FEEDBACK_COLUMNS, feedback_row
    from splitrender.protocol import Feedback

    fb = Feedback(7, 1_000, 2_000, 34_500, 3, 500, {"render": 9, "made_up": 1}, {"color": 7}, {"color": (5, 6)})
    row = feedback_row(fb, 100)
    assert row == {"frame_id": 7, "server_us": 100, "received_us": 1_000, "decoded_us": 2_000, "displayed_us": 34_500,
                   "pose_time_us": 500, "lost_packets": 3, "motion_to_photon_ms": 34.0, "lost_frames": "color:5,6",
                   "server_render_us": 9}
    assert set(row) <= set(FEEDBACK_COLUMNS) and feedback_row(fb, None)["server_us"] == ""


def test_every_client_front_door_writes_a_frame_row_s_shared_columns_one_way() -> None:
    """``frame_row``: the runner (scene seconds) and the live client (seconds from the display instant) give it
    times on their own clocks and get the same columns; a blank tick names update -1 with NaN ages, decode and client
    milliseconds, whatever the front door measured (the runner times its black frame, the live client nothing)."""
    from splitrender.pipeline.rows import frame_row

    row = frame_row(3, 0.1, 7, 2.0, 1.9, 1.85, 4.0, 2.5)
    assert row == {"frame": 3, "t_s": 0.1, "update_frame_id": 7, "update_age_ms": pytest.approx(100.0),
                   "motion_to_photon_ms": pytest.approx(150.0), "client_ms": 4.0, "decode_ms": 2.5}
    assert frame_row(3, 0.1, 7, 0.0, -0.1, -0.15, 4.0, 2.5) == pytest.approx(row)
    blank = frame_row(3, 0.1, None, 2.0, 1.9, 1.85, 4.0, 2.5)
    assert list(blank) == list(row) and blank["update_frame_id"] == -1
    assert all(math.isnan(blank[k]) for k in ("update_age_ms", "motion_to_photon_ms", "client_ms", "decode_ms"))


def test_a_live_clients_row_tells_each_stage_from_the_updates_timestamps() -> None:
    """``live_frame_row`` (issue 47: the live client's row with the shared ones in ``pipeline.rows``): the shared
    columns from the timestamps on the wall clock, and each stage: the update encoded at 1.010 s (server time 1.000,
    pose sampled 0.950), its metadata at 1.030, its planes at 1.040, decoded at 1.046, shown at 1.100 after 4 ms of
    apply and render."""
    from types import SimpleNamespace

    from splitrender.pipeline.rows import live_frame_row
    from splitrender.scene.pose import Pose as ScenePose

    fr = SimpleNamespace(env=SimpleNamespace(timing_us={"render": 6000, "encode": 3000, "encoded_at": 1_010_000}),
                         meta=SimpleNamespace(server_time_us=1_000_000, pose=SimpleNamespace(client_time_us=950_000),
                                              keyframe=True),
                         received_ms=1040.0, decoded_ms=1046.0, meta_ms=1030.0,
                         update=SimpleNamespace(frame_id=12, missing={"depth"}))
    row = live_frame_row(5, 7, 0.5, 3.25, ScenePose(), fr, 1_100_000, 4.0)
    assert row["update_frame_id"] == 12 and row["tick"] == 7 and row["scene_t_s"] == 3.25
    assert row["update_age_ms"] == pytest.approx(100.0) and row["motion_to_photon_ms"] == pytest.approx(150.0)
    assert (row["decode_ms"], row["client_ms"], row["server_render_ms"], row["server_encode_ms"]) == (6.0, 4.0, 6.0, 3.0)
    assert row["network_ms"] == pytest.approx(30.0) and row["meta_network_ms"] == pytest.approx(20.0)
    assert row["wait_display_ms"] == pytest.approx(50.0) and row["pose_uplink_age_ms"] == pytest.approx(50.0)
    assert (row["keyframe"], row["missing"], row["qw"]) == (1, "depth", 1.0)
    blank = live_frame_row(6, 8, 0.52, math.nan, ScenePose(), None, 1_120_000)
    assert blank["update_frame_id"] == -1 and math.isnan(blank["update_age_ms"]) and "network_ms" not in blank


def test_the_client_core_gives_what_arrived_over_the_last_second() -> None:
    """``ClientSession.received_kbps`` (the live client's ``kbps_*`` columns, from the core that counts the bytes in):
    each tick reads the bytes since the oldest tick of the last second over the time between (the first tick, with no
    tick before it, 0), and a second with nothing new reads 0."""
    p = Pair()
    for fid, t_ms in ((0, 0.0), (1, 500.0)):
        _, dgrams = p.frame(fid, t_ms)
        for d in dgrams:
            p.client.receive_datagram(d, t_ms)
        if fid == 0:
            w0 = p.client.rx.wire_bytes["color"]
            first = p.client.received_kbps(0.0)
            assert w0 > 0 and first == {"kbps_color": 0.0, "kbps_control": 0.0}
    w1 = p.client.rx.wire_bytes["color"]
    assert p.client.received_kbps(0.5)["kbps_color"] == pytest.approx((w1 - w0) * 8 / 0.5 / 1000)
    assert p.client.received_kbps(1.6)["kbps_color"] == 0.0


def test_the_server_core_owns_its_control_connection() -> None:
    """``accept_hello`` gives the core the handshake's ``ServerConnection`` (issue 47): the core frames its Welcome
    and its frames' FrameMeta on it, and reads the client's bytes with it (``receive_data``, ``next_event``),
    taking Pose, Feedback and KeyframeRequest by the core's rules (a Feedback's row for ``rows_to_write``) and giving
    the rest back in order as events, the connection's end last; a partial message waits for its rest and a request
    naming no stream is refused as before."""
    from splitrender.pipeline.session import ClientMessage, ControlClosed
    from splitrender.pipeline import accept_hello
    from splitrender.pipeline.wire import pack_meta
    from splitrender.protocol import Bye, Feedback, KeyframeRequest, MessageError, ServerConnection, Stats
    from splitrender.protocol import Pose as PoseMessage

    hello = Hello(PROTOCOL_VERSION, "", ("video",), ("h264",), W, H, FPS)
    cconn, sconn = ClientConnection(), ServerConnection()
    sconn.receive_data(cconn.send(hello))
    assert sconn.next_event() == hello
    acc = accept_hello(hello, "sid", Opening("video", method_config("video", {}), CameraIntrinsics(W, H)),
                       [StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)], pack_meta({}), sconn,
                       ServerConfig(scene="minimal", max_session_bytes=1 << 20), ServerOptions(),
                       rng=np.random.default_rng(1))
    core = acc.core
    assert core.conn is sconn
    cconn.receive_data(b"".join(acc.core.data_to_send(0.0)))
    while cconn.next_event() is not NEED_DATA:
        pass
    data = b"".join([cconn.send(PoseMessage(100_000, 1, (0.0, 1.6, 2.0), (0.0, 0.0, 0.0, 1.0))),
                     cconn.send(PoseMessage(50_000, 2, (0.0, 1.6, 2.0), (0.0, 0.0, 0.0, 1.0))),
                     cconn.send(Feedback(0, 1, 2, 3, 0)), cconn.send(KeyframeRequest("color", "loss")),
                     cconn.send(Stats({"fps": 30.0}))])

    def read(chunk: bytes, now: float) -> list[type]:
        core.receive_data(chunk)
        out = []
        while (ev := core.next_event(now)) is not None:
            out.append(type(ev.message) if isinstance(ev, ClientMessage) else type(ev))
            if isinstance(ev, ControlClosed):
                break
        return out

    assert read(data[:7], 0.0) == []
    assert read(data[7:], 10.0) == [Stats]
    assert [(k, r["frame_id"]) for k, r in core.rows_to_write()] == [("feedback", 0)] and core.rows_to_write() == []
    assert core.poses.counters() == {"poses_received": 1, "poses_stale": 1}
    assert (core.counters["feedback"], core.counters["keyframe_requests"]) == (1, 1)
    with pytest.raises(MessageError, match="KeyframeRequest.stream: unknown stream 'nope'"):
        read(cconn.send(KeyframeRequest("nope", "x")), 20.0)
    assert read(cconn.send(Bye("done")), 30.0) == [Bye]
    assert read(b"", 40.0) == [ControlClosed] and core.conn.state.name == "CLOSED"


def test_a_frame_back_from_the_render_worker_is_stamped_reported_and_rowed_once_for_both_live_doors() -> None:
    """Issue 47: ``frame_from_worker``, both live front doors' handling of a made frame.  On the RTP transport the
    FrameMeta carries the frame's server time (when it was ordered) and the worker's stages (render, encode, shared
    and when it was encoded: the time it came back), the core counts it, and the row has the update row's columns,
    the server time, the relighting and the worker round trip; on the WebRTC transport nothing is framed and the
    row has the same columns but the control channel's ``bytes_meta``."""
    from splitrender.pipeline.wire import parse_envelope
    from splitrender.protocol import FrameMeta
    from splitrender.scene.predict import make_predictor

    p = Pair()
    spec = p.tx.specs[0]
    rtp = ServerSession(p.tx, 60.0, ServerOptions(), rng=np.random.default_rng(3), predictor=make_predictor("cv"),
                        conn=p.sconn)
    page = ServerSession(ServerPipeline([spec]), 60.0, predictor=make_predictor("cv"), transport="webrtc")
    plane = (p.rng.random((H, W, 3)) * 255).astype(np.uint8)
    rows = {}
    for core, encoder in ((rtp, p.encoder), (page, StreamEncoder([spec]))):
        core.start(0.0)
        core.receive_pose(0.0, Pose(), 900_000, 7)
        order = core.order_frame(0, 0, 0.0, 1000.0)
        assert order is not None and order.keyframe is False
        enc = encoder.encode(Update(0, 0.0, Pose(), {"color": plane}, {}), force_idr=True)
        stages = {"shared_ms": 2.0, "produce_ms": 12.0, "gi_ms": 4.0, "encode_ms": enc.encode_ms, "frame_ms": 20.0,
                  "worker_rtt_ms": 0.5}
        out, row = core.frame_from_worker(order, enc, {"patches": 3.0}, stages, 1.5, 1600.0)
        assert core.counters["frames_sent"] == 1 and core.counters["keyframes"] == 1
        assert (row["frame_id"], row["keyframe"], row["server_us"], row["gi_ms"], row["worker_rtt_ms"]) == \
            (0, 1, 1_500_000, 4.0, 0.5)
        assert (row["server_ms"], row["shared_ms"]) == (12.0, 2.0) and row["bytes_color"] == out.wire_bytes["color"] > 0
        rows[core.transport] = (out, row, enc)
    out, row, enc = rows["rtp"]
    assert rtp.data_to_send(1600.0) == [d for _, d in out.control] and page.data_to_send(1600.0) == []
    p.cconn.receive_data(b"".join(d for _, d in out.control))
    meta = p.cconn.next_event()
    assert isinstance(meta, FrameMeta) and meta.server_time_us == 1_500_000 and meta.pose.client_time_us == 900_000
    env = parse_envelope(meta.method_meta, 1 << 20)
    assert env.timing_us == {"render": 12_000, "encode": int(enc.encode_ms * 1000), "encoded_at": 1_600_000,
                             "shared": 2000}
    assert env.srv == {"patches": 3.0} and row["bytes_meta"] == out.wire_bytes["meta"] > 0
    page_out, page_row, page_enc = rows["webrtc"]
    assert page_out.control == [] and page_out.datagrams == [] and page.datagrams_to_send(1e9) == []
    assert page_row["bytes_color"] == len(page_enc.video["color"].data)
    assert set(row) - set(page_row) == {"bytes_meta"} and set(page_row) <= set(row)


def test_display_frame_applies_the_ticks_updates_then_renders_or_shows_the_black_background() -> None:
    """Issue 47: the client half's side of a display tick, the one call of both client front doors: a half with
    nothing to draw gives the black background (every pixel a hole) without being rendered, a rejected update is
    reported as not applied and the half keeps what it had, and a half with content is rendered at the tick's pose
    and time."""
    from types import SimpleNamespace

    from splitrender.errors import RemoteProtocolError
    from splitrender.methods.base import ClientFrame
    from splitrender.pipeline import display_frame

    class Half:
        has_content = False
        rendered: list[tuple[object, float]] = []

        def apply(self, upd: object) -> None:
            if upd.frame_id == 1:  # type: ignore[attr-defined]
                raise RemoteProtocolError("update 1: bad")
            self.has_content = True

        def render(self, pose: object, t_s: float) -> ClientFrame:
            self.rendered.append((pose, t_s))
            return ClientFrame(np.full((3, 4, 3), 7, np.uint8))

    half = Half()
    rf = [SimpleNamespace(update=SimpleNamespace(frame_id=i)) for i in range(3)]
    frame, ok, apply_ms, render_ms = display_frame(half, [rf[1]], "pose", 0.5, (4, 3), "t")
    assert ok == [False] and half.rendered == [] and apply_ms >= 0 and render_ms >= 0
    assert frame.color.shape == (3, 4, 3) and not frame.color.any() and frame.holes is not None and frame.holes.all()
    frame, ok, _, _ = display_frame(half, [rf[0], rf[1], rf[2]], "pose", 0.75, (4, 3), "t")
    assert ok == [True, False, True] and half.rendered == [("pose", 0.75)] and (frame.color == 7).all()
