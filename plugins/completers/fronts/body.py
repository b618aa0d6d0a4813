"""An articulated completion of a storage object from its fronts (the functional-objects paper's
kinematic replacement, built from what was observed instead of picked from a CAD library).

Object frame: origin at the bottom centre of the object's box, +z up, the front face at
``y = -depth/2`` facing -y. The body is a carcass open at the front (back, sides, bottom and top
boards, each its own convex piece, so a simulator collides the boards and not their hull) with the
fixed panels on its face; every door, flap and appliance door is a panel link on a revolute joint
about the edge opposite its handle, on the panel's outer face (so it swings out within its own
width, clear of its neighbours); every drawer is a front with a drawer box behind it inside the
carcass, on a prismatic joint along -y.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stratamap.core.furniture.faces import OPENS
from stratamap.core.furniture.fixtures import Fixture
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import Completion, Joint, OrientedBox, Part
from stratamap.plugins.completers.fronts.face import Face

trimesh = lazy_module("trimesh")


@dataclass(frozen=True)
class BodyParams:
    board: float = 0.018  # carcass boards, m
    front_thickness: float = 0.019
    gap: float = 0.003  # between neighbouring fronts, and behind them
    door_opening: float = 1.6  # rad, a door's or a flap's upper limit
    drawer_travel: float = 0.8  # share of the drawer box's depth a drawer slides out
    drawer_depth: float = 0.55  # the deepest drawer box, m


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    mesh = trimesh.creation.box(extents=np.maximum(hi - lo, 1e-3))
    mesh.apply_translation((lo + hi) / 2)
    return mesh


def _translated(mesh: trimesh.Trimesh, offset: np.ndarray) -> trimesh.Trimesh:
    out = mesh.copy()
    out.apply_translation(offset)
    return out


def _fixture_boxes(fixtures: list[Fixture], to_object: np.ndarray, y_face: float) -> list[trimesh.Trimesh]:
    """Handles as bars and knobs as blocks standing out of the face (object frame)."""
    boxes = []
    for f in fixtures:
        c = to_object[:3, :3] @ np.asarray(f.center, float) + to_object[:3, 3]
        if f.kind == "handle" and f.direction is not None:
            d = to_object[:3, :3] @ np.asarray(f.direction, float)
            half = np.abs(d) * max(f.length, 0.04) / 2 + 0.0075
            half[1] = 0.0
        else:
            half = np.array([0.015, 0.0, 0.015])
        boxes.append(_box([c[0] - half[0], y_face - 0.03, c[2] - half[2]], [c[0] + half[0], y_face, c[2] + half[2]]))
    return boxes


def depth_behind(face: Face, box: OrientedBox, points: np.ndarray) -> float:
    """How deep (m) the object seen on ``face`` is: how far its observed ``points`` reach behind the
    face (98th percentile), else its box's depth across the face."""
    behind = -(np.asarray(points, float) @ face.normal + face.d)
    behind = behind[behind > 0]
    return float(np.percentile(behind, 98)) if len(behind) >= 50 else float(box.size[face.side]) + face.offset


#: How far a storage body reaches over its face's top edge (m): a worktop or a top board. What the
#: box holds higher up stands on the body or behind it (a counter's backsplash, the things on a
#: worktop the sensor saw no top of), and a carcass up there would swallow them.
TOP_OVER_FACE = 0.04


def object_frame(face: Face, box: OrientedBox, depth: float) -> tuple[np.ndarray, np.ndarray]:
    """The object frame of an object seen on ``face`` (-y out of the face, origin at the bottom
    centre between the face's ends and between the face and the object's back) as object-to-world,
    and the object's size in it; ``depth`` is :func:`depth_behind`'s, kept within 0.15-1.5 m, and
    the height the box's, but no more than :data:`TOP_OVER_FACE` over the face's top."""
    u0, u1 = face.rect[:2]
    depth = float(np.clip(depth, 0.15, 1.5))
    y_axis = -face.normal
    pose = np.eye(4)
    pose[:3, :3] = np.stack([np.cross(y_axis, [0.0, 0.0, 1.0]), y_axis, [0.0, 0.0, 1.0]], axis=1)
    pose[:3, 3] = (u0 + u1) / 2 * face.u_axis - (face.d + depth / 2) * face.normal
    pose[2, 3] = box.bottom_z
    height = min(float(box.size[2]), face.rect[3] - box.bottom_z + TOP_OVER_FACE)
    return pose, np.array([u1 - u0, depth, height])


def articulated_body(
    size: np.ndarray,
    fronts: list[tuple[tuple[float, float, float, float], str, str | None, list[Fixture]]],
    to_object: np.ndarray,
    pose: np.ndarray,
    completer: str,
    score: float,
    p: BodyParams | None = None,
) -> Completion | None:
    """The completion of an object of ``size`` (width, depth, height) whose fronts are
    ``(rect, label, hinge, fixtures)`` with ``rect = (x0, x1, z0, z1)`` in the object frame;
    ``to_object`` maps world points into it (for the fixtures), ``pose`` is object-to-world.
    None when no front moves."""
    p = p or BodyParams()
    w, dep, h = (float(v) for v in size)
    c, t, gap = p.board, p.front_thickness, p.gap
    y_face, y_back = -dep / 2, dep / 2
    y_carcass = y_face + t + gap
    if y_back - y_carcass < 2 * c:
        return None
    moving = [f for f in fronts if f[1] in OPENS]
    if not moving:
        return None
    z_fronts = [f[0][2] for f in fronts], [f[0][3] for f in fronts]
    z_bottom = float(np.clip(min(z_fronts[0]) - gap, c, h / 3))
    z_top = float(np.clip(max(z_fronts[1]) + gap, 2 * h / 3, h - c))
    body = [
        _box([-w / 2, y_back - c, 0.0], [w / 2, y_back, h]),
        _box([-w / 2, y_carcass, 0.0], [-w / 2 + c, y_back - c, h]),
        _box([w / 2 - c, y_carcass, 0.0], [w / 2, y_back - c, h]),
        _box([-w / 2 + c, y_carcass, 0.0], [w / 2 - c, y_back - c, z_bottom]),
        _box([-w / 2 + c, y_carcass, z_top], [w / 2 - c, y_back - c, h]),
    ]
    parts: list[Part] = []
    joints: list[Joint] = []
    inner = (-w / 2 + c + 0.005, w / 2 - c - 0.005)
    for k, (rect, label, hinge, fixtures) in enumerate(fronts):
        x0, x1, z0, z1 = rect
        x0, x1 = max(x0, -w / 2) + gap / 2, min(x1, w / 2) - gap / 2
        z0, z1 = max(z0, 0.0) + gap / 2, min(z1, h) - gap / 2
        if x1 - x0 < 0.05 or z1 - z0 < 0.05:
            continue
        panel = [_box([x0, y_face, z0], [x1, y_face + t, z1]), *_fixture_boxes(fixtures, to_object, y_face)]
        if label not in OPENS:
            body.extend(panel)
            continue
        name = f"front_{k}"
        if label == "drawer":
            hinge_point = np.array([(x0 + x1) / 2, y_face, (z0 + z1) / 2])
            depth = float(min(p.drawer_depth, 0.85 * (y_back - c - y_carcass)))
            bx0, bx1 = max(x0 + c, inner[0]), min(x1 - c, inner[1])
            bz0, bz1 = max(z0 + 0.015, z_bottom + 0.005), min(z1 - 0.02, z_top - 0.005)
            if bx1 - bx0 > 0.02 and bz1 - bz0 > 0.02 and depth > 0.05:
                panel.append(_box([bx0, y_face + t, bz0], [bx1, y_face + t + depth, bz1]))
            kind, axis, upper = "prismatic", np.array([0.0, -1.0, 0.0]), p.drawer_travel * max(depth, 0.05)
        else:
            kind, upper = "revolute", p.door_opening
            hinge_point, axis = {
                "right": (np.array([x1, y_face, (z0 + z1) / 2]), np.array([0.0, 0.0, 1.0])),
                "top": (np.array([(x0 + x1) / 2, y_face, z1]), np.array([-1.0, 0.0, 0.0])),
                "bottom": (np.array([(x0 + x1) / 2, y_face, z0]), np.array([1.0, 0.0, 0.0])),
            }.get(hinge or "left", (np.array([x0, y_face, (z0 + z1) / 2]), np.array([0.0, 0.0, -1.0])))
            name += f"_{hinge or 'left'}"
        origin = np.eye(4)
        origin[:3, 3] = hinge_point
        mesh = trimesh.util.concatenate([_translated(m, -hinge_point) for m in panel])
        parts.append(Part(name, mesh, origin))
        joints.append(Joint(f"{name}_{kind}", kind, "body", name, origin, axis, 0.0, float(upper)))
    if not joints:
        return None
    body_mesh = trimesh.util.concatenate(body)
    whole = trimesh.util.concatenate([body_mesh] + [_translated(part.mesh, part.pose[:3, 3]) for part in parts])
    return Completion(
        mesh=whole,
        pose=pose,
        completer=completer,
        model_id=None,
        scale=np.array([w, dep, h]),
        score=score,
        parts=[Part("body", body_mesh), *parts],
        joints=joints,
    )
