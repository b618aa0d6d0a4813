"""A map as a scene for simulators: the kinematic tree of its objects, the room's static slabs,
and the rest plan that decides where free bodies start (shared by the URDF, SDF and MJCF exporters,
so all three describe the same scene)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from stratamap.core.map.layers import LayeredMap, ObjectInstances
from stratamap.core.simulation.kinematics import KinematicTree, build_tree
from stratamap.core.simulation.rest import RestPlan, rest_offsets
from stratamap.core.simulation.structure import room_structure


def scene_tree(
    layered: LayeredMap,
    movable: Iterable[str],
    density: Mapping[str, float] | None = None,
    use_graph: bool = True,
    structure: bool = True,
    rest: bool = True,
) -> tuple[KinematicTree, RestPlan]:
    """The tree to export: objects of ``movable`` classes are free bodies (floating joints on the
    world) placed by the rest plan, or static where the plan says they cannot rest; the others are
    fixed to their supporter (``use_graph``) or to the world; ``structure`` adds floor, walls and
    ceiling."""
    instances = layered.instances if layered.instances is not None else ObjectInstances()
    movable = tuple(movable)
    statics = room_structure(layered) if structure else []
    graph = layered.contact_graph
    if rest:
        plan = rest_offsets(instances, graph, movable, statics)
    else:
        plan = RestPlan()
    free = plan.free_ids(instances, movable)
    tree = build_tree(
        instances,
        graph if use_graph else None,
        dict(density or {}),
        offsets=plan.offsets,
        rotations=plan.rotations,
        collision=plan.collision,
        statics=statics,
        floating_ids=free,
    )
    return tree, plan
