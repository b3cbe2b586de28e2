"""``probes`` under a changing link: adaptation off and full, at two I-frame distances, in one run (issue 48).

As ``benchmarks/bench_adapt.py`` (virtual time, the ``walk`` trace, a 30 Hz display, 20 ms each way, transport-wide
feedback), on the default scene *with* its GI (``default``: probes streams it; the other methods' bench runs
``default+nogi``), ``--duration`` seconds (10) at ``--size`` (160x90: what probes sends does not depend on the
display's size), over generated traces (none committed; :mod:`splitrender.netsim.traces`), as
``benchmarks/bench_adapt_quality.py`` builds them:

- ``step``: 20 -> 2 -> 20 Mbit/s (3, 4 and 3 s of a 10 s run; the share is kept for other durations);
- ``cellular``: the project's cellular-like trace (cv 0.5, 1 s correlation, 2 % outages, seed 0) at a mean of 4
  Mbit/s; ``cellular8``: the link study's, at 8 Mbit/s; ``harsh``: cv 0.8, 8 % outages, 0.3 s correlation, 4 Mbit/s;
- ``loss``: no capacity limit, 2 % random loss (each loss brings a keyframe request: the streams restart);
- ``ideal``: no capacity limit, no loss.

``full`` moves the client's operating point (``probe_bits``, ``vis_bits``, ``probe_div``, then ``frame_div``) over the
one GI server; ``rate`` has no encoder to steer (the probe pictures are lossless, the rest is data), so it differs
from ``off`` only by the estimator's pacing and probing.  ``--gops`` runs each at those I-frame distances (probe
updates between periodic I-frames; ``default`` is the method's own): 30 (the paper's, "as we use a reliable
communication protocol") against the default.  Each run's figures are the link study's
(:func:`splitrender.experiments.studies.link.figures`), beside the bits sent in the low step and its p95 update age.
Every run is its own process (``--jobs`` at once, under ``nice``).

Writes ``benchmarks/results/bench_adapt_probes.json``.

With ``--costs`` it measures the knobs' cost priors instead (``splitrender/methods/probes/config.py``): one client's
server half alone (sans-IO, 320x180, 30 fps, the walk, ``--duration`` seconds, no periodic I-frame) at each knob level,
the others at their first: the first I-frame's bytes, the P-updates' and the index's bytes a second; each level's
bytes a second over the first's, with the I-frame once every ``gop`` updates sent (updates at 10 Hz; 5 and 2.5 at
``probe_div`` 2 and 4, 6 at ``frame_div`` 5, whose frames merge two GI updates) and the frames' metadata at
``META_KBPS`` over the frame rate.  Writes ``benchmarks/results/bench_adapt_probes_costs.json``.

    python benchmarks/bench_adapt_probes.py [--traces step,cellular] [--adapt off,full] [--gops 30,default] [--jobs 2]
    python benchmarks/bench_adapt_probes.py --costs [--duration 3] [--gops 30,default]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

OUT = Path(__file__).resolve().parent / "results"
TRACES = ("step", "cellular", "cellular8", "loss", "ideal")
META_KBPS = 159.0
"""The frames' metadata at 30 fps on the walk (kbit/s: the frame header, pose and the objects' transforms, 0.66 kB a
frame; the method's own part is 5 kB/s of it)."""
LEVELS = (("own", {}, 1, 10.0), ("probe_bits", {"probe_bits": 6}, 1, 10.0), ("probe_bits", {"probe_bits": 4}, 1, 10.0),
          ("vis_bits", {"vis_bits": 2}, 1, 10.0), ("vis_bits", {"vis_bits": 1}, 1, 10.0),
          ("probe_div", {"probe_div": 2}, 1, 5.0), ("probe_div", {"probe_div": 4}, 1, 2.5),
          ("frame_div", {}, 2, 10.0), ("frame_div", {}, 3, 10.0), ("frame_div", {}, 5, 6.0))
"""(knob, point, frame_div, probe updates a second)."""


def costs(duration_s: float, gops: list[int]) -> dict[str, Any]:
    """The cost priors' measurement (module docstring)."""
    from splitrender.codecs.meta import pack_meta
    from splitrender.codecs.video import VideoEncoder
    from splitrender.methods import get_method, make_config
    from splitrender.pipeline.direct import server_context
    from splitrender.pipeline.producers import ProducerPool
    from splitrender.render.renderer import Renderer
    from splitrender.scene.loader import get_scene
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.trace import get_trace

    intr, renderer, scene, spec = CameraIntrinsics(320, 180, 60.0), Renderer(), get_scene("default"), get_method("probes")
    trace = get_trace("walk", scene=scene)
    n = int(round(duration_s * 30))
    rows = []
    for knob, point, div, hz in LEVELS:
        cfg = make_config(spec.config, {"gop": 100_000})
        pool = ProducerPool(scene, 30, renderer)
        half = spec.server_class(cfg, intr, scene, 30, pool.producer(spec, cfg))
        if point:
            half.set_knobs(point)
        enc = {s.name: VideoEncoder(s.codec, s.width, s.height) for s in half.streams() if getattr(s, "kind", "") == "video"}
        i_b = p_b = idx_b = meta_b = 0
        for frame in range(0, n, div):
            t = frame / 30
            pose = trace.pose_at(t)
            ctx = server_context(scene, renderer, intr, pose, t_s=t, frame_id=frame, shared=pool.prepare("probes", frame, t))
            upd = half.produce(ctx)
            for k, plane in upd.planes.items():
                b = len(enc[k].encode(plane, force_idr=upd.force_idr).data)
                i_b, p_b = (i_b + b, p_b) if frame == 0 else (i_b, p_b + b)
            idx_b += sum(len(v) for v in upd.data.values()) if frame else 0
            meta_b += len(pack_meta(upd.meta))
        secs = (n - 1) / 30
        rows.append({"knob": knob, "point": point, "frame_div": div, "updates_hz": hz, "i_frame_kB": i_b / 1e3,
                     "p_kBps": p_b / 1e3 / secs, "index_kBps": idx_b / 1e3 / secs, "method_meta_kBps": meta_b / 1e3 / (n / 30)})
        print(rows[-1], flush=True)
    priors: dict[str, Any] = {}
    for gop in gops:
        tot = [r["i_frame_kB"] * r["updates_hz"] / gop + r["p_kBps"] + r["index_kBps"] + META_KBPS / 8 / r["frame_div"]
               for r in rows]
        ratio = [x / tot[0] for x in tot]
        priors[str(gop)] = {"own_kbps": tot[0] * 8, "ratios": [{"knob": r["knob"], "point": r["point"], "frame_div":
                                                                 r["frame_div"], "cost": q} for r, q in zip(rows, ratio)]}
        print(f"gop {gop}: {tot[0] * 8:.0f} kbit/s at the own point; " +
              ", ".join(f"{r['knob']} {r['point'] or r['frame_div']}: {q:.3f}" for r, q in zip(rows, ratio)), flush=True)
    return {"levels": rows, "priors": priors}


def step_plan(duration_s: float) -> list[tuple[float, float]]:
    return [(duration_s * 0.3, 20.0), (duration_s * 0.4, 2.0), (duration_s * 0.3, 20.0)]


def networks(folder: Path, duration_s: float) -> dict[str, tuple[str, Any, list[tuple[float, float]], Any]]:
    """Per trace: the ``--network`` string, its capacity timestamps (None: no limit), the steady spans, the low span."""
    from splitrender.experiments.studies.link import step_spans
    from splitrender.netsim.traces import CELLULAR_LIKE, named_cellular_trace, step_trace, write_mahimahi

    d = duration_s + 2.0
    stamps = {"step": step_trace(step_plan(duration_s)),
              **{name: named_cellular_trace(name, d, seed=0) for name in CELLULAR_LIKE}}   # cellular, cellular8, harsh
    out: dict[str, tuple[str, Any, list[tuple[float, float]], Any]] = {}
    for name, st in stamps.items():
        path = write_mahimahi(st, folder / f"{name}.trace")
        steady, low = step_spans(step_plan(duration_s)) if name == "step" else ([(1.0, duration_s)], None)
        out[name] = (f"delay 20ms trace {path}", st, steady, low)
    out["loss"] = ("delay 20ms loss 2%", None, [(1.0, duration_s)], None)
    out["ideal"] = ("delay 20ms", None, [(1.0, duration_s)], None)
    return out


def one(trace: str, adapt: str, gop: str, size: str, duration_s: float, folder: str, seed: int = 0) -> dict[str, Any]:
    """One run (a worker process)."""
    os.nice(10)
    from splitrender.experiments.studies.link import figures
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import run

    network, stamps, steady, low = networks(Path(folder), duration_s)[trace]
    w, h = (int(x) for x in size.split("x"))
    params = {} if gop == "default" else {"gop": int(gop)}
    cfg = RunConfig(method="probes", method_params=params, scene="default", trace="walk", network=network,
                    duration_s=duration_s, width=w, height=h, client_fps=30, flip_every=0, seed=seed,
                    transport_cc=True, adapt=adapt, truth_cache=str(Path(folder) / "truth"))
    t0 = time.perf_counter()
    res = run(cfg)
    if stamps is None:   # no capacity limit: utilisation means nothing
        stamps = np.arange(0, int(duration_s * 1000) + 2000, dtype=np.int64)
    f = figures(res, stamps, steady, low)
    a, b = low if low is not None else (1.0, duration_s)
    f["low_kbps"] = sum(u["bytes"] for u in res.updates if a <= u["t_s"] < b) * 8 / (b - a) / 1000
    ages = np.array([x["update_age_ms"] for x in res.frames if a <= x["t_s"] < b and np.isfinite(x["update_age_ms"])])
    f["low_age_p95_ms"] = float(np.percentile(ages, 95)) if ages.size else float("nan")
    f["keyframes"] = int(res.summary.get("keyframes", 0))
    points = [(round(float(u["t_s"]), 3), int(u["adapt_point"])) for u in res.updates if "adapt_point" in u]
    f["points"] = [p for i, p in enumerate(points) if i == 0 or p[1] != points[i - 1][1]]
    from splitrender.methods import get_method, make_config
    g = make_config(get_method("probes").config, params).gop
    return {"trace": trace, "adapt": adapt, "gop": g, "gop_arg": gop, "seed": seed, **f, "wall_s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--traces", default="step,cellular", help=f"comma-separated, of {', '.join(TRACES)}, harsh")
    ap.add_argument("--adapt", default="off,full", help="the adaptation modes to run, comma-separated")
    ap.add_argument("--gops", default="30,default", help="I-frame distances ('default': the method's own)")
    ap.add_argument("--size", default="160x90")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0, help="the runs' seed (the loss draws)")
    ap.add_argument("--out", default=None)
    ap.add_argument("--costs", action="store_true", help="measure the knobs' cost priors instead")
    args = ap.parse_args()
    from splitrender.methods import get_method, make_config

    default_gop = make_config(get_method("probes").config, {}).gop
    if args.costs:
        gops = [default_gop if g == "default" else int(g) for g in args.gops.split(",")]
        t0 = time.perf_counter()
        out = {"benchmark": "bench_adapt_probes --costs", "duration_s": args.duration, "size": [320, 180],
               "scene": "default", "trace": "walk", "default_gop": default_gop, "meta_kbps": META_KBPS,
               **costs(args.duration, gops), "wall_s": time.perf_counter() - t0, "machine": platform.machine(),
               "cpus": os.cpu_count(), "load_avg": os.getloadavg()}
        path = Path(args.out or OUT / "bench_adapt_probes_costs.json")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(out, indent=1) + "\n")
        print(f"-> {path}")
        return
    args.out = args.out or str(OUT / "bench_adapt_probes.json")
    folder = tempfile.mkdtemp(prefix="bench_adapt_probes_")
    networks(Path(folder), args.duration)   # the trace files, once
    grid = [(tr, ad, g) for tr in args.traces.split(",") for g in args.gops.split(",") for ad in args.adapt.split(",")]
    t0 = time.perf_counter()
    runs = []
    with ProcessPoolExecutor(args.jobs) as pool:
        futs = [pool.submit(one, tr, ad, g, args.size, args.duration, folder, args.seed) for tr, ad, g in grid]
        for fut in futs:
            f = fut.result()
            runs.append(f)
            print(f"probes {f['trace']:9s} gop {f['gop']:3d} {f['adapt']:4s} model PSNR {f['model_psnr_db']:.2f} dB, "
                  f"mtp p95 {f['mtp_p95_ms']:6.0f} ms, freezes>500 {f['freezes_over_500ms']} (longest "
                  f"{f['longest_freeze_ms']:5.0f} ms), {f['mean_kbps']:5.0f} kbit/s, keyframes {f['keyframes']}, "
                  f"low/steady span {f['low_kbps']:5.0f} kbit/s, age p95 {f['low_age_p95_ms']:5.0f} ms, "
                  f"points {f['points'][:6]} ({f['wall_s']:.0f} s)", flush=True)
    out = {"benchmark": "bench_adapt_probes", "duration_s": args.duration, "size": args.size, "scene": "default",
           "trace": "walk", "seed": args.seed, "default_gop": default_gop, "step_plan": step_plan(args.duration), "runs": runs,
           "wall_s": time.perf_counter() - t0, "machine": platform.machine(), "cpus": os.cpu_count(),
           "load_avg": os.getloadavg()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(f"-> {args.out}")


if __name__ == "__main__":
    main()
