"""Small public-benchmark fixtures in the datasets' own formats: a ShapeNet-layout folder of two tiny
models, a ScanNet scan of a synthetic room holding them (a .sens file or exported frames, in a scan
frame tilted off gravity as a real one may be), its per-vertex NYU40 labels and instances, and a
Scan2CAD annotation file whose alignments may be planted off by a chosen error."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

CHAIR, TABLE = "03001627", "04379243"
SCAN_ID = "scene0001_00"
#: The scan's frame is the room's turned 8 degrees off gravity about x, 0.4 m up: the source's
#: gravity alignment undoes it, and scores are right only if the annotations follow it.
SCAN_FROM_ROOM = np.eye(4)
SCAN_FROM_ROOM[:3, :3] = Rotation.from_euler("x", 8, degrees=True).as_matrix()
SCAN_FROM_ROOM[:3, 3] = (0.3, -0.2, 0.4)
#: Scan2CAD's world (its scan trs: scan -> world) is y up, away from the scan.
WORLD_FROM_SCAN = np.eye(4)
WORLD_FROM_SCAN[:3, :3] = Rotation.from_euler("x", 90, degrees=True).as_matrix()
WORLD_FROM_SCAN[:3, 3] = (1.0, 2.0, 3.0)


def _normalized(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """As ShapeNetCore v2 ships a model: y up, centred on its box, box diagonal 1."""
    lo, hi = mesh.bounds
    mesh.apply_translation(-(lo + hi) / 2)
    mesh.apply_scale(1.0 / np.linalg.norm(hi - lo))
    return mesh


def chair_mesh() -> trimesh.Trimesh:
    parts = [
        trimesh.creation.box([0.45, 0.05, 0.45]).apply_translation([0, 0.45, 0]),
        trimesh.creation.box([0.45, 0.5, 0.05]).apply_translation([0, 0.7, -0.2]),
    ]
    parts += [
        trimesh.creation.box([0.04, 0.45, 0.04]).apply_translation([x, 0.225, z])
        for x in (-0.2, 0.2)
        for z in (-0.2, 0.2)
    ]
    return _normalized(trimesh.util.concatenate(parts))


def table_mesh() -> trimesh.Trimesh:
    parts = [trimesh.creation.box([1.2, 0.04, 0.7]).apply_translation([0, 0.73, 0])]
    parts += [
        trimesh.creation.box([0.05, 0.71, 0.05]).apply_translation([x, 0.355, z])
        for x in (-0.55, 0.55)
        for z in (-0.3, 0.3)
    ]
    return _normalized(trimesh.util.concatenate(parts))


def write_shapenet(root: Path) -> Path:
    """``root/SYNSET/MODEL/models/model_normalized.obj`` for a chair and a table."""
    for synset, model, mesh in ((CHAIR, "chair1", chair_mesh()), (TABLE, "table1", table_mesh())):
        folder = root / synset / model / "models"
        folder.mkdir(parents=True)
        mesh.export(folder / "model_normalized.obj")
    return root


def room(library: Path, frames: int = 12):
    from stratamap.core.synthetic import SceneSpec, SyntheticWorld

    spec = SceneSpec.model_validate(
        {
            "type": "room",
            "seed": 3,
            "room_size": [4, 4, 2.6],
            "objects": {"chair": 1, "table": 1},
            "library": {"path": str(library)},
            "camera": {"width": 160, "height": 120},
            "trajectory": {"type": "orbit", "frames": frames},
        }
    )
    return SyntheticWorld(spec)


def write_scan(folder: Path, world, form: str = "sens") -> Path:
    """The room's frames as ScanNet gives them, in the tilted scan frame: ``folder/<id>.sens`` or an
    export (color/, depth/, pose/, intrinsic/) in ``folder``."""
    from types import SimpleNamespace

    from stratamap.core.io.rgbd import write_scannet
    from stratamap.core.io.sens import write_sens

    stream = world.stream()
    posed = [(f.rgb, f.depth, SCAN_FROM_ROOM @ f.pose) for f in stream.frames]
    folder.mkdir(parents=True, exist_ok=True)
    if form == "sens":
        return write_sens(folder / f"{SCAN_ID}.sens", posed, stream.intrinsics.matrix)
    frames = [SimpleNamespace(rgb=rgb, depth=depth, pose=pose) for rgb, depth, pose in posed]
    return write_scannet(SimpleNamespace(frames=frames, intrinsics=stream.intrinsics), folder)


def cad_to_room(world, library) -> dict[str, np.ndarray]:
    """synset -> the 4x4 taking the ShapeNet file's points to where the room placed that model."""
    out = {}
    for obj in world.ground_truth().objects:
        model = library.get(obj.model_id)
        stretch = (obj.mesh.bounds[1] - obj.mesh.bounds[0]) / model.size
        out[model.params["synset"]] = obj.pose @ np.diag([*stretch, 1.0]) @ np.asarray(model.params["cad_to_model"])
    return out


def trs(m: np.ndarray) -> dict[str, list[float]]:
    scale = np.linalg.norm(m[:3, :3], axis=0)
    x, y, z, w = Rotation.from_matrix(m[:3, :3] / scale).as_quat()
    return {"translation": m[:3, 3].tolist(), "rotation": [w, x, y, z], "scale": scale.tolist()}


def planted(m: np.ndarray, shift=(0.0, 0.0, 0.0), turn_deg: float = 0.0, stretch: float = 1.0) -> np.ndarray:
    """A CAD-to-room transform moved by ``shift`` (room frame, m), turned about the room's up axis
    through the model's centre, and scaled about it by ``stretch``."""
    center = m[:3, 3].copy()  # the ShapeNet model's box centre is its origin
    about = np.eye(4)
    about[:3, :3] = Rotation.from_euler("z", turn_deg, degrees=True).as_matrix() * stretch
    about[:3, 3] = center - about[:3, :3] @ center + np.asarray(shift, float)
    return about @ m


def write_annotations(path: Path, models: list[tuple[str, np.ndarray, str]]) -> Path:
    """Scan2CAD's full_annotations.json for the scan: (synset, CAD-to-room transform, sym) each."""
    records = []
    for synset, cad_room, sym in models:
        mesh = chair_mesh() if synset == CHAIR else table_mesh()
        lo, hi = mesh.bounds
        records.append(
            {
                "catid_cad": synset,
                "id_cad": "chair1" if synset == CHAIR else "table1",
                "trs": trs(WORLD_FROM_SCAN @ SCAN_FROM_ROOM @ cad_room),
                "bbox": ((hi - lo) / 2).tolist(),
                "center": ((hi + lo) / 2).tolist(),
                "sym": sym,
            }
        )
    doc = [
        {"id_scan": "scene0999_00", "trs": trs(np.eye(4)), "aligned_models": []},
        {"id_scan": SCAN_ID, "trs": trs(WORLD_FROM_SCAN), "n_aligned_models": len(records), "aligned_models": records},
    ]
    path.write_text(json.dumps(doc))
    return path


#: NYU40 ids of the room's surfaces.
NYU40 = {"floor": 2, "wall": 1, "ceiling": 22, "chair": 5, "table": 7}


def write_labels(folder: Path, world, spacing: float = 0.04) -> dict[str, int]:
    """``<id>_vh_clean_2.labels.ply`` (vertices sampled on every surface of the room, in the scan
    frame, with NYU40 labels), ``.0.010000.segs.json`` and ``.aggregation.json`` (the chair and the
    table as objects 0 and 1). Returns class name -> vertex count."""
    from stratamap.core.io.pointcloud import write_ply
    from stratamap.core.synthetic.scene import room_layout

    gt = world.ground_truth()
    surfaces = [(el.mesh, el.class_name, None) for el in room_layout(tuple(gt.layout["room_size"]))]
    surfaces += [(o.world_mesh(), o.class_name, k) for k, o in enumerate(gt.objects)]
    points, labels, segs, groups = [], [], [], []
    counts: dict[str, int] = {}
    for seg, (mesh, name, object_id) in enumerate(surfaces):
        count = max(50, int(mesh.area / spacing**2))
        pts, _ = trimesh.sample.sample_surface(mesh, count, seed=seg)
        points.append(pts)
        labels.append(np.full(len(pts), NYU40[name], np.uint16))
        segs.append(np.full(len(pts), 100 + seg, np.int64))
        counts[name] = counts.get(name, 0) + len(pts)
        if object_id is not None:
            groups.append({"id": object_id, "objectId": object_id, "label": name, "segments": [100 + seg]})
    xyz = np.concatenate(points) @ SCAN_FROM_ROOM[:3, :3].T + SCAN_FROM_ROOM[:3, 3]
    folder.mkdir(parents=True, exist_ok=True)
    write_ply(
        folder / f"{SCAN_ID}_vh_clean_2.labels.ply", xyz.astype(np.float32), fields={"label": np.concatenate(labels)}
    )
    (folder / f"{SCAN_ID}_vh_clean_2.0.010000.segs.json").write_text(
        json.dumps({"sceneId": SCAN_ID, "segIndices": np.concatenate(segs).tolist()})
    )
    (folder / f"{SCAN_ID}.aggregation.json").write_text(json.dumps({"sceneId": SCAN_ID, "segGroups": groups}))
    return counts
