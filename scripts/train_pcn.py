"""Train the ``pcn`` completer's network and export it to ONNX, seeded and reproducible.

Needs the ``train`` extra (torch, CPU build). Training data are partial views (Kinect noise,
self-occlusion, segmentation spill) of the *training-only* shape families of
``plugins/completers/pcn/training_shapes.py``; no family of ``core.synthetic.models.FAMILIES`` (the
families every benchmark scene is made of) is seen in training. The held-out Chamfer is measured on
those benchmark families (never used to choose anything) and written, with the training curve and
the provenance, into the JSON sidecar beside the ONNX file.

    .venv/bin/pip install torch==2.13.0
    .venv/bin/python scripts/train_pcn.py    # 1-5 + 11-29 minutes (data + 500 steps) on 2 shared cores
    .venv/bin/python scripts/train_pcn.py --out /tmp/pcn.onnx --compare plugins/completers/pcn/models/pcn.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

from stratamap.core.synthetic.models import FAMILIES, make_model
from stratamap.plugins.completers.pcn.data import (
    CLASSES,
    COARSE_POINTS,
    DENSE_POINTS,
    FOLD_GRID,
    INPUT_POINTS,
    make_example,
)
from stratamap.plugins.completers.pcn.training_shapes import TRAINING_FAMILIES, make_training_model

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "plugins" / "completers" / "pcn" / "models" / "pcn.onnx"
#: Seed of the held-out models (benchmark families), apart from scene seeds (0-9) and the matching library's (1000).
HELDOUT_SEED = 4242


def build_set(models: list[tuple[str, str, object]], views: int, seed: int) -> dict[str, np.ndarray]:
    """Examples of (name, class, mesh) triples, ``views`` sampled viewings each."""
    pts, truth, onehot, scale, vis, cls = [], [], [], [], [], []
    for k, (_name, class_name, mesh) in enumerate(models):
        rng = np.random.default_rng([seed, k])
        for _ in range(views):
            ex = make_example(mesh, class_name, rng)
            if ex is None:
                continue
            pts.append(ex.points)
            truth.append(ex.truth)
            onehot.append(ex.onehot)
            scale.append(ex.scale)
            vis.append(ex.visibility)
            cls.append(class_name)
    return {
        "points": np.stack(pts),
        "truth": np.stack(truth),
        "onehot": np.stack(onehot),
        "scale": np.asarray(scale, np.float32),
        "visibility": np.asarray(vis, np.float32),
        "classes": np.asarray(cls),
    }


def heldout_models(per_family: int) -> list[tuple[str, str, object]]:
    """Benchmark families whose class has a slot (others go to the class-agnostic slot)."""
    out = []
    for family, (class_name, _) in sorted(FAMILIES.items()):
        for i in range(per_family):
            model = make_model(family, HELDOUT_SEED, i)
            out.append((family, class_name if class_name in CLASSES else "other", model.mesh()))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=0, help="Seed of data, initialization and batch order.")
    ap.add_argument("--steps", type=int, default=500, help="Optimizer steps.")
    ap.add_argument("--batch", type=int, default=16, help="Examples per step.")
    ap.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate (halved at 60%% and 85%% of the steps).")
    ap.add_argument("--models-per-family", type=int, default=60, help="Training models per training family.")
    ap.add_argument("--views", type=int, default=3, help="Partial viewings per training model.")
    ap.add_argument("--heldout-per-family", type=int, default=3, help="Held-out models per benchmark family.")
    ap.add_argument("--threads", type=int, default=2, help="torch threads (fixed, for reproducibility).")
    ap.add_argument("--eval-every", type=int, default=100, help="Steps between held-out evaluations.")
    ap.add_argument(
        "--out", type=Path, default=DEFAULT_OUT, help="ONNX file to write (the JSON sidecar goes beside it)."
    )
    ap.add_argument(
        "--compare", type=Path, default=None, help="A sidecar JSON: fail unless held-out Chamfer is within 10%%."
    )
    args = ap.parse_args(argv)

    try:
        import torch
    except ImportError:
        print("train_pcn.py needs torch: .venv/bin/pip install torch==2.13.0 (the `train` extra)", file=sys.stderr)
        return 2
    from stratamap.plugins.completers.pcn.network import PCN, chamfer_l1

    torch.manual_seed(args.seed)
    torch.use_deterministic_algorithms(True)
    torch.set_num_threads(args.threads)
    t0 = time.time()
    train_models = [
        (family, class_name, make_training_model(family, args.seed, i).mesh())
        for family, (class_name, _) in TRAINING_FAMILIES.items()
        for i in range(args.models_per_family)
    ]
    train = build_set(train_models, args.views, args.seed)
    held = build_set(heldout_models(args.heldout_per_family), 1, HELDOUT_SEED + args.seed)
    data_seconds = time.time() - t0
    print(f"data: {len(train['points'])} training and {len(held['points'])} held-out examples in {data_seconds:.0f} s")

    net = PCN()
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    sched = torch.optim.lr_scheduler.MultiStepLR(opt, [int(args.steps * 0.6), int(args.steps * 0.85)], 0.5)
    tensors = {k: torch.from_numpy(v) for k, v in train.items() if k != "classes"}
    order_rng = np.random.default_rng([args.seed, 7])

    def evaluate() -> tuple[float, dict[str, float]]:
        """Held-out Chamfer-L1 in metres (the normalized distance times each object's scale)."""
        net.eval()
        per = []
        with torch.no_grad():
            for s in range(0, len(held["points"]), 32):
                _, dense = net(
                    torch.from_numpy(held["points"][s : s + 32]), torch.from_numpy(held["onehot"][s : s + 32])
                )
                truth = torch.from_numpy(held["truth"][s : s + 32])
                d = torch.cdist(dense, truth)
                cd = (d.min(2).values.mean(1) + d.min(1).values.mean(1)) / 2
                per.append(cd.numpy() * held["scale"][s : s + 32])
        net.train()
        per_m = np.concatenate(per)
        by_class = {c: float(per_m[held["classes"] == c].mean()) for c in sorted(set(held["classes"]))}
        return float(per_m.mean()), by_class

    curve: list[dict[str, float]] = []
    losses: list[float] = []
    t1 = time.time()
    batch_order = np.zeros(0, dtype=int)
    for step in range(1, args.steps + 1):
        if len(batch_order) < args.batch:
            batch_order = np.concatenate([batch_order, order_rng.permutation(len(train["points"]))])
        idx, batch_order = batch_order[: args.batch], batch_order[args.batch :]
        pts, truth, onehot = tensors["points"][idx], tensors["truth"][idx], tensors["onehot"][idx]
        coarse, dense = net(pts, onehot)
        # The dense term against every other true point: half the cost, the same optimum.
        loss = chamfer_l1(coarse, truth[:, :: FOLD_GRID**2]) + chamfer_l1(dense, truth[:, ::2])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        losses.append(loss.item())
        if step % 50 == 0:
            print(f"step {step}: loss {np.mean(losses[-50:]):.4f} ({time.time() - t1:.0f} s)", flush=True)
        if step % args.eval_every == 0 or step == args.steps:
            heldout, _ = evaluate()
            entry = {
                "step": step,
                "train_loss": float(np.mean(losses[-args.eval_every :])),
                "heldout_chamfer_l1_m": heldout,
                "seconds": time.time() - t1,
            }
            curve.append(entry)
            print(json.dumps(entry), flush=True)
    train_seconds = time.time() - t1
    heldout, heldout_by_class = evaluate()

    args.out.parent.mkdir(parents=True, exist_ok=True)
    net.eval()
    torch.onnx.export(
        net,
        (torch.zeros(1, INPUT_POINTS, 3), torch.zeros(1, len(CLASSES))),
        str(args.out),
        input_names=["points", "class_onehot"],
        output_names=["coarse", "dense"],
        dynamic_axes={name: {0: "batch"} for name in ("points", "class_onehot", "coarse", "dense")},
        opset_version=17,
        dynamo=False,
    )
    sidecar = {
        "name": "pcn: PCN-style point completion (PointNet encoder, coarse decoder, folding), class-conditioned",
        "model": args.out.name,
        "sha256": hashlib.sha256(args.out.read_bytes()).hexdigest(),
        "license": "Apache-2.0 (trained here from procedurally generated shapes; see LICENSE)",
        "classes": list(CLASSES),
        "class_agnostic_slot": "other",
        "inputs": {"points": ["batch", INPUT_POINTS, 3], "class_onehot": ["batch", len(CLASSES)]},
        "outputs": {"coarse": ["batch", COARSE_POINTS, 3], "dense": ["batch", DENSE_POINTS, 3]},
        "frame": (
            "points minus the object's base (box footprint centre at its support height), rotated by minus the box "
            "yaw, divided by the largest observed box extent"
        ),
        "training_families": {f: c for f, (c, _) in TRAINING_FAMILIES.items()},
        "heldout_families": sorted(FAMILIES),
        "heldout_note": (
            "every family of core.synthetic.models.FAMILIES (all generated benchmark scenes) and every third-party "
            "model of the generalization benchmark is held out; the held-out Chamfer is measured on FAMILIES models "
            f"(seed {HELDOUT_SEED})"
        ),
        "training": {
            "seed": args.seed,
            "steps": args.steps,
            "batch": args.batch,
            "lr": args.lr,
            "models_per_family": args.models_per_family,
            "views": args.views,
            "threads": args.threads,
            "examples": len(train["points"]),
            "heldout_examples": len(held["points"]),
            "data_seconds": round(data_seconds, 1),
            "train_seconds": round(train_seconds, 1),
            "torch": torch.__version__,
            "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
            "command": "python scripts/train_pcn.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        },
        "heldout_chamfer_l1_m": heldout,
        "heldout_chamfer_l1_m_by_class": heldout_by_class,
        "final_train_loss": float(np.mean(losses[-50:])),
        "curve": curve,
    }
    sidecar_path = args.out.with_suffix(".json")
    sidecar_path.write_text(json.dumps(sidecar, indent=2) + "\n")
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB) and {sidecar_path}")
    print(f"held-out Chamfer-L1 {heldout * 100:.2f} cm; training {train_seconds:.0f} s")
    if args.compare is not None:
        reference = json.loads(args.compare.read_text())["heldout_chamfer_l1_m"]
        ratio = heldout / reference
        print(f"held-out Chamfer {heldout:.5f} m vs {reference:.5f} m in {args.compare}: ratio {ratio:.3f}")
        if not 0.9 <= ratio <= 1.1:
            print("not reproduced within 10%", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
