"""Sensor simulation by ray casting with Open3D (no GPU, no display): RGB-D camera, 2D laser, 3D LiDAR."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stratamap.core.geometry.transforms import invert
from stratamap.core.lazy import lazy_module
from stratamap.core.map.sensors import CameraIntrinsics
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.synthetic.scene import Scene

o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")

KINECT_FOCAL_BASELINE = 580.0 * 0.075  # pixels x metres

LIGHT_DIRECTION = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])


@dataclass
class RenderedView:
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 metres, 0 = no return
    class_ids: np.ndarray  # (H, W) uint16
    instance_ids: np.ndarray  # (H, W) int32
    incidence_cos: np.ndarray  # (H, W) float32: |cos| of the angle between ray and surface normal


class SceneRenderer:
    """Casts rays into a :class:`Scene`; each mesh part is one ray-casting geometry.

    A part has one albedo, or per-face colours (models from libraries: textures and materials);
    the per-face table is built only when some part has them, so generated scenes render as fast
    as ever."""

    def __init__(self, scene: Scene, vocabulary: Vocabulary | None = None):
        vocab = vocabulary or Vocabulary.default()
        self.raycaster = o3d.t.geometry.RaycastingScene()
        albedo, classes, instances, face_colors, face_counts = [], [], [], [], []
        for class_name, instance_id, mesh, color, colors in scene.colored_meshes():
            self.raycaster.add_triangles(
                o3c.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
                o3c.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
            )
            albedo.append(color)
            classes.append(vocab.id(class_name))
            instances.append(instance_id)
            face_colors.append(colors)
            face_counts.append(len(mesh.faces))
        # Index n is the "no hit" entry (Open3D reports INVALID_ID, remapped below).
        self._albedo = np.vstack([np.asarray(albedo, dtype=np.float32), np.zeros((1, 3), np.float32)])
        self._class = np.append(np.asarray(classes, dtype=np.uint16), 0)
        self._instance = np.append(np.asarray(instances, dtype=np.int32), 0)
        self._n = len(classes)
        self._face_albedo: np.ndarray | None = None
        if any(c is not None for c in face_colors):
            # One row per triangle of the scene (geometry g's faces start at _face_offset[g]).
            self._face_offset = np.concatenate([[0], np.cumsum(face_counts)]).astype(np.int64)
            rows = [
                np.broadcast_to(np.asarray(albedo[g], np.float32), (face_counts[g], 3)) if c is None else c
                for g, c in enumerate(face_colors)
            ]
            self._face_albedo = np.vstack([*rows, np.zeros((1, 3), np.float32)]).astype(np.float32)

    def render(
        self, intrinsics: CameraIntrinsics, camera_to_world: np.ndarray, max_range: float = 10.0
    ) -> RenderedView:
        rays = self.raycaster.create_rays_pinhole(
            o3c.Tensor(intrinsics.matrix), o3c.Tensor(invert(camera_to_world)), intrinsics.width, intrinsics.height
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
        facing = np.abs(np.einsum("hwc,hwc->hw", normals, -dirs)).astype(np.float32)
        sun = np.abs(normals @ LIGHT_DIRECTION)
        shade = 0.25 + 0.45 * facing + 0.3 * sun
        if self._face_albedo is None:
            color = self._albedo[gid]
        else:
            face = self._face_offset[gid] + np.where(valid, hit["primitive_ids"].numpy().astype(np.int64), 0)
            color = self._face_albedo[np.where(valid, face, len(self._face_albedo) - 1)]
        rgb = np.clip(color * shade[..., None], 0.0, 1.0)
        rgb = (rgb * 255.0 + 0.5).astype(np.uint8)
        rgb[~valid] = 0
        return RenderedView(
            rgb, depth, self._class[gid], self._instance[gid], np.where(valid, facing, 0).astype(np.float32)
        )

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Distances along unit ``directions`` from ``origins`` (inf where nothing is hit)."""
        rays = np.hstack([origins, directions]).astype(np.float32)
        return self.raycaster.cast_rays(o3c.Tensor(rays))["t_hit"].numpy().astype(np.float64)


def apply_kinect_noise(
    view: RenderedView,
    rng: np.random.Generator,
    min_range: float,
    max_range: float,
    grazing_angle_deg: float,
    edge_dropout: float,
) -> np.ndarray:
    """Kinect-v1-like depth: dropouts at grazing angles and depth edges, axial noise
    sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 (Nguyen et al. 2012), disparity quantized to 1/8 pixel."""
    z = view.depth.astype(np.float64)
    valid = (z >= min_range) & (z <= max_range)
    valid &= view.incidence_cos >= np.cos(np.radians(grazing_angle_deg))
    # Depth discontinuities: a neighbour differs by more than 4% of the depth.
    zp = np.pad(z, 1, mode="edge")
    jump = np.zeros_like(z, dtype=bool)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        jump |= np.abs(zp[dy : dy + z.shape[0], dx : dx + z.shape[1]] - z) > 0.04 * np.maximum(z, 1e-6)
    valid &= ~(jump & (rng.random(z.shape) < edge_dropout))
    sigma = 0.0012 + 0.0019 * (z - 0.4) ** 2
    noisy = z + rng.standard_normal(z.shape) * sigma
    # Quantization comes from the Kinect's own IR camera (f = 580 px, baseline 7.5 cm), whatever
    # resolution the simulated images have.
    fb = KINECT_FOCAL_BASELINE
    disparity = np.round(fb / np.maximum(noisy, 1e-3) * 8.0) / 8.0
    noisy = fb / np.maximum(disparity, 1e-6)
    return np.where(valid, noisy, 0.0).astype(np.float32)


def laser_directions(n: int, fov_deg: float) -> np.ndarray:
    """Beam angles of a planar scanner, centered on its heading."""
    fov = np.radians(fov_deg)
    if fov_deg >= 360:
        return -np.pi + np.arange(n) * (2 * np.pi / n)
    return -fov / 2 + np.arange(n) * (fov / max(n - 1, 1))


def lidar_directions(rings: int, vfov_deg: tuple[float, float], per_ring: int) -> np.ndarray:
    """Unit directions (rings * per_ring, 3) in the sensor frame (x forward, z up)."""
    elev = np.radians(np.linspace(vfov_deg[0], vfov_deg[1], rings))
    azim = np.arange(per_ring) * (2 * np.pi / per_ring)
    e, a = np.meshgrid(elev, azim, indexing="ij")
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
