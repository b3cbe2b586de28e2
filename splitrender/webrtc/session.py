"""One browser session: an aiortc peer connection fed by a method server half in a render worker.

Task layout: :meth:`BrowserSession.run` (the live session's, which the RTP front door's
:class:`splitrender.server.session.ServerSession` shares: :class:`~splitrender.pipeline.live.LiveSession`) owns the
frame clock (the server's shared frame grid) and ends the session
when the page says ``bye``, the peer connection fails or closes, the page breaks the
protocol, or the server closes.  Per frame the session's render worker renders and codes
the update (the same call the RTP front door makes); the colour access unit goes to the
video track (aiortc packetizes it, answers the browser's NACKs from its history and
forwards its PLIs here, where they become IDR requests), the frame's metadata to the
``frame`` data channel as JSON.

Data channels (the page creates them with its offer):

* ``meta``: reliable, ordered; server to page: ``origin`` (the sender's RTP timestamp
  origin), ``error`` and ``bye``;
* ``frame``: unordered, partially reliable (``maxPacketLifeTime``); server to page, one
  ``frame`` message per frame: frame id, RTP timestamp, scene time, the pose it was
  rendered for, and the page pose it was predicted from;
* ``pose``: unordered, unreliable; page to server: ``pose``, ``feedback`` and ``bye``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from typing import Any

from aiortc import RTCConfiguration, RTCPeerConnection

from ..errors import PeerTimeoutError, RemoteProtocolError, describe_error
from ..methods.base import PageGlue, get_method
from ..pipeline.live import LiveSession, MadeFrame
from ..pipeline.sender import rtp_timestamp
from ..pipeline.session import accept_page, open_page, page_terms
from ..transport.control import wall_ms
from .messages import PageFeedback, PageMessageError, PoseSample, SessionRequest, frame_message, parse_channel_message
from .sdp import check_offer, replace_candidates, udp_candidate_ports
from .track import EncodedVideoTrack, answer_offer, hook_sender_rtcp, sender_sent, try_offer

__all__ = ["BrowserSession", "BROWSER_CODEC_PARAMS", "answer_offer", "try_offer", "MAX_PAGE_ERRORS"]

logger = logging.getLogger(__name__)

BROWSER_CODEC_PARAMS = {"codec": "h264", "chroma": "420", "lossless": False}
"""What a browser session's method config is given over the server's: H.264 4:2:0 at the ``ultrafast`` preset
is Constrained Baseline, which every browser's WebRTC stack decodes (4:4:4 High and HEVC are not negotiated)."""
CONNECT_TIMEOUT_S = 30.0
"""A session whose page has not connected (ICE, DTLS, its data channels) and sent a pose by then ends."""
FRAME_LIFETIME_MS = 250
"""How long the ``frame`` channel retransmits a frame's metadata (the page asks for it; a later frame wins)."""
MAX_PAGE_ERRORS = 16
"""A page whose data channels carried this many messages the session refused (each counted in ``page_errors`` and
answered with an ``error`` naming what was wrong) has its session ended."""


class BrowserSession(LiveSession):
    """One page: its peer connection, method half (in a render worker), predictor and counters (the live session's
    life, frame clock and end: :class:`~splitrender.pipeline.live.LiveSession`)."""

    kind = "browser session"

    def __init__(self, front: Any, req: SessionRequest, ordinal: int) -> None:
        super().__init__(front.server, ordinal)
        self.front = front
        self.req = req
        self.remote = ""
        """The page's address, as the front door saw it (sessions per address are capped)."""
        self.method = req.method
        self.display_hz = req.display_hz
        self.pc: Any = None
        self.track: EncodedVideoTrack | None = None
        self.sender: Any = None
        self.relay: Any = None
        self.channels: dict[str, Any] = {}
        self.params: dict[str, Any] = {}
        self.stream = "color"
        """The method's video stream (``color``; ``atlas`` for ``sas``)."""
        self.page: PageGlue | None = None
        """The method's page glue (:attr:`~splitrender.methods.base.MethodSpec.page`: atw's overscan, sas's slots)."""
        self.started_at = time.time()
        self._origin_sent = False
        self._sender_sent: tuple[int, int] | None = None
        """(packets, bytes with their RTP headers) the RTP sender had sent at the last :meth:`read_sender_stats`."""
        self._counters.update({
            "nacks_received": 0, "nacked_packets": 0,
            "video_bytes": 0, "meta_bytes": 0, "page_errors": 0,
            "images_received": 0, "image_bytes_received": 0,
        })   # what this door alone counts; the core (aiortc owns the transport) counts frames, PLIs, REMBs, ...

    # ------------------------------------------------------------------ set-up

    async def open(self) -> dict[str, Any]:
        """Build the half, encoders and peer connection; returns the answer (SDP and the session's terms)."""
        check_offer(self.req.sdp)       # before a render worker is taken
        opening = open_page(self.method, self.req.width, self.req.height, self.cfg, BROWSER_CODEC_PARAMS)
        mcfg = opening.config
        specs, session_blob, _sets = await self._open_worker(opening)
        # aiortc owns packetizing and pacing; adaptation follows the page's REMB (track.hook_sender_rtcp), with the
        # method's knobs the page can follow
        self.core = accept_page(opening, specs, self.display_hz, self.cfg, session_blob)
        ref = specs[0]
        self.stream = ref.name
        self.page = get_method(self.method).page_class(mcfg, opening.intrinsics, session_blob)
        self.params = {"config": {k: v for k, v in vars(mcfg).items()}, "stream_width": ref.width,
                       "stream_height": ref.height}
        offer_sdp = self.req.sdp
        if self.front.network is not None:
            from ..netsim.relay import Relay

            host = self.front.ice_host
            self.relay = Relay(self.front.network, seed=self.ordinal)
            relay_listen, relay_inner, set_target = await self.relay.start_udp_unbound((host, 0))
            offer_sdp = replace_candidates(offer_sdp, *relay_inner)
        self.pc = pc = RTCPeerConnection(RTCConfiguration(iceServers=[]))
        pc.on("datachannel", self._on_datachannel)
        pc.on("connectionstatechange", self._on_state)
        self.track = EncodedVideoTrack()
        self.sender = await answer_offer(pc, offer_sdp, self.track)
        self.track.sender = self.sender
        hook_sender_rtcp(self.sender, self.core, self._counters)   # the page's PLIs, FIRs and REMBs into the core
        answer = pc.localDescription.sdp
        if self.relay is not None:
            ports = udp_candidate_ports(answer, self.front.ice_host)
            if not ports:
                raise RuntimeError(f"the answer has no UDP candidate on {self.front.ice_host}")
            set_target((self.front.ice_host, ports[0]))
            answer = replace_candidates(answer, *relay_listen)
        if "H264" not in answer:
            raise PageMessageError("the offer has no H.264 video the server can send (the page asks for H.264 "
                                   "Constrained Baseline, packetization-mode 1)")
        meta = page_terms(self.id, opening, ref, self.page, self.cfg, epoch_ms=self.server.epoch_wall_s * 1000,
                          server_ms=wall_ms(), frame_lifetime_ms=FRAME_LIFETIME_MS, recording=self.cfg.out_dir is not None)
        logger.info("browser session %s: %s %dx%d @ %g Hz%s", self.id, self.method, self.req.width, self.req.height,
                    self.display_hz, f" through a shaped path ({self.front.network_text})" if self.relay else "")
        return {"type": "answer", "sdp": answer, **meta}

    # ------------------------------------------------------------------ events

    def _on_state(self) -> None:
        state = self.pc.connectionState if self.pc is not None else "closed"
        logger.debug("browser session %s: connection %s", self.id, state)
        if state in ("failed", "closed"):
            self.end(f"peer connection {state}")

    def _on_datachannel(self, channel: Any) -> None:
        label = channel.label
        if label not in ("meta", "frame", "pose") or label in self.channels:
            self._page_error(f"unexpected data channel {label!r} (the page opens meta, frame and pose once each)")
            return
        self.channels[label] = channel
        if label == "pose":
            channel.on("message", self._on_message)

    def _on_message(self, text: Any) -> None:
        """A message on the ``pose`` channel.  Nothing raised here may reach aiortc: it would close the peer
        connection with no error counted or sent.  A refused message is counted, answered and dropped."""
        try:
            assert self.core is not None
            msg = parse_channel_message(text)
            if isinstance(msg, PoseSample):
                self.core.receive_pose_sample(msg)  # by the core's rule: a duplicate or reordered one counts as stale
            elif isinstance(msg, PageFeedback):
                self.core.receive_message(msg.feedback(self.stream), wall_ms())
                self._logs.write(self.core.rows_to_write())   # its feedback.csv row, as the RTP front door's
            else:
                self.end("the page said bye")
        except PageMessageError as exc:
            self._page_error(str(exc))
        except Exception as exc:  # noqa: BLE001 - our bug, but the page's session only
            logger.exception("browser session %s: a page message could not be handled", self.id)
            self._page_error(f"page message: could not be handled ({describe_error(exc)})"[:300])

    def _page_error(self, text: str) -> None:
        """A message the session refused: counted (``page_errors``), answered on ``meta`` with an ``error`` naming
        what was wrong, and dropped; the :data:`MAX_PAGE_ERRORS`-th ends the session."""
        self.count("page_errors")
        n = self._counters["page_errors"]
        if n <= 3 or n == MAX_PAGE_ERRORS:
            logger.warning("browser session %s: %s", self.id, text)
        self._send("meta", {"type": "error", "text": text})
        if n >= MAX_PAGE_ERRORS:
            self.end(f"page error: {n} messages refused, the last: {text}")

    def _send(self, label: str, obj: dict[str, Any] | bytes) -> int:
        """Send ``obj`` (JSON, or a method's own binary message) on channel ``label`` if it is open; its bytes."""
        ch = self.channels.get(label)
        if ch is None or ch.readyState != "open":
            return 0
        data = obj if isinstance(obj, bytes) else json.dumps(obj, separators=(",", ":"))
        ch.send(data)
        return len(data)

    # ------------------------------------------------------------------ running

    async def _send_error(self, exc: RemoteProtocolError | int, text: str = "") -> None:
        """An ``error`` to the page on ``meta``; the session ends with it."""
        text = str(exc) if isinstance(exc, RemoteProtocolError) else text
        self._send("meta", {"type": "error", "text": text})
        self.end(text)

    def _say_bye(self, reason: str) -> None:
        self.end(reason)
        self._send("meta", {"type": "bye", "reason": reason})

    async def read_sender_stats(self) -> None:
        """Take the RTP sender's packets and bytes sent so far (:func:`~.track.sender_sent`) into
        :meth:`server_counters` (``rtp_packets``, ``rtp_bytes``); where it can no longer be read the last reading stands."""
        if self.sender is not None:
            self._sender_sent = await sender_sent(self.sender) or self._sender_sent

    async def _teardown(self) -> None:
        """The session ends (its reason kept), the sender's last statistics are read, the peer connection and the
        relay closed."""
        self.end(self.end_reason or "closed")
        await self.read_sender_stats()
        if self.pc is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self.pc.close(), 5.0)
        if self.relay is not None:
            with contextlib.suppress(Exception):
                await self.relay.close()

    def server_counters(self) -> dict[str, Any]:
        """The session's counters: its core's (frames, keyframes, poses, feedback, PLIs, REMB estimates), its own,
        and the RTP sender's (packets and bytes sent), under the headless client's names where they count the same
        (``rtp_bytes``, ``meta_bytes``: the frames' metadata and the method's own messages), so that a recording's
        counters need no renaming."""
        out = super().server_counters()
        if self.track is not None:
            out["frames_dropped_sender"] = self.track.frames_dropped
        if self.page is not None:
            out.update(self.page.counters())
        if self._sender_sent is not None:
            out["rtp_packets"], out["rtp_bytes"] = self._sender_sent
        if self.relay is not None:
            st = self.relay.stats()
            out.update({"relay_down_in": st.downlink.packets_in, "relay_down_dropped": st.downlink.packets_dropped,
                        "relay_up_in": st.uplink.packets_in, "relay_up_dropped": st.uplink.packets_dropped})
        return out

    def _tick(self) -> tuple[bool, bool]:
        """A tick of the frame clock: a page that has not connected (its peer connection and ``frame`` channel) and
        sent a pose within :data:`CONNECT_TIMEOUT_S` ends the session; the core's rule then makes no frame before it
        has, nor while the sender has not taken the last frames yet (do not pile up)."""
        assert self.core is not None and self.track is not None
        ready = (self.pc.connectionState == "connected" and "frame" in self.channels
                 and self.channels["frame"].readyState == "open")
        if not self.frames_sent and time.time() - self.started_at > CONNECT_TIMEOUT_S and \
                not (ready and self.core.poses.latest is not None):
            raise PeerTimeoutError(f"the page did not connect and send a pose within {CONNECT_TIMEOUT_S:g} s "
                                   f"(connection {self.pc.connectionState}, channels {sorted(self.channels)})")
        return ready, self.track.queued >= 2

    async def _deliver(self, made: MadeFrame) -> None:
        core = self.core
        assert core is not None and self.track is not None
        if self.ended.is_set():
            return
        order, enc, _stats, stages, wall = made
        frame = enc.video[self.stream]
        rtp_ts = rtp_timestamp(order.t_s)
        if not self._origin_sent and self.track.rtp_origin is not None:
            self._origin_sent = bool(self._send("meta", {"type": "origin", "rtp_origin": self.track.rtp_origin}))
        if self.page is not None:    # the method's own messages first (sas: its patch slots), on the reliable channel
            self.count("meta_bytes", sum(self._send("meta", msg) for msg in self.page.frame(order.frame_id,
                                                                                             enc.update.meta)))
        n_meta = self._send("frame", frame_message(order, enc.update, frame.keyframe, rtp_ts, int(wall * 1e6),
                                                   self.track.rtp_origin))
        if not self.track.put(frame.data, rtp_ts):
            core.request_keyframe(wall_ms())     # the sender fell behind
        # the core counts the frame and its keyframe (aiortc packetizes it: nothing for an RTP history)
        _sent, row = core.frame_from_worker(*made, wall_ms())
        row["bytes_frame_meta"] = n_meta
        self.count("video_bytes", len(frame.data))
        self.count("meta_bytes", n_meta)
