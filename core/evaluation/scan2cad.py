"""CAD alignment scored by the Scan2CAD benchmark's rule (Avetisyan et al. 2019).

An annotated model is aligned when some completed object of the same category (its class mapped
to ShapeNet synsets by :data:`CLASS_SYNSETS`) has

* translation error <= 20 cm: the distance between the centres of the two models' boxes (a
  Scan2CAD ``trs`` places the CAD box's centre, ``center``; a completion's box is its model's);
* rotation error <= 20 degrees, the smallest over the turns about the up axis the annotation's
  ``sym`` allows (none; 2 or 4 turns; 36 for a round object, as the benchmark's script tries);
* scale error <= 20%: ``|mean(e / e_gt) - 1|`` over the three extents of the two boxes, each along
  its own model's axes (the annotated ones ``2 bbox`` times the ``trs`` scale). For the same
  ShapeNet model this is the script's ``mean(s / s_gt)``; for another model of the category it
  compares the sizes the two models are placed at.

Objects are taken in order of their confidence (then id), each aligning the first still
unaligned annotated model it passes, as the benchmark's script takes a method's alignments. The
scores: instance mean (aligned / annotated), class mean (the mean of the per-category accuracies,
categories as the benchmark names them: its eight most frequent, the rest "other").

Both sides are compared in the map's frame: the annotations (in the ScanNet scan's frame) are
taken through the source's ``world_transform`` (its gravity re-alignment), the ShapeNet frame (y
up) through the same turn to z up as the library loader's, so a completion's pose and an
annotation differ only by what the method got wrong.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import numpy as np

from stratamap.core.io.scan2cad import SYMMETRIES, AlignedModel
from stratamap.core.library.models import SHAPENET_CLASSES, Y_UP_TO_Z_UP

TRANSLATION_M = 0.2
ROTATION_DEG = 20.0
SCALE_PERCENT = 20.0

#: Scan2CAD's category names (its evaluation script's eight most frequent; every other is "other").
CATEGORIES = {
    "03211117": "display",
    "04379243": "table",
    "02808440": "bathtub",
    "02747177": "trashbin",
    "04256520": "sofa",
    "03001627": "chair",
    "02933112": "cabinet",
    "02871439": "bookshelf",
}

#: stratamap class -> the ShapeNet synsets its objects may align to: the library's own table, and
#: desks, which ShapeNet and Scan2CAD file under tables.
CLASS_SYNSETS: dict[str, tuple[str, ...]] = {
    **{c: tuple(s for s, k in SHAPENET_CLASSES.items() if k == c) for c in set(SHAPENET_CLASSES.values())},
    "desk": ("04379243",),
}


def category(catid: str) -> str:
    return CATEGORIES.get(catid, "other")


def _rz(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _angle_deg(r: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))


def _orthonormal(m: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    return r


def annotation_in_map(model: AlignedModel, world_transform: np.ndarray) -> dict[str, Any]:
    """An annotated model as the map sees it: box centre, rotation of its z-up model frame, extents
    along that frame's axes (metres)."""
    m = np.asarray(world_transform, float) @ model.cad_to_scan
    linear = m[:3, :3]
    scale = np.linalg.norm(linear, axis=0)
    rot_cad = linear / scale[None, :]
    to_z_up = Y_UP_TO_Z_UP[:3, :3]
    extents_cad = 2.0 * model.half_extents * scale
    return {
        "center": (m @ np.append(model.center, 1.0))[:3],
        "rotation": _orthonormal(rot_cad @ to_z_up.T),
        "extents": np.abs(to_z_up) @ extents_cad,
    }


def completion_in_map(instance: Any) -> dict[str, Any] | None:
    """A completed object's model box in the map: centre, rotation, extents (None if not completed)."""
    c = instance.completion
    if c is None or len(c.mesh.vertices) == 0:
        return None
    lo, hi = np.asarray(c.mesh.bounds, float)
    return {
        "center": (c.pose @ np.append((lo + hi) / 2.0, 1.0))[:3],
        "rotation": _orthonormal(c.pose[:3, :3]),
        "extents": hi - lo,
    }


def alignment_errors(pred: dict[str, Any], gt: dict[str, Any], sym: str) -> dict[str, float]:
    """Translation (m), rotation (degrees, best symmetry turn) and scale (%) errors of one pair."""
    turns = SYMMETRIES[sym]
    relative = pred["rotation"].T @ gt["rotation"]
    best_angle = min(_angle_deg(relative @ _rz(2.0 * np.pi * k / turns)) for k in range(turns))
    ratio = pred["extents"] / np.maximum(gt["extents"], 1e-9)
    return {
        "translation_m": float(np.linalg.norm(pred["center"] - gt["center"])),
        "rotation_deg": float(best_angle),
        "scale_percent": float(100.0 * abs(np.mean(ratio) - 1.0)),
    }


def passes(errors: dict[str, float]) -> bool:
    return (
        errors["translation_m"] <= TRANSLATION_M
        and errors["rotation_deg"] <= ROTATION_DEG
        and errors["scale_percent"] <= SCALE_PERCENT
    )


def evaluate_scan2cad(
    instances: Any, annotations: list[AlignedModel], world_transform: np.ndarray | None = None
) -> dict[str, Any]:
    """The Scan2CAD scores of one scan's completed objects; ``objects`` lists every annotated model
    with the object that aligned it (or None) and the errors of the closest candidate."""
    world = np.eye(4) if world_transform is None else np.asarray(world_transform, float)
    gts = [annotation_in_map(a, world) for a in annotations]
    preds = []
    for inst in sorted(instances or [], key=lambda i: (-float(i.score), int(i.id))):
        box = completion_in_map(inst)
        if box is not None:
            preds.append((inst, box))
    aligned_by: dict[int, int] = {}
    for inst, box in preds:
        synsets = CLASS_SYNSETS.get(inst.class_name, ())
        for g, a in enumerate(annotations):
            if g in aligned_by or a.catid not in synsets:
                continue
            if passes(alignment_errors(box, gts[g], a.sym)):
                aligned_by[g] = int(inst.id)
                break
    counts: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    objects = []
    for g, a in enumerate(annotations):
        name = category(a.catid)
        counts[name][1] += 1
        counts[name][0] += g in aligned_by
        candidates = [
            (inst, alignment_errors(box, gts[g], a.sym))
            for inst, box in preds
            if a.catid in CLASS_SYNSETS.get(inst.class_name, ())
        ]
        closest = min(candidates, key=lambda c: c[1]["translation_m"], default=None)
        objects.append(
            {
                "category": name,
                "catid": a.catid,
                "cad_id": a.cad_id,
                "sym": a.sym,
                "aligned_by": aligned_by.get(g),
                "closest": None if closest is None else {"instance": int(closest[0].id), **closest[1]},
            }
        )
    by_category = {
        name: {"aligned": good, "annotated": total, "accuracy": good / total}
        for name, (good, total) in sorted(counts.items())
    }
    return {
        **scores(by_category),
        "completed": len(preds),
        "by_category": by_category,
        "objects": objects,
    }


def scores(by_category: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Instance and class mean from per-category counts (``aligned``, ``annotated``)."""
    good = sum(c["aligned"] for c in by_category.values())
    total = sum(c["annotated"] for c in by_category.values())
    accuracies = [c["aligned"] / c["annotated"] for c in by_category.values() if c["annotated"]]
    return {
        "instance_mean": good / total if total else None,
        "class_mean": float(np.mean(accuracies)) if accuracies else None,
        "aligned": good,
        "annotated": total,
    }


def pooled(records: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per variant, the benchmark's scores over every scan of a bench's records (counts pooled, as
    the benchmark pools them: not the mean of per-scan accuracies)."""
    out: dict[str, dict[str, Any]] = {}
    for rec in records:
        family = rec.get("metrics", {}).get("scan2cad")
        if not family:
            continue
        variant = out.setdefault(rec["variant"], {"scans": 0, "by_category": {}})
        variant["scans"] += 1
        for name, c in family.get("by_category", {}).items():
            mine = variant["by_category"].setdefault(name, {"aligned": 0, "annotated": 0})
            mine["aligned"] += int(c["aligned"])
            mine["annotated"] += int(c["annotated"])
    for variant in out.values():
        for c in variant["by_category"].values():
            c["accuracy"] = c["aligned"] / c["annotated"] if c["annotated"] else None
        variant.update(scores(variant["by_category"]))
    return out


def write_pooled(records: list[dict[str, Any]], out: Any) -> Any:
    """``out/scan2cad.md`` and ``scan2cad.json``: :func:`pooled` per variant, a row per category;
    None (nothing written) when no record has the ``scan2cad`` family."""
    from pathlib import Path

    from stratamap.core.atomic import write_json, write_text

    scores_by_variant = pooled(records)
    if not scores_by_variant:
        return None
    out = Path(out)
    write_json(out / "scan2cad.json", scores_by_variant)

    def pct(value: float | None) -> str:
        return "-" if value is None else f"{100 * value:.1f}%"

    lines = ["# Scan2CAD alignment accuracy", ""]
    lines.append("Counts pooled over every scan, as the benchmark pools them (results.md averages per scan).")
    for variant, s in scores_by_variant.items():
        lines += ["", f"## {variant}", ""]
        lines.append(
            f"{s['scans']} scans: instance mean {pct(s['instance_mean'])} ({s['aligned']}/{s['annotated']}), "
            f"class mean {pct(s['class_mean'])}"
        )
        lines += ["", "| category | aligned | annotated | accuracy |", "|---|---|---|---|"]
        for name, c in s["by_category"].items():
            lines.append(f"| {name} | {c['aligned']} | {c['annotated']} | {pct(c['accuracy'])} |")
    return write_text(out / "scan2cad.md", "\n".join(lines) + "\n")
