"""Reading RGB-D sequences from disk, with errors that name the file and what was expected.

Shared by the ``tum``, ``redwood`` and ``scannet`` sources: image readers that check dtypes and
sizes, timestamp association and pose interpolation.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np
from PIL import Image, UnidentifiedImageError

from stratamap.core.documents import read_data_text
from stratamap.core.errors import DataError
from stratamap.core.io import brief
from stratamap.core.lazy import lazy_module
from stratamap.core.map.sensors import CameraIntrinsics, SensorStream

rotations = lazy_module("scipy.spatial.transform")


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
            if im.mode in ("P", "PA", "CMYK", "YCbCr", "LAB", "HSV"):  # palette or other color spaces: as RGB(A)
                return np.asarray(im.convert("RGBA" if im.mode == "PA" or "transparency" in im.info else "RGB"))
            return np.asarray(im)
    except UnidentifiedImageError as exc:
        raise DataError(f"{path}: cannot be read as an image ({brief(exc)})") from exc
    except Exception as exc:  # Pillow's decoders raise OSError, ValueError, SyntaxError, struct.error, ...
        raise DataError(f"{path}: cannot be read as an image ({brief(exc, True)})") from exc


def read_rgb(path: Path, shape: tuple[int, int] | None = None, resample: bool = False) -> np.ndarray:
    """8-bit RGB of size ``shape`` (height, width): a color image of another size is an error, or with
    ``resample`` (ScanNet's colour images are larger than its depth) resampled when the aspect ratio agrees."""
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
        h, w = img.shape[:2]
        if not resample or not h or not w or abs((w / h) / (shape[1] / shape[0]) - 1) > 0.05:
            raise DataError(
                f"{path}: color image is {w}x{h}, expected {shape[1]}x{shape[0]} as the camera intrinsics say (image "
                "size mismatch)"
            )
        # ScanNet ships larger color images than depth: resample to the depth grid.
        img = np.asarray(Image.fromarray(img).resize((shape[1], shape[0]), Image.BILINEAR))
    return img


#: How a 16-bit depth image stores depth: ``linear`` (units per metre: TUM, Redwood, ScanNet),
#: ``kinect_disparity`` (a Kinect v1's raw 11-bit disparity, as NYU Depth V2's raw dumps hold it) or
#: ``sun_rgbd`` (millimetres rotated by 3 bits, as SUN RGB-D stores them).
DepthEncoding = Literal["linear", "kinect_disparity", "sun_rgbd"]
DEPTH_ENCODINGS: tuple[str, ...] = get_args(DepthEncoding)

#: No measurement in a Kinect v1's 11-bit disparity.
KINECT_NO_DISPARITY = 2047


def kinect_disparity_to_metres(raw: np.ndarray) -> np.ndarray:
    """Metres from a Kinect v1's raw disparity, by the NYU Depth V2 toolbox's fit 351.3 / (1092.5 - d).
    The raw dumps store the samples little-endian though PGM is big-endian: a value over 2047, which
    11 bits cannot hold, means the bytes are swapped."""
    raw = np.asarray(raw).astype(np.uint16)
    if raw.size and int(raw.max()) > KINECT_NO_DISPARITY:
        raw = raw.byteswap()
        if int(raw.max()) > KINECT_NO_DISPARITY:
            raise ValueError(f"values over {KINECT_NO_DISPARITY} in either byte order: not 11-bit disparity")
    d = raw.astype(np.float64)
    with np.errstate(divide="ignore"):
        depth = 351.3 / (1092.5 - d)
    depth[(raw >= KINECT_NO_DISPARITY) | (depth <= 0) | (depth > 10.0)] = 0.0
    return depth.astype(np.float32)


def sun_rgbd_to_metres(raw: np.ndarray) -> np.ndarray:
    """Metres from SUN RGB-D's depth PNGs: millimetres whose 16 bits are rotated left by 3 (its
    toolbox's ``bitor(bitshift(d, -3), bitshift(d, 13))``)."""
    raw = np.asarray(raw).astype(np.uint16)
    mm = (raw >> np.uint16(3)) | (raw << np.uint16(13))
    return mm.astype(np.float32) / np.float32(1000.0)


def read_depth(
    path: Path, depth_scale: float, shape: tuple[int, int] | None = None, encoding: str = "linear"
) -> np.ndarray:
    """Metric float32 depth from a 16-bit image (``encoding``: see DEPTH_ENCODINGS; ``linear``: units per
    metre = ``depth_scale``) or a float image already in metres; NaN, inf and negative values become 0
    (no measurement)."""
    if encoding not in DEPTH_ENCODINGS:
        raise DataError(f"{path}: unknown depth encoding {encoding!r}; expected one of {', '.join(DEPTH_ENCODINGS)}")
    img = read_image(path)
    if img.ndim != 2:
        raise DataError(f"{path}: depth must be single-channel, got shape {img.shape} (is this a color image?)")
    if img.dtype == np.uint8:
        raise DataError(f"{path}: depth is 8-bit; expected 16-bit integers ({depth_scale:g} per metre) or float metres")
    if img.dtype.kind not in "iuf":
        raise DataError(f"{path}: depth of type {img.dtype}; expected 16-bit integers or float metres")
    if encoding != "linear":
        if not np.issubdtype(img.dtype, np.integer) or img.min() < 0 or img.max() > 65535:
            raise DataError(f"{path}: depth encoding {encoding!r} needs a 16-bit integer image, got {img.dtype}")
        convert = kinect_disparity_to_metres if encoding == "kinect_disparity" else sun_rgbd_to_metres
        try:
            depth = convert(img)
        except ValueError as exc:
            raise DataError(f"{path}: depth encoding {encoding!r} does not fit this image ({exc})") from None
    elif np.issubdtype(img.dtype, np.integer):
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
            f"{path}: depth is {depth.shape[1]}x{depth.shape[0]}, expected {shape[1]}x{shape[0]} as the camera "
            "intrinsics say (image size mismatch)"
        )
    return depth


def check_depth_scale(
    depth: np.ndarray, path: Path, depth_scale: float, max_plausible: float = 20.0, encoding: str = "linear"
) -> None:
    """Catch a wrong depth scale (or encoding) early: indoor depth in metres has a median between ~0.2
    and 20 m."""
    valid = depth[depth > 0]
    if valid.size == 0:
        return
    med = float(np.median(valid))
    if not 0.05 <= med <= max_plausible:
        if encoding != "linear":
            raise DataError(
                f"{path}: median depth is {med:.3g} m with depth_encoding {encoding}; this looks like the wrong "
                f"encoding (one of {', '.join(DEPTH_ENCODINGS)})"
            )
        raise DataError(
            f"{path}: median depth is {med:.3g} m with depth_scale {depth_scale:g}; this looks like the wrong depth "
            "scale "
            f"(TUM uses 5000, Redwood/ScanNet 1000 units per metre)"
        )


def read_text_lines(path: Path) -> list[str]:
    """The lines of a text file, or a DataError naming the file when it is missing or not text."""
    if not path.is_file():
        raise DataError(f"{path}: file missing")
    return read_data_text(path).splitlines()


def read_timestamped_list(path: Path, min_values: int = 0, what: str = "") -> list[tuple[float, list[str]]]:
    """Lines ``timestamp rest...`` (TUM lists); comments (#) skipped; timestamps must be finite and increase,
    and each line must have at least ``min_values`` values after its timestamp (``what`` names them)."""
    rows = []
    lines = []
    for n, line in enumerate(read_text_lines(path), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            t = float(parts[0])
        except ValueError:
            raise DataError(f"{path}:{n}: expected a timestamp, got {parts[0][:40]!r}") from None
        if not np.isfinite(t):
            raise DataError(f"{path}:{n}: timestamp {parts[0]!r} is not a finite number")
        if len(parts) - 1 < min_values:
            raise DataError(f"{path}:{n}: expected a timestamp and {what or f'{min_values} values'}, got {line[:80]!r}")
        rows.append((t, parts[1:]))
        lines.append(n)
    if not rows:
        raise DataError(f"{path}: no entries")
    times = np.array([r[0] for r in rows])
    bad = np.flatnonzero(np.diff(times) <= 0)
    if len(bad):
        k = int(bad[0])
        kind = "repeats" if times[k] == times[k + 1] else "goes back in time"
        raise DataError(
            f"{path}:{lines[k + 1]}: timestamps are not increasing: entry {k + 2} {kind} ({float(times[k])!r} then "
            f"{float(times[k + 1])!r})"
        )
    return rows


def intrinsics_from(values: Any, where: str) -> CameraIntrinsics:
    """A camera from ``width, height, fx, fy, cx, cy`` in a mapping, checked: whole positive image sizes,
    finite values and positive focal lengths; ``where`` names the file (and key) in errors."""
    keys = ("width", "height", "fx", "fy", "cx", "cy")
    if not isinstance(values, dict):
        raise DataError(f"{where}: expected an object with {', '.join(keys)}, got {type(values).__name__}")
    missing = [k for k in keys if k not in values]
    if missing:
        raise DataError(f"{where}: missing {', '.join(missing)} (a camera needs {', '.join(keys)})")
    values = {k: v.item() if isinstance(v, np.generic) else v for k, v in values.items()}
    nums = {}
    for k in keys:
        v = values[k]
        try:
            nums[k] = float(v) if not isinstance(v, bool) else math.nan
        except (TypeError, ValueError, OverflowError):
            nums[k] = math.nan
        if not math.isfinite(nums[k]):
            raise DataError(f"{where}: {k} must be a finite number, got {v!r}"[:200])
    for k in ("width", "height"):
        if nums[k] < 1 or nums[k] != int(nums[k]) or nums[k] > 1 << 16:
            raise DataError(f"{where}: {k} must be a whole number of pixels (1..65536), got {values[k]!r}")
    for k in ("fx", "fy"):
        if nums[k] <= 0:
            raise DataError(f"{where}: {k} must be positive, got {values[k]!r}")
    return CameraIntrinsics(int(nums["width"]), int(nums["height"]), nums["fx"], nums["fy"], nums["cx"], nums["cy"])


def read_json(path: Path) -> Any:
    """A JSON file's content, or a DataError naming the file."""
    try:
        return json.loads("\n".join(read_text_lines(path)))
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: corrupt JSON ({brief(exc)})") from exc


def rigid_pose(values: Any, where: str, tolerance: float = 2e-3) -> np.ndarray:
    """A 4x4 rigid transform (rotation and translation, last row 0 0 0 1), checked; ``where`` names it in errors."""
    try:
        mat = np.array(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise DataError(f"{where}: not a 4x4 matrix of numbers") from None
    if mat.shape != (4, 4):
        raise DataError(f"{where}: expected a 4x4 matrix, got shape {mat.shape}")
    if not np.all(np.isfinite(mat)):
        raise DataError(f"{where}: the pose holds NaN or infinite values")
    rot = mat[:3, :3]
    if (
        np.abs(mat[3] - (0, 0, 0, 1)).max() > 1e-6
        or np.abs(rot.T @ rot - np.eye(3)).max() > tolerance
        or np.linalg.det(rot) < 0
    ):
        raise DataError(f"{where}: not a rigid transform (rotation not orthonormal, or last row not 0 0 0 1)")
    return mat


def read_open3d_camera(path: Path) -> CameraIntrinsics:
    """An Open3D ``PinholeCameraIntrinsic`` JSON: width, height and a column-major 9-value ``intrinsic_matrix``."""
    cam = read_json(path)
    if not isinstance(cam, dict) or "intrinsic_matrix" not in cam:
        raise DataError(f"{path}: expected an object with width, height and a 9-value intrinsic_matrix")
    try:
        K = np.array(cam["intrinsic_matrix"], dtype=np.float64).reshape(3, 3).T  # Open3D stores column-major
    except (TypeError, ValueError):
        raise DataError(f"{path}: intrinsic_matrix must be 9 numbers, got {cam['intrinsic_matrix']!r}"[:200]) from None
    values = {"width": cam.get("width"), "height": cam.get("height")}
    values |= {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
    return intrinsics_from(values, str(path))


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
        try:
            v = np.array([float(x) for x in vals])
        except ValueError:
            raise DataError(
                f"{path}: entry {n + 1} holds a value that is not a number ({' '.join(vals)[:80]})"
            ) from None
        if not np.all(np.isfinite(v)) or np.linalg.norm(v[3:]) < 1e-6:
            raise DataError(f"{path}: entry {n + 1} is not a valid pose ({vals})")
        pose = np.eye(4)
        pose[:3, :3] = rotations.Rotation.from_quat(v[3:] / np.linalg.norm(v[3:])).as_matrix()
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
    slerp = rotations.Slerp(times, rotations.Rotation.from_matrix(poses[:, :3, :3]))
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
    last = -np.inf
    for n, line in enumerate(read_text_lines(path), 1):
        if not line.strip() or line.startswith("#"):
            continue
        vals = line.split()
        if len(vals) < 9:
            raise DataError(f"{path}:{n}: expected timestamp x y z yaw angle_min angle_increment range_max and ranges")
        try:
            head = [float(v) for v in vals[:8]]
            ranges = np.array([float(v) for v in vals[8:]], dtype=np.float32)
        except ValueError as exc:
            raise DataError(f"{path}:{n}: {brief(exc)}") from None
        if not np.all(np.isfinite(head)) or head[6] == 0 or head[7] <= 0:
            raise DataError(
                f"{path}:{n}: timestamp, pose and angles must be finite, angle_increment non-zero and range_max "
                f"positive, got {' '.join(vals[:8])}"
            )
        if head[0] <= last:
            raise DataError(f"{path}:{n}: timestamp {head[0]!r} does not follow {last!r}; timestamps must increase")
        last = head[0]
        t, x, y, z, yaw, amin, ainc, rmax = head
        scans.append(LaserScan(t, amin, ainc, ranges, rmax, make_pose((x, y, z), yaw)))
    return scans


def write_redwood(stream: SensorStream, root: Path) -> Path:
    """Write ``stream`` in the Open3D / Redwood layout: color/*.jpg, depth/*.png (mm),
    trajectory.log (camera-to-world), camera.json (column-major ``intrinsic_matrix``)."""
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
