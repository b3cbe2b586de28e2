"""``tss`` against ``sas`` on real models (issue 50, part 1): model-region PSNR and bits, before and after.

On assimp's duck, TextureTransformTest and 2CylinderEngine (``/usr/share/assimp/models``, Debian's
assimp-testmodels; a model that is absent is skipped), 320x180, 1 s, ``sas`` at its defaults as the baseline of every
comparison, measured in the same process as the ``tss`` runs:

- still: ``static`` trace, ``ideal`` network; ``tss`` at its defaults (1 sample per covered pixel, the paper's O1),
  with a lossless atlas, and at ``sas``'s budget (``samples_per_px = 4``, ``chroma = 444``: still fewer samples
  than ``sas`` shades; lossy and lossless);
- moving: the fitted ``orbit`` under ``cloud``; ``sas``, ``tss`` at its defaults and at ``sas``'s budget;
- both: ``tss`` at ``sas``'s budget with slivers sampled (:data:`BUDGET_SLIVERS`) and with a budget that moves with
  the scene (:data:`MOVING`, ``budget_px``), lossy and lossless still.
- issue 50 part 1: ``sas`` and the moving budget on the orbit under ``ideal`` too (latency apart), and the moving
  budget with the flip's triangles lifted (:data:`FLIPS`), and ``flip_level = 4`` at the defaults (``tss flip4``);
  the orbit lossless for both methods (``sas lossless``, ``tss flips lossless``: the gap without the codec, against
  ``sas lossless`` in ``model_db_minus_sas_lossless``) and ``tss flips`` at crf 18 (``tss flips crf18``); and
  :data:`RINGS` (``tss rings``: ``FLIPS`` with ``pvs_ring = 1``), still and on the orbit, lossy and lossless.
  ``--models`` and ``--runs`` (comma-separated names) measure a subset.

The default scene (``default``) is measured beside the three models.

Per run: model, interior and edge PSNR (means over the frames that show an update, ``update_frame_id >= 0``, the
start-up tick left out) and the summary's ``mean_model_psnr_db`` (every frame, as ``splitrender run`` prints it),
the steady kbit/s (every stream but the one-off session data), and the samples shaded per update (``srv_samples``;
``sas``: its atlas's block texels).

``--tree PATH`` runs the same list from another checkout (for the commit before the change: ``git worktree add
/tmp/tss_before <commit>``) in a child process with ``PYTHONPATH=PATH`` and files its figures under ``--label``.
Writes (merging labels) ``benchmarks/results/bench_tss_models.json``.  Run::

    python benchmarks/bench_tss_models.py --label after
    python benchmarks/bench_tss_models.py --tree /tmp/tss_before --label before

(about 10 minutes each on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).parent / "results" / "bench_tss_models.json"
MODELS = {"duck": "/usr/share/assimp/models/Collada/duck.dae",
          "TextureTransformTest": "/usr/share/assimp/models/glTF2/textureTransform/TextureTransformTest.gltf",
          "2CylinderEngine": "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb",
          "default": "default"}
BUDGET = {"samples_per_px": 4.0, "chroma": "444"}
"""``tss`` at ``sas``'s budget: 4 samples per covered pixel (``sas`` fills its atlas up to 16 texels per pixel)."""
MOVING = {"budget_px": 2.0, "chroma": "444", "sliver_px": 1.0}
"""``tss`` with a budget that moves with the scene (issue 50): up to 8 samples per covered pixel while the frame's
samples stay within 2 per display pixel (115k at 320x180, below ``sas``'s 144-261k on every scene here), slivers
sampled along their length (``sliver_px = 1``)."""
FLIPS = {**MOVING, "flip_level": 8, "hysteresis": 0.75}
""":data:`MOVING` with the triangles that the two-sided flip crosses L-packed at level 8 or more (``flip_level``) and
the layout's hysteresis at 0.75 (issue 50 part 1: the orbit's gap)."""
RINGS = {**FLIPS, "pvs_ring": 1}
""":data:`FLIPS` with the PVS's neighbours at one texel each while the view moves (``pvs_ring = 1``; issue 50 part 1:
the engine's orbit gap was holes, triangles the EVS samples missed)."""
BUDGET_SLIVERS = {**BUDGET, "sliver_px": 1.0}
"""``tss`` at ``sas``'s budget with slivers sampled along their length (issue 50's per-sample floor)."""
RUNS: list[tuple[str, str, str, str, dict[str, Any]]] = [
    # (name, trace, network, method, params)
    ("sas", "static", "ideal", "sas", {}),
    ("tss", "static", "ideal", "tss", {}),
    ("tss lossless", "static", "ideal", "tss", {"lossless": True}),
    ("tss budget", "static", "ideal", "tss", BUDGET),
    ("tss budget lossless", "static", "ideal", "tss", {**BUDGET, "lossless": True}),
    ("tss budget slivers", "static", "ideal", "tss", BUDGET_SLIVERS),
    ("tss budget slivers lossless", "static", "ideal", "tss", {**BUDGET_SLIVERS, "lossless": True}),
    ("tss moving", "static", "ideal", "tss", MOVING),
    ("tss moving lossless", "static", "ideal", "tss", {**MOVING, "lossless": True}),
    ("sas", "orbit", "cloud", "sas", {}),
    ("tss", "orbit", "cloud", "tss", {}),
    ("tss budget", "orbit", "cloud", "tss", BUDGET),
    ("tss budget slivers", "orbit", "cloud", "tss", BUDGET_SLIVERS),
    ("tss moving", "orbit", "cloud", "tss", MOVING),
    # issue 50 part 1: the orbit without latency (``ideal``), and the flip-lifted moving budget (FLIPS)
    ("sas", "orbit", "ideal", "sas", {}),
    ("tss moving", "orbit", "ideal", "tss", MOVING),
    ("tss flips", "static", "ideal", "tss", FLIPS),
    ("tss flips lossless", "static", "ideal", "tss", {**FLIPS, "lossless": True}),
    ("tss flips", "orbit", "cloud", "tss", FLIPS),
    ("tss flips", "orbit", "ideal", "tss", FLIPS),
    ("tss flip4", "static", "ideal", "tss", {"flip_level": 4}),
    ("tss flip4 lossless", "static", "ideal", "tss", {"flip_level": 4, "lossless": True}),
    ("tss flip4", "orbit", "cloud", "tss", {"flip_level": 4}),
    # issue 50 part 1, the codec's share of the orbit's gap: both lossless on the orbit, and tss at a lower crf
    ("sas lossless", "orbit", "cloud", "sas", {"lossless": True}),
    ("tss flips lossless", "orbit", "cloud", "tss", {**FLIPS, "lossless": True}),
    ("tss flips crf18", "orbit", "cloud", "tss", {**FLIPS, "crf": 18}),
    # issue 50 part 1: the PVS's ring (RINGS)
    ("tss rings", "static", "ideal", "tss", RINGS),
    ("tss rings lossless", "static", "ideal", "tss", {**RINGS, "lossless": True}),
    ("tss rings", "orbit", "cloud", "tss", RINGS),
    ("tss rings", "orbit", "ideal", "tss", RINGS),
    ("tss rings lossless", "orbit", "cloud", "tss", {**RINGS, "lossless": True}),
]


def measure(quick: bool = False, models: list[str] | None = None, runs: list[str] | None = None) -> list[dict[str, Any]]:
    """Every run of :data:`RUNS` on every model present, in this process (this checkout, or ``PYTHONPATH``'s);
    ``models`` (names of :data:`MODELS`) and ``runs`` (run names, as in :data:`RUNS`) keep only those."""
    import numpy as np

    from splitrender.render.renderer import Renderer
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import run
    from splitrender.errors import ConfigError

    import splitrender

    print(f"measuring {splitrender.__file__}", file=sys.stderr)
    renderer = Renderer()
    out = []
    for model, path in MODELS.items():
        if models and model not in models:
            continue
        if path != "default" and not os.path.exists(path):
            print(f"skip {model}: {path} absent", file=sys.stderr)
            continue
        for name, trace, network, method, params in RUNS:
            if (quick and trace != "static") or (runs and name not in runs):
                continue
            t0 = time.perf_counter()
            try:
                res = run(RunConfig(method=method, scene=path, trace=trace, network=network, duration_s=1.0, width=320, height=180,
                                    flip_every=0, seed=0, method_params=params, truth_cache="default"), renderer=renderer)
            except ConfigError as exc:   # a parameter the measured tree does not have (the tree before a change)
                print(f"skip {model} {name}: {exc}", file=sys.stderr)
                continue
            shown = [f for f in res.frames if f["update_frame_id"] >= 0]

            def mean(key: str) -> float:
                return float(np.nanmean([float(f[key]) for f in shown])) if shown else float("nan")

            s = res.summary
            row = {"model": model, "run": name, "trace": trace, "network": network, "method": method, "params": params,
                   "model_db": round(mean("model_psnr_db"), 3), "interior_db": round(mean("interior_psnr_db"), 3),
                   "edge_db": round(mean("edge_psnr_db"), 3), "summary_model_db": round(float(s["mean_model_psnr_db"]), 3),
                   "steady_kbps": round(float(s["steady_kbps"]), 1),
                   "samples": round(float(np.mean([u["srv_samples"] for u in res.updates if "srv_samples" in u])), 0),
                   "seconds": round(time.perf_counter() - t0, 1)}
            print(json.dumps(row), flush=True)
            out.append(row)
    return out


def compare(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per model and trace, each ``tss`` run against ``sas`` of the same list: dB and bit and sample ratios."""
    out: dict[str, dict[str, Any]] = {}
    for r in rows:
        if r["method"] != "tss":
            continue
        same = [b for b in rows if b["method"] == "sas" and b["model"] == r["model"] and b["trace"] == r["trace"]
                and b["network"] == r["network"]]
        base = next((b for b in same if not b["params"].get("lossless")), None)
        lossless = next((b for b in same if b["params"].get("lossless")), None)
        if base is None:
            continue
        key = f"{r['model']} {r['trace']} {r['run']}" + (f" {r['network']}" if r["trace"] != "static" and r["network"] != "cloud" else "")
        out[key] = {
            "model_db_minus_sas": round(r["model_db"] - base["model_db"], 2),
            "bits_over_sas": round(r["steady_kbps"] / base["steady_kbps"], 3),
            "samples_over_sas": round(r["samples"] / base["samples"], 3)}
        if r["params"].get("lossless") and lossless is not None:    # lossless against lossless: the sampling alone
            out[key]["model_db_minus_sas_lossless"] = round(r["model_db"] - lossless["model_db"], 2)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--label", default="after")
    ap.add_argument("--tree", help="another checkout to measure (run in a child process with PYTHONPATH)")
    ap.add_argument("--quick", action="store_true", help="still runs only")
    ap.add_argument("--models", help="comma-separated model names (default: all of MODELS)")
    ap.add_argument("--runs", help="comma-separated run names, e.g. 'sas,tss flips' (default: all of RUNS)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    models = a.models.split(",") if a.models else None
    runs = a.runs.split(",") if a.runs else None
    if a.child:
        print("ROWS " + json.dumps(measure(a.quick, models, runs)))
        return
    t0 = time.perf_counter()
    if a.tree:
        env = {**os.environ, "PYTHONPATH": str(Path(a.tree).resolve())}
        cmd = ([sys.executable, __file__, "--child"] + (["--quick"] if a.quick else []) + (["--models", a.models] if a.models else [])
               + (["--runs", a.runs] if a.runs else []))
        done = subprocess.run(cmd, env=env, cwd=a.tree, capture_output=True, text=True, check=True)
        rows = json.loads(next(line[5:] for line in done.stdout.splitlines() if line.startswith("ROWS ")))
        commit = subprocess.run(["git", "-C", a.tree, "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    else:
        sys.path.insert(0, str(ROOT))
        rows = measure(a.quick, models, runs)
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    data = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    data.setdefault("setting", "320x180, 1 s, still = static/ideal, moving = orbit/cloud; model-region PSNR over the frames "
                               "showing an update; sas at its defaults is the baseline, measured in the same process")
    data.setdefault("machine", f"{platform.node()} ({platform.machine()}, {os.cpu_count()} cpus, llvmpipe)")
    data[a.label] = {"commit": commit, "seconds": round(time.perf_counter() - t0, 1), "runs": rows, "against_sas": compare(rows)}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(data, indent=1) + "\n")
    for k, v in data[a.label]["against_sas"].items():
        print(f"{a.label:7s} {k:50s} {v}")


if __name__ == "__main__":
    main()
