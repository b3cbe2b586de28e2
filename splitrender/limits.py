"""What a client accepts from a server: limits on everything a server declares.

A server's ``Welcome`` and session data declare sizes (stream ``max_bytes``, session data
bytes, probe grid counts, scene triangles) that the client then allocates for.  A client
does not take a server's word for them: :class:`ClientLimits` caps each, and a session
that declares more is refused with an error naming the field and the limit.  The
defaults fit every built-in method at 4K with room to spare; ``splitrender client`` and
:class:`~splitrender.client.session.ClientConfig` can change them.

The same table is in ``docs/protocol.md`` (Limits).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from .errors import ConfigError

__all__ = ["ClientLimits", "DEFAULT_CLIENT_LIMITS"]


@dataclass(frozen=True)
class ClientLimits:
    """Caps on what a server may declare or make a client hold at once."""

    max_stream_bytes: int = 64 * 1024 * 1024
    """A data stream's ``max_bytes`` (one frame's payload, decompressed) in the Welcome stream table."""
    max_session_bytes: int = 256 * 1024 * 1024
    """``session_data_bytes``: the session data after Welcome, compressed as sent."""
    max_pending_frames: int = 64
    """Frames announced (FrameMeta) and not yet released; the oldest is given up (counted lost) beyond it."""
    max_pending_bytes: int = 128 * 1024 * 1024
    """Bytes announced for reliable data still being assembled, over all pending frames."""
    max_video_pixels: int = 4096 * 4096
    """A video stream's width x height in the Welcome stream table."""
    max_probes: int = 32 * 32 * 32
    """DDGI probes in a probe grid the server declares (product of its three counts)."""
    max_scene_triangles: int = 4_000_000
    """Triangles in a scene the server sends (methods whose client draws the scene)."""
    max_scene_objects: int = 65_535
    """Objects in that scene."""

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ConfigError(f"client limits: {f.name} must be a positive integer, got {v!r}")

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ClientLimits:
        """From a ``[limits]`` table; an unknown key is an error naming it."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ConfigError(f"client limits: unknown key(s) {unknown}; known: {sorted(names)}")
        return cls(**d)


DEFAULT_CLIENT_LIMITS = ClientLimits()
