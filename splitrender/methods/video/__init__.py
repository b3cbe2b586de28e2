"""``video``: plain remote rendering.  The server renders a colour frame at the predicted
pose; the client shows the newest decoded frame whatever its pose (the baseline every
paper compares against)."""

from __future__ import annotations

from dataclasses import dataclass

from ..base import SCALE_KNOB, Knob, MethodConfig, MethodSpec, QualityModel, register_method, with_model

QUALITY = QualityModel(
    (("scale", (0.0, -1.49, -1.33)),),
    latency_db_per_100ms=2.57, rate_db_per_halving=0.20,
    measured="benchmarks/bench_knobs.py --quality, 2026-12-06, fb7ffbf: default+nogi, walk, 320x180, 2 s, delay 20ms, model PSNR after 0.5 s")
"""video's quality model (:class:`~splitrender.methods.base.QualityModel`): model PSNR 19.62 dB at its own point;
a smaller picture measures *better* (21.11 and 20.96 dB: under the misalignment 92 ms of motion-to-photon leaves, a
blur scores better; the controller counts no level as a gain); 120 ms each way instead of 20 (+200 ms
motion-to-photon) loses 5.14 dB; crf 29 (0.56x the bits) 0.16 dB."""


@dataclass(frozen=True)
class VideoConfig(MethodConfig):
    """Plain streaming: only the common codec settings, with 4:4:4 colour by default (``chroma``: at the bits of
    4:2:0 it gives the model +1.8 dB, the whole frame +1.6 dB, median of 12 cells, ``benchmarks/bench_chroma.py``)."""

    chroma: str | int = "444"

    def adapt_knobs(self) -> tuple[Knob, ...]:
        """The pipeline's resolution scale, with video's quality model."""
        return with_model((SCALE_KNOB,), QUALITY)


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
