"""Segmenter ``plane_crf``: planes, furniture fronts, handles and hinges from a point cloud (the
kitchen paper: multi-LoD planar decomposition, region growing, geometric features and two CRFs).

Input: the geometry layer (a laser scan or a mapped cloud, z up). Output:

* Semantics, per point: ``floor``, ``ceiling``, ``wall``, ``table`` (horizontal work surfaces),
  and on furniture faces ``cupboard``, ``drawer``, ``appliance`` or ``cabinet`` (a fixed panel);
  ``plane_ids`` names the planar segment of every point (-1: on no plane).
* Object instances: one per front labelled cupboard, drawer or appliance, a thin box on the face
  with attributes ``hinge`` (left/right as seen facing it, top/bottom for flaps; doors and
  appliances), ``joint`` (revolute or prismatic), ``handles`` and ``knobs`` (fitted centres,
  directions and lengths or radii), ``plane_id``.

The CRF weights ship in ``stratamap/core/furniture/models/plane_crf.json`` (trained on virtual scans of procedural
kitchens: ``python scripts/train_plane_crf.py``). The algorithms live in
:mod:`stratamap.plugins.segmenters.plane_crf.fronts` and :mod:`stratamap.plugins.segmenters.plane_crf.planes`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import PipelineData, Segmenter, StageConfig, hookimpl
from stratamap.core.documents import read_data_text
from stratamap.core.errors import DataError
from stratamap.core.furniture.faces import OPENS
from stratamap.core.furniture.faces import SHIPPED_CRF as SHIPPED
from stratamap.core.map.layers import ObjectInstance, ObjectInstances, OrientedBox, Semantics
from stratamap.core.map.sensors import sensor_viewpoints
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.simulation.virtual_scan import LEVEL1_CLASS, LEVEL2_CLASS


class PlaneCRFConfig(StageConfig):
    path_fields = ("model",)

    model: str | None = Field(
        default=None, description="CRF weights (JSON); default: the shipped core/furniture/models/plane_crf.json."
    )
    viewpoints: list[tuple[float, float, float]] | None = Field(
        default=None,
        description=(
            "Scanner positions [x, y, z]; default: the source's (stream metadata; an RGB-D walk's camera "
            "positions), else 1.4 m above the cloud's centre."
        ),
    )
    voxel_size: float | None = Field(
        default=None, gt=0.0, description="Working resolution, metres; default: the one the CRFs were trained at."
    )
    plane_threshold: float | None = Field(
        default=None, gt=0.0, description="MSAC inlier distance, metres; default: as trained."
    )
    min_area: float | None = Field(
        default=None, gt=0.0, description="Smallest planar region kept, square metres; default: as trained."
    )
    seed: int = Field(default=0, description="Seed of the MSAC sampling.")


def load_model(path: Path) -> dict[str, Any]:
    from stratamap.core.furniture.crf import CRF

    if not path.is_file():
        raise DataError(f"plane_crf: model file not found: {path} (train one with scripts/train_plane_crf.py)")
    try:
        doc = json.loads(read_data_text(path, "plane_crf model"))
        return {
            "level1": CRF.from_dict(doc["level1"]),
            "level2": CRF.from_dict(doc["level2"]),
            "params": doc.get("params", {}),
        }
    except (ValueError, KeyError, TypeError) as exc:
        raise DataError(f"plane_crf: {path} is not a plane_crf model ({exc})") from exc


class PlaneCRFSegmenter(Segmenter[PlaneCRFConfig]):
    """Planes labelled by a CRF, furniture fronts with handles, knobs and hinge sides."""

    name = "plane_crf"
    Config = PlaneCRFConfig
    requires = frozenset({"geometry"})
    provides = frozenset({"semantics", "instances"})

    def segment(self, data: PipelineData) -> dict[str, Any]:
        from stratamap.core.furniture.faces import level2_feature_count
        from stratamap.plugins.segmenters.plane_crf.fronts import FurnitureParams, analyse, level1_feature_count

        cfg = self.config
        geometry = data.map.geometry
        if geometry is None or len(geometry.points) == 0:
            raise DataError("plane_crf: the geometry layer has no points")
        model = load_model(Path(cfg.model).expanduser() if cfg.model else SHIPPED)
        if model["level1"].n_features != level1_feature_count() or model["level2"].n_features != level2_feature_count():
            raise DataError(
                "plane_crf: the model's feature sizes do not match this version's features; retrain it "
                "(scripts/train_plane_crf.py)"
            )
        known = FurnitureParams.__dataclass_fields__
        params = FurnitureParams(
            **{k: (tuple(v) if isinstance(v, list) else v) for k, v in model["params"].items() if k in known}
        )
        for key in ("voxel_size", "plane_threshold", "min_area"):
            if getattr(cfg, key) is not None:
                setattr(params, key, getattr(cfg, key))
        params.seed = cfg.seed
        points = np.asarray(geometry.points, float)
        stream = data.stream
        views = cfg.viewpoints or (stream.metadata.get("viewpoints") if stream is not None else None)
        if not views and stream is not None and (stream.frames or stream.metadata.get("sensor_positions")):
            # An RGB-D walk or a scanner file: where its frames were taken, or its stations.
            views = sensor_viewpoints(stream, points).tolist()
        if not views:
            views = [tuple(points.mean(0)[:2]) + (float(np.percentile(points[:, 2], 5)) + 1.4,)]
            self.warn(
                "plane_crf: no scanner positions given; assuming one 1.4 m above the cloud's centre (set viewpoints)"
            )
        res = analyse(points, np.asarray(views, float), model["level1"], model["level2"], params)
        vocab = data.map.vocabulary or (
            data.ground_truth.vocabulary if data.ground_truth is not None else Vocabulary.default()
        )
        missing = [c for c in list(LEVEL1_CLASS.values()) + list(LEVEL2_CLASS.values()) if c not in vocab]
        if missing:
            raise DataError(f"plane_crf: the map's vocabulary lacks {sorted(set(missing))}")
        labels = model["level1"].labels
        cell_class = np.zeros(len(res.points), np.int32)
        cell_inst = np.zeros(len(res.points), np.int32)
        cell_plane = np.full(len(res.points), -1, np.int32)
        next_id = 1
        for r in res.regions:
            cell_plane[r.indices] = r.id
            lab = int(res.level1[r.id])
            if lab >= 0:
                cell_class[r.indices] = vocab.id(LEVEL1_CLASS[labels[lab]])
                if vocab.is_thing[vocab.id(LEVEL1_CLASS[labels[lab]])]:
                    cell_inst[r.indices] = next_id
                    next_id += 1
        front_of_point = res.front_of[res.cell_of_point]
        instances = ObjectInstances()
        front_ids = {}
        for f in res.fronts:
            cname = LEVEL2_CLASS.get(f.label or "panel", "cabinet")
            cell_class[f.indices] = vocab.id(cname)
            cell_inst[f.indices] = next_id
            front_ids[f.id] = next_id
            if f.label in OPENS:
                u = np.cross([0.0, 0.0, 1.0], f.normal)
                box = OrientedBox(
                    f.center() - 0.01 * f.normal, float(np.arctan2(u[1], u[0])), np.array([f.width, 0.02, f.height])
                )
                instances.add(
                    ObjectInstance(
                        next_id,
                        cname,
                        points[front_of_point == f.id],
                        box,
                        attributes={
                            "hinge": f.hinge if f.label != "drawer" else None,
                            "joint": "prismatic" if f.label == "drawer" else "revolute",
                            "plane_id": int(f.region),
                            "normal": f.normal.tolist(),
                            "handles": [
                                {"center": x.center.tolist(), "direction": x.direction.tolist(), "length": x.length}
                                for x in f.fixtures
                                if x.kind == "handle" and x.direction is not None
                            ],
                            "knobs": [
                                {"center": x.center.tolist(), "radius": x.radius}
                                for x in f.fixtures
                                if x.kind == "knob"
                            ],
                        },
                    )
                )
            next_id += 1
        per_point = res.cell_of_point
        semantics = Semantics(cell_class[per_point], cell_inst[per_point], vocab, cell_plane[per_point])
        counts = {lab: int((res.level1 == k).sum()) for k, lab in enumerate(labels)}
        self.note(
            "planes",
            {"regions": len(res.regions), "by_label": counts, "floor_z": res.floor_z, "ceiling_z": res.ceiling_z},
        )
        self.note(
            "fronts",
            {
                "count": len(res.fronts),
                "by_label": {
                    lab: sum(f.label == lab for f in res.fronts) for lab in ("cupboard", "drawer", "appliance", "panel")
                },
            },
        )
        return {"semantics": semantics, "instances": instances}

    @classmethod
    def example_params(cls) -> dict:
        return {}


@hookimpl
def stratamap_register_segmenters():
    return [PlaneCRFSegmenter]
