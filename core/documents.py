"""YAML documents users write (pipelines, benchmarks, scene specs): read and validated with errors
that name the file and the key at fault."""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from stratamap.core.errors import ConfigError, DataError, StratamapError

M = TypeVar("M", bound=BaseModel)

#: Nesting deeper than this is no pipeline, benchmark or scene: refused before PyYAML's recursive
#: composer and pydantic would overflow the stack on it.
MAX_DEPTH = 50
#: Values a document may hold once its aliases are expanded (code that walks it would take forever on more).
MAX_NODES = 1_000_000


def format_path(parts: tuple[Any, ...] | list[Any]) -> str:
    """``["stages", 0, "params"]`` -> ``stages[0].params``."""
    out = ""
    for p in parts:
        if isinstance(p, int):
            out += f"[{p}]"
        else:
            text = str(p)
            # A key with a line break or a tab in it would split its error over lines: quoted instead.
            out += ("." if out else "") + (text if text and text.isprintable() else repr(text))
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
        problems.append((format_path(loc), " ".join(str(msg).split())))  # one line per problem
    return problems


def _decode_problem(data: bytes, exc: UnicodeDecodeError) -> str:
    """Where a file stops being UTF-8, as a user can find it in an editor (byte offset, line, column)."""
    line = data.count(b"\n", 0, exc.start) + 1
    column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
    return (
        f"not a text file in UTF-8: byte 0x{data[exc.start]:02x} at offset {exc.start} (line {line}, column "
        f"{column}) is not UTF-8; save the file as UTF-8"
    )


def read_text(path: str | Path, what: str = "file", error: type[StratamapError] = ConfigError) -> str:
    """The text of a file a user wrote or recorded (a pipeline, a scene spec, a camera.json, an
    index), decoded as UTF-8 (a byte-order mark is dropped). A missing, unreadable or non-UTF-8
    file is one ``error`` (ConfigError for documents, DataError for data) naming the file and, for
    bad bytes, where the first one is; ``what`` names the kind of file."""
    path = Path(path)

    def fail(message: str) -> StratamapError:
        if issubclass(error, ConfigError):
            return error([("", message)], source=str(path))
        return error(f"{path}: {message}")

    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise fail(f"{what} not found") from None
    except IsADirectoryError:
        raise fail(f"is a folder, not a {what}") from None
    except OSError as exc:
        raise fail(f"cannot be read ({exc.strerror or exc})") from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise fail(_decode_problem(data, exc)) from None


def read_data_text(path: str | Path, what: str = "file") -> str:
    """:func:`read_text` for data files (a DataError names the file)."""
    return read_text(path, what, error=DataError)


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """PyYAML's multi-line message as one line: what is wrong and where."""
    problem = getattr(exc, "problem", None) or getattr(exc, "context", None)
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    if problem is None:
        text = " ".join(str(exc).split())
        return f"not valid YAML: {text[:300]}"
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    context = getattr(exc, "context", None)
    detail = f" ({context})" if context and context != problem else ""
    return f"not valid YAML{where}: {' '.join(str(problem).split())}{detail}"


def _shape_problem(doc: Any) -> str | None:
    """Why ``doc`` is no document: a structure that contains itself (a YAML anchor used inside
    itself), one nested deeper than MAX_DEPTH, or one whose aliases expand to more than MAX_NODES
    values (a "billion laughs"); None when it is fine. Shared values are measured once."""
    depth: dict[int, int] = {}
    size: dict[int, int] = {}
    open_: set[int] = set()
    stack: list[tuple[Any, bool]] = [(doc, False)]
    while stack:
        node, done = stack.pop()
        if not isinstance(node, (dict, list)):
            continue
        key = id(node)
        children = [c for c in (node.values() if isinstance(node, dict) else node) if isinstance(c, (dict, list))]
        if done:
            open_.discard(key)
            depth[key] = 1 + max((depth[id(c)] for c in children), default=0)
            size[key] = 1 + len(node) + sum(size[id(c)] for c in children)
            if depth[key] > MAX_DEPTH:
                return f"nested more than {MAX_DEPTH} levels deep"
            if size[key] > MAX_NODES:
                return f"its aliases expand to more than {MAX_NODES} values"
            continue
        if key in depth:
            continue
        if key in open_:
            return "a YAML anchor is used inside itself (a structure that contains itself)"
        open_.add(key)
        stack.append((node, True))
        for child in children:
            if id(child) in open_:
                return "a YAML anchor is used inside itself (a structure that contains itself)"
            stack.append((child, False))
    return None


def read_mapping(path: str | Path, what: str) -> dict[str, Any]:
    """The YAML mapping in ``path`` (empty file: ``{}``); ``what`` names the kind of file in errors."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError([("", f"{what} not found: {path}")])
    return parse_mapping(read_text(path, what), what, str(path))


def parse_mapping(text: str, what: str, source: str | None = None) -> dict[str, Any]:
    """The YAML mapping in ``text`` (empty: ``{}``); every problem is one ConfigError line naming ``source``."""
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError([("", _yaml_problem(exc))], source=source) from None
    except RecursionError:
        raise ConfigError([("", "not valid YAML: nested too deeply")], source=source) from None
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise ConfigError([("", f"a {what} must be a mapping, got {type(doc).__name__}")], source=source)
    problem = _shape_problem(doc)
    if problem is not None:
        raise ConfigError([("", f"not a {what}: {problem}")], source=source)
    return doc


def load_model(model: type[M], path: str | Path, what: str) -> M:
    """``path`` read as a ``model``; every problem is reported at once, each with its key path."""
    doc = read_mapping(path, what)
    try:
        return model.model_validate(doc)
    except ValidationError as exc:
        raise ConfigError(validation_problems(exc), source=str(path)) from None
