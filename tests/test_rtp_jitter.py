"""Jitter buffer: reordering, wraparound, marker completion, NACK list, timeout,
keyframe recovery, bounds."""

from __future__ import annotations

import random

from splitrender.protocol import JitterBuffer, RtpPacket, RtpPacketizer, join_annexb

SPS = bytes.fromhex("6742001f")
PPS = bytes.fromhex("68ce3c80")


def _au(kind: int, size: int, tag: int) -> bytes:
    nal = bytes([kind]) + bytes([tag + 1]) * size  # a NAL unit never ends in 0x00
    nals = [SPS, PPS, nal] if kind == 0x65 else [nal]
    return join_annexb(nals)


def _stream(n_frames: int, first_seq: int, idr_every: int = 1000, size: int = 2500) -> list[list[RtpPacket]]:
    pk = RtpPacketizer("h264", ssrc=1, payload_type=96, mtu=1000, first_sequence=first_seq)
    frames = []
    for i in range(n_frames):
        kind = 0x65 if i % idr_every == 0 else 0x41
        frames.append(pk.packetize(_au(kind, size, i), i * 3000))
    return frames


def test_in_order_marker_completion_without_waiting_for_next_frame() -> None:
    jb = JitterBuffer("h264")
    frames = _stream(3, 100)
    out = []
    for f in frames:
        for k, p in enumerate(f):
            got = jb.insert(p, 0.0)
            if k < len(f) - 1:
                assert got == []  # nothing before the marker packet
            out.extend(got)
        assert out[-1].timestamp == f[0].timestamp  # emitted at its own marker
    assert [a.timestamp for a in out] == [0, 3000, 6000]
    assert out[0].keyframe and not out[1].keyframe and not jb.needs_keyframe
    assert out[1].data == _au(0x41, 2500, 1)
    assert (out[0].first_seq, out[0].packet_count) == (100, len(frames[0]))


def test_reordering_across_sequence_wraparound() -> None:
    frames = _stream(6, 65530)
    pkts = [p for f in frames for p in f]
    assert any(p.sequence_number == 65535 for p in pkts) and any(p.sequence_number == 0 for p in pkts)
    rng = random.Random(7)
    # shuffle within windows of 5 packets (keeps the first packet first)
    shuffled = pkts[:1]
    rest = pkts[1:]
    for i in range(0, len(rest), 5):
        w = rest[i : i + 5]
        rng.shuffle(w)
        shuffled.extend(w)
    jb = JitterBuffer("h264")
    out = []
    for t, p in enumerate(shuffled):
        out.extend(jb.insert(p, float(t)))
    assert [a.timestamp for a in out] == [i * 3000 for i in range(6)]
    assert [a.data for a in out] == [_au(0x65 if i == 0 else 0x41, 2500, i) for i in range(6)]
    assert jb.missing() == [] and jb.frames_lost == 0


def test_one_packet_at_a_time_equals_any_permutation_within_frame() -> None:
    frames = _stream(3, 10)
    jb1, jb2 = JitterBuffer("h264"), JitterBuffer("h264")
    a = [au for f in frames for p in f for au in jb1.insert(p, 0.0)]
    b = [au for f in frames for p in [f[0], *reversed(f[1:])] for au in jb2.insert(p, 0.0)]
    assert [x.data for x in a] == [x.data for x in b]


def test_loss_gives_nack_list_and_retransmission_repairs() -> None:
    frames = _stream(3, 65534)
    jb = JitterBuffer("h264", frame_timeout_ms=100)
    lost = frames[1][1]
    out = []
    for f in frames:
        for p in f:
            if p is not lost:
                out.extend(jb.insert(p, 0.0))
    assert [a.timestamp for a in out] == [0]  # frame 2 waits behind the hole
    assert jb.missing() == [lost.sequence_number]
    out = jb.insert(lost, 50.0)  # retransmission
    assert [a.timestamp for a in out] == [3000, 6000]
    assert jb.missing() == [] and not jb.needs_keyframe


def test_timeout_needs_keyframe_until_idr() -> None:
    frames = _stream(6, 65000, idr_every=4)  # IDR at frames 0 and 4
    jb = JitterBuffer("h264", frame_timeout_ms=100)
    for p in frames[0]:
        jb.insert(p, 0.0)
    lost = frames[1][0]  # first packet of frame 1
    out = []
    for f in frames[1:4]:
        for p in f:
            if p is not lost:
                out.extend(jb.insert(p, 10.0))
    assert out == [] and jb.missing() == [lost.sequence_number]
    assert jb.poll(109.0) == [] and not jb.needs_keyframe
    assert jb.poll(110.0) == []  # frame 1 given up; frames 2, 3 are not keyframes: dropped
    assert jb.needs_keyframe and jb.frames_lost == 1 and jb.frames_dropped == 2
    assert jb.packets_lost == 1
    assert jb.insert(lost, 111.0) == [] and jb.packets_late == 1
    out = [au for p in frames[4] for au in jb.insert(p, 120.0)]
    assert [a.timestamp for a in out] == [4 * 3000] and out[0].keyframe
    assert not jb.needs_keyframe
    out = [au for p in frames[5] for au in jb.insert(p, 130.0)]
    assert [a.timestamp for a in out] == [5 * 3000]


def test_whole_frame_lost_resyncs_on_next_frame_boundary() -> None:
    frames = _stream(4, 500, idr_every=3)
    jb = JitterBuffer("h264", frame_timeout_ms=50, drop_until_keyframe=False)
    out = [au for p in frames[0] for au in jb.insert(p, 0.0)]
    for f in frames[2:]:  # frame 1 entirely lost
        for p in f:
            out.extend(jb.insert(p, 5.0))
    assert [a.timestamp for a in out] == [0]
    assert len(jb.missing()) == len(frames[1])
    out = jb.poll(60.0)
    # the buffer cannot know where frame 2 starts (its predecessor is missing), so it
    # drops it and resyncs on frame 3 (an IDR)
    assert [a.timestamp for a in out] == [9000]
    assert jb.frames_lost == 1 and not jb.needs_keyframe


def test_corrupt_frame_is_dropped_not_raised() -> None:
    jb = JitterBuffer("h264")
    good = _stream(1, 0)[0]
    out = [au for p in good for au in jb.insert(p, 0.0)]
    bad = RtpPacket(96, len(good), 3000, 1, b"\x7c\x05garbage", marker=True)  # FU-A without start
    assert jb.insert(bad, 1.0) == []
    assert jb.frames_corrupt == 1 and jb.needs_keyframe and len(out) == 1


def test_bounded_size_and_duplicates() -> None:
    jb = JitterBuffer("h264", max_packets=8, frame_timeout_ms=1e9)
    head = RtpPacket(96, 0, 0, 1, b"\x7c\x85\x01")  # FU-A start, frame not complete
    assert jb.insert(head, 0.0) == []
    assert jb.insert(head, 0.0) == [] and jb.packets_duplicate == 1
    # a hole at seq 1 followed by 20 packets of later frames: the buffer never exceeds 8
    for s in range(2, 22):
        jb.insert(RtpPacket(96, s, 3000 * s, 1, b"\x41\x00", marker=True), 1.0)
        assert len(jb) <= 8
    assert jb.frames_lost >= 1 and jb.needs_keyframe


def test_hevc_keyframe_detection() -> None:
    pk = RtpPacketizer("hevc", ssrc=1, payload_type=97, mtu=500)
    jb = JitterBuffer("hevc")
    irap = join_annexb([bytes.fromhex("40010c01"), bytes([21 << 1, 1]) + b"\x07" * 900])  # CRA
    out = [au for p in pk.packetize(irap, 0) for au in jb.insert(p, 0.0)]
    assert len(out) == 1 and out[0].keyframe and out[0].data == irap
    trail = join_annexb([bytes([1 << 1, 1]) + b"\x07" * 100])
    out = [au for p in pk.packetize(trail, 3000) for au in jb.insert(p, 1.0)]
    assert len(out) == 1 and not out[0].keyframe


def test_a_frame_larger_than_the_buffer_is_dropped_whole_and_the_next_one_kept() -> None:
    """A frame of 20 packets through a buffer of 8: it is given up on as one lost frame; the fragments that
    arrive after the give-up are skipped rather than depacketized as a frame of their own (which logged a
    corrupt "FU fragment without a start fragment" frame per oversized one), and the next keyframe comes out."""
    pk = RtpPacketizer("h264", ssrc=1, payload_type=96, mtu=300)
    jb = JitterBuffer("h264", max_packets=8, frame_timeout_ms=1e9)
    idr = join_annexb([b"\x67\x42\x00\x1e", b"\x68\xce\x3c\x80", b"\x65" + b"\x11" * 5000])
    big = pk.packetize(idr, 0)
    assert len(big) > 16
    out = [au for p in big for au in jb.insert(p, 0.0)]
    assert out == [] and jb.frames_lost == 1 and jb.frames_corrupt == 0
    nxt = [au for p in pk.packetize(join_annexb([b"\x65" + b"\x22" * 900]), 3000) for au in jb.insert(p, 1.0)]
    assert len(nxt) == 1 and nxt[0].timestamp == 3000 and nxt[0].keyframe
    assert jb.frames_corrupt == 0 and jb.frames_lost == 1 and len(jb) == 0


def test_a_large_frame_crossing_a_slow_link_is_waited_for_while_it_flows() -> None:
    """A 20 KB IDR at 0.6 Mbit/s takes about 270 ms to arrive, in order: the buffer waits while packets keep coming
    (it gave such a frame up 100 ms after its first packet, asked for a keyframe, and the next IDR met the same fate
    on every slow link).  Its tail lost for good, the frame is given up 100 ms after the last packet came."""
    frames = _stream(2, 500, idr_every=1, size=20_000)
    jb = JitterBuffer("h264", frame_timeout_ms=100)
    big = frames[0]
    spacing = 270.0 / len(big)
    out = []
    for k, p in enumerate(big):
        out += jb.poll(k * spacing) + jb.insert(p, k * spacing)
    assert [a.timestamp for a in out] == [0] and out[0].keyframe and jb.frames_lost == 0
    t0 = 400.0
    for k, p in enumerate(frames[1][:-1]):             # the marker packet never comes
        assert jb.insert(p, t0 + k * spacing) == []
    last = t0 + (len(frames[1]) - 2) * spacing
    assert jb.poll(last + 99.0) == [] and jb.frames_lost == 0
    jb.poll(last + 100.0)
    assert jb.frames_lost == 1
