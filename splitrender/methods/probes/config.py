"""``probes`` settings, shared by the server and client halves."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

from ...errors import ConfigError
from ..base import FRAME_DIV_KNOB, Knob, MethodConfig, QualityModel, with_model

PROBE_BITS_LEVELS = (10, 6, 4)
"""``probe_bits`` levels the adaptation steps through (the configured value first, the finer ones left out)."""
PROBE_BITS_COST = (1.0, 0.91, 0.85)
"""Everything a client is sent at each ``probe_bits`` level over what it is sent at the first (the knob's prior), from
the lossless colour pictures of the default scene's 256 probes at 10, 6 and 4 bits: I-frame 48.1, 44.2 and 29.7 kB,
P-frame (an update on the walk) 2.4, 0.9 and 0.3 kB, beside the visibility (I 251 kB, P 3.8 kB), the index and the
30 fps metadata (0.63 kB a frame), an I-frame every 30 probe updates.

The four knobs' priors are from an I-frame every 30 probe updates (the ``gop`` before 300) and are kept: measured at
300 (``benchmarks/bench_adapt_probes.py --costs``: one client's server half, the walk, 3 s; first I-frame 294 kB,
P-updates 64 kB/s at the own point) they are ``probe_bits`` 0.83 and 0.77, ``vis_bits`` 0.62 and 0.60, ``probe_div``
0.74 and 0.56, ``frame_div`` 0.89, 0.85 and 0.62 (the same measurement at 30 gives these within 0.03, but 0.61 for
``frame_div`` 5), and with them ``--adapt full`` on the step trace (20/2/20 Mbit/s, 160x90) went to point 6 at 5.6 s
and scored 31.67 dB against ``off``'s 35.90 (35.44 with these: ``benchmarks/results/bench_adapt_probes.json``)."""
VIS_BITS_LEVELS = (10, 2, 1)
"""``vis_bits`` levels (the configured value first, the finer ones left out)."""
VIS_BITS_COST = (1.0, 0.56, 0.53)
"""Everything a client is sent at each ``vis_bits`` level over the first (the knob's prior), measured: bytes a server
frame 9,546, 5,304 and 5,095 (``quality_model.measure``, 0.5-2 s, one I-frame in it).  The float16 moments' bytes
go over three byte planes, so HEVC lossless finds little to take until the low byte is nearly empty: the visibility
I-frame is 251, 243, 217, 93 and 83 kB at 10, 4, 3, 2 and 1 mantissa bits."""
PROBE_DIV_STEPS = (1, 2, 4)
"""``probe_div`` levels as multiples of the configured one."""
PROBE_DIV_COST = (1.0, 0.6, 0.38)
"""Everything a client is sent at each ``probe_div`` level over the first (the knob's prior): the P-frames of the
walk without their I-frames 0.74 and 0.56 of it (a probe that changed over two or four updates costs more than over
one), the I-frames (one in 30 probe updates) a half and a quarter as often."""
FRAME_DIV_COST = (1.0, 0.95, 0.93, 0.8)
"""Everything a client is sent at each ``frame_div`` level (1, 2, 3, 5) over the first (the knob's prior; the
pipeline's :data:`~splitrender.methods.base.FRAME_DIV_KNOB` assumes one n-th, as for a method whose every frame carries
its picture): probes' frames carry the metadata (159 kbit/s at 30 fps on the walk), its probes go with each GI update
(10 Hz) whatever the frame rate down to 10 fps (572 kbit/s of P-updates, with an I-frame of 300 kB every 3 s: 1.5
Mbit/s in all), and at 6 fps the updates of two GI steps merge.  With one n-th the controller took frame_div 5 (2.68
dB) for a fifth of the bits and went there first when a queue grew."""
QUALITY = QualityModel(
    (("probe_bits", (0.0, 0.04, 0.56)), ("vis_bits", (0.0, 0.0, 0.0)), ("probe_div", (0.0, 0.0, 0.0)),
     ("frame_div", (0.0, 0.91, 1.66, 2.68))),
    latency_db_per_100ms=1.96, rate_db_per_halving=0.0,
    measured="splitrender.experiments.quality_model.measure(scene='default'), 2026-12-06: default, walk, 320x180, 2 s, "
             "delay 20ms, model PSNR after 0.5 s")
"""probes' quality model (:class:`~splitrender.methods.base.QualityModel`): model PSNR 31.950 dB at its own point;
31.91 and 31.39 at ``probe_bits`` 6 and 4 (both pictures at that precision: the visibility's part is nil); 31.9496
and 31.9495 at ``vis_bits`` 2 and 1; 31.948 and 31.947 at ``probe_div`` 2 and 4 (the walk's indirect light changes
slowly); 31.04, 30.29 and 29.27 at ``frame_div`` 2, 3 and 5 (the moving objects' transforms go with each frame);
+200 ms of motion-to-photon loses 3.92 dB (the objects and the indirect light lag; the client draws the scene itself
at the display pose); no lossy video (rate 0).  Re-measured with ``gop`` 300 (2026-12-06): 31.9497 dB at its own point,
31.393 at ``probe_bits`` 4, as at 30: a 2 s run holds 20 probe updates, so no periodic I-frame at either."""


@dataclass(frozen=True)
class ProbesConfig(MethodConfig):
    """Probe streaming settings.

    ``gi_hz``: probe updates per second (paper: 10-30; the probes are relit at scene
    times on that grid and a client sees each state at most once).  ``pvs``: ``view``
    sends only probes that light points visible from a 360-degree view at the client's
    predicted position (``pvs_res`` pixels a cube face), ``all`` every active probe.
    The probe streams are always lossless HEVC (colour 10-bit 4:4:4 RGB, visibility
    float16 bytes over 8-bit 4:4:4) whatever ``codec``, ``crf`` and ``lossless`` say;
    ``gop`` sets their I-frame distance in probe updates sent (300: one every 30 s at
    10 Hz, not the paper's 30, "a high GOP length" for "a reliable communication protocol"; a
    loss that breaks the chain or a keyframe request still restarts both pictures at
    once).  A periodic I-frame is the whole probe canvas, lossless (294 kB on the default
    walk), and at 30 it queued on a narrow link: 20/2/20 Mbit/s for 3/4/3 s (160x90,
    ``benchmarks/bench_adapt_probes.py``), ``off`` 30.61 dB model PSNR, p95
    motion-to-photon 2,100 ms, 3,114 kbit/s; at 300 35.90 dB, 306 ms, 1,646 kbit/s (and
    ``--adapt full`` 28.83 -> 35.44 dB).  ``vis_lossy`` is an ablation: the
    visibility picture goes through lossy HEVC 4:4:4 at ``crf`` (23 unless set), which
    damages the float16 bytes (light leaks: the paper's reason to keep it lossless).
    ``refresh_probes``: probes the client does not have yet (the first update, after a
    keyframe request or a reported loss) go at most this many a frame, the nearest
    first (0: all at once, as the paper).

    Per client (rate adaptation's knobs, :meth:`adapt_knobs`; the GI server still traces and codes each update once
    for every session): ``probe_div`` sends this client the probes of one GI update in ``probe_div`` (1: every one;
    the probes changed in between go with the next one sent), ``probe_bits`` and ``vis_bits`` the precision it gets
    them at: each 10-bit irradiance code rounded to ``probe_bits`` bits, each float16 distance moment's 10-bit
    mantissa to ``vis_bits`` (10 and 10: lossless, as the paper).  A probe counts as changed for this client only where
    it differs at the precision it was last sent at (or the present one, where coarser): a finer precision refines
    each probe when it next changes, not all at once.
    """

    gop: int = 300
    gi_hz: float = 10.0
    pvs: Literal["view", "all"] = "view"
    pvs_res: int = 32
    vis_lossy: bool = False
    refresh_probes: int = 0
    probe_div: int = 1
    probe_bits: int = 10
    vis_bits: int = 10

    def adapt_knobs(self) -> tuple[Knob, ...]:
        """The probes' precision (``probe_bits``, ``vis_bits``), their update rate for this client (``probe_div``), then the
        server's frame rate (the metadata of the moving objects and lights), with probes' quality model."""
        knobs: list[Knob] = []
        bits = tuple(b for b in PROBE_BITS_LEVELS if b < self.probe_bits)
        if bits:
            levels = (self.probe_bits, *bits)
            knobs.append(Knob("probe_bits", levels, PROBE_BITS_COST[:len(levels)], "data",
                              "bits of each irradiance code a client gets"))
        vis = tuple(b for b in VIS_BITS_LEVELS if b < self.vis_bits)
        if vis:
            levels = (self.vis_bits, *vis)
            knobs.append(Knob("vis_bits", levels, VIS_BITS_COST[:len(levels)], "data",
                              "mantissa bits of each float16 distance moment a client gets"))
        divs = tuple(self.probe_div * f for f in PROBE_DIV_STEPS if self.probe_div * f <= 30)
        if len(divs) > 1:
            knobs.append(Knob("probe_div", divs, PROBE_DIV_COST[:len(divs)], "data",
                              "GI updates per probe update sent to this client"))
        frame_div = dataclasses.replace(FRAME_DIV_KNOB, cost=FRAME_DIV_COST)
        return with_model((*knobs, frame_div), QUALITY)

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
        if not 1 <= self.probe_div <= 30:
            raise ConfigError(f"ProbesConfig.probe_div: must be in [1, 30], got {self.probe_div}")
        if not 4 <= self.probe_bits <= 10:
            raise ConfigError(f"ProbesConfig.probe_bits: must be in [4, 10], got {self.probe_bits}")
        if not 1 <= self.vis_bits <= 10:
            raise ConfigError(f"ProbesConfig.vis_bits: must be in [1, 10], got {self.vis_bits}")
