"""TLS for the TCP control channel and the browser page (``serve --tls-cert/--tls-key``, ``client --tls``).

Contexts are built and their files checked when a server or client is configured, so a missing file, a key that
does not belong to its certificate or a CA file that is not PEM fails at start with a :class:`ConfigError` naming
the path, not at the first connection.  Clients verify the server's certificate and its name (the host they
connect to, a DNS name or an IP address in the certificate's subjectAltName) against ``--tls-ca`` or, without it,
the system's trusted CAs.  The RTP/RTCP datagrams stay plain UDP (as RTP without SRTP); WebRTC's media are
DTLS-SRTP already.
"""

from __future__ import annotations

import ssl
from pathlib import Path

from splitrender.errors import ConfigError

from .errors import describe_os_error, describe_tls_error

__all__ = ["server_context", "client_context", "describe_tls_error"]

_CERT_BLOCK = b"-----BEGIN CERTIFICATE-----"


def _read_pem(option: str, path: Path, what: str) -> bytes:
    """The bytes of ``path`` if it is a readable file holding a PEM ``what`` block; raises ``ConfigError``."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ConfigError(f"{option} {path}: cannot read it: {describe_os_error(exc)}") from None
    marker = _CERT_BLOCK if what == "certificate" else b"PRIVATE KEY-----"
    if marker not in data:
        raise ConfigError(f"{option} {path}: not a PEM {what} (no '{marker.decode().strip('-')}' block)")
    return data


def server_context(cert: Path, key: Path) -> ssl.SSLContext:
    """A server context (TLS 1.2 or newer) from a PEM certificate chain and its PEM private key; raises
    ``ConfigError`` naming the path and what was wrong (missing, unreadable, not PEM, encrypted, not matching)."""
    _read_pem("--tls-cert", cert, "certificate")
    key_pem = _read_pem("--tls-key", key, "private key")
    encrypted = ConfigError(f"--tls-key {key}: the key is passphrase-protected, which serve cannot prompt for "
                            "(write it out unencrypted, e.g. openssl pkey -in KEY -out PLAIN)")
    if b"ENCRYPTED" in key_pem:
        raise encrypted

    def no_passphrase() -> bytes:   # OpenSSL asks for one: never prompt on the terminal
        raise encrypted

    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        ctx.load_cert_chain(str(cert), str(key), password=no_passphrase)
    except ssl.SSLError as exc:
        if exc.reason == "KEY_VALUES_MISMATCH":
            raise ConfigError(f"--tls-key {key}: does not match the certificate in --tls-cert {cert}") from None
        raise ConfigError(f"--tls-cert {cert} / --tls-key {key}: cannot load them ({_reason(exc)})") from None
    return ctx


def client_context(ca: Path | None = None) -> ssl.SSLContext:
    """A client context that verifies the server's certificate and host name: against the PEM CA certificates in
    ``ca``, or the system's trusted CAs when ``None``; raises ``ConfigError`` naming a bad ``ca`` file."""
    if ca is None:
        return ssl.create_default_context(ssl.Purpose.SERVER_AUTH)
    _read_pem("--tls-ca", ca, "certificate")
    try:
        ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH, cafile=str(ca))
    except ssl.SSLError as exc:
        raise ConfigError(f"--tls-ca {ca}: cannot load its certificates ({_reason(exc)})") from None
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    return ctx


def _reason(exc: ssl.SSLError) -> str:
    """OpenSSL's reason in words (``EE_KEY_TOO_SMALL`` -> ``ee key too small``)."""
    if exc.reason:
        return exc.reason.lower().replace("_", " ")
    if "PEM lib" in str(exc):   # OpenSSL gives no reason for a block that does not decode
        return "a PEM block that does not decode"
    return str(exc)
