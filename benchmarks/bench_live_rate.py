"""Live server updates per second and per-stage milliseconds, every method, probes relit every frame against the
server's own GI rate; or this tree against the tree before a change, alternately.

Each method runs as a real live session on loopback (``splitrender.experiments.live_rate``: the server and its
render worker here, ``splitrender client`` as a separate process), default scene with GI, 320x180, client display
30 Hz.  The baseline, measured in the same run, relights the DDGI probes for every frame (``gi_hz = 0``, as the
virtual-time runner and the ground truth do); the candidate relights them at the live server's default rate
(``ServerConfig.gi_hz``).  The JSON holds both rows per method and their ratio of updates per second.  Nothing here
needs a GPU, and nothing here is tuned to llvmpipe: on a machine with one (EGL on NVIDIA) the same command measures
the same stages.

``--before TREE`` (a checkout of the commit before a change: ``git worktree add --detach /tmp/before REV``) runs
every session in a child process on that tree and on this one, alternately (before, this, before, this, ... for
``--repeat`` rounds), at the server's GI rate only (``--variants`` to change that), so that a loaded machine weighs
on both alike (both measured by this tree's ``live_rate``); ``bench_live_rate_before_after.json`` then holds each
method's median updates a second, render-worker CPU milliseconds per update and stage milliseconds per tree, and
their ratios (this tree over the one before).  Absolute rates need an idle machine; on a busy one the worker's CPU
per update is the steadier figure.

    python benchmarks/bench_live_rate.py [--seconds 8] [--methods video,atw] [--size 320x180] [--repeat 3]
                                         [--before TREE] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _trees import commit_of, run_in_tree  # noqa: E402  (beside this script)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "bench_live_rate.json"
RESULTS_BEFORE_AFTER = ROOT / "benchmarks" / "results" / "bench_live_rate_before_after.json"
VARIANTS = ("baseline_gi_every_frame", "server_gi_rate")
"""Row labels: probes relit every frame (``gi_hz`` 0), and at the server's rate (``--gi-hz``)."""
FIGURES = ("updates_per_s", "worker_cpu_ms_per_update", "gi_ms", "method_ms", "encode_ms", "worker_rtt_ms", "send_ms", "wait_ms",
           "client_displayed_per_s")

CHILD = r"""
import json, sys
a = json.loads(sys.argv[1])
ns = {"__name__": "live_rate_instrument"}     # this tree's instrument on the tree under test's server
exec(compile(open(a["instrument"]).read(), a["instrument"], "exec"), ns)
measure = ns["measure"]
r = measure(a["method"], seconds=a["seconds"], scene=a["scene"], width=a["width"], height=a["height"], gi_hz=a["gi_hz"])
print("RESULT " + json.dumps(r, default=str))
"""


def _line(m: str, label: str, r: dict) -> str:
    return (f"{m:7s} {label:28s} {r['updates_per_s']:5.1f} updates/s (target {r.get('target_ups', float('nan')):g}), "
            f"gi {r['gi_ms']:5.1f} ms, method {r['method_ms']:6.1f} ms, encode {r['encode_ms']:5.1f} ms, "
            f"client shown {r['client_displayed_per_s']:4.1f}/s, worker CPU {r.get('worker_cpu_ms_per_update', math.nan):6.1f} "
            f"ms/update, load {r.get('load1', math.nan):4.1f}")


def _median(rows: list[dict], key: str) -> float:
    v = [float(r[key]) for r in rows if r.get(key) is not None and math.isfinite(float(r[key]))]
    return statistics.median(v) if v else math.nan


def main() -> None:
    from splitrender.experiments.studies.live import target_ups
    from splitrender.methods import methods_for_scene
    from splitrender.server.server import DEFAULT_GI_HZ

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--methods", default=None, help="comma-separated (default: every method the scene allows)")
    ap.add_argument("--scene", default="default")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--gi-hz", type=float, default=DEFAULT_GI_HZ, help="the candidate's GI rate")
    ap.add_argument("--repeat", type=int, default=1, help="sessions per method, tree and variant")
    ap.add_argument("--before", type=Path, default=None,
                    help="a checkout of the commit before a change: run it and this tree alternately")
    ap.add_argument("--variants", default=None,
                    help=f"comma-separated of {','.join(VARIANTS)} (default: both; with --before: server_gi_rate)")
    ap.add_argument("--out", type=Path, default=None,
                    help=f"default {RESULTS.name}; with --before {RESULTS_BEFORE_AFTER.name} (in {RESULTS.parent})")
    a = ap.parse_args()
    a.out = a.out or (RESULTS_BEFORE_AFTER if a.before else RESULTS)
    w, h = (int(x) for x in a.size.split("x"))
    methods = a.methods.split(",") if a.methods else methods_for_scene(a.scene)
    variants = a.variants.split(",") if a.variants else (["server_gi_rate"] if a.before else list(VARIANTS))
    bad = [v for v in variants if v not in VARIANTS]
    if bad or a.repeat < 1:
        raise SystemExit(f"--variants: unknown {bad} (known: {list(VARIANTS)})" if bad else "--repeat: must be >= 1")
    if a.before is not None and not (a.before / "splitrender").is_dir():
        raise SystemExit(f"--before: {a.before} holds no splitrender package")
    trees = {"before": a.before.resolve(), "after": ROOT} if a.before else {"this": None}
    gi = {"baseline_gi_every_frame": 0.0, "server_gi_rate": a.gi_hz}

    def one(tree: Path | None, m: str, gi_hz: float) -> dict:
        if tree is None:
            from splitrender.experiments.live_rate import measure

            return measure(m, seconds=a.seconds, scene=a.scene, width=w, height=h, gi_hz=gi_hz)
        arg = {"method": m, "seconds": a.seconds, "scene": a.scene, "width": w, "height": h, "gi_hz": gi_hz,
               "instrument": str(ROOT / "splitrender" / "experiments" / "live_rate.py")}
        return run_in_tree(tree, CHILD, arg, f"{m} live session")

    rows: list[dict] = []
    t0 = time.perf_counter()
    for m in methods:
        for label in variants:
            for k in range(a.repeat):
                for tname, tree in trees.items():
                    r = one(tree, m, gi[label])
                    r.update(variant=label, tree=tname, round=k, target_ups=target_ups(m), load1=os.getloadavg()[0])
                    rows.append(r)
                    print(_line(m, f"{label} {tname} #{k}", r), flush=True)
    summary: dict[str, dict] = {}
    for m in methods:
        for label in variants:
            cell: dict[str, dict] = {}
            for tname in trees:
                sel = [r for r in rows if r["method"] == m and r["variant"] == label and r["tree"] == tname]
                cell[tname] = {f: _median(sel, f) for f in FIGURES}
                cell[tname]["updates_per_s_runs"] = [r["updates_per_s"] for r in sel]
            summary.setdefault(m, {})[label] = cell
    ratios: dict[str, float] = {}
    if a.before:
        for m in methods:
            for label in variants:
                c = summary[m][label]
                b, af = c["before"]["updates_per_s"], c["after"]["updates_per_s"]
                ratios[f"{m} {label}"] = af / b if b else math.nan
                cb, ca = c["before"]["worker_cpu_ms_per_update"], c["after"]["worker_cpu_ms_per_update"]
                ratios[f"{m} {label} worker CPU per update"] = ca / cb if cb else math.nan
    elif len(variants) == 2:
        for m in methods:
            b = summary[m]["baseline_gi_every_frame"]["this"]["updates_per_s"]
            c = summary[m]["server_gi_rate"]["this"]["updates_per_s"]
            ratios[m] = c / b if b else math.nan
    from splitrender.render.gl import get_context

    gl = get_context().info.get("GL_RENDERER")        # what the render workers get too (same EGL device)
    out = {"benchmark": "bench_live_rate",
           "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "renderer": gl},
           "trees": {k: (commit_of(v) if v is not None else commit_of(ROOT)) for k, v in trees.items()},
           "scene": a.scene, "size": a.size, "seconds": a.seconds, "gi_hz": a.gi_hz, "repeat": a.repeat,
           "wall_s": time.perf_counter() - t0,
           ("updates_per_s_ratio_after_over_before" if a.before else "updates_per_s_ratio_gi_rate_over_every_frame"):
               ratios, "median": summary, "rows": rows}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=1, default=str))
    print(json.dumps(ratios, indent=1))
    print(f"-> {a.out}")


if __name__ == "__main__":
    main()
