"""From a scene spec to a sensor stream with ground truth, in memory."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from stratamap.core.groundtruth import GroundTruth
from stratamap.core.sensors import CameraIntrinsics, FrameSegmentation, RGBDFrame, SensorStream
from stratamap.core.synthetic.render import SceneRenderer, orbit_trajectory
from stratamap.core.synthetic.scene import Scene, SceneSpec, generate_scene
from stratamap.core.vocabulary import Vocabulary


class CameraSpec(BaseModel):
    """The simulated RGB-D camera and its path."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    width: int = Field(default=640, ge=16, le=4096, description="Image width in pixels.")
    height: int = Field(default=480, ge=16, le=4096, description="Image height in pixels.")
    fov_x_deg: float = Field(default=62.0, gt=10, lt=170, description="Horizontal field of view, degrees (Kinect v1: ~62).")
    max_range: float = Field(default=8.0, gt=0, description="Depth beyond this range reads as no measurement, metres.")
    height_m: float = Field(default=1.4, gt=0, description="Camera height above the floor along the path, metres.")
    frame_rate: float = Field(default=30.0, gt=0, description="Timestamps advance by 1/frame_rate seconds.")

    def intrinsics(self) -> CameraIntrinsics:
        fx = self.width / (2 * np.tan(np.radians(self.fov_x_deg) / 2))
        return CameraIntrinsics(self.width, self.height, fx, fx, (self.width - 1) / 2, (self.height - 1) / 2)


@dataclass
class SyntheticSequence:
    scene: Scene
    stream: SensorStream
    ground_truth: GroundTruth


def generate_sequence(spec: SceneSpec, camera: CameraSpec, frames: int) -> SyntheticSequence:
    """Generate the scene, render ``frames`` RGB-D frames along an orbit, and collect ground truth."""
    vocab = Vocabulary.default()
    scene = generate_scene(spec)
    renderer = SceneRenderer(scene, vocab)
    intr = camera.intrinsics()
    out_frames, labels = [], []
    for k, pose in enumerate(orbit_trajectory(scene, frames, height=camera.height_m)):
        view = renderer.render(intr, pose, camera.max_range)
        t = k / camera.frame_rate
        out_frames.append(RGBDFrame(k, t, view.rgb, view.depth, pose))
        labels.append(FrameSegmentation(k, view.class_ids, view.instance_ids))
    stream = SensorStream(
        name=f"synthetic-{spec.type}-seed{spec.seed}",
        intrinsics=intr,
        frames=out_frames,
        metadata={"scene_spec": spec.model_dump(mode="json"), "depth_unit": "m"},
    )
    gt = GroundTruth(
        vocabulary=vocab,
        objects=scene.ground_truth_objects(),
        frame_labels=labels,
        contact_graph=scene.contact_graph(),
        layout=scene.layout_info(),
    )
    return SyntheticSequence(scene, stream, gt)
