"""Socket failures of the live server and client, as :class:`SplitRenderError`.

They also subclass the matching built-in (``OSError`` / ``ConnectionError``), so
``except OSError`` keeps working; the message names the address and says what failed,
which is what ``splitrender: error: ...`` prints.
"""

from __future__ import annotations

import os
import socket
import ssl

from splitrender.errors import SplitRenderError

__all__ = ["BindError", "ConnectError", "describe_os_error", "describe_tls_error"]


class BindError(SplitRenderError, OSError):
    """A listening socket could not be opened (address in use, bad host or port)."""


class ConnectError(SplitRenderError, ConnectionError):
    """The server could not be reached, refused the connection, or went away."""


def describe_os_error(exc: BaseException) -> str:
    """A one-line reason for a socket error, without the ``[Errno N]`` prefix."""
    if isinstance(exc, ssl.SSLError):  # before OSError: its errno is OpenSSL's, not the system's
        return describe_tls_error(exc)
    if isinstance(exc, TimeoutError):  # before OSError: it has no errno
        return "timed out"
    if isinstance(exc, socket.gaierror):
        return f"cannot resolve host ({exc.strerror or exc})"
    if isinstance(exc, OSError) and isinstance(exc.errno, int) and exc.errno > 0:
        text = os.strerror(exc.errno)  # asyncio's strerror adds "Connect call failed (...)"
        return text[0].lower() + text[1:]
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror[0].lower() + exc.strerror[1:]
    if isinstance(exc, OverflowError):  # socket's "bind(): port must be 0-65535."
        return "port must be in [0, 65535]"
    return str(exc) or type(exc).__name__


def describe_tls_error(exc: ssl.SSLError) -> str:
    """A one-line reason for a TLS failure: what certificate verification said, or OpenSSL's reason in words."""
    if isinstance(exc, ssl.SSLCertVerificationError):
        return f"TLS certificate verification failed: {exc.verify_message or exc.reason}"
    reason = exc.reason or ""
    if reason == "WRONG_VERSION_NUMBER":
        return "TLS handshake failed: the peer does not speak TLS (wrong version number)"
    if isinstance(exc, ssl.SSLEOFError) or reason == "UNEXPECTED_EOF_WHILE_READING":
        return "TLS handshake failed: the peer closed the connection (does it speak TLS?)"
    return f"TLS failed: {reason.lower().replace('_', ' ') if reason else exc}"
