"""Measuring a method's quality model: model PSNR against each operating-point knob, latency and the encoders' rate
(issue 48, part 2).

Each figure is one short virtual-time run against the method's own point on the same link (``default+nogi``, the
``walk`` trace, 320x180, a 30 Hz display, ``delay 20ms`` each way, no capacity limit, no adaptation), its mean model
PSNR over the frames shown after ``SKIP_S`` (the first IDR and the caches filling left out):

- a **knob** at one of its levels, the others at their first: the point is fixed for the whole run (the session
  core's operating point is pinned, :func:`pinned_point`), so the method's own knobs, the pipeline's ``scale`` and
  ``frame_div`` are measured the same way, through the same code ``--adapt full`` drives;
- **latency**: ``delay 20ms`` -> ``LATE_DELAY_MS`` each way; its figure is dB per 100 ms of motion-to-photon added
  (both runs' mean);
- **the encoders' rate**: crf + ``CRF_STEP`` (the lossy video streams' bits roughly halve); its figure is dB per
  halving of the lossy video streams' bytes (measured, not assumed).

``benchmarks/bench_knobs.py --quality`` runs every method's points and writes what the methods' tables store
(:class:`~splitrender.methods.base.QualityModel`); ``tests/test_adapt_quality.py`` re-measures a few.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np

SKIP_S = 0.5
"""Seconds left out at the start of each run."""
LATE_DELAY_MS = 120.0
"""One-way delay of the latency run (ms; the reference run has 20)."""
CRF_STEP = 6.0
"""crf added for the encoders' rate run (x264/x265: about half the bits)."""
LOSSY = ("color", "color0", "color1", "atlas")
"""The methods' lossy video streams (their bytes are the encoders' rate)."""


@dataclass(frozen=True)
class PointRun:
    """One run's figures: mean model PSNR (dB) and motion-to-photon (ms) after ``SKIP_S``, lossy video bytes per
    server frame sent and every stream's."""

    model_psnr_db: float
    mtp_ms: float
    video_bytes: float
    all_bytes: float


@contextlib.contextmanager
def pinned_point(point: dict[str, Any]) -> Iterator[None]:
    """Within the block every server session runs at ``point`` (knob name -> value; ``frame_div`` leaves ticks
    out as the controller does), whatever its adaptation mode."""
    from ..pipeline.session import ServerSession

    op, sk = ServerSession.operating_point, ServerSession.skips
    div = int(point.get("frame_div", 1))
    ServerSession.operating_point = lambda self, now_ms: dict(point)       # type: ignore[method-assign,assignment]
    ServerSession.skips = lambda self, tick: tick % div != 0               # type: ignore[method-assign,assignment]
    try:
        yield
    finally:
        ServerSession.operating_point = op                                 # type: ignore[method-assign]
        ServerSession.skips = sk                                           # type: ignore[method-assign]


def measure(method: str, point: dict[str, Any] | None = None, delay_ms: float = 20.0, crf_step: float = 0.0,
            duration_s: float = 2.0, size: tuple[int, int] = (320, 180), renderer: Any = None,
            truth_cache: str = "", scene: str = "default+nogi") -> PointRun:
    """One run of ``method`` at ``point`` (None: its own), ``delay_ms`` each way, its crf raised by ``crf_step``, on
    ``scene`` (``probes`` needs one with GI: ``default``)."""
    from ..methods import get_method, make_config
    from ..sim.config import RunConfig
    from ..sim.runner import run

    params: dict[str, Any] = {}
    if crf_step:
        crf = make_config(get_method(method).config, {}).crf
        params["crf"] = float(crf) + crf_step
    cfg = RunConfig(method=method, scene=scene, trace="walk", network=f"delay {delay_ms:g}ms",
                    duration_s=duration_s, width=size[0], height=size[1], client_fps=30, flip_every=0, seed=0,
                    method_params=params, truth_cache=truth_cache)
    with pinned_point(point) if point else contextlib.nullcontext():
        res = run(cfg, renderer=renderer)
    fr = [f for f in res.frames if f["t_s"] >= SKIP_S]
    psnr = np.array([f.get("model_psnr_db", np.nan) for f in fr], float)
    mtp = np.array([f["motion_to_photon_ms"] for f in fr], float)
    ups = [u for u in res.updates if u["t_s"] >= SKIP_S]
    video = sum(v for u in ups for k, v in u.items() if k.startswith("bytes_") and k[6:] in LOSSY)
    every = sum(v for u in ups for k, v in u.items() if k.startswith("bytes_") and k != "bytes_probe")
    n = max(1, len(ups))
    return PointRun(float(np.nanmean(psnr)), float(np.nanmean(mtp)), video / n, every / n)


def latency_db_per_100ms(ref: PointRun, late: PointRun) -> float:
    """Model PSNR lost per 100 ms of motion-to-photon added (>= 0)."""
    return max(0.0, (ref.model_psnr_db - late.model_psnr_db) / max(1e-6, late.mtp_ms - ref.mtp_ms) * 100)


def rate_db_per_halving(ref: PointRun, coarse: PointRun) -> float:
    """Model PSNR lost per halving of the lossy video streams' bytes (>= 0; 0 without lossy video)."""
    if ref.video_bytes <= 0 or coarse.video_bytes <= 0 or coarse.video_bytes >= ref.video_bytes:
        return 0.0
    return max(0.0, (ref.model_psnr_db - coarse.model_psnr_db) / math.log2(ref.video_bytes / coarse.video_bytes))
