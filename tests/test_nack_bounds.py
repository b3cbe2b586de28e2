"""The server core's answers to NACKs, bounded like libwebrtc's (issue 46, finding 2): a packet resent within an RTT
is not resent again, one RTCP datagram gets at most ``nack_max_per_datagram`` resends, and a stream's resent bytes
in any second stay within a share of its media bytes plus a floor.  Fed by hand with a hand-moved clock."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.codecs.video import VideoCodecConfig
from splitrender.errors import ConfigError
from splitrender.methods import StreamSpec
from splitrender.pipeline import ServerOptions, ServerPipeline, ServerSession
from splitrender.pipeline.sender import OutgoingFrame
from splitrender.options import (NACK_MAX_PER_DATAGRAM, NACK_MIN_RESEND_MS, NACK_RATE_FLOOR_BYTES,
                                          NACK_RATE_SHARE, NACK_RATE_WINDOW_MS)
from splitrender.protocol import GenericNack, RtpPacket, parse_rtcp, serialize_rtcp
from splitrender.protocol.errors import RtcpError

PAYLOAD = 1178
"""Payload bytes per media packet: 1,190 bytes on the wire with the 12-byte header."""
WIRE = PAYLOAD + 12
PER_FRAME = 14
FPS = 30
CLIENT = 0x1234


class Streaming:
    """A server core that has sent ``seconds`` of one video stream: ``FPS`` frames of ``PER_FRAME`` packets of
    ``WIRE`` bytes (4.0 Mbit/s), through :meth:`ServerSession.frame_sent` as a driver would."""

    def __init__(self, seconds: float = 2.0, **options: object) -> None:
        spec = StreamSpec("color", VideoCodecConfig("h264", gop=300), 64, 48)
        self.core = ServerSession(ServerPipeline([spec], mtu=1200, rng=np.random.default_rng(1)), 60.0,
                                  ServerOptions(**options), rng=np.random.default_rng(3))  # type: ignore[arg-type]
        self.core.start(0.0)
        self.ssrc = self.core.streams["color"].ssrc
        self.seq = 0
        self.frame = 0
        self.media: list[tuple[float, int]] = []
        while self.frame < seconds * FPS:
            self.send_frame()

    @property
    def now_ms(self) -> float:
        """The time of the next frame (ms)."""
        return self.frame * 1000 / FPS

    def send_frame(self) -> None:
        dgrams = []
        for _ in range(PER_FRAME):
            pkt = RtpPacket(96, self.seq & 0xFFFF, self.frame * 3000, self.ssrc, bytes(PAYLOAD))
            dgrams.append(("color", pkt, bytes(pkt)))
            self.seq += 1
        out = OutgoingFrame(self.frame, datagrams=dgrams, wire_bytes={"color": PER_FRAME * WIRE})
        self.core.frame_sent(self.frame, out, self.now_ms, 1000 + self.frame)
        self.media.append((self.now_ms, PER_FRAME * WIRE))
        self.frame += 1

    def answer(self, rtcp: bytes | list[GenericNack], now_ms: float) -> list[bytes]:
        """What the core resends at ``now_ms`` for ``rtcp`` (a datagram, or packets sent as one): the retransmissions
        among the datagrams it lets go, by its one way out (``datagrams_to_send``; no pacer here, so they leave at
        once)."""
        self.core.receive_datagram(rtcp if isinstance(rtcp, bytes) else serialize_rtcp(rtcp), now_ms)  # type: ignore[arg-type]
        return [d.data for d in self.core.datagrams_to_send(now_ms) if d.kind == "resend"]

    def last(self, n: int) -> tuple[int, ...]:
        """The sequence numbers of the last ``n`` packets sent."""
        return tuple(range(self.seq - n, self.seq))


def _nack(s: Streaming, seqs: tuple[int, ...]) -> GenericNack:
    return GenericNack(CLIENT, s.ssrc, seqs)


def test_the_bounds_are_the_documented_numbers() -> None:
    o = ServerOptions()
    assert (NACK_MIN_RESEND_MS, NACK_MAX_PER_DATAGRAM, NACK_RATE_WINDOW_MS, NACK_RATE_SHARE, NACK_RATE_FLOOR_BYTES) == \
        (20.0, 256, 1000.0, 0.5, 16_000)
    assert (o.nack_min_resend_ms, o.nack_max_per_datagram, o.nack_rate_share, o.nack_rate_floor_bytes) == \
        (20.0, 256, 0.5, 16_000)
    assert {"nack_duplicates", "nack_datagram_capped", "nack_rate_limited"} <= set(Streaming(0).core.counters)


def test_a_thousand_identical_nacks_in_one_datagram_resend_no_more_than_one_does() -> None:
    """Issue 46's datagram: 1,000 copies of a 44-byte NACK (8 FCIs, 136 sequence numbers) in 44,000 bytes.  It
    resent 128,000 packets (145 MiB); now exactly what one copy gets, the other 999 x 136 requests duplicates."""
    one, many = Streaming(), Streaming()
    nack = _nack(one, one.last(136))
    single = serialize_rtcp([nack])
    assert len(single) == 44
    got_one = one.answer(single, one.now_ms)
    got_many = many.answer(serialize_rtcp([nack] * 1000), many.now_ms)
    assert len(got_one) == 136 and got_many == got_one
    c = many.core.counters
    assert (c["nacks"], c["retransmitted"], c["retransmitted_bytes"]) == (1000, 136, 136 * WIRE)
    assert (c["nack_duplicates"], c["nack_datagram_capped"], c["nack_rate_limited"]) == (999 * 136, 0, 0)


def test_a_repeated_nack_waits_one_rtt_and_twenty_ms_while_the_rtt_is_unknown() -> None:
    s = Streaming()
    seq = s.last(1)
    t = s.now_ms
    assert s.core.rtt_ms is None
    assert len(s.answer([_nack(s, seq)], t)) == 1
    assert s.answer([_nack(s, seq)], t + 19.9) == []          # within the 20 ms floor
    assert s.core.counters["nack_duplicates"] == 1
    assert len(s.answer([_nack(s, seq)], t + 20.0)) == 1      # the floor has passed
    s.core.rtt_ms = 80.0                                                 # as a receiver report would set it
    assert s.answer([_nack(s, seq)], t + 20.0 + 79.9) == []
    assert len(s.answer([_nack(s, seq)], t + 20.0 + 80.0)) == 1
    s.core.rtt_ms = 5.0                                                  # a short RTT: the floor holds
    assert s.answer([_nack(s, seq)], t + 100.0 + 19.9) == []
    assert len(s.answer([_nack(s, seq)], t + 120.0)) == 1
    c = s.core.counters
    assert (c["retransmitted"], c["nack_duplicates"]) == (4, 3)


def test_a_sequence_number_sent_again_is_a_new_packet_with_no_hold() -> None:
    """The hold belongs to the stored packet: when a sequence number comes round again (65,536 packets later; here
    the counter is wound back) the new packet may be resent at once."""
    s = Streaming()
    seq = s.last(1)
    t = s.now_ms - 5
    old = s.answer([_nack(s, seq)], t)
    s.seq -= PER_FRAME
    s.send_frame()                                          # at t + 5: the last frame's numbers, new packets
    assert s.answer([_nack(s, seq)], t + 10) == [bytes(s.core.streams["color"].history.get(seq[0]))] != old
    assert s.answer([_nack(s, seq)], t + 11) == []
    assert (s.core.counters["retransmitted"], s.core.counters["nack_duplicates"]) == (2, 1)


def test_one_datagram_gets_at_most_256_resends_and_the_rest_is_refused_unread() -> None:
    s = Streaming(nack_rate_share=10.0)                     # the rate cap out of the way
    seqs = s.last(400)
    got = s.answer([_nack(s, seqs[:200]), _nack(s, seqs[200:]), _nack(s, seqs[:10])], s.now_ms)
    assert len(got) == 256 and [RtpPacket.parse(d).sequence_number for d in got] == list(seqs[:256])
    c = s.core.counters
    assert (c["retransmitted"], c["nack_datagram_capped"], c["nack_duplicates"]) == (256, 144 + 10, 0)
    # the next datagram has its own 256
    assert len(s.answer([_nack(s, seqs[256:])], s.now_ms + 1)) == 144


def test_the_per_datagram_cap_is_an_option() -> None:
    s = Streaming(nack_max_per_datagram=3)
    assert len(s.answer([_nack(s, s.last(5))], s.now_ms)) == 3
    assert s.core.counters["nack_datagram_capped"] == 2


def test_resent_bytes_in_any_second_stay_within_half_the_media_bytes_and_the_floor() -> None:
    """Streaming 4.0 Mbit/s (500 kB/s: a 16 kB frame every 33 ms) while a NACK every 10 ms asks for 20 of the last 400
    packets (about 2.4 MB/s of requests): in every 1 s window the resent bytes stay within 0.5 x the media bytes sent
    in it plus 16,000, and (once the window is full) within 21 packets of that bound."""
    s = Streaming(seconds=1.0)
    resent: list[tuple[float, int]] = []
    t = s.now_ms
    k = 0
    while t < 4000:
        while s.now_ms <= t:
            s.send_frame()
        want = tuple(range(s.seq - 400 + k, s.seq - 380 + k))   # 20 of the last 400 sent, each again 190 ms later
        k = (k + 20) % 380
        resent += [(t, len(d)) for d in s.answer([_nack(s, want)], t)]
        lo = t - NACK_RATE_WINDOW_MS
        media = sum(n for at, n in s.media if lo < at <= t)
        used = sum(n for at, n in resent if lo < at <= t)
        assert used <= 0.5 * media + 16_000, (t, used, media)
        if t >= 2000:
            assert used > 0.5 * media + 16_000 - WIRE - 20 * WIRE, (t, used, media)   # at most one NACK behind
        t += 10.0
    c = s.core.counters
    assert c["nack_rate_limited"] > 0 and c["retransmitted"] == len(resent)
    assert c["nack_duplicates"] == 0 and c["nack_datagram_capped"] == 0


def test_a_quiet_stream_still_gets_the_floor() -> None:
    """No media sent in the last second: 16,000 bytes, 13 packets of 1,190, and the rest refused."""
    s = Streaming(seconds=1.0)
    got = s.answer([_nack(s, s.last(20))], s.now_ms + 2000)
    assert len(got) == 16_000 // WIRE == 13
    assert s.core.counters["nack_rate_limited"] == 7


@pytest.mark.parametrize("field, value, message", [
    ("nack_min_resend_ms", -1.0, "server nack_min_resend_ms: must be in [0, 10000], got -1.0"),
    ("nack_max_per_datagram", 70_000, "server nack_max_per_datagram: must be in [0, 65536], got 70000"),
    ("nack_rate_share", 11.0, "server nack_rate_share: must be in [0, 10], got 11.0"),
    ("nack_rate_floor_bytes", -5, "server nack_rate_floor_bytes: must be in [0, 1073741824], got -5"),
])
def test_nonsense_bounds_are_config_errors(field: str, value: float, message: str) -> None:
    with pytest.raises(ConfigError) as e:
        ServerOptions(**{field: value})  # type: ignore[arg-type]
    assert str(e.value) == message


# ----------------------------------------------------------------------------- fuzz

_FUZZ_STREAM = Streaming(seconds=1.0)
_OTHER_SSRC = (_FUZZ_STREAM.ssrc + 1) & 0xFFFFFFFF


def _raw_nack(media: int, fcis: list[tuple[int, int]]) -> bytes:
    """An RTPFB generic NACK with these (PID, BLP) pairs, written by hand (no de-duplication by the encoder)."""
    body = struct.pack("!II", CLIENT, media) + b"".join(struct.pack("!HH", p, b) for p, b in fcis)
    return struct.pack("!BBH", 0x80 | 1, 205, len(body) // 4) + body


def _random_nacks(seed: int, count: int, max_fcis: int, copies: bool) -> bytes:
    """``count`` NACKs from a seeded generator (hypothesis draws the shape; the bytes of 300 NACKs are more than it
    likes to draw itself): mostly for the stream, some for another SSRC or any; PIDs mostly among the last 600
    packets sent; ``copies``: the first NACK ``count`` times, as in the issue."""
    rng = np.random.default_rng(seed)
    recent = _FUZZ_STREAM.seq
    out = []
    for _ in range(1 if copies else count):
        media = int(rng.choice([_FUZZ_STREAM.ssrc, _OTHER_SSRC, int(rng.integers(0, 1 << 32))], p=[0.7, 0.15, 0.15]))
        n = int(rng.integers(1, max_fcis + 1))
        pids = np.where(rng.random(n) < 0.8, rng.integers(recent - 600, recent + 40, n), rng.integers(0, 1 << 16, n))
        blps = rng.choice([0, 0xFFFF, int(rng.integers(0, 1 << 16))], n)
        out.append(_raw_nack(media, [(int(p) & 0xFFFF, int(b)) for p, b in zip(pids, blps)]))
    return out[0] * count if copies else b"".join(out)


_datagrams = st.lists(st.tuples(st.integers(0, 2**32 - 1), st.integers(1, 300), st.integers(1, 24), st.booleans(),
                                st.sampled_from([b""]) | st.binary(min_size=1, max_size=8), st.floats(0.0, 400.0)),
                      min_size=1, max_size=4)


@settings(max_examples=150, deadline=None)
@given(datagrams=_datagrams, share=st.sampled_from([0.5, 0.0, 2.0]), cap=st.sampled_from([256, 1, 40]))
def test_random_nack_datagrams_stay_within_the_caps(datagrams: list[tuple[int, int, int, bool, bytes, float]],
                                                     share: float, cap: int) -> None:
    """Compound datagrams of 1-300 NACKs (random SSRCs, PIDs and BLPs; up to 24 FCIs each; or copies of one; some
    with junk after them), a few in a row as the clock moves on: every answer stays within the datagram cap, every
    second's resent bytes within the share of the media and the floor, every packet resent at most once per 20 ms,
    and nothing escapes (``receive_datagram`` counts what does not parse as ``rtcp_bad``)."""
    s = Streaming(seconds=1.0, nack_rate_share=share, nack_max_per_datagram=cap)
    t = s.now_ms
    resent: list[tuple[float, int, int]] = []
    for seed, count, max_fcis, copies, tail, dt in datagrams:
        t += dt
        while s.now_ms <= t:
            s.send_frame()
        data = _random_nacks(seed, count, max_fcis, copies) + tail
        try:
            packets = parse_rtcp(data)
        except RtcpError:
            packets = None
        got = s.answer(data, t)
        if packets is None:
            assert got == []
            continue
        assert len(got) <= cap
        for d in got:
            p = RtpPacket.parse(d)
            assert p.ssrc == s.ssrc
            resent.append((t, p.sequence_number, len(d)))
        lo = t - NACK_RATE_WINDOW_MS
        media = sum(n for at, n in s.media if lo < at <= t)
        assert sum(n for at, _, n in resent if lo < at <= t) <= share * media + NACK_RATE_FLOOR_BYTES
    last: dict[int, float] = {}
    for at, seq, _ in resent:
        assert at - last.get(seq, -1e9) >= NACK_MIN_RESEND_MS, (seq, at, last.get(seq))
        last[seq] = at
    c = s.core.counters
    assert c["retransmitted"] == len(resent)
