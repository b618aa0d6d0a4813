"""Benchmark files: validation errors, the direction of better, and every shipped benchmark validating
(the runs themselves are in tests/integration/test_bench_runs.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from stratamap.core.errors import ConfigError
from stratamap.core.evaluation.bench import load_bench
from stratamap.core.evaluation.bench_report import lower_is_better
from tests.conftest import REPO


def tiny_bench(tmp_path: Path, seeds=(3,), frames: int = 12) -> Path:
    doc = {
        "name": "tiny",
        "scenes": [
            {
                "synthetic": {
                    "scene_file": str(REPO / "configs/scenes/office.yaml"),
                    "seeds": list(seeds),
                    "frames": frames,
                    "camera": {"width": 160, "height": 120},
                }
            }
        ],
        "pipeline": {
            "stages": [
                {"plugin": "oracle"},
                {"plugin": "tsdf", "params": {"voxel_size": 0.04}},
                {"plugin": "occupancy", "params": {"robot_height": 1.0}},
                {"plugin": "contact_graph"},
                {"plugin": "bbox"},
            ]
        },
        "variants": [{"name": "none", "drop": [4]}, {"name": "bbox"}],
    }
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_bench_file_errors_name_the_key(tmp_path):
    path = tiny_bench(tmp_path)
    doc = yaml.safe_load(path.read_text())
    doc["variants"][0]["sett"] = ["x=1"]
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match=r"variants\[0\]\.sett"):
        load_bench(path)
    doc["variants"][0].pop("sett")
    doc["variants"][1]["name"] = "none"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match="unique"):
        load_bench(path)


def test_direction_of_better():
    assert (
        lower_is_better("completion.chamfer_l1")
        and lower_is_better("graph.ged")
        and lower_is_better("navigation.colliding_multimap")
    )
    assert (
        not lower_is_better("detection.f1")
        and not lower_is_better("completion.fscore_5cm")
        and not lower_is_better("completion.scan2cad_accuracy")
    )


@pytest.mark.parametrize("name", sorted(p.name for p in (REPO / "configs" / "bench").glob("*.yaml")))
def test_shipped_benchmarks_validate_every_run(name):
    from stratamap.core.config import validate
    from stratamap.core.evaluation.bench import expand_scenes, variant_document

    spec, path = load_bench(REPO / "configs" / "bench" / name)
    scenes, _ = expand_scenes(spec, path)
    assert scenes
    for scene in scenes:
        for variant in spec.variants:
            if scene.get("variants") is None or variant.name in scene["variants"]:
                validate(variant_document(spec, variant, scene["source"]), origin=name)
