"""Protocol error classes and wire error codes.

Every error caused by peer input is a :class:`~splitrender.errors.RemoteProtocolError`
subclass whose ``code`` is the :class:`ErrorCode` to send back in an ``Error`` message.
"""

from __future__ import annotations

from enum import IntEnum

from splitrender.errors import RemoteProtocolError

__all__ = [
    "ErrorCode",
    "FramingError",
    "MessageError",
    "VersionError",
    "TooLargeError",
    "StateError",
    "UnauthorizedError",
    "UnsupportedMethodError",
    "RtpError",
    "RtcpError",
    "PayloadError",
    "SdpError",
]


class ErrorCode(IntEnum):
    """Codes carried by the ``Error`` message (HTTP-like numbers)."""

    BAD_MESSAGE = 400
    UNAUTHORIZED = 401
    TIMEOUT = 408
    """The peer stopped sending what the session needs (a client whose stream stalled past its timeout)."""
    ILLEGAL_STATE = 409
    TOO_LARGE = 413
    UNSUPPORTED_METHOD = 415
    INTERNAL = 500
    BAD_VERSION = 505


class FramingError(RemoteProtocolError):
    """A TCP frame header or body envelope (magic, flags, length, zstd) is invalid."""

    def __init__(self, message: str, code: int = ErrorCode.BAD_MESSAGE) -> None:
        super().__init__(message, int(code))


class TooLargeError(FramingError):
    """A frame is larger than the limit of its message type."""

    def __init__(self, message: str) -> None:
        super().__init__(message, ErrorCode.TOO_LARGE)


class VersionError(FramingError):
    """The peer speaks a protocol version we do not."""

    def __init__(self, message: str) -> None:
        super().__init__(message, ErrorCode.BAD_VERSION)


class MessageError(RemoteProtocolError):
    """A message body is not valid msgpack or a field has the wrong type or range."""

    def __init__(self, message: str) -> None:
        super().__init__(message, int(ErrorCode.BAD_MESSAGE))


class StateError(RemoteProtocolError):
    """The peer sent a message that is illegal in the current session state."""

    def __init__(self, message: str) -> None:
        super().__init__(message, int(ErrorCode.ILLEGAL_STATE))


class UnauthorizedError(RemoteProtocolError):
    """The auth token in ``Hello`` is wrong."""

    def __init__(self, message: str) -> None:
        super().__init__(message, int(ErrorCode.UNAUTHORIZED))


class UnsupportedMethodError(RemoteProtocolError):
    """None of the methods offered in ``Hello`` is supported by the server."""

    def __init__(self, message: str) -> None:
        super().__init__(message, int(ErrorCode.UNSUPPORTED_METHOD))


class RtpError(RemoteProtocolError):
    """An RTP packet header is malformed."""


class RtcpError(RemoteProtocolError):
    """An RTCP packet is malformed."""


class PayloadError(RemoteProtocolError):
    """An H.264 / H.265 RTP payload is malformed (RFC 6184 / RFC 7798)."""


class SdpError(RemoteProtocolError):
    """An SDP description is malformed (e.g. bad base64 in sprop parameter sets)."""
