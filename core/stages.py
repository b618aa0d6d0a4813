"""Stage protocols: the five kinds of pipeline stage and the data they exchange.

Every stage class declares

* ``name`` -- how pipelines refer to it (unique within its kind),
* ``Config`` -- a pydantic model of its parameters (extra keys forbidden, every field described),
* ``requires`` / ``optional`` / ``provides`` -- the data layers it reads and writes (see ``LAYERS``),

and implements the one verb of its kind:

==============  ===========================================  ==========================
kind            verb                                         returns
==============  ===========================================  ==========================
``sources``     ``read() -> dict``                           ``frames`` (+ ``ground_truth``)
``segmenters``  ``segment(data) -> dict``                    labels for frames or points
``mappers``     ``map(data) -> dict``                        map layers
``completers``  ``complete(data) -> dict``                   ``instances`` (+ ``augmented``)
``exporters``   ``export(data, out_dir) -> list[Path]``      the files written
==============  ===========================================  ==========================

The returned dict maps layer names to values; its keys must be a subset of ``provides``.
"""

from __future__ import annotations

import inspect
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Generic, Literal, TypeVar, get_args, get_origin

from pydantic import BaseModel, ConfigDict, model_validator
from pydantic_core import PydanticCustomError

from stratamap.core.hookspecs import configured
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.layers import (
    MAP_LAYERS,
    ContactGraph,
    Geometry,
    LayeredMap,
    ObjectInstances,
    OccupancyMaps,
    Semantics,
)
from stratamap.core.map.sensors import FrameLabels, SensorStream

KINDS = ("sources", "segmenters", "mappers", "completers", "exporters")

#: Every data layer a stage may require or provide, with its type.
LAYERS: dict[str, type] = {
    "frames": SensorStream,
    "frame_labels": FrameLabels,
    "ground_truth": GroundTruth,
    "occupancy": OccupancyMaps,
    "geometry": Geometry,
    "semantics": Semantics,
    "instances": ObjectInstances,
    "contact_graph": ContactGraph,
    "augmented": Geometry,
}

T = TypeVar("T")


def _literal_choices(annotation: Any) -> set[Any]:
    """The values a ``Literal[...]`` annotation (or an optional one) allows."""
    if get_origin(annotation) is Literal:
        return set(get_args(annotation))
    return {v for arg in get_args(annotation) for v in _literal_choices(arg)}


class StageConfig(BaseModel):
    """Base of every stage's parameters: unknown keys are errors, instances are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    #: Fields that hold a file or folder path: in a pipeline file, a relative one is resolved
    #: against the file's folder (on the command line, ``--set`` values against the working folder).
    path_fields: ClassVar[tuple[str, ...]] = ()
    #: Flat keys of an earlier release that moved into a nested section, old key -> "section.field"
    #: (``{"piece_min_points": "pieces.min_points"}``): still read, and the stage warns when it runs
    #: (:func:`warn_renamed`).
    renamed: ClassVar[Mapping[str, str]] = {}

    @model_validator(mode="wrap")
    @classmethod
    def _renamed_keys(cls, data: Any, handler: Any) -> Any:
        # A wrap, not a before validator: the keys are moved before validation, and the config
        # then remembers which, so its stage can say so in the run's warnings.
        data, moved = move_renamed(data, cls.renamed)
        config = handler(data)
        if moved:
            # Kept beside the fields in __dict__ (where a cached_property lives): pydantic leaves it
            # out of equality and dumps, so a config is the same whichever names it was read from.
            object.__setattr__(config, "_renamed", moved)
        return config

    @model_validator(mode="before")
    @classmethod
    def _yaml_switches(cls, data: Any) -> Any:
        """YAML 1.1 reads off/on/no/yes as booleans: give such a setting back its word when the
        field takes one (``gravity: off`` is ``"off"``, not ``False``)."""
        if not isinstance(data, dict):
            return data
        fixed = dict(data)
        for name, info in cls.model_fields.items():
            value = data.get(name)
            if isinstance(value, bool):
                words = ("on", "yes", "true") if value else ("off", "no", "false")
                choices = _literal_choices(info.annotation)
                fixed[name] = next((w for w in words if w in choices), value)
        return fixed


@dataclass
class PipelineData:
    """The blackboard stages read from and write to during one run."""

    stream: SensorStream | None = None
    frame_labels: FrameLabels | None = None
    ground_truth: GroundTruth | None = None
    map: LayeredMap = field(default_factory=LayeredMap)
    warnings: list[str] = field(default_factory=list)
    #: Free-form facts stages report (e.g. a gravity re-alignment); copied into report.json.
    notes: dict[str, Any] = field(default_factory=dict)

    def get(self, layer: str) -> Any:
        if layer == "frames":
            return self.stream
        if layer in ("frame_labels", "ground_truth"):
            return getattr(self, layer)
        return self.map.get(layer)

    def set(self, layer: str, value: Any, producer: str) -> None:
        if layer not in LAYERS:
            raise KeyError(f"unknown layer {layer!r}; layers are {sorted(LAYERS)}")
        if layer == "frames":
            self.stream = value
        elif layer in ("frame_labels", "ground_truth"):
            setattr(self, layer, value)
        else:
            self.map.set(layer, value, producer)

    def has(self, layer: str) -> bool:
        return self.get(layer) is not None

    def available(self) -> set[str]:
        return {name for name in LAYERS if self.has(name)}


ConfigT = TypeVar("ConfigT", bound=StageConfig)


def move_renamed(data: Any, renamed: Mapping[str, str]) -> tuple[Any, tuple[tuple[str, str], ...]]:
    """``data`` with each old flat key of ``renamed`` moved into its section, and the (old, new)
    pairs moved. The same setting under both names is an error: which one was meant cannot be guessed."""
    if not renamed or not isinstance(data, dict) or not any(old in data for old in renamed):
        return data, ()
    data = dict(data)
    moved = []
    for old, new in renamed.items():
        if old not in data:
            continue
        section, name = new.split(".")
        current = data.get(section)
        current = {} if current is None else current
        if not isinstance(current, dict):
            continue  # the section's own error says what it must be; the old key stays an extra field
        if name in current:
            raise PydanticCustomError(
                "renamed_key", "{old} and {new} are one setting, set twice: keep {new}", {"old": old, "new": new}
            )
        data[section] = {**current, name: data.pop(old)}
        moved.append((old, new))
    return data, tuple(moved)


def renamed_keys(config: BaseModel) -> tuple[tuple[str, str], ...]:
    """The (old, new) key pairs ``config`` was read with."""
    return config.__dict__.get("_renamed", ())


def warn_renamed(stage: Stage) -> None:
    """One warning for the old names ``stage``'s config used, each with its new key."""
    moved = renamed_keys(stage.config)
    if moved:
        pairs = ", ".join(f"{old} is now {new}" for old, new in moved)
        keys = "key" if len(moved) == 1 else "keys"
        stage.warn(f"deprecated {keys}: {pairs} (the old names stop working in the next release)")


class Stage(Generic[ConfigT]):
    """Base class of all stages. Subclass one of :class:`Source`, :class:`Segmenter`,
    :class:`Mapper`, :class:`Completer`, :class:`Exporter`, parameterised by the config class
    (``class MyMapper(Mapper[MyConfig])``) so that ``self.config`` is typed."""

    config: ConfigT

    kind: ClassVar[str] = ""
    name: ClassVar[str] = ""
    #: One line shown by ``stratamap plugins``; defaults to the first line of the class docstring.
    description: ClassVar[str] = ""
    Config: ClassVar[type[StageConfig]] = StageConfig
    requires: ClassVar[frozenset[str]] = frozenset()
    optional: ClassVar[frozenset[str]] = frozenset()
    provides: ClassVar[frozenset[str]] = frozenset()

    def __init__(self, config: StageConfig | None = None, **params: Any):
        self.config = configured(self, config, params)  # type: ignore[assignment]  # a ClassVar cannot say ConfigT
        self._hook = None  # set by the pipeline: the pluggy hook relay for progress events
        self._data: PipelineData | None = None

    @classmethod
    def summary(cls) -> str:
        if cls.description:
            return cls.description
        doc = inspect.getdoc(cls) or ""
        return doc.strip().splitlines()[0] if doc.strip() else ""

    # ------------------------------------------------------------------ helpers for stage authors

    def progress(self, items: Iterable[T], total: int | None = None, description: str = "") -> Iterator[T]:
        """Iterate ``items``, reporting progress to observers (rich progress bars in the CLI)."""
        if total is None:
            try:
                total = len(items)  # type: ignore[arg-type]
            except TypeError:
                total = None
        description = description or self.name
        for i, item in enumerate(items):
            yield item
            if self._hook is not None:
                self._hook.stratamap_stage_progress(stage=self, completed=i + 1, total=total, description=description)

    def warn(self, message: str) -> None:
        """Record a warning that ends up in ``report.json`` (the run goes on)."""
        text = f"{self.kind}.{self.name}: {message}"
        if self._data is not None:
            self._data.warnings.append(text)
        else:
            import warnings

            warnings.warn(text, stacklevel=2)

    def note(self, key: str, value: Any) -> None:
        """Record a fact for the report (e.g. ``gravity_alignment``)."""
        if self._data is not None:
            self._data.notes.setdefault(self.name, {})[key] = value

    # ------------------------------------------------------------------ dispatch

    def run(self, data: PipelineData, out_dir: Path | None = None) -> dict[str, Any] | list[Path]:
        """Call this stage's verb on ``data`` (used by the pipeline and the conformance kit)."""
        raise NotImplementedError


class Source(Stage[ConfigT]):
    """Reads sensor data. Verb: ``read() -> {"frames": SensorStream, "ground_truth"?: GroundTruth}``."""

    kind = "sources"
    provides = frozenset({"frames"})

    def read(self) -> dict[str, Any]:
        raise NotImplementedError

    def run(self, data: PipelineData, out_dir: Path | None = None) -> dict[str, Any]:
        self._data = data
        return self.read()


class Segmenter(Stage[ConfigT]):
    """Labels frames or points. Verb: ``segment(data) -> {"frame_labels": FrameLabels}`` (or ``semantics``)."""

    kind = "segmenters"
    requires = frozenset({"frames"})
    provides = frozenset({"frame_labels"})

    def segment(self, data: PipelineData) -> dict[str, Any]:
        raise NotImplementedError

    def run(self, data: PipelineData, out_dir: Path | None = None) -> dict[str, Any]:
        self._data = data
        return self.segment(data)


class Mapper(Stage[ConfigT]):
    """Builds map layers. Verb: ``map(data) -> {layer: value}``."""

    kind = "mappers"

    def map(self, data: PipelineData) -> dict[str, Any]:
        raise NotImplementedError

    def run(self, data: PipelineData, out_dir: Path | None = None) -> dict[str, Any]:
        self._data = data
        return self.map(data)


class Completer(Stage[ConfigT]):
    """Completes partially observed objects. Verb: ``complete(data) -> {"instances": ..., "augmented"?: ...}``."""

    kind = "completers"
    requires = frozenset({"instances"})
    provides = frozenset({"instances"})

    def complete(self, data: PipelineData) -> dict[str, Any]:
        raise NotImplementedError

    def run(self, data: PipelineData, out_dir: Path | None = None) -> dict[str, Any]:
        self._data = data
        return self.complete(data)


class Exporter(Stage[ConfigT]):
    """Writes files robot software loads. Verb: ``export(data, out_dir) -> list[Path]``; writes atomically."""

    kind = "exporters"

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        raise NotImplementedError

    def run(self, data: PipelineData, out_dir: Path | None = None) -> list[Path]:
        self._data = data
        if out_dir is None:
            raise ValueError(f"exporter {self.name!r} needs an output directory")
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        return self.export(data, Path(out_dir))


def missing_layers(stage: type[Stage] | Stage, available: Iterable[str]) -> list[str]:
    """The layers ``stage`` requires that are not among ``available`` (sorted): checked on the
    declared layers by ``validate`` and on the actual blackboard before each stage of a run."""
    return sorted(set(stage.requires) - set(available))


def originates(stage: type[Stage] | Stage, layer: str) -> bool:
    """Whether ``stage`` makes ``layer`` from other layers. A layer it also requires or takes as
    optional input is one it updates, not one it makes (``physical_check`` adjusts the contact graph
    when there is one, and writes none when there is none)."""
    return layer in stage.provides and layer not in stage.requires and layer not in stage.optional


def layers_after(stage: type[Stage] | Stage, available: Iterable[str]) -> set[str]:
    """The layers available once ``stage`` ran on ``available``: these, and those it originates;
    a layer it only passes through counts only if it was there before."""
    return set(available) | {layer for layer in stage.provides if originates(stage, layer) or layer in stage.requires}


KIND_BASES: dict[str, type[Stage]] = {
    "sources": Source,
    "segmenters": Segmenter,
    "mappers": Mapper,
    "completers": Completer,
    "exporters": Exporter,
}

__all__ = [
    "KINDS",
    "KIND_BASES",
    "LAYERS",
    "MAP_LAYERS",
    "PipelineData",
    "Stage",
    "StageConfig",
    "layers_after",
    "missing_layers",
    "originates",
]
