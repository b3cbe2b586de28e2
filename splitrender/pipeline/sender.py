"""The server's transmission path for one session (sans-IO): encode, packetize, count.

Two halves, which every session holds one of each of (the live server in two processes):

1. :class:`StreamEncoder` (heavy; beside the method's server half in :class:`~.frames.FrameMaker`, which the live
   server runs in the session's render worker): every video plane through the stream's real encoder, every data
   payload through its compression;
2. :class:`ServerPipeline` (light; the session core's): reliable data as ``DataChunk`` messages, then the
   ``FrameMeta`` with the update envelope, framed by the session's control
   :class:`~splitrender.protocol.Connection`; video and datagram data as RTP packets.  Every byte is counted per
   stream as it will cross the wire (:mod:`.wire`).  It holds no encoder: the encoders' parameter sets, for the
   SDP, are named to it (:attr:`ServerPipeline.described_sets`).

The drivers only move the bytes: the live session writes them to its sockets, the
virtual-time runner delays them through the network model.
"""

from __future__ import annotations

import dataclasses
import logging
import secrets
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from ..codecs.resize import resize, scaled_size
from ..codecs.video import EncodedFrame, VideoEncoder
from ..methods.base import AnyStreamSpec, DataStreamSpec, StreamSpec, Update
from ..protocol.fec import fec_encode
from ..protocol.rtp import RTP_CLOCK_HZ
from ..protocol.twcc import one_byte_extension
from ..protocol import (DataChunk, FrameMeta, Message, Pose as PoseMsg, RtpPacket, RtpPacketizer, StreamDescription, make_sdp,
                        split_annexb)
from .adapt import CEILING_JUMP, AdaptConfig, CappedCrf, retarget
from .wire import (DATA_CHUNK_BYTES, META_STREAM, SESSION_STREAM, Envelope, checksum, compress_data, control_wire_bytes,
                   datagram_wire_bytes, pack_envelope, rtp_format, stream_table)

logger = logging.getLogger(__name__)

FIRST_PAYLOAD_TYPE = 96
"""Dynamic RTP payload type of a session's first RTP stream (then 97, 98, ...)."""
FEC_PAYLOAD_TYPE = 127
"""Payload type of the first RTP stream's FEC stream (then 126, ...), when FEC is on."""

Framer = Callable[[Message], bytes]
"""Frames one control message for the wire (a :class:`~splitrender.protocol.Connection`'s ``send``)."""


@dataclass
class EncodedUpdate:
    """One update after coding: video access units and compressed data, with costs."""

    update: Update
    video: dict[str, EncodedFrame]
    data: dict[str, bytes]
    encode_ms: float
    rates_kbps: dict[str, float] = field(default_factory=dict)
    """The bit rate each rate-controlled video stream's encoder ran at for this frame (``encode``'s
    ``rates_kbps``; empty without rate adaptation)."""
    restarts: int = 0
    """Encoders restarted at a new rate for this frame."""

    @property
    def keyframe(self) -> bool:
        """True when every video stream sent an IDR (or there is no video)."""
        return bool(self.video) and all(e.keyframe for e in self.video.values())


@dataclass
class OutgoingFrame:
    """What one server frame puts on the wire, in sending order per channel."""

    frame_id: int
    control: list[tuple[str, bytes]] = field(default_factory=list)
    """(stream, framed bytes) for the control channel: reliable data chunks, then ``meta``."""
    datagrams: list[tuple[str, RtpPacket, bytes]] = field(default_factory=list)
    """(stream, packet, bytes) for UDP."""
    fec: list[tuple[str, bytes]] = field(default_factory=list)
    """(stream, bytes) of the FEC packets protecting ``datagrams`` (sent after them; not for NACK history)."""
    wire_bytes: dict[str, int] = field(default_factory=dict)
    """Bytes on the wire per stream (headers included)."""
    payload_bytes: dict[str, int] = field(default_factory=dict)
    """Coded payload bytes per stream (no transport headers)."""
    keyframe: bool = False
    idr_streams: tuple[str, ...] = ()
    """The video streams that sent an IDR in this frame (``keyframe``: all of them did)."""

    @property
    def total_wire_bytes(self) -> int:
        return sum(self.wire_bytes.values())


@dataclass
class TxStream:
    spec: AnyStreamSpec
    ssrc: int = 0
    payload_type: int = 0
    packetizer: RtpPacketizer | None = None
    fec_ssrc: int = 0
    fec_payload_type: int = 0
    fec_seq: int = 0


class StreamEncoder:
    """The encoders of one session's streams (heavy: the live server runs them in its render worker): every video
    plane through its stream's real encoder, every data payload through its compression."""

    def __init__(self, specs: list[AnyStreamSpec]) -> None:
        self.specs = {s.name: s for s in specs}
        self.encoders: dict[str, VideoEncoder] = {}
        self._sets_checked: set[str] = set()
        """Streams whose first IDR's in-band parameter sets were compared with the described ones."""

    def open(self) -> None:
        """Open every video stream's encoder now and read the parameter sets it will send (for the SDP)."""
        for name, spec in self.specs.items():
            if isinstance(spec, StreamSpec) and name not in self.encoders:
                self.encoders[name] = VideoEncoder(spec.codec, spec.width, spec.height)
        for e in self.encoders.values():
            e.parameter_sets()

    def parameter_sets(self, name: str) -> tuple[bytes, ...]:
        """The parameter sets stream ``name``'s encoder sends (empty before :meth:`open`)."""
        enc = self.encoders.get(name)
        return enc.parameter_sets() if enc is not None else ()

    def described_sets(self) -> dict[str, tuple[bytes, ...]]:
        """The parameter sets each open video encoder sends, by stream (:attr:`ServerPipeline.described_sets`)."""
        return {name: self.parameter_sets(name) for name in self.encoders}

    def encode(self, update: Update, force_idr: bool = False, rates_kbps: dict[str, float] | None = None,
               adapt: AdaptConfig | None = None, scale: float | None = None) -> EncodedUpdate:
        """Code every payload of ``update``.

        ``rates_kbps``: bit rates for lossy video streams (rate adaptation, :mod:`.adapt`); a stream whose
        encoder runs at a rate that far from it (``adapt``'s ``change_ratio``) gets a new encoder at that rate,
        at its next IDR or, for a steep fall, now with an IDR (:func:`~.adapt.retarget`).  ``scale``: the
        resolution of the scalable streams (``--adapt full``): their planes are resampled to it
        (:mod:`splitrender.codecs.resize`), and an encoder whose size changes restarts now with an IDR."""
        w0 = time.perf_counter()
        video: dict[str, EncodedFrame] = {}
        data: dict[str, bytes] = {}
        given: dict[str, float] = {}
        restarts = 0
        for name, plane in update.planes.items():
            spec = self.specs.get(name)
            if not isinstance(spec, StreamSpec):
                raise ValueError(f"update {update.frame_id}: plane {name!r} is not a declared video stream")
            idr = force_idr
            w, h = spec.width, spec.height
            encoder = self.encoders.get(name)
            if spec.scalable and scale is not None and scale < 1.0:
                w, h = scaled_size(w, h, scale)
                plane = resize(plane, w, h)
            # at most one new encoder a frame: for a new size (its first frame an IDR) and/or a new rate
            resized = encoder is not None and (encoder.width, encoder.height) != (w, h)
            fresh = encoder is None or resized or encoder.frames_encoded == 0
            cfg = encoder.cfg if encoder is not None else spec.codec
            retargeted = False
            want = rates_kbps.get(name) if rates_kbps else None
            capped = isinstance(want, CappedCrf) and spec.codec.crf is not None   # a ceiling over the method's crf
            if want is not None and not spec.codec.lossless:
                cur = (cfg.cap_kbps if capped else cfg.bitrate_kbps) if encoder is not None else None
                due = fresh or force_idr or encoder.idr_due  # type: ignore[union-attr]
                retargeted, urgent = retarget(cur, want, due, adapt or AdaptConfig())
                if capped and cur is not None and want >= CEILING_JUMP * cur:
                    retargeted = urgent = True     # a ceiling far above: the crf's own picture now, not at the next IDR
                if retargeted:
                    cfg = (dataclasses.replace(cfg, cap_kbps=float(want), bitrate_kbps=None, crf=spec.codec.crf,
                                               cap_buffer_ms=getattr(want, "buffer_ms", None))
                           if capped else dataclasses.replace(cfg, bitrate_kbps=float(want), crf=None, cap_kbps=None))
                    restarts += not fresh
                    idr = idr or urgent
            if encoder is None or resized or retargeted:
                encoder = self.encoders[name] = VideoEncoder(cfg, w, h)
            if resized or retargeted:
                self._sets_checked.add(name)   # the described sets were the first encoder's; each IDR carries its own
                restarts += resized
            if encoder.cfg.bitrate_kbps is not None and want is not None:
                given[name] = float(encoder.cfg.bitrate_kbps)
            elif encoder.cfg.cap_kbps is not None and want is not None:
                given[name] = CappedCrf(encoder.cfg.cap_kbps, encoder.cfg.cap_buffer_ms)
            video[name] = ef = encoder.encode(plane, force_idr=idr)
            if ef.keyframe and name not in self._sets_checked and encoder.parameter_sets_known:
                self._sets_checked.add(name)
                described = encoder.parameter_sets()
                missing = [n for n in described if n not in split_annexb(ef.data)]
                if missing:  # the SDP's sprop sets would disagree with the stream
                    logger.warning("stream %s: %d of the parameter sets in the SDP are not in the first IDR",
                                   name, len(missing))
        for name, payload in update.data.items():
            spec = self.specs.get(name)
            if not isinstance(spec, DataStreamSpec):
                raise ValueError(f"update {update.frame_id}: data {name!r} is not a declared data stream")
            data[name] = compress_data(spec, payload)
        return EncodedUpdate(update, video, data, (time.perf_counter() - w0) * 1000, given, restarts)


class ServerPipeline:
    """One session's sending side; see the module docstring."""

    def __init__(self, specs: list[AnyStreamSpec], mtu: int = 1200, ssrc_taken: Callable[[int], bool] | None = None,
                 rng: Any = None, fec: bool = False, transport_cc_id: int | None = None) -> None:
        names = [s.name for s in specs]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate stream names in {names}")
        self.specs = list(specs)
        self.mtu = mtu
        self._rand = (lambda bits: int(rng.integers(0, 1 << bits))) if rng is not None else secrets.randbits
        self.streams: dict[str, TxStream] = {}
        used: set[int] = set()

        def new_ssrc() -> int:
            """A random SSRC no stream of this session or (``ssrc_taken``) of the server uses."""
            ssrc = self._rand(32)
            while ssrc in used or (ssrc_taken is not None and ssrc_taken(ssrc)):
                ssrc = self._rand(32)
            used.add(ssrc)
            return ssrc

        self.transport_cc_id = transport_cc_id
        """One-byte header extension id of the transport sequence number every RTP packet carries (reserved here,
        written at send time by :meth:`ServerSession.stamp`), or None: no transport-wide feedback."""
        ext = one_byte_extension({transport_cc_id: b"\0\0"}) if transport_cc_id is not None else None
        k = 0
        for s in specs:
            st = TxStream(s)
            if not (isinstance(s, DataStreamSpec) and s.delivery == "reliable"):
                ssrc = new_ssrc()
                st.ssrc, st.payload_type = ssrc, FIRST_PAYLOAD_TYPE + k
                k += 1
                st.packetizer = RtpPacketizer(rtp_format(s), ssrc, st.payload_type, mtu, self._rand(16),  # type: ignore[arg-type]
                                              extension=ext)
            self.streams[s.name] = st
        self.fec = fec
        if fec:   # one FEC stream per RTP stream: its own SSRC, payload type 127, 126, ... and sequence numbers
            for k, st in enumerate(self.rtp_streams):
                st.fec_ssrc, st.fec_payload_type, st.fec_seq = new_ssrc(), FEC_PAYLOAD_TYPE - k, self._rand(16)
            if FEC_PAYLOAD_TYPE - len(self.rtp_streams) < FIRST_PAYLOAD_TYPE + len(self.rtp_streams):
                raise ValueError(f"{len(self.rtp_streams)} RTP streams leave no payload types for FEC")
        self.probe_ssrc: int | None = new_ssrc() if transport_cc_id is not None else None
        """SSRC of the session's probe packets (padding the rate estimator sends to find capacity, with transport-wide
        feedback only); named to the client in ``Welcome.method_params.probe_ssrc``."""
        self.probe_payload_type = FIRST_PAYLOAD_TYPE + len(self.rtp_streams)
        self.bytes_sent: dict[str, int] = {META_STREAM: 0, **{s.name: 0 for s in specs}}
        self.described_sets: dict[str, tuple[bytes, ...]] = {}
        """Parameter sets per video stream of the session's encoders (its :class:`StreamEncoder`'s), for the SDP."""

    # ------------------------------------------------------------------ set-up

    @property
    def rtp_streams(self) -> list[TxStream]:
        return [st for st in self.streams.values() if st.packetizer is not None]

    def parameter_sets(self, name: str) -> tuple[bytes, ...]:
        """The parameter sets stream ``name``'s encoder sends (:attr:`described_sets`; empty where none were named)."""
        return tuple(self.described_sets.get(name, ()))

    def describe(self, host: str, port: int, session_name: str) -> tuple[StreamDescription, ...]:
        """``Welcome.streams``: one description per RTP stream (SDP for video streams).

        With :attr:`described_sets` a video stream's SDP carries the parameter sets and the
        profile and level its encoder sends; without, only what the codec alone says.
        """
        out = []
        for st in self.rtp_streams:
            fmt = rtp_format(st.spec)
            sdp = self.sdp(st.spec.name, port, session_name, host) if fmt != "data" else ""
            out.append(StreamDescription(st.spec.name, fmt, st.ssrc, st.payload_type, port, sdp,  # type: ignore[arg-type]
                                         fec_ssrc=st.fec_ssrc, fec_payload_type=st.fec_payload_type))
        return tuple(out)

    def sdp(self, name: str, port: int, session_name: str, host: str = "127.0.0.1") -> str:
        """Video stream ``name``'s SDP, for RTP to ``host``:``port`` (its session named ``<session_name> <name>``): the
        Welcome's (:meth:`describe`), and the live server's mirror files for ffplay and the like."""
        st = self.streams[name]
        return make_sdp(rtp_format(st.spec), port, st.payload_type, address=host,  # type: ignore[arg-type]
                        session_name=f"{session_name} {name}", parameter_sets=self.parameter_sets(name))

    def welcome_params(self, session_blob: bytes) -> dict[str, Any]:
        """The stream table and session data size for ``Welcome.method_params``."""
        out = {"streams": stream_table(self.specs), "session_data_bytes": len(session_blob),
               "session_data_crc": checksum(session_blob)}
        if self.transport_cc_id is not None:
            out["transport_cc"] = self.transport_cc_id
            out["probe_ssrc"] = self.probe_ssrc
        return out

    def session_frames(self, session_blob: bytes, framer: Framer) -> list[tuple[str, bytes]]:
        """The session data as ``DataChunk`` control frames (sent right after ``Welcome``); counted as ``session``."""
        out = []
        for msg in _chunks(SESSION_STREAM, 0, session_blob):
            data = framer(msg)
            out.append((SESSION_STREAM, data))
        self.bytes_sent[SESSION_STREAM] = self.bytes_sent.get(SESSION_STREAM, 0) + sum(
            control_wire_bytes(len(d)) for _, d in out)
        return out

    # ------------------------------------------------------------------ per frame

    def packetize(self, enc: EncodedUpdate, framer: Framer, server_time_us: int, rtp_ts: int, pose_sample_us: int,
                  pose_seq: int, target_t_s: float, timing_us: dict[str, int], srv: dict[str, float]) -> OutgoingFrame:
        """Everything frame ``enc.update.frame_id`` sends, framed and counted."""
        upd = enc.update
        out = OutgoingFrame(upd.frame_id, keyframe=enc.keyframe,
                            idr_streams=tuple(n for n, e in enc.video.items() if e.keyframe))
        rtp_ts &= 0xFFFFFFFF
        reliable = []
        for name, blob in enc.data.items():
            st = self.streams[name]
            assert isinstance(st.spec, DataStreamSpec)
            out.payload_bytes[name] = len(blob)
            if st.spec.delivery == "reliable":
                reliable.append(name)
                for msg in _chunks(name, upd.frame_id, blob):
                    frame = framer(msg)
                    out.control.append((name, frame))
                    out.wire_bytes[name] = out.wire_bytes.get(name, 0) + control_wire_bytes(len(frame))
        rtp_names = [n for n in (*enc.video, *enc.data) if self.streams[n].packetizer is not None]
        env = Envelope(upd.t_s, upd.pose, upd.meta, target_t_s, timing_us, srv, tuple(reliable))
        blob = pack_envelope(env)
        q = upd.pose.orientation
        meta = FrameMeta(
            frame_id=upd.frame_id, server_time_us=int(server_time_us), rtp_timestamps={n: rtp_ts for n in rtp_names},
            pose=PoseMsg(int(pose_sample_us), int(pose_seq) & 0xFFFFFFFF, tuple(float(v) for v in upd.pose.position),  # type: ignore[arg-type]
                         tuple(float(v) for v in q)),  # type: ignore[arg-type]
            method_meta=blob, keyframe=enc.keyframe)
        frame = framer(meta)
        out.control.append((META_STREAM, frame))
        out.wire_bytes[META_STREAM] = control_wire_bytes(len(frame))
        out.payload_bytes[META_STREAM] = len(blob)
        for name in rtp_names:
            st = self.streams[name]
            assert st.packetizer is not None
            payload = enc.video[name].data if name in enc.video else enc.data[name]
            out.payload_bytes.setdefault(name, len(payload))
            media = []
            for pkt in st.packetizer.packetize(payload, rtp_ts):
                data = bytes(pkt)
                media.append(data)
                out.datagrams.append((name, pkt, data))
                out.wire_bytes[name] = out.wire_bytes.get(name, 0) + datagram_wire_bytes(len(data))
            if self.fec and media:
                for f in fec_encode(media, st.fec_ssrc, st.fec_payload_type, st.fec_seq, rtp_ts):
                    data = bytes(f)
                    out.fec.append((name, data))
                    out.wire_bytes[name] += datagram_wire_bytes(len(data))   # FEC counts as its stream's bytes
                    st.fec_seq = (st.fec_seq + 1) & 0xFFFF
        for k, v in out.wire_bytes.items():
            self.bytes_sent[k] = self.bytes_sent.get(k, 0) + v
        return out


def _chunks(stream: str, frame_id: int, blob: bytes) -> list[DataChunk]:
    n = len(blob)
    if n == 0:
        return [DataChunk(stream, frame_id, 0, 0, b"")]
    return [DataChunk(stream, frame_id, off, n, blob[off:off + DATA_CHUNK_BYTES]) for off in range(0, n, DATA_CHUNK_BYTES)]


def rtp_timestamp(scene_t_s: float) -> int:
    """The 90 kHz RTP timestamp of scene time ``scene_t_s``."""
    return int(round(scene_t_s * RTP_CLOCK_HZ)) & 0xFFFFFFFF

