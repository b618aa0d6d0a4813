"""Data sources: what they read, and the errors real data provokes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from stratamap.core.errors import DataError
from stratamap.core.io.rosbag import write_lidar_bag, write_rgbd_bag
from stratamap.core.stages import PipelineData
from stratamap.core.synthetic import SceneSpec, SyntheticWorld
from stratamap.core.synthetic.writer import write_sequence
from stratamap.plugins.sources.pointcloud import PointCloudSource
from stratamap.plugins.sources.redwood import RedwoodSource
from stratamap.plugins.sources.rosbag import RosbagSource
from stratamap.plugins.sources.scannet import ScanNetSource
from stratamap.plugins.sources.tum import TUMSource
from tests.conftest import low_poly_room, shared_data

SMALL = {"type": "room", "seed": 2, "camera": {"width": 96, "height": 72}, "trajectory": {"type": "orbit", "frames": 5}}


@pytest.fixture(scope="module")
def world():
    return SyntheticWorld(
        SceneSpec.model_validate({**SMALL, "lidar": {"enabled": True, "rings": 8, "points_per_ring": 96}})
    )


@pytest.fixture(scope="module")
def tum_seq(tmp_path_factory, world):
    path = tmp_path_factory.mktemp("tum") / "seq"
    write_sequence(world, path)
    return path


def read(source):
    return source.run(PipelineData())


def test_tum_reads_back_what_synth_wrote(tum_seq, world):
    out = read(TUMSource(path=str(tum_seq), gravity="off"))
    stream, gt = out["frames"], out["ground_truth"]
    assert len(stream.frames) == 5 and stream.intrinsics == world.intrinsics
    f, truth = stream.frames[3], world.frame(3)[0]
    assert np.abs(f.depth - truth.depth).max() <= 1 / 5000 + 1e-6
    np.testing.assert_array_equal(f.rgb, truth.rgb)
    np.testing.assert_allclose(f.pose, truth.pose, atol=1e-6)
    assert len(gt.objects) == len(world.scene.objects) and len(gt.frame_labels) == 5
    np.testing.assert_array_equal(gt.frame_labels[3].instance_ids, world.frame(3)[1].instance_ids)
    assert len(stream.laser_scans) == 5


def test_first_frame_starts_the_subsample_and_past_the_end_is_a_one_line_error(tum_seq, world):
    out = read(TUMSource(path=str(tum_seq), gravity="off", first_frame=1, stride=2))
    stream, gt = out["frames"], out["ground_truth"]
    assert len(stream.frames) == 2
    for frame, k in zip(stream.frames, (1, 3), strict=True):
        truth, labels = world.frame(k)
        np.testing.assert_array_equal(frame.rgb, truth.rgb)
        np.testing.assert_allclose(frame.pose, truth.pose, atol=1e-6)
        np.testing.assert_array_equal(gt.frame_labels[frame.index].instance_ids, labels.instance_ids)
    with pytest.raises(DataError, match=r"first_frame is 5, but it has 5 frames") as err:
        read(TUMSource(path=str(tum_seq), gravity="off", first_frame=5))
    assert str(tum_seq) in str(err.value)


def test_tum_gravity_auto_keeps_a_z_up_input(tum_seq):
    data = PipelineData()
    TUMSource(path=str(tum_seq)).run(data)
    assert data.notes["tum"]["gravity_alignment"]["rotation_deg"] < 1.0


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def test_tum_colour_larger_than_its_depth_is_read_at_the_depth_s_size(tum_seq, tmp_path):
    """A colour camera of twice the depth's pixels (the same view, as a phone's or an Azure Kinect's
    registered pair): read at the depth's size, with a note; depth and poses as before."""
    seq = _copy(tum_seq, tmp_path / "big")
    for path in sorted((seq / "rgb").glob("*.png")):
        img = Image.open(path)
        img.resize((img.width * 2, img.height * 2), Image.NEAREST).save(path)
    data = PipelineData()
    stream = TUMSource(path=str(seq), gravity="off").run(data)["frames"]
    plain = read(TUMSource(path=str(tum_seq), gravity="off"))["frames"]
    intr = stream.intrinsics
    assert data.notes["tum"]["colour_resampled"] == {
        "from": [2 * intr.width, 2 * intr.height],
        "to": [intr.width, intr.height],
    }
    for k in (0, len(stream) - 1):
        assert stream.frames[k].rgb.shape == plain.frames[k].rgb.shape
        assert np.abs(stream.frames[k].rgb.astype(int) - plain.frames[k].rgb).mean() < 3
        assert np.array_equal(stream.frames[k].depth, plain.frames[k].depth)


def test_tum_errors_name_the_file(tum_seq, tmp_path):
    with pytest.raises(DataError, match="not found"):
        read(TUMSource(path=str(tmp_path / "nowhere")))
    seq = _copy(tum_seq, tmp_path / "a")
    (seq / "rgb.txt").unlink()
    with pytest.raises(DataError, match="rgb.txt: file missing"):
        read(TUMSource(path=str(seq)))
    seq = _copy(tum_seq, tmp_path / "b")
    lines = (seq / "depth.txt").read_text().splitlines()
    body = [ln for ln in lines if not ln.startswith("#")]
    (seq / "depth.txt").write_text("\n".join([body[1], body[0], *body[2:]]) + "\n")
    with pytest.raises(DataError, match="not increasing"):
        read(TUMSource(path=str(seq)))
    seq = _copy(tum_seq, tmp_path / "c")
    first = sorted((seq / "depth").glob("*.png"))[0]
    Image.fromarray((np.asarray(Image.open(first)) // 256).astype(np.uint8)).save(first)
    with pytest.raises(DataError, match="8-bit"):
        read(TUMSource(path=str(seq), gravity="off"))
    with pytest.raises(DataError, match="wrong depth scale"):
        read(TUMSource(path=str(tum_seq), depth_scale=5.0))
    seq = _copy(tum_seq, tmp_path / "d")
    (seq / "camera.json").write_text('{"width": 96}')
    with pytest.raises(DataError, match="camera.json"):
        read(TUMSource(path=str(seq)))
    seq = _copy(tum_seq, tmp_path / "e")
    (seq / "camera.json").write_text(
        '{"width": 64, "height": 48, "fx": 50, "fy": 50, "cx": 32, "cy": 24, "depth_scale": 5000}'
    )
    with pytest.raises(DataError, match="size mismatch"):
        read(TUMSource(path=str(seq)))


@pytest.fixture(scope="module")
def orbit_without_poses(tmp_path_factory):
    """A TUM folder of a 144-frame orbit (2.5 degrees between frames) with no groundtruth.txt."""
    spec = SceneSpec.model_validate(
        {
            "type": "room",
            "seed": 4,
            "camera": {"width": 160, "height": 120},
            "trajectory": {"type": "orbit", "frames": 144},
        }
    )
    seq = write_sequence(SyntheticWorld(spec), tmp_path_factory.mktemp("orbit") / "noposes")
    (seq / "groundtruth.txt").unlink()
    return seq


@pytest.mark.slow
def test_tum_without_poses_runs_odometry_and_reports_ate(orbit_without_poses):
    seq = orbit_without_poses
    data = PipelineData()
    out = TUMSource(path=str(seq), gravity="off", max_frames=12).run(data)
    odo = data.notes["tum"]["odometry"]
    assert "ate_rmse_m" in odo and odo["ate_rmse_m"] < 0.05, odo  # ~1 cm with 2.5 degrees between frames
    assert all(f.pose is not None for f in out["frames"].frames)
    with pytest.raises(DataError, match="no pose"):
        read(TUMSource(path=str(seq), odometry="never"))


@pytest.mark.slow
def test_rgbd_odometry_reads_each_frame_once_and_holds_only_a_few(orbit_without_poses):
    """Odometry streams the frames: a sequence of thousands of frames must not be held whole (it
    was: 2 MB a 640x480 frame)."""
    import weakref

    alive = {"now": 0, "peak": 0, "reads": 0}

    def gone():
        alive["now"] -= 1

    class Counted(TUMSource):
        def load(self):
            stream, frames, gt = super().load()
            inner = frames._read

            def read(k):
                rgb, depth = inner(k)
                depth = depth.copy()
                alive["now"] += 1
                alive["reads"] += 1
                alive["peak"] = max(alive["peak"], alive["now"])
                weakref.finalize(depth, gone)
                return rgb, depth

            frames._read = read
            return stream, frames, gt

    data = PipelineData()
    Counted(path=str(orbit_without_poses), gravity="off", max_frames=24).run(data)
    assert data.notes["tum"]["odometry"]["frames"] == 24
    assert alive["peak"] <= 5, alive  # the frame cache's three, and the frame in hand


@pytest.mark.slow
def test_odometry_that_loses_its_way_says_where_and_a_lost_track_is_one_clean_line(orbit_without_poses):
    """Frames 2.5 degrees apart track without a word; 7.5 degrees apart, some frames match little
    of the map and the warning names them; 12.5 degrees apart, tracking fails: one line, without
    Open3D's terminal colours or C++ source file."""
    quiet = PipelineData()
    TUMSource(path=str(orbit_without_poses), gravity="off", max_frames=12).run(quiet)
    assert not any("odometry" in w for w in quiet.warnings), quiet.warnings
    assert quiet.notes["tum"]["odometry"]["fitness"]["min"] >= 0.3

    fast = PipelineData()
    TUMSource(path=str(orbit_without_poses), gravity="off", stride=3, max_frames=12).run(fast)
    (warning,) = [w for w in fast.warnings if "odometry" in w]
    assert "of 12 frames matched under 30%" in warning and "(frames " in warning and "stride" in warning

    with pytest.raises(DataError) as lost:
        read(TUMSource(path=str(orbit_without_poses), gravity="off", stride=5, max_frames=12))
    message = str(lost.value)
    assert message.startswith("odometry: tracking lost at frame") and "stride" in message
    assert "\x1b" not in message and ".cpp" not in message and "\n" not in message


def test_nan_and_zero_depth_become_no_measurement(tmp_path):
    from stratamap.core.io.rgbd import read_depth

    arr = np.array([[np.nan, 0.0], [-1.0, 1.5]], np.float32)
    Image.fromarray(arr, mode="F").save(tmp_path / "d.tiff")
    depth = read_depth(tmp_path / "d.tiff", 5000)
    np.testing.assert_array_equal(depth, [[0, 0], [0, 1.5]])


def test_kinect_disparity_and_sun_rgbd_depth_decode_to_metres(tmp_path):
    from stratamap.core.io.rgbd import read_depth

    metres = np.array([[0.0, 0.8, 1.5], [2.5, 4.0, 0.0]])
    # A Kinect v1's raw disparity by the NYU fit (351.3 / (1092.5 - d)), 2047 where nothing was measured.
    disparity = np.where(metres > 0, np.round(1092.5 - 351.3 / np.maximum(metres, 1e-9)), 2047).astype(np.uint16)
    expected = np.where(metres > 0, 351.3 / (1092.5 - disparity.astype(float)), 0.0)
    for order, raw in (("native", disparity), ("swapped", disparity.byteswap())):
        Image.fromarray(raw).save(tmp_path / f"{order}.png")
        depth = read_depth(tmp_path / f"{order}.png", 5000, encoding="kinect_disparity")
        np.testing.assert_allclose(depth, expected, atol=1e-4, err_msg=order)
        assert np.abs(depth - metres).max() < 0.02  # the disparity's quantisation at 4 m
    # SUN RGB-D: millimetres rotated left by 3 bits.
    mm = np.round(metres * 1000).astype(np.uint16)
    Image.fromarray(((mm << 3) | (mm >> 13)).astype(np.uint16)).save(tmp_path / "sun.png")
    np.testing.assert_allclose(read_depth(tmp_path / "sun.png", 5000, encoding="sun_rgbd"), mm / 1000.0, atol=1e-6)
    # A linear image is no disparity in either byte order: a one-line error naming the file.
    Image.fromarray((metres * 5000).astype(np.uint16)).save(tmp_path / "linear.png")
    with pytest.raises(DataError, match="linear.png: depth encoding 'kinect_disparity' does not fit"):
        read_depth(tmp_path / "linear.png", 5000, encoding="kinect_disparity")
    with pytest.raises(DataError, match="unknown depth encoding"):
        read_depth(tmp_path / "sun.png", 5000, encoding="mm")


@pytest.mark.parametrize("ros_version", [1, 2])
def test_rosbag_rgbd_round_trip(world, tmp_path, ros_version):
    bag = write_rgbd_bag(
        tmp_path / ("rgbd.bag" if ros_version == 1 else "rgbd"), world.stream(), ros_version=ros_version
    )
    stream = read(RosbagSource(path=str(bag), gravity="off"))["frames"]
    assert len(stream.frames) == 5 and stream.intrinsics == world.intrinsics
    for k in (0, 4):
        got, truth = stream.frames[k], world.frame(k)[0]
        np.testing.assert_array_equal(got.rgb, truth.rgb)
        assert np.abs(got.depth - truth.depth).max() <= 0.0005 + 1e-6  # written in millimetres
        np.testing.assert_allclose(got.pose, truth.pose, atol=1e-9)


@pytest.mark.parametrize("ros_version", [1, 2])
def test_a_bag_of_compressed_images_reads_as_its_raw_images_do(world, tmp_path, ros_version):
    """Images recorded through image_transport (colour JPEG on .../compressed, depth PNG on
    .../compressedDepth after its 12-byte header), as camera drivers' bags usually hold them: the
    topics are found by type, depth reads to the millimetre and colour within JPEG's error, with the
    same poses as the raw bag's."""
    name = "bag" if ros_version == 1 else ""
    raw = write_rgbd_bag(tmp_path / f"raw.{name}".rstrip("."), world.stream(), ros_version=ros_version)
    packed = write_rgbd_bag(
        tmp_path / f"packed.{name}".rstrip("."), world.stream(), ros_version=ros_version, compressed=True
    )
    data = PipelineData()
    got = RosbagSource(path=str(packed), gravity="off").run(data)["frames"]
    want = read(RosbagSource(path=str(raw), gravity="off"))["frames"]
    assert got.metadata["depth_topic"].endswith("compressedDepth") and got.metadata["color_topic"].endswith(
        "compressed"
    )
    assert len(got.frames) == len(want.frames) == 5
    for a, b in zip(got.frames, want.frames, strict=True):
        np.testing.assert_array_equal(a.depth, b.depth)
        assert np.abs(a.rgb.astype(int) - b.rgb.astype(int)).mean() < 3.0
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-9)


def test_compressed_depth_of_32fc1_is_quantized_inverse_depth():
    """compressed_depth_image_transport stores 32FC1 depth as v = a / depth + b in a 16-bit PNG (0: no
    depth); damaged data is a one-line error naming the topic."""
    import io
    import struct
    from types import SimpleNamespace

    from PIL import Image

    from stratamap.plugins.sources.rosbag import image_array

    depth = np.array([[0.5, 1.0], [2.0, 0.0]], np.float32)
    a, b = 100.0, 10.0
    inverse = np.where(depth > 0, np.round(a / np.where(depth > 0, depth, 1) + b), 0).astype(np.uint16)
    png = io.BytesIO()
    Image.fromarray(inverse).save(png, format="PNG")
    stamp = SimpleNamespace(sec=1, nanosec=0)
    msg = SimpleNamespace(
        header=SimpleNamespace(stamp=stamp),
        format="32FC1; compressedDepth png",
        data=np.frombuffer(struct.pack("<iff", 0, a, b) + png.getvalue(), np.uint8),
    )
    np.testing.assert_allclose(image_array(msg, "/depth"), depth, atol=1e-6)
    msg.data = msg.data[:40]
    with pytest.raises(DataError, match=r"/depth at t=1\.000000: its '32FC1; compressedDepth png' image cannot be"):
        image_array(msg, "/depth")


@pytest.mark.parametrize("ros_version", [1, 2])
def test_rosbag_pointcloud2_round_trip(world, tmp_path, ros_version):
    bag = write_lidar_bag(
        tmp_path / ("lidar.bag" if ros_version == 1 else "lidar"), world.lidar_scans, ros_version=ros_version
    )
    scans = read(RosbagSource(path=str(bag), gravity="off"))["frames"].lidar_scans
    assert len(scans) == len(world.lidar_scans)
    for got, truth in zip(scans, world.lidar_scans, strict=True):
        np.testing.assert_allclose(got.points, truth.points, atol=1e-5)
        np.testing.assert_allclose(got.pose, truth.pose, atol=1e-9)


@pytest.mark.parametrize("kind", ["rgbd", "lidar"])
def test_rosbag_holds_one_image_or_sweep_at_a_time(world, tmp_path, kind):
    """A long recording's images and sweeps are read from the bag when used, not held: reading a bag and
    every frame (or sweep) of it peaks at a fraction of what its images (or points) take."""
    import tracemalloc
    from dataclasses import replace

    from stratamap.core.map.sensors import LidarScan

    n = 300
    if kind == "rgbd":
        stream = world.stream()
        frames = [replace(stream.frames[k % 5], timestamp=0.1 * k) for k in range(n)]
        bag = write_rgbd_bag(tmp_path / "rgbd", replace(stream, frames=frames), ros_version=2)
        payload = sum(f.depth.nbytes + f.rgb.nbytes for f in frames)
    else:
        sweeps = [world.lidar_scans[k % len(world.lidar_scans)] for k in range(n)]
        sweeps = [LidarScan(0.1 * k, np.tile(s.points, (4, 1)), s.pose) for k, s in enumerate(sweeps)]
        bag = write_lidar_bag(tmp_path / "lidar.bag", sweeps, ros_version=1)
        payload = sum(s.points.nbytes for s in sweeps)
    tracemalloc.start()
    try:
        out = read(RosbagSource(path=str(bag), gravity="off"))["frames"]
        if kind == "rgbd":
            seen = sum(float(f.depth.sum()) for f in out.frames)
            truth = sum(float(np.round(f.depth * 1000).sum()) / 1000 for f in frames)
        else:
            seen = sum(len(s.points) for s in out.lidar_scans)
            truth = sum(len(s.points) for s in sweeps)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert seen == pytest.approx(truth, rel=1e-5)
    assert peak < 0.3 * payload, f"peak {peak / 1e6:.1f} MB reading {payload / 1e6:.1f} MB of {kind}"


def test_rosbag_errors(tmp_path):
    with pytest.raises(DataError, match="not found"):
        read(RosbagSource(path=str(tmp_path / "missing.bag")))
    (tmp_path / "junk.bag").write_bytes(b"not a bag")
    with pytest.raises(DataError, match="cannot open"):
        read(RosbagSource(path=str(tmp_path / "junk.bag")))
    unnamed = tmp_path / "recording"
    unnamed.write_bytes(b"#ROSBAG V2.0\n" + bytes(64))
    with pytest.raises(DataError, match=r"recording: a ROS 1 bag, whose file name must end in \.bag"):
        read(RosbagSource(path=str(unnamed)))


def test_scannet_and_redwood_layouts_read():
    for cls in (ScanNetSource, RedwoodSource):
        params = cls.example_params()
        stream = read(cls(**params, gravity="off"))["frames"]
        assert len(stream.frames) == 5 and all(f.pose is not None for f in stream.frames)
        assert stream.frames[0].rgb.shape[:2] == stream.frames[0].depth.shape


def test_a_scannet_sens_stream_reads_as_its_export_does(world, tmp_path):
    """A ScanNet .sens file (version 4: JPEG colour larger than the depth, zlib depth in mm, the depth
    intrinsics, camera-to-world poses) reads like the same frames exported to folders: the same depth,
    poses and intrinsics, colour within JPEG's error; a folder holding only the .sens file reads the
    same; a pose stored as -inf (tracking lost) is a missing pose."""
    from stratamap.core.io.rgbd import write_scannet
    from stratamap.core.io.sens import write_sens

    stream = world.stream()
    frames = [(f.rgb, f.depth, f.pose) for f in stream.frames]
    n = len(frames)
    width, height = stream.intrinsics.width, stream.intrinsics.height
    big = (2 * width, 2 * height)
    sens = write_sens(tmp_path / "scene" / "scene0000_00.sens", frames, stream.intrinsics.matrix, color_size=big)
    export = write_scannet(stream, tmp_path / "export", color_size=big)
    data = PipelineData()
    got = ScanNetSource(path=str(sens), gravity="off").run(data)["frames"]
    want = ScanNetSource(path=str(export), gravity="off").run(PipelineData())["frames"]
    assert n >= 5 and len(got.frames) == n and data.notes["scannet"]["sens"]["depth_shift"] == 1000.0
    np.testing.assert_allclose(got.intrinsics.matrix, want.intrinsics.matrix, rtol=1e-6)  # .sens holds float32
    for a, b in zip(got.frames, want.frames, strict=True):
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-6)
        assert np.abs(a.rgb.astype(int) - b.rgb.astype(int)).mean() < 2.0
    folder = ScanNetSource(path=str(sens.parent), gravity="off").run(PipelineData())["frames"]
    np.testing.assert_array_equal(folder.frames[n - 1].depth, got.frames[n - 1].depth)
    frames[3] = (frames[3][0], frames[3][1], np.full((4, 4), -np.inf))
    write_sens(sens, frames, stream.intrinsics.matrix)
    with pytest.raises(DataError, match=rf"1 of {n} frames have no pose and odometry is 'never'"):
        ScanNetSource(path=str(sens), gravity="off", odometry="never").run(PipelineData())


@pytest.mark.parametrize(
    "damage,message",
    [
        (lambda b: b[: len(b) - 100], r"truncated: the header promises 3 frames, frame 2 is cut"),
        (lambda b: (3).to_bytes(4, "little") + b[4:], r"\.sens version 3; expected 4"),
        (lambda b: b[:12], r"truncated: the sensor name needs"),
    ],
)
def test_a_damaged_sens_file_is_a_one_line_error_naming_it(world, tmp_path, damage, message):
    from stratamap.core.io.sens import write_sens

    stream = world.stream()
    frames = [(f.rgb, f.depth, f.pose) for f in stream.frames][:3]
    path = write_sens(tmp_path / "a.sens", frames, stream.intrinsics.matrix)
    path.write_bytes(damage(path.read_bytes()))
    with pytest.raises(DataError, match=message) as err:
        ScanNetSource(path=str(path)).run(PipelineData())
    assert "a.sens" in str(err.value) and "\n" not in str(err.value)


def test_a_tum_benchmark_folder_without_camera_json_takes_its_cameras_calibration(tmp_path):
    """A sequence as the TUM benchmark distributes it has no camera.json: its folder's name says which
    camera took it (rgbd_dataset_freiburg3_...), and that camera's published calibration is used, with
    no warning; a folder whose name says nothing gets the Freiburg 1 defaults and a warning."""
    spec = SceneSpec.model_validate({**SMALL, "camera": {"width": 640, "height": 480}, "trajectory": {"frames": 2}})
    world = SyntheticWorld(spec)
    for name, fx, warned in (("rgbd_dataset_freiburg3_long_office_household", 535.4, False), ("my_walk", 517.3, True)):
        seq = write_sequence(world, tmp_path / name)
        (seq / "camera.json").unlink()
        data = PipelineData()
        stream = TUMSource(path=str(seq), gravity="off").run(data)["frames"]
        assert stream.intrinsics.fx == fx and stream.intrinsics.width == 640
        assert any("TUM Freiburg-1 defaults" in w for w in data.warnings) == warned, data.warnings


def test_redwood_reads_the_open3d_sample():
    root = shared_data("open3d_rgbd")
    data = PipelineData()
    stream = RedwoodSource(path=str(root)).run(data)["frames"]
    assert len(stream.frames) == 5 and stream.intrinsics.fx == 525.0
    assert data.notes["redwood"]["gravity_alignment"]["realigned"]  # its world is y-up


def test_pointcloud_reads_mosd_with_labels_dropping_nan():
    path = shared_data("mosd", "learn", "learn0.pcd")
    data = PipelineData()
    out = PointCloudSource(path=str(path), label_scheme="mosd", up_axis="-y", up_tolerance_deg=60).run(data)
    stream, gt = out["frames"], out["ground_truth"]
    assert np.isfinite(stream.points).all() and len(stream.points) < 640 * 480
    assert data.notes["pointcloud"]["points"]["dropped_invalid"] > 0
    assert stream.point_colors.shape == stream.points.shape and stream.point_colors.max() <= 1.0
    assert set(np.unique(gt.point_instance_ids)) >= {1, 2}
    table = gt.point_class_ids == gt.vocabulary.id("table")
    assert abs(np.median(stream.points[table, 2])) < 0.01  # the support plane is z = 0 after alignment


def _plane_points(origin, u, v, size_u, size_v, spacing, rng) -> np.ndarray:
    a, b = np.meshgrid(np.arange(0, size_u, spacing), np.arange(0, size_v, spacing))
    pts = np.asarray(origin) + a.reshape(-1, 1) * np.asarray(u) + b.reshape(-1, 1) * np.asarray(v)
    return pts + rng.normal(0, 0.003, pts.shape)


def test_a_tabletop_scan_whose_floor_was_never_seen_is_levelled_on_its_table(tmp_path):
    """A steep view (58 deg down) of a table before a wall larger than it in the scan, which reaches
    below the table to an unseen floor, with a slanted board leaning on the wall (a monitor). The
    wall's normal is nearer the camera's up hint than the table's, but the camera stood before it,
    not over it; the wall's lower part lies below the table; the board is the only plane with nothing
    below it. Up is the table's normal (PCL's real stereo tabletop scan was tilted 24 deg before)."""
    from stratamap.plugins.sources._gravity import find_floor

    rng = np.random.default_rng(0)
    table = _plane_points((-0.6, -0.4, 0.0), (1, 0, 0), (0, 1, 0), 1.2, 0.8, 0.01, rng)
    wall = _plane_points((-1.0, 0.45, -0.8), (1, 0, 0), (0, 0, 1), 2.0, 1.8, 0.01, rng)
    tilt = np.radians(60.0)
    board = _plane_points((-0.2, 0.1, 0.05), (1, 0, 0), (0, np.cos(tilt), np.sin(tilt)), 0.4, 0.3, 0.01, rng)
    world = np.concatenate([table, wall, board])
    # Into a camera's optical frame (y down, z forward), looking 58 deg down at the table from 1 m.
    pitch = np.radians(58.0)
    cam_z = np.array([0.0, np.cos(pitch), -np.sin(pitch)])
    cam_x = np.array([1.0, 0.0, 0.0])
    cam_y = np.cross(cam_z, cam_x)
    eye = np.array([0.0, -0.9, 1.0])
    optical = (world - eye) @ np.stack([cam_x, cam_y, cam_z], 1)
    normal, _, _ = find_floor(optical, np.array([0.0, -1.0, 0.0]), max_angle_deg=60, viewpoints=np.zeros((1, 3)))
    table_up = np.array([0.0, 0.0, 1.0]) @ np.stack([cam_x, cam_y, cam_z], 1)
    assert np.degrees(np.arccos(np.clip(normal @ table_up, -1, 1))) < 3.0


def test_the_real_stereo_tabletop_scan_is_levelled_on_its_table():
    """PCL's stereo scan of a mug on a table (a camera's frame, a steep view; a vertical panel beyond
    the table, larger than the table in the scan, reaches below it, and the floor is unseen): after
    gravity alignment the table (the image's bottom rows) is level and the rest stands on it or
    beyond it, not over the camera."""
    from stratamap.core.geometry.transforms import apply
    from stratamap.plugins.sources.pointcloud import read_cloud

    path = shared_data("pcl_scenes", "table_scene_mug_stereo_textured.pcd")
    data = PipelineData()
    PointCloudSource(path=str(path), up_axis="-y", up_tolerance_deg=60).run(data)
    transform = np.asarray(data.notes["pointcloud"]["gravity_alignment"]["transform"])
    organized, _, _ = read_cloud(path, None)
    rows = organized.reshape(480, 640, 3)[400:, 100:540].reshape(-1, 3)  # the table before the mug
    table = apply(transform, rows[np.all(np.isfinite(rows), axis=1)])
    assert len(table) > 10000
    assert np.percentile(table[:, 2], 95) - np.percentile(table[:, 2], 5) < 0.03
    camera = apply(transform, np.zeros((1, 3)))[0]
    assert camera[2] > 0.3  # the camera looked down on the table


def test_an_organized_cloud_is_read_in_its_cameras_frame_by_default(tmp_path):
    """With the defaults (``up_axis: auto``), an organized PCD (one point per pixel: a camera's frame, y
    down) is levelled on its floor seen steeply from above, and an unorganized cloud of the same points
    is taken as z-up (the floor is then not found, and the error says which axis was looked along)."""
    from stratamap.core.io.pointcloud import write_pcd

    rng = np.random.default_rng(3)
    floor = _plane_points((-1.0, 0.5, 0.0), (1, 0, 0), (0, 1, 0), 2.0, 2.0, 0.02, rng)[: 100 * 100]
    pitch = np.radians(50.0)  # the camera 1.2 m up, looking 50 deg down
    cam_z = np.array([0.0, np.cos(pitch), -np.sin(pitch)])
    cam_x = np.array([1.0, 0.0, 0.0])
    optical = (floor - [0.0, 0.0, 1.2]) @ np.stack([cam_x, np.cross(cam_z, cam_x), cam_z], 1)
    organized = write_pcd(tmp_path / "kinect.pcd", optical, organized=(100, 100))
    data = PipelineData()
    out = PointCloudSource(path=str(organized)).run(data)
    assert data.notes["pointcloud"]["gravity_alignment"]["up_axis"] == "-y"
    assert np.abs(out["frames"].points[:, 2]).max() < 0.02
    flat = write_pcd(tmp_path / "flat.pcd", optical)
    data = PipelineData()
    assert np.abs(PointCloudSource(path=str(flat)).run(data)["frames"].points[:, 2]).max() < 0.02
    assert data.notes["pointcloud"]["gravity_alignment"]["up_axis"] == "-y"
    with pytest.raises(DataError, match="looked along up_axis z:"):
        PointCloudSource(path=str(flat), up_axis="z").run(PipelineData())


def cloud_file(folder: Path, name: str, points: np.ndarray) -> Path:
    import open3d as o3d

    path = folder / name
    o3d.io.write_point_cloud(str(path), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)))
    return path


def _box_room(rng: np.random.Generator) -> np.ndarray:
    """A 5 x 4 x 2.6 m room, z up: its floor, four walls and 60 % of its ceiling (scans miss some of it)."""
    floor = _plane_points((0, 0, 0), (1, 0, 0), (0, 1, 0), 5.0, 4.0, 0.05, rng)
    ceiling = _plane_points((0, 0, 2.6), (1, 0, 0), (0, 1, 0), 3.0, 4.0, 0.05, rng)
    walls = [
        _plane_points((0, 0, 0), (1, 0, 0), (0, 0, 1), 5.0, 2.6, 0.05, rng),
        _plane_points((0, 4, 0), (1, 0, 0), (0, 0, 1), 5.0, 2.6, 0.05, rng),
        _plane_points((0, 0, 0), (0, 1, 0), (0, 0, 1), 4.0, 2.6, 0.05, rng),
        _plane_points((5, 0, 0), (0, 1, 0), (0, 0, 1), 4.0, 2.6, 0.05, rng),
    ]
    return np.vstack([floor, ceiling, *walls])


def test_a_room_stored_y_up_is_flagged_by_auto_and_read_with_its_up_axis(tmp_path):
    """A room scan stored y up (glTF's and phone scanners' convention), read with ``up_axis: auto``: the
    z-up guess finds a wall for the floor (a bounding plane, all points on one side of it), and a
    plane along y larger than that "floor" makes it a warning naming the file and ``up_axis y``. With
    ``up_axis: y`` the floor is z = 0 and nothing is flagged; the same room stored z up is not flagged."""
    room = _box_room(np.random.default_rng(5))
    y_up = cloud_file(tmp_path, "phone.ply", np.c_[room[:, 0], room[:, 2], -room[:, 1]])
    data = PipelineData()
    PointCloudSource(path=str(y_up)).run(data)
    flagged = [w for w in data.warnings if "up_axis auto took" in w]
    assert len(flagged) == 1 and "phone.ply" in flagged[0] and "set up_axis y" in flagged[0], data.warnings
    assert data.notes["pointcloud"]["gravity_alignment"]["other_axes"]["y"] > 0
    data = PipelineData()
    out = PointCloudSource(path=str(y_up), up_axis="y").run(data)
    z = out["frames"].points[:, 2]
    assert abs(np.percentile(z, 1)) < 0.02 and 2.55 < np.percentile(z, 99.5) < 2.65
    assert not [w for w in data.warnings if "up_axis" in w]
    data = PipelineData()
    PointCloudSource(path=str(cloud_file(tmp_path, "lidar.ply", room))).run(data)
    assert not [w for w in data.warnings if "up_axis" in w], data.warnings


def test_a_fused_walk_whose_walls_outsize_its_seen_floor_is_not_flagged_z_up(tmp_path):
    """A walk's fused room: 5 x 4 m, its floor seen on a 1.3 m strip (furniture hides the rest), its
    walls seen up to 1.6 m, no ceiling; each long wall holds more points than the seen floor. Stored
    z up it is not flagged (the map spans 1.6 m along z, 4 m along y: rooms are wider than tall);
    stored on its side it still is."""
    rng = np.random.default_rng(3)
    room = np.vstack(
        [
            _plane_points((0, 1.0, 0), (1, 0, 0), (0, 1, 0), 5.0, 1.3, 0.05, rng),
            _plane_points((0, 0, 0), (1, 0, 0), (0, 0, 1), 5.0, 1.6, 0.05, rng),
            _plane_points((0, 4, 0), (1, 0, 0), (0, 0, 1), 5.0, 1.6, 0.05, rng),
            _plane_points((0, 0, 0), (0, 1, 0), (0, 0, 1), 4.0, 1.6, 0.05, rng),
            _plane_points((5, 0, 0), (0, 1, 0), (0, 0, 1), 4.0, 1.6, 0.05, rng),
        ]
    )
    data = PipelineData()
    PointCloudSource(path=str(cloud_file(tmp_path, "fused.ply", room))).run(data)
    alignment = data.notes["pointcloud"]["gravity_alignment"]
    assert alignment["up_axis"] == "z" and alignment["other_axes"]["y"] > alignment["floor_inliers"]
    assert not [w for w in data.warnings if "up_axis" in w], data.warnings
    data = PipelineData()
    PointCloudSource(path=str(cloud_file(tmp_path, "side.ply", np.c_[room[:, 0], room[:, 2], -room[:, 1]]))).run(data)
    assert [w for w in data.warnings if "side.ply" in w and "set up_axis y" in w], data.warnings


def test_a_real_room_scan_stored_y_up_is_flagged(tmp_path):
    """PCL's real 360-degree room scan turned y up: ``auto`` takes a wall for the floor along z, and says
    so (the floor along y is 3.5 times its size); z up as scanned, nothing is flagged."""
    from stratamap.core.io.pointcloud import read_point_cloud

    points = read_point_cloud(shared_data("pcl_scenes", "room_scan1.pcd"), "label").points
    points = points[np.all(np.isfinite(points), axis=1)]
    data = PipelineData()
    PointCloudSource(path=str(cloud_file(tmp_path, "scan.ply", points))).run(data)
    assert not [w for w in data.warnings if "up_axis" in w], data.warnings
    turned = np.c_[points[:, 0], points[:, 2], -points[:, 1]]
    data = PipelineData()
    PointCloudSource(path=str(cloud_file(tmp_path, "turned.ply", turned))).run(data)
    assert [w for w in data.warnings if "set up_axis y" in w], data.warnings


def test_a_scanned_room_mesh_is_read_as_points_on_its_surface(tmp_path):
    """A mesh (a PLY with faces, an OBJ) is sampled evenly on its surface, one point per mesh_spacing^2,
    with its colours, the same points on every read; its 72 vertices alone could not show its floor."""
    mesh = low_poly_room()
    path = tmp_path / "room.ply"
    mesh.export(path)
    data = PipelineData()
    out = PointCloudSource(path=str(path), mesh_spacing=0.05).run(data)
    points = out["frames"].points
    assert len(mesh.vertices) == 72 and abs(len(points) - mesh.area / 0.05**2) <= 1
    assert data.notes["pointcloud"]["mesh"] == {"triangles": 84, "area_m2": round(mesh.area, 3), "spacing_m": 0.05}
    assert np.allclose(out["frames"].point_colors, [180 / 255, 160 / 255, 140 / 255], atol=0.01)
    z = points[:, 2]
    assert (np.abs(z) < 0.01).mean() > 0.15 and not data.warnings  # the floor at z = 0, z up taken as stored
    again = PointCloudSource(path=str(path), mesh_spacing=0.05).run(PipelineData())["frames"].points
    assert np.array_equal(points, again)
    mesh.export(tmp_path / "room.obj")
    from_obj = PointCloudSource(path=str(tmp_path / "room.obj"), mesh_spacing=0.05).run(PipelineData())
    from_obj = from_obj["frames"].points
    assert abs(len(from_obj) - len(points)) <= 1 and abs(np.percentile(from_obj[:, 2], 99) - 2.6) < 0.02


@pytest.mark.slow
def test_a_gltf_room_is_turned_z_up_by_its_specification(tmp_path):
    """glTF is y up by its specification: a GLB room is turned z up as read, levelled without a guess or
    a warning, and its points are the PLY's; an up_axis given says how the file itself is stored."""
    import trimesh

    mesh = low_poly_room()
    mesh.export(tmp_path / "room.ply")
    stored = mesh.copy()
    stored.apply_transform([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])  # z up -> glTF's y up
    trimesh.Scene([stored]).export(tmp_path / "room.glb")
    data = PipelineData()
    glb = PointCloudSource(path=str(tmp_path / "room.glb"), mesh_spacing=0.05).run(data)["frames"].points
    ply = PointCloudSource(path=str(tmp_path / "room.ply"), mesh_spacing=0.05).run(PipelineData())["frames"].points
    assert np.allclose(glb, ply, atol=1e-4)
    assert data.notes["pointcloud"]["gravity_alignment"]["converted_from"] == "glTF y up" and not data.warnings
    data = PipelineData()
    out = PointCloudSource(path=str(tmp_path / "room.glb"), up_axis="y", mesh_spacing=0.05).run(data)
    out = out["frames"].points
    assert np.allclose(out, ply, atol=1e-3)
    trimesh.Scene([mesh]).export(tmp_path / "z_up.glb")  # written z up, against the specification
    data = PipelineData()
    PointCloudSource(path=str(tmp_path / "z_up.glb"), mesh_spacing=0.05).run(data)
    assert any("z_up.glb: taken y up, as glTF specifies" in w and w.endswith("set up_axis z") for w in data.warnings)
    out = PointCloudSource(path=str(tmp_path / "z_up.glb"), up_axis="z", mesh_spacing=0.05).run(PipelineData())
    assert np.allclose(out["frames"].points, ply, atol=1e-3)


def test_a_mesh_larger_than_its_point_budget_is_sampled_sparser_with_a_warning(tmp_path):
    mesh = low_poly_room()
    path = tmp_path / "room.ply"
    mesh.export(path)
    data = PipelineData()
    out = PointCloudSource(path=str(path), mesh_max_points=20000).run(data)
    assert len(out["frames"].points) == 20000
    assert any("room.ply" in w and "sampled every 0.069 m" in w for w in data.warnings), data.warnings
    assert data.notes["pointcloud"]["mesh"]["spacing_m"] == pytest.approx(np.sqrt(mesh.area / 20000), abs=1e-4)


def test_pointcloud_formats_and_errors(tmp_path):
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(0, 1, (500, 2)), np.zeros(500)]
    np.save(tmp_path / "c.npy", np.c_[pts, np.full(500, 3)])
    out = read(PointCloudSource(path=str(tmp_path / "c.npy"), gravity="off"))
    assert len(out["frames"].points) == 500 and set(np.unique(out["ground_truth"].point_instance_ids)) == {3}
    np.save(tmp_path / "bad.npy", np.zeros((10, 5)))
    with pytest.raises(DataError, match="expected an"):
        read(PointCloudSource(path=str(tmp_path / "bad.npy")))
    (tmp_path / "c.rcp").write_text("x")
    with pytest.raises(DataError, match="unsupported"):
        read(PointCloudSource(path=str(tmp_path / "c.rcp")))


def _held_upright(level: Path, folder: Path) -> Path:
    """``level``'s TUM sequence as a phone held upright records it: images turned a quarter clockwise,
    intrinsics to match, poses turned with them and given from the first camera (as odometry gives
    them: no z-up world to lean on)."""
    from scipy.spatial.transform import Rotation

    shutil.copytree(level, folder)
    shutil.rmtree(folder / "gt", ignore_errors=True)
    for sub in ("rgb", "depth"):
        for path in sorted((folder / sub).glob("*.png")):
            Image.fromarray(np.ascontiguousarray(np.rot90(np.asarray(Image.open(path)), -1))).save(path)
    cam = json.loads((folder / "camera.json").read_text())
    cam.update(
        width=cam["height"],
        height=cam["width"],
        fx=cam["fy"],
        fy=cam["fx"],
        cx=cam["height"] - 1 - cam["cy"],
        cy=cam["cx"],
    )
    (folder / "camera.json").write_text(json.dumps(cam))
    quarter = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    rows, first = [], None
    for line in (folder / "groundtruth.txt").read_text().splitlines():
        if line.startswith("#"):
            continue
        t, *v = line.split()
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_quat([float(x) for x in v[3:]]).as_matrix() @ quarter
        pose[:3, 3] = [float(x) for x in v[:3]]
        first = np.linalg.inv(pose) if first is None else first
        pose = first @ pose
        quat = Rotation.from_matrix(pose[:3, :3]).as_quat()
        rows.append(" ".join([t, *(f"{x:.9f}" for x in (*pose[:3, 3], *quat))]))
    (folder / "groundtruth.txt").write_text("\n".join(rows) + "\n")
    return folder


def test_a_camera_held_upright_is_levelled_on_the_floor_not_a_wall(tmp_path):
    """A phone recording upright has image right up: held level, the floor search finds a wall. The
    floor is where the cameras' heights hold steady; the map stands on it, and the warning says so.
    A level walk's floor stands as before, without a word."""
    spec = SceneSpec.model_validate(
        {"type": "room", "seed": 2, "camera": {"width": 160, "height": 120}, "trajectory": {"frames": 30}}
    )
    level = write_sequence(SyntheticWorld(spec), tmp_path / "level")
    data = PipelineData()
    TUMSource(path=str(level), load_ground_truth=False).run(data)
    assert not any("held" in w for w in data.warnings), data.warnings
    assert data.notes["tum"]["gravity_alignment"]["rotation_deg"] < 2  # the walk's world is z-up already

    upright = _held_upright(level, tmp_path / "upright")
    data = PipelineData()
    out = TUMSource(path=str(upright), load_ground_truth=False).run(data)
    assert data.notes["tum"]["gravity_alignment"]["camera_held"].startswith("turned a quarter")
    assert any("as a phone recording upright holds it" in w for w in data.warnings)
    # Levelled: each camera at the walk's height (1.3 m) over the floor, its image right pointing up.
    frames = out["frames"].frames
    for k in (0, len(frames) // 2, len(frames) - 1):
        pose = frames[k].pose
        assert abs(pose[2, 3] - 1.3) < 0.05 and pose[2, 0] > 0.9, pose


def test_a_camera_looking_steeply_down_is_levelled_on_the_floor(tmp_path):
    """A handheld camera looking down at a desk, held level: its image's up leans back by its pitch,
    here over 35 degrees from the true up (as TUM fr1/rpy's Kinect over office desks). The floor is
    sought again within a wider angle of that hint before the camera is taken for turned; the map's
    z-up world stands as it was, without a warning."""
    from stratamap.plugins.sources._gravity import camera_up_hint

    spec = SceneSpec.model_validate(
        {
            "type": "room",
            "seed": 2,
            "camera": {"width": 160, "height": 120},
            "trajectory": {"type": "fixed", "frames": 4, "height": 1.7, "look_height": -1.5},
        }
    )
    folder = write_sequence(SyntheticWorld(spec), tmp_path / "down")
    raw = TUMSource(path=str(folder), load_ground_truth=False, gravity="off").run(PipelineData())["frames"]
    hint = camera_up_hint(raw)
    assert np.degrees(np.arccos(hint[2])) > 36  # the level camera's hint misses the floor's 35-degree window
    data = PipelineData()
    TUMSource(path=str(folder), load_ground_truth=False).run(data)
    alignment = data.notes["tum"]["gravity_alignment"]
    assert alignment["rotation_deg"] < 2 and "camera_held" not in alignment, alignment
    assert not any("held" in w for w in data.warnings), data.warnings
