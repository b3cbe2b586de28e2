"""The client's receive path for one session (sans-IO): reassemble, decode, release.

:class:`ClientPipeline` takes control messages (``FrameMeta``, ``DataChunk``) and RTP
datagrams with their arrival times and gives back, in frame order, one
:class:`ReceivedFrame` per server frame: a
:class:`~splitrender.methods.base.DecodedUpdate` holding the streams that arrived and
naming those that did not.  Decoding is a separate synchronous step
(:meth:`ClientPipeline.decode`) so the live client can run it on its decoder thread;
the virtual-time runner calls it inline.

When is a stream of a frame known to be missing?  When its jitter buffer gave the
frame up (lost packets, timeout) or dropped it while waiting for a keyframe, when its
decoder failed on it (the stream then waits for a keyframe), when a later frame of the
same stream came out first (RTP streams are delivered in order), or when
``resolve_timeout_ms`` passed since the frame's ``FrameMeta`` arrived.  Frames are
released in order once every stream they sent is present or known missing.
"""

from __future__ import annotations

import logging
from collections import OrderedDict, deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..codecs.resize import is_scaled, resize
from ..codecs.video import VideoDecoder
from ..errors import CodecError
from ..limits import DEFAULT_CLIENT_LIMITS, ClientLimits
from ..methods.base import DataStreamSpec, DecodedUpdate
from ..protocol import (AccessUnit, DataChunk, FrameMeta, JitterBuffer, Message, ReceiverStatistics, RtpError, RtpPacket,
                        StreamDescription)
from .feedback import FeedbackTracker
from .wire import SESSION_STREAM, Envelope, datagram_wire_bytes, EnvelopeError, SessionDataError, checksum, decompress_data, parse_envelope

log = logging.getLogger(__name__)

MAX_ORPHANS = 128
"""Decoded payloads kept while their FrameMeta has not arrived."""
DEFAULT_META_MAX_BYTES = 64 * 1024 * 1024


@dataclass
class RxStream:
    """One stream as the client receives it."""

    name: str
    kind: str
    """``video``, ``datagram`` or ``reliable``."""
    codec: str = ""
    ssrc: int = 0
    output_format: str = "rgb24"
    spec: DataStreamSpec | None = None
    jitter: JitterBuffer | None = None
    stats: ReceiverStatistics | None = None
    decoder: VideoDecoder | None = None
    size: tuple[int, int] | None = None
    """A video stream's (height, width) as the Welcome table declares it: a decoded frame of another size is
    counted (``frames_wrong_size``) and dropped like a decode error."""
    broken: bool = False
    """A decode failed: frames are skipped until a keyframe."""

    @property
    def needs_keyframe(self) -> bool:
        return self.kind == "video" and (self.broken or (self.jitter is not None and self.jitter.needs_keyframe))

    @property
    def wants_keyframe(self) -> bool:
        """Needs a keyframe and the stream is flowing: a frame was decoded, dropped for want
        of a keyframe (the first IDR was lost) or given up on.  Before any of these the
        first IDR may simply be on its way, and a request would only cost an extra one."""
        j = self.jitter
        return self.needs_keyframe and (self.broken or (j is not None and bool(j.frames_emitted or j.frames_dropped
                                                                              or j.frames_lost)))


@dataclass
class Work:
    """One complete RTP frame of a stream, waiting to be decoded."""

    stream: RxStream
    unit: AccessUnit
    received_ms: float


@dataclass
class _Pending:
    frame_id: int
    meta: FrameMeta
    env: Envelope
    meta_ms: float
    expect: set[str]
    planes: dict[str, np.ndarray] = field(default_factory=dict)
    data: dict[str, bytes] = field(default_factory=dict)
    missing: set[str] = field(default_factory=set)
    received_ms: float = 0.0
    decoded_ms: float = 0.0
    meta_nbytes: int = 0
    """What the frame's decoded metadata holds (arrays and byte strings), counted against ``max_pending_bytes``."""

    @property
    def nbytes(self) -> int:
        return (self.meta_nbytes + sum(len(d) for d in self.data.values())
                + sum(int(getattr(p, "nbytes", 0)) for p in self.planes.values()))

    @property
    def resolved(self) -> bool:
        return all(n in self.planes or n in self.data or n in self.missing for n in self.expect)


@dataclass
class ReceivedFrame:
    """One server frame, released in order: the update and when each part arrived (ms, driver clock)."""

    update: DecodedUpdate
    meta: FrameMeta
    env: Envelope
    meta_ms: float
    received_ms: float
    decoded_ms: float
    decode_ms: float = 0.0
    """The decoding time charged to the frame (ms): what the driver reported decoding took since the last frame was
    released (:meth:`~.session.ClientSession.on_decoded`; the virtual-time runner's measured cost)."""


def held_nbytes(obj: Any, depth: int = 0) -> int:
    """Bytes held by a decoded metadata value: its arrays and byte/text strings (containers as 64 bytes an item;
    the msgpack limits bound how many there are)."""
    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if isinstance(obj, (bytes, bytearray, str)):
        return len(obj)
    if depth < 64 and isinstance(obj, dict):
        return sum(64 + held_nbytes(k, depth + 1) + held_nbytes(v, depth + 1) for k, v in obj.items())
    if depth < 64 and isinstance(obj, (list, tuple)):
        return sum(64 + held_nbytes(v, depth + 1) for v in obj)
    return 32


class SessionAssembler:
    """Collects the session data (``DataChunk`` on stream ``session``) announced in ``Welcome``."""

    def __init__(self, total: int, crc: int | None, limit: int) -> None:
        if not isinstance(total, int) or total < 0:
            raise SessionDataError(f"Welcome.method_params.session_data_bytes: {total!r} is not a size")
        if total > limit:
            raise SessionDataError(f"session data of {total} bytes exceeds this client's limit of {limit} bytes "
                                   "(max_session_bytes)")
        self.total, self.crc = total, crc
        self._buf = bytearray()

    @property
    def done(self) -> bool:
        return len(self._buf) == self.total

    @property
    def received(self) -> int:
        """Bytes taken so far."""
        return len(self._buf)

    def add(self, msg: DataChunk) -> bool:
        """Take one chunk; True when the session data is complete."""
        if msg.stream != SESSION_STREAM or msg.total != self.total or msg.offset != len(self._buf):
            raise SessionDataError(f"DataChunk for {msg.stream!r} at offset {msg.offset} of {msg.total}: expected "
                                   f"session data at offset {len(self._buf)} of {self.total}")
        self._buf += msg.payload
        if self.done and self.crc is not None and checksum(bytes(self._buf)) != self.crc:
            raise SessionDataError("session data: CRC-32 mismatch")
        return self.done

    @property
    def blob(self) -> bytes:
        return bytes(self._buf)


def check_stream_limits(row: Any, limits: ClientLimits) -> None:
    """A stream of the Welcome table within what this client accepts; :class:`SessionDataError` naming the field and
    the limit otherwise."""
    if isinstance(row, DataStreamSpec):
        if row.max_bytes > limits.max_stream_bytes:
            raise SessionDataError(f"Welcome.method_params.streams[{row.name!r}].max_bytes: {row.max_bytes} bytes exceeds "
                                   f"this client's limit of {limits.max_stream_bytes} (max_stream_bytes)")
        return
    w, h = row.get("width", 0), row.get("height", 0)
    if not all(isinstance(v, int) and not isinstance(v, bool) and 0 < v <= 16384 for v in (w, h)):
        raise EnvelopeError(f"Welcome.method_params.streams[{row.get('name')!r}]: width/height {w!r}x{h!r} is not a "
                            "frame size")
    if w * h > limits.max_video_pixels:
        raise SessionDataError(f"Welcome.method_params.streams[{row.get('name')!r}]: {w}x{h} video exceeds this client's "
                               f"limit of {limits.max_video_pixels} pixels (max_video_pixels)")


def _rtp_newer(a: int | None, b: int) -> bool:
    """Whether RTP timestamp ``a`` is later than ``b`` (32-bit serial arithmetic; ``None`` is never later)."""
    return a is not None and a != b and ((a - b) & 0xFFFFFFFF) < 0x80000000


class ClientPipeline:
    """One session's receiving side; see the module docstring."""

    def __init__(self, descriptions: tuple[StreamDescription, ...], table: list[Any], jitter_timeout_ms: float = 300.0,
                 resolve_timeout_ms: float = 500.0, meta_max_bytes: int = DEFAULT_META_MAX_BYTES,
                 limits: ClientLimits = DEFAULT_CLIENT_LIMITS) -> None:
        self.limits = limits
        """What this client holds at most: pending frames (oldest given up beyond it), pending bytes, stream sizes."""
        self.jitter_timeout_ms = jitter_timeout_ms
        self.resolve_timeout_ms = resolve_timeout_ms
        self.meta_max_bytes = meta_max_bytes
        self.streams: dict[str, RxStream] = {}
        self.by_ssrc: dict[int, RxStream] = {}
        self.by_fec_ssrc: dict[int, tuple[RxStream, int]] = {}
        """FEC stream SSRC -> (the stream it protects, its payload type); each stream's jitter buffer counts the
        FEC packets it took and the packets they rebuilt (``fec_packets``, ``fec_recovered``, ``fec_bad``)."""
        by_desc = {d.name: d for d in descriptions}
        for row in table:
            check_stream_limits(row, limits)
            if isinstance(row, DataStreamSpec):
                rx = RxStream(row.name, row.delivery, spec=row)
            else:
                rx = RxStream(row["name"], "video", output_format=str(row.get("format", "rgb24")),
                              size=(row["height"], row["width"]))
            d = by_desc.get(rx.name)
            if rx.kind != "reliable":
                if d is None:
                    raise EnvelopeError(f"Welcome.streams: no RTP description for stream {rx.name!r}")
                if (rx.kind == "video") != (d.codec != "data"):
                    raise EnvelopeError(f"Welcome.streams[{rx.name!r}]: codec {d.codec} does not fit a {rx.kind} stream")
                rx.codec, rx.ssrc = d.codec, d.ssrc
                rx.jitter = JitterBuffer(d.codec, frame_timeout_ms=jitter_timeout_ms)
                rx.stats = ReceiverStatistics(d.ssrc)
                if rx.kind == "video":
                    rx.decoder = VideoDecoder(d.codec, rx.output_format)  # type: ignore[arg-type]
                self.by_ssrc[d.ssrc] = rx
                if d.fec_payload_type:
                    self.by_fec_ssrc[d.fec_ssrc] = (rx, d.fec_payload_type)
            self.streams[rx.name] = rx
        self._pending: OrderedDict[int, _Pending] = OrderedDict()
        self._orphans: OrderedDict[tuple[str, int], tuple[Any, float, float]] = OrderedDict()
        self._lost_ts: OrderedDict[tuple[str, int], None] = OrderedDict()
        self._chunks: dict[tuple[str, int], bytearray] = {}
        self._reliable: dict[int, dict[str, bytes]] = {}
        self._last_released = -1
        self._given_up: deque[tuple[ReceivedFrame, int]] = deque()
        """Frames given up for the frame-count bound, without their pictures but with their reliable data (and the
        bytes they hold), for :meth:`ready` to hand over first: a method's cumulative state (geometry, tables) stays
        whole.  They count toward ``max_pending_bytes`` and go first when it is exceeded."""
        self._newest_ts: dict[str, int] = {}
        """Per RTP stream, the RTP timestamp of the newest frame decoded (frames of a stream come out in order)."""
        self.wire_bytes: dict[str, int] = {}
        """Bytes received per RTP stream as they crossed the wire (IPv4 + UDP headers included)."""
        self.last_envelope: Envelope | None = None
        """The newest ``FrameMeta`` envelope parsed (the live client reads the server clock from it)."""
        self.tracker = FeedbackTracker()
        self.counters: dict[str, int] = {
            "frames_meta": 0, "frames_complete": 0, "frames_partial": 0, "frames_given_up": 0, "decode_errors": 0,
            "rtp_packets": 0, "rtp_bytes": 0, "udp_bad": 0, "meta_bytes": 0, "data_bytes": 0, "keyframes_received": 0,
            "data_errors": 0, "frames_wrong_size": 0,
        }

    # ------------------------------------------------------------------ input

    def on_message(self, msg: Message, now_ms: float) -> None:
        """A ``FrameMeta`` or ``DataChunk`` from the control channel; raises ``RemoteProtocolError`` on bad input."""
        if isinstance(msg, DataChunk):
            self._on_chunk(msg)
        elif isinstance(msg, FrameMeta):
            self._on_meta(msg, now_ms)

    def _on_chunk(self, msg: DataChunk) -> None:
        rx = self.streams.get(msg.stream)
        if rx is None or rx.kind != "reliable" or rx.spec is None:
            raise EnvelopeError(f"DataChunk.stream: {msg.stream!r} is not a reliable data stream of this session")
        if msg.total > rx.spec.max_bytes + 1024:
            raise EnvelopeError(f"DataChunk.total: {msg.total} bytes exceeds stream {msg.stream}'s max_bytes {rx.spec.max_bytes}")
        key = (msg.stream, msg.frame_id)
        buf = self._chunks.get(key)
        if buf is None:
            if msg.offset != 0:
                raise EnvelopeError(f"DataChunk {msg.stream}/{msg.frame_id}: first chunk at offset {msg.offset}, expected 0")
            if len(self._chunks) >= 64:
                raise EnvelopeError("DataChunk: more than 64 data payloads in flight")
            buf = self._chunks[key] = bytearray()
        elif msg.offset != len(buf):
            raise EnvelopeError(f"DataChunk {msg.stream}/{msg.frame_id}: chunk at offset {msg.offset}, expected {len(buf)}")
        buf += msg.payload
        if len(buf) < msg.total:
            self._check_held(f"DataChunk {msg.stream}/{msg.frame_id}")
            return
        del self._chunks[key]
        self.counters["data_bytes"] += len(buf)
        try:
            payload = decompress_data(rx.spec, bytes(buf))
        except CodecError as exc:
            raise EnvelopeError(f"DataChunk {msg.stream}/{msg.frame_id}: {exc}") from None
        self._reliable.setdefault(msg.frame_id, {})[msg.stream] = payload
        while len(self._reliable) > self.limits.max_pending_frames:
            del self._reliable[next(iter(self._reliable))]
        self._check_held(f"DataChunk {msg.stream}/{msg.frame_id}")

    def held_bytes(self) -> int:
        """Bytes held for frames not yet released: reliable payloads in flight and complete, and pending frames'
        metadata, data and decoded planes."""
        return (sum(len(b) for b in self._chunks.values())
                + sum(len(p) for d in self._reliable.values() for p in d.values())
                + sum(fr.nbytes for fr in self._pending.values()) + sum(n for _, n in self._given_up))

    def _check_held(self, what: str) -> None:
        """Keep :meth:`held_bytes` within ``max_pending_bytes``: give up the oldest frames (counted, reported
        lost) while that helps; the server's error, named, when what is left is still over."""
        limit = self.limits.max_pending_bytes
        held = self.held_bytes()
        while held > limit and (self._given_up or self._reliable or len(self._pending) > 1):
            if self._given_up:
                self._drop_given_up()
            elif self._reliable and (not self._pending or next(iter(self._reliable)) < next(iter(self._pending))):
                del self._reliable[next(iter(self._reliable))]
            else:
                _, old = self._pending.popitem(last=False)
                old.missing.update(n for n in old.expect if n not in old.planes and n not in old.data)
                self._release_forced(old)
            held = self.held_bytes()
        if held > limit:
            raise EnvelopeError(f"{what}: frames not yet complete hold {held} bytes, over this client's limit of "
                                f"{limit} bytes (max_pending_bytes)")

    def _on_meta(self, msg: FrameMeta, now_ms: float) -> None:
        self.counters["frames_meta"] += 1
        blob = msg.method_meta if isinstance(msg.method_meta, bytes) else b""
        self.counters["meta_bytes"] += len(blob)
        try:
            env = parse_envelope(blob, self.meta_max_bytes)
        except EnvelopeError as exc:
            raise EnvelopeError(f"FrameMeta {msg.frame_id}: {exc}") from None
        self.last_envelope = env
        for name in (*msg.rtp_timestamps, *env.reliable):
            rx = self.streams.get(name)
            if rx is None or (rx.kind == "reliable") != (name in env.reliable):
                raise EnvelopeError(f"FrameMeta {msg.frame_id}: stream {name!r} is not a {'reliable' if name in env.reliable else 'RTP'} "
                                    "stream of this session")
        if msg.frame_id <= self._last_released or msg.frame_id in self._pending:
            raise EnvelopeError(f"FrameMeta.frame_id: {msg.frame_id} is not newer than frame {self._last_released}")
        fr = _Pending(msg.frame_id, msg, env, now_ms, set(msg.rtp_timestamps) | set(env.reliable), received_ms=now_ms,
                      decoded_ms=now_ms, meta_nbytes=held_nbytes(env.meta))
        got = self._reliable.pop(msg.frame_id, {})
        for name in env.reliable:
            if name in got:
                fr.data[name] = got[name]
            else:
                fr.missing.add(name)
        self._pending[msg.frame_id] = fr
        for name, ts in msg.rtp_timestamps.items():
            if self._lost_ts.pop((name, ts), 0) is None:
                fr.missing.add(name)
            orphan = self._orphans.pop((name, ts), None)
            if orphan is not None:
                self._attach(fr, name, *orphan)
            elif _rtp_newer(self._newest_ts.get(name), ts):
                # a later frame of this stream was already decoded (this FrameMeta came late, behind a TCP
                # retransmission): the stream delivers in order, so this frame's part will not come
                fr.missing.add(name)
        while len(self._pending) > self.limits.max_pending_frames:
            _, old = self._pending.popitem(last=False)
            old.missing.update(n for n in old.expect if n not in old.planes and n not in old.data)
            self._release_forced(old)
        self._check_held(f"FrameMeta {msg.frame_id}")

    def on_datagram(self, data: bytes, now_ms: float) -> list[Work]:
        """An RTP datagram (RTCP is the driver's); returns frames ready to decode."""
        try:
            pkt = RtpPacket.parse(data)
        except RtpError:
            self.counters["udp_bad"] += 1
            return []
        rx = self.by_ssrc.get(pkt.ssrc)
        if rx is None and pkt.ssrc in self.by_fec_ssrc:
            frx, pt = self.by_fec_ssrc[pkt.ssrc]
            if pkt.payload_type != pt or frx.jitter is None:
                self.counters["udp_bad"] += 1
                return []
            self.wire_bytes[frx.name] = self.wire_bytes.get(frx.name, 0) + datagram_wire_bytes(len(data))
            return self._units(frx, frx.jitter.insert_fec(pkt, frx.ssrc, now_ms), now_ms)
        if rx is None or rx.jitter is None:
            self.counters["udp_bad"] += 1
            return []
        self.counters["rtp_packets"] += 1
        self.counters["rtp_bytes"] += len(data)
        self.wire_bytes[rx.name] = self.wire_bytes.get(rx.name, 0) + datagram_wire_bytes(len(data))
        assert rx.stats is not None
        rx.stats.receive(pkt, now_ms)
        return self._units(rx, rx.jitter.insert(pkt, now_ms), now_ms)

    def poll(self, now_ms: float) -> list[Work]:
        """Apply jitter-buffer and resolution timeouts at ``now_ms``."""
        out: list[Work] = []
        for rx in self.streams.values():
            if rx.jitter is not None:
                out += self._units(rx, rx.jitter.poll(now_ms), now_ms)
        for fr in self._pending.values():
            if not fr.resolved and now_ms - fr.meta_ms >= self.resolve_timeout_ms:
                fr.missing.update(n for n in fr.expect if n not in fr.planes and n not in fr.data)
        return out

    def _units(self, rx: RxStream, units: list[AccessUnit], now_ms: float) -> list[Work]:
        assert rx.jitter is not None
        for ts in rx.jitter.discarded:
            self._mark_lost(rx.name, ts)
        rx.jitter.discarded.clear()
        out = []
        for au in units:
            if rx.kind == "video":
                if au.keyframe:
                    self.counters["keyframes_received"] += 1
                    rx.broken = False
                elif rx.broken:
                    self._mark_lost(rx.name, au.timestamp)
                    continue
            out.append(Work(rx, au, now_ms))
        return out

    # ------------------------------------------------------------------ decode

    @staticmethod
    def decode(work: Work) -> Any:
        """Decode one frame of a stream (synchronous; the live client runs it on its decoder thread).

        Returns the plane (video) or bytes (data), or the :class:`CodecError` it raised.
        """
        rx = work.stream
        try:
            if rx.kind == "video":
                assert rx.decoder is not None
                plane = rx.decoder.decode(work.unit.data)
                if rx.size is not None and plane.ndim == 3 and plane.dtype == np.uint8 and plane.shape[:2] != rx.size:
                    # a colour stream the server sent at a lower resolution (--adapt full): back to the declared size
                    # (any other size is left as it is, for on_decoded to refuse by name)
                    if is_scaled(plane.shape[1], plane.shape[0], rx.size[1], rx.size[0]):
                        plane = resize(plane, rx.size[1], rx.size[0])
                return plane
            assert rx.spec is not None
            return decompress_data(rx.spec, work.unit.data)
        except CodecError as exc:
            return exc

    def on_decoded(self, work: Work, result: Any, now_ms: float) -> None:
        """Take the result of :meth:`decode` for ``work``."""
        rx, ts = work.stream, work.unit.timestamp
        if rx.size is not None and not isinstance(result, CodecError) and tuple(getattr(result, "shape", ())[:2]) != rx.size:
            self.counters["frames_wrong_size"] += 1
            result = CodecError(f"stream {rx.name}: decoded a {'x'.join(map(str, getattr(result, 'shape', ())[1::-1]))} "
                                f"frame, the session declared {rx.size[1]}x{rx.size[0]}")
        if isinstance(result, CodecError):
            if rx.kind == "video":
                self.counters["decode_errors"] += 1
                rx.broken = True
                log.info("stream %s: decode error, waiting for a keyframe: %s", rx.name, result)
            else:
                self.counters["data_errors"] += 1
                log.info("stream %s: bad data frame: %s", rx.name, result)
            self._mark_lost(rx.name, ts)
            return
        if not _rtp_newer(self._newest_ts.get(rx.name), ts):
            self._newest_ts[rx.name] = ts
        fr = self._frame_for(rx.name, ts)
        if fr is None:
            self._orphans[(rx.name, ts)] = (result, work.received_ms, now_ms)
            while len(self._orphans) > MAX_ORPHANS:
                self._orphans.popitem(last=False)
            return
        self._attach(fr, rx.name, result, work.unit.complete_ms, now_ms)
        # streams arrive in order: earlier frames still waiting for this stream lost it
        for other in self._pending.values():
            if other.frame_id >= fr.frame_id:
                break
            if rx.name in other.expect and rx.name not in other.planes and rx.name not in other.data:
                other.missing.add(rx.name)

    def _attach(self, fr: _Pending, name: str, payload: Any, received_ms: float, decoded_ms: float) -> None:
        if self.streams[name].kind == "video":
            fr.planes[name] = payload
        else:
            fr.data[name] = payload
        fr.missing.discard(name)
        fr.received_ms = max(fr.received_ms, received_ms)
        fr.decoded_ms = max(fr.decoded_ms, decoded_ms)

    def _frame_for(self, name: str, ts: int) -> _Pending | None:
        for fr in reversed(self._pending.values()):
            if fr.meta.rtp_timestamps.get(name) == ts:
                return fr
        return None

    def _mark_lost(self, name: str, ts: int) -> None:
        fr = self._frame_for(name, ts)
        if fr is None:
            self._lost_ts[(name, ts)] = None
            while len(self._lost_ts) > MAX_ORPHANS:
                self._lost_ts.popitem(last=False)
            return
        if name not in fr.planes and name not in fr.data:
            fr.missing.add(name)

    # ------------------------------------------------------------------ output

    def ready(self) -> list[ReceivedFrame]:
        """Frames whose every stream is present or known missing, in frame order (frames given up for the memory
        bounds first, as partial frames with their reliable data only)."""
        out = [rf for rf, _ in self._given_up]
        self._given_up.clear()
        while self._pending:
            fid, fr = next(iter(self._pending.items()))
            if not fr.resolved:
                break
            del self._pending[fid]
            out.append(self._release(fr))
        return out

    def _release_forced(self, fr: _Pending) -> None:
        """Give ``fr`` up for the memory bounds: its pictures go, its reliable data still reaches the half in order
        (a delta left out would put every later one out of step with the server; at most ``max_pending_frames``
        such frames wait for :meth:`ready`, the oldest dropped beyond)."""
        self.counters["frames_given_up"] += 1
        missing = set(fr.missing) | set(fr.planes)
        self.tracker.on_lost(fr.frame_id, sorted(missing))
        self._last_released = max(self._last_released, fr.frame_id)
        if fr.data:
            upd = DecodedUpdate(fr.frame_id, fr.env.t_s, fr.env.pose, {}, fr.env.meta, dict(fr.data), frozenset(missing))
            nbytes = fr.meta_nbytes + sum(len(d) for d in fr.data.values())
            self._given_up.append((ReceivedFrame(upd, fr.meta, fr.env, fr.meta_ms, fr.received_ms, fr.decoded_ms), nbytes))
            while len(self._given_up) > self.limits.max_pending_frames:
                self._drop_given_up()

    def _drop_given_up(self) -> None:
        self._given_up.popleft()
        self.counters["given_up_data_dropped"] = self.counters.get("given_up_data_dropped", 0) + 1

    def _release(self, fr: _Pending) -> ReceivedFrame:
        self._last_released = fr.frame_id
        missing = frozenset(fr.missing)
        if missing:
            self.counters["frames_partial"] += 1
            self.tracker.on_lost(fr.frame_id, sorted(missing))
        else:
            self.counters["frames_complete"] += 1
        upd = DecodedUpdate(fr.frame_id, fr.env.t_s, fr.env.pose, fr.planes, fr.env.meta, fr.data, missing)
        return ReceivedFrame(upd, fr.meta, fr.env, fr.meta_ms, fr.received_ms, fr.decoded_ms)

    def needs_keyframe(self) -> list[str]:
        """Video streams whose decoder waits for a keyframe."""
        return [rx.name for rx in self.streams.values() if rx.needs_keyframe]

    def wants_keyframe(self) -> list[str]:
        """Video streams to request a keyframe for now (see :attr:`RxStream.wants_keyframe`)."""
        return [rx.name for rx in self.streams.values() if rx.wants_keyframe]

    @property
    def pending_frames(self) -> int:
        return len(self._pending)

