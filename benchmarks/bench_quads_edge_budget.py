"""Where QUASAR's and MeshWarp 60's model error sits, by pixel class (issue 50, part 2).

Runs one claims-ledger cell (a model alone, ``cloud``, 320x180, 1 s, server 30 Hz, client 60 Hz) for ``quads``
(QUASAR) at each ``--variants`` setting and for MeshWarp 60 (``warp`` as the ledger's ``Q-T4-4`` runs it), keeps every
displayed frame with its holes and ground truth, and splits the squared error over the model's pixels (the truth's
model mask) of the frames with content into:

- ``hole``: model pixels the client covered with no geometry (filled by the hole fill);
- ``silhouette``: other model pixels with a non-model pixel among their 8 neighbours in the truth;
- ``interior``: the rest.

Each class's share of the model's pixels and of its squared error, and its PSNR (pooled MSE), are written with the
run's own model PSNR (the mean over frames with content, the ledger's figure) and bit rate; and per displayed update
the first and the second display of it (16.7 ms later) apart.  Writes ``benchmarks/results/bench_quads_edge_budget.json``.

    python benchmarks/bench_quads_edge_budget.py [--scene 2CylinderEngine] [--trace orbit] \\
        [--variants 'default={};off={"underlap_px":0.0};seal={"underlap_px":0.0,"seal_cracks":true}']
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from splitrender import metrics  # noqa: E402

ASSIMP = "/usr/share/assimp/models"
SCENES = {"2CylinderEngine": f"{ASSIMP}/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb",
          "duck": f"{ASSIMP}/Collada/duck.dae",
          "TextureTransformTest": f"{ASSIMP}/glTF2/textureTransform/TextureTransformTest.gltf", "default": "default"}
MW60 = {"depth_coding": "bc4", "extrapolate": False, "fov_scale": 1.0, "reconstruction": "mesh", "resolution_scale": 1.0}


def _db(sse: float, n: float) -> float:
    return 10 * math.log10(255.0 ** 2 / max(sse / max(n, 1.0), 1e-10))


def run_cell(method: str, params: dict[str, Any], scene: str, trace: str, duration: float) -> dict[str, Any]:
    """One run, every scored frame kept; its class budget."""
    from scipy.ndimage import binary_erosion

    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import run

    kept: list[tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]] = []
    score = metrics.score_frame

    def keep(shown, holes, truth, geometry, *a, truth_model=None, **k):  # type: ignore[no-untyped-def]
        kept.append((shown.copy(), None if holes is None else holes.copy(), truth.copy(), np.asarray(truth_model).copy()))
        return score(shown, holes, truth, geometry, *a, truth_model=truth_model, **k)

    metrics.score_frame = keep
    try:
        t0 = time.perf_counter()
        res = run(RunConfig(method=method, method_params=params, scene=scene, trace=trace, network="cloud", width=320,
                            height=180, duration_s=duration, server_fps=30, client_fps=60, flip_every=0))
        wall = time.perf_counter() - t0
    finally:
        metrics.score_frame = score
    classes = {k: [0.0, 0.0] for k in ("hole", "silhouette", "interior", "model")}
    first: list[float] = []
    second: list[float] = []
    seen: set[int] = set()
    for row, (shown, holes, truth, model) in zip(res.frames, kept):
        fid = row.get("update_frame_id")
        if fid is None or fid < 0 or not model.any():
            continue
        err = ((shown.astype(np.float64) - truth.astype(np.float64)) ** 2).mean(-1)
        h = np.zeros(model.shape, bool) if holes is None else holes
        inner = binary_erosion(model, np.ones((3, 3), bool))
        for k, m in (("hole", model & h), ("silhouette", model & ~inner & ~h), ("interior", inner & ~h), ("model", model)):
            classes[k][0] += float(err[m].sum())
            classes[k][1] += float(m.sum())
        (second if fid in seen else first).append(float(err[model].mean()))
        seen.add(fid)
    tot_sse, tot_n = classes["model"]
    s = res.summary
    return {"method": method, "params": params, "wall_s": round(wall, 1),
            "model_psnr_db": s["mean_model_psnr_db_content"], "psnr_db": s["mean_psnr_db_content"],
            "kbps": s["mean_kbps"], "mean_pred_err_cm": s["mean_pred_err_cm"], "mean_update_age_ms": s["mean_update_age_ms"],
            "classes": {k: {"px_pct": 100 * n / tot_n, "sse_pct": 100 * e / tot_sse, "psnr_db": _db(e, n)}
                        for k, (e, n) in classes.items()},
            "first_display_model_psnr_db": _db(sum(first), len(first)) if first else None,
            "second_display_model_psnr_db": _db(sum(second), len(second)) if second else None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="2CylinderEngine", choices=sorted(SCENES))
    ap.add_argument("--trace", default="orbit")
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--variants", default='default={};off={"underlap_px":0.0};seal={"underlap_px":0.0,"seal_cracks":true}',
                    help="QUASAR settings, name=JSON separated by ';' (default: %(default)s)")
    ap.add_argument("--no-warp", action="store_true", help="leave MeshWarp 60 out")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/bench_quads_edge_budget.json"))
    args = ap.parse_args(argv)
    variants: dict[str, dict[str, Any]] = {}
    for item in filter(None, (v.strip() for v in args.variants.split(";"))):
        name, _, text = item.partition("=")
        try:
            params = json.loads(text)
        except json.JSONDecodeError as e:
            ap.error(f"--variants {item!r}: not name=JSON ({e})")
        if not isinstance(params, dict):
            ap.error(f"--variants {item!r}: the JSON must be an object")
        variants[name] = params
    scene = SCENES[args.scene]
    rows: dict[str, Any] = {}
    for name, params in variants.items():
        rows[f"quasar {name}"] = run_cell("quads", params, scene, args.trace, args.duration)
        print(f"quasar {name}: model {rows[f'quasar {name}']['model_psnr_db']:.3f} dB", flush=True)
    if not args.no_warp:
        rows["MW60"] = run_cell("warp", MW60, scene, args.trace, args.duration)
        print(f"MW60: model {rows['MW60']['model_psnr_db']:.3f} dB", flush=True)
    import subprocess
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    out = {"benchmark": "bench_quads_edge_budget", "scene": args.scene, "trace": args.trace, "network": "cloud",
           "size": "320x180", "duration_s": args.duration, "commit": commit, "rows": rows}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    for name, r in rows.items():
        c = r["classes"]
        print(f"{name:16s} model {r['model_psnr_db']:.2f} | " + "  ".join(
            f"{k} {c[k]['px_pct']:.1f}% px {c[k]['sse_pct']:.1f}% SSE {c[k]['psnr_db']:.2f} dB" for k in ("hole", "silhouette", "interior")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
