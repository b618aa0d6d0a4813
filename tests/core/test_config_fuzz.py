"""The config reader fuzzed: whatever bytes a pipeline file holds, whatever YAML and ``--set``
overrides, loading it gives a validated pipeline or a ConfigError whose every line names the file
(and exits 2 in the CLI), never another exception."""

from __future__ import annotations

import string

import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from stratamap.core.config import load_pipeline
from stratamap.core.errors import StratamapError
from stratamap.core.registry import default_registry

FUZZ = settings(
    max_examples=120, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

PLUGINS = sorted({info.name for info in default_registry().all()}) + ["nonexistent"]
#: Every parameter name of every installed plugin: random values then reach each plugin's own validation.
FIELDS = sorted({name for info in default_registry().all() for name in info.cls.Config.model_fields})
KEYS = ["source", "stages", "output", "observers", "plugin", "kind", "params", "name", "dir", "path", "frames"]

scalars = (
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=30)
    | st.sampled_from(PLUGINS + ["REQUIRED", "~nobody/x", "a\0b", "x" * 5000, "../" * 20, "/", "."])
)
keys = st.sampled_from(KEYS) | st.text(max_size=12) | st.integers(-3, 3)
values = st.recursive(
    scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(keys, inner, max_size=5),
    max_leaves=25,
)
stage = st.fixed_dictionaries(
    {"plugin": st.sampled_from(PLUGINS)},
    optional={
        "params": st.dictionaries(
            st.sampled_from(FIELDS) | st.text(string.ascii_lowercase + "_", max_size=20), values, max_size=4
        )
    },
)
pipelines = st.fixed_dictionaries(
    {"source": stage | values},
    optional={"stages": st.lists(stage, max_size=5) | values, "output": values, "observers": values},
)


def _check(path, overrides=None) -> None:
    """Loading ``path`` validates or raises a StratamapError of lines that name the file (one per
    problem; a ``--set`` override's problem names its key instead)."""
    try:
        load_pipeline(path, overrides)
    except StratamapError as exc:
        lines = str(exc).splitlines()
        assert lines and all(line.strip() for line in lines), str(exc)
        if not overrides:
            assert all(line.startswith(f"{path}: ") for line in lines), str(exc)


@FUZZ
@given(data=st.binary(max_size=400))
def test_random_bytes(tmp_path, data):
    path = tmp_path / "p.yaml"
    path.write_bytes(data)
    _check(path)


@FUZZ
@given(
    text=st.text(
        alphabet=st.sampled_from(list(":-[]{},&*!|>'\"#%@` \n\t?") + list("abcsourcestagesplugin012")), max_size=200
    )
)
def test_random_yaml_text(tmp_path, text):
    path = tmp_path / "p.yaml"
    path.write_text(text, encoding="utf-8")
    _check(path)


@FUZZ
@given(doc=pipelines)
def test_random_pipeline_documents(tmp_path, doc):
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(doc, allow_unicode=True), encoding="utf-8")
    _check(path)


@FUZZ
@example(overrides=["source.params.path=a\0b"])
@example(overrides=["source.params.path=" + "x" * 5000])
@given(
    overrides=st.lists(
        st.text(alphabet=st.sampled_from(list("stages[0]params.voxel_size=source.plugin:{}[] 12x\0")), max_size=40),
        max_size=3,
    )
)
def test_random_overrides(tmp_path, overrides):
    path = tmp_path / "p.yaml"
    (tmp_path / "scan.xyz").write_text("0 0 0\n1 0 0\n0 1 0\n")
    path.write_text(
        "source: {plugin: pointcloud, params: {path: scan.xyz}}\nstages: [{plugin: points}, {plugin: tsdf}]\n"
    )
    _check(path, overrides)


def _document_keys() -> list[str]:
    from stratamap.core.evaluation.bench import BenchSpec
    from stratamap.core.synthetic import SceneSpec

    return sorted({*SceneSpec.model_fields, *BenchSpec.model_fields})


documents = st.dictionaries(st.sampled_from(_document_keys()) | keys, values, max_size=6)


@FUZZ
@given(data=st.binary(max_size=300) | documents.map(lambda d: yaml.safe_dump(d, allow_unicode=True).encode()))
def test_random_scene_specs_and_benchmark_files(tmp_path, data):
    """The other documents users write go through the same reader: a scene spec (`stratamap synth`)
    and a benchmark file (`stratamap bench`)."""
    from stratamap.core.evaluation.bench import load_bench
    from stratamap.core.synthetic import SceneSpec

    path = tmp_path / "doc.yaml"
    path.write_bytes(data)
    for load in (SceneSpec.from_yaml, load_bench):
        try:
            load(path)
        except StratamapError as exc:
            lines = str(exc).splitlines()
            assert lines and all(line.startswith(f"{path}: ") for line in lines), str(exc)
