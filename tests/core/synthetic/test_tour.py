"""The `tour` trajectory sees every object of a scene of any size; coverage is measured from the ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.synthetic.coverage import surface_coverage
from stratamap.core.synthetic.generate import SyntheticWorld
from stratamap.core.synthetic.render import SceneRenderer
from stratamap.core.synthetic.scene import generate_scene
from stratamap.core.synthetic.spec import SceneSpec
from stratamap.core.synthetic.trajectory import free_space, make_trajectory

#: Four offices' worth of floor and furniture in one open space (configs/bench/scaling.yaml's rooms-4).
ROOMS_4 = {
    "type": "office",
    "room_size": [13.0, 11.0, 2.7],
    "objects": {"desk": 12, "chair": 16, "monitor": 12, "cabinet": 8, "shelf": 4, "table": 4, "book": 12, "cup": 12},
    "camera": {"width": 160, "height": 120},
}


def _coverage(spec: SceneSpec, trajectory: str, frames: int) -> tuple[dict, list[np.ndarray]]:
    spec = spec.model_copy(
        update={"trajectory": spec.trajectory.model_copy(update={"type": trajectory, "frames": frames})}
    )
    scene = generate_scene(spec)
    renderer = SceneRenderer(scene)
    poses = make_trajectory(scene, spec.trajectory, spec.seed, renderer.cast)
    cov = surface_coverage(scene, renderer.cast, spec.camera.intrinsics(), poses, 0.4, spec.camera.max_range)
    return cov, poses


@pytest.fixture(scope="module")
def rooms_4() -> SceneSpec:
    return SceneSpec.model_validate(ROOMS_4)


@pytest.mark.slow
def test_tour_sees_every_object_of_a_large_scene_where_the_walk_does_not(rooms_4):
    tour, poses = _coverage(rooms_4, "tour", 480)
    walk, _ = _coverage(rooms_4, "walk", 480)
    assert tour["objects"] == 80 and len(poses) == 480
    assert tour["objects_seen"] == 80, [o for o in tour["per_object"] if o["seen"] == 0]
    # Every object well seen (not a glimpse): at least 5% of its surface samples, half of them on average.
    assert tour["min"] >= 0.05 and tour["mean"] >= 0.5
    # The walk keeps to the walls of a large room and misses the furniture in its middle.
    assert walk["objects_seen"] < 70
    assert tour["mean"] > walk["mean"]


@pytest.mark.slow
def test_tour_stays_in_free_space_and_is_deterministic(rooms_4):
    spec = rooms_4.model_copy(
        update={"trajectory": rooms_4.trajectory.model_copy(update={"type": "tour", "frames": 200})}
    )
    scene = generate_scene(spec)
    cast = SceneRenderer(scene).cast
    poses = make_trajectory(scene, spec.trajectory, spec.seed, cast)
    again = make_trajectory(scene, spec.trajectory, spec.seed, cast)
    assert all(np.array_equal(a, b) for a, b in zip(poses, again, strict=True))
    dist, _ = free_space(scene, spec.trajectory.clearance)
    xy = np.array([p[:2, 3] for p in poses])
    cells = np.floor(xy / 0.05).astype(int)
    clearance = dist[cells[:, 1], cells[:, 0]]
    # Path cells come from a 10 cm grid of cells with full clearance: a cell's width of slack.
    assert clearance.min() >= spec.trajectory.clearance - 0.1
    assert np.allclose([p[2, 3] for p in poses], spec.trajectory.height)
    # The camera moves in small steps (no jumps across the room between frames).
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    assert steps.max() < 0.6


@pytest.mark.slow
def test_default_walk_is_unchanged_and_coverage_is_opt_in():
    spec = SceneSpec.model_validate({"type": "office", "camera": {"width": 160, "height": 120}})
    world = SyntheticWorld(spec)
    assert spec.trajectory.type == "walk"
    scene = generate_scene(spec)
    rng = np.random.default_rng([spec.seed, 104729])
    from stratamap.core.synthetic.trajectory import walk

    assert all(np.array_equal(a, b) for a, b in zip(world.true_poses, walk(scene, spec.trajectory, rng), strict=True))
    assert "coverage" not in world.ground_truth().layout
    measured = SyntheticWorld(
        spec.model_copy(update={"ground_truth": spec.ground_truth.model_copy(update={"coverage": True})})
    )
    cov = measured.ground_truth().layout["coverage"]
    assert cov["objects"] == len(scene.objects) == len(cov["per_object"])
    assert 0 < cov["mean"] <= 1
