"""One against four ``tss`` or ``quads`` clients on one server: what grows with clients and what is shared (issue 49, item 2).

The measurement of :mod:`bench_sas_clients` for the other two methods whose server work is per client: one
virtual-time run per client count (``walk``, client ``i`` starting ``i * offset`` s into it, ``ideal`` network,
320x180, no scoring), the counts alternated ``--rounds`` times in this one process (1, 4, 1, 4, ...), so both see
the same load on a shared machine.  Per server frame (frames after the first, whose set-up is reported apart):

- the whole server tick, wall (``perf_counter``) and process CPU (``process_time``, so llvmpipe's rasterising
  threads count);
- per stage, process CPU summed over the sessions: ``shared`` (the scene producer's ``prepare``, once a frame for
  every session: ``tss``'s object transforms; ``quads`` has no producer), the method's own stages (below), ``meta``
  (the rest of ``produce``: tables, geometry, wire sets), ``encode`` (each session's video and data encoders),
  ``other`` (the tick less all of those: the runner's and the core's bookkeeping).

The method's stages are its ``*_ms`` statistics (``tss``: ``pvs``, ``layout``, ``shade``; ``quads``: ``gbuffer``,
``quadgen``, ``merge``, ``edp``, ``mask``, ``pack_atlas``, ``pack``), taken in process CPU: while measuring, the
method's modules see a ``time`` whose ``perf_counter`` is ``process_time`` (those clocks only time stages there; the
run's ``cost_model`` is ``fixed``, so no decision reads them).

Reported per scene: the medians over the frames of all rounds, each count's ratio to one client's (``cpu``,
``wall``), and the ratio round by round (each four-client run over the one-client run before it).

Writes ``benchmarks/results/bench_clients_<method>.json``.  Run:
``python benchmarks/bench_clients.py --method tss [--scenes default,engine] [--rounds 2] [--duration 0.5]``.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from bench_sas_clients import SCENES   # the same scenes as the sas benchmark
from splitrender.pipeline.sender import StreamEncoder
from splitrender.render.renderer import Renderer
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import VirtualTimeRun

RESULTS = Path(__file__).parent / "results"
METHODS: dict[str, dict[str, Any]] = {
    "tss": {"server": ("splitrender.methods.tss.server", "TssServer"),
            "producer": ("splitrender.methods.tss.server", "TssProducer"),
            "clocks": ("splitrender.methods.tss.server",),
            "stages": ("pvs", "layout", "shade")},
    "quads": {"server": ("splitrender.methods.quads.server", "QuadsServer"),
              "producer": None,
              "clocks": ("splitrender.methods.quads.server", "splitrender.methods.quads.gen"),
              "stages": ("gbuffer", "quadgen", "merge", "edp", "mask", "pack_atlas", "pack")},
}


class _CpuClock:
    """Stands in for the ``time`` module of a method's module: ``perf_counter`` is the process time, so the stage
    statistics it times are CPU milliseconds."""

    def perf_counter(self) -> float:
        return time.process_time()

    def __getattr__(self, name: str) -> Any:
        return getattr(time, name)


class Recorder:
    """Wall and CPU milliseconds of the tick, and CPU milliseconds of every stage, per server frame and session."""

    def __init__(self, method: str) -> None:
        self.spec = METHODS[method]
        self.stages = ("shared", *self.spec["stages"], "meta", "encode", "other")
        self.reset()

    def reset(self) -> None:
        self.tick: dict[int, tuple[float, float]] = {}
        self.shared: dict[int, float] = {}
        self.stage: dict[tuple[int, int], dict[str, float]] = {}
        self.encode: dict[tuple[int, int], float] = {}
        self.setup: list[tuple[float, float]] = []

    def install(self) -> None:
        rec, spec = self, self.spec
        for mod in spec["clocks"]:
            importlib.import_module(mod).time = _CpuClock()  # type: ignore[attr-defined]
        server_cls = getattr(importlib.import_module(spec["server"][0]), spec["server"][1])
        tick0, produce0, encode0, setup0 = (VirtualTimeRun._server_tick, server_cls.produce, StreamEncoder.encode,
                                            VirtualTimeRun._setup)

        def _server_tick(self: VirtualTimeRun, f: int, *a: Any) -> None:
            w, c = time.perf_counter(), time.process_time()
            tick0(self, f, *a)
            rec.tick[f] = ((time.perf_counter() - w) * 1e3, (time.process_time() - c) * 1e3)

        def produce(self: Any, ctx: Any) -> Any:
            c = time.process_time()
            upd = produce0(self, ctx)
            c = (time.process_time() - c) * 1e3
            st = self.stats()
            row = {k: float(st.get(f"{k}_ms", 0.0)) for k in spec["stages"]}
            row["meta"] = c - sum(row.values())
            rec.stage[(ctx.client, ctx.frame_id)] = row
            return upd

        def encode(self: StreamEncoder, upd: Any, *a: Any, **kw: Any) -> Any:   # each session's encoders, in order
            c = time.process_time()
            out = encode0(self, upd, *a, **kw)
            key = (len([k for k in rec.encode if k[1] == upd.frame_id]), upd.frame_id)
            rec.encode[key] = (time.process_time() - c) * 1e3
            return out

        def _setup(self: VirtualTimeRun, *a: Any) -> Any:
            w, c = time.perf_counter(), time.process_time()
            out = setup0(self, *a)
            rec.setup.append(((time.perf_counter() - w) * 1e3, (time.process_time() - c) * 1e3))
            return out

        VirtualTimeRun._server_tick = _server_tick  # type: ignore[method-assign,assignment]
        server_cls.produce = produce
        StreamEncoder.encode = encode  # type: ignore[method-assign,assignment]
        VirtualTimeRun._setup = _setup  # type: ignore[method-assign,assignment]
        if spec["producer"] is not None:
            prod_cls = getattr(importlib.import_module(spec["producer"][0]), spec["producer"][1])
            prepare0 = prod_cls.prepare

            def prepare(self: Any, frame_id: int, t_s: float) -> Any:
                c = time.process_time()
                out = prepare0(self, frame_id, t_s)
                rec.shared[frame_id] = (time.process_time() - c) * 1e3
                return out

            prod_cls.prepare = prepare

    def frames(self, n: int) -> list[dict[str, float]]:
        """Per server frame >= 1 (every session served): each stage's CPU summed over the ``n`` sessions, and the
        tick's wall and CPU (ms)."""
        out = []
        for f in sorted(f for f in self.tick if f >= 1):
            if not all((c, f) in self.stage and (c, f) in self.encode for c in range(n)):
                continue
            rows = [self.stage[(c, f)] for c in range(n)]
            v = {"shared": self.shared.get(f, 0.0),
                 **{k: sum(r[k] for r in rows) for k in (*self.spec["stages"], "meta")},
                 "encode": sum(self.encode[(c, f)] for c in range(n))}
            v["other"] = self.tick[f][1] - sum(v.values())
            v["tick"], v["tick_wall"] = self.tick[f][1], self.tick[f][0]
            out.append(v)
        return out


def measure(method: str, names: list[str], counts: list[int], rounds: int, duration_s: float,
            size: tuple[int, int], offset_s: float) -> dict[str, Any]:
    rec = Recorder(method)
    rec.install()
    r = Renderer()
    out: dict[str, Any] = {}
    for name in names:
        base = RunConfig(method=method, scene=SCENES[name], trace="walk", network="ideal", width=size[0],
                         height=size[1], duration_s=duration_s, client_fps=30, flip_every=0, metrics=False,
                         client_offset_s=offset_s)
        VirtualTimeRun(base.replace(duration_s=0.1), r).run()   # warm up shaders and caches
        per: dict[int, list[list[dict[str, float]]]] = defaultdict(list)
        runs: dict[int, list[dict[str, float]]] = defaultdict(list)
        for rnd in range(rounds):
            for n in counts:
                rec.reset()
                vt = VirtualTimeRun(base.replace(clients=n), r)
                r.probe_states().enabled = False
                w0, c0 = time.perf_counter(), time.process_time()
                vt.run()
                fr = rec.frames(n)
                per[n].append(fr)
                runs[n].append({"run_wall_s": time.perf_counter() - w0, "run_cpu_s": time.process_time() - c0,
                                "frames": len(fr), "load": os.getloadavg()[0],
                                "setup_cpu_ms": float(np.mean([s[1] for s in rec.setup])),
                                "tick_cpu_median": float(np.median([v["tick"] for v in fr]))})
                print(f"{method} {name} round {rnd} {n} clients: {len(fr)} frames, tick CPU median "
                      f"{runs[n][-1]['tick_cpu_median']:.0f} ms, load {runs[n][-1]['load']:.0f}", flush=True)
        rows: dict[str, Any] = {}
        for n in counts:
            allf = [v for fr in per[n] for v in fr]
            rows[str(n)] = {
                "frames": len(allf), "rounds": rounds, "runs": runs[n],
                "cpu": {k: float(np.median([v[k] for v in allf])) for k in (*rec.stages, "tick")},
                "cpu_per_client": {k: float(np.median([v[k] for v in allf])) / n for k in rec.stages},
                "wall": {"tick": float(np.median([v["tick_wall"] for v in allf]))},
            }
        one = rows[str(counts[0])]
        for key, row in rows.items():
            row["ratio_to_one"] = {
                "cpu": {k: row["cpu"][k] / one["cpu"][k] if one["cpu"][k] > 0 else None for k in (*rec.stages, "tick")},
                "wall_tick": row["wall"]["tick"] / one["wall"]["tick"],
                "cpu_tick_by_round": [a["tick_cpu_median"] / b["tick_cpu_median"]
                                      for a, b in zip(runs[int(key)], runs[counts[0]])],
            }
        out[name] = {"scene": SCENES[name], "stages": list(rec.stages), "rows": rows}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", required=True, choices=sorted(METHODS))
    ap.add_argument("--clients", default="1,4", help="client counts, the first the baseline (default 1,4)")
    ap.add_argument("--scenes", default="default,engine", help=f"of {', '.join(SCENES)} (default default,engine)")
    ap.add_argument("--rounds", type=int, default=2, help="times each count runs, alternated (default 2)")
    ap.add_argument("--duration", type=float, default=0.5, help="seconds of each run (default 0.5)")
    ap.add_argument("--offset", type=float, default=0.5,
                    help="seconds between the clients' starts on the trace (default 0.5, as bench_sas_clients)")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--out", type=Path, default=None, help="default benchmarks/results/bench_clients_<method>.json")
    ns = ap.parse_args()
    w, h = (int(v) for v in ns.size.split("x"))
    counts = [int(v) for v in ns.clients.split(",")]
    names = ns.scenes.split(",")
    unknown = [n for n in names if n not in SCENES]
    if unknown:
        ap.error(f"unknown scene(s) {unknown}: choose from {sorted(SCENES)}")
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    scenes = measure(ns.method, names, counts, ns.rounds, ns.duration, (w, h), ns.offset)
    for name, sc in scenes.items():
        for key, row in sc["rows"].items():
            rt = row["ratio_to_one"]
            print(f"{ns.method} {name} {key}/{counts[0]}: tick CPU {rt['cpu']['tick']:.2f}x (rounds "
                  + ", ".join(f"{x:.2f}" for x in rt["cpu_tick_by_round"]) + f"), wall {rt['wall_tick']:.2f}x; "
                  + "per stage CPU ms " + ", ".join(f"{k} {row['cpu'][k]:.1f}" for k in sc["stages"]))
    doc = {"method": ns.method, "machine": platform.platform(), "cpus": os.cpu_count(), "load_before": load0,
           "load_after": os.getloadavg(), "wall_s": time.perf_counter() - t0, "duration_s": ns.duration,
           "client_offset_s": ns.offset, "size": [w, h], "network": "ideal", "trace": "walk", "rounds": ns.rounds,
           "clients": counts, "scenes": scenes}
    out = ns.out or RESULTS / f"bench_clients_{ns.method}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"-> {out}")


if __name__ == "__main__":
    main()
