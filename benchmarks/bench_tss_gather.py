"""Threads from the tessellator against a compute shader with fixed block sizes (TSS paper, figure 16).

One frame of the default scene's ``walk`` at 640x360 with every triangle oversampled
(``slant_threshold = 1``, ``tiny_samples = 0``, as the paper's figure measures
oversampling): the atlas is gathered (a) by ``tss``'s tessellation path, one patch per
triangle, every spawned thread shading one sample, and (b) by ``shaders/tss_gather.comp``,
one work group of 32-512 threads per triangle striding over its samples.  Both use the
same layout and shading code; the atlases are compared texel by texel.  Times are
medians of repeated runs, quoted as ratios to the tessellation path measured in the same
process.

Writes ``benchmarks/results/bench_tss_gather.json``.  Run: ``python benchmarks/bench_tss_gather.py``.

``--frames [REV]`` (issue 49) times whole ``tss`` server frames instead: 12 frames per session at 320x180 (the duck,
2CylinderEngine and default+nogi, still and orbit, ``tss``'s defaults and the claims ledger's ``tss matched``),
``produce`` and a ground-truth render of the same pose timed per frame, in child processes that alternate between this
checkout and a git worktree of ``REV`` (default ``HEAD~1``).  It asserts that every update is the same in both (a
sha256 per frame of the atlas plane, the data streams, the metadata and the non-timing stats) and reports the median
server ms over the ground truth's.  Writes ``benchmarks/results/bench_tss_gather_frames.json``.
"""

from __future__ import annotations

import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

# this checkout's package, not an installed one (``--child ROOT``: the checkout at ROOT, for --frames)
sys.path.insert(0, sys.argv[sys.argv.index("--child") + 1] if "--child" in sys.argv else str(Path(__file__).resolve().parents[1]))

from splitrender.methods import get_method, make_config  # noqa: E402
from splitrender.methods.tss.server import SHADERS  # noqa: E402
from splitrender.pipeline.direct import server_context  # noqa: E402
from splitrender.render.gl import read_shader, set_reference_view, set_uniform  # noqa: E402
from splitrender.render.renderer import Renderer  # noqa: E402
from splitrender.scene.loader import get_scene  # noqa: E402
from splitrender.scene.pose import CameraIntrinsics  # noqa: E402
from splitrender.scene.trace import get_trace  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "bench_tss_gather.json"
FRAMES_RESULTS = Path(__file__).parent / "results" / "bench_tss_gather_frames.json"
SCENES = {"duck": "/usr/share/assimp/models/Collada/duck.dae",
          "2CylinderEngine": "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb",
          "default+nogi": "default+nogi"}
FRAME_CONFIGS = [("duck", "static", "defaults"), ("duck", "orbit", "matched"), ("2CylinderEngine", "orbit", "defaults"),
                 ("2CylinderEngine", "static", "matched"), ("default+nogi", "static", "matched"),
                 ("default+nogi", "orbit", "defaults")]
N_FRAMES = 12
BLOCKS = (32, 64, 128, 256, 512)
REPEATS = 5


def main() -> None:
    r = Renderer()
    scene = get_scene("default")
    intr = CameraIntrinsics(640, 360)
    spec = get_method("tss")
    cfg = make_config(spec.config, {"slant_threshold": 1.0, "tiny_samples": 0.0})
    srv = spec.server_class(cfg, intr, scene, 30, None)
    t = 1.0
    pose = get_trace("walk", scene=scene).pose_at(t)
    ctx = server_context(scene, r, intr, pose, t_s=t)
    captured: dict = {}
    gather = srv._gather

    def spy(*a):  # type: ignore[no-untyped-def]
        captured["args"] = a
        return gather(*a)

    srv._gather = spy
    srv.produce(ctx)
    _, ids, plan, base, persp, models, px = captured["args"]
    W, H = srv.atlas
    n_samples = int(plan.samples.sum())
    assert (plan.kind == 2).all(), "every triangle oversampled"

    def tess() -> tuple[float, np.ndarray]:
        t0 = time.perf_counter()
        gather(ctx, ids, plan, base, persp, models, px)
        r.ctx.finish()
        ms = (time.perf_counter() - t0) * 1e3
        return ms, np.frombuffer(srv._tex.read(), np.uint8).reshape(H, W, 4).copy()

    # the compute path's per-triangle records: world-space corners, as the gathering stage's vertex shader makes them
    v = srv._vertices(ids, plan, base, persp, px).astype(np.float64)           # (N, 3, 24) object space + layout
    obj = srv.tris.obj[ids]
    m = models[obj].astype(np.float64)
    nm = np.linalg.inv(m[:, :3, :3]).transpose(0, 2, 1)
    world = np.einsum("nij,nkj->nki", m[:, :3, :3], v[:, :, 0:3]) + m[:, None, :3, 3]
    nrm = np.einsum("nij,nkj->nki", nm, v[:, :, 3:6])
    tan = np.einsum("nij,nkj->nki", m[:, :3, :3], v[:, :, 8:11])
    view = np.asarray(pose.view_matrix(), np.float64)
    depth = -(world @ view[2, :3] + view[2, 3])
    rec = np.zeros((ids.size, 19, 4), np.float32)
    rec[:, 0:3, :3] = world
    rec[:, 3:6, :3] = nrm
    rec[:, 6:9, :2] = v[:, :, 6:8]
    rec[:, 6:9, 2] = depth
    rec[:, 9:12, :3] = tan
    rec[:, 9:12, 3] = v[:, :, 11]
    rec[:, 12] = v[:, 0, 12:16]
    rec[:, 13] = v[:, 0, 16:20]
    rec[:, 14] = v[:, 0, 20:24]
    buf = r.ctx.buffer(rec.tobytes())
    src = read_shader(SHADERS / "tss_gather.comp")
    bounds = np.flatnonzero(np.diff(obj)) + 1
    starts = np.concatenate([[0], bounds]).tolist()
    ends = np.concatenate([bounds, [obj.size]]).tolist()

    def compute(block: int) -> tuple[float, np.ndarray]:
        prog = r.ctx.compute_shader(src.replace("#version 430", f"#version 430\n#define BLOCK {block}", 1))
        srv._fbo.use()
        srv._fbo.clear(0.0, 0.0, 0.0, 0.0)   # as the tessellation path clears an I-frame: alpha 0, no sample
        srv._counter.clear()
        t0 = time.perf_counter()
        r.bind_shading(prog, scene, t)
        prog["u_eye"].value = tuple(float(x) for x in pose.position)
        set_uniform(prog, "u_os_centred", int(srv.config.os_grid == "centred"))
        set_reference_view(prog, srv.intrinsics, pose)   # per-sample texture gradients, as the tessellation path's
        srv._tex.bind_to_image(0, read=False, write=True)
        srv._counter.bind_to_storage_buffer(1)
        buf.bind_to_storage_buffer(2)
        for s, e in zip(starts, ends):
            r.bind_material(prog, srv._sg.objects[int(obj[s])])
            prog["u_first"].value = int(s)
            prog.run(e - s)
        r.ctx.memory_barrier()
        r.ctx.finish()
        ms = (time.perf_counter() - t0) * 1e3
        shaded = int(np.frombuffer(srv._counter.read(4), np.uint32)[0])
        assert shaded == n_samples, (shaded, n_samples)
        return ms, np.frombuffer(srv._tex.read(), np.uint8).reshape(H, W, 4).copy()

    tess()   # warm-up (compiles)
    runs = [tess() for _ in range(REPEATS)]
    ref = runs[-1][1]
    base_ms = statistics.median(x[0] for x in runs)
    rows = [{"path": "tessellation", "ms": base_ms, "ratio": 1.0, "texels_differing": 0, "max_abs_diff": 0}]
    for b in BLOCKS:
        compute(b)  # warm-up
        res = [compute(b) for _ in range(REPEATS)]
        img = res[-1][1]
        d = np.abs(img.astype(np.int16) - ref.astype(np.int16)).max(axis=2)
        ms = statistics.median(x[0] for x in res)
        rows.append({"path": f"compute, block {b}", "ms": ms, "ratio": ms / base_ms, "texels_differing": int((d > 0).sum()),
                     "max_abs_diff": int(d.max())})
        print(f"block {b}: {ms:.0f} ms = {ms / base_ms:.2f}x tessellation, {int((d > 0).sum())} texels differ (max {int(d.max())})")
    out = {"benchmark": "bench_tss_gather", "machine": platform.platform(), "renderer": r.ctx.info.get("GL_RENDERER"),
           "display": [intr.width, intr.height], "triangles": int(ids.size), "samples": n_samples, "atlas": [W, H],
           "repeats": REPEATS, "baseline": "the tessellation path, same process", "results": rows,
           "paper": "figure 16: tessellation-spawned threads beat every fixed compute block size (32-512) on a Titan Xp"}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=2) + "\n")
    print(f"tessellation {base_ms:.0f} ms for {n_samples} samples of {ids.size} triangles; wrote {RESULTS}")


def child(scene_name: str, trace_name: str, params_name: str) -> None:
    """One session of :data:`N_FRAMES` server frames (``--frames``' child): prints digests and times as JSON."""
    import hashlib

    from splitrender.experiments.studies.claims import TSS_MATCHED   # the ledger's "tss matched", one source

    params = {"defaults": {}, "matched": TSS_MATCHED}[params_name]
    r = Renderer()
    scene = get_scene(SCENES[scene_name])
    intr = CameraIntrinsics(320, 180)
    spec = get_method("tss")
    srv = spec.server_class(make_config(spec.config, params), intr, scene, 30, None)
    tr = get_trace(trace_name, scene=scene)
    out: dict = {"digests": [], "srv_ms": [], "gt_ms": []}
    for i in range(N_FRAMES):
        t = i / 30.0
        pose, tgt = tr.pose_at(t), tr.pose_at(t + 0.05)
        ctx = server_context(scene, r, intr, pose, t_s=t, frame_id=i, predict=tr.pose_at, latency_s=0.05)
        t0 = time.perf_counter()
        u = srv.produce(ctx)
        r.ctx.finish()
        t1 = time.perf_counter()
        r.render(scene, t, tgt, intr)
        r.ctx.finish()
        t2 = time.perf_counter()
        out["srv_ms"].append((t1 - t0) * 1e3)
        out["gt_ms"].append((t2 - t1) * 1e3)
        h = hashlib.sha256()
        for k in sorted(u.planes):
            h.update(k.encode() + np.ascontiguousarray(u.planes[k]).tobytes())
        for k in sorted(u.data):
            h.update(k.encode() + u.data[k])
        h.update(repr(sorted((k, v.tobytes() if isinstance(v, np.ndarray) else v) for k, v in u.meta.items())).encode())
        h.update(repr((u.force_idr, sorted((k, v) for k, v in srv.stats().items() if not k.endswith("_ms")))).encode())
        out["digests"].append(h.hexdigest())
    print(json.dumps(out))


def frames(rev: str) -> None:
    """``--frames``: this checkout against a worktree of ``rev``, alternated, frame by frame identical."""
    import subprocess
    import tempfile

    root = Path(__file__).resolve().parents[1]
    base_sha = subprocess.run(["git", "rev-parse", rev], cwd=root, capture_output=True, text=True, check=True).stdout.strip()
    here_sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True).stdout.strip()
    dirty = [ln[3:] for ln in subprocess.run(["git", "status", "--porcelain", "--", "splitrender"], cwd=root,
                                               capture_output=True, text=True).stdout.splitlines()]
    wt = Path(tempfile.mkdtemp(prefix="bench_tss_frames_"))
    subprocess.run(["git", "worktree", "add", "-f", "--detach", str(wt), base_sha], cwd=root, check=True, capture_output=True)
    try:
        runs: dict = {c: {"base": [], "new": []} for c in FRAME_CONFIGS}
        for rnd in range(2):
            for c in FRAME_CONFIGS:
                order = [("base", wt), ("new", root)] if rnd == 0 else [("new", root), ("base", wt)]
                for name, at in order:
                    p = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", str(at), *c],
                                       capture_output=True, text=True, check=True)
                    runs[c][name].append(json.loads(p.stdout.strip().splitlines()[-1]))
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(wt)], cwd=root, capture_output=True)
    rows = []
    for c in FRAME_CONFIGS:
        b, n = runs[c]["base"], runs[c]["new"]
        same = all(x["digests"] == b[0]["digests"] for x in b + n)
        assert same, f"{c}: the updates differ between {rev} and this checkout"

        def over(rs: list) -> float:   # frame 0 (set-up, shader compiles) left out
            return statistics.median(s / g for r in rs for s, g in zip(r["srv_ms"][1:], r["gt_ms"][1:]))

        def ms(rs: list, key: str) -> float:
            return statistics.median(x for r in rs for x in r[key][1:])

        row = {"scene": c[0], "camera": c[1], "params": c[2], "updates_identical": same, "frames": N_FRAMES,
               "base_server_ms": round(ms(b, "srv_ms"), 1), "server_ms": round(ms(n, "srv_ms"), 1),
               "base_truth_ms": round(ms(b, "gt_ms"), 1), "truth_ms": round(ms(n, "gt_ms"), 1),
               "base_over_truth": round(over(b), 2), "over_truth": round(over(n), 2)}
        row["ratio"] = round(row["over_truth"] / row["base_over_truth"], 3)
        rows.append(row)
        print(json.dumps(row), flush=True)
    out = {"benchmark": "bench_tss_gather --frames", "machine": platform.platform(), "size": [320, 180],
           "base": base_sha, "measured": here_sha, "uncommitted": dirty,
           "method": "two sessions per side, alternated; median over frames 1-11 of server ms over the same frame's "
                     "ground-truth ms (both in the child's process); every update's sha256 the same on both sides",
           "results": rows}
    FRAMES_RESULTS.parent.mkdir(parents=True, exist_ok=True)
    FRAMES_RESULTS.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {FRAMES_RESULTS}")


if __name__ == "__main__":
    if "--child" in sys.argv:
        child(*sys.argv[sys.argv.index("--child") + 2:][:3])
    elif "--frames" in sys.argv:
        k = sys.argv.index("--frames")
        frames(sys.argv[k + 1] if len(sys.argv) > k + 1 else "HEAD~1")
    else:
        main()
