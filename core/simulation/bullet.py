"""Exported URDF scenes in PyBullet, free bodies free.

URDF's ``floating`` joint is how a scene says "this object is free", but PyBullet turns floating
joints into fixed ones (``Warning: joint unsupported, creating a fixed joint instead``).
:func:`load_scene` loads the scene the way it is meant: the tree under ``world`` as one fixed-base
multibody, and every subtree hanging from ``world`` by a floating joint as a multibody of its own
with a free base at that joint's pose. :func:`settle` runs it and reports how far free bodies move.
Needs ``pybullet`` (the ``test`` extra).
"""

from __future__ import annotations

import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.errors import DataError
from stratamap.core.lazy import lazy_module

rotations = lazy_module("scipy.spatial.transform")


@dataclass
class BulletScene:
    client: int
    fixed: int  # the multibody of everything fixed to the world
    free: dict[str, int] = field(default_factory=dict)  # link name -> free multibody
    joints: dict[str, int] = field(default_factory=dict)  # joint name -> index in ``fixed``


def _absolute_meshes(robot: ET.Element, folder: Path) -> None:
    for mesh in robot.iter("mesh"):
        name = mesh.get("filename", "")
        if name and "://" not in name and not Path(name).is_absolute():
            mesh.set("filename", str((folder / name).resolve()))


def _pose(origin: ET.Element | None) -> tuple[list[float], list[float]]:
    xyz = [float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()]
    rpy = [float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
    return xyz, list(rotations.Rotation.from_euler("xyz", rpy).as_quat())


def load_scene(path: str | Path, client: int | None = None, gravity: float = -9.81) -> BulletScene:
    """Load an exported scene URDF into PyBullet (a new DIRECT client unless ``client`` is given)."""
    import pybullet

    path = Path(path)
    try:
        robot = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise DataError(f"{path}: cannot be read as a URDF ({exc})") from exc
    _absolute_meshes(robot, path.parent)
    links = {el.get("name"): el for el in robot.findall("link")}
    joints = robot.findall("joint")
    children: dict[str, list[ET.Element]] = {}
    for j in joints:
        children.setdefault(j.find("parent").get("link"), []).append(j)  # type: ignore[union-attr]
    root_name = next(name for name in links if name not in {j.find("child").get("link") for j in joints})  # type: ignore[union-attr]
    free_roots = [j for j in children.get(root_name, []) if j.get("type") == "floating"]  # objects free in the world
    if client is None:
        client = pybullet.connect(pybullet.DIRECT)
    pybullet.setGravity(0, 0, gravity, physicsClientId=client)
    with tempfile.TemporaryDirectory() as tmp:
        subtrees: list[tuple[str, ET.Element, ET.Element]] = []
        for j in free_roots:
            top = j.find("child").get("link")  # type: ignore[union-attr]
            names, stack = [top], [top]
            while stack:
                for c in children.get(stack.pop(), []):
                    names.append(c.find("child").get("link"))  # type: ignore[union-attr]
                    stack.append(names[-1])
            sub = ET.Element("robot", name=top)
            for name in names:
                sub.append(links[name])
            for name in names:
                for c in children.get(name, []):
                    sub.append(c)
            subtrees.append((top, sub, j))
            robot.remove(j)
            for name in names:
                robot.remove(links[name])
                for c in children.get(name, []):
                    robot.remove(c)
        main = Path(tmp) / "scene.urdf"
        ET.ElementTree(robot).write(main)
        fixed = pybullet.loadURDF(str(main), useFixedBase=True, physicsClientId=client)
        scene = BulletScene(client, fixed)
        for k in range(pybullet.getNumJoints(fixed, physicsClientId=client)):
            info = pybullet.getJointInfo(fixed, k, physicsClientId=client)
            scene.joints[info[1].decode()] = k
        for top, sub, joint in subtrees:
            file = Path(tmp) / f"{top}.urdf"
            ET.ElementTree(sub).write(file)
            position, orientation = _pose(joint.find("origin"))
            scene.free[top] = pybullet.loadURDF(
                str(file), position, orientation, useFixedBase=False, physicsClientId=client
            )
    return scene


def settle(path: str | Path, seconds: float = 2.0, timestep: float = 1.0 / 240.0) -> dict[str, Any]:
    """Simulate the scene under gravity; how far each free body's base moved (metres)."""
    import pybullet

    scene = load_scene(path)
    try:
        pybullet.setTimeStep(timestep, physicsClientId=scene.client)
        start = {
            name: np.array(pybullet.getBasePositionAndOrientation(b, physicsClientId=scene.client)[0])
            for name, b in scene.free.items()
        }
        for _ in range(int(round(seconds / timestep))):
            pybullet.stepSimulation(physicsClientId=scene.client)
        moved = {
            name: float(
                np.linalg.norm(
                    np.array(pybullet.getBasePositionAndOrientation(b, physicsClientId=scene.client)[0]) - start[name]
                )
            )
            for name, b in scene.free.items()
        }
    finally:
        pybullet.disconnect(scene.client)
    return {"free_bodies": len(moved), "max_displacement_m": max(moved.values(), default=0.0), "displacement_m": moved}
