"""``tss``'s live server frame, stage by stage, in one process as a live render worker runs it (issue 49 item 5).

The default scene's walk at 320x180 with the probes relit at the live server's rate (``Renderer.gi_hz``), frames
``--dt`` seconds of scene time apart (0.5: about the live rate), ``OPENBLAS_NUM_THREADS=1`` as the workers have it
(:data:`splitrender.pipeline.processes.WORKER_ENV`).  Per frame after the first two: process CPU milliseconds
(llvmpipe's threads included: on a machine shared with other work the steadier figure) of the whole ``produce`` and
of its stages (the gathering with the probes' update inside it, ``fill_gutters``, the plan and its allocator,
``visible_area``, the live rows, the vertices), and a sha256 over every update's planes, data and metadata, so that
two trees can be shown to make the same bytes.

``--before TREE`` (a checkout of the commit before a change) runs each round on that tree and on this one
alternately, each in a process of its own.  Writes ``benchmarks/results/bench_tss_live.json`` (``--out``).  Run::

    python benchmarks/bench_tss_live.py [--frames 10] [--dt 0.5] [--rounds 3] [--before TREE] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _trees import commit_of, run_cell  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "bench_tss_live.json"
STAGES = (("server", "TssServer.produce", "produce"), ("server", "TssServer._gather", "gather"),
          ("ddgi", "DdgiVolume.update", "gi_update"), ("server", "fill_gutters", "fill_gutters"),
          ("server", "plan_atlas", "plan_atlas"), ("layout", "StableAtlas.place", "place"),
          ("server", "visible_area", "visible_area"), ("server", "TssServer._live_rows", "live_rows"),
          ("server", "TssServer._vertices", "vertices"))
"""(module, attribute, label): the stages timed (``server``, ``layout``: ``splitrender.methods.tss``'s)."""


def cell(frames: int, dt: float) -> dict:
    """This process's tree: the frames' stage CPU milliseconds and the updates' sha256."""
    import hashlib
    import time

    import numpy as np

    import splitrender
    from splitrender.methods import get_method, make_config
    from splitrender.methods.tss import layout, server
    from splitrender.pipeline.direct import server_context
    from splitrender.pipeline.producers import ProducerPool
    from splitrender.render import Renderer, ddgi
    from splitrender.scene.loader import get_scene
    from splitrender.scene.pose import CameraIntrinsics, Pose
    from splitrender.scene.trace import get_trace

    mods = {"server": server, "layout": layout, "ddgi": ddgi}
    acc: dict[str, list[float]] = {}

    def timed(label: str, f):  # type: ignore[no-untyped-def]
        def w(*a, **k):  # type: ignore[no-untyped-def]
            c0 = time.process_time()
            try:
                return f(*a, **k)
            finally:
                acc.setdefault(label, []).append((time.process_time() - c0) * 1e3)
        return w

    for mod, attr, label in STAGES:
        owner = mods[mod]
        parts = attr.split(".")
        for p in parts[:-1]:
            owner = getattr(owner, p)
        setattr(owner, parts[-1], timed(label, getattr(owner, parts[-1])))
    scene = get_scene("default")
    r = Renderer()
    r.gi_hz = 5.0
    intr = CameraIntrinsics(320, 180)
    r.render(scene, 0.0, Pose(), CameraIntrinsics(64, 36), ("color",))
    pool = ProducerPool(scene, 30, r)
    spec = get_method("tss")
    cfg = make_config(spec.config, None)
    half = spec.server_class(cfg, intr, scene, 30, producer=pool.producer(spec, cfg))
    trace = get_trace("walk")
    digest = hashlib.sha256()
    gathered = []
    for k in range(frames):
        if k == 2:
            acc.clear()
        t = 1.0 + k * dt
        shared = pool.prepare("tss", int(round(t * 30)), t)
        upd = half.produce(server_context(scene, r, intr, trace.pose_at(t), t_s=t, frame_id=k, shared=shared))
        for name in sorted(upd.planes):
            digest.update(np.ascontiguousarray(upd.planes[name]).tobytes())
        for name in sorted(upd.data):
            digest.update(name.encode() + upd.data[name])
        for name in sorted(upd.meta):
            v = upd.meta[name]
            digest.update(name.encode() + (repr(v).encode() if isinstance(v, (int, float, str)) else np.asarray(v).tobytes()))
        st = half.stats()
        gathered.append([st["pvs_triangles"], st["gathered_triangles"], st["iframe"]])
    n = max(frames - 2, 1)
    return {"tree": str(Path(splitrender.__file__).resolve().parents[1]), "sha256": digest.hexdigest(),
            "cpu_ms_per_frame": {label: sum(v) / n for label, v in acc.items()},
            "pvs_gathered_iframe": gathered}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--dt", type=float, default=0.5)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--before", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--cell", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.cell is not None:
        arg = json.loads(a.cell)
        print(json.dumps(cell(arg["frames"], arg["dt"])))
        return
    trees = {"before": a.before.resolve(), "after": ROOT} if a.before else {"this": ROOT}
    runs: dict[str, list[dict]] = {k: [] for k in trees}
    for k in range(a.rounds):
        for name, tree in trees.items():
            got = run_cell(tree, __file__, {"frames": a.frames, "dt": a.dt}, f"tss live frames on {tree}")
            got["load1"] = os.getloadavg()[0]
            runs[name].append(got)
            print(name, k, f"load {got['load1']:.1f}", got["sha256"][:16],
                  {s: round(v, 1) for s, v in got["cpu_ms_per_frame"].items()}, flush=True)
    median = {name: {s: statistics.median(r["cpu_ms_per_frame"].get(s, float("nan")) for r in rs)
                     for s in rs[0]["cpu_ms_per_frame"]} for name, rs in runs.items()}
    out = {"benchmark": "bench_tss_live", "trees": {k: commit_of(v) for k, v in trees.items()}, "frames": a.frames,
           "dt": a.dt, "rounds": a.rounds, "same_bytes": len({r["sha256"] for rs in runs.values() for r in rs}) == 1,
           "median_cpu_ms_per_frame": median, "runs": runs}
    if a.before:
        out["ratio_after_over_before"] = {s: median["after"][s] / median["before"][s] for s in median["after"]
                                          if median["before"].get(s)}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=1))
    print("same bytes:", out["same_bytes"], "->", a.out)


if __name__ == "__main__":
    main()
