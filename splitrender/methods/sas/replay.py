"""Offline replays for the allocator studies (paper sections 5.3 and 5.4).

:func:`record_visibility` runs the PVS and the continuous part of level selection
along a camera trace once (GL); :func:`replay_allocation` then feeds that sequence to
a :class:`~.allocator.PatchAllocator` of any strategy with the server's I-frame and
reset rules, timing every frame, so strategies are compared on identical input.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...scene.model import Scene
from ...scene.pose import CameraIntrinsics
from .allocator import AtlasLayout, BaselineAllocator, PatchAllocator, Strategy
from .levels import ideal_log_size, patch_world_slots, select_levels
from .patches import ScenePatches, build_scene_patches
from .pvs import PatchIdPass, sample_times


@dataclass
class VisibilityFrame:
    """One server frame: PVS patch ids (sorted) and their continuous ``(A, a)`` (log2 texels)."""

    t_s: float
    pvs: np.ndarray
    A: np.ndarray
    a: np.ndarray


def record_visibility(renderer: Any, scene: Scene, trace: Any, intr: CameraIntrinsics, t0_s: float, frames: int,
                      server_fps: int = 30, latency_s: float = 0.05, fov_margin: float = 0.2, step_s: float = 1 / 30,
                      patches: ScenePatches | None = None) -> tuple[ScenePatches, list[VisibilityFrame]]:
    """PVS (trace poses as perfect prediction) and ideal level sizes per server frame."""
    patches = patches or build_scene_patches(scene)
    ids = PatchIdPass(renderer, scene, patches)
    big = intr.enlarged(1 + fov_margin, keep_pixel_density=True)
    px_per_rad = intr.width / math.radians(intr.fov_x_deg)
    out = []
    for f in range(frames):
        t = t0_s + f / server_fps
        samples = [(s, trace.pose_at(s)) for s in sample_times(t, t + latency_s + 1 / server_fps, step_s)]
        pvs = np.flatnonzero(ids.pvs_area(samples, big) > 0)
        models = np.stack([o.model_matrix(t) for o in scene.objects])
        world = patch_world_slots(patches, pvs, models)
        A, a = ideal_log_size(patches, pvs, world, np.asarray(samples[-1][1].position), px_per_rad)
        out.append(VisibilityFrame(t, pvs, A, a))
    return patches, out


@dataclass
class ReplayResult:
    """Per-frame allocator numbers of one strategy (ms, texels, counts)."""

    strategy: str
    alloc_ms: list[float] = field(default_factory=list)
    levels_ms: list[float] = field(default_factory=list)
    memory: list[dict[str, int]] = field(default_factory=list)
    failed: list[int] = field(default_factory=list)
    resets: int = 0
    oom_frames: int = 0
    placed: list[int] = field(default_factory=list)


def replay_allocation(patches: ScenePatches, seq: list[VisibilityFrame], layout: AtlasLayout, strategy: Strategy,
                      gop: int = 5, high_water: float = 0.9, bias_fill: float = 0.75, hysteresis: float = 0.75) -> ReplayResult:
    """Run the server's level selection + allocation rules over ``seq`` with one strategy."""
    al = PatchAllocator(patches.count, layout, strategy)
    out = ReplayResult(strategy)
    for f, fr in enumerate(seq):
        t0 = time.perf_counter()
        c = select_levels(fr.A, fr.a, layout, bias_fill * layout.area, al.level_w[fr.pvs], al.level_h[fr.pvs], None, hysteresis)
        t1 = time.perf_counter()
        iframe = f % gop == 0
        reset = iframe and (f == 0 or al.memory_load() > high_water)
        res = al.update(fr.pvs, c.lw, c.lh, reset=reset)
        if res.failed.size and al.can_reset and not reset:
            c = select_levels(fr.A, fr.a, layout, bias_fill * layout.area)
            res = al.update(fr.pvs, c.lw, c.lh, reset=True)
        t2 = time.perf_counter()
        out.levels_ms.append((t1 - t0) * 1e3)
        out.alloc_ms.append((t2 - t1) * 1e3)
        out.memory.append(al.memory().as_dict())
        out.failed.append(int(res.failed.size))
        out.placed.append(int(res.placed.size))
        out.oom_frames += int(res.failed.size > 0)
    out.resets = al.resets
    return out


def replay_baseline(seq: list[VisibilityFrame], layout: AtlasLayout) -> list[float]:
    """Per-frame ms of the per-patch Python loop :class:`BaselineAllocator` on the same input."""
    b = BaselineAllocator(layout)
    ms = []
    for fr in seq:
        c = select_levels(fr.A, fr.a, layout, 0.75 * layout.area)
        t0 = time.perf_counter()
        b.update(fr.pvs, c.lw, c.lh)
        ms.append((time.perf_counter() - t0) * 1e3)
    return ms
