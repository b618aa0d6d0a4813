"""Write the PCN training families (plugins/completers/pcn/training_shapes.py) as a model library of
meshes with ``classes.csv``, one folder per class, for the tuning scene
configs/scenes/generalization/tuning/kitchen_tune_families.yaml (issue 28).

Those families (kitchen islands, bar counters, sideboards, lockers, ...) are in no benchmark scene:
neither in the generator's FAMILIES nor among the generalization benchmark's third-party models. A
tuning scene made of them shows the kinds of furniture the reported kitchens hold (an island whose
worktop overhangs, a sideboard a box detector calls a table) without showing their models.

    python scripts/export_training_library.py                       # writes out/tuning_library/
    python scripts/export_training_library.py --out DIR --models 3

Deterministic: the same files for the same arguments.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import trimesh

from stratamap.plugins.completers.pcn.training_shapes import TRAINING_FAMILIES, make_training_model

#: The seed of the exported models (the training script's seeds start at 0; these are others).
SEED = 100


def export(out: Path, models_per_family: int, classes: list[str]) -> list[Path]:
    """One PLY (faces coloured by part) per model and a ``classes.csv`` in ``out/CLASS/``."""
    written = []
    for class_name in classes:
        families = sorted(name for name, (cls, _) in TRAINING_FAMILIES.items() if cls == class_name)
        if not families:
            raise SystemExit(f"--classes: no training family of class {class_name!r}")
        folder = out / class_name
        folder.mkdir(parents=True, exist_ok=True)
        rows = []
        for family in families:
            for k in range(models_per_family):
                model = make_training_model(family, SEED + k)
                meshes = []
                for part in model.parts:
                    mesh = trimesh.Trimesh(part.mesh.vertices, part.mesh.faces, process=False)
                    rgb = (np.clip(np.asarray(part.albedo, float), 0.0, 1.0) * 255).astype(np.uint8)
                    mesh.visual = trimesh.visual.ColorVisuals(
                        mesh, face_colors=np.tile(np.r_[rgb, 255], (len(mesh.faces), 1))
                    )
                    meshes.append(mesh)
                name = f"{family}_{k}.ply"
                trimesh.util.concatenate(meshes).export(folder / name)
                rows.append({"file": name, "class": class_name, "id": f"{family}_{k}", "scale": "1"})
                written.append(folder / name)
        with open(folder / "classes.csv", "w", newline="") as fh:
            writer = csv.DictWriter(fh, ["file", "class", "id", "scale"])
            writer.writeheader()
            writer.writerows(rows)
    return written


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("out/tuning_library"), help="Library folder to write.")
    parser.add_argument("--models", type=int, default=3, help="Models per family.")
    parser.add_argument("--classes", nargs="+", default=["counter", "cabinet"], help="Classes to export.")
    args = parser.parse_args()
    files = export(args.out, args.models, args.classes)
    print(f"wrote {len(files)} models to {args.out}")


if __name__ == "__main__":
    main()
