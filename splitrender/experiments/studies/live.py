"""Study: the live system's rates, where a live server frame's time goes, and what the client keeps up with.

Every method as a real live session on loopback (``splitrender.experiments.live_rate``:
the server in this process with its render worker, ``splitrender client`` in another),
default scene with GI at 320x180, the client displaying at 30 Hz, the probes relit at
the server's default rate (``ServerConfig.gi_hz``).  Targets (issue 37): video and atw
at least 10 server updates a second, every other method at least 3, each client at its
display rate.  The CPU's two cores run the server, its render worker and the client
alike: what one needs the others wait for.
"""

from __future__ import annotations

import logging
import math
import platform
import time
from pathlib import Path
from typing import Any

from ...methods import methods_for_scene
from ...server.server import DEFAULT_GI_HZ
from ...tabular import write_csv
from ..charts import method_order
from ..live_rate import STAGES, measure
from ..sections import Section
from ._util import save_figure

log = logging.getLogger(__name__)

SCENE = "default"
TARGET_UPS = {"video": 10.0, "atw": 10.0}
"""Server updates a second each method should reach live (others: :data:`OTHER_TARGET_UPS`)."""
OTHER_TARGET_UPS = 3.0
COLUMNS = ("method", "updates_per_s", "target_ups", "client_displayed_per_s", "client_display_hz", "client_late_ticks",
           "gi_ms", "method_ms", "encode_ms", "worker_rtt_ms", "send_ms", "wait_ms", "frame_ms", "client_ms",
           "client_decode_ms", "kbps", "keyframes", "gi_hz", "seconds")
STAGE_COLORS = {"gi": "#d62728", "method": "#1f77b4", "encode": "#2ca02c", "worker_rtt": "#9467bd", "send": "#8c564b",
                "wait": "#cccccc"}


def target_ups(method: str) -> float:
    return TARGET_UPS.get(method, OTHER_TARGET_UPS)


def chart(rows: list[dict[str, Any]], path: Path) -> Path:
    """Updates a second (bars, target ticks, the client's display rate) and each frame's stages (stacked)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = [r["method"] for r in rows]
    xs = range(len(methods))
    fig, ax = plt.subplots(1, 2, figsize=(11, 3.8))
    ax[0].bar(xs, [r["updates_per_s"] for r in rows], 0.6, color="#1f77b4", label="server updates/s")
    for i, r in enumerate(rows):
        ax[0].hlines(r["target_ups"], i - 0.35, i + 0.35, colors="k", linestyles="--", label="target" if i == 0 else None)
    ax[0].plot(xs, [r["client_displayed_per_s"] for r in rows], "o", color="#ff7f0e", label="client frames shown/s")
    ax[0].set_xticks(list(xs), methods)
    ax[0].set_ylabel("per second")
    ax[0].set_title("live rates (320x180, default scene with GI)")
    ax[0].legend(fontsize=8)
    bottom = [0.0] * len(rows)
    for s in (*STAGES, "wait"):
        v = [0.0 if not math.isfinite(r[f"{s}_ms"]) else r[f"{s}_ms"] for r in rows]
        ax[1].bar(xs, v, 0.6, bottom=bottom, color=STAGE_COLORS[s], label=s)
        bottom = [b + x for b, x in zip(bottom, v)]
    ax[1].set_xticks(list(xs), methods)
    ax[1].set_ylabel("ms per server frame")
    ax[1].set_title("where a live frame's time goes")
    ax[1].legend(fontsize=8, ncol=2)
    save_figure(fig, path)
    return path


def run(out_dir: Path, quick: bool) -> Section:
    """Every available method live for a few seconds; ``live_rates.csv`` and ``live_rates.png`` in ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    seconds = 4.0 if quick else 10.0
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    for m in method_order(methods_for_scene(SCENE)):
        r = measure(m, seconds=seconds, scene=SCENE, gi_hz=DEFAULT_GI_HZ, out=out_dir / "sessions" / m)
        r["target_ups"] = target_ups(m)
        rows.append(r)
        log.info("live study: %s %.1f updates/s (target %g), client %.1f shown/s", m, r["updates_per_s"],
                 r["target_ups"], r["client_displayed_per_s"])
    elapsed = time.perf_counter() - t0
    table = out_dir / "live_rates.csv"
    write_csv(table, [{k: r.get(k, "") for k in COLUMNS} for r in rows])
    png = chart(rows, out_dir / "live_rates.png")
    met = [r["method"] for r in rows if r["updates_per_s"] >= r["target_ups"]]
    missed = [r for r in rows if r["updates_per_s"] < r["target_ups"]]
    head = ("| method | updates/s (target) | client shown/s | GI ms | method ms | encode ms | worker round trip ms | "
            "send ms | client ms/tick |\n|---|---|---|---|---|---|---|---|---|")
    lines = [f"| {r['method']} | {r['updates_per_s']:.1f} ({r['target_ups']:g}) | {r['client_displayed_per_s']:.1f} | "
             f"{r['gi_ms']:.0f} | {r['method_ms']:.0f} | {r['encode_ms']:.1f} | {r['worker_rtt_ms']:.1f} | "
             f"{r['send_ms']:.1f} | {r['client_ms']:.0f} |" for r in rows]
    errors = [f"{r['method']}: {r['client_error']}" for r in rows if r.get("client_error")]
    text = (
        f"Each method live for {seconds:g} s on loopback: the server and its render worker in one process pair, the "
        f"client in another, all on this machine's {platform.machine()} CPU ({_cores()} cores, Mesa llvmpipe, no GPU). "
        f"Default scene with GI, 320x180, client display 30 Hz, the probes relit {DEFAULT_GI_HZ:g} times a second; "
        f"{len(rows)} sessions in {elapsed:.0f} s. The first second of each session is left out.\n\n"
        f"{head}\n" + "\n".join(lines) + "\n\n"
        f"At or above its target: {', '.join(met) or 'none'}"
        + (f"; below: {', '.join(r['method'] + ' (' + format(r['updates_per_s'], '.1f') + ')' for r in missed)}" if missed else "")
        + ". GI is the probes' relighting (about 70 ms each on this CPU, paid once per relight whichever method asks "
        "first); `method` is the rest of the method's server work, shading most of it (the frame for video and atw, the "
        "shading atlas for sas and tss, the G-buffer layers for quads, the coded probes for probes); `wait` is the "
        "frame clock waiting or the loop busy. `benchmarks/bench_live_rate.py` measures the same with the probes relit "
        "every frame as its baseline and runs unchanged on a machine with a GPU."
        + (f"\n\nClient errors: {'; '.join(errors)}" if errors else "")
    )
    return Section("Live rates and where a server frame's time goes", text, [png], [table])


def _cores() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
