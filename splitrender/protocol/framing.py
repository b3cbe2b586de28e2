"""Length-prefixed framing of control messages (sans-IO, h11-style).

Header (9 bytes, big-endian)::

    offset 0  2 bytes  magic b"SR"
    offset 2  1 byte   protocol version (1)
    offset 3  1 byte   message type (MessageType)
    offset 4  1 byte   flags: bit0 = body is zstd-compressed; other bits must be 0
    offset 5  4 bytes  body length in bytes (as on the wire)

The body length is checked against the type's limit as soon as the header is in, before
any body byte is buffered; a compressed body must declare its content size in the zstd
frame header and that size is checked against the same limit before decompressing.
"""

from __future__ import annotations

import logging
import struct
from enum import Enum
from typing import Final

import zstandard

from splitrender.errors import LocalProtocolError
from splitrender.protocol.errors import FramingError, TooLargeError, VersionError
from splitrender.protocol.messages import (
    MAX_BODY_SIZE,
    MESSAGE_CLASSES,
    PROTOCOL_VERSION,
    Message,
    MessageType,
)

__all__ = [
    "MAGIC",
    "HEADER",
    "HEADER_SIZE",
    "FLAG_ZSTD",
    "COMPRESS_THRESHOLD",
    "NEED_DATA",
    "CONNECTION_CLOSED",
    "Sentinel",
    "encode_frame",
    "FrameDecoder",
]

logger = logging.getLogger(__name__)

MAGIC: Final = b"SR"
HEADER: Final = struct.Struct(">2sBBBI")
HEADER_SIZE: Final = HEADER.size  # 9
FLAG_ZSTD: Final = 0x01
KNOWN_FLAGS: Final = FLAG_ZSTD
COMPRESS_THRESHOLD: Final = 1024
"""Bodies at least this long (bytes) are zstd-compressed when that makes them smaller."""
ZSTD_LEVEL: Final = 3


class Sentinel(Enum):
    """Non-message results of ``next_event()``."""

    NEED_DATA = "NEED_DATA"
    CONNECTION_CLOSED = "CONNECTION_CLOSED"

    def __repr__(self) -> str:
        return self.value


NEED_DATA: Final = Sentinel.NEED_DATA
"""More bytes are needed before the next message can be returned."""
CONNECTION_CLOSED: Final = Sentinel.CONNECTION_CLOSED
"""The peer closed the stream cleanly (EOF on a frame boundary)."""

_compressor = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_content_size=True)
_decompressor = zstandard.ZstdDecompressor()


def encode_frame(msg: Message, compress: bool | None = None) -> bytes:
    """Header + body of ``msg``.

    ``compress=None`` compresses bodies of at least :data:`COMPRESS_THRESHOLD` bytes
    when that makes them smaller; ``True``/``False`` force it.  Raises
    :class:`LocalProtocolError` if the body exceeds the type's limit.
    """
    body = msg.encode()
    limit = MAX_BODY_SIZE[msg.TYPE]
    if len(body) > limit:
        raise LocalProtocolError(
            f"{type(msg).__name__} body of {len(body)} bytes exceeds the limit of {limit} bytes"
        )
    flags = 0
    if compress or (compress is None and len(body) >= COMPRESS_THRESHOLD):
        packed = _compressor.compress(body)
        if compress or len(packed) < len(body):
            body, flags = packed, FLAG_ZSTD
    return HEADER.pack(MAGIC, PROTOCOL_VERSION, int(msg.TYPE), flags, len(body)) + body


def _type_name(t: MessageType) -> str:
    return MESSAGE_CLASSES[t].__name__


class FrameDecoder:
    """Turn a byte stream into messages.

    ``receive_data(data)`` appends bytes (``b""`` means EOF); ``next_event()`` returns
    the next :class:`Message`, :data:`NEED_DATA`, or :data:`CONNECTION_CLOSED` after a
    clean EOF.  Malformed input raises a ``RemoteProtocolError`` subclass; after that
    the decoder stays broken and re-raises the same error.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._eof = False
        self._header: tuple[MessageType, int, int] | None = None  # type, flags, length
        self._error: FramingError | None = None
        self._error_exc: Exception | None = None
        self.bytes_received = 0
        """Total bytes passed to :meth:`receive_data`."""

    def receive_data(self, data: bytes) -> None:
        """Feed bytes from the transport; ``b""`` signals EOF."""
        if self._eof and data:
            raise LocalProtocolError("receive_data() after EOF")
        if not data:
            self._eof = True
            return
        self.bytes_received += len(data)
        self._buf += data

    def next_event(self) -> Message | Sentinel:
        """The next message, :data:`NEED_DATA` or :data:`CONNECTION_CLOSED`."""
        if self._error_exc is not None:
            raise self._error_exc
        try:
            return self._next()
        except Exception as exc:
            self._error_exc = exc
            raise

    def _next(self) -> Message | Sentinel:
        if self._header is None:
            if len(self._buf) < HEADER_SIZE:
                return self._starved(HEADER_SIZE, "header")
            self._header = self._parse_header(bytes(self._buf[:HEADER_SIZE]))
            del self._buf[:HEADER_SIZE]
        msg_type, flags, length = self._header
        if len(self._buf) < length:
            return self._starved(length, f"{_type_name(msg_type)} body")
        body = bytes(self._buf[:length])
        del self._buf[:length]
        self._header = None
        if flags & FLAG_ZSTD:
            body = self._decompress(msg_type, body)
        return MESSAGE_CLASSES[msg_type].decode(body)

    def _starved(self, need: int, what: str) -> Sentinel:
        if not self._eof:
            return NEED_DATA
        if not self._buf and self._header is None:
            return CONNECTION_CLOSED
        raise FramingError(
            f"connection closed mid-frame: have {len(self._buf)} of {need} {what} bytes"
        )

    @staticmethod
    def _parse_header(raw: bytes) -> tuple[MessageType, int, int]:
        magic, version, type_num, flags, length = HEADER.unpack(raw)
        if magic != MAGIC:
            raise FramingError(f"bad frame magic {magic!r}, expected {MAGIC!r}")
        if version != PROTOCOL_VERSION:
            raise VersionError(
                f"peer speaks protocol version {version}, this side speaks version {PROTOCOL_VERSION}"
            )
        try:
            msg_type = MessageType(type_num)
        except ValueError:
            raise FramingError(f"unknown message type {type_num}") from None
        if flags & ~KNOWN_FLAGS:
            raise FramingError(f"{_type_name(msg_type)} frame has unknown flags 0x{flags:02x}")
        limit = MAX_BODY_SIZE[msg_type]
        if length > limit:
            raise TooLargeError(
                f"{_type_name(msg_type)} frame body of {length} bytes exceeds the limit of {limit} bytes"
            )
        return msg_type, flags, length

    @staticmethod
    def _decompress(msg_type: MessageType, body: bytes) -> bytes:
        name = _type_name(msg_type)
        limit = MAX_BODY_SIZE[msg_type]
        try:
            size = zstandard.frame_content_size(body)
        except zstandard.ZstdError:
            raise FramingError(f"{name} body is not a zstd frame") from None
        if size < 0:
            raise FramingError(f"{name} zstd frame does not declare its content size")
        if size > limit:
            raise TooLargeError(
                f"{name} body decompresses to {size} bytes, over the limit of {limit} bytes"
            )
        try:
            # With a declared content size, zstd writes into a buffer of exactly that size
            # and fails if the frame would produce more: the bomb guard.
            return _decompressor.decompress(body, max_output_size=limit)
        except zstandard.ZstdError as exc:
            raise FramingError(f"{name} body zstd decompression failed: {exc}") from None
