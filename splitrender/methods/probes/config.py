"""``probes`` settings, shared by the server and client halves."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ...errors import ConfigError
from ..base import MethodConfig


@dataclass(frozen=True)
class ProbesConfig(MethodConfig):
    """Probe streaming settings.

    ``gi_hz``: probe updates per second (paper: 10-30; the probes are relit at scene
    times on that grid and a client sees each state at most once).  ``pvs``: ``view``
    sends only probes that light points visible from a 360-degree view at the client's
    predicted position (``pvs_res`` pixels a cube face), ``all`` every active probe.
    The probe streams are always lossless HEVC (colour 10-bit 4:4:4 RGB, visibility
    float16 bytes over 8-bit 4:4:4) whatever ``codec``, ``crf`` and ``lossless`` say;
    ``gop`` (30) sets their I-frame distance.  ``vis_lossy`` is an ablation: the
    visibility picture goes through lossy HEVC 4:4:4 at ``crf`` (23 unless set), which
    damages the float16 bytes (light leaks: the paper's reason to keep it lossless).
    ``refresh_probes``: probes the client does not have yet (the first update, after a
    keyframe request or a reported loss) go at most this many a frame, the nearest
    first (0: all at once, as the paper).
    """

    gi_hz: float = 10.0
    pvs: Literal["view", "all"] = "view"
    pvs_res: int = 32
    vis_lossy: bool = False
    refresh_probes: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0.5 <= self.gi_hz <= 120.0:
            raise ConfigError(f"ProbesConfig.gi_hz: must be in [0.5, 120], got {self.gi_hz}")
        if self.pvs not in ("view", "all"):
            raise ConfigError(f"ProbesConfig.pvs: {self.pvs!r} is not one of ['view', 'all']")
        if not 0 <= self.refresh_probes <= 65535:
            raise ConfigError(f"ProbesConfig.refresh_probes: must be in [0, 65535], got {self.refresh_probes}")
        if not 8 <= self.pvs_res <= 256:
            raise ConfigError(f"ProbesConfig.pvs_res: must be in [8, 256], got {self.pvs_res}")
