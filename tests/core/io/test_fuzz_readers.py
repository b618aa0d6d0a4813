"""Property-based fuzzing of the file readers of core/io (hypothesis, bounded in examples): valid small files
are cut at a random byte, get bytes flipped, garbage lines inserted and header numbers replaced, and random
bytes are read too. Whatever the input, a reader returns a valid result or raises ``DataError`` (one line,
naming the file): never another exception, never a silent partial result.

``STRATAMAP_FUZZ_EXAMPLES=N`` multiplies the number of examples (e.g. 20 for a long local run).
"""

from __future__ import annotations

import os
import re
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stratamap.core.errors import DataError
from stratamap.core.io.mesh import read_mesh
from stratamap.core.io.nav2 import read_map, write_map
from stratamap.core.io.pointcloud import read_point_cloud, write_point_cloud
from stratamap.core.io.rgbd import parse_tum_poses, read_depth, read_laser_file, read_rgb, read_timestamped_list
from stratamap.core.io.urdf import read_urdf
from stratamap.core.map.layers import OccupancyGrid

# Bounded (about 10 s per file): `make test` runs them, `make test-fast` leaves them out.
pytestmark = pytest.mark.slow

SCALE = max(1, int(os.environ.get("STRATAMAP_FUZZ_EXAMPLES", "1")))


def fuzz(examples: int) -> Callable:
    """Hypothesis settings of every fuzz test: bounded, no deadline, no example database in the work tree."""
    return settings(
        max_examples=examples * SCALE,
        deadline=None,
        database=None,
        derandomize=SCALE == 1,  # the suite's run is reproducible; a long local run explores
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )


HEADER_VALUES = ["0", "1", "2", "-1", "3", "39", "41", "80", "65535", "4294967297", "99999999999999", "nan", "x", ""]
JUNK_LINES = [
    b"",
    b"nan nan nan",
    b"1 2",
    b"1 2 3 4 5 6 7 8 9",
    b"end_header",
    b"DATA ascii",
    b"\xff\xfe",
    b"-",
    b"1e999",
]


@st.composite
def mutated(draw, base: bytes, header: int = 400) -> bytes:
    """``base`` after one to four edits: cut, flip, insert, delete, a junk line, a header number replaced."""
    data = bytearray(base)
    for op in draw(
        st.lists(st.sampled_from(("cut", "flip", "insert", "delete", "line", "number")), min_size=1, max_size=4)
    ):
        n = len(data)
        if op == "cut":
            data = data[: draw(st.integers(0, n))]
        elif op == "flip" and n:
            k = draw(st.integers(0, n - 1))
            data[k] ^= draw(st.integers(1, 255))
        elif op == "insert":
            k = draw(st.integers(0, n))
            data[k:k] = draw(st.binary(max_size=12))
        elif op == "delete" and n:
            k = draw(st.integers(0, n - 1))
            del data[k : k + draw(st.integers(1, 16))]
        elif op == "line":
            starts = [0] + [m.end() for m in re.finditer(rb"\n", bytes(data))]
            k = draw(st.sampled_from(starts))
            data[k:k] = draw(st.sampled_from(JUNK_LINES) | st.binary(max_size=20)) + b"\n"
        elif op == "number":
            numbers = list(re.finditer(rb"-?\d+(\.\d+)?", bytes(data[:header])))
            if numbers:
                m = draw(st.sampled_from(numbers))
                value = draw(st.sampled_from(HEADER_VALUES) | st.integers(-(2**40), 2**40).map(str)).encode()
                data[m.start() : m.end()] = value
    return bytes(data)


def inputs(base: bytes, header: int = 400) -> st.SearchStrategy[bytes]:
    """Mutations of a valid file, and now and then random bytes."""
    return st.one_of(mutated(base, header), mutated(base, header), mutated(base, header), st.binary(max_size=300))


def one_line_naming(err: DataError, *names: str) -> None:
    text = str(err)
    assert text and "\n" not in text, text
    assert any(n in text for n in names), (names, text)


def scratch() -> tempfile.TemporaryDirectory:
    return tempfile.TemporaryDirectory(prefix="stratamap-fuzz-")


# --------------------------------------------------------------------------------------------- point clouds


def valid_clouds() -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, (12, 3)).astype(np.float32)
    points[2] = np.nan
    colors = rng.integers(0, 256, (12, 3)).astype(np.uint8)
    labels = rng.integers(0, 9, 12).astype(np.int32)
    out = {}
    with scratch() as tmp:
        for name, binary in (("b.ply", True), ("a.ply", False), ("b.pcd", True), ("a.pcd", False)):
            out[name] = write_point_cloud(
                Path(tmp) / name, points, colors, {"label": labels}, binary=binary
            ).read_bytes()
        out["c.xyz"] = write_point_cloud(Path(tmp) / "c.xyz", points, colors / 255.0).read_bytes()
        out["c.npy"] = write_point_cloud(Path(tmp) / "c.npy", points, colors / 255.0, {"label": labels}).read_bytes()
        import open3d as o3d

        cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(points))
        o3d.t.io.write_point_cloud(str(Path(tmp) / "z.pcd"), cloud, compressed=True)
        out["z.pcd"] = (Path(tmp) / "z.pcd").read_bytes()
    out["c.pts"] = b"3\n0 0 0 1 255 0 0\n1 1 1 2 0 255 0\n2 2 2 3 0 0 255\n"
    import trimesh

    box = trimesh.creation.box((1, 1, 1))
    out["mb.ply"] = box.export(file_type="ply", encoding="binary")  # vertex and face elements
    out["ma.ply"] = box.export(file_type="ply", encoding="ascii")
    return out


CLOUDS = valid_clouds()


def check_cloud(name: str, data: bytes) -> None:
    with scratch() as tmp:
        path = Path(tmp) / name
        path.write_bytes(data)
        try:
            cloud = read_point_cloud(path)
        except DataError as err:
            one_line_naming(err, str(path))
            return
    n = len(cloud.points)
    assert n > 0 and cloud.points.shape == (n, 3) and cloud.points.dtype == np.float64
    assert cloud.colors is None or cloud.colors.shape == (n, 3)
    for key, values in cloud.fields.items():
        assert len(values) == n, key


@pytest.mark.parametrize("name", sorted(CLOUDS))
def test_fuzz_point_cloud_files(name):
    @fuzz(200)
    @given(inputs(CLOUDS[name]))
    def run(data: bytes) -> None:
        check_cloud(name, data)

    run()


# --------------------------------------------------------------------------------------------- meshes, URDF


MESHES = {
    "m.ply": (
        b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
        b"element face 2\nproperty list uchar int vertex_indices\nend_header\n"
        b"0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 2 3\n"
    ),
    "m.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\n",
    "m.off": b"OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 2 3\n",
}


@pytest.mark.parametrize("name", sorted(MESHES))
def test_fuzz_mesh_files(name):
    @fuzz(120)
    @given(inputs(MESHES[name], header=10_000))
    def run(data: bytes) -> None:
        with scratch() as tmp:
            path = Path(tmp) / name
            path.write_bytes(data)
            try:
                mesh = read_mesh(path)
            except DataError as err:
                one_line_naming(err, str(path))
                return
            assert len(mesh.faces) and mesh.faces.max() < len(mesh.vertices) and np.isfinite(mesh.vertices).all()

    run()


URDF = b"""<?xml version="1.0"?>
<robot name="cabinet">
  <link name="body"><visual><origin xyz="0 0 0.4" rpy="0 0 0"/><geometry><box size="0.6 0.5 0.8"/></geometry>
  </visual></link>
  <link name="door"><visual><geometry><mesh filename="door.obj" scale="1 1 1"/></geometry></visual>
    <collision><geometry><cylinder radius="0.02" length="0.7"/></geometry></collision></link>
  <link name="knob"><visual><geometry><sphere radius="0.01"/></geometry></visual></link>
  <joint name="hinge" type="revolute"><parent link="body"/><child link="door"/>
    <origin xyz="0.3 -0.25 0.4" rpy="0 0 1.57"/><axis xyz="0 0 1"/><limit lower="0" upper="1.6"/></joint>
  <joint name="fix" type="fixed"><parent link="door"/><child link="knob"/><origin xyz="0 0.2 0"/></joint>
</robot>
"""


def test_fuzz_urdf():
    @fuzz(250)
    @given(inputs(URDF, header=len(URDF)))
    def run(data: bytes) -> None:
        with scratch() as tmp:
            (Path(tmp) / "door.obj").write_bytes(MESHES["m.obj"])
            path = Path(tmp) / "r.urdf"
            path.write_bytes(data)
            try:
                model = read_urdf(path)
                poses = model.link_poses({j.name: 0.5 for j in model.joints})
            except DataError as err:
                one_line_naming(err, str(path))
                return
            assert set(poses) == set(model.links)
            assert all(p.shape == (4, 4) and np.isfinite(p).all() for p in poses.values())

    run()


# --------------------------------------------------------------------------------------------- Nav2


def nav2_files() -> dict[str, bytes]:
    data = np.zeros((5, 7), np.int8)
    data[1:3, 2:4] = 100
    data[4] = -1
    with scratch() as tmp:
        yml, pgm = write_map(OccupancyGrid(data, 0.05, (-1.0, 2.0, 0.1)), Path(tmp), "map")
        return {"map.yaml": yml.read_bytes(), "map.pgm": pgm.read_bytes()}


NAV2 = nav2_files()


@pytest.mark.parametrize("target", sorted(NAV2))
def test_fuzz_nav2_map(target):
    @fuzz(200)
    @given(inputs(NAV2[target], header=200), st.sampled_from(["trinary", "scale", "raw"]))
    def run(data: bytes, mode: str) -> None:
        with scratch() as tmp:
            files = dict(NAV2)
            files["map.yaml"] = files["map.yaml"].replace(b"trinary", mode.encode())
            files[target] = data
            for name, content in files.items():
                (Path(tmp) / name).write_bytes(content)
            yml = Path(tmp) / "map.yaml"
            try:
                grid = read_map(yml)
            except DataError as err:
                one_line_naming(err, str(yml), "map.pgm")
                return
            assert grid.data.ndim == 2 and grid.resolution > 0 and np.isfinite(grid.origin).all()

    run()


@given(
    st.dictionaries(
        st.sampled_from(["image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode"]),
        st.none()
        | st.booleans()
        | st.integers()
        | st.floats()
        | st.text(max_size=8)
        | st.lists(st.floats(), max_size=4),
    )
)
@fuzz(250)
def test_fuzz_nav2_yaml_values(meta):
    with scratch() as tmp:
        (Path(tmp) / "map.pgm").write_bytes(NAV2["map.pgm"])
        yml = Path(tmp) / "map.yaml"
        yml.write_text(yaml.safe_dump({"image": "map.pgm", "resolution": 0.05, "origin": [0, 0, 0], **meta}))
        try:
            grid = read_map(yml)
        except DataError as err:
            one_line_naming(err, str(yml), "map.pgm")
            return
        assert grid.resolution > 0 and np.isfinite(grid.origin).all()


# --------------------------------------------------------------------------------------------- RGB-D text and images


TEXT = {
    "rgb.txt": b"# color images\n1.000000 rgb/1.png\n1.033333 rgb/2.png\n1.066667 rgb/3.png\n",
    "groundtruth.txt": b"# tx ty tz qx qy qz qw\n1.0 0 0 0 0 0 0 1\n1.1 0.1 0 0 0 0 0.0998 0.995\n",
    "laser.txt": b"1.0 0 0 0.3 0 -1.57 0.01 8.0 1.5 1.6 1.7\n1.1 0.1 0 0.3 0 -1.57 0.01 8.0 1.5 nan 1.7\n",
}


@pytest.mark.parametrize("name", sorted(TEXT))
def test_fuzz_rgbd_text_files(name):
    read = {
        "rgb.txt": lambda p: read_timestamped_list(p, 1, "an image file name"),
        "groundtruth.txt": parse_tum_poses,
        "laser.txt": read_laser_file,
    }[name]

    @fuzz(200)
    @given(inputs(TEXT[name], header=len(TEXT[name])))
    def run(data: bytes) -> None:
        with scratch() as tmp:
            path = Path(tmp) / name
            path.write_bytes(data)
            try:
                out = read(path)
            except DataError as err:
                one_line_naming(err, str(path))
                return
            if name == "groundtruth.txt":
                times, poses = out
                assert np.all(np.diff(times) > 0) and np.isfinite(poses).all()

    run()


def images() -> dict[str, bytes]:
    from PIL import Image

    out = {}
    with scratch() as tmp:
        for name, array in (
            ("d.png", np.full((6, 8), 7500, np.uint16)),
            ("c.png", np.random.default_rng(0).integers(0, 256, (6, 8, 3)).astype(np.uint8)),
            ("d.tiff", np.full((6, 8), 1.5, np.float32)),
        ):
            Image.fromarray(array).save(Path(tmp) / name)
            out[name] = (Path(tmp) / name).read_bytes()
    return out


IMAGES = images()


@pytest.mark.filterwarnings("ignore::UserWarning")  # Pillow warns on corrupt EXIF before failing
@pytest.mark.parametrize("name", sorted(IMAGES))
def test_fuzz_images(name):
    @fuzz(150)
    @given(inputs(IMAGES[name], header=64))
    def run(data: bytes) -> None:
        with scratch() as tmp:
            path = Path(tmp) / name
            path.write_bytes(data)
            try:
                if name.startswith("c"):
                    rgb = read_rgb(path, (6, 8))
                    assert rgb.shape == (6, 8, 3) and rgb.dtype == np.uint8
                else:
                    depth = read_depth(path, 5000.0, (6, 8))
                    assert depth.shape == (6, 8) and np.isfinite(depth).all() and (depth >= 0).all()
            except DataError as err:
                one_line_naming(err, str(path))

    run()


def valid_sens() -> bytes:
    """A two-frame ScanNet .sens file of 8 x 6 images (JPEG colour, zlib depth)."""
    from stratamap.core.io.sens import write_sens

    rng = np.random.default_rng(1)
    frames = [
        (rng.integers(0, 256, (6, 8, 3)).astype(np.uint8), rng.uniform(0.5, 3.0, (6, 8)), np.eye(4)) for _ in range(2)
    ]
    with scratch() as tmp:
        return write_sens(Path(tmp) / "s.sens", frames, np.array([[5.0, 0, 4], [0, 5.0, 3], [0, 0, 1]])).read_bytes()


SENS = valid_sens()


def test_fuzz_sens_files():
    """A cut, flipped or garbled .sens file: its index and every frame read, or a one-line DataError."""
    from stratamap.core.io.sens import read_sens, read_sens_frame

    @fuzz(150)
    @given(inputs(SENS, header=400))
    def run(data: bytes) -> None:
        with scratch() as tmp:
            path = Path(tmp) / "s.sens"
            path.write_bytes(data)
            try:
                sens = read_sens(path)
                for k in range(len(sens)):
                    rgb, depth = read_sens_frame(sens, k)
                    w, h = sens.color_size
                    assert rgb.shape == (h, w, 3) and rgb.dtype == np.uint8
                    assert depth.shape == sens.depth_size[::-1] and depth.dtype == np.dtype("<u2")
            except DataError as err:
                one_line_naming(err, str(path))

    run()


def test_found_by_fuzzing(tmp_path):
    """Inputs the fuzzer once found to escape as other exceptions."""
    npy = CLOUDS["c.npy"].replace(b"'shape': (", b"'shape': )", 1)
    (tmp_path / "c.npy").write_bytes(npy)
    with pytest.raises(DataError, match=r"c\.npy: not a \.npy array file"):
        read_point_cloud(tmp_path / "c.npy")
    pcd = CLOUDS["a.pcd"].replace(b"COUNT 1 1 1 1 1", b"COUNT 1 1 1 4294967297 1")
    (tmp_path / "c.pcd").write_bytes(pcd)
    with pytest.raises(DataError, match=r"c\.pcd: header line 6: COUNT 1 1 1 4294967297 1 makes points over 1 MiB"):
        read_point_cloud(tmp_path / "c.pcd")
