"""A benchmark's report.html: self-contained (figures embedded as PNG data URIs), the tables of
results.md row for row, a link to each run's own report.html, the benchmark file; a figure that
cannot be drawn is named with the reason and costs the page nothing else."""

from __future__ import annotations

import base64
import html
import io
import re
from html.parser import HTMLParser
from pathlib import Path

import pytest
from PIL import Image

from stratamap.core.evaluation.bench import load_bench, run_bench
from stratamap.core.evaluation.bench_report import write_reports
from tests.core.evaluation.test_bench import tiny_bench

PNG_URI = "data:image/png;base64,"


class Page(HTMLParser):
    """Table rows (cells as text, ``**x**`` where the cell is bold), image sources and link targets."""

    def __init__(self, text: str):
        super().__init__()
        self.rows: list[list[str]] = []
        self.images: list[str] = []
        self.links: list[str] = []
        self.cell: str | None = None
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "tr":
            self.rows.append([])
        elif tag in ("td", "th"):
            self.cell = ""
        elif tag == "strong" and self.cell is not None:
            self.cell += "**"
        elif tag == "img":
            self.images.append(attrs["src"])
        elif tag == "a":
            self.links.append(attrs["href"])

    def handle_endtag(self, tag):
        if tag == "strong" and self.cell is not None:
            self.cell += "**"
        elif tag in ("td", "th"):
            self.rows[-1].append(self.cell)
            self.cell = None

    def handle_data(self, data):
        if self.cell is not None:
            self.cell += data


def markdown_rows(text: str) -> list[list[str]]:
    """Every table row of a Markdown file (header rows included, separator rows not), as cells."""
    rows = []
    for line in text.splitlines():
        if line.startswith("|") and not re.fullmatch(r"\|(-+\|)+", line):
            rows.append([cell.strip() for cell in line[1:-1].split("|")])
    return rows


def png_bytes(src: str) -> bytes:
    assert src.startswith(PNG_URI), src[:40]
    data = base64.b64decode(src[len(PNG_URI) :], validate=True)
    with Image.open(io.BytesIO(data)) as image:
        assert image.format == "PNG" and image.width > 50 and image.height > 50
    return data


@pytest.mark.slow
def test_bench_page_is_self_contained_with_the_tables_figures_config_and_run_reports(tmp_path):
    config = tiny_bench(tmp_path, frames=8)
    out = tmp_path / "out"
    summary = run_bench(config, out, progress=False)
    page_path = out / "report.html"
    assert summary["files"][-1] == str(page_path)
    text = page_path.read_text()
    page = Page(text)

    # Every figure of the results folder is on the page, embedded byte for byte; nothing is fetched.
    figures = sorted(out.glob("*.png"))
    assert len(figures) >= 2
    assert sorted(png_bytes(src) for src in page.images) == sorted(p.read_bytes() for p in figures)
    assert not re.search(r"""(src|href)=["']?(https?:|//)""", text) and "<script" not in text

    # Every table row of results.md, bold cells included, is a row of the page.
    md_rows = markdown_rows((out / "results.md").read_text())
    assert len(md_rows) > 10
    missing = [row for row in md_rows if row not in page.rows]
    assert not missing, missing[:3]
    assert any(cell.startswith("**") for row in page.rows for cell in row)  # the best values stand out

    # One link per run, relative, to that run's own report.html (a page with its map drawn).
    assert len(page.links) == summary["records"] == 2
    for href in page.links:
        target = (out / href).resolve()
        assert not Path(href).is_absolute() and target.name == "report.html" and target.is_file()
        assert target.is_relative_to(out.resolve() / "runs")
        run_page = Page(target.read_text())
        assert run_page.images and all(png_bytes(src) for src in run_page.images)
    assert {Path(href).parent.name for href in page.links} == {"none", "bbox"}

    # The benchmark file that produced it, as written.
    assert html.escape(config.read_text()) in text


def _records_needing_the_navigation_figure() -> list[dict]:
    def record(scene: str, variant: str) -> dict:
        return {
            "scene": scene,
            "variant": variant,
            "seconds_total": 1.0,
            "peak_memory_mb": 100.0,
            "metrics": {"panoptic": {"pq": 0.6}, "navigation": {"robot_radius": 0.4, "colliding_multimap": 0.0}},
            "details": {
                "pq_by_class": {"chair": 0.5, "table": 0.7},
                "navigation": [{"laser_only": [[0, 0], [1, 1]], "multimap": [[0, 0], [1, 1]]}],
            },
        }

    return [record("a", "none"), record("a", "bbox")]


@pytest.mark.parametrize("grids", ["absent", "corrupt"])
def test_a_figure_that_cannot_be_drawn_leaves_the_page_and_the_other_figures(tmp_path, grids):
    spec, bench_file = load_bench(tiny_bench(tmp_path))
    out = tmp_path / "out"
    npz = out / "runs" / "a" / "none" / "navigation.npz"
    npz.parent.mkdir(parents=True)
    if grids == "corrupt":
        npz.write_bytes(b"not a numpy archive")
    (out / "navigation.png").write_bytes(b"left by an earlier build")
    results = {"name": "tiny", "records": _records_needing_the_navigation_figure(), "skipped": []}

    written = write_reports(results, spec, out, bench_file)

    assert written[-1] == out / "report.html"
    assert not (out / "navigation.png").exists()  # a stale figure would show other records
    text = (out / "report.html").read_text()
    reason = re.search(r"<h2>navigation\.png</h2><p>not drawn: ([^<]+)</p>", text)
    assert reason, "the page names the missing figure"
    expected = {
        "absent": "runs/a/none/navigation.npz not found (written beside the run that planned the paths)",
        "corrupt": "runs/a/none/navigation.npz: expected a NumPy .npz archive of the planning grids",
    }
    assert html.unescape(reason.group(1)) == f"DataError: {expected[grids]}"
    md = (out / "results.md").read_text()
    assert f"- navigation.png not drawn: {html.unescape(reason.group(1))}" in md
    # The other figure and the tables are all there.
    page = Page(text)
    assert [png_bytes(src) for src in page.images] == [(out / "pq_by_class.png").read_bytes()]
    assert all(row in page.rows for row in markdown_rows(md))
    # Runs whose folders hold no report.html (a remote Ray task's, or an older version's) get no link.
    assert page.links == [] and ["a", "none", "1.0", "100", "–"] in page.rows
