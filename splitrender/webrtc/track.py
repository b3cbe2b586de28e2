"""The browser front door's adapters to aiortc: a video track that sends frames the session's own encoder coded,
the offer/answer, and the sender's RTCP into the session core (:func:`hook_sender_rtcp`).

aiortc packs an ``av.Packet`` a track returns as it is (RFC 6184, its own packetizer)
instead of encoding a frame, so the bytes the browser decodes are the method's encoder's,
exactly as the project's RTP front door sends them.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from fractions import Fraction
from typing import Any

from aiortc import RTCConfiguration, RTCPeerConnection, RTCSessionDescription
from aiortc.mediastreams import MediaStreamError, MediaStreamTrack
from aiortc.rtp import RtcpPsfbPacket, RtcpRtpfbPacket, unpack_remb_fci

from .messages import PageMessageError
from .sdp import check_offer, strip_candidates

__all__ = ["EncodedVideoTrack", "RTP_TIME_BASE", "answer_offer", "hook_sender_rtcp", "sender_sent", "try_offer"]

RTP_TIME_BASE = Fraction(1, 90_000)


class EncodedVideoTrack(MediaStreamTrack):
    """Annex-B access units in, ``av.Packet`` out; ``pts`` is the 90 kHz RTP timestamp (before the sender's
    random origin, which :attr:`rtp_origin` reports once the first frame has gone out)."""

    kind = "video"

    def __init__(self, max_queued: int = 4) -> None:
        super().__init__()
        self._queue: asyncio.Queue[Any] = asyncio.Queue()
        self.max_queued = max_queued
        self.sender: Any = None
        """The aiortc ``RTCRtpSender`` (set by the session), read for the timestamp origin."""
        self.rtp_origin: int | None = None
        """The sender's random RTP timestamp origin: what it adds to ``pts`` on the wire."""
        self._last_pts: int | None = None
        self.frames_sent = 0
        self.frames_dropped = 0

    @property
    def queued(self) -> int:
        return self._queue.qsize()

    def put(self, data: bytes, rtp_ts: int) -> bool:
        """Queue one access unit; False (and nothing queued) when the sender is ``max_queued`` behind."""
        if self._queue.qsize() >= self.max_queued:
            self.frames_dropped += 1
            return False
        import av

        pkt = av.Packet(data)
        pkt.pts = rtp_ts
        pkt.time_base = RTP_TIME_BASE
        self._queue.put_nowait(pkt)
        return True

    async def recv(self) -> Any:
        self._learn_origin()
        if self.readyState != "live":
            raise MediaStreamError
        pkt = await self._queue.get()
        if pkt is None:
            raise MediaStreamError
        self._last_pts = int(pkt.pts)
        self.frames_sent += 1
        return pkt

    def _learn_origin(self) -> None:
        """The previous frame has been sent whole when the sender asks for the next: its last RTP timestamp
        less the pts it was given is the sender's origin.  (aiortc keeps it private: ``__rtp_timestamp``.)"""
        if self.rtp_origin is not None or self._last_pts is None or self.sender is None:
            return
        wire = getattr(self.sender, "_RTCRtpSender__rtp_timestamp", None)
        if isinstance(wire, int):
            self.rtp_origin = (wire - self._last_pts) & 0xFFFFFFFF

    def stop(self) -> None:
        super().stop()
        self._queue.put_nowait(None)


async def answer_offer(pc: Any, offer_sdp: str, track: Any) -> Any:
    """Take the page's offer on ``pc`` (aiortc), add ``track`` and make the answer; returns the sender.  An offer
    aiortc fails on (it raises ``RuntimeError``, ``ValueError``, ``AttributeError`` ... for what :func:`check_offer`
    cannot foresee) is the page's error: :class:`PageMessageError` naming the SDP.  ``OSError`` (no socket for
    ICE) stays the server's."""
    try:
        await pc.setRemoteDescription(RTCSessionDescription(offer_sdp, "offer"))
        sender = pc.addTrack(track)
        await pc.setLocalDescription(await pc.createAnswer())
    except (OSError, asyncio.CancelledError):
        raise
    except Exception as exc:  # noqa: BLE001 - whatever aiortc raises on a peer's SDP
        raise PageMessageError(f"session request.sdp: not an offer this server can take "
                               f"({type(exc).__name__}: {exc})"[:300]) from None
    return sender


async def sender_sent(sender: Any) -> tuple[int, int] | None:
    """The RTP sender's packets and bytes sent so far, through aiortc's public ``getStats`` (its bytes are the
    payload's: 12 bytes of RTP header a packet are added, as the headless client counts what it receives); None where
    the transport is already torn down."""
    with contextlib.suppress(Exception):
        report = await sender.getStats()
        for st in report.values():
            if getattr(st, "type", "") == "outbound-rtp":
                return int(st.packetsSent), int(st.bytesSent) + 12 * int(st.packetsSent)
    return None


async def try_offer(sdp: str) -> str:
    """The answer the front door would give to an offer ``sdp`` (checked, then through aiortc), without a render
    worker; raises :class:`PageMessageError` naming what was wrong.  For tests and fuzzing of the offer path: the
    offer's candidates are stripped first, so ICE never sends a check to an address the offer names."""
    check_offer(sdp)
    sdp = strip_candidates(sdp)   # no remote candidate, so no connectivity check leaves this process, whatever a
    pc = RTCPeerConnection(RTCConfiguration(iceServers=[]))   # mutated offer names (fuzzing feeds it any address)
    try:
        await answer_offer(pc, sdp, EncodedVideoTrack())
        return str(pc.localDescription.sdp)
    finally:
        with contextlib.suppress(Exception):
            await asyncio.wait_for(pc.close(), 5.0)


def hook_sender_rtcp(sender: Any, core: Any, counters: dict[str, int]) -> None:
    """The one adapter from aiortc's sender to the session core (a :class:`~splitrender.pipeline.ServerSession` in
    its WebRTC profile): the page's PLIs and FIRs go to its ``receive_picture_loss`` (aiortc answers NACKs itself,
    from its own history, and they are only counted in ``counters``: ``nacks_received``, ``nacked_packets``; a PLI
    only sets a flag aiortc's encoder would read, and this track has none), its REMB estimates to its
    ``receive_estimate``, whose rate and operating-point controllers follow them (``--adapt``; aiortc negotiates
    ``goog-remb`` and ``abs-send-time``, so the browser estimates the path from arrivals and reports).

    The one private name it uses: aiortc (1.x) offers no public event for the RTCP feedback a sender receives, so
    this wraps its ``_handle_rtcp_packet``, and refuses to run, naming it, on an aiortc without one.  What the sender
    sent is read through the public ``getStats`` (:func:`sender_sent`)."""
    orig = getattr(sender, "_handle_rtcp_packet", None)
    if not callable(orig):
        raise RuntimeError("this aiortc's RTCRtpSender has no _handle_rtcp_packet: the browser session cannot "
                           "see the page's PLIs (splitrender was written against aiortc 1.x)")

    async def handle(packet: Any) -> None:
        now_ms = time.time() * 1000
        if isinstance(packet, RtcpRtpfbPacket) and packet.fmt == 1:      # generic NACK
            counters["nacks_received"] += 1
            counters["nacked_packets"] += len(packet.lost)
        elif isinstance(packet, RtcpPsfbPacket) and packet.fmt in (1, 4):   # PLI, FIR
            core.receive_picture_loss(now_ms)
        elif isinstance(packet, RtcpPsfbPacket) and packet.fmt == 15:       # REMB
            with contextlib.suppress(ValueError):                            # not a REMB: aiortc ignores it too
                core.receive_estimate(float(unpack_remb_fci(packet.fci)[0]), now_ms)
        await orig(packet)

    sender._handle_rtcp_packet = handle
