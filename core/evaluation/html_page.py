"""Pieces of the self-contained HTML pages stratamap writes (a run's ``report.html``, a benchmark's):
figures embedded as PNG data URIs, tables, and the page around them. Nothing is fetched from the
network, so a page opens anywhere it is copied to."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path
from typing import Any

STYLE = (
    "body{font-family:sans-serif;margin:2em;max-width:1100px}table{border-collapse:collapse;margin:1em 0}"
    "td,th{border:1px solid #ccc;padding:2px 6px;font-size:13px}img{max-width:100%}"
    "pre{background:#f6f6f6;padding:1em;overflow-x:auto;font-size:12px}"
)
PNG_PREFIX = "data:image/png;base64,"


class Markup(str):
    """Text that is already HTML: table cells and paragraphs put it in as it is, unescaped."""


def escape(value: Any) -> str:
    return value if isinstance(value, Markup) else html.escape(str(value))


def bold(text: Any) -> Markup:
    return Markup(f"<strong>{escape(text)}</strong>")


def link(href: str, text: Any) -> Markup:
    return Markup(f'<a href="{html.escape(href, quote=True)}">{escape(text)}</a>')


def png_data_uri(fig: Any) -> str:
    """A matplotlib figure as a PNG data URI (the figure is closed)."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return PNG_PREFIX + base64.b64encode(buffer.getvalue()).decode("ascii")


def file_data_uri(path: str | Path) -> str:
    """A PNG file as a data URI."""
    return PNG_PREFIX + base64.b64encode(Path(path).read_bytes()).decode("ascii")


def drawn(draw: Any, *args: Any) -> Any:
    """What ``draw(*args)`` returns, or why it failed as ``"Error: message"``: a figure that cannot
    be drawn never costs a page its other contents."""
    try:
        return draw(*args)
    except Exception as exc:  # the page says what went wrong instead
        return f"{type(exc).__name__}: {exc}"


def figure(title: str, image: str | None) -> str:
    """A titled figure from a data URI; a reason (any other text) is shown as why it is missing;
    ``None`` (nothing to draw) gives nothing."""
    if image is None:
        return ""
    if image.startswith("data:"):
        return f'<h2>{escape(title)}</h2><figure><img class="figure" alt="{escape(title)}" src="{image}"></figure>'
    return f"<h2>{escape(title)}</h2><p>not drawn: {escape(image)}</p>"


def table(header: list[Any], rows: list[list[Any]], cls: str) -> str:
    """An HTML table; cells are escaped unless they are :class:`Markup`."""
    head = "".join(f"<th>{escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{escape(v)}</td>" for v in row) + "</tr>" for row in rows)
    return f'<table class="{escape(cls)}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def dict_table(rows: list[dict[str, Any]], cls: str) -> str:
    """A table with one row per dict (the first dict's keys as the header), or "none"."""
    if not rows:
        return "<p>none</p>"
    return table(list(rows[0]), [list(row.values()) for row in rows], cls)


def page(title: str, parts: list[str]) -> str:
    """The whole document around ``parts`` (HTML fragments)."""
    head = f"<!doctype html><html><head><meta charset='utf-8'><title>{escape(title)}</title><style>{STYLE}</style>"
    return head + "</head><body>" + "".join(parts) + "</body></html>\n"
