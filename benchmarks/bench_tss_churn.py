"""Why ``tss``'s atlas changes between frames on a moving camera (issue 50 part 1): changed texels by cause.

One run of ``tss`` (``bench_tss_models.FLIPS`` unless ``--params``) and one of ``sas`` on a model's orbit (``ideal``
network, 320x180, 1 s).  Per P-frame, every atlas texel whose sent colour (after the gutter fill) differs from the
previous frame's by more than ``--thr`` in any channel is put down to the first cause that explains it:

- ``gutter``: no live triangle's cell covers it (the push-pull fill between cells, or texels a triangle left);
- ``unwritten``: inside a live cell but no sample writes it (filled as a gutter);
- ``new``: the triangle owning it entered the PVS this frame;
- ``relevel``: its triangle's kind, level or staircase sizes changed (a new class: a new cell too);
- ``moved``: same class, another cell;
- same cell, same class: the frame is shaded twice more with the new plan, once at the previous pose (reference view
  and eye) and once with the new reference view but the previous eye; a texel that differs between those two is a
  ``shift`` (the samples moved: perspective placement and texture gradients follow the reference view), one that
  differs only between the second and the real frame is ``shading`` (the eye: specular, two-sided flips), and one
  that differs at the previous pose already is ``other`` (should be none).

Then the view is taken out: ``tss`` again with every frame shaded at the first frame's pose (reference view and eye;
the layout still planned per frame, a wrong picture): its P-frames' bytes are the layout's share (``frozen_view``).
And the codec on its own: both methods' atlas sequences coded again with their streams' configs, the atlas's PSNR
and bytes for I- and P-frames, and ``tss``'s first atlas repeated (``tss_frozen_source``: a still view's P-frames).

Also per frame: the texels in use, the 16x16 macroblocks with any change, the frame's rate and the atlas's bytes;
``sas``'s changed texels and bytes on the same orbit for comparison.  Writes ``benchmarks/results/bench_tss_churn.json``
(under ``--label``).  Run::

    nice -n 5 python benchmarks/bench_tss_churn.py --model duck
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if "PYTHONPATH" not in os.environ:      # PYTHONPATH=another checkout measures that one (the sas of a clean tree)
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).parent))
RESULTS = Path(__file__).parent / "results" / "bench_tss_churn.json"
CAUSES = ("gutter", "stale", "unwritten", "new", "relevel", "moved", "shift", "shading", "other")


def owners(plan: Any, ids: np.ndarray, W: int, H: int) -> np.ndarray:
    """(H, W) index into ``ids`` of the triangle whose cell covers each texel (-1: none)."""
    from splitrender.methods.tss.layout import KIND_LP, KIND_SINGLE, os_rows, tip_dim

    own = np.full((H, W), -1, np.int64)
    o = plan.origin
    for i in range(ids.size):
        k = int(plan.kind[i])
        if k == KIND_SINGLE:
            x, y = o[i, 0]
            s = plan.single_px
            own[y:y + s, x:x + s] = i
        elif k == KIND_LP:
            D = int(tip_dim(int(plan.level[i])))
            for t in range(3):
                x, y = o[i, t]
                own[y:y + D, x:x + D] = i
        else:
            x, y = o[i, 0]
            pw = int(o[i, 1, 0])
            own[y:y + int(os_rows(int(plan.h[i]))), x:x + pw] = i
    return own


def code_atlas(frames: list[np.ndarray], cfg: Any, rows: list[int] | None) -> dict[str, float]:
    """The atlas sequence ``frames`` coded again with its stream's codec config ``cfg`` (lossy): bytes of the I-frame
    and median of the P-frames, and the atlas's PSNR (over the rows in use, ``rows``) of the I-frame and mean of the
    P-frames: how well the codec keeps each method's texels."""
    from splitrender.codecs.video import VideoDecoder, VideoEncoder

    H, W = frames[0].shape[:2]
    enc, dec = VideoEncoder(cfg, W, H), VideoDecoder(cfg.codec)
    nb, ps = [], []
    for i, f in enumerate(frames):
        e = enc.encode(np.ascontiguousarray(f), force_idr=(i % cfg.gop == 0))
        g = dec.decode(e.data)
        r = H if rows is None else max(16, int(rows[i]))
        mse = float(np.mean((g[:r].astype(np.float64) - f[:r].astype(np.float64)) ** 2))
        nb.append(e.nbytes)
        ps.append(10 * np.log10(255.0 ** 2 / max(mse, 1e-9)))
    p = [i for i in range(1, len(frames)) if i % cfg.gop]
    return {"i_bytes": nb[0], "p_bytes_median": float(np.median([nb[i] for i in p])), "i_psnr_db": round(ps[0], 2),
            "p_psnr_db_mean": round(float(np.mean([ps[i] for i in p])), 2), "p_psnr_db_last": round(ps[p[-1]], 2)}


def measure(model: str, params: dict[str, Any], thr: int, duration: float) -> dict[str, Any]:
    from splitrender.methods.sas.server import SasServer
    from splitrender.methods.tss import server as tss_server
    from splitrender.methods.tss.layout import KIND_OS, KIND_SINGLE
    from splitrender.methods.tss.server import NEAR_M, TssServer
    from splitrender.render.renderer import Renderer
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import run
    from bench_tss_models import MODELS

    frames: list[dict[str, Any]] = []
    orig_produce = TssServer.produce
    def gather_eye(self: Any, ctx: Any, eye: tuple[float, float, float], ids: np.ndarray, plan: Any, base: np.ndarray,
                   persp: np.ndarray, models: np.ndarray, px: np.ndarray) -> None:
        """:meth:`TssServer._gather` with ``u_eye`` at ``eye``, on a cleared atlas (every texel no triangle writes
        black, as in an I-frame)."""
        keep, self.keep_unwritten = self.keep_unwritten, False
        try:
            self._gather(ctx, ids, plan, base, persp, models, px, eye=eye)
        finally:
            self.keep_unwritten = keep

    def produce(self: Any, ctx: Any) -> Any:
        import dataclasses

        up = orig_produce(self, ctx)
        video["tss"] = self.streams()[0].codec
        if frozen:
            return up
        W, H = self.atlas
        raw = np.frombuffer(self._fbo.read(components=4, alignment=1), np.uint8).reshape(H, W, 4).copy()
        sent = up.planes["atlas"]
        plan, ids = self.last_plan, self.last_ids
        rec = {"ids": ids.copy(), "plan": plan, "raw": raw, "sent": np.asarray(sent).copy(), "pose": ctx.target_pose,
               "iframe": bool(self._stats["iframe"]), "rate": self._stats["rate"], "x": None}
        prev = frames[-1] if frames else None
        if prev is not None and not rec["iframe"]:
            # the new plan shaded at the previous pose, and with the new view but the previous eye
            pvs, models = ids, up.meta["xf"].astype(np.float64)
            T = self.tris
            m = models[T.obj[pvs]]
            world = np.einsum("nij,nkj->nki", m[:, :3, :3], T.pos[pvs].astype(np.float64)) + m[:, None, :3, 3]
            out = {}
            for name, view, eye in (("old", prev["pose"], prev["pose"]), ("view", ctx.target_pose, prev["pose"])):
                px, depth = tss_server.project(world, view, self.intrinsics)
                persp = (depth.min(axis=1) > NEAR_M) & self.config.perspective
                base = self._last_base
                gather_eye(self, dataclasses.replace(ctx, target_pose=view), tuple(float(v) for v in eye.position),
                           pvs, plan, base, persp, models, px)
                out[name] = np.frombuffer(self._fbo.read(components=4, alignment=1), np.uint8).reshape(H, W, 4).copy()
            rec["x"] = out
            self._tex.write(raw.tobytes())       # the next P-frame keeps this frame's unwritten texels, as it would
        frames.append(rec)
        return up

    orig_plan_view = TssServer.plan_view

    def plan_view(self: Any, ctx: Any, iframe: bool) -> Any:
        r = orig_plan_view(self, ctx, iframe)
        self._last_base = r[5]
        return r

    sas_frames: list[np.ndarray] = []
    orig_sas = SasServer.produce

    video: dict[str, Any] = {}

    def sas_produce(self: Any, ctx: Any) -> Any:
        up = orig_sas(self, ctx)
        video["sas"] = self.streams()[0].codec
        sas_frames.append(np.asarray(up.planes["atlas"]).copy())
        return up

    # the view frozen: every frame shaded at the first frame's pose (reference view and eye), the layout as planned
    frozen = False

    def gather_frozen(self: Any, ctx: Any, *a: Any) -> int:
        if not hasattr(self, "_pose0"):
            self._pose0 = ctx.target_pose
        return orig_gather(self, dataclasses.replace(ctx, target_pose=self._pose0), *a)

    orig_gather = TssServer._gather
    TssServer.produce, TssServer.plan_view, SasServer.produce = produce, plan_view, sas_produce
    renderer = Renderer()
    path = MODELS[model]
    common = dict(scene=path, trace="orbit", network="ideal", duration_s=duration, width=320, height=180, flip_every=0,
                  seed=0, truth_cache="default")
    try:
        res_t = run(RunConfig(method="tss", method_params=params, **common), renderer=renderer)
        res_s = run(RunConfig(method="sas", method_params={}, **common), renderer=renderer)
        frozen = True
        TssServer._gather = gather_frozen
        res_f = run(RunConfig(method="tss", method_params=params, **common), renderer=renderer)
    finally:
        TssServer.produce, TssServer.plan_view, SasServer.produce = orig_produce, orig_plan_view, orig_sas
        TssServer._gather = orig_gather

    rows = []
    bytes_t = {u["frame_id"]: u.get("bytes_atlas", 0) for u in res_t.updates}
    W = frames[0]["sent"].shape[1]
    for n in range(1, len(frames)):
        cur, prev = frames[n], frames[n - 1]
        if cur["iframe"] or cur["x"] is None:
            rows.append({"frame": n, "iframe": True, "bytes": bytes_t.get(n, 0)})
            continue
        H = cur["sent"].shape[0]
        rows_used = max(cur["plan"].height, prev["plan"].height)
        d = np.abs(cur["sent"][:rows_used].astype(np.int16) - prev["sent"][:rows_used].astype(np.int16)).max(axis=2) > thr
        own = owners(cur["plan"], cur["ids"], W, H)[:rows_used]
        cause = np.full(d.shape, -1, np.int64)
        # per triangle of the new plan: new, relevelled, moved
        pos_prev = {int(t): i for i, t in enumerate(prev["ids"].tolist())}
        pp, cp = prev["plan"], cur["plan"]
        tri_cause = np.full(cur["ids"].size, 6, np.int64)          # same cell: decided per texel below
        for i, t in enumerate(cur["ids"].tolist()):
            j = pos_prev.get(t)
            if j is None:
                tri_cause[i] = 3
            elif (pp.kind[j] != cp.kind[i] or (cp.kind[i] != KIND_SINGLE and pp.level[j] != cp.level[i])
                  or (cp.kind[i] == KIND_OS and (pp.w[j] != cp.w[i] or pp.w2[j] != cp.w2[i] or pp.h[j] != cp.h[i]
                                                 or pp.a[j] != cp.a[i]))):
                tri_cause[i] = 4
            elif (pp.origin[j] != cp.origin[i]).any():
                tri_cause[i] = 5
        alpha = cur["raw"][:rows_used, :, 3] > 127
        cause[(own < 0) & ~alpha] = 0
        cause[(own < 0) & alpha] = 1
        cause[(own >= 0) & ~alpha] = 2
        inside = (own >= 0) & alpha
        cause[inside] = tri_cause[own[inside]]
        same = cause == 6
        xo, xv = cur["x"]["old"][:rows_used, :, :3].astype(np.int16), cur["x"]["view"][:rows_used, :, :3].astype(np.int16)
        pr = prev["raw"][:rows_used, :, :3].astype(np.int16)
        other = np.abs(xo - pr).max(axis=2) > thr
        shift = np.abs(xv - xo).max(axis=2) > thr
        cause[same & other] = 8
        cause[same & ~other & shift] = 6
        cause[same & ~other & ~shift] = 7       # changed, and not by the previous pose nor the view: the eye
        counts = {name: int((d & (cause == k)).sum()) for k, name in enumerate(CAUSES)}
        used = int(rows_used * W)
        R = rows_used // 16 * 16
        blocks = (lambda m: m[:R].reshape(R // 16, 16, W // 16, 16).any(axis=(1, 3)))
        mb = blocks(d)
        mb_gutter_only = mb & ~blocks(d & (cause > 1))
        fresh_rows = int((d[prev["plan"].height:]).sum())
        # macroblocks by cause: those with a layout change (a cell filled anew: new, relevel, moved, and the gutters
        # and unwritten texels around them) and those whose only changes are the samples' (shift, shading)
        mb_layout = blocks(d & (cause >= 0) & (cause <= 5))
        mb_view = mb & ~mb_layout
        # the same texels without the threshold's noise: changed-by-shading texels whose change is small
        rows.append({"frame": n, "iframe": False, "rate": round(cur["rate"], 3), "texels_used": used,
                     "changed": int(d.sum()), "changed_pct": round(100.0 * d.sum() / max(used, 1), 2),
                     "by_cause": counts, "mb_changed_pct": round(100.0 * mb.mean(), 1) if mb.size else 0.0,
                     "mb_gutter_only_pct": round(100.0 * mb_gutter_only.mean(), 1) if mb.size else 0.0,
                     "changed_below_prev_rows": fresh_rows,
                     "mb_layout_pct": round(100.0 * mb_layout.mean(), 1) if mb.size else 0.0,
                     "mb_view_only_pct": round(100.0 * mb_view.mean(), 1) if mb.size else 0.0,
                     "tris_changed": {k: int((tri_cause == v).sum()) for k, v in (("new", 3), ("relevel", 4), ("moved", 5))},
                     "tris": int(cur["ids"].size), "bytes": bytes_t.get(n, 0)})
    sas_rows = []
    bytes_s = {u["frame_id"]: u.get("bytes_atlas", 0) for u in res_s.updates}
    for n in range(1, len(sas_frames)):
        d = np.abs(sas_frames[n].astype(np.int16) - sas_frames[n - 1].astype(np.int16)).max(axis=2) > thr
        sas_rows.append({"frame": n, "changed_pct": round(100.0 * d.mean(), 2), "bytes": bytes_s.get(n, 0)})
    codec = {"tss": code_atlas([f["sent"] for f in frames], video["tss"], [f["plan"].height for f in frames]),
             "sas": code_atlas(sas_frames, video["sas"], None)}
    codec["tss_frozen_source"] = code_atlas([frames[0]["sent"]] * len(frames), video["tss"],
                                            [frames[0]["plan"].height] * len(frames))
    p = [r for r in rows if not r["iframe"]]
    tot = {c: sum(r["by_cause"][c] for r in p) for c in CAUSES}
    allc = max(sum(tot.values()), 1)
    summary = {"tss_changed_pct_mean": round(float(np.mean([r["changed_pct"] for r in p])), 2),
               "tss_mb_changed_pct_mean": round(float(np.mean([r["mb_changed_pct"] for r in p])), 1),
               "tss_mb_layout_pct_mean": round(float(np.mean([r["mb_layout_pct"] for r in p])), 1),
               "tss_mb_view_only_pct_mean": round(float(np.mean([r["mb_view_only_pct"] for r in p])), 1),
               "tss_mb_gutter_only_pct_mean": round(float(np.mean([r["mb_gutter_only_pct"] for r in p])), 1),
               "tss_changed_below_prev_rows_mean": round(float(np.mean([r["changed_below_prev_rows"] for r in p])), 1),
               "tss_share_by_cause_pct": {c: round(100.0 * v / allc, 1) for c, v in tot.items()},
               "tss_p_bytes_median": float(np.median([r["bytes"] for r in p])) if p else 0.0,
               "sas_changed_pct_mean": round(float(np.mean([r["changed_pct"] for r in sas_rows[1:]])), 2),
               "sas_p_bytes_median": float(np.median([r["bytes"] for r in sas_rows[1:]])),
               "tss_model_db": round(float(np.nanmean([f["model_psnr_db"] for f in res_t.frames if f["update_frame_id"] >= 0])), 3),
               "sas_model_db": round(float(np.nanmean([f["model_psnr_db"] for f in res_s.frames if f["update_frame_id"] >= 0])), 3),
               "tss_kbps": round(float(res_t.summary["steady_kbps"]), 1), "sas_kbps": round(float(res_s.summary["steady_kbps"]), 1),
               "tss_frozen_view_p_bytes_median": float(np.median([u.get("bytes_atlas", 0) for u in res_f.updates[1:]
                                                                  if not u.get("srv_iframe", 0)])),
               "codec": codec}
    return {"model": model, "params": params, "thr": thr, "summary": summary, "tss_frames": rows, "sas_frames": sas_rows}


def main() -> None:
    from bench_tss_models import FLIPS

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="duck")
    ap.add_argument("--params", help="tss params as JSON (default: bench_tss_models.FLIPS)")
    ap.add_argument("--thr", type=int, default=2, help="a texel changed when a channel moved by more than this")
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--label", default="flips")
    a = ap.parse_args()
    params = json.loads(a.params) if a.params else FLIPS
    t0 = time.perf_counter()
    out = measure(a.model, params, a.thr, a.duration)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    import splitrender

    tree = Path(splitrender.__file__).resolve().parents[1]
    out["commit"] = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    out["tree"] = str(tree)
    data = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    data[f"{a.model} {a.label}"] = out
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(data, indent=1) + "\n")
    print(json.dumps(out["summary"], indent=1))
    for r in out["tss_frames"]:
        print(r)


if __name__ == "__main__":
    main()
