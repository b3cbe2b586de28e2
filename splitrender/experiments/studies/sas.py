"""Study: shading atlas streaming (``sas``) against ``video``, ``atw`` and ``warp``.

Evidence, following the paper's section 5:

1. quality (PSNR, SSIM, FLIP) against one-way network delay (5.6) and against the
   bitrate budget (5.8), beside the baselines;
2. PVS coverage and overestimation, area-weighted, for no, linear and perfect
   prediction with the regular and the 20% larger field of view (5.1);
3. atlas memory by state and atlas resets per allocator strategy S0-S3 (5.4);
4. allocator ms per frame (5.3), from a replay here and from
   ``benchmarks/results/bench_sas_allocator.json`` when present (>= 100k patches);
5. server and client ms per frame.

``quick=True`` keeps to 320x180, short traces and few points (well under 90 s on two
cores); the full study runs longer traces and more points.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from ...methods.sas.allocator import STRATEGIES, AtlasLayout
from ...methods.sas.patches import build_scene_patches
from ...methods.sas.pvs import PatchIdPass, pvs_rates, sample_times
from ...methods.sas.replay import record_visibility, replay_allocation, replay_baseline
from ...methods.sas.server import SasConfig
from ...render.renderer import Renderer
from ...scene.loader import get_scene
from ...scene.pose import CameraIntrinsics
from ...scene.predict import make_predictor
from ...scene.trace import get_trace
from ...sim.config import RunConfig
from ...sim.runner import run as run_one
from ...tabular import write_csv
from ..sections import Section
from ._util import STUDY_SCENE

log = logging.getLogger(__name__)
BASELINES = ("video", "atw", "warp")
BENCH_JSON = Path(__file__).resolve().parents[3] / "benchmarks" / "results" / "bench_sas_allocator.json"


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> Path:
    write_csv(path, rows)
    return path


def _mean(frames: list[dict[str, Any]], key: str) -> float:
    v = [float(f[key]) for f in frames if key in f and f[key] is not None and f[key] == f[key] and f[key] != ""]
    return float(np.mean(v)) if v else float("nan")


def _quality_runs(renderer: Any, quick: bool) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    dur = 0.5 if quick else 4.0
    common = dict(scene=STUDY_SCENE, trace="strafe", width=320, height=180, client_fps=30, duration_s=dur,
                  flip_every=3 if quick else 4, seed=0)
    delays = [0, 50] if quick else [0, 20, 50, 100]
    # (label, method, parameters): the paper compares 4 and 8 MPix atlases (scaled to 320x180); the default is 12
    methods: list[tuple[str, str, dict[str, Any]]] = [("sas", "sas", {})] + [(b, b, {}) for b in BASELINES]
    if not quick:
        methods[1:1] = [("sas-4MP", "sas", {"atlas_mpix_1080p": 4.0}), ("sas-8MP", "sas", {"atlas_mpix_1080p": 8.0})]
    lat_rows = []
    for d in delays:
        net = "ideal" if d == 0 else f"delay {d}ms"
        for label, m, params in methods if not quick or d else methods[:1] + [x for x in methods if x[0] == "atw"]:
            t0 = time.perf_counter()
            res = run_one(RunConfig(method=m, network=net, method_params=params, **common), renderer=renderer)  # type: ignore[arg-type]
            s = res.summary
            row = {"method": label, "delay_ms": d, "psnr_db": s["mean_psnr_db"], "ssim": s["mean_ssim"], "flip": s.get("mean_flip"),
                   "hole_pct": s["mean_hole_pct"], "kbps": s["mean_kbps"], "server_ms": s["mean_server_ms"],
                   "client_ms": s["mean_client_ms"], "wall_s": time.perf_counter() - t0}
            if label == "sas":
                for k in ("srv_pvs_ms", "srv_alloc_ms", "srv_shade_ms", "srv_pvs_patches", "srv_atlas_used_pct"):
                    row[k] = _mean(res.updates, k)
            lat_rows.append(row)
    rate_rows = []
    rates = [300, 1200] if quick else [250, 500, 1000, 2000, 4000]
    for kb in rates:
        for m in ("sas", "atw") if quick else ("sas",) + BASELINES:
            res = run_one(RunConfig(method=m, network="delay 50ms", method_params={"bitrate_kbps": float(kb), "crf": None},
                                **common), renderer=renderer)  # type: ignore[arg-type]
            s = res.summary
            rate_rows.append({"method": m, "budget_kbps": kb, "kbps": s["mean_kbps"], "psnr_db": s["mean_psnr_db"],
                              "ssim": s["mean_ssim"], "flip": s.get("mean_flip")})
    return lat_rows, rate_rows


def _pvs_rates(renderer: Any, quick: bool) -> list[dict[str, Any]]:
    scene = get_scene(STUDY_SCENE)
    intr = CameraIntrinsics(320, 180)
    ids = PatchIdPass(renderer, scene, build_scene_patches(scene))
    rows = []
    for trace_name in ("walk",) if quick else ("walk", "walk_fast", "turn"):
        trace = get_trace(trace_name)
        for latency_ms in (50.0,) if quick else (0.0, 50.0, 100.0):
            ts = np.linspace(0.5, trace.duration_s - 0.5, 6 if quick else 30)
            for mode in ("none", "linear", "perfect"):
                for fov in (1.0, 1.2):
                    v = fn = fp = 0.0
                    for t in ts:
                        times = sample_times(t, t + latency_ms / 1e3 + 1 / 30, 1 / 30)
                        truth = [(s, trace.pose_at(s)) for s in times]
                        if mode == "none":
                            samples = truth[:1]
                        elif mode == "perfect":
                            samples = truth
                        else:
                            pred = make_predictor("cv")
                            for k in range(4, -1, -1):
                                pred.observe(t - k / 120, trace.pose_at(t - k / 120))
                            samples = [(s, pred.predict(s)) for s in times]
                        r = pvs_rates(ids, samples, truth, intr, fov)
                        v += r.visible_px
                        fn += (1 - r.coverage) * r.visible_px
                        fp += r.overestimation * r.visible_px
                    rows.append({"trace": trace_name, "latency_ms": latency_ms, "prediction": mode, "fov_factor": fov,
                                 "coverage": 1 - fn / v, "overestimation": fp / v})
    return rows


def _allocator(renderer: Any, quick: bool) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    intr = CameraIntrinsics(320, 180)
    frames = 30 if quick else 300
    patches, seq = record_visibility(renderer, get_scene(STUDY_SCENE), get_trace("walk_fast"), intr, 0.5, frames)
    mem_rows, ms_rows = [], []
    for mpix in (4.0, 2.0):
        layout: AtlasLayout = SasConfig(atlas_mpix_1080p=mpix).atlas_layout(intr)
        for s in STRATEGIES:
            r = replay_allocation(patches, seq, layout, s, high_water=0.85)
            m = {k: float(np.mean([x[k] for x in r.memory])) / layout.area for k in r.memory[0]}
            mem_rows.append({"atlas_mpix_1080p": mpix, "strategy": s, **{f"{k}_frac": v for k, v in m.items()},
                             "resets": r.resets, "oom_frames": r.oom_frames})
            if mpix == 4.0:
                a = np.asarray(r.alloc_ms[1:])
                ms_rows.append({"scene": "default", "patches": patches.count, "strategy": s, "mean_ms": float(a.mean()),
                                "p95_ms": float(np.percentile(a, 95)), "levels_ms": float(np.mean(r.levels_ms))})
        if mpix == 4.0:
            b = np.asarray(replay_baseline(seq, layout)[1:])
            ms_rows.append({"scene": "default", "patches": patches.count, "strategy": "python loop", "mean_ms": float(b.mean()),
                            "p95_ms": float(np.percentile(b, 95)), "levels_ms": float("nan")})
    if BENCH_JSON.exists():
        for row in json.loads(BENCH_JSON.read_text())["results"]:
            if row["scene"] == "default":
                continue
            for s, v in row["strategies"].items():
                ms_rows.append({"scene": row["scene"] + " (bench)", "patches": row["patches"], "strategy": s,
                                "mean_ms": v["mean_ms"], "p95_ms": v["p95_ms"], "levels_ms": v["levels_mean_ms"]})
            b = row["baseline_python_loop"]
            ms_rows.append({"scene": row["scene"] + " (bench)", "patches": row["patches"], "strategy": "python loop",
                            "mean_ms": b["mean_ms"], "p95_ms": b["p95_ms"], "levels_ms": float("nan")})
    return mem_rows, ms_rows


def _charts(out: Path, lat: list[dict[str, Any]], rate: list[dict[str, Any]], pvs: list[dict[str, Any]],
            mem: list[dict[str, Any]]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs = []
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for ax, key, label in zip(axes, ("psnr_db", "ssim", "flip"), ("PSNR (dB)", "SSIM", "FLIP (lower is better)")):
        for m in sorted({r["method"] for r in lat}):
            pts = sorted((r["delay_ms"], r[key]) for r in lat if r["method"] == m and r[key] is not None and r[key] == r[key])
            if pts:
                ax.plot(*zip(*pts), "o-", label=m, lw=2.5 if m == "sas" else 1.2)
        ax.set_xlabel("one-way network delay (ms)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle("Quality vs network latency (strafe trace, 320x180)")
    fig.tight_layout()
    figs.append(out / "sas_quality_latency.png")
    fig.savefig(figs[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, key, label in zip(axes, ("psnr_db", "ssim"), ("PSNR (dB)", "SSIM")):
        for m in sorted({r["method"] for r in rate}):
            pts = sorted((r["kbps"], r[key]) for r in rate if r["method"] == m)
            ax.plot(*zip(*pts), "o-", label=m, lw=2.5 if m == "sas" else 1.2)
        ax.set_xscale("log")
        ax.set_xlabel("measured bitrate incl. metadata (kbit/s)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle("Rate-distortion (50 ms one-way delay)")
    fig.tight_layout()
    figs.append(out / "sas_rate_distortion.png")
    fig.savefig(figs[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 3.6))
    labels, cov, ovr = [], [], []
    for r in pvs:
        labels.append(f"{r['trace']} {int(r['latency_ms'])}ms\n{r['prediction']}{' +FOV' if r['fov_factor'] > 1 else ''}")
        cov.append(r["coverage"])
        ovr.append(r["overestimation"])
    x = np.arange(len(labels))
    ax.bar(x - 0.2, cov, 0.4, label="coverage")
    ax.bar(x + 0.2, ovr, 0.4, label="overestimation")
    ax.set_xticks(x, labels, fontsize=6, rotation=90)
    ax.axhline(0.99, color="k", lw=0.8, ls="--")
    ax.set_ylabel("area-weighted rate")
    ax.legend(fontsize=8)
    ax.set_title("PVS coverage / overestimation (section 5.1)")
    fig.tight_layout()
    figs.append(out / "sas_pvs_rates.png")
    fig.savefig(figs[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 3.6))
    cats = [("allocated_frac", "allocated", "tab:green"), ("superblock_tail_frac", "end of partial superblock", "tab:blue"),
            ("block_stacks_frac", "on block stacks", "tab:red"), ("inaccessible_frac", "inaccessible", "tab:orange"),
            ("free_superblocks_frac", "free superblocks", "tab:purple")]
    names = [f"{r['strategy']} {r['atlas_mpix_1080p']:g}MP\n({r['oom_frames']}, {r['resets']})" for r in mem]
    bottom = np.zeros(len(mem))
    for key, lab, col in cats:
        vals = np.array([r[key] for r in mem])
        ax.bar(names, vals, bottom=bottom, label=lab, color=col)
        bottom += vals
    ax.set_ylabel("fraction of atlas (mean over frames)")
    ax.set_title("Atlas memory by allocator strategy (OOM frames, resets)")
    ax.legend(fontsize=7, loc="lower right")
    ax.tick_params(axis="x", labelsize=7)
    fig.tight_layout()
    figs.append(out / "sas_memory_strategies.png")
    fig.savefig(figs[-1], dpi=110)
    plt.close(fig)
    return figs


def run(out_dir: Path, quick: bool) -> Section:
    """Run the SAS study into ``out_dir`` and return its report section."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    renderer = Renderer()
    pvs = _pvs_rates(renderer, quick)
    mem, ms = _allocator(renderer, quick)
    lat, rate = _quality_runs(renderer, quick)
    tables = [_write_csv(out / "sas_quality_latency.csv", lat), _write_csv(out / "sas_rate_distortion.csv", rate),
              _write_csv(out / "sas_pvs_rates.csv", pvs), _write_csv(out / "sas_memory_strategies.csv", mem),
              _write_csv(out / "sas_allocator_ms.csv", ms)]
    figs = _charts(out, lat, rate, pvs, mem)

    def q(m: str, d: int, k: str) -> float:
        v = [r[k] for r in lat if r["method"] == m and r["delay_ms"] == d]
        return float(v[0]) if v else float("nan")

    dmax = max(r["delay_ms"] for r in lat)
    lin = [r for r in pvs if r["prediction"] == "linear" and r["fov_factor"] > 1]
    non = [r for r in pvs if r["prediction"] == "none" and r["fov_factor"] > 1]
    s0 = [r for r in ms if r["strategy"] == "S0"]
    sas_rows = [r for r in lat if r["method"] == "sas"]
    text = [
        f"Shading atlas streaming at 320x180, default scene without GI (`{STUDY_SCENE}`), strafe trace ({'quick' if quick else 'full'} run, "
        f"{time.perf_counter() - t0:.0f} s).",
        "",
        f"- **Latency** ({dmax} ms one-way): sas {q('sas', dmax, 'psnr_db'):.2f} dB / SSIM {q('sas', dmax, 'ssim'):.3f}, "
        f"atw {q('atw', dmax, 'psnr_db'):.2f} dB / {q('atw', dmax, 'ssim'):.3f}, video {q('video', dmax, 'psnr_db'):.2f} dB, "
        f"warp {q('warp', dmax, 'psnr_db'):.2f} dB.  At 0 ms: sas {q('sas', 0, 'psnr_db'):.2f} dB, atw {q('atw', 0, 'psnr_db'):.2f} dB.",
        f"- **PVS** (walk, 20% larger FOV): linear prediction coverage {np.mean([r['coverage'] for r in lin]):.4f}, "
        f"overestimation {np.mean([r['overestimation'] for r in lin]):.3f}; no prediction {np.mean([r['coverage'] for r in non]):.4f}.",
        "- **Allocator** ms per frame (numpy, this CPU): " + ", ".join(f"{r['scene']} ({r['patches']} patches) {r['mean_ms']:.2f} ms" for r in s0)
        + "; paper: CPU 37-377 ms, GPU < 0.25 ms.  Per-patch Python loop baseline: "
        + ", ".join(f"{r['scene']} {r['mean_ms']:.2f} ms" for r in ms if r["strategy"] == "python loop") + ".",
        "- **Memory**: " + "; ".join(f"{r['strategy']}@{r['atlas_mpix_1080p']:g}MP free {r['free_superblocks_frac']:.2f}, "
                                     f"{r['resets']} resets, {r['oom_frames']} OOM frames" for r in mem) + ".",
        f"- **Per frame**: sas server {np.mean([r['server_ms'] for r in sas_rows]):.0f} ms (PVS "
        f"{np.nanmean([r['srv_pvs_ms'] for r in sas_rows]):.0f}, allocation {np.nanmean([r['srv_alloc_ms'] for r in sas_rows]):.1f}, "
        f"shading + readback {np.nanmean([r['srv_shade_ms'] for r in sas_rows]):.0f}), client {np.mean([r['client_ms'] for r in sas_rows]):.1f} ms "
        "on Mesa llvmpipe.",
        "",
        "Holes count every pixel no patch covers, sky included (the client cannot tell sky from a missed patch), "
        "so sas's hole rate is not comparable with methods that fill.  Bitrates include metadata (geometry is sent "
        "once; the first frame's geometry dominates short runs).",
    ]
    return Section("Shading atlas streaming (sas)", "\n".join(text), figs, tables)
