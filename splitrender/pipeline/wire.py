"""What one server frame looks like on the wire, and how its bytes are counted.

Both modes count the same bytes with the same functions: every RTP datagram as its
length plus IPv4 and UDP headers, every control-channel frame as its length plus one
TCP/IPv4 header per segment.  The per-frame metadata envelope (the ``FrameMeta``
``meta`` blob) is packed and validated here for the server and the client alike.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from typing import Any

import zstandard

from ..codecs.bounded import bounded_zstd_decompress
from ..codecs.meta import pack_meta, parse_update_envelope, unpack_meta
from ..errors import CodecError, RemoteProtocolError
from ..methods.base import AnyStreamSpec, DataStreamSpec, StreamSpec
from ..protocol.errors import ErrorCode
from ..scene.pose import Pose

IP_UDP_HEADER_BYTES = 20 + 8
"""IPv4 + UDP headers added to every RTP datagram on the wire."""
TCP_IP_HEADER_BYTES = 20 + 20
"""IPv4 + TCP headers added to every TCP segment."""
TCP_SEGMENT_BYTES = 1400
"""Payload bytes of one TCP segment (the counting model and the simulated link's unit)."""
DATA_CHUNK_BYTES = 256 * 1024
"""Reliable data and session data are sent in ``DataChunk`` messages of at most this many bytes."""
DEFAULT_MAX_SESSION_BYTES = 256 * 1024 * 1024
"""Default limit on a method's session data (configurable on server, client and runner)."""
META_STREAM = "meta"
SESSION_STREAM = "session"


def datagram_wire_bytes(rtp_bytes: int) -> int:
    """Bytes on the wire for one RTP datagram of ``rtp_bytes`` (RTP header included)."""
    return rtp_bytes + IP_UDP_HEADER_BYTES


def tcp_segments(nbytes: int) -> list[int]:
    """Wire sizes of the TCP segments carrying ``nbytes`` of control-channel data."""
    n = max(1, math.ceil(nbytes / TCP_SEGMENT_BYTES))
    sizes = [TCP_SEGMENT_BYTES] * (n - 1) + [nbytes - TCP_SEGMENT_BYTES * (n - 1)]
    return [s + TCP_IP_HEADER_BYTES for s in sizes]


def control_wire_bytes(nbytes: int) -> int:
    """Bytes on the wire for ``nbytes`` written to the control channel."""
    return sum(tcp_segments(nbytes))


class EnvelopeError(RemoteProtocolError, CodecError):
    """A ``FrameMeta`` metadata blob that is not a valid update envelope."""

    def __init__(self, message: str) -> None:
        super().__init__(message, ErrorCode.BAD_MESSAGE)


class SessionDataError(RemoteProtocolError):
    """Session data over the configured limit or inconsistent."""

    def __init__(self, message: str) -> None:
        super().__init__(message, ErrorCode.TOO_LARGE)


@dataclass
class Envelope:
    """The validated ``FrameMeta.meta`` blob of one update."""

    t_s: float
    pose: Pose
    meta: dict[str, Any]
    target_t_s: float
    timing_us: dict[str, int] = field(default_factory=dict)
    srv: dict[str, float] = field(default_factory=dict)
    reliable: tuple[str, ...] = ()
    """Reliable data streams sent with this frame (their chunks precede the FrameMeta)."""


def pack_envelope(env: Envelope) -> bytes:
    return pack_meta({"t_s": float(env.t_s), "pose": env.pose.to_list(), "m": env.meta,
                      "target_t_s": float(env.target_t_s), "timing_us": {k: int(v) for k, v in env.timing_us.items()},
                      "srv": {k: float(v) for k, v in env.srv.items()}, "d": list(env.reliable)})


def parse_envelope(blob: bytes, max_bytes: int) -> Envelope:
    """Unpack and validate a ``FrameMeta.meta`` blob (``codecs.meta.parse_update_envelope``
    for the fields every update has, then the reliable-stream list); raises
    :class:`EnvelopeError` naming the field."""
    try:
        d = unpack_meta(blob, max_bytes=max_bytes)
        env = parse_update_envelope(d, "metadata")
    except CodecError as exc:  # MetaEnvelopeError is one too; texts start with "metadata"
        raise EnvelopeError(str(exc)) from None
    rel = d.get("d", [])
    if not isinstance(rel, list) or len(rel) > 64 or not all(isinstance(n, str) and len(n) <= 64 for n in rel):
        raise EnvelopeError("metadata.d: expected a list of at most 64 stream names")
    target = env["target_t_s"]
    return Envelope(env["t_s"], Pose.from_list(env["pose"]), env["m"], env["t_s"] if target is None else target,
                    dict(env["timing_us"]), dict(env["srv"]), tuple(rel))


# --------------------------------------------------------------------------- data streams


def compress_data(spec: DataStreamSpec, payload: bytes) -> bytes:
    """A data stream's payload as sent; raises :class:`CodecError` past ``max_bytes``."""
    if len(payload) > spec.max_bytes:
        raise CodecError(f"data stream {spec.name}: {len(payload)} bytes exceeds its max_bytes {spec.max_bytes}")
    if spec.compression == "none":
        return bytes(payload)
    return zstandard.ZstdCompressor(level=spec.level).compress(payload)


def decompress_data(spec: DataStreamSpec, data: bytes) -> bytes:
    """Inverse of :func:`compress_data`, bounded by ``max_bytes`` before anything is allocated
    (:func:`~splitrender.codecs.bounded.bounded_zstd_decompress`)."""
    if len(data) > spec.max_bytes + 1024:
        raise CodecError(f"data stream {spec.name}: {len(data)} bytes received exceeds its max_bytes {spec.max_bytes}")
    if spec.compression == "none":
        return data
    return bounded_zstd_decompress(data, spec.max_bytes, f"data stream {spec.name}")


def rtp_format(spec: AnyStreamSpec) -> str:
    """The RTP payload format of a stream sent over RTP (``h264``, ``hevc`` or ``data``)."""
    return spec.codec.codec if isinstance(spec, StreamSpec) else "data"


def stream_table(specs: list[AnyStreamSpec]) -> list[dict[str, Any]]:
    """The ``Welcome.method_params["streams"]`` table: every stream's kind and limits."""
    out = []
    for s in specs:
        if isinstance(s, StreamSpec):
            out.append({"name": s.name, "kind": "video", "format": s.codec.input_format, "codec": s.codec.codec,
                        "width": s.width, "height": s.height})
        else:
            out.append({"name": s.name, "kind": "data", "delivery": s.delivery, "compression": s.compression,
                        "max_bytes": s.max_bytes})
    return out


def specs_from_table(table: Any) -> list[AnyStreamSpec | dict[str, Any]]:
    """Client side of :func:`stream_table`: data streams as :class:`DataStreamSpec`, video rows as dicts."""
    if not isinstance(table, list) or len(table) > 64:
        raise EnvelopeError("Welcome.method_params.streams: expected a list of at most 64 streams")
    out: list[AnyStreamSpec | dict[str, Any]] = []
    for i, row in enumerate(table):
        if not isinstance(row, dict) or row.get("kind") not in ("video", "data") or not isinstance(row.get("name"), str):
            raise EnvelopeError(f"Welcome.method_params.streams[{i}]: expected a map with name and kind video|data")
        if row["kind"] == "data":
            try:
                out.append(DataStreamSpec(row["name"], row.get("delivery", "reliable"), row.get("compression", "zstd"),
                                          max_bytes=int(row.get("max_bytes", 0))))
            except Exception as exc:  # noqa: BLE001 - ConfigError/TypeError/ValueError from peer values
                raise EnvelopeError(f"Welcome.method_params.streams[{i}]: {exc}") from None
        else:
            out.append(dict(row))
    return out


def checksum(data: bytes) -> int:
    """CRC-32 of session data (carried in ``Welcome`` so a truncated transfer is caught)."""
    return zlib.crc32(data) & 0xFFFFFFFF
