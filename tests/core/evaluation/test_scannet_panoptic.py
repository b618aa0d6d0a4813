"""The ScanNet panoptic harness: the per-vertex label reader, PQ against it in the map's frame, and
``stratamap bench configs/bench/scannet_panoptic.yaml`` on exported ScanNet frames."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from stratamap.core.errors import DataError
from stratamap.core.evaluation.scannet_panoptic import evaluate_scannet_panoptic
from stratamap.core.io.scannet_labels import read_scan_labels
from stratamap.core.map.layers import Semantics
from stratamap.core.map.vocabulary import Vocabulary
from tests.core.evaluation import scannet_fixtures as fx

REPO = fx.Path(__file__).resolve().parents[3]
ROOM_FROM_SCAN = np.linalg.inv(fx.SCAN_FROM_ROOM)


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    root = tmp_path_factory.mktemp("scannet")
    shapenet = fx.write_shapenet(root / "shapenet")
    world = fx.room(shapenet)
    folder = root / "frames" / fx.SCAN_ID
    counts = fx.write_labels(folder, world)
    return {"root": root, "world": world, "folder": folder, "counts": counts}


def test_labels_and_instances_are_read_per_vertex(scan):
    labels = read_scan_labels(scan["folder"], fx.SCAN_ID)
    counts = scan["counts"]
    assert len(labels.points) == sum(counts.values())
    for name, nyu in fx.NYU40.items():
        assert int(np.sum(labels.nyu40 == nyu)) == counts[name]
    # ScanNet's objects 0 (the table here) and 1 (the chair) become instances 1 and 2; layout has none.
    assert sorted(np.unique(labels.instance_ids).tolist()) == [0, 1, 2]
    assert np.all(labels.instance_ids[labels.nyu40 <= 2] == 0)
    vocab = Vocabulary.default()
    ids = labels.class_ids(vocab)
    assert set(np.unique(ids).tolist()) == {vocab.id(n) for n in ("floor", "wall", "ceiling", "chair", "table")}
    # ScanNet's 20 benchmark classes have no ceiling: void with that label set.
    assert np.all(labels.class_ids(vocab, "scannet20")[labels.nyu40 == 22] == -1)


def _map_of(labels, vocab, chair_as: str = "chair"):
    """The annotated vertices as a map would hold them: in the room's frame, labelled as given."""
    points = labels.points @ ROOM_FROM_SCAN[:3, :3].T + ROOM_FROM_SCAN[:3, 3]
    classes = labels.class_ids(vocab)
    classes[classes == vocab.id("chair")] = vocab.id(chair_as)
    return points, Semantics(np.maximum(classes, 0), labels.instance_ids, vocab)


def test_panoptic_quality_in_the_map_frame(scan):
    labels = read_scan_labels(scan["folder"], fx.SCAN_ID)
    vocab = Vocabulary.default()
    points, semantics = _map_of(labels, vocab)
    perfect = evaluate_scannet_panoptic(points, semantics, None, labels, ROOM_FROM_SCAN)
    assert perfect["panoptic"]["pq"] == pytest.approx(1.0) and perfect["panoptic"]["covered"] == pytest.approx(1.0)
    assert perfect["instances"]["precision"] == 1.0 and perfect["instances"]["recall"] == 1.0
    # Without the scan-to-map transform the labels land 0.4 m off: nothing matches.
    off = evaluate_scannet_panoptic(points, semantics, None, labels, np.eye(4))
    assert off["panoptic"]["covered"] < 0.2
    # The chair called a table: the chair is missed, the table gains a false positive.
    points, wrong = _map_of(labels, vocab, chair_as="table")
    result = evaluate_scannet_panoptic(points, wrong, None, labels, ROOM_FROM_SCAN)["panoptic"]
    assert result["by_class"]["chair"] == {"pq": 0.0, "sq": 0.0, "rq": 0.0, "tp": 0, "fp": 0, "fn": 1}
    assert result["by_class"]["table"]["fp"] == 1 and result["by_class"]["table"]["rq"] == pytest.approx(1 / 1.5)
    assert result["pq_stuff"] == pytest.approx(1.0)


def test_missing_annotation_files_are_named(tmp_path):
    (tmp_path / f"{fx.SCAN_ID}_vh_clean_2.labels.ply").write_bytes(b"")
    with pytest.raises(
        DataError, match=r"missing: scene0001_00_vh_clean_2.0.010000.segs.json, scene0001_00.aggregation"
    ):
        read_scan_labels(tmp_path, fx.SCAN_ID)


@pytest.mark.slow  # a whole benchmark or CLI run
def test_stratamap_bench_scannet_panoptic_on_exported_frames(scan, tmp_path):
    """Exported frames with the annotation files beside them, tilted off gravity: the mapped floor,
    walls and table match the annotated ones."""
    fx.write_scan(scan["folder"], scan["world"], "export")
    out = tmp_path / "bench"
    proc = subprocess.run(
        [
            sys.executable, "-m", "stratamap.core.cli", "bench", "configs/bench/scannet_panoptic.yaml",
            "--out", str(out),
            "--set", f"scenes[0].files={scan['root']}/frames/*",
            "--set", "scenes[0].source.params.stride=1",
            "--set", "scenes[0].variants=[geometric]",
        ],
        cwd=REPO, capture_output=True, text=True,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    record = json.loads((out / "records" / f"scannet-{fx.SCAN_ID}" / "geometric.json").read_text())
    panoptic = record["metrics"]["panoptic"]
    assert panoptic["covered"] > 0.95  # the labels found the map: the frames agree
    for name in ("floor", "wall", "table"):
        assert panoptic["by_class"][name]["pq"] > 0.9, (name, panoptic["by_class"])
    assert panoptic["pq_stuff"] > 0.9
