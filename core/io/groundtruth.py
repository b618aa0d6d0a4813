"""Read the ``gt/`` folder that ``stratamap synth`` writes beside a sequence into a :class:`GroundTruth`."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from stratamap.core.errors import DataError
from stratamap.core.io import brief
from stratamap.core.io.mesh import read_mesh
from stratamap.core.io.rgbd import read_image
from stratamap.core.lazy import lazy_module
from stratamap.core.map.groundtruth import GroundTruth, GroundTruthObject
from stratamap.core.map.layers import ContactGraph, Joint, OccupancyMaps
from stratamap.core.map.sensors import FrameSegmentation
from stratamap.core.map.vocabulary import Vocabulary

nx = lazy_module("networkx")


class FileLabels(Sequence):
    """Per-frame class and instance images read on access from ``gt/class`` and ``gt/instance``."""

    def __init__(self, gt_dir: Path, stamps: list[str], shape: tuple[int, int] | None = None):
        self.gt_dir, self.stamps, self.shape = gt_dir, stamps, shape

    def __len__(self) -> int:
        return len(self.stamps)

    def __getitem__(self, k):  # type: ignore[override]
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        stamp = self.stamps[k]
        images = []
        for kind, dtype in (("class", np.uint16), ("instance", np.int32)):
            path = self.gt_dir / kind / f"{stamp}.png"
            img = read_image(path)
            if img.ndim != 2 or img.dtype.kind not in "iu":
                raise DataError(f"{path}: a {kind} image must be single-channel integers, got {img.dtype} {img.shape}")
            if img.size and (img.min() < 0 or img.max() > np.iinfo(dtype).max):
                raise DataError(f"{path}: {kind} ids range {img.min()}..{img.max()}, beyond {np.dtype(dtype).name}")
            if self.shape is not None and img.shape != self.shape:
                raise DataError(
                    f"{path}: {kind} image is {img.shape[1]}x{img.shape[0]}, expected {self.shape[1]}x{self.shape[0]} "
                    "like the camera's images"
                )
            images.append(img.astype(dtype))
        if images[0].shape != images[1].shape:
            raise DataError(f"{self.gt_dir}: class and instance images of {stamp} differ in size")
        return FrameSegmentation(k, images[0], images[1])

    def __deepcopy__(self, memo: dict) -> list:
        return [self[i] for i in range(len(self))]


def _read_json(path: Path) -> object:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: corrupt JSON ({brief(exc)})") from exc
    except OSError as exc:
        raise DataError(f"{path}: cannot be read ({brief(exc)})") from exc


def _malformed(path: Path, what: str, exc: Exception) -> DataError:
    detail = f"missing key {exc.args[0]!r}" if isinstance(exc, KeyError) else brief(exc)
    return DataError(f"{path}: {what}: {detail}"[:500])


def _object(rec: object, n: int, gt_dir: Path, scene_file: Path) -> GroundTruthObject:
    if not isinstance(rec, dict):
        raise DataError(f"{scene_file}: objects[{n}] must be a JSON object")
    missing = [k for k in ("id", "class", "mesh", "pose") if k not in rec]
    if missing:
        raise DataError(f"{scene_file}: objects[{n}] lacks {', '.join(missing)}")
    if not isinstance(rec["mesh"], str) or not isinstance(rec["class"], str):
        raise DataError(f"{scene_file}: objects[{n}]: class and mesh must be strings")
    try:
        oid = int(rec["id"])
        pose = np.array(rec["pose"], float)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise ValueError(f"pose must be a 4x4 matrix of finite numbers, got shape {pose.shape}")
        joints = [Joint.from_dict(j) for j in rec.get("joints", [])]
        params = dict(rec.get("params", {}))
        # Optional (files written before it existed have none): moving part -> [lo, hi] in the object frame.
        part_boxes = {
            str(name): np.asarray(box, float).reshape(2, 3).tolist()
            for name, box in dict(rec.get("part_boxes") or {}).items()
        }
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise _malformed(scene_file, f"objects[{n}]", exc) from exc
    mesh = read_mesh(gt_dir / rec["mesh"], f"mesh of ground-truth object {oid}")
    return GroundTruthObject(
        id=oid,
        class_name=rec["class"],
        mesh=mesh,
        pose=pose,
        model_id=str(rec.get("model_id", "")),
        family=str(rec.get("family", "")),
        parent=rec.get("parent", "floor"),
        joints=joints,
        params=params,
        part_boxes=part_boxes,
    )


def load_ground_truth(gt_dir: Path, stamps: list[str], shape: tuple[int, int] | None = None) -> GroundTruth:
    """The ground truth of a ``gt/`` folder; ``stamps`` name the label images of the frames, which must be
    ``shape`` (height, width) when given. Malformed files are DataErrors naming the file and what is wrong."""
    scene_file = gt_dir / "scene.json"
    if not scene_file.is_file():
        raise DataError(f"{gt_dir}: no scene.json; not a stratamap ground-truth folder")
    scene = _read_json(scene_file)
    if not isinstance(scene, dict):
        raise DataError(f"{scene_file}: expected a JSON object with vocabulary, objects and layout")
    try:
        vocab = Vocabulary.from_dict(scene["vocabulary"]) if "vocabulary" in scene else Vocabulary.default()
        records = list(scene.get("objects", []))
        layout = dict(scene.get("layout", {}))
    except (KeyError, TypeError, ValueError) as exc:
        raise _malformed(scene_file, "vocabulary, objects or layout", exc) from exc
    objects = [_object(rec, n, gt_dir, scene_file) for n, rec in enumerate(records)]
    ids = [o.id for o in objects]
    if len(set(ids)) != len(ids):
        raise DataError(f"{scene_file}: object ids repeat ({sorted(i for i in set(ids) if ids.count(i) > 1)})")
    graph = None
    graph_file = gt_dir / "contact_graph.json"
    if graph_file.is_file():
        try:
            graph = ContactGraph(support=nx.node_link_graph(_read_json(graph_file), directed=True, edges="links"))
        except DataError:
            raise
        except Exception as exc:  # networkx raises KeyError, TypeError or its own errors on malformed node-link data
            raise _malformed(graph_file, "not a node-link graph", exc) from exc
        graph.proximal.add_nodes_from(graph.support.nodes)
    occupancy = OccupancyMaps()
    from stratamap.core.io.nav2 import read_map

    for name in ("objects", "laser"):
        yml = gt_dir / f"occupancy_{name}.yaml"
        if yml.is_file():
            occupancy[name] = read_map(yml)
    labels = FileLabels(gt_dir, stamps, shape) if (gt_dir / "class").is_dir() else []
    return GroundTruth(
        vocabulary=vocab,
        objects=objects,
        frame_labels=labels,  # type: ignore[arg-type]
        contact_graph=graph,
        layout=layout,
        occupancy=occupancy,
    )
