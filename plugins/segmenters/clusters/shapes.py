"""Recognition by class size priors and support context, for ``clusters`` (``recognize``,
``keep_instances``): what an object's points say of its size and where it stands (``Shape``), which
classes that shape allows (``fits_class``, ``typical_rather``) and the class it makes most likely
(``prior_class``). The priors themselves are in ``core/map/priors.py``; the passes that apply them
are the modules beside this one (docs/algorithms/segmenters-clusters.md lists them)."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from stratamap.core.map.priors import HAND_HELD
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.plugins.segmenters.clusters.sightlines import Sightlines


class Shape(NamedTuple):
    """What recognition by priors knows of an object: its size and where it stands."""

    length: float  # longest horizontal side of its gravity-aligned box, m
    depth: float  # shorter horizontal side, m
    height: float  # own height, m
    bottom: float  # foot above the floor (or the map's base), m
    reach: float  # farthest point from the centroid, m
    against_wall: bool  # a wall plane within WALL_GAP of it
    flat_top: bool  # its highest points form a flat top over most of its footprint
    solid: bool  # its body (middle heights) spans most of its length and was not seen through: a front, not legs
    seat: bool = False  # a third of its top view at sitting height, a back or arms rising above it
    knee_space: bool = False  # nothing below KNEE_HEIGHT across the middle of its length: legs or pedestals at its ends
    top_span: float = 0.0  # share of its length (5 cm bins) that its flat top's level covers: one worktop, not two tops


#: A desk's knee space is clear of its body up to at least this height (m) across the middle third of
#: its length (office desks: about 0.6 m; a writing desk's drawers may hang to 0.45 m); a sideboard's or
#: a night stand's body, on legs or not, comes lower.
KNEE_HEIGHT = 0.4
#: An object this close (m) to a wall plane stands against it (a unit's back edge, a countertop's).
WALL_GAP = 0.12
#: An object whose foot is this close (m) to the floor stands on it.
FLOOR_GAP = 0.1
#: A floor-standing object's foot may be this high (m) when its legs or base went unseen.
STANDING_GAP = 0.3
#: Thinner than this (m), a geometric object that frames called floor, wall or ceiling is that stuff.
THIN = 0.15
#: A thin piece is also at most this share as thick as it is broad (a floor patch, a poster; not a cup by a wall).
FLAT = 0.5
#: Sizes are priors of whole objects; a partly seen or noisy one may exceed them by this factor.
SIZE_MARGIN = 1.3
#: The most (m) an object's seen height may exceed its class's plausible heights, for classes whose
#: objects carry nothing that could join them (a chair, a monitor; not a table or a counter).
TALLER_BY = 0.15
#: Seats of chairs, armchairs and sofas lie this high (m) above the floor (seat heights 0.38-0.5 m,
#: cushions and the map's noise either side).
SEAT_HEIGHTS = (0.3, 0.6)
#: A backrest or arms rise at least this far (m) above the seat.
BACK_ABOVE_SEAT = 0.15
#: A body whose middle heights at least this share of the depth rays crossing them saw through, of
#: SEEN_THROUGH_RAYS rays or more, is open (a table's space under its top, a low shelf between its legs),
#: however many points lie there (``sightlines``). On the tuning walks closed units gave 0.11 at most,
#: coffee tables with a low shelf 0.34-0.48, tables on legs 0.51-0.97.
SEEN_THROUGH = 0.25
SEEN_THROUGH_RAYS = 100
#: The longest single base unit or chest of drawers (m): kitchen base units come 0.3-1.2 m wide (12-48
#: in). A worktop longer than that spans two units or more: a counter run, which kitchens have.
SINGLE_UNIT_LENGTH = 1.2
#: A worktop is one slab: its level covers at least this share of the run's length (two units side by
#: side that came out as one object show two tops, at two heights).
RUN_TOP_SPAN = 0.9


def describe_shape(pts: np.ndarray, base_z: float, walls: list[Any], sight: Sightlines | None = None) -> Shape:
    """The size and support context of an object's points (world, z up); with ``sight`` (an RGB-D
    stream's rays), a body the sensor saw through at its middle heights is not solid."""
    from stratamap.core.geometry.boxes import gravity_aligned_box
    from stratamap.plugins.segmenters.clusters.grid import footprint_area

    box = gravity_aligned_box(pts)
    length, depth = float(max(box.size[:2])), float(min(box.size[:2]))
    z = pts[:, 2]
    zmin, zmax = float(z.min()), float(z.max())
    height = zmax - zmin
    reach = float(np.linalg.norm(pts - pts.mean(0), axis=1).max())
    near_wall = any((plane.near(pts, WALL_GAP)).any() for plane in walls)
    # A flat top: a level of its upper third whose points (within 2 cm) cover half its footprint (5 cm
    # cells), as a table's, a counter's or a cabinet's top do (under a kettle too) and a chair's backrest
    # does not.
    cell = 0.05
    column, highest = _column_tops(pts, cell)  # the top view, for a seat and for the top's span
    footprint = max(footprint_area(pts[:, :2], cell), cell * cell)
    flat_top = False
    top = pts[:0]
    for level in np.arange(zmax, zmax - height / 3.0, -0.02):
        layer = pts[np.abs(z - level) <= 0.02]
        if len(layer) and footprint_area(layer[:, :2], cell) >= 0.5 * footprint:
            flat_top, top = True, layer
            break
    # A solid body: the middle heights' points, projected on the box's long axis, cover most of its
    # length (a unit's front or side) rather than two or four spots (a table's legs).
    axis = np.array([np.cos(box.yaw), np.sin(box.yaw)])
    if box.size[1] > box.size[0]:
        axis = np.array([-axis[1], axis[0]])
    middle = pts[(z >= zmin + 0.25 * height) & (z <= zmin + 0.75 * height)]
    along = middle[:, :2] @ axis
    full = pts[:, :2] @ axis
    low, high = float(full.min()), float(full.max())
    bins = max(1, int(np.ceil((high - low) / cell)))
    covered = len(np.unique(np.clip(((along - low) / cell).astype(np.int64), 0, bins - 1))) if len(along) else 0
    solid = covered / bins >= 0.6
    # The top's span: the 5 cm cells whose highest point lies on the flat top's level (a front face
    # crosses every level; only a cell's highest point says where its top is), along the long axis.
    top_span = 0.0
    if flat_top:
        on_level = np.abs(highest - float(np.median(top[:, 2]))) <= 0.02
        along_top = pts[on_level[column], :2] @ axis
        top_span = len(np.unique(np.clip(((along_top - low) / cell).astype(np.int64), 0, bins - 1))) / bins
    if solid and sight is not None:
        seen = sight.seen_through(pts, box)
        solid = not (seen.through + seen.stopped >= SEEN_THROUGH_RAYS and seen.share >= SEEN_THROUGH)
    # Knee space: below KNEE_HEIGHT, the middle third of its length holds points in under a quarter of
    # its 5 cm cells (stray points of the map's noise), where its ends hold legs or pedestals.
    third = (high - low) / 3.0
    knee_space = False
    if height > KNEE_HEIGHT + 0.2 and third >= 2 * cell:
        centre = (full >= low + third) & (full <= high - third) & (z < zmin + KNEE_HEIGHT)
        cells = max(1, int(round(third / cell)))
        taken = len(np.unique(((full[centre] - low - third) / cell).astype(np.int64)))
        knee_space = taken < 0.25 * cells
    return Shape(
        length,
        depth,
        height,
        zmin - base_z,
        reach,
        bool(near_wall),
        flat_top,
        solid,
        _seat(highest - zmin),
        knee_space,
        float(top_span),
    )


def _column_tops(pts: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Each point's vertical column (``cell`` m square) and each column's highest z: the top view."""
    from stratamap.core.geometry.points import cell_keys

    _, column = np.unique(cell_keys(pts * (1.0, 1.0, 0.0), cell), return_inverse=True)  # heights dropped
    column = column.reshape(-1)
    tops = np.full(int(column.max()) + 1, -np.inf)
    np.maximum.at(tops, column, pts[:, 2])
    return column, tops


def _seat(tops: np.ndarray) -> bool:
    """Whether the object is seating seen from above (``tops``: the highest point of each 5 cm column
    of its footprint, above its foot): that point lies at sitting height (SEAT_HEIGHTS) over a third
    of its columns or more, and over a tenth or more BACK_ABOVE_SEAT or more above the seat (a
    backrest, arms): a chair's, an armchair's or a sofa's top view, not a table's, a cabinet's or a
    counter's, whose top view is one level (their top), nor a stool's."""
    at_seat = (tops >= SEAT_HEIGHTS[0]) & (tops <= SEAT_HEIGHTS[1])
    if at_seat.mean() < 1.0 / 3.0:
        return False
    return bool((tops >= np.median(tops[at_seat]) + BACK_ABOVE_SEAT).mean() >= 0.1)


def fits_class(name: str, shape: Shape) -> bool:
    """Whether an object of this shape can be of the class by the class size priors
    (core/map/priors.py), with SIZE_MARGIN: its reach within the class's extents, its length within the
    class's longest and shortest sides, its height (standing on the floor: also from below) within the
    plausible heights; a class open below (OPEN_BELOW) standing on the floor with a solid body does
    not fit. Classes without priors always fit."""
    from stratamap.core.map.priors import CLASS_SIZES, OPEN_BELOW

    if smaller_than_class(name, shape) or longer_than_class(name, shape):
        return False
    size = CLASS_SIZES.get(name)
    if size is not None:
        if shape.reach > size.extent[1] * SIZE_MARGIN:
            return False
        if size.min_length is not None and shape.length < size.min_length / SIZE_MARGIN:
            return False
        if size.min_depth is not None and shape.depth < size.min_depth:
            return False
    # A table standing on the floor is open below its top; one closed along its length at mid-height
    # is a unit (a bedside cabinet, a sideboard) that a detector without such labels called a table.
    if name in OPEN_BELOW and shape.solid and shape.bottom <= FLOOR_GAP:
        return False
    # Nor is seating one: a table's top view is one level, a seat's has a back or arms above it.
    if name in OPEN_BELOW and shape.seat and not shape.flat_top:
        return False
    if hangs_unlike(name, shape):
        return False
    return not taller_than_class(name, shape) and not lower_than_class(name, shape)


def smaller_than_class(name: str, shape: Shape) -> bool:
    """Whether the object's reach is below its class's smallest extent (with SIZE_MARGIN)."""
    from stratamap.core.map.priors import CLASS_SIZES

    size = CLASS_SIZES.get(name)
    return size is not None and shape.reach < size.extent[0] / SIZE_MARGIN


def longer_than_class(name: str, shape: Shape) -> bool:
    """Whether the object is longer than one of a class whose objects have a longest side
    (``ClassSize.longest`` for its height, with SIZE_MARGIN: a 1.7 m run is no chair)."""
    from stratamap.core.map.priors import CLASS_SIZES

    size = CLASS_SIZES.get(name)
    longest = size.longest(shape.height) if size is not None else None
    return longest is not None and shape.length > longest * SIZE_MARGIN


def lower_than_class(name: str, shape: Shape) -> bool:
    """Whether the object, standing on the floor or on a support (its whole height seen), is lower
    than any of its class (``priors.lowest_height``: a 10 cm "monitor" is none); floor-standing
    furniture seen in the air (a table top whose legs went unseen) is ``hangs_unlike``'s to judge."""
    from stratamap.core.map.priors import NOT_STACKED, lowest_height, plausible_heights

    if plausible_heights(name) is None:
        return False
    whole = shape.bottom <= FLOOR_GAP or name not in NOT_STACKED
    return whole and shape.height < lowest_height(name, SIZE_MARGIN)


def taller_than_class(name: str, shape: Shape) -> bool:
    """Whether the object is taller than one of its class can be seen: the class's plausible heights'
    top with SIZE_MARGIN (what stands on a worktop, a table or a shelf may belong to it: a counter's
    coffee machine), TALLER_BY for classes whose objects carry nothing, or its ``max_height``."""
    from stratamap.core.map.priors import ANY_LENGTH, CLASS_SIZES, plausible_heights

    heights = plausible_heights(name)
    if heights is None:
        return False
    # Noise adds centimetres to a height, not a third of it (a 1.7 m "chair" is a tall unit).
    tallest = heights[1] * SIZE_MARGIN
    if name not in ANY_LENGTH:
        tallest = min(tallest, heights[1] + TALLER_BY)
    size = CLASS_SIZES.get(name)
    if size is not None and size.max_height is not None:
        tallest = size.max_height
    return shape.height > tallest


def hangs_unlike(name: str, shape: Shape) -> bool:
    """Whether the object hangs in the air unlike its class. Furniture whose objects stand on the floor,
    not on one another (NOT_STACKED: a chair, a table, a counter), seen in the air is the upper part
    of one whose legs or base went unseen only when it is as large as a whole one and its top is at
    the class's height; else a part of something."""
    from stratamap.core.map.priors import CLASS_SIZES, NOT_STACKED, plausible_heights

    if name not in NOT_STACKED or shape.bottom <= STANDING_GAP:
        return False
    size = CLASS_SIZES.get(name)
    if size is not None and shape.reach < size.extent[0]:
        return True
    top = shape.bottom + shape.height
    heights = plausible_heights(name)
    return heights is not None and not heights[0] / SIZE_MARGIN <= top <= heights[1] * SIZE_MARGIN


def ruled_out(name: str, shape: Shape) -> bool:
    """Whether the class facts rule the class out for the object: it is smaller than any object of the
    class can be (``smaller_than_class``; standing on the floor, ``lower_than_class``), longer than
    one of a class whose objects have a longest side (``longer_than_class``), or it hangs in the air
    unlike its class (``hangs_unlike``). Taller or deeper than the class is another matter: an
    instance may hold clutter its segmentation joined to it (the racks over a worktop, a tap), which
    says nothing of what it is."""
    # Standing on the floor, its whole height is seen: a bag by a wall is no cabinet.
    on_floor_and_lower = shape.bottom <= FLOOR_GAP and lower_than_class(name, shape)
    return (
        smaller_than_class(name, shape)
        or on_floor_and_lower
        or longer_than_class(name, shape)
        or hangs_unlike(name, shape)
    )


def typical_rather(geometric: str, voted: str, shape: Shape, slack: float = 0.05) -> bool:
    """Whether the class the shape gives overrules a voted class that fits: the object's height lies
    in the geometric class's typical range (TYPICAL_HEIGHTS, within ``slack`` m) and outside the
    voted one's (a 0.9 m solid unit against a wall that a detector without a 'counter' label calls a
    table: tables are 0.72-0.76 m, counters 0.86-0.92 m). Objects standing on the floor only."""
    from stratamap.core.map.priors import TYPICAL_HEIGHTS

    if (
        geometric == voted
        or shape.bottom > FLOOR_GAP
        or geometric not in TYPICAL_HEIGHTS
        or voted not in TYPICAL_HEIGHTS
    ):
        return False

    def within(name: str) -> bool:
        low, high = TYPICAL_HEIGHTS[name]
        return low - slack <= shape.height <= high + slack

    return within(geometric) and not within(voted)


def counter_run(shape: Shape) -> bool:
    """Whether an object of this shape is a worktop over two base units or more (longer than
    SINGLE_UNIT_LENGTH, a counter's size): no storage unit of an office or a living room is that."""
    from stratamap.core.map.priors import WORKTOP

    return shape.length > SINGLE_UNIT_LENGTH and shape.top_span >= RUN_TOP_SPAN and fits_class(WORKTOP, shape)


def on_a_support(foot: float, support_heights: np.ndarray, tolerance: float) -> bool:
    """Whether a foot at height ``foot`` (m) lies at a support surface's height, within ``tolerance``."""
    return bool(np.any(np.abs(np.asarray(support_heights) - foot) <= tolerance))


#: prior_class's reason when none of its rules names an object.
NO_RULE_FITS = "no rule fits"


def prior_class(shape: Shape, vocab: Vocabulary, on_support: bool = True) -> tuple[str, str]:
    """The class an object's shape and support context make most likely (and why), among the
    vocabulary's thing classes: the first of the shape rules (``SHAPE_RULES``, class facts in
    core/map/priors.py) whose conditions the shape meets and whose class its size allows
    (``fits_class``); ``on_floor`` is a foot within FLOOR_GAP of the floor, ``on_support`` a foot at a
    support surface's height (a small piece resting on no support, such as a fragment of a chair, is
    no cup). ``UNNAMED`` (``object``) when no rule fits."""
    from stratamap.core.map.priors import SHAPE_RULES

    facts = {
        "on_floor": shape.bottom <= FLOOR_GAP,
        "on_support": on_support,
        "against_wall": shape.against_wall,
        "flat_top": shape.flat_top,
        "solid": shape.solid,
        "seat": shape.seat,
        "knee_space": shape.knee_space,
    }
    for rule in SHAPE_RULES:
        name = rule.class_name
        if any(getattr(rule, fact) not in (None, value) for fact, value in facts.items()):
            continue
        if name in vocab and vocab.is_thing[vocab.id(name)] and fits_class(name, shape):
            return name, rule.why
    return unnamed(vocab), NO_RULE_FITS


def unnamed(vocab: Vocabulary) -> str:
    """The class of a thing nothing named: ``UNNAMED`` where the vocabulary has it, else its first thing."""
    from stratamap.core.map.priors import UNNAMED

    return UNNAMED if UNNAMED in vocab else vocab.name(vocab.thing_ids()[0])


def thin(pts: np.ndarray) -> bool:
    """Thinner than THIN across, in height (2-98 % of its points: a single frame's floor bends by
    centimetres at range) or in depth (a poster on a wall), and flat: at most FLAT times as thick as
    it is broad. A cup standing against a wall, 10 cm every way, is no piece of that wall."""
    from stratamap.core.geometry.boxes import gravity_aligned_box

    low, high = np.percentile(pts[:, 2], [2.0, 98.0])
    sides = sorted((float(high - low), *map(float, gravity_aligned_box(pts).size[:2])))
    return sides[0] < THIN and sides[0] <= FLAT * sides[1]


def hand_held(shape: Shape) -> bool:
    """Whether an object of this shape may be a thing of a hand's size (a cup, a bottle)."""
    return any(fits_class(name, shape) for name in HAND_HELD)
