"""Hook specifications of stratamap. Plugin modules implement them with ``@hookimpl``.

A plugin module registers its stages by returning their classes::

    from stratamap.core import hookimpl

    @hookimpl
    def stratamap_register_completers():
        return [MyCompleter]
"""

from __future__ import annotations

from typing import Any

import pluggy

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
