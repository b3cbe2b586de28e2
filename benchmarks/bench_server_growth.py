"""What each method's server work grows with: pixels, visible content, clients (issue 49, "Done when").

Every method's server in virtual time (``walk``, ``ideal`` network, ``cost_model`` fixed so every tick is served,
no scoring), in four cells that change one thing each against a base:

- ``base``: the default scene without GI (``default+nogi``; ``default`` for ``probes``, which streams the GI), 320x180,
  one client;
- ``pixels``: the same at 640x360 (4x the pixels);
- ``content``: the same at 320x180 on the ``minimal`` scene (a floor and a cube; ``minimal+gi`` for ``probes``): what
  the server does when little is visible;
- ``clients``: four clients ``--offset`` s apart on the base trace.

Per cell, the median over server frames (after the first, which builds the session) of the server tick's process
CPU milliseconds (``time.process_time`` around the runner's tick, so llvmpipe's rasterising threads count; for four
clients the tick serves all four), the ground truth's CPU milliseconds for the same client poses (a renderer of its
own, one render per client per tick, so ``server/GT`` compares like with like), and the method's own stage
statistics (the ``srv_*_ms`` the method reports, wall clock, medians: the profile).  The cells of a method run
alternately ``--rounds`` times in one process, so they share the machine's load.

The growth ratios (``pixels``: server CPU at 640x360 over 320x180; ``content``: base over minimal; ``clients``:
four over one) say what the work follows: about 4 for pixels where it is per pixel, about 4 for clients where
nothing is shared, about 1 where it is not.

Writes ``benchmarks/results/bench_server_growth.json`` (``--out``) and its chart beside it (``.png``).  Run:
``python benchmarks/bench_server_growth.py [--methods video,sas] [--duration 1.0] [--rounds 2] [--offset 0.3]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from splitrender.render.gl import make_current
from splitrender.render.renderer import Renderer
from splitrender.scene.loader import get_scene
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import VirtualTimeRun

RESULTS = Path(__file__).parent / "results"
METHODS = ("video", "atw", "warp", "sas", "tss", "quads", "probes")
CELLS = ("base", "pixels", "content", "clients")


def cell_config(method: str, cell: str, duration_s: float, offset_s: float) -> RunConfig:
    """The run of one cell (see the module's docstring)."""
    gi = method == "probes"
    scene = ("minimal" if cell == "content" else "default") + ("+gi" if gi and cell == "content" else "")
    if not gi and cell != "content":
        scene = "default+nogi"
    w, h = (640, 360) if cell == "pixels" else (320, 180)
    return RunConfig(method=method, scene=scene, trace="walk", network="ideal", width=w, height=h,
                     duration_s=duration_s, client_fps=30, server_fps=30, flip_every=0, metrics=False,
                     clients=4 if cell == "clients" else 1, client_offset_s=offset_s)


class TickClock:
    """The runner's server tick timed in process CPU (ms, per frame id), installed once."""

    def __init__(self) -> None:
        self.ticks: dict[int, float] = {}
        tick0 = VirtualTimeRun._server_tick
        clock = self

        def _server_tick(run: VirtualTimeRun, f: int, *a: Any) -> None:
            c = time.process_time()
            tick0(run, f, *a)
            clock.ticks[f] = (time.process_time() - c) * 1e3

        VirtualTimeRun._server_tick = _server_tick  # type: ignore[method-assign,assignment]


def ground_truth_ms(cfg: RunConfig, run: VirtualTimeRun, r_gt: Renderer, frames: list[int]) -> list[float]:
    """Process CPU ms of the ground truth at each server frame's time, one render per client (a renderer of its own:
    its GI, where the scene has it, relit as the server's is)."""
    scene = get_scene(cfg.scene)
    make_current(r_gt.ctx)
    out = []
    for f in frames:
        t = f / cfg.server_fps
        c = time.process_time()
        for cl in run.clients:
            img = r_gt.render(scene, t, cl.trace.pose_at(t), run.intr).color
        out.append((time.process_time() - c) * 1e3)
        del img
    return out


def measure(methods: list[str], duration_s: float, rounds: int, offset_s: float) -> dict[str, Any]:
    clock = TickClock()
    r, r_gt = Renderer(), Renderer()
    out: dict[str, Any] = {}
    for method in methods:
        per: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
        loads: list[float] = []
        VirtualTimeRun(cell_config(method, "base", 0.1, offset_s), r).run()   # shaders and caches
        for rnd in range(rounds):
            for cell in CELLS:
                cfg = cell_config(method, cell, duration_s, offset_s)
                clock.ticks.clear()
                run = VirtualTimeRun(cfg, r)
                res = run.run()
                frames = sorted(f for f in clock.ticks if f >= 1)
                gt = ground_truth_ms(cfg, run, r_gt, frames)
                make_current(r.ctx)
                per[cell]["server_cpu_ms"] += [clock.ticks[f] for f in frames]
                per[cell]["gt_cpu_ms"] += gt
                for u in res.updates:
                    if u.get("frame_id", 0) >= 1:
                        for k, v in u.items():
                            if (k.startswith("srv_") and k.endswith("_ms") or k in ("server_ms", "encode_ms",
                                                                                    "shared_ms")) and v == v:
                                per[cell][k].append(float(v))
                loads.append(os.getloadavg()[0])
                print(f"{method} round {rnd} {cell}: {len(frames)} frames, server CPU "
                      f"{np.median(per[cell]['server_cpu_ms'][-len(frames):]):.0f} ms, GT "
                      f"{np.median(gt):.0f} ms, load {loads[-1]:.1f}", flush=True)
        cells = {}
        for cell in CELLS:
            m = {k: float(np.median(v)) for k, v in per[cell].items() if v}
            m["server_over_gt"] = m["server_cpu_ms"] / m["gt_cpu_ms"]
            m["frames"] = len(per[cell]["server_cpu_ms"])
            cells[cell] = m
        base = cells["base"]["server_cpu_ms"]
        out[method] = {
            "cells": cells, "load": loads,
            "growth": {"pixels": cells["pixels"]["server_cpu_ms"] / base,
                       "content": base / cells["content"]["server_cpu_ms"],
                       "clients": cells["clients"]["server_cpu_ms"] / base},
            "gt_growth": {"pixels": cells["pixels"]["gt_cpu_ms"] / cells["base"]["gt_cpu_ms"],
                          "content": cells["base"]["gt_cpu_ms"] / cells["content"]["gt_cpu_ms"],
                          "clients": cells["clients"]["gt_cpu_ms"] / cells["base"]["gt_cpu_ms"]},
        }
    return out


def chart(doc: dict[str, Any], path: Path) -> Path:
    """Two panels: each method's server CPU over the ground truth's in every cell, and its growth factors (pixels x4,
    content: default over minimal, clients x4) beside the ground truth's own."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from splitrender.experiments.studies._util import save_figure

    methods = list(doc["methods"])
    x = np.arange(len(methods))
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8))
    wd = 0.2
    for k, cell in enumerate(CELLS):
        a.bar(x + (k - 1.5) * wd, [doc["methods"][m]["cells"][cell]["server_over_gt"] for m in methods], wd, label=cell)
    a.axhline(1.0, color="k", lw=0.8)
    a.set_yscale("log")
    a.set_xticks(x, methods)
    a.set_ylabel("server CPU / ground truth CPU")
    a.set_title("server over the ground truth, per cell")
    a.legend(fontsize=8)
    wd = 0.27
    for k, axis in enumerate(("pixels", "content", "clients")):
        b.bar(x + (k - 1) * wd, [doc["methods"][m]["growth"][axis] for m in methods], wd, label=axis)
        b.scatter(x + (k - 1) * wd, [doc["methods"][m]["gt_growth"][axis] for m in methods], marker="_", s=120,
                  color="k", zorder=3, label="ground truth" if k == 0 else None)
    b.axhline(4.0, color="grey", lw=0.6, ls=":")
    b.axhline(1.0, color="k", lw=0.8)
    b.set_yscale("log")
    b.set_xticks(x, methods)
    b.set_ylabel("server CPU, growth factor")
    b.set_title("x4 pixels, default over minimal scene, x4 clients")
    b.legend(fontsize=8)
    fig.suptitle(f"What server work grows with ({doc['rev'][:7]}, {doc['duration_s']:g} s walk, "
                 f"{doc['rounds']} rounds)", fontsize=10)
    return save_figure(fig, path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--duration", type=float, default=1.0, help="seconds of the walk per run")
    ap.add_argument("--rounds", type=int, default=2, help="the four cells of a method alternated this many times")
    ap.add_argument("--offset", type=float, default=0.3, help="seconds between the four clients on the trace")
    ap.add_argument("--out", default=str(RESULTS / "bench_server_growth.json"))
    ap.add_argument("--plot", action="store_true", help="only draw the chart (beside --out) from --out's JSON")
    a = ap.parse_args()
    if a.plot:
        print(f"wrote {chart(json.loads(Path(a.out).read_text()), Path(a.out).with_suffix('.png'))}")
        return
    t0 = time.perf_counter()
    git = Path(__file__).parent
    rev = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=git).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", "../splitrender"],
                           capture_output=True, text=True, cwd=git).stdout.split("\n")
    rows = measure([m for m in a.methods.split(",") if m], a.duration, a.rounds, a.offset)
    doc = {"benchmark": "bench_server_growth", "rev": rev, "uncommitted": [d[3:] for d in dirty if d.strip()], "machine": platform.platform(), "cpus": os.cpu_count(),
           "duration_s": a.duration, "rounds": a.rounds, "offset_s": a.offset, "cells": list(CELLS),
           "wall_s": time.perf_counter() - t0, "methods": rows}
    Path(a.out).write_text(json.dumps(doc, indent=1))
    chart(doc, Path(a.out).with_suffix(".png"))
    print(f"{'method':8} {'server/GT':>9} {'x pixels':>9} {'x content':>9} {'x clients':>9}   (GT: pixels, clients)")
    for m, v in rows.items():
        g, gg = v["growth"], v["gt_growth"]
        print(f"{m:8} {v['cells']['base']['server_over_gt']:9.2f} {g['pixels']:9.2f} {g['content']:9.2f} "
              f"{g['clients']:9.2f}   ({gg['pixels']:.2f}, {gg['clients']:.2f})")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
