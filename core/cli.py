"""The ``stratamap`` command line (typer + rich)."""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from stratamap.core.errors import ConfigError, StratamapError
from stratamap.core.hookspecs import hookimpl
from stratamap.core.paths import repo_root

app = typer.Typer(
    name="stratamap",
    help=(
        "Layered robot maps from indoor scans: occupancy, geometry, panoptic semantics, completed objects, contact "
        "graph."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console(stderr=True)
out_console = Console()

SetOption = Annotated[
    list[str] | None,
    typer.Option(
        "--set", "-s", help="Override a key by its path, value parsed as YAML: --set stages[0].params.voxel_size=0.02"
    ),
]


class RichProgress:
    """Observer: a rich progress bar per stage, fed by the pipeline's event hooks."""

    def __init__(self, console: Console):
        self.progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=console,
            transient=False,
            disable=not console.is_terminal,
        )
        self.tasks: dict[int, Any] = {}
        self.step: Any = None
        self.console = console

    @hookimpl
    def stratamap_pipeline_start(self, pipeline: Any) -> None:
        self.progress.start()

    @hookimpl
    def stratamap_stage_start(self, pipeline: Any, stage: Any, index: int) -> None:
        self.tasks[id(stage)] = self.progress.add_task(f"{stage.kind[:-1]} {stage.name}", total=None)

    @hookimpl
    def stratamap_stage_progress(self, stage: Any, completed: int, total: int | None, description: str) -> None:
        task = self.tasks.get(id(stage))
        if task is not None:
            self.progress.update(task, completed=completed, total=total, description=description)

    @hookimpl
    def stratamap_stage_end(self, pipeline: Any, stage: Any, index: int, seconds: float) -> None:
        task = self.tasks.get(id(stage))
        if task is not None:
            t = self.progress.tasks[task]
            self.progress.update(task, total=t.total or 1, completed=t.total or 1)
        if not self.console.is_terminal:
            self.console.print(f"  {stage.kind[:-1]:<9} {stage.name:<16} {seconds:8.2f} s")

    @hookimpl
    def stratamap_pipeline_step(self, pipeline: Any, description: str) -> None:
        if self.step is not None:
            self.progress.update(self.step, total=1, completed=1)
        self.step = self.progress.add_task(description, total=None)
        if not self.console.is_terminal:
            self.console.print(f"  {description}", highlight=False)

    @hookimpl
    def stratamap_pipeline_end(self, pipeline: Any, report: dict) -> None:
        if self.step is not None:
            self.progress.update(self.step, total=1, completed=1)
        self.progress.stop()


def _fail(exc: BaseException) -> None:
    console.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


#: The exit status of a command stopped by Ctrl-C (128 + SIGINT, as a shell reports it).
INTERRUPTED = 130


@contextmanager
def _interruptible(out: Path | None) -> Iterator[None]:
    """Ctrl-C inside the block ends the command with one line and exit status 130 (not click's
    "Aborted!" and 1): output folders are written atomically, so ``out`` is as it was."""
    try:
        yield
    except KeyboardInterrupt:
        where = f"{out} is as it was" if out is not None else "no output was written or replaced"
        console.print(f"[bold red]interrupted:[/] {escape(where)}", highlight=False, soft_wrap=True)
        raise typer.Exit(code=INTERRUPTED) from None


def _registry() -> Any:
    """The installed plugins; plugins that failed to load are warnings, a clash of names an error."""
    from stratamap.core.registry import default_registry

    try:
        registry = default_registry()
    except StratamapError as exc:
        _fail(exc)
    for failure in registry.failures:
        console.print(f"[yellow]warning:[/] {failure}", highlight=False, soft_wrap=True)
    for heavy in registry.heavy_imports:
        console.print(f"[yellow]note:[/] {heavy}", highlight=False, soft_wrap=True)
    return registry


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            out_console.print(f"stratamap {version('stratamap')}")
        except PackageNotFoundError:
            out_console.print("stratamap (not installed)")
        raise typer.Exit()


@app.callback()
def _options(
    show_version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """Layered robot maps from indoor scans."""


ObserveOption = Annotated[
    list[str] | None,
    typer.Option(
        "--observe",
        help="Follow the run with an observer (see `stratamap plugins`), e.g. --observe rerun; repeatable.",
    ),
]


def _run(
    config: Path,
    out: Path | None,
    overrides: list[str] | None,
    observe: list[str] | None = None,
    resume: bool = False,
) -> tuple[dict, Path]:
    """Run a pipeline file; return its report and the folder it was written to."""
    from stratamap.core.config import load_pipeline
    from stratamap.core.pipeline import Pipeline

    with _interruptible(out):
        registry = _registry()
        try:
            validated = load_pipeline(config, overrides, registry, observe)
        except StratamapError as exc:
            _fail(exc)
        pipeline = Pipeline(validated, registry)
        observer = RichProgress(console)
        registry.plugin_manager.register(observer, name="rich-progress")
        try:
            report = pipeline.run(out, resume=resume)
        except StratamapError as exc:
            _fail(exc)
        finally:
            registry.plugin_manager.unregister(observer)
    return report, pipeline.out_dir


def _print_report(report: dict, out: Path) -> None:
    table = Table(title=f"stratamap run -> {out}", show_header=True)
    table.add_column("stage")
    table.add_column("plugin")
    table.add_column("seconds", justify="right")
    for st in report["stages"]:
        table.add_row(st["name"], st["plugin"], f"{st['seconds']:.2f}")
    out_console.print(table)
    for family, values in report.get("metrics", {}).items():
        flat = {k: v for k, v in values.items() if isinstance(v, (int, float))}
        out_console.print(f"[bold]{family}[/]: " + ", ".join(f"{k}={v:.3g}" for k, v in flat.items()))
    for w in report.get("warnings", []):
        out_console.print(f"[yellow]warning:[/] {w}", highlight=False, soft_wrap=True)
    written = sorted(p for p in out.iterdir() if not p.name.startswith(".")) if out.is_dir() else []
    exported = [o for st in report["stages"] if st["kind"] == "exporters" for o in st["outputs"]]
    out_console.print(f"[green]wrote[/] {out}/: " + ", ".join(p.name + ("/" if p.is_dir() else "") for p in written))
    for path in exported:
        out_console.print(f"  {path}", highlight=False)
    if (out / "report.html").is_file():
        # soft_wrap: a path longer than the line (80 columns when piped) stays whole, for copying
        out_console.print(f"[bold]report:[/] {out / 'report.html'}", highlight=False, soft_wrap=True)


@app.command()
def run(
    config: Annotated[Path, typer.Argument(help="Pipeline YAML file.")],
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Output folder (map/, export/, report.json).")] = None,
    overrides: SetOption = None,
    observe: ObserveOption = None,
    resume: Annotated[
        bool,
        typer.Option(
            "--resume",
            help=(
                "Checkpoint after each stage (beside the output); if a run of the same pipeline, settings and input "
                "into the same folder was interrupted or failed, start after its last finished stage."
            ),
        ),
    ] = False,
) -> None:
    """Run a pipeline: read, segment, map, complete, export; write map/, export/ and report.json."""
    report, written = _run(config, out, overrides, observe, resume)
    _print_report(report, written)


@app.command()
def bench(
    config: Annotated[Path, typer.Argument(help="Benchmark YAML file (configs/bench/*.yaml).")],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Results folder (records/, results.json/.csv/.md, figures).")
    ],
    workers: Annotated[
        int, typer.Option("--workers", "-j", help="Scenes run in parallel (worker processes or Ray CPUs).")
    ] = 1,
    executor: Annotated[str, typer.Option("--executor", help="local (worker processes) or ray.")] = "local",
    address: Annotated[
        str | None, typer.Option("--address", help="Ray cluster address (default: start a local Ray instance).")
    ] = None,
    overrides: SetOption = None,
) -> None:
    """Run every (scene, variant) pair of a benchmark; resumable; tables and figures from the records."""
    from stratamap.core.evaluation.bench import run_bench

    if executor not in ("local", "ray"):
        _fail(ConfigError([("--executor", f"expected 'local' or 'ray', got {executor!r}")]))
    try:
        with _interruptible(out):
            summary = run_bench(
                config,
                out,
                workers=workers,
                executor=executor,  # type: ignore[arg-type]
                address=address,
                overrides=overrides,
            )
    except StratamapError as exc:
        _fail(exc)
    out_console.print(f"{summary['records']} records ({summary['ran']} run now) -> {out}")
    for note in summary["skipped"]:
        out_console.print(f"[yellow]skipped:[/] {note}", highlight=False)
    for path in summary["files"]:
        out_console.print(f"  {path}", highlight=False)
    for line in summary.get("scale", []):
        out_console.print(line, highlight=False)


@app.command()
def validate(
    config: Annotated[Path, typer.Argument(help="Pipeline YAML file.")],
    overrides: SetOption = None,
) -> None:
    """Check a pipeline file (structure, every plugin's parameters, data flow) without running it."""
    from stratamap.core.config import load_pipeline

    registry = _registry()
    try:
        v = load_pipeline(config, overrides, registry)
    except StratamapError as exc:
        _fail(exc)
    names = " -> ".join([v.source.spec.plugin] + [s.spec.plugin for s in v.stages])
    out_console.print(f"[green]ok[/] {config}: {names}")


@app.command()
def plugins(as_json: Annotated[bool, typer.Option("--json", help="Print a JSON list.")] = False) -> None:
    """List installed stage plugins and run observers (kind, name, distribution, description)."""
    registry = _registry()
    entries = [info.to_dict() for info in [*registry.all(), *registry.observers()]]
    if as_json:
        sys.stdout.write(json.dumps(entries, indent=2) + "\n")
    else:
        table = Table(show_header=True)
        for col in ("kind", "name", "distribution", "description"):
            table.add_column(col)
        for e in entries:
            table.add_row(e["kind"], e["name"], e["distribution"], e["description"])
        out_console.print(table)


@app.command()
def schema(
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Write the schema here instead of stdout.")] = None,
) -> None:
    """Print the JSON Schema of pipeline files, with every installed plugin's parameters."""
    from stratamap.core.schema import pipeline_schema

    text = json.dumps(pipeline_schema(_registry()), indent=2) + "\n"
    if out is None:
        sys.stdout.write(text)
    else:
        from stratamap.core.atomic import write_text

        write_text(out, text)


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")] = Path("out/demo"),
    overrides: SetOption = None,
) -> None:
    """Run configs/demo.yaml: a synthetic room, mapped, completed and exported."""
    config = repo_root() / "configs" / "demo.yaml"
    if not config.is_file():
        _fail(StratamapError(f"{config} not found: run the demo from a stratamap checkout"))
    report, written = _run(config, out, overrides)
    _print_report(report, written)


@app.command()
def view(
    out: Annotated[Path, typer.Argument(help="A run's output folder (holding map/) or a saved map folder.")],
    host: Annotated[str, typer.Option("--host", help="Address to serve on (0.0.0.0 to reach it from elsewhere).")] = (
        "127.0.0.1"
    ),
    port: Annotated[int, typer.Option("--port", min=0, max=65535, help="Port (the next free one if taken).")] = 8080,
    max_points: Annotated[
        int, typer.Option("--max-points", min=1, help="Geometry points drawn at most (evenly subsampled).")
    ] = 400_000,
) -> None:
    """Open a saved map in a local web viewer (layers, objects, joints); runs until Ctrl-C."""
    import time

    from stratamap.core.viewer.app import open_viewer

    try:
        viewer = open_viewer(out, host=host, port=port, max_points=max_points)
    except StratamapError as exc:
        _fail(exc)
    out_console.print(f"stratamap view: {viewer.url}  (Ctrl-C to stop)", highlight=False, soft_wrap=True)
    sys.stdout.flush()
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    # The web server's threads can outlive stop() while a browser keeps its socket open; the viewer
    # writes nothing, so the process ends here rather than waiting for them.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


models_app = typer.Typer(help="Model libraries (the CAD database completers match against).", no_args_is_help=True)
app.add_typer(models_app, name="models")


def _progress_callback(label: str):
    progress = Progress(
        TextColumn(f"[bold]{label}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        disable=not console.is_terminal,
    )
    task = progress.add_task(label, total=None)
    printed = [-1]

    def update(done: int, total: int) -> None:
        progress.update(task, completed=done, total=total)
        if not console.is_terminal and total:  # without a terminal: a line every tenth of the work
            step = done * 10 // total
            if step > printed[0]:
                printed[0] = step
                console.print(f"  {label}: {done}/{total}", highlight=False)

    return progress, update


@models_app.command("build")
def models_build(
    out: Annotated[Path, typer.Option("--out", "-o", help="Library folder to write (replaced atomically).")],
    per_family: Annotated[int, typer.Option("--per-family", "-n", min=1, help="Models sampled per family.")] = 5,
    seed: Annotated[int, typer.Option(help="Seed of the sampled parameters.")] = 0,
    families: Annotated[str | None, typer.Option(help="Comma-separated families (default: all).")] = None,
) -> None:
    """Write a library of procedural models (models.json + a mesh per part)."""
    from stratamap.core.library.models import build_library

    progress, update = _progress_callback("building models")
    try:
        with _interruptible(out), progress:
            lib = build_library(out, per_family, seed, families.split(",") if families else None, update)
    except StratamapError as exc:
        _fail(exc)
    joints = sum(len(m.joints) for m in lib)
    out_console.print(
        f"[green]wrote[/] {out}: {len(lib)} models, {len(lib.families())} families, {len(lib.classes())} classes, "
        f"{joints} joints"
    )


@models_app.command("info")
def models_info(
    path: Annotated[
        Path,
        typer.Argument(
            help="A library folder (stratamap, PartNet-Mobility, ShapeNet layout, or meshes + classes.csv)."
        ),
    ],
) -> None:
    """Summarize a model library: models per class and family, joints, what was skipped and why."""
    from stratamap.core.library.models import ModelLibrary

    try:
        lib = ModelLibrary.load(path)
    except StratamapError as exc:
        _fail(exc)
    table = Table(show_header=True)
    for col in ("class", "family", "models", "revolute", "prismatic"):
        table.add_column(col)
    rows: dict[tuple[str, str], list[int]] = {}
    for m in lib:
        r = rows.setdefault((m.class_name, m.family), [0, 0, 0])
        r[0] += 1
        r[1] += sum(j.type == "revolute" for j in m.joints)
        r[2] += sum(j.type == "prismatic" for j in m.joints)
    for (c, f), (n, rv, pr) in sorted(rows.items()):
        table.add_row(c, f, str(n), str(rv), str(pr))
    out_console.print(table)
    skipped = [p for p in lib.problems if p.endswith("skipped")]
    out_console.print(
        f"{len(lib)} models of {len(lib.classes())} classes ({', '.join(lib.classes()) or 'none'}); "
        f"{len(skipped)} skipped",
        highlight=False,
        soft_wrap=True,
    )
    for p in lib.problems:
        label = "skipped" if p in skipped else "warning"
        console.print(f"[yellow]{label}:[/] {escape(p)}", highlight=False, soft_wrap=True)


@app.command()
def synth(
    spec: Annotated[Path, typer.Argument(help="Scene spec YAML (configs/scenes/*.yaml).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder to write (TUM RGB-D layout + gt/).")],
    seed: Annotated[int | None, typer.Option(help="Override the spec's seed.")] = None,
    frames: Annotated[int | None, typer.Option(help="Override the number of frames.")] = None,
) -> None:
    """Generate a synthetic sequence with full ground truth and write it in standard formats."""
    from stratamap.core.synthetic import SceneSpec, SyntheticWorld
    from stratamap.core.synthetic.writer import write_sequence

    try:
        scene_spec = SceneSpec.from_yaml(spec)
    except StratamapError as exc:
        _fail(exc)
    updates: dict[str, Any] = {}
    if seed is not None:
        updates["seed"] = seed
    if frames is not None:
        updates["trajectory"] = scene_spec.trajectory.model_copy(update={"frames": frames})
    scene_spec = scene_spec.model_copy(update=updates)
    world = SyntheticWorld(scene_spec)
    progress, update = _progress_callback("rendering")
    try:
        with _interruptible(out), progress:
            write_sequence(world, out, update)
    except StratamapError as exc:
        _fail(exc)
    skipped = f" (did not fit: {world.scene.skipped})" if world.scene.skipped else ""
    out_console.print(f"[green]wrote[/] {out}: {len(world)} frames, {len(world.scene.objects)} objects{skipped}")


def main() -> None:
    # Commands turn the errors they expect into "error: ..." lines themselves; this is the net for
    # the rest, so that no user mistake ends in a traceback.
    try:
        app()
    except StratamapError as exc:
        console.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False, soft_wrap=True)
        raise SystemExit(2) from None
    except OSError as exc:
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        console.print(f"[bold red]error:[/] {where}{exc.strerror or exc}", highlight=False, soft_wrap=True)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
