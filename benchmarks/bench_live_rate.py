"""Live server updates per second and per-stage milliseconds, every method, probes relit every frame against the
server's own GI rate.

Each method runs as a real live session on loopback (``splitrender.experiments.live_rate``: the server and its
render worker here, ``splitrender client`` as a separate process), default scene with GI, 320x180, client display
30 Hz.  The baseline, measured in the same run, relights the DDGI probes for every frame (``gi_hz = 0``, as the
virtual-time runner and the ground truth do); the candidate relights them at the live server's default rate
(``ServerConfig.gi_hz``).  The JSON holds both rows per method and their ratio of updates per second.  Nothing here
needs a GPU, and nothing here is tuned to llvmpipe: on a machine with one (EGL on NVIDIA) the same command measures
the same stages.

    python benchmarks/bench_live_rate.py [--seconds 8] [--methods video,atw] [--size 320x180] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

from splitrender.experiments.live_rate import measure
from splitrender.experiments.studies.live import target_ups
from splitrender.methods import methods_for_scene
from splitrender.server.server import DEFAULT_GI_HZ

RESULTS = Path(__file__).parent / "results" / "bench_live_rate.json"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--methods", default=None, help="comma-separated (default: every method the scene allows)")
    ap.add_argument("--scene", default="default")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--gi-hz", type=float, default=DEFAULT_GI_HZ, help="the candidate's GI rate")
    ap.add_argument("--out", type=Path, default=RESULTS)
    a = ap.parse_args()
    w, h = (int(x) for x in a.size.split("x"))
    methods = a.methods.split(",") if a.methods else methods_for_scene(a.scene)
    rows, ratios = [], {}
    t0 = time.perf_counter()
    for m in methods:
        pair = {}
        for label, gi_hz in (("baseline_gi_every_frame", 0.0), ("server_gi_rate", a.gi_hz)):
            r = measure(m, seconds=a.seconds, scene=a.scene, width=w, height=h, gi_hz=gi_hz)
            r["variant"] = label
            r["target_ups"] = target_ups(m)
            rows.append(r)
            pair[label] = r
            print(f"{m:7s} {label:24s} {r['updates_per_s']:5.1f} updates/s (target {r['target_ups']:g}), "
                  f"gi {r['gi_ms']:5.1f} ms, method {r['method_ms']:6.1f} ms, encode {r['encode_ms']:5.1f} ms, "
                  f"client shown {r['client_displayed_per_s']:4.1f}/s", flush=True)
        b, c = pair["baseline_gi_every_frame"]["updates_per_s"], pair["server_gi_rate"]["updates_per_s"]
        ratios[m] = c / b if b else float("nan")
    from splitrender.render.gl import get_context

    gl = get_context().info.get("GL_RENDERER")        # what the render workers get too (same EGL device)
    out = {"benchmark": "bench_live_rate", "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "renderer": gl},
           "scene": a.scene, "size": a.size, "seconds": a.seconds, "gi_hz": a.gi_hz, "wall_s": time.perf_counter() - t0,
           "updates_per_s_ratio_gi_rate_over_every_frame": ratios, "rows": rows}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=1, default=str))
    print(json.dumps(ratios, indent=1))
    print(f"-> {a.out}")


if __name__ == "__main__":
    main()
