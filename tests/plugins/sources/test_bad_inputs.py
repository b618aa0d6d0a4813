"""Bad inputs through the sources (pointcloud, tum, redwood, scannet, rosbag): one named case per failure,
each building its own tiny fixture; every case is a one-line ``DataError`` naming the file (or topic) and
what was expected. Valid twins check that 16UC1 and 32FC1 depth (PNG / float TIFF, bag encodings) read
the same."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh
from PIL import Image

from stratamap.core.errors import DataError
from stratamap.core.io.pointcloud import write_point_cloud
from stratamap.core.io.rgbd import write_redwood, write_scannet
from stratamap.core.io.rosbag import write_lidar_bag, write_rgbd_bag
from stratamap.core.map.sensors import CameraIntrinsics, LidarScan, RGBDFrame, SensorStream
from stratamap.core.stages import PipelineData
from stratamap.plugins.sources.pointcloud import PointCloudSource
from stratamap.plugins.sources.redwood import RedwoodSource
from stratamap.plugins.sources.rosbag import RosbagSource, cloud_array, image_array
from stratamap.plugins.sources.scannet import ScanNetSource
from stratamap.plugins.sources.tum import TUMSource

W, H, FRAMES = 8, 6, 3
QUIET = {"gravity": "off", "odometry": "never"}


def tiny_stream(frames: int = FRAMES, depth_m: float = 1.5, same_stamps: bool = False) -> SensorStream:
    rng = np.random.default_rng(0)
    out = []
    for k in range(frames):
        pose = np.eye(4)
        pose[0, 3] = 0.05 * k
        depth = np.full((H, W), depth_m, np.float32) + 0.01 * np.arange(W, dtype=np.float32)
        rgb = rng.integers(0, 256, (H, W, 3)).astype(np.uint8)
        out.append(RGBDFrame(k, 0.0 if same_stamps else 0.1 * k, rgb, depth, pose))
    return SensorStream(name="tiny", intrinsics=CameraIntrinsics(W, H, 6.0, 6.0, 4.0, 3.0), frames=out)


def png(path: Path, array: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)
    return path


def tum_folder(root: Path, frames: int = FRAMES) -> Path:
    """A TUM RGB-D folder: rgb/, depth/ (16-bit, 5000 per metre), rgb.txt, depth.txt, groundtruth.txt, camera.json."""
    stream = tiny_stream(frames)
    rgb_lines, depth_lines, gt_lines = ["# color images"], ["# depth images"], ["# timestamp tx ty tz qx qy qz qw"]
    for f in stream.frames:
        stamp = f"{f.timestamp + 1:.6f}"
        png(root / "rgb" / f"{stamp}.png", f.rgb)
        png(root / "depth" / f"{stamp}.png", np.round(f.depth * 5000).astype(np.uint16))
        rgb_lines.append(f"{stamp} rgb/{stamp}.png")
        depth_lines.append(f"{stamp} depth/{stamp}.png")
        gt_lines.append(f"{stamp} {f.pose[0, 3]:.6f} 0 0 0 0 0 1")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")
    intr = stream.intrinsics.to_dict()
    (root / "camera.json").write_text(json.dumps({**intr, "depth_scale": 5000}))
    return root


def gt_folder(root: Path, faces: np.ndarray | None = None, label_size: tuple[int, int] = (H, W)) -> Path:
    """A gt/ folder beside a TUM sequence: scene.json, one object mesh, class and instance images."""
    gt = root / "gt"
    (gt / "meshes").mkdir(parents=True)
    box = trimesh.creation.box((0.2, 0.2, 0.2))
    mesh = trimesh.Trimesh(box.vertices, box.faces if faces is None else faces, process=False)
    mesh.export(gt / "meshes" / "1.ply")
    scene = {"objects": [{"id": 1, "class": "box", "mesh": "meshes/1.ply", "pose": np.eye(4).tolist()}]}
    (gt / "scene.json").write_text(json.dumps(scene))
    for line in (root / "rgb.txt").read_text().splitlines()[1:]:
        stem = Path(line.split()[1]).stem
        png(gt / "class" / f"{stem}.png", np.zeros(label_size, np.uint16))
        png(gt / "instance" / f"{stem}.png", np.zeros(label_size, np.uint16))
    return root


def lines(path: Path, change: Callable[[list[str]], list[str]]) -> None:
    path.write_text("\n".join(change(path.read_text().splitlines())) + "\n")


def first(folder: Path, pattern: str = "*.png") -> Path:
    return sorted(folder.glob(pattern))[0]


def read_all(source) -> dict:
    """Run a source and read every frame and label image (sequence sources read images on access)."""
    out = source.run(PipelineData())
    for _ in out["frames"].frames:
        pass
    if "ground_truth" in out:
        for _ in out["ground_truth"].frame_labels:
            pass
    return out


def swap(k: int) -> Callable[[list[str]], list[str]]:
    return lambda ls: [*ls[:k], ls[k + 1], ls[k], *ls[k + 2 :]]


#: case -> (change the valid folder, what the error must say)
TUM_CASES: dict[str, tuple[Callable[[Path], object], str]] = {
    "rgb-line-without-timestamp": (
        lambda r: lines(r / "rgb.txt", lambda ls: [*ls, "rgb/late.png"]),
        r"rgb\.txt:5: expected a timestamp, got 'rgb/late\.png'",
    ),
    "rgb-line-without-file-name": (
        lambda r: lines(r / "rgb.txt", lambda ls: [*ls, "9.000000"]),
        r"rgb\.txt:5: expected a timestamp and an image file name",
    ),
    "duplicated-depth-timestamp": (
        lambda r: lines(r / "depth.txt", lambda ls: [*ls[:3], ls[2], *ls[3:]]),
        r"depth\.txt:4: timestamps are not increasing: entry 3 repeats \(1\.1 then 1\.1\)",
    ),
    "groundtruth-goes-back-in-time": (
        lambda r: lines(r / "groundtruth.txt", swap(2)),
        r"groundtruth\.txt:4: timestamps are not increasing: entry 3 goes back in time",
    ),
    "groundtruth-nan": (
        lambda r: lines(r / "groundtruth.txt", lambda ls: [*ls[:2], ls[2].replace(" 0 0 0 0 0 1", " nan 0 0 0 0 1")]),
        r"groundtruth\.txt: entry 2 is not a valid pose",
    ),
    "groundtruth-not-a-number": (
        lambda r: lines(r / "groundtruth.txt", lambda ls: [*ls, "9.0 a b c 0 0 0 1"]),
        r"groundtruth\.txt: entry 4 holds a value that is not a number",
    ),
    "color-size-disagrees-with-camera": (
        lambda r: png(first(r / "rgb"), np.zeros((H + 2, W + 2, 3), np.uint8)),
        r"rgb/1\.000000\.png: color image is 10x8, expected 8x6 as the camera intrinsics say",
    ),
    "depth-size-disagrees-with-camera": (
        lambda r: png(first(r / "depth"), np.full((H + 2, W + 2), 7500, np.uint16)),
        r"depth/1\.000000\.png: depth is 10x8, expected 8x6 as the camera intrinsics say",
    ),
    "depth-8-bit": (
        lambda r: png(first(r / "depth"), np.full((H, W), 7, np.uint8)),
        r"depth/1\.000000\.png: depth is 8-bit; expected 16-bit integers",
    ),
    "depth-float-millimetres": (
        lambda r: (
            [
                png(r / "depth" / p.with_suffix(".tiff").name, np.full((H, W), 1500.0, np.float32))
                for p in (r / "depth").glob("*.png")
            ]
            and lines(r / "depth.txt", lambda ls: [ln.replace(".png", ".tiff") for ln in ls])
        ),
        r"depth/1\.000000\.tiff: float depth with median 1500: looks like millimetres",
    ),
    "depth-file-missing": (lambda r: first(r / "depth").unlink(), r"depth/1\.000000\.png: image file missing"),
    "depth-not-an-image": (
        lambda r: first(r / "depth").write_bytes(b"\x89PNG\r\n\x1a\n garbage"),
        r"depth/1\.000000\.png: cannot be read as an image",
    ),
    "depth-wrong-scale": (
        lambda r: (r / "camera.json").write_text(json.dumps({**tiny_stream().intrinsics.to_dict(), "depth_scale": 5})),
        r"depth/1\.000000\.png: median depth is .* m with depth_scale 5; this looks like the wrong depth scale",
    ),
    "camera-fx-zero": (
        lambda r: (r / "camera.json").write_text(json.dumps({**tiny_stream().intrinsics.to_dict(), "fx": 0})),
        r"camera\.json: fx must be positive",
    ),
    "camera-depth-scale-negative": (
        lambda r: (r / "camera.json").write_text(json.dumps({**tiny_stream().intrinsics.to_dict(), "depth_scale": -1})),
        r"camera\.json: depth_scale must be a positive number",
    ),
    "camera-not-json": (lambda r: (r / "camera.json").write_text("{width: 8"), r"camera\.json: corrupt JSON"),
    "camera-a-list": (lambda r: (r / "camera.json").write_text("[8, 6]"), r"camera\.json: expected an object"),
    "no-rgb-depth-pair": (
        lambda r: lines(r / "rgb.txt", lambda ls: [ln.replace("1.", "7.", 1) for ls_ in [ls] for ln in ls_]),
        r"no rgb/depth pair within 0\.02 s",
    ),
    "empty-rgb-list": (lambda r: (r / "rgb.txt").write_text(""), r"rgb\.txt: no entries"),
    "gt-mesh-with-out-of-range-indices": (
        lambda r: gt_folder(r, faces=np.array([[0, 1, 99]])),
        r"gt/meshes/1\.ply: a face uses vertex index 99, but there are 8 vertices",
    ),
    "gt-label-image-size-disagrees": (
        lambda r: gt_folder(r, label_size=(H + 1, W)),
        r"gt/class/1\.000000\.png: class image is 8x7, expected 8x6 like the camera's images",
    ),
    "gt-scene-not-json": (
        lambda r: gt_folder(r) and (r / "gt" / "scene.json").write_text("{"),
        r"gt/scene\.json: corrupt JSON",
    ),
    "gt-object-without-pose": (
        lambda r: gt_folder(r) and (r / "gt" / "scene.json").write_text('{"objects": [{"id": 1, "class": "a"}]}'),
        r"gt/scene\.json: objects\[0\] lacks mesh, pose",
    ),
    "no-poses-and-odometry-never": (
        lambda r: (r / "groundtruth.txt").unlink(),
        r"3 of 3 frames have no pose and odometry is 'never'",
    ),
}


@pytest.mark.parametrize("case", sorted(TUM_CASES))
def test_bad_tum_folder(case, tmp_path):
    change, message = TUM_CASES[case]
    root = tum_folder(tmp_path / "seq")
    change(root)
    with pytest.raises(DataError, match=message) as err:
        read_all(TUMSource(path=str(root), **QUIET))
    assert "\n" not in str(err.value)


def test_tum_16_bit_and_float_depth_read_the_same(tmp_path):
    root = tum_folder(tmp_path / "seq")
    a = read_all(TUMSource(path=str(root), **QUIET))["frames"]
    for p in (root / "depth").glob("*.png"):
        depth = np.asarray(Image.open(p)).astype(np.float32) / 5000  # 32FC1-like: float metres
        png(p.with_suffix(".tiff"), depth)
    lines(root / "depth.txt", lambda ls: [ln.replace(".png", ".tiff") for ln in ls])
    b = read_all(TUMSource(path=str(root), **QUIET))["frames"]
    for fa, fb in zip(a.frames, b.frames, strict=True):
        np.testing.assert_allclose(fa.depth, fb.depth, atol=1e-6)
    gt_folder(root)
    gt = read_all(TUMSource(path=str(root), **QUIET))["ground_truth"]
    assert len(gt.objects) == 1 and len(gt.frame_labels) == FRAMES and gt.frame_labels[2].class_ids.shape == (H, W)


REDWOOD_CASES: dict[str, tuple[Callable[[Path], object], str]] = {
    "log-frame-ids-go-back": (
        lambda r: lines(r / "trajectory.log", lambda ls: [*ls[5:10], *ls[:5], *ls[10:]]),
        r"trajectory\.log: entry 2: frame id 0 goes back after 1; frame ids must increase",
    ),
    "log-frame-id-repeats": (
        lambda r: lines(r / "trajectory.log", lambda ls: [*ls[:5], *ls[:5], *ls[10:]]),
        r"trajectory\.log: entry 2: frame id 0 repeats after 0",
    ),
    "log-cut": (
        lambda r: lines(r / "trajectory.log", lambda ls: ls[:7]),
        r"trajectory\.log: 7 non-empty lines; a \.log file has 5 lines per pose",
    ),
    "log-not-rigid": (
        lambda r: lines(r / "trajectory.log", lambda ls: [ls[0], "2 0 0 0", *ls[2:]]),
        r"trajectory\.log: entry 1: not a rigid transform",
    ),
    "log-not-numbers": (
        lambda r: lines(r / "trajectory.log", lambda ls: [ls[0], "1 0 0 x", *ls[2:]]),
        r"trajectory\.log: entry 1 is malformed",
    ),
    "camera-a-list": (
        lambda r: (r / "camera.json").write_text("[1, 2, 3]"),
        r"camera\.json: expected an object with width, height and a 9-value intrinsic_matrix",
    ),
    "camera-matrix-short": (
        lambda r: (r / "camera.json").write_text('{"width": 8, "height": 6, "intrinsic_matrix": [1, 2]}'),
        r"camera\.json: intrinsic_matrix must be 9 numbers",
    ),
    "color-size-disagrees-with-camera": (
        lambda r: Image.new("RGB", (W * 2, H * 2)).save(first(r / "color", "*.jpg")),
        r"color/000000\.jpg: color image is 16x12, expected 8x6",
    ),
    "fewer-color-than-depth": (
        lambda r: first(r / "color", "*.jpg").unlink(),
        r"2 color images but 3 depth images",
    ),
}


@pytest.mark.parametrize("case", sorted(REDWOOD_CASES))
def test_bad_redwood_folder(case, tmp_path):
    change, message = REDWOOD_CASES[case]
    root = write_redwood(tiny_stream(), tmp_path / "seq")
    change(root)
    with pytest.raises(DataError, match=message) as err:
        read_all(RedwoodSource(path=str(root), **QUIET))
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("layout", ["redwood", "scannet"])
def test_a_sequence_of_another_layout_read_as_tum_names_its_source(layout, tmp_path):
    """A Redwood/Open3D or ScanNet folder given to the tum source: the error names the source that reads it."""
    root = (write_redwood if layout == "redwood" else write_scannet)(tiny_stream(), tmp_path / "seq")
    with pytest.raises(
        DataError, match=rf"seq/rgb\.txt: file missing; .* read it with source\.plugin={layout}$"
    ) as err:
        read_all(TUMSource(path=str(root), **QUIET))
    assert "\n" not in str(err.value)


SCANNET_CASES: dict[str, tuple[Callable[[Path], object], str]] = {
    "pose-not-4x4": (lambda r: (r / "pose" / "1.txt").write_text("1 0 0\n0 1 0\n"), r"pose/1\.txt: expected a 4x4"),
    "pose-not-rigid": (
        lambda r: np.savetxt(r / "pose" / "1.txt", np.diag([3.0, 1, 1, 1])),
        r"pose/1\.txt: not a rigid transform",
    ),
    "pose-garbage": (
        lambda r: (r / "pose" / "1.txt").write_bytes(b"\xff\x00\x81 binary"),
        r"pose/1\.txt: not a whitespace-separated matrix",
    ),
    "intrinsic-fx-zero": (
        lambda r: np.savetxt(r / "intrinsic" / "intrinsic_depth.txt", np.diag([0.0, 6, 1, 1])),
        r"intrinsic_depth\.txt: fx must be positive",
    ),
    "intrinsic-missing": (
        lambda r: (r / "intrinsic" / "intrinsic_depth.txt").unlink(),
        r"intrinsic_depth\.txt: file missing",
    ),
    "color-aspect-disagrees": (
        lambda r: Image.new("RGB", (W * 2, H)).save(r / "color" / "0.jpg"),
        r"color/0\.jpg: color image is 16x6, expected 8x6 .*image size mismatch",
    ),
    "two-depth-images-one-number": (
        lambda r: (r / "depth" / "01.png").write_bytes((r / "depth" / "1.png").read_bytes()),
        r"depth: frame number 1 names two depth images",
    ),
    "depth-name-not-a-number": (
        lambda r: (r / "depth" / "last.png").write_bytes((r / "depth" / "1.png").read_bytes()),
        r"depth/last\.png: ScanNet frame files are named by their number",
    ),
}


@pytest.mark.parametrize("case", sorted(SCANNET_CASES))
def test_bad_scannet_folder(case, tmp_path):
    change, message = SCANNET_CASES[case]
    root = write_scannet(tiny_stream(), tmp_path / "seq", color_size=(W * 2, H * 2))
    change(root)
    with pytest.raises(DataError, match=message) as err:
        read_all(ScanNetSource(path=str(root), **QUIET))
    assert "\n" not in str(err.value)


# --------------------------------------------------------------------------------------------- bags


def rgbd_bag(tmp: Path, **kwargs) -> Path:
    stream = tiny_stream(same_stamps=kwargs.pop("same_stamps", False), depth_m=kwargs.pop("depth_m", 1.5))
    return write_rgbd_bag(tmp / "b.bag", stream, ros_version=1, **kwargs)


BAG_CASES: dict[str, tuple[Callable[[Path], Path], dict, str]] = {
    "depth-topic-asked-for-is-absent": (
        rgbd_bag,
        {"depth_topic": "/nope/depth"},
        r"b\.bag: no topic '/nope/depth' \(asked for by depth_topic\); the bag has \[",
    ),
    "camera-info-topic-asked-for-is-absent": (
        rgbd_bag,
        {"camera_info_topic": "/nope/info"},
        r"b\.bag: no topic '/nope/info' \(asked for by camera_info_topic\)",
    ),
    "pointcloud-topic-asked-for-is-absent": (
        rgbd_bag,
        {"pointcloud_topic": "/velodyne_points"},
        r"b\.bag: no topic '/velodyne_points' \(asked for by pointcloud_topic\)",
    ),
    "depth-topic-of-another-type": (
        rgbd_bag,
        {"depth_topic": "/camera/color/camera_info"},
        r"b\.bag: topic '/camera/color/camera_info' \(depth_topic\) carries sensor_msgs/msg/CameraInfo",
    ),
    "depth-topic-is-a-color-topic": (
        rgbd_bag,
        {"depth_topic": "/camera/color/image_raw"},
        r"b\.bag: depth topic '/camera/color/image_raw' has encoding 'rgb8'; expected 16UC1, 32FC1",
    ),
    "32FC1-in-millimetres": (
        lambda t: rgbd_bag(t, depth_encoding="32FC1", depth_m=1500.0),
        {},
        r"b\.bag: /camera/depth/image_raw at t=1\.000000: 32FC1 depth with median 1500: looks like millimetres",
    ),
    "duplicated-stamps": (
        lambda t: rgbd_bag(t, same_stamps=True),
        {},
        r"b\.bag: two messages on '/camera/depth/image_raw' have the same header stamp 1\.000000000",
    ),
    "cut-in-half": (
        lambda t: (lambda p: p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2]) and p)(rgbd_bag(t)),
        {},
        r"b\.bag: (cannot open as a ROS 1 or ROS 2 bag|corrupt bag)",
    ),
    "not-a-bag": (
        lambda t: (t / "b.bag").write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 64) and t / "b.bag",
        {},
        r"b\.bag: (cannot open as a ROS 1 or ROS 2 bag|corrupt bag)",
    ),
    "lidar-without-poses-and-odometry-never": (
        lambda t: write_lidar_bag(
            t / "b.bag", [LidarScan(0.1 * k, np.random.default_rng(k).normal(size=(50, 3)), None) for k in range(3)]
        ),
        {},
        r"b\.bag: LiDAR sweeps without tf poses and odometry is 'never'",
    ),
}


@pytest.mark.parametrize("case", sorted(BAG_CASES))
def test_bad_bag(case, tmp_path):
    build, params, message = BAG_CASES[case]
    path = build(tmp_path)
    with pytest.raises(DataError, match=message) as err:
        read_all(RosbagSource(path=str(path), **QUIET, **params))
    assert "\n" not in str(err.value)


def test_bag_16UC1_and_32FC1_read_the_same(tmp_path):
    a = read_all(RosbagSource(path=str(rgbd_bag(tmp_path)), **QUIET))["frames"]
    (tmp_path / "f").mkdir()
    b = read_all(RosbagSource(path=str(rgbd_bag(tmp_path / "f", depth_encoding="32FC1")), **QUIET))["frames"]
    for fa, fb in zip(a.frames, b.frames, strict=True):
        np.testing.assert_allclose(fa.depth, fb.depth, atol=1e-3)  # 16UC1 holds whole millimetres


def image_msg(**fields) -> SimpleNamespace:
    header = SimpleNamespace(stamp=SimpleNamespace(sec=5, nanosec=0), frame_id="cam")
    base = {"encoding": "16UC1", "height": H, "width": W, "step": 2 * W, "is_bigendian": 0}
    base["data"] = np.zeros(H * 2 * W, np.uint8)
    return SimpleNamespace(header=header, **{**base, **fields})


@pytest.mark.parametrize(
    "fields,message",
    [
        ({"step": W}, r"/d at t=5\.000000: a 8x6 16UC1 image with step 8 needs .* a step of at least 16"),
        ({"data": np.zeros(10, np.uint8)}, r"/d at t=5\.000000: .* the message holds 10 bytes"),
        ({"height": 0}, r"/d at t=5\.000000: a 8x0 16UC1 image"),
        ({"encoding": "yuv422"}, r"/d at t=5\.000000: unsupported image encoding 'yuv422'"),
    ],
)
def test_bad_image_message(fields, message):
    with pytest.raises(DataError, match=message):
        image_array(image_msg(**fields), "/d")


def test_bad_pointcloud2_message():
    field = SimpleNamespace
    msg = SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=0), frame_id="lidar"),
        fields=[field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")],
        point_step=12,
        width=10,
        height=1,
        is_bigendian=False,
        data=np.zeros(60, np.uint8),
    )
    with pytest.raises(DataError, match=r"/p at t=1\.000000: 10x1 points of 12 bytes need 120 bytes; .* holds 60"):
        cloud_array(msg, "/p")
    msg.data, msg.fields[2].datatype = np.zeros(120, np.uint8), 42
    with pytest.raises(DataError, match=r"/p at t=1\.000000: field 'z' has datatype 42"):
        cloud_array(msg, "/p")
    msg.fields[2].datatype, msg.fields[2].offset = 7, 10
    with pytest.raises(DataError, match=r"field 'z' at offset 10 does not fit in point_step 12"):
        cloud_array(msg, "/p")


# --------------------------------------------------------------------------------------------- point clouds


def cloud_file(tmp: Path, name: str, points: np.ndarray, colors=None, labels=None, binary: bool = True) -> Path:
    fields = None if labels is None else {"label": labels}
    return write_point_cloud(tmp / name, points, colors, fields, binary=binary)


def grid_points(n: int = 400) -> np.ndarray:
    rng = np.random.default_rng(1)
    return np.c_[rng.uniform(0, 2, (n, 2)), np.zeros(n)]


POINTCLOUD_CASES: dict[str, tuple[Callable[[Path], Path], str]] = {
    "binary-ply-cut-in-half": (
        lambda t: (lambda p: p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2]) and p)(
            cloud_file(t, "c.ply", grid_points())
        ),
        r"c\.ply: truncated or corrupt: the header promises 400 vertex rows",
    ),
    "ascii-pcd-cut-in-half": (
        lambda t: (lambda p: p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2]) and p)(
            cloud_file(t, "c.pcd", grid_points(), binary=False)
        ),
        r"c\.pcd: truncated or corrupt: the header promises 400 points \(POINTS 400\), the file holds \d+ rows",
    ),
    "all-nan": (lambda t: cloud_file(t, "c.ply", np.full((10, 3), np.nan)), r"c\.ply: none of its 10 points"),
    "all-infinite": (lambda t: cloud_file(t, "c.pcd", np.full((10, 3), np.inf)), r"c\.pcd: none of its 10 points"),
    "nan-colors": (
        lambda t: np.save(t / "c.npy", np.c_[grid_points(), np.full((400, 3), np.nan)]) or t / "c.npy",
        r"c\.npy: 400 points with valid coordinates have NaN or infinite colors",
    ),
    "nan-labels": (
        lambda t: np.save(t / "c.npy", np.c_[grid_points(), np.r_[np.nan, np.ones(399)]]) or t / "c.npy",
        r"c\.npy: 1 labels are not whole numbers \(first: nan\)",
    ),
    "fractional-labels": (
        lambda t: np.save(t / "c.npy", np.c_[grid_points(), np.full(400, 2.5)]) or t / "c.npy",
        r"c\.npy: 400 labels are not whole numbers \(first: 2\.5\)",
    ),
    "labels-beyond-32-bits": (
        lambda t: cloud_file(t, "c.pcd", grid_points(), labels=np.full(400, 2**40, np.int64)),
        r"c\.pcd: labels range 1099511627776\.\.1099511627776; expected 32-bit integers",
    ),
    "missing-file": (lambda t: t / "nothing.ply", r"nothing\.ply: point cloud file not found"),
}


@pytest.mark.parametrize("case", sorted(POINTCLOUD_CASES))
def test_bad_point_cloud_through_the_source(case, tmp_path):
    build, message = POINTCLOUD_CASES[case]
    path = build(tmp_path)
    with pytest.raises(DataError, match=message) as err:
        PointCloudSource(path=str(path), gravity="off").run(PipelineData())
    assert "\n" not in str(err.value)


def test_infinite_points_are_dropped_and_counted(tmp_path):
    points = grid_points()
    points[:7, 2] = np.inf
    points[7:10] = np.nan
    data = PipelineData()
    out = PointCloudSource(path=str(cloud_file(tmp_path, "c.ply", points)), gravity="off").run(data)
    assert len(out["frames"].points) == 390 and data.notes["pointcloud"]["points"]["dropped_invalid"] == 10


def test_a_cloud_whose_floor_is_not_up_says_which_settings_fit(tmp_path):
    """A tabletop seen by a camera (its optical frame: the table's normal along -y) read as z-up: the
    error names the file and the two settings that fit such clouds."""
    rng = np.random.default_rng(2)
    table = np.c_[rng.uniform(-0.5, 0.5, 3000), np.full(3000, 0.8), rng.uniform(0.5, 1.5, 3000)]
    path = cloud_file(tmp_path, "camera.ply", table)
    with pytest.raises(
        DataError, match=r"camera\.ply: no floor plane found .* up_axis \(-y for a camera's optical frame"
    ) as err:
        PointCloudSource(path=str(path), up_axis="z").run(PipelineData())
    assert "\n" not in str(err.value)
    out = PointCloudSource(path=str(path), up_axis="-y").run(PipelineData())
    assert np.allclose(out["frames"].points[:, 2], 0.0, atol=0.01)


def test_a_cloud_with_no_floor_either_way_names_both_axes_looked_along(tmp_path):
    """With the default ``up_axis: auto``, an unorganized cloud is looked at as z-up, then as a camera's
    (-y); a cloud with a floor neither way (one wall, its normal along x) is a one-line error saying so."""
    rng = np.random.default_rng(4)
    wall = np.c_[np.full(3000, 2.0), rng.uniform(-1, 1, 3000), rng.uniform(0, 2, 3000)]
    path = cloud_file(tmp_path, "wall.ply", wall)
    with pytest.raises(DataError, match=r"wall\.ply: no floor plane found .*looked along up_axis z then -y") as err:
        PointCloudSource(path=str(path)).run(PipelineData())
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    "name,content,message",
    [
        ("scan.glb", b"not a glTF file", r"scan\.glb: cannot be read as a scanned mesh \("),
        ("empty.stl", b"solid empty\nendsolid empty\n", r"empty\.stl: no triangles"),
        ("flat.obj", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", r"flat\.obj: the mesh has no surface area"),
        (
            "faces.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n",
            r"faces\.ply: a face uses vertex index 7, but there are 3 vertices",
        ),
    ],
)
def test_a_broken_scanned_mesh_is_a_one_line_error_naming_it(tmp_path, name, content, message):
    """A mesh that cannot be read, holds no triangles, has no surface or indexes missing vertices."""
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(DataError, match=message) as err:
        PointCloudSource(path=str(path)).run(PipelineData())
    assert "\n" not in str(err.value)
