"""report.json gives each stage's memory: resident memory at its start, its peak while it ran, and ru_maxrss after."""

from __future__ import annotations

import json

from stratamap.core.config import validate
from stratamap.core.pipeline import Pipeline


def test_report_gives_peak_memory_per_stage(tmp_path):
    doc = {
        "source": {
            "plugin": "synthetic",
            "params": {"scene": {"camera": {"width": 64, "height": 48}, "trajectory": {"frames": 6}}},
        },
        "stages": [
            {"plugin": "oracle"},
            {"plugin": "tsdf", "params": {"voxel_size": 0.05, "extract_mesh": False}},
        ],
        "output": {"save_map": False, "metrics": False},
    }
    report = Pipeline(validate(doc, origin="memory-test")).run(tmp_path / "out")
    assert json.loads((tmp_path / "out" / "report.json").read_text())["stages"] == report["stages"]
    assert [s["plugin"] for s in report["stages"]] == ["synthetic", "oracle", "tsdf"]
    for stage in report["stages"]:
        memory = stage["memory"]
        assert 0 < memory["start_mb"] <= memory["peak_mb"] <= memory["maxrss_after_mb"] + 1
    assert report["peak_memory_mb"] >= max(s["memory"]["peak_mb"] for s in report["stages"]) - 1
