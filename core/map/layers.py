"""The five layers of a stratamap map, and the ``LayeredMap`` that holds them.

All layers live in one metric, gravity-aligned world frame (z up, metres). Each is a plain
dataclass of numpy arrays plus metadata so that stages, tests and users can build them directly.

Layer names used in stage ``requires``/``provides`` declarations:

=================  =========================================================================
``occupancy``      :class:`OccupancyMaps` -- named 2D grids (``slam``, ``objects``, ``multimap``)
``geometry``       :class:`Geometry` -- colored points and/or a triangle mesh of the scene
``semantics``      :class:`Semantics` -- class and instance id per geometry point
``instances``      :class:`ObjectInstances` -- one entry per object, with its completion
``contact_graph``  :class:`ContactGraph` -- support and proximal relations
``augmented``      :class:`Geometry` -- the augmented scene A = (G \\ S) U O
=================  =========================================================================
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.atomic import atomic_directory, write_json
from stratamap.core.errors import MapFormatError
from stratamap.core.geometry.boxes import OrientedBox
from stratamap.core.lazy import lazy_module
from stratamap.core.map.vocabulary import Vocabulary

nx = lazy_module("networkx")
trimesh = lazy_module("trimesh")

MAP_FORMAT = "stratamap.map"
MAP_FORMAT_VERSION = 1

MAP_LAYERS = ("occupancy", "geometry", "semantics", "instances", "contact_graph", "augmented")


# --------------------------------------------------------------------------------------------
# 2D occupancy


@dataclass
class OccupancyGrid:
    """A 2D occupancy grid in the ROS convention.

    ``data[row, col]`` is the cell at ``x = origin_x + (col + 0.5) * resolution`` and
    ``y = origin_y + (row + 0.5) * resolution`` (row 0 is the *lowest* y, as in
    ``nav_msgs/OccupancyGrid``; image writers flip it). Values: -1 unknown, 0 free .. 100 occupied.
    """

    data: np.ndarray  # (H, W) int8
    resolution: float  # metres per cell
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)  # x, y, yaw of cell (0, 0)'s corner
    frame_id: str = "map"

    def __post_init__(self) -> None:
        self.data = np.asarray(self.data, dtype=np.int8)
        if self.data.ndim != 2:
            raise ValueError(f"occupancy data must be 2D, got shape {self.data.shape}")
        if self.resolution <= 0:
            raise ValueError(f"resolution must be positive, got {self.resolution}")
        self.origin = tuple(float(v) for v in self.origin)  # type: ignore[assignment]

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) world x, y -> (N, 2) integer (row, col); may be out of bounds."""
        xy = np.atleast_2d(np.asarray(xy, float))
        ox, oy, yaw = self.origin
        c, s = np.cos(-yaw), np.sin(-yaw)
        dx, dy = xy[:, 0] - ox, xy[:, 1] - oy
        lx, ly = c * dx - s * dy, s * dx + c * dy
        return np.stack([np.floor(ly / self.resolution), np.floor(lx / self.resolution)], axis=1).astype(np.int64)

    def cell_to_world(self, rc: np.ndarray) -> np.ndarray:
        """(N, 2) (row, col) -> (N, 2) world x, y of cell centers."""
        rc = np.atleast_2d(np.asarray(rc, float))
        ox, oy, yaw = self.origin
        lx, ly = (rc[:, 1] + 0.5) * self.resolution, (rc[:, 0] + 0.5) * self.resolution
        c, s = np.cos(yaw), np.sin(yaw)
        return np.stack([ox + c * lx - s * ly, oy + s * lx + c * ly], axis=1)

    def in_bounds(self, rc: np.ndarray) -> np.ndarray:
        rc = np.atleast_2d(rc)
        return (rc[:, 0] >= 0) & (rc[:, 0] < self.height) & (rc[:, 1] >= 0) & (rc[:, 1] < self.width)

    def counts(self) -> dict[str, int]:
        return {
            "free": int((self.data == 0).sum()),
            "occupied": int((self.data >= 65).sum()),
            "unknown": int((self.data < 0).sum()),
        }


class OccupancyMaps(dict[str, OccupancyGrid]):
    """Named occupancy grids. Conventional names: ``slam`` (laser only), ``objects`` (3D objects
    projected from a height band), ``multimap`` (the two overlaid)."""


# --------------------------------------------------------------------------------------------
# 3D geometry and semantics


@dataclass
class Geometry:
    """Reconstructed scene geometry: colored points and/or a triangle mesh."""

    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (N, 3) float64
    colors: np.ndarray | None = None  # (N, 3) float32 in [0, 1]
    normals: np.ndarray | None = None  # (N, 3)
    mesh: trimesh.Trimesh | None = None
    voxel_size: float | None = None  # set when a TSDF volume backs the geometry

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        for name in ("colors", "normals"):
            arr = getattr(self, name)
            if arr is not None:
                arr = np.asarray(arr, dtype=np.float32).reshape(-1, 3)
                if len(arr) != len(self.points):
                    raise ValueError(f"Geometry.{name} has {len(arr)} rows for {len(self.points)} points")
                setattr(self, name, arr)

    def __len__(self) -> int:
        return len(self.points)


@dataclass
class Semantics:
    """Panoptic labels of ``Geometry.points``: a class id and an instance id (0 = none) per point."""

    class_ids: np.ndarray  # (N,) int32
    instance_ids: np.ndarray  # (N,) int32
    vocabulary: Vocabulary = field(default_factory=Vocabulary.default)
    plane_ids: np.ndarray | None = None  # (N,) int32, planar segment per point (-1 none), from plane segmenters

    def __post_init__(self) -> None:
        self.class_ids = np.asarray(self.class_ids, dtype=np.int32).reshape(-1)
        self.instance_ids = np.asarray(self.instance_ids, dtype=np.int32).reshape(-1)
        if self.class_ids.shape != self.instance_ids.shape:
            raise ValueError("class_ids and instance_ids must have the same length")
        if self.plane_ids is not None:
            self.plane_ids = np.asarray(self.plane_ids, dtype=np.int32).reshape(-1)
            if self.plane_ids.shape != self.class_ids.shape:
                raise ValueError("plane_ids must have one entry per point")

    def __len__(self) -> int:
        return len(self.class_ids)


# --------------------------------------------------------------------------------------------
# Object instances


@dataclass
class Joint:
    """An articulation joint between two parts of a model (URDF semantics)."""

    name: str
    type: str  # "revolute" | "prismatic" | "continuous" | "fixed"
    parent: str  # part name
    child: str  # part name
    origin: np.ndarray  # (4, 4) child frame in the parent frame at joint position 0
    axis: np.ndarray  # (3,) unit axis in the joint frame
    lower: float = 0.0
    upper: float = 0.0

    def __post_init__(self) -> None:
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(4, 4)
        self.axis = np.asarray(self.axis, dtype=np.float64).reshape(3)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "type": self.type,
            "parent": self.parent,
            "child": self.child,
            "origin": self.origin.tolist(),
            "axis": self.axis.tolist(),
            "lower": self.lower,
            "upper": self.upper,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Joint:
        return cls(**d)


@dataclass
class Part:
    """A rigid part of a completed model; ``mesh`` is in the part frame, ``pose`` is part-to-object."""

    name: str
    mesh: trimesh.Trimesh
    pose: np.ndarray = field(default_factory=lambda: np.eye(4))


@dataclass
class Completion:
    """A complete model that explains a partially observed object.

    ``mesh`` is the whole model in the *object frame*; ``pose`` maps the object frame (origin at the
    bottom center of the model, +z up) into the world; ``scale`` has already been applied to ``mesh``.
    ``alternatives`` are the completer's next-best candidates for the same object, best first, each
    posed as it would be chosen (the physical check swaps to one that removes a conflict); they live
    in memory only: saved maps keep the chosen model.
    """

    mesh: trimesh.Trimesh
    pose: np.ndarray
    completer: str
    model_id: str | None = None
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    score: float = 0.0
    parts: list[Part] = field(default_factory=list)
    joints: list[Joint] = field(default_factory=list)
    alternatives: list[Completion] = field(default_factory=list, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.pose = np.asarray(self.pose, dtype=np.float64).reshape(4, 4)
        self.scale = np.broadcast_to(np.asarray(self.scale, dtype=np.float64), (3,)).copy()

    def world_mesh(self) -> trimesh.Trimesh:
        mesh = self.mesh.copy()
        mesh.apply_transform(self.pose)
        return mesh


@dataclass
class ObjectInstance:
    """One object of the scene: what was observed, and (once completed) the full model."""

    id: int
    class_name: str
    points: np.ndarray  # (N, 3) observed partial points, world frame
    box: OrientedBox
    colors: np.ndarray | None = None
    score: float = 1.0  # detection / segmentation confidence
    completion: Completion | None = None
    attributes: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.id = int(self.id)
        self.points = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        if self.colors is not None:
            self.colors = np.asarray(self.colors, dtype=np.float32).reshape(-1, 3)


class ObjectInstances:
    """An ordered collection of :class:`ObjectInstance`, addressable by id."""

    def __init__(self, instances: list[ObjectInstance] | None = None):
        self._items: dict[int, ObjectInstance] = {}
        for inst in instances or []:
            self.add(inst)

    def add(self, instance: ObjectInstance) -> None:
        if instance.id in self._items:
            raise ValueError(f"duplicate object instance id {instance.id}")
        self._items[instance.id] = instance

    def __getitem__(self, instance_id: int) -> ObjectInstance:
        return self._items[int(instance_id)]

    def __contains__(self, instance_id: object) -> bool:
        return instance_id in self._items

    def __iter__(self) -> Iterator[ObjectInstance]:
        return iter(self._items.values())

    def __len__(self) -> int:
        return len(self._items)

    def ids(self) -> list[int]:
        return list(self._items)

    def completed(self) -> list[ObjectInstance]:
        return [i for i in self if i.completion is not None]

    def copy(self) -> ObjectInstances:
        """A copy to fill completions and attributes on, leaving the input untouched (point
        arrays are shared: stages never modify them in place)."""
        import copy as _copy

        out = []
        for inst in self:
            dup = _copy.copy(inst)
            dup.attributes = _copy.deepcopy(inst.attributes)
            out.append(dup)
        return ObjectInstances(out)


# --------------------------------------------------------------------------------------------
# Contact graph

SCENE_NODE = "scene"


@dataclass
class ContactGraph:
    """Support and proximal relations between the scene root, layout and objects.

    ``support`` is a DiGraph: an edge ``parent -> child`` means the parent supports the child; its
    ``plane`` attribute is the supporting plane ``[a, b, c, d]`` (ax + by + cz + d = 0). Every node
    but the root has exactly one parent. Object nodes are the instance ids (ints); layout nodes are
    strings (``"floor"``, ``"wall_0"``, ``"ceiling"``) and the root is ``"scene"``. ``proximal`` is
    an undirected graph over the same nodes.
    """

    support: nx.DiGraph = field(default_factory=lambda: nx.DiGraph())
    proximal: nx.Graph = field(default_factory=lambda: nx.Graph())

    def __post_init__(self) -> None:
        if SCENE_NODE not in self.support:
            self.support.add_node(SCENE_NODE, kind="scene")

    def parent(self, node: Any) -> Any | None:
        preds = list(self.support.predecessors(node))
        return preds[0] if preds else None

    def is_tree(self) -> bool:
        return nx.is_arborescence(self.support)

    def object_nodes(self) -> list[Any]:
        return [n for n, d in self.support.nodes(data=True) if d.get("kind") == "object"]

    def to_dict(self) -> dict[str, Any]:
        return {
            "support": nx.node_link_data(self.support, edges="links"),
            "proximal": nx.node_link_data(self.proximal, edges="links"),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ContactGraph:
        return cls(
            support=nx.node_link_graph(d["support"], directed=True, edges="links"),
            proximal=nx.node_link_graph(d["proximal"], directed=False, edges="links"),
        )


# --------------------------------------------------------------------------------------------
# The layered map


@dataclass
class LayeredMap:
    """All layers of one map, the vocabulary, and which stage produced each layer."""

    vocabulary: Vocabulary = field(default_factory=Vocabulary.default)
    occupancy: OccupancyMaps = field(default_factory=OccupancyMaps)
    geometry: Geometry | None = None
    semantics: Semantics | None = None
    instances: ObjectInstances | None = None
    contact_graph: ContactGraph | None = None
    augmented: Geometry | None = None
    provenance: dict[str, str] = field(default_factory=dict)  # layer -> plugin name
    metadata: dict[str, Any] = field(default_factory=dict)

    def get(self, layer: str) -> Any:
        if layer not in MAP_LAYERS:
            raise KeyError(f"unknown map layer {layer!r}; layers are {MAP_LAYERS}")
        value = getattr(self, layer)
        if layer == "occupancy" and not value:
            return None
        return value

    def set(self, layer: str, value: Any, producer: str) -> None:
        if layer not in MAP_LAYERS:
            raise KeyError(f"unknown map layer {layer!r}; layers are {MAP_LAYERS}")
        if layer == "occupancy" and not isinstance(value, OccupancyMaps):
            value = OccupancyMaps(value)
        setattr(self, layer, value)
        self.provenance[layer] = producer

    def layer_counts(self) -> dict[str, Any]:
        """A short summary per present layer (for reports and logs)."""
        counts: dict[str, Any] = {}
        if self.occupancy:
            counts["occupancy"] = {name: grid.counts() for name, grid in self.occupancy.items()}
        if self.geometry is not None:
            counts["geometry"] = {
                "points": len(self.geometry),
                "triangles": 0 if self.geometry.mesh is None else len(self.geometry.mesh.faces),
            }
        if self.semantics is not None:
            counts["semantics"] = {
                "labelled_points": int((self.semantics.class_ids > 0).sum()),
                "instances": int(len(np.unique(self.semantics.instance_ids[self.semantics.instance_ids > 0]))),
            }
        if self.instances is not None:
            by_class: dict[str, int] = {}
            for inst in self.instances:
                by_class[inst.class_name] = by_class.get(inst.class_name, 0) + 1
            counts["instances"] = {
                "objects": len(self.instances),
                "completed": len(self.instances.completed()),
                "by_class": dict(sorted(by_class.items())),
            }
        if self.contact_graph is not None:
            counts["contact_graph"] = {
                "nodes": self.contact_graph.support.number_of_nodes(),
                "support_edges": self.contact_graph.support.number_of_edges(),
                "proximal_edges": self.contact_graph.proximal.number_of_edges(),
            }
        if self.augmented is not None:
            counts["augmented"] = {"points": len(self.augmented)}
        return counts

    # ---------------------------------------------------------------- persistence

    def save(self, directory: str | Path) -> Path:
        """Write the map to ``directory`` (replaced atomically as a whole; a file, or a folder of other files that
        is not a saved map, is refused). Saving a loaded map gives the same bytes. See ``docs/map-format.md``."""
        from stratamap.core.map import format as map_format

        directory = Path(directory)
        if directory.exists() and not directory.is_dir():
            raise MapFormatError(
                f"{directory}: is a file, not a folder; a map is saved as a folder (nothing was written)"
            )
        if directory.is_dir() and not (directory / "manifest.json").is_file() and any(directory.iterdir()):
            raise MapFormatError(
                f"{directory}: holds files but no manifest.json, so it is not a saved map; saving would replace "
                "them (choose a new or empty folder; nothing was written)"
            )
        with atomic_directory(directory) as staging:
            manifest = map_format.write_layers(self, staging)
            write_json(staging / "manifest.json", manifest)
        return directory

    @classmethod
    def load(cls, directory: str | Path) -> LayeredMap:
        from stratamap.core.map import format as map_format

        directory = Path(directory)
        manifest_path = directory / "manifest.json"
        if not manifest_path.is_file():
            raise MapFormatError(f"{manifest_path}: no manifest; is {directory} a saved stratamap map?")
        try:
            manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise MapFormatError(f"{manifest_path}: corrupt JSON ({' '.join(str(exc).split())})") from exc
        except OSError as exc:
            raise MapFormatError(f"{manifest_path}: cannot be read ({' '.join(str(exc).split())})") from exc
        if not isinstance(manifest, dict):
            raise MapFormatError(f"{manifest_path}: expected a JSON object, got {type(manifest).__name__}")
        if manifest.get("format") != MAP_FORMAT:
            raise MapFormatError(f"{manifest_path}: format is {manifest.get('format')!r}, expected {MAP_FORMAT!r}")
        if manifest.get("version") != MAP_FORMAT_VERSION:
            raise MapFormatError(
                f"{manifest_path}: format version {manifest.get('version')} is not supported "
                f"(this stratamap reads version {MAP_FORMAT_VERSION})"
            )
        return map_format.read_layers(manifest, directory)
