"""What the viewer draws, computed from a saved map with numpy only (no web server involved).

:func:`build_scene` turns a :class:`LayeredMap` into display-ready arrays: the geometry points
(evenly subsampled to a display budget) with their colours per mode, one :class:`ObjectView` per
object (box edges, label, completed model split into its parts, joints), the contact-graph edges,
and the occupancy layers and Nav2 costmap as ground textures. :func:`part_poses` is the forward
kinematics of a completed model for given joint values; :func:`object_info` is the text shown when
an object is clicked. ``stratamap.core.viewer.app`` puts all of it into a viser scene.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stratamap.core.errors import DataError
from stratamap.core.geometry.transforms import matrix_to_quat_xyzw
from stratamap.core.io.nav2 import costmap_values
from stratamap.core.lazy import lazy_module
from stratamap.core.map.colors import UNLABELLED_GREY as GREY
from stratamap.core.map.colors import id_colors
from stratamap.core.map.instances import naming_text
from stratamap.core.map.layers import SCENE_NODE, Completion, ContactGraph, Joint, LayeredMap, ObjectInstance
from stratamap.core.map.vocabulary import Vocabulary

trimesh = lazy_module("trimesh")

#: Geometry points sent to the browser at most: a whole room at 2 cm voxels stays interactive and loads in seconds.
MAX_DISPLAY_POINTS = 400_000
COLOR_MODES = ("rgb", "class", "instance")
#: How objects are shown: their observed points only, completed models in place of them, or both together.
OBJECT_VIEWS = ("completed", "observed", "both")
#: Nav2's inflation defaults, as the ``costmap`` exporter uses them (metres, metres, 1/metre).
COSTMAP_INFLATION = {"inscribed_radius": 0.2, "inflation_radius": 0.55, "cost_scaling_factor": 10.0}
COSTMAP_TEXTURE = "costmap"
UNLABELLED_GREY = np.full(3, GREY)
#: Box edges as pairs of corner indices (corners ordered bottom face then top face).
BOX_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]])
MOVING_JOINTS = ("revolute", "prismatic", "continuous")


def find_map_dir(path: str | Path) -> Path:
    """The saved map at ``path``: a map folder (with ``manifest.json``) or a run's output folder holding ``map/``."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file or folder; pass a run's output folder or its map/ folder")
    for candidate in (path, path / "map"):
        if (candidate / "manifest.json").is_file():
            return candidate
    raise DataError(
        f"{path}: not a stratamap map (no manifest.json here or in map/); pass a run's output folder or its map/ folder"
    )


def display_indices(count: int, limit: int) -> np.ndarray:
    """Indices of at most ``limit`` of ``count`` points, evenly spaced (deterministic, keeps the whole extent)."""
    if count <= limit:
        return np.arange(count)
    return np.unique(np.linspace(0, count - 1, limit).round().astype(np.int64))


def class_color(vocabulary: Vocabulary, class_name: str) -> np.ndarray:
    """The colour of a class in class mode; a class outside the vocabulary gets a stable colour from its name."""
    class_id = vocabulary.id(class_name) if class_name in vocabulary else zlib.crc32(class_name.encode()) % 19 + 1
    return id_colors(np.array([class_id]))[0]


def quaternion_wxyz(rotation: np.ndarray) -> np.ndarray:
    """A 3x3 rotation as a unit quaternion, scalar first (viser's convention)."""
    x, y, z, w = matrix_to_quat_xyzw(np.asarray(rotation, dtype=np.float64))
    return np.array([w, x, y, z])


def yaw_wxyz(yaw: float) -> np.ndarray:
    """A rotation about +z as a unit quaternion, scalar first."""
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


# --------------------------------------------------------------------------------------------
# Forward kinematics of completed models


def joint_motion(joint: Joint, value: float) -> np.ndarray:
    """The child's motion in the joint frame at joint position ``value`` (radians or metres; URDF semantics)."""
    motion = np.eye(4)
    if joint.type in ("revolute", "continuous"):
        motion = trimesh.transformations.rotation_matrix(float(value), joint.axis)
    elif joint.type == "prismatic":
        motion[:3, 3] = joint.axis * float(value)
    return motion


def joint_range(joint: Joint) -> tuple[float, float]:
    """The slider range of a joint: its limits, a full turn for a continuous joint."""
    if joint.type == "continuous" or joint.upper <= joint.lower:
        return (-float(np.pi), float(np.pi)) if joint.type == "continuous" else (joint.lower, joint.lower)
    return float(joint.lower), float(joint.upper)


def part_poses(completion: Completion, values: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """Part name -> part-to-object pose with joints at ``values`` (by joint name; 0 when absent).

    A part moved by a joint sits at ``parent pose @ joint.origin @ motion(value)``, as the URDF, MJCF and SDF
    exports place it; a part no joint moves keeps its saved pose."""
    values = values or {}
    parts = {p.name: p for p in completion.parts}
    by_child = {j.child: j for j in completion.joints if j.child in parts}
    poses: dict[str, np.ndarray] = {}

    def pose_of(name: str, chain: tuple[str, ...] = ()) -> np.ndarray:
        if name not in poses:
            joint = by_child.get(name)
            if joint is None or joint.parent not in parts or joint.parent in chain:
                poses[name] = np.asarray(parts[name].pose, dtype=np.float64)
            else:
                parent = pose_of(joint.parent, (*chain, name))
                poses[name] = parent @ joint.origin @ joint_motion(joint, values.get(joint.name, 0.0))
        return poses[name]

    for name in parts:
        pose_of(name)
    return poses


# --------------------------------------------------------------------------------------------
# The scene


@dataclass
class PartView:
    """One rigid piece of a completed model: its mesh in the part frame."""

    name: str
    vertices: np.ndarray  # (V, 3) float32
    faces: np.ndarray  # (F, 3) uint32


@dataclass
class JointControl:
    """A movable joint of a completed model and the range its slider spans."""

    name: str
    type: str
    child: str
    lower: float
    upper: float


@dataclass
class ObjectView:
    """One object of the map, ready to draw."""

    id: int
    class_name: str
    color: np.ndarray  # (3,) in [0, 1], its class colour
    box_segments: np.ndarray  # (12, 2, 3) the box's edges, world frame
    box_center: np.ndarray  # (3,)
    box_size: np.ndarray  # (3,) along the box's axes
    box_yaw: float
    label_position: np.ndarray  # (3,) above the box
    completion: Completion | None = None
    pose: np.ndarray | None = None  # object-to-world pose of the completed model
    parts: list[PartView] = field(default_factory=list)  # the completed model, split into rigid parts
    joints: list[JointControl] = field(default_factory=list)

    @property
    def title(self) -> str:
        return f"{self.class_name} {self.id}"

    def part_poses(self, values: dict[str, float] | None = None) -> dict[str, np.ndarray]:
        """Part name -> part-to-object pose with the joints at ``values`` (a rigid model: its one part at rest)."""
        if self.completion is None or not self.completion.parts:
            return {part.name: np.eye(4) for part in self.parts}
        return part_poses(self.completion, values)


@dataclass
class GroundTexture:
    """A 2D layer drawn as an image on the floor: ``image[row, col]`` covers world cells as the grid does."""

    name: str
    image: np.ndarray  # (H, W, 3) uint8, row 0 at the lowest y of the grid (as viser lays images out)
    width: float  # metres along the grid's x
    height: float  # metres along the grid's y
    center: np.ndarray  # (3,) world position of the image center
    yaw: float  # rotation of the grid about +z


@dataclass
class ViewerScene:
    """Everything the viewer shows, computed once from a map."""

    source: Path | None
    points: np.ndarray  # (N, 3) float32, the displayed subset of the geometry
    colors: dict[str, np.ndarray]  # mode -> (N, 3) uint8
    point_instance_ids: np.ndarray  # (N,) instance id of each displayed point (0 none)
    total_points: int  # before subsampling
    point_size: float
    mesh: trimesh.Trimesh | None  # the geometry layer's surface mesh, if any
    objects: list[ObjectView]
    support_edges: np.ndarray  # (E, 2, 3) supporter -> supported, between object box centers
    proximal_edges: np.ndarray  # (P, 2, 3)
    textures: dict[str, GroundTexture]
    floor_z: float
    bounds: np.ndarray  # (2, 3) min and max corner of everything drawn
    info: dict[int, str]  # object id -> markdown shown when it is clicked

    def object(self, object_id: int) -> ObjectView:
        for obj in self.objects:
            if obj.id == object_id:
                return obj
        raise KeyError(object_id)

    def visible_points(self, view: str) -> np.ndarray:
        """Mask of displayed points for an object view: completed objects' observed points give way to their models."""
        if view != "completed":
            return np.ones(len(self.points), dtype=bool)
        completed = [obj.id for obj in self.objects if obj.parts]
        return ~np.isin(self.point_instance_ids, completed)


def _box_corners(inst: ObjectInstance) -> np.ndarray:
    footprint = inst.box.corners_2d()
    bottom = np.column_stack([footprint, np.full(4, inst.box.bottom_z)])
    top = np.column_stack([footprint, np.full(4, inst.box.top_z)])
    return np.vstack([bottom, top])


def _object_view(inst: ObjectInstance, vocabulary: Vocabulary) -> ObjectView:
    corners = _box_corners(inst)
    view = ObjectView(
        id=inst.id,
        class_name=inst.class_name,
        color=class_color(vocabulary, inst.class_name),
        box_segments=corners[BOX_EDGES],
        box_center=inst.box.center.copy(),
        box_size=inst.box.size.copy(),
        box_yaw=inst.box.yaw,
        label_position=np.array([*inst.box.center[:2], inst.box.top_z + 0.08]),
    )
    c = inst.completion
    if c is None:
        return view
    view.completion, view.pose = c, c.pose
    if c.parts:
        meshes = [(p.name, p.mesh) for p in c.parts]
    else:  # a rigid model: one part, the whole mesh, in the object frame
        meshes = [("body", c.mesh)]
    view.parts = [
        PartView(name, np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32))
        for name, mesh in meshes
    ]
    part_names = {p.name for p in view.parts}
    for j in c.joints:
        if j.type in MOVING_JOINTS and j.child in part_names:
            lower, upper = joint_range(j)
            if upper > lower:
                view.joints.append(JointControl(j.name, j.type, j.child, lower, upper))
    return view


def supporters(graph: ContactGraph | None) -> dict[object, object]:
    """Supported node -> its supporter, from the contact graph's support tree."""
    if graph is None:
        return {}
    return {child: parent for parent, child in graph.support.edges() if parent != SCENE_NODE}


def _node_name(node: object, m: LayeredMap) -> str:
    if isinstance(node, int | np.integer) and m.instances is not None and int(node) in m.instances:
        inst = m.instances[int(node)]
        return f"{inst.class_name} {inst.id}"
    return str(node)


def object_info(m: LayeredMap, inst: ObjectInstance) -> str:
    """Markdown for a clicked object: class, how it got its class, points, model, fit score, scale, supporter,
    what it supports, joints."""
    below = supporters(m.contact_graph)
    on_top = sorted(
        (_node_name(child, m) for child, parent in below.items() if parent == inst.id and child != inst.id), key=str
    )
    c = inst.completion
    rows = [
        ("class", inst.class_name),
        ("named by", naming_text(inst)),
        ("points", f"{len(inst.points)} observed"),
        ("box", " x ".join(f"{v:.2f}" for v in inst.box.size) + " m"),
        ("detection score", f"{inst.score:.3g}"),
        ("model", "not completed" if c is None else f"{c.model_id or '-'} ({c.completer})"),
        ("fit score", "-" if c is None else f"{c.score:.4g}"),
        ("scale", "-" if c is None else " x ".join(f"{v:.3f}" for v in c.scale)),
        ("supporter", _node_name(below[inst.id], m) if inst.id in below else "-"),
        ("supports", ", ".join(on_top) or "-"),
    ]
    joints = [] if c is None else c.joints
    for j in joints:
        limits = "" if j.type in ("continuous", "fixed") else f", {j.lower:.3g} .. {j.upper:.3g}"
        rows.append((f"joint {j.name}", f"{j.type} ({j.parent} -> {j.child}{limits})"))
    if not joints:
        rows.append(("joints", "none"))
    table = "\n".join(f"| {k} | {v} |" for k, v in rows)
    return f"**{inst.class_name} {inst.id}**\n\n| | |\n|---|---|\n{table}\n"


def _floor_z(points: np.ndarray, class_ids: np.ndarray | None, vocabulary: Vocabulary | None) -> float:
    if len(points) == 0:
        return 0.0
    if class_ids is not None and vocabulary is not None and "floor" in vocabulary:
        floor = class_ids == vocabulary.id("floor")
        if floor.sum() >= 20:
            return float(np.median(points[floor, 2]))
    return float(np.percentile(points[:, 2], 2))


def _occupancy_rgb(data: np.ndarray) -> np.ndarray:
    """Occupancy values (-1 unknown, 0 free .. 100 occupied) as grey levels: free light, occupied dark."""
    level = 235.0 - np.clip(data, 0, 100).astype(np.float64) * 2.0
    level[data < 0] = 150.0
    return np.repeat(level.round().astype(np.uint8)[..., None], 3, axis=2)


def _costmap_rgb(values: np.ndarray) -> np.ndarray:
    """Nav2 cost values in RViz's colours: free white, inflation ramp, inscribed cyan, lethal magenta, unknown grey."""
    from matplotlib import colormaps

    ramp = (np.asarray(colormaps["plasma"](np.linspace(1.0, 0.0, 253)))[:, :3] * 255).round().astype(np.uint8)
    table = np.zeros((256, 3), np.uint8)
    table[:253] = ramp
    table[0] = (240, 240, 240)
    table[253] = (0, 220, 220)
    table[254] = (220, 0, 220)
    table[255] = (128, 128, 128)
    return table[np.asarray(values, np.uint8)]


def _crisp(image: np.ndarray, max_side: int = 2048) -> np.ndarray:
    """Repeat cells so that a coarse grid keeps sharp cell edges once the browser filters the texture."""
    factor = max(1, min(8, max_side // max(image.shape[:2])))
    return np.repeat(np.repeat(image, factor, axis=0), factor, axis=1)


def ground_textures(m: LayeredMap, floor_z: float) -> dict[str, GroundTexture]:
    """The occupancy layers, and the costmap of the multimap (or first) layer, as floor textures."""
    textures: dict[str, GroundTexture] = {}
    preferred = ["slam", "objects", "multimap"]
    names = [n for n in preferred if n in m.occupancy] + sorted(n for n in m.occupancy if n not in preferred)
    for name in names:
        grid = m.occupancy[name]
        ox, oy, yaw = grid.origin
        width, height = grid.width * grid.resolution, grid.height * grid.resolution
        c, s = np.cos(yaw), np.sin(yaw)
        center = np.array([ox + c * width / 2 - s * height / 2, oy + s * width / 2 + c * height / 2, floor_z - 0.01])
        textures[name] = GroundTexture(name, _crisp(_occupancy_rgb(grid.data)), width, height, center, float(yaw))
    if names:
        base = textures["multimap" if "multimap" in textures else names[0]]
        grid = m.occupancy[base.name]
        values = costmap_values(grid, **COSTMAP_INFLATION)
        textures[COSTMAP_TEXTURE] = GroundTexture(
            COSTMAP_TEXTURE, _crisp(_costmap_rgb(values)), base.width, base.height, base.center.copy(), base.yaw
        )
    return textures


def _edges(pairs: list[tuple[object, object]], centers: dict[int, np.ndarray]) -> np.ndarray:
    segments = [
        (centers[int(a)], centers[int(b)])
        for a, b in pairs
        if isinstance(a, int | np.integer)
        and isinstance(b, int | np.integer)
        and int(a) in centers
        and int(b) in centers
    ]
    return np.asarray(segments, dtype=np.float32).reshape(-1, 2, 3)


def build_scene(m: LayeredMap, max_points: int = MAX_DISPLAY_POINTS, source: Path | None = None) -> ViewerScene:
    """Everything the viewer draws for map ``m``; at most ``max_points`` geometry points (evenly subsampled)."""
    if max_points < 1:
        raise DataError(f"max_points must be at least 1, got {max_points}")
    vocabulary = m.semantics.vocabulary if m.semantics is not None else m.vocabulary
    instances = list(m.instances or [])
    rgb: np.ndarray | None
    if m.geometry is not None and len(m.geometry) > 0:
        all_points = m.geometry.points
        rgb = m.geometry.colors
        labelled = m.semantics is not None and len(m.semantics) == len(all_points)
        class_ids = m.semantics.class_ids if labelled else None
        instance_ids = m.semantics.instance_ids if labelled else None
    else:  # no geometry layer: the objects' observed points stand for it
        all_points = np.vstack([inst.points for inst in instances] or [np.zeros((0, 3))])
        colors = [inst.colors if inst.colors is not None else np.full((len(inst.points), 3), 0.5) for inst in instances]
        rgb = np.vstack(colors).astype(np.float32) if colors else None
        class_ids = np.concatenate(
            [
                np.full(len(i.points), vocabulary.id(i.class_name) if i.class_name in vocabulary else 0)
                for i in instances
            ]
            or [np.zeros(0, np.int64)]
        )
        instance_ids = np.concatenate([np.full(len(i.points), i.id) for i in instances] or [np.zeros(0, np.int64)])
    keep = display_indices(len(all_points), max_points)
    points = np.asarray(all_points[keep], dtype=np.float32)
    grey = np.tile(UNLABELLED_GREY, (len(keep), 1))
    by_mode = {
        "rgb": np.clip(rgb[keep], 0.0, 1.0) if rgb is not None else grey,
        "class": id_colors(class_ids[keep]) if class_ids is not None else grey,
        "instance": id_colors(instance_ids[keep]) if instance_ids is not None else grey,
    }
    colors = {mode: (c * 255).round().astype(np.uint8) for mode, c in by_mode.items()}
    point_instance_ids = (
        np.asarray(instance_ids[keep], np.int64) if instance_ids is not None else np.zeros(len(keep), np.int64)
    )

    objects = [_object_view(inst, vocabulary) for inst in instances]
    centers = {inst.id: np.asarray(inst.box.center, np.float32) for inst in instances}
    support = [] if m.contact_graph is None else list(m.contact_graph.support.edges())
    proximal = [] if m.contact_graph is None else list(m.contact_graph.proximal.edges())

    floor_z = _floor_z(points, None if class_ids is None else class_ids[keep], vocabulary)
    textures = ground_textures(m, floor_z)
    corners = [points] + [obj.box_segments.reshape(-1, 3) for obj in objects]
    for tex in textures.values():
        half = np.array([tex.width, tex.height, 0.0]) / 2
        # yaw ignored: framing the camera needs only a rough extent
        corners.append(np.vstack([tex.center - half, tex.center + half]))
    stacked = np.vstack([c for c in corners if len(c)] or [np.zeros((1, 3))]).astype(np.float64)
    bounds = np.vstack([stacked.min(axis=0), stacked.max(axis=0)])
    voxel = m.geometry.voxel_size if m.geometry is not None else None
    return ViewerScene(
        source=source,
        points=points,
        colors=colors,
        point_instance_ids=point_instance_ids,
        total_points=len(all_points),
        point_size=float(voxel) if voxel else 0.02,
        mesh=m.geometry.mesh if m.geometry is not None else None,
        objects=objects,
        support_edges=_edges(support, centers),
        proximal_edges=_edges(proximal, centers),
        textures=textures,
        floor_z=floor_z,
        bounds=bounds,
        info={inst.id: object_info(m, inst) for inst in instances},
    )


def load_scene(path: str | Path, max_points: int = MAX_DISPLAY_POINTS) -> tuple[LayeredMap, ViewerScene]:
    """The map at ``path`` (a run's output folder or a map folder) and its scene."""
    directory = find_map_dir(path)
    m = LayeredMap.load(directory)
    return m, build_scene(m, max_points, directory)
