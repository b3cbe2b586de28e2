"""Study: light probe streaming (``probes``) on the default scene with DDGI (``default``).

Evidence, following the light probe streaming paper's section 5:

1. **Rate over time** (table 2, figure 6): one client's probe streams, update by update,
   on a still camera while the sun dims (4-5 s) and the lamp switches on (6.0-6.2 s),
   with nothing else moving (``default+still``), and again with the moving objects
   (``default``); each update's bits beside the same probes uncompressed (the paper's
   texture formats) and zstd of the same update textures; a full refresh at the end
   (the paper's answer to a keyframe request) resends every selected probe.  Compression ratios per segment (still, light change,
   moving objects, I-frames).
2. **Selected over active probes** per update (figure 7: 65-99.5 % removed).
3. **GI lag**: PSNR against the ground truth (fresh probes at every display time) through
   the lamp switching on, at 10, 20 and 30 Hz, and at 10 Hz under ``lan`` and ``cloud``.
4. **Many clients** (``clients`` 1, 2, 4, 8 in one virtual-time run, measured costs):
   the GI server's milliseconds per relight, shared, and each session's own, and bits per
   client.
5. **Savings** of the update textures: guard bands dropped and inactive probes skipped,
   beside the paper's -36 % / -21 % / -25 %.
6. **Lossy visibility** (ablation): inside a closed shed (``shed+gi``), the visibility
   picture lossless against lossy HEVC: light leaks through the walls.

``quick=True`` shortens the rate runs, runs the GI-lag and many-client runs at 160x90 and
stops at four clients.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from ...codecs.video import VideoEncoder
from ...gi.stream import decode_index_list, guard_band_savings
from ...methods import get_method, make_config
from ...metrics.image import psnr
from ...pipeline.direct import server_context, still_frame
from ...render.renderer import Renderer, make_pose_looking
from ...scene.loader import get_scene
from ...scene.pose import CameraIntrinsics
from ...scene.trace import get_trace
from ...sim.config import RunConfig
from ...sim.runner import run as run_one
from ..sections import Section
from ._study import Study

log = logging.getLogger(__name__)

GI_HZ = 10.0
COLOR_BITS_PER_PROBE = 8 * 8 * 32
"""An update's colour probe uncompressed (the paper's R11G11B10 texels, no guard band)."""
VIS_BITS_PER_PROBE = 16 * 16 * 32
"""An update's visibility probe uncompressed (RG16F texels, no guard band)."""
PAPER_RAW_MBPS = 265.0
PAPER_RAW_PROBES = 2048


def _light_state(scene: Any, t: float) -> tuple[float, ...]:
    sun = scene.sun.intensity.value(t) if scene.sun is not None else 0.0
    return (round(sun, 6), *(round(pl.intensity.value(t), 6) for pl in scene.point_lights))


def _rate_run(renderer: Any, scene_name: str, times: np.ndarray, keyframe_at_end: bool) -> list[dict[str, Any]]:
    """One client's probe updates at ``times`` (one per GI tick, a still camera), each coded by the method's own
    lossless streams and, for comparison, by zstd."""
    import zstandard

    scene = get_scene(scene_name)
    spec = get_method("probes")
    cfg = make_config(spec.config, {"gi_hz": GI_HZ})
    intr = CameraIntrinsics(160, 90)
    srv = spec.server_class(cfg, intr, scene, int(GI_HZ), None)
    pose = get_trace("static", scene=scene).pose_at(0.0)
    encoders = {s.name: VideoEncoder(s.codec, s.width, s.height) for s in srv.streams() if getattr(s, "kind", "") == "video"}
    zc = zstandard.ZstdCompressor(level=3)
    rows: list[dict[str, Any]] = []
    schedule = [(float(t), False) for t in times] + ([(float(times[-1]), True)] if keyframe_at_end else [])
    for f, (t, kf) in enumerate(schedule):
        if kf:       # a full refresh, the paper's answer to a keyframe request (ours resends only what was lost)
            srv.sent[:] = False
        ctx = server_context(scene, renderer, intr, pose, t_s=t, frame_id=f, keyframe=kf)
        w0 = time.perf_counter()
        upd = srv.produce(ctx)
        server_ms = (time.perf_counter() - w0) * 1e3
        st = srv.stats()
        coded = {n: encoders[n].encode(img, force_idr=upd.force_idr) for n, img in upd.planes.items()}
        sel = decode_index_list(upd.data["index"], srv.count) if "index" in upd.data else np.zeros(0, np.int64)
        index_b = len(upd.data.get("index", b""))
        raw = sel.size * (COLOR_BITS_PER_PROBE * ("color" in upd.planes) + VIS_BITS_PER_PROBE * ("vis" in upd.planes))
        zbuf = b""
        if "color" in upd.planes:
            zbuf += srv.sent_codes[sel].astype("<u2").tobytes()
        if "vis" in upd.planes:
            zbuf += srv.sent_moments[sel].astype("<f2").tobytes()
        z_bits = 8 * (len(zc.compress(zbuf)) + index_b) if zbuf else 0
        hevc = {n: 8 * len(e.data) for n, e in coded.items()}
        bits = sum(hevc.values()) + 8 * index_b * bool(coded)
        prev = schedule[f - 1][0] if f else t
        if f == 0 or kf:
            segment = "keyframe request" if kf else "first update"
        elif _light_state(scene, t) != _light_state(scene, prev):
            segment = "light change"
        else:
            segment = "moving objects" if scene.dynamic_ids() else "still"
        rows.append({"scene": scene_name, "t_s": t, "segment": segment, "active": st["probes_active"],
                     "visible": st["probes_visible"], "changed": st["probes_changed"], "sent": st["probes_sent"],
                     "color_bits": hevc.get("color", 0), "vis_bits": hevc.get("vis", 0), "index_bits": 8 * index_b,
                     "bits": bits, "raw_bits": raw, "zstd_bits": z_bits,
                     "iframe": int(any(e.keyframe for e in coded.values())), "server_ms": server_ms,
                     "ratio": raw / bits if bits else float("nan")})
    return rows


SHED_POSE = ((0.0, 1.5, 1.5), (1.5, 0.5, -1.5))
"""Eye and target inside the ``shed`` scene, looking at its far corner."""


def leak_ablation(renderer: Any, size: tuple[int, int] = (160, 90)) -> list[dict[str, Any]]:
    """The lossy-visibility ablation on ``shed+gi``: one probe update through the method's streams with the
    visibility lossless (the method) and lossy (``vis_lossy``), the client's view inside the shed against the truth."""
    scene = get_scene("shed+gi")
    intr = CameraIntrinsics(*size)
    pose = make_pose_looking(*SHED_POSE)
    truth = renderer.render(scene, 0.0, pose, intr).color
    spec = get_method("probes")
    rows = []
    for lossy in (False, True):
        cfg = make_config(spec.config, {"vis_lossy": lossy})
        still = still_frame(spec, cfg, intr, scene, renderer, pose, 0.0, codec=True, fps=10,
                            producer=spec.producer_class(cfg, scene, 10, renderer))
        bits = {n: 8 * still.coded_bytes[n] for n in still.update.planes}
        shown = still.frame.color   # type: ignore[union-attr]
        rows.append({"visibility": "lossy HEVC (crf 23)" if lossy else "lossless HEVC", "psnr_db": psnr(shown, truth),
                     "brightness_over_truth": float(shown.astype(np.float64).mean() / max(truth.astype(np.float64).mean(), 1e-9)),
                     "vis_kbit": bits.get("vis", 0) / 1e3, "color_kbit": bits.get("color", 0) / 1e3})
    return rows


def _segment_table(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for seg in ("still", "moving objects", "light change", "first update", "keyframe request"):
        r = [x for x in rows if x["segment"] == seg]
        if not r:
            continue
        sent = [x for x in r if x["bits"]]
        ratios = np.array([x["ratio"] for x in sent]) if sent else np.zeros(0)
        iframes = [x["ratio"] for x in sent if x["iframe"]]
        out.append({"segment": seg, "updates": len(r), "updates_with_probes": len(sent),
                    "mean_sent": float(np.mean([x["sent"] for x in r])),
                    "mean_kbit_per_update": float(np.mean([x["bits"] for x in r])) / 1e3,
                    "mean_ratio": float(ratios.mean()) if ratios.size else float("nan"),
                    "iframe_ratio": float(np.mean(iframes)) if iframes else float("nan"),
                    "max_ratio": float(ratios.max()) if ratios.size else float("nan"),
                    "zstd_over_hevc": (float(np.sum([x["zstd_bits"] for x in sent]) / np.sum([x["bits"] for x in sent]))
                                       if sent else float("nan"))})
    return out


def _run(renderer: Any, scene: str, trace: str, network: str, dur: float, size: tuple[int, int], offset: float,
         params: dict[str, Any], **kw: Any) -> Any:
    return run_one(RunConfig(method="probes", scene=scene, trace=trace, network=network, duration_s=dur, width=size[0],
                         height=size[1], client_fps=30, flip_every=0, seed=0, scene_time_offset_s=offset,
                         method_params=params, **kw), renderer=renderer)


class ProbesStudy(Study):
    """The six experiments of the module's docstring, their tables, three charts and the section."""

    name = "probes"
    title = "Light probe streaming (probes)"

    def __init__(self, out_dir: Path, quick: bool) -> None:
        super().__init__(out_dir, quick)
        self.renderer = Renderer()
        self.size = (160, 90) if quick else (320, 180)

    def cells(self) -> None:
        quick, renderer, size, out = self.quick, self.renderer, self.size, self.out
        # 1-2. rate over time, selection
        step = 1.0 / GI_HZ
        t_light = np.round(np.arange(3.5 if quick else 2.5, 6.45 if quick else 7.0, step), 3)
        t_move = np.round(np.arange(3.0, 3.65 if quick else 4.0, step), 3)
        self.light = _rate_run(renderer, "default+still", t_light, keyframe_at_end=True)
        self.move = _rate_run(renderer, "default", t_move, keyframe_at_end=False)
        self.seg = _segment_table(self.light + self.move)
        self.table("probes_rate.csv", self.light + self.move)
        self.table("probes_segments.csv", self.seg)
        # 3. GI lag through the lamp switching on
        lag_setups = [(f"{hz:g} Hz, ideal", "ideal", hz) for hz in (10.0, 20.0, 30.0)]
        lag_setups += [(f"10 Hz, {n}", n, 10.0) for n in ("lan", "cloud")]
        self.lag_rows, self.series = [], {}
        cache = out / "truth_cache"
        for lab, net, hz in lag_setups:
            res = _run(renderer, "default+still", "static", net, 0.5 if quick else 0.8, size, 5.95, {"gi_hz": hz},
                       truth_cache=str(cache))
            fr = [f for f in res.frames if f["t_s"] >= 0.1]          # from the lamp's first change (6.05 s): the light change
            self.series[lab] = ([f["t_s"] + 5.95 for f in res.frames], [f["psnr_db"] for f in res.frames])
            self.lag_rows.append({"setup": lab, "network": net, "gi_hz": hz, "mean_psnr_db": float(np.mean([f["psnr_db"] for f in fr])),
                                  "min_psnr_db": float(np.min([f["psnr_db"] for f in fr])), "mean_kbps": float(res.summary["mean_kbps"])})
        self.table("probes_gi_lag.csv", self.lag_rows)
        # 4. many clients
        self.mc_rows = []
        for n in ((1, 2, 4) if quick else (1, 2, 4, 8)):
            res = _run(renderer, "default", "walk", "lan", 1.0, (160, 90), 0.0, {}, clients=n, cost_model="measured",
                       truth_cache=str(cache))
            ups = res.updates
            relit = [u["shared_ms"] for u in ups if u["client"] == 0 and u["shared_ms"] > 0]
            stream_kbps = [sum(v for k, v in c.items() if k.startswith("kbps_") and k != "kbps_session")
                           for c in res.client_summaries]
            self.mc_rows.append({"clients": n, "relights": len(relit), "shared_ms_per_relight": float(np.mean(relit)) if relit else float("nan"),
                                 "client_ms": float(np.mean([u["server_ms"] for u in ups])), "encode_ms": float(np.mean([u["encode_ms"] for u in ups])),
                                 "server_frames": len(ups) / n, "kbps_per_client": float(np.mean(stream_kbps)),
                                 "session_kbit": float(np.mean([c.get("kbps_session", 0.0) for c in res.client_summaries])),
                                 "mean_psnr_db": float(res.summary["mean_psnr_db"])})
        self.table("probes_clients.csv", self.mc_rows)
        # 6. the lossy-visibility ablation (light leaks)
        self.leak = leak_ablation(renderer, size)
        self.table("probes_leak_ablation.csv", self.leak)

    def charts(self) -> None:
        plt, light, move, size, mc_rows = self.pyplot(), self.light, self.move, self.size, self.mc_rows
        series = self.series
        fig, axes = plt.subplots(1, 2, figsize=(13, 3.9))
        ax = axes[0]
        ts = np.array([r["t_s"] for r in light[:-1]])
        for key, lab, sty in (("raw_bits", "uncompressed (R11G11B10 + RG16F)", "k.:"), ("zstd_bits", "zstd -3 of the same textures", "s--"),
                              ("color_bits", "colour, lossless HEVC", "o-"), ("vis_bits", "visibility, lossless HEVC", "^-"),
                              ("index_bits", "index list", "x-")):
            v = np.array([r[key] for r in light[:-1]], float) / 1e3
            ax.plot(ts, np.where(v > 0, v, np.nan), sty, ms=3, label=lab)
        kf = light[-1]
        ax.plot([kf["t_s"] + 0.05], [kf["bits"] / 1e3], "r*", ms=10, label=f"full refresh ({kf['ratio']:.2f}x)")
        for a, b in ((4.0, 5.0), (6.0, 6.2)):
            ax.axvspan(a, b, color="gold", alpha=0.2)
        ax.set_yscale("log")
        ax.set_xlabel("scene time (s); shaded: sun dims, lamp switches on")
        ax.set_ylabel("kbit per update (nothing drawn: nothing sent)")
        ax.set_title("one client, still camera, nothing else moving", fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        ax = axes[1]
        for rows, lab, c in ((light[:-1], "light change, nothing moving", "tab:blue"), (move, "moving objects, lights steady", "tab:red")):
            tt = [r["t_s"] for r in rows]
            ax.plot(tt, [100 * r["sent"] / r["active"] for r in rows], "o-", ms=3, color=c, label=f"sent / active: {lab}")
            ax.plot(tt, [100 * r["visible"] / r["active"] for r in rows], ":", color=c, label="visible / active")
        ax.set_xlabel("scene time (s)")
        ax.set_ylabel("% of the active probes")
        ax.set_title("probes selected per update (paper figure 7: 0.5-35 % kept)", fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        self.figure(fig, "probes_rate.png")

        fig, ax = plt.subplots(figsize=(7.5, 3.6))
        for lab, (tt, ps) in series.items():
            ax.plot(tt, ps, "o-" if "ideal" in lab else "s--", ms=3, label=lab)
        ax.axvspan(6.0, 6.2, color="gold", alpha=0.2)
        ax.set_xlabel("scene time (s); shaded: the lamp switches on")
        ax.set_ylabel("PSNR against the ground truth (dB)")
        ax.set_title(f"GI lag: probe update rate and network ({size[0]}x{size[1]}, still camera)", fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        self.figure(fig, "probes_gi_lag.png")

        fig, axes = plt.subplots(1, 2, figsize=(11, 3.4))
        ns = [r["clients"] for r in mc_rows]
        axes[0].plot(ns, [r["shared_ms_per_relight"] for r in mc_rows], "o-", label="GI relight (shared, per update)")
        axes[0].plot(ns, [r["client_ms"] for r in mc_rows], "s-", label="per session: selection and packing")
        axes[0].plot(ns, [r["encode_ms"] for r in mc_rows], "^-", label="per session: lossless HEVC")
        axes[0].set_ylabel("ms")
        axes[1].plot(ns, [r["kbps_per_client"] / 1e3 for r in mc_rows], "o-", label="per client, all streams but the scene")
        axes[1].set_ylabel("Mbit/s")
        for ax in axes:
            ax.set_xscale("log", base=2)
            ax.set_xticks(ns, [str(n) for n in ns])
            ax.set_xlabel("clients on one server")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        fig.suptitle("many clients: one GI server, per-session selection (default walk, lan, measured costs)", fontsize=9)
        self.figure(fig, "probes_clients.png")


    def text(self) -> str:
        quick, light, move, seg, lag_rows, mc_rows, leak = (self.quick, self.light, self.move, self.seg, self.lag_rows,
                                                            self.mc_rows, self.leak)
        # 5. savings and the uncompressed rate
        gb_c, gb_v = guard_band_savings()
        active = np.array([r["active"] for r in light])
        n_probes = int(np.prod(get_scene("default").gi_probes))
        inactive = 1.0 - float(active.mean()) / n_probes
        raw_mbps = n_probes * (10 * 10 + 18 * 18) * 32 * GI_HZ / 1e6
        segd = {r["segment"]: r for r in seg}
        lagd = {r["setup"]: r for r in lag_rows}

        def sg(name: str, key: str, fmt: str = ".1f") -> str:
            v = segd.get(name, {}).get(key, float("nan"))
            return format(v, fmt)

        removed = [100 * (1 - r["sent"] / r["active"]) for r in light[1:-1] + move[1:]]
        first = dict(light[0], raw_c=light[0]["sent"] * COLOR_BITS_PER_PROBE, raw_v=light[0]["sent"] * VIS_BITS_PER_PROBE)
        text = [
            f"Light probe streaming on the default scene with GI (`default`, {n_probes} probes; {'quick' if quick else 'full'} run, "
            f"{self.cells_s:.0f} s).",
            "",
            f"- **Rate** (one client, still camera, {GI_HZ:g} Hz): with nothing changing no probe, picture or index list "
            f"goes; the sun dimming sends {sg('light change', 'mean_sent', '.0f')} probes an update at "
            f"{sg('light change', 'mean_kbit_per_update')} kbit; the moving objects (their shadows change the probes) "
            f"{sg('moving objects', 'mean_sent', '.0f')} probes at {sg('moving objects', 'mean_kbit_per_update')} kbit.  "
            f"Uncompressed, the whole volume with guard bands is {raw_mbps:.1f} Mbit/s at {GI_HZ:g} Hz (the paper's "
            f"{PAPER_RAW_MBPS:g} Mbit/s for {PAPER_RAW_PROBES} probes scales to "
            f"{PAPER_RAW_MBPS * n_probes / PAPER_RAW_PROBES:.1f}).",
            f"- **Compression ratios** (uncompressed bits of what an update carries over its coded bits; mean / max): "
            f"light change {sg('light change', 'mean_ratio')} / {sg('light change', 'max_ratio')}, moving objects "
            f"{sg('moving objects', 'mean_ratio')} / {sg('moving objects', 'max_ratio')} (both pictures: the objects "
            f"are redrawn into the probes' view, so their distances change too); I-frames: the first update "
            f"{sg('first update', 'mean_ratio', '.2f')}x and a full refresh {sg('keyframe request', 'mean_ratio', '.2f')}x, "
            f"colour {first['raw_c'] / max(first['color_bits'], 1):.2f}x and visibility "
            f"{first['raw_v'] / max(first['vis_bits'], 1):.2f}x (paper table 2: I-frames 1.1-2x, ratios rising with "
            f"stillness; our still segments send nothing at all, as our probes have no random ray rotation).  zstd of the "
            f"same textures takes {sg('light change', 'zstd_over_hevc', '.2f')}x the HEVC bits during the light change but "
            f"{sg('first update', 'zstd_over_hevc', '.2f')}x on the first update: lossless HEVC predicts the float16 "
            "bytes of the distance moments worse than zstd matches their repeats (a quarter of the texels see the "
            "volume's far distance).",
            f"- **Selection**: {np.min(removed):.0f}-{np.max(removed):.0f} % of the active probes removed per update after "
            f"the first (paper figure 7: 65-99.5 %); the 360-degree view keeps "
            f"{100 * np.mean([r['visible'] / r['active'] for r in light]):.0f} % of them: {n_probes} probes span the one "
            "room the camera stands in, where the paper's thousands span scenes most of which a view does not reach.",
            "- **GI lag** through the lamp switching on (mean / lowest PSNR from its first change): " + "; ".join(
                f"{k} {v['mean_psnr_db']:.2f} / {v['min_psnr_db']:.2f} dB" for k, v in lagd.items()) +
            ".  The update rate matters little here: the lamp's direct light, which the client draws from each frame's "
            "light state, dominates the error; its bounce is a small share of the image.",
            "- **Many clients** (one server, measured): " + "; ".join(
                f"{r['clients']}: relight {r['shared_ms_per_relight']:.0f} ms shared, {r['client_ms']:.0f} + "
                f"{r['encode_ms']:.0f} ms a session, {r['kbps_per_client'] / 1e3:.2f} Mbit/s each" for r in mc_rows) +
            ".  The relight is paid once per update whatever the number of clients; each session pays its own "
            "360-degree visibility and coding.",
            f"- **Savings**: dropping the guard bands saves {100 * gb_c:.0f} % of the colour and {100 * gb_v:.0f} % of the "
            f"visibility texels; {100 * inactive:.0f} % of the probes are inactive (inside geometry) and never sent "
            "(paper: -36 % / -21 % / -25 %; the default scene's walls and pillars are thin beside the 2 m probe spacing).",
        ]
        ex, lo = leak
        text.append(f"- **Lossy visibility** (ablation, `vis_lossy`; inside the closed `shed+gi`, one update): lossless "
                    f"{ex['psnr_db']:.1f} dB against the truth with {ex['vis_kbit']:.0f} kbit of visibility; lossy HEVC at crf "
                    f"23 {lo['psnr_db']:.1f} dB with {lo['vis_kbit']:.0f} kbit, the inside {100 * (lo['brightness_over_truth'] - 1):.0f} % "
                    "brighter than the truth: damaged distance moments let the sunlit outside leak through the walls.  On "
                    "the default scene, one room with no such walls, the visibility term hardly shows: the walk's views "
                    "lose 0.4 dB without it at all.")
        return "\n".join(text)


def run(out_dir: Path, quick: bool) -> Section:
    """Run the probes study into ``out_dir`` and return its report section."""
    return ProbesStudy(out_dir, quick).run()
