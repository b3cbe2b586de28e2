"""The live headless client's settings (``client`` on the command line; :class:`~splitrender.client.session.LiveClient`
runs them), as :class:`~splitrender.sim.config.RunConfig` holds a virtual-time run's.  The session options are
its fields from their one declaration (:mod:`splitrender.options`)."""

from __future__ import annotations

import ssl
from dataclasses import dataclass
from pathlib import Path

from splitrender.errors import ConfigError
from splitrender.limits import DEFAULT_CLIENT_LIMITS, ClientLimits
from splitrender.options import ClientOptions, option_fields, options_of
from splitrender.pipeline.session import CLIENT_CODECS

__all__ = ["ClientConfig"]


@dataclass(frozen=True)
@option_fields(ClientOptions)
class ClientConfig:
    """Settings of a live client.  Times in seconds unless the name says ms.

    The session options (:class:`~splitrender.pipeline.ClientOptions`: loss recovery, reports, playout delay,
    stalls) are fields too, from their one declaration (:mod:`splitrender.options`).

    ``udp_port`` overrides the server UDP port from Welcome (to go through a relay).
    ``methods`` are offered in preference order.
    """

    server: str = "127.0.0.1"
    port: int = 9100
    udp_port: int | None = None
    token: str = ""
    methods: tuple[str, ...] = ("video",)
    codecs: tuple[str, ...] = CLIENT_CODECS
    width: int = 640
    height: int = 360
    display_hz: float = 60.0
    tracker_hz: float = 120.0
    trace: str = "walk"
    duration_s: float = 10.0
    out_dir: Path | None = None
    save_images: bool = False
    connect_timeout_s: float = 5.0
    limits: ClientLimits = DEFAULT_CLIENT_LIMITS
    """What this client accepts from a server: stream and session-data sizes, pending frames, probes, scene size
    (:class:`~splitrender.limits.ClientLimits`); a server declaring more is refused with an error naming it."""
    rows_kept: int = 4096
    """Displayed rows kept in memory (``ClientResult.rows``: the newest); the recording has every row, appended to
    ``frames.jsonl`` as it is shown, so memory stays flat however long the session."""
    metrics_interval_s: float = 5.0
    """Log a ``metrics`` line (the counters, the jitter buffers' drops included) this often; 0 = never."""
    tls: bool = False
    """Connect to the control port over TLS (``client --tls``; the server runs ``serve --tls-cert``), verifying the
    server's certificate and that it names ``server`` (host name or IP address), against ``tls_ca`` or the system's
    trusted CAs."""
    tls_ca: Path | None = None
    """With ``tls``: the PEM CA certificate(s) to trust instead of the system's (``client --tls-ca``)."""

    def __post_init__(self) -> None:
        self.options()   # raises ConfigError naming a bad option
        if isinstance(self.rows_kept, bool) or not isinstance(self.rows_kept, int) or self.rows_kept < 1:
            raise ConfigError(f"client rows_kept: must be a positive integer, got {self.rows_kept!r}")
        self.tls_context()   # an unreadable or non-PEM CA file fails here, by path

    def tls_context(self) -> ssl.SSLContext | None:
        """The TLS context the control connection uses (``tls``), or ``None``; raises ``ConfigError``."""
        if self.tls_ca is not None and not self.tls:
            raise ConfigError(f"client tls_ca {self.tls_ca}: a CA to verify the server by, so it needs tls")
        if not self.tls:
            return None
        from splitrender.transport.tls import client_context

        return client_context(self.tls_ca)

    def options(self) -> ClientOptions:
        """The session core's options (the same ones ``splitrender run`` takes)."""
        return options_of(self, ClientOptions, limits=self.limits)
