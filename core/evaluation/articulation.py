"""The ``articulation`` metric family: are the map's doors and drawers where the true ones are, and
do they open?

**Joints.** True joints come from the ground truth's objects: each revolute (``continuous`` counts
as revolute) or prismatic joint of an object's model, its frame chained from the object's root
part (the part that is no joint's child, placed by the object's pose) through its parents'
origins (URDF semantics: helper links between two joints included). Predicted joints come from
the map exactly as the exporters see it: the kinematic tree of
:func:`stratamap.core.simulation.kinematics.build_tree`, walked from the world. Each joint keeps
its type, unit world axis, pivot (the joint frame's origin), limits, object and the centre of its
moving part at joint position 0 (the child link's geometry with that of the links below it: a
drawer's handle on a fixed joint).

**Matching** (one to one, greedy by error): a predicted joint matches a true one of the same type
when

* their axes are within 10 degrees as lines (a hinge about -z is the one about +z);
* for revolute joints, the predicted axis line passes within 5 cm of the true pivot (both lines
  near-parallel, so this is the distance between the hinge lines);
* the predicted moving part's centre lies on the true part's front: its offset along each of the
  two face directions of the true part's box is at most half the face's size in that direction,
  and its offset across the face at most half the face's larger size (the face is the side across
  a drawer's slide axis, the largest side of a door). A drawer cannot match the drawer below it,
  whose centre is one drawer height away. Where the true part's box is unknown (ground truth
  written without ``part_boxes``) the centres must be within 0.25 m; where a centre is unknown, a
  revolute joint is matched by its line alone and a prismatic one by pivots within 0.25 m.

Among the pairs that pass, the one with the least error (each criterion's value over its limit,
summed) is taken first. Reported: precision, recall, F1, the counts (``true_joints``,
``predicted_joints``, ``matched_joints``) also by type, over matched hinges the median axis error
(degrees) and the median distance of the true pivot from the predicted hinge line (metres), and
how many matched joints open the same way as the true one (``opens_same_way``: a drawer's travel,
a door's swing of its part centre, towards the end of the range farther from 0; the axes match as
lines, so a drawer put in backwards matches and is caught here); ``recall_large`` over the true
joints whose front is at least 0.1 m², and with the walk's frames ``recall_large_seen`` over those
of them the walk saw from the front (:mod:`stratamap.core.evaluation.front_visibility`);
``per_joint`` lists every true joint with its match and errors, then the unmatched predictions.

**Opening** (:func:`opening_check`, on an MJCF file): from the rest configuration each hinge and
slide joint alone is moved to 90% of its range (towards the end of the range farther from the
rest position) and MuJoCo's collision detection is run (``mj_forward``); the joint opens cleanly
unless a geom of its moving body (or a body below it) then penetrates a geom of another body by
more than 1 cm where the two did not already at rest. MuJoCo never collides a body with its parent,
so a door is checked against the neighbouring units, the room and free objects, not against the
carcass that holds it. The rest check settles the scene for 2 s
(:func:`stratamap.core.simulation.physics.settle`) and reports the largest free-body displacement.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.map.groundtruth import GroundTruthObject
from stratamap.core.map.layers import ObjectInstances

#: Largest angle (degrees) between a predicted axis and the true one, as lines.
AXIS_TOLERANCE_DEG = 10.0
#: Largest distance (metres) of the true pivot from a predicted hinge's axis line.
LINE_TOLERANCE_M = 0.05
#: Largest centre distance (metres) where the true moving part's size is unknown.
CENTER_FALLBACK_M = 0.25
#: Joint types scored, and what each counts as.
KINDS = {"revolute": "revolute", "continuous": "revolute", "prismatic": "prismatic"}

#: A front this large (m²: a 0.5 x 0.2 m drawer, a 0.3 x 0.35 m door) counts among the large ones
#: (``recall_large``).
LARGE_FRONT_M2 = 0.1

#: The opening check: share of the range a joint is opened to, and the penetration (metres) that fails it.
OPEN_SHARE = 0.9
OPEN_PENETRATION_M = 0.01


@dataclass
class WorldJoint:
    """One revolute or prismatic joint in the world at joint position 0."""

    name: str
    type: str  # "revolute" (continuous included) or "prismatic"
    axis: np.ndarray  # (3,) unit, world
    pivot: np.ndarray  # (3,) the joint frame's origin, world
    lower: float
    upper: float
    object_id: int | None = None
    part_center: np.ndarray | None = None  # the moving part's box centre, world
    #: The moving part's box: its axes (columns) in the world and its extents along them.
    part_axes: np.ndarray | None = None
    part_size: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "type": self.type,
            "object": self.object_id,
            "axis": np.round(self.axis, 6).tolist(),
            "pivot": np.round(self.pivot, 6).tolist(),
            "lower": float(self.lower),
            "upper": float(self.upper),
            "part_center": None if self.part_center is None else np.round(self.part_center, 6).tolist(),
        }


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-12 else np.array([0.0, 0.0, 1.0])


def _chain(joints: Iterable[Any], roots: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Link frames from the ``roots``' frames through every joint's origin (child frame in its
    parent's frame at position 0), whatever order the joints are listed in."""
    frames = dict(roots)
    pending = list(joints)
    while pending:
        ready = [j for j in pending if j.parent in frames]
        if not ready:  # a parent no chain reaches: placed at the first root's frame
            ready = pending[:1]
        for j in ready:
            frames[j.child] = frames.get(j.parent, next(iter(roots.values()))) @ np.asarray(j.origin, float)
        done = {id(j) for j in ready}
        pending = [j for j in pending if id(j) not in done]
    return frames


def _below(joints: Iterable[Any], link: str) -> set[str]:
    """``link`` and every link under it."""
    children: dict[str, list[str]] = {}
    for j in joints:
        children.setdefault(j.parent, []).append(j.child)
    out, stack = {link}, [link]
    while stack:
        for child in children.get(stack.pop(), []):
            if child not in out:
                out.add(child)
                stack.append(child)
    return out


def true_joints(objects: Iterable[GroundTruthObject]) -> list[WorldJoint]:
    """Every revolute, continuous and prismatic joint of the ground truth's objects, in the world."""
    out: list[WorldJoint] = []
    for obj in objects:
        if not obj.joints:
            continue
        pose = np.asarray(obj.pose, float)
        children = {j.child for j in obj.joints}
        roots = [j.parent for j in obj.joints if j.parent not in children] or ["body"]
        frames = _chain(obj.joints, {name: pose for name in dict.fromkeys(roots)})
        for j in obj.joints:
            kind = KINDS.get(j.type)
            if kind is None:
                continue
            frame = frames[j.child]
            center = axes = size = None
            box = obj.part_boxes.get(j.child)
            if box is not None:
                lo, hi = np.asarray(box, float)
                center = (pose @ np.append((lo + hi) / 2, 1.0))[:3]
                axes, size = pose[:3, :3].copy(), hi - lo
            out.append(
                WorldJoint(
                    f"{obj.id}:{j.name}",
                    kind,
                    _unit(frame[:3, :3] @ j.axis),
                    frame[:3, 3].copy(),
                    float(j.lower),
                    float(j.upper),
                    obj.id,
                    center,
                    axes,
                    size,
                )
            )
    return out


def predicted_joints(instances: ObjectInstances | None) -> list[WorldJoint]:
    """Every revolute, continuous and prismatic joint of the map's kinematic tree (as the URDF, MJCF
    and SDF exporters build it), in the world."""
    if instances is None or not len(instances):
        return []
    from stratamap.core.simulation.kinematics import ROOT_LINK, build_tree

    tree = build_tree(instances, None)
    frames = _chain(tree.joints, {ROOT_LINK: np.eye(4)})
    links = {link.name: link for link in tree.links}
    out: list[WorldJoint] = []
    for j in tree.joints:
        kind = KINDS.get(j.type)
        if kind is None:
            continue
        frame = frames[j.child]
        # The moving part: the child link's mesh and those of the links below it, in the child's frame.
        corners = []
        for name in _below(tree.joints, j.child):
            link = links.get(name)
            if link is None or link.mesh is None or not len(link.mesh.vertices):
                continue
            to_child = np.linalg.inv(frame) @ frames[name]
            corners.append(np.asarray(link.mesh.bounds, float) @ to_child[:3, :3].T + to_child[:3, 3])
        center = axes = size = None
        if corners:
            stacked = np.vstack(corners)
            lo, hi = stacked.min(0), stacked.max(0)
            center = (frame @ np.append((lo + hi) / 2, 1.0))[:3]
            axes, size = frame[:3, :3].copy(), hi - lo
        child = links.get(j.child)
        out.append(
            WorldJoint(
                j.name,
                kind,
                _unit(frame[:3, :3] @ np.asarray(j.axis, float)),
                frame[:3, 3].copy(),
                float(j.lower),
                float(j.upper),
                None if child is None else child.instance_id,
                center,
                axes,
                size,
            )
        )
    return out


def axis_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between two axes as lines (0..90 degrees)."""
    return float(np.degrees(np.arccos(np.clip(abs(float(np.dot(_unit(a), _unit(b)))), 0.0, 1.0))))


def line_distance(point: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> float:
    """Distance of ``point`` from the line through ``origin`` along ``axis``."""
    return float(np.linalg.norm(np.cross(np.asarray(point, float) - origin, _unit(axis))))


def center_error(true: WorldJoint, pred: WorldJoint) -> float | None:
    """How far the predicted part's centre is off the true part's front, as a share of what is
    allowed (at most 1 passes); None where either centre is unknown."""
    if true.part_center is None or pred.part_center is None:
        return None
    offset = pred.part_center - true.part_center
    if true.part_axes is None or true.part_size is None:
        return float(np.linalg.norm(offset)) / CENTER_FALLBACK_M
    local = np.abs(true.part_axes.T @ offset)
    size = np.maximum(np.asarray(true.part_size, float), 1e-3)
    if true.type == "prismatic":  # the front is across the slide
        normal = int(np.argmax(np.abs(true.part_axes.T @ true.axis)))
    else:  # a door's panel: its thinnest side is across it
        normal = int(np.argmin(size))
    face = [k for k in range(3) if k != normal]
    limits = np.empty(3)
    limits[face] = size[face] / 2
    limits[normal] = size[face].max() / 2
    return float(np.max(local / limits))


def joint_errors(true: WorldJoint, pred: WorldJoint) -> dict[str, Any] | None:
    """The errors of ``pred`` as a match of ``true``: axis (degrees), line (metres, hinges),
    centre (share of the allowed offset), ``passes`` and the greedy order's ``cost``; None when the
    types differ."""
    if true.type != pred.type:
        return None
    axis = axis_error_deg(true.axis, pred.axis)
    line = line_distance(true.pivot, pred.pivot, pred.axis) if true.type == "revolute" else None
    center = center_error(true, pred)
    passes = axis <= AXIS_TOLERANCE_DEG and (line is None or line <= LINE_TOLERANCE_M)
    cost = axis / AXIS_TOLERANCE_DEG + (0.0 if line is None else line / LINE_TOLERANCE_M)
    if center is not None:
        passes = passes and center <= 1.0
        cost += center
    elif true.type == "prismatic":  # no part on either side: the pivots stand in
        pivots = float(np.linalg.norm(true.pivot - pred.pivot)) / CENTER_FALLBACK_M
        passes = passes and pivots <= 1.0
        cost += pivots
    return {"axis_error_deg": axis, "line_error_m": line, "center_error": center, "passes": passes, "cost": cost}


def opening_motion(j: WorldJoint) -> np.ndarray | None:
    """Which way the joint opens, as a unit vector in the world: a slide's direction of travel, or
    how a hinge's part centre starts to move, towards the end of its range farther from 0; None for
    a hinge whose part centre is unknown."""
    end = j.upper if abs(j.upper) >= abs(j.lower) else j.lower
    axis = j.axis if end >= 0 else -j.axis
    if j.type == "prismatic":
        return _unit(axis)
    if j.part_center is None:
        return None
    swing = np.cross(axis, j.part_center - j.pivot)
    return _unit(swing) if np.linalg.norm(swing) > 1e-9 else None


def match_joints(truth: list[WorldJoint], predicted: list[WorldJoint]) -> list[tuple[int, int, dict[str, Any]]]:
    """One-to-one matches ``(true index, predicted index, errors)``, greedy by error (least first)."""
    pairs = []
    for t, tj in enumerate(truth):
        for p, pj in enumerate(predicted):
            errors = joint_errors(tj, pj)
            if errors is not None and errors["passes"]:
                pairs.append((errors["cost"], t, p, errors))
    pairs.sort(key=lambda x: (x[0], x[1], x[2]))
    used_t: set[int] = set()
    used_p: set[int] = set()
    out = []
    for _, t, p, errors in pairs:
        if t in used_t or p in used_p:
            continue
        used_t.add(t)
        used_p.add(p)
        out.append((t, p, errors))
    return sorted(out)


def _prf(matched: int, predicted: int, true: int) -> dict[str, float]:
    precision = matched / predicted if predicted else 0.0
    recall = matched / true if true else 0.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return {"precision": precision, "recall": recall, "f1": f1}


def front_area(joint: WorldJoint) -> float | None:
    """The area (m²) of the moving part's front: across a drawer's slide, a door's largest side;
    None where the part's box is unknown."""
    if joint.part_size is None or joint.part_axes is None:
        return None
    size = np.asarray(joint.part_size, float)
    if joint.type == "prismatic":
        along = int(np.argmax(np.abs(np.asarray(joint.part_axes, float).T @ joint.axis)))
        return float(np.prod(np.delete(size, along)))
    return float(np.prod(np.sort(size)[1:]))


def score_joints(
    truth: list[WorldJoint], predicted: list[WorldJoint], seen: list[bool | None] | None = None
) -> dict[str, Any]:
    """The family's figures for these joints (see the module's docstring); ``per_joint`` lists
    every true joint with its match, then the predictions that matched none. ``seen``: for each
    true joint, whether the walk saw its front from the front (``front_visibility``)."""
    matches = match_joints(truth, predicted)
    out: dict[str, Any] = _prf(len(matches), len(predicted), len(truth))
    out.update({"true_joints": len(truth), "predicted_joints": len(predicted), "matched_joints": len(matches)})
    by_type = {}
    for kind in ("revolute", "prismatic"):
        n_true = sum(j.type == kind for j in truth)
        n_pred = sum(j.type == kind for j in predicted)
        n_match = sum(truth[t].type == kind for t, _, _ in matches)
        by_type[kind] = {"true_joints": n_true, "predicted_joints": n_pred, "matched_joints": n_match}
        by_type[kind].update(_prf(n_match, n_pred, n_true))
    out["by_type"] = by_type
    # Large doors and drawers (every one, seen or not: the walk's coverage is not known here).
    large = [t for t, tj in enumerate(truth) if (front_area(tj) or 0.0) >= LARGE_FRONT_M2]
    matched_large = sum(t in {m[0] for m in matches} for t in large)
    out["large_joints"] = len(large)
    out["recall_large"] = matched_large / len(large) if large else None
    # Of those, the ones the walk saw from the front: the ones a pipeline can be asked to find.
    if seen is not None:
        large_seen = [t for t in large if seen[t]]
        out["large_seen_joints"] = len(large_seen)
        out["recall_large_seen"] = (
            sum(t in {m[0] for m in matches} for t in large_seen) / len(large_seen) if large_seen else None
        )
    # The axes match as lines: whether the matched joints also open the same way (a drawer put in
    # backwards, a door hinged on the right edge of the wrong face) is counted apart.
    agrees = {}
    for t, p, _ in matches:
        a, b = opening_motion(truth[t]), opening_motion(predicted[p])
        if a is not None and b is not None:
            agrees[t] = bool(np.dot(a, b) > 0)
    out["opens_same_way"] = sum(agrees.values())
    out["opens_same_way_share"] = sum(agrees.values()) / len(agrees) if agrees else None
    hinges = [e for t, _, e in matches if truth[t].type == "revolute"]
    out["axis_error_deg_median"] = float(np.median([e["axis_error_deg"] for e in hinges])) if hinges else None
    out["pivot_error_m_median"] = float(np.median([e["line_error_m"] for e in hinges])) if hinges else None
    matched = {t: (p, e) for t, p, e in matches}
    rows = []
    for t, tj in enumerate(truth):
        row = {"truth": tj.to_dict(), "match": None}
        if t in matched:
            p, e = matched[t]
            row["match"] = predicted[p].to_dict()
            row.update({k: e[k] for k in ("axis_error_deg", "line_error_m", "center_error")})
            row["opens_same_way"] = agrees.get(t)
        if seen is not None:
            row["seen_from_front"] = seen[t]
        rows.append(row)
    used = {p for _, p, _ in matches}
    rows += [{"truth": None, "match": pj.to_dict()} for p, pj in enumerate(predicted) if p not in used]
    out["per_joint"] = rows
    return out


def has_articulation(objects: Iterable[GroundTruthObject]) -> bool:
    """Whether any object has a revolute, continuous or prismatic joint."""
    return any(j.type in KINDS for obj in objects for j in obj.joints)


def evaluate_articulation(
    instances: ObjectInstances | None, objects: list[GroundTruthObject], stream: Any = None
) -> dict[str, Any]:
    """The ``articulation`` family of a map against its ground truth's objects; with an RGB-D
    ``stream`` (posed depth frames) also which large fronts the walk saw from the front."""
    from stratamap.core.evaluation.front_visibility import seen_from_front

    truth = true_joints(objects)
    return score_joints(truth, predicted_joints(instances), seen_from_front(truth, stream))


# ----------------------------------------------------------------------------------- MuJoCo


def _penetrations(model: Any, data: Any, moving: set[int], depth: float) -> dict[tuple[int, int], float]:
    """(moving geom, other geom) -> deepest penetration (metres) of the contacts MuJoCo found
    between a geom of a ``moving`` body and a geom of any other body."""
    found: dict[tuple[int, int], float] = {}
    for c in data.contact[: data.ncon]:
        if c.dist >= -depth:
            continue
        g1, g2 = int(c.geom1), int(c.geom2)
        in1, in2 = int(model.geom_bodyid[g1]) in moving, int(model.geom_bodyid[g2]) in moving
        if in1 == in2:
            continue
        key = (g1, g2) if in1 else (g2, g1)
        found[key] = max(found.get(key, 0.0), -float(c.dist))
    return found


def opening_check(
    mjcf_path: str | Path,
    share: float = OPEN_SHARE,
    depth: float = OPEN_PENETRATION_M,
    settle_seconds: float | None = 2.0,
) -> dict[str, Any]:
    """Open every limited hinge and slide joint of an MJCF scene alone to ``share`` of its range and
    look for new penetrations deeper than ``depth`` (see the module's docstring); then settle the
    scene for ``settle_seconds`` (None: not) for the rest check. Needs ``mujoco``.

    Returns ``joints_checked``, ``opens_clean`` and ``opens_clean_share`` (None without joints),
    ``unlimited_joints`` (hinges without a range, not checked), ``failures`` (per joint: its name,
    the opening it was checked at and the bodies it ran into, deepest first), and from the rest
    check ``rest_max_displacement_m`` (None when the simulation diverged), ``rest_diverged`` and
    ``free_bodies``."""
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(mjcf_path))
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    mujoco.mj_forward(model, data)
    subtree: dict[int, set[int]] = {b: {b} for b in range(model.nbody)}
    for b in range(model.nbody - 1, 0, -1):  # parents come before their children in MuJoCo's order
        subtree[int(model.body_parentid[b])] |= subtree[b]

    def name(kind: Any, i: int) -> str:
        return mujoco.mj_id2name(model, kind, i) or f"#{i}"

    hinge, slide = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
    checked, clean, unlimited = 0, 0, 0
    failures = []
    for j in range(model.njnt):
        kind = int(model.jnt_type[j])
        if kind not in (hinge, slide):
            continue
        if not model.jnt_limited[j]:
            unlimited += 1
            continue
        moving = subtree[int(model.jnt_bodyid[j])]
        adr = int(model.jnt_qposadr[j])
        rest = float(model.qpos0[adr])
        lo, hi = (float(v) for v in model.jnt_range[j])
        end = hi if abs(hi - rest) >= abs(lo - rest) else lo
        target = rest + share * (end - rest)
        data.qpos[:] = model.qpos0
        mujoco.mj_forward(model, data)
        before = _penetrations(model, data, moving, depth)
        data.qpos[adr] = target
        mujoco.mj_forward(model, data)
        after = _penetrations(model, data, moving, depth)
        new = {k: v for k, v in after.items() if k not in before or v > before[k] + depth}
        checked += 1
        if not new:
            clean += 1
            continue
        hits: dict[str, float] = {}
        for (_, other), d in new.items():
            body = name(mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[other]))
            if body == "world":
                body = name(mujoco.mjtObj.mjOBJ_GEOM, other)
            hits[body] = max(hits.get(body, 0.0), d)
        failures.append(
            {
                "joint": name(mujoco.mjtObj.mjOBJ_JOINT, j),
                "type": "hinge" if kind == hinge else "slide",
                "opened_to": round(target, 6),
                "hits": {k: round(v, 4) for k, v in sorted(hits.items(), key=lambda kv: -kv[1])},
            }
        )
    out: dict[str, Any] = {
        "joints_checked": checked,
        "opens_clean": clean,
        "opens_clean_share": clean / checked if checked else None,
        "unlimited_joints": unlimited,
        "failures": failures,
    }
    if settle_seconds is not None:
        from stratamap.core.simulation.physics import settle

        settled = settle(mjcf_path, settle_seconds)
        out["rest_diverged"] = bool(settled["diverged"])
        out["rest_max_displacement_m"] = None if settled["diverged"] else float(settled["max_displacement_m"])
        out["free_bodies"] = int(settled["free_bodies"])
    return out


__all__ = [
    "WorldJoint",
    "axis_error_deg",
    "evaluate_articulation",
    "has_articulation",
    "joint_errors",
    "line_distance",
    "match_joints",
    "opening_check",
    "opening_motion",
    "predicted_joints",
    "score_joints",
    "true_joints",
]
