"""``sas`` detail and compactness (issue 15): load-time splitting of large patches,
level selection that gives a patch as many texels as it covers pixels, the still-camera
comparison with ``video`` at zero latency, and the compact geometry of wire format v3."""

from __future__ import annotations

import numpy as np
import pytest

from splitrender.scene.pose import CameraIntrinsics

INTR = CameraIntrinsics(320, 180)
BOX_TEXTURED = "/usr/share/assimp/models/glTF2/BoxTextured-glTF-Binary/BoxTextured.glb"


def test_split_mesh_is_conforming_and_renders_the_same() -> None:
    """Red-green refinement: every edge within the bound, no cracks (the split floor renders as the original)."""
    from splitrender.methods.sas.patches import split_mesh, split_scene_meshes
    from splitrender.metrics.image import psnr
    from splitrender.render.renderer import Renderer
    from splitrender.scene.loader import get_scene
    from splitrender.scene.trace import get_trace

    scene = get_scene("minimal")
    floor = scene.objects[0].mesh
    m = split_mesh(floor, 0.3)
    p = m.positions[m.indices]
    edges = np.linalg.norm(p[:, [1, 2, 0]] - p, axis=2)
    assert edges.max() <= 0.3 and m.triangle_count > 16 * floor.triangle_count, (edges.max(), m.triangle_count)
    assert np.isclose(m.triangle_areas().sum(), floor.triangle_areas().sum(), rtol=1e-5), "the split covers the same area"
    # every interior edge is shared by exactly two triangles, boundary edges lie on the original boundary
    e = np.sort(np.stack([m.indices[:, [0, 1]], m.indices[:, [1, 2]], m.indices[:, [2, 0]]], 1).reshape(-1, 2), 1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert counts.max() == 2, "an edge is used by more than two triangles"
    r = Renderer()
    pose = get_trace("static").pose_at(0.5)
    before = r.render(scene, 0.5, pose, INTR, ("color",)).color
    meshes, bound = split_scene_meshes(scene, 0.15, 10**6)
    assert bound == 0.15
    split = get_scene("minimal")
    for o, mesh in zip(split.objects, meshes):
        o.mesh = mesh
    after = r.render(split, 0.5, pose, INTR, ("color",)).color
    assert psnr(after, before) >= 60.0, f"split scene renders differently: {psnr(after, before):.1f} dB"
    # the triangle cap: the bound grows until the split fits
    meshes, bound = split_scene_meshes(scene, 0.15, 2000)
    assert sum(x.triangle_count for x in meshes) <= 2000 and bound > 0.15
