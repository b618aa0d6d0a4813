"""Property-based fuzzing of the sources that read folders and bags (tum, redwood, scannet, rosbag) and of the
pointcloud source: one file of a valid tiny input is mutated (cut, bytes flipped, junk lines, header numbers
replaced, or replaced by random bytes). Whatever the input, the source (read through every frame and label
image) gives valid frames or a one-line ``DataError``, never another exception."""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stratamap.core.errors import DataError
from stratamap.core.io.pointcloud import write_point_cloud
from stratamap.core.io.rgbd import write_redwood, write_scannet
from stratamap.core.io.rosbag import write_lidar_bag, write_rgbd_bag
from stratamap.core.map.sensors import LidarScan
from stratamap.core.stages import PipelineData
from stratamap.plugins.sources.pointcloud import PointCloudSource
from stratamap.plugins.sources.redwood import RedwoodSource
from stratamap.plugins.sources.rosbag import RosbagSource
from stratamap.plugins.sources.scannet import ScanNetSource
from stratamap.plugins.sources.tum import TUMSource
from tests.core.io.test_fuzz_readers import fuzz, inputs
from tests.plugins.sources.test_bad_inputs import QUIET, gt_folder, tiny_stream, tum_folder

# Bounded (about 10 s per file): `make test` runs them, `make test-fast` leaves them out.
pytestmark = pytest.mark.slow


def snapshot(build: Callable[[Path], Path]) -> dict[str, bytes]:
    """Every file (by path relative to the input) of a valid input that ``build`` writes into a folder."""
    with tempfile.TemporaryDirectory() as tmp:
        root = build(Path(tmp) / "in")
        if root.is_file():
            return {"": root.read_bytes()}
        return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def lidar_bag(root: Path) -> Path:
    rng = np.random.default_rng(0)
    scans = [LidarScan(0.1 * k, rng.normal(size=(30, 3)), np.eye(4)) for k in range(3)]
    return write_lidar_bag(root / "l.bag", scans, ros_version=1)


INPUTS: dict[str, tuple[Callable[[Path], Path], Callable[[str], object]]] = {
    "tum": (lambda r: gt_folder(tum_folder(r)), lambda p: TUMSource(path=p, **QUIET)),
    "redwood": (lambda r: write_redwood(tiny_stream(), r), lambda p: RedwoodSource(path=p, **QUIET)),
    "scannet": (
        lambda r: write_scannet(tiny_stream(), r, color_size=(16, 12)),
        lambda p: ScanNetSource(path=p, **QUIET),
    ),
    "ros1-rgbd-bag": (
        lambda r: write_rgbd_bag((r.mkdir(), r / "b.bag")[1], tiny_stream(), ros_version=1),
        lambda p: RosbagSource(path=p, **QUIET),
    ),
    "ros2-rgbd-bag": (
        lambda r: write_rgbd_bag((r.mkdir(), r / "b")[1], tiny_stream(), ros_version=2),
        lambda p: RosbagSource(path=p, **QUIET),
    ),
    "ros1-lidar-bag": (lambda r: lidar_bag((r.mkdir(), r)[1]), lambda p: RosbagSource(path=p, **QUIET)),
}
SNAPSHOTS = {name: snapshot(build) for name, (build, _) in INPUTS.items()}


def check_source(kind: str, files: dict[str, bytes]) -> None:
    with tempfile.TemporaryDirectory(prefix="stratamap-fuzz-") as tmp:
        root = Path(tmp) / "in"
        if "" in files:
            root = root.with_suffix(".bag")
            root.write_bytes(files[""])
        else:
            for rel, data in files.items():
                (root / rel).parent.mkdir(parents=True, exist_ok=True)
                (root / rel).write_bytes(data)
        try:
            out = INPUTS[kind][1](str(root)).run(PipelineData())
            stream = out["frames"]
            frames = list(stream.frames)
            labels = list(out["ground_truth"].frame_labels) if "ground_truth" in out else []
        except DataError as err:
            text = str(err)
            assert text and "\n" not in text and str(root) in text, text
            return
    assert frames or stream.lidar_scans
    for f in frames:
        assert f.rgb.dtype == np.uint8 and f.rgb.shape == (*f.depth.shape, 3)
        assert f.depth.dtype == np.float32 and np.isfinite(f.depth).all() and (f.depth >= 0).all()
        assert f.pose is not None and f.pose.shape == (4, 4) and np.isfinite(f.pose).all()
    for seg in labels:
        assert seg.class_ids.shape == frames[0].depth.shape
    for s in stream.lidar_scans:
        assert np.isfinite(s.points).all() and np.isfinite(s.pose).all()


@pytest.mark.parametrize("kind", sorted(INPUTS))
def test_fuzz_source(kind):
    files = SNAPSHOTS[kind]

    @fuzz(100)
    @given(st.sampled_from(sorted(files)).flatmap(lambda rel: st.tuples(st.just(rel), inputs(files[rel], 300))))
    def run(change: tuple[str, bytes]) -> None:
        rel, data = change
        check_source(kind, {**files, rel: data})

    run()


def clouds() -> dict[str, bytes]:
    rng = np.random.default_rng(2)
    points = np.c_[rng.uniform(0, 2, (30, 2)), np.zeros(30)]
    labels = rng.integers(0, 40, 30).astype(np.int32)
    with tempfile.TemporaryDirectory() as tmp:
        out = {
            name: write_point_cloud(Path(tmp) / name, points, None, {"label": labels}, binary=binary).read_bytes()
            for name, binary in (("c.ply", True), ("c.pcd", False), ("c.npy", True))
        }
        out |= scanner_files(Path(tmp), points)
    return out


def scanner_files(tmp: Path, points: np.ndarray) -> dict[str, bytes]:
    """The points as LAS 1.4, LAZ and E57 (the libraries of the ``scans`` extra write them)."""
    try:
        import laspy
        import pye57
    except ImportError:
        return {}
    header = laspy.LasHeader(point_format=3, version="1.4")
    header.scales = [0.001] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = points.T
    for name in ("c.las", "c.laz"):
        las.write(str(tmp / name))
    e57 = pye57.E57(str(tmp / "c.e57"), mode="w")
    e57.write_scan_raw({f"cartesian{a}": points[:, k] for k, a in enumerate("XYZ")}, translation=np.zeros(3))
    e57.close()
    return {name: (tmp / name).read_bytes() for name in ("c.las", "c.laz", "c.e57")}


CLOUDS = clouds()


@pytest.mark.parametrize("name", sorted(CLOUDS))
def test_fuzz_pointcloud_source(name):
    @fuzz(120)
    @given(inputs(CLOUDS[name]), st.sampled_from(["raw", "mosd"]))
    def run(data: bytes, scheme: str) -> None:
        with tempfile.TemporaryDirectory(prefix="stratamap-fuzz-") as tmp:
            path = Path(tmp) / name
            path.write_bytes(data)
            try:
                out = PointCloudSource(path=str(path), gravity="off", label_scheme=scheme).run(PipelineData())
            except DataError as err:
                assert "\n" not in str(err) and str(path) in str(err), str(err)
                return
        pts = out["frames"].points
        assert len(pts) and np.isfinite(pts).all()
        gt = out.get("ground_truth")
        assert gt is None or len(gt.point_class_ids) == len(pts)

    run()
