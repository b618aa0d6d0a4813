from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED_DATA = REPO.parent / "shared" / "data"


def shared_data(*parts: str) -> Path:
    """Path under ../shared/data/, or skip the test when it is absent (a user's clone has none)."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not available: {path}")
    return path


@pytest.fixture
def repo() -> Path:
    return REPO


#: The files that take longest in `make test` (pytest --durations, 2026-11-28), longest first: they
#: start first, so that none of them is left running alone at the end while the other processes idle.
LONGEST_FILES = (
    "integration/test_ray_completion.py",
    "integration/test_scenes.py",
    "plugins/mappers/test_mapping.py",
    "integration/test_bench_runs.py",
    "plugins/segmenters/test_clusters.py",
    "plugins/completers/test_completion.py",
    "integration/test_exports_at_rest.py",
    "integration/test_browser.py",
)


def pytest_collection_modifyitems(config, items):
    """The longest files first, then the other files holding slow tests, then the rest: with the
    files spread over processes (`make test`, pytest-xdist's `--dist loadfile`), a long file started
    last would leave the other processes idle at the end."""
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    tests_dir = Path(__file__).resolve().parent

    def rank(item) -> tuple[int, int]:
        name = item.path.relative_to(tests_dir).as_posix() if item.path.is_relative_to(tests_dir) else ""
        longest = LONGEST_FILES.index(name) if name in LONGEST_FILES else len(LONGEST_FILES)
        return longest, item.path not in slow_files

    items.sort(key=rank)  # stable: the order of tests within each file is kept


def low_poly_room():
    """A room mesh as a modeller or a simplifying scanner leaves it: a 5 x 4 x 2.6 m box whose floor,
    walls and ceiling are two triangles each, a table (top and four legs) and a cabinet in a corner;
    72 vertices in all, z up, coloured."""
    import trimesh

    def box(extents, centre):
        return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))

    def quad(p0, u, v):
        p0, u, v = map(np.asarray, (p0, u, v))
        return trimesh.Trimesh([p0, p0 + u, p0 + u + v, p0 + v], [[0, 1, 2], [0, 2, 3]])

    x, y, up = (5.0, 0, 0), (0, 4.0, 0), (0, 0, 2.6)
    shell = [quad((0, 0, 0), x, y), quad(up, y, x), quad((0, 0, 0), up, x), quad((0, 4, 0), x, up)]
    shell += [quad((0, 0, 0), y, up), quad((5, 0, 0), up, y)]
    table = [box((1.2, 0.8, 0.04), (2.5, 2.0, 0.73))]
    table += [box((0.05, 0.05, 0.71), (2.5 + sx * 0.55, 2.0 + sy * 0.35, 0.355)) for sx in (-1, 1) for sy in (-1, 1)]
    mesh = trimesh.util.concatenate([*shell, *table, box((0.8, 0.45, 1.8), (4.6, 0.225, 0.9))])
    mesh.visual.vertex_colors = np.tile([180, 160, 140, 255], (len(mesh.vertices), 1))
    return mesh
