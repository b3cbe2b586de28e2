"""``quads`` against ``warp`` and ``atw`` on the model region of assimp models (issue 50, part 2).

QUASAR's table 4 orders QUASAR > MeshWarp 120 > MeshWarp 60 > ATW.  This runs, per model (``+ground``, the fitted
``orbit``, ``cloud``, 320x180, 2 s, the project's defaults otherwise), in virtual time:

- ``atw``, ``warp`` (the baseline, measured in the same run), ``warp`` as the paper's MW 60
  (``reconstruction=mesh fov_scale=1``) and MW 120 (``fov_scale=3 resolution_scale=2/3``: 120 degrees at twice the
  display's resolution along each axis, as the paper's 3840x2160 for a 1080p client);
- ``quads`` (``variant=quasar``) from this checkout and, with ``--before PATH`` (a ``git worktree`` of the commit
  before the change), from that tree in the same run; ``--budget`` adds QUASAR with each stage of the error budget
  turned off or to its ideal; ``--thresholds`` adds QUASAR with reference frames also on distance and angle
  thresholds (its section 3.5.1); ``--baselines MW60,warp`` runs only those baselines; ``--quadstream`` adds
  ``variant=quadstream`` (about 4 minutes a model here).

``--trace static --duration 1 --no-ground --baselines ''`` is the claims ledger's still camera (its ``Q-T4-7`` cells:
the models alone, 1 s); ``--before-variants quadstream`` takes only QuadStream from the ``--before`` tree.

Each configuration runs in its own process (``PYTHONPATH`` picks the tree).  Scores: the mean model-region PSNR over
the displayed frames that show content (``model_psnr_content_db``; the runner's ``mean_model_psnr_db`` over all frames
is kept too), bits, and for ``quads`` the quads per reference frame, how many of them are background quads and the
reference frames' bytes as QUASAR counts them.

Writes ``benchmarks/results/bench_quads_models.json``.
Run: ``python benchmarks/bench_quads_models.py [--before /tmp/quads_before] [--budget] [--quadstream]``;
``--models`` also takes ``TextureTransformTest`` and ``default`` (the project's scene, which has its own ground).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _trees import commit_of, run_in_tree  # noqa: E402  (beside this script)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "bench_quads_models.json"
ASSIMP = Path("/usr/share/assimp/models")
MODELS = {"2CylinderEngine": ASSIMP / "glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb",
          "duck": ASSIMP / "Collada/duck.dae",
          "Wuson": ASSIMP / "PLY/Wuson.ply",
          "TextureTransformTest": ASSIMP / "glTF2/textureTransform/TextureTransformTest.gltf"}
BUILTIN = {"default"}
"""Scenes of the project's own, run as they are (no ``+ground``)."""
SETTINGS = {"trace": "orbit", "network": "cloud", "duration_s": 2.0, "width": 320, "height": 180, "flip_every": 0}
BASELINES = {"warp": ("warp", {}), "atw": ("atw", {}),
             "MW60": ("warp", {"reconstruction": "mesh", "fov_scale": 1.0}),
             "MW120": ("warp", {"reconstruction": "mesh", "fov_scale": 3.0, "resolution_scale": 2 / 3})}
BUDGET = {   # QUASAR with one stage off or at its ideal
    "flatten 0 (every quad keeps its offsets)": {"delta_flatten": 0.0, "relax": 1.0},
    "no merging (one quad a pixel, offsets kept)": {"delta_sim": 0.0, "coarse_passes": 0, "relaxed_coarse_passes": 0,
                                                    "delta_flatten": 0.0, "relax": 1.0},
    "1 layer": {"layers": 1}, "4 layers": {"layers": 4},
    "no wide view": {"wide_fov_deg": 0.0},
    "lossless atlas": {"lossless": True},
    "reference frames only": {"reference_every": 1},
}
THRESHOLDS = {   # QUASAR's reference frames also on its section 3.5.1 thresholds (turned, moved since the reference)
    "reference past 2 degrees": {"reference_angle_deg": 2.0},
    "reference past 1 degree": {"reference_angle_deg": 1.0},
    "reference past 5 cm or 2 degrees": {"reference_distance_m": 0.05, "reference_angle_deg": 2.0},
}

CHILD = r"""
import json, math, sys
import numpy as np
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import run
a = json.loads(sys.argv[1])
r = run(RunConfig(method=a["method"], method_params=a["params"], scene=a["scene"], truth_cache=a["truth_cache"], **a["settings"]))
fr, s = r.frames, r.summary
has = [f.get("update_frame_id", -1) != -1 for f in fr]
mp = [f.get("model_psnr_db", math.nan) for f, h in zip(fr, has) if h]
ups = r.updates
ref = [u for u in ups if u.get("srv_reference") == 1.0]
def mean(rows, k):
    v = [u[k] for u in rows if k in u and u[k] == u[k]]
    return float(np.mean(v)) if v else None
print("RESULT " + json.dumps({
    "model_psnr_content_db": float(np.nanmean(mp)) if mp else None, "mean_model_psnr_db": s.get("mean_model_psnr_db"),
    "mean_model_psnr_db_content": s.get("mean_model_psnr_db_content"),
    "mean_psnr_db": s["mean_psnr_db"], "mean_kbps": s["mean_kbps"], "kbps_quads": s.get("kbps_quads"),
    "content_frames": int(sum(has)), "frames": len(fr),
    "quads_per_reference": mean(ref, "srv_quads_ref"), "quads_per_frame": mean(ups, "srv_quads"),
    "quasar_bytes_reference": mean(ref, "srv_quasar_bytes"), "quasar_bytes": mean(ups, "srv_quasar_bytes"),
    "reference_frames": len(ref)}))
"""


def one(tree: Path, scene: str, method: str, params: dict, truth_cache: str, settings: dict) -> dict:
    """One run in its own process with ``tree`` on ``PYTHONPATH``; its numbers and wall seconds."""
    return run_in_tree(tree, CHILD, {"method": method, "params": params, "scene": scene, "settings": settings,
                                     "truth_cache": truth_cache}, f"{method} {params} on {scene}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", default=",".join(MODELS), help=f"comma-separated, of {', '.join(MODELS)}")
    ap.add_argument("--before", type=Path, help="a worktree of the commit before the change (QUASAR from it too)")
    ap.add_argument("--budget", action="store_true", help="QUASAR with each stage of the error budget off or ideal")
    ap.add_argument("--thresholds", action="store_true", help="QUASAR with reference frames on distance/angle thresholds")
    ap.add_argument("--baselines", default=",".join(BASELINES), help=f"comma-separated, of {', '.join(BASELINES)}")
    ap.add_argument("--quadstream", action="store_true", help="QuadStream too (slow)")
    ap.add_argument("--before-variants", default="quasar,quadstream", help="which variants to run from --before too")
    ap.add_argument("--trace", default=SETTINGS["trace"], help="the camera (static: the still camera)")
    ap.add_argument("--duration", type=float, default=SETTINGS["duration_s"], help="seconds")
    ap.add_argument("--no-ground", action="store_true", help="the models alone, as the claims ledger runs them")
    ap.add_argument("--truth-cache", default="default")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ns = ap.parse_args()
    missing = [m for m in ns.models.split(",") if m not in BUILTIN and not MODELS[m].exists()]
    if missing:
        sys.exit(f"bench_quads_models: assimp-testmodels is not installed ({', '.join(str(MODELS[m]) for m in missing)} missing)")
    settings = dict(SETTINGS, trace=ns.trace, duration_s=ns.duration)
    suffix = "" if ns.no_ground else "+ground"
    res: dict = {"machine": platform.platform(), "settings": settings, "scene_suffix": suffix,
                 "after": commit_of(ROOT, "splitrender/methods/quads"),
                 "before": commit_of(ns.before, "splitrender/methods/quads") if ns.before else None, "models": {}}
    for name in ns.models.split(","):
        scene = name if name in BUILTIN else f"{MODELS[name]}{suffix}"
        runs: dict = {}
        todo = [(k, ROOT, m, p) for k, (m, p) in BASELINES.items() if k in ns.baselines.split(",")]
        todo.append(("quasar", ROOT, "quads", {}))
        before = ns.before_variants.split(",") if ns.before else []
        if "quasar" in before:
            todo.append(("quasar before", ns.before, "quads", {}))
        if ns.budget:
            todo += [(f"quasar, {k}", ROOT, "quads", p) for k, p in BUDGET.items()]
        if ns.thresholds:
            todo += [(f"quasar, {k}", ROOT, "quads", p) for k, p in THRESHOLDS.items()]
        if ns.quadstream:
            todo.append(("quadstream", ROOT, "quads", {"variant": "quadstream"}))
            if "quadstream" in before:
                todo.append(("quadstream before", ns.before, "quads", {"variant": "quadstream"}))
        for label, tree, method, params in todo:
            r = one(tree, scene, method, params, ns.truth_cache, settings)
            r.update(method=method, params=params)
            runs[label] = r
            bl = "warp" if "warp" in runs else next(iter(runs))
            base = runs[bl]["model_psnr_content_db"]
            print(f"{name:16s} {label:48s} model {r['model_psnr_content_db']:6.2f} dB ({r['model_psnr_content_db'] - base:+.2f} "
                  f"against {bl})  frame {r['mean_psnr_db']:6.2f}  {r['mean_kbps']:8.0f} kbit/s  {r['wall_s']:5.0f} s",
                  flush=True)
            res["models"][name] = runs
            ns.out.parent.mkdir(parents=True, exist_ok=True)
            ns.out.write_text(json.dumps(res, indent=1))
    print(f"wrote {ns.out}")


if __name__ == "__main__":
    main()
