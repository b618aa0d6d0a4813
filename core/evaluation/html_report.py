"""``report.html``: a run's map for a person to look at, beside ``report.json``.

One self-contained file (figures embedded as PNG, no network): the top-down map coloured by class
and by instance with labelled boxes and the support edges of the contact graph, the occupancy
layers side by side, a table of objects (class, how it got it, points, completion model, score, scale, supporter,
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
from stratamap.core.map.instances import naming_text

#: Pixels across the longer side of a top-down view: finer than the figure shows adds nothing.
RASTER_PIXELS = 560


def top_down_raster(xy: np.ndarray, z: np.ndarray, rgba: np.ndarray) -> tuple[np.ndarray, tuple[float, ...]]:
    """Points seen from above as an RGBA image (transparent where none falls) and its extent
    (xmin, xmax, ymin, ymax): each pixel shows the highest point in it and its eight neighbours
    (tabletops over floors), so a surface sampled sparser than the pixels still reads as a surface."""
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    pixel = max(float((hi - lo).max()) / RASTER_PIXELS, 1e-6)
    width, height = (np.floor((hi - lo) / pixel).astype(np.int64) + 1).tolist()
    col, row = (np.floor((xy - lo) / pixel).astype(np.int64)).T
    flat = np.minimum(row, height - 1) * width + np.minimum(col, width - 1)
    order = np.lexsort((z, flat))
    flat = flat[order]
    top = np.r_[flat[1:] != flat[:-1], True]  # the last, highest, point of each pixel
    zbuf = np.full(height * width, -np.inf)
    image = np.zeros((height * width, 4))
    zbuf[flat[top]], image[flat[top]] = z[order][top], rgba[order][top]
    zbuf, image = zbuf.reshape(height, width), image.reshape(height, width, 4)
    best, filled = zbuf.copy(), image.copy()
    padded_z = np.pad(zbuf, 1, constant_values=-np.inf)
    padded = np.pad(image, ((1, 1), (1, 1), (0, 0)))
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            z_near = padded_z[1 + dr : 1 + dr + height, 1 + dc : 1 + dc + width]
            take = z_near > best
            best[take] = z_near[take]
            filled[take] = padded[1 + dr : 1 + dr + height, 1 + dc : 1 + dc + width][take]
    extent = (float(lo[0]), float(lo[0] + width * pixel), float(lo[1]), float(lo[1] + height * pixel))
    return filled, extent


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
    keep = np.arange(len(pts))
    if semantics is not None and len(semantics) == len(pts) and "ceiling" in semantics.vocabulary:
        # Seen from above, a room's ceiling would hide everything under it.
        keep = keep[np.asarray(semantics.class_ids)[keep] != semantics.vocabulary.id("ceiling")]
    if not len(keep):
        return None
    if semantics is not None and len(semantics) == len(pts):
        ids = semantics.class_ids if by == "class" else semantics.instance_ids
        palette = _palette(plt)
        color = palette[np.asarray(ids)[keep] % len(palette)]
        color[np.asarray(ids)[keep] == 0] = (0.75, 0.75, 0.75, 1.0)
    elif geometry.colors is not None:
        color = np.c_[np.clip(geometry.colors[keep], 0, 1), np.ones(len(keep))]
    else:
        color = np.tile((0.4, 0.4, 0.4, 1.0), (len(keep), 1))
    image, extent = top_down_raster(pts[keep, :2], pts[keep, 2], color)
    fig, ax = plt.subplots(figsize=(7, 6))
    ax.imshow(image, origin="lower", extent=extent, interpolation="nearest")
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


#: How fronts are drawn: colour by label.
FRONT_COLOURS = {"cupboard": "#4c9be8", "appliance": "#9b6ad6", "drawer": "#f0a030", "panel": "#cccccc"}


def fronts_figure(data: Any, most: int = 12) -> str | None:
    """Each storage object's face as the ``fronts`` completer saw it (``attributes['fronts']``):
    its fronts by label, the hinge side of every door as a thick edge, handles and knobs; None when
    no object has fronts."""
    objects = [inst for inst in data.map.instances or [] if inst.attributes.get("fronts")][:most]
    if not objects:
        return None
    import matplotlib.pyplot as plt

    cols = min(3, len(objects))
    rows = (len(objects) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    for ax in axes.ravel()[len(objects) :]:
        ax.axis("off")
    for ax, inst in zip(axes.ravel(), objects, strict=False):
        for front in inst.attributes["fronts"]:
            x0, x1, z0, z1 = front["rect"]
            colour = FRONT_COLOURS.get(front["label"], "#cccccc")
            ax.add_patch(plt.Rectangle((x0, z0), x1 - x0, z1 - z0, fc=colour, ec="k", lw=0.8, alpha=0.8))
            edge = {
                "left": ([x0, x0], [z0, z1]),
                "right": ([x1, x1], [z0, z1]),
                "top": ([x0, x1], [z1, z1]),
                "bottom": ([x0, x1], [z0, z0]),
            }.get(front.get("hinge") or "")
            if edge is not None:
                ax.plot(*edge, color="#b00020", lw=3)
            ax.text((x0 + x1) / 2, (z0 + z1) / 2, front["label"], ha="center", va="center", fontsize=7)
            for fx in front.get("fixtures", []):
                ax.plot(fx["x"], fx["z"], "ks" if fx["kind"] == "handle" else "ko", ms=4)
        ax.autoscale()
        ax.set_aspect("equal")
        ax.set_title(f"{inst.class_name} {inst.id} (seen from the front; red: hinge side)", fontsize=8)
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
                "named by": naming_text(inst),
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
    parts.append(figure("Fronts of storage objects", drawn(fronts_figure, data)))
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
