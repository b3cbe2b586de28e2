"""What a client accepts from a server: limits on everything a server declares.

A server's ``Welcome`` and session data declare sizes (stream ``max_bytes``, session data
bytes, probe grid counts, scene triangles) that the client then allocates for.  A client
does not take a server's word for them: :class:`ClientLimits` caps each, and a session
that declares more is refused with an error naming the field and the limit.  ``splitrender
client`` (``--limit KEY=N``) and :class:`~splitrender.client.session.ClientConfig` can change them.

A method's config sizes client memory too (warp's reference image and mesh, atw's overscanned
frame, the sas, tss and quads atlases): each config says what it makes a client of a given
display hold (:meth:`~splitrender.methods.base.MethodConfig.client_sizes`, a tuple of
:class:`ClientSize`), and :func:`check_client_sizes` holds them to these limits when the client
takes the Welcome, before anything is allocated (:class:`ClientLimitError`, 413, naming the
config field).

The same table is in ``docs/protocol.md`` (Limits).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass, fields
from typing import Any

from .errors import ConfigError, RemoteProtocolError

__all__ = ["ClientLimitError", "ClientLimits", "ClientSize", "DEFAULT_CLIENT_LIMITS", "check_client_sizes"]

TOO_LARGE = 413
"""The wire error code of a refusal (``ErrorCode.TOO_LARGE``; this module sits below :mod:`splitrender.protocol`)."""


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
    max_reference_pixels: int = 4096 * 4096
    """Pixels of the reference images a method's config makes the client hold for one server frame, all views
    together: warp's ``views`` x its reference image (``fov_scale`` x ``resolution_scale`` times the display along
    each axis), atw's frame ``overscan`` times the display along each axis."""
    max_atlas_pixels: int = 4096 * 4096
    """Texels of the atlas a method's config makes the client hold: sas (``atlas_mpix_1080p`` scaled to the display,
    or ``atlas_width`` x ``atlas_height``), tss (``atlas_mpix_1080p``), quads (a display-sized slot per layer and
    view, or QuadStream's packed atlas)."""
    max_mesh_vertices: int = 2048 * 2048
    """Vertices of a mesh a method's client builds from its config before any frame arrives: warp's
    ``reconstruction = "mesh"`` grid, one vertex per reference pixel and a ring on the border (24 bytes of
    indices per vertex)."""

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

    def to_dict(self) -> dict[str, int]:
        """The ``[limits]`` table of these limits (:meth:`from_dict` reads it back)."""
        return asdict(self)


DEFAULT_CLIENT_LIMITS = ClientLimits()


class ClientLimitError(RemoteProtocolError):
    """A server's Welcome sizes more client memory than this client's :class:`ClientLimits` allow (413); the
    message names the config field, what it sizes, and the limit."""

    def __init__(self, message: str) -> None:
        super().__init__(message, TOO_LARGE)


@dataclass(frozen=True)
class ClientSize:
    """One amount a method's config makes a client hold, checked against one :class:`ClientLimits` field.

    ``field``: the config field named in a refusal (the one that set the amount); ``limit``: the
    :class:`ClientLimits` field that caps it; ``amount`` in ``unit`` (``pixels``, ``texels``, ``vertices``,
    ``triangles``); ``what``: the thing, with the values that sized it (``the warp reference image 3840x2160
    (fov_scale 6 x resolution_scale 4 at a 160x90 display)``)."""

    field: str
    limit: str
    amount: int
    unit: str
    what: str


def _count(n: int) -> str:
    """``8.3 M`` above a million, else the number."""
    return f"{n / 1e6:.1f} M" if n >= 1_000_000 else str(n)


def check_client_sizes(sizes: Iterable[ClientSize], limits: ClientLimits,
                       where: str = "Welcome.method_params.config") -> None:
    """Every size within ``limits``; :class:`ClientLimitError` for the first that is not, naming ``where.field``."""
    for s in sizes:
        cap = getattr(limits, s.limit)
        if s.amount > cap:
            raise ClientLimitError(f"{where}.{s.field}: {s.what} is {_count(s.amount)} {s.unit}, over this client's "
                                   f"limit {s.limit} {cap}")
