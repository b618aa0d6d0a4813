"""Turn a Microsoft 7-Scenes sequence (``frame-XXXXXX.color.png|jpg``, ``frame-XXXXXX.depth.png`` in
millimetres with 65535 for no depth, ``frame-XXXXXX.pose.txt`` camera-to-world 4x4) into the TUM
layout the ``tum`` source reads: ``rgb/``, ``depth/``, ``rgb.txt``, ``depth.txt``, ``groundtruth.txt``
and a ``camera.json``.

The real kitchen of configs/bench/real_rooms.yaml is 7-Scenes' ``redkitchen`` as
andyzeng/tsdf-fusion-python ships it (``data/``, 1000 frames; 7-Scenes is licensed by Microsoft for
non-commercial research only: it is not in this repository)::

    python scripts/convert_7scenes.py tsdf-fusion-python/data ../shared/data/7scenes_redkitchen --frames 150

7-Scenes gives no colour calibration and its colour is not registered to its depth (the colour
camera's focal length is about 525 pixels, the depth camera's 585): ``camera.json`` holds the depth
camera's intrinsics, which is what the geometry needs; colour lies 10-25 pixels off the depth at the
image's edges. Timestamps are frame index / 30 Hz (7-Scenes has none). The output is written to a
temporary folder beside it and renamed when complete: a failed run leaves nothing behind, and an
existing folder is never overwritten.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

#: 7-Scenes' depth camera (Kinect v1), as the dataset and tsdf-fusion-python give it.
DEPTH_INTRINSICS = {"fx": 585.0, "fy": 585.0, "cx": 320.0, "cy": 240.0}
NO_DEPTH = 65535
FRAME_RATE = 30.0


def _fail(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def frames_of(folder: Path) -> list[tuple[int, Path, Path, Path]]:
    """(index, colour, depth, pose) of every complete frame, in index order."""
    out = []
    for depth in sorted(folder.glob("frame-*.depth.png")):
        stem = depth.name[: -len(".depth.png")]
        colour = next((p for p in (folder / f"{stem}.color.png", folder / f"{stem}.color.jpg") if p.exists()), None)
        pose = folder / f"{stem}.pose.txt"
        if colour is None or not pose.exists():
            _fail(f"{depth}: no colour image or pose.txt beside it (expected {stem}.color.png|jpg and {stem}.pose.txt)")
        try:
            index = int(stem.split("-", 1)[1])
        except ValueError:
            _fail(f"{depth}: expected a name frame-NNNNNN.depth.png")
        out.append((index, colour, depth, pose))
    if not out:
        _fail(f"{folder}: no frame-NNNNNN.depth.png files (a 7-Scenes sequence folder was expected)")
    return out


def read_pose(path: Path) -> np.ndarray:
    try:
        pose = np.loadtxt(path, dtype=np.float64)
    except ValueError as error:
        _fail(f"{path}: expected a 4x4 matrix of numbers ({error})")
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        _fail(f"{path}: expected a 4x4 camera-to-world matrix, got shape {pose.shape}")
    return pose


def convert(frames: list[tuple[int, Path, Path, Path]], out: Path) -> None:
    from PIL import Image
    from scipy.spatial.transform import Rotation

    (out / "rgb").mkdir(parents=True)
    (out / "depth").mkdir()
    rgb, depth, truth = [], [], []
    for index, colour_path, depth_path, pose_path in frames:
        stamp = f"{index / FRAME_RATE:.6f}"
        colour_name = f"rgb/{stamp}{colour_path.suffix}"
        shutil.copyfile(colour_path, out / colour_name)
        image = np.asarray(Image.open(depth_path))
        if image.dtype != np.uint16:
            _fail(f"{depth_path}: expected a 16-bit depth image in millimetres, got {image.dtype}")
        image = np.where(image == NO_DEPTH, 0, image).astype(np.uint16)
        Image.fromarray(image).save(out / f"depth/{stamp}.png")
        pose = read_pose(pose_path)
        qx, qy, qz, qw = Rotation.from_matrix(pose[:3, :3]).as_quat()
        rgb.append(f"{stamp} {colour_name}")
        depth.append(f"{stamp} depth/{stamp}.png")
        t = pose[:3, 3]
        truth.append(f"{stamp} {t[0]:.6f} {t[1]:.6f} {t[2]:.6f} {qx:.6f} {qy:.6f} {qz:.6f} {qw:.6f}")
    header = f"# converted from 7-Scenes by scripts/convert_7scenes.py; timestamp = frame index / {FRAME_RATE:g} Hz\n"
    (out / "rgb.txt").write_text(header + "\n".join(rgb) + "\n")
    (out / "depth.txt").write_text(header + "\n".join(depth) + "\n")
    (out / "groundtruth.txt").write_text(header + "# timestamp tx ty tz qx qy qz qw\n" + "\n".join(truth) + "\n")
    camera = {
        "width": 640,
        "height": 480,
        **DEPTH_INTRINSICS,
        "depth_scale": 1000.0,
        "note": "Microsoft 7-Scenes (Kinect v1): the depth camera's intrinsics; colour is not registered to depth; "
        "poses are camera-to-world from KinectFusion; non-commercial research use only (Microsoft's licence)",
    }
    (out / "camera.json").write_text(json.dumps(camera, indent=1) + "\n")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sequence", type=Path, help="a 7-Scenes sequence folder (frame-NNNNNN.* files)")
    parser.add_argument("out", type=Path, help="the TUM-layout folder to write (must not exist)")
    parser.add_argument("--frames", type=int, default=0, help="keep this many frames, evenly spaced (0: all)")
    args = parser.parse_args(argv)
    if not args.sequence.is_dir():
        _fail(f"{args.sequence}: not a folder")
    if args.out.exists():
        _fail(f"{args.out}: exists; choose a new folder (nothing is overwritten)")
    if args.frames < 0:
        _fail(f"--frames: expected 0 or more, got {args.frames}")
    frames = frames_of(args.sequence)
    if args.frames and args.frames < len(frames):
        keep = np.unique(np.round(np.linspace(0, len(frames) - 1, args.frames)).astype(int))
        frames = [frames[k] for k in keep]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{args.out.name}.", dir=args.out.parent))
    try:
        convert(frames, work / "sequence")
        (work / "sequence").rename(args.out)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"wrote {args.out}: {len(frames)} frames")


if __name__ == "__main__":
    main()
