"""Objects from model libraries (other people's models) as scene models: loaded, turned to face -y,
scaled to metres, given support surfaces, and made ready for the placer like generated ones.

Sources without units (PartNet-Mobility) are scaled to a height drawn from the class's typical
range (:data:`TYPICAL_HEIGHTS`, the ranges the generator's own families span); a spec's
``height`` or ``scale`` overrides that for any source.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from stratamap.core.errors import DataError
from stratamap.core.geometry.transforms import make_pose
from stratamap.core.lazy import lazy_module
from stratamap.core.library.models import LibraryModel, ModelLibrary, load_partnet, model_from_urdf
from stratamap.core.map.layers import Joint
from stratamap.core.map.priors import TYPICAL_HEIGHTS
from stratamap.core.synthetic.models import ROOT_LINK, Model, ModelPart
from stratamap.core.synthetic.spec import LibrarySource

trimesh = lazy_module("trimesh")
o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")

#: Yaw that turns a model's declared front to -y (the canonical front).
FRONT_YAW = {"-y": 0.0, "+y": np.pi, "+x": -np.pi / 2, "-x": np.pi / 2}

#: Upward faces open to the sky count as a support surface from this much area (m^2) at one
#: height (1 cm bins) and this height (m) up.
MIN_SUPPORT_AREA = 0.03
MIN_SUPPORT_HEIGHT = 0.2


@lru_cache(maxsize=16)
def _library(path: str, up_axis: str) -> ModelLibrary:
    return ModelLibrary.load(path, up_axis=up_axis)


@lru_cache(maxsize=64)
def _partnet(folder: str) -> LibraryModel:
    return load_partnet(Path(folder))


@lru_cache(maxsize=32)
def _urdf(path: str, class_name: str, links: tuple[str, ...]) -> LibraryModel:
    stem = Path(path).stem
    model_id = f"{stem}:{'+'.join(links)}" if links else stem
    return model_from_urdf(Path(path), model_id, class_name, f"urdf_{stem}", links=list(links) or None)


def candidates(source: LibrarySource, class_name: str, key: str) -> list[LibraryModel]:
    """The library models a class may draw from; ``key`` names the spec entry in errors."""
    path = Path(source.path)
    if path.is_file():
        if path.suffix.lower() != ".urdf":
            raise DataError(f"{path}: {key}.path must be a library folder or a .urdf file")
        return [_urdf(str(path), class_name, tuple(source.links or ()))]
    if source.models:
        # PartNet-Mobility objects named by folder: load just those, not the whole collection.
        folders = [path / m for m in source.models]
        if all((f / "mobility.urdf").is_file() for f in folders):
            return [_partnet(str(f)) for f in folders]
        library = _library(str(path), source.up_axis)
        by_id = {m.id: m for m in library}
        found, missing = [], []
        for name in source.models:
            model = by_id.get(name) or by_id.get(f"partnet_{name}")
            (found if model is not None else missing).append(model or name)
        if missing:
            raise DataError(f"{path}: no model {missing} ({key}.models); it holds {sorted(by_id)[:20]}")
        return found
    library = _library(str(path), source.up_axis)
    found = library.by_class(class_name)
    if not found:
        raise DataError(f"{path}: no model of class {class_name!r} ({key}); it holds classes {library.classes()}")
    return found


def scale_for(model: LibraryModel, class_name: str, source: LibrarySource, rng: np.random.Generator) -> float:
    """Metres per model unit: the spec's ``scale``, or its ``height``, or the class's typical
    height for sources without units, else 1."""
    height = float(model.size[2])
    if source.scale is not None:
        return float(source.scale)
    target = source.height
    if target is None and "units" in model.params and model.params["units"] is None:
        target = TYPICAL_HEIGHTS.get(class_name)
        if target is None:
            raise DataError(f"{model.source}: no units and no typical height for class {class_name!r}; give `height`")
    if target is None or height <= 0:
        return 1.0
    low, high = (target, target) if isinstance(target, (int, float)) else target
    return float(rng.uniform(low, high) if high > low else low) / height


def support_surfaces(parts: list[ModelPart]) -> list[tuple[float, float, float, float, float]]:
    """Horizontal upward-facing surfaces open to the sky (nothing of the model above them: a
    countertop, a cabinet's top, not the shelves inside it) as ``(xmin, ymin, xmax, ymax, z)``
    rectangles shrunk by 2 cm: where cups and monitors may go."""
    mesh = trimesh.util.concatenate([p.mesh for p in parts])
    normals, centers, areas = mesh.face_normals, mesh.triangles_center, mesh.area_faces
    up = np.flatnonzero((normals[:, 2] > 0.97) & (areas > 0) & (centers[:, 2] >= MIN_SUPPORT_HEIGHT))
    if len(up) == 0:
        return []
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3c.Tensor(np.asarray(mesh.vertices, np.float32)), o3c.Tensor(np.asarray(mesh.faces, np.uint32))
    )
    origins = centers[up] + [0.0, 0.0, 1e-3]
    rays = np.hstack([origins, np.tile([0.0, 0.0, 1.0], (len(up), 1))]).astype(np.float32)
    up = up[~np.isfinite(scene.cast_rays(o3c.Tensor(rays))["t_hit"].numpy())]
    if len(up) == 0:
        return []
    level = np.round(centers[up, 2] / 0.01).astype(np.int64)
    keys, inverse = np.unique(level, return_inverse=True)
    total = np.bincount(inverse.reshape(-1), weights=areas[up])
    out = []
    for key in keys[total >= MIN_SUPPORT_AREA]:
        faces = up[level == key]
        corners = mesh.triangles[faces]
        lo, hi = corners[:, :, :2].reshape(-1, 2).min(0) + 0.02, corners[:, :, :2].reshape(-1, 2).max(0) - 0.02
        if (hi > lo).all():
            out.append((float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]), float(corners[:, :, 2].max())))
    return out


def to_scene_model(model: LibraryModel, class_name: str, source: LibrarySource, rng: np.random.Generator) -> Model:
    """One object of ``model`` for a scene: front to -y, scaled to metres, origin at the bottom center."""
    s = scale_for(model, class_name, source, rng)
    turn = make_pose((0.0, 0.0, 0.0), FRONT_YAW[source.front])
    placed = turn.copy()
    placed[:3, :3] *= s
    parts = []
    for p in model.parts:
        mesh = p.load().copy()
        mesh.apply_transform(placed)
        colors = None if p.face_colors is None else np.asarray(p.face_colors, np.float32)
        parts.append(ModelPart(p.name, mesh, tuple(p.albedo), p.semantic or p.name, p.link, colors))
    lo = np.min([p.mesh.bounds[0] for p in parts], 0)
    hi = np.max([p.mesh.bounds[1] for p in parts], 0)
    shift = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    for p in parts:
        p.mesh.apply_translation(shift)
    joints = []
    for j in model.joints:
        origin = np.asarray(j.origin, float).copy()
        origin[:3, 3] *= s
        if j.parent == ROOT_LINK:
            origin = turn @ origin
            origin[:3, 3] += shift
        travel = s if j.type == "prismatic" else 1.0  # prismatic limits are lengths; angles do not scale
        lower, upper = j.lower * travel, j.upper * travel
        joints.append(Joint(j.name, j.type, j.parent, j.child, origin, j.axis.copy(), lower, upper))
    params = {
        "library": str(source.path),
        "library_model": model.id,
        "scale": round(s, 6),
        "front": source.front,
    }
    return Model(model.id, class_name, model.family, params, parts, joints, support_surfaces(parts))
