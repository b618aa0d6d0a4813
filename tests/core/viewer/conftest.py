"""A small hand-made map for the viewer's tests: a room with a table (rigid model), a box on it, an articulated
cabinet (a door on a hinge, a drawer on a slide), an uncompleted plant, occupancy grids and a contact graph."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from stratamap.core.geometry.boxes import OrientedBox
from stratamap.core.geometry.transforms import make_pose
from stratamap.core.map.layers import (
    Completion,
    ContactGraph,
    Geometry,
    Joint,
    LayeredMap,
    ObjectInstance,
    ObjectInstances,
    OccupancyGrid,
    OccupancyMaps,
    Part,
    Semantics,
)
from stratamap.core.map.vocabulary import Vocabulary

DOOR_WIDTH = 0.4


def box_mesh(extents, center) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=make_pose(center))


def cabinet_completion(pose: np.ndarray) -> Completion:
    """A 0.4 x 0.4 x 0.8 m cabinet: a door hinged on its left edge (revolute about z, opening outwards to -y) and
    a drawer on a slide along -y. Each part's saved pose is its joint origin, as completers save them."""
    door_origin = make_pose((-0.2, -0.21, 0.0))  # the hinge line: x = -0.2, y = -0.21 in the object frame
    drawer_origin = make_pose((0.0, -0.2, 0.6))
    parts = [
        Part("body", box_mesh((0.4, 0.4, 0.8), (0.0, 0.0, 0.4))),
        Part("door", box_mesh((DOOR_WIDTH, 0.02, 0.5), (DOOR_WIDTH / 2, 0.0, 0.25)), door_origin),
        Part("drawer", box_mesh((0.36, 0.3, 0.15), (0.0, 0.15, 0.0)), drawer_origin),
    ]
    joints = [
        Joint("door_hinge", "revolute", "body", "door", door_origin, (0, 0, -1), 0.0, np.pi / 2),
        Joint("drawer_slide", "prismatic", "body", "drawer", drawer_origin, (0, -1, 0), 0.0, 0.3),
    ]
    whole = trimesh.util.concatenate([p.mesh.copy().apply_transform(p.pose) for p in parts])
    return Completion(whole, pose, "test", "cabinet_test", np.array([1.0, 1.0, 1.25]), 0.0123, parts, joints)


@pytest.fixture
def small_map() -> LayeredMap:
    """A 4 x 3 m room: floor points, a table (rigid model) with a box on it, an articulated cabinet, and one
    object left uncompleted; occupancy grids with a wall of occupied cells."""
    vocabulary = Vocabulary.default()
    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(0, 4, 3000), rng.uniform(0, 3, 3000), np.zeros(3000)])
    table_pts = np.column_stack([rng.uniform(0.5, 1.5, 400), rng.uniform(0.5, 1.0, 400), np.full(400, 0.75)])
    box_pts = np.column_stack([rng.uniform(0.8, 1.0, 100), rng.uniform(0.6, 0.8, 100), rng.uniform(0.75, 0.95, 100)])
    cab_pts = np.column_stack([rng.uniform(2.8, 3.2, 300), rng.uniform(1.8, 2.2, 300), rng.uniform(0, 0.8, 300)])
    plant_pts = np.column_stack([rng.uniform(3.5, 3.7, 60), rng.uniform(0.2, 0.4, 60), rng.uniform(0, 0.5, 60)])
    groups = [(floor, "floor", 0), (table_pts, "table", 1), (box_pts, "box", 2), (cab_pts, "cabinet", 3)]
    groups.append((plant_pts, "plant", 4))
    points = np.vstack([g[0] for g in groups])
    class_ids = np.concatenate([np.full(len(g[0]), vocabulary.id(g[1])) for g in groups])
    instance_ids = np.concatenate([np.full(len(g[0]), g[2]) for g in groups])
    colors = rng.uniform(0, 1, (len(points), 3)).astype(np.float32)

    def instance(oid, name, pts, completion=None):
        box = OrientedBox((pts.min(0) + pts.max(0)) / 2, 0.0, np.maximum(pts.max(0) - pts.min(0), 0.01))
        return ObjectInstance(oid, name, pts, box, completion=completion)

    table_model = box_mesh((1.0, 0.5, 0.75), (0.0, 0.0, 0.375))
    table = Completion(table_model, make_pose((1.0, 0.75, 0.0)), "test", "table_test", np.ones(3), 0.02)
    cabinet = cabinet_completion(make_pose((3.0, 2.0, 0.0), yaw=0.3))
    instances = ObjectInstances(
        [
            instance(1, "table", table_pts, table),
            instance(2, "box", box_pts),
            instance(3, "cabinet", cab_pts, cabinet),
            instance(4, "plant", plant_pts),
        ]
    )
    graph = ContactGraph()
    graph.support.add_node("floor", kind="layout")
    graph.support.add_edge("scene", "floor")
    for oid in (1, 3, 4):
        graph.support.add_node(oid, kind="object")
        graph.support.add_edge("floor", oid)
    graph.support.add_node(2, kind="object")
    graph.support.add_edge(1, 2)
    graph.proximal.add_edge(1, 3)
    data = np.zeros((60, 80), np.int8)  # 5 cm cells over 4 x 3 m
    data[:, 0] = 100  # the wall at x = 0 .. 0.05
    data[50:, 70:] = -1  # unknown corner at high y, high x
    occupancy = OccupancyMaps(
        slam=OccupancyGrid(data, 0.05, (0.0, 0.0, 0.0)), multimap=OccupancyGrid(data, 0.05, (0.0, 0.0, 0.0))
    )
    return LayeredMap(
        vocabulary=vocabulary,
        occupancy=occupancy,
        geometry=Geometry(points, colors, voxel_size=0.02),
        semantics=Semantics(class_ids, instance_ids, vocabulary),
        instances=instances,
        contact_graph=graph,
    )
