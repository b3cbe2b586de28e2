"""Scene model, procedural scenes, file loading, camera traces and pose prediction.

Names are loaded on first use, so that importing :mod:`splitrender.scene.pose` (which a
client half needs) does not import the scene model or the loaders (which it must not).
"""

from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "get_scene": "loader", "load_scene_file": "loader",
    **{n: "model" for n in ("Animation", "DirectionalLight", "Material", "Mesh", "Oscillate", "Patrol", "PointLight", "Scene",
                            "SceneObject", "Schedule", "Spin")},
    "CameraIntrinsics": "pose", "Pose": "pose", "default_scene": "procedural", "minimal_scene": "procedural",
}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    mod = _WHERE.get(name)
    if mod is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{mod}"), name)
