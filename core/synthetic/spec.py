"""Scene specs: what a procedural scene contains and how it is sensed. One YAML file per scene.

Example (``configs/scenes/office.yaml``)::

    type: office
    room_size: [6.5, 5.5, 2.7]
    objects: {desk: 3, chair: 4, cabinet: 2, monitor: 3, cup: 3}
    seed: 0
    camera: {width: 640, height: 480}
    trajectory: {type: walk, frames: 120}
    noise: {depth: kinect}
    laser: {height: 0.25}

Objects may come from a model library instead of the generator (see docs/generalization.md):
per class, ``objects: {chair: {count: 3, library: {path: ../data/partnet_mobility, models: ["179"]}}}``,
or for every class at once, a top-level ``library: {path: ...}``. Relative library paths are
resolved against the spec file's folder; ``pybullet_data:table/table.urdf`` names a file of the
``pybullet_data`` package. Such objects are placed by the same rules as generated ones, scaled
to metres (sources without units, PartNet-Mobility, to the class's typical height) and rendered
in their own colours.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from stratamap.core.documents import read_mapping, validation_problems
from stratamap.core.errors import ConfigError
from stratamap.core.map.sensors import CameraIntrinsics

SCENE_TYPES = ("room", "office", "meeting_room", "kitchen", "lounge", "corridor")

#: Default room size (x, y, z) and object counts by class per scene type.
SCENE_DEFAULTS: dict[str, tuple[tuple[float, float, float], dict[str, int]]] = {
    "room": ((5.0, 4.0, 2.6), {"table": 1, "chair": 4, "box": 2}),
    "office": (
        (6.5, 5.5, 2.7),
        {
            "desk": 3,
            "chair": 5,
            "table": 1,
            "cabinet": 2,
            "shelf": 1,
            "monitor": 3,
            "laptop": 1,
            "cup": 3,
            "book": 3,
            "plant": 1,
        },
    ),
    "meeting_room": (
        (7.0, 5.0, 2.7),
        {"table": 1, "chair": 8, "cabinet": 1, "shelf": 1, "laptop": 2, "cup": 4, "bottle": 2, "plant": 1},
    ),
    "kitchen": (
        (6.0, 5.0, 2.6),
        {
            "counter": 2,
            "fridge": 1,
            "oven": 1,
            "cabinet": 1,
            "microwave": 1,
            "table": 1,
            "chair": 3,
            "cup": 3,
            "bottle": 2,
            "plant": 1,
        },
    ),
    "lounge": (
        (6.0, 5.0, 2.7),
        {"sofa": 1, "chair": 2, "table": 1, "shelf": 2, "cabinet": 1, "plant": 2, "book": 3, "cup": 2},
    ),
    "corridor": ((10.0, 2.4, 2.7), {"bench": 2, "cabinet": 2, "shelf": 1, "plant": 2, "box": 2, "chair": 1}),
}


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class CameraSpec(_Spec):
    """The simulated RGB-D camera."""

    width: int = Field(default=640, ge=16, le=4096, description="Image width in pixels.")
    height: int = Field(default=480, ge=16, le=4096, description="Image height in pixels.")
    fov_x_deg: float = Field(
        default=62.0, gt=10, lt=170, description="Horizontal field of view, degrees (Kinect v1: ~62)."
    )
    max_range: float = Field(default=8.0, gt=0, description="Depth beyond this range reads as no measurement, metres.")
    frame_rate: float = Field(default=30.0, gt=0, description="Timestamps advance by 1/frame_rate seconds.")

    def intrinsics(self) -> CameraIntrinsics:
        fx = self.width / (2 * np.tan(np.radians(self.fov_x_deg) / 2))
        return CameraIntrinsics(self.width, self.height, fx, fx, (self.width - 1) / 2, (self.height - 1) / 2)


class TrajectorySpec(_Spec):
    """The camera path."""

    type: Literal["walk", "orbit", "fixed", "tour"] = Field(
        default="walk",
        description=(
            "walk: a loop through free space like a teleoperated robot; orbit: an ellipse looking at the room center; "
            "fixed: one viewpoint; tour: a path through free space past viewpoints that see every object, for "
            "scenes of any size (the walk keeps to the walls of one room)."
        ),
    )
    frames: int = Field(default=120, ge=1, le=100000, description="Number of frames along the path.")
    height: float = Field(default=1.3, gt=0.1, description="Camera height above the floor, metres (robots: 1.0-1.5).")
    look_height: float = Field(default=0.6, description="Height of the point the camera looks toward, metres.")
    clearance: float = Field(
        default=0.45, gt=0.0, description="Minimum distance from the walk's path to any obstacle, metres."
    )
    view_range: float = Field(
        default=3.0,
        gt=0.5,
        description="tour: the farthest an object may be from the viewpoint chosen to see it, metres.",
    )
    dwell: float = Field(
        default=0.4,
        ge=0.0,
        lt=1.0,
        description="tour: the share of frames spent turning toward objects at viewpoints (the rest: travelling).",
    )


class NoiseSpec(_Spec):
    """Sensor noise. ``depth: none`` renders perfect depth."""

    depth: Literal["none", "kinect"] = Field(
        default="none",
        description=(
            "kinect: axial noise growing with depth squared, disparity quantization, dropouts at grazing angles and "
            "edges."
        ),
    )
    min_range: float = Field(
        default=0.4, ge=0.0, description="Depth closer than this reads as no measurement (Kinect: 0.4 m), metres."
    )
    grazing_angle_deg: float = Field(
        default=84.0, gt=0, le=90, description="Surfaces seen at a larger incidence angle drop out."
    )
    edge_dropout: float = Field(
        default=0.5, ge=0, le=1, description="Probability that a pixel on a depth discontinuity drops out."
    )
    pose_drift: float = Field(
        default=0.0,
        ge=0.0,
        description=(
            "Std of the random walk added to reported poses per frame (metres; radians/10 for yaw). 0: exact poses."
        ),
    )
    laser_std: float = Field(default=0.01, ge=0.0, description="Std of the 2D laser's range noise, metres.")


class LaserSpec(_Spec):
    """A planar 2D laser scanner on the robot base."""

    enabled: bool = Field(default=True, description="Simulate the laser.")
    height: float = Field(
        default=0.25, gt=0.0, description="Scan plane height above the floor, metres (sees chair legs, not seats)."
    )
    beams: int = Field(default=720, ge=8, description="Number of beams.")
    fov_deg: float = Field(
        default=270.0, gt=0, le=360, description="Angular field of view, degrees, centered on the robot's heading."
    )
    range_max: float = Field(
        default=12.0, gt=0, description="Maximum range, metres; farther hits read as no return (inf)."
    )


class LidarSpec(_Spec):
    """A spinning 3D LiDAR on the robot."""

    enabled: bool = Field(default=False, description="Simulate the LiDAR.")
    rings: int = Field(default=16, ge=1, le=256, description="Number of laser rings.")
    vertical_fov_deg: tuple[float, float] = Field(
        default=(-15.0, 15.0), description="Lowest and highest ring elevation, degrees."
    )
    points_per_ring: int = Field(default=900, ge=8, description="Azimuth samples per ring.")
    height: float = Field(default=1.0, gt=0.0, description="Sensor height above the floor, metres.")
    range_max: float = Field(default=30.0, gt=0.0, description="Maximum range, metres.")
    range_std: float = Field(default=0.01, ge=0.0, description="Std of the range noise, metres.")


class GroundTruthSpec(_Spec):
    """How ground-truth occupancy is computed."""

    robot_height: float = Field(default=1.0, gt=0.0, description="Top of the obstacle band, metres.")
    z_min: float = Field(default=0.1, ge=0.0, description="Bottom of the obstacle band, metres.")
    resolution: float = Field(
        default=0.05, gt=0.005, description="Cell and voxel size of ground-truth occupancy, metres."
    )
    coverage: bool = Field(
        default=False,
        description=(
            "Measure the trajectory's coverage: the share of each object's surface (sampled points) that some "
            "frame sees, in the ground truth's layout['coverage']."
        ),
    )


PYBULLET_DATA_PREFIX = "pybullet_data:"


def resolve_library_path(value: str, base: Path | None) -> Path:
    """A library path as written in a spec: ``pybullet_data:REL`` (a file of the pybullet_data
    package), absolute, or relative to ``base`` (the spec file's folder; the working folder when
    None). Raises ValueError when it does not exist."""
    if value.startswith(PYBULLET_DATA_PREFIX):
        import importlib.util

        found = importlib.util.find_spec("pybullet_data")
        if found is None or not found.submodule_search_locations:
            raise ValueError(f"{value!r} needs the pybullet_data package (pip install pybullet)")
        path = Path(list(found.submodule_search_locations)[0]) / value[len(PYBULLET_DATA_PREFIX) :]
    else:
        path = Path(value).expanduser()
        if not path.is_absolute():
            path = (base or Path.cwd()) / path
    if not path.exists():
        where = f" (relative paths are resolved against {base})" if base is not None else ""
        raise ValueError(f"{value!r} not found{where}: expected a model library folder or a .urdf file")
    return path.resolve()


class LibrarySource(_Spec):
    """Where objects come from when they are not generated: a model library folder (PartNet-Mobility
    objects, stratamap's own format, meshes with classes.csv) or one URDF file."""

    path: str = Field(
        description=(
            "Library folder or .urdf file; relative to the spec file's folder, or pybullet_data:REL for a file of "
            "the pybullet_data package."
        )
    )
    models: list[str] | None = Field(
        default=None,
        description=(
            "Ids of the models to draw from (PartNet folder names such as '179' work too); default: every model "
            "of the object's class in the library."
        ),
    )
    links: list[str] | None = Field(
        default=None,
        description="URDF only: the links whose subtrees make the object (one cabinet of a whole kitchen).",
    )
    front: Literal["-y", "+y", "-x", "+x"] = Field(
        default="-y",
        description="The side of the model that is its front (doors, the seat's open side), turned to face the room.",
    )
    height: float | tuple[float, float] | None = Field(
        default=None,
        description="Scale each object uniformly to this height, or to a height drawn from [low, high], metres.",
    )
    scale: float | None = Field(
        default=None, gt=0, description="Scale factor to metres; default 1, or the class's typical height if unitless."
    )
    up_axis: Literal["z", "y"] = Field(default="z", description="Up axis of the meshes of a mesh folder.")

    @field_validator("path")
    @classmethod
    def _exists(cls, value: str, info: ValidationInfo) -> str:
        base = (info.context or {}).get("base_dir")
        return str(resolve_library_path(value, Path(base) if base else None))

    @field_validator("height")
    @classmethod
    def _positive_height(cls, value: float | tuple[float, float] | None) -> float | tuple[float, float] | None:
        low, high = (value, value) if isinstance(value, (int, float)) else (value or (1.0, 1.0))
        if not 0 < low <= high:
            raise ValueError(f"height must be positive (a range as [low, high] with low <= high), got {value}")
        return value

    @model_validator(mode="after")
    def _links_need_urdf(self) -> LibrarySource:
        if self.links and not self.path.lower().endswith(".urdf"):
            raise ValueError("`links` selects parts of a .urdf file; `path` is not one")
        if self.height is not None and self.scale is not None:
            raise ValueError("give `height` or `scale`, not both")
        return self


#: Tags of the union branches below; dropped from error locations (``objects.chair.library.path``).
_BRANCH_TAGS = ("<one library>", "<libraries>", "<count>", "<entry>")

Libraries = Annotated[
    Annotated[LibrarySource, Tag("<one library>")] | Annotated[list[LibrarySource], Tag("<libraries>")],
    Discriminator(lambda value: "<libraries>" if isinstance(value, list) else "<one library>"),
]


class ObjectSpec(_Spec):
    """How many objects of a class, and where their models come from."""

    count: int = Field(ge=0, le=64, description="Number of objects of this class.")
    library: Libraries | None = Field(
        default=None,
        description=(
            "Draw the models from this library, or from these in turn (default: the spec's `library`, else generate)."
        ),
    )


ObjectEntry = Annotated[
    Annotated[int, Tag("<count>")] | Annotated[ObjectSpec, Tag("<entry>")],
    Discriminator(lambda value: "<entry>" if isinstance(value, (dict, ObjectSpec)) else "<count>"),
]


class SceneSpec(_Spec):
    """A procedural scene: type, room, objects, seed, sensors, trajectory and noise."""

    type: Literal["room", "office", "meeting_room", "kitchen", "lounge", "corridor"] = Field(
        default="room", description="Scene type; decides default room size, furniture and placement rules."
    )
    room_size: tuple[float, float, float] | None = Field(
        default=None, description="Interior length (x), width (y), height (z) in metres; default per type."
    )
    objects: dict[str, ObjectEntry] | None = Field(
        default=None,
        description="Object counts by class, or {count, library} to draw a class from a library; default per type.",
    )
    library: LibrarySource | None = Field(
        default=None, description="Draw every class that names no library of its own from this model library."
    )
    seed: int = Field(default=0, description="Seed of every random choice: same spec and seed, same files bit for bit.")
    camera: CameraSpec = Field(default_factory=CameraSpec, description="The RGB-D camera.")
    trajectory: TrajectorySpec = Field(default_factory=TrajectorySpec, description="The camera path.")
    noise: NoiseSpec = Field(default_factory=NoiseSpec, description="Sensor noise.")
    laser: LaserSpec = Field(default_factory=LaserSpec, description="The 2D laser scanner.")
    lidar: LidarSpec = Field(default_factory=LidarSpec, description="The 3D LiDAR.")
    ground_truth: GroundTruthSpec = Field(
        default_factory=GroundTruthSpec, description="Ground-truth occupancy settings."
    )
    varied_fixtures: bool = Field(
        default=False,
        description=(
            "Give each generated model's handles and knobs a style of their own (bar section, standoff, length, "
            "light metal or dark), as training data for the fixture classifier (scripts/train_fixtures.py); "
            "false: the one style every benchmark scene was made with."
        ),
    )

    @field_validator("objects")
    @classmethod
    def _known_classes(cls, value: dict[str, ObjectEntry] | None) -> dict[str, ObjectEntry] | None:
        if value is None:
            return value
        from stratamap.core.synthetic.placement import PLACEMENT

        unknown = sorted(set(value) - set(PLACEMENT))
        if unknown:
            raise ValueError(f"unknown object classes {unknown}; known: {sorted(PLACEMENT)}")
        for name, entry in value.items():
            count = entry.count if isinstance(entry, ObjectSpec) else entry
            if count < 0 or count > 64:
                raise ValueError(f"count of {name!r} must be between 0 and 64, got {count}")
        return value

    def resolved_room_size(self) -> tuple[float, float, float]:
        return tuple(self.room_size or SCENE_DEFAULTS[self.type][0])  # type: ignore[return-value]

    def resolved_objects(self) -> dict[str, int]:
        objects = self.objects if self.objects is not None else SCENE_DEFAULTS[self.type][1]
        return {name: (entry.count if isinstance(entry, ObjectSpec) else entry) for name, entry in objects.items()}

    def resolved_sources(self) -> dict[str, list[LibrarySource]]:
        """The model libraries of each class drawn from them (classes absent are generated)."""
        objects = self.objects if self.objects is not None else SCENE_DEFAULTS[self.type][1]
        out = {}
        for name, entry in objects.items():
            source = entry.library if isinstance(entry, ObjectSpec) else None
            source = source or self.library
            if source is not None:
                out[name] = source if isinstance(source, list) else [source]
        return out

    @classmethod
    def from_yaml(cls, path: str | Path) -> SceneSpec:
        """A spec file; its relative library paths are resolved against the file's folder."""
        path = Path(path)
        doc = read_mapping(path, "scene spec")
        return cls.from_document(doc, path.parent, source=str(path))

    @classmethod
    def from_document(cls, doc: dict[str, Any], base_dir: Path | None, source: str | None = None) -> SceneSpec:
        """A spec from its YAML mapping, relative library paths resolved against ``base_dir``."""
        try:
            return cls.model_validate(doc, context={"base_dir": str(base_dir) if base_dir else None})
        except ValidationError as exc:
            problems = [
                (".".join(part for part in key.split(".") if part not in _BRANCH_TAGS), message)
                for key, message in validation_problems(exc)
            ]
            raise ConfigError(problems, source=source) from None


def resolve_spec_paths(doc: dict[str, Any], base_dir: Path) -> dict[str, Any]:
    """A copy of a spec's YAML mapping whose relative library paths are made absolute against
    ``base_dir`` (for specs read from a file and then passed on as a mapping, as benchmarks do)."""
    import copy

    out = copy.deepcopy(doc)

    def fix(library: Any) -> None:
        if isinstance(library, dict) and isinstance(library.get("path"), str):
            value = library["path"]
            if not value.startswith(PYBULLET_DATA_PREFIX) and not Path(value).expanduser().is_absolute():
                library["path"] = str((base_dir / value).resolve())

    fix(out.get("library"))
    objects = out.get("objects")
    for entry in objects.values() if isinstance(objects, dict) else []:
        libraries = entry.get("library") if isinstance(entry, dict) else None
        for library in libraries if isinstance(libraries, list) else [libraries]:
            fix(library)
    return out
