"""The sans-IO session cores alone, fed bytes and times by hand (the aioquic habit): NACK and
retransmission, PLI after a lost keyframe, stall detection, randomised RTCP intervals."""

from __future__ import annotations

import numpy as np
import pytest

from splitrender.codecs.video import VideoCodecConfig
from splitrender.errors import ConfigError
from splitrender.methods import StreamSpec, Update
from splitrender.pipeline import (ClientOptions, ClientPipeline, ClientSession, ServerOptions, ServerPipeline, ServerSession,
                                  Stalled, StallTimeout, specs_from_table)
from splitrender.protocol import (PROTOCOL_VERSION, ClientConnection, GenericNack, Hello, PictureLossIndication,
                                  ReceiverReport, SenderReport, ServerConnection, Welcome, parse_rtcp)
from splitrender.protocol.framing import NEED_DATA
from splitrender.scene.pose import Pose

W, H = 64, 48
FPS = 30.0


class Pair:
    """A server core and a client core over hand-moved bytes and time (no network, no clock)."""

    def __init__(self, **client_opts: object) -> None:
        spec = StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H)
        self.tx = ServerPipeline([spec], mtu=300, rng=np.random.default_rng(1))
        self.sconn, self.cconn = ServerConnection(), ClientConnection()
        self.sconn.receive_data(self.cconn.send(Hello(PROTOCOL_VERSION, "", ("x",), ("h264",), W, H, FPS)))
        self.sconn.next_event()
        self.cconn.receive_data(self.sconn.send(Welcome("s", "x", self.tx.welcome_params(b""),
                                                        self.tx.describe("127.0.0.1", 5000, "t"))))
        w = self.cconn.next_event()
        assert isinstance(w, Welcome)
        opts = ClientOptions(**client_opts)  # type: ignore[arg-type]
        rx = ClientPipeline(w.streams, specs_from_table(w.method_params["streams"]), opts.jitter_timeout_ms,
                            resolve_timeout_ms=opts.resolve_timeout_ms)
        self.client = ClientSession(rx, opts, FPS, rng=np.random.default_rng(2))
        self.server = ServerSession(self.tx, 60.0, ServerOptions(keyframe_min_interval_ms=100.0), rng=np.random.default_rng(3))
        self.client.start(0.0)
        self.server.start(0.0)
        self.rng = np.random.default_rng(4)

    def frame(self, fid: int, now_ms: float) -> tuple[list[bytes], list[bytes]]:
        """Server frame ``fid`` at ``now_ms``: (control frames, RTP datagrams)."""
        kf = self.server.keyframe_due(now_ms)
        plane = (self.rng.random((H, W, 3)) * 255).astype(np.uint8)
        enc = self.tx.encode(Update(fid, fid / FPS, Pose(), {"color": plane}, {}), force_idr=kf or fid == 0)
        out = self.tx.packetize(enc, self.sconn.send, 1_000_000 + fid, fid * 3000, 0, fid, fid / FPS, {}, {})
        self.server.frame_sent(fid, out, now_ms, 1_000_000 + fid)
        return [d for _, d in out.control], [d for _, _, d in out.datagrams]

    def to_client(self, control: list[bytes], datagrams: list[bytes], now_ms: float) -> None:
        for data in control:
            self.cconn.receive_data(data)
            while (ev := self.cconn.next_event()) is not NEED_DATA:
                self.client.receive_message(ev, now_ms)  # type: ignore[arg-type]
        for d in datagrams:
            self._decode(self.client.receive_datagram(d, now_ms), now_ms)
        self.client.collect(now_ms)

    def _decode(self, works: list, now_ms: float) -> None:  # type: ignore[type-arg]
        for w in works:
            self.client.on_decoded(w, ClientPipeline.decode(w), now_ms)

    def timer(self, now_ms: float) -> list[list]:  # type: ignore[type-arg]
        """Run the client's timer at ``now_ms``; the RTCP it sent, parsed."""
        self._decode(self.client.handle_timer(now_ms), now_ms)
        self.client.collect(now_ms)
        return [parse_rtcp(d) for d in self.client.datagrams_to_send()]


def _nacks(rtcp: list[list]) -> list[GenericNack]:  # type: ignore[type-arg]
    return [p for c in rtcp for p in c if isinstance(p, GenericNack)]


def test_a_lost_packet_is_nacked_once_after_the_delay_and_the_retransmission_completes_the_frame() -> None:
    p = Pair(nack_delay_ms=20.0, nack_retry_ms=120.0)
    p.timer(0.0)
    ctrl, dgrams = p.frame(0, 0.0)
    p.to_client(ctrl, dgrams, 5.0)
    assert [f.update.frame_id for f in p.client.display(6.0)] == [0]
    ctrl, dgrams = p.frame(1, 33.0)
    assert len(dgrams) >= 3
    lost = dgrams[1]
    p.to_client(ctrl, dgrams[:1] + dgrams[2:], 38.0)
    assert p.client.display(39.0) == []              # held: a packet of frame 1 is missing
    assert _nacks(p.timer(40.0)) == []               # the timer sees the hole at 40 ms
    assert _nacks(p.timer(50.0)) == []               # 10 ms later: too early
    nacks = _nacks(p.timer(60.0))                    # 20 ms: one NACK naming the lost sequence number
    assert len(nacks) == 1 and nacks[0].lost == (int.from_bytes(lost[2:4], "big"),)
    assert _nacks(p.timer(70.0)) == [] and _nacks(p.timer(170.0)) == []   # the retry waits 120 ms
    resend = p.server.receive_rtcp([nacks[0]], 80.0)
    assert resend == [lost] and p.server.counters["retransmitted"] == 1
    p.to_client([], resend, 95.0)
    shown = p.client.display(96.0)
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
    p.server.receive_rtcp(plis, 155.0)
    ctrl, dgrams = p.frame(2, 160.0)
    assert p.server.counters["plis"] == 1 and p.server.counters["keyframes"] == 2
    p.to_client(ctrl, dgrams, 165.0)
    shown = [f for f in p.client.display(170.0) if f.update.planes]
    assert [f.update.frame_id for f in shown] == [2]
    assert p.client.counters["keyframes_after_pli"] == 1


def test_a_stall_is_reported_after_stall_frames_intervals_and_asks_for_keyframes() -> None:
    p = Pair(stall_frames=6.0, stall_timeout_s=1.0, pli_interval_ms=100.0)
    ctrl, dgrams = p.frame(0, 0.0)
    p.to_client(ctrl, dgrams, 5.0)                   # the last frame arrives at 5 ms
    p.timer(100.0)
    assert p.client.take_events() == []
    stall_ms = 6.0 / FPS * 1000                      # 200 ms
    assert p.client.next_timer() == pytest.approx(5.0 + stall_ms)
    rtcp = p.timer(5.0 + stall_ms)
    (ev,) = p.client.take_events()
    assert isinstance(ev, Stalled) and ev.idle_ms == pytest.approx(stall_ms)
    assert any(isinstance(x, PictureLossIndication) for c in rtcp for x in c)
    assert p.client.counters["stalls"] == 1 and p.client.counters["stall_plis"] == 1
    p.timer(1004.0)
    assert p.client.take_events() == []
    p.timer(1006.0)
    assert any(isinstance(e, StallTimeout) for e in p.client.take_events())


def test_rtcp_report_intervals_are_randomised_around_their_mean() -> None:
    p = Pair(rr_interval_s=0.5)
    ctrl, dgrams = p.frame(0, 0.0)
    p.to_client(ctrl, dgrams, 5.0)
    rr_times, sr_times = [], []
    for t in np.arange(10.0, 60_000.0, 10.0):
        if any(isinstance(x, ReceiverReport) and x.reports for c in p.timer(float(t)) for x in c):
            rr_times.append(float(t))
        if p.server.handle_timer(float(t)):
            sr_times.append(float(t))
    for times, mean in ((rr_times, 500.0), (sr_times, 1000.0)):
        gaps = np.diff(times)
        assert len(set(gaps.round())) > 10, gaps[:20]                       # the interval varies
        assert gaps.min() >= 0.5 * mean - 10 and gaps.max() <= 1.5 * mean + 10, (gaps.min(), gaps.max())
        assert abs(gaps.mean() - mean) < 0.1 * mean, gaps.mean()
    sr = parse_rtcp(p.server.handle_timer(120_000.0)[0])
    assert isinstance(sr[0], SenderReport) and sr[0].packet_count == p.tx.streams["color"].packetizer.packets_sent  # type: ignore[union-attr]


def test_playout_delay_holds_each_update_until_its_turn() -> None:
    p = Pair(playout_delay_ms=100.0)
    for fid in range(3):
        ctrl, dgrams = p.frame(fid, fid * 33.0)
        p.to_client(ctrl, dgrams, fid * 33.0 + 5.0)
    # server times are 1_000_000 + fid µs on the protocol clock (offset 0): due 100 ms after
    assert p.client.display(1099.9) == []
    assert [f.update.frame_id for f in p.client.display(1100.001)] == [0, 1]
    assert [f.update.frame_id for f in p.client.display(1101.0)] == [2]


def test_bad_options_are_named() -> None:
    with pytest.raises(ConfigError, match="playout_delay_ms"):
        ClientOptions(playout_delay_ms=-1)
    with pytest.raises(ConfigError, match="nack_max_tries"):
        ClientOptions(nack_max_tries=1.5)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="history_packets"):
        ServerOptions(history_packets=0)
    from splitrender.sim.config import RunConfig

    with pytest.raises(ConfigError, match="run config client options: client nack_max_tries: must be in"):
        RunConfig(nack_tries=-1)
    with pytest.raises(ConfigError, match="playout_delay_ms: must be in \\[0, 2000\\], got 5000"):
        RunConfig.from_dict({"playout_delay_ms": 5000})


def test_a_welcome_without_a_stream_table_is_the_peers_error() -> None:
    from splitrender.errors import RemoteProtocolError
    from splitrender.protocol import Welcome

    with pytest.raises(RemoteProtocolError, match=r"Welcome.method_params.streams: expected a list"):
        ClientSession.from_welcome(Welcome("s", "video", {}, ()), ClientOptions())
