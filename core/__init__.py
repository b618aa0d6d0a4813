"""stratamap core: typed map layers, stage protocols, plugin registry, pipelines and the CLI.

Plugin authors import from here::

    from stratamap.core import hookimpl, Mapper, StageConfig
"""

from stratamap.core.hookspecs import hookimpl
from stratamap.core.stages import (
    Completer,
    Exporter,
    Mapper,
    PipelineData,
    Segmenter,
    Source,
    Stage,
    StageConfig,
)

__all__ = [
    "Completer",
    "Exporter",
    "Mapper",
    "PipelineData",
    "Segmenter",
    "Source",
    "Stage",
    "StageConfig",
    "hookimpl",
]
