"""``video``: plain remote rendering.  The server renders a colour frame at the predicted
pose; the client shows the newest decoded frame whatever its pose (the baseline every
paper compares against)."""

from __future__ import annotations

from dataclasses import dataclass

from ..base import MethodConfig, MethodSpec, register_method


@dataclass(frozen=True)
class VideoConfig(MethodConfig):
    """Plain streaming: only the common codec settings, with 4:4:4 colour by default (``chroma``: at the bits of
    4:2:0 it gives the model +1.8 dB, the whole frame +1.6 dB, median of 12 cells, ``benchmarks/bench_chroma.py``)."""

    chroma: str | int = "444"


SPEC = register_method(MethodSpec("video", "splitrender.methods.video.server:VideoServer",
                                  "splitrender.methods.video.client:VideoClient", VideoConfig, "plain video of the predicted view"))


def __getattr__(attr: str) -> object:
    """The halves, loaded on first use (importing the client never imports the server)."""
    if attr == "VideoServer":
        from .server import VideoServer

        return VideoServer
    if attr == "VideoClient":
        from .client import VideoClient

        return VideoClient
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")
