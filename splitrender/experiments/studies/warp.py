"""Study: depth-image warping (``warp``, the MeshWarp baseline) against ``video`` and ``atw``.

Four experiments on the default scene without GI (``default+nogi``), all through the virtual-time runner:

1. **Frame-ratio trend** (the paper's table 3): error-pixel rate (CIE Lab distance
   > 20) as the server:client frame ratio goes 2:1, 5:1, 10:1, 20:1 (client at 60 Hz,
   server at 30, 12, 6, 3 Hz), point splats, on the ``walk`` trace, with ``video`` and
   ``atw`` at the same ratios.
2. **One vs two reference views** on the ``strafe`` trace (sideways motion: disocclusions).
3. **Reconstructions**: points, quads and mesh with client ms per frame (the paper's
   speed/quality trade-off), beside ``video`` and ``atw``.
4. **Networks**: warp points, ``atw`` and ``video`` at 2:1 under the demo's network
   profiles and traces (``ideal``, ``lan``, ``cloud``; ``walk`` and ``turn``); the
   quick run does ``cloud`` on ``walk`` and reuses experiment 1's ideal 2:1 rows.

Every row records PSNR, SSIM, FLIP, error pixels, holes, bitrate and client ms.
``quick=True`` uses 0.5 s traces at 320x180 (about 80 s on two CPU cores).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

from ...render.renderer import Renderer
from ...sim.config import RunConfig
from ...sim.runner import run as run_one
from ..sections import Section
from ._study import Study
from ._util import STUDY_SCENE

log = logging.getLogger(__name__)

CLIENT_FPS = 60
RATIOS = (2, 5, 10, 20)
NETWORKS = ("ideal", "lan", "cloud")
TRACES = ("walk", "turn")
COLUMNS = ("experiment", "method", "label", "trace", "network", "ratio", "psnr_db", "ssim", "flip", "lab_err_pct", "hole_pct",
           "kbps", "client_ms", "gt_ms")


def _run(method: str, params: dict[str, Any], trace: str, ratio: int, quick: bool, renderer: Any,
         network: str = "ideal") -> dict[str, float]:
    dur = 0.5 if quick else 3.0
    w, h = (320, 180) if quick else (640, 360)
    cfg = RunConfig(method=method, method_params=params, scene=STUDY_SCENE, trace=trace, network=network, duration_s=dur, width=w, height=h,
                    server_fps=max(1, CLIENT_FPS // ratio), client_fps=CLIENT_FPS, seed=0, flip_every=0 if quick else 6)
    s = run_one(cfg, renderer=renderer).summary
    return {"psnr_db": s["mean_psnr_db"], "ssim": s["mean_ssim"], "flip": s.get("mean_flip", math.nan),
            "lab_err_pct": s["mean_lab_err_pct"], "hole_pct": s["mean_hole_pct"], "kbps": s["mean_kbps"],
            "client_ms": s["mean_client_ms"], "gt_ms": s.get("mean_gt_ms", math.nan)}


class WarpStudy(Study):
    """The four experiments, ``warp_results.csv``, three charts and the section."""

    name = "warp"
    title = "Depth-image warping (warp / MeshWarp)"
    REC_RATIO = 2
    NET_RATIO = 2

    def __init__(self, out_dir: Path, quick: bool) -> None:
        super().__init__(out_dir, quick)
        self.renderer = Renderer()
        self.rows: list[dict[str, Any]] = []

    def _add(self, exp: str, method: str, label: str, params: dict[str, Any], trace: str, ratio: int,
             network: str = "ideal") -> dict[str, Any]:
        r = {"experiment": exp, "method": method, "label": label, "trace": trace, "network": network, "ratio": ratio,
             **_run(method, params, trace, ratio, self.quick, self.renderer, network)}
        self.rows.append(r)
        log.info("warp study: %s %s %s %s 1:%d -> %.2f dB, %.2f%% err", exp, label, trace, network, ratio, r["psnr_db"],
                 r["lab_err_pct"])
        return r

    def cells(self) -> None:
        add, quick = self._add, self.quick
        # 1. frame-ratio trend (points, as the paper), with the baselines
        for ratio in RATIOS:
            add("ratio", "warp", "warp points", {"reconstruction": "points"}, "walk", ratio)
        for m in ("atw", "video"):
            for ratio in (RATIOS if not quick else (2, 20)):
                add("ratio", m, m, {}, "walk", ratio)
        # 2. one vs two views on a disocclusion trace
        view_ratio = 5
        for label, p in [("1 view", {"views": 1}), ("2 views stereo", {"views": 2, "second_view": "stereo", "baseline_m": 0.4})]:
            add("views", "warp", label, {"reconstruction": "points", **p}, "strafe", view_ratio)
        if not quick:
            add("views", "warp", "2 views motion", {"views": 2, "second_view": "motion", "baseline_m": 0.3, "reconstruction": "points"}, "strafe", view_ratio)
            for m in ("atw", "video"):
                add("views", m, m, {}, "strafe", view_ratio)
        # 3. reconstructions (points reuses experiment 1's 2:1 row) and bitrate of the depth codings
        for rec in ("quads", "mesh"):
            add("recon", "warp", f"warp {rec}", {"reconstruction": rec}, "walk", self.REC_RATIO)
        if not quick:
            add("recon", "warp", "warp points bc4", {"reconstruction": "points", "depth_coding": "bc4"}, "walk", self.REC_RATIO)
            add("recon", "warp", "warp quads MW120", {"reconstruction": "quads", "fov_scale": 3.0, "resolution_scale": 0.5}, "walk", self.REC_RATIO)
        # 4. networks: the demo's profiles and traces at 2:1 (quick: cloud on walk; ideal walk is experiment 1's 2:1)
        baselines: list[tuple[str, str, dict[str, Any]]] = [("warp", "warp points", {"reconstruction": "points"}),
                                                            ("atw", "atw", {}), ("video", "video", {})]
        for trace in ("walk",) if quick else TRACES:
            for net in ("cloud",) if quick else NETWORKS:
                if net == "ideal" and trace == "walk":
                    continue  # experiment 1 ran these
                for m, label, p in baselines:
                    add("network", m, label, p, trace, self.NET_RATIO, net)
        self.table("warp_results.csv", ({k: r[k] for k in COLUMNS} for r in self.rows))

    def charts(self) -> None:
        plt, rows, rec_ratio, net_ratio = self.pyplot(), self.rows, self.REC_RATIO, self.NET_RATIO
        # chart 1: error pixels vs ratio
        fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
        for label in ("warp points", "atw", "video"):
            pts = sorted((r["ratio"], r["lab_err_pct"], r["psnr_db"]) for r in rows if r["experiment"] == "ratio" and r["label"] == label)
            if pts:
                ax[0].plot([f"{p[0]}:1" for p in pts], [p[1] for p in pts], marker="o", label=label)
                ax[1].plot([f"{p[0]}:1" for p in pts], [p[2] for p in pts], marker="o", label=label)
        ax[0].set_xlabel("server:client frame ratio (client 60 Hz)")
        ax[0].set_ylabel("error pixels, % (Lab > 20)")
        ax[1].set_xlabel("server:client frame ratio")
        ax[1].set_ylabel("PSNR, dB")
        ax[0].legend()
        self.figure(fig, "warp_ratio.png")
        # chart 2: reconstructions & views: quality vs client ms
        fig, ax = plt.subplots(figsize=(6, 3.6))
        sel = [r for r in rows if (r["experiment"] == "recon") or (r["experiment"] == "ratio" and r["ratio"] == rec_ratio)]
        for r in sel:
            ax.scatter(r["client_ms"], r["psnr_db"])
            ax.annotate(r["label"], (r["client_ms"], r["psnr_db"]), fontsize=8, xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel("client ms per frame (llvmpipe, wall clock)")
        ax.set_ylabel("PSNR, dB")
        ax.set_title(f"walk, {rec_ratio}:1")
        self.figure(fig, "warp_recon.png")
        # chart 3: PSNR by network profile and trace at 2:1
        net_rows = [r for r in rows if r["ratio"] == net_ratio and r["label"] in ("warp points", "atw", "video")
                    and r["experiment"] in ("ratio", "network")]
        groups = [(tr, net) for tr in TRACES for net in NETWORKS if any(r["trace"] == tr and r["network"] == net for r in net_rows)]
        fig, ax = plt.subplots(figsize=(7, 3.4))
        width = 0.8 / 3
        for k, label in enumerate(("warp points", "atw", "video")):
            vals = [next((r["psnr_db"] for r in net_rows if r["label"] == label and (r["trace"], r["network"]) == g), math.nan)
                    for g in groups]
            ax.bar([i + (k - 1) * width for i in range(len(groups))], vals, width, label=label)
        ax.set_xticks(range(len(groups)), [f"{tr}\n{net}" for tr, net in groups])
        ax.set_ylabel("PSNR, dB")
        ax.set_title(f"network profiles, {net_ratio}:1")
        ax.legend(fontsize=8)
        self.figure(fig, "warp_network.png")

    def text(self) -> str:
        rows, quick = self.rows, self.quick

        def fmt(r: dict[str, Any]) -> str:
            return (f"| {r['label']} | {r['trace']} | {r['network']} | {r['ratio']}:1 | {r['psnr_db']:.2f} | {r['ssim']:.3f} | "
                    f"{r['flip']:.3f} | {r['lab_err_pct']:.2f} | {r['hole_pct']:.2f} | {r['kbps']:.0f} | {r['client_ms']:.1f} |")

        head = ("| config | trace | network | ratio | PSNR dB | SSIM | FLIP | err px % | holes % | kbit/s | client ms |\n"
                "|---|---|---|---|---|---|---|---|---|---|---|")
        trend = sorted((r for r in rows if r["experiment"] == "ratio" and r["label"] == "warp points"), key=lambda r: r["ratio"])
        base = trend[0]["lab_err_pct"] if trend else math.nan
        rel = ", ".join(f"{r['ratio']}:1 {r['lab_err_pct']:.2f}% ({(r['lab_err_pct'] / base - 1) * 100:+.0f}%)" for r in trend)
        return (
            f"Depth-image warping (`warp`, the MeshWarp baseline) on the default scene without GI (`{STUDY_SCENE}`), "
            f"{'quick run: 0.5 s traces at 320x180' if quick else '3 s traces at 640x360'}, client at {CLIENT_FPS} Hz, "
            f"ideal network unless the row says otherwise; {len(rows)} runs in {self.cells_s:.0f} s.\n\n"
            f"**Frame-ratio trend** (paper, table 3): error pixels of point-splat warping by server:client ratio: {rel}.\n\n"
            f"{head}\n" + "\n".join(fmt(r) for r in rows) + "\n\n"
            "Client ms is wall-clock time on this machine's software GL (Mesa llvmpipe), not a GPU; "
            "FLIP is NaN in quick mode (not scored). Depth goes lossless (16-bit inverse depth, two byte planes "
            "in lossless HEVC) unless the row says bc4."
        )


def run(out_dir: Path, quick: bool) -> Section:
    """Run the four experiments, write ``warp_results.csv`` and charts into ``out_dir``."""
    return WarpStudy(out_dir, quick).run()
