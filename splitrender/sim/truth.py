"""A ground truth rendered once: a file-store cache of ground-truth frames.

The ground truth of a displayed frame depends only on the scene, the renderer, the
camera pose and scene time (from the trace and the display instant), the image size
and the field of view -- not on the method or the network.  A demo or a sweep renders
the same frames once per method and network; this cache renders them once.

Key: a *run key* (SHA-256 of the scene's content, the renderer version, the trace's
samples, width, height, vertical field of view and client frame rate) names a folder;
in it one file per frame, named by the scene time and the camera pose (their exact
float bits).  Any key part that changes misses.

- scene content: every mesh array, material (texture pixels included), transform,
  animation parameter, light and colour of the :class:`~splitrender.scene.model.Scene`
  (:func:`scene_digest`); a plain function inside a scene counts by its qualified
  name only;
- renderer version: the bytes of the shader sources and ``renderer.py`` in
  ``splitrender/render/``, and the GL renderer and version strings (llvmpipe and a
  GPU do not round alike);
- trace: its sample times, positions and orientations.

A value is the colour image (H, W, 3) uint8 and the object ids (H, W) uint32, in one
zstd-compressed file (``SRGT`` magic, version, height, width, and the milliseconds
the render took, which a hit reports as its ``render_ms`` so ``gt_ms`` stays the cost
of rendering the truth, the yardstick of the client-cost ratio).  A file that does not
parse is a miss (and is overwritten).  Writers write a temporary file in the same
folder and ``os.replace`` it into place, so concurrent writers (pool workers, Dask
workers on one machine) never leave a torn file and readers never see one.

Location: ``RunConfig.truth_cache`` -- ``""`` (off), ``"default"``
(``$SPLITRENDER_TRUTH_CACHE``, else ``~/.cache/splitrender/truth``) or a folder.  The
demo and sweeps use ``<out>/truth_cache`` (or ``$SPLITRENDER_TRUTH_CACHE`` when set),
one folder shared by all their runs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import os
import struct
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, Sequence

import numpy as np
import zstandard

from ..scene.digest import feed, scene_digest
from ..scene.model import Scene
from ..scene.pose import CameraIntrinsics, Pose
from ..scene.trace import CameraTrace

log = logging.getLogger(__name__)

ENV_VAR = "SPLITRENDER_TRUTH_CACHE"
DEFAULT_DIR = Path("~/.cache/splitrender/truth")
MAGIC = b"SRGT"
FORMAT_VERSION = 1
_HEADER = struct.Struct("<4sBxxxIId")  # magic, version, pad, height, width, render_ms
TRUTH_OUTPUTS = ("color", "object_id")
ZSTD_LEVEL = 3
RENDER_DIR = Path(__file__).resolve().parent.parent / "render"


def cache_dir(setting: str) -> Path | None:
    """The folder a ``RunConfig.truth_cache`` setting names; None when off (``""``)."""
    if not setting:
        return None
    if setting == "default":
        return Path(os.environ.get(ENV_VAR) or DEFAULT_DIR).expanduser()
    return Path(setting).expanduser()


def shared_cache_setting(out: str | Path) -> str:
    """What the demo and sweeps use: ``$SPLITRENDER_TRUTH_CACHE`` when set, else ``<out>/truth_cache``."""
    return os.environ.get(ENV_VAR) or str((Path(out) / "truth_cache").resolve())


# ----------------------------------------------------------------------------- digests
def trace_digest(trace: CameraTrace) -> str:
    """SHA-256 of a trace's sample times, positions and orientations."""
    h = hashlib.sha256()
    for a in (trace.t_s, trace.positions, trace.orientations):
        feed(h, np.asarray(a, np.float64))
    return h.hexdigest()


def renderer_version(gl_info: dict[str, Any] | None = None) -> str:
    """SHA-256 of the shader sources and ``renderer.py``, plus the GL renderer and version strings."""
    h = hashlib.sha256()
    files = sorted(p for p in RENDER_DIR.rglob("*") if p.is_file() and p.suffix in (".glsl", ".frag", ".vert", ".comp", ".geom"))
    for p in files + [RENDER_DIR / "renderer.py"]:
        h.update(str(p.relative_to(RENDER_DIR)).encode() + b"\0")
        h.update(p.read_bytes())
    info = gl_info or {}
    h.update(str(info.get("GL_RENDERER", "")).encode() + b"\0" + str(info.get("GL_VERSION", "")).encode())
    return h.hexdigest()


@dataclass(frozen=True)
class TruthKey:
    """Everything one run's ground truth depends on, apart from each frame's time and pose."""

    scene: str
    renderer: str
    trace: str
    width: int
    height: int
    fov_y_deg: float
    fps: float
    supersample: int = 1

    def digest(self) -> str:
        h = hashlib.sha256()
        feed(h, dataclasses.astuple(self))
        return h.hexdigest()[:32]


# ----------------------------------------------------------------------------- the store
@dataclass
class TruthFrame:
    """One cached ground-truth frame (the parts of a ``RenderOutput`` the scores use)."""

    color: np.ndarray
    object_id: np.ndarray
    render_ms: float = float("nan")


class GroundTruthCache:
    """A folder of ground-truth frames; safe for concurrent readers and writers on one machine."""

    def __init__(self, root: str | Path | None = None) -> None:
        self.root = Path(root).expanduser() if root is not None else cache_dir("default")
        assert self.root is not None
        self.hits = 0
        self.misses = 0

    def _path(self, key: TruthKey, t_s: float, pose: Pose) -> Path:
        h = hashlib.sha256()
        feed(h, float(t_s))
        feed(h, np.asarray(pose.position, np.float64))
        feed(h, np.asarray(pose.orientation, np.float64))
        return self.root / key.digest() / f"{h.hexdigest()[:32]}.srgt"

    def get(self, key: TruthKey, t_s: float, pose: Pose) -> TruthFrame | None:
        """The cached frame, or None (a missing or unreadable file is a miss)."""
        p = self._path(key, t_s, pose)
        try:
            blob = p.read_bytes()
        except OSError:
            self.misses += 1
            return None
        frame = decode_frame(blob, key.height, key.width)
        if frame is None:
            log.warning("truth cache: %s does not parse; rendering again", p)
            self.misses += 1
            return None
        self.hits += 1
        return frame

    def put(self, key: TruthKey, t_s: float, pose: Pose, color: np.ndarray, object_id: np.ndarray,
            render_ms: float = float("nan")) -> None:
        """Store a frame: written to a temporary file in the same folder, then renamed into place."""
        p = self._path(key, t_s, pose)
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".srgt", dir=p.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(encode_frame(color, object_id, render_ms))
            os.replace(tmp, p)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise


def encode_frame(color: np.ndarray, object_id: np.ndarray, render_ms: float = float("nan")) -> bytes:
    c = np.ascontiguousarray(color, np.uint8)
    ids = np.ascontiguousarray(object_id, np.uint32)
    h, w = ids.shape
    if c.shape != (h, w, 3):
        raise ValueError(f"truth cache: colour {c.shape} and ids {ids.shape} differ in size")
    body = zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress(c.tobytes() + ids.astype("<u4").tobytes())
    return _HEADER.pack(MAGIC, FORMAT_VERSION, h, w, float(render_ms)) + body


def decode_frame(blob: bytes, height: int, width: int) -> TruthFrame | None:
    """Parse a cache file; None unless it is exactly a frame of ``height`` x ``width``."""
    if len(blob) < _HEADER.size:
        return None
    magic, version, h, w, render_ms = _HEADER.unpack_from(blob)
    if magic != MAGIC or version != FORMAT_VERSION or (h, w) != (height, width):
        return None
    n = h * w
    try:
        raw = zstandard.ZstdDecompressor().decompress(blob[_HEADER.size:], max_output_size=n * 7)
    except zstandard.ZstdError:
        return None
    if len(raw) != n * 7:
        return None
    color = np.frombuffer(raw, np.uint8, n * 3).reshape(h, w, 3).copy()
    ids = np.frombuffer(raw, "<u4", n, offset=n * 3).reshape(h, w).astype(np.uint32)
    return TruthFrame(color, ids, render_ms)


class _Renders(Protocol):
    ctx: Any

    def render(self, scene: Scene, t_s: float, pose: Pose, intr: CameraIntrinsics, outputs: Sequence[str] = ...) -> Any: ...


class CachedTruth:
    """Drop-in for ``renderer.render`` at the runner's ground-truth call site, through a :class:`GroundTruthCache`."""

    def __init__(self, renderer: _Renders, cache: GroundTruthCache, key: TruthKey) -> None:
        self.renderer, self.cache, self.key = renderer, cache, key

    def render(self, scene: Scene, t_s: float, pose: Pose, intr: CameraIntrinsics,
               outputs: Sequence[str] = TRUTH_OUTPUTS) -> Any:
        if tuple(outputs) != TRUTH_OUTPUTS:
            return self.renderer.render(scene, t_s, pose, intr, outputs)
        got = self.cache.get(self.key, t_s, pose)
        if got is not None:
            return got
        w0 = time.perf_counter()
        out = self.renderer.render(scene, t_s, pose, intr, outputs)
        ms = (time.perf_counter() - w0) * 1000
        self.cache.put(self.key, t_s, pose, out.color, out.object_id, ms)
        return TruthFrame(out.color, out.object_id, ms)


def truth_source(setting: str, renderer: _Renders, scene: Scene, trace: CameraTrace, intr: CameraIntrinsics,
                 fps: float, supersample: int = 1) -> Any:
    """What the runner renders its ground truth with: the renderer itself, or a :class:`CachedTruth`.

    ``supersample`` is the renderer's setting while the run renders (part of the cache key)."""
    root = cache_dir(setting)
    if root is None:
        return renderer
    info = getattr(getattr(renderer, "ctx", None), "info", None)
    key = TruthKey(scene_digest(scene), renderer_version(info if isinstance(info, dict) else None), trace_digest(trace),
                   intr.width, intr.height, float(intr.fov_y_deg), float(fps), int(supersample))
    return CachedTruth(renderer, GroundTruthCache(root), key)
