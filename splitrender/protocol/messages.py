"""Control/metadata channel messages (TCP).

Each message is a frozen dataclass whose body on the wire is a msgpack map with the
field names below as keys.  ``encode()`` returns the body; ``decode(body)`` validates
every field and raises :class:`~splitrender.protocol.errors.MessageError` naming the
message and field (``"Pose.position: expected 3 floats, got 2"``).  Unknown keys are
ignored so that a later minor revision can add optional fields.  Times are integer
microseconds (µs), positions metres, orientations unit quaternions (x, y, z, w).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, ClassVar, Literal, TypeVar, cast

import msgpack

from splitrender.protocol.errors import MessageError
from splitrender.protocol.rtp import RTP_CLOCK_HZ
from splitrender.protocol.msgpack_limits import MsgpackLimitError, MsgpackLimits, bounded_unpackb

__all__ = [
    "PROTOCOL_VERSION",
    "MessageType",
    "MAX_BODY_SIZE",
    "Message",
    "Hello",
    "StreamDescription",
    "Welcome",
    "Pose",
    "FrameMeta",
    "Feedback",
    "KeyframeRequest",
    "Stats",
    "Bye",
    "Error",
    "DataChunk",
    "MAX_DATA_CHUNK",
    "MESSAGE_CLASSES",
    "decode_message",
]

PROTOCOL_VERSION = 2
"""The protocol version this code speaks (header byte 2 and ``Hello.version``)."""

KIB = 1024
MIB = 1024 * 1024

U32_MAX = 0xFFFFFFFF
U64_MAX = 0xFFFFFFFFFFFFFFFF
I64_MIN = -(2**63)
I64_MAX = 2**63 - 1
MAX_DIMENSION_PX = 16384
MAX_POSITION_M = 1e6
"""A pose's coordinates, metres: farther is a peer error (a predictor extrapolating from 1e306 overflows)."""
MAX_NAME_LEN = 64
MAX_TEXT_LEN = 1024
MAX_LIST_LEN = 64
MAX_NESTING = 32
QUATERNION_NORM_TOLERANCE = 1e-3
RTP_CLOCK_RATE_HZ = RTP_CLOCK_HZ

CodecName = Literal["h264", "hevc", "data"]
CODECS: tuple[str, ...] = ("h264", "hevc")
"""Video codecs a client may offer in ``Hello``."""
RTP_FORMATS: tuple[str, ...] = (*CODECS, "data")
"""Payload formats of RTP streams in ``Welcome``: the video codecs and datagram ``data`` streams."""


class MessageType(IntEnum):
    """Wire numbers of the message types (header byte 3)."""

    HELLO = 1
    WELCOME = 2
    POSE = 3
    FRAME_META = 4
    FEEDBACK = 5
    KEYFRAME_REQUEST = 6
    STATS = 7
    BYE = 8
    ERROR = 9
    DATA_CHUNK = 10


MAX_BODY_SIZE: dict[MessageType, int] = {
    MessageType.HELLO: 4 * KIB,
    MessageType.WELCOME: 64 * KIB,
    MessageType.POSE: 256,
    MessageType.FRAME_META: 4 * MIB,
    MessageType.FEEDBACK: 4 * KIB,
    MessageType.KEYFRAME_REQUEST: 1 * KIB,
    MessageType.STATS: 64 * KIB,
    MessageType.BYE: 1 * KIB,
    MessageType.ERROR: 4 * KIB,
    MessageType.DATA_CHUNK: 1 * MIB + 4 * KIB,
}
"""Largest body (bytes, compressed on the wire and after decompression) per type."""

MAX_OBJECTS = 65536
"""Most msgpack objects (containers and scalars) in one body, whatever its size."""
MSGPACK_LIMITS: dict[MessageType, MsgpackLimits] = {
    t: MsgpackLimits(max_objects=min(size, MAX_OBJECTS), max_array_len=min(size, MAX_OBJECTS),
                     max_map_len=min(size, MAX_OBJECTS) // 2, max_str_len=size, max_bin_len=size,
                     max_ext_len=size, max_depth=MAX_NESTING + 1)
    for t, size in MAX_BODY_SIZE.items()
}
"""Per-type msgpack limits, checked by a scan before anything is unpacked: a 4 MiB
body of empty arrays would otherwise become four million Python lists."""


# --------------------------------------------------------------------------- helpers


def _pack(obj: dict[str, Any]) -> bytes:
    return cast(bytes, msgpack.packb(obj, use_bin_type=True))


def _unpack_map(name: str, body: bytes, limits: MsgpackLimits) -> dict[str, Any]:
    try:
        obj = bounded_unpackb(body, limits)
    except MsgpackLimitError as exc:
        raise MessageError(f"{name}: body is not valid msgpack ({exc})") from None
    except Exception as exc:  # msgpack raises many unrelated types on garbage
        raise MessageError(f"{name}: body is not valid msgpack ({type(exc).__name__})") from None
    if not isinstance(obj, dict):
        raise MessageError(f"{name}: body must be a msgpack map, got {_tname(obj)}")
    return obj


def _tname(v: Any) -> str:
    if v is None:
        return "nil"
    return type(v).__name__


def _get(name: str, d: Mapping[str, Any], key: str) -> Any:
    if key not in d:
        raise MessageError(f"{name}: missing field {key!r}")
    return d[key]


def _int(name: str, d: Mapping[str, Any], key: str, lo: int, hi: int) -> int:
    v = _get(name, d, key)
    if not isinstance(v, int) or isinstance(v, bool):
        raise MessageError(f"{name}.{key}: expected int, got {_tname(v)}")
    if not lo <= v <= hi:
        raise MessageError(f"{name}.{key}: {v} out of range [{lo}, {hi}]")
    return v


def _float(name: str, d: Mapping[str, Any], key: str, lo: float, hi: float) -> float:
    v = _get(name, d, key)
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        raise MessageError(f"{name}.{key}: expected float, got {_tname(v)}")
    f = float(v)
    if not (math.isfinite(f) and lo <= f <= hi):
        raise MessageError(f"{name}.{key}: {f!r} out of range [{lo}, {hi}]")
    return f


def _bool(name: str, d: Mapping[str, Any], key: str) -> bool:
    v = _get(name, d, key)
    if not isinstance(v, bool):
        raise MessageError(f"{name}.{key}: expected bool, got {_tname(v)}")
    return v


def _str(name: str, d: Mapping[str, Any], key: str, max_len: int = MAX_TEXT_LEN) -> str:
    v = _get(name, d, key)
    if not isinstance(v, str):
        raise MessageError(f"{name}.{key}: expected str, got {_tname(v)}")
    if len(v) > max_len:
        raise MessageError(f"{name}.{key}: string of {len(v)} chars exceeds {max_len}")
    return v


def _str_list(name: str, d: Mapping[str, Any], key: str) -> tuple[str, ...]:
    v = _get(name, d, key)
    if not isinstance(v, list):
        raise MessageError(f"{name}.{key}: expected list of str, got {_tname(v)}")
    if len(v) > MAX_LIST_LEN:
        raise MessageError(f"{name}.{key}: {len(v)} items exceeds {MAX_LIST_LEN}")
    for i, item in enumerate(v):
        if not isinstance(item, str) or len(item) > MAX_NAME_LEN:
            raise MessageError(f"{name}.{key}[{i}]: expected str of at most {MAX_NAME_LEN} chars")
    return tuple(v)


def _floats(name: str, d: Mapping[str, Any], key: str, n: int) -> tuple[float, ...]:
    v = _get(name, d, key)
    if not isinstance(v, list):
        raise MessageError(f"{name}.{key}: expected {n} floats, got {_tname(v)}")
    if len(v) != n:
        raise MessageError(f"{name}.{key}: expected {n} floats, got {len(v)}")
    out = []
    for i, item in enumerate(v):
        if not isinstance(item, (int, float)) or isinstance(item, bool):
            raise MessageError(f"{name}.{key}[{i}]: expected float, got {_tname(item)}")
        f = float(item)
        if not math.isfinite(f):
            raise MessageError(f"{name}.{key}[{i}]: {f!r} is not finite")
        out.append(f)
    return tuple(out)


def _check_plain(name: str, v: Any, depth: int = 0) -> None:
    """Accept nil/bool/int/float/str/bytes and lists/maps of them (no ext types)."""
    if depth > MAX_NESTING:
        raise MessageError(f"{name}: nested deeper than {MAX_NESTING} levels")
    if v is None or isinstance(v, (bool, int, float, str, bytes)):
        return
    if isinstance(v, list):
        for item in v:
            _check_plain(name, item, depth + 1)
        return
    if isinstance(v, dict):
        for k, item in v.items():
            if not isinstance(k, str):
                raise MessageError(f"{name}: map keys must be str, got {_tname(k)}")
            _check_plain(name, item, depth + 1)
        return
    raise MessageError(f"{name}: unsupported value of type {_tname(v)}")


def _plain_map(name: str, d: Mapping[str, Any], key: str) -> dict[str, Any]:
    v = _get(name, d, key)
    if not isinstance(v, dict):
        raise MessageError(f"{name}.{key}: expected map, got {_tname(v)}")
    _check_plain(f"{name}.{key}", v)
    return v


def _int_map(
    name: str, d: Mapping[str, Any], key: str, lo: int, hi: int, allow_float: bool = False
) -> dict[str, Any]:
    v = _get(name, d, key)
    if not isinstance(v, dict):
        raise MessageError(f"{name}.{key}: expected map, got {_tname(v)}")
    for k, item in v.items():
        if not isinstance(k, str) or len(k) > MAX_NAME_LEN:
            raise MessageError(f"{name}.{key}: keys must be str of at most {MAX_NAME_LEN} chars")
        ok = isinstance(item, int) and not isinstance(item, bool) and lo <= item <= hi
        if allow_float and isinstance(item, float) and math.isfinite(item):
            ok = True
        if not ok:
            kind = "number" if allow_float else f"int in [{lo}, {hi}]"
            raise MessageError(f"{name}.{key}[{k!r}]: expected {kind}, got {item!r}")
    return dict(v)


# --------------------------------------------------------------------------- messages


@dataclass(frozen=True)
class Message:
    """Base class: ``TYPE`` is the wire number, ``encode()`` gives the msgpack body."""

    TYPE: ClassVar[MessageType]

    def to_wire(self) -> dict[str, Any]:
        raise NotImplementedError

    def encode(self) -> bytes:
        """The msgpack body (no frame header)."""
        return _pack(self.to_wire())

    @classmethod
    def from_wire(cls, d: Mapping[str, Any]) -> Message:
        raise NotImplementedError

    @classmethod
    def decode(cls: type[_M], body: bytes) -> _M:
        """Parse and validate a msgpack body; raises :class:`MessageError`."""
        return cast(_M, cls.from_wire(_unpack_map(cls.__name__, body, MSGPACK_LIMITS[cls.TYPE])))


_M = TypeVar("_M", bound=Message)


@dataclass(frozen=True)
class Hello(Message):
    """Client → server, first message: version, auth token and capabilities."""

    TYPE: ClassVar[MessageType] = MessageType.HELLO
    version: int
    auth_token: str
    methods: tuple[str, ...]
    codecs: tuple[str, ...]
    width: int
    """Display width in pixels."""
    height: int
    """Display height in pixels."""
    display_hz: float
    """Display refresh rate in Hz."""

    def to_wire(self) -> dict[str, Any]:
        return {
            "version": self.version,
            "auth_token": self.auth_token,
            "methods": list(self.methods),
            "codecs": list(self.codecs),
            "width": self.width,
            "height": self.height,
            "display_hz": float(self.display_hz),
        }

    @classmethod
    def from_wire(cls, d: Mapping[str, Any]) -> Hello:
        n = "Hello"
        version = _int(n, d, "version", 0, 255)
        auth_token = _str(n, d, "auth_token", 256)
        methods = _str_list(n, d, "methods")
        codecs = _str_list(n, d, "codecs")
        for c in codecs:
            if c not in CODECS:
                raise MessageError(f"Hello.codecs: unknown codec {c!r} (expected one of {CODECS})")
        return cls(
            version=version,
            auth_token=auth_token,
            methods=methods,
            codecs=codecs,
            width=_int(n, d, "width", 1, MAX_DIMENSION_PX),
            height=_int(n, d, "height", 1, MAX_DIMENSION_PX),
            display_hz=_float(n, d, "display_hz", 1.0, 1000.0),
        )


@dataclass(frozen=True)
class StreamDescription:
    """One RTP stream announced in ``Welcome``: video (``h264``/``hevc``) or a datagram ``data`` stream."""

    name: str
    codec: CodecName
    ssrc: int
    payload_type: int
    """RTP payload type, 0..127 (dynamic range 96..127 recommended)."""
    port: int
    """UDP port the server sends to / the client listens on."""
    sdp: str
    clock_rate: int = RTP_CLOCK_RATE_HZ
    """RTP timestamp clock in Hz; always 90000 for video."""
    fec_ssrc: int = 0
    """SSRC of the RFC 5109 FEC stream protecting this one (``fec_payload_type`` 0: no FEC)."""
    fec_payload_type: int = 0

    def to_wire(self) -> dict[str, Any]:
        d = {
            "name": self.name,
            "codec": self.codec,
            "ssrc": self.ssrc,
            "payload_type": self.payload_type,
            "clock_rate": self.clock_rate,
            "port": self.port,
            "sdp": self.sdp,
        }
        if self.fec_payload_type:
            d["fec"] = [self.fec_ssrc, self.fec_payload_type]
        return d

    @classmethod
    def from_wire(cls, where: str, d: Any) -> StreamDescription:
        if not isinstance(d, dict):
            raise MessageError(f"{where}: expected map, got {_tname(d)}")
        codec = _str(where, d, "codec", MAX_NAME_LEN)
        if codec not in RTP_FORMATS:
            raise MessageError(f"{where}.codec: unknown codec {codec!r} (expected one of {RTP_FORMATS})")
        clock = _int(where, d, "clock_rate", 1, U32_MAX)
        if clock != RTP_CLOCK_RATE_HZ:
            raise MessageError(f"{where}.clock_rate: expected {RTP_CLOCK_RATE_HZ}, got {clock}")
        fec_ssrc, fec_pt = 0, 0
        if "fec" in d:
            fec = d["fec"]
            if (not isinstance(fec, list) or len(fec) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in fec)
                    or not 0 <= fec[0] <= U32_MAX or not 96 <= fec[1] <= 127):
                raise MessageError(f"{where}.fec: expected [ssrc (u32), payload type (96..127)], got {fec!r:.80}")
            fec_ssrc, fec_pt = fec
        ssrc = _int(where, d, "ssrc", 0, U32_MAX)
        pt = _int(where, d, "payload_type", 0, 127)
        if fec_pt and (fec_ssrc == ssrc or fec_pt == pt):
            raise MessageError(f"{where}.fec: the FEC stream must differ from the media stream in SSRC and payload type")
        return cls(
            name=_str(where, d, "name", MAX_NAME_LEN),
            codec=cast(CodecName, codec),
            ssrc=ssrc,
            payload_type=pt,
            port=_int(where, d, "port", 0, 65535),
            sdp=_str(where, d, "sdp", 16 * KIB),
            clock_rate=clock,
            fec_ssrc=fec_ssrc,
            fec_payload_type=fec_pt,
        )


@dataclass(frozen=True)
class Welcome(Message):
    """Server → client reply to ``Hello``: session id, chosen method, streams."""

    TYPE: ClassVar[MessageType] = MessageType.WELCOME
    session_id: str
    method: str
    method_params: Mapping[str, Any] = field(default_factory=dict)
    streams: tuple[StreamDescription, ...] = ()

    def to_wire(self) -> dict[str, Any]:
        return {
            "session_id": self.session_id,
            "method": self.method,
            "method_params": dict(self.method_params),
            "streams": [s.to_wire() for s in self.streams],
        }

    @classmethod
    def from_wire(cls, d: Mapping[str, Any]) -> Welcome:
        n = "Welcome"
        streams = _get(n, d, "streams")
        if not isinstance(streams, list):
            raise MessageError(f"Welcome.streams: expected list, got {_tname(streams)}")
        if len(streams) > MAX_LIST_LEN:
            raise MessageError(f"Welcome.streams: {len(streams)} items exceeds {MAX_LIST_LEN}")
        return cls(
            session_id=_str(n, d, "session_id", MAX_NAME_LEN),
            method=_str(n, d, "method", MAX_NAME_LEN),
            method_params=_plain_map(n, d, "method_params"),
            streams=tuple(
                StreamDescription.from_wire(f"Welcome.streams[{i}]", s) for i, s in enumerate(streams)
            ),
        )


@dataclass(frozen=True)
class Pose(Message):
    """Client → server head/camera pose sample."""

    TYPE: ClassVar[MessageType] = MessageType.POSE
    client_time_us: int
    """Client clock at sampling time, µs."""
    seq: int
    """Pose sequence number, uint32."""
    position: tuple[float, float, float]
    """World position, metres."""
    orientation: tuple[float, float, float, float]
    """Unit quaternion (x, y, z, w), camera-to-world."""

    def to_wire(self) -> dict[str, Any]:
        return {
            "t_us": self.client_time_us,
            "seq": self.seq,
            "position": [float(v) for v in self.position],
            "orientation": [float(v) for v in self.orientation],
        }

    @classmethod
    def from_wire(cls, d: Mapping[str, Any], name: str = "Pose") -> Pose:
        q = _floats(name, d, "orientation", 4)
        norm = math.sqrt(sum(v * v for v in q))
        if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
            raise MessageError(f"{name}.orientation: quaternion norm {norm:.6g} is not 1")
        pos = _floats(name, d, "position", 3)
        if max(abs(v) for v in pos) > MAX_POSITION_M:
            raise MessageError(f"{name}.position: {list(pos)} is more than {MAX_POSITION_M:g} m from the origin")
        return cls(
            client_time_us=_int(name, d, "t_us", I64_MIN, I64_MAX),
            seq=_int(name, d, "seq", 0, U32_MAX),
            position=cast(tuple[float, float, float], pos),
            orientation=cast(tuple[float, float, float, float], q),
        )


@dataclass(frozen=True)
class FrameMeta(Message):
    """Server → client metadata of one rendered frame (update)."""

    TYPE: ClassVar[MessageType] = MessageType.FRAME_META
    frame_id: int
    server_time_us: int
    """Server clock when rendering started, µs."""
    rtp_timestamps: Mapping[str, int]
    """Stream name → RTP timestamp (90 kHz) of this frame's access unit."""
    pose: Pose
    """The (predicted) pose the frame was rendered for."""
    method_meta: bytes | Mapping[str, Any]
    """Method-specific metadata: opaque bytes or a msgpack-able map."""
    keyframe: bool

    def to_wire(self) -> dict[str, Any]:
        meta = self.method_meta if isinstance(self.method_meta, bytes) else dict(self.method_meta)
        return {
            "frame_id": self.frame_id,
            "t_us": self.server_time_us,
            "rtp_ts": dict(self.rtp_timestamps),
            "pose": self.pose.to_wire(),
            "meta": meta,
            "keyframe": self.keyframe,
        }

    @classmethod
    def from_wire(cls, d: Mapping[str, Any]) -> FrameMeta:
        n = "FrameMeta"
        pose = _get(n, d, "pose")
        if not isinstance(pose, dict):
            raise MessageError(f"FrameMeta.pose: expected map, got {_tname(pose)}")
        meta = _get(n, d, "meta")
        if isinstance(meta, dict):
            _check_plain("FrameMeta.meta", meta)
        elif not isinstance(meta, bytes):
            raise MessageError(f"FrameMeta.meta: expected bytes or map, got {_tname(meta)}")
        return cls(
            frame_id=_int(n, d, "frame_id", 0, U64_MAX),
            server_time_us=_int(n, d, "t_us", I64_MIN, I64_MAX),
            rtp_timestamps=_int_map(n, d, "rtp_ts", 0, U32_MAX),
            pose=Pose.from_wire(pose, "FrameMeta.pose"),
            method_meta=meta,
            keyframe=_bool(n, d, "keyframe"),
        )


@dataclass(frozen=True)
class Feedback(Message):
    """Client → server per-frame timing feedback (client clock, µs)."""

    TYPE: ClassVar[MessageType] = MessageType.FEEDBACK
    frame_id: int
    received_us: int
    """Last packet of the frame received, client clock µs."""
    decoded_us: int
    displayed_us: int
    lost_packets: int
    """RTP packets of this frame never received (after retransmission)."""
    pose_time_us: int = 0
    """``Pose.client_time_us`` of the pose the frame was rendered for (motion-to-photon)."""
    server_timings_us: Mapping[str, int] = field(default_factory=dict)
    """Server stage durations echoed back (e.g. ``render``, ``encode``), µs."""
    applied: Mapping[str, int] = field(default_factory=dict)
    """Per stream, the newest frame id whose payload the client half applied."""
    lost: Mapping[str, tuple[int, ...]] = field(default_factory=dict)
    """Per stream, frame ids the client will never get (lost or undecodable) since the last Feedback."""

    def to_wire(self) -> dict[str, Any]:
        return {
            "applied": dict(self.applied),
            "lost": {k: list(v) for k, v in self.lost.items()},
            "frame_id": self.frame_id,
            "received_us": self.received_us,
            "decoded_us": self.decoded_us,
            "displayed_us": self.displayed_us,
            "lost_packets": self.lost_packets,
            "pose_time_us": self.pose_time_us,
            "server_us": dict(self.server_timings_us),
        }

    @classmethod
    def from_wire(cls, d: Mapping[str, Any]) -> Feedback:
        n = "Feedback"
        return cls(
            frame_id=_int(n, d, "frame_id", 0, U64_MAX),
            received_us=_int(n, d, "received_us", I64_MIN, I64_MAX),
            decoded_us=_int(n, d, "decoded_us", I64_MIN, I64_MAX),
            displayed_us=_int(n, d, "displayed_us", I64_MIN, I64_MAX),
            lost_packets=_int(n, d, "lost_packets", 0, U32_MAX),
            pose_time_us=_int(n, d, "pose_time_us", I64_MIN, I64_MAX),
            server_timings_us=_int_map(n, d, "server_us", I64_MIN, I64_MAX),
            applied=_int_map(n, d, "applied", -1, U64_MAX) if "applied" in d else {},
            lost=_lost_map(d) if "lost" in d else {},
        )


def _lost_map(d: Mapping[str, Any]) -> dict[str, tuple[int, ...]]:
    v = d["lost"]
    if not isinstance(v, dict):
        raise MessageError(f"Feedback.lost: expected map, got {_tname(v)}")
    if len(v) > MAX_LIST_LEN:
        raise MessageError(f"Feedback.lost: {len(v)} streams exceeds {MAX_LIST_LEN}")
    out: dict[str, tuple[int, ...]] = {}
    for k, ids in v.items():
        if not isinstance(k, str) or len(k) > MAX_NAME_LEN:
            raise MessageError(f"Feedback.lost: keys must be str of at most {MAX_NAME_LEN} chars")
        if not isinstance(ids, list) or len(ids) > MAX_LOST_REPORTED:
            raise MessageError(f"Feedback.lost[{k!r}]: expected a list of at most {MAX_LOST_REPORTED} frame ids")
        for i in ids:
            if not isinstance(i, int) or isinstance(i, bool) or not 0 <= i <= U64_MAX:
                raise MessageError(f"Feedback.lost[{k!r}]: expected frame ids, got {i!r}")
        out[k] = tuple(ids)
    return out


MAX_DATA_CHUNK = 1 * MIB
"""Largest ``DataChunk.payload`` in bytes."""
MAX_LOST_REPORTED = 256
"""Most lost frame ids one ``Feedback`` lists per stream."""


@dataclass(frozen=True)
class DataChunk(Message):
    """Server → client: a piece of a reliable ``data`` stream's payload for one frame.

    ``stream`` is the method's stream name, or ``session`` for the session data sent
    once after ``Welcome``.  A payload of ``total`` bytes is sent as chunks with
    increasing ``offset``; for a frame, all its chunks come before its ``FrameMeta``.
    """

    TYPE: ClassVar[MessageType] = MessageType.DATA_CHUNK
    stream: str
    frame_id: int
    offset: int
    total: int
    payload: bytes

    def to_wire(self) -> dict[str, Any]:
        return {"stream": self.stream, "frame_id": self.frame_id, "offset": self.offset, "total": self.total,
                "data": self.payload}

    @classmethod
    def from_wire(cls, d: Mapping[str, Any]) -> DataChunk:
        n = "DataChunk"
        data = _get(n, d, "data")
        if not isinstance(data, bytes):
            raise MessageError(f"DataChunk.data: expected bytes, got {_tname(data)}")
        if len(data) > MAX_DATA_CHUNK:
            raise MessageError(f"DataChunk.data: {len(data)} bytes exceeds {MAX_DATA_CHUNK}")
        total = _int(n, d, "total", 0, I64_MAX)
        offset = _int(n, d, "offset", 0, I64_MAX)
        if offset + len(data) > total:
            raise MessageError(f"DataChunk: bytes {offset}..{offset + len(data)} run past total {total}")
        return cls(stream=_str(n, d, "stream", MAX_NAME_LEN), frame_id=_int(n, d, "frame_id", 0, U64_MAX),
                   offset=offset, total=total, payload=data)


@dataclass(frozen=True)
class KeyframeRequest(Message):
    """Client → server: please send an IDR on ``stream``."""

    TYPE: ClassVar[MessageType] = MessageType.KEYFRAME_REQUEST
    stream: str
    reason: str = ""

    def to_wire(self) -> dict[str, Any]:
        return {"stream": self.stream, "reason": self.reason}

    @classmethod
    def from_wire(cls, d: Mapping[str, Any]) -> KeyframeRequest:
        n = "KeyframeRequest"
        return cls(stream=_str(n, d, "stream", MAX_NAME_LEN), reason=_str(n, d, "reason", 256))


@dataclass(frozen=True)
class Stats(Message):
    """Either side: free-form numeric counters (name → int or float)."""

    TYPE: ClassVar[MessageType] = MessageType.STATS
    counters: Mapping[str, int | float] = field(default_factory=dict)

    def to_wire(self) -> dict[str, Any]:
        return {"counters": dict(self.counters)}

    @classmethod
    def from_wire(cls, d: Mapping[str, Any]) -> Stats:
        return cls(counters=_int_map("Stats", d, "counters", I64_MIN, U64_MAX, allow_float=True))


@dataclass(frozen=True)
class Bye(Message):
    """Either side: orderly close."""

    TYPE: ClassVar[MessageType] = MessageType.BYE
    reason: str = ""

    def to_wire(self) -> dict[str, Any]:
        return {"reason": self.reason}

    @classmethod
    def from_wire(cls, d: Mapping[str, Any]) -> Bye:
        return cls(reason=_str("Bye", d, "reason"))


@dataclass(frozen=True)
class Error(Message):
    """Either side: fatal error; ``code`` is an :class:`ErrorCode` value."""

    TYPE: ClassVar[MessageType] = MessageType.ERROR
    code: int
    text: str = ""

    def to_wire(self) -> dict[str, Any]:
        return {"code": int(self.code), "text": self.text}

    @classmethod
    def from_wire(cls, d: Mapping[str, Any]) -> Error:
        return cls(code=_int("Error", d, "code", 0, 999), text=_str("Error", d, "text"))


MESSAGE_CLASSES: dict[MessageType, type[Message]] = {
    cls.TYPE: cls
    for cls in (Hello, Welcome, Pose, FrameMeta, Feedback, KeyframeRequest, Stats, Bye, Error, DataChunk)
}


def decode_message(msg_type: MessageType, body: bytes) -> Message:
    """Decode a body of the given type; raises :class:`MessageError`."""
    return MESSAGE_CLASSES[msg_type].decode(body)
