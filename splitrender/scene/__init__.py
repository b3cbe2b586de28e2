"""Scene model, procedural scenes, file loading, camera traces and pose prediction."""

from .loader import get_scene, load_scene_file
from .model import Animation, DirectionalLight, Material, Mesh, Oscillate, Patrol, PointLight, Scene, SceneObject, Schedule, Spin
from .pose import CameraIntrinsics, Pose
from .procedural import default_scene, minimal_scene

__all__ = [
    "Animation", "CameraIntrinsics", "DirectionalLight", "Material", "Mesh", "Oscillate", "Patrol", "PointLight", "Pose",
    "Scene", "SceneObject", "Schedule", "Spin", "default_scene", "get_scene", "load_scene_file", "minimal_scene",
]
