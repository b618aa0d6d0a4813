"""The scaling benchmark: scene sizes on one library, the library sweep on one room; its table and figure."""

from __future__ import annotations

from stratamap.core.evaluation.bench import expand_scenes, load_bench
from stratamap.core.evaluation.bench_report import area_figure, scale_rows, scale_table
from tests.conftest import REPO


def test_scaling_runs_sizes_on_one_library_and_libraries_on_one_room():
    spec, path = load_bench(REPO / "configs" / "bench" / "scaling.yaml")
    scenes, skipped = expand_scenes(spec, path)
    assert not skipped
    runs = {
        s["name"]: [v.name for v in spec.variants if s["variants"] is None or v.name in s["variants"]] for s in scenes
    }
    assert runs == {
        "rooms-1-s0": ["library-23", "library-92", "library-368", "library-1012"],
        "rooms-4-s0": ["library-92"],
        "rooms-16-s0": ["library-92"],
    }
    for scene in scenes:  # every size walks a tour and measures its coverage
        params = scene["source"]["params"]["scene"]
        assert params["trajectory"]["type"] == "tour" and params["ground_truth"]["coverage"] is True


def _record(scene: str, area: float, frames: int, seconds: float, peak: float, found: int, objects: int) -> dict:
    return {
        "scene": scene,
        "variant": "library-92",
        "seconds_total": seconds,
        "cpu_seconds_total": 2 * seconds,
        "peak_memory_mb": peak,
        "memory_by_stage": {"stages[1]:tsdf": peak - 100, "source:synthetic": 300.0},
        "scale": {
            "frames": frames,
            "objects": objects,
            "area_m2": area,
            "coverage": {"mean": 0.6, "objects_seen": objects},
        },
        "metrics": {"detection": {"recall": found / objects, "true_positives": found}},
    }


def test_scale_table_and_figure_by_floor_area(tmp_path):
    records = [
        _record("rooms-4-s0", 143.0, 480, 144.0, 2000.0, 79, 80),
        _record("rooms-1-s0", 35.75, 120, 60.0, 1500.0, 20, 20),
        {"scene": "other", "variant": "library-92", "metrics": {}},  # no size: left out
        {**_record("rooms-1-s0", 35.75, 120, 70.0, 1600.0, 20, 20), "variant": "library-1012"},  # one size only
    ]
    rows = scale_rows(records)
    assert [r["scene"] for r in rows] == ["rooms-1-s0", "rooms-4-s0"]
    assert rows[0]["seconds_per_frame"] == 0.5 and rows[1]["seconds_per_frame"] == 0.3
    assert rows[1]["cpu_seconds_per_frame"] == 0.6
    assert rows[1]["map_peak_mb"] == 1900.0 and rows[1]["recall"] == 79 / 80
    table = scale_table(records)
    assert table is not None
    assert table.rows[1][-1] == "0.988 (79 / 80)" and table.rows[1][7:9] == ["0.300", "0.600"]
    assert (area_figure(records, tmp_path)).is_file()
    # One size only: nothing to plot against.
    assert scale_table(records[:1]) is None and area_figure(records[:1], tmp_path / "none") is None
    assert scale_table(records[1:]) is None
