"""Completed models rest on their supporters, a completion that disagrees with what was seen is
rejected, and plane_box_match's min-conflict choice is made on mesh penetrations, whatever ids the
objects carry (functional-scenes paper, section 4.4)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from stratamap.core.geometry.boxes import box_iou_3d, gravity_aligned_box
from stratamap.core.library.models import LibraryModel, LibraryPart
from stratamap.core.map.layers import ObjectInstance, ObjectInstances, OrientedBox
from stratamap.core.simulation.physics import Placement, mesh_shells, min_conflict, shells_penetration
from stratamap.core.stages import PipelineData
from stratamap.plugins.completers._matching import (
    Match,
    MatcherConfig,
    object_base,
    posed_completion,
    rejection_reason,
)
from stratamap.plugins.completers.icp_match import ICPMatchCompleter
from stratamap.plugins.completers.plane_box_match import Candidate, Layout, placement


def pair_penetration(a: Placement, b: Placement, tolerance: float) -> float:
    return shells_penetration(a.shells, b.shells, tolerance)


def boxes(*specs: tuple[tuple[float, float, float], tuple[float, float, float]]) -> trimesh.Trimesh:
    """Boxes given as (extents, centre): a piece of furniture as the convex pieces a simulator collides."""
    return trimesh.util.concatenate(
        [trimesh.creation.box(extents=e, transform=trimesh.transformations.translation_matrix(c)) for e, c in specs]
    )


def table_mesh() -> trimesh.Trimesh:
    legs = [((0.05, 0.05, 0.7), (x, y, 0.35)) for x in (-0.55, 0.55) for y in (-0.35, 0.35)]
    return boxes(((1.2, 0.8, 0.04), (0.0, 0.0, 0.72)), *legs)


def chair_mesh() -> trimesh.Trimesh:
    legs = [((0.04, 0.04, 0.44), (x, y, 0.22)) for x in (-0.2, 0.2) for y in (-0.2, 0.2)]
    return boxes(((0.45, 0.45, 0.04), (0.0, 0.0, 0.46)), ((0.45, 0.04, 0.2), (0.0, 0.22, 0.58)), *legs)


def candidate(mesh: trimesh.Trimesh, xy: tuple[float, float], ae: float, name: str) -> Placement:
    """A plane_box_match candidate as its min-conflict search sees it (``item``: the candidate)."""
    world = mesh.copy()
    world.apply_translation([xy[0], xy[1], 0.0])
    lo, hi = world.bounds
    cnd = Candidate(name, 0, 0.0, 0.0, 1.0, np.array([*(lo[:2] + hi[:2]) / 2, 0.0]), ae, hi - lo)
    cnd.shells = mesh_shells(world)
    return placement(cnd)


def test_a_chair_pushed_under_a_table_whose_meshes_do_not_touch_is_no_conflict():
    table = candidate(table_mesh(), (0.0, 0.0), 0.01, "table")
    chair = candidate(chair_mesh(), (0.0, -0.2), 0.01, "chair")  # seat and back under the tabletop
    box_a = OrientedBox(table.item.translation + [0, 0, table.item.size[2] / 2], 0.0, table.item.size)
    box_b = OrientedBox(chair.item.translation + [0, 0, chair.item.size[2] / 2], 0.0, chair.item.size)
    assert box_iou_3d(box_a, box_b) > 0.05  # what the box test called a conflict
    assert pair_penetration(table, chair, 0.02) == 0.0
    choice = min_conflict({1: [table], 2: [chair]}, 0.02)
    assert choice[1] is table and choice[2] is chair
    sunk = candidate(chair_mesh(), (0.0, -0.2), 0.01, "chair")
    sunk.shells = [s.translated(np.array([0.0, 0.0, 0.3])) for s in sunk.shells]  # back through the tabletop
    assert pair_penetration(table, sunk, 0.02) > 0.0


def scene_options(ids: list[int]) -> dict[int, list[Placement]]:
    """Three objects: the first has one candidate, which the second's best candidate penetrates; the
    second has a free alternative; the third stands alone. Repairing the first conflicted object
    only (by id) would leave the conflict whenever the first object has the lower id."""
    a = [candidate(boxes(((0.6, 0.6, 0.8), (0, 0, 0.4))), (0.0, 0.0), 0.01, "fixed")]
    b = [
        candidate(boxes(((0.6, 0.6, 0.8), (0, 0, 0.4))), (0.3, 0.0), 0.01, "overlapping"),
        candidate(boxes(((0.6, 0.6, 0.8), (0, 0, 0.4))), (0.9, 0.0), 0.03, "beside"),
    ]
    c = [candidate(boxes(((0.4, 0.4, 0.4), (0, 0, 0.2))), (3.0, 3.0), 0.02, "alone")]
    return dict(zip(ids, (a, b, c), strict=True))


@pytest.mark.parametrize("ids", [[1, 2, 3], [2, 1, 3], [3, 2, 1], [7, 4, 5], [5, 9, 1]])
def test_min_conflict_is_the_same_for_any_order_of_object_ids(ids):
    options = scene_options(ids)
    choice = min_conflict(options, 0.02)
    chosen = [choice[i].item.model_id for i in ids]
    assert chosen == ["fixed", "beside", "alone"]
    assert all(pair_penetration(choice[i], choice[j], 0.02) == 0.0 for i in ids for j in ids if i != j)


def test_min_conflict_stops_when_no_move_helps():
    one = [candidate(boxes(((0.6, 0.6, 0.8), (0, 0, 0.4))), (0.0, 0.0), 0.01, "a")]
    two = [candidate(boxes(((0.6, 0.6, 0.8), (0, 0, 0.4))), (0.2, 0.0), 0.01, "b")]
    choice = min_conflict({1: one, 2: two}, 0.02, iterations=50)
    assert choice[1] is one[0] and choice[2] is two[0]  # nothing better to try: left as it is


def test_layout_penetration_through_walls_floor_and_ceiling():
    wall = np.stack(np.meshgrid(np.linspace(-2, 2, 60), [1.0], np.linspace(0, 2.5, 40)), -1).reshape(-1, 3)
    layout = Layout(floor_z=0.0, ceiling_z=2.5, walls=wall)
    inside = mesh_shells(boxes(((0.5, 0.5, 0.8), (0.0, 0.5, 0.4))))  # 0.25 m from the wall
    through = mesh_shells(boxes(((0.5, 0.5, 0.8), (0.0, 0.9, 0.4))))  # 0.15 m through it
    assert layout.penetration(inside, 0.02) == 0.0
    assert layout.penetration(through, 0.02) == pytest.approx(0.13, abs=0.02)
    assert layout.penetration(mesh_shells(boxes(((0.5, 0.5, 2.8), (0.0, 0.0, 1.4)))), 0.02) > 0.2  # the ceiling


def library_model(mesh: trimesh.Trimesh) -> LibraryModel:
    return LibraryModel("m", "chair", "test", {}, [LibraryPart("body", mesh=mesh.copy())], bounds=mesh.bounds)


def test_a_model_rests_on_its_support_whatever_its_source_put_below_zero():
    sunk = chair_mesh()
    sunk.apply_translation([0, 0, -0.12])  # a source whose origin is not the model's bottom
    completion = posed_completion(library_model(sunk), Match("m", 0.3, np.array([1.0, 2.0, 0.75]), 1.0, 0.0, {}), "t")
    assert completion.world_mesh().bounds[0][2] == pytest.approx(0.75)


def test_a_chair_whose_legs_were_never_mapped_stands_on_the_floor():
    rng = np.random.default_rng(0)
    seat_and_back = np.vstack(
        [
            rng.uniform([0, 0, 0.44], [0.45, 0.45, 0.48], (300, 3)),
            rng.uniform([0, 0.42, 0.48], [0.45, 0.45, 0.95], (300, 3)),
        ]
    )
    chair = ObjectInstance(1, "chair", seat_and_back, gravity_aligned_box(seat_and_back))
    assert chair.box.bottom_z > 0.4
    data = PipelineData()
    data.map.instances = ObjectInstances([chair])
    assert object_base(chair, data)[2] == 0.0
    cup_pts = rng.uniform([0, 0, 0.75], [0.08, 0.08, 0.85], (200, 3))
    cup = ObjectInstance(2, "cup", cup_pts, gravity_aligned_box(cup_pts))
    assert object_base(cup, data)[2] == pytest.approx(cup.box.bottom_z)  # not a floor-standing height: left


def surface_points(mesh: trimesh.Trimesh, offset, n: int = 800) -> np.ndarray:
    return trimesh.sample.sample_surface_even(mesh, n, seed=0)[0] + np.asarray(offset)


def test_a_completion_that_disagrees_with_the_observed_points_is_rejected():
    seen = surface_points(chair_mesh(), (0.0, 0.0, 0.0))
    inst = ObjectInstance(1, "chair", seen, gravity_aligned_box(seen))
    cfg = MatcherConfig()
    model = library_model(chair_mesh())
    right = posed_completion(model, Match("m", 0.0, np.zeros(3), 1.0, 0.0, {}), "t")
    turned = posed_completion(model, Match("m", np.pi / 2, np.zeros(3), 1.0, 0.0, {}), "t")  # back on the side
    assert rejection_reason(inst, right, cfg) is None
    reason = rejection_reason(inst, turned, cfg)
    assert reason is not None and "observed points" in reason
    assert rejection_reason(inst, turned, cfg.model_copy(update={"reject_distance": None})) is None


def test_icp_match_keeps_what_was_seen_when_no_model_agrees(tmp_path):
    """A library with only a tall narrow cabinet: a wide low object is left as observed, and says why."""
    boxes(((0.3, 0.3, 1.6), (0, 0, 0.8))).export(tmp_path / "tall.stl")
    (tmp_path / "classes.csv").write_text("file,class\ntall.stl,cabinet\n")
    seen = surface_points(boxes(((1.4, 0.5, 0.6), (1.0, 1.0, 0.3))), (0, 0, 0))
    seen = seen[seen[:, 2] > 0.01]
    data = PipelineData()
    data.map.instances = ObjectInstances([ObjectInstance(1, "cabinet", seen, gravity_aligned_box(seen))])
    out = ICPMatchCompleter(library=str(tmp_path)).run(data)
    inst = out["instances"][1]
    assert inst.completion is None and "observed points" in inst.attributes["completion_rejected"]
    (warning,) = [w for w in data.warnings if "completion rejected" in w]
    assert "object 1 (cabinet)" in warning and inst.attributes["completion_rejected"] in warning


def test_rejected_completions_are_one_warning_with_each_reason_in_the_notes(tmp_path):
    """A real room's clutter rejects a dozen models: one warning names them all, the notes say why each."""
    boxes(((0.3, 0.3, 1.6), (0, 0, 0.8))).export(tmp_path / "tall.stl")
    (tmp_path / "classes.csv").write_text("file,class\ntall.stl,cabinet\n")
    instances = []
    for k in range(3):
        seen = surface_points(boxes(((1.4, 0.5, 0.6), (3.0 * k, 1.0, 0.3))), (0, 0, 0))
        seen = seen[seen[:, 2] > 0.01]
        instances.append(ObjectInstance(k + 1, "cabinet", seen, gravity_aligned_box(seen)))
    data = PipelineData()
    data.map.instances = ObjectInstances(instances)
    ICPMatchCompleter(library=str(tmp_path)).run(data)
    warnings = [w for w in data.warnings if "completion rejected" in w]
    assert len(warnings) == 1 and "objects 1 (cabinet), 2 (cabinet), 3 (cabinet)" in warnings[0]
    rejected = data.notes["icp_match"]["completions_rejected"]
    assert [r["instance"] for r in rejected] == [1, 2, 3] and all("observed points" in r["why"] for r in rejected)


def test_matching_completers_keep_ranked_alternatives_in_memory_not_in_the_map(tmp_path):
    """Both matching completers keep the next-best models beside the chosen one, posed where the
    observation is and agreeing with it; a saved map keeps the chosen model only, and loads."""
    from stratamap.core.map.layers import LayeredMap
    from stratamap.plugins.completers.plane_box_match import PlaneBoxMatchCompleter

    library = tmp_path / "library"
    library.mkdir()
    for name, width in (("a", 1.4), ("b", 1.3), ("c", 1.2)):
        boxes(((width, 0.5, 0.6), (0, 0, 0.3))).export(library / f"{name}.stl")
    (library / "classes.csv").write_text("file,class\na.stl,cabinet\nb.stl,cabinet\nc.stl,cabinet\n")
    seen = surface_points(boxes(((1.35, 0.5, 0.6), (1.0, 1.0, 0.3))), (0, 0, 0), n=1500)
    seen = seen[seen[:, 2] > 0.01]
    for completer in (ICPMatchCompleter(library=str(library)), PlaneBoxMatchCompleter(library=str(library))):
        data = PipelineData()
        data.map.instances = ObjectInstances([ObjectInstance(1, "cabinet", seen, gravity_aligned_box(seen))])
        completion = completer.run(data)["instances"][1].completion
        assert completion is not None and 1 <= len(completion.alternatives) <= MatcherConfig().alternatives
        for alt in completion.alternatives:
            assert alt.completer == completer.name
            assert np.linalg.norm(alt.pose[:2, 3] - completion.pose[:2, 3]) < 0.1  # posed where it was seen
            assert alt.model_id != completion.model_id or completer.name == "plane_box_match"
        saved = LayeredMap(instances=ObjectInstances([data.map.instances[1]]))
        saved.instances[1].completion = completion
        loaded = LayeredMap.load(saved.save(tmp_path / completer.name)).instances[1].completion
        assert loaded.model_id == completion.model_id and loaded.alternatives == []


def test_rocking_angle_of_a_cup_upright_and_on_its_side():
    from stratamap.core.simulation.rest import rocking_angle

    cup = trimesh.creation.cylinder(radius=0.05, height=0.14, sections=20)
    assert rocking_angle(cup) < 0.5
    on_side = cup.copy().apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    on_side.apply_transform(trimesh.transformations.rotation_matrix(np.radians(4.0), [0, 1, 0]))  # lowest: an edge
    assert 4.0 < rocking_angle(on_side) < 14.0


def test_plane_box_match_drops_candidates_that_would_rock_as_posed(tmp_path):
    """A cup seen lying on its side, and a library of a round cup and a square one of the same size:
    the round one on its side fits best but, posed on an edge of its 20 sides, would rock onto a
    facet; the square one lies still. Without the check (any rocking allowed) the round one wins."""
    from stratamap.core.simulation.rest import rocking_angle
    from stratamap.plugins.completers.plane_box_match import PlaneBoxMatchCompleter

    library = tmp_path / "library"
    library.mkdir()
    round_cup = trimesh.creation.cylinder(radius=0.05, height=0.14, sections=20)
    round_cup.apply_translation((0, 0, 0.07))
    round_cup.export(library / "round.stl")
    boxes(((0.1, 0.1, 0.14), (0, 0, 0.07))).export(library / "square.stl")
    (library / "classes.csv").write_text("file,class\nround.stl,cup\nsquare.stl,cup\n")
    lying = trimesh.creation.cylinder(radius=0.05, height=0.14, sections=64)
    lying.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    seen = surface_points(lying, (1.0, 1.0, 0.05), n=1500)
    seen = seen[seen[:, 2] > 0.03]  # seen from above
    chosen = {}
    for limit in (5.0, 180.0):
        data = PipelineData()
        data.map.instances = ObjectInstances([ObjectInstance(1, "cup", seen, gravity_aligned_box(seen))])
        completer = PlaneBoxMatchCompleter(library=str(library), max_rocking_deg=limit)
        completion = completer.run(data)["instances"][1].completion
        assert completion is not None
        chosen[limit] = (completion.model_id, rocking_angle(completion.world_mesh()))
    assert chosen[180.0][1] > 5.0, chosen  # the best fit alone would rock
    assert chosen[5.0][1] <= 5.0 and chosen[5.0][0] != chosen[180.0][0], chosen
