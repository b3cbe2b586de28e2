"""Shared versus per-client server work for 1, 2, 4 and 8 clients on ``sas``.

One server in virtual time runs ``sas`` for N clients (walk traces offset by 0.25 s,
``lan``), with the scene producer shared: patches and the patch-id pass built once,
each frame's object transforms once.  Measured in the same run, the baseline is what
N independent sessions would pay for the same scene work: N patch builds and N
per-frame producer passes.  Reported as ratios (shared / unshared) and per-client
server milliseconds relative to one client's.

Writes ``benchmarks/results/bench_multiclient.json``.  Run: ``python benchmarks/bench_multiclient.py``.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from splitrender.methods.sas.server import SasProducer
from splitrender.render.renderer import Renderer
from splitrender.scene.loader import get_scene
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import VirtualTimeRun

RESULTS = Path(__file__).parent / "results" / "bench_multiclient.json"
CLIENTS = (1, 2, 4, 8)


def main() -> None:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=1.0, help="seconds of each run (default 1)")
    ap.add_argument("--size", default="320x180", help="display size WxH (default 320x180)")
    ap.add_argument("--scene", default="default")
    ns = ap.parse_args()
    w, h = (int(v) for v in ns.size.split("x"))
    r = Renderer()
    base = RunConfig(method="sas", scene=ns.scene, trace="walk", network="lan", width=w, height=h, duration_s=ns.duration,
                     client_fps=30, flip_every=0, metrics=False, client_offset_s=0.1)
    VirtualTimeRun(base.replace(duration_s=0.1), r).run()  # warm up shaders and caches
    scene = get_scene(ns.scene)
    rows = []
    for n in CLIENTS:
        vt = VirtualTimeRun(base.replace(clients=n), r)
        w0 = time.perf_counter()
        res = vt.run()
        wall = time.perf_counter() - w0
        frames = vt.pool.frames_prepared["sas"]
        build_ms = vt.pool.build_ms["sas"] + vt.pool._producers["sas"].patch_build_ms  # type: ignore[attr-defined]
        shared_ms = float(np.mean([u["shared_ms"] for u in res.updates if u["client"] == 0]))
        # median over frames after each client's first (which pays its GL set-up)
        per_client_ms = float(np.median([u["server_ms"] for u in res.updates if u["frame_id"] > 0]))
        # baseline, same run: every client building and preparing the scene itself
        t0 = time.perf_counter()
        p = SasProducer(vt.mcfg, scene, base.server_fps)
        p.patches_for(vt.intr)
        one_build = (time.perf_counter() - t0) * 1000
        t0 = time.perf_counter()
        for f in range(frames):
            p.prepare(f, f / base.server_fps)
        one_prepare = (time.perf_counter() - t0) * 1000 / frames
        shared_total = build_ms + frames * shared_ms
        unshared_total = n * (one_build + frames * one_prepare)
        rows.append({"clients": n, "server_frames": frames, "producer_build_ms": build_ms, "shared_ms_per_frame": shared_ms,
                     "per_client_server_ms_per_frame": per_client_ms, "wall_s": wall,
                     "unshared_scene_work_ms": unshared_total, "shared_scene_work_ms": shared_total,
                     "scene_work_ratio_shared_over_unshared": shared_total / unshared_total,
                     "psnr_db_client0": res.client_summaries[0]["mean_psnr_db"] if res.client_summaries else None})
        print(f"{n} clients: scene work shared/unshared {shared_total / unshared_total:.3f} "
              f"({shared_total:.0f} vs {unshared_total:.0f} ms), "
              f"per-client server {per_client_ms:.1f} ms/frame, producer build {build_ms:.0f} ms")
    one = rows[0]["per_client_server_ms_per_frame"]
    for row in rows:
        row["per_client_ms_over_one_client"] = row["per_client_server_ms_per_frame"] / one
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"machine": platform.platform(), "cpus": os.cpu_count(), "load": os.getloadavg(),
                                   "config": base.to_dict(), "rows": rows}, indent=2, default=str))
    print(f"-> {RESULTS}")


if __name__ == "__main__":
    main()
