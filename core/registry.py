"""Plugin discovery: entry points, pluggy hooks, and the stage registry.

Every plugin is a module that implements the ``stratamap_register_<kind>`` hook of its kind (and,
optionally, ``stratamap_evaluate`` to add metric families). Built-in plugins are listed once, in
``stratamap.plugins.BUILTIN_PLUGINS``, and registered in code; third-party plugins are modules
declared under one entry-point group per kind (``stratamap.sources``, ``stratamap.segmenters``,
``stratamap.mappers``, ``stratamap.completers``, ``stratamap.exporters``, and
``stratamap.observers`` for run observers). An entry point may also name a stage or observer class
directly.

Environment variables:

``STRATAMAP_DISABLE_PLUGIN_AUTOLOAD=1``
    load only stratamap's own plugins, skipping every third-party entry point.
``STRATAMAP_PLUGINS=mod_a,path/to/mod_b.py``
    also load these unpackaged plugin modules (importable names or file paths).

A third-party plugin that fails to import is reported (with its distribution name) and skipped;
two stages of one kind with one name is an error that names both.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import os
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from types import ModuleType
from typing import Any

import pluggy

from stratamap.core import hookspecs
from stratamap.core.errors import PluginError
from stratamap.core.hookspecs import Observer
from stratamap.core.stages import KIND_BASES, KINDS, Stage

DISTRIBUTION = "stratamap"
AUTOLOAD_ENV = "STRATAMAP_DISABLE_PLUGIN_AUTOLOAD"
EXTRA_PLUGINS_ENV = "STRATAMAP_PLUGINS"
#: Observers are a plugin kind beside the five stage kinds: registered and listed the same way,
#: but never stages of a pipeline (they follow a run through the event hooks).
OBSERVERS = "observers"
PLUGIN_KINDS: tuple[str, ...] = (*KINDS, OBSERVERS)
PLUGIN_BASES: dict[str, type] = {**KIND_BASES, OBSERVERS: Observer}

#: The package whose ``BUILTIN_PLUGINS`` tuple lists stratamap's own plugin modules. They are
#: registered in code, through the same hooks third parties implement (as pytest and datasette do);
#: entry points are for third-party plugins only.
BUILTIN_PACKAGE = "stratamap.plugins"
#: The framework's own hook implementations outside plugins: the built-in metric families and the
#: HTML run report.
CORE_HOOK_MODULES: tuple[str, ...] = ("stratamap.core.evaluation.metrics", "stratamap.core.evaluation.html_report")


def builtin_modules() -> tuple[str, ...]:
    """The built-in plugin modules, from the one list that names them."""
    return tuple(importlib.import_module(BUILTIN_PACKAGE).BUILTIN_PLUGINS)


def group_name(kind: str) -> str:
    return f"stratamap.{kind}"


@dataclass(frozen=True)
class PluginInfo:
    """A registered stage (or observer) class and where it came from."""

    kind: str
    name: str
    cls: type[Any]
    distribution: str
    module: str

    @property
    def description(self) -> str:
        return self.cls.summary()

    def to_dict(self) -> dict[str, str]:
        return {
            "kind": self.kind,
            "name": self.name,
            "distribution": self.distribution,
            "module": self.module,
            "description": self.description,
        }


@dataclass(frozen=True)
class LoadFailure:
    """A plugin that could not be loaded; the run goes on without it."""

    distribution: str
    entry_point: str
    error: str

    def __str__(self) -> str:
        return f"plugin {self.entry_point!r} from distribution {self.distribution!r} failed to load: {self.error}"


#: Libraries that take a second or more to import: a plugin that imports one at load time makes every
#: command slower (``--help`` aside), so the registry names it. Built-ins import them lazily.
HEAVY_LIBRARIES: tuple[str, ...] = (
    "open3d",
    "trimesh",
    "scipy.spatial",
    "networkx",
    "onnxruntime",
    "matplotlib",
    "torch",
    "pxr",
    "mujoco",
    "pybullet",
)


@dataclass(frozen=True)
class HeavyImport:
    """A plugin whose module imported heavy libraries when it was loaded, not when its stage ran."""

    distribution: str
    entry_point: str
    libraries: tuple[str, ...]

    def __str__(self) -> str:
        return (
            f"plugin {self.entry_point!r} from distribution {self.distribution!r} imports "
            f"{', '.join(self.libraries)} when it is loaded, which slows every stratamap command: import them "
            "inside the stage (stratamap.core.lazy.lazy_module; docs/plugins.md)"
        )


def _newly_imported(before: set[str]) -> tuple[str, ...]:
    return tuple(lib for lib in HEAVY_LIBRARIES if lib in sys.modules and lib not in before)


@dataclass
class Registry:
    """Stage classes by kind and name (observer classes under ``observers``), plus the plugin
    manager that carries event hooks."""

    plugin_manager: pluggy.PluginManager
    stages: dict[str, dict[str, PluginInfo]] = field(default_factory=lambda: {k: {} for k in PLUGIN_KINDS})
    failures: list[LoadFailure] = field(default_factory=list)
    heavy_imports: list[HeavyImport] = field(default_factory=list)

    def get(self, kind: str, name: str) -> PluginInfo:
        if kind not in self.stages:
            raise PluginError(f"unknown plugin kind {kind!r}; kinds are {list(PLUGIN_KINDS)}")
        try:
            return self.stages[kind][name]
        except KeyError:
            known = ", ".join(sorted(self.stages[kind])) or "none"
            hint = ""
            broken = [f for f in self.failures if f.entry_point == name]
            if broken:
                hint = f" ({broken[0]})"
            raise PluginError(f"no {kind[:-1]} plugin named {name!r}; installed: {known}{hint}") from None

    def find(self, name: str, kinds: Iterable[str] = KINDS) -> list[PluginInfo]:
        """All registered stages called ``name`` among ``kinds``."""
        return [self.stages[k][name] for k in kinds if name in self.stages[k]]

    def all(self) -> list[PluginInfo]:
        """Every stage class (observers are not stages: see :meth:`observers`)."""
        return [info for kind in KINDS for _, info in sorted(self.stages[kind].items())]

    def observers(self) -> list[PluginInfo]:
        """Every observer class, by name."""
        return [info for _, info in sorted(self.stages[OBSERVERS].items())]

    @property
    def hook(self) -> Any:
        return self.plugin_manager.hook


def _new_plugin_manager() -> pluggy.PluginManager:
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    return pm


class _ClassPlugin:
    """Adapts an entry point that names a stage or observer class directly to the register hook."""

    def __init__(self, cls: type[Stage] | type[Observer]):
        self.cls = cls
        self.__name__ = f"{cls.__module__}.{cls.__qualname__}"
        setattr(self, f"stratamap_register_{cls.kind}", hookspecs.hookimpl(lambda: [cls]))


def _load_module_from_path(path: str) -> ModuleType:
    p = Path(path)
    if not p.is_file():
        raise ImportError(f"{EXTRA_PLUGINS_ENV}: no such file {path}")
    name = f"stratamap_local_plugin_{p.stem}"
    spec = importlib.util.spec_from_file_location(name, p)
    if spec is None or spec.loader is None:
        raise ImportError(f"{EXTRA_PLUGINS_ENV}: cannot import {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _distribution_of(ep: EntryPoint) -> str:
    dist = getattr(ep, "dist", None)
    return dist.name if dist is not None else "<unknown>"


def build_registry(
    eps: Iterable[EntryPoint] | None = None,
    extra_modules: Iterable[str] | None = None,
    autoload: bool | None = None,
    builtins: bool = True,
) -> Registry:
    """Discover plugins and build the registry.

    ``builtins``: register stratamap's own plugins and metric families first;
    ``eps`` replaces the installed entry points (tests pass fake ``EntryPoint`` objects);
    ``extra_modules`` defaults to ``$STRATAMAP_PLUGINS``; ``autoload`` defaults to the negation of
    ``$STRATAMAP_DISABLE_PLUGIN_AUTOLOAD``.
    """
    if autoload is None:
        autoload = os.environ.get(AUTOLOAD_ENV, "").strip().lower() in ("", "0", "false", "no")
    if eps is None:
        eps = [ep for kind in PLUGIN_KINDS for ep in entry_points(group=group_name(kind))]
    if extra_modules is None:
        extra_modules = [m.strip() for m in os.environ.get(EXTRA_PLUGINS_ENV, "").split(",") if m.strip()]

    pm = _new_plugin_manager()
    registry = Registry(plugin_manager=pm)
    origins: dict[str, tuple[str, str]] = {}  # plugin name in pm -> (distribution, module)
    seen_eps: set[tuple[str, str]] = set()

    if builtins:
        for module_name in (*CORE_HOOK_MODULES, *builtin_modules()):
            # A built-in that fails to import is a bug in stratamap, not a plugin to skip.
            _register_object(pm, importlib.import_module(module_name), DISTRIBUTION, origins, registry, module_name)

    for ep in eps:
        dist = _distribution_of(ep)
        if (ep.group, ep.value) in seen_eps:
            continue  # the same module listed twice (e.g. editable + regular install)
        seen_eps.add((ep.group, ep.value))
        if not autoload and dist != DISTRIBUTION:
            continue
        before = set(sys.modules)
        try:
            obj = ep.load()
        except Exception as exc:  # a broken plugin must not take the run down
            registry.failures.append(LoadFailure(dist, ep.name, f"{type(exc).__name__}: {exc}"))
            continue
        if dist != DISTRIBUTION and (heavy := _newly_imported(before)):
            registry.heavy_imports.append(HeavyImport(dist, ep.name, heavy))
        _register_object(pm, obj, dist, origins, registry, ep.name)

    for spec in extra_modules:
        before = set(sys.modules)
        try:
            module = _load_module_from_path(spec) if spec.endswith(".py") else importlib.import_module(spec)
        except Exception as exc:
            registry.failures.append(LoadFailure(f"<{EXTRA_PLUGINS_ENV}>", spec, f"{type(exc).__name__}: {exc}"))
            continue
        if heavy := _newly_imported(before):
            registry.heavy_imports.append(HeavyImport(f"<{EXTRA_PLUGINS_ENV}>", spec, heavy))
        _register_object(pm, module, f"<{EXTRA_PLUGINS_ENV}>", origins, registry, spec)

    for kind in PLUGIN_KINDS:
        hook = getattr(pm.hook, f"stratamap_register_{kind}")
        for impl in hook.get_hookimpls():
            dist, module = origins.get(impl.plugin_name, ("<unknown>", impl.plugin_name))
            try:
                classes = impl.function() or []
            except Exception as exc:
                registry.failures.append(LoadFailure(dist, module, f"stratamap_register_{kind} raised {exc!r}"))
                continue
            for cls in classes:
                _add_stage(registry, kind, cls, dist, module)
    return registry


def _register_object(
    pm: pluggy.PluginManager,
    obj: Any,
    dist: str,
    origins: dict[str, tuple[str, str]],
    registry: Registry,
    ep_name: str,
) -> None:
    if inspect.isclass(obj) and issubclass(obj, (Stage, Observer)):
        plugin: Any = _ClassPlugin(obj)
        module_name = obj.__module__
    elif isinstance(obj, ModuleType):
        plugin, module_name = obj, obj.__name__
    else:
        registry.failures.append(
            LoadFailure(
                dist, ep_name, f"entry point must name a module, a Stage or an Observer class, got {type(obj).__name__}"
            )
        )
        return
    if pm.is_registered(plugin):
        return
    try:
        name = pm.register(plugin, name=f"{dist}:{module_name}:{ep_name}")
    except ValueError:
        return  # the same module under two entry-point names: registered once is enough
    except pluggy.PluginValidationError as exc:
        registry.failures.append(LoadFailure(dist, ep_name, str(exc)))
        return
    if name is not None:
        origins[name] = (dist, module_name)


def _add_stage(registry: Registry, kind: str, cls: Any, dist: str, module: str) -> None:
    base = PLUGIN_BASES[kind]
    if not (inspect.isclass(cls) and issubclass(cls, base)):
        registry.failures.append(LoadFailure(dist, module, f"{cls!r} is not a subclass of {base.__name__}"))
        return
    if not cls.name:
        registry.failures.append(LoadFailure(dist, module, f"{cls.__qualname__} has no 'name'"))
        return
    existing = registry.stages[kind].get(cls.name)
    if existing is not None:
        if existing.cls is cls:
            return
        raise PluginError(
            f"two {kind} plugins are named {cls.name!r}: {existing.module}.{existing.cls.__qualname__} "
            f"(distribution {existing.distribution}) and {cls.__module__}.{cls.__qualname__} "
            f"(distribution {dist}); uninstall one of them"
        )
    registry.stages[kind][cls.name] = PluginInfo(kind, cls.name, cls, dist, module)


_DEFAULT: Registry | None = None


def default_registry(refresh: bool = False) -> Registry:
    """The process-wide registry of installed plugins (built on first use)."""
    global _DEFAULT
    if _DEFAULT is None or refresh:
        _DEFAULT = build_registry()
    return _DEFAULT
