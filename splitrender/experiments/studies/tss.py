"""Study: tessellated shading streaming (``tss``) beside ``sas`` and ``atw``.

Evidence, following the paper's section 5:

1. quality (PSNR, SSIM and DSSIM = (1 - SSIM) / 2, as the paper reports) and shaded
   samples per frame under ``ideal``, ``lan`` and ``cloud`` on the default walk, beside
   ``sas`` on the same runs (table 4: TSS quality holds while SAS's falls; TSS samples
   follow the PVS);
2. gathering cost per shaded sample for L-packing only, oversampling-heavy and the
   default mix, and for ``sas``, as ratios to forward rendering per pixel (table 2:
   oversampling 2-3x L-packing);
3. the slantedness threshold swept from 2 to 8 (the paper does not give it) and on to
   the default 16: quality, samples and oversampling overhead (samples past the
   triangle / all oversampled samples; the paper: 25-35%);
4. client ms per frame against ``sas``'s (the paper: lower);
5. the oversampling grids (the paper's lattice, our centred grid): PSNR against shaded
   samples as the sampling rate varies, ``sas`` beside them;
6. PSNR against shaded samples at 320x180 and 640x360 for ``sas``, the default and the
   paper-like threshold 4 (the paper's claim, TSS better with fewer samples, holds from
   480x270 up at the default);
7. rate-distortion at equal bits (issue 33): PSNR against kbit/s (every stream: atlas,
   tables, geometry, metadata) over each method's atlas budget, ``tss``'s sampling rate
   (``samples_per_px``) and ``sas``'s atlas size (``atlas_mpix_1080p``; it fills its
   atlas), still and walk traces under ``ideal`` and ``cloud``, at 320x180 and 640x360,
   lossy 4:2:0 atlases at the default ``crf``; ``tss``'s PSNR interpolated (linear in
   log kbit/s) at each ``sas`` point's bits;
8. stage by stage at one or two budgets per method (640x360; 320x180 when quick): samples
   and the lossless PSNR (sampling and reconstruction), the dB the lossy atlas loses
   (codec), atlas bits per sample in I- and P-frames (packing), the side streams' kbit/s.

``quick=True`` keeps to 320x180 and short runs; the full study runs longer.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from ...methods.tss.config import TssConfig
from ...render.renderer import Renderer
from ...sim.config import RunConfig
from ...sim.runner import run as run_one
from ...sim.truth import shared_cache_setting
from ..charts import style
from ..sections import Section
from ._study import Study
from ._util import STUDY_SCENE, save_figure, update_mean as _upd_mean

log = logging.getLogger(__name__)


def _run(renderer: Any, method: str, params: dict[str, Any], trace: str, network: str, dur: float,
         size: tuple[int, int], truth_cache: str = "") -> dict[str, Any]:
    res = run_one(RunConfig(method=method, scene=STUDY_SCENE, trace=trace, network=network, duration_s=dur, width=size[0], height=size[1],
                        client_fps=30, flip_every=0, seed=0, method_params=params, truth_cache=truth_cache), renderer=renderer)
    s = res.summary
    ssim = float(s["mean_ssim"])
    ups = res.updates
    psnr_db = float(s["mean_psnr_db"])
    if trace == "static":  # still runs score the ticks that show an update (the first ones show nothing yet), as the tests
        shown = [f for f in res.frames if f["update_frame_id"] >= 0]
        psnr_db = float(np.mean([f["psnr_db"] for f in shown]))
        ssim = float(np.mean([f["ssim"] for f in shown]))
    return {"method": method, "network": network, "trace": trace, "psnr_db": psnr_db, "ssim": ssim,
            "dssim": (1.0 - ssim) / 2.0, "kbps": float(s["mean_kbps"]), "samples": _upd_mean(ups, "srv_samples"),
            "server_ms": _upd_mean(ups, "server_ms"), "shade_ms": _upd_mean(ups, "srv_shade_ms"),
            "client_ms": float(s["mean_client_ms"]), "gt_ms": float(s["mean_gt_ms"]),
            "os_samples": _upd_mean(ups, "srv_os_samples"), "os_inside": _upd_mean(ups, "srv_os_inside"),
            "lp_samples": _upd_mean(ups, "srv_lp_samples"), "rate": _upd_mean(ups, "srv_rate"),
            "atlas_i_bytes": _atlas_bytes(ups, True), "atlas_p_bytes": _atlas_bytes(ups, False),
            "side_kbps": float(s["mean_kbps"]) - float(s.get("kbps_atlas", float("nan")))}


def _atlas_bytes(ups: list[dict[str, Any]], keyframe: bool) -> float:
    """Mean bytes of the atlas stream per I-frame (``keyframe``) or per P-frame; NaN when there is none."""
    v = [float(u["bytes_atlas"]) for u in ups if "bytes_atlas" in u and bool(u.get("keyframe")) == keyframe]
    return float(np.mean(v)) if v else float("nan")


RD_BUDGETS: dict[str, tuple[str, tuple[float, ...]]] = {
    "tss": ("samples_per_px", (0.5, 1.0, 2.0, 3.0)),
    "sas": ("atlas_mpix_1080p", (3.0, 6.0, 12.0, 24.0)),
}
"""Each method's atlas budget for the rate-distortion curves: the parameter and its values (the first three in a
quick run).  ``sas`` fills its atlas (``fill_atlas``), so its atlas size sets its sampling rate; ``tss`` stops at 3
samples per pixel, as at 4 its default atlas overflows on the walk at 320x180 and repacks (an I-frame) nearly every
frame (29 Mbit/s before issue 33's layout, 27 after)."""

RD_CURVES: tuple[tuple[str, str, dict[str, Any], tuple[str, ...]], ...] = (
    ("tss", "tss", {}, ("static", "walk")),
    ("tss, hysteresis 0.75", "tss", {"hysteresis": 0.75}, ("walk",)),
    ("sas", "sas", {}, ("static", "walk")),
)
"""The rate-distortion curves: label, method, fixed parameters and the traces each is run on, its atlas budget swept
(:data:`RD_BUDGETS`).  Under motion most of tss's bits go to cells that move when a triangle's level changes, so a
wider hysteresis is a second budget beside the sampling rate (it changes nothing for a still camera)."""


def rd_runs(renderer: Any, sizes: tuple[tuple[int, int], ...], traces: tuple[str, ...], nets: tuple[str, ...], dur: float,
            points: int = 4, truth_cache: str = "") -> list[dict[str, Any]]:
    """One run per size, trace, network, curve (:data:`RD_CURVES`) and atlas budget (:data:`RD_BUDGETS`, the first
    ``points`` values)."""
    rows = []
    for sz in sizes:
        for trace in traces:
            for net in nets:
                for label, m, fixed, on in RD_CURVES:
                    if trace not in on:
                        continue
                    key, vals = RD_BUDGETS[m]
                    for v in vals[:points]:
                        r = _run(renderer, m, {**fixed, key: v}, trace, net, dur, sz, truth_cache)
                        rows.append({**r, "curve": label, "width": sz[0], "height": sz[1], "budget_param": key, "budget": v})
                        log.info("tss study rd %dx%d %s %s %s %s=%g: %.2f dB, %.0f kbit/s", sz[0], sz[1], trace, net, label, key, v,
                                 r["psnr_db"], r["kbps"])
    return rows


def equal_bits(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per size, trace, network and tss curve, at each ``sas`` point's kbit/s inside the curve's range: the curve's PSNR
    there (linear in log kbit/s between its two nearest points) and its difference to ``sas``'s (dB, + = tss ahead)."""
    out = []
    for key in sorted({(r["width"], r["height"], r["trace"], r["network"]) for r in rows}):
        pick = lambda c: sorted((r["kbps"], r["psnr_db"]) for r in rows  # noqa: E731
                                if (r["width"], r["height"], r["trace"], r["network"]) == key and r["curve"] == c)
        sas = pick("sas")
        for curve in sorted({r["curve"] for r in rows if r["method"] == "tss"}):
            tss = pick(curve)
            if len(tss) < 2:
                continue
            lk = np.log([k for k, _ in tss])
            for kbps, db in sas:
                if not lk[0] <= np.log(kbps) <= lk[-1]:
                    continue
                at = float(np.interp(np.log(kbps), lk, [d for _, d in tss]))
                out.append({"width": key[0], "height": key[1], "trace": key[2], "network": key[3], "curve": curve, "kbps": kbps,
                            "sas_psnr_db": db, "tss_psnr_db": at, "tss_minus_sas_db": at - db})
    return out


def stage_runs(renderer: Any, size: tuple[int, int], traces: tuple[str, ...], dur: float, points: dict[str, tuple[float, ...]],
               truth_cache: str = "") -> list[dict[str, Any]]:
    """Where the bits go, stage by stage: per trace and atlas budget (``points``: method -> values of its
    :data:`RD_BUDGETS` parameter, ``ideal``), the lossy run and the lossless one.  Sampling and reconstruction: the
    lossless PSNR against the samples shaded; packing: atlas bytes per sample in I- and P-frames; codec: the dB the
    lossy atlas loses; side streams: the kbit/s besides the atlas (tables, geometry, metadata)."""
    rows = []
    for trace in traces:
        for m, vals in points.items():
            key = RD_BUDGETS[m][0]
            for v in vals:
                lossy = _run(renderer, m, {key: v}, trace, "ideal", dur, size, truth_cache)
                exact = _run(renderer, m, {key: v, "lossless": True}, trace, "ideal", dur, size, truth_cache)
                n = lossy["samples"]
                rows.append({"method": m, "trace": trace, "width": size[0], "height": size[1], "budget_param": key, "budget": v,
                             "samples": n, "psnr_db": lossy["psnr_db"], "lossless_psnr_db": exact["psnr_db"],
                             "codec_loss_db": exact["psnr_db"] - lossy["psnr_db"], "kbps": lossy["kbps"],
                             "side_kbps": lossy["side_kbps"], "i_bits_per_sample": 8 * lossy["atlas_i_bytes"] / n,
                             "p_bits_per_sample": 8 * lossy["atlas_p_bytes"] / n})
    return rows


def rd_chart(rows: list[dict[str, Any]], path: Path) -> Path:
    """PSNR against kbit/s, one panel per size (rows) and trace and network (columns), a curve per method."""
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FormatStrFormatter

    sizes = sorted({(r["width"], r["height"]) for r in rows})
    cols = sorted({(r["trace"], r["network"]) for r in rows})
    curves = [c for c, *_ in RD_CURVES if any(r["curve"] == c for r in rows)]
    fig, axes = plt.subplots(len(sizes), len(cols), figsize=(3.4 * len(cols) + 0.6, 3.0 * len(sizes)), squeeze=False)
    for i, sz in enumerate(sizes):
        for j, (trace, net) in enumerate(cols):
            ax = axes[i][j]
            for c in curves:
                pts = sorted((r["kbps"] / 1e3, r["psnr_db"]) for r in rows
                             if (r["width"], r["height"], r["trace"], r["network"], r["curve"]) == (*sz, trace, net, c))
                if pts:
                    ax.plot(*zip(*pts), **style(c, curves))
            ax.set_xscale("log")
            ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
            ax.xaxis.set_minor_formatter(FormatStrFormatter("%g"))
            ax.tick_params(axis="x", which="both", labelsize=7)
            ax.set_title(f"{sz[0]}x{sz[1]}, {trace}, {net}", fontsize=9)
            ax.grid(alpha=0.3, which="both")
            if i == len(sizes) - 1:
                ax.set_xlabel("Mbit/s (all streams)")
            if j == 0:
                ax.set_ylabel("PSNR (dB)")
    shown = {lab: h for ax in axes.ravel() for h, lab in zip(*ax.get_legend_handles_labels())}
    axes[0][0].legend(list(shown.values()), list(shown), fontsize=7)
    fig.suptitle("tss and sas at equal bits: each method's atlas budget swept (tss samples per pixel, sas atlas size)")
    return save_figure(fig, path)


class TssStudy(Study):
    """The eight experiments of the module's docstring, their tables, six charts and the section."""

    name = "tss"
    title = "Tessellated shading streaming (tss)"

    def __init__(self, out_dir: Path, quick: bool) -> None:
        super().__init__(out_dir, quick)
        self.renderer = Renderer()
        self.size = (320, 180)
        self.nets = ("ideal", "cloud") if quick else ("ideal", "lan", "cloud")
        self.dur = 0.5 if quick else 3.0
        self.methods = ("tss", "sas") if quick else ("tss", "sas", "atw")
        self.default_th = TssConfig.slant_threshold
        self.dflt = f"slant {self.default_th:g}"
        # the paper's claim (TSS better with fewer samples) against the display size: sas, the default threshold and
        # the paper-like 4 (and L-packing alone), still camera, lossless
        kinds: tuple[tuple[str, str, dict[str, Any], str], ...] = (
            ("sas", "sas", {}, "sas"), (f"tss, threshold {self.default_th:g} (default)", "tss", {}, self.dflt),
            ("tss, threshold 4", "tss", {"slant_threshold": 4.0}, "slant 4"))
        if not quick:
            kinds += (("tss, L-packing only", "tss", {"slant_threshold": 1000.0}, "L-packing only"),)
        self.kinds = kinds
        self.rd_dur = 0.5 if quick else 1.0
        self.stage_size = (320, 180) if quick else (640, 360)

    def _one(self, method: str, params: dict[str, Any], trace: str, network: str, dur: float,
             size: tuple[int, int] | None = None, truth_cache: str = "") -> dict[str, Any]:
        return _run(self.renderer, method, params, trace, network, dur, size or self.size, truth_cache)

    def cells(self) -> None:
        quick, one, size = self.quick, self._one, self.size
        self.lat = [one(m, {}, "walk", n, self.dur) for n in self.nets for m in self.methods]
        # still camera, lossless atlases: sampling alone
        th = self.default_th
        thresholds = tuple(sorted({2.0, 4.0, 8.0, th} if quick else {2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 12.0, th}))
        still = [{**one("tss", {"lossless": True, "slant_threshold": t}, "static", "ideal", 0.3), "variant": f"slant {t:g}",
                  "slant_threshold": t} for t in thresholds]
        variants = (("L-packing only", {"slant_threshold": 1000.0}),) + ((("oversampling only", {"slant_threshold": 1.0}),) if not quick else ())
        for label, p in variants:
            still.append({**one("tss", {"lossless": True, **p}, "static", "ideal", 0.3), "variant": label})
        still.append({**one("sas", {"lossless": True}, "static", "ideal", 0.3), "variant": "sas"})
        # oversampling grids: the paper's lattice against the centred grid, PSNR against samples as the rate varies
        grids = [{**var_row, "grid": "paper", "spp": 1.0} for var_row in still if var_row.get("slant_threshold") == 4.0]
        for grid, spp in ((("paper", 0.75), ("centred", 1.0), ("centred", 1.35)) if quick else
                          (("paper", 0.75), ("paper", 1.35), ("centred", 1.0), ("centred", 1.35), ("centred", 1.8))):
            r = one("tss", {"lossless": True, "os_grid": grid, "samples_per_px": spp, "slant_threshold": 4.0}, "static", "ideal", 0.3)
            grids.append({**r, "grid": grid, "spp": spp})
        # slot assignment: the stable layout against the paper's per-frame (prefix) layout, and that at GOP 1
        g = TssConfig.gop
        self.layouts = [{**one("tss", p, "walk", "ideal", self.dur), "variant": label}
                        for label, p in ((f"stable, GOP {g}", {}), (f"per-frame, GOP {g}", {"layout": "prefix"}),
                                         ("per-frame, GOP 1", {"layout": "prefix", "gop": 1}), ("stable, GOP 1", {"gop": 1}))]
        # quality against samples by display size (the study's own size from the still runs above)
        by_size = []
        for sz in ((320, 180), (640, 360)) if quick else ((320, 180), (480, 270), (640, 360)):
            for label, m, p, same in self.kinds:
                r = (next(x for x in still if x["variant"] == same) if sz == size else
                     one(m, {"lossless": True, **p}, "static", "ideal", 0.3, sz))
                by_size.append({k: r[k] for k in ("method", "psnr_db", "ssim", "samples", "server_ms")} |
                               {"variant": label, "width": sz[0], "height": sz[1]})
        # rate-distortion at equal bits: each method's atlas budget swept, lossy atlases, every stream's bits
        cache = shared_cache_setting(self.out)
        self.rd = rd_runs(self.renderer, ((320, 180),) if quick else ((320, 180), (640, 360)), ("static", "walk"),
                          ("ideal", "cloud"), self.rd_dur, 3 if quick else 4, cache)
        self.eq = equal_bits(self.rd)
        self.stages = stage_runs(self.renderer, self.stage_size, ("static", "walk"), 0.5 if quick else 1.0,
                                 {"tss": (1.0,), "sas": (6.0,)} if quick else {"tss": (1.0, 2.0), "sas": (6.0, 12.0)}, cache)
        px = size[0] * size[1]
        self.fw_ns = float(np.mean([r["gt_ms"] for r in still])) * 1e6 / px
        for r in still:
            r["os_overhead"] = 1.0 - r["os_inside"] / r["os_samples"] if r["os_samples"] > 0 else float("nan")
            extra = r["os_samples"] - r["os_inside"]
            r["frame_overhead"] = extra / (r["samples"] - extra) if r["samples"] > extra else float("nan")
            r["ns_per_sample"] = r["shade_ms"] * 1e6 / r["samples"] if r["samples"] > 0 else float("nan")
            r["ratio_to_forward"] = r["ns_per_sample"] / self.fw_ns
        self.still, self.grids, self.by_size = still, grids, by_size
        for name, rows in (("tss_quality_latency.csv", self.lat), ("tss_still.csv", still), ("tss_layouts.csv", self.layouts),
                           ("tss_grids.csv", grids), ("tss_by_size.csv", by_size), ("tss_rd.csv", self.rd),
                           ("tss_rd_equal_bits.csv", self.eq), ("tss_stages.csv", self.stages)):
            self.table(name, rows)

    def charts(self) -> None:
        plt, lat, still, nets, methods, size = self.pyplot(), self.lat, self.still, self.nets, self.methods, self.size
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
        x = np.arange(len(nets))
        for i, m in enumerate(methods):
            rows = [next(r for r in lat if r["method"] == m and r["network"] == n) for n in nets]
            axes[0].bar(x + (i - (len(methods) - 1) / 2) * 0.27, [r["psnr_db"] for r in rows], 0.27, label=m)
            axes[1].bar(x + (i - (len(methods) - 1) / 2) * 0.27, [r["dssim"] for r in rows], 0.27, label=m)
            if m != "atw":
                axes[2].bar(x + (i - 0.5) * 0.35, [r["samples"] / 1e3 for r in rows], 0.35, label=m)
        for ax, lab in zip(axes, ("PSNR (dB)", "DSSIM (lower is better)", "shaded samples per frame (thousands)")):
            ax.set_xticks(x, nets)
            ax.set_ylabel(lab)
            ax.grid(alpha=0.3, axis="y")
        axes[0].legend()
        fig.suptitle(f"tss beside {' and '.join(methods[1:])}: default walk, {size[0]}x{size[1]}, {self.dur:g} s per run")
        self.figure(fig, "tss_quality_latency.png")

        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
        sw = [r for r in still if "slant_threshold" in r]
        ax = axes[0]
        ax.plot([r["slant_threshold"] for r in sw], [r["psnr_db"] for r in sw], "o-", color="tab:blue", label="PSNR")
        ax.set_xlabel("slantedness threshold (longest edge / height)")
        ax.set_ylabel("PSNR (dB), still camera, lossless", color="tab:blue")
        ax2 = ax.twinx()
        ax2.plot([r["slant_threshold"] for r in sw], [r["samples"] / 1e3 for r in sw], "s--", color="tab:red")
        ax2.set_ylabel("samples per frame (thousands)", color="tab:red")
        ax.grid(alpha=0.3)
        ax = axes[1]
        shown = [r for r in still if "slant_threshold" not in r or r["slant_threshold"] in (4.0, self.default_th)]
        names = ["forward"] + [r["variant"] for r in shown]
        vals = [1.0] + [r["ratio_to_forward"] for r in shown]
        ax.bar(names, vals, color=["gray", "tab:blue", "tab:cyan", "tab:green", "tab:orange", "tab:purple"][:len(vals)])
        ax.set_ylabel("ms per shaded sample / forward ms per pixel")
        ax.tick_params(axis="x", labelsize=7)
        ax.grid(alpha=0.3, axis="y")
        self.figure(fig, "tss_sampling.png")

        fig, ax = plt.subplots(figsize=(6, 3.8))
        for grid, mk in (("paper", "o-"), ("centred", "s-")):
            rows = sorted((r for r in self.grids if r["grid"] == grid), key=lambda r: r["samples"])
            rates = ", ".join(f"{r['spp']:g}" for r in rows)
            ax.plot([r["samples"] / 1e3 for r in rows], [r["psnr_db"] for r in rows], mk, label=f"tss, {grid} grid ({rates} samples/px)")
        sas_still = next(r for r in still if r["variant"] == "sas")
        ax.plot(sas_still["samples"] / 1e3, sas_still["psnr_db"], "k*", ms=12, label="sas (block texels)")
        ax.set_xlabel("shaded samples per frame (thousands)")
        ax.set_ylabel("PSNR (dB), still camera, lossless")
        ax.set_title(f"quality against samples: oversampling grids, {size[0]}x{size[1]}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        self.figure(fig, "tss_grids.png")

        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        sizes = sorted({(r["width"], r["height"]) for r in self.by_size})
        for (label, *_), colour in zip(self.kinds, ("black", "tab:blue", "tab:orange", "tab:green")):
            rows = [next(r for r in self.by_size if r["variant"] == label and (r["width"], r["height"]) == sz) for sz in sizes]
            ax.plot([r["samples"] / 1e3 for r in rows], [r["psnr_db"] for r in rows], "-", color=colour, alpha=0.4)
            for r, mk in zip(rows, "os^D"):
                ax.plot(r["samples"] / 1e3, r["psnr_db"], mk, color=colour, ms=8, label=label if r is rows[0] else None)
        for sz, mk in zip(sizes, "os^D"):
            ax.plot([], [], mk, color="gray", label=f"{sz[0]}x{sz[1]}")
        ax.set_xscale("log")
        ax.set_xlabel("shaded samples per frame (thousands; sas: block texels)")
        ax.set_ylabel("PSNR (dB), still camera, lossless")
        ax.set_title("quality against samples by display size (up and left is better)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
        self.figure(fig, "tss_by_size.png")

        fig, ax = plt.subplots(figsize=(6, 3.8))
        for r, mk in zip(self.layouts, "osD^"):
            ax.plot(r["kbps"] / 1e3, r["psnr_db"], mk, ms=9, label=r["variant"])
        ax.set_xlabel("Mbit/s (atlas video + tables + geometry)")
        ax.set_ylabel("PSNR (dB)")
        ax.set_title(f"tss slot layouts: walk, ideal, {size[0]}x{size[1]}, {self.dur:g} s")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        self.figure(fig, "tss_layouts.png")

        self.figures.append(rd_chart(self.rd, self.out / "tss_rd.png"))

    def text(self) -> str:
        quick, lat, still, nets, methods, size = self.quick, self.lat, self.still, self.nets, self.methods, self.size
        eq, rd, stages, grids, by_size, layouts = self.eq, self.rd, self.stages, self.grids, self.by_size, self.layouts
        dflt, default_th, dur, rd_dur, fw_ns, stage_size = self.dflt, self.default_th, self.dur, self.rd_dur, self.fw_ns, self.stage_size
        sizes = sorted({(r["width"], r["height"]) for r in by_size})
        sw = [r for r in still if "slant_threshold" in r]

        def gap(key: tuple[Any, ...], curve: str) -> str:
            d = [e["tss_minus_sas_db"] for e in eq if (e["width"], e["height"], e["trace"], e["network"], e["curve"]) == (*key, curve)]
            return (f"{curve} {np.mean(d):+.2f} dB ({min(d):+.2f} to {max(d):+.2f}, {len(d)} points)" if d else
                    f"{curve}: no sas point inside its range")

        def get(m: str, n: str, k: str) -> float:
            return float(next(r[k] for r in lat if r["method"] == m and r["network"] == n))

        def var(v: str, k: str) -> float:
            return float(next(r[k] for r in still if r["variant"] == v))

        best = max(sw, key=lambda r: r["psnr_db"])
        far = nets[-1]
        text = [
            f"Tessellated shading streaming at {size[0]}x{size[1]}, default scene without GI (`{STUDY_SCENE}`; {'quick' if quick else 'full'} run, "
            f"{self.cells_s:.0f} s).",
            "",
            f"- **Quality vs latency** (walk, {dur:g} s): " + "; ".join(
                f"{n}: tss {get('tss', n, 'psnr_db'):.2f} dB (DSSIM {get('tss', n, 'dssim'):.4f}), sas {get('sas', n, 'psnr_db'):.2f} dB "
                f"({get('sas', n, 'dssim'):.4f})" + (f", atw {get('atw', n, 'psnr_db'):.2f} dB" if "atw" in methods else "")
                for n in nets) + ("." if "atw" in methods else " (atw: the demo's runs above)."),
            f"- **Samples per frame** under {far}: tss {get('tss', far, 'samples') / 1e3:.0f}k, sas {get('sas', far, 'samples') / 1e3:.0f}k "
            f"(block texels).  Bitrate tss {get('tss', far, 'kbps'):.0f} kbit/s, sas {get('sas', far, 'kbps'):.0f} kbit/s.",
            f"- **Still camera, lossless**: tss (default, threshold {default_th:g}) {var(dflt, 'psnr_db'):.2f} dB with "
            f"{var(dflt, 'samples') / 1e3:.0f}k samples, at threshold 4 {var('slant 4', 'psnr_db'):.2f} dB with "
            f"{var('slant 4', 'samples') / 1e3:.0f}k, "
            f"sas {var('sas', 'psnr_db'):.2f} dB with {var('sas', 'samples') / 1e3:.0f}k; L-packing only {var('L-packing only', 'psnr_db'):.2f} dB "
            f"({var('L-packing only', 'samples') / 1e3:.0f}k)" + ("" if quick else
            f", oversampling only {var('oversampling only', 'psnr_db'):.2f} dB ({var('oversampling only', 'samples') / 1e3:.0f}k)") + ".",
            "- **Slantedness threshold** " + ", ".join(f"{r['slant_threshold']:g}: {r['psnr_db']:.2f} dB / {r['samples'] / 1e3:.0f}k" for r in sw) + "; "
            f"best {best['slant_threshold']:g}.  Conservative samples (oversampled samples outside their triangle) at threshold 4: "
            f"{var('slant 4', 'frame_overhead') * 100:.0f}% on top of the frame's other samples, "
            f"{var('slant 4', 'os_overhead') * 100:.0f}% of the oversampled ones (paper: 25-35%, at 1920x1080; at this size our "
            "slanted triangles are a few pixels high, where each staircase row's two conservative samples dominate; "
            "at 1920x1080 the test measures 30.5% and 46%).",
            f"- **Gathering cost per sample** / forward cost per pixel ({fw_ns:.0f} ns on this CPU): L-packing only "
            f"{var('L-packing only', 'ratio_to_forward'):.2f}x, " + ("" if quick else
            f"oversampling only {var('oversampling only', 'ratio_to_forward'):.2f}x, ") +
            f"default mix {var(dflt, 'ratio_to_forward'):.2f}x, threshold 4 {var('slant 4', 'ratio_to_forward'):.2f}x, sas {var('sas', 'ratio_to_forward'):.2f}x (paper, Robot Lab: "
            "LP 2.5x, OS 7x, SAS 2.6x forward).  Includes the layout upload and the atlas readback.",
            "- **Oversampling grids** (still, lossless; PSNR / samples): " + "; ".join(
                f"{r['grid']} at {r['spp']:g}/px {r['psnr_db']:.2f} dB / {r['samples'] / 1e3:.0f}k"
                for r in sorted(grids, key=lambda r: (r["grid"], r["spp"]))) +
            ".  The centred grid drops the lattice's two conservative samples per row; per sample it is the better one.",
            "- **Slot layouts** (walk, ideal): " + "; ".join(f"{r['variant']} {r['kbps'] / 1e3:.1f} Mbit/s, {r['psnr_db']:.2f} dB"
                                                         for r in layouts) +
            ".  A new layout every frame defeats P-frames; the paper's per-frame layout is only fair at GOP 1.",
            "- **Quality against samples by size** (still, lossless; PSNR / samples): " + "; ".join(
                f"{sz[0]}x{sz[1]}: " + ", ".join(f"{r['variant']} {r['psnr_db']:.2f} dB / {r['samples'] / 1e3:.0f}k"
                                              for r in by_size if (r["width"], r["height"]) == sz) for sz in sizes) +
            ".  The paper's claim, TSS better than SAS with fewer samples, at the default from 480x270 up; at 320x180 most "
            "triangles are a few pixels across and sas's shared blocks are ahead.",
            f"- **Client ms per frame** (walk, {far}): tss {get('tss', far, 'client_ms'):.1f} ms, sas {get('sas', far, 'client_ms'):.1f} ms.",
            f"- **At equal bits** ({rd_dur:g} s runs, lossy atlases, every stream's bits; tss's samples per pixel "
            f"{', '.join(f'{v:g}' for v in RD_BUDGETS['tss'][1][:3 if quick else 4])} against sas's atlas of "
            f"{', '.join(f'{v:g}' for v in RD_BUDGETS['sas'][1][:3 if quick else 4])} Mpix at 1080p; tss's PSNR at sas's bits, "
            "minus sas's): " + "; ".join(f"{k[0]}x{k[1]} {k[2]} {k[3]}: " + ", ".join(
                gap(k, c) for c in sorted({r["curve"] for r in rd if r["method"] == "tss" and r["trace"] == k[2]}))
                for k in sorted({(r['width'], r['height'], r['trace'], r['network']) for r in rd})) + ".",
            f"- **Stage by stage** ({stage_size[0]}x{stage_size[1]}, ideal; samples, lossless PSNR (sampling and reconstruction), "
            "dB lost to the codec, atlas bits per sample in I- / P-frames (packing), side kbit/s): " + "; ".join(
                f"{r['trace']} {r['method']} {r['budget_param']}={r['budget']:g}: {r['samples'] / 1e3:.0f}k, {r['lossless_psnr_db']:.2f} dB, "
                f"-{r['codec_loss_db']:.2f} dB, {r['i_bits_per_sample']:.2f} / {r['p_bits_per_sample']:.2f} bit, {r['side_kbps']:.0f}"
                for r in stages) + ".  Short runs favour tss: its geometry and first I-frame weigh most there, and "
            "sas's 5-frame GOP pays an I-frame more often as a run lengthens.",
        ]
        return "\n".join(text)


def run(out_dir: Path, quick: bool) -> Section:
    """Run the TSS study into ``out_dir`` and return its report section."""
    return TssStudy(out_dir, quick).run()
