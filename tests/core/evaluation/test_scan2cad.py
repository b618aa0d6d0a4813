"""The Scan2CAD harness: its annotation reader, the benchmark's rule on planted errors, the frames
it compares in, and ``stratamap bench configs/bench/scan2cad.yaml`` on a ScanNet-format fixture."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from stratamap.core.errors import DataError
from stratamap.core.evaluation.scan2cad import evaluate_scan2cad, pooled
from stratamap.core.io.scan2cad import read_scan2cad
from stratamap.core.library.models import ModelLibrary
from stratamap.core.map.layers import Completion, ObjectInstance, ObjectInstances, OrientedBox
from tests.core.evaluation import scannet_fixtures as fx

REPO = fx.Path(__file__).resolve().parents[3]
ROOM_FROM_SCAN = np.linalg.inv(fx.SCAN_FROM_ROOM)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("scan2cad")
    shapenet = fx.write_shapenet(root / "shapenet")
    library = ModelLibrary.load(shapenet)
    world = fx.room(shapenet)
    return {"root": root, "shapenet": shapenet, "library": library, "world": world}


def completed(library, synset: str, cad_room: np.ndarray, iid: int = 1, class_name: str | None = None, score=1.0):
    """An object completed with the library's model of ``synset`` placed exactly as ``cad_room``
    places the ShapeNet file (pose rigid, the stretch in the completion's scale)."""
    model = next(m for m in library if m.params["synset"] == synset)
    placed = cad_room @ np.linalg.inv(np.asarray(model.params["cad_to_model"]))
    scale = np.linalg.norm(placed[:3, :3], axis=0)
    pose = placed.copy()
    pose[:3, :3] /= scale
    mesh = model.mesh().copy()
    mesh.vertices = np.asarray(mesh.vertices) * scale
    box = OrientedBox(pose[:3, 3], 0.0, np.ones(3))
    inst = ObjectInstance(iid, class_name or model.class_name, np.zeros((0, 3)), box, score=score)
    inst.completion = Completion(mesh, pose, "test", model.id, scale)
    return inst


def score(scene, truths, predictions, world_transform=ROOM_FROM_SCAN):
    """Annotations (synset, CAD-to-room, sym) written as full_annotations.json and read back, scored
    against ``predictions`` (ObjectInstances) in the room's frame."""
    path = fx.write_annotations(scene["root"] / "full_annotations.json", truths)
    return evaluate_scan2cad(ObjectInstances(predictions), read_scan2cad(path, fx.SCAN_ID), world_transform)


def test_the_benchmark_rule_on_planted_errors(scene):
    lib, at = scene["library"], fx.cad_to_room(scene["world"], scene["library"])
    chair, table = at[fx.CHAIR], at[fx.TABLE]
    cases = [
        # (what the truth says, where the completion is, sym, aligned?)
        ("exact chair", chair, chair, "__SYM_NONE", True),
        ("chair 15 cm off", chair, fx.planted(chair, shift=(0.15, 0, 0)), "__SYM_NONE", True),
        ("chair 25 cm off", chair, fx.planted(chair, shift=(0.0, 0.25, 0)), "__SYM_NONE", False),
        ("table turned 180 deg, 2-fold symmetric", table, fx.planted(table, turn_deg=180), "__SYM_ROTATE_UP_2", True),
        ("table turned 180 deg, no symmetry", table, fx.planted(table, turn_deg=180), "__SYM_NONE", False),
        ("chair turned 15 deg", chair, fx.planted(chair, turn_deg=15), "__SYM_NONE", True),
        ("chair turned 25 deg", chair, fx.planted(chair, turn_deg=25), "__SYM_NONE", False),
        ("table turned 90 deg, 4-fold symmetric", table, fx.planted(table, turn_deg=90), "__SYM_ROTATE_UP_4", True),
        ("table turned 50 deg, round", table, fx.planted(table, turn_deg=50), "__SYM_ROTATE_UP_INF", True),
        ("chair 25% too large", chair, fx.planted(chair, stretch=1.25), "__SYM_NONE", False),
        ("chair 15% too large", chair, fx.planted(chair, stretch=1.15), "__SYM_NONE", True),
    ]
    for name, truth, placed, sym, expected in cases:
        synset = fx.CHAIR if truth is chair else fx.TABLE
        result = score(scene, [(synset, truth, sym)], [completed(lib, synset, placed)])
        assert (result["aligned"] == 1) is expected, (name, result["objects"][0]["closest"])
    stretched = score(
        scene, [(fx.CHAIR, chair, "__SYM_NONE")], [completed(lib, fx.CHAIR, fx.planted(chair, stretch=1.25))]
    )
    closest = stretched["objects"][0]["closest"]
    assert closest["scale_percent"] == pytest.approx(25.0, abs=0.5)
    assert closest["translation_m"] < 0.01 and closest["rotation_deg"] < 0.1  # the scale alone fails it


def test_category_matching_instance_and_class_means(scene):
    lib, at = scene["library"], fx.cad_to_room(scene["world"], scene["library"])
    chair, table = at[fx.CHAIR], at[fx.TABLE]
    # A chair completed right but called a sofa aligns nothing; a desk may align a table.
    wrong = score(scene, [(fx.CHAIR, chair, "__SYM_NONE")], [completed(lib, fx.CHAIR, chair, class_name="sofa")])
    assert wrong["aligned"] == 0 and wrong["objects"][0]["closest"] is None
    desk = score(scene, [(fx.TABLE, table, "__SYM_NONE")], [completed(lib, fx.TABLE, table, class_name="desk")])
    assert desk["aligned"] == 1
    # Two annotated tables and one completed table: one aligned, the first the table passes.
    far = fx.planted(table, shift=(0.3, 0, 0))
    result = score(
        scene,
        [(fx.TABLE, far, "__SYM_NONE"), (fx.TABLE, table, "__SYM_NONE"), (fx.CHAIR, chair, "__SYM_NONE")],
        [completed(lib, fx.TABLE, table, 1), completed(lib, fx.CHAIR, chair, 2)],
    )
    assert [o["aligned_by"] for o in result["objects"]] == [None, 1, 2]
    assert result["by_category"] == {
        "chair": {"aligned": 1, "annotated": 1, "accuracy": 1.0},
        "table": {"aligned": 1, "annotated": 2, "accuracy": 0.5},
    }
    assert result["instance_mean"] == pytest.approx(2 / 3) and result["class_mean"] == pytest.approx(0.75)
    # Pooled over scans as the benchmark pools them, not the mean of per-scan accuracies.
    records = [
        {"variant": "v", "metrics": {"scan2cad": result}},
        {"variant": "v", "metrics": {"scan2cad": {"by_category": {"chair": {"aligned": 0, "annotated": 3}}}}},
    ]
    total = pooled(records)["v"]
    assert total["instance_mean"] == pytest.approx(2 / 6) and total["class_mean"] == pytest.approx((1 / 4 + 1 / 2) / 2)


def test_annotations_are_compared_in_the_map_frame(scene):
    """The annotation is in the scan's frame (and Scan2CAD's world beyond it): only the source's
    world_transform brings it onto a map made in the gravity-aligned frame."""
    lib, at = scene["library"], fx.cad_to_room(scene["world"], scene["library"])
    truth = [(fx.CHAIR, at[fx.CHAIR], "__SYM_NONE")]
    assert score(scene, truth, [completed(lib, fx.CHAIR, at[fx.CHAIR])])["aligned"] == 1
    assert score(scene, truth, [completed(lib, fx.CHAIR, at[fx.CHAIR])], world_transform=np.eye(4))["aligned"] == 0


def test_bad_annotation_files_are_one_line_errors(tmp_path):
    path = tmp_path / "full_annotations.json"
    path.write_text(json.dumps([{"id_scan": "scene0000_00", "trs": fx.trs(np.eye(4)), "aligned_models": []}]))
    with pytest.raises(DataError, match=r"full_annotations.json: no record with id_scan 'scene0001_00'"):
        read_scan2cad(path, "scene0001_00")
    model = {"catid_cad": "03001627", "id_cad": "x", "trs": fx.trs(np.eye(4)), "bbox": [1, 1, 1], "center": [0, 0, 0]}
    for broken, message in (
        ({**model, "sym": "__SYM_MIRROR"}, r"aligned_models\[0\]: sym must be one of __SYM_NONE"),
        (model, r"aligned_models\[0\]: missing sym"),
        (
            {
                **model,
                "sym": "__SYM_NONE",
                "trs": {"translation": [0, 0], "rotation": [1, 0, 0, 0], "scale": [1, 1, 1]},
            },
            r"aligned_models\[0\]: trs needs translation \[x, y, z\]",
        ),
    ):
        path.write_text(json.dumps([{"id_scan": "s", "trs": fx.trs(np.eye(4)), "aligned_models": [broken]}]))
        with pytest.raises(DataError, match=message):
            read_scan2cad(path, "s")
    path.write_text("{")
    with pytest.raises(DataError, match="corrupt JSON"):
        read_scan2cad(path, "s")


@pytest.mark.slow  # a whole benchmark or CLI run
def test_stratamap_bench_scan2cad_on_a_scannet_fixture(scene, tmp_path):
    """A .sens scan tilted off gravity, Scan2CAD's file and the ShapeNet folder, through the bench
    file as shipped: the mapped table is 25 cm from the first annotated table (not aligned) and 15 cm
    and a half turn from the second, a 2-fold symmetric one (aligned)."""
    root, world, lib = scene["root"], scene["world"], scene["library"]
    fx.write_scan(root / "scans" / fx.SCAN_ID, world, "sens")
    at = fx.cad_to_room(world, lib)
    annotations = fx.write_annotations(
        root / "bench_annotations.json",
        [
            (fx.TABLE, fx.planted(at[fx.TABLE], shift=(0.25, 0, 0)), "__SYM_ROTATE_UP_2"),
            (fx.TABLE, fx.planted(at[fx.TABLE], shift=(0, 0.15, 0), turn_deg=180), "__SYM_ROTATE_UP_2"),
            (fx.CHAIR, at[fx.CHAIR], "__SYM_NONE"),
        ],
    )
    listing = tmp_path / "val.txt"
    listing.write_text(f"{fx.SCAN_ID}\nscene0999_00\n")
    out = tmp_path / "bench"
    proc = subprocess.run(
        [
            sys.executable, "-m", "stratamap.core.cli", "bench", "configs/bench/scan2cad.yaml", "--out", str(out),
            "--set", f"scenes[0].files={root}/scans/*/*.sens",
            "--set", f"scenes[0].scene_list={listing}",
            "--set", f"scenes[0].source.params.scan2cad={annotations}",
            "--set", "scenes[0].source.params.stride=1",
            "--set", f"pipeline.stages[4].params.library={scene['shapenet']}",
            "--set", "scenes[0].variants=[geometric]",
        ],
        cwd=REPO, capture_output=True, text=True,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "1 of the 2 scenes" in proc.stdout and "scene0999_00" in proc.stdout  # listed, no file
    record = json.loads((out / "records" / f"scannet-{fx.SCAN_ID}" / "geometric.json").read_text())
    objects = record["metrics"]["scan2cad"]["objects"]
    assert objects[0]["aligned_by"] is None and objects[0]["closest"]["translation_m"] == pytest.approx(0.25, abs=0.03)
    assert objects[1]["aligned_by"] is not None and objects[1]["closest"]["translation_m"] == pytest.approx(
        0.15, abs=0.03
    )
    assert objects[1]["closest"]["rotation_deg"] < 5.0  # the half turn is the table's symmetry
    pooled_md = (out / "scan2cad.md").read_text()
    assert "| table | 1 | 2 | 50.0% |" in pooled_md
