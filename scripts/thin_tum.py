"""Keep N evenly spaced frames of a TUM RGB-D sequence, in the layout the ``tum`` source reads
(``rgb/``, ``depth/``, ``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, ``camera.json``).

The ``tum`` source reads a whole TUM folder as it is (``stride`` and ``max_frames`` thin it as it
reads); this makes a small copy to keep or share. The held-out office of configs/bench/real_rooms.yaml
is TUM fr1/rpy (CC BY 4.0, Sturm et al., IROS 2012; the sequence as TUM publishes it, also committed
whole in jmstark/gpu_odometry's ``data/``)::

    python scripts/thin_tum.py rgbd_dataset_freiburg1_rpy ../shared/data/tum_fr1_rpy --frames 200

Colour and depth are paired by the nearest timestamp within 0.02 s (as TUM's associate.py), only
pairs within the ground truth's time span are kept, and N of them are kept evenly spaced. Depth PNGs
are copied byte for byte; colour is re-encoded as JPEG (quality 95) to keep the copy small;
``groundtruth.txt`` is copied whole (the source interpolates it). ``camera.json`` holds TUM's
published colour intrinsics of the sequence's camera (``--freiburg``, else the folder's name). The
copy is written beside its destination and renamed when complete: a failed run leaves nothing
behind, and an existing folder is never overwritten.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from stratamap.plugins.sources.tum import TUM_CAMERAS, TUM_DEFAULT

#: Colour and depth closer in time than this (s) are one frame (the tum source's association_tolerance).
PAIR_TOLERANCE = 0.02


def _fail(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def _pairs(src: Path) -> list[tuple[float, str, float, str]]:
    """(depth time, depth file, colour time, colour file) of the frames the tum source would pair
    (core/io/rgbd.py's lists and association), within the poses' time span."""
    from stratamap.core.errors import DataError
    from stratamap.core.io.rgbd import associate, parse_tum_poses, read_timestamped_list

    try:
        rgb = read_timestamped_list(src / "rgb.txt", 1, "an image file name")
        depth = read_timestamped_list(src / "depth.txt", 1, "an image file name")
        times, _ = parse_tum_poses(src / "groundtruth.txt")
    except DataError as exc:
        _fail(str(exc))
    depth_t = np.array([t for t, _ in depth])
    pairs = [
        (depth_t[d], depth[d][1][0], rgb[r][0], rgb[r][1][0])
        for d, r in associate(depth_t, np.array([t for t, _ in rgb]), PAIR_TOLERANCE)
        if times[0] <= depth_t[d] <= times[-1]
    ]
    if not pairs:
        _fail(f"{src}: no colour and depth frames within {PAIR_TOLERANCE} s of each other inside the poses' time span")
    return pairs


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("src", type=Path, help="a TUM RGB-D sequence folder")
    parser.add_argument("out", type=Path, help="the folder to write (must not exist)")
    parser.add_argument("--frames", type=int, default=200, help="frames to keep, evenly spaced")
    parser.add_argument("--freiburg", choices=sorted(TUM_CAMERAS), help="the camera; default: from the folder's name")
    args = parser.parse_args(argv)
    from PIL import Image

    if not args.src.is_dir():
        _fail(f"{args.src}: not a folder")
    if args.out.exists():
        _fail(f"{args.out}: exists (never overwritten)")
    if args.frames < 1:
        _fail(f"--frames: expected 1 or more, got {args.frames}")
    camera = args.freiburg
    if camera is None:
        named = re.search(r"freiburg([123])", args.src.resolve().name)
        if named is None:
            _fail(f"{args.src}: its name says no freiburg1/2/3 camera; give --freiburg")
        camera = named.group(1)
    pairs = _pairs(args.src)
    keep = np.unique(np.round(np.linspace(0, len(pairs) - 1, min(args.frames, len(pairs)))).astype(int))
    pairs = [pairs[i] for i in keep]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{args.out.name}.", dir=args.out.parent))
    try:
        (work / "rgb").mkdir()
        (work / "depth").mkdir()
        rgb_lines, depth_lines = [], []
        for depth_time, depth_name, rgb_time, rgb_name in pairs:
            for name in (depth_name, rgb_name):
                if not (args.src / name).is_file():
                    _fail(f"{args.src / name}: listed but missing")
            colour = f"rgb/{Path(rgb_name).stem}.jpg"
            Image.open(args.src / rgb_name).convert("RGB").save(work / colour, quality=95)
            shutil.copyfile(args.src / depth_name, work / "depth" / Path(depth_name).name)
            rgb_lines.append(f"{rgb_time:.6f} {colour}")
            depth_lines.append(f"{depth_time:.6f} depth/{Path(depth_name).name}")
        head = f"# {len(pairs)} evenly spaced frames of {args.src.resolve().name} (scripts/thin_tum.py)\n"
        for listing, title, lines in (("rgb.txt", "color images", rgb_lines), ("depth.txt", "depth maps", depth_lines)):
            (work / listing).write_text(f"# {title}\n{head}# timestamp filename\n" + "\n".join(lines) + "\n")
        shutil.copyfile(args.src / "groundtruth.txt", work / "groundtruth.txt")
        cam = {**TUM_DEFAULT, **TUM_CAMERAS[camera]}
        (work / "camera.json").write_text(json.dumps(cam, indent=1) + "\n")
        work.rename(args.out)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    print(f"wrote {args.out}: {len(pairs)} frames")


if __name__ == "__main__":
    main()
