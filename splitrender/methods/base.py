"""The method interface: a server half, a client half and what passes between them.

A method is one module (or subpackage) with two halves that share nothing but the
wire format (DESIGN.md):

- :class:`ServerHalf` turns a :class:`ServerContext` (scene at time t, the client's
  newest pose, a pose predictor, feedback) into an :class:`Update`: named image planes,
  one per declared :class:`StreamSpec`, plus msgpack-able metadata;
- the transport (virtual-time runner or live server/client) encodes every plane with
  its stream's video codec and the metadata with msgpack + zstd, counts the bytes,
  delays/loses them, decodes them again and hands a :class:`DecodedUpdate` to
- :class:`ClientHalf`, which applies updates to its cache and renders a
  :class:`ClientFrame` for any pose and time.

The client half never sees the scene, the renderer or the uncompressed planes; all it
gets at start is ``ServerHalf.session_data()`` (msgpack-able, counted as bytes too).

Adding a method means writing the two halves and a config dataclass and calling
:func:`register_method`; the runner, server, client and experiments pick it up by name.
"""

from __future__ import annotations

import dataclasses
import logging
import typing
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..codecs.video import VideoCodecConfig
from ..errors import ConfigError
from ..scene.model import Scene
from ..scene.pose import CameraIntrinsics, Pose

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StreamSpec:
    """One video stream a method sends: a name, a codec configuration and a plane size."""

    name: str
    codec: VideoCodecConfig
    width: int
    height: int

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ConfigError(f"stream name {self.name!r} must be an identifier")
        if self.width % 2 or self.height % 2 or self.width <= 0 or self.height <= 0:
            raise ConfigError(f"stream {self.name}: size {self.width}x{self.height} must be positive and even")


@dataclass
class ClientFeedback:
    """What the client reported back that a server half may react to."""

    last_applied_frame: int = -1
    keyframe_requested: bool = False
    lost_frames: int = 0


@dataclass
class ServerContext:
    """Everything a server half may use to produce one frame.

    ``t_s`` is the scene time the frame shows; ``target_pose`` is the predicted client
    pose at the time the frame is expected to be displayed (``t_s + expected_latency_s``);
    ``predict(t)`` extrapolates the client pose to any time (for PVS steps).
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


@dataclass
class Update:
    """A server half's output for one frame, before coding."""

    frame_id: int
    t_s: float
    pose: Pose
    planes: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)
    force_idr: bool = False


@dataclass
class DecodedUpdate:
    """What reaches the client half: decoded planes (same names/shapes) and metadata.

    ``planes`` may be missing a stream when the method sent no new picture for it.
    """

    frame_id: int
    t_s: float
    pose: Pose
    planes: dict[str, np.ndarray]
    meta: dict[str, Any]


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
    """

    codec: str = "h264"
    bitrate_kbps: float | None = None
    crf: float | None = 23.0
    gop: int = 30
    preset: str = "ultrafast"
    lossless: bool = False

    def __post_init__(self) -> None:
        if self.codec not in ("h264", "hevc"):
            raise ConfigError(f"{type(self).__name__}.codec: {self.codec!r} is not one of ['h264', 'hevc']")
        if self.gop < 1:
            raise ConfigError(f"{type(self).__name__}.gop: must be >= 1, got {self.gop}")
        if self.bitrate_kbps is not None and not self.bitrate_kbps > 0:
            raise ConfigError(f"{type(self).__name__}.bitrate_kbps: must be > 0, got {self.bitrate_kbps}")
        if self.crf is not None and not 0 <= self.crf <= 51:
            raise ConfigError(f"{type(self).__name__}.crf: must be in [0, 51], got {self.crf}")

    def video(self, fps: int, share: float = 1.0, **kw: Any) -> VideoCodecConfig:
        """The codec config for a stream getting ``share`` of the bitrate budget."""
        if self.lossless:
            return VideoCodecConfig(codec="hevc", pix_fmt="gbrp", lossless=True, crf=None, gop=self.gop, preset=self.preset, fps=fps, **kw)
        br = None if self.bitrate_kbps is None else self.bitrate_kbps * share
        return VideoCodecConfig(codec=self.codec, bitrate_kbps=br, crf=self.crf, gop=self.gop, preset=self.preset, fps=fps, **kw)  # type: ignore[arg-type]


class ServerHalf(ABC):
    """Produces updates; one instance per session."""

    def __init__(self, config: MethodConfig, intrinsics: CameraIntrinsics, scene: Scene, server_fps: int) -> None:
        self.config = config
        self.intrinsics = intrinsics
        self.scene = scene
        self.server_fps = server_fps

    @abstractmethod
    def streams(self) -> list[StreamSpec]:
        """The video streams this method sends (fixed for the session)."""

    def session_data(self) -> dict[str, Any]:
        """Sent once at session start (msgpack-able); e.g. scene geometry for ``probes``."""
        return {}

    @abstractmethod
    def produce(self, ctx: ServerContext) -> Update:
        """Render and pack one frame."""

    def stats(self) -> dict[str, float]:
        """Per-frame numbers (e.g. PVS size, atlas use); the runner writes them to updates.csv as ``srv_<key>``."""
        return {}


class ClientHalf(ABC):
    """Applies updates and renders at any pose/time; one instance per session."""

    def __init__(self, config: MethodConfig, intrinsics: CameraIntrinsics, gl: Any, session_data: dict[str, Any]) -> None:
        self.config = config
        self.intrinsics = intrinsics
        self.gl = gl
        self.session_data = session_data

    @abstractmethod
    def apply(self, update: DecodedUpdate) -> None:
        """Take a decoded update into the cache (updates arrive in frame order)."""

    @abstractmethod
    def render(self, pose: Pose, t_s: float) -> ClientFrame:
        """The image to display for the client's true pose at time ``t_s``."""

    @property
    def has_content(self) -> bool:
        """False until the first update was applied."""
        return getattr(self, "_has_content", False)


@dataclass(frozen=True)
class MethodSpec:
    name: str
    server: type[ServerHalf]
    client: type[ClientHalf]
    config: type[MethodConfig]
    description: str = ""


_REGISTRY: dict[str, MethodSpec] = {}


def register_method(spec: MethodSpec) -> MethodSpec:
    if spec.name in _REGISTRY and _REGISTRY[spec.name] is not spec:
        raise ValueError(f"method {spec.name!r} is already registered")
    _REGISTRY[spec.name] = spec
    return spec


def get_method(name: str) -> MethodSpec:
    from . import _load_builtin

    _load_builtin()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ConfigError(f"unknown method {name!r}; available: {', '.join(available_methods())}") from None


def available_methods() -> list[str]:
    """Registered method names: the built-in ones in their canonical order, then others by name."""
    from . import BUILTIN_MODULES, _load_builtin

    _load_builtin()
    builtin = [m for m in BUILTIN_MODULES if m in _REGISTRY]
    return builtin + sorted(m for m in _REGISTRY if m not in builtin)


def make_config(cls: type[MethodConfig], params: dict[str, Any] | None) -> MethodConfig:
    """Build a method config from a dict, rejecting unknown keys and wrong types by name."""
    params = dict(params or {})
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    for k, v in params.items():
        if k not in names:
            raise ConfigError(f"{cls.__name__}: unknown parameter {k!r} (valid: {', '.join(sorted(names))})")
        params[k] = _coerce(cls.__name__, k, hints.get(k), v)
    return cls(**params)


def _coerce(owner: str, key: str, hint: Any, v: Any) -> Any:
    """Check a TOML/CLI value against a dataclass field type, with ints accepted as floats."""
    if hint is None:
        return v
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        if v is None and type(None) in args:
            return None
        errs = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(owner, key, a, v)
            except ConfigError as e:
                errs.append(str(e))
        raise ConfigError(f"{owner}.{key}: {v!r} does not fit {hint}")
    if origin is typing.Literal:
        if v not in args:
            raise ConfigError(f"{owner}.{key}: {v!r} is not one of {list(args)}")
        return v
    if origin in (tuple, list):
        if not isinstance(v, (list, tuple)):
            raise ConfigError(f"{owner}.{key}: expected a list, got {type(v).__name__} {v!r}")
        return tuple(v) if origin is tuple else list(v)
    if hint is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f"{owner}.{key}: expected a number, got {type(v).__name__} {v!r}")
        return float(v)
    if hint is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConfigError(f"{owner}.{key}: expected an integer, got {type(v).__name__} {v!r}")
        return v
    if hint is bool:
        if not isinstance(v, bool):
            raise ConfigError(f"{owner}.{key}: expected true/false, got {type(v).__name__} {v!r}")
        return v
    if hint is str:
        if not isinstance(v, str):
            raise ConfigError(f"{owner}.{key}: expected a string, got {type(v).__name__} {v!r}")
        return v
    return v
