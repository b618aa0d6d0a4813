"""Bad inputs to the file readers of core/io: one named case per failure, each building its own fixture.

Every case must end in a ``DataError`` whose one-line message names the file and says what was expected
(issue 27: "nothing lost, nothing silent"); a few valid twins check the readers still read what they should.
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from stratamap.core.errors import DataError
from stratamap.core.io.mesh import read_mesh
from stratamap.core.io.nav2 import read_map, write_map
from stratamap.core.io.pointcloud import read_point_cloud, write_point_cloud
from stratamap.core.io.rgbd import (
    intrinsics_from,
    parse_tum_poses,
    read_depth,
    read_laser_file,
    read_rgb,
    read_timestamped_list,
    rigid_pose,
)
from stratamap.core.io.urdf import read_urdf
from stratamap.core.map.layers import OccupancyGrid

N = 40


def small_cloud(n: int = N, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
    colors = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    labels = rng.integers(0, 30, n).astype(np.int32)
    return points, colors, labels


def write_cloud(path: Path, binary: bool = True, n: int = N) -> Path:
    """A valid small cloud in the format ``path``'s suffix names (colors and a label field where it can)."""
    points, colors, labels = small_cloud(n)
    if path.suffix in (".ply", ".pcd"):
        return write_point_cloud(path, points, colors, {"label": labels}, binary=binary)
    if path.suffix == ".npy":
        return write_point_cloud(path, points, colors / 255.0, {"label": labels})
    return write_point_cloud(path, points, colors / 255.0)  # .xyz: x y z r g b


def cut(path: Path, fraction: float = 0.5) -> Path:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])
    return path


def replace(path: Path, old: bytes, new: bytes) -> Path:
    data = path.read_bytes()
    assert old in data, old
    path.write_bytes(data.replace(old, new, 1))
    return path


def put(folder: Path, name: str, content: str | bytes) -> Path:
    path = folder / name
    if isinstance(content, str):
        path.write_text(content)
    else:
        path.write_bytes(content)
    return path


def ascii_ply(tmp: Path) -> Path:
    return write_cloud(tmp / "c.ply", binary=False)


def ascii_pcd(tmp: Path) -> Path:
    return write_cloud(tmp / "c.pcd", binary=False)


def compressed_pcd(tmp: Path) -> Path:
    import open3d as o3d

    points, _, _ = small_cloud(200)
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(points))
    o3d.t.io.write_point_cloud(str(tmp / "c.pcd"), cloud, write_ascii=False, compressed=True)
    return tmp / "c.pcd"


def npy(tmp: Path, array: np.ndarray, name: str = "c.npy") -> Path:
    np.save(tmp / name, array)
    return tmp / name


def ply_with_faces(tmp: Path, index: int) -> Path:
    text = (
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        f"0 0 0\n1 0 0\n0 1 0\n3 0 1 {index}\n"
    )
    (tmp / "m.ply").write_text(text)
    return tmp / "m.ply"


#: case -> (build the file in a folder, what the error must say)
CLOUD_CASES: dict[str, tuple[Callable[[Path], Path], str]] = {
    "ply-binary-cut-in-half": (
        lambda t: cut(write_cloud(t / "c.ply")),
        r"c\.ply: truncated or corrupt: the header promises 40 vertex rows \(\d+ bytes of binary_little_endian",
    ),
    "ply-ascii-cut-in-half": (
        lambda t: cut(ascii_ply(t)),
        r"c\.ply: truncated or corrupt: the header promises 40 vertex rows, the file holds \d+ rows",
    ),
    "ply-ascii-cut-mid-line": (
        lambda t: cut(ascii_ply(t), 0.73),
        r"c\.ply: truncated or corrupt: the header promises 40 vertex rows, the file holds \d+ rows and a cut one",
    ),
    "pcd-ascii-cut-in-half": (
        lambda t: cut(ascii_pcd(t)),
        r"c\.pcd: truncated or corrupt: the header promises 40 points \(POINTS 40\), the file holds \d+ rows",
    ),
    "pcd-binary-cut-in-half": (
        lambda t: cut(write_cloud(t / "c.pcd")),
        r"c\.pcd: truncated or corrupt: the header promises 40 points",
    ),
    "pcd-binary-compressed-cut": (lambda t: cut(compressed_pcd(t)), r"c\.pcd: truncated or corrupt"),
    "pcd-binary-compressed-corrupt-sizes": (
        lambda t: replace(compressed_pcd(t), b"DATA binary_compressed\n", b"DATA binary_compressed\n\x01\x00"),
        r"c\.pcd: the compressed block unpacks to",
    ),
    "ply-header-promises-more": (
        lambda t: replace(write_cloud(t / "c.ply"), b"element vertex 40", b"element vertex 80"),
        r"c\.ply: truncated or corrupt: the header promises 80 vertex rows",
    ),
    "ply-header-promises-fewer": (
        lambda t: replace(write_cloud(t / "c.ply"), b"element vertex 40", b"element vertex 20"),
        r"c\.ply: \d+ bytes follow the 20 vertex rows the header promises",
    ),
    "ply-ascii-extra-rows": (
        lambda t: replace(ascii_ply(t), b"element vertex 40", b"element vertex 39"),
        r"c\.ply:\d+: 1 more rows than the 39 vertex rows the header promises",
    ),
    "ply-ascii-not-a-number": (
        lambda t: replace(ascii_ply(t), b"end_header\n", b"end_header\nabc 0 0 1 2 3 4\n"),
        r"c\.ply:\d+: 'abc' is not a number",
    ),
    "ply-ascii-row-short": (
        lambda t: replace(ascii_ply(t), b"end_header\n", b"end_header\n1 2\n"),
        r"c\.ply:\d+: vertex row 1 of 40 has 2 values, expected 7 \(x y z red green blue label\)",
    ),
    "ply-uchar-out-of-range": (
        lambda t: replace(ascii_ply(t), b"end_header\n", b"end_header\n0 0 0 300 0 0 1\n"),
        r"c\.ply: vertex property 'red' \(uchar\), row 1: 300 is not a uint8 value",
    ),
    "ply-no-end-header": (
        lambda t: replace(write_cloud(t / "c.ply"), b"end_header", b"end_heder"),
        r"c\.ply: no 'end_header' line",
    ),
    "ply-unknown-type": (
        lambda t: replace(write_cloud(t / "c.ply"), b"property float x", b"property float128 x"),
        r"c\.ply: header line \d+: expected 'property TYPE NAME'",
    ),
    "ply-no-z": (
        lambda t: replace(write_cloud(t / "c.ply"), b"property float z", b"property float w"),
        r"c\.ply: the vertex element has no scalar 'z' property",
    ),
    "ply-not-ply": (lambda t: put(t, "c.ply", b"solid mesh\n"), r"c\.ply: not a PLY file"),
    "ply-face-index-out-of-range": (
        lambda t: ply_with_faces(t, 7),
        r"m\.ply: a face uses vertex index 7, but there are 3 vertices",
    ),
    "pcd-points-not-width-times-height": (
        lambda t: replace(write_cloud(t / "c.pcd"), b"HEIGHT 1", b"HEIGHT 2"),
        r"c\.pcd: the header says POINTS 40 but WIDTH x HEIGHT is 40 x 2 = 80",
    ),
    "pcd-size-count-mismatch": (
        lambda t: replace(write_cloud(t / "c.pcd"), b"SIZE 4 4 4", b"SIZE 4 4"),
        r"c\.pcd: header line \d+: SIZE has \d+ values for \d+ FIELDS",
    ),
    "pcd-no-x": (
        lambda t: replace(write_cloud(t / "c.pcd"), b"FIELDS x", b"FIELDS q"),
        r"c\.pcd: no 'x' field",
    ),
    "pcd-bad-type": (
        lambda t: replace(write_cloud(t / "c.pcd"), b"TYPE F", b"TYPE Q"),
        r"c\.pcd: header line \d+: field 'x' has TYPE Q SIZE 4",
    ),
    "pcd-no-data-line": (
        lambda t: replace(write_cloud(t / "c.pcd"), b"DATA binary", b"DAT binary"),
        r"c\.pcd: (header line \d+: unexpected|no 'DATA)",
    ),
    "pcd-ascii-extra-rows": (
        lambda t: replace(replace(ascii_pcd(t), b"POINTS 40", b"POINTS 39"), b"WIDTH 40", b"WIDTH 39"),
        r"c\.pcd:\d+: 1 more rows than the POINTS 39",
    ),
    "empty-ply": (lambda t: put(t, "c.ply", b""), r"c\.ply: empty file"),
    "empty-pcd": (lambda t: put(t, "c.pcd", b""), r"c\.pcd: empty file"),
    "empty-xyz": (lambda t: put(t, "c.xyz", "\n# nothing\n"), r"c\.xyz: empty: no points"),
    "empty-npy-file": (lambda t: put(t, "c.npy", b""), r"c\.npy: empty file"),
    "ply-zero-points": (
        lambda t: write_cloud(t / "c.ply", n=0),
        r"c\.ply: the header declares no points",
    ),
    "xyz-ragged-line": (
        lambda t: put(t, "c.xyz", "0 0 0\n1 1 1\n2 2\n3 3 3\n"),
        r"c\.xyz:3: 2 values, expected 3 \(xyz\)",
    ),
    "xyz-not-a-number": (
        lambda t: put(t, "c.xyz", "0 0 0\n1 x 1\n"),
        r"c\.xyz:2: 'x' is not a number",
    ),
    "xyz-five-columns": (
        lambda t: put(t, "c.xyz", "0 0 0 1 1\n"),
        r"c\.xyz:1: 5 values per line; a \.xyz file has 3 \(xyz\), 4",
    ),
    "pts-count-mismatch": (
        lambda t: put(t, "c.pts", "3\n0 0 0\n1 1 1\n"),
        r"c\.pts: the first line promises 3 points, the file has 2",
    ),
    "npy-truncated": (
        lambda t: cut(npy(t, np.zeros((100, 3)))),
        r"c\.npy: truncated: the header promises a \(100, 3\)",
    ),
    "npy-complex-dtype": (
        lambda t: npy(t, np.zeros((10, 3), np.complex64)),
        r"c\.npy: expected an integer or float array, got dtype complex64",
    ),
    "npy-string-dtype": (
        lambda t: npy(t, np.full((10, 3), "a")),
        r"c\.npy: expected an integer or float array, got dtype <U1",
    ),
    "npy-object-dtype": (
        lambda t: (np.save(t / "c.npy", np.array([[1, "a", None]], dtype=object), allow_pickle=True), t / "c.npy")[1],
        r"c\.npy: expected an integer or float array, got dtype object",
    ),
    "npy-bool-dtype": (lambda t: npy(t, np.zeros((10, 3), bool)), r"c\.npy: expected an integer or float array"),
    "npy-wrong-shape": (lambda t: npy(t, np.zeros((10, 5))), r"c\.npy: expected an \(N, 3\|4\|6\|7\) array"),
    "npy-not-npy": (
        lambda t: put(t, "c.npy", b"PK\x03\x04 this is a zip"),
        r"c\.npy: not a \.npy array file",
    ),
    "unsupported-suffix": (lambda t: put(t, "c.rcp", b"RCP"), r"c\.rcp: unsupported point"),
    "las-header-cut": (lambda t: put(t, "c.las", b"LASF"), r"c\.las: not a LAS file \(no 'LASF' header of 227"),
}


@pytest.mark.parametrize("case", sorted(CLOUD_CASES))
def test_bad_point_cloud(case, tmp_path):
    build, message = CLOUD_CASES[case]
    path = build(tmp_path)
    with pytest.raises(DataError, match=message) as err:
        read_point_cloud(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)


@pytest.mark.parametrize("suffix,binary", [(".ply", True), (".ply", False), (".pcd", True), (".pcd", False)])
def test_writer_and_reader_agree(tmp_path, suffix, binary):
    points, colors, labels = small_cloud()
    points[3] = np.nan  # organized clouds mark no-return pixels with NaN: kept as read
    path = write_point_cloud(tmp_path / f"c{suffix}", points, colors, {"label": labels}, binary=binary)
    cloud = read_point_cloud(path)
    np.testing.assert_array_equal(cloud.points, points.astype(np.float64))
    np.testing.assert_allclose(cloud.colors, colors / 255.0)
    np.testing.assert_array_equal(cloud.fields["label"], labels)


def test_open3d_reads_what_we_write_and_we_read_what_open3d_writes(tmp_path):
    import open3d as o3d

    points, colors, _ = small_cloud()
    for suffix, binary in ((".ply", True), (".pcd", False), (".pcd", True)):
        path = write_point_cloud(tmp_path / f"ours{suffix}", points, colors, binary=binary)
        theirs = o3d.t.io.read_point_cloud(str(path))
        np.testing.assert_allclose(theirs.point.positions.numpy(), points)
        c = theirs.point.colors.numpy().astype(float)
        np.testing.assert_allclose(c / 255 if c.max() > 1 else c, colors / 255.0, atol=1e-6)
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(points))
    cloud.point.colors = o3d.core.Tensor(colors)
    for name, kwargs in (("a.ply", {"write_ascii": True}), ("b.pcd", {"compressed": True})):
        o3d.t.io.write_point_cloud(str(tmp_path / name), cloud, **kwargs)
        ours = read_point_cloud(tmp_path / name)
        np.testing.assert_allclose(ours.points, points, atol=1e-6)
        np.testing.assert_allclose(ours.colors, colors / 255.0, atol=1e-6)


def test_text_and_npy_layouts(tmp_path):
    (tmp_path / "a.pts").write_text("2\n0 0 0 5 255 0 0\n1 1 1 6 0 255 0\n")
    cloud = read_point_cloud(tmp_path / "a.pts")
    assert cloud.points.shape == (2, 3) and cloud.fields["intensity"].tolist() == [5, 6]
    np.testing.assert_allclose(cloud.colors, [[1, 0, 0], [0, 1, 0]])
    cloud = read_point_cloud(npy(tmp_path, np.array([[0, 0, 0, 3.0], [1, 1, 1, 4.0]])), label_field="seg")
    assert cloud.fields["seg"].tolist() == [3, 4] and cloud.colors is None


# --------------------------------------------------------------------------------------------- meshes


def test_mesh_with_out_of_range_indices(tmp_path):
    with pytest.raises(DataError, match=r"m\.ply: a face uses vertex index 7, but there are 3 vertices \(0\.\.2\)"):
        read_mesh(ply_with_faces(tmp_path, 7))
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    with pytest.raises(DataError, match=r"m\.obj: cannot be read as a mesh"):
        read_mesh(tmp_path / "m.obj")
    (tmp_path / "n.obj").write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(DataError, match=r"n\.obj: 1 vertices are NaN or infinite"):
        read_mesh(tmp_path / "n.obj")
    (tmp_path / "e.stl").write_bytes(b"")
    with pytest.raises(DataError, match=r"e\.stl"):
        read_mesh(tmp_path / "e.stl")
    assert len(read_mesh(ply_with_faces(tmp_path, 2)).faces) == 1


# --------------------------------------------------------------------------------------------- RGB-D files


def png(path: Path, array: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)
    return path


def test_image_size_disagrees_with_the_camera(tmp_path):
    rgb = png(tmp_path / "rgb.png", np.zeros((6, 8, 3), np.uint8))
    with pytest.raises(DataError, match=r"rgb\.png: color image is 8x6, expected 10x6 as the camera intrinsics say"):
        read_rgb(rgb, (6, 10))
    with pytest.raises(DataError, match=r"image size mismatch"):
        read_rgb(rgb, (3, 8), resample=True)  # another aspect ratio: not resampled
    assert read_rgb(rgb, (3, 4), resample=True).shape == (3, 4, 3)
    depth = png(tmp_path / "d.png", np.full((6, 8), 5000, np.uint16))
    with pytest.raises(DataError, match=r"d\.png: depth is 8x6, expected 10x6 as the camera intrinsics say"):
        read_depth(depth, 5000, (6, 10))


def test_16_bit_and_float_depth(tmp_path):
    """16UC1-like PNG in units and 32FC1-like float TIFF in metres read the same; float mm or 8-bit is an error."""
    mm = np.full((6, 8), 1500, np.uint16)
    a = read_depth(png(tmp_path / "a.png", mm), 1000.0)
    b = read_depth(png(tmp_path / "b.tiff", mm.astype(np.float32) / 1000), 1000.0)
    np.testing.assert_allclose(a, b)
    with pytest.raises(DataError, match=r"c\.tiff: float depth with median 1500: looks like millimetres"):
        read_depth(png(tmp_path / "c.tiff", mm.astype(np.float32)), 1000.0)
    with pytest.raises(DataError, match=r"e\.png: depth is 8-bit"):
        read_depth(png(tmp_path / "e.png", np.full((6, 8), 7, np.uint8)), 1000.0)
    with pytest.raises(DataError, match=r"f\.png: depth must be single-channel"):
        read_depth(png(tmp_path / "f.png", np.zeros((6, 8, 3), np.uint8)), 1000.0)
    (tmp_path / "g.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)
    with pytest.raises(DataError, match=r"g\.png: cannot be read as an image"):
        read_depth(tmp_path / "g.png", 1000.0)
    nan = np.array([[np.nan, np.inf], [-np.inf, 1.5]], np.float32)
    np.testing.assert_array_equal(read_depth(png(tmp_path / "n.tiff", nan), 1000.0), [[0, 0], [0, 1.5]])


TIMESTAMP_CASES = {
    "missing-timestamp": ("rgb/1.png\n", r"l\.txt:1: expected a timestamp, got 'rgb/1.png'"),
    "missing-file-name": ("1.0 rgb/1.png\n2.0\n", r"l\.txt:2: expected a timestamp and an image file name"),
    "duplicated-timestamp": (
        "1.0 a.png\n2.0 b.png\n2.0 c.png\n",
        r"l\.txt:3: timestamps are not increasing: entry 3 repeats \(2\.0 then 2\.0\)",
    ),
    "timestamps-go-back": ("1.0 a.png\n3.0 b.png\n2.0 c.png\n", r"l\.txt:3: .*entry 3 goes back in time"),
    "nan-timestamp": ("nan a.png\n", r"l\.txt:1: timestamp 'nan' is not a finite number"),
    "empty": ("# only a comment\n", r"l\.txt: no entries"),
}


@pytest.mark.parametrize("case", sorted(TIMESTAMP_CASES))
def test_bad_timestamp_list(case, tmp_path):
    text, message = TIMESTAMP_CASES[case]
    (tmp_path / "l.txt").write_text(text)
    with pytest.raises(DataError, match=message):
        read_timestamped_list(tmp_path / "l.txt", 1, "an image file name")


def test_bad_trajectories(tmp_path):
    (tmp_path / "g.txt").write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(DataError, match=r"g\.txt: not a text file"):
        parse_tum_poses(tmp_path / "g.txt")
    (tmp_path / "g.txt").write_text("1.0 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n")
    with pytest.raises(DataError, match=r"g\.txt:2: timestamps are not increasing: entry 2 goes back in time"):
        parse_tum_poses(tmp_path / "g.txt")
    (tmp_path / "g.txt").write_text("1.0 0 0 0 0 0 0 1\n2.0 0 nan 0 0 0 0 1\n")
    with pytest.raises(DataError, match=r"g\.txt: entry 2 is not a valid pose"):
        parse_tum_poses(tmp_path / "g.txt")
    (tmp_path / "g.txt").write_text("1.0 0 0 0 0 0 0 one\n")
    with pytest.raises(DataError, match=r"g\.txt: entry 1 holds a value that is not a number"):
        parse_tum_poses(tmp_path / "g.txt")
    with pytest.raises(DataError, match=r"pose 3: not a rigid transform"):
        rigid_pose(np.diag([2.0, 1, 1, 1]), "pose 3")
    with pytest.raises(DataError, match=r"pose 4: the pose holds NaN"):
        rigid_pose(np.full((4, 4), np.nan), "pose 4")
    (tmp_path / "laser.txt").write_text("1 0 0 0 0 -1 0.1 5 1 1 1\n0.5 0 0 0 0 -1 0.1 5 1 1 1\n")
    with pytest.raises(DataError, match=r"laser\.txt:2: timestamp 0\.5 does not follow 1\.0"):
        read_laser_file(tmp_path / "laser.txt")


@pytest.mark.parametrize(
    "camera,message",
    [
        ({"width": 8, "height": 6, "fx": 0, "fy": 5, "cx": 4, "cy": 3}, r"cam\.json: fx must be positive"),
        ({"width": 8, "height": 6, "fx": "a", "fy": 5, "cx": 4, "cy": 3}, r"cam\.json: fx must be a finite number"),
        ({"width": 8.5, "height": 6, "fx": 5, "fy": 5, "cx": 4, "cy": 3}, r"cam\.json: width must be a whole number"),
        ({"width": 8, "height": 6, "fx": 5, "fy": 5, "cx": float("nan"), "cy": 3}, r"cam\.json: cx must be a finite"),
        ({"width": 8}, r"cam\.json: missing height, fx, fy, cx, cy"),
        ([1, 2], r"cam\.json: expected an object with width, height"),
    ],
)
def test_bad_camera(camera, message):
    with pytest.raises(DataError, match=message):
        intrinsics_from(camera, "cam.json")


# --------------------------------------------------------------------------------------------- URDF


URDF = """<robot name="r">
  <link name="base"><visual><geometry><box size="1 1 1"/></geometry></visual></link>
  <link name="door"/>
  <joint name="hinge" type="revolute"><parent link="base"/><child link="door"/>
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="0" upper="1.5"/></joint>
</robot>
"""

URDF_CASES = {
    "bad-number": (
        ('xyz="0 0 0"', 'xyz="0 zero 0"'),
        r"r\.urdf: joint 'hinge' <origin> xyz: expected 3 finite numbers",
    ),
    "nan-number": (('upper="1.5"', 'upper="nan"'), r"r\.urdf: joint 'hinge' <limit> upper: expected 1 finite"),
    "two-values": (('rpy="0 0 0"', 'rpy="0 0"'), r"joint 'hinge' <origin> rpy: expected 3 finite numbers, got '0 0'"),
    "zero-axis": (('<axis xyz="0 0 1"/>', '<axis xyz="0 0 0"/>'), r"joint 'hinge': a revolute joint needs a non-zero"),
    "unknown-type": (('type="revolute"', 'type="hinge"'), r"joint 'hinge': type 'hinge' is not one of"),
    "undefined-link": (('<child link="door"/>', '<child link="lid"/>'), r"names link 'lid', which is not defined"),
    "cycle": (
        ('<child link="door"/>', '<child link="base"/>'),
        r"r\.urdf: links \['base'\] are not connected to the root 'door' \(a joint cycle\?\)",
    ),
    "two-links-one-name": (('<link name="door"/>', '<link name="base"/>'), r"link 'base' is defined twice"),
    "bad-box": (('size="1 1 1"', 'size="1 1"'), r"link 'base' visual 0 <box> size: expected 3 finite numbers"),
    "not-xml": (("</robot>", "</robt>"), r"r\.urdf: not valid XML"),
    "not-a-robot": (('<robot name="r">', '<sdf name="r">'), r"r\.urdf: (not valid XML|root element is <sdf>)"),
}


@pytest.mark.parametrize("case", sorted(URDF_CASES))
def test_bad_urdf(case, tmp_path):
    (old, new), message = URDF_CASES[case]
    assert old in URDF
    (tmp_path / "r.urdf").write_text(URDF.replace(old, new))
    with pytest.raises(DataError, match=message):
        read_urdf(tmp_path / "r.urdf")


def test_urdf_mesh_with_bad_indices_falls_back_with_a_warning(tmp_path):
    ply_with_faces(tmp_path, 9)
    text = URDF.replace('<box size="1 1 1"/>', '<mesh filename="m.ply"/>').replace(
        "</visual>", '</visual><collision><geometry><box size="1 1 1"/></geometry></collision>'
    )
    (tmp_path / "r.urdf").write_text(text)
    model = read_urdf(tmp_path / "r.urdf")
    assert len(model.links["base"]) == 1
    assert "a face uses vertex index 9" in model.warnings[0] and "collision geometry box" in model.warnings[0]


# --------------------------------------------------------------------------------------------- Nav2


def nav2_map(tmp: Path) -> Path:
    data = np.zeros((4, 5), np.int8)
    data[1, 1] = 100
    yml, _ = write_map(OccupancyGrid(data, 0.05, (0.0, 0.0, 0.0)), tmp, "map")
    return yml


NAV2_CASES = {
    "resolution-string": ({"resolution": "fine"}, r"map\.yaml: resolution must be a number, got 'fine'"),
    "resolution-zero": ({"resolution": 0}, r"map\.yaml: resolution must be a positive number"),
    "origin-string": ({"origin": [0, "x", 0]}, r"map\.yaml: origin must be a number, got 'x'"),
    "origin-short": ({"origin": [0, 0]}, r"map\.yaml: origin must be \[x, y, yaw\]"),
    "negate-two": ({"negate": 2}, r"map\.yaml: negate must be 0 or 1"),
    "thresholds-swapped": ({"free_thresh": 0.9}, r"map\.yaml: thresholds must satisfy"),
    "threshold-nan": ({"occupied_thresh": float("nan")}, r"map\.yaml: occupied_thresh must be a finite number"),
    "image-missing": ({"image": "nothing.pgm"}, r"map\.yaml: the map image .*nothing\.pgm named by key 'image'"),
    "image-not-a-name": ({"image": 5}, r"map\.yaml: image must be a file name"),
    "mode-unknown": ({"mode": "ternary"}, r"map\.yaml: mode 'ternary' is not one of"),
}


@pytest.mark.parametrize("case", sorted(NAV2_CASES))
def test_bad_nav2_yaml(case, tmp_path):
    change, message = NAV2_CASES[case]
    yml = nav2_map(tmp_path)
    meta = yaml.safe_load(yml.read_text())
    meta.update(change)
    yml.write_text(yaml.safe_dump(meta))
    with pytest.raises(DataError, match=message):
        read_map(yml)


def test_bad_nav2_files(tmp_path):
    yml = nav2_map(tmp_path)
    (tmp_path / "map.pgm").write_bytes(b"P5\n5 4\n255\n\x00")
    with pytest.raises(DataError, match=r"map\.pgm: cannot be read as an image"):
        read_map(yml)
    yml.write_text("image: [unclosed\n")
    with pytest.raises(DataError, match=r"map\.yaml: not valid YAML"):
        read_map(yml)
    yml.write_text("created: 2022-13-45\n")
    with pytest.raises(DataError, match=r"map\.yaml: not valid YAML"):
        read_map(yml)
    yml.write_text("")
    with pytest.raises(DataError, match=r"map\.yaml: expected a mapping"):
        read_map(yml)


def test_errors_are_one_line(tmp_path):
    """Messages quoting the input (JSON, YAML, tokens) stay on one line."""
    (tmp_path / "c.xyz").write_text("0 0 0\n1 'a\n b' 1\n")
    yml = tmp_path / "m.yaml"
    yml.write_text("image: a\nresolution: [1,\n")
    buf = io.StringIO(json.dumps({"width": "8\n9"}))
    for call in (
        lambda: read_point_cloud(tmp_path / "c.xyz"),
        lambda: read_map(yml),
        lambda: intrinsics_from(json.load(buf), "c"),
    ):
        with pytest.raises(DataError) as err:
            call()
        assert "\n" not in str(err.value), str(err.value)
