"""One still frame of ``tss`` and ``sas`` with the atlas as shaded (no codec): model PSNR per object (issue 50 part 1).

The reconstruction alone, without the video codec: what the sampling and the client's filter give, per object of the
scene, at a given sample count (``docs/methods.md``, "The samples a patch holds for itself, and the client's filter").
Each run: ``static`` trace at 0.5 s, 320x180, zero latency; the server's first update applied to a fresh client and
drawn at the same pose; PSNR against the ground truth on the model (every object but the ground) and on each object
covering over 300 pixels; the samples of that update (``tss``: its plan; ``sas``: its atlas blocks' texels) and
``tss``'s sampling rate.  ``tss`` runs start from :data:`BASE` (``bench_tss_rd.py``'s ``mbc split16 lp 420 block8``
sampling with 4:4:4 chroma, which no codec reads here) with each variant's parameters on top.

Writes (merging labels) ``benchmarks/results/bench_tss_frame.json``.  Run::

    python benchmarks/bench_tss_frame.py --label NAME

(about a minute a scene on an idle machine).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

RESULTS = Path(__file__).parent / "results" / "bench_tss_frame.json"
BASE = {"budget_px": 3.0, "chroma": "444", "sliver_px": 1.0, "flip_level": 16, "hysteresis": 0.75, "pvs_ring": 1,
        "budget_max_spp": 16.0, "codec_block": 8, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0}
"""``bench_tss_rd.py``'s ``mbc split16 lp 420 block8`` less its 4:2:0 chroma (a codec setting)."""
MATCHED = {"budget_px": 4.5, "atlas_mpix_1080p": 48.0}
"""About ``sas``'s samples: 4.5 per display pixel, with an atlas the tip blocks' padding to 8 texels does not fill."""
SLANT = {"slant_threshold": 4.0, "os_grid": "centred", "os_min_rows": 4.0, "os_min_step": 1.5}
MODELS = "/usr/share/assimp/models"
SCENES = {"default": "default+nogi", "duck": f"{MODELS}/Collada/duck.dae",
          "2CylinderEngine": f"{MODELS}/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb",
          "TextureTransformTest": f"{MODELS}/glTF2/textureTransform/TextureTransformTest.gltf"}
RUNS: dict[str, tuple[str, dict[str, Any]]] = {
    "sas": ("sas", {}), "sas bilinear": ("sas", {"atlas_filter": "bilinear"}),
    "tss": ("tss", {}), "tss cubic": ("tss", {"lp_filter": "cubic"}), "tss own": ("tss", {"lp_own": True}),
    "tss own cubic": ("tss", {"lp_own": True, "lp_filter": "cubic"}),
    "tss matched": ("tss", MATCHED), "tss matched own": ("tss", {**MATCHED, "lp_own": True}),
    "tss matched own slant": ("tss", {**MATCHED, **SLANT, "lp_own": True}),
    "tss split4": ("tss", {"split_near_m": 4.0}), "tss split4 cubic": ("tss", {"split_near_m": 4.0, "lp_filter": "cubic"}),
    "tss split4 matched": ("tss", {**MATCHED, "split_near_m": 4.0}),
}
"""Name -> (method, parameters; ``tss``'s on top of :data:`BASE`)."""


def frame(renderer: Any, method: str, scene_name: str, params: dict[str, Any], t: float = 0.5) -> dict[str, Any]:
    """One update of ``method`` at the ``static`` pose, drawn by a fresh client: PSNR on the model and per object."""
    from splitrender.methods import get_method, make_config
    from splitrender.pipeline.direct import still_frame
    from splitrender.scene.loader import get_scene
    from splitrender.scene.pose import CameraIntrinsics
    from splitrender.scene.trace import get_trace

    intr = CameraIntrinsics(320, 180)
    scene = get_scene(scene_name)
    spec = get_method(method)
    cfg = make_config(spec.config, params)
    pose = get_trace("static", scene=scene).pose_at(t)
    still = still_frame(spec, cfg, intr, scene, renderer, pose, t)
    truth = renderer.render(scene, t, pose, intr, ("color", "object_id"))
    got = still.frame.color   # type: ignore[union-attr]
    stats = getattr(still.server, "_stats", {})

    def db(m: np.ndarray) -> float:
        e = float(np.mean((got[m].astype(np.float64) - truth.color[m].astype(np.float64)) ** 2))
        return round(10.0 * np.log10(255.0 ** 2 / max(e, 1e-9)), 2)

    model = truth.object_id > 0
    for o in scene.objects:
        if o.name in ("ground", "floor"):
            model &= truth.object_id != o.object_id
    out: dict[str, Any] = {"samples": stats.get("samples"), "rate": round(float(stats.get("rate", 0.0)), 3),
                           "model_db": db(model), "objects": {}}
    for o in scene.objects:
        m = truth.object_id == o.object_id
        if m.sum() > 300:
            out["objects"][o.name] = db(m)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--label", default="after")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--runs", default=",".join(RUNS))
    a = ap.parse_args()
    from splitrender.render.renderer import Renderer

    from _trees import commit_of  # noqa: E402  (benchmarks/ is the script's directory)

    renderer = Renderer()
    t0 = time.perf_counter()
    rows = []
    for scene in a.scenes.split(","):
        if SCENES[scene].startswith("/") and not Path(SCENES[scene]).exists():
            continue
        for name in a.runs.split(","):
            method, params = RUNS[name]
            r = frame(renderer, method, SCENES[scene], params if method == "sas" else {**BASE, **params})
            rows.append({"scene": scene, "run": name, **r})
            print(f"{scene:22s} {name:24s} {r['model_db']:6.2f} dB  {r['samples']:>9}  rate {r['rate']}", flush=True)
    import splitrender

    data = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    data.setdefault("setting", "one still frame (static, 0.5 s), 320x180, the atlas as shaded (no codec), zero latency; "
                               "tss from BASE plus each run's parameters; PSNR on the model (every object but the ground)")
    data[a.label] = {"tree": commit_of(Path(splitrender.__file__).resolve().parents[1]),
                     "seconds": round(time.perf_counter() - t0, 1), "base": BASE, "rows": rows}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(data, indent=1) + "\n")


if __name__ == "__main__":
    main()
