"""Chroma where it matters: 4:2:0 against 4:4:4 colour video for every method that sends colour.

Issue 33, item 2: most of plain video's squared error lies in a 2-pixel ring about the
model's outline, where 4:2:0 chroma blurs colour across the silhouette.  For each of
``video``, ``atw``, ``warp``, ``sas``, ``tss`` and ``quads`` on three scenes (assimp's
duck, its 2CylinderEngine and ``default+nogi``), a still and a walking camera
(``static``, ``walk``) and two networks (``ideal``, ``cloud``), at 320x180 for 1 s
(virtual time, H.264, the methods' defaults otherwise), three runs:

* ``420``: ``chroma=420`` at the default ``crf`` (23);
* ``444``: ``chroma=444`` at the same ``crf``: what full chroma gains, and what it costs
  in bits;
* ``444eq``: ``chroma=444`` at the ``crf`` that brings its colour streams' bits down to
  the 4:2:0 run's (equal bits): a first guess from x264's rule of thumb (``crf`` + 6
  halves the bits), then up to two secant steps on log(kbit/s) until the colour bits are
  within 3 % (``EQ_TOL``); the run closest to the target is kept, its bit ratio recorded.

Colour bits are the method's colour video streams (``kbps_color*``, ``kbps_atlas``), the
streams ``chroma`` changes; depth, geometry and metadata are the same in all three runs.
Each run records the region scores of its ``summary.csv``: the 2-px ring about the
model's outline (``mean_edge_psnr_db``), the model more than 2 px inside it
(``mean_interior_psnr_db``), the whole model (``mean_model_psnr_db``, and
``model_psnr_mse_db``, ``mean_model_ssim``), the whole frame (``mean_psnr_db``) and
``mean_kbps``.  ``--hevc`` adds ``video`` with ``codec=hevc`` on the same grid.

A method's verdict: 4:4:4 pays where, at equal bits, its median model PSNR gain over the
cells is at least ``PAYS_DB`` (0.25 dB) and its median whole-frame gain is not negative: a
smaller gain does not buy a profile fewer decoders take (H.264 High 4:4:4 Predictive, HEVC
Range Extensions: many hardware decoders take neither).

Results go to a result store (``--store``, default ``out/bench_chroma``; runs already
there are reused) and ``benchmarks/results/bench_chroma.json`` (``bench_chroma_quick.json``
with ``--quick``); a table is printed.

    python benchmarks/bench_chroma.py [--quick] [--hevc] [--store DIR] [--duration 1] [--no-cost]

It ends with what 4:4:4 costs the codec in time: milliseconds per frame to encode and decode (the conversion to
and from rgb24 included), 4:2:0 against 4:4:4, at 320x180 and 1280x720 (:func:`codec_cost`).

``--quick``: ``video`` and ``warp`` on the duck, still and walking, ``ideal`` only (about 12 runs).

Measured (the full grid and ``--hevc``, 335 runs; medians over a method's 12 cells, gain of 4:4:4 over 4:2:0 at
equal colour bits): ``video`` model +1.81 dB, whole frame +1.62, ring +3.23; ``atw`` +1.39 / +1.10 / +1.69;
``warp`` +1.88 / +1.54 / +2.55; ``quads`` +2.09 / +1.56 / +2.23; ``video`` on HEVC +1.75 / +1.62 / +2.56; ``sas``
-0.02 / -0.02 / -0.00; ``tss`` +0.04 / +0.01 / +0.01.  At the same crf 4:4:4 costs 1.16x the colour bits (``sas``,
``tss``: 1.06x).  The still duck gains most (ring 20.2 -> 34.0 dB, whole frame 32.7 -> 43.1 at equal bits), walks
under ``cloud`` least (within 0.1 dB either way), where the error is the motion's, not the chroma's.  So ``video``,
``atw``, ``warp`` and ``quads`` default to 4:4:4, ``sas`` and ``tss`` keep 4:2:0.  ``model_psnr_mse_db`` and
``psnr_mse_db`` (PSNR of the mean squared error) are held down in 1-s runs by the black tick before the first
frame, and SSIM is of luma only, so neither sees chroma; the per-frame means are the ones to read.

Moving cameras (issue 50; ``--methods video,atw,warp,quads --scenes default,duck --traces orbit,walk,static
--networks cloud``, 98 runs, ``results/bench_chroma_motion.json``; the ``*_content`` scores leave the black start-up
ticks out): median model gain of 4:4:4 at equal bits over the four moving cells ``video`` +0.06 dB, ``atw`` +0.02,
``warp`` +0.44, ``quads`` +0.72 (worst cell -0.07, ``video`` walking through the default scene), still +4.8 to +5.2;
at the same crf 4:4:4 costs 9-23 % more bits (``video``, ``atw``) or 2.5-5 % (``warp``, ``quads``) under motion.
4:2:0 is never the better picture for the bits, so the defaults stand.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, not an installed one

from splitrender.experiments.store import ResultStore  # noqa: E402
from splitrender.experiments.sweep import run_configs  # noqa: E402
from splitrender.sim.config import RunConfig  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "bench_chroma.json"
METHODS = ("video", "atw", "warp", "sas", "tss", "quads")
SCENES = {
    "duck": "/usr/share/assimp/models/Collada/duck.dae",
    "engine": "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb",
    "default": "default+nogi",
}
TRACES = ("static", "walk")
NETWORKS = ("ideal", "cloud")
QUICK = {"methods": ("video", "warp"), "scenes": ("duck",), "traces": TRACES, "networks": ("ideal",)}
CRF = 23.0
EQ_TOL = 0.03
"""Equal bits: the 4:4:4 run's colour kbit/s within 3 % of the 4:2:0 run's."""
PAYS_DB = 0.25
"""The median model PSNR gain at equal bits for which 4:4:4 is worth a less widely decoded profile."""
CRF_PER_HALVING = 6.0
"""x264/x265's rule of thumb: ``crf`` + 6 halves the bits (the first guess of the equal-bits search)."""
SCORES = ("mean_edge_psnr_db", "mean_interior_psnr_db", "mean_model_psnr_db", "model_psnr_mse_db", "mean_model_ssim",
          "mean_psnr_db", "mean_ssim", "mean_kbps", "edge_psnr_mse_db", "psnr_mse_db", "frames_before_content",
          "mean_edge_psnr_db_content", "mean_model_psnr_db_content", "model_psnr_mse_db_content", "mean_psnr_db_content",
          "psnr_mse_db_content", "steady_kbps")
"""The scores kept per run; ``*_content`` over the frames with content only (after the black start-up ticks)."""
SHORT = {"mean_edge_psnr_db": "edge", "mean_interior_psnr_db": "interior", "mean_model_psnr_db": "model",
         "mean_psnr_db": "whole"}


def colour_kbps(summary: dict[str, Any]) -> float:
    """kbit/s of the streams ``chroma`` changes: ``kbps_color``, ``kbps_color<N>`` (warp's views), ``kbps_atlas``."""
    keys = [k for k in summary if k in ("kbps_atlas", "kbps_color") or (k.startswith("kbps_color") and k[10:].isdigit())]
    vals = [float(summary[k]) for k in keys if isinstance(summary[k], (int, float)) and math.isfinite(summary[k])]
    return float(sum(vals)) if vals else math.nan


def base_config(method: str, scene: str, trace: str, network: str, codec: str, ns: argparse.Namespace,
                **params: Any) -> RunConfig:
    mp: dict[str, Any] = {"crf": CRF, **params}
    if codec != "h264":
        mp["codec"] = codec
    return RunConfig.from_dict({"method": method, "scene": SCENES[scene], "trace": trace, "network": network,
                                "width": ns.width, "height": ns.height, "duration_s": ns.duration, "flip_every": 0,
                                "truth_cache": ns.truth_cache, "method_params": mp})


RUN_COUNTS = {"ran": 0, "cached": 0, "failed": 0, "run_wall_s": 0.0}
"""Runs made by this invocation, found in the store, failed; the seconds the runs made took."""


def _run(store: ResultStore, cfgs: list[RunConfig], workers: int) -> None:
    res = run_configs(cfgs, store, workers=workers)
    RUN_COUNTS["ran"] += len(res.ran)
    RUN_COUNTS["cached"] += len(res.cached)
    RUN_COUNTS["failed"] += len(res.failures)
    RUN_COUNTS["run_wall_s"] += float(sum(res.wall_s.values()))
    for f in res.failures:
        print(f"FAILED {f.label}: {f.error}", flush=True)


def _summary(store: ResultStore, cfg: RunConfig) -> dict[str, Any] | None:
    return store.load_summary(cfg) if store.has(cfg) else None


def _scores(s: dict[str, Any], crf: float) -> dict[str, float]:
    out = {k: float(s[k]) if isinstance(s.get(k), (int, float)) else math.nan for k in SCORES}
    out["colour_kbps"] = colour_kbps(s)
    out["crf"] = crf
    return out


def _next_crf(tried: list[tuple[float, float]], target: float) -> float:
    """The crf whose colour kbit/s should hit ``target``: secant on log(kbit/s) through the two newest tries, or
    the rule of thumb from one."""
    (c1, k1) = tried[-1]
    slope = -math.log(2.0) / CRF_PER_HALVING
    if len(tried) >= 2:
        c0, k0 = tried[-2]
        if c1 != c0 and k0 > 0 and k1 > 0:
            s = (math.log(k1) - math.log(k0)) / (c1 - c0)
            if s < -1e-3:
                slope = s
    return float(min(51.0, max(0.0, round(c1 + math.log(target / k1) / slope, 2))))


def codec_cost(sizes: tuple[tuple[int, int], ...] = ((320, 180), (1280, 720)), frames: int = 20) -> list[dict[str, Any]]:
    """Milliseconds per frame to encode (conversion from rgb24 included) and decode (back to rgb24 included) 4:2:0
    and 4:4:4 at crf 23, a yellow disc moving 2 px a frame over colour waves: medians of ``frames`` frames after
    the first (the IDR), in this process on this machine.  (Bits are the grid's business: this picture is not a
    scene.)"""
    import numpy as np

    from splitrender.codecs.video import VideoCodecConfig, VideoDecoder, VideoEncoder

    out = []
    for w, h in sizes:
        y, x = np.mgrid[0:h, 0:w]
        for codec in ("h264", "hevc"):
            for pix_fmt in ("yuv420p", "yuv444p"):
                enc = VideoEncoder(VideoCodecConfig(codec=codec, pix_fmt=pix_fmt, crf=CRF, gop=1000), w, h)  # type: ignore[arg-type]
                dec = VideoDecoder(codec)  # type: ignore[arg-type]
                e_ms, d_ms = [], []
                for i in range(frames + 1):
                    img = np.empty((h, w, 3), np.uint8)
                    img[..., 0] = 128 + 100 * np.sin((x + 2 * i) / 13.0)
                    img[..., 1] = 128 + 100 * np.cos((y - 2 * i) / 9.0)
                    img[..., 2] = (x + y + 2 * i) % 256
                    img[(y - h // 2) ** 2 + (x - w // 4 - 2 * i) ** 2 < (h // 4) ** 2] = (250, 220, 30)
                    t0 = time.perf_counter()
                    ef = enc.encode(img)
                    t1 = time.perf_counter()
                    dec.decode(ef.data)
                    t2 = time.perf_counter()
                    if i:
                        e_ms.append((t1 - t0) * 1e3)
                        d_ms.append((t2 - t1) * 1e3)
                out.append({"size": f"{w}x{h}", "codec": codec, "pix_fmt": pix_fmt, "encode_ms": statistics.median(e_ms),
                            "decode_ms": statistics.median(d_ms)})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="video and warp on the duck, still and walking, ideal network")
    ap.add_argument("--hevc", action="store_true", help="also video with codec=hevc on the same grid")
    ap.add_argument("--methods", default=None, help="comma-separated subset of the methods")
    ap.add_argument("--scenes", default=None, help=f"comma-separated subset of {','.join(SCENES)}")
    ap.add_argument("--traces", default=None, help=f"comma-separated traces (default {','.join(TRACES)}; any built-in, e.g. orbit)")
    ap.add_argument("--networks", default=None, help=f"comma-separated networks (default {','.join(NETWORKS)})")
    ap.add_argument("--store", type=Path, default=Path("out/bench_chroma"))
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--eq-steps", type=int, default=3, help="runs at most to find 4:4:4's equal-bits crf (1: the rule of thumb only)")
    ap.add_argument("--truth-cache", default="default", help="RunConfig.truth_cache (default: the user's cache)")
    ap.add_argument("--no-cost", action="store_true", help="skip the codec cost timings (encode and decode ms)")
    ap.add_argument("--note", default=None, help="the JSON's note (default: the full grid's timing)")
    ap.add_argument("--out", type=Path, default=None,
                    help="the JSON (default benchmarks/results/bench_chroma.json, bench_chroma_quick.json with --quick)")
    ns = ap.parse_args()
    if ns.out is None:
        ns.out = RESULTS.with_name("bench_chroma_quick.json") if ns.quick else RESULTS
    logging.basicConfig(level=logging.ERROR)
    ns.width, ns.height = (int(v) for v in ns.size.split("x"))
    grid = QUICK if ns.quick else {"methods": METHODS, "scenes": tuple(SCENES), "traces": TRACES, "networks": NETWORKS}
    methods = tuple(ns.methods.split(",")) if ns.methods else grid["methods"]
    grid = {**grid, **{k: tuple(str(getattr(ns, k)).split(",")) for k in ("scenes", "traces", "networks") if getattr(ns, k)}}
    arms = [(m, "h264") for m in methods] + ([("video", "hevc")] if ns.hevc else [])
    cells = [(m, codec, sc, tr, nw) for sc in grid["scenes"] for tr in grid["traces"] for nw in grid["networks"]
             for m, codec in arms]
    store = ResultStore(ns.store)
    t0 = time.perf_counter()

    # 1. both chroma formats at the default crf
    _run(store, [base_config(m, sc, tr, nw, codec, ns, chroma=ch) for (m, codec, sc, tr, nw) in cells
                 for ch in ("420", "444")], ns.workers)
    rows: list[dict[str, Any]] = []
    tried: dict[tuple[str, ...], list[tuple[float, float]]] = {}
    for cell in cells:
        m, codec, sc, tr, nw = cell
        s420 = _summary(store, base_config(m, sc, tr, nw, codec, ns, chroma="420"))
        s444 = _summary(store, base_config(m, sc, tr, nw, codec, ns, chroma="444"))
        if s420 is None or s444 is None:
            continue
        rows.append({"method": m, "codec": codec, "scene": sc, "trace": tr, "network": nw,
                     "420": _scores(s420, CRF), "444": _scores(s444, CRF)})
        tried[cell] = [(CRF, colour_kbps(s444))]
    # 2. 4:4:4 at the 4:2:0 run's colour bits: the rule of thumb, then up to two secant steps
    for _step in range(ns.eq_steps):
        todo: dict[tuple[str, ...], float] = {}
        for r in rows:
            cell = (r["method"], r["codec"], r["scene"], r["trace"], r["network"])
            target, tries = r["420"]["colour_kbps"], tried[cell]
            if not (target > 0 and all(k > 0 for _, k in tries)):
                continue
            if min(abs(k / target - 1) for _, k in tries) <= EQ_TOL or tries[-1][1] <= target and len(tries) == 1:
                continue  # close enough, or 4:4:4 costs no more than 4:2:0 at the same crf
            todo[cell] = _next_crf(tries, target)
        if not todo:
            break
        cfgs = {cell: base_config(cell[0], cell[2], cell[3], cell[4], cell[1], ns, chroma="444", crf=c)
                for cell, c in todo.items()}
        _run(store, list(cfgs.values()), ns.workers)
        for cell, cfg in cfgs.items():
            s = _summary(store, cfg)
            if s is not None:
                tried[cell].append((todo[cell], colour_kbps(s)))
    for r in rows:
        cell = (r["method"], r["codec"], r["scene"], r["trace"], r["network"])
        target = r["420"]["colour_kbps"]
        best_crf, best_k = min(tried[cell], key=lambda ck: abs(ck[1] / target - 1) if target > 0 and ck[1] > 0 else math.inf)
        cfg = base_config(cell[0], cell[2], cell[3], cell[4], cell[1], ns, chroma="444",
                          **({} if best_crf == CRF else {"crf": best_crf}))
        s = _summary(store, cfg)
        if s is not None:
            r["444eq"] = _scores(s, best_crf)
            r["444eq"]["colour_kbps_ratio"] = best_k / target if target > 0 else math.nan
        r["crf_tries"] = tried[cell]

    verdicts = summarise(rows, arms)
    cost = [] if ns.no_cost else codec_cost(((ns.width, ns.height),) if ns.quick else ((ns.width, ns.height), (1280, 720)))
    doc = {"benchmark": "bench_chroma", "argv": sys.argv[1:], "commit": _commit(), "size": ns.size, "duration_s": ns.duration, "crf": CRF, "eq_tol": EQ_TOL,
           "quick": ns.quick, "scenes": {k: SCENES[k] for k in grid["scenes"]}, "rows": rows, "verdicts": verdicts,
           "codec_cost": cost,
           "machine": platform.machine(), "cpus": os.cpu_count(), "python": platform.python_version(),
           "load_avg": os.getloadavg(), "wall_s": time.perf_counter() - t0, "runs": RUN_COUNTS,
           "note": ns.note or ("wall_s is this invocation's; the full grid's 335 runs took 2870 s the first time (2 cores, "
                               "shared with other work, load average 4-7, llvmpipe), later invocations read them from the store")}
    ns.out.parent.mkdir(parents=True, exist_ok=True)
    ns.out.write_text(json.dumps(doc, indent=1, default=float))
    print_table(rows, verdicts)
    for c in cost:
        print(f"{c['size']:9s} {c['codec']:4s} {c['pix_fmt']}: encode {c['encode_ms']:6.2f} ms, decode {c['decode_ms']:6.2f} ms")
    print(f"-> {ns.out} ({doc['wall_s']:.0f} s)")


def _commit() -> str:
    """This checkout's commit (``+dirty`` with uncommitted changes), or '' outside git."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True, text=True).stdout
        return head + ("+dirty" if dirty.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return ""


def _delta(r: dict[str, Any], arm: str, key: str) -> float:
    if arm not in r:
        return math.nan
    return float(r[arm][key] - r["420"][key])


def _median(xs: list[float]) -> float:
    xs = [x for x in xs if math.isfinite(x)]
    return statistics.median(xs) if xs else math.nan


def summarise(rows: list[dict[str, Any]], arms: list[tuple[str, str]]) -> dict[str, Any]:
    """Per method (and codec): median gains of 4:4:4 over 4:2:0 at the same crf and at equal bits, and the verdict."""
    out: dict[str, Any] = {}
    for m, codec in arms:
        rs = [r for r in rows if r["method"] == m and r["codec"] == codec]
        if not rs:
            continue
        v: dict[str, Any] = {"cells": len(rs)}
        for arm in ("444", "444eq"):
            for key in ("mean_edge_psnr_db", "mean_interior_psnr_db", "mean_model_psnr_db", "mean_psnr_db"):
                ds = [_delta(r, arm, key) for r in rs]
                v[f"{arm}_median_d_{SHORT[key]}_db"] = _median(ds)
                v[f"{arm}_min_d_{SHORT[key]}_db"] = min((d for d in ds if math.isfinite(d)), default=math.nan)
        v["444_median_colour_kbps_ratio"] = _median([r["444"]["colour_kbps"] / r["420"]["colour_kbps"] for r in rs
                                                     if r["420"]["colour_kbps"] > 0])
        v["444_median_total_kbps_ratio"] = _median([r["444"]["mean_kbps"] / r["420"]["mean_kbps"] for r in rs
                                                    if r["420"]["mean_kbps"] > 0])
        v["cells_444eq_model_better"] = sum(1 for r in rs if _delta(r, "444eq", "mean_model_psnr_db") > 0)
        v["cells_444eq_whole_better"] = sum(1 for r in rs if _delta(r, "444eq", "mean_psnr_db") > 0)
        v["pays_at_equal_bits"] = bool(v["444eq_median_d_model_db"] >= PAYS_DB and v["444eq_median_d_whole_db"] >= 0)
        v["by_trace"] = {tr: _trace_verdict([r for r in rs if r["trace"] == tr]) for tr in dict.fromkeys(r["trace"] for r in rs)}
        moving = [r for r in rs if r["trace"] != "static"]
        if moving and len(moving) < len(rs):   # the moving cameras' cells together (every trace but static)
            v["by_trace"]["moving"] = _trace_verdict(moving)
        out[f"{m}/{codec}"] = v
    return out


def _trace_verdict(rs: list[dict[str, Any]]) -> dict[str, Any]:
    """One trace's cells (scenes x networks): median gains of 4:4:4 over 4:2:0 in model and whole-frame PSNR over all
    frames and over the frames with content, at the same crf and at equal bits, and the bit ratio at the same crf."""
    v: dict[str, Any] = {"cells": len(rs)}
    for arm in ("444", "444eq"):
        for key in ("mean_model_psnr_db", "mean_psnr_db", "mean_model_psnr_db_content", "mean_psnr_db_content"):
            short = SHORT[key.removesuffix("_content")] + ("_content" if key.endswith("_content") else "")
            v[f"{arm}_median_d_{short}_db"] = _median([_delta(r, arm, key) for r in rs])
    v["444_median_total_kbps_ratio"] = _median([r["444"]["mean_kbps"] / r["420"]["mean_kbps"] for r in rs
                                                if r["420"]["mean_kbps"] > 0])
    v["444_median_colour_kbps_ratio"] = _median([r["444"]["colour_kbps"] / r["420"]["colour_kbps"] for r in rs
                                                 if r["420"]["colour_kbps"] > 0])
    v["pays_at_equal_bits"] = bool(v["444eq_median_d_model_db"] >= PAYS_DB and v["444eq_median_d_whole_db"] >= 0)
    return v


def print_table(rows: list[dict[str, Any]], verdicts: dict[str, Any]) -> None:
    def f(x: float, w: int = 5, p: int = 1) -> str:
        return f"{x:{w}.{p}f}" if math.isfinite(x) else " " * (w - 3) + "nan"

    print("PSNR dB as 4:2:0 / 4:4:4 same crf / 4:4:4 equal bits; colour kbit/s 4:2:0 / 4:4:4 / equal-bits (crf)")
    print(f"{'method':12s} {'scene':8s} {'trace':6s} {'net':5s} | {'edge':^17s} | {'interior':^17s} | {'model':^17s} | "
          f"{'whole':^17s} | colour kbit/s")
    for r in rows:
        a, b, e = r["420"], r["444"], r.get("444eq", {})
        cells = []
        for key in ("mean_edge_psnr_db", "mean_interior_psnr_db", "mean_model_psnr_db", "mean_psnr_db"):
            cells.append(f"{f(a[key])} {f(b[key])} {f(e.get(key, math.nan))}")
        name = r["method"] + ("" if r["codec"] == "h264" else "/" + r["codec"])
        print(f"{name:12s} {r['scene']:8s} {r['trace']:6s} {r['network']:5s} | " + " | ".join(cells)
              + f" | {f(a['colour_kbps'], 5, 0)} {f(b['colour_kbps'], 5, 0)} {f(e.get('colour_kbps', math.nan), 5, 0)}"
              f" ({e.get('crf', math.nan):.1f})")
    print("\nmedian gain of 4:4:4 over 4:2:0, dB (same crf | equal bits), and 4:4:4's colour bits at the same crf")
    for k, v in verdicts.items():
        print(f"{k:12s} edge {f(v['444_median_d_edge_db'], 5, 2)} | {f(v['444eq_median_d_edge_db'], 5, 2)}   "
              f"interior {f(v['444_median_d_interior_db'], 5, 2)} | {f(v['444eq_median_d_interior_db'], 5, 2)}   "
              f"model {f(v['444_median_d_model_db'], 5, 2)} | {f(v['444eq_median_d_model_db'], 5, 2)}   "
              f"whole {f(v['444_median_d_whole_db'], 5, 2)} | {f(v['444eq_median_d_whole_db'], 5, 2)}   "
              f"bits x{v['444_median_colour_kbps_ratio']:.2f}   equal bits: model better in "
              f"{v['cells_444eq_model_better']}/{v['cells']}, whole in {v['cells_444eq_whole_better']}/{v['cells']} -> "
              f"{'4:4:4 pays' if v['pays_at_equal_bits'] else 'keep 4:2:0'}")
        for tr, t in v.get("by_trace", {}).items():
            print(f"  {tr:10s} model {f(t['444_median_d_model_db'], 5, 2)} | {f(t['444eq_median_d_model_db'], 5, 2)}   "
                  f"(content {f(t['444_median_d_model_content_db'], 5, 2)} | {f(t['444eq_median_d_model_content_db'], 5, 2)})   "
                  f"whole {f(t['444_median_d_whole_db'], 5, 2)} | {f(t['444eq_median_d_whole_db'], 5, 2)}   "
                  f"bits x{t['444_median_total_kbps_ratio']:.3f} (colour x{t['444_median_colour_kbps_ratio']:.3f}) -> "
                  f"{'4:4:4 pays' if t['pays_at_equal_bits'] else 'keep 4:2:0'}")


if __name__ == "__main__":
    main()
