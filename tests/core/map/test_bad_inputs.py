"""Bad map folders: every malformed file of the map format is a MapFormatError that names the file and
what was expected (never a KeyError, ValueError or IndexError from deep inside); saving refuses to replace
what is not a map, and a load-then-save writes the same bytes."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from stratamap.core.errors import MapFormatError
from stratamap.core.map.layers import LayeredMap
from tests.core.map.test_format import full_map


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("map") / "map"
    full_map().save(folder)
    return folder


def copy_map(saved: Path, dst: Path) -> Path:
    dst.mkdir()
    for f in saved.iterdir():
        (dst / f.name).write_bytes(f.read_bytes())
    return dst


def edit_npz(path: Path, change: Callable[[dict[str, np.ndarray]], None]) -> None:
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    change(arrays)
    np.savez(path, **arrays)


def edit_json(path: Path, change: Callable[[dict], object]) -> None:
    obj = json.loads(path.read_text())
    change(obj)  # in place; what it returns is ignored
    path.write_text(json.dumps(obj))


def drop(*keys: str) -> Callable[[dict], None]:
    return lambda d: [d.pop(k) for k in keys]


def put(key: str, value) -> Callable[[dict], None]:
    return lambda d: d.__setitem__(key, value)


def points_of(d: dict) -> np.ndarray:
    return d["points"]


#: case -> (file to change, how, what the error must say)
CASES: dict[str, tuple[str, Callable[[Path], None], str]] = {
    "geometry-without-points": (
        "geometry.npz",
        lambda p: edit_npz(p, drop("points")),
        r"geometry\.npz: no array 'points'; the map format requires it",
    ),
    "points-wrong-shape": (
        "geometry.npz",
        lambda p: edit_npz(p, lambda d: d.__setitem__("points", d["points"][:, :2].copy())),
        r"geometry\.npz: array 'points' has shape \(500, 2\), expected \(N, 3\)",
    ),
    "points-wrong-dtype": (
        "geometry.npz",
        lambda p: edit_npz(p, lambda d: d.__setitem__("points", d["points"].astype("U8"))),
        r"geometry\.npz: array 'points' has dtype <U8, expected float values",
    ),
    "points-nan": (
        "geometry.npz",
        lambda p: edit_npz(p, lambda d: d["points"].__setitem__((3, 1), np.nan)),
        r"geometry\.npz: array 'points' holds 1 NaN or infinite values",
    ),
    "points-inf": (
        "augmented.npz",
        lambda p: edit_npz(p, lambda d: d["points"].__setitem__((0, 0), -np.inf)),
        r"augmented\.npz: array 'points' holds 1 NaN or infinite values",
    ),
    "colors-too-short": (
        "geometry.npz",
        lambda p: edit_npz(p, lambda d: d.__setitem__("colors", d["colors"][:10])),
        r"geometry\.npz: array 'colors' has shape \(10, 3\), expected \(500 \(as 'points'\), 3\)",
    ),
    "mesh-index-out-of-range": (
        "geometry.npz",
        lambda p: edit_npz(p, lambda d: d["mesh.faces"].__setitem__((0, 0), 10_000)),
        r"geometry\.npz: array 'mesh\.faces' indexes vertex 10000, but 'mesh\.vertices' holds 162 vertices",
    ),
    "mesh-faces-without-vertices": (
        "geometry.npz",
        lambda p: edit_npz(p, drop("mesh.vertices")),
        r"geometry\.npz: no array 'mesh\.vertices'",
    ),
    "mesh-colors-wrong-dtype": (
        "geometry.npz",
        lambda p: edit_npz(p, lambda d: d.__setitem__("mesh.vertex_colors", d["mesh.vertex_colors"].astype(float))),
        r"geometry\.npz: array 'mesh\.vertex_colors' has dtype float64, expected uint8",
    ),
    "voxel-size-negative": (
        "geometry.npz",
        lambda p: edit_npz(p, put("voxel_size", np.array(-0.02))),
        r"geometry\.npz: array 'voxel_size' must be positive",
    ),
    "unexpected-array": (
        "geometry.npz",
        lambda p: edit_npz(p, put("intensity", np.zeros(500))),
        r"geometry\.npz: unexpected arrays 'intensity'",
    ),
    "npz-garbage": (
        "semantics.npz",
        lambda p: p.write_bytes(b"PK\x03\x04 not really a zip"),
        r"semantics\.npz: cannot be read as \.npz",
    ),
    "npz-truncated": (
        "geometry.npz",
        lambda p: p.write_bytes(p.read_bytes()[:3000]),
        r"geometry\.npz: cannot be read as \.npz",
    ),
    "npz-empty": ("occupancy.npz", lambda p: p.write_bytes(b""), r"occupancy\.npz: cannot be read as \.npz"),
    "occupancy-meta-missing": (
        "occupancy.npz",
        lambda p: edit_npz(p, drop("slam.meta")),
        r"occupancy\.npz: no array 'slam\.meta'",
    ),
    "occupancy-meta-not-json": (
        "occupancy.npz",
        lambda p: edit_npz(p, put("slam.meta", np.array("{resolution: 0.05"))),
        r"occupancy\.npz: array 'slam\.meta' is not JSON",
    ),
    "occupancy-resolution-zero": (
        "occupancy.npz",
        lambda p: edit_npz(p, put("slam.meta", np.array('{"resolution": 0, "origin": [0, 0, 0], "frame_id": "map"}'))),
        r"occupancy\.npz: grid 'slam' resolution must be positive",
    ),
    "occupancy-data-wrong-dtype": (
        "occupancy.npz",
        lambda p: edit_npz(p, lambda d: d.__setitem__("slam.data", d["slam.data"].astype(np.float32))),
        r"occupancy\.npz: array 'slam\.data' has dtype float32, expected int8",
    ),
    "orphan-meta": (
        "occupancy.npz",
        lambda p: edit_npz(p, drop("slam.data")),
        r"occupancy\.npz: unexpected arrays 'slam\.meta'",
    ),
    "semantics-length": (
        "semantics.npz",
        lambda p: edit_npz(p, lambda d: d.update(class_ids=d["class_ids"][:5], instance_ids=d["instance_ids"][:5])),
        r"semantics\.npz: 5 labels for the 500 points of the geometry layer",
    ),
    "semantics-class-beyond-vocabulary": (
        "semantics.npz",
        lambda p: edit_npz(p, lambda d: d["class_ids"].__setitem__(0, 99)),
        r"semantics\.npz: class ids range 0\.\.99, the vocabulary has 26 classes",
    ),
    "semantics-ids-differ-in-length": (
        "semantics.npz",
        lambda p: edit_npz(p, lambda d: d.__setitem__("instance_ids", d["instance_ids"][:7])),
        r"semantics\.npz: array 'instance_ids' has shape \(7,\), expected \(500 \(as 'class_ids'\),\)",
    ),
    "manifest-bad-json": ("manifest.json", lambda p: p.write_text('{"format": '), r"manifest\.json: corrupt JSON"),
    "manifest-binary": ("manifest.json", lambda p: p.write_bytes(b"\xff\xfe\x00"), r"manifest\.json: corrupt JSON"),
    "manifest-a-list": ("manifest.json", lambda p: p.write_text("[1, 2]"), r"manifest\.json: expected a JSON object"),
    "manifest-missing": ("manifest.json", lambda p: p.unlink(), r"manifest\.json: no manifest"),
    "manifest-wrong-format": (
        "manifest.json",
        lambda p: edit_json(p, put("format", "other")),
        r"manifest\.json: format is 'other', expected 'stratamap\.map'",
    ),
    "manifest-no-vocabulary": (
        "manifest.json",
        lambda p: edit_json(p, drop("vocabulary")),
        r"manifest\.json: no 'vocabulary'",
    ),
    "manifest-vocabulary-mismatch": (
        "manifest.json",
        lambda p: edit_json(p, lambda d: d["vocabulary"]["is_thing"].pop()),
        r"manifest\.json: vocabulary\.is_thing must be a list of 26 true/false values",
    ),
    "manifest-unknown-layer": (
        "manifest.json",
        lambda p: edit_json(p, lambda d: d["layers"].__setitem__("lidar", {"file": "lidar.npz"})),
        r"manifest\.json: unknown layers \['lidar'\]",
    ),
    "manifest-file-outside-the-map": (
        "manifest.json",
        lambda p: edit_json(p, lambda d: d["layers"]["geometry"].__setitem__("file", "../elsewhere.npz")),
        r"manifest\.json: layers\.geometry\.file must be a file name inside the map folder",
    ),
    "layer-file-missing": (
        "geometry.npz",
        lambda p: p.unlink(),
        r"geometry\.npz: listed in the manifest but missing",
    ),
    "instances-not-a-list": (
        "instances.json",
        lambda p: p.write_text(json.dumps({"objects": json.loads(p.read_text())})),
        r"instances\.json: expected a JSON list of objects, got dict",
    ),
    "instance-without-box": (
        "instances.json",
        lambda p: edit_json(p, lambda d: d[0].pop("box")),
        r"instances\.json: entry 0 lacks box",
    ),
    "instance-box-malformed": (
        "instances.json",
        lambda p: edit_json(p, lambda d: d[0]["box"].__setitem__("size", [1, 2])),
        r"instances\.json: object 3 box size must be 3 finite numbers",
    ),
    "instance-ids-repeat": (
        "instances.json",
        lambda p: edit_json(p, lambda d: d[1].__setitem__("id", 3)),
        r"instances\.json: entry 1: object id 3 appears twice",
    ),
    "instance-points-missing": (
        "instances.npz",
        lambda p: edit_npz(p, drop("7.points")),
        r"instances\.npz: no array '7\.points'",
    ),
    "instance-completion-pose": (
        "instances.json",
        lambda p: edit_json(p, lambda d: d[0]["completion"].__setitem__("pose", [[1, 0], [0, 1]])),
        r"instances\.json: object 3 completion pose must be 4x4 finite numbers",
    ),
    "instance-joint-malformed": (
        "instances.json",
        lambda p: edit_json(p, lambda d: d[0]["completion"]["joints"][0].pop("axis")),
        r"instances\.json: object 3 completion: .*axis",
    ),
    "contact-graph-malformed": (
        "contact_graph.json",
        lambda p: edit_json(p, lambda d: d["support"].pop("nodes")),
        r"contact_graph\.json: .*nodes",
    ),
    "contact-graph-bad-json": ("contact_graph.json", lambda p: p.write_text("{"), r"contact_graph\.json: corrupt JSON"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_map_file(case, saved, tmp_path):
    name, change, message = CASES[case]
    folder = copy_map(saved, tmp_path / "m")
    change(folder / name)
    with pytest.raises(MapFormatError, match=message) as err:
        LayeredMap.load(folder)
    assert "\n" not in str(err.value)


def test_the_intact_copy_loads(saved, tmp_path):
    loaded = LayeredMap.load(copy_map(saved, tmp_path / "m"))
    assert len(loaded.geometry.points) == 500 and len(loaded.instances) == 2


def test_save_onto_a_file_is_an_error_and_leaves_nothing_behind(tmp_path):
    target = tmp_path / "map"
    target.write_text("my notes")
    with pytest.raises(MapFormatError, match=r"map: is a file, not a folder"):
        LayeredMap().save(target)
    assert target.read_text() == "my notes"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map"]  # no .map.PID.old, no staging folder


def test_save_onto_a_folder_that_is_not_a_map_is_an_error(tmp_path):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "cat.jpg").write_bytes(b"\xff\xd8")
    with pytest.raises(MapFormatError, match=r"photos: holds files but no manifest\.json"):
        LayeredMap().save(tmp_path / "photos")
    assert [p.name for p in (tmp_path / "photos").iterdir()] == ["cat.jpg"]
    (tmp_path / "empty").mkdir()
    LayeredMap().save(tmp_path / "empty")  # an empty folder, or an earlier map, may be written
    LayeredMap().save(tmp_path / "empty")
    assert (tmp_path / "empty" / "manifest.json").is_file()


def test_load_then_save_gives_identical_bytes(saved, tmp_path):
    LayeredMap.load(saved).save(tmp_path / "again")
    full_map().save(tmp_path / "twice")  # a second save of the same map, at another time
    for folder in (tmp_path / "again", tmp_path / "twice"):
        assert sorted(p.name for p in folder.iterdir()) == sorted(p.name for p in saved.iterdir())
        for f in saved.iterdir():
            assert (folder / f.name).read_bytes() == f.read_bytes(), (folder.name, f.name)
