"""The ``pieces`` section of the ``tsdf`` config, and the flat names of old it replaced.

``pieces`` tunes ``instances: masks`` (:mod:`stratamap.plugins.mappers.tsdf.mask_instances`):
how the map's label instances are cut into connected 3D pieces and re-joined where the frames'
masks keep covering them together. Until the release before, its fields were flat ``piece_*``
keys of the stage (``piece_min_points``); those are still read into the section for one more
release, and the stage warns when it runs, naming the old key and the new one.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, PositiveInt

from stratamap.plugins.mappers.tsdf.mask_instances import (
    DEFAULT_MAX_LENGTH,
    DEFAULT_MIN_POINTS_BY_CLASS,
    DEFAULT_STACKED_CLASSES,
)


class Pieces(BaseModel):
    """'masks' extraction: how 3D pieces are cut, merged and dropped."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    min_points: int = Field(
        default=60, ge=1, description="Connected pieces with fewer points join the piece they touch most."
    )
    min_points_by_class: dict[str, PositiveInt] = Field(
        default_factory=lambda: dict(DEFAULT_MIN_POINTS_BY_CLASS),
        description=(
            "Per class, the points a piece needs to stand alone instead of min_points: a whole cup is about a "
            "hundred points, and the part most frames call 'cup' would otherwise join the table it stands on."
        ),
    )
    merge_ratio: float = Field(
        default=0.5,
        gt=0,
        lt=1,
        description="Same-class pieces merge while frames saw them in one mask more than this share of the time.",
    )
    near_gap: float = Field(
        default=0.2,
        ge=0,
        description=(
            "Pieces with no points this close (m) merge only at far_ratio (objects are compact); 0: no limit."
        ),
    )
    far_ratio: float = Field(
        default=0.9,
        gt=0,
        le=1,
        description="The share of frames in one mask that pieces farther apart than near_gap need to merge (1: never).",
    )
    min_class_share: float = Field(
        default=0.1,
        ge=0,
        lt=1,
        description=(
            "Instances under this share of the typical size of their class's instances (fragment_reference) are "
            "dropped as misfires; 0: keep all."
        ),
    )
    fragment_reference: Literal["median", "point_median"] = Field(
        default="point_median",
        description=(
            "The size min_class_share is a share of: the class's median instance, or the instance its median point "
            "is in (the size-weighted median: four misfire 'chairs' beside two real ones do not pull it down to a "
            "misfire's size)."
        ),
    )
    cross_ratio: float = Field(
        default=0.8,
        ge=0,
        le=1,
        description=(
            "Near pieces of two classes (one object the segmenter calls by two names) merge when frames saw them in "
            "one mask more than this share of the time, taking their points' majority class; 0: never."
        ),
    )
    cross_share: float = Field(
        default=0.1,
        ge=0,
        le=1,
        description=(
            "Pieces of two classes merge only if the smaller has at least this share of the larger's points (a book "
            "on a shelf stays a book)."
        ),
    )
    stacked_classes: list[str] = Field(
        default_factory=lambda: list(DEFAULT_STACKED_CLASSES),
        description=(
            "Classes whose objects never stand on one another: two instances of one of them, one above the other, "
            "are one object whose thin joining parts the TSDF lost (a swivel chair's base and seat, a table's legs "
            "and top); []: off."
        ),
    )
    stack_overlap: float = Field(
        default=0.5,
        gt=0,
        le=1,
        description=(
            "The share of the smaller instance's footprint (5 cm cells) that must lie under or over the larger one."
        ),
    )
    max_length: dict[str, PositiveFloat] = Field(
        default_factory=lambda: dict(DEFAULT_MAX_LENGTH),
        description=(
            "Per class, the longest horizontal side (m) one object has; a longer instance is several touching "
            "objects (two cups one segment in every frame) and is cut by k-means along its length. Classes left "
            "out are never cut; {}: off."
        ),
    )
    split_balance: float = Field(
        default=0.35,
        ge=0,
        le=1,
        description=(
            "An over-long instance is cut only if every part holds this share of the largest part's points (a "
            "monitor that took a scrap of something far beyond it stays whole)."
        ),
    )


#: The flat keys of the release before: ``piece_min_points`` is ``pieces.min_points``, ...
RENAMED: dict[str, str] = {f"piece_{name}": f"pieces.{name}" for name in Pieces.model_fields}
