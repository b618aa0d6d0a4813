"""Pipeline validation: structure, plugin params and data flow, each error with its YAML path."""

from __future__ import annotations

import json

import pytest
import yaml
from typer.testing import CliRunner

from stratamap.core.cli import app
from stratamap.core.config import apply_override, load_document, parse_path, validate
from stratamap.core.errors import ConfigError

runner = CliRunner()

GOOD = {
    "source": {"plugin": "synthetic", "params": {"frames": 5}},
    "stages": [
        {"plugin": "oracle"},
        {"plugin": "tsdf", "params": {"voxel_size": 0.03}},
        {"plugin": "bbox"},
        {"plugin": "urdf"},
    ],
    "output": {"save_map": True},
}


def write(tmp_path, doc, name="pipe.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc))
    return path


def problems(doc):
    with pytest.raises(ConfigError) as exc:
        validate(doc)
    return exc.value.problems


def test_good_pipeline_validates():
    v = validate(GOOD)
    assert [s.spec.plugin for s in v.stages] == ["oracle", "tsdf", "bbox", "urdf"]
    assert v.stages[1].config.voxel_size == 0.03


def test_misspelt_plugin_param_names_its_yaml_path():
    doc = json.loads(json.dumps(GOOD))
    doc["stages"][1]["params"] = {"voxel_sise": 0.02}
    assert ("stages[1].params.voxel_sise", "extra field (not a parameter of this plugin)") in problems(doc)


def test_misspelt_structure_key_and_bad_value():
    doc = json.loads(json.dumps(GOOD))
    doc["stage"] = doc.pop("stages")
    assert any(p == "stage" and "extra" in m for p, m in problems(doc))
    doc = json.loads(json.dumps(GOOD))
    doc["stages"][1]["params"] = {"voxel_size": -1}
    assert any(p == "stages[1].params.voxel_size" for p, _ in problems(doc))
    doc = json.loads(json.dumps(GOOD))
    doc["source"]["params"] = {"scene": {"chiars": 3}}
    assert any(p == "source.params.scene.chiars" for p, _ in problems(doc))


def test_every_problem_is_reported_at_once():
    doc = json.loads(json.dumps(GOOD))
    doc["stages"][1]["params"] = {"voxel_sise": 0.02}
    doc["stages"][2]["params"] = {"min_point": 3}
    paths = [p for p, _ in problems(doc)]
    assert "stages[1].params.voxel_sise" in paths and "stages[2].params.min_point" in paths


def test_unknown_plugin_lists_installed_ones():
    doc = json.loads(json.dumps(GOOD))
    doc["stages"][1]["plugin"] = "tsfd"
    [(path, msg)] = problems(doc)
    assert path == "stages[1].plugin" and "tsfd" in msg and "tsdf" in msg


def test_completer_before_instances_names_missing_layer_and_providers():
    doc = json.loads(json.dumps(GOOD))
    doc["stages"] = [{"plugin": "bbox"}, {"plugin": "oracle"}, {"plugin": "tsdf"}]
    [(path, msg)] = problems(doc)
    assert path == "stages[0].plugin"
    assert "'instances'" in msg and "tsdf (mappers)" in msg and "reorder" in msg


def test_overrides_address_any_key():
    doc = json.loads(json.dumps(GOOD))
    apply_override(doc, "stages[1].params.voxel_size=0.05")
    apply_override(doc, "source.params.scene={seed: 3, chairs: 2}")
    apply_override(doc, "output.dir=out/x")
    apply_override(doc, "stages[4]={plugin: nav2_map}")
    assert doc["stages"][1]["params"]["voxel_size"] == 0.05
    assert doc["source"]["params"]["scene"] == {"seed": 3, "chairs": 2}
    assert doc["output"]["dir"] == "out/x" and doc["stages"][4]["plugin"] == "nav2_map"
    assert parse_path("a.b[2].c") == ["a", "b", 2, "c"]
    with pytest.raises(ConfigError, match="out of range"):
        apply_override(doc, "stages[9].params.x=1")


def test_load_document_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("source: [unclosed")
    with pytest.raises(ConfigError, match="bad.yaml"):
        load_document(bad)
    with pytest.raises(ConfigError, match="not found"):
        load_document(tmp_path / "missing.yaml")


def test_cli_validate_misspelt_key_exits_nonzero_with_path(tmp_path):
    doc = json.loads(json.dumps(GOOD))
    doc["stages"][1]["params"] = {"voxel_sise": 0.02}
    result = runner.invoke(app, ["validate", str(write(tmp_path, doc))])
    assert result.exit_code != 0
    assert "stages[1].params.voxel_sise" in result.output


def test_cli_run_without_an_output_folder_says_how_to_give_one(tmp_path):
    path = write(tmp_path, GOOD)
    result = runner.invoke(app, ["run", str(path)])
    assert result.exit_code != 0
    assert isinstance(result.exception, SystemExit), result.exception  # a message, not a traceback
    assert "output.dir" in result.output and "--out" in result.output and str(path) in result.output


def test_cli_validate_missing_layer_exits_nonzero(tmp_path):
    doc = json.loads(json.dumps(GOOD))
    doc["stages"] = [{"plugin": "bbox"}, {"plugin": "oracle"}, {"plugin": "tsdf"}]
    result = runner.invoke(app, ["validate", str(write(tmp_path, doc))])
    assert result.exit_code != 0 and "instances" in result.output


def test_cli_validate_with_set_override(tmp_path):
    path = write(tmp_path, GOOD)
    assert runner.invoke(app, ["validate", str(path)]).exit_code == 0
    result = runner.invoke(app, ["validate", str(path), "--set", "stages[1].params.voxel_sise=1"])
    assert result.exit_code != 0 and "stages[1].params.voxel_sise" in result.output


def test_shipped_configs_validate(repo, tmp_path):
    """Every shipped pipeline validates once its REQUIRED placeholders are set (and says which are
    not set when they are not)."""
    from stratamap.core.config import PLACEHOLDER, load_pipeline, placeholders
    from stratamap.core.documents import format_path
    from tests.conftest import SHARED_DATA

    for path in sorted((repo / "configs").glob("*.yaml")):
        if "shared/data" in path.read_text().split("source:")[-1] and not SHARED_DATA.exists():
            continue  # reads real data that this checkout does not have
        unset = [format_path(k) for k in placeholders(load_document(path), ())]
        if unset:
            with pytest.raises(ConfigError, match=PLACEHOLDER):
                load_pipeline(path)
        load_pipeline(path, [f"{key}={tmp_path}" for key in unset])


def test_cli_plugins_json_lists_all_kinds():
    result = runner.invoke(app, ["plugins", "--json"])
    assert result.exit_code == 0
    entries = json.loads(result.stdout)
    assert {e["kind"] for e in entries} == {"sources", "segmenters", "mappers", "completers", "exporters", "observers"}
    assert all({"kind", "name", "distribution", "description"} <= set(e) for e in entries)


def test_cli_schema_documents_plugin_params():
    result = runner.invoke(app, ["schema"])
    assert result.exit_code == 0
    schema = json.loads(result.stdout)
    stages = schema["properties"]["stages"]["items"]["oneOf"]
    tsdf = next(s for s in stages if s["properties"]["plugin"]["const"] == "tsdf")
    voxel = tsdf["properties"]["params"]["properties"]["voxel_size"]
    assert voxel["description"] and voxel["default"] == 0.02
