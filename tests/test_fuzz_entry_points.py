"""Bounded hypothesis fuzzing of every untrusted-input entry point (issue 32 item 6).

The same entry points, seeds and mutations as ``benchmarks/fuzz_decoders.py`` (seeds captured
from a short virtual-time session of every method, :mod:`fuzz_seeds`), a few examples each
so the file runs in about a minute; derandomised, so CI runs the same examples every time.
The rule is h11's: an input either decodes or raises the entry point's documented error
class (``RemoteProtocolError`` for peer input; the issue 16 decoders' own classes), and a
client half that refused an update still takes the next valid one and renders finite
pixels.  The long campaign is the benchmark: ``python benchmarks/fuzz_decoders.py``.
"""

from __future__ import annotations

import random
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import Phase, given, note, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import fuzz_decoders as fz  # noqa: E402

from splitrender.errors import RemoteProtocolError  # noqa: E402
from splitrender.protocol import RtpPacket, Welcome  # noqa: E402

METHODS = fz.METHODS
RENDER_EXAMPLES = {"probes": 6}
"""Examples of the entry points that render, per method (the default otherwise): probes draws the whole scene."""
FRAME_EXAMPLES = 15
NO_SHRINK = (Phase.explicit, Phase.reuse, Phase.generate)
"""Shrinking random draws buys little (the failing input is in the note) and costs a minute on a failing test."""


@pytest.fixture(scope="module")
def entry_points(renderer: Any) -> Any:
    """``get(name)``: the harness's entry point ``name`` (its group built once, seeds captured once with the
    session renderer); the client halves' own GL context is released after the module."""
    from splitrender.render.gl import make_current

    for m in METHODS:
        fz.method_seeds(m, renderer)
    built: dict[str, fz.EntryPoint] = {}

    def get(name: str) -> fz.EntryPoint:
        if name not in built:
            for ep in fz.build_entry_points((name,)):
                half = getattr(ep.run, "__self__", None)
                if isinstance(half, fz.ClientHalfFuzzer):
                    half.sequential = False   # the update to mutate is the seed's, whatever the half's state
                built.setdefault(ep.name, ep)
        return built[name]

    yield get
    built.clear()
    if fz._GL:
        fz.release_gl_garbage()
        fz._GL.pop().release()
    make_current(renderer.ctx)


def check(ep: fz.EntryPoint, rnd: random.Random, i: int) -> None:
    """One mutated input of ``ep``: it decodes or raises what ``ep`` documents (anything else fails the test)."""
    base = ep.seeds[i % len(ep.seeds)]
    data = ep.mutate(base, ep.seeds, rnd) if ep.mutate is not None else fz.mutate(base, ep.seeds, rnd)
    if ep.encode is not None:
        data = ep.encode(data, rnd)
    note(f"{ep.name}: {fz.show_input(ep, data)}")
    try:
        ep.run(data)
    except ep.expected:
        pass
    except fz.Unencodable:
        pass


def fuzz(ep: fz.EntryPoint, examples: int) -> None:
    """``examples`` derandomised hypothesis examples of :func:`check` (a seed index and the mutations' random draws),
    not shrunk."""

    @settings(max_examples=examples, deadline=None, derandomize=True, phases=NO_SHRINK)
    @given(rnd=st.randoms(use_true_random=False), i=st.integers(0, 1 << 16))
    def one(rnd: random.Random, i: int) -> None:
        check(ep, rnd, i)

    one()


# ----------------------------------------------------------------------------- client halves
@pytest.mark.parametrize("method", METHODS)
def test_session_data(entry_points: Any, method: str) -> None:
    """Session data as the client half receives it: refused with a ``RemoteProtocolError``, or accepted
    and then the session's valid updates apply (or are refused) and render finite pixels."""
    fuzz(entry_points(f"session.{method}"), RENDER_EXAMPLES.get(method, 25))


@pytest.mark.parametrize("method", METHODS)
def test_update(entry_points: Any, method: str) -> None:
    """A mutated update (envelope msgpack, decoded values, data payloads, planes) on a half that took the
    session's valid updates before it: refused with a ``RemoteProtocolError`` (then the valid update still
    applies and renders), or taken and rendered."""
    fuzz(entry_points(f"frame.{method}"), RENDER_EXAMPLES.get(method, FRAME_EXAMPLES))


# ----------------------------------------------------------------------------- client session core
@pytest.mark.parametrize("method", METHODS)
def test_client_control(entry_points: Any, method: str) -> None:
    """Control frames (DataChunk, FrameMeta; their bytes or their fields) into a ClientConnection and the client core."""
    fuzz(entry_points(f"client.control.{method}"), 40)


@pytest.mark.parametrize("method", METHODS)
def test_client_datagrams(entry_points: Any, method: str) -> None:
    """RTP, FEC and RTCP datagrams into the client core: malformed ones are counted, never raised."""
    fuzz(entry_points(f"client.datagrams.{method}"), 10 if method == "probes" else 30)


def test_client_welcome(entry_points: Any) -> None:
    """A Welcome and the session data after it, through the client's handshake core (``ClientHandshake``, which the
    live client and the runner drive).  The harness's find: the live client let get_method/make_config's
    ConfigError (unknown method, unknown config key, value out of range) and dict()/float()'s ValueError/TypeError
    (config not a map, fov_y_deg not a number) out; now each is the peer's EnvelopeError naming the field."""
    fuzz(entry_points("client.welcome"), 150)


@pytest.mark.parametrize("server_fps", [[30], "thirty", float("inf"), -30, True])
def test_welcome_server_fps_is_checked(entry_points: Any, server_fps: Any) -> None:
    from splitrender.pipeline import ClientOptions, ClientSession

    w = fz.method_seeds("video").welcome
    bad = Welcome(w.session_id, w.method, {**w.method_params, "server_fps": server_fps}, w.streams)
    with pytest.raises(RemoteProtocolError, match=r"Welcome.method_params.server_fps: expected a number in \(0, 1000\]"):
        ClientSession.from_welcome(bad, ClientOptions())


# ----------------------------------------------------------------------------- server session core
def test_server_control(entry_points: Any) -> None:
    """Client control frames into a ServerConnection and the server session core (poses into its predictor)."""
    fuzz(entry_points("server.control"), 120)


def test_server_rtcp(entry_points: Any) -> None:
    """Client RTCP into the server core, as bytes and as the live server routes it; NACKs answered from history."""
    fuzz(entry_points("server.rtcp"), 150)


def test_feedback_flood_keeps_server_state_bounded(entry_points: Any) -> None:
    """1,600 valid Feedback messages naming random streams: the core's retained memory levels off."""
    ep = entry_points("server.feedback_flood")
    rng = random.Random(32)
    n = 1600
    assert ep.start is not None and ep.finish is not None
    ep.start(n)
    for _ in range(n):
        try:
            ep.run(ep.mutate(b"", ep.seeds, rng))   # type: ignore[misc]
        except ep.expected:
            pass
    findings = ep.finish()
    assert not findings, findings[0].message


# ----------------------------------------------------------------------------- FEC
def test_fec_parse(entry_points: Any) -> None:
    fuzz(entry_points("fec.parse"), 200)


def test_fec_recover(entry_points: Any) -> None:
    """An FEC packet and its group but one (some with the protection cut short) into fec_recover."""
    fuzz(entry_points("fec.recover"), 150)


@pytest.mark.parametrize("codec", ["h264", "hevc"])
def test_jitter_fec(entry_points: Any, codec: str) -> None:
    """Media and FEC packets through a jitter buffer: nothing is raised."""
    fuzz(entry_points(f"jitter.fec.{codec}"), 100)


def test_fec_shorter_than_a_media_payload_is_the_peers_error() -> None:
    """The group's short packet lost, the FEC packet cut to cover it but not the long one: ``fec_recover``
    raises ``PayloadError`` and a jitter buffer counts the packet as bad; neither raises anything else."""
    from splitrender.protocol import JitterBuffer
    from splitrender.protocol.fec import fec_recover, parse_fec

    s = fz.method_seeds("video")
    d = next(x for x in s.welcome.streams if x.name == "color")
    media = {RtpPacket.parse(p).sequence_number: p for p in s.rtp["color"]}
    cases = 0
    for f in s.fec["color"]:
        fec = parse_fec(RtpPacket.parse(f).payload)
        group = [media.get(q) for q in fec.protected()]
        if len(group) < 2 or any(p is None for p in group):
            continue
        *others, short = group
        assert short is not None
        if len(short) >= min(len(p) for p in others if p is not None):   # the last of a frame is the short one
            continue
        prot = len(short) - 12   # covers the lost short packet, not the others
        pkt = RtpPacket.parse(f)
        p = pkt.payload
        cut = RtpPacket(pkt.payload_type, pkt.sequence_number, pkt.timestamp, pkt.ssrc,
                        p[:10] + prot.to_bytes(2, "big") + p[12:14] + p[14:14 + prot])
        have = {RtpPacket.parse(x).sequence_number: x for x in others if x is not None}
        with pytest.raises(RemoteProtocolError):
            fec_recover(parse_fec(cut.payload), d.ssrc, have.get)
        jb = JitterBuffer("h264")
        for x in others:
            assert x is not None
            jb.insert(RtpPacket.parse(x), 0.0)
        jb.insert_fec(cut, d.ssrc, 1.0)
        assert jb.fec_bad == 1
        cases += 1
    assert cases, "the captured session has no FEC group ending in a short packet"


# ----------------------------------------------------------------------------- issue 16 entry points
ISSUE16_EXAMPLES = {"video.h264": 10, "video.hevc": 10}


@pytest.mark.parametrize("name", fz.ISSUE16)
def test_issue16_entry_points(entry_points: Any, name: str) -> None:
    """The first campaign's decoders keep to their rule under the harness's mutations."""
    fuzz(entry_points(name), ISSUE16_EXAMPLES.get(name, 30))


ISSUE46 = {"twcc.parse": 400, "twcc.recorder": 200, "server.nack": 150, "webrtc.message": 300, "webrtc.session_request": 200,
           "webrtc.recording": 150, "webrtc.offer": 150}
"""Issue 46's entry points and their examples here (the campaign runs 100,000 each)."""


@pytest.mark.parametrize("name", sorted(ISSUE46))
def test_issue46_entry_points(entry_points: Any, name: str) -> None:
    """Transport-cc parsing at every size to past the MTU, the receiver's recorder at any sequence jumps, and NACK
    datagrams into the server core, the page's messages, request and recording bodies and offers through aiortc:
    each input parses or raises ``RemoteProtocolError``, holds no more than its bytes pay for, round-trips, and is
    answered within the retransmission caps."""
    fuzz(entry_points(name), ISSUE46[name])


def test_every_entry_point_is_fuzzed_here() -> None:
    """The harness's entry points are the ones this file tests (a new one needs a test here)."""
    names = {n for group, _ in fz.entry_point_groups() for n in group}
    tested = ({f"session.{m}" for m in METHODS} | {f"frame.{m}" for m in METHODS}
              | {f"client.control.{m}" for m in METHODS} | {f"client.datagrams.{m}" for m in METHODS}
              | {"client.welcome", "server.control", "server.rtcp", "server.feedback_flood", "fec.parse",
                 "fec.recover", "jitter.fec.h264", "jitter.fec.hevc"} | set(fz.ISSUE16) | set(ISSUE46))
    assert names == tested


def test_a_client_half_that_keeps_a_bad_update_is_caught(entry_points: Any) -> None:
    """The harness's follow-up check works: a half whose failed apply leaves it broken is a StateCorrupted."""
    from splitrender.methods.video.client import VideoClient

    fzr = fz.ClientHalfFuzzer(fz.method_seeds("video"))

    class Breaks(VideoClient):
        def apply(self, update: Any) -> None:
            if getattr(self, "_broken", False):
                raise RuntimeError("broken by the previous update")
            if update.meta.get("poison"):
                self._broken = True
                raise RemoteProtocolError("poison")
            super().apply(update)

    fzr.cls = Breaks
    op = fz.Op(("m", "poison"), True, "extra key")
    with pytest.raises(fz.StateCorrupted, match="broken by the previous update"):
        fzr.run_frame(fz.FrameCase(1, ops=(op,)))
