"""Score a live recording afterwards, exactly like the virtual-time runner does.

For every displayed frame the recording holds the trace pose, the scene time of the
display instant and (with ``--save-images``) the displayed image and hole mask.  The
ground truth is rendered at that pose and scene time with no latency, and the same
metrics as :mod:`splitrender.sim.runner` are computed; ``frames.csv`` gains the
columns of :func:`splitrender.metrics.score_frame` and ``gt_ms``, and
``summary.csv`` gets the runner's summary keys (where a live run has them).
"""

from __future__ import annotations

import csv
import json
import logging
import math
import zipfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from splitrender import metrics
from splitrender.errors import ConfigError
from splitrender.pipeline.rows import frames_summary, mean_of, session_summary
from splitrender.scene.loader import get_scene
from splitrender.scene.pose import CameraIntrinsics, Pose
from splitrender.pipeline.recording import JOURNAL, iter_journal
from splitrender.tabular import write_csv

__all__ = ["score_recording", "read_frames", "read_journal"]

logger = logging.getLogger(__name__)


def read_frames(path: Path) -> list[dict[str, Any]]:
    """Rows of a frames.csv with numbers parsed (empty cells become NaN)."""
    rows = []
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            row: dict[str, Any] = {}
            for k, v in r.items():
                try:
                    row[k] = float(v) if v != "" else math.nan
                except ValueError:
                    row[k] = v
            rows.append(row)
    return rows


def read_journal(path: Path) -> list[dict[str, Any]]:
    """Rows of a frames.jsonl (one JSON object per line); a torn last line is dropped."""
    return list(iter_journal(path))


def score_recording(out_dir: str | Path, renderer: Any | None = None, flip_every: int = 4,
                    progress: Callable[[int, int], None] | None = None, ssim_sigma: float = metrics.SSIM_SIGMA) -> dict[str, Any]:
    """Add image metrics to ``out_dir``'s frames.csv and write summary.csv; returns the summary.

    Needs a recording made with ``save_images``.  ``renderer`` must belong to the
    calling thread (one is created when ``None``).
    """
    d = Path(out_dir)
    rec = json.loads((d / "recording.json").read_text())
    if not rec.get("images"):
        raise ConfigError(f"{d}: the recording has no images (record with --save-images to score it)")
    counters = json.loads((d / "counters.json").read_text()) if (d / "counters.json").exists() else {}
    if (d / "frames.csv").exists():
        rows = read_frames(d / "frames.csv")
    elif (d / JOURNAL).exists():  # the client was killed: the rows it had appended
        rows = read_journal(d / JOURNAL)
    else:
        raise ConfigError(f"{d}: no frames.csv or {JOURNAL} (was the session started?)")
    if not rec.get("complete", True):
        logger.warning("%s: a partial recording (%s): scoring its %d frames", d, rec.get("error", "the client did not finish"),
                       len(rows))
    if renderer is None:
        from splitrender.render import Renderer

        renderer = Renderer()
    scene = get_scene(rec["scene"])
    intr = CameraIntrinsics(int(rec["width"]), int(rec["height"]), float(rec["fov_y_deg"]))
    damaged = 0
    for i, row in enumerate(rows):
        img_path = d / "images" / f"{int(row['frame']):06d}.npz"
        if not img_path.exists():
            continue
        try:
            with np.load(img_path) as z:
                color = z["color"]
                holes = z["holes"] if "holes" in z.files else None
        except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as exc:
            # a recording made before images were written atomically, or damaged since: skip and count it
            damaged += 1
            logger.warning("%s: image %s is damaged (%s: %s); frame %s not scored", d, img_path.name,
                           type(exc).__name__, exc, row["frame"])
            continue
        pose = Pose(np.array([row["px"], row["py"], row["pz"]]), np.array([row["qx"], row["qy"], row["qz"], row["qw"]]))
        w0 = time.perf_counter()
        gt = renderer.render(scene, float(row["scene_t_s"]), pose, intr, ("color", "object_id"))
        row["gt_ms"] = (time.perf_counter() - w0) * 1000
        # the same per-frame scoring as the virtual-time runner
        row.update(metrics.score_frame(color, holes, gt.color, gt.object_id > 0, bool(flip_every) and i % flip_every == 0,
                                         ssim_sigma, truth_model=scene.model_mask(gt.object_id)))
        if progress:
            progress(i + 1, len(rows))
    summary = _summary(rec, rows, counters, flip_every)
    summary["images_damaged"] = damaged
    write_csv(d / "frames.csv", rows)
    write_csv(d / "summary.csv", [summary])
    logger.info("scored %s: %d frames, mean PSNR %.2f dB", d, len(rows), summary["mean_psnr_db"])
    return summary


def _summary(rec: dict[str, Any], rows: list[dict[str, Any]], counters: dict[str, Any], flip_every: int) -> dict[str, Any]:
    dur = float(rec.get("duration_s", 0.0)) or math.nan
    kbps = counters.get("rtp_bytes", 0) * 8 / dur / 1000.0
    meta_kbps = counters.get("meta_bytes", 0) * 8 / dur / 1000.0
    once_kb = counters.get("session_bytes", 0) / 1000.0  # the one-off session data, as virtual time counts it
    params = rec.get("params", {})
    return {
        "method": rec["method"], "network": rec.get("network", "live"), "scene": rec["scene"], "trace": rec["trace"],
        "seed": 0, "params": ";".join(f"{k}={v}" for k, v in sorted(params.items())),
        "width": rec["width"], "height": rec["height"], "server_fps": rec.get("server_fps"),
        "client_fps": rec.get("display_hz"), **frames_summary(rows),    # the same display-side columns as virtual time's
        "mean_kbps": kbps + meta_kbps + once_kb * 8 / dur, "kbps_video": kbps,
        "kbps_meta": meta_kbps, "session_kb": once_kb, "steady_kbps": kbps + meta_kbps,
        "mean_server_ms": mean_of(rows, "server_render_ms"), "mean_encode_ms": mean_of(rows, "server_encode_ms"),
        "mean_network_ms": mean_of(rows, "network_ms"),
        **session_summary(counters, {}, rows),
        "lost_frames": counters.get("frames_partial", 0), "keyframes": counters.get("keyframes_received", 0),
        "mean_pred_err_cm": math.nan, "mean_pred_err_deg": math.nan,
        "flip_every": flip_every, "config_key": rec.get("session_id", ""),
    }
