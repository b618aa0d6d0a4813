"""Synthetic worlds: deterministic, physically consistent, and rendered correctly."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import open3d.core as o3c
import pytest

from stratamap.core.synthetic import CameraSpec, SceneSpec, generate_scene, generate_sequence
from stratamap.core.synthetic.models import FAMILIES, make_model
from stratamap.core.synthetic.render import SceneRenderer
from stratamap.core.sensors import CameraIntrinsics
from stratamap.core.testing import fingerprint
from stratamap.core.transforms import look_at


def test_same_spec_and_seed_same_sequence():
    cam = CameraSpec(width=96, height=72)
    a = generate_sequence(SceneSpec(seed=5), cam, 4)
    b = generate_sequence(SceneSpec(seed=5), cam, 4)
    c = generate_sequence(SceneSpec(seed=6), cam, 4)
    fa = fingerprint([(f.rgb, f.depth, f.pose) for f in a.stream.frames])
    assert fa == fingerprint([(f.rgb, f.depth, f.pose) for f in b.stream.frames])
    assert fa != fingerprint([(f.rgb, f.depth, f.pose) for f in c.stream.frames])


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_models_are_watertight_and_canonical(family):
    model = make_model(family, seed=3, index=1)
    for part in model.parts:
        assert part.mesh.is_watertight, part.name
    lo, hi = model.bounds
    assert abs(lo[2]) < 1e-9, "origin at the bottom"
    np.testing.assert_allclose((lo[:2] + hi[:2]) / 2, 0, atol=0.05)


@pytest.mark.parametrize("seed", range(5))
def test_objects_do_not_interpenetrate(seed):
    scene = generate_scene(SceneSpec(seed=seed, chairs=6, boxes=3))
    objs = scene.objects
    assert len(objs) >= 5
    for i, a in enumerate(objs):
        sdf = o3d.t.geometry.RaycastingScene()
        for _, mesh in a.world_parts():
            sdf.add_triangles(o3c.Tensor(mesh.vertices.astype(np.float32)), o3c.Tensor(mesh.faces.astype(np.uint32)))
        for b in objs[i + 1 :]:
            pts = np.vstack([np.vstack([m.sample(400, seed=0), m.vertices]) for _, m in b.world_parts()])
            # Resting contact is allowed; penetration deeper than 1 mm is not.
            depth = -sdf.compute_signed_distance(o3c.Tensor(pts.astype(np.float32))).numpy().min()
            assert depth < 1e-3, f"object {b.id} ({b.class_name}) penetrates {a.id} ({a.class_name}) by {depth:.4f} m"


def test_support_tree_matches_placement():
    scene = generate_scene(SceneSpec(seed=2, boxes=3))
    g = scene.contact_graph().support
    for obj in scene.objects:
        assert g.in_degree(obj.id) == 1
        parent = next(iter(g.predecessors(obj.id)))
        if obj.class_name == "box":
            table = next(o for o in scene.objects if o.id == parent)
            top = table.pose[2, 3] + table.model.params["height"]
            assert obj.pose[2, 3] == pytest.approx(top)
        else:
            assert parent == "floor" and obj.pose[2, 3] == 0.0


def test_rendered_depth_matches_geometry():
    """Looking straight down from 2 m at the empty floor gives depth 2 m everywhere."""
    scene = generate_scene(SceneSpec(seed=0, tables=0, chairs=0, boxes=0, room_size=(4, 4, 2.6)))
    renderer = SceneRenderer(scene)
    intr = CameraIntrinsics(64, 48, 40.0, 40.0, 31.5, 23.5)
    pose = look_at([2.0, 2.0, 2.0], [2.0, 2.0, 0.0], up=(0, 1, 0))
    view = renderer.render(intr, pose)
    np.testing.assert_allclose(view.depth, 2.0, atol=1e-4)
    assert (view.class_ids == 1).all() and (view.instance_ids == 0).all()
