"""Where the video codec's error on ``tss``'s atlas comes from, and what aligning it to the codec's blocks does
(issue 50 part 1, the lossy half of T-T4-1).

One still frame (``static``, 320x180) of ``tss`` at the claims ledger's ``TSS_MATCHED`` on each scene; its atlas
(after the gutter fill, as sent) is coded once as an I-frame with the stream's own codec config, and ``sas``'s first
atlas beside it.  Per texel the squared error after coding (mean over RGB) is put into a category:

- ``gutter``: no sample wrote it (between cells, and with ``codec_block`` the padding of each tip block);
- ``single``: a single texel's cell; ``os``: an oversampling rectangle;
- ``lp_border``: an L-packing tip block's outer row or column; ``lp_diag``: its diagonal (where its two folded
  halves meet); ``lp_interior``: the rest.

and per 4 x 4 block (H.264's transform) the number of triangles whose samples it holds.  Per configuration: the
atlas's bytes and PSNR over the rows in use, each category's texels, MSE and share of the error; ``sas``'s bytes and
PSNR.  ``codec_block`` 1 (no alignment), 4 and 8, and 4 with ``fill_pitch``.  With ``--mosaic``, what the tiles'
means alone cost and what reordering the tiles could save (:func:`mosaic`).  Writes (under ``--label``)
``benchmarks/results/bench_tss_codec.json``.  Run::

    nice python benchmarks/bench_tss_codec.py

(about 3 minutes on 2 cores with a warm truth cache).  The client-side figures (model PSNR and DSSIM, kbit/s, ``sas``
in the same run) are ``bench_tss_matched.py``'s ``tss matched block4`` rows.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if "PYTHONPATH" not in os.environ:
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).parent))
RESULTS = Path(__file__).parent / "results" / "bench_tss_codec.json"
VARIANTS = {"block1": {}, "block4": {"codec_block": 4}, "block8": {"codec_block": 8},
            "block4 fill_pitch": {"codec_block": 4, "fill_pitch": True}}
CATEGORIES = ("gutter", "single", "lp_border", "lp_interior", "lp_diag", "os")


def categories(plan: Any, ids: np.ndarray, alpha: np.ndarray, W: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, W) category index (:data:`CATEGORIES`) and owning triangle (-1: none) of every texel in use."""
    from splitrender.methods.tss.layout import KIND_LP, KIND_SINGLE, os_rows, tip_dim

    rows = alpha.shape[0]
    cat = np.zeros((rows, W), np.int64)
    own = np.full((rows, W), -1, np.int64)
    for i in range(ids.size):
        k, o = int(plan.kind[i]), plan.origin[i]
        if k == KIND_SINGLE:
            x, y = o[0]
            s = plan.single_px
            cat[y:y + s, x:x + s], own[y:y + s, x:x + s] = 1, i
        elif k == KIND_LP:
            D = int(tip_dim(int(plan.level[i])))
            yy, xx = np.mgrid[0:D, 0:D]
            c = np.where((xx == 0) | (yy == 0) | (xx == D - 1) | (yy == D - 1), 2, np.where(xx == yy, 4, 3))
            for t in range(3):
                x, y = o[t]
                cat[y:y + D, x:x + D], own[y:y + D, x:x + D] = c, i
        else:
            x, y = o[0]
            pw, hh = int(o[1, 0]), int(os_rows(int(plan.h[i])))
            cat[y:y + hh, x:x + pw], own[y:y + hh, x:x + pw] = 5, i
    cat[~alpha] = 0
    own[~alpha] = -1
    return cat, own


def code(img: np.ndarray, cfg: Any) -> tuple[int, np.ndarray]:
    """``img`` coded as one I-frame with ``cfg``: bytes and the decoded picture."""
    from splitrender.codecs.video import VideoDecoder, VideoEncoder

    H, W = img.shape[:2]
    enc, dec = VideoEncoder(cfg, W, H), VideoDecoder(cfg.codec)
    f = enc.encode(np.ascontiguousarray(img), force_idr=True)
    return f.nbytes, dec.decode(f.data)


def _blocks(img: np.ndarray, b: int) -> np.ndarray:
    """(N, b, b, 3) the ``b``-square blocks of ``img`` (H, W, 3), row after row."""
    H, W = img.shape[0] // b * b, img.shape[1] // b * b
    return img[:H, :W].reshape(H // b, b, W // b, b, 3).transpose(0, 2, 1, 3, 4).reshape(-1, b, b, 3)


def _unblocks(blocks: np.ndarray, like: np.ndarray, b: int) -> np.ndarray:
    out = like.copy()
    H, W = like.shape[0] // b * b, like.shape[1] // b * b
    out[:H, :W] = blocks.reshape(H // b, W // b, b, b, 3).transpose(0, 2, 1, 3, 4).reshape(H, W, 3)
    return out


def mosaic(sent: np.ndarray, rows: int, cfg: Any) -> dict[str, int]:
    """Bytes of the atlas's rows in use coded as one I-frame (``--mosaic``): as sent; each 4 x 4 and 8 x 8 block
    replaced by its mean (what coding the blocks' means alone costs: the mosaic of tiles); its 8 x 8 blocks moved
    into the order of their mean luma along a serpentine (the best a reordering of the tiles could do for their
    means), and into a random order (what the id order already saves)."""
    img = np.ascontiguousarray(sent[: -(-rows // 16) * 16])
    out = {"as_sent": code(img, cfg)[0]}
    for b in (4, 8):
        bl = _blocks(img, b)
        flat = np.broadcast_to(bl.astype(np.float32).mean(axis=(1, 2), keepdims=True), bl.shape)
        out[f"block{b}_means"] = code(_unblocks(np.rint(flat).astype(np.uint8), img, b), cfg)[0]
    bl = _blocks(img, 8)
    luma = bl.astype(np.float32).mean(axis=(1, 2)) @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    per_row = img.shape[1] // 8
    for name, order in (("block8_sorted_by_luma", np.argsort(luma, kind="stable")),
                        ("block8_shuffled", np.random.default_rng(0).permutation(luma.size))):
        nb = bl[order].reshape(-1, per_row, 8, 8, 3).copy()
        nb[1::2] = nb[1::2, ::-1]
        out[name] = code(_unblocks(nb.reshape(bl.shape), img, 8), cfg)[0]
    return out


def measure(scene: str, variants: list[str], with_mosaic: bool = False) -> dict[str, Any]:
    from bench_tss_matched import MATCHED, SCENES
    from splitrender.methods.sas.server import SasServer
    from splitrender.methods.tss.server import TssServer
    from splitrender.render.renderer import Renderer
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import run

    cap: dict[str, Any] = {}
    orig_t, orig_s = TssServer.produce, SasServer.produce

    def produce(self: Any, ctx: Any) -> Any:
        up = orig_t(self, ctx)
        if "tss" not in cap:
            W, H = self.atlas
            raw = np.frombuffer(self._fbo.read(components=4, alignment=1), np.uint8).reshape(H, W, 4).copy()
            cap["tss"] = (raw, np.asarray(up.planes["atlas"]).copy(), self.last_plan, self.last_ids.copy(), self.streams()[0].codec)
        return up

    def sas_produce(self: Any, ctx: Any) -> Any:
        up = orig_s(self, ctx)
        if "sas" not in cap:
            cap["sas"] = (np.asarray(up.planes["atlas"]).copy(), self.streams()[0].codec)
        return up

    renderer = Renderer()
    common = dict(scene=SCENES[scene], trace="static", network="ideal", duration_s=0.05, width=320, height=180,
                  flip_every=0, seed=0, truth_cache="default")
    out: dict[str, Any] = {}
    TssServer.produce, SasServer.produce = produce, sas_produce
    try:
        run(RunConfig(method="sas", method_params={}, **common), renderer=renderer)
        sas, scfg = cap["sas"]
        nb, dec = code(sas, scfg)
        mse = float(((dec.astype(float) - sas.astype(float)) ** 2).mean())
        out["sas"] = {"atlas": [sas.shape[1], sas.shape[0]], "bytes": nb, "psnr_db": round(10 * np.log10(255 ** 2 / mse), 2)}
        for v in variants:
            cap.pop("tss", None)
            run(RunConfig(method="tss", method_params={**MATCHED, **VARIANTS[v]}, **common), renderer=renderer)
            raw, sent, plan, ids, cfg = cap["tss"]
            W = sent.shape[1]
            rows = max(16, -(-plan.height // 16) * 16)
            nb, dec = code(sent, cfg)
            err = ((dec[:rows].astype(float) - sent[:rows].astype(float)) ** 2).mean(axis=2)
            cat, own = categories(plan, ids, raw[:rows, :, 3] > 127, W)
            row: dict[str, Any] = {"rows": int(plan.height), "bytes": nb, "samples": int(plan.samples.sum()),
                                   "triangles": {n: int((plan.kind == k).sum()) for k, n in enumerate(("single", "lp", "os"))},
                                   "psnr_db_rows_used": round(10 * np.log10(255 ** 2 / max(float(err.mean()), 1e-9)), 2)}
            written = cat > 0
            row["psnr_db_written"] = round(10 * np.log10(255 ** 2 / max(float(err[written].mean()), 1e-9)), 2)
            for k, n in enumerate(CATEGORIES):
                m = cat == k
                if m.any():
                    row[n] = {"texels": int(m.sum()), "mse": round(float(err[m].mean()), 2),
                              "error_share_pct": round(100 * float(err[m].sum() / max(err.sum(), 1e-9)), 1)}
            R = rows // 4 * 4
            blk = (lambda a: a[:R, :W // 4 * 4].reshape(R // 4, 4, W // 4, 4).transpose(0, 2, 1, 3).reshape(-1, 16))
            o4, e4 = blk(own), blk(err)
            owners = np.array([len(set(b[b >= 0].tolist())) for b in o4])
            row["blocks4_by_triangles"] = {str(int(n)): {"blocks": int((owners == n).sum()), "mse": round(float(e4[owners == n].mean()), 2)}
                                           for n in np.unique(owners)}
            if with_mosaic:
                row["mosaic_bytes"] = mosaic(sent, rows, cfg)
                row["mosaic_bytes"]["sas_as_sent"] = out["sas"]["bytes"]
            out[v] = row
            print(scene, v, json.dumps({k: row[k] for k in ("rows", "bytes", "psnr_db_rows_used", "psnr_db_written", "mosaic_bytes")
                                        if k in row}), flush=True)
    finally:
        TssServer.produce, SasServer.produce = orig_t, orig_s
    return out


def main() -> None:
    from bench_tss_matched import SCENES

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--label", default="after")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--mosaic", action="store_true", help="per variant, what the atlas's tiles' means cost (mosaic())")
    a = ap.parse_args()
    t0 = time.perf_counter()
    res = {}
    for s in a.scenes.split(","):
        if SCENES[s].startswith("/") and not os.path.exists(SCENES[s]):
            print(f"skip {s}: absent", file=sys.stderr)
            continue
        res[s] = measure(s, a.variants.split(","), a.mosaic)
    import splitrender

    tree = Path(splitrender.__file__).resolve().parents[1]
    commit = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    data = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    data.setdefault("setting", "320x180, static camera, first frame; tss at the claims ledger's TSS_MATCHED with each variant's "
                               "settings, its atlas coded as one I-frame with its stream's config (H.264 ultrafast, crf 23, "
                               "4:4:4); sas's first atlas the same way; error = squared error after coding, mean over RGB")
    data[a.label] = {"commit": commit, "seconds": round(time.perf_counter() - t0, 1), "scenes": res}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(data, indent=1) + "\n")


if __name__ == "__main__":
    main()
