"""Per-SSRC jitter buffer: reorder RTP packets, assemble access units, detect loss.

Behaviour (times are passed in, in ms):

* packets are keyed by extended sequence number (16-bit wraparound unwrapped);
* a frame is complete when every packet from its first one to the one with the marker
  bit (same RTP timestamp) is present; it is emitted at once, in sequence order; a
  frame's first packet is the one after the previous frame's last packet (or, before
  the first frame, the lowest sequence number received);
* :meth:`JitterBuffer.missing` lists holes between the next expected packet and the
  highest received one (for generic NACKs);
* if the head of the buffer cannot complete within ``frame_timeout_ms`` of its oldest
  packet's arrival while a packet is missing, or of its newest packet's while the head
  frame still arrives in order with no hole (a large frame crossing a slow link), or
  the buffer holds more than ``max_packets``, the broken frame is
  dropped, the buffer resynchronises on the next frame boundary it can see, and
  ``needs_keyframe`` is set; it is cleared by the next frame containing an IDR (H.264
  type 5) / IRAP (HEVC types 16..21) NAL unit.  While it is set, non-keyframes are
  dropped (``drop_until_keyframe``); ``needs_keyframe`` starts True;
* packets older than the last emitted frame are dropped as late; malformed payloads
  drop the frame (logged, counted) instead of raising, as one bad UDP datagram must
  not end a session;
* FEC packets (RFC 5109, :mod:`.fec`) go to :meth:`JitterBuffer.insert_fec`: when every
  packet of an FEC group but one is in, the missing one is rebuilt and inserted as if
  it had arrived (``fec_recovered``); malformed FEC packets are counted (``fec_bad``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from splitrender.protocol.annexb import Codec, contains_keyframe, join_annexb
from splitrender.protocol.data import data_depayload
from splitrender.protocol.errors import PayloadError
from splitrender.protocol.fec import FecPacket, fec_recover, parse_fec
from splitrender.protocol.h264 import h264_depayload
from splitrender.protocol.h265 import h265_depayload
from splitrender.protocol.rtp import RtpPacket, SequenceUnwrapper

__all__ = ["AccessUnit", "JitterBuffer"]

logger = logging.getLogger(__name__)

DEFAULT_MAX_PACKETS = 8192
"""About 10 MB of 1200-byte packets: a lossless 1280x720 atlas frame (tss, sas) runs past 2048."""
MAX_PENDING_FEC = 64
DEFAULT_FRAME_TIMEOUT_MS = 100.0
MAX_NACK_ITEMS = 256


@dataclass(frozen=True, slots=True)
class AccessUnit:
    """One complete, depacketized frame."""

    data: bytes
    """Annex-B bytes (4-byte start codes)."""
    timestamp: int
    """RTP timestamp (90 kHz)."""
    first_seq: int
    last_seq: int
    arrival_ms: float
    """Arrival time of the frame's first packet."""
    complete_ms: float
    """Arrival time of the packet that completed the frame."""
    keyframe: bool
    packet_count: int


class JitterBuffer:
    """Reordering buffer for one SSRC (sans-IO; call with arrival times in ms)."""

    def __init__(
        self,
        codec: Codec,
        max_packets: int = DEFAULT_MAX_PACKETS,
        frame_timeout_ms: float = DEFAULT_FRAME_TIMEOUT_MS,
        drop_until_keyframe: bool = True,
    ) -> None:
        if codec not in ("h264", "hevc", "data"):
            raise ValueError(f"unknown codec {codec!r}")
        self.codec: Codec = codec
        self._depayload = {"h264": h264_depayload, "hevc": h265_depayload, "data": data_depayload}[codec]
        self.max_packets = max_packets
        self.frame_timeout_ms = frame_timeout_ms
        self.drop_until_keyframe = drop_until_keyframe
        self._unwrap = SequenceUnwrapper()
        self._packets: dict[int, tuple[RtpPacket, float]] = {}
        self._next: int | None = None
        self._abandoned_ts: int | None = None
        """RTP timestamp of the frame last given up on: its later packets are dropped, not taken for a frame."""
        self.needs_keyframe = True
        """Decoder sync is lost (or not yet established): request a keyframe (PLI)."""
        self.frames_emitted = 0
        self.frames_dropped = 0
        """Complete frames dropped while waiting for a keyframe."""
        self.frames_lost = 0
        """Frames given up on (timeout or overflow)."""
        self.frames_corrupt = 0
        self.packets_late = 0
        self.packets_duplicate = 0
        self.packets_lost = 0
        """Sequence numbers skipped for good."""
        self.fec_packets = 0
        self.fec_recovered = 0
        self.fec_bad = 0
        self._fec: list[FecPacket] = []
        self._ssrc_fec = 0
        self.discarded: list[int] = []
        """RTP timestamps of frames given up on, found corrupt or dropped while waiting for a
        keyframe, oldest first (where the timestamp is known); the owner drains it."""

    def __len__(self) -> int:
        return len(self._packets)

    def insert(self, packet: RtpPacket, now_ms: float) -> list[AccessUnit]:
        """Add a packet that arrived at ``now_ms``; returns frames completed by it."""
        ext = self._unwrap.unwrap(packet.sequence_number)
        if self._next is not None and ext < self._next:
            self.packets_late += 1
            return self._process(now_ms)
        if ext in self._packets:
            self.packets_duplicate += 1
            return []
        if self._next is not None and ext - self._next >= self.max_packets:
            logger.info("sequence jump to %d: flushing %d packets", packet.sequence_number, len(self))
            self.packets_lost += ext - self._next - len(self._packets)
            self._packets.clear()
            self._next = None
            self._lose_sync()
        self._packets[ext] = (packet, now_ms)
        if self._fec:
            return self._process(now_ms) + self._try_fec(now_ms)
        return self._process(now_ms)

    def insert_fec(self, packet: RtpPacket, ssrc: int, now_ms: float) -> list[AccessUnit]:
        """An FEC packet protecting this buffer's stream (media SSRC ``ssrc``) arrived at ``now_ms``; returns
        frames completed by a packet it recovers."""
        self.fec_packets += 1
        try:
            fec = parse_fec(packet.payload)
        except PayloadError as exc:
            self.fec_bad += 1
            logger.info("dropping FEC packet %d: %s", packet.sequence_number, exc)
            return []
        self._ssrc_fec = ssrc
        self._fec.append(fec)
        if len(self._fec) > MAX_PENDING_FEC:
            del self._fec[0]
        return self._try_fec(now_ms)

    def _try_fec(self, now_ms: float) -> list[AccessUnit]:
        out: list[AccessUnit] = []
        keep: list[FecPacket] = []
        for fec in self._fec:
            exts = [self._unwrap.peek(s) for s in fec.protected()]
            if any(e is None for e in exts):
                keep.append(fec)                              # no media packet yet
                continue
            if self._next is not None and max(exts) < self._next:  # type: ignore[type-var]
                continue                                      # the group is done with
            missing = [e for e in exts if e not in self._packets and (self._next is None or e >= self._next)]  # type: ignore[operator]
            if len(missing) > 1:
                keep.append(fec)
                continue
            if not missing or any(e not in self._packets for e in exts if e != missing[0]):
                continue                                      # complete, or others already emitted
            try:
                pkt = fec_recover(fec, self._ssrc_fec, self._packet_bytes)
            except PayloadError as exc:
                self.fec_bad += 1
                logger.info("FEC recovery failed: %s", exc)
                continue
            except Exception:  # noqa: BLE001 - a peer's FEC packet is lost protection, never a failure of the stream
                self.fec_bad += 1
                logger.warning("FEC recovery failed unexpectedly; dropping the FEC packet", exc_info=True)
                continue
            if pkt is not None:
                self.fec_recovered += 1
                ext = self._unwrap.unwrap(pkt.sequence_number)
                self._packets[ext] = (pkt, now_ms)
                out += self._process(now_ms)
        self._fec = keep
        return out

    def _packet_bytes(self, seq: int) -> bytes | None:
        ext = self._unwrap.peek(seq)
        e = self._packets.get(ext) if ext is not None else None
        return bytes(e[0]) if e is not None else None

    def poll(self, now_ms: float) -> list[AccessUnit]:
        """Apply timeouts at ``now_ms``; returns frames released by giving up on others."""
        return self._process(now_ms)

    def missing(self) -> list[int]:
        """16-bit sequence numbers of holes to NACK (at most 256, newest kept)."""
        if self._next is None or not self._packets:
            return []
        hi = max(self._packets)
        holes = [s & 0xFFFF for s in range(max(self._next, hi - 4096), hi) if s not in self._packets]
        return holes[-MAX_NACK_ITEMS:]

    # ------------------------------------------------------------------ internals

    def _lose_sync(self) -> None:
        if not self.needs_keyframe:
            logger.info("decoder sync lost: keyframe needed")
        self.needs_keyframe = True

    def _frame_end(self, start: int) -> int | None:
        entry = self._packets.get(start)
        if entry is None:
            return None
        ts = entry[0].timestamp
        s = start
        while True:
            e = self._packets.get(s)
            if e is None:
                return None
            if e[0].timestamp != ts:
                return s - 1  # marker missing but the next frame has begun
            if e[0].marker:
                return s
            s += 1

    def _process(self, now_ms: float) -> list[AccessUnit]:
        out: list[AccessUnit] = []
        while self._packets:
            start = self._next if self._next is not None else min(self._packets)
            head = self._packets.get(start)
            if head is not None and self._abandoned_ts is not None and head[0].timestamp == self._abandoned_ts:
                # the tail of a frame given up on (one larger than max_packets, say): skipped, so that its middle
                # fragments are not read as a frame of their own
                del self._packets[start]
                self._next = start + 1
                continue
            end = self._frame_end(start)
            if end is not None:
                au = self._emit(start, end)
                if au is not None:
                    out.append(au)
                continue
            # a frame still arriving in order (no hole from its start to the newest packet: a large frame crossing
            # a slow link) is waited for while packets keep coming; a hole is given up on once its oldest packet
            # has waited frame_timeout_ms
            keys = self._packets.keys()
            arrivals = [t for _, t in self._packets.values()]
            flowing = head is not None and max(keys) - start + 1 == len(keys)
            waited = now_ms - (max(arrivals) if flowing else min(arrivals))
            if waited >= self.frame_timeout_ms or len(self._packets) > self.max_packets:
                self._give_up(start)
                continue
            break
        return out

    def _emit(self, start: int, end: int) -> AccessUnit | None:
        entries = [self._packets.pop(s) for s in range(start, end + 1)]
        self._next = end + 1
        try:
            nals = self._depayload([p.payload for p, _ in entries])
        except PayloadError as exc:
            logger.warning("dropping malformed frame at seq %d: %s", entries[0][0].sequence_number, exc)
            self.frames_corrupt += 1
            self._discard(entries[0][0].timestamp)
            self._lose_sync()
            return None
        key = True if self.codec == "data" else contains_keyframe(self.codec, nals)
        if key:
            if self.needs_keyframe:
                logger.info("keyframe received: decoder sync restored")
            self.needs_keyframe = False
        elif self.needs_keyframe and self.drop_until_keyframe:
            self.frames_dropped += 1
            self._discard(entries[0][0].timestamp)
            return None
        self.frames_emitted += 1
        first, last = entries[0], entries[-1]
        return AccessUnit(
            data=nals[0] if self.codec == "data" else join_annexb(nals),
            timestamp=first[0].timestamp,
            first_seq=first[0].sequence_number,
            last_seq=last[0].sequence_number,
            arrival_ms=first[1],
            complete_ms=max(t for _, t in entries),
            keyframe=key,
            packet_count=len(entries),
        )

    def _discard(self, timestamp: int) -> None:
        self.discarded.append(timestamp)
        if len(self.discarded) > 4 * MAX_NACK_ITEMS:
            del self.discarded[: len(self.discarded) - 4 * MAX_NACK_ITEMS]

    def _give_up(self, start: int) -> None:
        keys = sorted(self._packets)
        resync: int | None = None
        for r in keys:
            if r <= start:
                continue
            prev = self._packets.get(r - 1)
            cur = self._packets[r][0]
            if prev is not None and (prev[0].marker or prev[0].timestamp != cur.timestamp):
                resync = r
                break
        if resync is None:
            markers = [k for k in keys if self._packets[k][0].marker]
            resync = markers[0] + 1 if markers else keys[-1] + 1
        dropped = [k for k in keys if k < resync]
        for ts in dict.fromkeys(self._packets[k][0].timestamp for k in dropped):
            self._discard(ts)
        if dropped:
            self._abandoned_ts = self._packets[dropped[-1]][0].timestamp
        if len(self._packets) > self.max_packets and resync > keys[-1]:
            logger.warning("frame at seq %d is larger than the buffer's %d packets: dropped", start & 0xFFFF, self.max_packets)
        for k in dropped:
            del self._packets[k]
        lo = start if self._next is not None else keys[0]
        self.packets_lost += max(0, resync - lo - len(dropped))
        self.frames_lost += 1
        logger.info("giving up on frame at seq %d; resync at %d", lo & 0xFFFF, resync & 0xFFFF)
        self._next = resync
        self._lose_sync()
