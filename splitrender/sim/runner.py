"""The virtual-time runner: a deterministic discrete-event run of one method.

Timeline (all on the simulated clock, seconds):

- The client's tracker samples the trace at ``tracker_hz``; each pose travels the
  uplink as a small datagram (a lost pose is simply superseded by the next one).
- The server ticks at ``server_fps``.  At tick ``t`` it feeds the poses that have
  arrived to its predictor, predicts the pose at the expected display time
  (``t + server_latency + mean downlink delay + decode + half a display interval``),
  asks the method's server half for an :class:`Update`, encodes every plane with the
  stream's real codec and the metadata with msgpack + zstd.  Bytes counted are the
  bytes produced, for every stream.
- After ``server_latency_ms`` the frame leaves: video as MTU-sized RTP packets over
  the (lossy) downlink, metadata as reliable TCP segments (a lost segment costs one
  RTO, head-of-line blocking included).  A video frame with a lost or corrupted packet
  cannot be decoded, nor can later frames of that stream until an IDR: the client
  sends a keyframe request up the control uplink and the server answers with an IDR.
- Updates are released to the client in frame order once all their streams and
  metadata have arrived, plus ``decode_latency_ms``.
- The client displays at ``client_fps``: at each tick it applies every released
  update, renders through the method's client half at the true pose of that tick,
  and the ground truth is rendered at the same pose and time with no latency.

Wall-clock costs (server render+pack, encode, decode, client render, ground truth)
are measured and recorded, but never move the simulated clock, so a run is the same
on any machine for a given seed.
"""

from __future__ import annotations

import csv
import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .. import metrics
from ..codecs.meta import pack_meta, unpack_meta
from ..codecs.video import VideoDecoder, VideoEncoder
from ..errors import CodecError, RemoteProtocolError
from ..methods.base import ClientFeedback, DecodedUpdate, ServerContext, get_method, make_config
from ..netsim import Link, parse_path
from ..render.renderer import Renderer
from ..scene.loader import get_scene
from ..scene.pose import CameraIntrinsics, Pose
from ..scene.predict import PerfectPredictor, make_predictor, prediction_error
from ..scene.trace import get_trace
from .config import RunConfig, to_toml
from .truth import truth_source

log = logging.getLogger(__name__)

RTP_OVERHEAD_BYTES = 12 + 8 + 20  # RTP + UDP + IPv4 headers per packet
TCP_SEGMENT_BYTES = 1400
POSE_MESSAGE_BYTES = 64 + 40
ProgressFn = Callable[[int, int], None]


@dataclass
class _Pending:
    frame_id: int
    release_s: float
    update: DecodedUpdate
    t_s: float
    pose_sample_t_s: float
    decode_ms: float
    nbytes: int
    pred_err_cm: float = math.nan
    pred_err_deg: float = math.nan


@dataclass
class RunResult:
    config: RunConfig
    frames: list[dict[str, Any]] = field(default_factory=list)
    updates: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)
    images: list[tuple[int, np.ndarray, np.ndarray]] = field(default_factory=list)
    resolved: dict[str, Any] = field(default_factory=dict)

    def write(self, out_dir: str | Path) -> Path:
        """Write frames.csv, updates.csv, summary.csv and config.toml into ``out_dir``."""
        d = Path(out_dir)
        d.mkdir(parents=True, exist_ok=True)
        write_csv(d / "frames.csv", self.frames)
        write_csv(d / "updates.csv", self.updates)
        write_csv(d / "summary.csv", [self.summary])
        text = "[run]\n" + to_toml(self.config.to_dict(), "run.")
        if self.resolved:  # every method parameter (defaults included) and both network directions
            text += "\n[resolved]\n" + to_toml(self.resolved, "resolved.")
        (d / "config.toml").write_text(text)
        if self.images:
            from PIL import Image

            (d / "images").mkdir(exist_ok=True)
            for frame, shown, truth in self.images:
                Image.fromarray(np.concatenate([shown, truth], axis=1)).save(d / "images" / f"frame{frame:05d}_client_vs_truth.png")
        return d


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    keys: list[str] = []
    for r in rows:
        for k in r:
            if k not in keys:
                keys.append(k)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys, restval="")
        w.writeheader()
        for r in rows:
            w.writerow({k: _fmt(v) for k, v in r.items()})


def _fmt(v: Any) -> Any:
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return v


def _packets(nbytes: int, mtu: int) -> list[int]:
    n = max(1, math.ceil(nbytes / mtu))
    sizes = [mtu] * (n - 1) + [nbytes - mtu * (n - 1)]
    return [s + RTP_OVERHEAD_BYTES for s in sizes]


class VirtualTimeRun:
    """One run; call :meth:`run`.  Holds the GL renderer (one thread owns it)."""

    def __init__(self, cfg: RunConfig, renderer: Renderer | None = None, progress: ProgressFn | None = None) -> None:
        self.cfg = cfg
        self.progress = progress
        self.spec = get_method(cfg.method)
        self.mcfg = make_config(self.spec.config, cfg.method_params)
        self.scene = get_scene(cfg.scene)
        self.trace = get_trace(cfg.trace, scene=self.scene, fov_y_deg=cfg.fov_y_deg, aspect=cfg.width / cfg.height)
        self.path = parse_path(cfg.network)
        self.intr = CameraIntrinsics(cfg.width, cfg.height, cfg.fov_y_deg)
        self.renderer = renderer or Renderer()
        self.duration_s = min(cfg.duration_s or self.trace.duration_s, self.trace.duration_s)
        self.truth = truth_source(cfg.truth_cache, self.renderer, self.scene, self.trace, self.intr, cfg.client_fps)

    def run(self) -> RunResult:
        cfg, intr = self.cfg, self.intr
        seeds = np.random.SeedSequence(cfg.seed).spawn(3)
        up = Link(self.path.uplink, np.random.default_rng(seeds[0]))
        ctrl = Link(self.path.uplink, np.random.default_rng(seeds[1]))
        down = Link(self.path.downlink, np.random.default_rng(seeds[2]))
        server = self.spec.server(self.mcfg, intr, self.scene, cfg.server_fps)
        streams = server.streams()
        encoders = {s.name: VideoEncoder(s.codec, s.width, s.height) for s in streams}
        decoders = {s.name: VideoDecoder(s.codec.codec, s.codec.input_format) for s in streams}
        session_blob = pack_meta(server.session_data())
        client = self.spec.client(self.mcfg, intr, self.renderer.ctx, unpack_meta(session_blob))
        predictor = PerfectPredictor(self.trace) if cfg.predictor == "perfect" else make_predictor(cfg.predictor)

        # upstream poses: precomputed deliveries (the uplink model is deterministic)
        arrivals: list[tuple[float, float]] = []
        for k in range(int(self.duration_s * cfg.tracker_hz) + 1):
            ts = k / cfg.tracker_hz
            for d in up.send(ts, POSE_MESSAGE_BYTES):
                if not d.corrupted:
                    arrivals.append((d.time_s, ts))
        arrivals.sort()
        arrival_idx = 0
        latest_pose_t = 0.0
        predictor.observe(0.0, self.trace.pose_at(0.0))  # the Hello carries the first pose

        mean_down_s = self.path.downlink.delay_ms / 1000.0
        expected_latency = (cfg.server_latency_ms + cfg.decode_latency_ms) / 1000.0 + mean_down_s + 0.5 / cfg.client_fps
        broken = {s.name: False for s in streams}
        kf_request_arrival = math.inf
        kf_request_pending = False
        kf_requests = 0
        last_release = -math.inf
        pending: deque[_Pending] = deque()
        import dataclasses

        result = RunResult(cfg, resolved={"method": dataclasses.asdict(self.mcfg), "network": dataclasses.asdict(self.path)})
        bytes_by_stream: dict[str, int] = {s.name: 0 for s in streams}
        bytes_by_stream["meta"] = 0
        bytes_by_stream["session"] = len(session_blob)
        n_server = int(math.floor(self.duration_s * cfg.server_fps)) + 1
        n_display = int(math.floor(self.duration_s * cfg.client_fps)) + 1
        next_server = 0
        shown: _Pending | None = None
        first_release: float | None = None
        lost_frames = 0
        keyframes = 0
        apply_errors = 0

        for di in range(n_display):
            t_d = di / cfg.client_fps
            # -- server frames due before this display tick
            while next_server < n_server and next_server / cfg.server_fps <= t_d:
                f = next_server
                next_server += 1
                t_f = f / cfg.server_fps
                while arrival_idx < len(arrivals) and arrivals[arrival_idx][0] <= t_f:
                    ts = arrivals[arrival_idx][1]
                    if ts >= latest_pose_t:
                        predictor.observe(ts, self.trace.pose_at(ts))
                        latest_pose_t = ts
                    arrival_idx += 1
                kf = False
                if kf_request_pending and kf_request_arrival <= t_f:
                    kf, kf_request_pending = True, False
                target_t = t_f + expected_latency
                target_pose = predictor.predict(target_t)
                ctx = ServerContext(
                    frame_id=f, t_s=t_f, scene=self.scene, renderer=self.renderer, intrinsics=intr,
                    latest_pose=self.trace.pose_at(latest_pose_t), latest_pose_t_s=latest_pose_t,
                    target_pose=target_pose, target_t_s=target_t, predict=predictor.predict,
                    expected_latency_s=expected_latency, keyframe_requested=kf,
                    feedback=ClientFeedback(keyframe_requested=kf),
                )
                w0 = time.perf_counter()
                upd = server.produce(ctx)
                server_ms = (time.perf_counter() - w0) * 1000
                force = upd.force_idr or kf
                w0 = time.perf_counter()
                encoded = {}
                for s in streams:
                    if s.name in upd.planes:
                        encoded[s.name] = encoders[s.name].encode(upd.planes[s.name], force_idr=force)
                meta_blob = pack_meta({"frame_id": f, "t_s": t_f, "pose": upd.pose.to_list(), "m": upd.meta})
                encode_ms = (time.perf_counter() - w0) * 1000
                send_t = t_f + cfg.server_latency_ms / 1000.0
                arrive = send_t
                ok = True
                frame_bytes = len(meta_blob)
                bytes_by_stream["meta"] += len(meta_blob)
                any_key = False
                for name, ef in encoded.items():
                    bytes_by_stream[name] += ef.nbytes
                    frame_bytes += ef.nbytes
                    any_key |= ef.keyframe
                    got = True
                    last = send_t
                    for size in _packets(ef.nbytes, cfg.mtu_bytes):
                        ds = [d for d in down.send(send_t, size) if not d.corrupted]
                        if not ds:
                            got = False
                        else:
                            last = max(last, min(d.time_s for d in ds))
                    if ef.keyframe and got:
                        broken[name] = False
                    if not got:
                        broken[name] = True
                    if broken[name]:
                        ok = False
                    arrive = max(arrive, last)
                meta_arrive = send_t
                for i in range(0, max(1, len(meta_blob)), TCP_SEGMENT_BYTES):
                    seg = min(TCP_SEGMENT_BYTES, len(meta_blob) - i) + 40
                    meta_arrive = max(meta_arrive, down.send(send_t, seg, reliable=True)[0].time_s)
                arrive = max(arrive, meta_arrive)
                keyframes += int(any_key)
                pred_cm, pred_deg = prediction_error(target_pose, self.trace.pose_at(target_t))
                urow = {"frame_id": f, "t_s": t_f, "bytes": frame_bytes, "keyframe": int(any_key), "delivered": int(ok),
                        "server_ms": server_ms, "encode_ms": encode_ms, "pred_err_cm": pred_cm, "pred_err_deg": pred_deg,
                        "arrival_s": arrive}
                for name, ef in encoded.items():
                    urow[f"bytes_{name}"] = ef.nbytes
                urow["bytes_meta"] = len(meta_blob)
                urow.update({f"srv_{k}": v for k, v in server.stats().items()})
                result.updates.append(urow)
                if not ok:
                    lost_frames += 1
                    if not kf_request_pending:
                        kf_requests += 1
                        kf_request_pending = True
                        notice = max(arrive, send_t + mean_down_s)
                        kf_request_arrival = min(d.time_s for d in ctrl.send(max(notice, ctrl._last_now), 80, reliable=True))
                    # decoders of streams that are fine still decode this frame to stay in sync
                    for name, ef in encoded.items():
                        if not broken[name]:
                            decoders[name].decode(ef.data)
                    continue
                w0 = time.perf_counter()
                planes = {}
                try:
                    for name, ef in encoded.items():
                        planes[name] = decoders[name].decode(ef.data)
                except CodecError:
                    log.warning("run %s: frame %d failed to decode", cfg.method, f)
                    continue
                meta = unpack_meta(meta_blob)
                decode_ms = (time.perf_counter() - w0) * 1000
                release = max(arrive + cfg.decode_latency_ms / 1000.0, last_release)
                last_release = release
                du = DecodedUpdate(f, meta["t_s"], Pose.from_list(meta["pose"]), planes, meta["m"])
                pending.append(_Pending(f, release, du, t_f, latest_pose_t, decode_ms, frame_bytes, pred_cm, pred_deg))
            # -- display tick
            applied_ms = 0.0
            while pending and pending[0].release_s <= t_d:
                p = pending.popleft()
                w0 = time.perf_counter()
                try:
                    client.apply(p.update)
                except RemoteProtocolError as exc:  # a malformed update: keep the last good state
                    apply_errors += 1
                    log.warning("run %s: update %d rejected by the client half: %s", cfg.method, p.frame_id, exc)
                    continue
                finally:
                    applied_ms += (time.perf_counter() - w0) * 1000
                shown = p
                if first_release is None:
                    first_release = p.release_s
            if shown is None:
                continue
            true_pose = self.trace.pose_at(t_d)
            w0 = time.perf_counter()
            cf = client.render(true_pose, t_d)
            client_ms = (time.perf_counter() - w0) * 1000 + applied_ms
            row: dict[str, Any] = {
                "frame": di, "t_s": t_d, "update_frame_id": shown.frame_id,
                "update_age_ms": (t_d - shown.t_s) * 1000, "motion_to_photon_ms": (t_d - shown.pose_sample_t_s) * 1000,
                "client_ms": client_ms, "decode_ms": shown.decode_ms,
                "pred_err_cm": shown.pred_err_cm, "pred_err_deg": shown.pred_err_deg,
            }
            if cfg.metrics:
                w0 = time.perf_counter()
                gt_out = self.truth.render(self.scene, t_d, true_pose, intr, ("color", "object_id"))
                gt = gt_out.color
                row["gt_ms"] = getattr(gt_out, "render_ms", None) or (time.perf_counter() - w0) * 1000  # a cache hit: its render time
                row.update(metrics.score_frame(cf.color, cf.holes, gt, gt_out.object_id > 0,
                                               bool(cfg.flip_every) and di % cfg.flip_every == 0, cfg.ssim_sigma))
                if cfg.save_images_every and di % cfg.save_images_every == 0:
                    result.images.append((di, cf.color, gt))
            row.update({f"cli_{k}": v for k, v in cf.stats.items()})
            result.frames.append(row)
            if self.progress:
                self.progress(di + 1, n_display)
        result.summary = self._summary(result, bytes_by_stream, lost_frames, keyframes, kf_requests)
        result.summary["apply_errors"] = apply_errors
        return result

    def _summary(self, r: RunResult, bytes_by_stream: dict[str, int], lost: int, keyframes: int, kf_requests: int) -> dict[str, Any]:
        cfg = self.cfg
        fr = r.frames

        def col(k: str) -> np.ndarray:
            return np.array([f.get(k, math.nan) for f in fr], dtype=np.float64)

        def mean(k: str) -> float:
            a = col(k)
            a = a[~np.isnan(a)]
            return float(a.mean()) if a.size else math.nan

        def pct(k: str, q: float) -> float:
            a = col(k)
            a = a[~np.isnan(a)]
            return float(np.percentile(a, q)) if a.size else math.nan

        dur = self.duration_s + 1.0 / cfg.server_fps
        total = sum(bytes_by_stream.values())
        s: dict[str, Any] = {
            "method": cfg.method, "network": cfg.network, "scene": cfg.scene, "trace": cfg.trace, "seed": cfg.seed,
            "params": ";".join(f"{k}={v}" for k, v in sorted(cfg.method_params.items())),
            "width": cfg.width, "height": cfg.height, "server_fps": cfg.server_fps, "client_fps": cfg.client_fps,
            "frames": len(fr), **metrics.quality_summary(fr), "mean_kbps": total * 8 / dur / 1000.0,
        }
        for name, b in bytes_by_stream.items():
            s[f"kbps_{name}"] = b * 8 / dur / 1000.0
        ups = r.updates
        s.update({
            "mean_update_age_ms": mean("update_age_ms"), "p95_update_age_ms": pct("update_age_ms", 95),
            "mean_motion_to_photon_ms": mean("motion_to_photon_ms"),
            "mean_server_ms": float(np.mean([u["server_ms"] for u in ups])) if ups else math.nan,
            "mean_encode_ms": float(np.mean([u["encode_ms"] for u in ups])) if ups else math.nan,
            "mean_decode_ms": mean("decode_ms"), "mean_client_ms": mean("client_ms"), "mean_gt_ms": mean("gt_ms"),
            "lost_frames": lost, "keyframes": keyframes, "keyframe_requests": kf_requests,
            "mean_pred_err_cm": float(np.mean([u["pred_err_cm"] for u in ups])) if ups else math.nan,
            "mean_pred_err_deg": float(np.mean([u["pred_err_deg"] for u in ups])) if ups else math.nan,
            "flip_every": cfg.flip_every, "config_key": cfg.key(),
        })
        return s


def run(cfg: RunConfig, out_dir: str | Path | None = None, renderer: Renderer | None = None, progress: ProgressFn | None = None) -> RunResult:
    """Run ``cfg`` in virtual time; write CSVs and the resolved config when ``out_dir`` is given."""
    res = VirtualTimeRun(cfg, renderer, progress).run()
    if out_dir is not None:
        res.write(out_dir)
    return res
