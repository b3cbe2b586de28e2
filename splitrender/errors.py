"""The exception hierarchy shared by every subpackage.

One root, :class:`SplitRenderError`.  Anything a peer sent us that is wrong raises a
:class:`RemoteProtocolError` subclass whose message says what was wrong and where;
our own misuse of an API raises :class:`LocalProtocolError`.  Errors that correspond
to a built-in category also subclass it (as PyAV does), so ``except ValueError``
keeps working for callers that do not know this package.
"""

from __future__ import annotations


class SplitRenderError(Exception):
    """Root of every error raised by splitrender."""


class ConfigError(SplitRenderError, ValueError):
    """A configuration value or file is invalid; the message names the key."""


class SceneError(SplitRenderError, ValueError):
    """A scene file is missing, corrupt or unsupported; the message names the file."""


class TraceError(SplitRenderError, ValueError):
    """A camera trace file is malformed; the message names the file and line."""


class RenderError(SplitRenderError, RuntimeError):
    """The renderer could not be created or failed (e.g. no EGL / OpenGL 4.3)."""


class CodecError(SplitRenderError, ValueError):
    """A video or metadata codec failed to encode or decode."""


class ProtocolError(SplitRenderError):
    """Base of protocol errors."""


class RemoteProtocolError(ProtocolError, ValueError):
    """The peer sent something invalid.  ``code`` is the wire error code to send back."""

    def __init__(self, message: str, code: int = 400) -> None:
        super().__init__(message)
        self.code = code


class LocalProtocolError(ProtocolError, RuntimeError):
    """We tried to do something the protocol does not allow in the current state."""


class ServerRefusedError(SplitRenderError):
    """The server refused or ended the session: it answered with an ``Error`` message, said ``Bye``, or closed the
    connection during the handshake (the client's handshake core, :class:`~splitrender.pipeline.ClientHandshake`,
    and the live client name which)."""


class PeerTimeoutError(SplitRenderError, TimeoutError):
    """The peer did not send what a session waited for in time; the message names what was awaited, from where and
    for how long (``no Welcome from 127.0.0.1:9100 within connect_timeout_s 5 s``).  The CLI exits 2 with it, as with
    any session error; the peer is told with ``Error`` 408 where it is still there to tell."""


class NetworkConfigError(ConfigError):
    """A network profile or netem-style string is invalid."""


def describe_error(exc: BaseException) -> str:
    """A failure of ours in one line for a peer or a log: the message of a ``SplitRenderError``, else the
    class name and message (``RuntimeError: ...``)."""
    text = str(exc)
    if isinstance(exc, SplitRenderError) and text:
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


class WorkerError(SplitRenderError):
    """A request failed inside a render worker (the worker keeps running); the text names the cause."""


class WorkerTimeout(SplitRenderError):
    """A render worker's request missed its deadline; the worker was killed."""


class WorkerDied(SplitRenderError):
    """A render worker process ended (crashed, was killed, or was closed) while requests were pending."""
