"""``tiny``: a method from outside splitrender, for the plug-in tests.

The server renders the predicted view, shrinks it ``factor`` times and sends the raw
pixels as a *datagram* data stream (zstd), with a frame counter on a *reliable* data
stream; the client scales the newest thumbnail back up.  It declares no video stream,
so it exercises the data paths of the pipeline end to end.
"""

from __future__ import annotations

from dataclasses import dataclass

from splitrender.errors import ConfigError
from splitrender.methods import MethodConfig, MethodSpec

__version__ = "0.1"


@dataclass(frozen=True)
class TinyConfig(MethodConfig):
    """``factor``: how many times smaller the thumbnail is on each side."""

    factor: int = 4

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 1 <= self.factor <= 16:
            raise ConfigError(f"TinyConfig.factor: must be in [1, 16], got {self.factor}")


SPEC = MethodSpec("tiny", "splitrender_tiny.server:TinyServer", "splitrender_tiny.client:TinyClient", TinyConfig,
                  "thumbnail over data streams (plug-in test method)")
