"""Train the `fronts` completer's front classifier on RGB-D walks of procedural kitchens.

The kitchen paper's level-2 CRF (door / drawer / appliance door / fixed panel over the graph of
neighbouring fronts; :mod:`stratamap.core.furniture.faces` features) refitted on the fronts that
the ``fronts`` stage itself cuts from height maps of RGB-D walks (``oracle`` instances, ``tsdf``
map), so that it learns what fronts look like through a depth camera instead of a laser scanner.
A front's label comes from the scene's own joints: the moving link that covers most of it (its
parts' box on the face), prismatic -> drawer, revolute -> door (appliance door on appliances),
none -> panel.

The shipped CRF uses only stratamap's own procedural kitchens (``configs/scenes/kitchen.yaml``, its
seeds): kitchens made of other people's models (IAI apartment, PartNet-Mobility) stay out for
evaluation (``configs/bench/articulation.yaml``). ``--also`` adds other scene files' walks to the
training data (never the benchmark's held-out models); ``--instances detector`` cuts the fronts
from ``configs/rgbd.yaml``'s own instances
(docs/experiments/2026-12-07-fronts-trained-on-the-pipelines-own-instances.md).

    python scripts/train_fronts.py --out plugins/completers/fronts/models   # about 10 minutes on 2 cores
    python scripts/train_fronts.py --instances detector --cache out/fronts --workers 2 --out out/fronts_detector
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "configs" / "scenes" / "kitchen.yaml"


def moving_parts(scene) -> list[dict]:
    """Every moving link of the scene's objects: its world box corners and its front's label."""
    from stratamap.core.map.priors import DOOR_APPLIANCES
    from stratamap.core.synthetic.models import ROOT_LINK

    out = []
    for obj in scene.objects:
        kinds = {j.child: j.type for j in obj.model.joints if j.type in ("revolute", "prismatic")}
        # A link's parts, and the parts of the links that hang from it (a drawer's front on its box).
        children: dict[str, list[str]] = {}
        for j in obj.model.joints:
            children.setdefault(j.parent, []).append(j.child)
        for link, kind in kinds.items():
            links, todo = set(), [link]
            while todo:
                cur = todo.pop()
                links.add(cur)
                todo.extend(children.get(cur, []))
            meshes = [part.mesh for part in obj.model.parts if part.link in links and part.link != ROOT_LINK]
            if not meshes:
                continue
            pts = np.concatenate([np.asarray(m.vertices) for m in meshes])
            world = pts @ obj.pose[:3, :3].T + obj.pose[:3, 3]
            label = (
                "drawer" if kind == "prismatic" else ("appliance" if obj.class_name in DOOR_APPLIANCES else "cupboard")
            )
            out.append({"points": world, "label": label})
    return out


def label_of(front, face, parts: list[dict]) -> str:
    """The label of the moving links covering most of ``front`` (face coordinates; a front cut too
    coarsely over two doors is a door), else panel."""
    u0, u1 = front.u_range
    z0, z1 = front.z_range
    area = max((u1 - u0) * (z1 - z0), 1e-6)
    cover: dict[str, float] = {}
    for part in parts:
        pts = part["points"]
        h = pts @ face.normal + face.d
        if h.max() < -0.06 or h.min() > 0.08:  # not on this face
            continue
        pu, pz = pts @ face.u_axis, pts[:, 2]
        ov = max(0.0, min(u1, pu.max()) - max(u0, pu.min())) * max(0.0, min(z1, pz.max()) - max(z0, pz.min()))
        cover[part["label"]] = cover.get(part["label"], 0.0) + ov / area
    label = max(cover, key=cover.get) if cover else "panel"
    return label if cover.get(label, 0.0) >= 0.5 else "panel"


#: The stages before ``fronts`` that make the instances it reads: the scenes' own (``oracle``), or
#: those of ``configs/rgbd.yaml`` (``detector``: boxes too large or too small, names wrong, a unit
#: split in two or joined to the next, as the stage meets them in use).
INSTANCE_STAGES = {
    "oracle": [{"plugin": "oracle"}, {"plugin": "tsdf", "params": {"voxel_size": 0.02}}],
    "detector": [
        {"plugin": "detector"},
        {"plugin": "tsdf", "params": {"voxel_size": 0.02, "instances": "masks"}},
        {"plugin": "clusters", "params": {"keep_instances": True, "recognize": True, "naming": "rules_then_model"}},
    ],
}


def kitchen_graphs(
    seed: int, frames: int, fixture_model: str | None = None, instances: str = "oracle", scene: Path = SCENE
) -> list[tuple]:
    """(X, E, relations, labels) of every face the ``fronts`` stage would cut in one procedural
    kitchen walk: storage objects' with ``oracle`` instances, every object's that the stage looks at
    (``may_have_fronts``) with ``detector`` ones."""
    from stratamap.core.config import validate
    from stratamap.core.furniture.faces import front_graph, level2_features
    from stratamap.core.map.priors import WITH_FRONTS
    from stratamap.core.map.sensors import sensor_viewpoints
    from stratamap.core.pipeline import Pipeline
    from stratamap.core.simulation.structure import floor_height, room_structure
    from stratamap.core.simulation.virtual_scan import LEVEL2
    from stratamap.core.synthetic.scene import generate_scene
    from stratamap.core.synthetic.spec import SceneSpec
    from stratamap.plugins.completers.fronts import may_have_fronts
    from stratamap.plugins.completers.fronts.fronts import FaceParams, observe_object

    doc = {
        "source": {"plugin": "synthetic", "params": {"scene_file": str(scene), "seed": seed, "frames": frames}},
        "stages": INSTANCE_STAGES[instances],
    }
    pipe = Pipeline(validate(doc, base_dir=REPO))
    with tempfile.TemporaryDirectory() as tmp:
        pipe.run(Path(tmp) / "run")
    data = pipe.data
    spec = SceneSpec.from_yaml(scene).model_copy(update={"seed": seed})
    parts = moving_parts(generate_scene(spec))
    cloud = np.asarray(data.map.geometry.points, float)
    views = sensor_viewpoints(data.stream, cloud)
    floor = floor_height(data.map)
    walls = [b for b in room_structure(data.map) if b.class_name == "wall"]  # as the stage chooses its faces
    graphs = []
    for inst in data.map.instances:
        if not (inst.class_name in WITH_FRONTS if instances == "oracle" else may_have_fronts(inst, None)):
            continue
        found = observe_object(
            inst.box, cloud, views, data.stream, floor, FaceParams(fixture_model=fixture_model), walls
        )
        if found is None or not found[2]:
            continue
        face, _, fronts = found
        y = np.array([LEVEL2.index(label_of(f, face, parts)) for f in fronts], np.int64)
        E, rel = front_graph(fronts)
        graphs.append((level2_features(fronts, floor), E, rel, y))
    return graphs


def cached_graphs(job: tuple) -> list[tuple]:
    """One walk's graphs, read from or written to the cache folder when there is one."""
    import pickle

    seed, frames, fixture_model, instances, cache, scene = job
    if cache is None:
        return kitchen_graphs(seed, frames, fixture_model, instances, scene)
    stem = "" if Path(scene) == SCENE else f"{Path(scene).stem}-"
    name = f"{stem}{instances}-{'model' if fixture_model else 'thresholds'}-{frames}-{seed}.pkl"
    path = Path(cache) / name
    if path.exists():
        return pickle.loads(path.read_bytes())
    graphs = kitchen_graphs(seed, frames, fixture_model, instances, scene)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.with_suffix(".tmp").write_bytes(pickle.dumps(graphs))
    path.with_suffix(".tmp").replace(path)
    return graphs


def walk_graphs(jobs: list[tuple], workers: int):
    """Each job's graphs, in the jobs' order (``workers`` processes at a time)."""
    if workers <= 1:
        yield from map(cached_graphs, jobs)
        return
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(workers) as pool:
        yield from pool.map(cached_graphs, jobs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "plugins" / "completers" / "fronts" / "models")
    parser.add_argument("--kitchens", type=int, default=24, help="Training kitchens (seeds 100, 101, ...).")
    parser.add_argument("--held-out", type=int, default=6, help="Evaluation kitchens (seeds 0, 1, ...).")
    parser.add_argument("--frames", type=int, default=80, help="Frames of each walk.")
    parser.add_argument("--l2", type=float, default=1.0, help="L2 prior on the node weights.")
    parser.add_argument("--edge-l2", type=float, default=1.0, help="L2 prior on the edge weights.")
    parser.add_argument(
        "--fixtures",
        choices=["model", "thresholds"],
        default="thresholds",
        help="How the fronts' handles and knobs are found (the stage's `fixtures`): thresholds (the shipped CRF's) "
        "or the fixture model.",
    )
    parser.add_argument(
        "--instances",
        choices=["oracle", "detector", "both"],
        default="oracle",
        help="Whose instances the fronts are cut from: the scenes' own (oracle), configs/rgbd.yaml's (detector), "
        "or both walks' fronts together.",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=None,
        help="Folder keeping each walk's fronts, so a refit does not map again (empty it after changing the code).",
    )
    parser.add_argument(
        "--also",
        type=Path,
        nargs="*",
        default=[],
        help="Scene files of more training kitchens (each walked with the same seeds as the procedural ones).",
    )
    parser.add_argument("--workers", type=int, default=1, help="Walks mapped at once (one process each).")
    args = parser.parse_args()

    from stratamap.core.furniture.crf import CRF
    from stratamap.core.furniture.faces import L2_RELATIONS, level2_feature_count
    from stratamap.core.simulation.virtual_scan import LEVEL2
    from stratamap.plugins.completers.fronts import SHIPPED_FIXTURES

    fixture_model = str(SHIPPED_FIXTURES) if args.fixtures == "model" else None
    kinds = ["oracle", "detector"] if args.instances == "both" else [args.instances]
    t0 = time.perf_counter()
    jobs = [
        (seed, args.frames, fixture_model, kind, args.cache, scene)
        for scene in [SCENE, *[p.resolve() for p in args.also]]
        for seed in range(100, 100 + args.kitchens)
        for kind in kinds
    ]
    train: list[tuple] = []
    for k, graphs in enumerate(walk_graphs(jobs, args.workers)):
        train += graphs
        done = sum(len(g[3]) for g in train)
        print(f"walk {k + 1}/{len(jobs)}: {done} fronts ({time.perf_counter() - t0:.0f} s)", flush=True)
    crf = CRF(LEVEL2, level2_feature_count(), len(L2_RELATIONS)).fit(train, args.l2, args.edge_l2)
    # Judged on the fronts the shipped pipeline cuts: the last kind listed.
    held_jobs = [(seed, args.frames, fixture_model, kinds[-1], args.cache, SCENE) for seed in range(args.held_out)]
    held = [g for graphs in walk_graphs(held_jobs, args.workers) for g in graphs]
    truth = np.concatenate([g[3] for g in held]) if held else np.zeros(0, np.int64)
    pred = np.concatenate([crf.predict(g[0], g[1], g[2]) for g in held]) if held else np.zeros(0, np.int64)
    per_label = {}
    for k, name in enumerate(LEVEL2):
        tp = int(((pred == k) & (truth == k)).sum())
        p, r = tp / max(1, int((pred == k).sum())), tp / max(1, int((truth == k).sum()))
        per_label[name] = {"precision": round(p, 3), "recall": round(r, 3), "support": int((truth == k).sum())}
    counts = np.bincount(np.concatenate([g[3] for g in train]), minlength=len(LEVEL2))
    doc = {
        "name": "stratamap fronts",
        "trained_on": "RGB-D walks of procedural kitchens (configs/scenes/kitchen.yaml), not real recordings",
        "level2": crf.to_dict(),
        "training": {
            "kitchens": f"seeds 100-{99 + args.kitchens}",
            "also": [p.name for p in args.also],
            "instances": args.instances,
            "frames": args.frames,
            "fixtures": args.fixtures,
            "fronts": {name: int(c) for name, c in zip(LEVEL2, counts, strict=True)},
            "l2": args.l2,
            "edge_l2": args.edge_l2,
        },
        "held_out": {
            "kitchens": f"seeds 0-{args.held_out - 1}",
            "instances": kinds[-1],
            "accuracy": round(float((pred == truth).mean()), 3) if len(truth) else None,
            "per_label": per_label,
        },
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "fronts_crf.json").write_text(json.dumps(doc) + "\n")
    print(json.dumps({"held_out": doc["held_out"], "seconds": round(time.perf_counter() - t0)}))


if __name__ == "__main__":
    main()
