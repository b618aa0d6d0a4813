"""Synthetic worlds: parametric models, procedural scenes, ray-cast sensors and full ground truth."""

from stratamap.core.synthetic.generate import SyntheticSequence, SyntheticWorld, generate_sequence
from stratamap.core.synthetic.scene import Scene, generate_scene
from stratamap.core.synthetic.spec import SCENE_TYPES, CameraSpec, SceneSpec

__all__ = [
    "SCENE_TYPES",
    "CameraSpec",
    "Scene",
    "SceneSpec",
    "SyntheticSequence",
    "SyntheticWorld",
    "generate_scene",
    "generate_sequence",
]
