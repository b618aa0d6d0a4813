"""Conformance kit for stage plugins, in the style of scikit-learn's ``parametrize_with_checks``.

Run it on your stage in your own CI::

    from stratamap.core.testing import parametrize_with_checks
    from my_package import MyCompleter

    @parametrize_with_checks([MyCompleter])
    def test_conformance(stage_cls, check):
        check(stage_cls)

Each check asserts one property every stage must have: its config validates and documents
itself, it declares what it requires and provides, its verb accepts the declared layers and
returns the declared ones (of the right types), it leaves its inputs untouched, and it is
deterministic. Inputs come from a small synthetic scene run through stratamap's built-in stages.

A stage whose ``Config`` has required fields sets ``example_params`` on the class: a dict, or a
classmethod that prepares example inputs (for a file reader: writes a small dataset) and returns
the parameters.

Observers (``stratamap.core.hookspecs.Observer``) get the checks that apply to them: declarations,
a config that forbids unknown keys, documents itself and constructs.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import inspect
import re
from collections.abc import Callable, Iterable
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ValidationError

from stratamap.core.hookspecs import Observer
from stratamap.core.lazy import lazy_module
from stratamap.core.paths import scratch_dir
from stratamap.core.stages import KIND_BASES, KINDS, LAYERS, PipelineData, Stage

nx = lazy_module("networkx")
trimesh = lazy_module("trimesh")

Check = Callable[[type[Stage]], None]


# ------------------------------------------------------------------------------------------
# Fingerprints: a stable hash of any layer value, for determinism and immutability checks


def fingerprint(value: Any) -> str:
    h = hashlib.sha256()
    _feed(h, value, depth=0)
    return h.hexdigest()


def _feed(h: Any, value: Any, depth: int) -> None:
    if depth > 12:
        return
    if value is None or isinstance(value, (bool, int, float, str)):
        h.update(repr(value).encode())
    elif isinstance(value, np.ndarray):
        h.update(str(value.dtype).encode() + str(value.shape).encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, np.generic):
        h.update(repr(value.item()).encode())
    elif isinstance(value, trimesh.Trimesh):
        _feed(h, np.asarray(value.vertices), depth + 1)
        _feed(h, np.asarray(value.faces), depth + 1)
    elif isinstance(value, nx.Graph):
        _feed(h, nx.node_link_data(value, edges="links"), depth + 1)
    elif isinstance(value, dict):
        for k in sorted(value, key=repr):
            h.update(repr(k).encode())
            _feed(h, value[k], depth + 1)
    elif isinstance(value, (list, tuple)):
        h.update(f"[{len(value)}".encode())
        for v in value:
            _feed(h, v, depth + 1)
    elif dataclasses.is_dataclass(value):
        h.update(type(value).__name__.encode())
        for f in dataclasses.fields(value):
            if not f.name.startswith("_"):
                _feed(h, getattr(value, f.name), depth + 1)
    elif isinstance(value, BaseModel):
        _feed(h, value.model_dump(), depth + 1)
    elif hasattr(value, "__iter__"):
        _feed(h, list(value), depth + 1)
    else:
        h.update(type(value).__name__.encode())


# ------------------------------------------------------------------------------------------
# Example inputs


@lru_cache(maxsize=1)
def _reference_data() -> PipelineData:
    """A tiny synthetic scene run through the built-in stages: every layer filled."""
    from stratamap.core.registry import build_registry

    registry = build_registry(eps=[], extra_modules=[], autoload=True)
    stages = [
        (
            "sources",
            "synthetic",
            {
                "scene": {
                    "type": "room",
                    "seed": 1,
                    "objects": {"table": 1, "chair": 2, "box": 1},
                    "camera": {"width": 160, "height": 120},
                    "trajectory": {"type": "orbit", "frames": 10},
                    "lidar": {"enabled": True, "rings": 8, "points_per_ring": 128},
                }
            },
        ),
        ("segmenters", "oracle", {}),
        ("mappers", "tsdf", {"voxel_size": 0.04}),
        ("mappers", "occupancy", {}),
        ("completers", "bbox", {}),
        ("mappers", "contact_graph", {}),
    ]
    data = PipelineData()
    for kind, name, params in stages:
        stage = registry.get(kind, name).cls(**params)
        for layer, value in stage.run(data).items():  # type: ignore[union-attr]
            data.set(layer, value, stage.name)
    data.map.augmented = data.map.geometry
    return data


def example_data(layers: Iterable[str] | None = None) -> PipelineData:
    """A fresh copy of the reference data (optionally only the named layers and what they need)."""
    data = copy.deepcopy(_reference_data())
    data.warnings.clear()
    if layers is not None:
        keep = set(layers)
        for name in LAYERS:
            if name not in keep:
                _clear(data, name)
    return data


def _clear(data: PipelineData, layer: str) -> None:
    if layer == "frames":
        data.stream = None
    elif layer in ("frame_labels", "ground_truth"):
        setattr(data, layer, None)
    elif layer == "occupancy":
        data.map.occupancy.clear()
    else:
        setattr(data.map, layer, None)


def example_params(stage_cls: type[Stage]) -> dict[str, Any]:
    """``example_params`` of a stage: a dict, or a classmethod that prepares inputs (e.g. writes a
    small dataset) and returns the parameters that read them. Computed once per class."""
    if stage_cls not in _EXAMPLE_PARAMS:
        params = getattr(stage_cls, "example_params", {})
        _EXAMPLE_PARAMS[stage_cls] = dict(params() if callable(params) else params)
    return dict(_EXAMPLE_PARAMS[stage_cls])


_EXAMPLE_PARAMS: dict[type, dict[str, Any]] = {}


def make_stage(stage_cls: type[Stage]) -> Stage:
    return stage_cls(**example_params(stage_cls))


def run_stage(stage_cls: type[Stage], data: PipelineData | None = None) -> tuple[Any, PipelineData, Path | None]:
    """Run the stage's verb on example inputs; returns (result, data, export folder)."""
    if data is None:
        data = example_data(set(stage_cls.requires) | set(stage_cls.optional))
    stage = make_stage(stage_cls)
    out_dir = scratch_dir(f"stratamap-check-{stage_cls.name}-") if stage.kind == "exporters" else None
    return stage.run(data, out_dir), data, out_dir


# ------------------------------------------------------------------------------------------
# Checks


def check_declarations(stage_cls: type[Stage]) -> None:
    """name, kind, description and layer declarations are present and well-formed."""
    assert re.fullmatch(r"[a-z][a-z0-9_]*", stage_cls.name or ""), f"name {stage_cls.name!r} must be snake_case"
    assert stage_cls.kind in KINDS, f"kind {stage_cls.kind!r} must be one of {KINDS}"
    assert issubclass(stage_cls, KIND_BASES[stage_cls.kind]), (
        f"{stage_cls.__name__} must subclass {KIND_BASES[stage_cls.kind].__name__}"
    )
    assert stage_cls.summary(), f"{stage_cls.__name__} needs a docstring or a description"
    for attr in ("requires", "optional", "provides"):
        declared = set(getattr(stage_cls, attr))
        unknown = declared - set(LAYERS)
        assert not unknown, f"{attr} names unknown layers {sorted(unknown)}; layers are {sorted(LAYERS)}"
    assert not (set(stage_cls.requires) & set(stage_cls.optional)), "a layer cannot be both required and optional"
    if stage_cls.kind != "exporters":
        assert stage_cls.provides, "a stage other than an exporter must provide at least one layer"


def check_config_forbids_extra(stage_cls: type[Stage]) -> None:
    """The Config rejects unknown keys (a misspelt parameter must be an error, not ignored)."""
    assert stage_cls.Config.model_config.get("extra") == "forbid", "Config must set extra='forbid'"
    params = example_params(stage_cls)
    params["definitely_not_a_parameter"] = 1
    try:
        stage_cls.Config(**params)
    except ValidationError:
        return
    raise AssertionError("Config accepted an unknown key")


def check_config_documented(stage_cls: type[Stage]) -> None:
    """Every Config field has a description, so `stratamap schema` documents it."""
    missing = [name for name, f in stage_cls.Config.model_fields.items() if not f.description]
    assert not missing, f"Config fields without Field(description=...): {missing}"
    schema = stage_cls.Config.model_json_schema()
    assert schema.get("type") == "object"


def check_config_constructs(stage_cls: type[Stage]) -> None:
    """The stage builds from its defaults (plus ``example_params``) and keeps its config."""
    stage = make_stage(stage_cls)
    assert isinstance(stage.config, stage_cls.Config)
    again = stage_cls.Config.model_validate(stage.config.model_dump())
    assert again == stage.config, "Config does not round-trip through model_dump/model_validate"


@dataclasses.dataclass
class _Run:
    """One run of a stage's verb on example inputs, and the input layers it changed in place."""

    result: Any
    out_dir: Path | None
    inputs_changed: list[str]


#: The last stage class's first run (one entry: parametrize_with_checks runs a stage's checks in a row).
_FIRST_RUN: dict[type[Stage], _Run] = {}


def first_run(stage_cls: type[Stage]) -> _Run:
    """The stage's verb run on example inputs, once for the checks that read a run (the verb's
    contract, untouched inputs, and the first of the two runs the determinism check compares): a
    run is most of what the kit costs, and each of the three running its own doubled it."""
    if stage_cls not in _FIRST_RUN:
        data = example_data(set(stage_cls.requires) | set(stage_cls.optional))
        before = {layer: fingerprint(data.get(layer)) for layer in data.available()}
        result, _, out_dir = run_stage(stage_cls, data)
        changed = [layer for layer, fp in before.items() if fingerprint(data.get(layer)) != fp]
        _FIRST_RUN.clear()
        _FIRST_RUN[stage_cls] = _Run(result, out_dir, changed)
    return _FIRST_RUN[stage_cls]


def check_verb_contract(stage_cls: type[Stage]) -> None:
    """The verb accepts the declared inputs and returns only declared layers of the right types."""
    run = first_run(stage_cls)
    result, out_dir = run.result, run.out_dir
    if stage_cls.kind == "exporters":
        assert isinstance(result, list), "export() must return the list of written paths"
        assert result, "an exporter must write at least one file"
        for p in result:
            p = Path(p)
            assert p.exists(), f"export() returned {p}, which does not exist"
            assert out_dir is not None and out_dir in p.resolve().parents, f"{p} is outside the export folder {out_dir}"
        return
    assert isinstance(result, dict), f"{stage_cls.kind} verb must return a dict of layers"
    extra = set(result) - set(stage_cls.provides)
    assert not extra, f"returned layers {sorted(extra)} are not declared in provides"
    assert result, "returned no layer at all"
    for layer, value in result.items():
        assert value is None or isinstance(value, LAYERS[layer]), (
            f"layer {layer!r} is a {type(value).__name__}, expected {LAYERS[layer].__name__}"
        )


def check_inputs_untouched(stage_cls: type[Stage]) -> None:
    """The verb does not modify the layers it reads (stages return new values instead)."""
    changed = first_run(stage_cls).inputs_changed
    assert not changed, f"the verb modified its input layers {changed} in place"


def check_deterministic(stage_cls: type[Stage]) -> None:
    """Two runs on equal inputs give equal outputs."""
    first = first_run(stage_cls)
    r1, d1 = first.result, first.out_dir
    r2, _, d2 = run_stage(stage_cls)
    if stage_cls.kind == "exporters":
        f1 = {Path(p).relative_to(d1).as_posix(): Path(p).read_bytes() for p in r1 if Path(p).is_file()}
        f2 = {Path(p).relative_to(d2).as_posix(): Path(p).read_bytes() for p in r2 if Path(p).is_file()}
        assert f1.keys() == f2.keys(), "two runs wrote different files"
        diff = [k for k in f1 if f1[k] != f2[k]]
        assert not diff, f"two runs wrote different contents to {diff}"
        return
    assert fingerprint(r1) == fingerprint(r2), "two runs on equal inputs gave different outputs"


CHECKS: tuple[Check, ...] = (
    check_declarations,
    check_config_forbids_extra,
    check_config_documented,
    check_config_constructs,
    check_verb_contract,
    check_inputs_untouched,
    check_deterministic,
)


def check_observer_declarations(observer_cls: type[Observer]) -> None:
    """An observer has a snake_case name, the observers kind and a description."""
    assert re.fullmatch(r"[a-z][a-z0-9_]*", observer_cls.name or ""), f"name {observer_cls.name!r} must be snake_case"
    assert observer_cls.kind == "observers", f"kind {observer_cls.kind!r} must be 'observers'"
    assert observer_cls.summary(), f"{observer_cls.__name__} needs a docstring or a description"


OBSERVER_CHECKS: tuple[Check, ...] = (
    check_observer_declarations,
    check_config_forbids_extra,
    check_config_documented,
    check_config_constructs,
)


def all_checks(stage_cls: type[Stage] | type[Observer]) -> list[Check]:
    if inspect.isclass(stage_cls) and issubclass(stage_cls, Observer):
        return list(OBSERVER_CHECKS)
    return list(CHECKS)


def check_stage(stage_cls: type[Stage]) -> None:
    """Run every check on ``stage_cls``; raise AssertionError naming the first that fails."""
    for check in all_checks(stage_cls):
        try:
            check(stage_cls)
        except AssertionError as exc:
            raise AssertionError(f"{stage_cls.__name__} fails {check.__name__}: {exc}") from exc


def parametrize_with_checks(stage_classes: Iterable[type[Stage]]) -> Any:
    """A ``pytest.mark.parametrize`` over (stage class, check) pairs with readable ids."""
    import pytest

    classes = list(stage_classes)
    for cls in classes:
        if not (inspect.isclass(cls) and issubclass(cls, (Stage, Observer))):
            raise TypeError(f"{cls!r} is not a Stage or Observer class")
    params = [(cls, check) for cls in classes for check in all_checks(cls)]
    ids = [f"{cls.kind}.{cls.name}-{check.__name__}" for cls, check in params]
    return pytest.mark.parametrize("stage_cls, check", params, ids=ids)
