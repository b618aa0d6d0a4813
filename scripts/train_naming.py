"""Train the naming model of ``clusters`` (``naming: model``, issue 65 step 4): a gradient-boosting
classifier over measured features of each instance (plugins/segmenters/clusters/features.py), exported
to ONNX for onnxruntime; the runtime never imports scikit-learn.

Data: fused maps of rendered walks through the tuning scenes (configs/scenes/generalization/tuning/,
seeds 0-11, at reduced frames and resolution) and one scene of the PartNet-Mobility models, with the
detector's votes. ``scripts/tune_walks.py`` computes and caches each walk's prefix (source, detector,
tsdf); the passes of ``clusters`` up to naming run on it; each instance is matched one to one to the
ground truth by 3D box IoU >= 0.25 (class-agnostic) for its label; an unmatched one that is a piece
of a true object (``holding_object``, overlapping it by ``--piece-iou``) takes that object's class,
else it is ``object``; it takes the library of the true object its box overlaps most. Never the benchmark scenes
(configs/scenes/generalization/office_3p.yaml, kitchen_3p.yaml) nor real recordings. Needs the
libraries first (scripts/export_training_library.py, scripts/build_aws_library.py) and, for training
only, ``pip install scikit-learn skl2onnx``:

    python scripts/train_naming.py walks                 # the walks' prefixes, cached in out/naming/cache
    python scripts/train_naming.py features              # out/naming/features.npz
    python scripts/train_naming.py evaluate              # leave-one-library-out table and confusion matrix
    python scripts/train_naming.py train                 # plugins/segmenters/clusters/models/naming.onnx + .json
    python scripts/train_naming.py compare               # rules vs model on the validation walks, full size

Deterministic for a seed (``--seed``, default 0): the walks, the features and the classifier are.
Validation seeds (4-7, as tune_walks.py's) are left out of the shipped model's training so that
``tune_walks.py score`` on them compares it with the rules fairly.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import pickle
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from stratamap.core.map.priors import UNNAMED

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "out" / "naming"
MODELS = ROOT / "plugins" / "segmenters" / "clusters" / "models"
TUNING = ROOT / "configs" / "scenes" / "generalization" / "tuning"
SEEDS = list(range(12))
VALIDATION_SEEDS = [4, 5, 6, 7]
#: The walks are rendered smaller than the tuning benchmark's (80 frames at 640 x 480): the machine
#: that trained the shipped model had two cores shared with others.
FRAMES, WIDTH, HEIGHT = 40, 320, 240
#: The model library of each ground-truth object, by a part of its library path; objects with no
#: library are the procedural generator's.
LIBRARIES = {
    "partnet_mobility": "partnet_mobility",
    "iai_apartment": "iai_apartment",
    "pybullet_data": "pybullet_data",
    "aws_library": "aws_robomaker",
    "tuning_library": "pcn_families",
}
PROCEDURAL = "procedural"
#: Instances no true object overlaps: trained on in every fold, tested in none.
NO_LIBRARY = "(none)"
#: The PartNet-Mobility models of the shared data are those the generalization benchmark's scenes are
#: made of: the leave-one-library-out table tests on them, the shipped model is not trained on them.
SHIPPED_WITHOUT = ("partnet_mobility",)
#: An instance no true object matches (IoU < 0.25) is a piece of the true object whose box, this much
#: wider (m), holds this share of its points: a chair seen as its backrest is labelled chair, as the
#: maps of real rooms show chairs whose seats the table hides.
PIECE_MARGIN = 0.03
PIECE_SHARE = 0.6


def tune_walks() -> Any:
    """scripts/tune_walks.py as a module (scripts/ is no package)."""
    spec = importlib.util.spec_from_file_location("tune_walks", ROOT / "scripts" / "tune_walks.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["tune_walks"] = module  # its worker processes find their functions by this name
    spec.loader.exec_module(module)
    return module


def partnet_scene(out: Path) -> Path:
    """The office tuning scene with PartNet-Mobility's chair and storage units in place of its own."""
    from stratamap.core.synthetic.spec import resolve_spec_paths

    doc = resolve_spec_paths(yaml.safe_load((TUNING / "office_tune.yaml").read_text()), TUNING)
    library = str(ROOT.parent / "shared" / "data" / "partnet_mobility")
    doc["objects"]["chair"] = {"count": 3, "library": {"path": library, "models": ["179"]}}
    doc["objects"]["cabinet"] = {"count": 3, "library": {"path": library, "models": ["40147", "45940", "41083"]}}
    path = out / "partnet_tune.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def write_bench(out: Path) -> Path:
    """The walks as a benchmark file of tune_walks.py: the tuning benchmark's scenes and pipeline, each
    scene at FRAMES frames of WIDTH x HEIGHT, plus the PartNet-Mobility scene; variants ``detector``
    (naming by rules) and ``model``."""
    tuning = yaml.safe_load((ROOT / "configs" / "bench" / "generalization_tuning.yaml").read_text())
    out.mkdir(parents=True, exist_ok=True)
    scenes = []
    for entry in tuning["scenes"]:
        syn = dict(entry["synthetic"], scene_file=str(TUNING / Path(entry["synthetic"]["scene_file"]).name))
        syn.update(seeds=SEEDS, frames=FRAMES, camera={"width": WIDTH, "height": HEIGHT})
        scenes.append({"synthetic": syn, "requires_path": str(ROOT / entry["requires_path"])})
    scenes.append(
        {
            "synthetic": {
                "scene_file": str(partnet_scene(out)),
                "seeds": SEEDS,
                "frames": FRAMES,
                "camera": {"width": WIDTH, "height": HEIGHT},
            },
            "requires_path": str(ROOT.parent / "shared" / "data" / "partnet_mobility"),
        }
    )
    doc = {
        "name": "naming_walks",
        "description": "Walks for the naming model of clusters (scripts/train_naming.py); never reported.",
        "per_scene": tuning["per_scene"],
        "physics": False,
        "scenes": scenes,
        "pipeline": tuning["pipeline"],
        "variants": [{"name": "detector"}, {"name": "model", "set": ["stages[2].params.naming=model"]}],
    }
    path = out / "walks.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def cmd_walks(args: argparse.Namespace) -> int:
    bench = write_bench(args.out)
    return tune_walks().main(["prefix", str(bench), "--cache", str(args.out / "cache"), "--workers", str(args.workers)])


def cmd_compare(args: argparse.Namespace) -> int:
    """Rules against the model on the tuning benchmark's own validation walks (seeds 4-7, 80 frames of
    640 x 480, as configs/bench/generalization_tuning.yaml renders them): tune_walks.py's prefix, then
    its score for the variants ``detector`` (naming by rules) and ``model``."""
    tuning = yaml.safe_load((ROOT / "configs" / "bench" / "generalization_tuning.yaml").read_text())
    for entry in tuning["scenes"]:
        entry["synthetic"]["scene_file"] = str(TUNING / Path(entry["synthetic"]["scene_file"]).name)
        entry["synthetic"]["seeds"] = VALIDATION_SEEDS
        entry["requires_path"] = str(ROOT / entry["requires_path"])
    tuning["variants"] = [{"name": "detector"}, {"name": "model", "set": ["stages[2].params.naming=model"]}]
    args.out.mkdir(parents=True, exist_ok=True)
    bench = args.out / "validation.yaml"
    bench.write_text(yaml.safe_dump(tuning, sort_keys=False))
    tw, cache = tune_walks(), str(args.out / "validation_cache")
    code = tw.main(["prefix", str(bench), "--cache", cache, "--workers", str(args.workers)])
    for variant in ("detector", "model"):
        print(f"== variant {variant} (naming: {'rules' if variant == 'detector' else 'model'})", flush=True)
        code = code or tw.main(["score", str(bench), "--variant", variant, "--cache", cache])
    return code


def walk_list(out: Path) -> list[dict[str, Any]]:
    """The walks of the benchmark file ``walks`` wrote, with where each one's prefix is cached."""
    tw = tune_walks()
    bench = out / "walks.yaml"
    if not bench.exists():
        raise SystemExit(f"error: {bench} not found: run `train_naming.py walks` first")
    spec, scenes, variant = tw.load(bench, "detector")
    for scene in scenes:
        scene["cache"] = tw.cache_file(out / "cache", scene, spec, variant, 2)
        scene["clusters"] = tw.bench.variant_document(spec, variant, scene["source"])["stages"][2]["params"]
    return scenes


def library_of(obj: Any) -> str:
    """The model library a ground-truth object was drawn from (LIBRARIES), else ``procedural``."""
    path = str(obj.params.get("library", ""))
    return next((name for key, name in LIBRARIES.items() if key in path), PROCEDURAL)


def vote_classes() -> list[str]:
    """The classes the features' vote and neighbour columns name: the default vocabulary's things."""
    from stratamap.core.map.vocabulary import Vocabulary

    vocab = Vocabulary.default()
    return [vocab.name(i) for i in vocab.thing_ids()]


def holding_object(points: np.ndarray, true_boxes: list[Any]) -> int | None:
    """The true object a piece of one belongs to: the one whose box (PIECE_MARGIN wider) holds
    PIECE_SHARE or more of the instance's points, the largest share first; None if none does."""
    if not len(points) or not true_boxes:
        return None
    shares = [float(b.contains(points, PIECE_MARGIN).mean()) for b in true_boxes]
    best = int(np.argmax(shares))
    return best if shares[best] >= PIECE_SHARE else None


def walk_rows(scene: dict[str, Any], classes: list[str]) -> dict[str, list[Any]]:
    """One walk's instances: features, label (the true class of the object matched one to one at 3D
    box IoU >= 0.25, else ``object``), its piece label (else the class of the true object it is a piece
    of, holding_object), library, and the class the rule passes give them."""
    from stratamap.core.evaluation.detection import match_boxes
    from stratamap.core.geometry.boxes import box_iou_3d, gravity_aligned_box
    from stratamap.plugins.segmenters.clusters import ClustersSegmenter
    from stratamap.plugins.segmenters.clusters.features import instance_features
    from stratamap.plugins.segmenters.clusters.passes import PASSES

    with open(scene["cache"], "rb") as fh:
        data = pickle.load(fh)
    seg = ClustersSegmenter(**scene["clusters"])
    lab = seg._labelling(data)
    order = list(seg.config.passes)
    cut = order.index("name_by_model")
    for name in order[:cut]:
        PASSES[name].run(lab)
    ids, features = instance_features(lab, classes)
    for name in order[cut + 1 :]:  # the rules' names of the same instances, for the comparison
        PASSES[name].run(lab)
    info = lab.thing_shapes()
    rules = [info[i][0] if i in info else UNNAMED for i in ids]
    boxes = [gravity_aligned_box(lab.points[lab.instance_ids == i]) for i in ids]
    truth = list(data.ground_truth.objects)
    true_boxes = [o.box() for o in truth]
    matches = dict(match_boxes([("x", b) for b in boxes], [("x", b) for b in true_boxes], center_threshold=0.0))
    labels, piece_labels, piece_iou, libraries = [], [], [], []
    for k, (i, box) in enumerate(zip(ids, boxes, strict=True)):
        if k in matches:
            labels.append(truth[matches[k]].class_name)
            piece_labels.append(labels[-1])
            piece_iou.append(box_iou_3d(box, true_boxes[matches[k]]))
            libraries.append(library_of(truth[matches[k]]))
            continue
        labels.append(UNNAMED)
        holder = holding_object(lab.points[lab.instance_ids == i], true_boxes)
        if holder is not None:
            piece_labels.append(truth[holder].class_name)
            piece_iou.append(box_iou_3d(box, true_boxes[holder]))
            libraries.append(library_of(truth[holder]))
            continue
        piece_labels.append(UNNAMED)
        piece_iou.append(0.0)
        overlap = [box_iou_3d(box, t) for t in true_boxes]
        libraries.append(library_of(truth[int(np.argmax(overlap))]) if overlap and max(overlap) > 0 else NO_LIBRARY)
    n = len(ids)
    return {
        "features": [features],
        "label": labels,
        "piece_label": piece_labels,
        "piece_iou": piece_iou,
        "library": libraries,
        "rules": rules,
        "walk": [scene["name"]] * n,
    }


def cmd_features(args: argparse.Namespace) -> int:
    from stratamap.plugins.segmenters.clusters.features import feature_names

    classes = vote_classes()
    scenes = [s for s in walk_list(args.out) if s["cache"].exists()]
    if not scenes:
        raise SystemExit("error: no cached walk: run `train_naming.py walks` first")
    table: dict[str, list[Any]] = {}
    rows = args.out / "rows"
    rows.mkdir(parents=True, exist_ok=True)
    for scene in scenes:
        # Each walk's rows are kept, so that a second run adds only the walks cached since.
        done = rows / f"{scene['cache'].stem}.pkl"
        if done.exists() and not args.rebuild:
            found = pickle.loads(done.read_bytes())
        else:
            found = walk_rows(scene, classes)
            done.write_bytes(pickle.dumps(found))
        for key, values in found.items():
            table.setdefault(key, []).extend(values)
        print(f"{scene['name']}: {len(table['label'])} instances so far", flush=True)
    np.savez(
        args.out / "features.npz",
        X=np.concatenate(table["features"]).astype(np.float32),
        names=np.array(feature_names(classes)),
        vote_classes=np.array(classes),
        **{k: np.array(table[k]) for k in ("label", "piece_label", "piece_iou", "library", "rules", "walk")},
    )
    counts = Counter(zip(table["library"], table["label"], strict=True))
    print(f"{len(table['label'])} instances of {len(scenes)} walks -> {args.out / 'features.npz'}")
    for (library, label), count in sorted(counts.items()):
        print(f"  {library:18s} {label:10s} {count}")
    return 0


def load_features(out: Path) -> dict[str, np.ndarray]:
    path = out / "features.npz"
    if not path.exists():
        raise SystemExit(f"error: {path} not found: run `train_naming.py features` first")
    return dict(np.load(path))


def labels_of(data: dict[str, np.ndarray], rule: str, piece_iou: float) -> np.ndarray:
    """The training labels: ``matched`` (one to one at box IoU >= 0.25, else ``object``) or ``pieces``
    (an unmatched instance takes the class of the true object it is a piece of when its box overlaps
    that object's by ``piece_iou`` or more: a backrest, not a stray leg)."""
    if rule == "matched":
        return data["label"]
    if "piece_iou" not in data:
        raise SystemExit("error: features.npz has no piece labels: run `train_naming.py features --rebuild`")
    return np.where(data["piece_iou"] >= piece_iou, data["piece_label"], data["label"])


def is_validation(walk: str) -> bool:
    return int(walk.rsplit("-s", 1)[1]) in VALIDATION_SEEDS


def classifier(seed: int) -> Any:
    """The classifier: gradient-boosted trees (deterministic for ``seed``: no subsampling)."""
    from sklearn.ensemble import GradientBoostingClassifier

    return GradientBoostingClassifier(n_estimators=150, max_depth=3, learning_rate=0.1, random_state=seed)


def balanced(labels: np.ndarray) -> np.ndarray:
    """Sample weights giving each class the same total weight (the catch-all class outnumbers furniture)."""
    classes, inverse, counts = np.unique(labels, return_inverse=True, return_counts=True)
    return (len(labels) / (len(classes) * counts))[inverse]


def fit(features: np.ndarray, labels: np.ndarray, names: np.ndarray, seed: int) -> Any:
    """The classifier fitted to the rows and to a copy of them without rays (seen_through -1, rays 0),
    as a scan or a point cloud gives them: the walks all had depth frames."""
    rayless = features.copy()
    rayless[:, list(names).index("seen_through")] = -1.0
    rayless[:, list(names).index("rays")] = 0.0
    both, twice = np.concatenate([features, rayless]), np.concatenate([labels, labels])
    from threadpoolctl import threadpool_limits

    # One thread: scikit-learn's losses sum over OpenMP threads, whose order a busy machine changes.
    with threadpool_limits(limits=1):
        return classifier(seed).fit(both, twice, sample_weight=balanced(twice))


def macro_f1(truth: np.ndarray, given: np.ndarray) -> float:
    """F1 averaged over the classes of ``truth``."""
    scores = []
    for c in np.unique(truth):
        tp = float(np.sum((truth == c) & (given == c)))
        p, r = tp / max(1, np.sum(given == c)), tp / max(1, np.sum(truth == c))
        scores.append(2 * p * r / (p + r) if p + r else 0.0)
    return float(np.mean(scores)) if scores else float("nan")


def thresholded(model: Any, features: np.ndarray, threshold: float) -> np.ndarray:
    """The model's classes, ``object`` where the best score is below ``threshold`` (as the pass names)."""
    probs = model.predict_proba(features)
    names = model.classes_[probs.argmax(1)]
    return np.where(probs.max(1) >= threshold, names, UNNAMED)


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Leave-one-library-out: per library, train on every other library's instances, test on its own."""
    data = load_features(args.out)
    X, y, lib, rules = data["X"], labels_of(data, args.labels, args.piece_iou), data["library"], data["rules"]
    # Instances matched to a true object one to one: what the benchmarks' class-aware figures score,
    # whichever labels the model was trained on.
    matched = data["label"] != UNNAMED
    libraries = sorted(set(lib) - {NO_LIBRARY})
    predicted = np.full(len(y), "", dtype=object)
    print(f"leave-one-library-out, {len(y)} instances, labels {args.labels}, naming_threshold {args.threshold:g}")
    print(
        "| held-out library | instances | classes | model accuracy | model macro F1 | rules accuracy | rules macro F1 "
        "| matched: model accuracy | matched: rules accuracy |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for held in [*libraries, None]:
        test = lib == held if held else lib != NO_LIBRARY
        if held:
            model = fit(X[~test], y[~test], data["names"], args.seed)
            predicted[test] = thresholded(model, X[test], args.threshold)
        given, m = predicted[test].astype(str), matched[test]
        classes = ", ".join(f"{c} {n}" for c, n in sorted(Counter(y[test]).items())) if held else ""
        print(
            f"| {held or 'all (pooled)'} | {int(test.sum())} | {classes} | {np.mean(given == y[test]):.3f} "
            f"| {macro_f1(y[test], given):.3f} | {np.mean(rules[test] == y[test]):.3f} "
            f"| {macro_f1(y[test], rules[test]):.3f} | {np.mean(given[m] == data['label'][test][m]):.3f} "
            f"| {np.mean(rules[test][m] == data['label'][test][m]):.3f} |"
        )
    tested = lib != NO_LIBRARY
    for title, given in (
        ("model (each library predicted by the model trained without it)", predicted),
        ("rules", rules),
    ):
        names = sorted(set(y[tested]) | set(given[tested].astype(str)))
        print(f"\nconfusion, {title}: rows true, columns given\n")
        print("| true \\ given | " + " | ".join(names) + " |")
        print("|---" * (len(names) + 1) + "|")
        for t in names:
            row = [int(np.sum((y[tested] == t) & (given[tested] == g))) for g in names]
            if sum(row):
                print(f"| {t} | " + " | ".join(str(v) for v in row) + " |")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    """The shipped model: every library but SHIPPED_WITHOUT, the tuning seeds only, as ONNX + sidecar."""
    import hashlib

    from skl2onnx import to_onnx

    data = load_features(args.out)
    X, y, lib, walk = data["X"], labels_of(data, args.labels, args.piece_iou), data["library"], data["walk"]
    keep = ~np.isin(lib, SHIPPED_WITHOUT) & ~np.array([is_validation(w) for w in walk])
    model = fit(X[keep], y[keep], data["names"], args.seed)
    onx = to_onnx(model, X[:1], options={id(model): {"zipmap": False}}, target_opset=17)
    blob = onx.SerializeToString()
    MODELS.mkdir(parents=True, exist_ok=True)
    (MODELS / "naming.onnx").write_bytes(blob)
    counts = Counter(zip(lib[keep].tolist(), y[keep].tolist(), strict=True))
    side = {
        "name": "clusters naming model: gradient-boosted trees over measured instance features",
        "model": "naming.onnx",
        "sha256": hashlib.sha256(blob).hexdigest(),
        "classes": [str(c) for c in model.classes_],
        "vote_classes": [str(c) for c in data["vote_classes"]],
        "features": [str(c) for c in data["names"]],
        "trained_on": {f"{a}/{b}": n for (a, b), n in sorted(counts.items())},
        "command": "python scripts/train_naming.py walks && python scripts/train_naming.py features && "
        f"python scripts/train_naming.py train --seed {args.seed} --labels {args.labels} "
        f"--piece-iou {args.piece_iou:g}",
        "seed": args.seed,
        "labels": args.labels,
        "piece_iou": args.piece_iou,
    }
    (MODELS / "naming.json").write_text(json.dumps(side, indent=2) + "\n")
    check = model.predict_proba(X[keep][:50])
    from stratamap.plugins.segmenters.clusters.model import NamingModel

    runtime = NamingModel(MODELS / "naming.json").scores(X[keep][:50])
    print(
        f"trained on {int(keep.sum())} instances; onnxruntime vs scikit-learn: "
        f"max |diff| {np.abs(check - runtime).max():.2e}"
    )
    print(f"wrote {MODELS / 'naming.onnx'} and {MODELS / 'naming.json'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("command", choices=["walks", "features", "evaluate", "train", "compare"])
    parser.add_argument("--out", type=Path, default=OUT, help="Work folder (default out/naming).")
    parser.add_argument("--workers", type=int, default=1, help="walks: walks rendered side by side.")
    parser.add_argument("--seed", type=int, default=0, help="The classifier's random seed.")
    parser.add_argument("--rebuild", action="store_true", help="features: measure every walk again.")
    parser.add_argument(
        "--threshold", type=float, default=0.4, help="evaluate: naming_threshold (below it: object; default 0.4)."
    )
    parser.add_argument(
        "--labels",
        choices=["matched", "pieces"],
        default="pieces",
        help="evaluate, train: labels matched one to one only, or pieces of a true object too (default).",
    )
    parser.add_argument(
        "--piece-iou",
        type=float,
        default=0.05,
        help="evaluate, train: a piece's least box IoU with its object for its label (default 0.05).",
    )
    args = parser.parse_args(argv)
    commands = {
        "walks": cmd_walks,
        "features": cmd_features,
        "evaluate": cmd_evaluate,
        "train": cmd_train,
        "compare": cmd_compare,
    }
    return commands[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
