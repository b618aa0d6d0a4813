"""JSON Schema of pipeline files, including every installed plugin's parameters.

Each entry of ``stages`` is a ``oneOf`` over the installed plugins, discriminated by ``plugin``;
each plugin's ``params`` schema is its pydantic ``Config`` schema (descriptions included).
"""

from __future__ import annotations

from typing import Any

from stratamap.core.config import OutputSpec
from stratamap.core.registry import PluginInfo, Registry, default_registry


def _stage_schema(info: PluginInfo) -> dict[str, Any]:
    params = info.cls.Config.model_json_schema()
    defs = params.pop("$defs", {})
    schema: dict[str, Any] = {
        "type": "object",
        "title": f"{info.kind[:-1]} {info.name}",
        "description": info.description,
        "properties": {
            "plugin": {"const": info.name, "description": f"{info.kind[:-1]} plugin from {info.distribution}"},
            "kind": {"const": info.kind},
            "params": params,
        },
        "required": ["plugin"],
        "additionalProperties": False,
    }
    if defs:
        schema["$defs"] = defs
    return schema


def _inline_defs(schema: dict[str, Any], prefix: str, collected: dict[str, Any]) -> dict[str, Any]:
    """Move nested ``$defs`` to the top under unique names and rewrite the references."""
    defs = schema.pop("$defs", {})
    mapping = {f"#/$defs/{k}": f"#/$defs/{prefix}.{k}" for k in defs}

    def rewrite(node: Any) -> Any:
        if isinstance(node, dict):
            return {k: (mapping.get(v, v) if k == "$ref" else rewrite(v)) for k, v in node.items()}
        if isinstance(node, list):
            return [rewrite(v) for v in node]
        return node

    for k, v in defs.items():
        collected[f"{prefix}.{k}"] = rewrite(v)
    return rewrite(schema)


def pipeline_schema(registry: Registry | None = None) -> dict[str, Any]:
    registry = registry or default_registry()
    defs: dict[str, Any] = {}
    sources, stages = [], []
    for info in registry.all():
        s = _inline_defs(_stage_schema(info), f"{info.kind}.{info.name}", defs)
        (sources if info.kind == "sources" else stages).append(s)
    observers = []
    for info in registry.observers():
        params = _inline_defs(info.cls.Config.model_json_schema(), f"observers.{info.name}", defs)
        observers.append(
            {
                "type": "object",
                "title": f"observer {info.name}",
                "description": info.description,
                "properties": {"name": {"const": info.name}, "params": params},
                "required": ["name"],
                "additionalProperties": False,
            }
        )
    output = OutputSpec.model_json_schema()
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "stratamap pipeline",
        "description": "A pipeline file: a source, an ordered list of stages, and output settings.",
        "type": "object",
        "properties": {
            "source": {"description": "The source stage that reads sensor data.", "oneOf": sources},
            "stages": {
                "description": "Stages run in order after the source.",
                "type": "array",
                "items": {"oneOf": stages},
            },
            "observers": {
                "description": "Observers that follow the run (e.g. rerun, which records it).",
                "type": "array",
                "items": {"oneOf": observers},
            },
            "output": output,
        },
        "required": ["source"],
        "additionalProperties": False,
        "$defs": defs,
    }
