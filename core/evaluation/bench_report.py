"""Tables and figures of a benchmark, rebuilt from its records (see :mod:`stratamap.core.evaluation.bench`).

``results.csv``: one row per run, metrics flattened to ``family.key`` columns. ``results.md``: a
table per metric family, variants as columns, mean ± std over scenes, the best value in bold.
Figures (PNG, matplotlib): Chamfer distance by visibility per completer, PQ by class, the
navigation figure, seconds per object against library size when the variants vary it, and
seconds per frame and peak memory against floor area when the scenes vary it (with a table); a
figure that cannot be drawn is named with the reason instead. ``report.html``: the same tables
and figures in one self-contained page, with the benchmark file and a link to each run's own
``report.html``.
"""

from __future__ import annotations

import csv
import io
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.atomic import atomic_path, write_text
from stratamap.core.documents import read_text
from stratamap.core.errors import DataError

#: Families in table order; keys not listed still appear (sorted) after these.
FAMILIES = [
    "detection",
    "completion",
    "panoptic",
    "instances",
    "graph",
    "classification",
    "physics",
    "navigation",
    "trajectory",
    "cost",
]
LOWER_IS_BETTER = (
    "chamfer",
    "error",
    "ged",
    "wrong_support",
    "missing",
    "extra",
    "displacement",
    "penetration",
    "colliding",
    "seconds",
    "memory",
    "ate",
    "rpe",
    "largest_share",
    "elsewhere",
)
SKIP = ("count", "frames", "objects", "true_positives", "predicted", "ground_truth", "free_bodies", "robot_radius")


def flatten(metrics: dict[str, Any], prefix: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    for key, value in metrics.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            if key == "by_class" and not name.startswith("completion"):
                continue
            out.update(flatten(value, name + "."))
        elif isinstance(value, bool):
            out[name] = float(value)
        elif isinstance(value, (int, float)) and value is not None and np.isfinite(value):
            out[name] = float(value)
    return out


def record_row(rec: dict[str, Any]) -> dict[str, float]:
    row = flatten(rec.get("metrics", {}))
    row["cost.seconds_total"] = float(rec.get("seconds_total", 0.0))
    row["cost.peak_memory_mb"] = float(rec.get("peak_memory_mb", 0.0))
    return row


def lower_is_better(key: str) -> bool:
    return (
        any(tag in key.split(".")[-1] or tag in key for tag in LOWER_IS_BETTER)
        and "accuracy" not in key
        and "fscore" not in key
    )


def write_reports(results: dict[str, Any], spec: Any, out: Path, bench_file: str | Path | None = None) -> list[Path]:
    """``results.csv``, ``results.md``, the figures and ``report.html`` (listed last) under ``out``;
    ``bench_file`` is the benchmark file shown on the page (default: the spec as validated)."""
    records = results["records"]
    variants = [v.name for v in spec.variants]
    rows = [record_row(r) for r in records]
    # Figures first: results.md links the figures this build wrote (it used to glob for PNGs before
    # they existed, so a benchmark's first results.md had no figures section).
    drawn = draw_figures(records, variants, out)
    figures = [image for _, image in drawn if isinstance(image, Path)]
    tables = result_tables(results, spec, rows, variants)
    return [
        write_csv(records, rows, out / "results.csv"),
        write_markdown(results, spec, rows, variants, out / "results.md", figures=figures, drawn=drawn),
        *figures,
        write_html(results, spec, tables, drawn, out, bench_file),
    ]


def write_csv(records: list[dict[str, Any]], rows: list[dict[str, float]], path: Path) -> Path:
    columns = sorted({k for row in rows for k in row})
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(["scene", "variant", *columns])
    for rec, row in zip(records, rows, strict=True):
        writer.writerow([rec["scene"], rec["variant"], *[("" if k not in row else f"{row[k]:.6g}") for k in columns]])
    return write_text(path, buf.getvalue())


def table_values(records, rows, variants) -> dict[str, dict[str, list[float]]]:
    """key -> variant -> values over scenes."""
    values: dict[str, dict[str, list[float]]] = {}
    for rec, row in zip(records, rows, strict=True):
        for key, val in row.items():
            if key.split(".")[-1] in SKIP or ".segments." in key:
                continue
            values.setdefault(key, {v: [] for v in variants}).setdefault(rec["variant"], []).append(val)
    return values


@dataclass
class ResultTable:
    """One table of a benchmark's results, shared by ``results.md`` and ``report.html``: cells as
    Markdown text, the best value of a row as ``**bold**``."""

    title: str
    header: list[str]
    rows: list[list[str]]

    def markdown(self) -> list[str]:
        lines = [f"## {self.title}", "", "| " + " | ".join(self.header) + " |", "|" + "---|" * len(self.header)]
        cells = [[cell.replace("|", "\\|") for cell in row] for row in self.rows]  # an error may hold a |
        return lines + ["|" + "".join(f" {cell} |" if cell else " |" for cell in row) for row in cells] + [""]


def summary_lines(results: dict[str, Any], spec: Any, variants: list[str]) -> list[str]:
    """The paragraphs above the tables: description, counts, skipped scenes."""
    records = results["records"]
    scenes = {r["scene"] for r in records}
    lines = [spec.description.strip()] if spec.description else []
    lines.append(
        f"{len(records)} runs: {len(scenes)} scenes x {len(variants)} variants. Mean ± std over scenes; best in bold "
        "(for each row, lower or higher is better as the metric says)."
    )
    if results.get("skipped"):
        lines.append("Skipped: " + "; ".join(results["skipped"]))
    failures = results.get("failures") or []
    if failures:
        lines.append(
            f"Failed: {len(failures)} of {len(failures) + len(records)} runs, without results (table 'failed runs'); "
            "the next `stratamap bench` into this folder runs them again."
        )
    lines += network_lines(records, variants)
    return lines


def failures_table(results: dict[str, Any]) -> ResultTable | None:
    """The runs that failed: where and why, one line each."""
    failures = results.get("failures") or []
    if not failures:
        return None
    rows = [[f["scene"], f["variant"], f.get("stage") or "–", str(f["error"])] for f in failures]
    return ResultTable("failed runs", ["scene", "variant", "stage", "error"], rows)


def network_lines(records: list[dict[str, Any]], variants: list[str]) -> list[str]:
    """One paragraph per learned model a variant ran: its file, the families it was trained on and
    those it never saw (from the model's provenance)."""
    lines = []
    for variant in variants:
        networks = next((r.get("networks") for r in records if r["variant"] == variant and r.get("networks")), {})
        for stage, facts in sorted(networks.items()):
            text = f"Variant `{variant}`, stage `{stage}`: network `{facts.get('model', '?')}`"
            if facts.get("trained_on"):
                text += ", trained on the families " + ", ".join(f"`{f}`" for f in facts["trained_on"])
            if facts.get("held_out"):
                text += f". Held out: {facts['held_out']}"
            lines.append(text.rstrip(".") + ".")
    return lines


def labels_table(records: list[dict[str, Any]], variants: list[str]) -> ResultTable | None:
    """What each variant called the true objects of each class, summed over scenes (the class-agnostic
    matches at 3D box IoU >= 0.25; ``labels_of_matches``), and its predictions that matched nothing."""
    from stratamap.core.evaluation.detection import MISSED, sum_labels

    runs: dict[str, list[dict[str, Any]]] = {v: [] for v in variants}
    for rec in records:
        labels = rec.get("details", {}).get("labels_iou25")
        if labels and rec["variant"] in runs:
            runs[rec["variant"]].append(labels)
    by_variant = {v: sum_labels(labels) for v, labels in runs.items() if labels}
    if not any(summed["called"] or summed["extra"] for summed in by_variant.values()):
        return None
    called = {
        true: {v: summed["called"][true] for v, summed in by_variant.items() if true in summed["called"]}
        for true in sorted({t for summed in by_variant.values() for t in summed["called"]})
    }
    extra = {v: summed["extra"] for v, summed in by_variant.items()}

    def text(counts: dict[str, int], first: str | None) -> str:
        order = sorted(counts, key=lambda name: (name != first, name == MISSED, -counts[name], name))
        return ", ".join(f"{name} {counts[name]}" for name in order) if counts else "–"

    shown = list(by_variant)
    table = ResultTable(
        "detection: what the true objects were called (3D box IoU >= 0.25, summed over scenes)",
        ["true class", *shown],
        [],
    )
    for true in sorted(called):
        table.rows.append([true, *(text(called[true].get(v, {}), true) for v in shown)])
    table.rows.append(["*no true object*", *(text(extra.get(v, {}), None) for v in shown)])
    return table


def result_tables(
    results: dict[str, Any], spec: Any, rows: list[dict[str, float]], variants: list[str]
) -> list[ResultTable]:
    """The runs that failed (first, when some did), a table per metric family (variants as columns),
    one per ``per_scene`` metric, and Table IV of each run that classified planes."""
    records = results["records"]
    values = table_values(records, rows, variants)
    scenes = sorted({r["scene"] for r in records})
    failed = failures_table(results)
    tables = [] if failed is None else [failed]
    families = sorted(
        {k.split(".")[0] for k in values}, key=lambda f: (FAMILIES.index(f) if f in FAMILIES else len(FAMILIES), f)
    )
    for family in families:
        keys = sorted(k for k in values if k.split(".")[0] == family)
        table = ResultTable(family, ["metric", *variants], [])
        for key in keys:
            per = values[key]
            means = {v: float(np.mean(per[v])) if per.get(v) else None for v in variants}
            present = [m for m in means.values() if m is not None]
            best = (
                (min(present) if lower_is_better(key) else max(present))
                if len(present) > 1 and not np.allclose(present, present[0])
                else None
            )
            cells = []
            for v in variants:
                if means[v] is None:
                    cells.append("–")
                    continue
                text = f"{means[v]:.4g} ± {float(np.std(per[v])):.2g}"
                cells.append(f"**{text}**" if best is not None and np.isclose(means[v], best) else text)
            table.rows.append([key[len(family) + 1 :], *cells])
        tables.append(table)
    for key in spec.per_scene:
        table = ResultTable(f"{key} per scene", ["scene", *variants], [])
        for scene in scenes:
            cells = []
            for v in variants:
                rec = next(
                    (r for r, row in zip(records, rows, strict=True) if r["scene"] == scene and r["variant"] == v), None
                )
                value = record_row(rec).get(key) if rec is not None else None
                cells.append("–" if value is None else f"{value:.3f}")
            if any(c != "–" for c in cells):
                table.rows.append([scene, *cells])
        means = [np.mean(values[key][v]) if key in values and values[key].get(v) else None for v in variants]
        table.rows.append(["**mean**", *("–" if m is None else f"**{m:.3f}**" for m in means)])
        tables.append(table)
    labels = labels_table(records, variants)
    if labels is not None:
        tables.append(labels)
    scale = scale_table(records)
    if scale is not None:
        tables.append(scale)
    for rec in records:  # plane and furniture labels in the layout of the kitchen paper's Table IV
        if "classification" in rec.get("metrics", {}):
            from stratamap.core.evaluation.classification import format_table

            header, _, *lines = format_table(rec["metrics"]["classification"]).splitlines()
            tables.append(
                ResultTable(f"Table IV: {rec['scene']} ({rec['variant']})", _cells(header), [_cells(x) for x in lines])
            )
    return tables


def scale_rows(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per run of a scene whose size is known (``scale.area_m2``): frames, area, objects, coverage,
    seconds per frame, peak memory (building the map; the whole process, evaluation included) and
    the oracle's detection recall, by floor area."""
    rows = []
    for rec in records:
        scale = rec.get("scale") or {}
        if not scale.get("area_m2") or not scale.get("frames"):
            continue
        detection = rec.get("metrics", {}).get("detection", {})
        coverage = scale.get("coverage") or {}
        by_stage = rec.get("memory_by_stage") or {}
        rows.append(
            {
                "scene": rec["scene"],
                "variant": rec["variant"],
                "frames": int(scale["frames"]),
                "area_m2": float(scale["area_m2"]),
                "objects": int(scale.get("objects", 0)),
                "coverage_mean": coverage.get("mean"),
                "objects_seen": coverage.get("objects_seen"),
                "seconds": float(rec.get("seconds_total", 0.0)),
                "seconds_per_frame": float(rec.get("seconds_total", 0.0)) / int(scale["frames"]),
                "cpu_seconds_per_frame": (
                    float(rec["cpu_seconds_total"]) / int(scale["frames"]) if "cpu_seconds_total" in rec else None
                ),
                "map_peak_mb": max(by_stage.values()) if by_stage else None,
                "peak_mb": float(rec.get("peak_memory_mb", 0.0)),
                "recall": detection.get("recall"),
                "found": detection.get("true_positives"),
            }
        )
    # Only the variants run at several sizes: a library sweep on one scene is no series against area.
    areas: dict[str, set[float]] = {}
    for r in rows:
        areas.setdefault(r["variant"], set()).add(r["area_m2"])
    rows = [r for r in rows if len(areas[r["variant"]]) > 1]
    return sorted(rows, key=lambda r: (r["area_m2"], r["scene"], r["variant"]))


def scale_table(records: list[dict[str, Any]]) -> ResultTable | None:
    """The scaling table (:func:`scale_rows`), when some variant ran at more than one scene size."""
    rows = scale_rows(records)
    if len({r["area_m2"] for r in rows}) < 2:
        return None

    def num(value: Any, fmt: str) -> str:
        return "–" if value is None else format(value, fmt)

    table = ResultTable(
        "cost against scene size",
        [
            "scene",
            "variant",
            "frames",
            "floor m²",
            "objects",
            "coverage (mean share seen; objects seen)",
            "seconds",
            "s / frame",
            "CPU s / frame",
            "peak MB (map)",
            "peak MB (process)",
            "detection recall",
        ],
        [],
    )
    for r in rows:
        seen = "–" if r["objects_seen"] is None else f"{r['objects_seen']} / {r['objects']}"
        table.rows.append(
            [
                r["scene"],
                r["variant"],
                str(r["frames"]),
                f"{r['area_m2']:.0f}",
                str(r["objects"]),
                f"{num(r['coverage_mean'], '.2f')}; {seen}",
                f"{r['seconds']:.0f}",
                f"{r['seconds_per_frame']:.3f}",
                num(r["cpu_seconds_per_frame"], ".3f"),
                num(r["map_peak_mb"], ".0f"),
                f"{r['peak_mb']:.0f}",
                f"{num(r['recall'], '.3f')} ({num(r['found'], 'd')} / {r['objects']})",
            ]
        )
    return table


def area_figure(records: list[dict[str, Any]], out: Path) -> Path | None:
    """Seconds per frame and peak memory against floor area, one line per variant run at several sizes."""
    import matplotlib.pyplot as plt

    rows = scale_rows(records)
    if len({r["area_m2"] for r in rows}) < 2:
        return None
    fig, (ax_time, ax_memory) = plt.subplots(1, 2, figsize=(10, 4))
    for variant in sorted({r["variant"] for r in rows}):
        mine = [r for r in rows if r["variant"] == variant]
        areas = [r["area_m2"] for r in mine]
        ax_time.plot(areas, [r["seconds_per_frame"] for r in mine], marker="o", label=f"{variant}: wall")
        if all(r["cpu_seconds_per_frame"] is not None for r in mine):
            cpu = [r["cpu_seconds_per_frame"] for r in mine]
            ax_time.plot(areas, cpu, marker="s", ls="--", label=f"{variant}: CPU (all threads)")
        ax_memory.plot(areas, [r["peak_mb"] / 1024 for r in mine], marker="o", label=f"{variant}: process")
        if all(r["map_peak_mb"] is not None for r in mine):
            ax_memory.plot(
                areas,
                [r["map_peak_mb"] / 1024 for r in mine],
                marker="s",
                ls="--",
                label=f"{variant}: building the map",
            )
    for ax in (ax_time, ax_memory):
        ax.set_xlabel("floor area (m²)")
        ax.set_xlim(left=0)
        ax.set_ylim(bottom=0)
        ax.legend(fontsize=8)
    ax_time.set_ylabel("seconds per frame (all stages)")
    ax_memory.set_ylabel("peak resident memory (GB)")
    fig.suptitle("Cost against scene size")
    return _save(fig, out / "cost_vs_area.png")


def _cells(line: str) -> list[str]:
    """``| a | b |`` as ``["a", "b"]`` (an empty cell stays empty)."""
    return [cell.strip() for cell in line.strip()[1:-1].split("|")]


def write_markdown(
    results: dict[str, Any],
    spec: Any,
    rows: list[dict[str, float]],
    variants: list[str],
    path: Path,
    figures: list[Path] | None = None,
    drawn: list[tuple[str, Path | str]] | None = None,
) -> Path:
    """The tables, and a section linking ``figures`` (default: the PNGs beside ``path``) and saying
    why any figure of ``drawn`` could not be drawn."""
    lines = [f"# Benchmark: {spec.name}", ""]
    for paragraph in summary_lines(results, spec, variants):
        lines += [paragraph, ""]
    for table in result_tables(results, spec, rows, variants):
        lines += table.markdown()
    names = sorted(p.name for p in (path.parent.glob("*.png") if figures is None else figures))
    failed = [(name, image) for name, image in drawn or [] if not isinstance(image, Path)]
    if names:
        lines += ["## Figures", ""] + [f"![{name}]({name})" for name in names] + [""]
    if failed:
        lines += ([] if names else ["## Figures", ""]) + [f"- {name} not drawn: {reason}" for name, reason in failed]
        lines.append("")
    return write_text(path, "\n".join(lines))


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def chamfer_figure(records: list[dict[str, Any]], variants: list[str], out: Path) -> Path | None:
    """Chamfer-L1 by visibility, one line per completer variant."""
    import matplotlib.pyplot as plt

    objects = {
        v: [o for r in records if r["variant"] == v for o in r.get("details", {}).get("completion_objects", [])]
        for v in variants
    }
    if not any(objects.values()):
        return None
    bins = np.linspace(0, 1, 6)
    fig, ax = plt.subplots(figsize=(6, 4))
    for v, objs in objects.items():
        if not objs:
            continue
        vis = np.array([o["visibility"] for o in objs])
        cd = np.array([o["chamfer_l1"] for o in objs])
        idx = np.clip(np.digitize(vis, bins) - 1, 0, len(bins) - 2)
        centers = [(bins[i] + bins[i + 1]) / 2 for i in range(len(bins) - 1) if (idx == i).any()]
        medians = [float(np.median(cd[idx == i])) for i in range(len(bins) - 1) if (idx == i).any()]
        ax.plot(centers, medians, marker="o", label=v)
    ax.set_xlabel("visibility (share of the true surface observed)")
    ax.set_ylabel("Chamfer-L1 to the true shape (m, median)")
    ax.set_title("Completion error by visibility")
    ax.grid(alpha=0.3)
    ax.legend()
    return _save(fig, out / "chamfer_by_visibility.png")


def pq_figure(records: list[dict[str, Any]], variants: list[str], out: Path) -> Path | None:
    """Panoptic quality by class, one bar per variant."""
    import matplotlib.pyplot as plt

    pq = {
        v: [
            r["details"]["pq_by_class"]
            for r in records
            if r["variant"] == v and r.get("details", {}).get("pq_by_class")
        ]
        for v in variants
    }
    classes = sorted({c for rows in pq.values() for row in rows for c in row})
    if not classes:
        return None
    fig, ax = plt.subplots(figsize=(max(6, 0.5 * len(classes)), 4))
    width = 0.8 / max(1, sum(1 for rows in pq.values() if rows))
    k = 0
    for v, rows in pq.items():
        if not rows:
            continue
        # A class in no scene of this variant (neither true nor predicted) has no PQ: no bar, not a 0.
        means = [
            float(np.mean([row[c] for row in rows if row.get(c) is not None]))
            if any(row.get(c) is not None for row in rows)
            else np.nan
            for c in classes
        ]
        ax.bar(np.arange(len(classes)) + k * width, means, width, label=v)
        k += 1
    ax.set_xticks(np.arange(len(classes)) + 0.4 - width / 2, classes, rotation=45, ha="right")
    ax.set_ylabel("PQ")
    ax.set_title("Panoptic quality by class")
    ax.legend()
    return _save(fig, out / "pq_by_class.png")


def draw_figures(records: list[dict[str, Any]], variants: list[str], out: Path) -> list[tuple[str, Path | str]]:
    """Each figure the records call for, as (file name, the PNG written) or (file name, why it could
    not be drawn): one figure that fails costs the benchmark neither its tables nor its other figures."""
    import matplotlib

    matplotlib.use("Agg")
    from stratamap.core.evaluation.html_page import drawn

    drawers = (
        ("chamfer_by_visibility.png", chamfer_figure, (records, variants, out)),
        ("pq_by_class.png", pq_figure, (records, variants, out)),
        ("navigation.png", navigation_figure, (records, out)),
        ("seconds_vs_library.png", scaling_figure, (records, out)),
        ("cost_vs_area.png", area_figure, (records, out)),
    )
    figures: list[tuple[str, Path | str]] = []
    for name, draw, args in drawers:
        image = drawn(draw, *args)
        if isinstance(image, str):  # a PNG left by an earlier build no longer shows these records
            (out / name).unlink(missing_ok=True)
        if image is not None:
            figures.append((name, image))
    return figures


def navigation_figure(records: list[dict[str, Any]], out: Path) -> Path | None:
    """Paths planned on the laser-only map and on the multimap over the true obstacles, collisions marked."""
    import matplotlib.pyplot as plt

    from stratamap.core.evaluation.bench import safe

    rec = next((r for r in records if r.get("details", {}).get("navigation")), None)
    if rec is None:
        return None
    npz = out / "runs" / safe(rec["scene"]) / safe(rec["variant"]) / "navigation.npz"
    if not npz.is_file():  # e.g. the run was a Ray task on a machine that does not share this folder
        raise DataError(f"{npz.relative_to(out)} not found (written beside the run that planned the paths)")
    try:
        grids = np.load(npz)
    except (OSError, ValueError) as exc:  # numpy's words for a damaged archive name no file
        raise DataError(f"{npz.relative_to(out)}: expected a NumPy .npz archive of the planning grids") from exc
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    for ax, (title, key, hit) in zip(
        axes,
        (("laser-only map", "laser_only", "laser_collides"), ("multimap", "multimap", "multimap_collides")),
        strict=True,
    ):
        grid = grids["slam" if key == "laser_only" else "multimap"]
        # Each grid at its own origin and resolution (older files keep the multimap's only).
        own = "slam_origin" in grids.files and key == "laser_only"
        ox, oy = grids["slam_origin" if own else "origin"][:2]
        res = float(grids["slam_resolution" if own else "resolution"])
        extent = (ox, ox + grid.shape[1] * res, oy, oy + grid.shape[0] * res)
        ax.imshow(
            np.where(grid == 100, 0.0, np.where(grid == 0, 1.0, 0.6)),
            cmap="gray",
            origin="lower",
            extent=extent,
            vmin=0,
            vmax=1,
        )
        truth = grids["truth"]
        tox, toy = grids["truth_origin"][:2]
        tres = float(grids["truth_resolution"])
        ax.contour(
            np.arange(truth.shape[1]) * tres + tox + tres / 2,
            np.arange(truth.shape[0]) * tres + toy + tres / 2,
            (truth == 100).astype(float),
            levels=[0.5],
            colors="tab:orange",
            linewidths=0.8,
        )
        n_hit = 0
        for path in rec["details"]["navigation"]:
            xy = np.asarray(path[key])
            collided = bool(path[hit])
            n_hit += collided
            ax.plot(xy[:, 0], xy[:, 1], color="tab:red" if collided else "tab:blue", linewidth=1.4 if collided else 0.9)
        ax.set_title(f"{title}: {n_hit} of {len(rec['details']['navigation'])} paths hit 3D obstacles")
        ax.set_aspect("equal")
    fig.suptitle(
        f"A* for a robot of radius {rec['metrics']['navigation'].get('robot_radius', 0.4)} m ({rec['scene']}); orange: "
        "true obstacles in [0.1 m, robot height]"
    )
    return _save(fig, out / "navigation.png")


def scaling_figure(records: list[dict[str, Any]], out: Path) -> Path | None:
    """Seconds per object of the completer against library size, when the variants vary it."""
    import matplotlib.pyplot as plt

    points: dict[str, list[tuple[float, float]]] = {}
    # The scenes that ran several library sizes (a scene-size sweep runs one: its larger scenes would
    # otherwise weigh on that one size's point).
    sizes: dict[str, set] = {}
    for r in records:
        for p in r.get("plugins", []):
            if p["kind"] == "completers" and "library_per_family" in p["params"]:
                sizes.setdefault(r["scene"], set()).add(p["params"]["library_per_family"])
    for r in (r for r in records if len(sizes.get(r["scene"], ())) > 1):
        for p in r.get("plugins", []):
            if p["kind"] == "completers" and "library_per_family" in p["params"]:
                n = r["metrics"].get("completion", {}).get("objects") or 0
                sec = sum(v for k, v in r["seconds"].items() if k.endswith(":" + p["plugin"]))
                if n:
                    points.setdefault(p["plugin"], []).append((float(p["params"]["library_per_family"]), sec / n))
    if not points or all(len({x for x, _ in v}) < 2 for v in points.values()):
        return None
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, pts in points.items():
        xs = sorted({x for x, _ in pts})
        ax.plot(xs, [np.mean([s for x, s in pts if x == xv]) for xv in xs], marker="o", label=name)
    ax.set_xscale("log")
    ax.set_xlabel("library models per family")
    ax.set_ylabel("seconds per object")
    ax.set_title("Completion cost against library size")
    ax.legend()
    return _save(fig, out / "seconds_vs_library.png")


def _html_cell(cell: str) -> Any:
    """A Markdown cell of a :class:`ResultTable` for HTML: ``**best**`` in bold."""
    from stratamap.core.evaluation.html_page import bold

    match = re.fullmatch(r"\*\*(.*)\*\*", cell)
    return bold(match.group(1)) if match else cell


def write_html(
    results: dict[str, Any],
    spec: Any,
    tables: list[ResultTable],
    figures: list[tuple[str, Path | str]],
    out: Path,
    bench_file: str | Path | None = None,
) -> Path:
    """``out/report.html``, the benchmark for a person, self-contained (figures embedded): the tables
    of results.md, the figures (or why one could not be drawn), every run with a link to its own
    report.html, and the benchmark file that produced it."""
    import yaml

    from stratamap.core.evaluation.bench import safe
    from stratamap.core.evaluation.html_page import escape, figure, file_data_uri, link, page, table

    variants = [v.name for v in spec.variants]
    parts = [f"<h1>Benchmark: {escape(spec.name)}</h1>"]
    parts += [f"<p>{escape(paragraph)}</p>" for paragraph in summary_lines(results, spec, variants)]
    if results.get("versions"):
        parts.append("<p>versions: " + escape(", ".join(f"{k} {v}" for k, v in results["versions"].items())) + "</p>")
    for t in tables:
        cells = [[_html_cell(cell) for cell in row] for row in t.rows]
        parts.append(f"<h2>{escape(t.title)}</h2>" + table(t.header, cells, "results"))
    for name, image in figures:
        parts.append(figure(name, file_data_uri(image) if isinstance(image, Path) else image))
    runs = []
    for rec in results["records"]:
        report = f"runs/{safe(rec['scene'])}/{safe(rec['variant'])}/report.html"
        runs.append(
            [
                rec["scene"],
                rec["variant"],
                f"{rec.get('seconds_total', 0.0):.1f}",
                f"{rec.get('peak_memory_mb', 0.0):.0f}",
                link(report, "report.html") if (out / report).is_file() else "–",
            ]
        )
    parts.append("<h2>Runs</h2>" + table(["scene", "variant", "seconds", "peak memory (MB)", "report"], runs, "runs"))
    config, shown = yaml.safe_dump(spec.model_dump(mode="json"), sort_keys=False), "the benchmark, as validated"
    if bench_file is not None and Path(bench_file).is_file():  # as written, comments included
        config, shown = read_text(bench_file, "benchmark file"), str(bench_file)
    parts.append(f"<h2>Benchmark file</h2><p>{escape(shown)}</p><pre>{escape(config)}</pre>")
    return write_text(out / "report.html", page(f"stratamap benchmark: {spec.name}", parts))


def records_equal(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> bool:
    """Same runs with the same metrics (timings and memory aside)."""

    def key(rs):
        return sorted((r["scene"], r["variant"], json.dumps(r["metrics"], sort_keys=True)) for r in rs)

    return key(a) == key(b)
