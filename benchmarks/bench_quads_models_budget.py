"""QUASAR against MeshWarp 60 on the model region, stage by stage: the error budget (issue 50, part 2, item 2).

The claims ledger's ``Q-T4-4`` cells (``docs/claims.md``): the models alone, ``orbit`` (moving) or ``static`` (still),
``cloud``, 320x180, 1 s, MeshWarp 60 as the ledger runs it (``warp`` with ``reconstruction=mesh fov_scale=1
resolution_scale=1 depth_coding=bc4 extrapolate=false``).  Per model, QUASAR at its defaults and with each stage of its
error turned off or to its ideal, one at a time:

- **merge flattening tolerance**: ``delta_flatten = 0`` (every merged quad keeps its 16 depth offsets; the hidden
  layers' and wide view's relaxed tolerance is 10x this, so 0 too);
- **merging**: no merging at all (one quad a pixel, offsets kept);
- **depth-offset quantisation**: the wire's float16 offsets; no run turns it off (the wire has no other format), so
  the child records, over every generated set of the QUASAR run, the rounding error of each non-flat quad's corner
  depth (metres, and relative to the corner's depth) and the image shift it makes for an eye ``view_cell_m / 2``
  (25 cm) off the view's centre: ``focal * 0.25 * dz / z**2`` pixels;
- **layers**: the visible layer alone (``layers = 1``);
- **wide view**: none (``wide_fov_deg = 0``);
- **the colour atlas**: coded losslessly (the atlas's slots are the display's size, one texel a pixel of the view
  that drew it, as MeshWarp 60's frame; what is left of "its resolution" is the coding and the resampling from the
  reference view, the next stage);
- **residual frames** (a residual frame draws the cached reference mesh, whose colours are drawn from the reference
  pose, up to ``reference_every - 1`` server frames older than the frame's own): a reference frame every frame;
- **all ideal**: exact quads (no merging, offsets kept), a lossless atlas and a reference frame every frame.

Each run's mean model-region PSNR over the displayed frames that show content, and also that mean split by the kind
of QUASAR frame on display (reference or residual), against MeshWarp 60 on the same display frames: the split says
which frames the gap comes from.  With ``--before PATH`` (a ``git worktree`` of the commit before a change) QUASAR
runs from that tree too, in the same invocation: the before/after rows of a change.

Writes ``benchmarks/results/bench_quads_models_budget_cloud.json``.
Run: ``python benchmarks/bench_quads_models_budget.py [--models 2CylinderEngine,duck,default] [--traces orbit,static]
[--stages all|none|name,...] [--before /tmp/wt] [--jobs 2]``.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _trees import commit_of, run_in_tree  # noqa: E402  (beside this script)
from bench_quads_models import BUILTIN, MODELS as QUADS_MODELS  # noqa: E402  (the same models, but Wuson)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "bench_quads_models_budget_cloud.json"
MODELS = {k: v for k, v in QUADS_MODELS.items() if k != "Wuson"}
SETTINGS = {"network": "cloud", "duration_s": 1.0, "width": 320, "height": 180, "flip_every": 0}
MW60 = ("warp", {"depth_coding": "bc4", "extrapolate": False, "fov_scale": 1.0, "reconstruction": "mesh",
                 "resolution_scale": 1.0})
EXACT = {"delta_sim": 0.0, "coarse_passes": 0, "relaxed_coarse_passes": 0, "delta_flatten": 0.0, "relax": 1.0}
STAGES = {
    "flatten 0": {"delta_flatten": 0.0},
    "no merging": EXACT,
    "1 layer": {"layers": 1},
    "no wide view": {"wide_fov_deg": 0.0},
    "lossless atlas": {"lossless": True},
    "reference every frame": {"reference_every": 1},
    "all ideal": {**EXACT, "lossless": True, "reference_every": 1},
}

CHILD = r"""
import json, math, sys
import numpy as np
a = json.loads(sys.argv[1])
offs = {"n": 0, "max_dz_m": 0.0, "max_rel": 0.0, "sum_px": 0.0, "max_px": 0.0}
if a["method"] == "quads":
    from splitrender.methods.quads import gen
    from splitrender.scene.pose import CameraIntrinsics
    f = 180 / 2 / math.tan(math.radians(CameraIntrinsics(320, 180).fov_y_deg) / 2)
    g0 = gen.gather
    def gather(maps):
        out = g0(maps)
        for m in maps:       # the non-flat quads' offsets before the wire's float16, and their corner depths
            sel = m["present"] & ~m["flat"]
            if not sel.any():
                continue
            o, z = m["offs"][sel], m["corners"][sel]
            dz = np.abs(o.astype(np.float16).astype(np.float64) - o)
            ok = np.isfinite(z) & (z > 0)
            rel, px = dz[ok] / z[ok], f * 0.25 * dz[ok] / z[ok] ** 2
            offs["n"] += int(ok.sum())
            if rel.size:
                offs["max_dz_m"] = max(offs["max_dz_m"], float(dz[ok].max()))
                offs["max_rel"] = max(offs["max_rel"], float(rel.max()))
                offs["max_px"] = max(offs["max_px"], float(px.max()))
                offs["sum_px"] += float(px.sum())
        return out
    gen.gather = gather
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import run
r = run(RunConfig(method=a["method"], method_params=a["params"], scene=a["scene"], truth_cache=a["truth_cache"], **a["settings"]))
fr, s = r.frames, r.summary
ref = {int(u["frame_id"]): u.get("srv_reference", math.nan) for u in r.updates if "frame_id" in u}
rows = [[f.get("update_frame_id", -1), f.get("model_psnr_db", math.nan), ref.get(int(f.get("update_frame_id", -1)), math.nan)]
        for f in fr]
mp = [p for u, p, _ in rows if u != -1]
print("RESULT " + json.dumps({
    "model_psnr_content_db": float(np.nanmean(mp)) if mp else None, "mean_model_psnr_db": s.get("mean_model_psnr_db"),
    "mean_psnr_db": s["mean_psnr_db"], "mean_kbps": s["mean_kbps"], "frames": rows,
    "offsets": dict(offs, mean_px=offs["sum_px"] / max(offs["n"], 1)) if offs["n"] else None}))
"""


def split(run: dict, base: dict) -> dict:
    """``run``'s model PSNR minus ``base``'s on the same display frames, over the frames where ``run`` showed a
    reference frame and where it showed a residual one (both showing content)."""
    out = {}
    for name, want in (("reference", 1.0), ("residual", 0.0)):
        d = [a[1] - b[1] for a, b in zip(run["frames"], base["frames"])
             if a[0] != -1 and b[0] != -1 and a[2] == want and math.isfinite(a[1]) and math.isfinite(b[1])]
        out[name] = {"frames": len(d), "gap_db": sum(d) / len(d) if d else None}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", default="2CylinderEngine,duck,default", help=f"of {', '.join([*MODELS, *BUILTIN])}")
    ap.add_argument("--traces", default="orbit", help="comma-separated: orbit (moving), static (still)")
    ap.add_argument("--stages", default="all", help="all, none, or comma-separated names of: " + ", ".join(STAGES))
    ap.add_argument("--before", type=Path, help="a worktree of the commit before a change: QUASAR from it too")
    ap.add_argument("--extra", default="{}", help='JSON {"label": {params}}: more QUASAR configurations')
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--truth-cache", default="default")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ns = ap.parse_args()
    names = ns.models.split(",")
    missing = [m for m in names if m not in BUILTIN and not MODELS[m].exists()]
    if missing:
        sys.exit(f"bench_quads_models_budget: assimp-testmodels is not installed ({', '.join(missing)} missing)")
    stages = dict(STAGES) if ns.stages == "all" else {} if ns.stages == "none" else {k: STAGES[k] for k in ns.stages.split(",")}
    stages.update(json.loads(ns.extra))
    res: dict = {"machine": platform.platform(), "settings": SETTINGS, "mw60": MW60[1],
                 "after": commit_of(ROOT, "splitrender/methods/quads"),
                 "before": commit_of(ns.before, "splitrender/methods/quads") if ns.before else None, "cells": {}}
    todo = []
    for name in names:
        scene = name if name in BUILTIN else str(MODELS[name])
        for trace in ns.traces.split(","):
            cell = f"{name} {trace}"
            runs = [("MW60", ROOT, *MW60), ("quasar", ROOT, "quads", {})]
            if ns.before:
                runs.append(("quasar before", ns.before, "quads", {}))
            runs += [(f"quasar, {k}", ROOT, "quads", p) for k, p in stages.items()]
            todo += [(cell, scene, trace, *r) for r in runs]

    def one(item: tuple) -> tuple:
        cell, scene, trace, label, tree, method, params = item
        r = run_in_tree(tree, CHILD, {"method": method, "params": params, "scene": scene, "truth_cache": ns.truth_cache,
                                      "settings": dict(SETTINGS, trace=trace)}, f"{label} on {cell}")
        r.update(method=method, params=params, tree=str(tree))
        print(f"{cell:24s} {label:36s} model {r['model_psnr_content_db']:6.2f} dB  {r['mean_kbps']:7.0f} kbit/s "
              f"{r['wall_s']:5.0f} s", flush=True)
        return cell, label, r

    with ThreadPoolExecutor(ns.jobs) as ex:
        for cell, label, r in ex.map(one, todo):
            res["cells"].setdefault(cell, {})[label] = r
    for cell, runs in res["cells"].items():
        base = runs["MW60"]
        for label, r in runs.items():
            if label != "MW60":
                r["against_mw60_db"] = r["model_psnr_content_db"] - base["model_psnr_content_db"]
                r["against_mw60_by_frame_kind"] = split(r, base)
        print(cell)
        for label, r in runs.items():
            if label != "MW60":
                sp = r["against_mw60_by_frame_kind"]
                print(f"  {label:36s} {r['against_mw60_db']:+6.2f} dB against MW60 (reference frames "
                      f"{sp['reference']['gap_db'] if sp['reference']['gap_db'] is not None else math.nan:+.2f} over "
                      f"{sp['reference']['frames']}, residual {sp['residual']['gap_db'] if sp['residual']['gap_db'] is not None else math.nan:+.2f} "
                      f"over {sp['residual']['frames']})")
    ns.out.parent.mkdir(parents=True, exist_ok=True)
    ns.out.write_text(json.dumps(res, indent=1))
    print(f"wrote {ns.out}")


if __name__ == "__main__":
    main()
