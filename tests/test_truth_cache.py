"""The ground-truth cache: a second run reuses every frame with identical scores; any key part misses."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from splitrender.scene import get_scene
from splitrender.scene.pose import Pose
from splitrender.scene.trace import get_trace
from splitrender.sim import RunConfig
from splitrender.sim.runner import VirtualTimeRun
from splitrender.sim.truth import (CachedTruth, GroundTruthCache, TruthKey, cache_dir, decode_frame, encode_frame, renderer_version,
                                   scene_digest, trace_digest)

SCORES = ("mse", "psnr_db", "ssim", "dssim", "flip", "lab_err_pct", "hole_pct", "fg_pct", "fg_mse", "fg_psnr_db", "fg_flip")


def _scores(frames):
    return [[f[k] for k in SCORES] for f in frames]


def _same(a, b):
    return all((x == y) or (math.isnan(x) and math.isnan(y)) for ra, rb in zip(a, b) for x, y in zip(ra, rb)) and len(a) == len(b)


def test_second_run_reuses_every_ground_truth_frame_with_identical_scores(tmp_path, renderer):
    cfg = RunConfig(method="atw", scene="default+nogi", trace="walk", network="lan", duration_s=0.5, width=160, height=90,
                    flip_every=3, truth_cache=str(tmp_path / "gt"))
    first = VirtualTimeRun(cfg, renderer)
    a = first.run()
    n = len(a.frames)
    assert n >= 25 and (first.truth.cache.hits, first.truth.cache.misses) == (0, n)
    assert len(list((tmp_path / "gt").rglob("*.srgt"))) == n and not list((tmp_path / "gt").rglob(".tmp-*"))
    second = VirtualTimeRun(cfg, renderer)
    b = second.run()
    assert (second.truth.cache.hits, second.truth.cache.misses) == (n, 0)
    assert _same(_scores(a.frames), _scores(b.frames))
    # a hit reports the render time stored with the frame, so gt_ms stays the cost of rendering
    assert [f["gt_ms"] for f in b.frames] == pytest.approx([f["gt_ms"] for f in a.frames])
    # and the cache changes nothing: the same run without it scores the same
    c = VirtualTimeRun(cfg.replace(truth_cache=""), renderer).run()
    assert _same(_scores(a.frames), _scores(c.frames))
    assert cfg.key() == cfg.replace(truth_cache="").key()   # the cache location is not part of a run's identity


def test_changing_any_key_part_misses(tmp_path, renderer):
    scene = get_scene("minimal")
    trace = get_trace("walk", 1.0)
    base = TruthKey(scene_digest(scene), renderer_version(renderer.ctx.info), trace_digest(trace), 160, 90, 60.0, 30.0)
    cache = GroundTruthCache(tmp_path)
    pose = trace.pose_at(0.5)
    img = np.zeros((90, 160, 3), np.uint8)
    ids = np.zeros((90, 160), np.uint32)
    cache.put(base, 0.5, pose, img, ids, 3.0)
    assert cache.get(base, 0.5, pose) is not None

    edited = get_scene("minimal")
    edited.objects[0].material.texture[0, 0, 0] ^= 1          # one texel of the floor
    moved = get_scene("minimal")
    moved.objects[1].transform = moved.objects[1].transform.copy()
    moved.objects[1].transform[0, 3] += 1e-6                   # a micrometre
    sky = dataclasses.replace(get_scene("minimal"), sky_color=(0.55, 0.7, 0.91))
    lit = get_scene("minimal+gi")                                 # global illumination changes every pixel
    assert len({scene_digest(s) for s in (scene, edited, moved, sky, lit)}) == 5
    assert scene_digest(get_scene("default")) != scene_digest(get_scene("default+nogi"))
    assert scene_digest(get_scene("minimal")) == base.scene        # the same content hashes the same
    other_gl = renderer_version({"GL_RENDERER": "some GPU", "GL_VERSION": "4.6"})
    variants = [
        dataclasses.replace(base, scene=scene_digest(edited)),
        dataclasses.replace(base, renderer=other_gl),
        dataclasses.replace(base, trace=trace_digest(get_trace("turn", 1.0))),
        dataclasses.replace(base, trace=trace_digest(get_trace("walk", 2.0))),   # a longer trace is another trace
        dataclasses.replace(base, width=162),
        dataclasses.replace(base, height=92),
        dataclasses.replace(base, fov_y_deg=70.0),
        dataclasses.replace(base, fps=60.0),
    ]
    for k in variants:
        assert cache.get(k, 0.5, pose) is None, k
    assert cache.get(base, 0.5 + 1e-9, pose) is None                        # time
    assert cache.get(base, 0.5, Pose(pose.position + 1e-9, pose.orientation)) is None   # pose
    assert cache.get(base, 0.5, pose) is not None


def test_renderer_version_follows_the_shader_sources(monkeypatch, tmp_path):
    import splitrender.sim.truth as truth

    (tmp_path / "shaders").mkdir()
    (tmp_path / "shaders" / "a.frag").write_text("void main() {}\n")
    (tmp_path / "renderer.py").write_text("# renderer\n")
    monkeypatch.setattr(truth, "RENDER_DIR", tmp_path)
    v1 = truth.renderer_version({})
    (tmp_path / "shaders" / "a.frag").write_text("void main() { }\n")
    assert truth.renderer_version({}) != v1


def test_unreadable_or_torn_files_are_misses_and_get_replaced(tmp_path, renderer):
    scene, trace = get_scene("minimal"), get_trace("static", 1.0)
    key = TruthKey(scene_digest(scene), "r", trace_digest(trace), 32, 18, 60.0, 30.0)
    pose = trace.pose_at(0.0)
    color = (np.arange(32 * 18 * 3) % 251).astype(np.uint8).reshape(18, 32, 3)
    ids = (np.arange(32 * 18) % 7).astype(np.uint32).reshape(18, 32)
    blob = encode_frame(color, ids, 1.5)
    f = decode_frame(blob, 18, 32)
    assert f is not None and np.array_equal(f.color, color) and np.array_equal(f.object_id, ids) and f.render_ms == 1.5
    for bad in (blob[:-1], blob[:10], b"", b"XXXX" + blob[4:], blob[:-4] + b"\0\0\0\0"):
        assert decode_frame(bad, 18, 32) is None
    assert decode_frame(blob, 18, 34) is None
    cache = GroundTruthCache(tmp_path)
    cache.put(key, 0.0, pose, color, ids)
    path = next(tmp_path.rglob("*.srgt"))
    path.write_bytes(blob[: len(blob) // 2])          # a torn write from a crashed process
    src = CachedTruth(renderer, cache, dataclasses.replace(key))
    from splitrender.scene.pose import CameraIntrinsics

    out = src.render(scene, 0.0, pose, CameraIntrinsics(32, 18), ("color", "object_id"))
    assert cache.misses == 1 and out.color.shape == (18, 32, 3)
    again = cache.get(key, 0.0, pose)
    assert again is not None and np.array_equal(again.color, out.color)


def test_cache_location(monkeypatch, tmp_path):
    monkeypatch.delenv("SPLITRENDER_TRUTH_CACHE", raising=False)
    assert cache_dir("") is None
    assert str(cache_dir("default")).endswith(".cache/splitrender/truth")
    monkeypatch.setenv("SPLITRENDER_TRUTH_CACHE", str(tmp_path))
    assert cache_dir("default") == tmp_path
    assert cache_dir(str(tmp_path / "x")) == tmp_path / "x"
