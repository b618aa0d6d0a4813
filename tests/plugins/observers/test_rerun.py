"""The rerun observer: a run recorded as an ``.rrd`` that rerun's own reader reads back with every
logged entity, deterministic content, written atomically, and a one-line hint without the SDK."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from stratamap.core.config import load_pipeline
from stratamap.core.errors import DataError, PluginError
from stratamap.core.map.layers import OccupancyGrid
from stratamap.core.pipeline import Pipeline
from stratamap.core.registry import build_registry
from stratamap.core.testing import parametrize_with_checks
from stratamap.plugins.observers.rerun import RerunObserver, occupancy_image
from tests.conftest import REPO

SYNTHETIC = {
    "plugin": "synthetic",
    "params": {
        "scene": {
            "type": "room",
            "seed": 1,
            "objects": {"table": 1, "chair": 1, "box": 1},
            "camera": {"width": 96, "height": 72},
            "trajectory": {"type": "orbit", "frames": 4},
            "lidar": {"enabled": True, "rings": 8, "points_per_ring": 64},
        }
    },
}
STAGES = [
    {"plugin": "oracle"},
    {"plugin": "tsdf", "params": {"voxel_size": 0.06}},
    {"plugin": "occupancy"},
    {"plugin": "bbox"},
    {"plugin": "contact_graph"},
]


def _write(tmp_path: Path, doc: dict[str, Any]) -> Path:
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _cloud_pipeline(tmp_path: Path, observer_params: dict[str, Any], cloud: str) -> Path:
    (tmp_path / "scan.xyz").write_text(cloud)
    doc = {
        "source": {"plugin": "pointcloud", "params": {"path": "scan.xyz", "gravity": "off"}},
        "output": {"metrics": False, "report": False},
        "observers": [{"name": "rerun", "params": observer_params}],
    }
    return _write(tmp_path, doc)


def _rows(path: Path) -> list[tuple[str, dict[str, Any]]]:
    """Every logged row as (entity path, {column: value}) in a stable order, read with rerun's own
    reader; row ids are left out (they are time-based), so equal content gives equal rows however
    the SDK cut the stream into chunks."""
    from rerun.chunk import RrdReader

    rows = []
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        columns = {name: batch.column(name).to_pylist() for name in batch.schema.names if "RowId" not in name}
        for i in range(batch.num_rows):
            rows.append((chunk.entity_path, {name: values[i] for name, values in columns.items()}))
    return sorted(rows, key=repr)


def _entity(rows: list[tuple[str, dict[str, Any]]], path: str, column: str) -> list[dict[str, Any]]:
    return [r for entity, r in rows if entity == path and r.get(column) is not None]


@parametrize_with_checks([RerunObserver])
def test_rerun_observer_conforms(stage_cls, check):
    check(stage_cls)


def test_occupancy_image_is_north_up_free_white_occupied_black():
    grid = OccupancyGrid(np.array([[0, 100], [-1, 50]], np.int8), resolution=0.1)
    image = occupancy_image(grid)
    assert image.dtype == np.uint8
    assert image.tolist() == [[205, 127], [254, 0]]  # first row is the grid's top (highest y)


def test_missing_sdk_is_a_one_line_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # what `import rerun` does when it is not installed
    with pytest.raises(PluginError, match=r"pip install 'stratamap\[viz\]'"):
        RerunObserver()


def test_cli_without_sdk_exits_2_before_writing(tmp_path):
    path = _cloud_pipeline(tmp_path, {}, "0 0 0\n1 0 0\n0 1 0\n")
    code = (
        "import sys; sys.modules['rerun'] = None; from stratamap.core.cli import main; "
        f"sys.argv = ['stratamap', 'run', {str(path)!r}, '--out', {str(tmp_path / 'out')!r}]; main()"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "pip install 'stratamap[viz]'" in result.stderr
    assert not (tmp_path / "out").exists()


def test_point_cloud_run_is_recorded(tmp_path):
    cloud = "".join(f"{x} {y} {z}\n" for x, y, z in np.random.default_rng(0).random((50, 3)).round(4))
    path = _cloud_pipeline(tmp_path, {"path": "rec/run.rrd"}, cloud)
    registry = build_registry(eps=[], extra_modules=[])
    Pipeline(load_pipeline(path, registry=registry), registry).run(tmp_path / "out")
    rows = _rows(tmp_path / "out" / "rec" / "run.rrd")  # a relative path lands inside the run's output
    (points,) = _entity(rows, "/world/input/points", "Points3D:positions")
    assert len(points["Points3D:positions"]) == 50


def test_failed_run_leaves_no_recording_outside_the_output(tmp_path):
    target = tmp_path / "elsewhere" / "run.rrd"
    path = _cloud_pipeline(tmp_path, {"path": str(target)}, "not a point cloud\n")
    registry = build_registry(eps=[], extra_modules=[])
    with pytest.raises(DataError):
        Pipeline(load_pipeline(path, registry=registry), registry).run(tmp_path / "out")
    assert not target.exists() and not list(target.parent.glob("*"))  # no partial file, no temporary left


@pytest.mark.slow
def test_recording_reads_back_with_every_entity_and_equal_content(tmp_path):
    doc = {"source": SYNTHETIC, "stages": STAGES, "output": {"metrics": False}, "observers": [{"name": "rerun"}]}
    path = _write(tmp_path, doc)
    registry = build_registry(eps=[], extra_modules=[])
    pipeline = Pipeline(load_pipeline(path, registry=registry), registry)
    pipeline.run(tmp_path / "a")
    data = pipeline.data
    rows = _rows(tmp_path / "a" / "recording.rrd")
    entities = {entity for entity, _ in rows}

    frames = len(data.stream)
    assert len(_entity(rows, "/world/camera", "Transform3D:translation")) == frames
    for image in ("rgb", "depth", "classes", "instances"):
        assert len([r for r in _entity(rows, f"/world/camera/{image}", "frame")]) == frames, image
    assert _entity(rows, "/world/camera", "Pinhole:image_from_camera")

    # the map as the last stage left it: every point by class and by instance, every object boxed
    last = max(r["stage"] for _, r in rows if r.get("stage") is not None)
    (classes,) = [r for r in _entity(rows, "/world/map/points/classes", "Points3D:class_ids") if r["stage"] <= last][
        -1:
    ]
    assert len(classes["Points3D:positions"]) == len(data.map.geometry)
    assert classes["Points3D:class_ids"] == data.map.semantics.class_ids.tolist()
    assert _entity(rows, "/world/map/points/instances", "Points3D:colors")
    boxes = [r for r in _entity(rows, "/world/objects/boxes", "Boxes3D:labels") if r["stage"] == last]
    assert boxes[0]["Boxes3D:labels"] == [f"{o.class_name} {o.id}" for o in data.map.instances]
    completed = {f"/world/objects/completions/{o.id}" for o in data.map.instances.completed()}
    assert completed and completed <= entities
    assert {f"/occupancy/{name}" for name in data.map.occupancy} <= entities
    assert "/world/objects/support" in entities

    Pipeline(load_pipeline(path, registry=registry), registry).run(tmp_path / "b")
    assert _rows(tmp_path / "b" / "recording.rrd") == rows  # a fixed input records the same content
