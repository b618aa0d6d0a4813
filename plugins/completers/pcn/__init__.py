"""Completer ``pcn``: a learned point completion network (PCN-style) head to head with model matching.

Each object's observed points, in its gravity-aligned frame (see :mod:`.data`), go through the
shipped ONNX network with the one-hot of the object's class; its dense completed point set (merged
with the observed points, by default) is meshed by Open3D's ball pivoting (or screened Poisson),
so the completion is a mesh like any other completer's and every downstream stage and exporter
takes it. Objects of classes the network has no slot for go through its class-agnostic ``other``
slot (``class_agnostic: false`` leaves them uncompleted, with a warning). Inference runs on the
CPU with onnxruntime; torch is needed only to retrain (``scripts/train_pcn.py``).

The network never saw a family of the generated benchmark scenes: it was trained on the
training-only families of :mod:`.training_shapes`; ``models/pcn.json`` lists both.
"""

from __future__ import annotations

import functools
import json
import time
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field

from stratamap.core import Completer, PipelineData, StageConfig, hookimpl
from stratamap.core.errors import ConfigError, DataError
from stratamap.core.geometry.hulls import convex_hull
from stratamap.core.geometry.points import voxel_downsample
from stratamap.core.lazy import lazy_module
from stratamap.core.map.augmented import augmented_scene
from stratamap.core.map.layers import Completion, ObjectInstance
from stratamap.plugins.completers._matching import object_base
from stratamap.plugins.completers.pcn.data import (
    CLASSES,
    DENSE_POINTS,
    INPUT_POINTS,
    THIN_VOXEL,
    ObjectFrame,
    class_onehot,
    fixed_count,
    frame_for,
)

o3d = lazy_module("open3d")
ort = lazy_module("onnxruntime")
spatial = lazy_module("scipy.spatial")
trimesh = lazy_module("trimesh")

MODELS = Path(__file__).resolve().parent / "models"
SHIPPED = MODELS / "pcn.onnx"


class PCNConfig(StageConfig):
    path_fields = ("model",)

    model: str | None = Field(
        default=None, description="ONNX file of the network (default: the shipped models/pcn.onnx)."
    )
    classes: list[str] | None = Field(
        default=None, description="Complete only these classes (default: every object the network can take)."
    )
    class_agnostic: bool = Field(
        default=True,
        description=(
            "Objects of classes the network has no slot for go through its class-agnostic 'other' slot; false: they "
            "are left uncompleted (with a warning)."
        ),
    )
    min_points: int = Field(
        default=50, ge=3, description="Objects with fewer observed points are left uncompleted (with a warning)."
    )
    merge_observed: bool = Field(
        default=True,
        description="Mesh the network's points together with the observed ones (the observation is where it is).",
    )
    seen_radius: float = Field(
        default=0.03,
        ge=0.0,
        description=(
            "With merge_observed: network points within this distance of an observed point are dropped (the "
            "observation stands where it exists), metres; 0 keeps them all."
        ),
    )
    mesher: Literal["ball_pivoting", "poisson"] = Field(
        default="ball_pivoting", description="Open3D surface reconstruction of the completed points."
    )
    poisson_depth: int = Field(default=7, ge=4, le=10, description="Octree depth of the Poisson reconstruction.")
    mesh_voxel: float = Field(
        default=0.015,
        gt=0.0,
        description="Completed points are thinned to one per voxel of this size before meshing, metres.",
    )
    epsilon: float = Field(
        default=0.1,
        gt=0.0,
        description="Augmented scene: observed points this close to a completed object are replaced, metres.",
    )
    sample_spacing: float = Field(
        default=0.02, gt=0.0, description="Surface sampling spacing of the completions in the augmented scene, metres."
    )


@functools.lru_cache(maxsize=4)
def load_session(path: str) -> Any:
    """An onnxruntime CPU session of the network (one thread: outputs identical run to run)."""
    file = Path(path)
    if not file.is_file():
        raise ConfigError([("model", f"{file} does not exist (expected an ONNX file, e.g. {SHIPPED})")])
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    try:
        session = ort.InferenceSession(str(file), sess_options=options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types for unreadable files
        raise ConfigError([("model", f"{file} is not a loadable ONNX file ({exc.__class__.__name__})")]) from exc
    names = {i.name: i.shape for i in session.get_inputs()}
    if set(names) != {"points", "class_onehot"} or names["class_onehot"][1] != len(CLASSES):
        raise ConfigError(
            [
                (
                    "model",
                    f"{file} has inputs {names}; expected points (batch, {INPUT_POINTS}, 3) and class_onehot "
                    f"(batch, {len(CLASSES)})",
                )
            ]
        )
    return session


@functools.lru_cache(maxsize=4)
def network_provenance(model: Path) -> dict[str, Any]:
    """What the report says about the network: its file, and the families it was and was not trained on."""
    sidecar = model.with_suffix(".json")
    if not sidecar.is_file():
        return {"model": model.name}
    try:
        meta = json.loads(sidecar.read_text())
    except (OSError, ValueError) as exc:
        raise DataError(f"{sidecar}: not a readable JSON sidecar ({exc})") from exc
    return {
        "model": model.name,
        "heldout_chamfer_l1_m": meta.get("heldout_chamfer_l1_m"),
        "trained_on": sorted(meta.get("training_families", {})),
        "held_out": meta.get("heldout_note", ""),
    }


def complete_points(session: Any, observed: np.ndarray, class_name: str, frame: ObjectFrame) -> np.ndarray:
    """The network's dense completion of ``observed`` (world points), in the object frame in metres."""
    local = frame.to_local(observed).astype(np.float32)
    points = fixed_count(local, INPUT_POINTS)[None]
    dense = session.run(["dense"], {"points": points, "class_onehot": class_onehot(class_name)[None]})[0][0]
    if dense.shape != (DENSE_POINTS, 3) or not np.isfinite(dense).all():
        raise DataError(
            f"pcn model: output dense has shape {dense.shape} or non-finite values; expected ({DENSE_POINTS}, 3)"
        )
    return dense.astype(np.float64) * frame.scale


def mesh_points(points: np.ndarray, mesher: str, poisson_depth: int) -> trimesh.Trimesh:
    """A surface through completed points (object frame, metres) by Open3D; the convex hull when that fails."""
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    spacing = float(np.mean(np.asarray(pcd.compute_nearest_neighbor_distance())))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(16))
    pcd.orient_normals_consistent_tangent_plane(10)
    if mesher == "poisson":
        mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=poisson_depth)
        density = np.asarray(density)
        mesh.remove_vertices_by_mask(density < np.quantile(density, 0.05))  # the far, weakly supported extrapolation
    else:
        radii = o3d.utility.DoubleVector([1.5 * spacing, 3.0 * spacing, 6.0 * spacing])
        mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(pcd, radii)
    out = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.triangles), process=True)
    if len(out.faces) < 20:
        out = convex_hull(points)
    return out


class PCNCompleter(Completer[PCNConfig]):
    """Learned shape completion (PCN-style network in ONNX, CPU) meshed by Open3D."""

    name = "pcn"
    Config = PCNConfig
    requires = frozenset({"instances"})
    optional = frozenset({"geometry", "contact_graph"})
    provides = frozenset({"instances", "augmented"})

    def select(self, inst: ObjectInstance) -> bool:
        cfg = self.config
        if cfg.classes is not None and inst.class_name not in cfg.classes:
            return False
        if inst.class_name not in CLASSES and not cfg.class_agnostic:
            self.warn(f"object {inst.id}: the network has no {inst.class_name!r} slot; left uncompleted")
            return False
        if len(inst.points) < cfg.min_points:
            self.warn(
                f"object {inst.id} ({inst.class_name}) has {len(inst.points)} points (< {cfg.min_points}); left "
                "uncompleted"
            )
            return False
        return True

    def complete(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        session = load_session(str(Path(cfg.model) if cfg.model else SHIPPED))
        insts = data.map.instances.copy()  # type: ignore[union-attr]
        todo = [inst for inst in insts if self.select(inst)]
        seconds = []
        for inst in todo:
            t0 = time.perf_counter()
            frame = frame_for(object_base(inst, data), inst.box.yaw, inst.box.size)
            observed = voxel_downsample(inst.points, THIN_VOXEL)[0]
            dense = complete_points(session, observed, inst.class_name, frame)
            seen = frame.to_local(observed) * frame.scale
            # Score: how far the observation lies from the network's shape (how well it explains what was seen).
            fit = float(np.mean(spatial.cKDTree(dense).query(seen)[0]))
            if cfg.merge_observed:
                # Where the sensor saw the object, its points stand; the network fills in the rest.
                unseen = spatial.cKDTree(seen).query(dense)[0] > cfg.seen_radius
                dense = np.vstack([dense[unseen], seen])
            dense[:, 2] = np.maximum(dense[:, 2], 0.0)  # the object stands on its support
            dense = voxel_downsample(dense, cfg.mesh_voxel)[0]
            mesh = mesh_points(dense, cfg.mesher, cfg.poisson_depth)
            inst.completion = Completion(
                mesh=mesh, pose=frame.pose(), completer=self.name, model_id=None, scale=np.ones(3), score=fit
            )
            inst.attributes["pcn"] = {
                "slot": inst.class_name if inst.class_name in CLASSES else "other",
                "fit_m": round(fit, 4),
                "points": len(dense),
            }
            seconds.append(time.perf_counter() - t0)
        self.note("network", network_provenance(Path(cfg.model) if cfg.model else SHIPPED))
        self.note("seconds_per_object", float(np.mean(seconds)) if seconds else 0.0)
        self.note("objects", {"completed": len(insts.completed()), "attempted": len(todo)})
        out: dict[str, Any] = {"instances": insts}
        aug = augmented_scene(data.map.geometry, insts, cfg.epsilon, cfg.sample_spacing)
        if aug is not None:
            out["augmented"] = aug
        return out


@hookimpl
def stratamap_register_completers():
    return [PCNCompleter]
