"""Reading RGB-D sequences from disk, with errors that name the file and what was expected.

Shared by the ``tum``, ``redwood`` and ``scannet`` sources: image readers that check dtypes and
sizes, timestamp association and pose interpolation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError
from scipy.spatial.transform import Rotation, Slerp

from stratamap.core.errors import DataError
from stratamap.core.map.sensors import SensorStream


def read_image(path: Path) -> np.ndarray:
    if not path.is_file():
        raise DataError(f"{path}: image file missing")
    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("I;16", "I;16B", "I;16L"):
                return np.asarray(im, dtype=np.uint16)
            if im.mode == "I":
                return np.asarray(im, dtype=np.int32)
            if im.mode == "F":
                return np.asarray(im, dtype=np.float32)
            return np.asarray(im)
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise DataError(f"{path}: cannot be read as an image ({exc})") from exc


def read_rgb(path: Path, shape: tuple[int, int] | None = None) -> np.ndarray:
    img = read_image(path)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise DataError(f"{path}: expected an RGB image, got shape {img.shape}")
    img = img[..., :3]
    if img.dtype != np.uint8:
        if img.dtype == np.uint16:
            img = (img >> 8).astype(np.uint8)
        else:
            raise DataError(f"{path}: expected 8-bit color, got {img.dtype}")
    if shape is not None and img.shape[:2] != shape:
        # Some datasets (ScanNet) ship larger color images than depth: resample to the depth grid.
        img = np.asarray(Image.fromarray(img).resize((shape[1], shape[0]), Image.BILINEAR))
    return img


def read_depth(path: Path, depth_scale: float, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Metric float32 depth from a 16-bit PNG (units per metre = ``depth_scale``) or a float image
    already in metres; NaN, inf and negative values become 0 (no measurement)."""
    img = read_image(path)
    if img.ndim != 2:
        raise DataError(f"{path}: depth must be single-channel, got shape {img.shape} (is this a color image?)")
    if img.dtype == np.uint8:
        raise DataError(f"{path}: depth is 8-bit; expected 16-bit integers ({depth_scale:g} per metre) or float metres")
    if np.issubdtype(img.dtype, np.integer):
        depth = img.astype(np.float32) / np.float32(depth_scale)
    else:
        depth = img.astype(np.float32)
        finite = depth[np.isfinite(depth) & (depth > 0)]
        if finite.size and np.median(finite) > 100:
            raise DataError(
                f"{path}: float depth with median {np.median(finite):.0f}: looks like millimetres or raw units, "
                "expected metres"
            )
    depth[~np.isfinite(depth) | (depth < 0)] = 0.0
    if shape is not None and depth.shape != shape:
        raise DataError(
            f"{path}: depth is {depth.shape[1]}x{depth.shape[0]}, expected {shape[1]}x{shape[0]} (rgb/depth size "
            "mismatch?)"
        )
    return depth


def check_depth_scale(depth: np.ndarray, path: Path, depth_scale: float, max_plausible: float = 20.0) -> None:
    """Catch a wrong depth scale early: indoor depth in metres has a median between ~0.2 and 20 m."""
    valid = depth[depth > 0]
    if valid.size == 0:
        return
    med = float(np.median(valid))
    if med > max_plausible or med < 0.05:
        raise DataError(
            f"{path}: median depth is {med:.3g} m with depth_scale {depth_scale:g}; this looks like the wrong depth "
            "scale "
            f"(TUM uses 5000, Redwood/ScanNet 1000 units per metre)"
        )


def read_timestamped_list(path: Path) -> list[tuple[float, list[str]]]:
    """Lines ``timestamp rest...`` (TUM lists); comments (#) skipped; timestamps must increase."""
    if not path.is_file():
        raise DataError(f"{path}: file missing")
    rows = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            t = float(parts[0])
        except ValueError:
            raise DataError(f"{path}:{n}: expected a timestamp, got {parts[0]!r}") from None
        rows.append((t, parts[1:]))
    if not rows:
        raise DataError(f"{path}: no entries")
    times = np.array([r[0] for r in rows])
    bad = np.flatnonzero(np.diff(times) <= 0)
    if len(bad):
        raise DataError(
            f"{path}: timestamps are not increasing at entry {bad[0] + 2} ({times[bad[0]]} then {times[bad[0] + 1]})"
        )
    return rows


def associate(a: np.ndarray, b: np.ndarray, tolerance: float) -> list[tuple[int, int]]:
    """Pairs (i, j) of nearest timestamps within ``tolerance``, each used once (TUM's associate.py rule)."""
    pairs = []
    if len(b) == 0:
        return pairs
    idx = np.clip(np.searchsorted(b, a), 1, len(b) - 1) if len(b) > 1 else np.zeros(len(a), int)
    used = set()
    candidates = []
    for i, t in enumerate(a):
        for j in {int(idx[i]), int(max(idx[i] - 1, 0))}:
            d = abs(b[j] - t)
            if d <= tolerance:
                candidates.append((d, i, j))
    taken_a: set[int] = set()
    for _distance, i, j in sorted(candidates):
        if i in taken_a or j in used:
            continue
        taken_a.add(i)
        used.add(j)
        pairs.append((i, j))
    return sorted(pairs)


def parse_tum_poses(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps and (N, 4, 4) poses from ``timestamp tx ty tz qx qy qz qw`` lines."""
    rows = read_timestamped_list(path)
    times, poses = [], []
    for n, (t, vals) in enumerate(rows):
        if len(vals) != 7:
            raise DataError(
                f"{path}: entry {n + 1} has {len(vals)} values after the timestamp, expected 7 (tx ty tz qx qy qz qw)"
            )
        v = np.array([float(x) for x in vals])
        if not np.all(np.isfinite(v)) or np.linalg.norm(v[3:]) < 1e-6:
            raise DataError(f"{path}: entry {n + 1} is not a valid pose ({vals})")
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_quat(v[3:] / np.linalg.norm(v[3:])).as_matrix()
        pose[:3, 3] = v[:3]
        times.append(t)
        poses.append(pose)
    return np.array(times), np.array(poses)


def interpolate_poses(
    times: np.ndarray, poses: np.ndarray, query: np.ndarray, tolerance: float
) -> list[np.ndarray | None]:
    """Poses at ``query`` times: linear/slerp between neighbours, or the nearest within ``tolerance``."""
    out: list[np.ndarray | None] = []
    if len(times) == 1:
        return [poses[0].copy() if abs(q - times[0]) <= tolerance else None for q in query]
    slerp = Slerp(times, Rotation.from_matrix(poses[:, :3, :3]))
    for q in query:
        if times[0] <= q <= times[-1]:
            j = int(np.clip(np.searchsorted(times, q), 1, len(times) - 1))
            if (
                min(q - times[j - 1], times[j] - q) > max(tolerance, 0.5 * (times[j] - times[j - 1]))
                and times[j] - times[j - 1] > 2 * tolerance
            ):
                out.append(None)  # a gap in the ground truth
                continue
            w = (q - times[j - 1]) / (times[j] - times[j - 1])
            pose = np.eye(4)
            pose[:3, :3] = slerp([q]).as_matrix()[0]
            pose[:3, 3] = (1 - w) * poses[j - 1, :3, 3] + w * poses[j, :3, 3]
            out.append(pose)
        else:
            k = 0 if q < times[0] else len(times) - 1
            out.append(poses[k].copy() if abs(q - times[k]) <= tolerance else None)
    return out


def read_laser_file(path: Path) -> list:
    """2D laser scans from ``laser.txt``: ``timestamp x y z yaw angle_min angle_increment range_max r...``."""
    from stratamap.core.geometry.transforms import make_pose
    from stratamap.core.map.sensors import LaserScan

    scans = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        vals = line.split()
        if len(vals) < 9:
            raise DataError(f"{path}:{n}: expected timestamp x y z yaw angle_min angle_increment range_max and ranges")
        try:
            head = [float(v) for v in vals[:8]]
            ranges = np.array([float(v) for v in vals[8:]], dtype=np.float32)
        except ValueError as exc:
            raise DataError(f"{path}:{n}: {exc}") from None
        t, x, y, z, yaw, amin, ainc, rmax = head
        scans.append(LaserScan(t, amin, ainc, ranges, rmax, make_pose((x, y, z), yaw)))
    return scans


def write_redwood(stream: SensorStream, root: Path) -> Path:
    """Write ``stream`` in the Open3D / Redwood layout: color/*.jpg, depth/*.png (mm),
    trajectory.log (camera-to-world), camera.json (column-major ``intrinsic_matrix``)."""
    import json

    root = Path(root)
    (root / "color").mkdir(parents=True, exist_ok=True)
    (root / "depth").mkdir(parents=True, exist_ok=True)
    log = []
    for k, f in enumerate(stream.frames):
        Image.fromarray(f.rgb).save(root / "color" / f"{k:06d}.jpg", quality=95)
        Image.fromarray(np.round(f.depth * 1000).astype(np.uint16)).save(root / "depth" / f"{k:06d}.png")
        log.append(f"{k} {k} {k + 1}\n" + "\n".join(" ".join(f"{v:.12g}" for v in row) for row in f.pose) + "\n")
    (root / "trajectory.log").write_text("".join(log))
    intr = stream.intrinsics
    (root / "camera.json").write_text(
        json.dumps({"width": intr.width, "height": intr.height, "intrinsic_matrix": intr.matrix.T.reshape(-1).tolist()})
    )
    return root


def write_scannet(stream: SensorStream, root: Path, color_size: tuple[int, int] | None = None) -> Path:
    """Write ``stream`` as a ScanNet export: color/N.jpg (resized to ``color_size``, as ScanNet's
    colour images differ from its depth), depth/N.png (mm), pose/N.txt, intrinsic/intrinsic_depth.txt."""
    root = Path(root)
    for sub in ("color", "depth", "pose", "intrinsic"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    for k, f in enumerate(stream.frames):
        image = Image.fromarray(f.rgb)
        if color_size is not None:
            image = image.resize(color_size)
        image.save(root / "color" / f"{k}.jpg", quality=95)
        Image.fromarray(np.round(f.depth * 1000).astype(np.uint16)).save(root / "depth" / f"{k}.png")
        np.savetxt(root / "pose" / f"{k}.txt", f.pose)
    K = np.eye(4)
    K[:3, :3] = stream.intrinsics.matrix
    np.savetxt(root / "intrinsic" / "intrinsic_depth.txt", K)
    return root
