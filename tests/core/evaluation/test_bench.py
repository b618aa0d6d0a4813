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
    scenes, skipped = expand_scenes(spec, path)
    # Every scene either runs or is skipped for real data that is absent (a clone without ../shared).
    assert len(scenes) + len(skipped) >= len(spec.scenes)
    if not scenes:
        pytest.skip(f"{name}: every scene needs real data that is absent: {skipped}")
    for scene in scenes:
        for variant in spec.variants:
            if scene.get("variants") is None or variant.name in scene["variants"]:
                validate(variant_document(spec, variant, scene["source"]), origin=name)


def test_first_report_links_its_figures_and_skips_undefined_metrics(tmp_path):
    from stratamap.core.evaluation.bench_report import write_reports

    spec, _ = load_bench(tiny_bench(tmp_path))

    def record(scene: str, variant: str, pq_stuff: float | None) -> dict:
        return {
            "scene": scene,
            "variant": variant,
            "seconds_total": 1.0,
            "peak_memory_mb": 100.0,
            "metrics": {"panoptic": {"pq": 0.6, "pq_things": 0.5, "pq_stuff": pq_stuff}},
            "details": {"pq_by_class": {"chair": 0.5, **({} if pq_stuff is None else {"floor": pq_stuff})}},
        }

    # Scene a has no stuff segment, true or predicted: its pq_stuff is undefined (None), not 0.
    records = [record("a", "none", None), record("b", "none", 0.8), record("a", "bbox", None), record("b", "bbox", 0.8)]
    out = tmp_path / "out"
    out.mkdir()
    written = write_reports({"name": "tiny", "records": records, "skipped": []}, spec, out)
    figures = sorted(p.name for p in out.glob("*.png"))
    assert figures and {out / name for name in figures} <= set(written)
    md = (out / "results.md").read_text()
    assert "## Figures" in md and all(f"![{name}]({name})" in md for name in figures)
    # The mean over scenes is over the scenes where pq_stuff is defined: 0.8, not (0 + 0.8) / 2.
    assert "| pq_stuff | 0.8 ± 0 | 0.8 ± 0 |" in md
    csv_rows = (out / "results.csv").read_text().splitlines()
    header = csv_rows[0].split(",")
    assert [row.split(",")[header.index("panoptic.pq_stuff")] for row in csv_rows[1:]] == ["", "0.8", "", "0.8"]


def test_the_report_says_what_each_variant_called_the_true_objects(tmp_path):
    """Summed over scenes, per true class: the variant's names for the objects it found (its own class
    first), the objects it missed, and its predictions that matched no object."""
    from stratamap.core.evaluation.bench_report import write_reports

    spec, _ = load_bench(tiny_bench(tmp_path))

    def record(scene: str, variant: str, called: dict, extra: dict) -> dict:
        return {
            "scene": scene,
            "variant": variant,
            "seconds_total": 1.0,
            "peak_memory_mb": 100.0,
            "metrics": {"detection": {"f1_iou25": 0.5}},
            "details": {"labels_iou25": {"called": called, "extra": extra}},
        }

    records = [
        record("a", "none", {"cabinet": {"counter": 1, "cabinet": 1}, "cup": {"(missed)": 2}}, {"object": 1}),
        record("b", "none", {"cabinet": {"counter": 2}}, {"object": 2, "box": 1}),
        record("a", "bbox", {"cabinet": {"cabinet": 2}, "cup": {"cup": 2}}, {}),
    ]
    out = tmp_path / "out"
    out.mkdir()
    write_reports({"name": "tiny", "records": records, "skipped": []}, spec, out)
    md = (out / "results.md").read_text()
    assert "## detection: what the true objects were called" in md
    assert "| cabinet | cabinet 1, counter 3 | cabinet 2 |" in md
    assert "| cup | (missed) 2 | cup 2 |" in md
    assert "| *no true object* | object 3, box 1 | – |" in md
