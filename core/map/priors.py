"""What a class's objects are like in indoor scenes: one table of sizes that stages use to tell
an object from a fragment or from several objects. Values are metres, for the default vocabulary.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Objects lower than this (m) are low units for ClassSize.low_max_length.
LOW_UNIT_HEIGHT = 0.6


@dataclass(frozen=True)
class ClassSize:
    #: Smallest and largest distance from an object's centroid to its farthest point.
    extent: tuple[float, float]
    #: Longest horizontal side one object has, with a margin for the map's noise; None for classes
    #: whose single objects come in any length (tables, shelves, counters, sofas).
    max_length: float | None = None
    #: Shortest longest-horizontal-side one object has (a counter is a run of base units under one
    #: worktop); None when small ones exist.
    min_length: float | None = None
    #: Tallest one object is, where the class comes far taller than its typical height range (a
    #: kitchen's tall unit, a wardrobe); None: the typical range (TYPICAL_HEIGHTS) with its slack.
    max_height: float | None = None
    #: Lowest one object is, where the class comes far lower than its typical height range (a bedside
    #: cabinet, a low sideboard); None: the typical range with its slack.
    min_height: float | None = None
    #: Shallowest one object is front to back (a unit holds things: a panel on a wall is none); None: any.
    #: A map sees a unit's whole depth wherever it sees its top, and its surfaces make a unit deeper,
    #: never shallower (on the tuning walks each of the 20 counters 0.63-0.69 m deep measured 1.5-5 cm
    #: deeper than it is, and a 0.49 m sideboard 0.53 m), so no allowance is made below it.
    min_depth: float | None = None
    #: Longest horizontal side one low object has (under LOW_UNIT_HEIGHT: a TV bench, a lowboard),
    #: where the class's low objects come longer than its max_length; None: max_length for any height.
    low_max_length: float | None = None
    #: Largest level surface (m^2) one object holds, where the class has a small one (a chair's seat,
    #: about 0.5 x 0.5 m, an armchair's up to 0.7 x 0.7 m): a desk top in a "chair" is a desk's; None: any.
    max_top_area: float | None = None
    #: Deepest one object is front to back, for classes whose objects come in any length (ANY_LENGTH):
    #: a longer one than ``extent`` allows is still one object while it is no deeper than this (a 4 m
    #: counter run is 0.6-1 m deep); None: its extent bounds it.
    max_depth: float | None = None
    #: How deep one object usually is front to back, at the small end of the common sizes (m): a box
    #: seen from one side only (a chair pushed in under a table shows its backrest) is completed to it
    #: where the sensor never saw the space beside its face (the contact graph's refined box); None:
    #: never completed so.
    usual_depth: float | None = None

    def longest(self, height: float) -> float | None:
        """The longest horizontal side one object of this height may have (None: any)."""
        if self.low_max_length is not None and height < LOW_UNIT_HEIGHT:
            return self.low_max_length
        return self.max_length


CLASS_SIZES: dict[str, ClassSize] = {
    # One seat: an armchair is under a metre wide (with the map's noise, 1.1 m); wider seating is a sofa
    # or a bench, and a longer "chair" in a mapper's masks is two (tsdf's size prior splits it).
    "chair": ClassSize((0.2, 0.9), max_length=1.1, max_top_area=0.5, usual_depth=0.45),
    # Coffee tables stand 0.35-0.5 m high, far below dining and desk height.
    # Dining and conference tables come up to 1.5 m wide, desks (an L-shaped one's arm) to 1 m.
    "table": ClassSize((0.3, 1.6), min_height=0.35, max_depth=1.5, usual_depth=0.5),
    "desk": ClassSize((0.4, 1.4), max_depth=1.0, usual_depth=0.5),
    # One unit: a sideboard, a credenza or a wardrobe reaches 2 m as one object; a longer run of
    # cabinets is several units. Low ones (TV benches, lowboards) come up to 3 m long as one piece.
    "cabinet": ClassSize(
        (0.25, 1.3),
        max_length=2.0,
        max_height=2.4,
        min_height=0.35,
        min_depth=0.2,
        low_max_length=3.0,
        usual_depth=0.35,
    ),
    "shelf": ClassSize((0.3, 1.4), max_height=2.4, max_depth=0.8, usual_depth=0.25),
    # Worktops stand 0.85-0.95 m high and reach 0.6 m or more from the wall (base units are 0.56-0.6 m
    # deep): a long low or shallow unit is a sideboard, a cabinet. A map measures a unit's top where it
    # is or a few centimetres higher, so 3 cm under 0.85 m are allowed. The rare lower worktops (for
    # children or wheelchair users, 0.75-0.85 m) are given up: a flat-topped unit that low is far more
    # often a desk, a table, a sideboard or a display cube.
    # An island with an overhang is up to 1.3 m deep; each arm of an L-shaped run is a counter of its own.
    "counter": ClassSize((0.4, 1.8), min_length=0.9, min_height=0.82, min_depth=0.55, max_depth=1.3, usual_depth=0.6),
    "sofa": ClassSize((0.5, 1.6), max_depth=1.2, usual_depth=0.75),
    "bench": ClassSize((0.3, 1.2), max_depth=0.8, usual_depth=0.35),
    "fridge": ClassSize((0.4, 1.2)),
    "microwave": ClassSize((0.15, 0.5), max_length=0.7),
    "oven": ClassSize((0.3, 0.8)),
    "monitor": ClassSize((0.15, 0.6), max_length=1.0),
    "laptop": ClassSize((0.1, 0.4), max_length=0.45),
    "box": ClassSize((0.05, 0.5)),
    "book": ClassSize((0.05, 0.3), max_length=0.45),
    "cup": ClassSize((0.02, 0.15), max_length=0.15),
    "bottle": ClassSize((0.05, 0.3), max_length=0.15),
    "plant": ClassSize((0.1, 0.7)),
}

#: Classes whose single objects come in any length: their size never rules a label out.
ANY_LENGTH: tuple[str, ...] = ("table", "desk", "shelf", "counter", "sofa", "bench")

#: Classes whose objects do not stand on one another: two of them one above the other are one
#: object (a swivel chair's base and seat, a table's legs and top).
NOT_STACKED: tuple[str, ...] = ("chair", "table", "desk", "sofa", "bench", "counter", "fridge", "oven")

#: Classes whose objects stand on a support (a worktop, a table, a shelf), not on a room's floor:
#: recognition by matching does not give them to an object standing on the floor (a table's pedestal
#: foot fits a microwave's model as well as a microwave does).
ON_A_SUPPORT: tuple[str, ...] = ("cup", "bottle", "book", "laptop", "monitor", "microwave")

#: Classes whose objects stand on legs or a pedestal, open below their top (knees go under a table):
#: a body closed from side to side at mid-height is a unit, not one of these. Desks are not here: a
#: pedestal desk or one with a modesty panel is closed along its length.
OPEN_BELOW: tuple[str, ...] = ("table",)

#: Classes built around their top: every part of one stands under the top's outline (a table's legs, a
#: desk's pedestals), so what lies beside it is another object (a chair pushed in at a table). Not a
#: counter: a run of units holds units whose tops are no worktop (a cooker, a tall unit at its end).
UNDER_THEIR_TOP: tuple[str, ...] = ("table", "desk")

#: Appliances that stand in kitchens, not in offices or living rooms.
KITCHEN_APPLIANCES: tuple[str, ...] = ("fridge", "oven", "sink", "dishwasher")

#: Appliances behind a door: their hinged fronts are appliance doors (the kitchen paper's label).
DOOR_APPLIANCES: tuple[str, ...] = ("fridge", "oven", "microwave", "dishwasher")

#: Furniture that keeps things behind fronts (doors, drawers, flaps): the storage objects the front
#: classifier is trained on (``scripts/train_fronts.py``); ``fronts`` looks at every object but
#: WITHOUT_FRONTS.
WITH_FRONTS: tuple[str, ...] = ("cabinet", "counter", *DOOR_APPLIANCES)

#: The widest one front of each kind opens (m): a wider "door" is two doors or a fixed panel that
#: no gap or handle split, and is not exported as one joint (kitchen doors come 0.3-0.6 m wide, a
#: fridge's or a wardrobe's up to 0.9 m; drawers up to 1.2 m).
FRONT_MAX_WIDTH: dict[str, float] = {"cupboard": 1.0, "appliance": 1.0, "drawer": 1.2}

#: Things a robot or a person moves: exported as free bodies by default, and no obstacle a door's
#: swing must keep clear of.
MOVABLE: tuple[str, ...] = ("cup", "bottle", "book", "box", "chair")

#: Things the shape rules name when they stand on a support surface, by size.
ON_SUPPORTS: tuple[str, ...] = ("cup", "bottle", "box")

#: Things of a hand's size among them (a box may be a microwave's size).
HAND_HELD: tuple[str, ...] = ("cup", "bottle")

#: Things that stand on others besides ON_SUPPORTS: never a piece of a chair.
STANDS_ON_OTHERS: tuple[str, ...] = ("monitor", "laptop", "book", "microwave")

#: Seating: furniture stands within a table's, a desk's or a unit's box (a chair pushed under it or
#: close beside it), never within a seat's.
SEATING: tuple[str, ...] = ("chair", "sofa", "bench")

#: Classes whose objects have no doors or drawers: ``fronts`` does not look at them (a chair's back
#: is a flat panel, and a bar across it looks like a handle).
WITHOUT_FRONTS: tuple[str, ...] = SEATING

#: The class of what has lost pieces of one seat (a back, a post) that ``clusters`` puts back together.
ONE_SEAT = "chair"

#: The class of several seats in a row that came out as one object, or as chairs side by side.
SEATS_IN_A_ROW = "sofa"

#: The class of a worktop over base units: a kitchen's, which elsewhere is a UNIT.
WORKTOP = "counter"

#: The class of a storage unit with a body closed at its front (what a WORKTOP outside a kitchen is).
UNIT = "cabinet"

#: The class of an object holding a support surface that nothing else named (``clusters`` without votes
#: and without ``recognize``).
HOLDS_A_TOP = "table"

#: The name of a thing no rule or vote named.
UNNAMED = "object"


@dataclass(frozen=True)
class ShapeRule:
    """One rule of naming by shape (``clusters``' ``recognize``): its class, why, and what the
    object's shape must be (None: either). The first rule in SHAPE_RULES whose conditions an object
    meets and whose class its size allows (the class size priors) names it."""

    class_name: str
    why: str
    #: Its foot on the floor (else raised: on a support, on a wall).
    on_floor: bool | None = None
    #: Its foot at a support surface's height.
    on_support: bool | None = None
    #: A wall plane close behind it.
    against_wall: bool | None = None
    #: Its highest points form a flat top over most of its footprint.
    flat_top: bool | None = None
    #: Its body at middle heights spans its length and was not seen through (a front, not legs).
    solid: bool | None = None
    #: A seat with a back or arms above it, seen from above.
    seat: bool | None = None
    #: Nothing below knee height across the middle of its length.
    knee_space: bool | None = None


#: General rules of indoor objects, in the order they are tried.
SHAPE_RULES: tuple[ShapeRule, ...] = (
    *(ShapeRule(name, "on a support, its size", on_floor=False, on_support=True) for name in ON_SUPPORTS),
    ShapeRule("cabinet", "on a wall, off the floor", on_floor=False, against_wall=True),
    *(
        ShapeRule(name, "a seat with a back or arms above it", on_floor=True, seat=True, flat_top=False)
        for name in ("chair", "sofa")
    ),
    ShapeRule(
        "desk",
        "flat top over knee space, its body closed above it (drawers, a modesty panel)",
        on_floor=True,
        flat_top=True,
        solid=True,
        knee_space=True,
    ),
    ShapeRule(
        "counter", "flat top at worktop height, solid body, long and deep", on_floor=True, flat_top=True, solid=True
    ),
    ShapeRule("cabinet", "flat top, solid body", on_floor=True, flat_top=True, solid=True),
    ShapeRule("table", "flat top on legs", on_floor=True, flat_top=True, solid=False),
    ShapeRule("cabinet", "solid unit against a wall", on_floor=True, against_wall=True, solid=True),
    ShapeRule("chair", "free-standing, no flat top, a chair's size", on_floor=True, flat_top=False, against_wall=False),
)


#: class -> (low, high) height in metres of the class's objects: what a model of a source without
#: units is scaled to on load, and how far a matcher may stretch a model to fit an observation.
TYPICAL_HEIGHTS: dict[str, tuple[float, float]] = {
    "chair": (0.88, 1.05),
    "table": (0.72, 0.76),
    "desk": (0.72, 0.76),
    "cabinet": (0.8, 1.0),
    "shelf": (1.2, 1.9),
    "counter": (0.86, 0.92),
    "sofa": (0.75, 0.9),
    "bench": (0.42, 0.8),
    "fridge": (1.5, 1.9),
    "microwave": (0.26, 0.32),
    "oven": (0.84, 0.9),
    "monitor": (0.4, 0.55),
    "laptop": (0.2, 0.25),
    "box": (0.1, 0.3),
    "book": (0.02, 0.05),
    "cup": (0.08, 0.11),
    "bottle": (0.2, 0.32),
    "plant": (0.4, 0.9),
}

#: Heights of real objects spread beyond the typical range (a bar stool, a tall cabinet): how far
#: outside it (as a factor) a match may still scale a model.
HEIGHT_SLACK = 1.25


def typical_height(class_name: str) -> float | None:
    """The middle of the class's typical height range (metres), or None for an unknown class."""
    span = TYPICAL_HEIGHTS.get(class_name)
    return None if span is None else (span[0] + span[1]) / 2


def plausible_heights(class_name: str) -> tuple[float, float] | None:
    """Heights (metres) an object of the class may have: the typical range widened by HEIGHT_SLACK."""
    span = TYPICAL_HEIGHTS.get(class_name)
    return None if span is None else (span[0] / HEIGHT_SLACK, span[1] * HEIGHT_SLACK)


def least_usual_depth(height: float) -> float | None:
    """The least usual depth (``ClassSize.usual_depth``) among the classes whose objects may be
    ``height`` high standing on the floor (``plausible_heights``): how deep at least an object of no
    known class, standing there that high, is taken to be; None when no such class has one."""
    depths = [
        size.usual_depth
        for name, size in CLASS_SIZES.items()
        if size.usual_depth is not None
        and (heights := plausible_heights(name)) is not None
        and heights[0] <= height <= heights[1]
    ]
    return min(depths) if depths else None


def lowest_height(class_name: str, margin: float) -> float | None:
    """The lowest (metres) a whole object of the class may be seen: its ``min_height`` where the class
    has one, else the plausible heights' low end over ``margin``; None for a class without priors."""
    size = CLASS_SIZES.get(class_name)
    if size is not None and size.min_height is not None:
        return size.min_height
    heights = plausible_heights(class_name)
    return None if heights is None else heights[0] / margin


def class_extents() -> dict[str, tuple[float, float]]:
    """(min, max) extent per class."""
    return {name: size.extent for name, size in CLASS_SIZES.items()}


def class_max_lengths() -> dict[str, float]:
    """Longest horizontal side per class, for the classes that have one."""
    return {name: size.max_length for name, size in CLASS_SIZES.items() if size.max_length is not None}


# ------------------------------------------------------------------------------------------
# Masses: what objects of a class are made of


@dataclass(frozen=True)
class ClassBody:
    """What an object of a class weighs, as the simulators' exports give it: ``density`` (kg/m^3)
    of the material times the material's volume, which is the object's solid volume but at most
    ``fill`` of its box (a table is a top and four legs, not a block of wood)."""

    #: kg/m^3 of what the object is made of (solid wood about 600, chipboard 650, glazed ceramic 2400).
    density: float
    #: Share of the object's gravity-aligned box that is material.
    fill: float


#: A part or object no thicker than this (m) is a solid slab whatever its class (a door, a
#: tabletop, a book): ``fill`` describes a whole object's box, not a board cut from it.
SOLID_THICKNESS = 0.05

#: The figures behind each fill are those of a typical object, in its box (real ones vary by about a
#: factor of two either way, as the simulators' friction does not care much about).
CLASS_BODIES: dict[str, ClassBody] = {
    # 1.6 x 0.9 m top 30 mm thick and four 70 mm legs: 0.057 m^3 of a 1.08 m^3 box; about 40 kg in wood.
    "table": ClassBody(600.0, 0.055),
    "desk": ClassBody(600.0, 0.07),  # a table's top and legs, often a drawer unit under it
    # 0.45 m seat 30 mm thick, a back, four 40 mm legs: 0.012 m^3 of a 0.5 x 0.5 x 0.9 m box, about 7 kg.
    "chair": ClassBody(600.0, 0.055),
    "bench": ClassBody(600.0, 0.08),
    # A hollow carcass of 18 mm chipboard with a shelf inside: 0.065 m^3 of a 0.8 x 0.5 x 0.9 m box, 42 kg.
    "cabinet": ClassBody(650.0, 0.18),
    "counter": ClassBody(650.0, 0.2),  # base units (carcasses) under a worktop
    # An open bookcase 0.8 x 0.3 x 1.8 m: two sides, five shelves and a back, 0.045 m^3, about 29 kg.
    "shelf": ClassBody(650.0, 0.1),
    # Foam, webbing and a wooden frame (a mixed density): a three-seater of 2 x 0.9 x 0.85 m, about 70 kg.
    "sofa": ClassBody(150.0, 0.3),
    # A storage box and what it holds, taken as filling it.
    "box": ClassBody(150.0, 1.0),
    "book": ClassBody(750.0, 1.0),
    # Ceramic walls and handle: a 0.3 kg mug in a 8 x 8 x 10 cm box.
    "cup": ClassBody(2400.0, 0.2),
    # Water in a thin bottle, which fills half its box (round, with a neck).
    "bottle": ClassBody(1000.0, 0.55),
    "laptop": ClassBody(1100.0, 1.0),  # aluminium, plastic and a battery: about 1.8 kg
    # A 24-inch panel and its stand: about 5 kg in a 0.55 x 0.2 x 0.45 m box.
    "monitor": ClassBody(700.0, 0.15),
    # Sheet steel, plastic liners, insulation and a compressor: a 0.7 m^3 fridge about 70 kg.
    "fridge": ClassBody(1000.0, 0.1),
    "microwave": ClassBody(1300.0, 0.2),
    "oven": ClassBody(1600.0, 0.1),
    # Soil in a pot under the plant's far larger (and almost weightless) crown.
    "plant": ClassBody(1300.0, 0.15),
}

#: An object of a class without a body above: wooden furniture of a table's fill or so.
FALLBACK_BODY = ClassBody(600.0, 0.1)


def class_body(class_name: str, density: float | None = None) -> ClassBody:
    """The body facts of ``class_name`` (FALLBACK_BODY for an unknown class); ``density``, when
    given, replaces its material density (an exporter's per-class override)."""
    body = CLASS_BODIES.get(class_name, FALLBACK_BODY)
    return body if density is None else ClassBody(float(density), body.fill)


def material_volume(solid_volume: float, box_extents: tuple[float, ...], fill: float) -> float:
    """The volume (m^3) of material in an object of this solid volume and box: at most ``fill`` of
    its box, all of it for a slab no thicker than SOLID_THICKNESS."""
    box = float(box_extents[0]) * float(box_extents[1]) * float(box_extents[2])
    share = 1.0 if min(box_extents) <= SOLID_THICKNESS else fill
    return max(0.0, min(float(solid_volume), share * box))
