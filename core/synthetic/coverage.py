"""How much of each object a camera path sees: points sampled on every object's surface, each seen
when some frame has it in view, in range, facing the camera and unoccluded (one ray cast per point
and frame that passes the cheap tests). A ground-truth measure: scaling figures are only about cost
when every object was in view."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from stratamap.core.geometry.transforms import invert
from stratamap.core.map.sensors import CameraIntrinsics
from stratamap.core.synthetic.scene import PlacedObject, Scene

#: A point is unoccluded when the first hit along its ray is no nearer than this to it (metres).
OCCLUSION_TOLERANCE = 0.02


@dataclass
class SurfaceSamples:
    """Points on the objects' surfaces, area-weighted, with their outward normals and owners."""

    points: np.ndarray  # (N, 3)
    normals: np.ndarray  # (N, 3)
    owner: np.ndarray  # (N,) index into the scene's objects


def object_samples(obj: PlacedObject, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points spread over an object's parts by area, and their face normals."""
    verts, faces = [], []
    offset = 0
    for _, mesh in obj.world_parts():
        verts.append(np.asarray(mesh.vertices, float))
        faces.append(np.asarray(mesh.faces, np.int64) + offset)
        offset += len(mesh.vertices)
    v, f = np.vstack(verts), np.vstack(faces)
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(cross, axis=1)
    if area.sum() <= 0:
        return np.repeat(v.mean(0, keepdims=True), count, 0), np.tile([0.0, 0.0, 1.0], (count, 1))
    pick = rng.choice(len(f), size=count, p=area / area.sum())
    a, b = rng.random(count), rng.random(count)
    flip = a + b > 1
    a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
    t = tri[pick]
    points = t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])
    normals = cross[pick] / np.maximum(area[pick], 1e-12)[:, None]
    return points, normals


def scene_samples(scene: Scene, per_object: int, seed: int) -> SurfaceSamples:
    rng = np.random.default_rng([seed, 7919])
    pts, nrm, owner = [], [], []
    for k, obj in enumerate(scene.objects):
        p, n = object_samples(obj, per_object, rng)
        pts.append(p)
        nrm.append(n)
        owner.append(np.full(len(p), k, np.int64))
    if not pts:
        return SurfaceSamples(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64))
    return SurfaceSamples(np.vstack(pts), np.vstack(nrm), np.concatenate(owner))


def visible(
    cast: Any,
    eye: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    min_range: float,
    max_range: float,
) -> np.ndarray:
    """Which ``points`` the eye sees: in range, facing it, and first along their rays (``cast``
    gives distances along unit directions from origins)."""
    out = np.zeros(len(points), bool)
    to_eye = eye - points
    dist = np.linalg.norm(to_eye, axis=1)
    # Either side of a face counts: generated parts are closed boxes, library meshes may be open shells.
    cand = (dist >= min_range) & (dist <= max_range)
    cand &= np.abs(np.einsum("ij,ij->i", normals, to_eye)) > 0.05 * dist
    idx = np.flatnonzero(cand)
    if len(idx) == 0:
        return out
    dirs = -to_eye[idx] / dist[idx, None]
    hit = cast(np.broadcast_to(eye, (len(idx), 3)), dirs)
    out[idx] = hit >= dist[idx] - OCCLUSION_TOLERANCE
    return out


def in_view(intrinsics: CameraIntrinsics, camera_to_world: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Which points project inside the image, in front of the camera."""
    world_to_camera = invert(camera_to_world)
    cam = points @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    z = cam[:, 2]
    front = z > 1e-6
    u = intrinsics.fx * cam[:, 0] / np.where(front, z, 1) + intrinsics.cx
    v = intrinsics.fy * cam[:, 1] / np.where(front, z, 1) + intrinsics.cy
    return front & (u >= 0) & (u <= intrinsics.width - 1) & (v >= 0) & (v <= intrinsics.height - 1)


def surface_coverage(
    scene: Scene,
    cast: Any,
    intrinsics: CameraIntrinsics,
    poses: list[np.ndarray],
    min_range: float,
    max_range: float,
    per_object: int = 200,
    seed: int = 0,
) -> dict[str, Any]:
    """The share of each object's surface samples that some frame sees; ``cast`` is
    :meth:`SceneRenderer.cast`. Points an object hides itself (the underside of a box on the floor)
    are never seen, so a fully seen object scores below 1."""
    samples = scene_samples(scene, per_object, seed)
    seen = np.zeros(len(samples.points), bool)
    for pose in poses:
        todo = np.flatnonzero(~seen)
        if len(todo) == 0:
            break
        look = todo[in_view(intrinsics, pose, samples.points[todo])]
        if len(look):
            hit = visible(cast, pose[:3, 3], samples.points[look], samples.normals[look], min_range, max_range)
            seen[look[hit]] = True
    n = len(scene.objects)
    share = np.bincount(samples.owner[seen], minlength=n) / max(per_object, 1)
    per = [
        {"id": int(obj.id), "class": obj.class_name, "seen": round(float(share[k]), 4)}
        for k, obj in enumerate(scene.objects)
    ]
    return {
        "objects": n,
        "points_per_object": per_object,
        "mean": round(float(share.mean()), 4) if n else None,
        "min": round(float(share.min()), 4) if n else None,
        "objects_seen": int((share > 0).sum()),
        "objects_half_seen": int((share >= 0.5).sum()),
        "per_object": per,
    }
