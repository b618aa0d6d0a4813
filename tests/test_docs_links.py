"""The documentation's own links: every relative link in the README, the changelog, docs/ and
examples/ names a file of the repository and, where it names a heading, a heading of that file."""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

import pytest

from tests.conftest import REPO

FENCED = re.compile(r"```.*?```", re.S)
LINK = re.compile(r"\]\(([^)\s]+)\)")


def documents() -> list[Path]:
    pages = [REPO / "README.md", REPO / "CHANGELOG.md"]
    return pages + sorted((REPO / "docs").rglob("*.md")) + sorted((REPO / "examples").rglob("*.md"))


@cache  # a page many links point to is read once
def anchors(page: Path) -> frozenset[str]:
    """The heading anchors GitHub gives a page: lower case, punctuation dropped, spaces to
    hyphens, a repeated heading suffixed -1, -2, ..."""
    found: set[str] = set()
    seen: dict[str, int] = {}
    for heading in re.findall(r"^#{1,6}\s+(.*)$", FENCED.sub("", page.read_text()), re.M):
        slug = re.sub(r"[^\w\- ]", "", heading.replace("`", "").strip().lower()).replace(" ", "-")
        found.add(slug if slug not in seen else f"{slug}-{seen[slug]}")
        seen[slug] = seen.get(slug, 0) + 1
    return frozenset(found)


def test_anchors_follow_githubs_rules():
    page = REPO / "docs" / "generalization.md"
    assert {"measured", "where-the-class-aware-f1-is-lost", "known-limits"} <= anchors(page)


@pytest.mark.parametrize("page", documents(), ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_resolves(page: Path):
    broken = []
    for target in LINK.findall(FENCED.sub("", page.read_text())):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # https:, mailto:, ...
            continue
        path, _, heading = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(f"{target}: no such file")
        elif heading and dest.suffix == ".md" and heading not in anchors(dest):
            broken.append(f"{target}: no such heading")
    assert not broken, broken
