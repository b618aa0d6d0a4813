"""Segmenter ``clusters``: model-free 3D instances from geometry first (point clouds and fused maps).

1. Scale. Every distance follows the map's resolution: the working grid is the map's voxel size
   (a TSDF map's ``geometry.voxel_size``), or ``spacing_factor`` times a raw cloud's median point
   spacing; the neighbour radius, normal radius, patch size and cut distance are multiples of it,
   and the smallest instance is an area. The same scene mapped at two voxel sizes gives the same
   instances, and a 2 cm room map gets 2 cm-scale parameters instead of a Kinect tabletop's.
2. Layout (``layout.find_layout``, gravity-aligned planes): floor, walls and ceiling become stuff
   and leave the object search, so they are never a thing; so do an object's cells flush on a
   layout plane, and objects lying mostly near one (``layout_share``: what the plane fit left at
   corners and edges). Horizontal surfaces at table and counter heights are *support surfaces*:
   kept out of the clustering too, so what stands on them comes apart from them, and then given
   back to their object (below). Each takes up to three rings of neighbouring cells within half a
   voxel of its height and inside its footprint (``grow_supports``): the plane fit leaves out the
   top where normals bend at a cup's foot, and that ring would join the cup to the table's rim;
   cells it took under a segment standing there go back to it (``return_feet``).
3. Convexity-aware clustering of the rest (``method: convex``). Neighbouring cells (within
   ``radius_voxels``) stay connected when their surfaces are locally convex,
   ``(n_i - n_j) . (x_i - x_j) >= 0`` for normals facing the sensor, or nearly coplanar; the
   concave crease where a box stands on another, or leans on something, cuts the link (the
   point-level form of locally convex connected patches, LCCP, on supervoxel-like patches).
   ``method: euclidean`` links every pair within the radius instead.
4. Constrained planar cuts (after CPC, Schoeler et al. 2015): where a segment holds sharp concave
   creases between patches, the planes of the faces along them are tried as cuts through the
   whole segment; one is made when most patch edges it severs are concave (two boxes' flush sides).
5. Support surfaces get their object back: a segment touching a support surface *stands on it*
   when its foot is at the surface's height and it rises above it (a cup, a monitor, a box: its
   own instance); otherwise it is part of the support's object (a table's legs and edge, a cabinet
   under its counter top, a chair's back posts), joined through further touching segments that lie
   below the surface and under its convex hull (``below_share``).
6. Instances are the joined segments of at least ``min_area`` (and ``min_cells`` cells). Each
   takes its class from the fused per-point class votes already on the map (the ``semantics``
   layer a previous segmenter or the ``tsdf`` mapper left) when there are any: the majority class
   of its points; a majority of a stuff class makes it stuff. Without votes a support's object
   with a top of ``table_min_area`` is a ``table``, others follow ``class_rules`` or are ``object``.

The steps are named passes (``passes.PASSES``), each a module of this package with one job, run in
the order of the config's ``passes`` on one shared :class:`Labelling` (points, cells, labels,
instances and each object's cached shape); docs/algorithms/segmenters-clusters.md lists them.

Memory and time are near-linear in the points: a voxel grid, k-d tree neighbour pairs within a
few voxels, sparse connected components; no all-pairs step. Deterministic: no random sampling.
"""

from __future__ import annotations

from typing import Any

from stratamap.core import PipelineData, Segmenter, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.geometry.points import voxel_downsample
from stratamap.core.map.instances import NAMING, SHAPE, SHAPE_FLAGS, set_naming
from stratamap.core.map.layers import Semantics
from stratamap.core.map.sensors import sensor_viewpoints
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.plugins.segmenters.clusters.config import DEFAULT_PASSES, ClassRule, ClustersConfig
from stratamap.plugins.segmenters.clusters.grid import estimate_normals, source_floor, working_voxel
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.layout import wall_yaws
from stratamap.plugins.segmenters.clusters.patches import patch_graph
from stratamap.plugins.segmenters.clusters.strays import stray_points

__all__ = [
    "DEFAULT_PASSES",
    "ClassRule",
    "ClustersConfig",
    "ClustersSegmenter",
    "Labelling",
    "patch_graph",
    "stray_points",
    "working_voxel",
]


class ClustersSegmenter(Segmenter[ClustersConfig]):
    """Model-free instances: gravity-aligned layout as stuff, convexity-aware clustering around support surfaces."""

    name = "clusters"
    Config = ClustersConfig
    requires = frozenset({"geometry"})
    optional = frozenset({"semantics"})
    provides = frozenset({"semantics", "instances"})

    @classmethod
    def example_params(cls) -> dict:
        return {"min_cells": 5}

    def segment(self, data: PipelineData) -> dict[str, Any]:
        from stratamap.core.map.instances import instances_from_semantics
        from stratamap.plugins.segmenters.clusters.passes import PASSES

        lab = self._labelling(data)
        for name in self.config.passes:
            PASSES[name].run(lab)
        for key, items in lab.notes.items():
            self.note(key, items)
        layout, segment = lab.layout, lab.segment
        self.note(
            "segments",
            {
                "voxel_size": round(lab.voxel, 5),
                "foot_points_given_back": lab.counts.get("foot_points_given_back", 0),
                "stray_points_dropped": lab.counts.get("stray_points_dropped", 0),
                "floor_height": None if layout.floor_height is None else round(layout.floor_height, 3),
                "walls": layout.walls,
                "supports": len(layout.supports),
                "segments": int(segment.max()) + 1 if (segment >= 0).any() else 0,
                "instances": lab.counts["instances"],
                "stuff_by_votes": lab.counts["stuff_by_votes"],
                "stuff_on_planes": lab.counts["stuff_on_planes"],
            },
        )
        geometry = data.map.geometry
        semantics = Semantics(lab.class_ids, lab.instance_ids, lab.vocab)
        instances = instances_from_semantics(
            lab.points, geometry.colors, semantics, 1, axes=wall_yaws(layout), axes_slack=self.config.square_to_walls
        )
        before = data.map.instances if self.config.keep_instances else None
        shapes = lab.thing_shapes()
        for inst in instances:
            if inst.id in shapes:
                measured = shapes[inst.id][1]
                inst.attributes[SHAPE] = {flag: bool(getattr(measured, flag)) for flag in SHAPE_FLAGS}
            if inst.id in lab.naming:
                set_naming(inst, *lab.naming[inst.id])
                if inst.id in lab.scores:
                    inst.attributes[NAMING]["score"] = lab.scores[inst.id]
            elif before is not None and inst.id in before and NAMING in before[inst.id].attributes:
                inst.attributes[NAMING] = dict(before[inst.id].attributes[NAMING])
            else:
                set_naming(inst, "labels", "kept from the previous stage's objects with their class")
        return {"semantics": semantics, "instances": instances}

    def _labelling(self, data: PipelineData) -> Labelling:
        """The map's points on the working grid, with their normals, before any pass."""
        cfg = self.config
        geometry = data.map.geometry
        if geometry is None or len(geometry.points) == 0:
            raise DataError("clusters: the geometry layer has no points")
        points = geometry.points
        votes = (
            data.map.semantics if data.map.semantics is not None and len(data.map.semantics) == len(points) else None
        )
        vocab = (
            votes.vocabulary
            if votes is not None
            else data.map.vocabulary
            or (data.ground_truth.vocabulary if data.ground_truth is not None else Vocabulary.default())
        )
        for rule in cfg.class_rules:
            if rule.class_name not in vocab or not vocab.is_thing[vocab.id(rule.class_name)]:
                raise DataError(
                    f"clusters: class_rules names {rule.class_name!r}, which is not a thing class of the vocabulary"
                )
        voxel = working_voxel(points, geometry.voxel_size, cfg)
        cells, cell_of_point = voxel_downsample(points, voxel)
        views = sensor_viewpoints(data.stream, cells)
        return Labelling(
            cfg=cfg,
            points=points,
            vocab=vocab,
            votes=votes,
            voxel=voxel,
            cells=cells,
            cell_of_point=cell_of_point,
            views=views,
            normals=estimate_normals(cells, cfg.normal_radius_voxels * voxel, views),
            voxel_map=bool(geometry.voxel_size),
            floor_hint=source_floor(data),
            stream=data.stream,
        )


@hookimpl
def stratamap_register_segmenters():
    return [ClustersSegmenter]
