"""The parameters of ``clusters``: its distances (in voxels of the working grid), its thresholds, and
the order of its passes (``passes``)."""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from stratamap.core import StageConfig
from stratamap.plugins.segmenters.clusters.layout import LayoutParams

#: The passes in the order they run by default (docs/algorithms/segmenters-clusters.md says what
#: each does). The splits come before the joins, so that the pieces a split makes are joined to what
#: they are part of as every other piece is.
DEFAULT_PASSES = (
    "layout",
    "grow_supports",
    "segment",
    "split_standing",
    "join_supports",
    "return_feet",
    "flush_to_layout",
    "instances",
    "drop_strays",
    "trim_feet",
    "split_beside_tops",
    "split_units",
    "split_oversized",
    "split_seen_apart",
    "join_parts",
    "assemble_chairs",
    "join_seating",
    "join_enclosed",
    "cut_below_supports",
    "name_by_model",
    "rename_by_priors",
    "counters_need_a_kitchen",
    "name_after_rules_by_model",
)


class ClassRule(BaseModel):
    """Name a cluster by its size: the first rule that fits wins (used when the map has no class votes)."""

    model_config = ConfigDict(extra="forbid")

    class_name: str = Field(description="Class to give (must be a thing class of the vocabulary).")
    max_extent: float = Field(default=np.inf, gt=0, description="Largest box side, metres.")
    min_extent: float = Field(default=0.0, ge=0, description="Smallest largest-box-side, metres.")
    max_height: float = Field(default=np.inf, description="Highest top above the support, metres.")


class ClustersConfig(StageConfig):
    method: Literal["convex", "euclidean"] = Field(
        default="convex", description="convex: cut concave creases between touching objects; euclidean: distance only."
    )
    voxel_size: float | None = Field(
        default=None,
        gt=0.0,
        description=(
            "Working grid, metres. Default: the map's voxel size (geometry.voxel_size, set by tsdf), else "
            "spacing_factor times the cloud's median point spacing."
        ),
    )
    spacing_factor: float = Field(
        default=3.4,
        gt=0.0,
        description="Working grid of a raw cloud (no voxel size) in median point spacings (raw points are noisy).",
    )
    gravity: Literal["z", "none"] = Field(
        default="z",
        description="z: the map is gravity-aligned, z up (stratamap's world); none: no floor, wall or ceiling named.",
    )
    radius_voxels: float = Field(default=2.4, gt=0.0, description="Cells closer than this are neighbours, in voxels.")
    normal_radius_voxels: float = Field(default=4.0, gt=0.0, description="Radius of the normal estimate, in voxels.")
    smooth_deg: float = Field(
        default=12.0,
        ge=0.0,
        le=90.0,
        description="Neighbours whose normals differ by less than this stay linked even when slightly concave.",
    )
    patch_voxels: float = Field(
        default=4.0, gt=0.0, description="Cell size of the supervoxel patches the convexity test works on, in voxels."
    )
    patch_normal_deg: float = Field(
        default=20.0,
        gt=0.0,
        le=90.0,
        description="Neighbours in one cell whose normals differ by less than this form a patch.",
    )
    convex_votes: float = Field(
        default=0.5,
        ge=0.0,
        le=1.0,
        description="Share of point links across a patch boundary that must be convex (or smooth) to merge.",
    )
    concavity_tolerance: float | None = Field(
        default=None,
        ge=0.0,
        description=(
            "Concavity tolerated (noise), as a fraction of the neighbour distance. Default: 0.2 for a raw cloud (set "
            "on mOSD/learn), 0.4 for a voxel map (set on held-out fused maps: normals over few coarse voxels bend)."
        ),
    )
    min_area: float = Field(
        default=0.0015, gt=0.0, description="Smallest instance, as surface area (cells times voxel area), m^2."
    )
    min_cells: int = Field(default=18, ge=1, description="Smallest instance in working-grid cells (noise).")
    below_share: float = Field(
        default=0.7,
        ge=0.0,
        le=1.0,
        description=(
            "A segment touching a support's object, wholly below the support, joins it when this share of its "
            "footprint lies in the support's convex hull (a table's legs; not a chair pushed beside it)."
        ),
    )
    layout_share: float = Field(
        default=0.6,
        gt=0.0,
        le=1.0,
        description=(
            "An object with this share of its cells near one floor, wall or ceiling plane is that stuff (what the "
            "plane fit left at corners and edges; a poster)."
        ),
    )
    layout_voxels: float = Field(
        default=3.0, gt=0.0, description="Near a floor, wall or ceiling plane: within this distance, in voxels."
    )
    table_min_area: float = Field(
        default=0.3,
        gt=0.0,
        description="Without class votes, a support's object with a top this large is a table, m^2.",
    )
    layout: LayoutParams = Field(
        default_factory=LayoutParams, description="Floor, wall, ceiling and support-surface detection."
    )
    cut_min_links: int = Field(
        default=5,
        ge=0,
        description="Concave patch edges (creases) a segment needs before planar cuts are tried (0: no cuts).",
    )
    cut_concavity_tolerance: float | None = Field(
        default=None,
        ge=0.0,
        description=(
            "Concavity that makes a patch edge a crease for the planar cuts, as concavity_tolerance (default: the "
            "same; stricter makes more cuts, also spurious ones through clean boxes)."
        ),
    )
    cut_concave_share: float = Field(
        default=0.5,
        ge=0.0,
        le=1.0,
        description="Share of the patch edges a cut severs that must be concave for the cut to be made.",
    )
    cut_distance_voxels: float = Field(
        default=3.0,
        gt=0.0,
        description="Crease edges (patch centroid midpoints) this close to a candidate plane support it, in voxels.",
    )
    cut_crease_deg: float = Field(
        default=45.0,
        gt=0.0,
        le=90.0,
        description="Concave edges whose patch normals turn by more than this are creases that propose cut planes.",
    )
    cut_face_patches: int = Field(
        default=10, ge=1, description="Patches that must lie on a cut plane facing its way (the face the cut follows)."
    )
    cut_candidates: int = Field(
        default=20, ge=1, description="Best supported candidate planes tried per segment and cut."
    )
    cut_depth: int = Field(default=2, ge=0, description="Cuts applied in sequence at most per segment.")
    class_rules: list[ClassRule] = Field(
        default_factory=list, description="Size rules naming clusters when the map has no class votes."
    )
    trim_feet: bool = Field(
        default=True,
        description=(
            "Give a thing's points at its foot that lie outside its body's footprint, where the floor or a support "
            "surface goes on beyond them (the ring of table top a detector's mask takes at a cup's foot), back to "
            "that surface."
        ),
    )
    drop_strays: bool = Field(
        default=True,
        description=(
            "A thing's few cells apart from the rest of it and above everything else it holds (a wall corner's "
            "cells a metre above a sofa, left when the corner's flush cells went to the walls) are not the object: "
            "nothing holds them up. They leave the instance before it is named and measured."
        ),
    )
    keep_instances: bool = Field(
        default=False,
        description=(
            "Keep the instances already on the map (a tsdf mapper's, from a detector's masks) and add every "
            "geometric object they leave uncovered as an instance of its own; an instance's unmasked parts (a "
            "table's legs under its masked top) join it. False: the clusters alone are the instances."
        ),
    )
    covered_share: float = Field(
        default=0.5,
        gt=0.0,
        le=1.0,
        description=(
            "keep_instances: a geometric object with less than this share of its points in kept instances is a "
            "new instance (what no detector box covered); otherwise its unmasked points join the nearest instance."
        ),
    )
    recognize: bool = Field(
        default=False,
        description=(
            "Name objects with no thing votes, or with a voted class their size rules out (a 1.7 m box, a 12 cm "
            "table), by class size priors (core/map/priors.py) and support context: what stands on a support "
            "surface, whether it stands against a wall, has a flat top, a solid body or legs."
        ),
    )
    sightlines: bool = Field(
        default=True,
        description=(
            "recognize: with an RGB-D stream, a body its frames' depth rays saw through at its middle heights (the "
            "open space under a table's top, past a low shelf between its legs) is not a closed unit, however many "
            "points lie there. Reads up to 60 frames' depth again; scans and point clouds have no rays."
        ),
    )
    square_to_walls: float = Field(
        default=0.2,
        ge=0.0,
        le=1.0,
        description=(
            "An instance's box is turned square to a wall the layout found when that makes its footprint at most "
            "this share larger than the smallest one (a partly seen fridge's tilted rectangle is a few per cent "
            "smaller than the upright one; a chair turned 20 degrees at a table is not square to anything). "
            "0: the smallest footprint always."
        ),
    )
    naming: Literal["rules", "model", "rules_then_model"] = Field(
        default="rules",
        description=(
            "How thing instances get their class after the geometry passes: rules (the votes, then the class size "
            "priors' rules with recognize), model (a trained classifier over measured features, run by "
            "onnxruntime: naming_model; the rule passes rename_by_priors and counters_need_a_kitchen then stand down) "
            "or rules_then_model (the rules name; what they leave 'object' the model names where it scores "
            "naming_threshold or more)."
        ),
    )
    naming_threshold: float = Field(
        default=0.4,
        ge=0.0,
        le=1.0,
        description=(
            "naming: model or rules_then_model: an instance the model names whose most likely class scores below "
            "this is 'object'; its score is in its naming either way."
        ),
    )
    naming_model: str | None = Field(
        default=None,
        description=(
            "naming: model or rules_then_model: the model's JSON sidecar (the ONNX file it names lies beside it). "
            "Default: the shipped model, plugins/segmenters/clusters/models/naming.json (see its README for its data)."
        ),
    )
    passes: list[str] = Field(
        default_factory=lambda: list(DEFAULT_PASSES),
        description=(
            "The passes run, in this order (default: all, in the order listed in "
            "docs/algorithms/segmenters-clusters.md); each needs the passes that make what it reads to come "
            "before it. The switches above (trim_feet, drop_strays, recognize, ...) still turn passes off."
        ),
    )

    @field_validator("passes")
    @classmethod
    def _known_passes_in_order(cls, value: list[str]) -> list[str]:
        from stratamap.plugins.segmenters.clusters.passes import PASSES

        seen: list[str] = []
        for name in value:
            if name not in PASSES:
                raise ValueError(f"unknown pass {name!r}; passes are {', '.join(PASSES)}")
            if name in seen:
                raise ValueError(f"pass {name!r} is listed twice")
            missing = [need for need in PASSES[name].needs if need not in seen]
            if missing:
                raise ValueError(f"pass {name!r} needs {', '.join(map(repr, missing))} before it")
            seen.append(name)
        if "instances" not in seen:
            raise ValueError("the passes must include 'instances' (it makes the stage's labels)")
        return value
