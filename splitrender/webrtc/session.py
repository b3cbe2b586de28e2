"""One browser session: an aiortc peer connection fed by a method server half in a render worker.

Task layout: :meth:`BrowserSession.run` owns the frame clock (the server's shared frame
grid, as :class:`splitrender.server.session.ServerSession` ticks) and ends the session
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
import secrets
import time
from pathlib import Path
from typing import Any

from aiortc import RTCConfiguration, RTCPeerConnection

from ..errors import describe_error
from ..methods.base import PageGlue, get_method
from ..pipeline.sender import rtp_timestamp
from ..pipeline.recording import SessionLogs
from ..pipeline.session import ServerSession, accept_page, open_page, page_terms
from ..transport.control import wall_ms
from .messages import PageFeedback, PageMessageError, PoseSample, SessionRequest, frame_message, parse_channel_message
from .sdp import check_offer, replace_candidates, udp_candidate_ports
from .track import EncodedVideoTrack, answer_offer, hook_sender_rtcp, try_offer

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


class BrowserSession:
    """One page: its peer connection, method half (in a render worker), predictor and counters."""

    def __init__(self, front: Any, req: SessionRequest, ordinal: int) -> None:
        self.front = front
        self.server = front.server
        self.cfg = self.server.config
        self.req = req
        self.ordinal = ordinal
        self.id = secrets.token_hex(6)
        self.remote = ""
        """The page's address, as the front door saw it (sessions per address are capped)."""
        self.method = req.method
        self.display_hz = req.display_hz
        self.core: ServerSession | None = None
        """The session core in its WebRTC profile (aiortc owns the transport): the page's poses, by the rule every
        front door keeps, its feedback, keyframes and frame orders."""
        self.pc: Any = None
        self.worker: Any = None
        self.track: EncodedVideoTrack | None = None
        self.sender: Any = None
        self.relay: Any = None
        self.channels: dict[str, Any] = {}
        self.params: dict[str, Any] = {}
        self.stream = "color"
        """The method's video stream (``color``; ``atlas`` for ``sas``)."""
        self.page: PageGlue | None = None
        """The method's page glue (:attr:`~splitrender.methods.base.MethodSpec.page`: atw's overscan, sas's slots)."""
        self.ended = asyncio.Event()
        self.end_reason = ""
        self.ended_at: float | None = None
        self.started_at = time.time()
        self._origin_sent = False
        self._logs = SessionLogs(self.out_dir)
        self._sender_sent: tuple[int, int] | None = None
        """(packets, bytes with their RTP headers) the RTP sender had sent at the last :meth:`read_sender_stats`."""
        self.counters: dict[str, int] = {
            "nacks_received": 0, "nacked_packets": 0,
            "video_bytes": 0, "meta_bytes": 0, "page_errors": 0, "render_timeouts": 0,
            "images_received": 0, "image_bytes_received": 0,
        }
        """What this front door alone counts; the core counts frames (those skipped too), keyframes, poses, feedback,
        PLIs and REMB estimates (:meth:`server_counters` has both)."""

    @property
    def out_dir(self) -> Path | None:
        return None if self.cfg.out_dir is None else Path(self.cfg.out_dir) / self.id

    # ------------------------------------------------------------------ set-up

    async def open(self) -> dict[str, Any]:
        """Build the half, encoders and peer connection; returns the answer (SDP and the session's terms)."""
        check_offer(self.req.sdp)       # before a render worker is taken
        opening = open_page(self.method, self.req.width, self.req.height, self.cfg, BROWSER_CODEC_PARAMS)
        mcfg = opening.config
        self.worker = await self.server.acquire_worker()
        specs, session_blob, _sets = await self.worker.call("open", self.id, opening, deadline_s=self.cfg.setup_deadline_s)
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
        hook_sender_rtcp(self.sender, self.core, self.counters)   # the page's PLIs, FIRs and REMBs into the core
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
        self.counters["page_errors"] += 1
        n = self.counters["page_errors"]
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

    def end(self, reason: str) -> None:
        if not self.ended.is_set():
            self.end_reason = reason
            self.ended_at = time.time()
            self.ended.set()

    # ------------------------------------------------------------------ running

    async def run(self) -> None:
        """Stream until the session ends; then close the peer connection and hand the worker back."""
        frames = asyncio.create_task(self._frame_loop(), name=f"browser-{self.id}-frames")
        ended = asyncio.create_task(self.ended.wait())
        try:
            done, _ = await asyncio.wait({frames, ended}, return_when=asyncio.FIRST_COMPLETED)
            if frames in done and frames.exception() is not None:
                err = frames.exception()
                logger.error("browser session %s: failed: %s", self.id, describe_error(err))
                self._send("meta", {"type": "error", "text": f"server error: {describe_error(err)}"})
                self.end(f"server error: {describe_error(err)}")
            for t in (frames, ended):
                t.cancel()
            await asyncio.gather(frames, ended, return_exceptions=True)
        except asyncio.CancelledError:
            self.end("server shutting down")
            self._send("meta", {"type": "bye", "reason": "server shutting down"})
            for t in (frames, ended):       # cancelled while waiting: the session's tasks go with it
                t.cancel()
            raise
        finally:
            await self.close()

    async def read_sender_stats(self) -> None:
        """Take the RTP sender's packets and bytes sent so far (aiortc's public ``getStats``: the payload, and 12 bytes
        of RTP header a packet) into :meth:`server_counters` (``rtp_packets``, ``rtp_bytes``: as the headless client
        counts what it receives)."""
        if self.sender is None:
            return
        with contextlib.suppress(Exception):     # a transport already torn down: the last reading stands
            report = await self.sender.getStats()
            for st in report.values():
                if getattr(st, "type", "") == "outbound-rtp":
                    self._sender_sent = (int(st.packetsSent), int(st.bytesSent) + 12 * int(st.packetsSent))

    async def close(self) -> None:
        self.end(self.end_reason or "closed")
        await self.read_sender_stats()
        if self.pc is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self.pc.close(), 5.0)
        if self.relay is not None:
            with contextlib.suppress(Exception):
                await self.relay.close()
        if self.worker is not None:
            worker, self.worker = self.worker, None
            await self.server.release_worker(worker, self.id)
        self._logs.write(self.core.rows_to_write() if self.core is not None else ())
        self._logs.close(self.server_counters())
        logger.info("browser session %s: closed (%s): %s", self.id, self.end_reason,
                    ", ".join(f"{k}={v}" for k, v in self.server_counters().items() if v))

    @property
    def frames_sent(self) -> int:
        return self.core.counters["frames_sent"] if self.core is not None else 0

    def server_counters(self) -> dict[str, Any]:
        """The session's counters: its core's (frames, keyframes, poses, feedback, PLIs, REMB estimates), its own,
        and the RTP sender's (packets and bytes sent), under the headless client's names where they count the same
        (``rtp_bytes``, ``meta_bytes``: the frames' metadata and the method's own messages), so that a recording's
        counters need no renaming."""
        core = self.core.all_counters() if self.core is not None else {}
        out: dict[str, Any] = dict(core, **self.counters, method=self.method)
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

    async def _frame_loop(self) -> None:
        core, track = self.core, self.track
        assert core is not None and track is not None
        async for skipped in self.server.frame_ticks():
            wall = time.time()
            ready = (self.pc.connectionState == "connected" and "frame" in self.channels
                     and self.channels["frame"].readyState == "open")
            if not self.frames_sent and wall - self.started_at > CONNECT_TIMEOUT_S and \
                    not (ready and core.poses.latest is not None):
                raise TimeoutError(f"the page did not connect and send a pose within {CONNECT_TIMEOUT_S:g} s "
                                   f"(connection {self.pc.connectionState}, channels {sorted(self.channels)})")
            # the core's rule; the backlog: the sender has not taken the last frames yet (do not pile up)
            if core.live_tick(skipped, ready, backlog=track.queued >= 2):
                await self._send_frame()

    async def _send_frame(self) -> None:
        core = self.core
        assert core is not None and self.track is not None
        made = await self.worker.frame(self.id, core, self.server, self.counters)
        if made is None or self.ended.is_set():
            return
        order, enc, _stats, stages, wall = made
        frame = enc.video[self.stream]
        rtp_ts = rtp_timestamp(order.t_s)
        if not self._origin_sent and self.track.rtp_origin is not None:
            self._origin_sent = bool(self._send("meta", {"type": "origin", "rtp_origin": self.track.rtp_origin}))
        if self.page is not None:    # the method's own messages first (sas: its patch slots), on the reliable channel
            self.counters["meta_bytes"] += sum(self._send("meta", msg) for msg in self.page.frame(order.frame_id,
                                                                                                    enc.update.meta))
        n_meta = self._send("frame", frame_message(order, enc.update, frame.keyframe, rtp_ts, int(wall * 1e6),
                                                   self.track.rtp_origin))
        if not self.track.put(frame.data, rtp_ts):
            core.request_keyframe(wall_ms())     # the sender fell behind
        # the core counts the frame and its keyframe (aiortc packetizes it: nothing for an RTP history)
        _sent, row = core.frame_from_worker(*made, wall_ms())
        row["bytes_frame_meta"] = n_meta
        self._logs.write(core.rows_to_write())
        self.counters["video_bytes"] += len(frame.data)
        self.counters["meta_bytes"] += n_meta
