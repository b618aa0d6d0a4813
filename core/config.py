"""Pipeline files: YAML structure, ``--set`` overrides, and validation before anything runs.

A pipeline file has three top-level keys, and an optional fourth::

    source: {plugin: synthetic, params: {frames: 40}}
    stages:
      - {plugin: oracle}
      - {plugin: tsdf, params: {voxel_size: 0.02}}
    output: {save_map: true}
    observers: [{name: rerun, params: {path: run.rrd}}]   # follow the run (``--observe NAME`` adds one)

Validation has three phases, each reporting every problem with its YAML path:

1. structure (this module's pydantic models);
2. each plugin's (and observer's) own ``Config`` (``stages[1].params.voxel_sise: extra field``);
3. data flow: every layer a stage requires is provided by the source or an earlier stage.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from stratamap.core.documents import format_path, read_mapping, validation_problems
from stratamap.core.errors import ConfigError
from stratamap.core.hookspecs import Observer, ObserverConfig
from stratamap.core.registry import OBSERVERS, PluginInfo, Registry, default_registry
from stratamap.core.stages import KINDS, Stage, StageConfig, layers_after, missing_layers, originates


class StageSpec(BaseModel):
    """One stage of a pipeline: a plugin by name, and its parameters."""

    model_config = ConfigDict(extra="forbid")

    plugin: str = Field(description="Name of the stage plugin (see `stratamap plugins`).")
    kind: str | None = Field(
        default=None,
        description=(
            "Stage kind (segmenters, mappers, completers, exporters); needed only when two kinds share the name."
        ),
    )
    params: dict[str, Any] = Field(default_factory=dict, description="Parameters of the plugin's Config.")


class OutputSpec(BaseModel):
    """Where and what a run writes."""

    model_config = ConfigDict(extra="forbid")

    dir: str | None = Field(default=None, description="Output folder; `--out` on the command line overrides it.")
    save_map: bool = Field(default=True, description="Save the layered map to OUT/map/ (manifest.json + layers).")
    export_dir: str = Field(default="export", description="Sub-folder of the output folder that exporters write into.")
    report: bool = Field(
        default=True, description="Write OUT/report.json with stage timings, layer counts and metrics."
    )
    metrics: bool = Field(default=True, description="Evaluate the map against ground truth when the source has it.")


class ObserverSpec(BaseModel):
    """An observer of a run: a plugin by name, and its parameters."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(description="Name of the observer plugin (see `stratamap plugins`).")
    params: dict[str, Any] = Field(default_factory=dict, description="Parameters of the observer's Config.")


class PipelineSpec(BaseModel):
    """A pipeline file."""

    model_config = ConfigDict(extra="forbid")

    source: StageSpec = Field(description="The source stage that reads sensor data.")
    stages: list[StageSpec] = Field(default_factory=list, description="Stages run in order after the source.")
    output: OutputSpec = Field(default_factory=OutputSpec, description="Output settings.")
    observers: list[ObserverSpec] = Field(
        default_factory=list,
        description="Observers that follow the run through its events (e.g. rerun: a recording of it).",
    )


@dataclass
class ResolvedStage:
    """A validated stage: its spec, YAML path, registered class and parsed config."""

    path: str  # "source" or "stages[2]"
    spec: StageSpec
    info: PluginInfo
    config: StageConfig

    def instantiate(self) -> Stage:
        return self.info.cls(self.config)


@dataclass
class ResolvedObserver:
    """A validated observer: its spec, YAML path, registered class and parsed config."""

    path: str  # "observers[0]"
    spec: ObserverSpec
    info: PluginInfo
    config: ObserverConfig

    def instantiate(self) -> Observer:
        return self.info.cls(self.config)


@dataclass
class ValidatedPipeline:
    spec: PipelineSpec
    source: ResolvedStage
    stages: list[ResolvedStage]
    origin: str | None = None  # file the pipeline came from
    observers: list[ResolvedObserver] = field(default_factory=list)


# ------------------------------------------------------------------------------------------
# YAML paths and overrides

_TOKEN = re.compile(r"([^.\[\]]+)|\[(\d+)\]")


def parse_path(path: str) -> list[str | int]:
    """``stages[0].params.voxel_size`` -> ``["stages", 0, "params", "voxel_size"]``."""
    parts: list[str | int] = []
    pos = 0
    path = path.strip()
    while pos < len(path):
        if path[pos] == ".":
            pos += 1
            continue
        m = _TOKEN.match(path, pos)
        if not m:
            raise ConfigError([(path, f"cannot parse key path at {path[pos:]!r}")])
        parts.append(m.group(1) if m.group(1) is not None else int(m.group(2)))
        pos = m.end()
    if not parts:
        raise ConfigError([(path, "empty key path")])
    return parts


def apply_override(doc: dict[str, Any], assignment: str) -> None:
    """Apply ``path=value`` (value parsed as YAML) to a loaded pipeline document in place."""
    if "=" not in assignment:
        raise ConfigError([(assignment, "override must look like key.path=value")])
    key, raw = assignment.split("=", 1)
    parts = parse_path(key)
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError as exc:
        raise ConfigError([(key, f"value {raw!r} is not valid YAML ({exc})")]) from exc
    node: Any = doc
    for i, part in enumerate(parts[:-1]):
        nxt = parts[i + 1]
        here = format_path(parts[: i + 1])
        if isinstance(part, int):
            if not isinstance(node, list) or part >= len(node):
                size = len(node) if isinstance(node, list) else 0
                raise ConfigError([(here, f"index {part} out of range (the list has {size} items)")])
            node = node[part]
        else:
            if not isinstance(node, dict):
                raise ConfigError([(here, "cannot set a key inside a non-mapping value")])
            if node.get(part) is None:
                node[part] = [] if isinstance(nxt, int) else {}
            node = node[part]
    last = parts[-1]
    if isinstance(last, int):
        if not isinstance(node, list) or last > len(node):
            raise ConfigError([(key, "index out of range")])
        if last == len(node):
            node.append(value)
        else:
            node[last] = value
    else:
        if not isinstance(node, dict):
            raise ConfigError([(key, "cannot set a key inside a non-mapping value")])
        node[last] = value


def add_observers(doc: dict[str, Any], names: list[str]) -> None:
    """Append ``{name: NAME}`` to the document's ``observers`` for each name it does not list yet
    (``stratamap run --observe NAME``); its parameters may then be set with ``--set``."""
    if not names:
        return
    listed = doc.get("observers")
    if listed is None:
        listed = doc["observers"] = []
    if not isinstance(listed, list):
        raise ConfigError([("observers", "must be a list of {name: ..., params: {...}}")])
    present = {entry.get("name") for entry in listed if isinstance(entry, dict)}
    for name in names:
        if name not in present:
            listed.append({"name": name})
            present.add(name)


def load_document(
    path: str | Path, overrides: list[str] | None = None, observe: list[str] | None = None
) -> dict[str, Any]:
    """A pipeline file as a mapping, with the ``observe`` names added to its observers and then
    the ``overrides`` applied (so ``--set observers[0].params...`` reaches an added observer)."""
    doc = read_mapping(path, "pipeline file")
    add_observers(doc, observe or [])
    for assignment in overrides or []:
        apply_override(doc, assignment)
    return doc


# ------------------------------------------------------------------------------------------
# Validation


def _resolve_plugin(
    registry: Registry, spec: StageSpec, path: str, kinds: tuple[str, ...]
) -> tuple[PluginInfo | None, list[tuple[str, str]]]:
    if spec.kind is not None:
        if spec.kind not in kinds:
            return None, [(f"{path}.kind", f"must be one of {list(kinds)}")]
        kinds = (spec.kind,)
    matches = registry.find(spec.plugin, kinds)
    if not matches:
        known = sorted({n for k in kinds for n in registry.stages[k]})
        hint = ""
        broken = [f for f in registry.failures if f.entry_point == spec.plugin]
        if broken:
            hint = f"; {broken[0]}"
        return None, [(f"{path}.plugin", f"no plugin named {spec.plugin!r} (installed: {', '.join(known)}){hint}")]
    if len(matches) > 1:
        return None, [
            (
                f"{path}.plugin",
                f"{spec.plugin!r} is a plugin of several kinds ({', '.join(m.kind for m in matches)}); add `kind:`",
            )
        ]
    return matches[0], []


#: What shipped pipeline files hold where the user must fill in a value (``--set KEY=VALUE``).
PLACEHOLDER = "REQUIRED"


def placeholders(value: Any, parts: tuple[Any, ...]) -> list[tuple[Any, ...]]:
    """Key paths under ``value`` still holding :data:`PLACEHOLDER`."""
    if isinstance(value, str):
        return [parts] if value.strip() == PLACEHOLDER else []
    if isinstance(value, dict):
        return [p for k, v in value.items() for p in placeholders(v, (*parts, k))]
    if isinstance(value, list):
        return [p for i, v in enumerate(value) for p in placeholders(v, (*parts, i))]
    return []


def _expanded(value: str) -> Path:
    """``value`` with ``~`` expanded; as written when it names no known user (``~nobody/x``)."""
    try:
        return Path(value).expanduser()
    except RuntimeError:
        return Path(value)


def _missing_input(value: str) -> str | None:
    """Why the input file or folder ``value`` cannot be read, or None when it exists."""
    if "\0" in value:
        return "not a valid path (it holds a NUL character)"
    try:
        if _expanded(value).exists():
            return None
    except OSError as exc:  # a name too long for the file system, say
        return f"{value[:200]!r}: not a valid path ({exc.strerror or exc})"
    return f"{value if value.isprintable() else repr(value)} does not exist"


def _resolve_paths(config: StageConfig, base_dir: Path, key: str, overridden: set[str]) -> StageConfig:
    """``config`` with its relative paths (``Config.path_fields``) taken from ``base_dir``; values
    set on the command line (``overridden``) stay relative to the working folder."""
    updates = {}
    for name in type(config).path_fields:
        value = getattr(config, name, None)
        if not isinstance(value, str) or not value or value.startswith("<") or f"{key}.{name}" in overridden:
            continue
        expanded = _expanded(value)
        if not expanded.is_absolute():
            updates[name] = os.path.normpath(base_dir.absolute() / expanded)
    return config.model_copy(update=updates) if updates else config


def validate(
    doc: dict[str, Any],
    registry: Registry | None = None,
    origin: str | None = None,
    base_dir: Path | None = None,
    overridden: set[str] | None = None,
) -> ValidatedPipeline:
    """Validate a loaded pipeline document; raise :class:`ConfigError` listing every problem.

    ``base_dir``: the folder relative paths in stage parameters are resolved against (the
    pipeline file's); ``overridden``: keys set on the command line, which stay as given."""
    registry = registry or default_registry()
    try:
        spec = PipelineSpec.model_validate(doc)
    except ValidationError as exc:
        raise ConfigError(validation_problems(exc), source=origin) from None

    problems: list[tuple[str, str]] = []
    resolved: list[ResolvedStage] = []
    entries = [("source", spec.source, ("sources",))] + [
        (f"stages[{i}]", s, tuple(k for k in KINDS if k != "sources")) for i, s in enumerate(spec.stages)
    ]
    for path, stage_spec, kinds in entries:
        info, errs = _resolve_plugin(registry, stage_spec, path, kinds)
        problems += errs
        unset = placeholders(stage_spec.params, (*parse_path(path), "params"))
        problems += [
            (format_path(k), f"still the placeholder {PLACEHOLDER}: set it, e.g. --set {format_path(k)}=VALUE")
            for k in unset
        ]
        if info is None or unset:
            continue
        try:
            config = info.cls.Config.model_validate(stage_spec.params)
        except ValidationError as exc:
            problems += validation_problems(exc, prefix=(*parse_path(path), "params"))
            continue
        if base_dir is not None:
            config = _resolve_paths(config, base_dir, f"{path}.params", overridden or set())
            if path == "source":  # what a source reads must exist before anything runs
                for name in type(config).path_fields:
                    value = getattr(config, name, None)
                    problem = _missing_input(value) if isinstance(value, str) and value else None
                    if problem is not None:
                        problems.append((f"source.params.{name}", problem))
        resolved.append(ResolvedStage(path, stage_spec, info, config))
    observers, observer_problems = _resolve_observers(registry, spec)
    problems += observer_problems
    if problems:
        raise ConfigError(problems, source=origin)

    source, stages = resolved[0], resolved[1:]
    problems += check_data_flow(source, stages, registry)
    if problems:
        raise ConfigError(problems, source=origin)
    return ValidatedPipeline(spec, source, stages, origin, observers)


def _resolve_observers(registry: Registry, spec: PipelineSpec) -> tuple[list[ResolvedObserver], list[tuple[str, str]]]:
    """Each observer's registered class and parsed config, or what is wrong with it. Relative
    paths in observer parameters stay relative: observers write them inside the run's output."""
    resolved: list[ResolvedObserver] = []
    problems: list[tuple[str, str]] = []
    for i, observer_spec in enumerate(spec.observers):
        path = f"observers[{i}]"
        info = registry.stages[OBSERVERS].get(observer_spec.name)
        if info is None:
            known = ", ".join(sorted(registry.stages[OBSERVERS])) or "none"
            broken = [f for f in registry.failures if f.entry_point == observer_spec.name]
            hint = f"; {broken[0]}" if broken else ""
            problems.append((f"{path}.name", f"no observer named {observer_spec.name!r} (installed: {known}){hint}"))
            continue
        try:
            config = info.cls.Config.model_validate(observer_spec.params)
        except ValidationError as exc:
            problems += validation_problems(exc, prefix=("observers", i, "params"))
            continue
        resolved.append(ResolvedObserver(path, observer_spec, info, config))
    return resolved, problems


def check_data_flow(source: ResolvedStage, stages: list[ResolvedStage], registry: Registry) -> list[tuple[str, str]]:
    """Every required layer must be made by the source or an earlier stage (a stage that only
    updates a layer it may be given does not make it): the rule a run checks again on its data."""
    problems = []
    available = layers_after(source.info.cls, set())
    for k, st in enumerate(stages):
        for layer in missing_layers(st.info.cls, available):
            problems.append((f"{st.path}.plugin", missing_layer_message(st, layer, registry, stages[k + 1 :])))
        available = layers_after(st.info.cls, available)
    return problems


def missing_layer_message(
    stage: ResolvedStage, layer: str, registry: Registry, later: list[ResolvedStage] | None = None
) -> str:
    """Why ``stage`` cannot run without ``layer``, and which plugins could make it."""
    providers = sorted(f"{info.name} ({info.kind})" for info in registry.all() if originates(info.cls, layer))
    after = [s.spec.plugin for s in later or [] if originates(s.info.cls, layer)]
    hint = f"; it comes later from {', '.join(after)}: reorder the stages" if after else ""
    return (
        f"stage {stage.spec.plugin!r} requires layer {layer!r}, which no earlier stage provides "
        f"(could provide it: {', '.join(providers) or 'no installed plugin'}){hint}"
    )


def load_pipeline(
    path: str | Path,
    overrides: list[str] | None = None,
    registry: Registry | None = None,
    observe: list[str] | None = None,
) -> ValidatedPipeline:
    """Read, override and validate a pipeline file. Relative paths in it are resolved against its
    folder; those in ``overrides`` against the working folder. ``observe``: observer names to add
    (``--observe``)."""
    doc = load_document(path, overrides, observe)
    overridden = {format_path(parse_path(a.split("=", 1)[0])) for a in overrides or [] if "=" in a}
    return validate(doc, registry=registry, origin=str(path), base_dir=Path(path).parent, overridden=overridden)
