"""``tss`` against ``sas`` at matched sample counts (issue 50 part 1, claim T-T4-1): DSSIM, model PSNR, bits.

The TSS paper's table 4 gives TSS 0.48-1.61x SAS's samples and a lower DSSIM.  At its default (one sample per
covered pixel, the paper's O1) our ``tss`` shades 0.07-0.18x ``sas``'s samples on the models, so the ledger compared
unequal budgets.  This benchmark runs, on assimp's duck, TextureTransformTest, 2CylinderEngine (Debian's
assimp-testmodels; absent ones skipped) and ``default+nogi`` (the ledger's default scene), 320x180, 1 s:

- cameras: ``still`` (``static``, ``ideal``: the ledger's still cell), ``orbit`` (``orbit``, ``ideal``: the ledger's
  moving cell) and ``orbit cloud`` (``orbit``, ``cloud``: issue 50's moving target);
- ``sas`` at its defaults, lossy and lossless (the baseline, measured in the same process);
- ``tss old``: ``tss`` at its defaults as of issue 50 part 1 (:data:`OLD_DEFAULTS`: one sample per covered pixel, the
  paper's O1; spelled out so the row means the same whatever the defaults become);
- ``tss half``: the moving budget with every measured fix (:data:`HALF`: ``budget_px = 2``, about 0.4-0.75x
  ``sas``'s samples);
- ``tss equal``: the same at ``budget_px = 4.5`` (:data:`EQUAL`: about ``sas``'s samples where the model's coverage
  lets the rate reach ``budget_max_spp``);
- ``tss matched``: :data:`MATCHED`, 0.63-1.15x ``sas``'s samples on the three models;
- ``tss matched block4``: :data:`MATCHED` with ``codec_block = 4`` (the atlas aligned to the codec's 4 x 4 transform
  blocks, ``bench_tss_codec.py``);
- ``tss now``: ``tss`` at the current defaults; ``tss now block1`` / ``tss now block4`` the same with ``codec_block``
  1 and 4;
- each ``tss`` run lossy and lossless, and ``--crf`` adds lossy runs at other crfs (bits against quality).

Per run: model DSSIM and PSNR over the frames that show an update (``_shown``: the claims ledger's numbers; the
comparisons use these), the summary's ``mean_model_dssim`` and ``mean_model_psnr_db`` over every frame, start-up
ticks included, interior and edge PSNR, steady kbit/s and samples per update.  Writes (merging labels)
``benchmarks/results/bench_tss_matched.json``; prints tss minus sas per cell.  Run::

    nice python benchmarks/bench_tss_matched.py --label after

(about 20 minutes on 2 cores with a warm truth cache for three configurations; ``--scenes``, ``--cameras``, ``--configs``
and ``--size`` measure a subset).
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
sys.path.insert(0, str(ROOT))  # run from a checkout
from splitrender.experiments.studies.claims import TSS_MATCHED  # noqa: E402  (the ledger's diagnostic, one source)
RESULTS = Path(__file__).parent / "results" / "bench_tss_matched.json"
SCENES = {"duck": "/usr/share/assimp/models/Collada/duck.dae",
          "TextureTransformTest": "/usr/share/assimp/models/glTF2/textureTransform/TextureTransformTest.gltf",
          "2CylinderEngine": "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb",
          "default": "default+nogi"}
CAMERAS = {"still": ("static", "ideal"), "orbit": ("orbit", "ideal"), "orbit cloud": ("orbit", "cloud")}
OLD_DEFAULTS = {"samples_per_px": 1.0, "budget_px": 0.0, "chroma": "420", "sliver_px": 0.0, "flip_level": 0,
                "hysteresis": 0.25, "pvs_ring": 0}
"""``tss``'s defaults as of issue 50 part 1 (the paper's O1: one sample per covered pixel), unchanged by it."""
HALF = {"budget_px": 2.0, "chroma": "444", "sliver_px": 1.0, "flip_level": 8, "hysteresis": 0.75, "pvs_ring": 1}
"""The moving budget at 2 samples per display pixel with slivers, flips and the PVS ring (``bench_tss_models``'s
``RINGS``)."""
EQUAL = {**HALF, "budget_px": 4.5}
""":data:`HALF` at 4.5 samples per display pixel (``sas`` shades 2.5-4.5 texels per display pixel here)."""
MATCHED = TSS_MATCHED
assert MATCHED == {**HALF, "budget_px": 3.0, "budget_max_spp": 16.0, "flip_level": 16}
""":data:`HALF` at 3 samples per display pixel (the claims ledger's ``tss matched``), up to 16 per covered pixel (``sas``'s own cap on textured patches), the
flip's triangles at level 16: 0.66-1.15x ``sas``'s samples on the four scenes."""
BLOCK4 = {**MATCHED, "codec_block": 4}
""":data:`MATCHED` with its L-packing tip blocks and oversampling shelves aligned to the codec's 4 x 4 transform blocks
(``codec_block = 4``; the padding filled from each block's own texels): ``bench_tss_codec.py``."""
CONFIGS = {"tss old": OLD_DEFAULTS, "tss half": HALF, "tss equal": EQUAL, "tss matched": MATCHED, "tss matched block4": BLOCK4,
           "tss now": {}, "tss now block1": {"codec_block": 1}, "tss now block4": {"codec_block": 4}}


def one(renderer: Any, scene: str, camera: str, method: str, params: dict[str, Any],
        size: tuple[int, int] = (320, 180)) -> dict[str, Any]:
    import numpy as np

    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import run

    trace, network = CAMERAS[camera]
    t0 = time.perf_counter()
    res = run(RunConfig(method=method, scene=SCENES[scene], trace=trace, network=network, duration_s=1.0, width=size[0],
                        height=size[1], server_fps=30, client_fps=60, seed=0, flip_every=0, method_params=params,
                        truth_cache="default"), renderer=renderer)
    shown = [f for f in res.frames if f["update_frame_id"] >= 0]

    def mean(key: str) -> float:
        v = [float(f[key]) for f in shown if f.get(key) is not None]
        return float(np.nanmean(v)) if v else float("nan")

    s = res.summary
    return {"scene": scene, "camera": camera, "method": method, "params": params, "size": list(size),
            "model_dssim": round(float(s["mean_model_dssim"]), 5), "model_db": round(float(s["mean_model_psnr_db"]), 3),
            "model_dssim_shown": round(mean("model_dssim"), 5), "model_db_shown": round(mean("model_psnr_db"), 3),
            "interior_db": round(mean("interior_psnr_db"), 3), "edge_db": round(mean("edge_psnr_db"), 3),
            "steady_kbps": round(float(s["steady_kbps"]), 1),
            "samples": round(float(np.mean([u["srv_samples"] for u in res.updates if "srv_samples" in u])), 0),
            "seconds": round(time.perf_counter() - t0, 1)}


def measure(scenes: list[str], cameras: list[str], configs: list[str], crfs: list[float],
            lossless: bool = True, size: tuple[int, int] = (320, 180)) -> list[dict[str, Any]]:
    from splitrender.render.renderer import Renderer

    renderer = Renderer()
    out = []
    for scene in scenes:
        if SCENES[scene].startswith("/") and not os.path.exists(SCENES[scene]):
            print(f"skip {scene}: absent", file=sys.stderr)
            continue
        for camera in cameras:
            todo: list[tuple[str, str, dict[str, Any]]] = [("sas", "sas", {})]
            if lossless:
                todo.append(("sas lossless", "sas", {"lossless": True}))
            for c in configs:
                todo.append((c, "tss", CONFIGS[c]))
                if lossless:
                    todo.append((c + " lossless", "tss", {**CONFIGS[c], "lossless": True}))
                for crf in crfs:
                    todo.append((f"{c} crf{crf:g}", "tss", {**CONFIGS[c], "crf": crf}))
            for name, method, params in todo:
                row = {"run": name, **one(renderer, scene, camera, method, params, size)}
                print(json.dumps(row), flush=True)
                out.append(row)
    return out


def compare(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per scene and camera, each ``tss`` run against ``sas`` (lossy, and lossless against lossless)."""
    out: dict[str, dict[str, Any]] = {}
    for r in rows:
        if r["method"] != "tss":
            continue
        ll = bool(r["params"].get("lossless"))
        base = next((b for b in rows if b["method"] == "sas" and b["scene"] == r["scene"] and b["camera"] == r["camera"]
                     and bool(b["params"].get("lossless")) == ll), None)
        if base is None:
            continue
        out[f"{r['scene']} | {r['camera']} | {r['run']}"] = {
            "dssim_minus_sas": round(r["model_dssim_shown"] - base["model_dssim_shown"], 5),
            "db_minus_sas": round(r["model_db_shown"] - base["model_db_shown"], 2),
            "db_minus_sas_all_frames": round(r["model_db"] - base["model_db"], 2),
            "bits_over_sas": round(r["steady_kbps"] / base["steady_kbps"], 3),
            "samples_over_sas": round(r["samples"] / base["samples"], 3)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--label", default="after")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--cameras", default=",".join(CAMERAS))
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--crf", default="", help="comma-separated extra crfs for the lossy tss runs")
    ap.add_argument("--no-lossless", action="store_true")
    ap.add_argument("--size", default="320x180", help="display WxH (320x180: the claims ledger's)")
    a = ap.parse_args()
    t0 = time.perf_counter()
    rows = measure(a.scenes.split(","), a.cameras.split(","), a.configs.split(","),
                   [float(c) for c in a.crf.split(",") if c], not a.no_lossless,
                   tuple(int(v) for v in a.size.split("x")))  # type: ignore[arg-type]
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    data = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    data.setdefault("setting", "320x180, 1 s, server 30 Hz, client 60 Hz; still = static/ideal, orbit = orbit/ideal, orbit "
                               "cloud = orbit/cloud; model DSSIM and PSNR: _shown over the frames showing an update (the "
                               "claims ledger's, used by against_sas), without it the summary's means over every frame; "
                               "sas at its defaults measured in the same process")
    data.setdefault("machine", f"{platform.node()} ({platform.machine()}, {os.cpu_count()} cpus, llvmpipe)")
    data[a.label] = {"commit": commit, "seconds": round(time.perf_counter() - t0, 1), "runs": rows, "against_sas": compare(rows)}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(data, indent=1) + "\n")
    for k, v in data[a.label]["against_sas"].items():
        print(f"{k:60s} {v}")


if __name__ == "__main__":
    main()
