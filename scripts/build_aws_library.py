"""Write furniture of AWS RoboMaker's Gazebo worlds as a model library of meshes with ``classes.csv``,
one folder per class, for the tuning scenes configs/scenes/generalization/tuning/house_tune.yaml,
study_tune.yaml and galley_tune.yaml (issue 28).

The models come from two public repositories (MIT-0 licence: use, copy and modify without
attribution), made by neither stratamap's generator nor the sources of the generalization
benchmark (PartNet-Mobility, the IAI apartment, pybullet's data). Clone them first:

    git clone https://github.com/aws-robotics/aws-robomaker-small-house-world /tmp/small-house
    git clone https://github.com/aws-robotics/aws-robomaker-bookstore-world /tmp/bookstore
    python scripts/build_aws_library.py /tmp/small-house /tmp/bookstore      # writes out/aws_library/

Each model's COLLADA visual mesh is read with its unit (centimetres in these worlds) and up axis, its
faces coloured from its textures, and written as one PLY in metres, z up. Deterministic: the same
files for the same clones.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import trimesh

from stratamap.core.atomic import atomic_directory, check_output_folder
from stratamap.core.errors import DataError, StratamapError
from stratamap.core.library.models import NEUTRAL_ALBEDO, Y_UP_TO_Z_UP, mesh_face_colors

#: What this script writes beside the class folders: how an earlier output is recognised.
NOTICE = "LICENSE"

#: stratamap class -> the worlds' model names (folder ``models/<prefix><name>``). Chosen for what the
#: tuning scenes lack: other chairs and an armchair, tables and a desk, low and tall storage, a
#: display cube, a shoe rack, a fridge and a kitchen's counter.
MODELS: dict[str, list[str]] = {
    # SofaB is one seat 0.84 m wide: an armchair, a chair in stratamap's vocabulary.
    "chair": [
        "aws_robomaker_residential_ChairA_01",
        "aws_robomaker_residential_ChairD_01",
        "aws_robomaker_retail_ChairB_01",
        "aws_robomaker_residential_SofaB_01",
    ],
    "table": [
        "aws_robomaker_residential_KitchenTable_01",
        "aws_robomaker_residential_CoffeeTable_01",
        "aws_robomaker_residential_BalconyTable_01",
    ],
    "desk": ["aws_robomaker_residential_ReadingDesk_01"],
    # The bookstore's "BookshelfC" is a closed 0.86 m cube (a display unit): storage, by its shape.
    "cabinet": [
        "aws_robomaker_residential_NightStand_01",
        "aws_robomaker_residential_TVCabinet_01",
        "aws_robomaker_residential_Wardrobe_01",
        "aws_robomaker_retail_BookshelfC_01",
    ],
    # The shoe rack is open boards between two side frames: a shelf, by its shape.
    "shelf": ["aws_robomaker_residential_ShoeRack_01"],
    "fridge": ["aws_robomaker_residential_Refrigerator_01"],
    # An L of base units under one worktop (2.6 x 3.2 m, 0.6 m deep) with a double sink and its tap:
    # a kitchen's counter, its fixtures part of it.
    "counter": ["aws_robomaker_residential_KitchenCabinet_01"],
}


def find_model(sources: list[Path], name: str) -> Path:
    for source in sources:
        folder = source / "models" / name
        if folder.is_dir():
            return folder
    raise DataError(f"model {name!r} is in none of {', '.join(map(str, sources))} (models/{name})")


def visual_mesh(folder: Path) -> Path:
    meshes = sorted((folder / "meshes").glob("*_visual.[dD][aA][eE]"))
    if not meshes:
        raise DataError(f"{folder}/meshes: no *_visual.DAE")
    return meshes[0]


def convert(dae: Path) -> trimesh.Trimesh:
    """One mesh in metres, z up, with a colour per face."""
    import xml.etree.ElementTree as ET

    asset = ET.parse(dae).getroot().find("{*}asset")
    unit = asset.find("{*}unit") if asset is not None else None
    axis = asset.find("{*}up_axis") if asset is not None else None
    metres = float(unit.get("meter", 1.0)) if unit is not None else 1.0
    up = axis.text.strip() if axis is not None and axis.text else "Y_UP"  # COLLADA's default
    # The worlds keep textures in ../materials/textures/, outside the mesh folder.
    resolver = trimesh.resolvers.FilePathResolver(dae, allow_anywhere=True)
    scene = trimesh.load(dae, force="scene", resolver=resolver)
    parts = []
    for mesh in scene.dump():
        colors = mesh_face_colors(mesh)
        if colors is None:
            colors = np.tile(NEUTRAL_ALBEDO, (len(mesh.faces), 1))
        plain = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        plain.visual.face_colors = np.clip(np.round(np.asarray(colors)[:, :3] * 255), 0, 255).astype(np.uint8)
        parts.append(plain)
    out = trimesh.util.concatenate(parts)
    out.apply_scale(metres)
    if up == "Y_UP":
        out.apply_transform(Y_UP_TO_Z_UP)
    elif up != "Z_UP":
        raise DataError(f"{dae}: up axis {up} (expected Z_UP or Y_UP)")
    return out


def build(sources: list[Path], out: Path) -> list[Path]:
    """Convert every model of MODELS into ``out`` (replaced as a whole only once all are written)."""
    final = check_output_folder(out, lambda folder: (folder / NOTICE).is_file(), "model library")
    written = []
    with atomic_directory(final) as staging:
        for class_name, names in MODELS.items():
            folder = staging / class_name
            folder.mkdir()
            rows = []
            for name in names:
                mesh = convert(visual_mesh(find_model(sources, name)))
                mesh.export(folder / f"{name}.ply")
                rows.append({"file": f"{name}.ply", "class": class_name, "id": name, "scale": "1.0"})
                size = np.round(mesh.extents, 2).tolist()
                print(f"{class_name:8s} {name}: {len(mesh.faces)} faces, {size} m", file=sys.stderr)
                written.append(final / class_name / f"{name}.ply")
            with open(folder / "classes.csv", "w", newline="") as fh:
                writer = csv.DictWriter(fh, fieldnames=["file", "class", "id", "scale"])
                writer.writeheader()
                writer.writerows(rows)
        (staging / NOTICE).write_text(
            "Meshes converted from aws-robotics/aws-robomaker-small-house-world and\n"
            "aws-robotics/aws-robomaker-bookstore-world (MIT-0) by scripts/build_aws_library.py.\n"
        )
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sources", type=Path, nargs="+", help="Clones of the AWS RoboMaker world repositories.")
    parser.add_argument("--out", type=Path, default=Path("out/aws_library"), help="Library folder to write.")
    args = parser.parse_args(argv)
    try:
        build(args.sources, args.out)
    except StratamapError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
