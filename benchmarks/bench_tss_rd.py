"""``tss`` against ``sas`` at ``sas``'s bits (issue 50 part 1): rate-distortion over ``tss``'s crf, before and after.

Issue 50's lossy target is ``tss`` within 1 dB of ``sas`` (model-region PSNR) at no more than ``sas``'s bits.  Earlier
benchmarks compared the two at one crf, where ``tss`` spent 2-3x the bits.  This one runs ``tss`` over a ladder of crfs
and reads its model PSNR at ``sas``'s bits off the ladder (linear in dB against log kbit/s between the two crfs that
bracket ``sas``'s rate; ``null`` when the ladder's lowest rate is still above it) and the bits it needs to come
within 1 dB of ``sas`` (the same interpolation the other way).

- scenes: assimp's duck, TextureTransformTest, 2CylinderEngine (Debian's assimp-testmodels; absent ones skipped)
  and ``default+nogi`` (``--scenes`` adds ``default gi``, the default scene with its GI); cameras ``still`` (``static``, ``ideal``) and ``orbit cloud`` (``orbit``, ``cloud``); 320x180,
  1 s, server 30 Hz, client 60 Hz (``bench_tss_matched.py``'s setting);
- ``sas`` at its defaults (crf 23), once per cell, in the "after" checkout;
- ``tss`` configurations (:data:`CONFIGS`) each over its crf ladder, in this checkout or ``--after TREE`` ("after") and, with
  ``--before TREE``, the same runs on another checkout (``git worktree add /tmp/before <commit>``) in the same
  invocation (``_trees.run_in_tree``), so both are measured on the same loaded machine.

Per run: model PSNR and DSSIM over the frames that show an update (the claims ledger's numbers), steady kbit/s and
each stream's share (atlas, tris, geo, meta), samples per update.  Writes (merging labels)
``benchmarks/results/bench_tss_rd.json``.  Run::

    git worktree add -f --detach /tmp/before <commit>
    nice python benchmarks/bench_tss_rd.py --before /tmp/before --label after --jobs 2
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).parent))
from _trees import commit_of, run_in_tree  # noqa: E402
from bench_tss_matched import BLOCK4, CAMERAS, HALF, SCENES as MATCHED_SCENES  # noqa: E402
SCENES = {**MATCHED_SCENES, "default gi": "default"}
"""``bench_tss_matched.py``'s scenes and the default scene with its GI (``--scenes`` picks it; not run by default)."""

RESULTS = Path(__file__).parent / "results" / "bench_tss_rd.json"
CONFIGS: dict[str, tuple[dict[str, Any], tuple[float, ...]]] = {
    "defaults": ({}, (23.0,)),
    "matched block4": (BLOCK4, (23.0, 31.0, 39.0)),
    "half block4": ({**HALF, "codec_block": 4}, (23.0, 31.0)),
    "matched block4 fill": ({**BLOCK4, "fill_pitch": True}, (31.0, 39.0)),
    "matched block4 colour": ({**BLOCK4, "colour_order": 16.0}, (31.0, 36.0, 41.0)),
    "defaults colour": ({"colour_order": 16.0}, (23.0,)),
    "defaults own": ({"lp_own": True}, (23.0,)),
    "matched block4 colour4": ({**BLOCK4, "colour_order": 4.0}, (31.0, 36.0, 41.0)),
    # issue 50 part 1, tss's own knobs at sas's bits (helper-49): "matched block4 colour" with one knob moved
    "mbc split4": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 4.0}, (31.0, 36.0, 41.0)),
    "mbc split8": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 8.0}, (31.0, 36.0, 41.0)),
    "mbc spp8": ({**BLOCK4, "colour_order": 16.0, "budget_max_spp": 8.0}, (31.0, 36.0, 41.0)),
    "mbc px2": ({**BLOCK4, "colour_order": 16.0, "budget_px": 2.0}, (31.0, 36.0, 41.0)),
    "mbc 420": ({**BLOCK4, "colour_order": 16.0, "chroma": "420"}, (31.0, 36.0, 41.0)),
    "mbc split16": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0}, (31.0, 36.0, 41.0)),
    "mbc nosplit": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 0.0}, (31.0, 36.0, 41.0)),
    "mbc split8 os": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 8.0, "slant_threshold": 1.0}, (31.0, 36.0, 41.0)),
    "mbc nosplit os": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 0.0, "slant_threshold": 1.0}, (31.0, 36.0, 41.0)),
    "mbc split16 px2": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "budget_px": 2.0}, (31.0, 33.0)),
    "mbc split16 flip8": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "flip_level": 8}, (31.0, 33.0)),
    "mbc split16 single1": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "single_px": 1}, (31.0, 33.0)),
    "mbc split16 420": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "chroma": "420"}, (26.0, 28.0, 31.0, 33.0)),
    "mbc split16 lp": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0}, (31.0, 33.0)),
    "mbc split16 lp 420": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                           "chroma": "420"}, (31.0, 33.0)),
    "mbc split16 lp 420 px4": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                               "chroma": "420", "budget_px": 4.0}, (32.0,)),
    "mbc split16 lp 420 block8": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                  "chroma": "420", "codec_block": 8}, (32.0,)),
    "mbc split16 lp 420 block8 cap1": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                       "chroma": "420", "codec_block": 8, "flip_cap": 1.0}, (32.0,)),
    "mbc split16 lp 420 block8 cap2": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                       "chroma": "420", "codec_block": 8, "flip_cap": 2.0}, (32.0,)),
    "mbc split16 lp 420 block8 cap3": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                       "chroma": "420", "codec_block": 8, "flip_cap": 3.0}, (32.0,)),
    "mbc split16 lp 420 block8 cap4": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                       "chroma": "420", "codec_block": 8, "flip_cap": 4.0}, (32.0,)),
    "mbc split16 lp 420 block8 flip0": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                        "chroma": "420", "codec_block": 8, "flip_level": 0}, (32.0,)),
    "mbc split16 os4c 420 block8": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 4.0,
                                    "os_grid": "centred", "os_min_rows": 2.0, "chroma": "420", "codec_block": 8}, (32.0,)),
    "mbc split16 os4c 420 block8 step15": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 4.0,
                                           "os_grid": "centred", "os_min_rows": 2.0, "os_min_step": 1.5, "chroma": "420",
                                           "codec_block": 8}, (32.0,)),
    "mbc split16 os4c 420 block8 step15 rows4": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 4.0,
                                                 "os_grid": "centred", "os_min_rows": 4.0, "os_min_step": 1.5,
                                                 "chroma": "420", "codec_block": 8}, (32.0,)),
    "mbc split16 lp 420 colour4": ({**BLOCK4, "colour_order": 4.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                   "chroma": "420"}, (32.0,)),
    "mbc split16 lp 420 block8 px4": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                      "chroma": "420", "codec_block": 8, "budget_px": 4.0}, (32.0, 33.0)),
    "mbc split16 lp 420 block8 px45": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                       "chroma": "420", "codec_block": 8, "budget_px": 4.5, "atlas_mpix_1080p": 48.0},
                                       (31.0, 35.0)),
    "mbc split16 lp 420 block8 own": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                      "chroma": "420", "codec_block": 8, "lp_own": True}, (31.0, 35.0)),
    "mbc split16 lp 420 block8 cubic": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                        "chroma": "420", "codec_block": 8, "lp_filter": "cubic"}, (31.0,)),
    "mbc split16 lp 420 block8 own cubic": ({**BLOCK4, "colour_order": 16.0, "split_near_m": 16.0, "slant_threshold": 1000.0,
                                            "chroma": "420", "codec_block": 8, "lp_own": True, "lp_filter": "cubic"}, (31.0,)),
}
"""Name -> (``tss`` parameters, crf ladder).  ``defaults``: ``tss`` as shipped (one sample per covered pixel);
``matched block4``: the claims ledger's ``TSS_MATCHED`` with ``codec_block = 4`` (``bench_tss_matched.py``, 0.6-1.2x
``sas``'s samples); ``half block4``: ``bench_tss_matched.py``'s ``HALF`` (the moving budget at 2 samples per display
pixel, up to 8 per covered pixel) with ``codec_block = 4``, fewer samples at a lower crf; ``matched block4 fill``:
``matched block4`` with ``fill_pitch`` (L-packing levels raised to fill their tip blocks' padding with samples);
``matched block4 colour`` and ``defaults colour``: the same with ``colour_order = 16`` (a repack's L-packing cells in the
order of their samples' mean luma, in bins of 16 levels); ``matched block4 colour4``: in bins of 4 levels.

``mbc ...`` (helper-49: tss's own knobs at ``sas``'s bits): ``matched block4 colour`` with one knob moved.
``split4`` / ``split8`` / ``split16`` / ``nosplit``: ``split_near_m`` 4, 8, 16 or 0 (the load-time split guarantees a
level of at most 64 at that distance at ``budget_max_spp``: each extra triangle is another tile in the atlas and more
geometry; the fitted still camera is 3.3-4.4 m from the models' centres, and at 16 m TextureTransformTest's largest
triangles are capped at ``v(64)`` samples: 82k samples, 158k at 2 m); ``spp8``: ``budget_max_spp = 8``; ``px2``:
``budget_px = 2``; ``420``: 4:2:0 chroma; ``os``: ``slant_threshold = 1`` (every triangle oversampled); ``split16
px2`` / ``flip8`` / ``single1`` / ``420`` / ``lp``: ``split16`` with ``budget_px = 2``, ``flip_level = 8``,
``single_px = 1``, 4:2:0 or ``slant_threshold = 1000`` (every triangle L-packed); ``split16 lp 420``: both, and ``px4`` / ``block8`` /
``colour4`` on top: ``budget_px = 4``, ``codec_block = 8``, ``colour_order = 4``; ``block8 px4``: the first two;
``block8 cap1`` ... ``cap4``: ``block8`` with ``flip_cap`` 1 to 4 (the flips' lift capped at that many times the
samples along the triangle's longest edge); ``block8 flip0``: ``block8`` with ``flip_level = 0``.  ``split16 os4c 420
block8`` (helper-66): ``split16 lp 420 block8`` with the slanted triangles (longest edge over height above 4) whose
height holds at least 2 samples oversampled on the centred grid (``os_min_rows = 2``), the rest L-packed; ``step15``: only those that L-packing would sample more than 1.5 px apart
along their longest edge (``os_min_step = 1.5``); ``step15 rows4``: with ``os_min_rows = 4``.  ``block8 px45`` (helper-74): ``split16 lp 420 block8`` at ``budget_px = 4.5``,
about ``sas``'s texels per display pixel (issue 50's "no more samples" read as a density matched to ``sas``'s), with
``atlas_mpix_1080p = 48``: at 24 the tip blocks' padding to 8 texels fills the atlas and holds the default scene's rate
at 3.1 (224k samples whatever the budget above 4).  ``block8 own`` (helper-74): ``split16 lp 420 block8`` with ``lp_own``
(L-packing levels chosen for the samples each patch holds for itself, its shared edge and corner samples counted
once); ``block8 cubic``: with ``lp_filter = "cubic"`` (the client reads L-packed triangles off their tip blocks'
diagonals with a Catmull-Rom filter, as ``sas``'s client reads its atlas; the same bits); ``block8 own cubic``: both.
``defaults own``: ``tss``'s defaults with ``lp_own``."""

CHILD = r"""
import json, sys
import numpy as np
from splitrender.render.renderer import Renderer
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import run
a = json.loads(sys.argv[1])
res = run(RunConfig(method=a["method"], scene=a["scene"], trace=a["trace"], network=a["network"], duration_s=1.0,
                    width=320, height=180, server_fps=30, client_fps=60, seed=0, flip_every=0,
                    method_params=a["params"], truth_cache="default"), renderer=Renderer())
shown = [f for f in res.frames if f["update_frame_id"] >= 0]
def mean(k):
    v = [float(f[k]) for f in shown if f.get(k) is not None]
    return float(np.nanmean(v)) if v else float("nan")
s = res.summary
print("RESULT " + json.dumps({
    "model_db": round(mean("model_psnr_db"), 3), "model_dssim": round(mean("model_dssim"), 5),
    "steady_kbps": round(float(s["steady_kbps"]), 1),
    "kbps": {k[5:]: round(float(v), 1) for k, v in s.items() if k.startswith("kbps_") and k != "kbps_session"},
    "samples": round(float(np.mean([u["srv_samples"] for u in res.updates if "srv_samples" in u])), 0)}))
"""


def interp(points: list[tuple[float, float]], x: float) -> float | None:
    """``y`` at ``x`` on the polyline through ``points`` (x increasing after sorting); None outside its span."""
    pts = sorted(points)
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        if x0 <= x <= x1:
            return y0 if x1 == x0 else y0 + (y1 - y0) * (x - x0) / (x1 - x0)
    return None


def at_sas(rows: list[dict[str, Any]], sas: dict[str, Any]) -> dict[str, Any]:
    """One ladder's dB at ``sas``'s bits and bits (over ``sas``'s) at ``sas``'s dB - 1."""
    lr = [(math.log(r["steady_kbps"]), r["model_db"]) for r in rows]
    db = interp(lr, math.log(sas["steady_kbps"]))
    need = interp([(d, x) for x, d in lr], sas["model_db"] - 1.0)
    lo = min(rows, key=lambda r: r["steady_kbps"])
    return {"db_minus_sas_at_sas_bits": None if db is None else round(db - sas["model_db"], 2),
            "bits_over_sas_within_1db": None if need is None else round(math.exp(need) / sas["steady_kbps"], 3),
            "lowest_rate": {"crf": lo["crf"], "bits_over_sas": round(lo["steady_kbps"] / sas["steady_kbps"], 3),
                            "db_minus_sas": round(lo["model_db"] - sas["model_db"], 2)},
            "ladder": [{"crf": r["crf"], "bits_over_sas": round(r["steady_kbps"] / sas["steady_kbps"], 3),
                        "db_minus_sas": round(r["model_db"] - sas["model_db"], 2)} for r in rows]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--label", default="after")
    ap.add_argument("--after", default="", help="the checkout measured as 'after' (default: this one)")
    ap.add_argument("--before", default="", help="a checkout of the commit before the change (its tss runs too)")
    ap.add_argument("--before-configs", default="", help="configs run on --before (default: all)")
    ap.add_argument("--after-configs", default="", help="configs run on the after tree (default: all)")
    ap.add_argument("--scenes", default=",".join(MATCHED_SCENES))
    ap.add_argument("--cameras", default="still,orbit cloud")
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--crfs", default="", help="comma-separated crfs replacing every config's ladder")
    ap.add_argument("--before-crfs", default="", help="comma-separated crfs of the --before runs (default: the ladder)")
    ap.add_argument("--reuse", default="", help="a file of rows this benchmark printed (one JSON a line): runs found "
                                                 "there (scene, camera, tree, config, crf) are taken, not run again")
    ap.add_argument("--sas-bilinear", action="store_true", help="also run sas with atlas_filter=bilinear (row config "
                                                                 "'sas bilinear': how much sas's Catmull-Rom client filter buys)")
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args()
    crfs_all = tuple(float(c) for c in a.crfs.split(",") if c)
    crfs_before = tuple(float(c) for c in a.before_crfs.split(",") if c)
    trees = {"after": Path(a.after).resolve() if a.after else ROOT}
    if a.before:
        trees["before"] = Path(a.before).resolve()
    bconf = set((a.before_configs or a.configs).split(","))
    aconf = set((a.after_configs or a.configs).split(","))
    jobs: list[dict[str, Any]] = []
    for scene in a.scenes.split(","):
        if SCENES[scene].startswith("/") and not Path(SCENES[scene]).exists():
            print(f"skip {scene}: absent", file=sys.stderr)
            continue
        for camera in a.cameras.split(","):
            trace, network = CAMERAS[camera]
            base = {"scene": SCENES[scene], "trace": trace, "network": network}
            jobs.append({"cell": (scene, camera), "tree": "after", "config": "sas", "crf": 23.0,
                         "arg": {**base, "method": "sas", "params": {}}})
            if a.sas_bilinear:
                jobs.append({"cell": (scene, camera), "tree": "after", "config": "sas bilinear", "crf": 23.0,
                             "arg": {**base, "method": "sas", "params": {"atlas_filter": "bilinear"}}})
            for name in a.configs.split(","):
                params, crfs = CONFIGS[name]
                for tree in trees:
                    if (tree == "before" and name not in bconf) or (tree == "after" and name not in aconf):
                        continue
                    for crf in (crfs_before if tree == "before" and crfs_before else crfs_all or crfs):
                        jobs.append({"cell": (scene, camera), "tree": tree, "config": name, "crf": crf,
                                     "arg": {**base, "method": "tss", "params": {**params, "crf": crf}}})
    t0 = time.perf_counter()
    key = (lambda r: (r["scene"], r["camera"], r["tree"], r["config"], float(r["crf"])))
    reused = {key(r): r for r in (json.loads(x) for x in Path(a.reuse).read_text().splitlines() if x.startswith("{"))} if a.reuse else {}

    def one(j: dict[str, Any]) -> dict[str, Any]:
        old = reused.get((j["cell"][0], j["cell"][1], j["tree"], j["config"], float(j["crf"])))
        if old is not None:
            return {**old, "reused": True}
        r = run_in_tree(trees[j["tree"]], CHILD, j["arg"], f"{j['cell']} {j['config']} crf {j['crf']}")
        row = {"scene": j["cell"][0], "camera": j["cell"][1], "tree": j["tree"], "config": j["config"], "crf": j["crf"],
               **{k: v for k, v in r.items() if k != "wall_s"}, "wall_s": round(r["wall_s"], 1)}
        print(json.dumps(row), flush=True)
        return row

    with ThreadPoolExecutor(a.jobs) as ex:
        rows = list(ex.map(one, jobs))
    summary: dict[str, Any] = {}
    for scene, camera in dict.fromkeys(j["cell"] for j in jobs):
        cell = [r for r in rows if r["scene"] == scene and r["camera"] == camera]
        sas = next(r for r in cell if r["config"] == "sas")
        out: dict[str, Any] = {"sas": {k: sas[k] for k in ("model_db", "model_dssim", "steady_kbps", "kbps", "samples")}}
        for r in cell:
            if r["config"] == "sas bilinear":
                out["sas bilinear"] = {"model_db_minus_sas": round(r["model_db"] - sas["model_db"], 2),
                                       "bits_over_sas": round(r["steady_kbps"] / sas["steady_kbps"], 3)}
        for tree in trees:
            for name in CONFIGS:
                ladder = sorted((r for r in cell if r["tree"] == tree and r["config"] == name), key=lambda r: r["crf"])
                if ladder:
                    out[f"{name} | {tree}"] = at_sas(ladder, sas)
        dflt = [r for r in cell if r["tree"] == "after" and r["config"] == "defaults" and r["crf"] == 23.0]
        mb4 = [r for r in cell if r["tree"] == "after" and r["config"] == "matched block4"]
        if dflt and len(mb4) > 1:   # the default question: matched block4 at the defaults' bits
            db = interp([(math.log(r["steady_kbps"]), r["model_db"]) for r in mb4], math.log(dflt[0]["steady_kbps"]))
            out["matched block4 at the defaults' bits"] = {
                "db_minus_defaults": None if db is None else round(db - dflt[0]["model_db"], 2),
                "defaults_bits_over_sas": round(dflt[0]["steady_kbps"] / sas["steady_kbps"], 3)}
        summary[f"{scene} | {camera}"] = out
    data = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    data.setdefault("setting", "320x180, 1 s, server 30 Hz, client 60 Hz; still = static/ideal, orbit cloud = orbit/cloud; "
                               "model PSNR and DSSIM over the frames showing an update; sas at its defaults (crf 23) in the "
                               "after tree; tss over each config's crf ladder in each tree, the same invocation")
    data[a.label] = {"trees": {k: commit_of(v) for k, v in trees.items()}, "seconds": round(time.perf_counter() - t0, 1),
                     "runs": rows, "at_sas_bits": summary}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(data, indent=1) + "\n")
    for k, v in summary.items():
        for n, s in v.items():
            if n != "sas" and "ladder" in s:
                print(f"{k:40s} {n:28s} at sas bits {s['db_minus_sas_at_sas_bits']} dB; within 1 dB at "
                      f"{s['bits_over_sas_within_1db']}x; lowest {s['lowest_rate']}")


if __name__ == "__main__":
    main()
