"""Study: server and client cost on the simulated clock (``cost_model``).

Every method on the default scene's ``walk`` (without GI, ``default+nogi``) under ``lan``, twice: with the modelled
processing delays (``cost_model = "fixed"``: 10 ms server, 4 ms decode, whatever the
method costs) and with this machine's measured milliseconds on the clock
(``"measured"``: a frame leaves after its shared, server and encode work, a tick that
finds the server busy is skipped, a frame is applied its measured decode time after it
arrives).  The full run adds ``cost_scale = 0.1``, this machine's costs projected onto
one ten times faster.  The fixed model compares methods as if servers were free; the
measured one shows what software GL on this machine does to each of them.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Any

from ...methods import methods_for_scene
from ...render.renderer import Renderer
from ...sim.config import RunConfig
from ...sim.runner import run as run_one
from ...tabular import write_csv
from ..charts import method_order
from ..sections import Section
from ._util import STUDY_SCENE

log = logging.getLogger(__name__)

COLUMNS = ("method", "model", "cost_scale", "psnr_db", "ssim", "update_age_ms", "cost_ms", "server_skipped", "kbps",
           "server_ms", "shared_ms", "decode_ms")


def _run(method: str, model: str, scale: float, quick: bool, renderer: Any) -> dict[str, Any]:
    w, h = (320, 180) if quick else (640, 360)
    cfg = RunConfig(method=method, scene=STUDY_SCENE, trace="walk", network="lan", duration_s=0.6 if quick else 3.0, width=w, height=h,
                    client_fps=30 if quick else 60, seed=0, flip_every=0, cost_model=model, cost_scale=scale)
    s = run_one(cfg, renderer=renderer).summary
    return {"method": method, "model": model, "cost_scale": scale, "psnr_db": s["mean_psnr_db"], "ssim": s["mean_ssim"],
            "update_age_ms": s["mean_update_age_ms"], "cost_ms": s["mean_cost_ms"], "server_skipped": s["server_skipped"],
            "kbps": s["mean_kbps"], "server_ms": s["mean_server_ms"], "shared_ms": s["mean_shared_server_ms"],
            "decode_ms": s["mean_decode_ms"]}


def run(out_dir: Path, quick: bool) -> Section:
    """Run every method under both cost models; write ``cost_results.csv`` and a chart into ``out_dir``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    renderer = Renderer()
    methods = method_order(methods_for_scene(STUDY_SCENE))
    variants = [("fixed", 1.0), ("measured", 1.0)] + ([] if quick else [("measured", 0.1)])
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    for m in methods:
        for model, scale in variants:
            r = _run(m, model, scale, quick, renderer)
            rows.append(r)
            log.info("cost study: %s %s x%g -> %.2f dB, age %.0f ms, cost %.0f ms", m, model, scale, r["psnr_db"],
                     r["update_age_ms"], r["cost_ms"])
    elapsed = time.perf_counter() - t0

    table = out_dir / "cost_results.csv"
    write_csv(table, ({k: r[k] for k in COLUMNS} for r in rows))

    def label(model: str, scale: float) -> str:
        return model if scale == 1.0 else f"{model} x{scale:g}"

    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    width = 0.8 / len(variants)
    for k, (model, scale) in enumerate(variants):
        sel = [next((r for r in rows if r["method"] == m and r["model"] == model and r["cost_scale"] == scale), None)
               for m in methods]
        xs = [i + (k - (len(variants) - 1) / 2) * width for i in range(len(methods))]
        ax[0].bar(xs, [r["psnr_db"] if r else math.nan for r in sel], width, label=label(model, scale))
        ax[1].bar(xs, [r["update_age_ms"] if r else math.nan for r in sel], width, label=label(model, scale))
    for a, yl in ((ax[0], "PSNR, dB"), (ax[1], "mean update age, ms")):
        a.set_xticks(range(len(methods)), methods)
        a.set_ylabel(yl)
    ax[0].legend(fontsize=8)
    ax[0].set_title("quality: modelled vs measured cost")
    ax[1].set_title("age of the update on screen")
    fig.tight_layout()
    png = out_dir / "cost_models.png"
    fig.savefig(png, dpi=110)
    fig.savefig(png.with_suffix(".svg"))
    plt.close(fig)

    head = ("| method | cost model | PSNR dB | SSIM | update age ms | cost ms/frame | ticks skipped | kbit/s |\n"
            "|---|---|---|---|---|---|---|---|")
    lines = [f"| {r['method']} | {label(r['model'], r['cost_scale'])} | {r['psnr_db']:.2f} | {r['ssim']:.3f} | "
             f"{r['update_age_ms']:.0f} | {r['cost_ms']:.1f} | {r['server_skipped']} | {r['kbps']:.0f} |" for r in rows]
    text = (
        "The same runs with processing time modelled (`cost_model = \"fixed\"`: 10 ms server, 4 ms decode for every "
        "method) and measured on this machine (`\"measured\"`: the shared scene work, the method's server work and the "
        "encoding on the clock, busy ticks skipped, the measured decode time before a frame is applied)"
        f"{'' if quick else ', and measured times 0.1 (a machine ten times faster)'}. Default scene without GI (`{STUDY_SCENE}`), `walk`, `lan`, "
        f"{'0.6 s at 320x180' if quick else '3 s at 640x360'}; {len(rows)} runs in {elapsed:.0f} s.\n\n"
        f"{head}\n" + "\n".join(lines) + "\n\n"
        "Measured costs are wall-clock milliseconds of Mesa llvmpipe on this machine's CPU, not of a GPU; "
        "under the measured model the methods with expensive server halves pay for them in latency and skipped frames."
    )
    return Section("Cost on the clock (fixed vs measured)", text, [png], [table])
