"""The run report's top-down view: a raster of the map seen from above."""

from __future__ import annotations

import numpy as np

from stratamap.core.evaluation.html_report import RASTER_PIXELS, top_down_raster


def test_each_pixel_shows_its_highest_point_and_the_extent_holds_every_point():
    """A tabletop over a floor, each sampled sparser than the pixels: the tabletop's colour is shown
    where it is, whatever the order the points come in, and the floor beside it."""
    rng = np.random.default_rng(0)
    xs = np.arange(0.0, 4.0, 8.0 / RASTER_PIXELS)
    floor = np.c_[np.array(np.meshgrid(xs, xs)).reshape(2, -1).T, np.zeros(len(xs) ** 2)]
    table = np.c_[rng.uniform(1, 2, (40000, 2)), np.full(40000, 0.75)]
    points = np.vstack([table, floor])  # the table first: drawing in input order would bury it
    red, grey = (1.0, 0.0, 0.0, 1.0), (0.5, 0.5, 0.5, 1.0)
    colours = np.array([red] * len(table) + [grey] * len(floor))
    image, extent = top_down_raster(points[:, :2], points[:, 2], colours)
    assert image.shape[2] == 4 and max(image.shape[:2]) <= RASTER_PIXELS + 1
    xmin, xmax, ymin, ymax = extent
    assert xmin <= points[:, 0].min() and xmax >= points[:, 0].max()
    assert ymin <= points[:, 1].min() and ymax >= points[:, 1].max()

    def colour_at(x: float, y: float) -> tuple[float, ...]:
        col = int((x - xmin) / (xmax - xmin) * image.shape[1])
        row = int((y - ymin) / (ymax - ymin) * image.shape[0])
        return tuple(image[row, col])

    assert colour_at(1.5, 1.5) == red
    assert colour_at(3.0, 3.0) == grey


def test_a_sparse_surface_is_drawn_whole_and_empty_space_stays_clear():
    """Points spaced two pixels apart fill the pixels between them; far from any point the image is
    transparent."""
    pixel = 4.0 / RASTER_PIXELS
    xs = np.arange(0.0, 1.0, 2 * pixel)
    grid = np.array(np.meshgrid(xs, xs)).reshape(2, -1).T
    points = np.vstack([grid, [[4.0, 4.0]]])
    image, _ = top_down_raster(points, np.zeros(len(points)), np.ones((len(points), 4)))
    inner = image[5:40, 5:40, 3]
    assert inner.min() == 1.0  # every pixel of the patch is drawn
    assert image[200:300, 200:300, 3].max() == 0.0  # nothing there
