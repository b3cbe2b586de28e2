"""H.264 / HEVC encode and decode through PyAV (FFmpeg libx264 / libx265).

Tuned for interactive streaming: no B-frames, ``tune=zerolatency`` (one packet out per
frame in, no lookahead), a fixed GOP with IDR on request, constant bitrate (with a
VBV buffer of one frame) or CRF, and a lossless mode (HEVC ``lossless=1``, or x264
``qp=0``).  Encoded frames are Annex-B byte strings, ready for the RTP payloaders.

HEVC level: x265 picks the lowest level that fits the size, rate and bit rate itself,
except in lossless mode, where it writes general_level_idc 255 (level 8.5, "no limits")
and refuses ``level-idc`` (lossless is constant QP, which x265 will not pair with a
level).  An HEVC stream whose VPS/SPS say no level of H.265 Table A.8 gets the lowest
level whose picture size and sample rate limits fit it
(:func:`splitrender.protocol.sps.hevc_level_idc`) written into its VPS and SPS, in
:meth:`VideoEncoder.parameter_sets` and in-band alike, so the SDP's ``level-id`` (read
from the SPS) names a real level.  ``level-idc`` is not passed to x265 for lossy streams
either: there it would switch on VBV under CRF and cut a bit rate above the level's
MaxBR, while x265's own choice already is a real level.

Input planes are numpy arrays, row 0 at the top:

- ``rgb24``: (H, W, 3) uint8 sRGB.  Into ``yuv420p`` / ``yuv444p`` it is converted
  here, not by swscale: BT.709 matrix, **full range** (Y, Cb, Cr in 0..255), exact
  float arithmetic rounded to nearest, chroma averaged over each 2x2 block for 4:2:0.
  The bitstream says so (VUI: matrix BT.709, range full, primaries BT.709, transfer
  IEC 61966-2-1 = sRGB), so FFmpeg, GStreamer or a browser decode the same colours;
  :class:`VideoDecoder` inverts it with the matrix and range the stream signals.  A
  flat colour comes back within one code value per channel (exhaustively checked:
  full range loses at most 1; the old swscale path turned the sky (140, 178, 230)
  into (138, 178, 228), limited range loses up to 2).  Into ``gbrp`` (lossless RGB
  4:4:4) the planes are only reordered.  ``yuv444p`` (``MethodConfig.chroma = "444"``)
  keeps every pixel's chroma: the stream is H.264 High 4:4:4 Predictive (profile_idc
  244) or HEVC Main 4:4:4 (profile_idc 4, Range Extensions); the conversion alone gives
  back every pixel within one code value, where 4:2:0 gives each 2x2 block one chroma
  pair (the edge pixels of a silhouette take a mix of its colour and the background's);
- ``yuv444p``: (3, H, W) uint8 Y, Cb, Cr planes as :func:`rgb_to_yuv` makes them (BT.709,
  full range), sent as they are (pixel format ``yuv444p`` only): what a test needs to check
  the codec's lossless mode plane for plane;
- ``gray``: (H, W) uint8;
- ``gray16le`` / ``gray10le`` / ``gray12le``: (H, W) uint16 (lossless depth, probes);
- ``gbrp10le`` / ``gbrp16le``: (H, W, 3) uint16 high-bit-depth colour.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Literal

import numpy as np

from ..errors import CodecError, ConfigError
from ..protocol.annexb import join_annexb, nal_type, split_annexb
from ..protocol.errors import SdpError
from ..protocol.sps import hevc_level_idc, hevc_level_of, is_hevc_level, set_hevc_level

log = logging.getLogger(__name__)

CodecName = Literal["h264", "hevc"]
ENCODERS = {"h264": "libx264", "hevc": "libx265"}
IDR_NAL_TYPES_H264 = {5}
IDR_NAL_TYPES_HEVC = set(range(16, 22))

# Colour description written into the bitstream (ISO/IEC 23091-2 code points, as FFmpeg numbers them)
COLOR_MATRIX_BT709 = 1
COLOR_PRIMARIES_BT709 = 1
COLOR_TRC_SRGB = 13        # IEC 61966-2-1
COLOR_RANGE_FULL = 2       # AVCOL_RANGE_JPEG
# luma weights (Kr, Kb) per matrix code point; unspecified (2) decodes as BT.601, FFmpeg's default
_KR_KB = {1: (0.2126, 0.0722), 5: (0.299, 0.114), 6: (0.299, 0.114), 2: (0.299, 0.114), 9: (0.2627, 0.0593), 10: (0.2627, 0.0593)}
_YUV_FORMATS = {"yuv420p": 2, "yuvj420p": 2, "yuv444p": 1, "yuvj444p": 1}  # chroma subsampling factor


def rgb_to_yuv(rgb: np.ndarray, sub: int, kr: float = 0.2126, kb: float = 0.0722) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(H, W, 3) uint8 RGB -> full-range Y (H, W), Cb, Cr (H/sub, W/sub) uint8 planes.

    Float arithmetic rounded to nearest; 4:2:0 chroma is that of the mean colour of each
    2x2 block.
    """
    kg = 1.0 - kr - kb
    x = rgb.astype(np.float32)
    y = x @ np.array([kr, kg, kb], np.float32)
    if sub == 2:
        x = x[0::2, 0::2] + x[1::2, 0::2] + x[0::2, 1::2] + x[1::2, 1::2]
    m = np.array([[-kr / (2 * (1 - kb)), 0.5], [-kg / (2 * (1 - kb)), -kg / (2 * (1 - kr))], [0.5, -kb / (2 * (1 - kr))]],
                 np.float32) / (sub * sub)
    c = x @ m
    c += 128.0
    for a in (y, c):
        np.rint(a, out=a)
        np.clip(a, 0, 255, out=a)
    c8 = c.astype(np.uint8)
    return y.astype(np.uint8), np.ascontiguousarray(c8[..., 0]), np.ascontiguousarray(c8[..., 1])


_INV_LUTS: dict[tuple[float, float], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}


def _inverse_luts(kr: float, kb: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Full-range offsets added to Y: R by Cr, B by Cb, G by (Cb, Cr); int16, rounded."""
    if (kr, kb) not in _INV_LUTS:
        kg = 1.0 - kr - kb
        u = np.arange(256, dtype=np.float64) - 128.0
        r_v = np.rint(2 * (1 - kr) * u).astype(np.int16)
        b_u = np.rint(2 * (1 - kb) * u).astype(np.int16)
        g_uv = np.rint(-(kb * 2 * (1 - kb) * u[:, None] + kr * 2 * (1 - kr) * u[None, :]) / kg).astype(np.int16)
        _INV_LUTS[(kr, kb)] = (r_v, g_uv, b_u)
    return _INV_LUTS[(kr, kb)]


def yuv_to_rgb(y: np.ndarray, cb: np.ndarray, cr: np.ndarray, full_range: bool, kr: float = 0.2126,
               kb: float = 0.0722) -> np.ndarray:
    """Y (H, W) and Cb, Cr (H/s, W/s) uint8 planes -> (H, W, 3) uint8 RGB, chroma repeated over its block.

    Full range: Y is an integer, so round(Y + k * (C - 128)) = Y + round(k * (C - 128))
    and the offsets come from tables.  Limited range (streams from elsewhere) in floats.
    """
    h, w = y.shape
    ch, cw = cb.shape
    sy, sx = h // ch, w // cw
    if full_range:
        r_v, g_uv, b_u = _inverse_luts(kr, kb)
        off = np.stack([r_v[cr], g_uv[cb, cr], b_u[cb]], axis=-1)
        out = y.astype(np.int16).reshape(ch, sy, cw, sx, 1) + off[:, None, :, None, :]
    else:
        kg = 1.0 - kr - kb
        u = (cb.astype(np.float32) - 128.0) * (255.0 / 224.0)
        v = (cr.astype(np.float32) - 128.0) * (255.0 / 224.0)
        off = np.stack([2 * (1 - kr) * v, -(kb * 2 * (1 - kb) * u + kr * 2 * (1 - kr) * v) / kg, 2 * (1 - kb) * u], axis=-1)
        yf = (y.astype(np.float32) - 16.0) * (255.0 / 219.0)
        out = np.rint(yf.reshape(ch, sy, cw, sx, 1) + off[:, None, :, None, :])
    return np.clip(out, 0, 255).astype(np.uint8).reshape(h, w, 3)


def _vbv(kbps: int, fps: int, buffer_ms: float | None = None) -> list[str]:
    """x264/x265 parameters holding a stream under ``kbps`` with a two-frame VBV buffer (bit-rate mode and capped
    crf alike), or one of ``buffer_ms`` where that is longer."""
    frames = kbps / fps * 2
    return [f"vbv-maxrate={kbps}", f"vbv-bufsize={max(1, int(max(frames, kbps * (buffer_ms or 0.0) / 1000)))}"]


VBV_THREADS = 1
"""Threads of an encoder under a VBV (bit-rate mode, capped crf).  x264's sliced threads (its zerolatency tune) and
x265's thread pool, with a VBV's row-by-row rate control, code one picture differently from run to run (measured,
384x192, a fresh capped-crf encoder at 270 kbit/s, one IDR and two P-frames: 4 distinct byte counts in 30 tries with
x264's 3 threads on 2 cores, 5 in 12 with x265; one each with one thread), and an adapting session or a run at a bit
rate would not repeat.  One thread codes them the same every time.  Without a VBV (crf, lossless) the threads'
output repeats: they keep the machine's threads."""


@dataclass(frozen=True)
class VideoCodecConfig:
    """How one video stream is coded.  ``bitrate_kbps`` wins over ``crf`` when both are set; ``cap_kbps`` with
    ``crf`` (and no ``bitrate_kbps``) is capped crf: the crf's quality, the rate held under ``cap_kbps`` by the
    encoder's VBV (a two-frame buffer, as in bit-rate mode, or ``cap_buffer_ms`` of the cap where that is longer: a
    method that tolerates a queue lets an I-frame take its crf's bits and the pacer spread it, rather than squeeze
    it into two frames' worth)."""

    codec: CodecName = "h264"
    pix_fmt: str = "yuv420p"
    input_format: str = "rgb24"
    bitrate_kbps: float | None = None
    crf: float | None = 23.0
    cap_kbps: float | None = None
    cap_buffer_ms: float | None = None
    gop: int = 30
    lossless: bool = False
    preset: str = "ultrafast"
    fps: int = 30
    extra: dict[str, str] = field(default_factory=dict)

    @property
    def vbv(self) -> bool:
        """Coded under a VBV (a bit rate, or a cap over the crf): by :data:`VBV_THREADS` threads."""
        return not self.lossless and (self.bitrate_kbps is not None or (self.crf is not None and self.cap_kbps is not None))

    def __post_init__(self) -> None:
        if self.codec not in ENCODERS:
            raise ConfigError(f"video codec: {self.codec!r} is not one of {sorted(ENCODERS)}")
        if self.gop < 1:
            raise ConfigError(f"video gop: must be >= 1, got {self.gop}")
        if self.bitrate_kbps is not None and not self.bitrate_kbps > 0:
            raise ConfigError(f"video bitrate_kbps: must be > 0, got {self.bitrate_kbps}")
        if self.crf is not None and not 0 <= self.crf <= 51:
            raise ConfigError(f"video crf: must be in [0, 51], got {self.crf}")
        if self.cap_kbps is not None and not self.cap_kbps > 0:
            raise ConfigError(f"video cap_kbps: must be > 0, got {self.cap_kbps}")
        if self.cap_buffer_ms is not None and not 0 <= self.cap_buffer_ms <= 10_000:
            raise ConfigError(f"video cap_buffer_ms: must be in [0, 10000], got {self.cap_buffer_ms}")
        if self.fps <= 0:
            raise ConfigError(f"video fps: must be > 0, got {self.fps}")


@dataclass(frozen=True)
class EncodedFrame:
    """One access unit: Annex-B bytes, whether it is an IDR, and its index in the stream."""

    data: bytes
    keyframe: bool
    index: int

    @property
    def nbytes(self) -> int:
        return len(self.data)


class VideoEncoder:
    """Encodes one stream of same-sized planes; ``encode`` returns exactly one frame per call."""

    def __init__(self, cfg: VideoCodecConfig, width: int, height: int) -> None:
        if width <= 0 or height <= 0 or width % 2 or height % 2:
            raise ConfigError(f"video size {width}x{height}: width and height must be positive and even")
        self.cfg, self.width, self.height = cfg, width, height
        self._index = 0
        self._since_idr = 0
        self._parameter_sets: tuple[bytes, ...] | None = None
        self._yuv_sub = _YUV_FORMATS.get(cfg.pix_fmt) if cfg.input_format == "rgb24" else None
        if cfg.input_format == "yuv444p" and cfg.pix_fmt != "yuv444p":
            raise ConfigError(f"video input_format yuv444p: pixel format must be yuv444p, got {cfg.pix_fmt}")
        self.level_idc = hevc_level_idc(width, height, cfg.fps) if cfg.codec == "hevc" else None
        """HEVC: the general_level_idc written into VPS and SPS that name no real level (x265's lossless 255)."""
        self._level_fixed: dict[bytes, bytes] = {}
        self._ctx = self._open(global_header=False)

    def _open(self, global_header: bool):  # type: ignore[no-untyped-def]
        """An opened encoder context for this configuration (``global_header``: headers in ``extradata``)."""
        import av

        cfg, width, height = self.cfg, self.width, self.height
        ctx = av.CodecContext.create(ENCODERS[cfg.codec], "w")
        ctx.width, ctx.height = width, height
        ctx.pix_fmt = cfg.pix_fmt
        ctx.time_base = Fraction(1, cfg.fps)
        ctx.framerate = Fraction(cfg.fps, 1)
        ctx.gop_size = cfg.gop
        ctx.max_b_frames = 0
        if global_header:
            ctx.flags |= av.codec.context.Flags.global_header
        if cfg.input_format in ("rgb24", "yuv444p", "gbrp10le", "gbrp16le"):  # colour: say what the samples mean
            ctx.color_primaries = COLOR_PRIMARIES_BT709
            ctx.color_trc = COLOR_TRC_SRGB
            ctx.colorspace = COLOR_MATRIX_BT709 if self._yuv_sub or cfg.input_format == "yuv444p" else 0   # 0: RGB (gbrp)
            ctx.color_range = COLOR_RANGE_FULL
        opts: dict[str, str] = {"preset": cfg.preset, "tune": "zerolatency"}
        if cfg.codec == "h264":
            params = ["bframes=0", "forced-idr=1", f"keyint={cfg.gop}", f"min-keyint={cfg.gop}", "scenecut=0", "repeat-headers=1"]
            if cfg.lossless:
                opts["qp"] = "0"
            elif cfg.bitrate_kbps is not None:
                kb = int(cfg.bitrate_kbps)
                params += [f"bitrate={kb}", *_vbv(kb, cfg.fps), "nal-hrd=none"]
            elif cfg.crf is not None:
                opts["crf"] = str(cfg.crf)
                if cfg.cap_kbps is not None:
                    params += [*_vbv(max(1, int(cfg.cap_kbps)), cfg.fps, cfg.cap_buffer_ms), "nal-hrd=none"]
            if cfg.vbv:
                opts["threads"] = str(VBV_THREADS)
            opts["x264-params"] = ":".join(params)
        else:
            params = ["bframes=0", f"keyint={cfg.gop}", f"min-keyint={cfg.gop}", "scenecut=0", "repeat-headers=1", "log-level=error", "frame-threads=1"]
            if cfg.lossless:
                params.append("lossless=1")
            elif cfg.bitrate_kbps is not None:
                kb = int(cfg.bitrate_kbps)
                params += [f"bitrate={kb}", *_vbv(kb, cfg.fps)]
            elif cfg.crf is not None:
                params.append(f"crf={cfg.crf}")
                if cfg.cap_kbps is not None:
                    params += _vbv(max(1, int(cfg.cap_kbps)), cfg.fps, cfg.cap_buffer_ms)
            if cfg.vbv:
                params.append(f"pools={VBV_THREADS}")
            opts["x265-params"] = ":".join(params)
            opts["forced-idr"] = "1"  # FFmpeg's libx265 wrapper: an I picture request becomes an IDR
        opts.update(cfg.extra)
        ctx.options = opts
        try:
            ctx.open()
        except Exception as exc:
            raise CodecError(f"cannot open {ENCODERS[cfg.codec]} for {width}x{height} {cfg.pix_fmt}: {exc}") from exc
        return ctx

    @property
    def parameter_sets_known(self) -> bool:
        """:meth:`parameter_sets` has run (so calling it again costs nothing)."""
        return self._parameter_sets is not None

    def parameter_sets(self) -> tuple[bytes, ...]:
        """The parameter set NAL units (H.264 SPS, PPS; HEVC VPS, SPS, PPS) this encoder sends before each IDR.

        Read, without encoding a picture, from the ``extradata`` of a second context of the
        same configuration opened with the global-header flag (the headers the encoder
        would repeat in-band); the streaming context itself is left as it is.  Cached.
        """
        if self._parameter_sets is None:
            ctx = self._open(global_header=True)
            try:
                extra = bytes(ctx.extradata or b"")
            finally:
                del ctx
            keep = {7, 8} if self.cfg.codec == "h264" else {32, 33, 34}
            self._parameter_sets = tuple(self._with_level(bytes(nal)) for nal in iter_nal_units(extra)
                                         if nal and nal_type(self.cfg.codec, nal) in keep)
        return self._parameter_sets

    def _with_level(self, nal: bytes) -> bytes:
        """An HEVC VPS or SPS with a real level: itself when it names one, else with :attr:`level_idc`."""
        if self.level_idc is None or not nal or nal_type("hevc", nal) not in (32, 33):
            return nal
        fixed = self._level_fixed.get(nal)
        if fixed is None:
            try:
                fixed = nal if is_hevc_level(hevc_level_of(nal)) else set_hevc_level(nal, self.level_idc)
            except SdpError:  # too short to carry a level: leave it
                fixed = nal
            if len(self._level_fixed) < 16:
                self._level_fixed[nal] = fixed
        return fixed

    def _levels_in_band(self, data: bytes) -> bytes:
        """``data`` with :meth:`_with_level` applied to its VPS and SPS (itself when none needed a level)."""
        nals = split_annexb(data)
        fixed = [self._with_level(n) for n in nals]
        return data if fixed == nals else join_annexb(fixed)

    def _frame(self, plane: np.ndarray):  # type: ignore[no-untyped-def]
        import av

        fmt = self.cfg.input_format
        expect = (self.height, self.width)
        if fmt == "yuv444p":
            if plane.shape != (3, *expect):
                raise CodecError(f"encoder {self.width}x{self.height} yuv444p: got planes of shape {plane.shape}, "
                                 f"expected {(3, *expect)}")
            frame = av.VideoFrame(self.width, self.height, "yuv444p")
            for p, data in zip(frame.planes, np.ascontiguousarray(plane, dtype=np.uint8)):
                p.update(_pad_rows(data, p.line_size).tobytes())
            frame.colorspace = COLOR_MATRIX_BT709
            frame.color_range = COLOR_RANGE_FULL
            return frame
        if plane.shape[:2] != expect:
            raise CodecError(f"encoder {self.width}x{self.height}: got a plane of shape {plane.shape}")
        if fmt in ("rgb24", "gray"):
            arr = np.ascontiguousarray(plane, dtype=np.uint8)
        else:
            arr = np.ascontiguousarray(plane, dtype=np.uint16)
        if self._yuv_sub:
            frame = av.VideoFrame(self.width, self.height, self.cfg.pix_fmt)
            for p, data in zip(frame.planes, rgb_to_yuv(arr, self._yuv_sub)):
                p.update(_pad_rows(data, p.line_size).tobytes())
            frame.colorspace = COLOR_MATRIX_BT709
            frame.color_range = COLOR_RANGE_FULL
            return frame
        if fmt in ("gray10le", "gray12le"):
            frame = av.VideoFrame(self.width, self.height, fmt)
            frame.planes[0].update(_pad_rows(arr, frame.planes[0].line_size // 2).tobytes())
        elif fmt == "gbrp10le" or fmt == "gbrp16le":
            frame = av.VideoFrame.from_ndarray(arr, format=fmt)
        else:
            frame = av.VideoFrame.from_ndarray(arr, format=fmt)
        if frame.format.name != self.cfg.pix_fmt:
            frame = frame.reformat(format=self.cfg.pix_fmt)
        return frame

    def encode(self, plane: np.ndarray, force_idr: bool = False) -> EncodedFrame:
        """Encode one plane; ``force_idr`` makes this frame an IDR (resets the GOP)."""
        from av.video.frame import PictureType

        frame = self._frame(plane)
        frame.pts = self._index
        idr = force_idr or self._index == 0
        frame.pict_type = PictureType.I if idr else PictureType.NONE
        try:
            packets = self._ctx.encode(frame)
        except Exception as exc:
            raise CodecError(f"{ENCODERS[self.cfg.codec]} encode failed at frame {self._index}: {exc}") from exc
        data = b"".join(bytes(p) for p in packets)
        if not data:
            raise CodecError(f"{ENCODERS[self.cfg.codec]} produced no packet for frame {self._index} (zerolatency expected one)")
        if self.level_idc is not None:
            data = self._levels_in_band(data)
        key = any(p.is_keyframe for p in packets) or contains_idr(data, self.cfg.codec)
        ef = EncodedFrame(data, key, self._index)
        self._index += 1
        self._since_idr = 0 if key else self._since_idr + 1
        return ef

    @property
    def idr_due(self) -> bool:
        """The next frame is an IDR whatever is asked (the first, or the GOP's ``keyint`` is reached)."""
        return self._index == 0 or self._since_idr + 1 >= self.cfg.gop

    @property
    def frames_encoded(self) -> int:
        return self._index


class VideoDecoder:
    """Decodes Annex-B access units back into numpy planes of ``output_format``: ``rgb24`` (H, W, 3) from any
    4:2:0 or 4:4:4 YUV stream (inverted with the matrix and range it signals), ``yuv444p`` the coded planes
    (3, H, W) as they are, other formats as PyAV converts them."""

    def __init__(self, codec: CodecName, output_format: str = "rgb24") -> None:
        import av

        if codec not in ENCODERS:
            raise ConfigError(f"video codec: {codec!r} is not one of {sorted(ENCODERS)}")
        self.codec = codec
        self.output_format = output_format
        self._ctx = av.CodecContext.create(codec, "r")
        self._ctx.thread_count = 1

    def decode(self, data: bytes) -> np.ndarray:
        """Decode one access unit; raises :class:`CodecError` when it yields no picture."""
        import av

        try:
            frames = self._ctx.decode(av.Packet(data))
        except Exception as exc:
            raise CodecError(f"{self.codec} decode failed ({len(data)} bytes): {exc}") from exc
        if not frames:
            raise CodecError(f"{self.codec} decoder returned no picture for a {len(data)}-byte access unit")
        return frame_to_array(frames[-1], self.output_format)


def frame_to_array(frame, fmt: str) -> np.ndarray:  # type: ignore[no-untyped-def]
    if fmt == "rgb24" and frame.format.name in _YUV_FORMATS:
        kr, kb = _KR_KB.get(int(frame.colorspace), _KR_KB[2])
        full = int(frame.color_range) == COLOR_RANGE_FULL or frame.format.name.startswith("yuvj")
        planes = [np.frombuffer(p, np.uint8).reshape(p.height, p.line_size)[:, : p.width] for p in frame.planes]
        return yuv_to_rgb(planes[0], planes[1], planes[2], full, kr, kb)
    if fmt in ("gray10le", "gray12le", "gray16le"):
        f = frame if frame.format.name == fmt else frame.reformat(format=fmt)
        p = f.planes[0]
        a = np.frombuffer(p, np.uint16).reshape(f.height, p.line_size // 2)
        return a[:, : f.width].copy()
    return frame.to_ndarray(format=fmt)


def _pad_rows(arr: np.ndarray, stride: int) -> np.ndarray:
    if arr.shape[1] == stride:
        return arr
    out = np.zeros((arr.shape[0], stride), arr.dtype)
    out[:, : arr.shape[1]] = arr
    return out


def iter_nal_units(data: bytes):  # type: ignore[no-untyped-def]
    """Yield NAL unit payloads (without start codes) from an Annex-B byte string."""
    i, n = 0, len(data)
    starts = []
    while True:
        j = data.find(b"\x00\x00\x01", i)
        if j < 0:
            break
        starts.append(j + 3)
        i = j + 3
    for k, s in enumerate(starts):
        e = starts[k + 1] - 3 if k + 1 < len(starts) else n
        if k + 1 < len(starts) and e > s and data[e - 1] == 0:
            e -= 1
        yield data[s:e]


def contains_idr(data: bytes, codec: str) -> bool:
    idr = IDR_NAL_TYPES_H264 if codec == "h264" else IDR_NAL_TYPES_HEVC
    return any(nal and nal_type(codec, nal) in idr for nal in iter_nal_units(data))  # type: ignore[arg-type]
