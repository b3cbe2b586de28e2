"""Cost of DDGI global illumination (``splitrender/gi``), as ratios to a ground-truth render without it.

The default scene's probe volume (8 x 4 x 8 probes, 6 x 8^2 = 384 rays each): the one-time capture
of every probe's cube faces, one update (relighting with two bounces, the irradiance
and distance reductions, the texture uploads), an update a volume built alike relit before (a
shared state, :class:`~splitrender.render.ddgi.ProbeStates`: what every run after the first
in a demo worker meets), and a 320x180 render of a walk frame
with GI on, each as a ratio to the median 320x180 render of the same frame without GI,
measured in the same process.  An update happens whenever the lights or (with animated
shadow casters, as in the default scene) the time change.

Writes ``benchmarks/results/bench_gi.json``.  Run: ``python benchmarks/bench_gi.py``.
"""

from __future__ import annotations

import json
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, not an installed one

from splitrender.render.renderer import Renderer  # noqa: E402
from splitrender.scene.loader import get_scene  # noqa: E402
from splitrender.scene.pose import CameraIntrinsics  # noqa: E402
from splitrender.scene.trace import get_trace  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "bench_gi.json"
REPEATS = 7


def main() -> None:
    r = Renderer()
    intr = CameraIntrinsics(320, 180, 60.0)
    plain, lit = get_scene("default+nogi"), get_scene("default")
    pose = get_trace("walk", scene=plain).pose_at(1.0)

    def timed(fn) -> float:  # type: ignore[no-untyped-def]
        t0 = time.perf_counter()
        fn()
        return (time.perf_counter() - t0) * 1e3

    r.render(plain, 1.0, pose, intr)
    base = statistics.median(timed(lambda: r.render(plain, 1.0, pose, intr)) for _ in range(REPEATS))
    capture = timed(lambda: r.gi_volume(lit))
    vol = r.gi_volume(lit)
    ts = iter([1.0 + 0.01 * k for k in range(1, 100)])
    update = statistics.median(timed(lambda: vol.update(next(ts))) for _ in range(REPEATS))
    again = r.gi_volume(get_scene("default"))         # the next run's scene, built alike: the same times are kept states
    ts_again = iter([1.0 + 0.01 * k for k in range(1, 100)])
    update_shared = statistics.median(timed(lambda: again.update(next(ts_again))) for _ in range(REPEATS))
    assert again.reused == REPEATS and again.updates == 0
    vol.update(1.0)
    render_cached = statistics.median(timed(lambda: r.render(lit, 1.0, pose, intr)) for _ in range(REPEATS))
    ts2 = iter([2.0 + 0.01 * k for k in range(1, 100)])
    render_fresh = statistics.median(timed(lambda: r.render(lit, next(ts2), pose, intr)) for _ in range(REPEATS))
    out = {"benchmark": "bench_gi", "machine": platform.platform(), "renderer": r.ctx.info.get("GL_RENDERER"),
           "probes": vol.count, "rays_per_probe": 6 * vol.settings.face_res ** 2, "bounces": vol.settings.bounces,
           "render_ms_without_gi": base,
           "ratio_to_render": {"capture_once": capture / base, "update": update / base, "update_shared_state": update_shared / base,
                               "render_probes_cached": render_cached / base, "render_with_update": render_fresh / base}}
    for k, v in out["ratio_to_render"].items():
        print(f"{k:22s} {v:6.2f}x a 320x180 render without GI ({base:.0f} ms)")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=1))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
