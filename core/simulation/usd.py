"""USD scenes with UsdPhysics (Isaac Sim, Isaac Lab, OmniGibson): the kinematic tree the URDF
exporter writes (:func:`stratamap.core.simulation.scene.scene_tree`), as one self-contained layer.

Stage: metres (``metersPerUnit`` 1), kilograms, z up, ``defaultPrim`` ``/World``, a
``PhysicsScene`` with gravity along -z. Every link is a rigid body (``RigidBodyAPI``, ``MassAPI``
with the URDF's mass, centre of mass and principal inertia) at its world pose, its mesh a visual
``Mesh`` and each convex collision part (:func:`~stratamap.core.simulation.kinematics.link_collision`,
the URDF's collision blocks) a guide-purpose ``Mesh`` collider approximated by its convex hull.
Bodies are grouped by the tree under ``/World/Objects/<model>``, one model per link hanging from
``world``:

- a model with a revolute, prismatic or continuous joint below its root link (an articulated
  completion) is an articulation (``ArticulationRootAPI`` on the model): its joints as USD
  joints, the root welded to the world by a ``FixedJoint`` unless it is a free body;
- a free model (a floating joint on ``world``) is dynamic, its fixed children joined by
  ``FixedJoint``;
- a model fixed to the world is kinematic (``kinematicEnabled``): static furniture that still
  carries its mass;
- a front found on a scan (a panel on a revolute or prismatic joint to the world) is a dynamic
  body on that joint.

USD joints turn about or slide along one axis of their frames, so each joint frame is turned to
put the URDF axis on X; revolute limits are degrees, as USD writes them, and every moving joint
has a drive (``DriveAPI``, damping only, so parts keep still unless pushed). Floor, walls and
ceiling are kinematic ``Cube`` bodies with colliders under ``/World/Room``. ``pxr`` (PyPI ``usd-core``, the
``usd`` extra) is imported only when a scene is written.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from stratamap.core.atomic import atomic_path, write_text
from stratamap.core.errors import PluginError
from stratamap.core.lazy import lazy_module
from stratamap.core.simulation.kinematics import ROOT_LINK, KinematicJoint, KinematicTree, Link, link_collision

rotations = lazy_module("scipy.spatial.transform")

USD_INSTALL_HINT = "pip install 'stratamap[usd]'"
#: File name suffixes USD reads: text (``.usda``) or binary crate (``.usdc``; ``.usd`` is a crate too).
USD_SUFFIXES = (".usda", ".usdc", ".usd")
GRAVITY = 9.81
MOVING = ("revolute", "prismatic", "continuous")
WORLD = "/World"


def load_pxr() -> dict[str, ModuleType]:
    """The pxr modules the writer uses; a one-line error naming the extra when usd-core is missing."""
    names = ("Gf", "Sdf", "Tf", "Usd", "UsdGeom", "UsdPhysics", "UsdShade", "Vt")
    try:
        return {name: importlib.import_module(f"pxr.{name}") for name in names}
    except ImportError as exc:
        raise PluginError(f"the usd exporter needs usd-core ({exc}): {USD_INSTALL_HINT}") from None


def _quat_wxyz(rotation: np.ndarray) -> tuple[float, float, float, float]:
    x, y, z, w = rotations.Rotation.from_matrix(np.asarray(rotation, float)[:3, :3]).as_quat()
    return float(w), float(x), float(y), float(z)


def axis_frame(axis: np.ndarray) -> np.ndarray:
    """A rotation whose x column is ``axis`` (USD joints move about or along their frame's X)."""
    norm = float(np.linalg.norm(axis))
    # A zero axis (a model's error) turns about x, URDF's default axis, rather than writing NaNs.
    x = np.asarray(axis, float) / norm if norm > 1e-12 else np.array([1.0, 0.0, 0.0])
    helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    y = np.cross(helper, x)
    y /= np.linalg.norm(y)
    frame = np.eye(4)
    frame[:3, :3] = np.column_stack([x, y, np.cross(x, y)])
    return frame


class _Writer:
    def __init__(self, pxr: dict[str, ModuleType], tree: KinematicTree, hinge_damping: float, slide_damping: float):
        self.pxr = pxr
        self.tree = tree
        self.hinge_damping = hinge_damping
        self.slide_damping = slide_damping
        self.stage = pxr["Usd"].Stage.CreateInMemory()
        self.links = {link.name: link for link in tree.links}
        self.children: dict[str, list[KinematicJoint]] = {}
        for joint in tree.joints:
            self.children.setdefault(joint.parent, []).append(joint)
        self.world_pose: dict[str, np.ndarray] = {ROOT_LINK: np.eye(4)}
        self.link_path: dict[str, Any] = {}
        self.used: set[tuple[Any, str]] = set()

    def child(self, parent: Any, text: str) -> Any:
        """The path of a new prim under ``parent`` named ``text`` as USD allows it, unique among its
        siblings (link and joint names already are, up to USD's rules for names)."""
        parent = self.pxr["Sdf"].Path(str(parent))
        base = self.pxr["Tf"].MakeValidIdentifier(text)
        name, k = base, 1
        while (parent, name) in self.used:
            name, k = f"{base}_{k}", k + 1
        self.used.add((parent, name))
        return parent.AppendChild(name)

    def place(self, prim: Any, pose: np.ndarray, scale: np.ndarray | None = None) -> None:
        Gf, UsdGeom = self.pxr["Gf"], self.pxr["UsdGeom"]
        xform = UsdGeom.Xformable(prim)
        xform.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*(float(v) for v in pose[:3, 3])))
        xform.AddOrientOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Quatd(*_quat_wxyz(pose)))
        if scale is not None:
            xform.AddScaleOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*(float(v) for v in scale)))

    def mesh(self, path: Any, mesh: Any) -> Any:
        Gf, UsdGeom, Vt = self.pxr["Gf"], self.pxr["UsdGeom"], self.pxr["Vt"]
        prim = UsdGeom.Mesh.Define(self.stage, path)
        vertices = np.ascontiguousarray(mesh.vertices, np.float32)
        faces = np.ascontiguousarray(mesh.faces, np.int32)
        prim.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(vertices))
        prim.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
        prim.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
        lo, hi = (vertices.min(0), vertices.max(0)) if len(vertices) else (np.zeros(3), np.zeros(3))
        prim.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
        # Triangle meshes as they are: USD's default subdivides them into smooth blobs.
        prim.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        return prim

    def collider(self, prim: Any) -> None:
        UsdPhysics, UsdShade = self.pxr["UsdPhysics"], self.pxr["UsdShade"]
        UsdPhysics.CollisionAPI.Apply(prim)
        binding = UsdShade.MaterialBindingAPI.Apply(prim)
        binding.Bind(self.material, UsdShade.Tokens.weakerThanDescendants, "physics")

    def write(self, friction: float) -> Any:
        Gf, UsdGeom, UsdPhysics, UsdShade = (self.pxr[n] for n in ("Gf", "UsdGeom", "UsdPhysics", "UsdShade"))
        stage = self.stage
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.LinearUnits.meters)
        UsdPhysics.SetStageKilogramsPerUnit(stage, UsdPhysics.MassUnits.kilograms)
        world = UsdGeom.Xform.Define(stage, WORLD)
        stage.SetDefaultPrim(world.GetPrim())
        scene = UsdPhysics.Scene.Define(stage, f"{WORLD}/PhysicsScene")
        scene.CreateGravityDirectionAttr(Gf.Vec3f(0.0, 0.0, -1.0))
        scene.CreateGravityMagnitudeAttr(GRAVITY)
        self.material = UsdShade.Material.Define(stage, f"{WORLD}/PhysicsMaterial")
        material = UsdPhysics.MaterialAPI.Apply(self.material.GetPrim())
        material.CreateStaticFrictionAttr(friction)
        material.CreateDynamicFrictionAttr(friction)
        material.CreateRestitutionAttr(0.0)
        if self.tree.statics:
            UsdGeom.Scope.Define(stage, f"{WORLD}/Room")
            for slab in self.tree.statics:
                # A link in the URDF, so a (kinematic) body here: the two files list the same bodies.
                body = UsdGeom.Xform.Define(stage, self.child(f"{WORLD}/Room", slab.name))
                self.place(body.GetPrim(), slab.pose)
                UsdPhysics.RigidBodyAPI.Apply(body.GetPrim()).CreateKinematicEnabledAttr(True)
                cube = UsdGeom.Cube.Define(stage, self.child(body.GetPath(), slab.name))
                cube.CreateSizeAttr(1.0)
                self.place(cube.GetPrim(), np.eye(4), np.asarray(slab.size, float))
                self.collider(cube.GetPrim())
        UsdGeom.Scope.Define(stage, f"{WORLD}/Objects")
        for top in self.children.get(ROOT_LINK, []):
            self.model(top)
        return stage

    def subtree(self, top: KinematicJoint) -> list[KinematicJoint]:
        """The joints of the model hanging from ``top``, parents first (``top`` included)."""
        order, stack = [], [top]
        while stack:
            joint = stack.pop(0)
            order.append(joint)
            self.world_pose[joint.child] = self.world_pose[joint.parent] @ joint.origin
            stack.extend(self.children.get(joint.child, []))
        return order

    def model(self, top: KinematicJoint) -> None:
        UsdGeom, UsdPhysics = self.pxr["UsdGeom"], self.pxr["UsdPhysics"]
        joints = self.subtree(top)
        model = UsdGeom.Xform.Define(self.stage, self.child(f"{WORLD}/Objects", top.child))
        articulated = any(j.type in MOVING for j in joints[1:])
        if articulated:
            UsdPhysics.ArticulationRootAPI.Apply(model.GetPrim())
        # Welded to the world and not articulated: kinematic, so no joint can sag under the load.
        kinematic = top.type == "fixed" and not articulated
        for joint in joints:
            self.body(model.GetPath(), self.links[joint.child], kinematic)
        if kinematic:
            return
        scope = None
        for joint in joints:
            if joint.type == "floating":
                continue
            if scope is None:
                scope = UsdGeom.Scope.Define(self.stage, self.child(model.GetPath(), "Joints")).GetPath()
            self.joint(self.child(scope, joint.name), joint)

    def body(self, parent: Any, link: Link, kinematic: bool) -> None:
        Gf, UsdGeom, UsdPhysics = self.pxr["Gf"], self.pxr["UsdGeom"], self.pxr["UsdPhysics"]
        xform = UsdGeom.Xform.Define(self.stage, self.child(parent, link.name))
        prim = xform.GetPrim()
        self.link_path[link.name] = prim.GetPath()
        self.place(prim, self.world_pose[link.name])
        body = UsdPhysics.RigidBodyAPI.Apply(prim)
        if kinematic:
            body.CreateKinematicEnabledAttr(True)
        inertial = link.inertial
        evals, evecs = np.linalg.eigh(np.asarray(inertial.inertia, float))
        if np.linalg.det(evecs) < 0:
            evecs[:, 0] = -evecs[:, 0]
        mass = UsdPhysics.MassAPI.Apply(prim)
        mass.CreateMassAttr(float(inertial.mass))
        mass.CreateCenterOfMassAttr(Gf.Vec3f(*(float(v) for v in inertial.center)))
        mass.CreateDiagonalInertiaAttr(Gf.Vec3f(*(float(v) for v in np.maximum(evals, 1e-8))))
        mass.CreatePrincipalAxesAttr(Gf.Quatf(*_quat_wxyz(evecs)))
        Sdf = self.pxr["Sdf"]
        prim.CreateAttribute("stratamap:link", Sdf.ValueTypeNames.String, custom=True).Set(link.name)
        if link.instance_id is not None:
            prim.CreateAttribute("stratamap:instance_id", Sdf.ValueTypeNames.Int, custom=True).Set(link.instance_id)
            prim.CreateAttribute("stratamap:class", Sdf.ValueTypeNames.String, custom=True).Set(link.class_name)
        if link.mesh is None:  # a helper frame between two joints
            return
        self.mesh(prim.GetPath().AppendChild("Visual"), link.mesh)
        for k, part in enumerate(link_collision(link)):
            collider = self.mesh(prim.GetPath().AppendChild(f"Collider_{k}"), part)
            collider.CreatePurposeAttr(UsdGeom.Tokens.guide)
            self.collider(collider.GetPrim())
            UsdPhysics.MeshCollisionAPI.Apply(collider.GetPrim()).CreateApproximationAttr(UsdPhysics.Tokens.convexHull)

    def joint(self, path: Any, joint: KinematicJoint) -> None:
        Gf, UsdPhysics = self.pxr["Gf"], self.pxr["UsdPhysics"]
        schema = {
            "fixed": UsdPhysics.FixedJoint,
            "prismatic": UsdPhysics.PrismaticJoint,
            "revolute": UsdPhysics.RevoluteJoint,
            "continuous": UsdPhysics.RevoluteJoint,
        }[joint.type]
        usd = schema.Define(self.stage, path)
        if joint.parent != ROOT_LINK:  # no body0: the joint holds body1 to the world
            usd.CreateBody0Rel().SetTargets([self.link_path[joint.parent]])
        usd.CreateBody1Rel().SetTargets([self.link_path[joint.child]])
        # The joint frame is the child's frame at rest (URDF), turned so that its X is the axis.
        turn = axis_frame(joint.axis) if joint.type in MOVING else np.eye(4)
        frame0 = joint.origin @ turn
        usd.CreateLocalPos0Attr(Gf.Vec3f(*(float(v) for v in frame0[:3, 3])))
        usd.CreateLocalRot0Attr(Gf.Quatf(*_quat_wxyz(frame0)))
        usd.CreateLocalPos1Attr(Gf.Vec3f(0.0, 0.0, 0.0))
        usd.CreateLocalRot1Attr(Gf.Quatf(*_quat_wxyz(turn)))
        usd.GetPrim().CreateAttribute("stratamap:joint", self.pxr["Sdf"].ValueTypeNames.String, custom=True).Set(
            joint.name
        )
        if joint.type not in MOVING:
            return
        usd.CreateAxisAttr(UsdPhysics.Tokens.x)
        if joint.type == "revolute":
            usd.CreateLowerLimitAttr(float(np.degrees(joint.lower)))
            usd.CreateUpperLimitAttr(float(np.degrees(joint.upper)))
        elif joint.type == "prismatic":
            usd.CreateLowerLimitAttr(float(joint.lower))
            usd.CreateUpperLimitAttr(float(joint.upper))
        angular = joint.type != "prismatic"
        drive = UsdPhysics.DriveAPI.Apply(usd.GetPrim(), "angular" if angular else "linear")
        drive.CreateTypeAttr("force")
        drive.CreateTargetVelocityAttr(0.0)
        drive.CreateStiffnessAttr(0.0)
        # USD's angular drives take gains per degree.
        drive.CreateDampingAttr(float(np.radians(self.hinge_damping)) if angular else float(self.slide_damping))


def write_usd(
    tree: KinematicTree,
    path: Path,
    hinge_damping: float = 1.0,
    slide_damping: float = 5.0,
    friction: float = 0.8,
) -> Path:
    """Write ``tree`` as the USD file ``path`` (``.usda`` text, ``.usdc`` or ``.usd`` binary), atomically.

    ``hinge_damping`` (N m s/rad) and ``slide_damping`` (N s/m) are the drives' damping on revolute
    and prismatic joints, ``friction`` the static and dynamic friction of every collider."""
    path = Path(path)
    if path.suffix not in USD_SUFFIXES:
        raise PluginError(f"{path}: a USD file name ends in {', '.join(USD_SUFFIXES)}")
    pxr = load_pxr()
    stage = _Writer(pxr, tree, hinge_damping, slide_damping).write(friction)
    layer = stage.GetRootLayer()
    if path.suffix == ".usda":
        write_text(path, layer.ExportToString())
        return path
    with atomic_path(path) as tmp:
        # USD picks the format from the suffix: write under the final suffix, then move into place.
        named = tmp.with_name(tmp.name + path.suffix)
        try:
            if not layer.Export(str(named)):
                raise PluginError(f"{path}: USD could not write the file")
            named.replace(tmp)
        finally:
            named.unlink(missing_ok=True)
    return path
