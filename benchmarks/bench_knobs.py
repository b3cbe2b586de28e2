"""What each operating-point knob saves: the cost priors of ``--adapt full`` (issue 35).

Every method's knobs (:meth:`~splitrender.methods.base.MethodConfig.adapt_knobs`) declare a prior: the bits each
level sends over those of its first level.  This benchmark measures them.

* Method knobs: one virtual-time run per level (the other knobs at their first), the default scene without GI, the
  ``walk`` trace, 320x180, 1.5 s, an ideal network, no adaptation.  Its figure is the bytes of the streams the knob
  acts on: the lossy video streams for a ``video`` knob, everything else (reliable data, geometry, lossless video)
  for a ``data`` knob.  The first 0.5 s (the first IDR and the caches filling) is left out.
* The pipeline's resolution ``scale``: the ground truth of the same walk, coded by x264 at the method's defaults
  (crf 23, 4:4:4, GOP 30) at each scale.

Writes ``benchmarks/results/bench_knobs.json`` with each level's ratio beside the prior the code declares.

With ``--quality`` it measures each method's quality model instead (issue 48, part 2;
:mod:`splitrender.experiments.quality_model`): model PSNR at every level of every knob the controller may move (the
method's own, ``frame_div`` where it offers it, ``scale`` where a stream is scalable), the others at their first, the
point pinned for a 2 s run; dB per 100 ms of motion-to-photon (20 -> 120 ms each way); dB per halving of the lossy
video's bytes (crf + 6).  Writes ``benchmarks/results/bench_knobs_quality.json``: what the methods' tables
(``QUALITY`` in each method's config module) store.

    python benchmarks/bench_knobs.py [--methods warp,sas] [--duration 1.5]
    python benchmarks/bench_knobs.py --quality [--methods video,atw,warp,sas,tss,quads] [--duration 2] [--knobs frame_div]

``--knobs`` measures only the named knobs (no latency or rate runs), into ``bench_knobs_quality_<methods>_<knobs>_<duration>s.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

OUT = Path(__file__).resolve().parent / "results"
METHODS = ("warp", "sas", "tss", "quads")
SKIP = {"frame_div"}     # the server rate: not a method parameter (its prior is 1/n)


def stream_bytes(res: Any, streams: set[str] | None, exclude: set[str], after_s: float) -> float:
    """Mean bytes per server frame of ``streams`` (None: every stream not in ``exclude``) after ``after_s``."""
    ups = [u for u in res.updates if u["t_s"] >= after_s]
    tot = 0
    for u in ups:
        for k, v in u.items():
            if k.startswith("bytes_") and k != "bytes_probe":
                name = k[6:]
                if (streams is None and name not in exclude) or (streams is not None and name in streams):
                    tot += v
    return tot / max(1, len(ups))


def method_knobs(method: str, duration_s: float, renderer: Any, tmp: Path) -> list[dict[str, Any]]:
    from splitrender.methods import get_method, make_config
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import run

    spec = get_method(method)
    cfg = make_config(spec.config, {})
    out = []
    for knob in cfg.adapt_knobs():
        if knob.name in SKIP:
            continue
        per_level = []
        for level in knob.levels:
            rc = RunConfig(method=method, scene="default+nogi", trace="walk", network="ideal", duration_s=duration_s,
                           width=320, height=180, client_fps=30, flip_every=0, seed=0,
                           method_params={knob.name: level}, truth_cache=str(tmp / "truth"))
            res = run(rc, renderer=renderer)
            lossy = {"color", "color0", "color1", "atlas"}      # the methods' lossy video streams
            b = stream_bytes(res, lossy, set(), 0.5) if knob.affects == "video" else stream_bytes(res, None, lossy, 0.5)
            per_level.append(b)
            print(f"{method:6s} {knob.name}={level}: {b:9.0f} B/frame", flush=True)
        ratios = [b / per_level[0] for b in per_level]
        out.append({"knob": knob.name, "affects": knob.affects, "levels": list(knob.levels),
                    "bytes_per_frame": per_level, "measured": ratios, "prior": list(knob.cost)})
    return out


def scale_knob(duration_s: float, renderer: Any) -> dict[str, Any]:
    from splitrender.codecs.resize import resize, scaled_size
    from splitrender.codecs.video import VideoCodecConfig, VideoEncoder
    from splitrender.methods.base import SCALE_KNOB
    from splitrender.scene.loader import get_scene
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.trace import get_trace

    scene = get_scene("default+nogi")
    trace = get_trace("walk", scene=scene)
    intr = CameraIntrinsics(320, 180, 60.0, 0.05, 200.0)
    frames = [renderer.render(scene, t, trace.pose_at(t), intr, ("color",)).color
              for t in np.arange(0.0, duration_s, 1 / 30)]
    sizes = []
    for s in SCALE_KNOB.levels:
        w, h = scaled_size(320, 180, s)
        enc = VideoEncoder(VideoCodecConfig(codec="h264", crf=23.0, gop=30, preset="ultrafast", pix_fmt="yuv444p", fps=30), w, h)
        sizes.append(float(np.mean([len(enc.encode(resize(f, w, h)).data) for f in frames][15:])))
        print(f"scale {s}: {sizes[-1]:9.0f} B/frame", flush=True)
    return {"knob": "scale", "affects": "video", "levels": list(SCALE_KNOB.levels), "bytes_per_frame": sizes,
            "measured": [b / sizes[0] for b in sizes], "prior": list(SCALE_KNOB.cost)}


def quality(method: str, duration_s: float, renderer: Any, tmp: Path, only: set[str] | None = None) -> dict[str, Any]:
    """One method's quality model (module docstring); with ``only``, just those knobs (no latency or rate runs)."""
    from dataclasses import asdict

    from splitrender.experiments.quality_model import latency_db_per_100ms, measure, rate_db_per_halving
    from splitrender.methods import get_method, make_config
    from splitrender.methods.base import SCALE_KNOB

    cfg = make_config(get_method(method).config, {})
    knobs = list(cfg.adapt_knobs())
    if method in ("video", "atw", "warp"):            # their scalable colour: the pipeline adds the scale knob
        knobs.append(SCALE_KNOB)
    if only is not None:
        unknown = only - {k.name for k in knobs}
        if unknown:
            raise SystemExit(f"bench_knobs --knobs: {method} has no knob {', '.join(sorted(unknown))} "
                             f"(it has {', '.join(k.name for k in knobs)})")
        knobs = [k for k in knobs if k.name in only]
    kw = dict(duration_s=duration_s, renderer=renderer, truth_cache=str(tmp / "truth"))
    ref = measure(method, **kw)
    print(f"{method:6s} ref: {ref}", flush=True)
    out: dict[str, Any] = {"ref": asdict(ref), "knobs": {}}
    for k in knobs:
        runs = [ref]
        for level in k.levels[1:]:
            runs.append(measure(method, {k.name: level}, **kw))
            print(f"{method:6s} {k.name}={level}: {runs[-1]}", flush=True)
        out["knobs"][k.name] = {"levels": list(k.levels), "model_psnr_db": [r.model_psnr_db for r in runs],
                                "db_lost": [ref.model_psnr_db - r.model_psnr_db for r in runs],
                                "bytes": [r.all_bytes for r in runs], "video_bytes": [r.video_bytes for r in runs]}
    if only is not None:
        return out
    late = measure(method, delay_ms=120.0, **kw)
    print(f"{method:6s} late: {late}", flush=True)
    out["late"] = asdict(late)
    out["latency_db_per_100ms"] = latency_db_per_100ms(ref, late)
    if ref.video_bytes > 0:
        coarse = measure(method, crf_step=6.0, **kw)
        print(f"{method:6s} crf+6: {coarse}", flush=True)
        out["crf_plus_6"] = asdict(coarse)
        out["rate_db_per_halving"] = rate_db_per_halving(ref, coarse)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--methods", default=None)
    ap.add_argument("--duration", type=float, default=None)
    ap.add_argument("--quality", action="store_true", help="measure the quality models instead of the cost priors")
    ap.add_argument("--knobs", default=None, help="with --quality: only these knobs (no latency or rate runs)")
    args = ap.parse_args()
    from splitrender.render.renderer import Renderer

    if args.quality:
        renderer = Renderer()
        tmp = Path(tempfile.mkdtemp(prefix="bench_knobs_q_"))
        t0 = time.perf_counter()
        dur = args.duration or 2.0
        only = set(args.knobs.split(",")) if args.knobs else None
        models = {m: quality(m, dur, renderer, tmp, only) for m in (args.methods or "video,atw,warp,sas,tss,quads").split(",")}
        OUT.mkdir(parents=True, exist_ok=True)
        name = "bench_knobs_quality" + ("" if args.methods is None else "_" + args.methods.replace(",", "_"))
        if only is not None:
            name += "_" + "_".join(sorted(only)) + f"_{dur:g}s"
        path = OUT / f"{name}.json"
        path.write_text(json.dumps({"benchmark": "bench_knobs --quality", "scene": "default+nogi", "trace": "walk",
                                    "size": [320, 180], "duration_s": dur, "models": models,
                                    "wall_s": time.perf_counter() - t0, "machine": platform.machine(),
                                    "cpus": os.cpu_count(), "load_avg": os.getloadavg()}, indent=1) + "\n")
        print(f"-> {path}")
        return
    args.methods = args.methods or ",".join(METHODS)
    args.duration = args.duration or 1.5

    renderer = Renderer()
    tmp = Path(tempfile.mkdtemp(prefix="bench_knobs_"))
    t0 = time.perf_counter()
    res: dict[str, Any] = {"scale": scale_knob(args.duration, renderer)}
    for m in args.methods.split(","):
        res[m] = method_knobs(m, args.duration, renderer, tmp)
    OUT.mkdir(parents=True, exist_ok=True)
    out = {"benchmark": "bench_knobs", "scene": "default+nogi", "trace": "walk", "size": [320, 180],
           "duration_s": args.duration, "knobs": res, "wall_s": time.perf_counter() - t0,
           "machine": platform.machine(), "cpus": os.cpu_count(), "load_avg": os.getloadavg()}
    (OUT / "bench_knobs.json").write_text(json.dumps(out, indent=1) + "\n")
    print(f"-> {OUT / 'bench_knobs.json'}")


if __name__ == "__main__":
    main()
