"""Sensor simulation by ray casting with Open3D (no GPU, no display)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
import open3d.core as o3c

from stratamap.core.sensors import CameraIntrinsics
from stratamap.core.synthetic.scene import Scene
from stratamap.core.transforms import invert, look_at
from stratamap.core.vocabulary import Vocabulary

LIGHT_DIRECTION = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])


@dataclass
class RenderedView:
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 metres, 0 = no return
    class_ids: np.ndarray  # (H, W) uint16
    instance_ids: np.ndarray  # (H, W) int32


class SceneRenderer:
    """Casts camera rays into a :class:`Scene`; each mesh part is one ray-casting geometry."""

    def __init__(self, scene: Scene, vocabulary: Vocabulary | None = None):
        vocab = vocabulary or Vocabulary.default()
        self.raycaster = o3d.t.geometry.RaycastingScene()
        albedo, classes, instances = [], [], []

        def add(mesh, color, class_name, instance_id):
            self.raycaster.add_triangles(
                o3c.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
                o3c.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
            )
            albedo.append(color)
            classes.append(vocab.id(class_name))
            instances.append(instance_id)

        for el in scene.layout:
            add(el.mesh, el.albedo, el.class_name, 0)
        for obj in scene.objects:
            for part, mesh in obj.world_parts():
                add(mesh, part.albedo, obj.class_name, obj.id)
        # Index len(...) is the "no hit" entry (Open3D reports INVALID_ID, remapped below).
        self._albedo = np.vstack([np.asarray(albedo, dtype=np.float32), np.zeros((1, 3), np.float32)])
        self._class = np.append(np.asarray(classes, dtype=np.uint16), 0)
        self._instance = np.append(np.asarray(instances, dtype=np.int32), 0)
        self._n = len(classes)

    def render(self, intrinsics: CameraIntrinsics, camera_to_world: np.ndarray, max_range: float = 10.0) -> RenderedView:
        rays = self.raycaster.create_rays_pinhole(
            o3c.Tensor(intrinsics.matrix),
            o3c.Tensor(invert(camera_to_world)),
            intrinsics.width,
            intrinsics.height,
        )
        hit = self.raycaster.cast_rays(rays)
        # With pinhole rays whose direction has unit optical-axis component, t_hit is the z depth.
        depth = hit["t_hit"].numpy().astype(np.float32)
        gid = hit["geometry_ids"].numpy().astype(np.int64)
        valid = np.isfinite(depth) & (depth < max_range) & (gid < self._n)
        gid = np.where(valid, gid, self._n)
        depth = np.where(valid, depth, 0.0).astype(np.float32)

        normals = hit["primitive_normals"].numpy()
        dirs = rays.numpy()[..., 3:]
        dirs = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
        facing = np.abs(np.einsum("hwc,hwc->hw", normals, -dirs))
        sun = np.abs(normals @ LIGHT_DIRECTION)
        shade = 0.25 + 0.45 * facing + 0.3 * sun
        rgb = np.clip(self._albedo[gid] * shade[..., None], 0.0, 1.0)
        rgb = (rgb * 255.0 + 0.5).astype(np.uint8)
        rgb[~valid] = 0
        return RenderedView(rgb, depth, self._class[gid], self._instance[gid])


def orbit_trajectory(scene: Scene, frames: int, height: float = 1.4, look_height: float = 0.5) -> list[np.ndarray]:
    """Camera-to-world optical poses on an ellipse inside the room, looking at its center."""
    lx, ly, _ = scene.room_size
    center = np.array([lx / 2, ly / 2])
    rx, ry = max(lx / 2 - 0.45, 0.5), max(ly / 2 - 0.45, 0.5)
    poses = []
    for k in range(frames):
        a = 2 * np.pi * k / max(frames, 1)
        eye = np.array([center[0] + rx * np.cos(a), center[1] + ry * np.sin(a), height])
        poses.append(look_at(eye, [center[0], center[1], look_height]))
    return poses
