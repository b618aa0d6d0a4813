"""Shared machinery of model-matching completers: the library, per-object matching in parallel,
posing a library model (with its articulation) in the world, the ranked alternatives kept beside
the chosen model, and the augmented scene (built by :mod:`stratamap.core.map.augmented`).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from pydantic import Field

from stratamap.core.errors import ConfigError
from stratamap.core.geometry.meshes import raycasting_scene, surface_distances
from stratamap.core.geometry.transforms import make_pose
from stratamap.core.lazy import lazy_module
from stratamap.core.library.index import ModelIndex
from stratamap.core.library.models import LibraryModel, ModelLibrary, model_to_library
from stratamap.core.map.augmented import augmented_scene
from stratamap.core.map.instances import plausible, set_naming
from stratamap.core.map.layers import Completion, Joint, ObjectInstance, ObjectInstances, Part
from stratamap.core.map.priors import plausible_heights
from stratamap.core.map.sensors import sensor_viewpoints
from stratamap.core.parallel import ExecutorConfig, map_tasks
from stratamap.core.stages import Completer, PipelineData, StageConfig

o3c = lazy_module("open3d.core")
spatial = lazy_module("scipy.spatial")
trimesh = lazy_module("trimesh")

#: An object whose lowest point is this close (m) to the floor (z = 0 in a gravity-aligned map) stands on it.
FLOOR_FOOT = 0.1


class MatcherConfig(StageConfig, ExecutorConfig):
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
        default=2,
        ge=1,
        le=64,
        description=(
            "Objects matched in parallel: threads (KD-tree queries release the GIL), or the CPUs of the local Ray "
            "instance that executor: ray starts."
        ),
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
    recognize_coverage: float = Field(
        default=0.5,
        ge=0.0,
        le=1.0,
        description=(
            "Smallest share of the model's seeable surface (posed as fitted: what a ray from one of the map's "
            "viewpoints reaches before any other part of the model) within recognize_fit of the observed points for "
            "recognition to take its class: the fit is one-sided, so a sliver of a wall lies on many a model's "
            "surface; 0 turns the check off. 0.5 was chosen on the tuning walks of "
            "configs/bench/generalization_tuning.yaml (docs/experiments/2026-11-29-recognition-two-sided.md)."
        ),
    )
    reject_distance: float | None = Field(
        default=0.05,
        gt=0.0,
        description=(
            "Never worse than what was seen: a completion is rejected (the object keeps its observed points) when "
            "reject_share of the observed points lie farther than this from its surface, metres; null: never."
        ),
    )
    reject_share: float = Field(
        default=0.1,
        gt=0.0,
        lt=1.0,
        description="Share of observed points allowed beyond reject_distance from a completion's surface.",
    )
    alternatives: int = Field(
        default=2,
        ge=0,
        le=10,
        description=(
            "Next-best candidates kept per object beside the chosen model, posed and checked against the observed "
            "points like it (in memory, not saved): the physical check swaps to one that removes a conflict."
        ),
    )


@dataclass
class Match:
    model_id: str
    yaw: float
    translation: np.ndarray  # object frame origin in the world
    scale: float | np.ndarray  # uniform, or (sx, sy, sz) along the model's own axes
    score: float
    details: dict[str, Any]
    alternatives: list[Match] = field(default_factory=list)  # next-best matches, best first


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
    elif abs(z) < 0.08 or stands_on_floor(inst.class_name, box.top_z):
        z = 0.0  # gravity-aligned maps have the floor at z = 0
    return np.array([box.center[0], box.center[1], z])


def stands_on_floor(class_name: str, top_z: float, floor_z: float = 0.0) -> bool:
    """Whether an object of the class reaching up to ``top_z`` is one standing on the floor: its top
    is at a height the class's objects have (a chair whose legs were never mapped), not one hanging
    higher up (a wall cabinet)."""
    heights = plausible_heights(class_name)
    return heights is not None and heights[0] <= top_z - floor_z <= heights[1]


def observation_disagreement(points: np.ndarray, mesh: trimesh.Trimesh, distance: float) -> float:
    """Share of the observed ``points`` farther than ``distance`` from the surface of ``mesh`` (world frame)."""
    if len(points) == 0 or len(mesh.faces) == 0:
        return 0.0
    return float(np.mean(surface_distances(points, mesh) > distance))


#: At most this many viewpoints (evenly spaced) judge which of a model's surface could be seen.
COVERAGE_VIEWS = 40
#: Surface samples of a model whose share near the observed points is its coverage.
COVERAGE_SAMPLES = 2000


def seen_coverage(mesh: trimesh.Trimesh, points: np.ndarray, views: np.ndarray, distance: float) -> float:
    """Share of the surface of ``mesh`` (world frame) that a sensor at ``views`` (V, 3) could have seen
    and that lies within ``distance`` of the observed ``points``: the other direction of a one-sided fit.
    A surface sample counts as seeable from a viewpoint when the ray from the viewpoint to it meets no
    other part of the mesh first (a unit's back against the wall, its bottom and what its doors close in are not); where
    no viewpoint sees any of it, the whole surface counts. Deterministic (fixed sampling seed)."""
    if len(mesh.faces) == 0 or len(points) == 0:
        return 0.0
    samples = np.asarray(trimesh.sample.sample_surface(mesh, COVERAGE_SAMPLES, seed=0)[0], dtype=np.float64)
    scene = raycasting_scene(mesh)
    views = np.asarray(views, dtype=np.float64).reshape(-1, 3)
    views = views[np.unique(np.linspace(0, len(views) - 1, min(len(views), COVERAGE_VIEWS)).astype(int))]
    seeable = np.zeros(len(samples), dtype=bool)
    for view in views:
        offset = samples - view
        reach = np.linalg.norm(offset, axis=1)
        rays = np.c_[np.broadcast_to(view, samples.shape), offset / np.maximum(reach, 1e-9)[:, None]]
        hit = scene.cast_rays(o3c.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
        seeable |= hit >= reach - 0.01  # the first surface the ray meets is the sample's own
    if not seeable.any():
        seeable[:] = True
    near = spatial.cKDTree(np.asarray(points, dtype=np.float64)).query(samples[seeable], workers=1)[0]
    return float(np.mean(near <= distance))


def rejection_reason(inst: ObjectInstance, completion: Completion, cfg: MatcherConfig) -> str | None:
    """Why ``completion`` may not replace what was seen of ``inst`` (None: it may): its surface
    disagrees with the observed points beyond ``cfg.reject_distance``."""
    if cfg.reject_distance is None:
        return None
    share = observation_disagreement(inst.points, completion.world_mesh(), cfg.reject_distance)
    if share <= cfg.reject_share:
        return None
    return (
        f"{share:.0%} of the observed points lie farther than {cfg.reject_distance} m from model "
        f"{completion.model_id} (at most {cfg.reject_share:.0%} allowed)"
    )


def posed_completion(model: LibraryModel, match: Match, completer: str) -> Completion:
    """The library model scaled and placed; parts in their link frames and joints scaled along."""
    s = np.broadcast_to(np.asarray(match.scale, dtype=float), (3,)).copy()
    scale = np.diag([*s, 1.0])
    mesh = model.mesh()
    mesh.apply_transform(scale)
    links: dict[str, list[trimesh.Trimesh]] = {}
    for p in model.parts:
        links.setdefault(p.link, []).append(p.load())
    # Link frames chain from the root whatever order the source lists its joints in (PartNet-Mobility
    # names a helper link as a parent before the joint that places it).
    frames = {"body": np.eye(4)}
    pending = list(model.joints)
    while pending:
        ready = [j for j in pending if j.parent in frames] or pending[:1]
        for j in ready:
            frames[j.child] = frames.get(j.parent, np.eye(4)) @ j.origin
        done = {id(j) for j in ready}
        pending = [j for j in pending if id(j) not in done]
    scaled = {}
    for link, frame in frames.items():
        scaled[link] = frame.copy()
        scaled[link][:3, 3] *= s
    parts, joints = [], []
    for link, meshes in links.items():
        frame = scaled.get(link, np.eye(4))
        local = trimesh.util.concatenate([m.copy() for m in meshes])
        local.apply_transform(scale)
        local.apply_transform(np.linalg.inv(frame))
        parts.append(Part(link, local, frame))
    for j in model.joints:
        origin = np.linalg.inv(scaled.get(j.parent, np.eye(4))) @ scaled.get(j.child, np.eye(4))
        stretch = float(np.linalg.norm(s * (frames.get(j.child, np.eye(4))[:3, :3] @ j.axis))) / max(
            float(np.linalg.norm(j.axis)), 1e-12
        )
        lower, upper = (j.lower * stretch, j.upper * stretch) if j.type == "prismatic" else (j.lower, j.upper)
        joints.append(Joint(j.name, j.type, j.parent, j.child, origin, j.axis, lower, upper))
    # The object frame's origin is the model's bottom centre: the model's lowest point rests at the
    # support height whatever its source put below z = 0 (nothing sinks, nothing floats).
    translation = np.asarray(match.translation, dtype=float).copy()
    if len(mesh.vertices):
        translation[2] -= float(mesh.bounds[0][2])
    pose = make_pose(translation, match.yaw)
    return Completion(
        mesh=mesh,
        pose=pose,
        completer=completer,
        model_id=model.id,
        scale=s,
        score=match.score,
        parts=parts,
        joints=joints,
    )


MatcherConfigT = TypeVar("MatcherConfigT", bound=MatcherConfig)


@dataclass
class ObjectWork:
    """What every per-object task of a matching completer needs, shipped to Ray once: the completer's
    class and config (a worker builds its own instance from them) and the model index."""

    completer: type[Completer[Any]]
    config: MatcherConfig
    index: ModelIndex | None
    method: str
    instance: Any = field(default=None, compare=False)  # the completer that runs the method here

    def __getstate__(self) -> dict[str, Any]:
        # The pipeline's stage holds the run's data: a worker builds a bare instance instead. KD-trees
        # are left out (a worker rebuilds the same tree from the same samples when it first queries one).
        index = self.index
        if index is not None:
            index = copy.copy(index)
            index.models = {key: dataclasses.replace(m, _tree=None) for key, m in index.models.items()}
        return {**self.__dict__, "instance": None, "index": index}

    def stage(self) -> Any:
        if self.instance is None:
            self.instance = self.completer(self.config)
        return self.instance


def run_object_task(work: ObjectWork, item: tuple[ObjectInstance, np.ndarray, tuple[Any, ...]]) -> Any:
    """One object's work: ``completer.<method>(inst, base, index, *args)``."""
    inst, base, args = item
    return getattr(work.stage(), work.method)(inst, base, work.index, *args)


def call_closure(work: ObjectWork, item: tuple[ObjectInstance, None, tuple[Callable[[ObjectInstance], Any]]]) -> Any:
    inst, _, (fn,) = item
    return fn(inst)


class MatchingCompleter(Completer[MatcherConfigT]):
    """Base of completers that match objects against a model library."""

    Config = MatcherConfig
    requires = frozenset({"instances"})
    optional = frozenset({"geometry", "contact_graph"})
    provides = frozenset({"instances", "augmented"})

    def match(
        self,
        inst: ObjectInstance,
        base: np.ndarray,
        index: ModelIndex,
        data: PipelineData | None,
        views: np.ndarray | None = None,
    ) -> Match | None:
        """The best model for one object standing at ``base``; ``views``: where the sensor stood (V, 3),
        or None. Runs in a thread or a Ray task: ``data`` is None (see :meth:`map_objects`)."""
        raise NotImplementedError

    def select(self, insts: ObjectInstances, index: ModelIndex) -> list[ObjectInstance]:
        """The objects to complete; the others are reported and left as observed."""
        cfg = self.config
        for problem in index.problems:
            self.warn(f"library: {problem}")
        todo = []
        # One warning per reason and class, naming the objects: a map of many unnamed objects would
        # otherwise print a line for each.
        no_models: dict[str, list[int]] = {}
        too_few: dict[str, list[int]] = {}
        for inst in insts:
            if cfg.classes is not None and inst.class_name not in cfg.classes:
                continue
            if not index.candidates(inst.class_name):
                no_models.setdefault(inst.class_name, []).append(inst.id)
                continue
            if len(inst.points) < cfg.min_points:
                too_few.setdefault(inst.class_name, []).append(inst.id)
                continue
            todo.append(inst)
        for name, ids in no_models.items():
            if name == "object":
                # No library has models of the catch-all class: expected, nothing to act on; noted.
                self.note("unnamed_left_uncompleted", ids)
                continue
            self.warn(f"{_objects(ids)}: no {name!r} models in the library; left uncompleted")
        for name, ids in too_few.items():
            self.warn(f"{_objects(ids)} ({name}): fewer than {cfg.min_points} points; left uncompleted")
        return todo

    def map_objects(
        self,
        todo: list[ObjectInstance],
        method: str | Callable[[ObjectInstance], Any],
        index: ModelIndex | None = None,
        data: PipelineData | None = None,
        *args: Any,
    ) -> list[tuple[ObjectInstance, Any]]:
        """``self.<method>(inst, base, index, *args)`` for every object (``base``: where it stands, see
        :func:`object_base`), in ``workers`` threads or, with ``executor: ray``, as Ray tasks; results in
        input order, paired with the objects of ``todo``. Notes the mean seconds per object.

        On Ray the completer's class, config and the model index go into the object store once; each
        task gets the object and its base, and runs the method on an instance of the completer built
        from the config in the worker, so the method must depend on nothing else (no ``data``: it is
        computed into ``base`` and ``args`` here; warnings and notes are returned, not recorded).
        A callable ``method`` (``fn(inst)``, a closure) runs in threads only."""
        cfg = self.config
        if callable(method):
            if cfg.executor != "local":
                raise ConfigError(
                    [("executor", f"{self.name} matches objects in a closure, which runs only with executor: local")]
                )
            work = ObjectWork(type(self), cfg, index, "", instance=self)
            items = [(inst, None, (method,)) for inst in todo]
            mapped = map_tasks(call_closure, items, work, executor="local", workers=cfg.workers)
        else:
            assert index is not None and data is not None, "map_objects(todo, method, index, data, *args)"
            # Threads share this instance (its warnings reach the report); Ray workers build their own.
            work = ObjectWork(type(self), cfg, index, method, instance=self)
            items = [(inst, object_base(inst, data), args) for inst in todo]
            mapped = map_tasks(
                run_object_task,
                items,
                work,
                executor=cfg.executor,
                workers=cfg.workers,
                ray_address=cfg.ray_address,
            )
            if mapped.shipped:
                self.note(f"shipped_bytes_{method}", {**mapped.shipped, "objects": len(todo)})
        self.note("seconds_per_object", float(np.mean(mapped.seconds)) if mapped.seconds else 0.0)
        return list(zip(todo, mapped.results, strict=True))

    def finish(self, insts: ObjectInstances, data: PipelineData, attempted: int) -> dict[str, Any]:
        """The completed instances and the augmented scene built from them."""
        cfg = self.config
        rejected = [inst for inst in insts if "completion_rejected" in inst.attributes]
        self.note("objects", {"completed": len(insts.completed()), "attempted": attempted, "rejected": len(rejected)})
        if rejected:
            # One line for all: a real room's clutter rejects a dozen models, and a line each buried the rest.
            self.note(
                "completions_rejected",
                [
                    {"instance": i.id, "class": i.class_name, "why": i.attributes["completion_rejected"]}
                    for i in rejected
                ],
            )
            named = ", ".join(f"{i.id} ({i.class_name})" for i in rejected)
            first = rejected[0].attributes["completion_rejected"]
            self.warn(
                f"{'object' if len(rejected) == 1 else 'objects'} {named}: completion rejected, kept as observed: "
                + (first if len(rejected) == 1 else f"each one's reason in notes.{self.name}.completions_rejected")
            )
        out: dict[str, Any] = {"instances": insts}
        aug = augmented_scene(data.map.geometry, insts, cfg.epsilon, cfg.sample_spacing)
        if aug is not None:
            out["augmented"] = aug
        return out

    def recognize(self, insts: ObjectInstances, index: ModelIndex, data: PipelineData) -> None:
        """Recognition by matching: an object with no class (or a weakly voted one) is matched against
        every class of the library its size allows, and takes the class of the best-fitting model when
        that fit is within ``recognize_fit`` and the observed points cover ``recognize_coverage`` of the
        model's seeable surface (``seen_coverage``). The attempt is recorded in
        ``attributes['recognition']``."""
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

        recognized = 0
        for inst, found in self.map_objects(todo, "best_class", index, data, classes):
            record: dict[str, Any] = {"from": inst.class_name, "vote_share": round(float(inst.score), 3)}
            if found is not None:
                name, match = found
                fit = float(match.details.get("fit_m", match.score))
                record.update({"best_class": name, "model": match.model_id, "fit_m": round(fit, 4)})
                renames = fit <= cfg.recognize_fit and name != inst.class_name
                covered = 1.0
                if renames and cfg.recognize_coverage > 0:
                    mesh = posed_completion(index.library.get(match.model_id), match, self.name).world_mesh()
                    views = sensor_viewpoints(data.stream if data is not None else None, inst.points)
                    covered = seen_coverage(mesh, inst.points, views, cfg.recognize_fit)
                    record["coverage"] = round(covered, 3)
                if renames and covered >= cfg.recognize_coverage:
                    record["class"] = name
                    set_naming(
                        inst,
                        "matching",
                        f"model {match.model_id} fits at {fit * 100:.1f} cm mean distance, the best of every class "
                        f"(at most {cfg.recognize_fit * 100:g} cm), and the object covers {covered:.0%} of its "
                        f"seeable surface (at least {cfg.recognize_coverage:.0%}; was {inst.class_name})",
                    )
                    inst.class_name = name
                    recognized += 1
            inst.attributes["recognition"] = record
        self.note("recognition", {"attempted": len(todo), "recognized": recognized})

    def best_class(
        self, inst: ObjectInstance, base: np.ndarray, index: ModelIndex, classes: list[str]
    ) -> tuple[str, Match] | None:
        """The class (of ``classes`` the object's size and footing allow) whose best model fits the
        object best. An object standing on the floor is none of the classes that stand on a support
        (ON_A_SUPPORT)."""
        from stratamap.core.map.priors import ON_A_SUPPORT

        on_floor = base[2] == 0.0 and inst.box.bottom_z < FLOOR_FOOT
        best = None
        for name in classes:
            if not plausible(name, inst.points, whole=True) or (on_floor and name in ON_A_SUPPORT):
                continue
            match = self.match(dataclasses.replace(inst, class_name=name), base, index, None)
            if match is not None and (best is None or (match.score, name) < (best[1].score, best[0])):
                best = (name, match)
        return best

    def complete(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        index = load_index(cfg)
        insts = data.map.instances.copy()  # type: ignore[union-attr]
        self.recognize(insts, index, data)
        todo = self.select(insts, index)
        # match gets data=None: per-object work sees only what a Ray task is shipped (with where the
        # sensor stood, for matchers that turn a model's front towards it).
        seen = data.map.geometry.points if data.map.geometry is not None else np.zeros((0, 3))
        if not len(seen) and len(insts):
            seen = np.concatenate([inst.points for inst in insts])
        views = sensor_viewpoints(data.stream, seen) if len(seen) else None
        results = self.map_objects(todo, "match", index, data, None, views)
        for inst, match in results:
            if match is None:
                self.warn(f"object {inst.id} ({inst.class_name}): no model could be aligned; left uncompleted")
                continue
            model = index.library.get(match.model_id)
            completion = posed_completion(model, match, self.name)
            inst.attributes["match"] = {
                k: v for k, v in match.details.items() if isinstance(v, (int, float, str, list))
            }
            reason = rejection_reason(inst, completion, cfg)
            if reason is not None:
                self.reject(inst, reason)
                continue
            completion.alternatives = self.alternative_completions(inst, match, index)
            inst.completion = completion
        return self.finish(insts, data, len(todo))

    def alternative_completions(self, inst: ObjectInstance, match: Match, index: ModelIndex) -> list[Completion]:
        """The match's next-best models posed like it, those the observed points reject left out, at most
        ``alternatives`` of them, best first."""
        out: list[Completion] = []
        for alt in match.alternatives:
            if len(out) >= self.config.alternatives:
                break
            completion = posed_completion(index.library.get(alt.model_id), alt, self.name)
            if rejection_reason(inst, completion, self.config) is None:
                out.append(completion)
        return out

    def reject(self, inst: ObjectInstance, reason: str) -> None:
        """Leave ``inst`` as observed, with the reason in its attributes (:meth:`finish` warns once for all)."""
        inst.completion = None
        inst.attributes["completion_rejected"] = reason


def _objects(ids: list[int]) -> str:
    """``object 3`` or ``objects 1, 2, 5``."""
    return f"object {ids[0]}" if len(ids) == 1 else "objects " + ", ".join(map(str, ids))
