"""An aiortc video track that sends frames the session's own encoder coded.

aiortc packs an ``av.Packet`` a track returns as it is (RFC 6184, its own packetizer)
instead of encoding a frame, so the bytes the browser decodes are the method's encoder's,
exactly as the project's RTP front door sends them.
"""

from __future__ import annotations

import asyncio
from fractions import Fraction
from typing import Any

from aiortc.mediastreams import MediaStreamError, MediaStreamTrack

__all__ = ["EncodedVideoTrack", "RTP_TIME_BASE"]

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
