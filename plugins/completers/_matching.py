"""Shared machinery of model-matching completers: the library, per-object matching in parallel,
posing a library model (with its articulation) in the world, and the augmented scene.

The augmented scene (augmented-representations paper, section IV-B3) is A = (G \\ S) U O: S are
the points of the geometry G within ``epsilon`` of a completed model, O the completed models.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from pydantic import Field

from stratamap.core.geometry.transforms import make_pose
from stratamap.core.lazy import lazy_module
from stratamap.core.library.index import ModelIndex
from stratamap.core.library.models import LibraryModel, ModelLibrary, model_to_library
from stratamap.core.map.instances import plausible
from stratamap.core.map.layers import Completion, Geometry, Joint, ObjectInstance, ObjectInstances, Part
from stratamap.core.stages import Completer, PipelineData, StageConfig

o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")
trimesh = lazy_module("trimesh")


class MatcherConfig(StageConfig):
    path_fields = ("library", "cache_dir")

    library: str | None = Field(
        default=None,
        description=(
            "Model library folder (stratamap, PartNet-Mobility, or meshes + classes.csv); default: a procedural "
            "library."
        ),
    )
    library_per_family: int = Field(
        default=8, ge=1, le=500, description="Models per family of the default procedural library."
    )
    library_seed: int = Field(
        default=1000, description="Seed of the default procedural library (distinct from scene seeds)."
    )
    classes: list[str] | None = Field(
        default=None, description="Complete only these classes (default: every class the library has)."
    )
    min_points: int = Field(
        default=50, ge=3, description="Objects with fewer observed points are left uncompleted (with a warning)."
    )
    shortlist: int | None = Field(
        default=20, ge=1, description="Rank models by global descriptor and align only the top k; null: every model."
    )
    workers: int = Field(
        default=2, ge=1, le=64, description="Objects matched in parallel (threads; KD-tree queries release the GIL)."
    )
    epsilon: float = Field(
        default=0.1,
        gt=0.0,
        description="Augmented scene: observed points this close to a completed model are replaced, metres.",
    )
    sample_spacing: float = Field(
        default=0.02, gt=0.0, description="Surface sampling spacing of models (and of the augmented scene), metres."
    )
    cache_dir: str | None = Field(
        default=None, description="Folder for the model index cache (default: $STRATAMAP_CACHE or ~/.cache/stratamap)."
    )
    recognize: list[str] = Field(
        default_factory=lambda: ["object"],
        description=(
            "Recognition by matching: objects of these classes (no class, as a detector's unknown labels become) "
            "are matched against every class of the library and take the best model's class when its fit passes "
            "recognize_fit; [] turns it off."
        ),
    )
    recognize_weak: float = Field(
        default=0.0,
        ge=0.0,
        le=1.0,
        description=(
            "Objects whose class won less than this share of their points' votes are matched against every class too "
            "(their own included) and take the best-fitting one; 0 (the default) turns it off: a detector's votes "
            "say more than a shape fit against library models unlike the object."
        ),
    )
    recognize_fit: float = Field(
        default=0.03,
        gt=0.0,
        description="Largest mean distance (m) from the observed points to a model for recognition to take its class.",
    )


@dataclass
class Match:
    model_id: str
    yaw: float
    translation: np.ndarray  # object frame origin in the world
    scale: float
    score: float
    details: dict[str, Any]


def default_cache_dir(configured: str | None) -> Path:
    if configured:
        return Path(configured).expanduser()
    return Path(os.environ.get("STRATAMAP_CACHE", Path.home() / ".cache" / "stratamap"))


@functools.lru_cache(maxsize=4)
def procedural_library(per_family: int, seed: int) -> ModelLibrary:
    from stratamap.core.synthetic.models import FAMILIES, make_model

    return ModelLibrary([model_to_library(make_model(f, seed, i)) for f in FAMILIES for i in range(per_family)])


_INDEXES: dict[tuple, ModelIndex] = {}


def register_library(name: str, library: ModelLibrary, spacing: float = 0.02) -> str:
    """Make an in-memory library usable as ``library: "<name>"`` in completer configs (benchmarks, notebooks)."""
    key = f"<{name}>"
    _INDEXES[
        (
            key,
            MatcherConfig.model_fields["library_per_family"].default,
            MatcherConfig.model_fields["library_seed"].default,
            spacing,
        )
    ] = ModelIndex(library, spacing=spacing)
    return key


def load_index(cfg: MatcherConfig) -> ModelIndex:
    key = (
        (
            cfg.library,
            MatcherConfig.model_fields["library_per_family"].default,
            MatcherConfig.model_fields["library_seed"].default,
            cfg.sample_spacing,
        )
        if (cfg.library or "").startswith("<")
        else (cfg.library, cfg.library_per_family, cfg.library_seed, cfg.sample_spacing)
    )
    if cfg.library is not None and cfg.library.startswith("<") and key not in _INDEXES:
        raise KeyError(f"no in-memory library registered as {cfg.library!r} (see register_library)")
    if key not in _INDEXES:
        library = (
            ModelLibrary.load(cfg.library)
            if cfg.library
            else procedural_library(cfg.library_per_family, cfg.library_seed)
        )
        try:
            cache = default_cache_dir(cfg.cache_dir)
            cache.mkdir(parents=True, exist_ok=True)
        except OSError:
            cache = None  # read-only home: index in memory only
        _INDEXES[key] = ModelIndex(library, spacing=cfg.sample_spacing, cache_dir=cache)
    return _INDEXES[key]


def object_base(inst: ObjectInstance, data: PipelineData) -> np.ndarray:
    """Where the object stands: its box's footprint center at its support height (the floor at
    z = 0, or the top of the supporting object when the contact graph says so)."""
    box = inst.box
    z = box.bottom_z
    graph = data.map.contact_graph
    if graph is not None and inst.id in graph.support:
        parent = graph.parent(inst.id)
        edge = graph.support.edges[parent, inst.id] if parent is not None else {}
        plane = edge.get("plane")
        if plane is not None and abs(plane[2]) > 0.9:
            z = -plane[3] / plane[2]
    elif abs(z) < 0.08:
        z = 0.0  # gravity-aligned maps have the floor at z = 0
    return np.array([box.center[0], box.center[1], z])


def posed_completion(model: LibraryModel, match: Match, completer: str) -> Completion:
    """The library model scaled and placed; parts in their link frames and joints scaled along."""
    s = match.scale
    scale = np.diag([s, s, s, 1.0])
    mesh = model.mesh()
    mesh.apply_transform(scale)
    links: dict[str, list[trimesh.Trimesh]] = {}
    for p in model.parts:
        links.setdefault(p.link, []).append(p.load())
    frames = {"body": np.eye(4)}
    for j in model.joints:  # joint origins chain from the root (parents come first in our libraries)
        frames[j.child] = frames.get(j.parent, np.eye(4)) @ j.origin
    parts, joints = [], []
    for link, meshes in links.items():
        frame = frames.get(link, np.eye(4)).copy()
        frame[:3, 3] *= s
        local = trimesh.util.concatenate([m.copy() for m in meshes])
        local.apply_transform(scale)
        local.apply_transform(np.linalg.inv(frame))
        parts.append(Part(link, local, frame))
    for j in model.joints:
        origin = j.origin.copy()
        origin[:3, 3] *= s
        lower, upper = (j.lower * s, j.upper * s) if j.type == "prismatic" else (j.lower, j.upper)
        joints.append(Joint(j.name, j.type, j.parent, j.child, origin, j.axis, lower, upper))
    pose = make_pose(match.translation, match.yaw)
    return Completion(
        mesh=mesh,
        pose=pose,
        completer=completer,
        model_id=model.id,
        scale=np.full(3, s),
        score=match.score,
        parts=parts,
        joints=joints,
    )


def augmented_scene(
    geometry: Geometry | None, instances: ObjectInstances, epsilon: float, spacing: float
) -> Geometry | None:
    """A = (G \\ S) U O: observed points near completed models are replaced by the models."""
    completed = instances.completed()
    if geometry is None:
        return None
    if not completed:
        return Geometry(
            points=geometry.points.copy(),
            colors=None if geometry.colors is None else geometry.colors.copy(),
            mesh=geometry.mesh,
        )
    scene = o3d.t.geometry.RaycastingScene()
    model_pts, model_cols = [], []
    meshes = []
    for inst in completed:
        world = inst.completion.world_mesh()  # type: ignore[union-attr]
        meshes.append(world)
        scene.add_triangles(o3c.Tensor(world.vertices.astype(np.float32)), o3c.Tensor(world.faces.astype(np.uint32)))
        count = int(np.clip(world.area / spacing**2, 64, 20000))
        pts, _ = trimesh.sample.sample_surface(world, count, seed=inst.id)
        model_pts.append(pts)
        color = (
            np.mean(inst.colors, axis=0) if inst.colors is not None and len(inst.colors) else np.array([0.6, 0.6, 0.6])
        )
        model_cols.append(np.tile(color, (len(pts), 1)))
    dist = scene.compute_distance(o3c.Tensor(geometry.points.astype(np.float32))).numpy()
    keep = dist > epsilon
    points = np.vstack([geometry.points[keep], *model_pts])
    colors = None
    if geometry.colors is not None:
        colors = np.vstack([geometry.colors[keep], *model_cols])
    mesh = None
    if geometry.mesh is not None:
        g = geometry.mesh
        vd = scene.compute_distance(o3c.Tensor(np.asarray(g.vertices, dtype=np.float32))).numpy()
        face_keep = (vd[g.faces] > epsilon).all(axis=1)
        kept = g.copy()
        kept.update_faces(face_keep)
        kept.remove_unreferenced_vertices()
        mesh = trimesh.util.concatenate([kept, *meshes])
    return Geometry(points=points, colors=colors, mesh=mesh, voxel_size=geometry.voxel_size)


MatcherConfigT = TypeVar("MatcherConfigT", bound=MatcherConfig)


class MatchingCompleter(Completer[MatcherConfigT]):
    """Base of completers that match objects against a model library."""

    Config = MatcherConfig
    requires = frozenset({"instances"})
    optional = frozenset({"geometry", "contact_graph"})
    provides = frozenset({"instances", "augmented"})

    def match(self, inst: ObjectInstance, base: np.ndarray, index: ModelIndex, data: PipelineData) -> Match | None:
        raise NotImplementedError

    def select(self, insts: ObjectInstances, index: ModelIndex) -> list[ObjectInstance]:
        """The objects to complete; the others are reported and left as observed."""
        cfg = self.config
        for problem in index.problems:
            self.warn(f"library: {problem}")
        todo = []
        for inst in insts:
            if cfg.classes is not None and inst.class_name not in cfg.classes:
                continue
            if not index.candidates(inst.class_name):
                self.warn(f"object {inst.id}: no {inst.class_name!r} models in the library; left uncompleted")
                continue
            if len(inst.points) < cfg.min_points:
                self.warn(
                    f"object {inst.id} ({inst.class_name}) has {len(inst.points)} points (< {cfg.min_points}); left "
                    "uncompleted"
                )
                continue
            todo.append(inst)
        return todo

    def map_objects(self, todo: list[ObjectInstance], fn: Any) -> list[tuple[ObjectInstance, Any]]:
        """``fn(inst)`` for every object, in parallel threads; notes the mean seconds per object."""
        cfg = self.config
        timings: dict[int, float] = {}

        def work(inst: ObjectInstance) -> tuple[ObjectInstance, Any]:
            t0 = time.perf_counter()
            result = fn(inst)
            timings[inst.id] = time.perf_counter() - t0
            return inst, result

        with ThreadPoolExecutor(max_workers=cfg.workers) as pool:
            results = list(pool.map(work, todo))
        self.note("seconds_per_object", float(np.mean(list(timings.values()))) if timings else 0.0)
        return results

    def finish(self, insts: ObjectInstances, data: PipelineData, attempted: int) -> dict[str, Any]:
        """The completed instances and the augmented scene built from them."""
        cfg = self.config
        self.note("objects", {"completed": len(insts.completed()), "attempted": attempted})
        out: dict[str, Any] = {"instances": insts}
        aug = augmented_scene(data.map.geometry, insts, cfg.epsilon, cfg.sample_spacing)
        if aug is not None:
            out["augmented"] = aug
        return out

    def recognize(self, insts: ObjectInstances, index: ModelIndex, data: PipelineData) -> None:
        """Recognition by matching: an object with no class (or a weakly voted one) is matched against
        every class of the library its size allows, and takes the class of the best-fitting model when
        that fit is within ``recognize_fit``. The attempt is recorded in ``attributes['recognition']``."""
        cfg = self.config
        todo = [
            inst
            for inst in insts
            if len(inst.points) >= cfg.min_points
            and (inst.class_name in cfg.recognize or (cfg.recognize_weak > 0 and inst.score < cfg.recognize_weak))
        ]
        if not todo:
            return
        classes = [c for c in index.classes() if c not in cfg.recognize]

        def best_class(inst: ObjectInstance) -> tuple[str, Match] | None:
            base = object_base(inst, data)
            best = None
            for name in classes:
                if not plausible(name, inst.points):
                    continue
                match = self.match(dataclasses.replace(inst, class_name=name), base, index, data)
                if match is not None and (best is None or (match.score, name) < (best[1].score, best[0])):
                    best = (name, match)
            return best

        recognized = 0
        for inst, found in self.map_objects(todo, best_class):
            record: dict[str, Any] = {"from": inst.class_name, "vote_share": round(float(inst.score), 3)}
            if found is not None:
                name, match = found
                fit = float(match.details.get("fit_m", match.score))
                record.update({"best_class": name, "model": match.model_id, "fit_m": round(fit, 4)})
                if fit <= cfg.recognize_fit and name != inst.class_name:
                    record["class"] = name
                    inst.class_name = name
                    recognized += 1
            inst.attributes["recognition"] = record
        self.note("recognition", {"attempted": len(todo), "recognized": recognized})

    def complete(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        index = load_index(cfg)
        insts = data.map.instances.copy()  # type: ignore[union-attr]
        self.recognize(insts, index, data)
        todo = self.select(insts, index)
        results = self.map_objects(todo, lambda inst: self.match(inst, object_base(inst, data), index, data))
        for inst, match in results:
            if match is None:
                self.warn(f"object {inst.id} ({inst.class_name}): no model could be aligned; left uncompleted")
                continue
            model = index.library.get(match.model_id)
            inst.completion = posed_completion(model, match, self.name)
            inst.attributes["match"] = {
                k: v for k, v in match.details.items() if isinstance(v, (int, float, str, list))
            }
        return self.finish(insts, data, len(todo))
