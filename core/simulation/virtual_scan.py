"""Virtual laser scans of articulated furniture (URDF kitchens) with per-point ground truth.

The kitchen paper evaluates plane and furniture labels on scans of a real kitchen. Here the
kitchen is a URDF (the real IAI apartment, or a procedural one from
:mod:`stratamap.core.synthetic.kitchens`): its links become *parts* with a role, a room (floor,
walls, ceiling) is added around it, and panoramic scans from a few viewpoints are ray cast with
Open3D. Every point knows the part it hit and the surface normal there, which gives the labels:

* level 1, per point: ``floor``, ``ceiling``, ``table`` (any other horizontal surface: counter
  tops, tables), ``wall``, ``furniture`` (any other vertical surface);
* level 2, per point of a vertical surface: ``drawer`` (a front moving on a prismatic joint),
  ``cupboard`` (a door on a revolute joint), ``appliance`` (a link whose name matches
  ``appliance_pattern``: oven, dishwasher, fridge; or a door with such a link right behind it,
  like the IAI kitchen's dishwasher door), else ``panel``;
* hinge side of every door (``left``/``right`` as seen facing it, or ``top``/``bottom`` for
  flaps), from where its joint axis lies relative to the door's face.

Fixed links named like handles or knobs belong to the front they are attached to.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from stratamap.core.errors import DataError
from stratamap.core.io.urdf import UrdfModel
from stratamap.core.lazy import lazy_module

trimesh = lazy_module("trimesh")

LEVEL1 = ("floor", "table", "ceiling", "wall", "furniture")
LEVEL1_HORIZONTAL = ("floor", "table", "ceiling")
LEVEL1_VERTICAL = ("wall", "furniture")
LEVEL2 = ("cupboard", "drawer", "appliance", "panel")
#: The map vocabulary's class for each level-1 and level-2 label (a fixed panel is a cabinet face).
LEVEL1_CLASS = {"floor": "floor", "table": "table", "ceiling": "ceiling", "wall": "wall", "furniture": "cabinet"}
LEVEL2_CLASS = {"cupboard": "cupboard", "drawer": "drawer", "appliance": "appliance", "panel": "cabinet"}
#: A surface is horizontal (vertical) when its normal is within this many degrees of (perpendicular to) +z.
ORIENTATION_TOLERANCE_DEG = 20.0


@dataclass
class Front:
    """A movable (or appliance) front: a drawer, a door, or an appliance's face."""

    name: str
    kind: str  # cupboard | drawer | appliance
    joint: str | None = None
    joint_type: str = "fixed"
    axis_point: np.ndarray | None = None  # world point on the hinge axis (revolute fronts)
    axis: np.ndarray | None = None  # world unit hinge axis
    hinge: str | None = None  # left | right | top | bottom (doors, filled by label_points)
    normal: np.ndarray | None = None  # outward face normal, from the scan


@dataclass
class Part:
    """One link's geometry in the world, with what it is."""

    name: str
    role: str  # floor | wall | ceiling | furniture | handle | knob | object
    mesh: trimesh.Trimesh
    front: int = -1  # index into KitchenScene.fronts


@dataclass
class KitchenScene:
    parts: list[Part] = field(default_factory=list)
    fronts: list[Front] = field(default_factory=list)
    room: tuple[float, float, float, float, float] | None = None  # x0, y0, x1, y1, height
    warnings: list[str] = field(default_factory=list)

    def bounds(self) -> np.ndarray:
        """(2, 3) lower and upper corner over every part."""
        return np.stack(
            [
                np.min([p.mesh.bounds[0] for p in self.parts], axis=0),
                np.max([p.mesh.bounds[1] for p in self.parts], axis=0),
            ]
        )


def _world_axis(model: UrdfModel, poses: dict[str, np.ndarray], joint) -> tuple[np.ndarray, np.ndarray]:
    frame = poses[joint.parent] @ joint.origin
    axis = frame[:3, :3] @ (joint.axis / np.linalg.norm(joint.axis))
    return frame[:3, 3].copy(), axis


def kitchen_from_urdf(
    model: UrdfModel,
    root_link: str | None = None,
    appliance_pattern: str = r"oven|dishwasher|fridge|refrigerator|microwave",
    handle_pattern: str = r"handle",
    knob_pattern: str = r"knob",
    ignore_pattern: str | None = r"tap|hotplate|socket",
    q: dict[str, float] | None = None,
) -> KitchenScene:
    """Parts and fronts of ``model`` (only the subtree under ``root_link`` when given)."""
    poses = model.link_poses(q)
    joint_of = {j.child: j for j in model.joints}
    children: dict[str, list[str]] = {}
    for j in model.joints:
        children.setdefault(j.parent, []).append(j.child)
    if root_link is not None:
        if root_link not in model.links:
            raise DataError(f"{model.path}: no link named {root_link!r} (root_link)")
        keep, stack = set(), [root_link]
        while stack:
            name = stack.pop()
            keep.add(name)
            stack.extend(children.get(name, []))
    else:
        keep = set(model.links)

    def subtree(name: str) -> list[str]:
        out, stack = [], [name]
        while stack:
            n = stack.pop()
            out.append(n)
            stack.extend(children.get(n, []))
        return out

    appliance = re.compile(appliance_pattern, re.I)
    handle = re.compile(handle_pattern, re.I)
    knob = re.compile(knob_pattern, re.I)
    ignore = re.compile(ignore_pattern, re.I) if ignore_pattern else None
    scene = KitchenScene()
    front_of_link: dict[str, int] = {}

    def front_for(link: str) -> int:
        """The front a link belongs to: its nearest ancestor (itself included) that moves, or an appliance."""
        name = link
        while True:
            j = joint_of.get(name)
            is_app = bool(appliance.search(name)) and bool(model.links.get(name))
            if is_app or (j is not None and j.type in ("prismatic", "revolute") and model.links.get(name)):
                break
            if j is None or name == root_link:
                return -1
            name = j.parent
        if name in front_of_link:
            return front_of_link[name]
        j = joint_of.get(name)
        moving = j is not None and j.type in ("prismatic", "revolute")
        if appliance.search(name) or (
            moving and j.type == "revolute" and any(appliance.search(s) for s in subtree(name))
        ):
            kind = "appliance"
        elif moving and j.type == "prismatic":
            kind = "drawer"
        else:
            kind = "cupboard"
        front = Front(name, kind, j.name if moving else None, j.type if moving else "fixed")
        if moving and j.type == "revolute":
            front.axis_point, front.axis = _world_axis(model, poses, j)
        front_of_link[name] = len(scene.fronts)
        scene.fronts.append(front)
        return front_of_link[name]

    for name, visuals in model.links.items():
        if name not in keep or not visuals:
            continue
        if ignore is not None and ignore.search(name):
            continue
        mesh = trimesh.util.concatenate([v.mesh for v in visuals]).copy()
        mesh.apply_transform(poses[name])
        role = "handle" if handle.search(name) else "knob" if knob.search(name) else "furniture"
        scene.parts.append(Part(name, role, mesh, front_for(name)))
    if not scene.parts:
        raise DataError(f"{model.path}: no link with geometry under {root_link or model.root!r}")
    scene.warnings.extend(w for w in model.warnings if not w.startswith("link '") or w.split("'")[1] in keep)
    return scene


def add_room(
    scene: KitchenScene,
    room: tuple[float, float, float, float, float] | None = None,
    margin: float = 1.0,
    thickness: float = 0.05,
) -> None:
    """Floor, ceiling and four walls: ``room`` = (x0, y0, x1, y1, height), or the furniture's
    footprint grown by ``margin`` and 2.6 m high."""
    if room is None:
        lo, hi = scene.bounds()
        room = (lo[0] - margin, lo[1] - margin, hi[0] + margin, hi[1] + margin, max(2.6, hi[2] + 0.3))
    x0, y0, x1, y1, h = room
    if not (x1 > x0 and y1 > y0 and h > 0):
        raise DataError(f"room: expected x0 < x1, y0 < y1 and height > 0, got {room}")
    t = thickness

    def box(lo, hi) -> trimesh.Trimesh:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        b = trimesh.creation.box(extents=hi - lo)
        b.apply_translation((lo + hi) / 2)
        return b

    scene.parts += [
        Part("floor", "floor", box([x0, y0, -t], [x1, y1, 0.0])),
        Part("ceiling", "ceiling", box([x0, y0, h], [x1, y1, h + t])),
        Part("wall_x0", "wall", box([x0 - t, y0, 0], [x0, y1, h])),
        Part("wall_x1", "wall", box([x1, y0, 0], [x1 + t, y1, h])),
        Part("wall_y0", "wall", box([x0, y0 - t, 0], [x1, y0, h])),
        Part("wall_y1", "wall", box([x0, y1, 0], [x1, y1 + t, h])),
    ]
    scene.room = tuple(float(v) for v in room)  # type: ignore[assignment]


@dataclass
class Scan:
    """A merged virtual scan: points, the part each hit, the true surface normal there, and viewpoints."""

    points: np.ndarray
    part: np.ndarray  # (N,) index into KitchenScene.parts
    normals: np.ndarray  # (N, 3) true surface normals, facing the sensor
    viewpoints: np.ndarray  # (V, 3)
    view: np.ndarray  # (N,) index of the viewpoint


def virtual_scan(
    scene: KitchenScene,
    viewpoints: np.ndarray,
    resolution_deg: float = 0.4,
    elevation_deg: tuple[float, float] = (-70.0, 70.0),
    max_range: float = 8.0,
    noise: float = 0.003,
    seed: int = 0,
) -> Scan:
    """Panoramic scans (like a tilting laser on a robot) from every viewpoint, ray cast against
    every part; range noise ``noise`` (m, Gaussian, seeded)."""
    import open3d as o3d

    viewpoints = np.asarray(viewpoints, float).reshape(-1, 3)
    rscene = o3d.t.geometry.RaycastingScene()
    for p in scene.parts:
        rscene.add_triangles(
            o3d.core.Tensor(np.asarray(p.mesh.vertices, np.float32)),
            o3d.core.Tensor(np.asarray(p.mesh.faces, np.uint32)),
        )
    az = np.radians(np.arange(0.0, 360.0, resolution_deg))
    el = np.radians(np.arange(elevation_deg[0], elevation_deg[1] + 1e-9, resolution_deg))
    A, E = np.meshgrid(az, el)
    dirs = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    pts, part, nrm, view = [], [], [], []
    for v, origin in enumerate(viewpoints):
        rays = np.hstack([np.broadcast_to(origin, dirs.shape), dirs]).astype(np.float32)
        hit = rscene.cast_rays(o3d.core.Tensor(rays))
        t = hit["t_hit"].numpy()
        ok = np.isfinite(t) & (t <= max_range)
        gid = hit["geometry_ids"].numpy()[ok].astype(np.int64)
        n = hit["primitive_normals"].numpy()[ok].astype(np.float64)
        d = dirs[ok]
        flip = np.einsum("ij,ij->i", n, d) > 0
        n[flip] *= -1
        r = t[ok] + (rng.normal(0.0, noise, ok.sum()) if noise > 0 else 0.0)
        pts.append(origin + d * r[:, None])
        part.append(gid)
        nrm.append(n)
        view.append(np.full(len(gid), v))
    return Scan(np.vstack(pts), np.concatenate(part), np.vstack(nrm), viewpoints, np.concatenate(view))


@dataclass
class ScanLabels:
    """Per-point ground truth of a scan (indices into LEVEL1 / LEVEL2 / fronts; -1 = none)."""

    level1: np.ndarray
    level2: np.ndarray
    front: np.ndarray


def label_points(scene: KitchenScene, scan: Scan) -> ScanLabels:
    """Level-1 and level-2 labels per point, and each front's outward normal and hinge side."""
    nz = np.abs(scan.normals[:, 2])
    tol = np.cos(np.radians(90.0 - ORIENTATION_TOLERANCE_DEG))
    horizontal = nz >= np.cos(np.radians(ORIENTATION_TOLERANCE_DEG))
    vertical = nz <= tol
    role = np.array([p.role for p in scene.parts])[scan.part]
    front_of_part = np.array([p.front for p in scene.parts])
    front = front_of_part[scan.part]
    l1 = np.full(len(scan.points), -1, np.int64)
    l1[horizontal & (role == "floor")] = LEVEL1.index("floor")
    l1[horizontal & (role == "ceiling")] = LEVEL1.index("ceiling")
    l1[horizontal & ~np.isin(role, ["floor", "ceiling"])] = LEVEL1.index("table")
    l1[vertical & (role == "wall")] = LEVEL1.index("wall")
    l1[vertical & ~np.isin(role, ["floor", "ceiling", "wall"])] = LEVEL1.index("furniture")
    l2 = np.full(len(scan.points), -1, np.int64)
    furn = l1 == LEVEL1.index("furniture")
    l2[furn] = LEVEL2.index("panel")
    kinds = np.array([LEVEL2.index(f.kind) for f in scene.fronts] + [LEVEL2.index("panel")])
    on_front = furn & (front >= 0)
    appliances = [
        p.mesh.bounds.mean(axis=0)
        for p in scene.parts
        if p.front >= 0 and scene.fronts[p.front].kind == "appliance" and scene.fronts[p.front].joint_type != "revolute"
    ]
    # A front's label holds on the face it shows, not on the sides of a drawer box seen past it.
    for k, f in enumerate(scene.fronts):
        mine = on_front & (front == k) & ~np.isin(role, ["handle", "knob"])
        if mine.sum() < 10:
            continue
        n = scan.normals[mine].copy()
        n[:, 2] = 0
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-9)
        # the dominant horizontal direction among the front's hits
        angles = np.arctan2(n[:, 1], n[:, 0])
        hist, edges = np.histogram(angles, bins=72, range=(-np.pi, np.pi))
        a = (edges[np.argmax(hist)] + edges[np.argmax(hist) + 1]) / 2
        f.normal = np.array([np.cos(a), np.sin(a), 0.0])
        facing = n @ f.normal > np.cos(np.radians(ORIENTATION_TOLERANCE_DEG))
        idx = np.flatnonzero(mine)
        if (
            f.kind == "cupboard"
            and f.joint_type == "revolute"
            and facing.any()
            and _covers_appliance(f, scan.points[idx[facing]], appliances)
        ):
            f.kind = "appliance"  # the door of a dishwasher or an oven: an appliance's face
            kinds[k] = LEVEL2.index("appliance")
        l2[idx[facing]] = kinds[k]
        if f.axis is not None:
            center = scan.points[idx[facing]].mean(axis=0) if facing.any() else scan.points[idx].mean(axis=0)
            offset = f.axis_point - center
            if abs(f.axis[2]) > 0.7:
                right = np.cross(-f.normal, [0.0, 0.0, 1.0])
                f.hinge = "right" if offset @ right > 0 else "left"
            else:
                f.hinge = "top" if offset[2] > 0 else "bottom"
    fixtures = on_front & np.isin(role, ["handle", "knob"])
    l2[fixtures] = kinds[front[fixtures]]
    return ScanLabels(l1, l2, np.where(l2 >= 0, front, -1))


def _covers_appliance(front: Front, face: np.ndarray, appliance_centers: list[np.ndarray], depth: float = 0.8) -> bool:
    """Whether an appliance link (e.g. a dishwasher's rack) sits right behind this door."""
    right = np.cross(-front.normal, [0.0, 0.0, 1.0])
    u, z = face @ right, face[:, 2]
    center = face.mean(axis=0)
    for c in appliance_centers:
        behind = (c - center) @ front.normal
        if (
            -depth < behind < 0
            and u.min() - 0.02 <= c @ right <= u.max() + 0.02
            and z.min() - 0.02 <= c[2] <= z.max() + 0.02
        ):
            return True
    return False
