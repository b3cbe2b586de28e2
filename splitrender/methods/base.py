"""The method interface: a server half, a client half and what passes between them.

A method is one package (or module) with two halves that share nothing but the wire
format (DESIGN.md):

- :class:`ServerHalf` turns a :class:`ServerContext` (scene at time t, the client's
  newest pose, a pose predictor, the client's :class:`ClientFeedback`, and whatever the
  method's :class:`SceneProducer` prepared for this frame) into an :class:`Update`: one
  payload per declared stream (an image plane for a :class:`StreamSpec` video stream,
  bytes for a :class:`DataStreamSpec` data stream) plus msgpack-able metadata;
- the transmission path (:mod:`splitrender.pipeline`, the same code in virtual time
  and live) encodes every payload, counts the bytes that cross the wire, sends them
  over RTP or the control channel, and hands the client a :class:`DecodedUpdate`
  per server frame, naming the streams that did not arrive (``missing``);
- :class:`ClientHalf` applies updates to its cache and renders a :class:`ClientFrame`
  for any pose and time, in its own GL context.

A :class:`SceneProducer` does the scene-level work of a method once per server frame
for every session (patch building, probe tracing); per-client halves do the rest.

The client half never sees the scene, the renderer or the uncompressed payloads; all it
gets at start is ``ServerHalf.session_data()`` (msgpack-able, counted as bytes too).
Methods are found through the ``splitrender.methods`` entry-point group (see
:mod:`splitrender.methods`); a :class:`MethodSpec` names its halves as classes or as
``"module:attribute"`` strings, so importing a client half never imports its server.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import logging
import typing
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Literal, Union

import numpy as np

from ..codecs.video import VideoCodecConfig
from ..coerce import coerce_value
from ..errors import ConfigError
from ..limits import DEFAULT_CLIENT_LIMITS, ClientLimits, ClientSize, check_client_sizes
from ..scene.pose import CameraIntrinsics, Pose

if TYPE_CHECKING:
    from ..scene.model import Scene

log = logging.getLogger(__name__)

DEFAULT_DATA_MAX_BYTES = 64 * 1024 * 1024
"""Largest payload of one data stream per frame unless the stream says otherwise."""


@dataclass(frozen=True)
class StreamSpec:
    """One video stream a method sends: a name, a codec configuration and a plane size."""

    name: str
    codec: VideoCodecConfig
    width: int
    height: int
    kind: Literal["video"] = "video"
    scalable: bool = False
    """Colour whose resolution rate adaptation may lower (``--adapt full``'s ``scale`` knob): the server codes a
    smaller picture and the client's pipeline brings it back to this size (:mod:`splitrender.codecs.resize`).  Not
    for atlases (a patch's texels would bleed into the next) nor depth."""

    def __post_init__(self) -> None:
        if not self.name.isidentifier() or self.name in RESERVED_STREAMS:
            raise ConfigError(f"stream name {self.name!r} must be an identifier other than {RESERVED_STREAMS}")
        if self.width % 2 or self.height % 2 or self.width <= 0 or self.height <= 0:
            raise ConfigError(f"stream {self.name}: size {self.width}x{self.height} must be positive and even")


@dataclass(frozen=True)
class DataStreamSpec:
    """One data stream: bytes per frame, compressed, over a delivery class.

    ``delivery``: ``reliable`` (control channel, TCP: in order, never lost, head-of-line
    blocked) or ``datagram`` (RTP over UDP with the splitrender data payload format:
    fast, may be lost whole).  ``compression``: ``zstd`` (level ``level``) or ``none``.
    ``max_bytes`` bounds one frame's payload before and after compression on both ends.
    """

    name: str
    delivery: Literal["reliable", "datagram"] = "reliable"
    compression: Literal["zstd", "none"] = "zstd"
    level: int = 3
    max_bytes: int = DEFAULT_DATA_MAX_BYTES
    kind: Literal["data"] = "data"

    def __post_init__(self) -> None:
        if not self.name.isidentifier() or self.name in RESERVED_STREAMS:
            raise ConfigError(f"stream name {self.name!r} must be an identifier other than {RESERVED_STREAMS}")
        if self.delivery not in ("reliable", "datagram"):
            raise ConfigError(f"data stream {self.name}: delivery {self.delivery!r} is not one of ['reliable', 'datagram']")
        if self.compression not in ("zstd", "none"):
            raise ConfigError(f"data stream {self.name}: compression {self.compression!r} is not one of ['zstd', 'none']")
        if not 0 < self.max_bytes <= 1 << 31:
            raise ConfigError(f"data stream {self.name}: max_bytes must be in (0, 2 GiB], got {self.max_bytes}")


AnyStreamSpec = Union[StreamSpec, DataStreamSpec]


REFERENCE_MTP_MS = 100.0
"""The motion-to-photon budget video keeps (``AdaptConfig.mtp_budget_ms``): what its queueing may cost it."""
REFERENCE_LATENCY_DB_PER_100MS = 2.57
"""video's measured model PSNR lost per 100 ms of motion-to-photon (its :class:`QualityModel`): a method's latency
tolerance is the queueing that costs it what ``REFERENCE_MTP_MS`` costs video."""
TOLERANCE_MS = (100.0, 300.0)
"""Bounds of a method's latency tolerance (ms): at least video's budget; at most 300, where the stress suite's
capacity drop keeps every method's oldest update shown under its bound (420 ms for sas and quads, 460 for tss,
``tests/test_stress.py``) and a queue is far from a 500 ms freeze."""


QUEUE_TOLERANT_ESTIMATOR: tuple[tuple[str, Any], ...] = (("start_probes", (3.0, 6.0, 12.0, 24.0)), ("acked_cap", 2.0),
                                                        ("probe_interval_s", 1.0))
"""The send-rate estimator of an adapting sas or tss session (:attr:`QualityModel.estimator`, fields of
:class:`~splitrender.pipeline.gcc.GccConfig`): a method that redraws geometry at the display pose takes the queue an
estimate that runs ahead may leave, where video and atw show it as latency.  Start-up probes at 3x to 24x the start
rate (to 7.2 Mbit/s, back to back: the estimate found within the first feedback, where tss's atlas's first I-frames
were coded under ceilings of 0.27-3.5 Mbit/s); an increase up to twice the acknowledged rate, not 1.5 (an
application-limited session at one frame in 2 held its estimate at 1.5x what that point sends); a periodic probe every
second, not two.  Measured on tss on the 8 Mbit/s cellular-like trace (8 s, ``bench_adapt_quality``'s run,
2026-12-07, 99f0add plus the change): 26.86 dB without them, 27.73 with the probes alone, 27.90 with all three
(``off`` 28.90), 27.48 with a gentler decrease (``beta`` 0.9) as well; sas on it -0.24 -> -0.17 dB against ``off``."""


@dataclass(frozen=True)
class QualityModel:
    """What a method's operating points and latency cost in model PSNR, for rate adaptation (``--adapt full``,
    :class:`~splitrender.pipeline.adapt.PointController`; issue 48).

    ``knob_db``: per knob name, the model PSNR (dB) lost at each of its levels against its first (0 first), the other
    knobs at their first; ``latency_db_per_100ms``: model PSNR lost per 100 ms of motion-to-photon added;
    ``rate_db_per_halving``: lost per halving of the lossy video streams' bits (their encoders squeezed below the
    method's own crf); ``measured``: where the figures come from (:mod:`splitrender.experiments.quality_model`,
    ``benchmarks/bench_knobs.py --quality``).  The losses of two knobs add (each was measured alone)."""

    knob_db: tuple[tuple[str, tuple[float, ...]], ...]
    latency_db_per_100ms: float
    rate_db_per_halving: float
    measured: str = ""
    estimator: tuple[tuple[str, Any], ...] = ()
    """``(field, value)`` pairs of :class:`~splitrender.pipeline.gcc.GccConfig` that an adapting session of the
    method (``adapt = "full"``) sets on its send-rate estimator: a method that redraws geometry at the display pose
    tolerates the queue a bigger start-up probe or a faster climb may leave, where video and atw show it as latency
    (empty: the estimator's own).  sas and tss set one; quads and warp, whose adaptive runs hold their targets with
    GCC's own, do not (with tss's, warp's oldest update shown in the quick stress suite's capacity drop was 333 ms
    against its 292 ms bound, quads's 367 against 375)."""

    track_cap: bool = False
    """The rate controller keeps learning what the method's own operating point sends after its calibration
    (:attr:`~splitrender.pipeline.adapt.RateController.track_cap`): a cap measured once, in a window of fast motion
    and restart IDRs, priced tss's own point at 8.6 Mbit/s (``off`` sends 5.8 on average) and held it at one frame in
    2 for the last 3.7 s of the 8 Mbit/s cellular-like trace, sending 3.5 Mbit/s under a 7.3 Mbit/s estimate."""

    start_boost: bool = False
    """Until the estimator's first measurement the method's calibrating streams take their share of the highest of
    its start-up probes (its ``estimator``'s ``start_probes``), not of the 300 kbit/s guess
    (:attr:`~splitrender.pipeline.adapt.RateController.start_boost`; tss: its first atlas IDR was 2.9 kB)."""
    up_room: float = 0.0
    """Where a richer point's cost fits this many times over in the budget with no queue, the point controller steps
    up to it at once, without the up hold (0: never; :attr:`~splitrender.pipeline.adapt.PointController.up_room`): a
    probe that finds the link wide is a measurement, not a creep.  tss on the 8 Mbit/s cellular-like trace found 16
    Mbit/s at 2.7 s and stayed at one frame in 3 (its own point costing 5 Mbit/s) until 3.7 s."""

    def __post_init__(self) -> None:
        for name, db in self.knob_db:
            if not db or db[0] != 0.0 or any(not (x == x) for x in db):
                raise ConfigError(f"quality model: knob {name}'s losses must start at 0 dB, got {db}")
        if not (self.latency_db_per_100ms >= 0 and self.rate_db_per_halving >= 0):
            raise ConfigError(f"quality model: slopes must be >= 0, got {self.latency_db_per_100ms}, "
                              f"{self.rate_db_per_halving}")

    @property
    def tolerance_ms(self) -> float:
        """The queueing (ms) the method takes before it drops detail: what costs it as much as ``REFERENCE_MTP_MS``
        costs video, within ``TOLERANCE_MS``.  Methods that redraw geometry at the display pose lose less to latency
        and take more."""
        lo, hi = TOLERANCE_MS
        if self.latency_db_per_100ms <= 0:
            return hi
        return min(hi, max(lo, REFERENCE_MTP_MS * REFERENCE_LATENCY_DB_PER_100MS / self.latency_db_per_100ms))

    def db_lost(self, knob: str, level: int) -> float | None:
        """Model PSNR lost (dB) at level index ``level`` of ``knob``; None where the model does not know the knob."""
        for name, db in self.knob_db:
            if name == knob:
                return db[level] if level < len(db) else None
        return None


@dataclass(frozen=True)
class Knob:
    """One of a method's operating-point knobs, for rate adaptation (``--adapt full``, :mod:`splitrender.pipeline.adapt`).

    ``name``: the :class:`MethodConfig` field it sets (``scale`` is the pipeline's own: the resolution of the
    :attr:`StreamSpec.scalable` streams); ``levels``: its values, richest first (the method's configured value
    first); ``cost``: the prior of the bits each level sends over those of the first (1 first, falling), measured
    offline (``benchmarks/bench_knobs.py``) and learnt online where the controller can observe it; ``affects``:
    ``video`` when the bits are the lossy video streams' (the encoders' rate controller sees them), ``data`` when
    they are sent as made (reliable data, geometry, lossless video: what the controller pays first), ``both`` for
    the server's frame rate; ``order``: knobs of a higher order are lowered only once those of lower orders are
    at their last level (without a quality model: with one, the controller's ladder follows the model's dB per bit).
    """

    name: str
    levels: tuple[Any, ...]
    cost: tuple[float, ...]
    affects: Literal["video", "data", "both"] = "video"
    what: str = ""
    order: int = 0
    model: QualityModel | None = field(default=None, compare=False, repr=False)
    """The method's quality model (every knob of a method carries the same one; the pipeline's own knobs carry
    none until a method offers them with its model): the point controller maximises it where it is given."""

    def __post_init__(self) -> None:
        if len(self.levels) < 2 or len(self.cost) != len(self.levels):
            raise ConfigError(f"knob {self.name}: needs two or more levels and a cost for each, got {len(self.levels)} "
                              f"levels and {len(self.cost)} costs")
        if self.cost[0] != 1.0 or any(not 0 < b < a for a, b in zip(self.cost, self.cost[1:])):
            raise ConfigError(f"knob {self.name}: costs must start at 1 and fall, got {self.cost}")
        if self.affects not in ("video", "data", "both"):
            raise ConfigError(f"knob {self.name}: affects {self.affects!r} is not one of ['video', 'data', 'both']")


SCALE_KNOB = Knob("scale", (1.0, 0.75, 0.5), (1.0, 0.55, 0.28), "video",
                  "resolution of the scalable colour streams (the client resamples to the declared size)")
"""The pipeline's resolution-scale knob, offered for every session with a :attr:`StreamSpec.scalable` stream."""

FRAME_DIV_KNOB = Knob("frame_div", (1, 2, 3, 5), (1.0, 0.5, 0.34, 0.21), "both",
                      "server frames sent: one tick in n (the client draws the newest it has at every display tick)",
                      order=1)
"""The pipeline's server-rate knob, for methods whose client draws any pose from what it holds (a method offers it
in its :meth:`MethodConfig.adapt_knobs`; lowered only after the method's own knobs).  Its prior is one n-th of the
bits (a frame sent costs what it did); the data part is learnt at each point."""


def with_model(knobs: tuple[Knob, ...], model: QualityModel) -> tuple[Knob, ...]:
    """``knobs`` each carrying ``model`` (a method's quality model goes with every knob it offers, the pipeline's
    ``scale`` and ``frame_div`` included)."""
    return tuple(dataclasses.replace(k, model=model) for k in knobs)


RESERVED_STREAMS = ("meta", "session", "pose", "control")
"""Names the pipeline uses for its own byte counts."""

CHROMA_PIX_FMT: dict[str, str] = {"420": "yuv420p", "444": "yuv444p"}
"""``MethodConfig.chroma`` -> the encoder's pixel format for lossy colour (converted from rgb24 by
:func:`splitrender.codecs.video.rgb_to_yuv`: BT.709, full range)."""


@dataclass
class ClientFeedback:
    """What the client reported back, merged over all Feedback that reached the server so far.

    ``applied``: per stream, the newest frame id the client half applied with that
    stream present; ``last_applied_frame``: the newest frame id applied at all;
    ``lost``: per stream, every frame id the client reported it will never get (lost
    packets, undecodable after a loss); ``lost_frames``: how many frames lost at least
    one stream; ``lost_since``: per stream, ids reported lost since the server half's
    previous update (what it has not reacted to yet).
    """

    last_applied_frame: int = -1
    keyframe_requested: bool = False
    lost_frames: int = 0
    applied: dict[str, int] = field(default_factory=dict)
    lost: dict[str, set[int]] = field(default_factory=dict)
    lost_since: dict[str, tuple[int, ...]] = field(default_factory=dict)

    def newly_lost(self, stream: str) -> tuple[int, ...]:
        """Frame ids of ``stream`` reported lost since the previous update."""
        return self.lost_since.get(stream, ())


@dataclass
class ServerContext:
    """Everything a server half may use to produce one frame.

    ``t_s`` is the scene time the frame shows; ``target_pose`` is the predicted client
    pose at the time the frame is expected to be displayed (``t_s + expected_latency_s``);
    ``predict(t)`` extrapolates the client pose to any time (for PVS steps).
    ``shared`` is what the method's :class:`SceneProducer` prepared for this server
    frame (``None`` without a producer); ``client`` numbers the session on this server.  A session's core builds
    it (``pipeline.frames.FrameOrder.context``); benchmarks, studies and tests that drive a half directly build it
    with ``pipeline.direct.server_context``.
    """

    frame_id: int
    t_s: float
    scene: Scene
    renderer: Any
    intrinsics: CameraIntrinsics
    latest_pose: Pose
    latest_pose_t_s: float
    target_pose: Pose
    target_t_s: float
    predict: Callable[[float], Pose]
    expected_latency_s: float
    keyframe_requested: bool = False
    feedback: ClientFeedback = field(default_factory=ClientFeedback)
    shared: Any = None
    client: int = 0


@dataclass
class Update:
    """A server half's output for one frame, before coding.

    ``planes``: video stream name → image; ``data``: data stream name → bytes; a
    stream absent from both sends nothing this frame.  ``meta`` rides reliably with
    the frame's ``FrameMeta``.
    """

    frame_id: int
    t_s: float
    pose: Pose
    planes: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)
    force_idr: bool = False
    data: dict[str, bytes] = field(default_factory=dict)


@dataclass
class DecodedUpdate:
    """What reaches the client half for one server frame, in frame order.

    ``planes`` (decoded video) and ``data`` (decompressed bytes) hold the streams that
    arrived complete; ``missing`` names the streams the server sent for this frame
    that did not (lost, or undecodable until the next keyframe).  ``meta`` always
    arrives (it is reliable).  Each method decides what it can still show.
    """

    frame_id: int
    t_s: float
    pose: Pose
    planes: dict[str, np.ndarray]
    meta: dict[str, Any]
    data: dict[str, bytes] = field(default_factory=dict)
    missing: frozenset[str] = frozenset()

    @property
    def complete(self) -> bool:
        """True when every stream sent for this frame arrived."""
        return not self.missing


@dataclass
class ClientFrame:
    """One displayed image (H, W, 3) uint8 and, where the method knows, a hole mask (H, W) bool."""

    color: np.ndarray
    holes: np.ndarray | None = None
    stats: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class MethodConfig:
    """Settings every method has; methods subclass this with their own fields.

    ``bitrate_kbps`` (when set) is the total video budget of the method, split across
    its streams as the method sees fit; otherwise streams use ``crf``.  ``lossless``
    sends the colour streams as lossless HEVC in 8-bit planar RGB 4:4:4 (``gbrp``),
    whatever ``codec`` says: bit-exact colour, no bitrate control.

    ``chroma``: how the lossy colour streams sample chroma, ``"420"`` (``yuv420p``: one
    Cb/Cr pair per 2x2 pixels; H.264 Constrained Baseline at the ``ultrafast`` preset,
    HEVC Main) or ``"444"`` (``yuv444p``: chroma at every pixel; H.264 High 4:4:4
    Predictive, profile_idc 244, HEVC Main 4:4:4, a Range Extensions profile, id 4).
    ``lossless`` ignores it (``gbrp`` is 4:4:4 already).  TOML and ``--param chroma=444``
    give the number; it is kept as the string.

    The default is per method, from ``benchmarks/bench_chroma.py`` (320x180, 1 s, H.264
    crf 23; duck, 2CylinderEngine and ``default+nogi``; ``static`` and ``walk``; ``ideal``
    and ``cloud``: 12 cells a method; ``results/bench_chroma.json``).  4:2:0 puts colour
    edges into 2x2 blocks: at a model's outline against the sky an edge pixel shows its
    own luma with the block's mixed chroma, which the 2-px ring about the outline pays
    for (the conversion alone takes a still view of the duck to 33.3 dB, 4:4:4's to 53.0).
    Where the picture shown is the one sent (``video``, ``atw``, ``warp``, ``quads``),
    4:4:4 costs 16 % more colour bits at the same crf and, given only the bits of 4:2:0
    (its crf raised until they match within 3 %, 23 -> 23.8-27.7), still gains at the
    median of the cells +1.4 to +2.1 dB on the model, +1.1 to +1.6 dB on the whole frame
    and +1.7 to +3.2 dB on the ring (+14 dB on the still duck; the worst cells, walks
    through the default scene where motion error dominates, -0.1 dB): those methods
    default to ``"444"``.  Where the colour is an atlas the client resamples onto geometry
    it draws itself (``sas``, ``tss``), no silhouette is coded in the video: 4:4:4 costs
    6 % more bits and gains 0.1 dB at the same crf, at equal bits -0.02 (``sas``) and
    +0.04 dB (``tss``) on the model, under the 0.25 dB that pays for a profile fewer
    decoders take; they stay ``"420"``, as does this base (``probes`` sends no lossy
    colour).  HEVC (``video``, same grid) agrees:
    +1.75 dB model at equal bits.  A client that decodes in hardware may need ``"420"``:
    many hardware decoders take neither H.264 High 4:4:4 nor HEVC Range Extensions.

    Moving cameras (issue 50; ``results/bench_chroma_motion.json``: ``orbit`` and ``walk``
    under ``cloud`` on ``default+nogi`` and the duck, both chroma in one run): at equal
    bits 4:4:4 scores the model -0.07 to +0.60 dB (``video``), -0.03 to +0.20 (``atw``),
    -0.01 to +1.13 (``warp``), +0.05 to +1.45 (``quads``); still, in the same run, +0.8 to
    +9.1 dB.  Under motion the error is the motion's: on the default scene 4:4:4 only costs
    bits at the same crf (+2.5 to +10 % of the total; the rate, not the picture), and the
    crf that gives 4:2:0's bits (23.8-24.4) gives its picture.  So 4:2:0 is never the
    better picture for the bits, and these defaults stand; choosing per session by the
    expected motion would save bits at a fixed crf and buy nothing at a fixed rate.
    """

    codec: str = "h264"
    bitrate_kbps: float | None = None
    crf: float | None = 23.0
    gop: int = 30
    preset: str = "ultrafast"
    lossless: bool = False
    chroma: str | int = "420"

    def __post_init__(self) -> None:
        if self.codec not in ("h264", "hevc"):
            raise ConfigError(f"{type(self).__name__}.codec: {self.codec!r} is not one of ['h264', 'hevc']")
        if self.gop < 1:
            raise ConfigError(f"{type(self).__name__}.gop: must be >= 1, got {self.gop}")
        if self.bitrate_kbps is not None and not self.bitrate_kbps > 0:
            raise ConfigError(f"{type(self).__name__}.bitrate_kbps: must be > 0, got {self.bitrate_kbps}")
        if self.crf is not None and not 0 <= self.crf <= 51:
            raise ConfigError(f"{type(self).__name__}.crf: must be in [0, 51], got {self.crf}")
        chroma = str(self.chroma) if isinstance(self.chroma, int) and not isinstance(self.chroma, bool) else self.chroma
        if chroma not in CHROMA_PIX_FMT:
            raise ConfigError(f"{type(self).__name__}.chroma: {self.chroma!r} is not one of {list(CHROMA_PIX_FMT)}")
        object.__setattr__(self, "chroma", chroma)  # 444 from TOML or --param is kept as "444"

    def adapt_knobs(self) -> tuple[Knob, ...]:
        """The knobs this method offers rate adaptation beyond its encoders' rate (``--adapt full``), in the order
        the controller lowers them; none by default.  Each names a field of this config that the server half
        reads afresh every frame (:meth:`ServerHalf.set_knobs` sets it)."""
        return ()

    def client_sizes(self, display: CameraIntrinsics) -> tuple[ClientSize, ...]:
        """What this config makes a client with display ``display`` hold beyond the display-sized buffers every
        method has: reference images, atlases, meshes, each against a :class:`~splitrender.limits.ClientLimits`
        field and naming the config field that sets it.  The client checks them
        (:func:`~splitrender.limits.check_client_sizes`) when it takes the Welcome, before it allocates anything;
        none by default.  Pure arithmetic: it must not allocate what it sizes."""
        return ()

    def for_codecs(self, codecs: tuple[str, ...]) -> MethodConfig:
        """This config adapted to a client that decodes only ``codecs`` (its ``Hello.codecs``, in preference order):
        the colour codec becomes the client's first choice when it does not take this one.  Methods with other
        coded streams override this to choose what the client can decode; a stream that still does not fit is
        refused at set-up with 415 naming it."""
        if codecs and self.codec not in codecs:
            return dataclasses.replace(self, codec=codecs[0])
        return self

    def video(self, fps: int, share: float = 1.0, **kw: Any) -> VideoCodecConfig:
        """The codec config for a stream getting ``share`` of the bitrate budget."""
        if self.lossless:
            return VideoCodecConfig(codec="hevc", pix_fmt="gbrp", lossless=True, crf=None, gop=self.gop, preset=self.preset, fps=fps, **kw)
        br = None if self.bitrate_kbps is None else self.bitrate_kbps * share
        kw.setdefault("pix_fmt", CHROMA_PIX_FMT[str(self.chroma)])
        return VideoCodecConfig(codec=self.codec, bitrate_kbps=br, crf=self.crf, gop=self.gop, preset=self.preset, fps=fps, **kw)  # type: ignore[arg-type]


class SceneProducer:
    """Scene-level work of a method, done once per server frame for all its sessions.

    One producer exists per (method, scene) on a server; :meth:`prepare` is called once
    per server frame, before any session's server half runs, and its result reaches
    every half as ``ServerContext.shared``.  GL work happens on the server's GL thread.
    """

    def __init__(self, config: MethodConfig, scene: Scene, server_fps: int, renderer: Any = None) -> None:
        self.config = config
        self.scene = scene
        self.server_fps = server_fps
        self.renderer = renderer

    def prepare(self, frame_id: int, t_s: float) -> Any:
        """The shared state of server frame ``frame_id`` (scene time ``t_s``)."""
        return None

    def stats(self) -> dict[str, float]:
        """Per-frame numbers of the shared work (written as ``shared_<key>``)."""
        return {}


class ServerHalf(ABC):
    """Produces updates; one instance per session."""

    def __init__(self, config: MethodConfig, intrinsics: CameraIntrinsics, scene: Scene, server_fps: int,
                 producer: SceneProducer | None = None) -> None:
        self.config = config
        self.intrinsics = intrinsics
        self.scene = scene
        self.server_fps = server_fps
        self.producer = producer

    @abstractmethod
    def streams(self) -> list[AnyStreamSpec]:
        """The streams this method sends (fixed for the session): video and data."""

    def session_data(self) -> dict[str, Any]:
        """Sent once at session start (msgpack-able); e.g. scene geometry for ``probes``."""
        return {}

    @abstractmethod
    def produce(self, ctx: ServerContext) -> Update:
        """Render and pack one frame."""

    def stats(self) -> dict[str, float]:
        """Per-frame numbers (e.g. PVS size, atlas use); the runner writes them to updates.csv as ``srv_<key>``."""
        return {}

    def set_knobs(self, values: dict[str, Any]) -> None:
        """Take the operating point rate adaptation chose (``--adapt full``): each key a field the config's
        :meth:`MethodConfig.adapt_knobs` names; the next :meth:`produce` runs with them.  Halves that derive state
        from such a field at set-up override this to rebuild it."""
        fields = {f.name for f in dataclasses.fields(self.config)}
        mine = {k: v for k, v in values.items() if k in fields and getattr(self.config, k) != v}
        if mine:
            self.config = dataclasses.replace(self.config, **mine)


class ClientHalf(ABC):
    """Applies updates and renders at any pose/time; one instance per session, in its own GL context."""

    has_content: bool = False
    """False until the half has something to draw; :meth:`apply` sets it once an update gave it content (until then
    the runner shows and scores the black background)."""

    def __init__(self, config: MethodConfig, intrinsics: CameraIntrinsics, gl: Any, session_data: dict[str, Any],
                 limits: ClientLimits | None = None) -> None:
        self.config = config
        self.intrinsics = intrinsics
        self.gl = gl
        self.session_data = session_data
        self.limits = limits if limits is not None else DEFAULT_CLIENT_LIMITS
        """What this client accepts from the server (probe counts, scene size, ...): session data that declares
        more is refused with the method's error naming the field and the limit."""
        if isinstance(config, MethodConfig):   # the handshake checked these already; again for a half built otherwise
            check_client_sizes(config.client_sizes(intrinsics), self.limits, type(config).__name__)

    @abstractmethod
    def apply(self, update: DecodedUpdate) -> None:
        """Take a decoded update into the cache (updates arrive in frame order, possibly partial)."""

    @abstractmethod
    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        """The image to display for the client's true pose at time ``t_s``."""


def _resolve(ref: Any, what: str) -> Any:
    """A class given directly or as ``"package.module:Attribute"``."""
    if not isinstance(ref, str):
        return ref
    mod, _, attr = ref.partition(":")
    if not mod or not attr:
        raise ConfigError(f"{what}: {ref!r} is not 'module:attribute'")
    try:
        return getattr(importlib.import_module(mod), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"{what}: cannot load {ref!r}: {exc}") from exc


class PageGlue:
    """What a method needs beyond its video track to run in the browser page (:mod:`splitrender.webrtc`), in the
    server process: extra session terms for the page, and per frame messages for its reliable ``meta`` channel.
    A method names its glue in :attr:`MethodSpec.page`; the page's own drawing code is in ``webrtc/static/``.  Built
    from the session's config, the display's intrinsics and the session data the server half made."""

    def __init__(self, config: Any, intrinsics: Any, session_blob: bytes) -> None:
        self.config = config
        self.intrinsics = intrinsics

    def terms(self) -> dict[str, Any]:
        """Entries added to the answer's session terms."""
        return {}

    def frame(self, frame_id: int, meta: dict[str, Any]) -> list[bytes]:
        """Messages for the ``meta`` channel before frame ``frame_id``'s video (its update's ``meta``)."""
        return []

    def counters(self) -> dict[str, int]:
        """Counters added to the session's ``counters.csv``."""
        return {}


@dataclass(frozen=True)
class MethodSpec:
    """A method: its name, its halves (classes or ``"module:Class"`` strings, loaded on
    first use so that a client never imports its server half), config and optional
    scene producer."""

    name: str
    server: Any
    client: Any
    config: type[MethodConfig]
    description: str = ""
    producer: Any = None
    needs_gi: bool = False
    """The method streams the scene's global illumination: it runs only on scenes with ``gi = "ddgi"`` (``default``,
    or any scene with ``+gi``)."""
    client_draws_scene: bool = False
    """The client half holds the whole scene and renders it (what it streams is lighting): a different kind of thin
    client, marked as such where methods are compared."""
    page: Any = None
    """Its :class:`PageGlue` (a class or ``"module:Class"``) where the browser page needs more than the video track
    and the frame's pose; None: nothing more."""

    @property
    def server_class(self) -> type[ServerHalf]:
        return typing.cast(type[ServerHalf], _resolve(self.server, f"method {self.name} server half"))

    @property
    def client_class(self) -> type[ClientHalf]:
        return typing.cast(type[ClientHalf], _resolve(self.client, f"method {self.name} client half"))

    @property
    def page_class(self) -> type[PageGlue]:
        """The method's page glue (the base class, which adds nothing, where it names none)."""
        if self.page is None:
            return PageGlue
        return typing.cast(type[PageGlue], _resolve(self.page, f"method {self.name} page glue"))

    @property
    def producer_class(self) -> type[SceneProducer] | None:
        if self.producer is None:
            return None
        return typing.cast(type[SceneProducer], _resolve(self.producer, f"method {self.name} producer"))


_REGISTRY: dict[str, MethodSpec] = {}

ENTRY_POINT_GROUP = "splitrender.methods"
BUILTIN_MODULES = ("video", "atw", "warp", "sas", "tss", "quads", "probes")
_PACKAGE = __name__.rpartition(".")[0]  # splitrender.methods, where the built-in methods live
_loaded = False
_seen_entry_points: set[str] = set()


def register_method(spec: MethodSpec) -> MethodSpec:
    if spec.name in _REGISTRY and _REGISTRY[spec.name] is not spec:
        raise ValueError(f"method {spec.name!r} is already registered")
    _REGISTRY[spec.name] = spec
    return spec


def load_methods(rescan: bool = False) -> None:
    """Register every method of the entry-point group (once; again with ``rescan``)."""
    global _loaded
    if _loaded and not rescan:
        return
    _loaded = True
    builtin_found = set()
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        key = f"{ep.name}={ep.value}"
        if ep.value.startswith(_PACKAGE + "."):
            builtin_found.add(ep.name)
        if key in _seen_entry_points:
            continue
        _seen_entry_points.add(key)
        try:
            obj = ep.load()
        except Exception:  # noqa: BLE001 - one broken plug-in must not hide the others
            log.exception("method plug-in %s (%s) failed to load", ep.name, ep.value)
            continue
        if isinstance(obj, MethodSpec):
            register_method(obj)
        elif obj is None or not hasattr(obj, "__name__"):
            log.warning("method plug-in %s (%s) is neither a MethodSpec nor a module", ep.name, ep.value)
    for name in BUILTIN_MODULES:
        if name in builtin_found:
            continue
        try:
            importlib.import_module(f"{_PACKAGE}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{_PACKAGE}.{name}":
                raise
            log.debug("method module %s not present", name)


def get_method(name: str) -> MethodSpec:
    load_methods()
    if name not in _REGISTRY:
        load_methods(rescan=True)  # a package installed since the first scan
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ConfigError(f"unknown method {name!r}; available: {', '.join(available_methods())}") from None


def available_methods() -> list[str]:
    """Registered method names: the built-in ones in their canonical order, then others by name."""
    load_methods()
    builtin = [m for m in BUILTIN_MODULES if m in _REGISTRY]
    return builtin + sorted(m for m in _REGISTRY if m not in builtin)


def methods_for_scene(scene: str) -> list[str]:
    """The registered methods that can run on scene ``scene`` (a name or path; whether it has GI is read from the name,
    :func:`~splitrender.scene.loader.scene_has_gi`): what demos, sweeps, the stress suite and the server offer when no
    method is named."""
    from ..scene.loader import scene_has_gi

    gi = scene_has_gi(scene)
    return [m for m in available_methods() if gi or not _REGISTRY[m].needs_gi]


def make_config(cls: type[MethodConfig], params: dict[str, Any] | None) -> MethodConfig:
    """Build a method config from a dict, rejecting unknown keys and wrong types by name."""
    params = dict(params or {})
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    for k, v in params.items():
        if k not in names:
            raise ConfigError(f"{cls.__name__}: unknown parameter {k!r} (valid: {', '.join(sorted(names))})")
        params[k] = coerce_value(cls.__name__, k, hints.get(k), v)
    return cls(**params)
