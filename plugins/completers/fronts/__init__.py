"""Completer ``fronts``: doors and drawers that open, on any fused map (the kitchen paper's fronts,
handles and hinge sides; the functional-objects paper's articulated replacement).

For every object but seating (``priors.WITHOUT_FRONTS``; a face with flat fronts and handles is
storage whatever the object was named), and for seating too where the segmenter measured a solid
body without a seat (``attributes['shape']``: a counter's run a detector voted "chair"), it finds
the front face among the map's points (:mod:`.face`) and its height map (:mod:`.relief`), finds
handles and knobs standing off it (by thresholds, or with ``fixtures: model`` by a trained
classifier, :mod:`.fixture_model`), cuts it into fronts at gaps and between handles, labels each
front door, drawer, appliance door or fixed panel with the kitchen paper's level-2 CRF (refitted
on RGB-D walks of procedural kitchens: ``models/fronts_crf.json``, ``scripts/train_fronts.py``)
and gives each door a hinge side opposite its handle. The object's completion becomes articulated
(:mod:`.body`): a carcass open at the front, every door on a revolute joint, every drawer (with a
drawer box behind its front) on a prismatic one; an object shallower behind its face than
``min_depth`` has no room for either and opens nothing.
The URDF, MJCF and SDF exporters write these joints as they are.

Where fronts were found they replace a library model's joints (the observed fronts win where a
model disagrees); where the face was seen and nothing on it opens, a library model stays rigid
(``notes.fronts.rigid``); an object whose face was not seen keeps its completion
(``keep_articulated`` keeps every library model's joints instead).
Each object's fronts are kept in ``attributes['fronts']`` (label, hinge side, rectangle in the
object frame, handles and knobs) and summed up under ``notes.fronts``.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field

from stratamap.core import Completer, PipelineData, StageConfig, hookimpl
from stratamap.core.documents import read_data_text
from stratamap.core.errors import DataError
from stratamap.core.furniture.faces import OPENS, level2_feature_count
from stratamap.core.geometry.transforms import invert
from stratamap.core.map.instances import SHAPE
from stratamap.core.map.priors import MOVABLE, WITHOUT_FRONTS
from stratamap.core.map.sensors import sensor_viewpoints
from stratamap.core.simulation.structure import floor_height, room_structure

#: The shipped front classifier and fixture classifier (models/README.md).
SHIPPED = Path(__file__).resolve().parent / "models" / "fronts_crf.json"
SHIPPED_FIXTURES = Path(__file__).resolve().parent / "models" / "fixtures.json"


class FrontsConfig(StageConfig):
    path_fields = ("model", "fixture_model")

    classes: list[str] | None = Field(
        default=None,
        description=(
            "Classes whose objects may have fronts; default: every object but those of priors.WITHOUT_FRONTS whose "
            "measured shape (attributes['shape']) is open or has a seat (a face with flat fronts and handles is "
            "storage whatever the object was named)."
        ),
    )
    model: str | None = Field(
        default=None,
        description=(
            "Front CRF weights (JSON with a 'level2' CRF); default: the shipped models/fronts_crf.json "
            "(core/furniture/models/plane_crf.json: the laser-trained one of plane_crf)."
        ),
    )
    fixtures: Literal["model", "thresholds"] = Field(
        default="thresholds",
        description=(
            "How handles and knobs are found on a face: 'model', a trained classifier over every blob any cue lifts "
            "(relief, colour contrast, thin lines in the frames' colour; fixture_model.py); 'thresholds', blobs of the "
            "relief over fixture_standoff and elongated blobs of colour contrast."
        ),
    )
    fixture_model: str | None = Field(
        default=None,
        description="Fixture classifier sidecar (JSON beside its ONNX file); default: the shipped models/fixtures.json",
    )
    min_coverage: float = Field(
        default=0.35, gt=0.0, le=1.0, description="Share of a side the map must cover for it to be a front face."
    )
    fixture_standoff: tuple[float, float] = Field(
        default=(0.012, 0.07), description="Handles and knobs stand this far (m, min and max) off the face."
    )
    gap_depth: tuple[float, float] = Field(
        default=(0.008, 0.06), description="Gaps between fronts lie this far (m, min and max) behind the face."
    )
    min_front: float = Field(default=0.06, gt=0.0, description="Narrowest and lowest front kept, metres.")
    door_opening: float = Field(
        default=1.6, gt=0.0, le=3.1, description="Upper limit of door and flap joints, radians (1.6: 92 degrees)."
    )
    drawer_travel: float = Field(
        default=0.8, gt=0.0, le=1.0, description="Share of its box's depth a drawer slides out."
    )
    min_depth: float = Field(
        default=0.2,
        ge=0.0,
        description=(
            "Shallowest object (m behind its face, as its points measure it) whose fronts open: a shallower one has "
            "no room behind them for a drawer box or a shelf (a backsplash, a leaflet rack, a chair's back); its "
            "fronts are kept in attributes['fronts'], none as a joint."
        ),
    )
    max_frames: int = Field(
        default=40,
        ge=0,
        description=(
            "Depth frames (those that saw a face most squarely and closest) fused into a 1 cm height map of it, "
            "where handles and gaps show; 0: the map's points only."
        ),
    )
    max_range: float = Field(default=5.0, gt=0.0, description="Farthest depth (m) used from a frame for a face.")
    room_to_open: bool = Field(
        default=True,
        description=(
            "A side-hinged door whose swing, on the side its handle or its face's end chose, runs into the box of a "
            "fixed neighbour (an object of no movable class, or a wall) and on the other side into less than half as "
            "much hinges on the other side (swing.py; noted per object as 'hinges_turned')."
        ),
    )
    keep_articulated: bool = Field(
        default=False,
        description=(
            "Leave objects whose completion already has joints (a library model's) as they are; by default the "
            "fronts observed on an object's face replace a library model's joints where any were found."
        ),
    )


def load_front_crf(path: Path):
    from stratamap.core.furniture.crf import CRF

    if not path.is_file():
        raise DataError(f"fronts: model file not found: {path}")
    try:
        crf = CRF.from_dict(json.loads(read_data_text(path, "fronts model"))["level2"])
    except (ValueError, KeyError, TypeError) as exc:
        raise DataError(f"fronts: {path} is not a front CRF model ({exc})") from exc
    if crf.n_features != level2_feature_count():
        raise DataError(f"fronts: {path} was trained on other front features; retrain it (scripts/train_fronts.py)")
    return crf


class FrontsCompleter(Completer[FrontsConfig]):
    """Storage objects as articulated bodies: doors on hinges and drawers on slides, from their faces."""

    name = "fronts"
    Config = FrontsConfig
    requires = frozenset({"instances", "geometry"})

    def complete(self, data: PipelineData) -> dict[str, Any]:
        from stratamap.plugins.completers.fronts.body import BodyParams, articulated_body, depth_behind, object_frame
        from stratamap.plugins.completers.fronts.fronts import FaceParams, label_fronts, observe_object
        from stratamap.plugins.completers.fronts.swing import room_to_open

        cfg = self.config
        crf = load_front_crf(Path(cfg.model).expanduser() if cfg.model else SHIPPED)
        insts = data.map.instances.copy()  # type: ignore[union-attr]
        cloud = np.asarray(data.map.geometry.points, float)  # type: ignore[union-attr]
        views = sensor_viewpoints(data.stream, cloud) if len(cloud) else np.zeros((0, 3))
        floor_z = floor_height(data.map)
        walls = [b for b in room_structure(data.map) if b.class_name == "wall"]
        classes = set(cfg.classes) if cfg.classes is not None else None
        params = BodyParams(door_opening=cfg.door_opening, drawer_travel=cfg.drawer_travel)
        face_params = FaceParams(
            cfg.min_coverage,
            tuple(cfg.fixture_standoff),
            tuple(cfg.gap_depth),
            cfg.min_front,
            cfg.max_frames,
            cfg.max_range,
            None
            if cfg.fixtures == "thresholds"
            else str(Path(cfg.fixture_model).expanduser() if cfg.fixture_model else SHIPPED_FIXTURES),
        )
        summary: dict[str, Any] = {
            "objects": 0,
            "articulated": 0,
            "rigid": 0,
            "joints": {"revolute": 0, "prismatic": 0},
        }
        per_object = {}
        # What a door may not swing into: the walls and the objects no one moves away.
        fixed, fixed_objects = [], {}
        if cfg.room_to_open:
            fixed = [(w.pose, w.size) for w in walls]
            fixed_objects = {i.id: (i.box.pose, i.box.size) for i in insts if i.class_name not in MOVABLE}
        for inst in insts:
            if not may_have_fronts(inst, classes):
                continue
            if cfg.keep_articulated and inst.completion is not None and inst.completion.joints:
                continue
            summary["objects"] += 1
            box = inst.box
            found = observe_object(box, cloud, views, data.stream, floor_z, face_params, walls)
            if found is None:
                per_object[inst.id] = {"class": inst.class_name, "face": None}
                continue
            face, _, candidates = found
            fronts = label_fronts(candidates, floor_z, crf)
            depth = depth_behind(face, box, inst.points)
            pose, size = object_frame(face, box, depth)
            to_object = invert(pose)
            u_center = float(pose[:3, 3] @ face.u_axis)
            rects = [
                (
                    (f.rect[0] - u_center, f.rect[1] - u_center, f.rect[2] - box.bottom_z, f.rect[3] - box.bottom_z),
                    f.label,
                    f.hinge,
                    f.fixtures,
                )
                for f in fronts
            ]
            turned: list[dict[str, Any]] = []
            if cfg.room_to_open:
                neighbours = fixed + [b for i, b in fixed_objects.items() if i != inst.id]
                rects, turned = room_to_open(rects, -float(size[1]) / 2, cfg.door_opening, pose, neighbours)
            shallow = depth < cfg.min_depth and any(f.label in OPENS for f in fronts)
            completion = (
                None if shallow else articulated_body(size, rects, to_object, pose, self.name, face.coverage, params)
            )
            per_object[inst.id] = {
                "class": inst.class_name,
                "coverage": round(face.coverage, 3),
                "fronts": [f.label for f in fronts],
                "fixtures": len(face.fixtures),
                "depth": round(depth, 3),
                **({"opens": f"nothing: {depth:.2f} m deep, min_depth {cfg.min_depth:g}"} if shallow else {}),
                **({"hinges_turned": turned} if turned else {}),
            }
            inst.attributes["fronts"] = [
                {
                    "label": label,
                    "hinge": hinge,
                    "rect": [round(float(v), 4) for v in rect],
                    "handles": sum(x.kind == "handle" for x in fix),
                    "knobs": sum(x.kind == "knob" for x in fix),
                    # Where each fixture sits on the face: x along it, z up (object frame).
                    "fixtures": [
                        {"kind": x.kind, "x": round(float(q[0]), 4), "z": round(float(q[2]), 4)}
                        for x in fix
                        for q in [to_object[:3, :3] @ np.asarray(x.center, float) + to_object[:3, 3]]
                    ],
                }
                for rect, label, hinge, fix in rects
            ]
            if completion is None:
                if inst.completion is not None and inst.completion.joints:
                    # The face was seen and nothing on it opens: a library model's doors and drawers
                    # are guesses the observation does not bear out; the model stays, rigid.
                    inst.completion = replace(inst.completion, parts=[], joints=[], alternatives=[])
                    summary["rigid"] += 1
                continue
            inst.completion = completion
            summary["articulated"] += 1
            for j in completion.joints:
                summary["joints"][j.type] += 1
        self.note("fronts", {**summary, "per_object": per_object})
        return {"instances": insts}

    @classmethod
    def example_params(cls) -> dict:
        return {}


def may_have_fronts(inst: Any, classes: set[str] | None) -> bool:
    """Whether ``fronts`` looks at ``inst``: its class is one of ``classes`` when they are given; else
    any class but seating, and seating too where its measured shape is a solid body with no seat (a
    name from a detector's votes is weaker evidence than the shape: a chair's back is open below its
    seat, a run of drawers is not)."""
    if classes is not None:
        return inst.class_name in classes
    if inst.class_name not in WITHOUT_FRONTS:
        return True
    shape = inst.attributes.get(SHAPE)
    return isinstance(shape, dict) and bool(shape.get("solid")) and not shape.get("seat", True)


@hookimpl
def stratamap_register_completers():
    return [FrontsCompleter]
