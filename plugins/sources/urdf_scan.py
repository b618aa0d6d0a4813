"""Source ``urdf_scan``: virtual laser scans of an articulated URDF scene (a kitchen), with
per-point ground truth from its links and joints.

The scene is a URDF file (e.g. the real IAI apartment kitchen) or a procedural kitchen
(``synthetic_seed``). A room (floor, walls, ceiling) is added around it, panoramic scans are ray
cast from ``viewpoints`` (a tilting laser on a robot), and every point is labelled: level 1
(floor, table, ceiling, wall, furniture), level 2 (cupboard, drawer, appliance, panel), the front
it belongs to, and each door's hinge side (see :mod:`stratamap.core.simulation.virtual_scan`).

    source:
      plugin: urdf_scan
      params:
        path: ../shared/data/iai_apartment/urdf/apartment.urdf
        root_link: kitchen_root
        room: [0.0, 0.0, 4.2, 5.0, 2.6]
        viewpoints: [[1.45, 1.3, 1.4], [1.45, 2.6, 1.4], [1.45, 3.9, 1.4]]
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field, model_validator

from stratamap.core import Source, StageConfig, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.sensors import SensorStream
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.simulation.virtual_scan import LEVEL1, LEVEL1_CLASS, LEVEL2, LEVEL2_CLASS


class UrdfScanConfig(StageConfig):
    path_fields = ("path",)

    path: str | None = Field(
        default=None, description="URDF file of the scene (meshes resolved via package:// and the file's folders)."
    )
    synthetic_seed: int | None = Field(
        default=None, description="Scan a procedural kitchen with this seed instead of a URDF file."
    )
    root_link: str | None = Field(
        default=None, description="Only the links under this one (e.g. kitchen_root); default: the whole model."
    )
    room: tuple[float, float, float, float, float] | None = Field(
        default=None,
        description=(
            "Room [x0, y0, x1, y1, height] added around the scene, metres; default: the scene's footprint + 1 m."
        ),
    )
    viewpoints: list[tuple[float, float, float]] | None = Field(
        default=None, description="Scanner positions [x, y, z], metres (procedural kitchens bring their own)."
    )
    resolution_deg: float = Field(
        default=0.4, gt=0.02, le=5.0, description="Angular step of the panoramic scans, degrees."
    )
    elevation_deg: tuple[float, float] = Field(
        default=(-70.0, 70.0), description="Lowest and highest beam elevation, degrees."
    )
    max_range: float = Field(default=8.0, gt=0.0, description="Beams longer than this return nothing, metres.")
    noise: float = Field(default=0.003, ge=0.0, description="Gaussian range noise, metres.")
    seed: int = Field(default=0, description="Seed of the range noise.")
    joint_positions: dict[str, float] = Field(
        default_factory=dict, description="Joint values to scan at (default: all closed)."
    )
    appliance_pattern: str = Field(
        default=r"oven|dishwasher|fridge|refrigerator|microwave", description="Regex on link names that are appliances."
    )
    handle_pattern: str = Field(default="handle", description="Regex on link names that are handles.")
    knob_pattern: str = Field(default="knob", description="Regex on link names that are knobs.")
    ignore_pattern: str | None = Field(
        default=r"tap|hotplate|socket", description="Regex on link names left out of the scan."
    )

    @model_validator(mode="after")
    def _one_scene(self) -> UrdfScanConfig:
        if (self.path is None) == (self.synthetic_seed is None):
            raise ValueError("give exactly one of path (a URDF file) and synthetic_seed")
        if self.path is not None and not self.viewpoints:
            raise ValueError("viewpoints: a URDF scene needs at least one scanner position [x, y, z]")
        return self


class UrdfScanSource(Source[UrdfScanConfig]):
    """Virtual laser scans of a URDF scene with per-point plane and furniture ground truth."""

    name = "urdf_scan"
    Config = UrdfScanConfig
    provides = frozenset({"frames", "ground_truth"})

    @classmethod
    def example_params(cls) -> dict:
        return {"synthetic_seed": 0, "resolution_deg": 2.0}

    def read(self) -> dict[str, Any]:
        from stratamap.core.io.urdf import read_urdf
        from stratamap.core.simulation import virtual_scan as ks

        cfg = self.config
        room = cfg.room
        viewpoints = cfg.viewpoints
        if cfg.synthetic_seed is not None:
            import tempfile

            from stratamap.core.synthetic.kitchens import generate_kitchen

            layout = generate_kitchen(cfg.synthetic_seed)
            with tempfile.TemporaryDirectory(prefix="stratamap-kitchen-") as tmp:
                urdf_path = Path(tmp) / "kitchen.urdf"
                urdf_path.write_text(layout.urdf)
                model = read_urdf(urdf_path)
            room = room or layout.room
            viewpoints = viewpoints or [tuple(v) for v in layout.viewpoints]
            name = f"kitchen_{cfg.synthetic_seed}"
        else:
            path = Path(cfg.path).expanduser()  # type: ignore[arg-type]
            model = read_urdf(path)
            name = path.stem
        scene = ks.kitchen_from_urdf(
            model,
            cfg.root_link,
            cfg.appliance_pattern,
            cfg.handle_pattern,
            cfg.knob_pattern,
            cfg.ignore_pattern,
            cfg.joint_positions,
        )
        for w in scene.warnings:
            self.warn(w)
        ks.add_room(scene, room)
        views = np.asarray(viewpoints, float)
        lo, hi = scene.bounds()
        outside = np.any(views < lo - 1e-6, axis=1) | np.any(views > hi + 1e-6, axis=1)
        if outside.any():
            raise DataError(f"urdf_scan: viewpoints {views[outside].tolist()} lie outside the room {scene.room}")
        scan = ks.virtual_scan(scene, views, cfg.resolution_deg, cfg.elevation_deg, cfg.max_range, cfg.noise, cfg.seed)
        labels = ks.label_points(scene, scan)
        vocab = Vocabulary.default()
        cls = np.zeros(len(scan.points), np.int32)
        for k, lab in enumerate(LEVEL1):
            cls[labels.level1 == k] = vocab.id(LEVEL1_CLASS[lab])
        for k, lab in enumerate(LEVEL2):
            cls[labels.level2 == k] = vocab.id(LEVEL2_CLASS[lab])
        inst = np.where(labels.front >= 0, labels.front + 1, 0).astype(np.int32)
        fronts = [{"name": f.name, "kind": f.kind, "joint_type": f.joint_type, "hinge": f.hinge} for f in scene.fronts]
        gt = GroundTruth(
            vocabulary=vocab,
            point_class_ids=cls,
            point_instance_ids=inst,
            layout={
                "kitchen_scan": {
                    "level1": labels.level1,
                    "level2": labels.level2,
                    "front": labels.front,
                    "fronts": fronts,
                    "room": scene.room,
                }
            },
        )
        stream = SensorStream(
            name=name, points=scan.points, metadata={"viewpoints": views.tolist(), "source": "urdf_scan"}
        )
        self.note(
            "scan",
            {
                "points": len(scan.points),
                "viewpoints": len(views),
                "fronts": len(fronts),
                "doors": sum(1 for f in fronts if f["joint_type"] == "revolute"),
            },
        )
        return {"frames": stream, "ground_truth": gt}


@hookimpl
def stratamap_register_sources():
    return [UrdfScanSource]
