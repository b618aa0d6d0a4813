"""Scenes whose objects come from model libraries (other people's models): spec validation, sizes in
metres, placement on the floor and on support surfaces, material colours in the images, determinism."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml

from stratamap.core.errors import ConfigError
from stratamap.core.synthetic import SceneSpec, SyntheticWorld
from stratamap.core.synthetic.spec import resolve_spec_paths
from tests.conftest import shared_data

RED, BLUE = (0.8, 0.1, 0.1), (0.1, 0.2, 0.8)


def _obj_with_color(mesh: trimesh.Trimesh, path: Path, kd: tuple[float, float, float]) -> None:
    """An OBJ whose MTL gives it one diffuse colour (Kd), as a modelling tool writes it."""
    lines = [f"mtllib {path.stem}.mtl", "usemtl paint"]
    lines += [f"v {x:.5f} {y:.5f} {z:.5f}" for x, y, z in mesh.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
    path.write_text("\n".join(lines) + "\n")
    path.with_suffix(".mtl").write_text(f"newmtl paint\nKd {kd[0]} {kd[1]} {kd[2]}\n")


@pytest.fixture
def mesh_library(tmp_path: Path) -> Path:
    """A folder of coloured meshes with classes.csv: a red table (slab on four legs) and a blue box."""
    folder = tmp_path / "models"
    folder.mkdir()
    parts = [trimesh.creation.box((1.2, 0.7, 0.04), trimesh.transformations.translation_matrix((0, 0, 0.72)))]
    for sx in (-1, 1):
        for sy in (-1, 1):
            leg = trimesh.creation.box(
                (0.05, 0.05, 0.7), trimesh.transformations.translation_matrix((sx * 0.5, sy * 0.28, 0.35))
            )
            parts.append(leg)
    _obj_with_color(trimesh.util.concatenate(parts), folder / "table.obj", RED)
    _obj_with_color(trimesh.creation.box((0.3, 0.2, 0.15)), folder / "crate.obj", BLUE)
    (folder / "classes.csv").write_text("file,class\ntable.obj,table\ncrate.obj,box\n")
    return folder


def _spec_file(folder: Path, doc: dict) -> Path:
    base = {"type": "room", "room_size": [4.0, 3.5, 2.5], "camera": {"width": 96, "height": 72}}
    base["trajectory"] = {"type": "orbit", "frames": 6, "height": 1.6, "look_height": 0.5}
    path = folder / "scene.yaml"
    path.write_text(yaml.safe_dump({**base, **doc}))
    return path


def test_library_paths_are_resolved_against_the_spec_file(tmp_path, mesh_library):
    specs = tmp_path / "specs"
    specs.mkdir()
    path = _spec_file(specs, {"objects": {"table": {"count": 1, "library": {"path": "../models"}}}})
    spec = SceneSpec.from_yaml(path)
    assert Path(spec.resolved_sources()["table"][0].path) == mesh_library.resolve()
    # Passed on as a mapping (as benchmarks do), the paths are made absolute first.
    doc = resolve_spec_paths(yaml.safe_load(path.read_text()), specs)
    assert Path(doc["objects"]["table"]["library"]["path"]) == mesh_library.resolve()


@pytest.mark.parametrize(
    ("library", "key", "message"),
    [
        ({"path": "no/such/folder"}, "objects.chair.library.path", "not found"),
        ({"path": "."}, "objects.chair.library.linkz", "extra field"),
        ({"path": ".", "links": ["cabinet1"]}, "objects.chair.library", "links"),
        ({"path": ".", "height": 1.0, "scale": 0.5}, "objects.chair.library", "not both"),
        ({"path": ".", "height": [1.0, 0.5]}, "objects.chair.library.height", "low <= high"),
    ],
)
def test_bad_library_entries_name_the_key(tmp_path, library, key, message):
    bad = dict(library)
    if key.endswith("linkz"):
        bad["linkz"] = ["x"]
    path = _spec_file(tmp_path, {"objects": {"chair": {"count": 2, "library": bad}}})
    with pytest.raises(ConfigError) as err:
        SceneSpec.from_yaml(path)
    text = str(err.value)
    assert str(path) in text and key in text and message in text
    assert len(text.splitlines()) == 1


def test_a_library_without_the_class_is_a_data_error_naming_the_folder(tmp_path, mesh_library):
    from stratamap.core.errors import DataError

    spec = SceneSpec.from_yaml(
        _spec_file(tmp_path, {"objects": {"chair": {"count": 1, "library": {"path": str(mesh_library)}}}})
    )
    with pytest.raises(DataError, match=r"models.*no model of class 'chair'.*objects.chair.library"):
        SyntheticWorld(spec)


def _world(tmp_path: Path, mesh_library: Path, seed: int = 0) -> SyntheticWorld:
    library = {"path": str(mesh_library)}
    doc = {
        "seed": seed,
        "objects": {"table": {"count": 1, "library": library}, "box": {"count": 1, "library": library}},
    }
    return SyntheticWorld(SceneSpec.from_yaml(_spec_file(tmp_path, doc)))


def test_library_objects_stand_on_the_floor_and_on_support_surfaces(tmp_path, mesh_library):
    world = _world(tmp_path, mesh_library)
    objects = {o.class_name: o for o in world.scene.objects}
    assert set(objects) == {"table", "box"}, world.scene.skipped
    table, crate = objects["table"], objects["box"]
    box = table.to_ground_truth().box()
    np.testing.assert_allclose(sorted(box.size[:2]), [0.7, 1.2], atol=1e-6)  # a mesh folder is in metres
    assert box.center[2] - box.size[2] / 2 == pytest.approx(0.0, abs=1e-9)  # on the floor
    assert table.parent == "floor"
    # The crate rests on the tabletop (its support surface), not on the floor or inside the table.
    assert crate.parent == table.id
    assert crate.to_ground_truth().box().center[2] - 0.075 == pytest.approx(0.74, abs=1e-6)


def test_images_take_the_models_material_colours_and_labels(tmp_path, mesh_library):
    world = _world(tmp_path, mesh_library)
    ids = {o.class_name: o.id for o in world.scene.objects}
    pixels = {"table": [], "box": []}
    for k in range(len(world)):
        frame, seg = world.frame(k)
        for name in pixels:
            mask = seg.instance_ids == ids[name]
            pixels[name].append(frame.rgb[mask].astype(float))
            assert (seg.class_ids[mask] == world.vocabulary.id(name)).all()
    red, blue = np.vstack(pixels["table"]), np.vstack(pixels["box"])
    assert len(red) > 50 and len(blue) > 5
    # Shading scales all channels alike, so the channel ratios are the material's Kd.
    for rgb, kd in ((red, RED), (blue, BLUE)):
        ratio = rgb.mean(0) / rgb.mean(0).max()
        np.testing.assert_allclose(ratio, np.array(kd) / max(kd), atol=0.03)


def test_same_spec_and_seed_give_the_same_images(tmp_path, mesh_library):
    a, b = _world(tmp_path, mesh_library, seed=3), _world(tmp_path, mesh_library, seed=3)
    for k in (0, 4):
        np.testing.assert_array_equal(a.frame(k)[0].rgb, b.frame(k)[0].rgb)
        np.testing.assert_array_equal(a.frame(k)[0].depth, b.frame(k)[0].depth)
    assert [o.pose.tolist() for o in a.scene.objects] == [o.pose.tolist() for o in b.scene.objects]
    other = _world(tmp_path, mesh_library, seed=4)
    assert [o.pose.tolist() for o in other.scene.objects] != [o.pose.tolist() for o in a.scene.objects]


def test_partnet_chair_is_sized_to_metres_and_rendered_in_its_colours(tmp_path):
    """PartNet-Mobility has no units (chair 179 is 1.61 tall as shipped): a scene scales it to a
    chair's height, stands it on the floor, and renders it in its own (dark) colours."""
    partnet = shared_data("partnet_mobility", "179")
    library = {"path": str(partnet.parent), "models": ["179"]}
    doc = {"objects": {"chair": {"count": 1, "library": library}}, "trajectory": {"type": "orbit", "frames": 4}}
    doc["camera"] = {"width": 128, "height": 96}
    world = SyntheticWorld(SceneSpec.from_yaml(_spec_file(tmp_path, doc)))
    (chair,) = world.scene.objects
    box = chair.to_ground_truth().box()
    assert 0.85 <= box.size[2] <= 1.1
    assert box.center[2] - box.size[2] / 2 == pytest.approx(0.0, abs=1e-6)
    assert chair.model.joints and chair.model.family == "partnet_Chair"
    # Its faces carry the colours of the object's own (textured) samples: dark casters and base, a light seat.
    colors = np.vstack([p.face_colors if p.face_colors is not None else [p.albedo] for p in chair.model.parts])
    assert colors.max(1).min() < 0.2 and colors.min(1).max() > 0.6
    rgb = np.vstack([world.frame(k)[0].rgb[world.frame(k)[1].instance_ids == chair.id] for k in range(len(world))])
    brightness = rgb.astype(float).mean(1)
    assert len(rgb) > 100
    assert (brightness < 40).mean() > 0.05 and (brightness > 120).mean() > 0.05


def test_an_office_seats_a_chair_at_a_desk_from_a_model_library(tmp_path, mesh_library):
    """A library desk has none of the generated desks' knee-space parameters: an office that seats
    chairs at desks raised a KeyError on it. The chair now stands at the middle of the desk's front."""
    (mesh_library / "classes.csv").write_text("file,class,id\ntable.obj,desk,writing_desk\n")
    doc = {
        "type": "office",
        "seed": 0,
        "objects": {"desk": {"count": 1, "library": {"path": str(mesh_library)}}, "chair": 1},
    }
    world = SyntheticWorld(SceneSpec.from_yaml(_spec_file(tmp_path, doc)))
    objects = {o.class_name: o for o in world.scene.objects}
    assert set(objects) == {"desk", "chair"}, world.scene.skipped
    # In the desk's frame (front -y): the chair stands at the middle of the front, in front of it.
    desk = objects["desk"]
    chair = np.linalg.inv(desk.pose) @ np.append(objects["chair"].to_ground_truth().box().center, 1.0)
    assert abs(chair[0]) < 0.1, chair
    assert -0.35 - 0.7 < chair[1] < -0.35, chair


def test_chairs_sit_at_a_table_from_a_model_library(tmp_path, mesh_library):
    """A library table is one part, whose box fills the space under its top: a chair pushed in under
    it overlaps that box, so every chair went to a wall, often into a corner no walk looked at. The
    chairs now stand at the table's sides, pulled out, clear of its box and facing it."""
    doc = {
        "type": "kitchen",
        "room_size": [5.0, 4.4, 2.6],
        "objects": {"table": {"count": 1, "library": {"path": str(mesh_library), "models": ["table"]}}, "chair": 2},
    }
    for seed in (0, 1, 2):
        world = SyntheticWorld(SceneSpec.from_yaml(_spec_file(tmp_path, {**doc, "seed": seed})))
        table = next(o for o in world.scene.objects if o.class_name == "table")
        chairs = [o for o in world.scene.objects if o.class_name == "chair"]
        assert len(chairs) == 2, world.scene.skipped
        for chair in chairs:
            at = (np.linalg.inv(table.pose) @ np.append(chair.pose[:3, 3], 1.0))[:2]
            # Within half a metre of the table's 1.2 x 0.7 m top, beside it, not under it.
            gap = np.abs(at) - np.array([0.6, 0.35])
            assert gap.max() < 0.5 and gap.max() > 0.0, (seed, at)
            # Facing it: the chair's front (-y in its frame) points toward the table's middle.
            front = chair.pose[:2, :2] @ np.array([0.0, -1.0])
            toward = table.pose[:2, 3] - chair.pose[:2, 3]
            assert front @ toward / np.linalg.norm(toward) > 0.5, (seed, at)
