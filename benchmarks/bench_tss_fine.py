"""``tss`` on fine meshes with a lossy atlas (issue 33): lossy against lossless against ``sas``, and what each idea adds.

Still camera (``static``), zero latency (``ideal``), 320x180, 1 s, H.264 4:2:0 at the default crf, on assimp's duck
(``/usr/share/assimp/models/Collada/duck.dae``, skipped when absent) split fine at load (``split_near_m = 0.0483``:
191k triangles, of which the 14.3k in view are all single texels; the split every earlier commit made of the duck,
whose object-space bound missed its 1/41 scale) and on the default scene (also on its 1 s walk).  The duck at its
own scale (``duck own``: the default split since the scale fix, 4.2k triangles) gets the three headline runs.  For each run: PSNR (the
summary's mean over every displayed frame, as ``splitrender run`` reports it), kbit/s of every stream and each
stream's share.  Quoted as dB differences and bit ratios: ``tss`` lossy against its lossless atlas and against
``sas`` (the issue's target: within 2 and 1 dB, at no more of ``sas``'s bits), and each idea against the final
configuration with that idea taken away:

- ``single_px = 1``: one texel per single-texel triangle instead of a 2 x 2 cell (a 4:2:0 chroma sample of its own);
- ``spatial_order = true`` (off by default): triangle ids along a Z-order curve of their centroids instead of the split
  mesh's order;
- rows: single texels along rows of their shelf instead of Z-ordered 16 x 16 tiles (``layout.single_origins``
  replaced in this process, the client's decode with it), with ``single_px = 1``: the old layout, with the new
  geometry and table coding;
- ``high_water = 0.9`` (walk only): the atlas repacked on I-frames only once 90 % full, the old default, instead of
  on every I-frame;
- before: the ``tss`` of commit :data:`BEFORE` (the code this work started from), run from ``git archive`` in a child
  process: 1-texel rows, ``f32`` geometry, ``u32`` slots, no guard texel in odd L-packing blocks.

Writes ``benchmarks/results/bench_tss_fine.json``.  Run: ``python benchmarks/bench_tss_fine.py`` (about 4 minutes on
2 cores).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's package, not an installed one

RESULTS = Path(__file__).parent / "results" / "bench_tss_fine.json"
DUCK = "/usr/share/assimp/models/Collada/duck.dae"
BEFORE = "d293e8e"
FINE_DUCK = {"split_near_m": 0.0483}
"""The duck's split before the scale fix: 2 m x its 0.02417 placement scale."""
BASE: dict[str, Any] = dict(network="ideal", width=320, height=180, duration_s=1.0, flip_every=0, seed=0)
KEYS = ("mean_psnr_db", "mean_fg_psnr_db", "mean_kbps", "kbps_atlas", "kbps_tris", "kbps_geo", "kbps_meta")

_RUN = """
import json, sys
sys.path.insert(0, sys.argv[1])
from splitrender.render.renderer import Renderer
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import run
r = Renderer()
out = []
for cfg in json.loads(sys.argv[2]):
    s = run(RunConfig.from_dict(cfg), renderer=r).summary
    out.append({k: float(s[k]) for k in json.loads(sys.argv[3]) if k in s})
print("RESULT " + json.dumps(out))
"""


def _summary(s: dict[str, Any]) -> dict[str, float]:
    return {k: float(s[k]) for k in KEYS if k in s}


def _rows_layout() -> Any:
    """Single texels along rows of their shelf (the ablation of the Z-ordered tiles): patches both halves' lookups."""
    from splitrender.methods.tss import layout, wire

    def rows(slot: np.ndarray, shelves: np.ndarray, strip: int, px: int) -> np.ndarray:
        slot = np.asarray(slot, np.int64)
        per = layout.single_per_shelf(strip, px)
        across = (strip // layout.SINGLE_TILE) * layout.SINGLE_TILE // px
        sh = np.asarray(shelves, np.int64).reshape(-1, 2)[slot // per]
        k = slot % per
        return np.stack([sh[:, 0] + (k % across) * px, sh[:, 1] + (k // across) * px], 1)

    saved = layout.single_origins
    layout.single_origins = wire.single_origins = rows

    def undo() -> None:
        layout.single_origins = wire.single_origins = saved

    return undo


def _before(cfgs: list[dict[str, Any]]) -> list[dict[str, float]] | None:
    """The runs ``cfgs`` with commit :data:`BEFORE`'s package, in a child process; None when git cannot give it."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            arch = subprocess.run(["git", "-C", str(ROOT), "archive", BEFORE, "splitrender"], check=True, capture_output=True).stdout
            subprocess.run(["tar", "-x", "-C", tmp], input=arch, check=True)
        except (OSError, subprocess.CalledProcessError) as e:
            print(f"before: no commit {BEFORE} here ({e}); skipped")
            return None
        p = subprocess.run([sys.executable, "-c", _RUN, tmp, json.dumps(cfgs), json.dumps(KEYS)], capture_output=True, text=True,
                           check=True, cwd=tmp)
        line = next(x for x in p.stdout.splitlines() if x.startswith("RESULT "))
        return list(json.loads(line[len("RESULT "):]))


def main() -> None:
    from splitrender.render.renderer import Renderer
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import run

    renderer = Renderer()
    t0 = time.perf_counter()
    cache = tempfile.mkdtemp(prefix="bench_tss_fine_truth_")
    scenes = (["duck"] if os.path.exists(DUCK) else []) + ["default"]
    runs: list[dict[str, Any]] = []

    def cfg(scene: str, trace: str, method: str, params: dict[str, Any], before: bool = False) -> dict[str, Any]:
        # BEFORE's split took the bound in object space: with its defaults it made the fine duck itself
        extra = FINE_DUCK if scene == "duck" and not before else {}
        return {**BASE, "scene": DUCK if scene.startswith("duck") else scene, "trace": trace, "method": method,
                "method_params": {**params, **extra}}

    def one(label: str, scene: str, trace: str, method: str, params: dict[str, Any], rows: bool = False) -> dict[str, Any]:
        undo = _rows_layout() if rows else None
        try:
            s = run(RunConfig.from_dict({**cfg(scene, trace, method, params), "truth_cache": cache}), renderer=renderer).summary
        finally:
            if undo:
                undo()
        r = {"label": label, "scene": scene, "trace": trace, "method": method, "params": params, **_summary(s)}
        runs.append(r)
        print(f"{scene:8s} {trace:6s} {label:28s} {r['mean_psnr_db']:6.2f} dB {r['mean_kbps']:8.0f} kbit/s "
              f"(atlas {r.get('kbps_atlas', float('nan')):.0f}, tris {r.get('kbps_tris', float('nan')):.0f}, "
              f"geo {r.get('kbps_geo', float('nan')):.0f})", flush=True)
        return r

    plan: list[tuple[str, str, str, str, dict[str, Any], bool]] = []
    for sc in scenes:
        plan += [("tss", sc, "static", "tss", {}, False), ("tss lossless", sc, "static", "tss", {"lossless": True}, False),
                 ("sas", sc, "static", "sas", {}, False), ("single_px = 1", sc, "static", "tss", {"single_px": 1}, False),
                 ("spatial_order = true", sc, "static", "tss", {"spatial_order": True}, False),
                 ("rows, 1 texel", sc, "static", "tss", {"single_px": 1}, True)]
    if "duck" in scenes:
        plan += [("tss", "duck own", "static", "tss", {}, False), ("tss lossless", "duck own", "static", "tss", {"lossless": True}, False),
                 ("sas", "duck own", "static", "sas", {}, False)]
    plan += [("tss", "default", "walk", "tss", {}, False), ("sas", "default", "walk", "sas", {}, False),
             ("high_water = 0.9", "default", "walk", "tss", {"high_water": 0.9}, False)]
    for label, sc, tr, m, params, rows in plan:
        one(label, sc, tr, m, params, rows)
    before_cfgs = [(sc, tr, p) for sc in scenes for tr, p in (("static", {}), ("static", {"lossless": True}))]
    before_cfgs += [("default", "walk", {})]
    got = _before([{**cfg(sc, tr, "tss", bp, before=True), "truth_cache": cache} for sc, tr, bp in before_cfgs])
    if got is not None:
        for (sc, tr, bp), s in zip(before_cfgs, got):
            runs.append({"label": "before" + (" lossless" if bp else ""), "scene": sc, "trace": tr, "method": "tss", "params": bp,
                         "commit": BEFORE, **s})
            print(f"{sc:8s} {tr:6s} {runs[-1]['label']:28s} {s['mean_psnr_db']:6.2f} dB {s['mean_kbps']:8.0f} kbit/s", flush=True)

    def get(scene: str, trace: str, label: str) -> dict[str, Any] | None:
        return next((r for r in runs if (r["scene"], r["trace"], r["label"]) == (scene, trace, label)), None)

    findings = []
    for sc in scenes + (["duck own"] if "duck" in scenes else []):
        for tr in ("static", "walk"):
            final, sas = get(sc, tr, "tss"), get(sc, tr, "sas")
            if final is None or sas is None:
                continue
            f: dict[str, Any] = {"scene": sc, "trace": tr, "tss_psnr_db": final["mean_psnr_db"], "tss_kbps": final["mean_kbps"],
                                 "tss_minus_sas_db": final["mean_psnr_db"] - sas["mean_psnr_db"],
                                 "kbps_over_sas": final["mean_kbps"] / sas["mean_kbps"]}
            lossless = get(sc, tr, "tss lossless")
            if lossless is not None:
                f["tss_minus_lossless_db"] = final["mean_psnr_db"] - lossless["mean_psnr_db"]
                if sc == "duck":   # the target for the fine mesh
                    f["target_met"] = bool(f["tss_minus_lossless_db"] >= -2.0 and f["tss_minus_sas_db"] >= -1.0
                                           and f["kbps_over_sas"] <= 1.0)
            ideas = {}
            for r in runs:
                if (r["scene"], r["trace"]) == (sc, tr) and r["label"] not in ("tss", "sas", "tss lossless", "before lossless"):
                    ideas[r["label"]] = {"final_minus_this_db": final["mean_psnr_db"] - r["mean_psnr_db"],
                                         "final_kbps_over_this": final["mean_kbps"] / r["mean_kbps"]}
            f["ideas"] = ideas
            before = get(sc, tr, "before")
            if before is not None:
                f["before_minus_sas_db"] = before["mean_psnr_db"] - sas["mean_psnr_db"]
                f["before_kbps_over_sas"] = before["mean_kbps"] / sas["mean_kbps"]
            findings.append(f)
    out = {"benchmark": "bench_tss_fine", "config": BASE, "scenes": scenes, "before_commit": BEFORE, "findings": findings,
           "runs": runs, "wall_s": time.perf_counter() - t0, "load_avg": os.getloadavg(), "machine": platform.machine(),
           "cpus": os.cpu_count(),
           "note": "PSNR: the summary's mean over displayed frames (the first shows nothing yet); kbit/s: every stream over the "
                   "run; ideas: the final configuration against it with that idea taken away (+ dB: the idea helps)"}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=1) + "\n")
    print(f"-> {RESULTS}")


if __name__ == "__main__":
    main()
