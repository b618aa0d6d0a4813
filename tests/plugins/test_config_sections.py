"""Nested config sections: tsdf's ``pieces``, the simulator exporters' ``bodies`` and the costmap and
ros2_bag exporters' ``inflation``; one name for one setting in every stage, and the flat names of
the release before still read, with a warning naming the old key and the new one."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import yaml

from stratamap.core.config import validate
from stratamap.core.errors import ConfigError
from stratamap.core.registry import default_registry
from stratamap.core.testing import example_data
from tests.conftest import REPO

SIMULATORS = ("urdf", "mjcf", "sdf", "usd")
NAVIGATION = ("costmap", "ros2_bag")


def pipeline(**params: dict) -> dict:
    """A pipeline whose stages are given by plugin name -> params, after a synthetic source."""
    stages = [{"plugin": "oracle"}, {"plugin": "tsdf", "params": params.pop("tsdf", {})}, {"plugin": "bbox"}]
    stages += [{"plugin": "occupancy"}] + [{"plugin": name, "params": p} for name, p in params.items()]
    return {"source": {"plugin": "synthetic", "params": {"frames": 3}}, "stages": stages}


def configs(doc: dict) -> dict:
    return {s.spec.plugin: s.config for s in validate(doc).stages}


def problems(doc: dict) -> list[tuple[str, str]]:
    with pytest.raises(ConfigError) as exc:
        validate(doc)
    return exc.value.problems


def stratamap(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "stratamap.core.cli", *args], cwd=REPO, capture_output=True, text=True)


def test_nested_sections_validate_into_their_settings():
    got = configs(
        pipeline(
            tsdf={"instances": "masks", "pieces": {"min_points": 40, "max_length": {"cup": 0.2}}},
            urdf={"bodies": {"movable_classes": ["chair"], "rest": False}},
            sdf={"bodies": {"density": {"table": 500.0}}},
            costmap={"inflation": {"inflation_radius": 0.8}},
        )
    )
    pieces = got["tsdf"].pieces
    assert (pieces.min_points, pieces.max_length, pieces.merge_ratio) == (40, {"cup": 0.2}, 0.5)
    bodies = got["urdf"].bodies
    assert (bodies.movable_classes, bodies.rest, bodies.structure) == (["chair"], False, True)
    assert got["sdf"].bodies.density == {"table": 500.0}
    inflation = got["costmap"].inflation
    assert (inflation.inscribed_radius, inflation.inflation_radius, inflation.cost_scaling_factor) == (0.2, 0.8, 10.0)


def test_commented_sections_in_a_file_validate(tmp_path):
    path = tmp_path / "pipe.yaml"
    path.write_text(
        "source: {plugin: synthetic, params: {frames: 3}}\n"
        "stages:\n"
        "  - plugin: oracle\n"
        "  - plugin: tsdf\n"
        "    params:\n"
        "      instances: masks\n"
        "      pieces:               # how the masks' 3D pieces are re-joined\n"
        "        min_points: 40      # smaller pieces join their neighbour\n"
        "        near_gap: 0.1       # m\n"
        "  - plugin: bbox\n"
        "  - plugin: urdf\n"
        "    params:\n"
        "      bodies:\n"
        "        movable_classes: [chair, cup]   # free bodies\n"
    )
    result = stratamap("validate", str(path))
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("ok ")


# (plugin, the flat params of the release before, the same settings in their section)
RENAMED = [
    (
        "tsdf",
        {"instances": "masks", "piece_min_points": 40, "piece_near_gap": 0.1},
        {"instances": "masks", "pieces": {"min_points": 40, "near_gap": 0.1}},
    ),
    ("urdf", {"movable_classes": ["chair"], "rest": False}, {"bodies": {"movable_classes": ["chair"], "rest": False}}),
    (
        "mjcf",
        {"free_classes": ["chair"], "density": {"chair": 300.0}},
        {"bodies": {"movable_classes": ["chair"], "density": {"chair": 300.0}}},
    ),
    (
        "sdf",
        {"dynamic_classes": ["chair"], "structure": False},
        {"bodies": {"movable_classes": ["chair"], "structure": False}},
    ),
    ("costmap", {"inscribed_radius": 0.3}, {"inflation": {"inscribed_radius": 0.3}}),
    (
        "ros2_bag",
        {"inflation_radius": 0.7, "cost_scaling_factor": 5.0},
        {"inflation": {"inflation_radius": 0.7, "cost_scaling_factor": 5.0}},
    ),
]


@pytest.mark.parametrize(("plugin", "old", "new"), RENAMED, ids=[r[0] for r in RENAMED])
def test_an_old_flat_key_is_read_into_its_section_and_the_run_warns(plugin, old, new, tmp_path):
    cls = default_registry().get("exporters" if plugin != "tsdf" else "mappers", plugin).cls
    from_old, from_new = cls.Config.model_validate(old), cls.Config.model_validate(new)
    assert from_old == from_new and from_old.model_dump() == from_new.model_dump()
    assert from_old != cls.Config()  # the settings took effect, they were not dropped

    def run(config):
        data = example_data(["frames", "frame_labels", "ground_truth"] if plugin == "tsdf" else None)
        out = tmp_path / str(len(list(tmp_path.iterdir())))
        result = cls(config).run(data, out)
        written = {p.relative_to(out).as_posix(): p.read_bytes() for p in result} if plugin != "tsdf" else None
        return data.warnings, written, result

    warned, written_old, result_old = run(from_old)
    quiet, written_new, result_new = run(from_new)
    assert quiet == []
    (line,) = warned
    assert "\n" not in line and line.startswith(f"{cls.kind}.{plugin}: deprecated key")
    (section,) = [key for key, value in new.items() if isinstance(value, dict)]
    for key in old.keys() - new.keys():
        field = "movable_classes" if key.endswith("_classes") else key.removeprefix("piece_")
        assert f"{key} is now {section}.{field}" in line, line
    # The same values under their new names: the same output.
    if plugin == "tsdf":
        assert len(result_old["instances"]) == len(result_new["instances"])
        for ids in ("class_ids", "instance_ids"):
            assert (getattr(result_old["semantics"], ids) == getattr(result_new["semantics"], ids)).all()
    elif plugin != "ros2_bag":  # a bag's sqlite file holds its own write time
        assert written_old == written_new


def test_old_flat_names_through_a_pipeline_file_say_their_section():
    # A bad value under an old name is reported at the key it is read into, which is the one to write.
    (problem,) = problems(pipeline(tsdf={"piece_min_points": 0}))
    assert problem[0] == "stages[1].params.pieces.min_points"
    got = configs(pipeline(mjcf={"free_classes": ["cup"]}, costmap={"cost_scaling_factor": 4.0}))
    assert got["mjcf"].bodies.movable_classes == ["cup"] and got["costmap"].inflation.cost_scaling_factor == 4.0


@pytest.mark.parametrize(
    ("params", "path"),
    [
        ({"tsdf": {"pieces": {"min_pointz": 3}}}, "stages[1].params.pieces.min_pointz"),
        ({"urdf": {"bodies": {"movable_classez": ["chair"]}}}, "stages[4].params.bodies.movable_classez"),
        ({"costmap": {"inflation": {"inflation_radiuz": 1.0}}}, "stages[4].params.inflation.inflation_radiuz"),
    ],
)
def test_an_unknown_key_inside_a_section_names_its_full_path(params, path, tmp_path):
    assert (path, "extra field (not a parameter of this plugin)") in problems(pipeline(**params))
    file = tmp_path / "pipe.yaml"
    file.write_text(yaml.safe_dump(pipeline(**params)))
    result = stratamap("validate", str(file))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    (line,) = [line for line in result.stderr.splitlines() if path in line]
    assert line.endswith(f"{path}: extra field (not a parameter of this plugin)"), result.stderr


def test_one_setting_under_its_old_and_its_new_name_is_an_error(tmp_path):
    doc = pipeline(sdf={"dynamic_classes": ["cup"], "bodies": {"movable_classes": ["chair"]}})
    (problem,) = problems(doc)
    assert problem[0] == "stages[4].params" and "dynamic_classes and bodies.movable_classes" in problem[1]
    file = tmp_path / "pipe.yaml"
    file.write_text(yaml.safe_dump(doc))
    result = stratamap("validate", str(file))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr


def _field_type(config: type, name: str) -> type:
    return config.model_fields[name].annotation


def test_movable_classes_have_one_name_in_every_simulator_exporter():
    registry = default_registry()
    simulators = [registry.get("exporters", name).cls.Config for name in SIMULATORS]
    bodies = {_field_type(config, "bodies") for config in simulators}
    assert len(bodies) == 1  # one section, one model
    (section,) = bodies
    assert {"movable_classes", "density", "rest", "structure"} <= set(section.model_fields)
    # No exporter keeps a setting of its own for what the section says.
    for info in registry.stages["exporters"].values():
        flat = set(info.cls.Config.model_fields)
        assert not flat & {"movable_classes", "free_classes", "dynamic_classes"}, (info.name, flat)
        if "bodies" not in flat:
            continue
        assert not flat & set(section.model_fields), (info.name, flat)


def test_inflation_is_one_section_of_the_costmap_and_the_bag():
    registry = default_registry()
    sections = {_field_type(registry.get("exporters", name).cls.Config, "inflation") for name in NAVIGATION}
    assert len(sections) == 1
    (section,) = sections
    assert set(section.model_fields) == {"inscribed_radius", "inflation_radius", "cost_scaling_factor"}
    for name in NAVIGATION:
        assert not set(registry.get("exporters", name).cls.Config.model_fields) & set(section.model_fields)


def test_every_section_field_is_described_in_the_schema():
    result = stratamap("schema")
    assert result.returncode == 0, result.stderr
    defs = json.loads(result.stdout)["$defs"]
    sections = {k: v for k, v in defs.items() if k.split(".")[-1] in ("Pieces", "Bodies", "Inflation")}
    assert {k.rsplit(".", 1)[0] for k in sections} == {
        "mappers.tsdf",
        *(f"exporters.{name}" for name in (*SIMULATORS, *NAVIGATION)),
    }
    for name, schema in sections.items():
        assert schema["additionalProperties"] is False, name
        assert all(field.get("description") for field in schema["properties"].values()), name
