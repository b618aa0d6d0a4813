"""ScanNet's per-vertex annotations of a scan, as ScanNet v2 distributes them in ``scans/<id>/``:

* ``<id>_vh_clean_2.labels.ply``: the cleaned mesh's vertices (x, y, z in the scan's frame, the
  frame of its ``.sens`` poses) with ``label``, each vertex's NYU40 class id (0: unannotated);
* ``<id>_vh_clean_2.0.010000.segs.json``: ``segIndices``, the over-segment of every vertex;
* ``<id>.aggregation.json`` (or ``<id>_vh_clean.aggregation.json``): ``segGroups``, one per object
  instance, each with its ``objectId`` (or ``id``), raw ``label`` and the ``segments`` it covers.

NYU40 classes become stratamap classes by :data:`NYU40_CLASSES` (a table: NYU40 id -> class name);
a class with no counterpart in the vocabulary is void (-1: neither right nor wrong). With
``label_set="scannet20"`` only ScanNet's 20 benchmark classes (:data:`SCANNET20`) are kept.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stratamap.core.documents import read_data_text
from stratamap.core.errors import DataError
from stratamap.core.io.pointcloud import read_ply
from stratamap.core.map.vocabulary import Vocabulary

VOID = -1

#: NYU40 id -> stratamap class (default vocabulary). Ids not listed are void: bed 4, door 8,
#: window 9, picture 11, blinds 13, curtain 16, pillow 18, mirror 19, floor mat 20, clothes 21,
#: paper 26, towel 27, shower curtain 28, whiteboard 30, person 31, toilet 33, sink 34, lamp 35,
#: bathtub 36, bag 37, other structure 38, other furniture 39 (no class of the vocabulary is theirs).
NYU40_CLASSES: dict[int, str] = {
    1: "wall",
    2: "floor",
    3: "cabinet",
    5: "chair",
    6: "sofa",
    7: "table",
    10: "shelf",  # bookshelf
    12: "counter",
    14: "desk",
    15: "shelf",  # shelves
    17: "cabinet",  # dresser
    22: "ceiling",
    23: "book",
    24: "fridge",
    25: "monitor",  # television
    29: "box",
    32: "cabinet",  # night stand
    40: "object",  # other prop
}

#: ScanNet's 20 benchmark classes, as NYU40 ids.
SCANNET20 = (1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 14, 16, 24, 28, 33, 34, 36, 39)

LABEL_SETS = ("nyu40", "scannet20")


@dataclass
class ScanLabels:
    """Per-vertex ground truth of a scan (vertices in the scan's frame)."""

    points: np.ndarray  # (N, 3)
    nyu40: np.ndarray  # (N,) NYU40 ids, 0 unannotated
    instance_ids: np.ndarray  # (N,) 1-based object ids of the aggregation, 0 none

    def class_ids(self, vocabulary: Vocabulary, label_set: str = "nyu40") -> np.ndarray:
        """Each vertex's class id in ``vocabulary`` (VOID where the table or the label set has none)."""
        if label_set not in LABEL_SETS:
            raise DataError(f"label_set must be one of {', '.join(LABEL_SETS)}, got {label_set!r}")
        lut = np.full(max(max(NYU40_CLASSES), int(self.nyu40.max(initial=0))) + 1, VOID, np.int32)
        for nyu, name in NYU40_CLASSES.items():
            if name in vocabulary and (label_set == "nyu40" or nyu in SCANNET20):
                lut[nyu] = vocabulary.id(name)
        return lut[self.nyu40]


def scan_files(folder: Path, scan_id: str) -> dict[str, Path]:
    """The annotation files of ``scan_id`` in ``folder`` (a DataError naming what is missing)."""
    files = {
        "labels": folder / f"{scan_id}_vh_clean_2.labels.ply",
        "segs": folder / f"{scan_id}_vh_clean_2.0.010000.segs.json",
        "aggregation": folder / f"{scan_id}.aggregation.json",
    }
    if not files["aggregation"].is_file() and (folder / f"{scan_id}_vh_clean.aggregation.json").is_file():
        files["aggregation"] = folder / f"{scan_id}_vh_clean.aggregation.json"
    missing = [p.name for p in files.values() if not p.is_file()]
    if missing:
        raise DataError(f"{folder}: ScanNet annotations of {scan_id} missing: {', '.join(missing)}")
    return files


def _json(path: Path, what: str) -> dict:
    try:
        doc = json.loads(read_data_text(path, what))
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: corrupt JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise DataError(f"{path}: expected a JSON object ({what})")
    return doc


def read_scan_labels(folder: str | Path, scan_id: str) -> ScanLabels:
    """The per-vertex NYU40 classes and object instances of one ScanNet scan."""
    files = scan_files(Path(folder), scan_id)
    path = files["labels"]
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DataError(f"{path}: cannot be read ({exc})") from exc
    vertex = read_ply(data, path)
    if "label" not in vertex:
        raise DataError(f"{path}: the vertex element has no 'label' property (NYU40 ids)")
    points = np.stack([vertex[a] for a in "xyz"], 1).astype(np.float64)
    nyu40 = np.asarray(vertex["label"]).astype(np.int64)
    if np.any(nyu40 < 0):
        raise DataError(f"{path}: negative NYU40 label")
    segs = _json(files["segs"], "ScanNet segments")
    seg_indices = segs.get("segIndices")
    if not isinstance(seg_indices, list) or len(seg_indices) != len(points):
        count = len(seg_indices) if isinstance(seg_indices, list) else "no"
        raise DataError(f"{files['segs']}: segIndices must list one segment per vertex ({len(points)}), has {count}")
    seg_of_vertex = np.asarray(seg_indices, np.int64)
    groups = _json(files["aggregation"], "ScanNet aggregation").get("segGroups")
    if not isinstance(groups, list):
        raise DataError(f"{files['aggregation']}: expected segGroups, a list of object instances")
    instance_of_seg: dict[int, int] = {}
    for k, group in enumerate(groups):
        if not isinstance(group, dict) or not isinstance(group.get("segments"), list):
            raise DataError(f"{files['aggregation']}: segGroups[{k}] needs a segments list")
        object_id = group.get("objectId", group.get("id", k))
        try:
            iid = int(object_id) + 1  # ScanNet counts objects from 0; 0 here is "no instance"
        except (TypeError, ValueError):
            raise DataError(f"{files['aggregation']}: segGroups[{k}] objectId {object_id!r} is not a number") from None
        for seg in group["segments"]:
            instance_of_seg.setdefault(int(seg), iid)
    unique, inverse = np.unique(seg_of_vertex, return_inverse=True)
    per_unique = np.array([instance_of_seg.get(int(s), 0) for s in unique], np.int64)
    instances = per_unique[inverse.reshape(-1)].astype(np.int32)
    return ScanLabels(points, nyu40, instances)
