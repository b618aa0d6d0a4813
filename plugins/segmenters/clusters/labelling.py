"""The one object every pass of ``clusters`` reads and changes: the map's points on the working grid,
what the geometry passes found per cell (layout, support surfaces, segments, objects), and the
point labels the instance passes make (class, instance, how each instance got its class), with each
object's shape cached. A pass changes it only by assigning a field a new array or through
:meth:`Labelling.relabel`, never by writing into an array another pass handed it."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from stratamap.plugins.segmenters.clusters.layout import LAYOUT_NAMES, NONE
from stratamap.plugins.segmenters.clusters.shapes import SIZE_MARGIN, Shape, describe_shape, on_a_support, prior_class

if TYPE_CHECKING:
    from stratamap.core.map.layers import Semantics
    from stratamap.core.map.visibility import FreeSpace
    from stratamap.core.map.vocabulary import Vocabulary
    from stratamap.plugins.segmenters.clusters.config import ClustersConfig
    from stratamap.plugins.segmenters.clusters.layout import Layout
    from stratamap.plugins.segmenters.clusters.sightlines import Sightlines


class Supports(NamedTuple):
    """Which working cells belong to which support surface, and the surfaces' heights and areas."""

    of_cell: np.ndarray  # support index per cell, -1 none
    height: np.ndarray
    area: np.ndarray


@dataclass(eq=False)
class Labelling:
    """The shared state of one ``clusters`` run (see the module's docstring)."""

    cfg: ClustersConfig
    points: np.ndarray  # the map's points, world, z up
    vocab: Vocabulary
    votes: Semantics | None  # the map's fused class votes, when it has them for every point
    voxel: float  # the working grid, m
    cells: np.ndarray  # the working grid's cells
    cell_of_point: np.ndarray
    views: np.ndarray  # where the sensor stood (normals face them)
    normals: np.ndarray  # per cell
    voxel_map: bool  # the map came with its voxel size (a fused map, not a raw cloud)
    floor_hint: float | None  # the floor's height where the source found it
    stream: Any  # the sensor stream, for the sightlines
    # Per cell, from the geometry passes.
    layout: Layout | None = None
    supports: Supports | None = None
    pairs: np.ndarray | None = None  # neighbouring cells, stuff left out
    grown: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # cells support surfaces grew into
    segment: np.ndarray | None = None  # segment id per cell, -1 for stuff and support surfaces
    obj: np.ndarray | None = None  # object id per cell, -1 for stuff
    # Per point, from the instance passes.
    class_ids: np.ndarray | None = None
    instance_ids: np.ndarray | None = None
    naming: dict[int, tuple[str, str]] = field(default_factory=dict)  # instance id -> (by, why)
    scores: dict[int, float] = field(default_factory=dict)  # instance id -> the naming model's score
    base_z: float = 0.0  # the floor's height, or the map's base without one
    walls: list[Any] = field(default_factory=list)
    sight: Sightlines | None = None
    counts: dict[str, int] = field(default_factory=dict)  # what the passes did, for the `segments` note
    notes: dict[str, Any] = field(default_factory=dict)  # the passes' notes, in the order they were made
    #: Pairs of point sets a pass found to be two objects: the joining passes after it leave them apart.
    apart: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    _shapes: dict[tuple[str, bytes], Shape] = field(default_factory=dict)

    @classmethod
    def of_labels(
        cls,
        cfg: ClustersConfig,
        points: np.ndarray,
        vocab: Vocabulary,
        class_ids: np.ndarray,
        instance_ids: np.ndarray,
        voxel: float,
        support_heights: np.ndarray,
        base_z: float = 0.0,
    ) -> Labelling:
        """A labelling of points already labelled, each point its own cell, on no support surface but
        with support surfaces at ``support_heights``: for running the passes after ``instances`` alone."""
        n = len(points)
        lab = cls(
            cfg=cfg,
            points=points,
            vocab=vocab,
            votes=None,
            voxel=voxel,
            cells=points,
            cell_of_point=np.arange(n),
            views=np.zeros((0, 3)),
            normals=np.zeros((n, 3)),
            voxel_map=True,
            floor_hint=None,
            stream=None,
            supports=Supports(
                np.full(n, -1, np.int64), np.asarray(support_heights, float), np.zeros(len(support_heights))
            ),
            class_ids=class_ids,
            instance_ids=instance_ids,
        )
        lab.set_context(base_z, [], None)
        return lab

    # ------------------------------------------------------------------ labels

    def relabel(self, sel: np.ndarray, instance: int | np.ndarray | None = None, cls: Any = None) -> None:
        """Give the points ``sel`` an instance id and/or a class id (new arrays; the old ones stay as they were)."""
        if instance is not None:
            self.instance_ids = self.instance_ids.copy()
            self.instance_ids[sel] = instance
        if cls is not None:
            self.class_ids = self.class_ids.copy()
            self.class_ids[sel] = cls

    def keep_apart(self, first: np.ndarray, second: np.ndarray) -> None:
        """Record that the points ``first`` and ``second`` (indices) are two objects: a later join of an
        instance holding most of one with an instance holding most of the other is refused."""
        self.apart.append((np.asarray(first), np.asarray(second)))

    def held_apart(self, first: np.ndarray, second: np.ndarray) -> bool:
        """Whether joining the instances of points ``first`` and ``second`` undoes a ``keep_apart``."""

        def most(part: np.ndarray, whole: np.ndarray) -> bool:
            return len(part) > 0 and np.isin(part, whole).mean() >= 0.5

        return any((most(a, first) and most(b, second)) or (most(a, second) and most(b, first)) for a, b in self.apart)

    def note(self, key: str, items: list[dict[str, Any]]) -> None:
        """Record what a pass did under ``key``; a second pass noting the same key adds to it."""
        if items:
            self.notes.setdefault(key, []).extend(items)

    # ------------------------------------------------------------------ shapes and context

    def set_context(self, base_z: float, walls: list[Any], sight: Sightlines | None) -> None:
        """What shapes are measured against: the floor's height, the wall planes, the sensor's rays."""
        self.base_z, self.walls, self.sight = base_z, walls, sight
        self._shapes = {}

    def shape(self, sel: np.ndarray) -> Shape:
        """``describe_shape`` of the points ``sel``, computed once per set of points."""
        key = (sel.dtype.str, sel.tobytes())
        if key not in self._shapes:
            self._shapes[key] = describe_shape(self.points[sel], self.base_z, self.walls, self.sight)
        return self._shapes[key]

    def thing_shapes(self) -> dict[int, tuple[str, Shape, np.ndarray]]:
        """Each instance of a thing class (its points' most frequent) with 4 points or more, by id: its
        class, its shape and its point indices."""
        from stratamap.core.map.instances import instance_members

        info = {}
        for iid, sel in instance_members(self.instance_ids).items():
            cls = int(np.bincount(self.class_ids[sel]).argmax())
            if len(sel) >= 4 and self.vocab.is_thing[cls]:
                info[iid] = (self.vocab.name(cls), self.shape(sel), sel)
        return info

    def too_large(self, shape: Shape) -> bool:
        """Whether no thing class of the vocabulary has objects this large by the class size priors
        (core/map/priors.py, with their SIZE_MARGIN): a class whose objects come in any length
        (ANY_LENGTH) admits any length no deeper than its ``max_depth`` and no taller than its
        ``max_height`` (else its plausible heights), another one what reaches no farther from its
        centroid than its extent. False where no thing class has a size prior."""
        bounds = self._largest_objects
        return bool(bounds) and not any(
            shape.reach <= reach and shape.depth <= depth and shape.height <= height for reach, depth, height in bounds
        )

    @cached_property
    def free_space(self) -> FreeSpace | None:
        """Where the stream's posed depth frames saw empty space (read when a pass first asks), or
        None for a stream without them (a point cloud, a scan)."""
        from stratamap.core.map.visibility import FreeSpace

        return FreeSpace.from_stream(self.stream)

    @cached_property
    def _largest_objects(self) -> list[tuple[float, float, float]]:
        """Per thing class of the vocabulary with a size prior: the farthest reach, the greatest depth
        and the greatest height one object has (inf: unbounded), for ``too_large``."""
        from stratamap.core.map.priors import ANY_LENGTH, CLASS_SIZES, plausible_heights

        bounds = []
        for name in self.vocab.names:
            size = CLASS_SIZES.get(name)
            if size is None or not self.vocab.is_thing[self.vocab.id(name)]:
                continue
            if name in ANY_LENGTH and size.max_depth is not None:
                heights = plausible_heights(name)
                tallest = size.max_height or (heights[1] if heights is not None else np.inf)
                bounds.append((np.inf, size.max_depth * SIZE_MARGIN, tallest))
            else:
                bounds.append((size.extent[1] * SIZE_MARGIN, np.inf, np.inf))
        return bounds

    @property
    def standing_tolerance(self) -> float:
        """How close (m) an object's foot lies to a support surface's height when it stands on it."""
        return 2.0 * self.cfg.layout.plane_voxels * self.voxel

    @property
    def scrap_size(self) -> int:
        """Fewer cells than this are a scrap, no object (a few cells of a mask that missed its object)."""
        return max(self.cfg.min_cells, 30)

    @property
    def min_cells(self) -> int:
        """The smallest object, in cells: ``min_cells`` or ``min_area``, whichever is more."""
        return max(self.cfg.min_cells, int(np.ceil(self.cfg.min_area / self.voxel**2)))

    @property
    def stuff_ids(self) -> np.ndarray:
        """The class id of each layout label (floor, wall, ceiling; 0 for none or a class the vocabulary lacks)."""
        ids = np.array([self.vocab.id(n) if n in self.vocab else 0 for n in LAYOUT_NAMES], np.int32)
        ids[NONE] = 0
        return ids

    @property
    def support_of_point(self) -> np.ndarray:
        """The support surface of each point, -1 none."""
        return self.supports.of_cell[self.cell_of_point]

    def prior(self, shape: Shape, support_heights: np.ndarray | None = None) -> tuple[str, str]:
        """``prior_class`` with the object's support context: whether its foot is at a support's height
        (``support_heights``, absolute; default: the support surfaces')."""
        heights = self.supports.height if support_heights is None else support_heights
        on_support = on_a_support(self.base_z + shape.bottom, heights, self.standing_tolerance)
        return prior_class(shape, self.vocab, on_support)
