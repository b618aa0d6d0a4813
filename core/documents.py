"""YAML documents users write (pipelines, benchmarks, scene specs): read and validated with errors
that name the file and the key at fault."""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from stratamap.core.errors import ConfigError

M = TypeVar("M", bound=BaseModel)


def format_path(parts: tuple[Any, ...] | list[Any]) -> str:
    """``["stages", 0, "params"]`` -> ``stages[0].params``."""
    out = ""
    for p in parts:
        if isinstance(p, int):
            out += f"[{p}]"
        else:
            out += ("." if out else "") + str(p)
    return out


def validation_problems(exc: ValidationError, prefix: tuple[Any, ...] = ()) -> list[tuple[str, str]]:
    """(key path, message) for each error pydantic found, keys under ``prefix``."""
    problems = []
    for err in exc.errors():
        loc = tuple(prefix) + tuple(err["loc"])
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "extra field (not a parameter of this plugin)" if "params" in prefix else "extra field"
        elif err["type"] == "missing":
            msg = "required field missing"
        problems.append((format_path(loc), msg))
    return problems


def read_mapping(path: str | Path, what: str) -> dict[str, Any]:
    """The YAML mapping in ``path`` (empty file: ``{}``); ``what`` names the kind of file in errors."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError([("", f"{what} not found: {path}")])
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError([("", f"not valid YAML: {exc}")], source=str(path)) from exc
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise ConfigError([("", f"a {what} must be a mapping, got {type(doc).__name__}")], source=str(path))
    return doc


def load_model(model: type[M], path: str | Path, what: str) -> M:
    """``path`` read as a ``model``; every problem is reported at once, each with its key path."""
    doc = read_mapping(path, what)
    try:
        return model.model_validate(doc)
    except ValidationError as exc:
        raise ConfigError(validation_problems(exc), source=str(path)) from None
