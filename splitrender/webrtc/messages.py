"""The page's messages and requests, parsed and checked (sans-IO), and the frame message it is sent.

Everything a page sends arrives here first: the session request (JSON posted with the
SDP offer), poses and feedback on the data channels (JSON text), the recording's rows
and images.  Each parser returns plain values or raises :class:`PageMessageError`
naming the field and what was wrong, so the front door can answer a bad request with
400 and end a session whose page misbehaves without touching any other session.  A page's
feedback becomes the protocol's :class:`~splitrender.protocol.Feedback`
(:meth:`PageFeedback.feedback`), and each frame's metadata goes to it as :func:`frame_message`.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from typing import Any

from ..errors import RemoteProtocolError
from ..protocol import Feedback

__all__ = ["BROWSER_METHODS", "HEADLESS_ONLY", "browser_methods", "PageMessageError", "SessionRequest", "PoseSample", "PageFeedback",
           "parse_session_request", "parse_channel_message", "parse_rows", "parse_recording", "Recording", "decode_json",
           "MAX_MESSAGE_BYTES", "MAX_JSON_DEPTH", "MAX_STATS", "ROW_COLUMNS", "rgba_to_rgb", "frame_message"]

BROWSER_METHODS = {
    "video": "shows the newest frame",
    "atw": "reprojects the newest frame to the current orientation (the pose it was rendered for comes by RTP timestamp)",
    "sas": "draws the PVS patches from the atlas (the video) at the current pose (patch slots come on a data channel)",
}
"""Methods the page draws, with what it does (the others: :data:`HEADLESS_ONLY`)."""

HEADLESS_ONLY = {
    "warp": "its depth is 16-bit and lossless, which no browser's WebRTC decoder takes",
    "tss": "the page does not decode its per-triangle atlas layout",
    "quads": "the page does not build its layered quad mesh",
    "probes": "its probes are lossless HEVC, which browsers do not decode over WebRTC",
}
"""Methods that stay headless-only, and why."""

MAX_MESSAGE_BYTES = 4096
"""Largest pose or feedback message a page may send on a data channel."""
MAX_ROWS = 18_000
"""Most rows one recording may post (5 minutes at 60 Hz; the page's traces are at most 2 minutes)."""
MAX_JSON_DEPTH = 8
"""Deepest nesting of arrays and objects in anything a page sends (its deepest, a recording's rows, is 3)."""
MAX_STATS = 64
"""Most entries in a recording's ``stats`` (the browser's getStats figures: about 20), names at most 64 characters."""
_JSON_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.S)

ROW_COLUMNS = ("frame", "t_s", "tick", "scene_t_s", "displayed_us", "update_frame_id", "update_age_ms",
               "motion_to_photon_ms", "client_ms", "rtp_timestamp", "px", "py", "pz", "qx", "qy", "qz", "qw")
"""The columns a page's recording row carries (the headless client's, less those only it measures)."""


def browser_methods(offered: tuple[str, ...] | list[str]) -> list[str]:
    """The offered methods the page can draw, in the server's order."""
    return [m for m in offered if m in BROWSER_METHODS]


class PageMessageError(RemoteProtocolError):
    """A request or message from a page that is malformed or out of range; the text names the field."""


def decode_json(data: bytes | str, where: str, max_bytes: int, max_values: int,
                max_depth: int = MAX_JSON_DEPTH) -> Any:
    """``data`` (UTF-8 JSON) decoded, with its work bounded before :func:`json.loads` builds anything: at most
    ``max_bytes`` bytes, ``max_values`` values (counted as commas and opening brackets outside strings) and
    ``max_depth`` levels of nesting.  Raises :class:`PageMessageError` naming ``where`` and the bound."""
    import numpy as np

    raw = data.encode("utf-8", "surrogatepass") if isinstance(data, str) else bytes(data)
    if len(raw) > max_bytes:
        raise PageMessageError(f"{where}: {len(raw)} bytes of JSON, more than the {max_bytes} allowed")
    bare = np.frombuffer(_JSON_STRING.sub(b'""', raw), np.uint8)     # strings' brackets and commas do not count
    opens = (bare == 0x5B) | (bare == 0x7B)
    n_values = int(np.count_nonzero(opens)) + int(np.count_nonzero(bare == 0x2C))
    if n_values > max_values:
        raise PageMessageError(f"{where}: about {n_values} JSON values, more than the {max_values} allowed")
    if n_values:
        steps = opens.view(np.int8) - ((bare == 0x5D) | (bare == 0x7D)).view(np.int8)
        deepest = int(np.cumsum(steps[steps != 0], dtype=np.int32).max(initial=0))   # over the brackets only
        if deepest > max_depth:
            raise PageMessageError(f"{where}: JSON nested {deepest} deep, more than the {max_depth} allowed")
        del steps
    del bare, opens             # the scan's copies go before json.loads builds the values
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise PageMessageError(f"{where}: not UTF-8 ({exc})") from None
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:   # JSONDecodeError, or an integer of more than 4300 digits
        raise PageMessageError(f"{where}: not JSON ({exc})"[:300]) from None


def _finite(v: Any) -> bool:
    """A JSON number that is not NaN or infinite (an integer of any size is finite: it is range-checked, never
    converted to a float, which would overflow)."""
    return isinstance(v, int) or math.isfinite(v)


def _number(d: dict[str, Any], key: str, where: str, lo: float, hi: float, integer: bool = False) -> float:
    if key not in d:
        raise PageMessageError(f"{where}: missing {key!r}")
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not _finite(v):
        raise PageMessageError(f"{where}.{key}: expected a finite number, got {_show(v)}")
    if not lo <= v <= hi:                       # before int(): an integer past float range compares exactly
        raise PageMessageError(f"{where}.{key}: {_show(v)} is out of range [{lo:g}, {hi:g}]")
    if integer and int(v) != v:
        raise PageMessageError(f"{where}.{key}: expected an integer, got {v!r}")
    return int(v) if integer else float(v)


def _show(v: Any) -> str:
    """``repr(v)`` cut to 60 characters (an integer of thousands of digits stays readable in an error)."""
    text = repr(v) if not isinstance(v, int) or abs(v) < 10**40 else f"an integer of {len(str(abs(v)))} digits"
    return text if len(text) <= 60 else text[:57] + "..."


def _vector(d: dict[str, Any], key: str, where: str, n: int, bound: float) -> tuple[float, ...]:
    v = d.get(key)
    if not isinstance(v, list) or len(v) != n:
        raise PageMessageError(f"{where}.{key}: expected a list of {n} numbers, got {v!r}"[:200])
    out = []
    for i, x in enumerate(v):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not _finite(x) or abs(x) > bound:
            raise PageMessageError(f"{where}.{key}[{i}]: expected a finite number within ±{bound:g}, got {_show(x)}")
        out.append(float(x))
    return tuple(out)


@dataclass(frozen=True)
class SessionRequest:
    """What a page asks for with its offer."""

    sdp: str
    method: str
    width: int
    height: int
    display_hz: float


def parse_session_request(body: Any, offered: list[str], max_pixels: int) -> SessionRequest:
    """The ``POST /api/session`` body: ``{"sdp", "type": "offer", "method", "width", "height", "display_hz"}``."""
    where = "session request"
    if not isinstance(body, dict):
        raise PageMessageError(f"{where}: expected a JSON object, got {type(body).__name__}")
    if body.get("type") != "offer":
        raise PageMessageError(f"{where}.type: expected 'offer', got {body.get('type')!r}"[:200])
    sdp = body.get("sdp")
    if not isinstance(sdp, str) or not sdp.startswith("v=0"):
        raise PageMessageError(f"{where}.sdp: expected an SDP offer starting 'v=0'")
    if len(sdp) > 64 * 1024:
        raise PageMessageError(f"{where}.sdp: {len(sdp)} characters, more than the 65536 allowed")
    method = body.get("method")
    if method not in offered:
        raise PageMessageError(f"{where}.method: {method!r} is not one this server offers the page "
                               f"({', '.join(offered) or 'none'})"[:300])
    w = int(_number(body, "width", where, 16, 7680, integer=True))
    h = int(_number(body, "height", where, 16, 4320, integer=True))
    if w % 2 or h % 2:
        raise PageMessageError(f"{where}: width and height must be even (H.264 4:2:0), got {w}x{h}")
    if w * h > max_pixels:
        raise PageMessageError(f"{where}: {w}x{h} is more than this server's {max_pixels} pixels")
    hz = _number(body, "display_hz", where, 1, 240)
    return SessionRequest(sdp, method, w, h, hz)


@dataclass(frozen=True)
class PoseSample:
    """A pose from the page: its clock (the server's wall clock, µs, as the page estimates it), a sequence
    number, position and orientation (x, y, z, w)."""

    seq: int
    client_time_us: int
    position: tuple[float, ...]
    orientation: tuple[float, ...]


@dataclass(frozen=True)
class PageFeedback:
    """A shown frame: its id, when it was shown and when it was received (µs, server clock)."""

    frame_id: int
    displayed_us: int
    received_us: int

    def feedback(self, stream: str) -> Feedback:
        """The protocol's Feedback for the session core: the frame applied on the page's one video ``stream``, decoded
        when received (the page sees no decode time), nothing lost that it could tell."""
        return Feedback(frame_id=self.frame_id, received_us=self.received_us, decoded_us=self.received_us,
                        displayed_us=self.displayed_us, lost_packets=0, applied={stream: self.frame_id})


def frame_message(order: Any, update: Any, keyframe: bool, rtp_ts: int, server_us: int,
                  origin: int | None) -> dict[str, Any]:
    """The ``frame`` channel's message for one frame (the page's FrameMeta): its id, RTP timestamp (``origin``: the
    sender's timestamp origin, once known), scene time, server time (µs), the page pose it was predicted from (time and
    sequence number, from the frame ``order``), keyframe, the pose it was rendered for, and the field of view where
    the method widened it (atw's overscan)."""
    meta = {"type": "frame", "id": order.frame_id, "rtp": rtp_ts, "t": order.t_s, "server_us": server_us,
            "pose_us": order.pose_us, "seq": order.pose_seq, "kf": bool(keyframe),
            "p": [round(float(v), 6) for v in update.pose.position],
            "q": [round(float(v), 7) for v in update.pose.orientation], "origin": origin}
    if "fov_y_deg" in update.meta:
        meta["fov"] = float(update.meta["fov_y_deg"])
    return meta


def parse_channel_message(text: Any) -> PoseSample | PageFeedback | str:
    """One message from the page's ``pose`` channel: a pose, feedback, or ``"bye"``."""
    where = "page message"
    if isinstance(text, bytes):
        raise PageMessageError(f"{where}: expected JSON text, got {len(text)} binary bytes")
    if not isinstance(text, str):
        raise PageMessageError(f"{where}: expected JSON text, got {type(text).__name__}")
    if len(text) > MAX_MESSAGE_BYTES:
        raise PageMessageError(f"{where}: {len(text)} characters, more than the {MAX_MESSAGE_BYTES} allowed")
    d = decode_json(text, where, 4 * MAX_MESSAGE_BYTES, MAX_MESSAGE_BYTES)
    if not isinstance(d, dict):
        raise PageMessageError(f"{where}: expected a JSON object, got {type(d).__name__}")
    kind = d.get("type")
    where = f"{kind} message" if isinstance(kind, str) else where
    if kind == "pose":
        q = _vector(d, "q", where, 4, 2.0)
        if not 0.5 < math.sqrt(sum(x * x for x in q)) < 1.5:
            raise PageMessageError(f"{where}.q: not a unit quaternion ({list(q)})")
        return PoseSample(int(_number(d, "seq", where, 0, 2**53, integer=True)),
                          int(_number(d, "t_us", where, 0, 2**62, integer=True)), _vector(d, "p", where, 3, 1e6), q)
    if kind == "feedback":
        return PageFeedback(int(_number(d, "frame_id", where, 0, 2**31, integer=True)),
                            int(_number(d, "displayed_us", where, 0, 2**62, integer=True)),
                            int(_number(d, "received_us", where, 0, 2**62, integer=True)))
    if kind == "bye":
        return "bye"
    raise PageMessageError(f"page message.type: {kind!r} is not one of 'pose', 'feedback', 'bye'"[:200])


def parse_rows(rows: Any) -> list[dict[str, float]]:
    """A recording's rows: a list of objects with the :data:`ROW_COLUMNS` (numbers or null)."""
    if not isinstance(rows, list):
        raise PageMessageError(f"recording.rows: expected a list, got {type(rows).__name__}")
    if len(rows) > MAX_ROWS:
        raise PageMessageError(f"recording.rows: {len(rows)} rows, more than the {MAX_ROWS} allowed")
    out = []
    for i, r in enumerate(rows):
        if not isinstance(r, dict):
            raise PageMessageError(f"recording.rows[{i}]: expected an object, got {type(r).__name__}")
        row: dict[str, float] = {}
        for k in ROW_COLUMNS:
            v = r.get(k)
            if v is None:
                row[k] = math.nan
            elif isinstance(v, bool) or not isinstance(v, (int, float)):
                raise PageMessageError(f"recording.rows[{i}].{k}: expected a number or null, got {_show(v)}")
            elif isinstance(v, int) and abs(v) > 2**63:
                raise PageMessageError(f"recording.rows[{i}].{k}: {_show(v)} is out of range (beyond ±2^63)")
            else:
                row[k] = float(v)
        for k in ("frame", "px", "py", "pz", "qx", "qy", "qz", "qw", "scene_t_s"):
            if not math.isfinite(row[k]):
                raise PageMessageError(f"recording.rows[{i}].{k}: missing or not finite")
        out.append(row)
    return out


def rgba_to_rgb(data: bytes, width: int, height: int) -> Any:
    """A WebGL ``readPixels`` read-back (RGBA, rows bottom up) as an (H, W, 3) uint8 image, rows top down."""
    import numpy as np

    if len(data) != width * height * 4:
        raise PageMessageError(f"recording image: {len(data)} bytes, expected {width}x{height}x4 = {width * height * 4}")
    return np.frombuffer(data, np.uint8).reshape(height, width, 4)[::-1, :, :3].copy()


@dataclass(frozen=True)
class Recording:
    """What a page posts back at its end: its rows (:func:`parse_rows`), the browser's own statistics (numbers
    only), and notes on the run."""

    rows: list[dict[str, float]]
    stats: dict[str, float] = field(default_factory=dict)
    trace: str = ""
    duration_s: float = math.nan
    complete: bool = True
    user_agent: str = ""
    record_every: int | None = None


def parse_recording(body: Any) -> Recording:
    """The ``POST /api/session/ID/recording`` body: ``{"rows", "stats", "trace", "duration_s", "complete",
    "user_agent", "record_every"}``.  Statistics that are not finite numbers (the decoder's name) are left out."""
    where = "recording"
    if not isinstance(body, dict):
        raise PageMessageError(f"{where}: expected a JSON object, got {type(body).__name__}")
    rows = parse_rows(body.get("rows"))
    raw_stats = body.get("stats", {})
    if not isinstance(raw_stats, dict):
        raise PageMessageError(f"{where}.stats: expected an object, got {type(raw_stats).__name__}")
    if len(raw_stats) > MAX_STATS:
        raise PageMessageError(f"{where}.stats: {len(raw_stats)} entries, more than the {MAX_STATS} allowed")
    stats: dict[str, float] = {}
    for k, v in raw_stats.items():
        if len(k) > 64:
            raise PageMessageError(f"{where}.stats: a name of {len(k)} characters, more than the 64 allowed")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not _finite(v) or abs(v) > 2**63:
            continue
        stats[k] = v
    duration = body.get("duration_s")
    every = body.get("record_every")
    trace, agent = body.get("trace", ""), body.get("user_agent", "")
    return Recording(
        rows, stats, trace[:100] if isinstance(trace, str) else "",
        float(duration) if not isinstance(duration, bool) and isinstance(duration, (int, float)) and _finite(duration)
        and abs(duration) < 1e9 else math.nan,
        bool(body.get("complete", True)), agent[:300] if isinstance(agent, str) else "",
        every if isinstance(every, int) and not isinstance(every, bool) and 0 <= every <= 1_000_000 else None)
