"""Where ``sas``'s server time goes with 1, 2, 4 and 8 clients on one server (issue 33, item 5).

One virtual-time run per client count (``walk``, client ``i`` starting ``i * offset`` s into
it, ``--offset`` 0.5 s by default; issue 49 spaces them 0.3 s apart, ``ideal`` network, 320x180, no scoring), on two scenes: the 121k-triangle
``2CylinderEngine.glb`` (a fine mesh, 115 still objects) and the default scene without
GI (17k triangles split to 99k, shading-bound, animated objects); ``--scenes gi`` adds the default scene with
its GI (the probes' relight, once a frame for every session, counts in the shading stage of the session that
binds them first).  Per server frame
(frames after the first, whose set-up is reported apart; median over frames):

- the whole server tick, wall (``perf_counter``) and process CPU (``process_time``, so
  llvmpipe's rasterising threads count): the scene producer once, then per session
  ``produce`` and ``encode``, packetizing and bookkeeping;
- per stage, summed over the sessions: ``shared`` (the producer's ``prepare``), ``pvs``
  (patch-id passes and counting), ``alloc`` (levels and allocation), ``shade`` (shading
  and the atlas read-back), ``meta`` (the rest of ``produce``: metadata), ``encode``,
  ``other`` (the tick less all of those);
- each client count's ratio to one client's, all measured in the same invocation
  (``wall``/``cpu``: medians over frames; ``wall_min``/``cpu_min``, the fastest frame,
  less disturbed by other work on a shared machine).

Stage CPU comes from the server half's ``*_cpu_ms`` statistics where it has them, else
from a clock that records the process time at each ``perf_counter`` stamp of
``produce`` (the tree before issue 33 had only wall-clock stages).  Each session's
updates are hashed (atlas bytes and packed metadata, frame by frame) so two trees can
be compared bit for bit.  ``--before-tree DIR`` (a copy of the package before the
change: ``git archive HEAD splitrender | tar -x -C DIR``) measures that tree and this
one alternately, in subprocesses, one scene and client count at a time, so both see
the same load; or ``--label before`` on the old tree and ``--label after`` on the new
one, into the same JSON.  The ``after`` rows report whether their digests equal
``before``'s.  The network is ``ideal``: under jitter a run's updates vary from run to
run (the frame metadata carries the stages' wall-clock times, its size varies, and so
do the TCP segments drawing the link's jitter).

``--solo`` also runs each client of the largest count alone on a server of its own (the same trace offset, scene
times and poses; :func:`solo_run`): the many-client tick over the sum of its clients' ticks alone is what the
sessions share (1: nothing; the plain ratio to one client also counts how much more the other clients' views cost),
and each client's updates are checked to be the bytes it gets alone.

Writes ``benchmarks/results/bench_sas_clients.json``.  Run:
``python benchmarks/bench_sas_clients.py --before-tree DIR [--clients 1,2,4,8] [--duration 0.5] [--offset 0.5]``
(about 17 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

import splitrender.methods.sas.server as sas_server
from splitrender.codecs.meta import pack_meta
from splitrender.methods.sas.server import SasProducer, SasServer
from splitrender.pipeline.sender import StreamEncoder
from splitrender.render.renderer import Renderer
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import VirtualTimeRun, _ShiftedTrace

OUT = Path(__file__).parent / "results" / "bench_sas_clients.json"
ENGINE = "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb"
SCENES = {"engine": ENGINE, "default": "default+nogi", "gi": "default"}
"""``gi``: the default scene with its DDGI probes, relit once a server frame for every session (the renderer's);
not in the default set (``--scenes``)."""
STAGES = ("shared", "pvs", "alloc", "shade", "meta", "encode", "other")


class _StampClock:
    """Stands in for the ``time`` module in :mod:`splitrender.methods.sas.server`: each ``perf_counter`` call
    also notes the process time, so the wall-clock stages of ``produce`` get their CPU time."""

    def __init__(self) -> None:
        self.cpu: list[float] = []

    def perf_counter(self) -> float:
        self.cpu.append(time.process_time())
        return time.perf_counter()

    def __getattr__(self, name: str) -> Any:
        return getattr(time, name)


class Recorder:
    """Wall and CPU milliseconds of every stage, per server frame and session, for one run."""

    def __init__(self) -> None:
        self.clock = _StampClock()
        self.reset()

    def reset(self) -> None:
        self.tick: dict[int, tuple[float, float]] = {}
        self.shared: dict[int, tuple[float, float]] = {}
        self.stage: dict[tuple[int, int], dict[str, float]] = {}
        self.encode: dict[tuple[int, int], tuple[float, float]] = {}
        self.setup: list[tuple[float, float]] = []
        self.digest: dict[int, Any] = defaultdict(hashlib.sha1)
        self.frame = -1
        self.hash_s = (0.0, 0.0)

    def install(self) -> None:
        rec = self
        sas_server.time = rec.clock  # type: ignore[assignment]
        tick0, produce0, encode0 = VirtualTimeRun._server_tick, SasServer.produce, StreamEncoder.encode
        prepare0, setup0 = SasProducer.prepare, VirtualTimeRun._setup

        def _server_tick(self: VirtualTimeRun, f: int, *a: Any) -> None:
            rec.frame, rec.hash_s = f, (0.0, 0.0)
            w, c = time.perf_counter(), time.process_time()
            tick0(self, f, *a)
            w, c = time.perf_counter() - w - rec.hash_s[0], time.process_time() - c - rec.hash_s[1]
            rec.tick[f] = (w * 1e3, c * 1e3)

        def produce(self: SasServer, ctx: Any) -> Any:
            rec.clock.cpu.clear()
            w, c = time.perf_counter(), time.process_time()
            upd = produce0(self, ctx)
            w, c = (time.perf_counter() - w) * 1e3, (time.process_time() - c) * 1e3
            st = self.stats()
            stamps = list(rec.clock.cpu)
            row = {"produce_wall": w, "produce_cpu": c}
            for k in ("pvs", "alloc", "shade"):
                row[f"{k}_wall"] = st[f"{k}_ms"]
            if "pvs_cpu_ms" in st:
                for k in ("pvs", "alloc", "shade"):
                    row[f"{k}_cpu"] = st[f"{k}_cpu_ms"]
            else:   # before issue 33: t0..t3 are the first four perf_counter stamps of produce
                for i, k in enumerate(("pvs", "alloc", "shade")):
                    row[f"{k}_cpu"] = (stamps[i + 1] - stamps[i]) * 1e3
            row["meta_wall"] = w - sum(row[f"{k}_wall"] for k in ("pvs", "alloc", "shade"))
            row["meta_cpu"] = c - sum(row[f"{k}_cpu"] for k in ("pvs", "alloc", "shade"))
            rec.stage[(ctx.client, ctx.frame_id)] = row
            hw, hc = time.perf_counter(), time.process_time()
            h = rec.digest[ctx.client]
            for p in upd.planes.values():
                h.update(np.ascontiguousarray(p).tobytes())
            h.update(pack_meta(upd.meta))
            rec.hash_s = (rec.hash_s[0] + time.perf_counter() - hw, rec.hash_s[1] + time.process_time() - hc)
            return upd

        def encode(self: StreamEncoder, upd: Any, *a: Any, **kw: Any) -> Any:   # each session's encoders (its
            # FrameMaker's, which the runner holds one of per client)
            w, c = time.perf_counter(), time.process_time()
            out = encode0(self, upd, *a, **kw)
            rec.encode[(len([k for k in rec.encode if k[1] == upd.frame_id]), upd.frame_id)] = (
                (time.perf_counter() - w) * 1e3, (time.process_time() - c) * 1e3)
            return out

        def prepare(self: SasProducer, frame_id: int, t_s: float) -> Any:
            w, c = time.perf_counter(), time.process_time()
            out = prepare0(self, frame_id, t_s)
            rec.shared[frame_id] = ((time.perf_counter() - w) * 1e3, (time.process_time() - c) * 1e3)
            return out

        def _setup(self: VirtualTimeRun, *a: Any) -> Any:
            w, c = time.perf_counter(), time.process_time()
            out = setup0(self, *a)
            rec.setup.append(((time.perf_counter() - w) * 1e3, (time.process_time() - c) * 1e3))
            return out

        VirtualTimeRun._server_tick = _server_tick  # type: ignore[method-assign,assignment]
        SasServer.produce = produce  # type: ignore[method-assign,assignment]
        StreamEncoder.encode = encode  # type: ignore[method-assign,assignment]
        SasProducer.prepare = prepare  # type: ignore[method-assign,assignment]
        VirtualTimeRun._setup = _setup  # type: ignore[method-assign,assignment]

    def per_frame(self, n: int) -> dict[str, Any]:
        """Medians over frames >= 1 of each stage summed over the ``n`` sessions, wall and CPU (ms)."""
        frames = sorted(f for f in self.tick if f >= 1)
        out: dict[str, Any] = {}
        for kind, i in (("wall", 0), ("cpu", 1)):
            per: dict[str, list[float]] = defaultdict(list)
            for f in frames:
                rows = [self.stage[(c, f)] for c in range(n)]
                v = {"shared": self.shared.get(f, (0.0, 0.0))[i],
                     **{k: sum(r[f"{k}_{kind}"] for r in rows) for k in ("pvs", "alloc", "shade", "meta")},
                     "encode": sum(self.encode[(c, f)][i] for c in range(n))}
                v["other"] = self.tick[f][i] - sum(v.values())
                v["tick"] = self.tick[f][i]
                for k, x in v.items():
                    per[k].append(x)
            out[kind] = {k: float(np.median(x)) for k, x in per.items()}
            out[f"{kind}_min"] = {k: float(np.min(x)) for k, x in per.items()}   # least disturbed by other work
        f0 = [self.stage[(c, 0)] for c in range(n) if (c, 0) in self.stage]
        out["first_frame_produce_wall_per_client"] = float(np.mean([r["produce_wall"] for r in f0])) if f0 else None
        out["setup_per_client_wall"] = float(np.mean([s[0] for s in self.setup]))
        out["setup_per_client_cpu"] = float(np.mean([s[1] for s in self.setup]))
        out["frames"] = len(frames)
        out["digests"] = [self.digest[c].hexdigest() for c in range(n)]
        return out


def solo_run(base: RunConfig, i: int, r: Renderer) -> VirtualTimeRun:
    """A one-client run of ``base`` whose client sees the trace ``i * client_offset_s`` later: client ``i`` of a
    many-client run, alone on the server (same scene times, same poses)."""
    vt = VirtualTimeRun(base.replace(clients=1), r)
    vt.traces[0] = _ShiftedTrace(vt.trace, i * base.client_offset_s)
    return vt


def measure(names: list[str], counts: list[int], duration_s: float, size: tuple[int, int], network: str,
            solo: bool = False, params: dict[str, Any] | None = None, offset_s: float = 0.5) -> dict[str, Any]:
    """Rows per scene and client count, measured in this process (this process's ``splitrender``); with ``solo``
    each client of the largest count also alone (:func:`solo_run`; client 0 alone is the one-client row).
    Client ``i`` starts ``i * offset_s`` seconds into the trace."""
    rec = Recorder()
    rec.install()
    r = Renderer()
    out: dict[str, Any] = {}
    for name in names:
        base = RunConfig(method="sas", method_params=dict(params or {}), scene=SCENES[name], trace="walk", network=network, width=size[0], height=size[1],
                         duration_s=duration_s, client_fps=30, flip_every=0, metrics=False, client_offset_s=offset_s)
        VirtualTimeRun(base.replace(duration_s=0.1), r).run()   # warm up shaders and caches
        rows = out.setdefault(name, {})
        runs: list[tuple[str, Any, int]] = [(str(n), lambda n=n: VirtualTimeRun(base.replace(clients=n), r), n)
                                            for n in counts]
        if solo:
            runs += [(f"solo{i}", lambda i=i: solo_run(base, i, r), 1) for i in range(1, max(counts))]
        for key, make, n in runs:
            rec.reset()
            vt = make()
            # each run relights its own GI probes: runs on one renderer would otherwise reuse the states an earlier
            # run relit at the same times, and a client alone would skip the relight the clients share together
            r.probe_states().enabled = False
            w0, c0 = time.perf_counter(), time.process_time()
            vt.run()
            row = rec.per_frame(n)
            row["run_wall_s"], row["run_cpu_s"] = time.perf_counter() - w0, time.process_time() - c0
            row["load"] = os.getloadavg()[0]
            rows[key] = row
    return out


def ratios(rows: dict[str, Any]) -> None:
    """Each row's ratio to the one-client row (same label, same invocation), per stage, wall and CPU; where each
    client of a row also ran alone (``solo<i>`` rows, :func:`solo_run`), the row's ratio to the sum of its clients
    alone (``ratio_to_solo_sum``: 1 when the sessions share nothing, each client's own view costing what it does
    alone) and whether each client's updates are the bytes it gets alone (``digests_equal_solo``)."""
    one = rows["1"]
    for key, row in rows.items():
        n = int(key) if key.isdigit() else 0
        alone = [one] + [rows.get(f"solo{i}") for i in range(1, n)]
        if n > 1 and all(a is not None for a in alone):
            row["ratio_to_solo_sum"] = {kind: {k: row[kind][k] / s if (s := sum(a[kind][k] for a in alone)) > 0 else None
                                               for k in (*STAGES, "tick")} for kind in ("wall", "cpu", "wall_min", "cpu_min")}
            row["digests_equal_solo"] = [a["digests"][0] == d for a, d in zip(alone, row["digests"])]
    for row in rows.values():
        rt = {kind: {k: row[kind][k] / one[kind][k] if one[kind][k] > 0 else None for k in (*STAGES, "tick")}
              for kind in ("wall", "cpu", "wall_min", "cpu_min")}
        rt["run_wall"] = row["run_wall_s"] / one["run_wall_s"]
        rt["run_cpu"] = row["run_cpu_s"] / one["run_cpu_s"]
        row["ratio_to_one"] = rt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", default="after", help="where the rows go in the JSON (before / after)")
    ap.add_argument("--before-tree", type=Path, default=None,
                    help="a copy of the package before the change (e.g. git archive HEAD splitrender | tar -x -C DIR): "
                         "measure it and this tree alternately, scene by scene and client count by client count, in "
                         "subprocesses, so both see the same load on a shared machine")
    ap.add_argument("--clients", default="1,2,4,8")
    ap.add_argument("--scenes", default="engine,default", help=f"of {', '.join(SCENES)} (default engine,default)")
    ap.add_argument("--duration", type=float, default=0.5, help="seconds of each run (default 0.5: 16 server frames)")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--offset", type=float, default=0.5,
                    help="seconds between the clients' starts along the trace (default 0.5; issue 49: 0.3)")
    ap.add_argument("--network", default="ideal",
                    help="network profile (default ideal: with jitter the runs' packet timings, and so the updates, vary "
                         "from run to run, as the metadata carries the stages' wall-clock times)")
    ap.add_argument("--solo", action="store_true",
                    help="also run each client of the largest count alone (its own trace offset): the sessions' "
                         "sharing is the many-client tick over the sum of its clients' ticks alone")
    ap.add_argument("--params", default="{}", help="SasConfig fields, JSON (e.g. '{\"reshade_eye_deg\": 2}'), both trees")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)   # write measure()'s rows here
    ns = ap.parse_args()
    w, h = (int(v) for v in ns.size.split("x"))
    counts = [int(v) for v in ns.clients.split(",")]
    names = ns.scenes.split(",")
    if ns.worker is not None:
        ns.worker.write_text(json.dumps(measure(names, counts, ns.duration, (w, h), ns.network, ns.solo,
                                                json.loads(ns.params), ns.offset)))
        return
    load0 = os.getloadavg()
    labels: dict[str, dict[str, Any]] = {}
    if ns.before_tree is None:
        labels[ns.label] = measure(names, counts, ns.duration, (w, h), ns.network, ns.solo, json.loads(ns.params),
                                   ns.offset)
    else:
        import subprocess
        import sys
        import tempfile

        for name in names:
            for n in counts:
                for label, tree in (("before", ns.before_tree), ("after", None)):
                    env = dict(os.environ)
                    if tree is not None:
                        env["PYTHONPATH"] = os.pathsep.join([str(tree), env.get("PYTHONPATH", "")])
                    with tempfile.TemporaryDirectory() as d:
                        part = Path(d) / "rows.json"
                        subprocess.run([sys.executable, __file__, "--worker", str(part), "--scenes", name, "--clients",
                                        str(n), "--duration", str(ns.duration), "--size", ns.size, "--offset", str(ns.offset), "--network",
                                        ns.network, "--params", ns.params,
                                        *(["--solo"] if ns.solo and n == max(counts) else [])],
                                       env=env, check=True)
                        got = json.loads(part.read_text())
                    labels.setdefault(label, {}).setdefault(name, {}).update(got[name])
                    row = got[name][str(n)]
                    print(f"{label:6s} {name} {n} clients: tick {row['wall']['tick']:.0f} ms wall, {row['cpu']['tick']:.0f} ms "
                          f"CPU; " + ", ".join(f"{k} {row['wall'][k]:.0f}" for k in STAGES), flush=True)
    doc = json.loads(ns.out.read_text()) if ns.out.exists() else {}
    for label, scenes in labels.items():
        for name, rows in scenes.items():
            ratios(rows)
            for key, row in rows.items():
                rt = row["ratio_to_one"]
                print(f"{label:6s} {name} {key}/1: tick wall {rt['wall']['tick']:.2f}x cpu {rt['cpu']['tick']:.2f}x; "
                      f"whole run wall {rt['run_wall']:.2f}x cpu {rt['run_cpu']:.2f}x")
                if "ratio_to_solo_sum" in row:
                    rs = row["ratio_to_solo_sum"]
                    print(f"{label:6s} {name} {key}/(its clients alone): tick wall {rs['wall']['tick']:.2f}x cpu "
                          f"{rs['cpu']['tick']:.2f}x; updates as alone: {row['digests_equal_solo']}")
        doc[label] = {"machine": platform.platform(), "cpus": os.cpu_count(), "load_before": load0, "params": json.loads(ns.params),
                      "load_after": os.getloadavg(), "duration_s": ns.duration, "size": [w, h], "network": ns.network,
                      "client_offset_s": ns.offset,
                      "interleaved_with_before_tree": ns.before_tree is not None,
                      "scenes": {name: {"scene": SCENES[name], "rows": rows} for name, rows in scenes.items()}}
    if "before" in doc:
        for label in labels:
            if label == "before":
                continue
            same = {}
            for name, sc in doc[label]["scenes"].items():
                old = doc["before"]["scenes"].get(name, {}).get("rows", {})
                same[name] = {key: (row["digests"] == old[key]["digests"]) if key in old else None
                              for key, row in sc["rows"].items()}
            doc[label]["digests_equal_before"] = same
            print(f"{label}: updates bit-identical to before:", same)
    ns.out.parent.mkdir(parents=True, exist_ok=True)
    ns.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"-> {ns.out}")


if __name__ == "__main__":
    main()
