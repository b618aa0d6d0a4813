"""Synthetic worlds: parametric models, procedural scenes, ray-cast sensors and full ground truth."""

from stratamap.core.synthetic.generate import SyntheticSequence, CameraSpec, generate_sequence
from stratamap.core.synthetic.scene import Scene, SceneSpec, generate_scene

__all__ = ["CameraSpec", "Scene", "SceneSpec", "SyntheticSequence", "generate_scene", "generate_sequence"]
