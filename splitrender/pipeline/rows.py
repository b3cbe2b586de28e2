"""The rows a session records and their summaries, written once for every front door.

An *update row* is one per server frame (``updates.csv``: virtual time's, the live server's), a *frame row* one per
display tick (``frames.csv``: virtual time's, and a live client's recording once scored).  :func:`update_row` makes
the columns every server front door shares, :func:`frame_row` those every client front door shares (and
:func:`live_frame_row` the live client's whole row), :func:`feedback_row` a live server's ``feedback.csv`` row (one per
``Feedback``); :func:`frames_summary`, :func:`updates_summary` and
:func:`session_summary` make a run's summary columns from the rows and the cores' counters, the same for a
virtual-time run and a scored live recording (:func:`run_summary`: a virtual-time run's whole summary row).  Each
front door adds only what it alone measures (virtual time: the modelled cost, delivery and prediction error; live:
the wall-clock stages of the worker round trip and the send).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, Iterable

from .. import metrics
from ..metrics.image import mean_of, pct_of
from .wire import SESSION_STREAM

__all__ = ["FEEDBACK_COLUMNS", "feedback_row", "frame_row", "frames_summary", "live_frame_row", "mean_of", "pct_of",
           "run_summary", "SentBytes", "session_summary", "update_row", "updates_summary"]

FEEDBACK_TIMINGS = ("render", "encode", "encoded_at")
"""The server timings a client echoes in Feedback (those the server put in FrameMeta); others are ignored."""
FEEDBACK_COLUMNS = ("frame_id", "server_us", "received_us", "decoded_us", "displayed_us", "pose_time_us", "lost_packets",
                    "motion_to_photon_ms", "lost_frames", *(f"server_{k}_us" for k in FEEDBACK_TIMINGS))
"""The columns of a live server's ``feedback.csv``, fixed (a Feedback may echo fewer timings)."""


def update_row(frame_id: int, t_s: float, out: Any, enc: Any, order: Any, stages: dict[str, float],
               streams: Iterable[str], congestion: dict[str, float]) -> dict[str, Any]:
    """The columns of one server frame's row that every front door writes: its id and scene time, wire bytes in all
    and per stream (``streams``: the session's, the one-off session data left out), keyframe, the stages of
    :func:`~.frames.make_frame` (``shared_ms``, ``server_ms``: the method's own), ``encode_ms``, the latency the
    order expected, and the estimator's state (:meth:`~.session.ServerSession.congestion`)."""
    row: dict[str, Any] = {"frame_id": frame_id, "t_s": t_s, "bytes": out.total_wire_bytes,
                           "keyframe": int(out.keyframe), "shared_ms": stages.get("shared_ms", 0.0),
                           "server_ms": stages["produce_ms"], "encode_ms": enc.encode_ms,
                           "expected_latency_ms": order.expected_latency_s * 1000}
    row.update({f"bytes_{k}": out.wire_bytes.get(k, 0) for k in streams if k != "session"})
    row.update(congestion)
    return row


class SentBytes:
    """The wire bytes a session sent per stream (in the order the streams are named or first counted): :attr:`total`
    over the session, and its frames' over the last second (:meth:`kbps`, a display tick's ``kbps_<stream>``
    columns); the virtual-time runner's, whose clock says when each frame left."""

    def __init__(self, names: Iterable[str]) -> None:
        self.total: dict[str, int] = dict.fromkeys(names, 0)
        self._frames: deque[tuple[float, dict[str, int]]] = deque()

    def add(self, name: str, n: int) -> None:
        """``n`` more bytes of stream ``name`` (outside any frame's: the session data, probes)."""
        self.total[name] = self.total.get(name, 0) + n

    def frame(self, t_s: float, wire_bytes: dict[str, int]) -> None:
        """A frame's wire bytes per stream, sent at ``t_s``."""
        for k, v in wire_bytes.items():
            self.add(k, v)
        self._frames.append((t_s, dict(wire_bytes)))

    def kbps(self, t_s: float) -> dict[str, float]:
        """``kbps_<stream>`` of every stream but the one-off session data: the frames sent after ``t_s`` - 1 s."""
        while self._frames and self._frames[0][0] <= t_s - 1.0:
            self._frames.popleft()
        return {f"kbps_{name}": sum(w.get(name, 0) for _, w in self._frames) * 8 / 1000.0 for name in self.total
                if name != SESSION_STREAM}


def frame_row(index: int, t_s: float, shown: int | None, display_s: float, update_s: float, pose_s: float,
              client_ms: float, decode_ms: float) -> dict[str, Any]:
    """The columns of one display tick's row (``frames.csv``) that every client front door writes: its index and
    time, the update shown (``shown``: its frame id; None for a blank tick, the black background, whose row names
    update -1), its age and motion-to-photon (the tick's display time ``display_s``
    less the update's server time ``update_s``, and less the time its pose was sampled ``pose_s``: seconds on one
    clock), and the client's apply-and-render and decode milliseconds.  A blank tick has no ages, client or decode
    milliseconds (NaN, whatever the front door measured: it shows no update), so ``mean_client_ms`` is the cost of a
    tick that shows one in every front door."""
    if shown is None:
        return {"frame": index, "t_s": t_s, "update_frame_id": -1, "update_age_ms": math.nan,
                "motion_to_photon_ms": math.nan, "client_ms": math.nan, "decode_ms": math.nan}
    return {"frame": index, "t_s": t_s, "update_frame_id": shown, "update_age_ms": (display_s - update_s) * 1000,
            "motion_to_photon_ms": (display_s - pose_s) * 1000, "client_ms": client_ms, "decode_ms": decode_ms}


def live_frame_row(index: int, tick: int, trace_t: float, scene_t: float, pose: Any, fr: Any, displayed_us: int,
                   client_ms: float = math.nan) -> dict[str, Any]:
    """A live client's display tick row (its recording's ``frames.csv``, which :mod:`splitrender.client.score` reads):
    :func:`frame_row`'s columns from the shown update's timestamps (``fr``: a
    :class:`~splitrender.pipeline.receiver.ReceivedFrame`; None: the black background), the tick, its scene time and
    wall-clock µs, the pose shown (``pose.to_list()``: position, then the quaternion x, y, z, w), and the stages of the
    update shown as its timestamps tell them (ms)."""
    p = pose.to_list()
    place = {"tick": tick, "scene_t_s": scene_t, "displayed_us": displayed_us,
             "px": p[0], "py": p[1], "pz": p[2], "qx": p[3], "qy": p[4], "qz": p[5], "qw": p[6]}
    if fr is None:
        return {**frame_row(index, trace_t, None, 0.0, math.nan, math.nan, client_ms, math.nan), **place}
    timing, server_us, pose_us = fr.env.timing_us, fr.meta.server_time_us, fr.meta.pose.client_time_us
    received_us, decoded_us = int(fr.received_ms * 1000), int(fr.decoded_ms * 1000)
    encoded_at = int(timing.get("encoded_at", server_us))
    # times in seconds from the display instant (the wall clock's µs are too many for a float's seconds)
    return {**frame_row(index, trace_t, fr.update.frame_id, 0.0, (server_us - displayed_us) / 1e6,
                        (pose_us - displayed_us) / 1e6, client_ms, (decoded_us - received_us) / 1000.0), **place,
            "server_render_ms": timing.get("render", 0) / 1000.0, "server_encode_ms": timing.get("encode", 0) / 1000.0,
            "network_ms": (received_us - encoded_at) / 1000.0,
            "meta_network_ms": (int(fr.meta_ms * 1000) - encoded_at) / 1000.0,
            "wait_display_ms": (displayed_us - decoded_us) / 1000.0 - client_ms,
            "pose_uplink_age_ms": (server_us - pose_us) / 1000.0,
            "keyframe": int(fr.meta.keyframe), "missing": ";".join(sorted(fr.update.missing))}


def feedback_row(fb: Any, server_us: int | None) -> dict[str, Any]:
    """One ``Feedback``'s row (:data:`FEEDBACK_COLUMNS`): its times (µs on the protocol's clock), the frame's server
    time ``server_us`` as the server remembers it ("" where it no longer does), motion-to-photon ("" where the
    Feedback names no pose time: a browser page's), and the lost frames
    per stream as ``stream:id,id;...``."""
    row: dict[str, Any] = {"frame_id": fb.frame_id, "server_us": server_us if server_us is not None else "",
                           "received_us": fb.received_us, "decoded_us": fb.decoded_us, "displayed_us": fb.displayed_us,
                           "pose_time_us": fb.pose_time_us, "lost_packets": fb.lost_packets,
                           "motion_to_photon_ms": (fb.displayed_us - fb.pose_time_us) / 1000.0 if fb.pose_time_us else "",
                           "lost_frames": ";".join(f"{k}:{','.join(map(str, v))}" for k, v in fb.lost.items())}
    row.update({f"server_{k}_us": v for k, v in fb.server_timings_us.items() if k in FEEDBACK_TIMINGS})
    return row


def updates_summary(rows: list[dict[str, Any]]) -> dict[str, float]:
    """A session's server-side means from its update rows."""
    return {"mean_server_ms": mean_of(rows, "server_ms"), "mean_shared_server_ms": mean_of(rows, "shared_ms"),
            "mean_encode_ms": mean_of(rows, "encode_ms"), "mean_expected_latency_ms": mean_of(rows, "expected_latency_ms")}


def frames_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """A session's display-side summary from its frame rows: the quality aggregates over every tick and over the
    ticks with content (:func:`~splitrender.metrics.quality_summary`, :func:`~splitrender.metrics.content_quality_summary`),
    update age (mean and p95), motion-to-photon, the client's decode, apply-and-render and ground-truth milliseconds,
    and the start-up ticks before any content."""
    return {
        "frames": len(rows), **metrics.quality_summary(rows), **metrics.content_quality_summary(rows),
        "mean_update_age_ms": mean_of(rows, "update_age_ms"), "p95_update_age_ms": pct_of(rows, "update_age_ms", 95),
        "mean_motion_to_photon_ms": mean_of(rows, "motion_to_photon_ms"), "mean_decode_ms": mean_of(rows, "decode_ms"),
        "mean_client_ms": mean_of(rows, "client_ms"), "mean_gt_ms": mean_of(rows, "gt_ms"),
        "frames_before_content": int(sum(1 for r in rows if r.get("update_frame_id", -1) == -1)),
    }


def session_summary(client: dict[str, Any], server: dict[str, Any], rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The loss-recovery columns of a session's summary, the same for a virtual-time run and a live recording.

    ``client``: :meth:`ClientSession.all_counters`; ``server``: :attr:`ServerSession.counters`; ``rows``:
    one per display tick with ``t_s`` (s) and ``update_frame_id`` (-1 before the first update).
    ``shown_pct``: distinct updates shown over the server frames from the first shown to the last;
    ``longest_freeze_ms``: the longest time between two new updates reaching the screen; ``lost_frames``: the frames
    released with a stream missing."""
    firsts: dict[int, float] = {}
    for r in rows:
        fid = int(r.get("update_frame_id", -1))
        if fid >= 0 and fid not in firsts:
            firsts[fid] = float(r["t_s"])
    ids = sorted(firsts)
    span = ids[-1] - ids[0] + 1 if ids else 0
    times = sorted(firsts.values())
    gaps = [b - a for a, b in zip(times, times[1:])]
    return {
        "updates_shown": len(ids), "shown_pct": 100.0 * len(ids) / span if span else math.nan,
        "longest_freeze_ms": 1000.0 * max(gaps) if gaps else math.nan,
        "lost_frames": int(client.get("frames_partial", 0)), "keyframes": int(server.get("keyframes", 0)),
        "keyframe_requests": int(client.get("plis_sent", 0)),
        "plis_received": int(server.get("plis", 0)), "nacks": int(client.get("nacks_sent", 0)),
        "nacked_packets": int(client.get("nacked_packets", 0)), "retransmitted": int(server.get("retransmitted", 0)),
        "fec_recovered": int(sum(v for k, v in client.items() if k.endswith("_fec_recovered"))),
        "stalls": int(client.get("stalls", 0)), "longest_stall_ms": float(client.get("longest_stall_ms", 0.0)),
        "apply_errors": int(client.get("apply_errors", 0)), "decode_errors": int(client.get("decode_errors", 0)),
        "rtcp_up_bytes": int(client.get("rtcp_bytes_sent", 0)), "rtcp_down_bytes": int(server.get("rtcp_bytes_sent", 0)),
        "retransmitted_bytes": int(server.get("retransmitted_bytes", 0)),
    }


def run_summary(cfg: Any, client: int, frames: list[dict[str, Any]], updates: list[dict[str, Any]],
                wire_bytes: dict[str, int], duration_s: float, server_skipped: int, protocol_errors: int,
                packets_lost: int, client_counters: dict[str, Any], server_counters: dict[str, Any],
                server_summary: dict[str, Any]) -> dict[str, Any]:
    """A virtual-time run's ``summary.csv`` row for client ``client`` (a scored live recording's has the same columns
    where both measure them): the run's settings (``cfg``, a :class:`~splitrender.sim.config.RunConfig`),
    :func:`frames_summary` of its display rows, the bit rates of ``wire_bytes`` (per stream, over ``duration_s``; the
    one-off session data apart), :func:`updates_summary`, the modelled cost and the prediction error of its update
    rows, the runner's own counts (ticks the busy server skipped, malformed updates, datagrams the downlink lost),
    :func:`session_summary` of the cores' counters, and ``server_summary`` (what the server core's estimator, rate
    adaptation and operating point did: :meth:`~.session.ServerSession.summary`)."""
    total = sum(wire_bytes.values())
    once = wire_bytes.get(SESSION_STREAM, 0)  # the one-off session data (a probes scene upload)
    traces = cfg.client_traces or (cfg.trace,)
    return {
        "client": client, "method": cfg.method, "network": cfg.network, "scene": cfg.scene, "trace": cfg.trace,
        "seed": cfg.seed, "params": ";".join(f"{k}={v}" for k, v in sorted(cfg.method_params.items())),
        "client_trace": traces[client % len(traces)], "width": cfg.width, "height": cfg.height,
        "server_fps": cfg.server_fps, "client_fps": cfg.client_fps, **frames_summary(frames),
        "mean_kbps": total * 8 / duration_s / 1000.0,
        **{f"kbps_{k}": b * 8 / duration_s / 1000.0 for k, b in wire_bytes.items()},
        "session_kb": once / 1000.0, "steady_kbps": (total - once) * 8 / duration_s / 1000.0,
        **updates_summary(updates),
        "cost_model": cfg.cost_model, "mean_cost_ms": mean_of(updates, "cost_ms"), "server_skipped": server_skipped,
        "clients": cfg.clients, "protocol_errors": protocol_errors, "packets_lost": packets_lost,
        "rtp_packets": server_counters["rtp_packets"], **session_summary(client_counters, server_counters, frames),
        "mean_pred_err_cm": mean_of(updates, "pred_err_cm"), "mean_pred_err_deg": mean_of(updates, "pred_err_deg"),
        "flip_every": cfg.flip_every, "config_key": cfg.key(), **server_summary,
    }
