"""``sas`` at a low bitrate (issue 50, claim S-F15-1): before and after its I-frame change, beside ``atw``.

The claims ledger's cells of S-F15-1 (``--param bitrate_kbps=500``, 320x180, ``ideal``, server 30 Hz, client
60 Hz): the duck, TextureTransformTest, 2CylinderEngine and the default scene without GI on a still camera
(``static``), and the duck on ``orbit``.  Each cell runs ``sas`` at a commit before the change (a
``git worktree`` on ``PYTHONPATH``, ``--before``), ``sas`` at this tree, and ``atw`` at this tree, in one
invocation, one run at a time under ``nice``.  Per run: the mean model PSNR over the frames with content (the
ledger's measure), the model PSNR of the last displayed frame (where a still view has converged to), the
steady kbit/s, and the number of I-frames.  Extras: the still duck over ``--long`` seconds (does it keep
converging), and ``sas`` lossless on the still duck (the ceiling of the resampled atlas at this size).

Before the change ``sas`` coded an I-frame every 5 frames (the paper's period, with its atlas-reset check); at
500 kbit/s the rate control's two-frame buffer starves each I-frame, and a still view climbed for four frames
and fell back.  After it, I-frames come every ``gop`` (30) frames, on a full resend, or with an atlas reset
(checked every ``reset_period`` = 5 frames).

Writes ``benchmarks/results/bench_sas_lowrate.json``.  Run:
``python benchmarks/bench_sas_lowrate.py --before /tmp/wt [--duration 1] [--long 3]``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
OUT = Path(__file__).parent / "results" / "bench_sas_lowrate.json"
ASSIMP = "/usr/share/assimp/models"
SCENES = {"duck": f"{ASSIMP}/Collada/duck.dae",
          "TextureTransformTest": f"{ASSIMP}/glTF2/textureTransform/TextureTransformTest.gltf",
          "2CylinderEngine": f"{ASSIMP}/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb",
          "default": "default+nogi"}
CELLS = (("duck", "static"), ("duck", "orbit"), ("TextureTransformTest", "static"), ("2CylinderEngine", "static"),
         ("default", "static"))
RUN = "import sys; from splitrender.cli import main; sys.exit(main(sys.argv[1:]))"


def git_rev(path: Path) -> str:
    return subprocess.run(["git", "-C", str(path), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()


def run(tree: Path, method: str, params: list[str], scene: str, trace: str, duration: float, size: tuple[int, int]) -> dict[str, Any]:
    """One ``splitrender run`` with the code of ``tree``; its summary and per-frame figures."""
    with tempfile.TemporaryDirectory(prefix="bench_sas_lowrate_") as tmp:
        cmd = ["nice", "-n", "5", sys.executable, "-c", RUN, "run", "--method", method, "--scene", scene, "--trace", trace,
               "--network", "ideal", "--width", str(size[0]), "--height", str(size[1]), "--duration", str(duration),
               "--server-fps", "30", "--client-fps", "60", "--flip-every", "0", "--out", tmp]
        for p in params:
            cmd += ["--param", p]
        env = dict(os.environ, PYTHONPATH=str(tree))
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, env=env, cwd=tmp, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        summary = next(csv.DictReader(open(Path(tmp) / "summary.csv")))
        frames = list(csv.DictReader(open(Path(tmp) / "frames.csv")))
        updates = list(csv.DictReader(open(Path(tmp) / "updates.csv")))
    psnr = [float(f["model_psnr_db"]) for f in frames if f["model_psnr_db"] not in ("", "nan")]
    return {"model_psnr_db": round(float(summary["mean_model_psnr_db_content"]), 2),
            "last_model_psnr_db": round(psnr[-1], 2) if psnr else None,
            "steady_kbps": round(float(summary["steady_kbps"]), 1),
            "iframes": sum(int(float(u["keyframe"])) for u in updates),
            "updates": len(updates), "wall_s": round(wall, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, required=True, help="a checkout of the commit before the change")
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--long", type=float, default=3.0, help="the still duck's longer run (s); 0 skips it")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--kbps", type=float, default=500.0)
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    rate = [f"bitrate_kbps={args.kbps:g}"]
    trees = {"sas before": (args.before, "sas"), "sas after": (ROOT, "sas"), "atw": (ROOT, "atw")}
    rows: list[dict[str, Any]] = []
    for scene, trace in CELLS:
        for name, (tree, method) in trees.items():
            r = run(tree, method, rate, SCENES[scene], trace, args.duration, size)  # type: ignore[arg-type]
            rows.append({"scene": scene, "trace": trace, "run": name, "duration_s": args.duration, **r})
            print(json.dumps(rows[-1]), flush=True)
    extras: list[tuple[str, tuple[Path, str], list[str], float]] = [
        ("sas after lossless", (ROOT, "sas"), ["lossless=true"], args.duration)]
    if args.long > 0:
        extras += [(name, tree, rate, args.long) for name, tree in trees.items()]
    for name, (tree, method), params, dur in extras:
        r = run(tree, method, params, SCENES["duck"], "static", dur, size)  # type: ignore[arg-type]
        rows.append({"scene": "duck", "trace": "static", "run": name, "duration_s": dur, **r})
        print(json.dumps(rows[-1]), flush=True)
    OUT.write_text(json.dumps({
        "benchmark": "bench_sas_lowrate", "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "commit_before": git_rev(args.before), "commit_after": git_rev(ROOT) + " + working tree",
        "setting": f"{args.size}, bitrate_kbps={args.kbps:g}, ideal, server 30 Hz, client 60 Hz, {args.duration:g} s",
        "machine": platform.platform(), "rows": rows}, indent=1) + "\n")
    print(f"-> {OUT}")


if __name__ == "__main__":
    main()
