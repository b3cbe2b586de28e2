"""The estimator and the rate controller on one step trace, live through the relay and in virtual time (issue 35).

``video`` on ``minimal``, 320x180, asked for 3 Mbit/s (``bitrate_kbps``, so its own operating point needs more
than the low step carries), ``--adapt rate``, 20 ms each way, the downlink's capacity a generated step trace
(``--steps`` seconds at 4, 0.5 and 4 Mbit/s; default 4, 4, 4).  Live: ``splitrender serve --adapt rate --out DIR``
in its own process, the shaping relay and the headless client in this one; virtual time: the same configuration
through :class:`~splitrender.sim.runner.VirtualTimeRun`.  From each server's ``updates.csv`` rows:

* how long after the drop the encoder rate is within 1.2x the new capacity (issue 35's target: 1 s), and the
  delay-based target;
* how long after the rise the target is back at 70 % of what the session asks (the capacity, or the session's own
  operating point where that is lower: issue 35's target, 5 s);
* the queue the estimator measured, at most, after the drop.

The live clock starts when the relay's first listener does (``Relay.origin_wall_s``, where the trace begins);
the server rows are placed on it by their wall times.  Writes ``benchmarks/results/bench_adapt_live.json`` and ``bench_adapt_live.png`` (both timelines on the
capacity).

    python benchmarks/bench_adapt_live.py [--steps 4,4,4] [--seed 1]
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import json
import math
import os
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, not an installed one

from splitrender.client.session import ClientConfig, LiveClient  # noqa: E402
from splitrender.netsim import Relay, parse_path  # noqa: E402
from splitrender.netsim.traces import step_trace, write_mahimahi  # noqa: E402

from _live import LOOPBACK, served  # noqa: E402  (beside this script)

OUT = Path(__file__).resolve().parent / "results"
ASK_KBPS = 3000.0


def _network(trace: Path) -> str:
    return f"up: delay 20ms; down: delay 20ms trace {trace}"


async def live(trace: Path, duration_s: float, seed: int, work: Path) -> list[dict[str, float]]:
    out = work / "live"
    args = ["--scene", "minimal", "--methods", "video", "--adapt", "rate", "--param", f"video.bitrate_kbps={ASK_KBPS:g}",
            "--out", str(out)]
    async with served(args) as (port, udp_port):
        relay = Relay(parse_path(_network(trace)), seed=seed)
        try:
            tcp = await relay.start_tcp((LOOPBACK, 0), (LOOPBACK, port))
            udp = await relay.start_udp((LOOPBACK, 0), (LOOPBACK, udp_port))
            origin_s = relay.origin_wall_s     # link time 0: the trace begins there
            assert origin_s is not None
            await LiveClient(ClientConfig(port=tcp[1], udp_port=udp[1], width=320, height=180, display_hz=30,
                                          duration_s=duration_s, trace="walk", out_dir=work / "client")).run()
        finally:
            await relay.wait_tcp_idle(1.0)
            await relay.close()
    path = next(out.glob("*/updates.csv"))
    rows = []
    for r in csv.DictReader(open(path)):
        rows.append({"t_s": int(r["server_us"]) / 1e6 - origin_s, **{k: float(r[k]) if r[k] not in ("", "nan") else math.nan
                                                                     for k in ("cc_target_kbps", "cc_encoder_kbps",
                                                                               "cc_queue_ms", "bytes")}})
    return rows


def virtual(trace: Path, duration_s: float, seed: int) -> list[dict[str, float]]:
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import VirtualTimeRun

    res = VirtualTimeRun(RunConfig(method="video", scene="minimal", trace="walk", duration_s=duration_s, width=320,
                                   height=180, client_fps=30, network=_network(trace), transport_cc=True, adapt="rate",
                                   method_params={"bitrate_kbps": ASK_KBPS}, metrics=False, seed=seed)).run()
    return [{"t_s": u["t_s"], **{k: float(u.get(k, math.nan)) for k in ("cc_target_kbps", "cc_encoder_kbps", "cc_queue_ms",
                                                                       "bytes")}} for u in res.updates]


def figures(rows: list[dict[str, float]], steps: tuple[float, float, float], caps: tuple[float, float, float]) -> dict[str, float]:
    t = np.array([r["t_s"] for r in rows])
    enc = np.array([r["cc_encoder_kbps"] for r in rows])
    tgt = np.array([r["cc_target_kbps"] for r in rows])
    q = np.array([r["cc_queue_ms"] for r in rows])
    down, up = steps[0], steps[0] + steps[1]

    def first(cond: np.ndarray, t0: float, t1: float) -> float:
        hit = t[(t >= t0) & (t < t1) & cond]
        return float(hit[0] - t0) if hit.size else math.nan

    ask = ASK_KBPS * 1.15        # what the session sends at its own operating point, metadata beside it
    return {"down_encoder_s": first(enc <= 1.2 * caps[1] * 1000, down, up),
            "down_target_s": first(tgt <= 1.2 * caps[1] * 1000, down, up),
            "up_target_s": first(tgt >= 0.7 * min(caps[2] * 1000, ask), up, math.inf),
            "max_queue_ms_after_drop": float(np.nanmax(q[(t >= down) & (t < up)])) if ((t >= down) & (t < up)).any() else math.nan}


def chart(runs: dict[str, list[dict[str, float]]], steps: tuple[float, float, float], caps: tuple[float, float, float],
          path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7.5, 5.2), sharex=True)
    a, b, c = steps
    a1.plot([0, a, a, a + b, a + b, a + b + c], np.array([caps[0], caps[0], caps[1], caps[1], caps[2], caps[2]]) * 1000,
            color="0.6", lw=1.2, label="capacity")
    for name, rows, style in (("live", runs["live"], "-"), ("virtual time", runs["virtual"], "--")):
        t = [r["t_s"] for r in rows]
        a1.plot(t, [r["cc_target_kbps"] for r in rows], style, label=f"target, {name}")
        a1.plot(t, [r["cc_encoder_kbps"] for r in rows], style, alpha=0.6, label=f"encoder rate, {name}")
        a2.plot(t, [r["cc_queue_ms"] for r in rows], style, label=name)
    a1.set_ylabel("kbit/s")
    a1.set_yscale("log")
    a1.legend(fontsize=7, ncol=2)
    a2.set_ylabel("queue the estimator sees (ms)")
    a2.set_xlabel("time since the trace began (s)")
    a2.legend(fontsize=7)
    for ax in (a1, a2):
        ax.axvspan(a, a + b, color="0.92", zorder=0)
        ax.grid(alpha=0.3)
    fig.suptitle("The estimator live and in virtual time, one step trace (video, --adapt rate)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", default="4,4,4")
    ap.add_argument("--caps", default="4,0.5,4", help="Mbit/s of the three steps")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    steps = tuple(float(x) for x in args.steps.split(","))
    caps = tuple(float(x) for x in args.caps.split(","))
    work = Path(tempfile.mkdtemp(prefix="bench_adapt_live_"))
    trace = write_mahimahi(step_trace(list(zip(steps, caps))), work / "step.trace")
    dur = sum(steps)
    runs = {"live": asyncio.run(live(trace, dur, args.seed, work)), "virtual": virtual(trace, dur, args.seed)}
    figs = {k: figures(v, steps, caps) for k, v in runs.items()}  # type: ignore[arg-type]
    for k, f in figs.items():
        print(f"{k:8s} encoder within 1.2x of the drop {f['down_encoder_s']:.2f} s, target {f['down_target_s']:.2f} s; "
              f"back to 70 % {f['up_target_s']:.2f} s after the rise; queue at most {f['max_queue_ms_after_drop']:.0f} ms")
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "bench_adapt_live.json").write_text(json.dumps({
        "benchmark": "bench_adapt_live", "steps_s": steps, "capacity_mbps": caps, "ask_kbps": ASK_KBPS, "figures": figs,
        "timelines": runs, "machine": platform.machine(), "cpus": os.cpu_count(), "load_avg": os.getloadavg()},
        indent=1) + "\n")
    chart(runs, steps, caps, OUT / "bench_adapt_live.png")  # type: ignore[arg-type]
    print(f"-> {OUT / 'bench_adapt_live.json'}, {OUT / 'bench_adapt_live.png'}")


if __name__ == "__main__":
    main()
