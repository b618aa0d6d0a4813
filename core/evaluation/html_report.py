"""``report.html``: a run's map for a person to look at, beside ``report.json``.

One self-contained file (figures embedded as PNG, no network): the top-down map coloured by class
and by instance with labelled boxes and the support edges of the contact graph, the occupancy
layers side by side, a table of objects (class, points, completion model, score, scale, supporter,
joints), metrics, stage timings and warnings. It is written by the built-in implementation of
``stratamap_pipeline_end``, so every ``stratamap run`` with ``output.report`` on writes one.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.atomic import write_text
from stratamap.core.evaluation.html_page import dict_table, drawn, figure, page, png_data_uri
from stratamap.core.hookspecs import hookimpl

MAX_POINTS = 60_000  # drawn in the top-down views; more add nothing visible


def _subsample(n: int) -> np.ndarray:
    return np.arange(n) if n <= MAX_POINTS else np.linspace(0, n - 1, MAX_POINTS).astype(np.int64)


def _palette(plt: Any) -> np.ndarray:
    """40 distinct RGBA colours (tab20, then tab20b): the default vocabulary's 22 classes each get
    their own, so `object` (21) is not coloured as `floor` (1)."""
    return np.array([(*rgb, 1.0) for name in ("tab20", "tab20b") for rgb in plt.get_cmap(name).colors])


def _supporters(data: Any) -> dict[Any, Any]:
    graph = data.map.contact_graph
    if graph is None:
        return {}
    return {child: parent for parent, child in graph.support.edges()}


def top_down(data: Any, by: str) -> str | None:
    """The map from above, points coloured ``by`` class or instance, object boxes labelled."""
    geometry, semantics, instances = data.map.geometry, data.map.semantics, data.map.instances
    if geometry is None or len(geometry) == 0:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = geometry.points
    keep = _subsample(len(pts))
    if semantics is not None and len(semantics) == len(pts) and "ceiling" in semantics.vocabulary:
        # Seen from above, a room's ceiling would hide everything under it.
        keep = keep[np.asarray(semantics.class_ids)[keep] != semantics.vocabulary.id("ceiling")]
    if semantics is not None and len(semantics) == len(pts):
        ids = semantics.class_ids if by == "class" else semantics.instance_ids
        palette = _palette(plt)
        color = palette[np.asarray(ids)[keep] % len(palette)]
        color[np.asarray(ids)[keep] == 0] = (0.75, 0.75, 0.75, 1.0)
    elif geometry.colors is not None:
        color = geometry.colors[keep]
    else:
        color = "0.4"
    fig, ax = plt.subplots(figsize=(7, 6))
    order = np.argsort(pts[keep, 2])  # higher points drawn last: tabletops over floors
    ax.scatter(
        pts[keep][order, 0],
        pts[keep][order, 1],
        s=0.3,
        c=np.asarray(color)[order] if not isinstance(color, str) else color,
    )
    centers = {}
    for inst in instances or []:
        corners = np.vstack([inst.box.corners_2d(), inst.box.corners_2d()[:1]])
        ax.plot(corners[:, 0], corners[:, 1], color="black", linewidth=0.8)
        centers[inst.id] = inst.box.center[:2]
        ax.annotate(f"{inst.class_name} {inst.id}", inst.box.center[:2], fontsize=6, ha="center", va="center")
    for child, parent in _supporters(data).items():
        if child in centers and parent in centers:
            (x0, y0), (x1, y1) = centers[parent], centers[child]
            ax.annotate("", (x1, y1), (x0, y0), arrowprops={"arrowstyle": "->", "color": "tab:red", "lw": 0.8})
    if by == "class" and semantics is not None and len(semantics) == len(pts):
        from matplotlib.patches import Patch

        present = [int(c) for c in np.unique(semantics.class_ids) if c > 0]
        palette = _palette(plt)
        handles = [Patch(color=palette[c % len(palette)], label=semantics.vocabulary.name(c)) for c in present]
        ax.legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    title = "classes" if by == "class" else "instances"
    ax.set_title(f"top-down, coloured by {title} (ceiling left out); red arrows: supporter -> supported")
    return png_data_uri(fig)


def occupancy_layers(data: Any) -> str | None:
    """The occupancy layers side by side, in world coordinates."""
    layers = data.map.occupancy
    if not layers:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    preferred = ["slam", "objects", "multimap"]
    names = [n for n in preferred if n in layers] + sorted(n for n in layers if n not in preferred)
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 4), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        grid = layers[name]
        h, w = grid.data.shape
        x0, y0 = grid.origin[0], grid.origin[1]
        shown = np.where(grid.data < 0, 0.5, 1.0 - np.clip(grid.data, 0, 100) / 100.0)
        extent = (x0, x0 + w * grid.resolution, y0, y0 + h * grid.resolution)
        ax.imshow(shown, origin="lower", cmap="gray", vmin=0, vmax=1, extent=extent)
        ax.set_title(f"{name} ({grid.resolution:g} m cells)")
        ax.set_aspect("equal")
    return png_data_uri(fig)


def object_rows(data: Any) -> list[dict[str, Any]]:
    """One row per object of the map: what a person checks first."""
    supporters = _supporters(data)
    rows = []
    for inst in data.map.instances or []:
        c = inst.completion
        rows.append(
            {
                "id": inst.id,
                "class": inst.class_name,
                "points": len(inst.points),
                "size (m)": " x ".join(f"{v:.2f}" for v in inst.box.size),
                "completion": "-" if c is None else (c.model_id or c.completer),
                "score": "-" if c is None else f"{c.score:.3g}",
                "scale": "-" if c is None else " x ".join(f"{v:.2f}" for v in c.scale),
                "supporter": supporters.get(inst.id, "-"),
                "joints": "-" if c is None or not c.joints else ", ".join(f"{j.name} ({j.type})" for j in c.joints),
            }
        )
    return rows


def _metric_rows(metrics: dict[str, Any]) -> list[dict[str, Any]]:
    rows = []
    for family, values in metrics.items():
        if isinstance(values, dict):
            flat = {k: v for k, v in values.items() if isinstance(v, int | float) and not isinstance(v, bool)}
            rows.append({"family": family, "values": ", ".join(f"{k}={v:.4g}" for k, v in flat.items())})
    return rows


def render(data: Any, report: dict[str, Any]) -> str:
    """The whole page."""
    figures = [
        ("Map by class", drawn(top_down, data, "class")),
        ("Map by instance", drawn(top_down, data, "instance")),
        ("Occupancy layers", drawn(occupancy_layers, data)),
    ]
    stages = [
        {"stage": s["name"], "plugin": s["plugin"], "kind": s["kind"], "seconds": f"{s['seconds']:.2f}"}
        for s in report.get("stages", [])
    ]
    parts = [
        f"<h1>stratamap run report</h1><p>pipeline: {html.escape(str(report.get('pipeline')))}; "
        f"{report.get('frames', 0)} frames; {report.get('seconds_total', 0):.1f} s; "
        f"layers: {html.escape(json_line(report.get('layers', {})))}</p>",
    ]
    parts += [figure(title, image) for title, image in figures]
    parts.append("<h2>Objects</h2>" + dict_table(object_rows(data), "objects"))
    parts.append("<h2>Metrics</h2>" + dict_table(_metric_rows(report.get("metrics", {})), "metrics"))
    parts.append("<h2>Stages</h2>" + dict_table(stages, "stages"))
    warnings = report.get("warnings", [])
    parts.append(
        "<h2>Warnings</h2>"
        + ("<ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in warnings) + "</ul>" if warnings else "<p>none</p>")
    )
    return page("stratamap run report", parts)


def json_line(value: Any) -> str:
    """``{"geometry": {"points": 5}}`` as ``geometry points 5``, nested dicts flattened."""
    if not isinstance(value, dict):
        return str(value)
    return "; ".join(f"{k} {json_line(v) if isinstance(v, dict) else v}" for k, v in value.items())


def write_report(data: Any, report: dict[str, Any], folder: str | Path) -> Path:
    """``folder/report.html`` for the run whose blackboard is ``data`` and whose report is ``report``."""
    return write_text(Path(folder) / "report.html", render(data, report))


@hookimpl
def stratamap_pipeline_end(pipeline: Any, report: dict) -> None:
    """Write report.html beside report.json (when the pipeline writes a report)."""
    if not pipeline.validated.spec.output.report or pipeline.out_dir is None or pipeline.data is None:
        return
    write_report(pipeline.data, report, pipeline.out_dir)
