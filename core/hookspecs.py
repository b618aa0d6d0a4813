"""Hook specifications of stratamap. Plugin modules implement them with ``@hookimpl``.

A plugin module registers its stages by returning their classes::

    from stratamap.core import hookimpl

    @hookimpl
    def stratamap_register_completers():
        return [MyCompleter]

Observers (``stratamap_register_observers``) are :class:`Observer` classes whose methods implement
the event hooks; a pipeline that names one (``observers:`` in its file, or ``stratamap run
--observe NAME``) makes an instance for the run and registers it for the run's duration only.
"""

from __future__ import annotations

import inspect
from typing import Any, ClassVar, Generic, TypeVar

import pluggy
from pydantic import BaseModel, ConfigDict

PROJECT = "stratamap"

hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def stratamap_register_sources() -> list[type]:
    """Return source stage classes (read sensor data: RGB-D, LiDAR, point clouds)."""


@hookspec
def stratamap_register_segmenters() -> list[type]:
    """Return segmenter stage classes (per-frame or 3D semantic and instance labels)."""


@hookspec
def stratamap_register_mappers() -> list[type]:
    """Return mapper stage classes (build occupancy, geometry, semantics, instances, contact graph)."""


@hookspec
def stratamap_register_completers() -> list[type]:
    """Return completer stage classes (complete partially observed objects with full models)."""


@hookspec
def stratamap_register_exporters() -> list[type]:
    """Return exporter stage classes (write the map in formats robot software loads)."""


@hookspec
def stratamap_register_observers() -> list[type]:
    """Return observer classes (:class:`Observer`: follow a run through the event hooks, e.g. record it)."""


@hookspec
def stratamap_evaluate(data: Any, details: bool) -> dict[str, dict] | None:
    """Return metric families ``{family: {metric: value}}`` for a run's data (``details``: keep per-item records)."""


@hookspec
def stratamap_pipeline_start(pipeline: Any) -> None:
    """Called once before the source reads."""


@hookspec
def stratamap_pipeline_end(pipeline: Any, report: dict) -> None:
    """Called once after the last stage, with the run report."""


@hookspec
def stratamap_stage_start(pipeline: Any, stage: Any, index: int) -> None:
    """Called before a stage runs; ``index`` is -1 for the source."""


@hookspec
def stratamap_stage_end(pipeline: Any, stage: Any, index: int, seconds: float) -> None:
    """Called after a stage ran, with its wall time."""


@hookspec
def stratamap_pipeline_step(pipeline: Any, description: str) -> None:
    """Called when the pipeline itself starts a step after the stages (evaluating, saving the map)."""


@hookspec
def stratamap_stage_progress(stage: Any, completed: int, total: int | None, description: str) -> None:
    """Called by long-running stages to report progress (e.g. frames integrated)."""


# ------------------------------------------------------------------------------------------
# Observers


def configured(owner: Any, config: Any, params: dict[str, Any]) -> Any:
    """The config of a stage or observer built either from a ``Config`` instance or from keyword parameters."""
    if config is not None and params:
        raise TypeError("pass either a Config instance or keyword parameters, not both")
    config = config if config is not None else owner.Config(**params)
    if not isinstance(config, owner.Config):
        raise TypeError(f"{type(owner).__name__} expects a {owner.Config.__name__}, got {type(config).__name__}")
    return config


class ObserverConfig(BaseModel):
    """Base of every observer's parameters: unknown keys are errors, instances are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)


ObserverConfigT = TypeVar("ObserverConfigT", bound=ObserverConfig)


class Observer(Generic[ObserverConfigT]):
    """Base class of observers: objects whose ``@hookimpl`` methods implement the event hooks
    (``stratamap_pipeline_start``, ``stratamap_stage_end``, ...). The pipeline makes one per run from
    its ``Config`` and registers it with the plugin manager until the run ends; :meth:`close` is
    called then, whether the run succeeded or failed."""

    config: ObserverConfigT

    kind: ClassVar[str] = "observers"
    name: ClassVar[str] = ""
    #: One line shown by ``stratamap plugins``; defaults to the first line of the class docstring.
    description: ClassVar[str] = ""
    Config: ClassVar[type[ObserverConfig]] = ObserverConfig

    def __init__(self, config: ObserverConfig | None = None, **params: Any):
        self.config = configured(self, config, params)  # type: ignore[assignment]  # Config is ObserverConfigT's

    @classmethod
    def summary(cls) -> str:
        if cls.description:
            return cls.description
        doc = inspect.getdoc(cls) or ""
        return doc.strip().splitlines()[0] if doc.strip() else ""

    def close(self) -> None:
        """Release what the observer holds (open files, sinks); called once after the run, also after a failure."""
