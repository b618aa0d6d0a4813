"""Mapper ``physical_check``: make the completed scene physically plausible before export.

The functional-scenes paper (section 4.4) checks the matched CAD models for physical conflicts. Here,
before anything moves, the min-conflict search (``core/simulation/physics.py``) chooses among each
completed object's candidates (the chosen model and the ranked ``alternatives`` a matching completer
kept) so that no two meshes interpenetrate, whatever ids the objects carry; uncompleted objects are
observations, obstacles that never change. Then every object is rested on the surface of its
supporter from the contact graph, and an object that still overlaps one placed before it moves to
the nearest horizontal offset without overlap (the least overlapping one when none is free within
``max_shift``). A move that takes a model away from what was observed of it is undone (the
observations are evidence; the overlap is reported instead). The contact graph and the augmented
layer are updated after: a moved or swapped object's surface moves with it, completed nodes get the
box of their model as placed, and the augmented scene is rebuilt from the models where they now are.
What was swapped, moved or undone, and any overlap left, go into the run's notes.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import Mapper, PipelineData, StageConfig, hookimpl
from stratamap.core.geometry.meshes import surface_distances
from stratamap.core.geometry.transforms import yaw_of
from stratamap.core.map.augmented import augmented_scene
from stratamap.core.map.layers import ContactGraph, ObjectInstances, OrientedBox
from stratamap.core.simulation.kinematics import DEFAULT_MOVABLE_CLASSES
from stratamap.core.simulation.physics import (
    CONTACT_TOLERANCE,
    Placement,
    conflicting,
    contradicting,
    mesh_shells,
    min_conflict,
    resolve_scene,
    world_mesh,
)
from stratamap.plugins.mappers._floor import floor_height


class PhysicalCheckConfig(StageConfig):
    max_shift: float = Field(
        default=0.3, ge=0.0, description="Farthest an object may move sideways to leave an overlap, metres."
    )
    step: float = Field(default=0.01, gt=0.0, description="Radius step of the search for a free offset, metres.")
    directions: int = Field(default=16, ge=4, description="Directions tried on every radius of the search.")
    snap_distance: float = Field(
        default=0.1, ge=0.0, description="Largest gap or sinking closed by resting an object on its supporter, metres."
    )
    observed_distance: float | None = Field(
        default=0.05,
        gt=0.0,
        description=(
            "A move is undone when it leaves more than observed_share of the observed points its model explained "
            "(those this close to it where it was) farther than this from it, metres (the observations are evidence; "
            "a slide away from them is no repair; points the model never explained, such as what stands on a "
            "carcass, judge no move); null: keep every move."
        ),
    )
    observed_share: float = Field(
        default=0.1,
        gt=0.0,
        lt=1.0,
        description="Share of the observed points a model explained that a move may take beyond observed_distance.",
    )
    movable_classes: list[str] = Field(
        default_factory=lambda: list(DEFAULT_MOVABLE_CLASSES),
        description=(
            "Classes the exporters free (their bodies.movable_classes): an undone model of these that meets the "
            "convex pieces of an uncompleted neighbour is rejected, since a simulator would push it out; a fixed "
            "one only where it holds that neighbour's observed points."
        ),
    )
    swap: bool = Field(
        default=True,
        description=(
            "Before moving anything, choose among each completed object's candidates (the alternatives a matching "
            "completer kept) so that no two models interpenetrate (min-conflict); false: keep every chosen model."
        ),
    )
    swap_iterations: int = Field(
        default=200, ge=1, description="Iterations of the min-conflict search among candidates."
    )
    epsilon: float = Field(
        default=0.1,
        gt=0.0,
        description=(
            "Augmented scene rebuilt after a move or swap: observed points this close to a completed model are "
            "replaced, metres (the matching completers' epsilon)."
        ),
    )
    sample_spacing: float = Field(
        default=0.02,
        gt=0.0,
        description="Surface sampling spacing of models in the rebuilt augmented scene, metres (the completers').",
    )


class PhysicalCheckMapper(Mapper[PhysicalCheckConfig]):
    """Chooses among candidates (min-conflict), rests objects on their supporters and moves overlapping ones apart."""

    name = "physical_check"
    Config = PhysicalCheckConfig
    requires = frozenset({"instances"})
    optional = frozenset({"contact_graph", "geometry", "augmented"})
    provides = frozenset({"instances", "contact_graph", "augmented"})

    def map(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        before: ObjectInstances = data.map.instances  # type: ignore[assignment]
        instances = before.copy()
        swapped = self._swap(instances) if cfg.swap else {}
        chosen = instances.copy()  # the models chosen, before anything moves: moves are measured from here
        floor_z = floor_height(data)
        result = resolve_scene(
            instances, data.map.contact_graph, floor_z, cfg.max_shift, cfg.step, cfg.directions, cfg.snap_distance
        )
        undone = self._undo_contradicted_moves(chosen, instances)
        # A model that can neither move (its observed points say where it is) nor stay (it
        # penetrates a neighbour's model, or an uncompleted neighbour as the export collides it)
        # is wrong: the object keeps its observed shape, as a completer's rejection leaves it. A
        # fixed object's model meets an uncompleted neighbour's convex pieces harmlessly (nothing
        # fixed moves in a simulator), and those pieces fill space nobody saw (what stands on a
        # counter whose worktop the sensor missed reaches into the counter in its hull, not in its
        # points): it goes only where it holds the neighbour's observed points. A real counter's
        # doors were lost to the hulls.
        # A kept model that then penetrates what was seen of a rejected neighbour (the convex
        # pieces the export collides) goes too (until no rejection leaves such a conflict); not
        # its supporter's, whose top mixes with the underside seen standing on it.
        graph = data.map.contact_graph
        supports = (
            set()
            if graph is None
            else {(int(p), int(c)) for c in graph.support if isinstance(p := graph.parent(c), (int, np.integer))}
        )
        modelled = {inst.id for inst in instances if inst.completion is not None}
        movable = set(cfg.movable_classes)
        free = [i for i in undone if instances[i].class_name in movable]
        fixed = [i for i in undone if i not in free]
        rejected = sorted(
            set(conflicting(instances, free))
            | set(conflicting(instances, fixed, against=modelled))
            | set(contradicting(instances, fixed, against={inst.id for inst in instances} - modelled))
        )
        reason = "penetrates a neighbour where it was seen"
        all_rejected: list[int] = []
        while rejected:
            for i in rejected:
                joints = len(instances[i].completion.joints) if instances[i].completion is not None else 0
                if joints:
                    # The report counts joints where the completer made them (notes.fronts): say which go.
                    instances[i].attributes["joints_rejected"] = joints
                instances[i].completion = None
                instances[i].attributes["completion_rejected"] = reason
            all_rejected += rejected
            completed = [inst.id for inst in instances if inst.completion is not None]
            rejected = conflicting(instances, completed, against=rejected, exempt=supports)
            reason = "penetrates what was seen of a neighbour whose model was rejected"
        self._warn_rejected([instances[i] for i in all_rejected])
        shifts = {
            inst.id: inst.completion.pose[:3, 3] - chosen[inst.id].completion.pose[:3, 3]  # type: ignore[union-attr]
            for inst in instances
            if inst.completion is not None and inst.id in chosen and chosen[inst.id].completion is not None
        }
        moved = {k: v for k, v in shifts.items() if np.linalg.norm(v) > 1e-4}
        summary = result.to_dict()
        summary.update(
            {
                "swapped": sorted(swapped),
                "moved": len(moved),
                "max_shift_m": max((float(np.linalg.norm(v)) for v in moved.values()), default=0.0),
                "undone": undone,
                # An undone move puts the object back where it was seen: unresolved only if its
                # kept model conflicts there.
                "unresolved": sorted(
                    (set(summary["unresolved"]) - set(undone))
                    | set(conflicting(instances, [i for i in undone if instances[i].completion is not None]))
                ),
            }
        )
        for key, value in summary.items():
            self.note(key, value)
        if summary["unresolved"]:
            self.warn(f"objects still overlapping after the physical check: {summary['unresolved']}")
        out: dict[str, Any] = {"instances": instances}
        if data.map.contact_graph is not None:
            out["contact_graph"] = updated_graph(data.map.contact_graph, instances, moved, set(swapped))
        if (swapped or moved) and data.map.augmented is not None and data.map.geometry is not None:
            # The augmented scene of the models where they now are (a completer built it where they were).
            out["augmented"] = augmented_scene(data.map.geometry, instances, cfg.epsilon, cfg.sample_spacing)
        return out

    def _warn_rejected(self, rejected: list[Any]) -> None:
        """One warning for every completion rejected (a real kitchen's clutter rejects several, and a
        line each buried the rest), each one's reason in the notes (``completions_rejected``)."""
        if not rejected:
            return
        self.note(
            "completions_rejected",
            [
                {
                    "instance": i.id,
                    "class": i.class_name,
                    "why": i.attributes["completion_rejected"],
                    **({"joints": i.attributes["joints_rejected"]} if "joints_rejected" in i.attributes else {}),
                }
                for i in rejected
            ],
        )
        joints = sum(int(i.attributes.get("joints_rejected", 0)) for i in rejected)
        if joints:
            self.note("joints_rejected", joints)
        named = ", ".join(f"{i.id} ({i.class_name})" for i in rejected)
        reason = (
            rejected[0].attributes["completion_rejected"]
            if len(rejected) == 1
            else f"each one's reason in notes.{self.name}.completions_rejected"
        )
        lost = f" ({joints} joint{'s' if joints != 1 else ''} with {'them' if len(rejected) > 1 else 'it'})"
        self.warn(
            f"{'object' if len(rejected) == 1 else 'objects'} {named}: completion rejected, kept as observed"
            f"{lost if joints else ''}: {reason}"
        )

    def _swap(self, instances: ObjectInstances) -> dict[int, tuple[str | None, str | None]]:
        """Min-conflict choice among every completed object's candidates, in place, before anything
        moves (conflicts are mesh penetrations beyond contact; uncompleted objects are fixed
        obstacles). Returns ``{id: (model before, model after)}`` for the objects that changed."""
        if not any(inst.completion is not None and inst.completion.alternatives for inst in instances):
            return {}
        options: dict[int, list[Placement]] = {}
        for inst in instances:
            c = inst.completion
            if c is None:
                options[inst.id] = [Placement(mesh_shells(world_mesh(inst)), 0.0, ("observed",))]
                continue
            ranked = [c, *c.alternatives]
            options[inst.id] = [
                Placement(mesh_shells(alt.world_mesh()), float(alt.score), (alt.model_id or "", rank), alt)
                for rank, alt in enumerate(ranked)
            ]
        choice = min_conflict(options, CONTACT_TOLERANCE, self.config.swap_iterations)
        swapped: dict[int, tuple[str | None, str | None]] = {}
        for inst in instances:
            old = inst.completion
            new = choice[inst.id].item if inst.id in choice else old
            if old is None or new is old:
                continue
            # The model given up becomes an alternative in turn (ranked where the completer put it).
            rest = [alt for alt in [old, *old.alternatives] if alt is not new]
            inst.completion = dataclasses.replace(
                new, alternatives=[dataclasses.replace(a, alternatives=[]) for a in rest]
            )
            inst.attributes["physical_check"] = {"swapped_from": old.model_id, "swapped_to": new.model_id}
            swapped[inst.id] = (old.model_id, new.model_id)
        return swapped

    def _undo_contradicted_moves(self, before: ObjectInstances, after: ObjectInstances) -> list[int]:
        """Put back every completed object whose move leaves its model disagreeing with what was
        observed of it (see ``observed_distance``); returns their ids."""
        cfg = self.config
        if cfg.observed_distance is None:
            return []
        undone = []
        for inst in after:
            old = before[inst.id] if inst.id in before else None
            if inst.completion is None or old is None or old.completion is None:
                continue
            if np.allclose(inst.completion.pose, old.completion.pose, atol=1e-6):
                continue
            explained = surface_distances(old.points, old.completion.world_mesh()) <= cfg.observed_distance
            if not explained.any():
                continue
            away = surface_distances(inst.points[explained], inst.completion.world_mesh()) > cfg.observed_distance
            if float(np.mean(away)) > cfg.observed_share:
                inst.completion = old.completion
                undone.append(inst.id)
        return undone


def updated_graph(
    graph: ContactGraph, instances: ObjectInstances, moved: dict[int, np.ndarray], swapped: set[int] | None = None
) -> ContactGraph:
    """The contact graph after the check: the surface a moved object offers its children moves
    with it, a swapped object's surface is the new model's top under each child, and every completed
    object's node carries the box of its model as placed (``box_completed``, in the object's yaw)."""
    graph = copy.deepcopy(graph)
    swapped = swapped or set()
    for parent, child, edge in graph.support.edges(data=True):
        plane = edge.get("plane")
        if plane is None:
            continue
        if parent in swapped and abs(plane[2]) > 0.9 and child in instances:
            top = swapped_surface(instances[parent], instances[child])
            if top is not None:
                edge["plane"] = [0.0, 0.0, 1.0, -top]
                continue
        if parent in moved:
            a, b, c, d = plane
            t = moved[parent]
            edge["plane"] = [a, b, c, float(d - (a * t[0] + b * t[1] + c * t[2]))]
    for inst in instances:
        if inst.completion is None or inst.id not in graph.support:
            continue
        yaw = yaw_of(inst.completion.pose)
        vertices = np.asarray(inst.completion.world_mesh().vertices)
        c, s = np.cos(yaw), np.sin(yaw)
        local = np.c_[vertices[:, :2] @ np.array([[c, -s], [s, c]]), vertices[:, 2]]  # rotate by -yaw
        lo, hi = local.min(axis=0), local.max(axis=0)
        mid = (lo + hi) / 2
        center = np.array([c * mid[0] - s * mid[1], s * mid[0] + c * mid[1], mid[2]])
        graph.support.nodes[inst.id]["box_completed"] = OrientedBox(center, yaw, hi - lo).to_dict()
    return graph


def swapped_surface(parent: Any, child: Any) -> float | None:
    """Height of the parent's model top under the child's footprint centre (None where it has none)."""
    xy = np.asarray(child.box.center[:2], dtype=float).reshape(1, 2)
    tops = [float(s.top_at(xy)[0]) for s in mesh_shells(world_mesh(parent))]
    tops = [t for t in tops if np.isfinite(t)]
    return max(tops) if tops else None


@hookimpl
def stratamap_register_mappers():
    return [PhysicalCheckMapper]
