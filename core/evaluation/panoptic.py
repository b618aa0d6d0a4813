"""Panoptic quality of a 3D map (functional-scenes paper, eq. 15; Kirillov et al. 2019).

Ground-truth labels of map points come from the closest ground-truth surface (object meshes and
the room's floor, walls and ceiling); points farther than ``max_distance`` from every surface are
void and ignored. Segments are instances for *thing* classes and one segment per class for
*stuff*. A predicted segment matches a ground-truth segment of the same class with IoU > 0.5
(unique by construction). Per class::

    PQ = sum_TP IoU / (|TP| + |FP|/2 + |FN|/2) = SQ x RQ

reported averaged over the classes present, over things, over stuff, and per class. A class is
present when the ground truth or the prediction holds a segment of it (Kirillov et al. average PQ
over those): an average over no class at all (``pq_stuff`` of a scene with no stuff segment either
way, ``pq_things`` of one with no thing) is undefined and reported as ``None``, not as 0, which
would read as "every stuff segment missed". Predicted segments made mostly (> 50%) of void points
are not counted as false positives.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stratamap.core.lazy import lazy_module
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.vocabulary import Vocabulary

o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")

VOID = -1


def frame_quality(pred: list, truth: list, vocab: Vocabulary, stride: int = 5) -> dict[str, Any]:
    """2D segmentation quality over every ``stride``-th frame the segmenter labelled (``frames``: how
    many): mIoU over classes present (None when none is), and PQ (things, stuff) with all sampled
    frames pooled as one image (instance ids kept apart per frame).
    Pixels the ground truth leaves unknown (class 0) are not counted. The pooled image is never built:
    its segment sizes and overlaps are sums over frames, so memory does not grow with the frames."""
    n = len(vocab.names)
    inter, union = np.zeros(n), np.zeros(n)
    counts = SegmentCounts()
    scored = 0
    for k in range(0, len(truth), stride):
        p, g = pred[k], truth[k]
        if not p.labelled:
            continue  # a frame the segmenter did not label (not a keyframe)
        scored += 1
        pcls = np.asarray(p.class_ids, np.int64)
        if pcls.shape != g.class_ids.shape:
            raise ValueError(f"frame {k}: predicted labels are {pcls.shape}, the ground truth {g.class_ids.shape}")
        gcls = np.asarray(g.class_ids, np.int64)
        valid = gcls > 0
        inter += np.bincount(gcls[valid & (pcls == gcls)], minlength=n)[:n]
        union += (
            np.bincount(gcls[valid], minlength=n)
            + np.bincount(pcls[valid], minlength=n)
            - np.bincount(gcls[valid & (pcls == gcls)], minlength=n)
        )[:n]
        off = (k + 1) << 20
        counts.add(
            pcls.ravel(),
            np.where(p.instance_ids > 0, np.asarray(p.instance_ids, np.int64) + off, 0).ravel(),
            np.where(valid, gcls, VOID).ravel(),
            np.where(g.instance_ids > 0, np.asarray(g.instance_ids, np.int64) + off, 0).ravel(),
            vocab,
        )
    present = union > 0
    present[0] = False  # "unknown" is the void label, not a class
    pq = counts.quality(vocab)
    return {
        "miou": float(np.mean(inter[present] / union[present])) if present.any() else None,
        "iou_by_class": {vocab.name(c): float(inter[c] / union[c]) for c in np.flatnonzero(present)},
        "pq": pq["pq"],
        "sq": pq["sq"],
        "rq": pq["rq"],
        "pq_things": pq["pq_things"],
        "pq_stuff": pq["pq_stuff"],
        "by_class": pq["by_class"],
        "frames": scored,
    }


def instance_map(
    semantics: Any, instances: Any, gt_class: np.ndarray, gt_instance: np.ndarray, threshold: float = 0.5
) -> float:
    """Instance segmentation mAP at mask IoU ``threshold`` over map points (functional-scenes paper,
    Table 2): a predicted instance's mask is its points, scored by its confidence."""
    from stratamap.core.evaluation.detection import mean_average_precision

    vocab = semantics.vocabulary
    score = {i.id: float(i.score) for i in (instances or [])}
    pred, gt = [], []
    for iid in np.unique(semantics.instance_ids[semantics.instance_ids > 0]):
        mask = semantics.instance_ids == iid
        cls = int(np.bincount(semantics.class_ids[mask]).argmax())
        if vocab.is_thing[cls]:
            pred.append((vocab.name(cls), score.get(int(iid), 1.0), np.flatnonzero(mask)))
    for iid in np.unique(gt_instance[gt_instance > 0]):
        mask = (gt_instance == iid) & (gt_class > 0)
        if mask.any():
            cls = int(np.bincount(gt_class[mask]).argmax())
            if vocab.is_thing[cls]:
                gt.append((vocab.name(cls), np.flatnonzero(mask)))

    def iou(a: np.ndarray, b: np.ndarray) -> float:
        inter = len(np.intersect1d(a, b, assume_unique=True))
        return inter / (len(a) + len(b) - inter)

    return mean_average_precision(pred, gt, iou, threshold)["map"]


def transfer_point_labels(
    points: np.ndarray,
    labelled: np.ndarray,
    classes: np.ndarray,
    instances: np.ndarray | None,
    max_distance: float = 0.02,
) -> tuple[np.ndarray, np.ndarray]:
    """Labels of the nearest labelled point (a dataset's per-point ground truth, e.g. mOSD) for
    each map point; class -1 (void) farther than ``max_distance`` or on unlabelled points."""
    from scipy.spatial import cKDTree

    dist, nearest = cKDTree(labelled).query(points, distance_upper_bound=max_distance)
    ok = np.isfinite(dist)
    near = np.where(ok, nearest, 0)
    cls = np.where(ok, np.asarray(classes)[near], VOID).astype(np.int32)
    cls[cls == 0] = VOID  # unlabelled in the dataset: not counted either way
    inst = (
        np.where(ok, np.asarray(instances)[near], 0).astype(np.int32)
        if instances is not None
        else np.zeros(len(points), np.int32)
    )
    return cls, inst


def ground_truth_point_labels(
    points: np.ndarray, gt: GroundTruth, max_distance: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """Class and instance of the closest ground-truth surface for each point (class -1: void)."""
    from stratamap.core.synthetic.scene import room_layout

    scene = o3d.t.geometry.RaycastingScene()
    classes, instances = [], []
    meshes = []
    for obj in gt.objects:
        meshes.append((obj.world_mesh(), obj.class_name, obj.id))
    if "room_size" in gt.layout:
        transform = np.asarray(gt.layout.get("world_transform", np.eye(4)))
        for el in room_layout(tuple(gt.layout["room_size"])):
            mesh = el.mesh.copy()
            mesh.apply_transform(transform)
            meshes.append((mesh, el.class_name, 0))
    for mesh, class_name, iid in meshes:
        scene.add_triangles(o3c.Tensor(mesh.vertices.astype(np.float32)), o3c.Tensor(mesh.faces.astype(np.uint32)))
        classes.append(gt.vocabulary.id(class_name))
        instances.append(iid)
    if not meshes or len(points) == 0:
        return np.full(len(points), VOID, np.int32), np.zeros(len(points), np.int32)
    query = o3c.Tensor(np.asarray(points, dtype=np.float32))
    closest = scene.compute_closest_points(query)
    gid = closest["geometry_ids"].numpy().astype(np.int64)
    dist = np.linalg.norm(closest["points"].numpy() - np.asarray(points, dtype=np.float32), axis=1)
    cls = np.asarray(classes, np.int32)[gid]
    inst = np.asarray(instances, np.int32)[gid]
    void = dist > max_distance
    cls[void] = VOID
    inst[void] = 0
    return cls, inst


def _segments(cls: np.ndarray, inst: np.ndarray, vocab: Vocabulary) -> np.ndarray:
    """A segment key per point: (class << 32 | instance) for things, (class << 32) for stuff, -1 for none."""
    is_thing = np.asarray(vocab.is_thing)[np.clip(cls, 0, len(vocab) - 1)]
    key = (cls.astype(np.int64) << 32) | np.where(is_thing, inst, 0).astype(np.int64)
    key[cls <= 0] = -1
    key[is_thing & (inst <= 0)] = -1  # a thing point without an instance belongs to no segment
    return key


def _pair_counts(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct (a, b) pairs and their counts (what ``np.unique(axis=0)`` gives, much faster)."""
    a_ids, a_inv = np.unique(a, return_inverse=True)
    b_ids, b_inv = np.unique(b, return_inverse=True)
    combo = a_inv.reshape(-1).astype(np.int64) * len(b_ids) + b_inv.reshape(-1)
    if len(a_ids) * len(b_ids) <= 4_000_000:
        counts = np.bincount(combo, minlength=len(a_ids) * len(b_ids))
        keys = np.flatnonzero(counts)
        counts = counts[keys]
    else:
        keys, counts = np.unique(combo, return_counts=True)
    return np.stack([a_ids[keys // len(b_ids)], b_ids[keys % len(b_ids)]], 1).reshape(-1, 2), counts


@dataclass
class SegmentCounts:
    """Segment sizes and overlaps of a labelling, summed over the parts it is added in (frames of
    one pooled image): what panoptic quality is computed from."""

    gt_size: Counter = field(default_factory=Counter)
    pred_size: Counter = field(default_factory=Counter)
    pred_void: Counter = field(default_factory=Counter)  # points of a predicted segment on void ground truth
    inter: Counter = field(default_factory=Counter)  # (pred segment, gt segment) -> shared points

    def add(
        self,
        pred_class: np.ndarray,
        pred_instance: np.ndarray,
        gt_class: np.ndarray,
        gt_instance: np.ndarray,
        vocab: Vocabulary,
    ) -> None:
        # plain arrays: labels derived from trimesh data arrive as TrackedArray, whose sort is slow
        pred_class, pred_instance, gt_class, gt_instance = (
            np.asarray(a).view(np.ndarray) for a in (pred_class, pred_instance, gt_class, gt_instance)
        )
        valid = gt_class != VOID
        gt_key = _segments(np.where(valid, gt_class, 0), gt_instance, vocab)
        pred_key = _segments(pred_class, pred_instance, vocab)
        self.gt_size.update(
            dict(zip(*(a.tolist() for a in np.unique(gt_key[gt_key >= 0], return_counts=True)), strict=True))
        )
        self.pred_size.update(
            dict(zip(*(a.tolist() for a in np.unique(pred_key[pred_key >= 0], return_counts=True)), strict=True))
        )
        self.pred_void.update(
            dict(
                zip(
                    *(a.tolist() for a in np.unique(pred_key[(pred_key >= 0) & ~valid], return_counts=True)),
                    strict=True,
                )
            )
        )
        both = (gt_key >= 0) & (pred_key >= 0)
        pairs, inter = _pair_counts(pred_key[both], gt_key[both])
        self.inter.update(dict(zip(map(tuple, pairs.tolist()), inter.tolist(), strict=True)))

    def quality(self, vocab: Vocabulary, iou_threshold: float = 0.5) -> dict[str, Any]:
        return _quality(self, vocab, iou_threshold)


def panoptic_quality(
    pred_class: np.ndarray,
    pred_instance: np.ndarray,
    gt_class: np.ndarray,
    gt_instance: np.ndarray,
    vocab: Vocabulary,
    iou_threshold: float = 0.5,
) -> dict[str, Any]:
    counts = SegmentCounts()
    counts.add(pred_class, pred_instance, gt_class, gt_instance, vocab)
    return counts.quality(vocab, iou_threshold)


def _quality(counts: SegmentCounts, vocab: Vocabulary, iou_threshold: float) -> dict[str, Any]:
    gt_size, pred_size, pred_void = counts.gt_size, counts.pred_size, counts.pred_void
    matched_pred: set[int] = set()
    matched_gt: set[int] = set()
    stats: dict[int, dict[str, float]] = defaultdict(lambda: {"tp": 0, "fp": 0, "fn": 0, "iou": 0.0})
    for (p, g), n in sorted(counts.inter.items()):
        if (p >> 32) != (g >> 32):
            continue
        union = pred_size[p] - pred_void.get(p, 0) + gt_size[g] - n
        iou = n / union if union > 0 else 0.0
        if iou > iou_threshold:
            matched_pred.add(p)
            matched_gt.add(g)
            c = g >> 32
            stats[c]["tp"] += 1
            stats[c]["iou"] += iou
    for g in gt_size:
        if g not in matched_gt:
            stats[g >> 32]["fn"] += 1
    for p, size in pred_size.items():
        if p not in matched_pred and pred_void.get(p, 0) <= 0.5 * size:
            stats[p >> 32]["fp"] += 1

    per_class = {}
    for c, s in sorted(stats.items()):
        denom = s["tp"] + 0.5 * s["fp"] + 0.5 * s["fn"]
        pq = s["iou"] / denom if denom else 0.0
        sq = s["iou"] / s["tp"] if s["tp"] else 0.0
        rq = s["tp"] / denom if denom else 0.0
        per_class[vocab.name(c)] = {
            "pq": pq,
            "sq": sq,
            "rq": rq,
            "tp": int(s["tp"]),
            "fp": int(s["fp"]),
            "fn": int(s["fn"]),
        }

    def mean(names: list[str], key: str) -> float | None:
        """Over the classes present; None (undefined, not 0) when no class of the kind is present."""
        return float(np.mean([per_class[n][key] for n in names])) if names else None

    things = [n for n in per_class if vocab.is_thing[vocab.id(n)]]
    stuff = [n for n in per_class if not vocab.is_thing[vocab.id(n)]]
    names = list(per_class)
    tp = sum(s["tp"] for s in stats.values())
    fp = sum(s["fp"] for s in stats.values())
    fn = sum(s["fn"] for s in stats.values())
    thing_tp = sum(per_class[n]["tp"] for n in things)
    thing_fp = sum(per_class[n]["fp"] for n in things)
    thing_fn = sum(per_class[n]["fn"] for n in things)
    return {
        "pq": mean(names, "pq"),
        "sq": mean(names, "sq"),
        "rq": mean(names, "rq"),
        "pq_things": mean(things, "pq"),
        "pq_stuff": mean(stuff, "pq"),
        "segments": {"tp": tp, "fp": fp, "fn": fn},
        "instances": {
            "precision": thing_tp / (thing_tp + thing_fp) if thing_tp + thing_fp else 0.0,
            "recall": thing_tp / (thing_tp + thing_fn) if thing_tp + thing_fn else 0.0,
        },
        "by_class": per_class,
    }
