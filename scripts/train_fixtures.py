"""Train the `fronts` completer's fixture classifier (handles and knobs) on RGB-D walks of procedural
kitchens.

Every candidate blob of every seen side of every storage object's height map
(:func:`stratamap.plugins.completers.fronts.fixture_model.fixture_candidates`, ``oracle`` instances,
``tsdf`` map, the frames' depth and colour as the stage reads them) is labelled from the scene's
models: a fixture where its centre lies on a handle's or a knob's parts (their box on the face,
grown by ``--reach``), else none. A gradient-boosting classifier over the candidates' features is
fitted and exported to ONNX (``models/fixtures.onnx`` and its sidecar ``models/fixtures.json``).

Only stratamap's own procedural kitchens (``configs/scenes/kitchen.yaml``) are used, at seeds 100
and up (the articulation benchmark's tuning walks are seeds 0-3; its held-out kitchens of
third-party models and the real recordings never enter). Needs ``pip install scikit-learn
skl2onnx`` (the ``train`` extra):

    python scripts/train_fixtures.py data --kitchens 16      # out/fixtures/candidates.npz, about 10 min
    python scripts/train_fixtures.py train                   # plugins/completers/fronts/models/fixtures.*

Deterministic for a seed: the walks, the candidates and the classifier are.
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "configs" / "scenes" / "kitchen.yaml"
OUT = REPO / "out" / "fixtures"
MODELS = REPO / "plugins" / "completers" / "fronts" / "models"
FIXTURE_PARTS = ("handle", "knob")


def true_fixtures(scene) -> list[np.ndarray]:
    """The world points of each handle and knob of the scene's storage and appliances (a handle's
    bar and posts together)."""
    from stratamap.core.map.priors import WITH_FRONTS

    groups: dict[tuple[int, str], list[np.ndarray]] = {}
    for k, obj in enumerate(scene.objects):
        if obj.class_name not in WITH_FRONTS:
            continue
        for part, mesh in obj.world_parts():
            if part.semantic in FIXTURE_PARTS:
                stem = part.name.rsplit("_bar", 1)[0].rsplit("_post", 1)[0]
                groups.setdefault((k, stem), []).append(np.asarray(mesh.vertices))
    return [np.concatenate(v) for v in groups.values()]


#: How a rendered frame's colour is made like a real Kinect's (``--degrade``): shifted off the depth
#: by up to this many pixels (unregistered colour, 1-3 cm at 2 m), blurred by a Gaussian of this
#: sigma range (pixels) and given this much noise (0-255 scale).
SHIFT_PIXELS = 4
BLUR_SIGMA = (0.6, 1.4)
NOISE_LEVEL = 5.0
#: A copy of each face reaches this much higher (m): a counter's box that holds what stands on its
#: worktop has its face reach above the worktop, and the worktop's lip is then inside the face.
RAISED_TOP = 0.2


def degraded(frame):
    """``frame`` with its colour as a real Kinect's: shifted, blurred and noisy (the same for the
    same frame index)."""
    from scipy import ndimage

    rng = np.random.default_rng(1000 + int(frame.index))
    dx, dy = rng.integers(-SHIFT_PIXELS, SHIFT_PIXELS + 1, size=2)
    rgb = np.roll(np.asarray(frame.rgb, np.float32), (int(dy), int(dx)), axis=(0, 1))
    rgb = ndimage.gaussian_filter(rgb, sigma=(*([rng.uniform(*BLUR_SIGMA)] * 2), 0))
    rgb += rng.normal(0.0, NOISE_LEVEL, rgb.shape).astype(np.float32)
    return replace(frame, rgb=np.clip(rgb, 0, 255).astype(np.uint8))


class DegradedStream:
    """A stream whose frames' colour is :func:`degraded`."""

    def __init__(self, stream):
        from stratamap.core.map.sensors import MappedFrames

        self.intrinsics = stream.intrinsics
        self.frames = MappedFrames(stream.frames, degraded)
        poses = getattr(stream.frames, "poses", None)
        self.frames.poses = poses if poses is not None else [f.pose for f in stream.frames]


def labels_of(cands, face, fixtures: list[np.ndarray], reach: float) -> np.ndarray:
    """1 where a candidate's centre lies on a true fixture of ``face`` (its box in face coordinates,
    grown by ``reach``), else 0."""
    boxes = []
    for pts in fixtures:
        h = pts @ face.normal + face.d
        if h.max() < -0.02 or h.min() > 0.12:
            continue
        u, z = pts @ face.u_axis, pts[:, 2]
        boxes.append((u.min() - reach, u.max() + reach, z.min() - reach, z.max() + reach))
    y = np.zeros(len(cands), np.int64)
    for i, c in enumerate(cands):
        cu, cz = c.center
        y[i] = int(any(b[0] <= cu <= b[1] and b[2] <= cz <= b[3] for b in boxes))
    return y


def kitchen_candidates(args: tuple[int, int, float, bool, bool]) -> tuple[np.ndarray, np.ndarray]:
    """(features, labels) of every candidate of one procedural kitchen walk, on each seen side of
    its storage objects and on the side raised by RAISED_TOP (and again with the colour
    :func:`degraded`, with ``degrade``)."""
    seed, frames, reach, degrade, varied = args
    from stratamap.core.config import validate
    from stratamap.core.map.priors import WITH_FRONTS
    from stratamap.core.map.sensors import sensor_viewpoints
    from stratamap.core.pipeline import Pipeline
    from stratamap.core.simulation.structure import floor_height
    from stratamap.core.synthetic.scene import generate_scene
    from stratamap.core.synthetic.spec import SceneSpec
    from stratamap.plugins.completers.fronts.face import find_faces
    from stratamap.plugins.completers.fronts.fixture_model import FEATURES, fixture_candidates
    from stratamap.plugins.completers.fronts.fronts import OBJECT_REACH, FaceParams
    from stratamap.plugins.completers.fronts.relief import CELL_MIN, FACE_CELL, frame_points, height_map

    spec = SceneSpec.from_yaml(SCENE).model_copy(update={"seed": seed, "varied_fixtures": varied})
    doc = {
        "source": {"plugin": "synthetic", "params": {"scene": spec.model_dump(mode="json"), "frames": frames}},
        "stages": [{"plugin": "oracle"}, {"plugin": "tsdf", "params": {"voxel_size": 0.02}}],
    }
    pipe = Pipeline(validate(doc, base_dir=REPO))
    with tempfile.TemporaryDirectory() as tmp:
        pipe.run(Path(tmp) / "run")
    data = pipe.data
    fixtures = true_fixtures(generate_scene(spec))
    cloud = np.asarray(data.map.geometry.points, float)
    views = sensor_viewpoints(data.stream, cloud)
    floor = floor_height(data.map)
    p = FaceParams()
    streams = [data.stream, DegradedStream(data.stream)] if degrade else [data.stream]
    X, y = [], []
    for inst in data.map.instances:
        if inst.class_name not in WITH_FRONTS:
            continue
        box = inst.box
        local = (cloud - box.center) @ box.pose[:3, :3]
        near_reach = np.asarray(box.size, float)[:2] / 2 + OBJECT_REACH
        near = (np.abs(local[:, 0]) <= near_reach[0]) & (np.abs(local[:, 1]) <= near_reach[1])
        near &= (cloud[:, 2] >= box.bottom_z - 0.02) & (cloud[:, 2] <= box.bottom_z + box.size[2] + 0.02)
        for found, _ in find_faces(box, cloud[near], views, p.min_coverage, floor):
            u0, u1, z0, z1 = found.rect
            for face, stream in itertools.product((found, replace(found, rect=(u0, u1, z0, z1 + RAISED_TOP))), streams):
                seen = frame_points(stream, face, p.max_frames, p.max_range)
                if seen is None or len(seen) < 1000:
                    continue
                hm = height_map(seen, face, FACE_CELL, CELL_MIN)
                cands = fixture_candidates(hm, p.standoff)
                if cands:
                    X.append(np.stack([c.features for c in cands]))
                    y.append(labels_of(cands, face, fixtures, reach))
    if not X:
        return np.zeros((0, len(FEATURES)), np.float32), np.zeros(0, np.int64)
    return np.concatenate(X).astype(np.float32), np.concatenate(y)


def make_data(args) -> None:
    seeds = list(range(100, 100 + args.kitchens))
    t0 = time.perf_counter()
    X, y, s = [], [], []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for seed, (xs, ys) in zip(
            seeds,
            pool.map(
                kitchen_candidates, [(k, args.frames, args.reach, args.degrade, args.varied_fixtures) for k in seeds]
            ),
            strict=True,
        ):
            X.append(xs)
            y.append(ys)
            s.append(np.full(len(ys), seed))
            print(
                f"kitchen {seed}: {len(ys)} candidates, {int(ys.sum())} fixtures ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
    OUT.mkdir(parents=True, exist_ok=True)
    np.savez(OUT / "candidates.npz", X=np.concatenate(X), y=np.concatenate(y), seed=np.concatenate(s))


def depth_blind(X: np.ndarray, y: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, ...]:
    """The candidates and a copy of each as a depth camera that does not resolve a 1 cm bar sees it
    (a real Kinect at 1.5-2.5 m: its correlation window smooths the bar into the face): no relief
    over the blob. The rendered walks' depth shows every bar; the copies teach the model the bars
    that only the colour shows."""
    from stratamap.plugins.completers.fronts.fixture_model import CANDIDATE_SHARE, DEPTH_FEATURES, FEATURES

    # Only what the colour lifts at all: a bar neither cue shows is not to be found.
    col = {name: X[:, FEATURES.index(name)] for name in ("light_max", "dark_max", "contrast_median")}
    coloured = (
        (col["light_max"] > CANDIDATE_SHARE)
        | (col["dark_max"] > CANDIDATE_SHARE)
        | (np.abs(col["contrast_median"]) > 0.03)
    )
    blind = X[coloured].copy()
    for name in DEPTH_FEATURES:
        blind[:, FEATURES.index(name)] = 0.0
    return np.concatenate([X, blind]), np.concatenate([y, y[coloured]]), np.concatenate([seeds, seeds[coloured]])


def classifier(seed: int):
    from sklearn.ensemble import GradientBoostingClassifier

    return GradientBoostingClassifier(
        n_estimators=200, max_depth=3, learning_rate=0.05, subsample=0.8, random_state=seed
    )


def train(args) -> None:
    from skl2onnx import to_onnx

    from stratamap.plugins.completers.fronts.fixture_model import FEATURES

    d = np.load(OUT / "candidates.npz")
    X, y, seeds = d["X"], d["y"], d["seed"]
    X, y, seeds = depth_blind(X, y, seeds)
    kitchens = np.unique(seeds)
    # Kitchens held out of the fit, to choose the threshold and report on.
    held = np.isin(seeds, kitchens[-args.held_out :])
    model = classifier(args.seed).fit(X[~held], y[~held])
    p = model.predict_proba(X[held])[:, 1]
    rows = []
    for t in (0.3, 0.4, 0.5, 0.6, 0.7):
        tp = int(((p >= t) & (y[held] == 1)).sum())
        prec = tp / max(1, int((p >= t).sum()))
        rec = tp / max(1, int((y[held] == 1).sum()))
        rows.append({"threshold": t, "precision": round(prec, 3), "recall": round(rec, 3)})
    print(json.dumps(rows))
    final = classifier(args.seed).fit(X, y)
    onx = to_onnx(final, X[:1], options={id(final): {"zipmap": False}}, target_opset=17)
    blob = onx.SerializeToString()
    MODELS.mkdir(parents=True, exist_ok=True)
    (MODELS / "fixtures.onnx").write_bytes(blob)
    importance = sorted(zip(FEATURES, final.feature_importances_.tolist(), strict=True), key=lambda kv: -kv[1])
    side = {
        "name": "stratamap fronts fixtures",
        "model": "fixtures.onnx",
        "sha256": hashlib.sha256(blob).hexdigest(),
        "features": list(FEATURES),
        "threshold": args.threshold,
        "trained_on": "RGB-D walks of procedural kitchens (configs/scenes/kitchen.yaml), not real recordings",
        "training": {
            "kitchens": f"seeds {int(kitchens.min())}-{int(kitchens.max())}",
            "candidates": int(len(y)),
            "fixtures": int(y.sum()),
            "classifier": "scikit-learn GradientBoostingClassifier(n_estimators=200, max_depth=3, "
            "learning_rate=0.05, subsample=0.8)",
        },
        "held_out": {"kitchens": [int(k) for k in kitchens[-args.held_out :]], "by_threshold": rows},
        "importance": {k: round(v, 4) for k, v in importance},
    }
    (MODELS / "fixtures.json").write_text(json.dumps(side, indent=1) + "\n")
    print(json.dumps(side["importance"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("step", choices=["data", "train"])
    parser.add_argument("--kitchens", type=int, default=16, help="Training kitchens (seeds 100, 101, ...).")
    parser.add_argument("--frames", type=int, default=80, help="Frames of each walk.")
    parser.add_argument(
        "--reach", type=float, default=0.03, help="How far (m) off a true fixture a candidate's centre may lie."
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--varied-fixtures",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="Give each kitchen model's handles and knobs a style of its own (SceneSpec.varied_fixtures).",
    )
    parser.add_argument(
        "--degrade",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="Also take each face's candidates with the frames' colour shifted, blurred and noisy, as a real Kinect's.",
    )
    parser.add_argument("--held-out", type=int, default=3, help="Kitchens left out of the fit to report on.")
    parser.add_argument("--threshold", type=float, default=0.5, help="The shipped model's fixture score threshold.")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    make_data(args) if args.step == "data" else train(args)


if __name__ == "__main__":
    main()
