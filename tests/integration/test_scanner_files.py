"""Laser scanners' files through configs/scan.yaml: E57 (terrestrial scanners' export, several scans
with the scanners' poses) and LAS/LAZ (georeferenced, no scanner position), written with their own
libraries; a broken file is a one-line error naming it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stratamap.core.config import load_pipeline
from stratamap.core.errors import DataError
from stratamap.core.map.layers import LayeredMap
from stratamap.core.pipeline import Pipeline
from stratamap.core.stages import PipelineData
from stratamap.plugins.sources.pointcloud import PointCloudSource
from tests.conftest import REPO, low_poly_room

pye57 = pytest.importorskip("pye57")
laspy = pytest.importorskip("laspy")

#: Where the room lies in the files: the file's origin outside it, as a site's survey frame puts it.
SHIFT = np.array([3.0, 2.0, 0.0])
#: Two scanner stations inside the room, 1.5 m up (room frame).
STATIONS = np.array([[1.2, 2.0, 1.5], [3.8, 2.0, 1.5]])


def room_points() -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    mesh = low_poly_room()
    points, faces = trimesh.sample.sample_surface(mesh, 150_000, seed=0)
    colors = np.asarray(mesh.visual.face_colors)[faces, :3]
    return np.asarray(points), colors


def write_e57(path, points: np.ndarray, colors: np.ndarray) -> None:
    """Each station's half of the room as one scan, in that scanner's own frame, with its pose."""
    e57 = pye57.E57(str(path), mode="w")
    half = points[:, 0] < 2.5
    for station, mine in zip(STATIONS + SHIFT, (half, ~half), strict=True):
        local = points[mine] + SHIFT - station
        data = {f"cartesian{a}": local[:, k] for k, a in enumerate("XYZ")}
        data |= {f"color{c}": colors[mine, k].astype(np.uint8) for k, c in enumerate(("Red", "Green", "Blue"))}
        e57.write_scan_raw(data, rotation=np.array([1.0, 0.0, 0.0, 0.0]), translation=station)
    e57.close()


def check_room(report: dict, out) -> LayeredMap:
    notes = report["notes"]["clusters"]["segments"]
    assert notes["walls"] == 4 and abs(notes["floor_height"]) < 0.01, notes
    m = LayeredMap.load(out / "map")
    tables = [inst for inst in m.instances if inst.class_name == "table"]
    assert len(tables) == 1 and np.allclose(sorted(tables[0].box.size), [0.72, 0.8, 1.2], atol=0.05)
    return m


def test_an_e57_of_two_scans_is_one_room_seen_from_its_stations(tmp_path):
    """The scans come back in the file's common frame, and `clusters` looks from the scanners' stations
    (from the file's origin, outside the room, it found two walls and a 5 m "object")."""
    points, colors = room_points()
    path = tmp_path / "site.e57"
    write_e57(path, points, colors)
    data = PipelineData()
    stream = PointCloudSource(path=str(path), gravity="off").run(data)["frames"]
    assert len(stream.points) == len(points)
    assert np.allclose(np.sort(stream.points, axis=0), np.sort(points + SHIFT, axis=0), atol=1e-6)
    assert np.allclose(stream.metadata["sensor_positions"], STATIONS + SHIFT)
    assert np.allclose(stream.point_colors[0], colors[0] / 255.0, atol=1e-6)
    out = tmp_path / "room"
    report = Pipeline(load_pipeline(REPO / "configs" / "scan.yaml", [f"source.params.path={path}"])).run(out)
    check_room(report, out)


def test_an_e57s_stations_clear_the_laser_map_where_its_floor_was_too_sparse(tmp_path):
    """A terrestrial scanner sees the floor at a grazing angle away from its station: past 1.5 m there
    are too few floor points to call a cell free. The file says which station saw each point, so the
    laser map is ray cast from the stations, as a LiDAR's sweeps are: free out to the walls and the
    furniture, and never beyond the walls."""
    from stratamap.core.map.layers import Geometry
    from stratamap.core.pipeline import run_stages
    from stratamap.plugins.mappers.occupancy import OccupancyMapper

    points, colors = room_points()
    floor = points[:, 2] < 1e-6
    near = np.min(np.linalg.norm(points[:, None, :2] - STATIONS[None, :, :2], axis=2), axis=1) < 1.5
    keep = ~floor | near
    path = tmp_path / "site.e57"
    write_e57(path, points[keep], colors[keep])
    stream = PointCloudSource(path=str(path), gravity="off").run(PipelineData())["frames"]
    assert stream.point_sensor_ids is not None and np.bincount(stream.point_sensor_ids).size == 2

    def slam(ids) -> dict[str, int]:
        data = PipelineData(stream=dataclasses.replace(stream, point_sensor_ids=ids))
        data.map.geometry = Geometry(points=stream.points)
        grid = run_stages([OccupancyMapper(robot_height=1.0)], data).map.occupancy["slam"]
        rows, cols = np.indices(grid.data.shape)
        x = np.asarray(grid.origin[0]) + (cols + 0.5) * grid.resolution - SHIFT[0]
        y = np.asarray(grid.origin[1]) + (rows + 0.5) * grid.resolution - SHIFT[1]
        inside = (x > 0) & (x < 5) & (y > 0) & (y < 4)
        beyond = (x < -0.05) | (x > 5.05) | (y < -0.05) | (y > 4.05)  # a cell or more past a wall
        free = grid.data == 0
        return {"free": int(free[inside].sum()), "free beyond": int(free[beyond].sum()), "inside": int(inside.sum())}

    stations, floor_only = slam(stream.point_sensor_ids), slam(None)
    assert stations["free beyond"] == 0, stations
    assert stations["free"] > 0.85 * stations["inside"], stations
    assert floor_only["free"] < 0.7 * stations["inside"], floor_only


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_a_georeferenced_las_is_moved_next_to_the_origin(tmp_path, suffix):
    """A LAS/LAZ room 500 km east: its map keeps centimetres (moved next to the origin, the offset in
    the stream's metadata and a warning), 16-bit colours are read in [0, 1], and no scanner is taken
    to stand at the survey frame's origin."""
    points, colors = room_points()
    east = np.array([500_000.0, 5_400_000.0, 0.0])
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets, header.scales = east, [0.001, 0.001, 0.001]
    las = laspy.LasData(header)
    las.x, las.y, las.z = (points + east).T
    las.red, las.green, las.blue = (colors.astype(np.uint16) * 257).T
    path = tmp_path / f"site{suffix}"
    las.write(str(path))
    data = PipelineData()
    stream = PointCloudSource(path=str(path), gravity="off").run(data)["frames"]
    assert np.allclose(np.asarray(stream.metadata["origin_offset"]), east, atol=1.0)
    assert np.abs(stream.points).max() < 10.0 and stream.metadata["sensor_origin"] is False
    assert np.allclose(stream.points + stream.metadata["origin_offset"], points + east, atol=2e-3)
    assert np.allclose(stream.point_colors[0], colors[0] / 255.0, atol=1e-3)
    assert any("georeferenced" in w for w in data.warnings)
    out = tmp_path / "room"
    report = Pipeline(load_pipeline(REPO / "configs" / "scan.yaml", [f"source.params.path={path}"])).run(out)
    m = check_room(report, out)
    assert np.abs(m.geometry.points).max() < 10.0
    assert np.allclose(report["notes"]["pointcloud"]["origin_offset"], east, atol=1.0)


@pytest.mark.parametrize("suffix", [".e57", ".las", ".pcd"])
def test_a_scan_with_intensity_and_no_colours_is_shown_in_its_grey_levels(tmp_path, suffix):
    """Terrestrial scanners often store each return's intensity and no colour: the points take grey
    levels of it (1st to 99th percentile stretched; the outliers clipped), so the walls' reflectance
    shows in views and exports; the stretch is noted, and `intensity_as_color: false` keeps no colours.
    A LAS file that records no intensity (all zeros) has no colours."""
    from stratamap.plugins.sources.pointcloud import intensity_grey

    points, colors = room_points()
    rng = np.random.default_rng(0)
    intensity = (colors.mean(axis=1) * 4 + rng.uniform(0, 5, len(points))).astype(np.uint16)  # 0-1025
    intensity[:10] = 60000  # specular returns: clipped, not the scale
    path = tmp_path / f"site{suffix}"
    if suffix == ".e57":
        e57 = pye57.E57(str(path), mode="w")
        data = {f"cartesian{a}": points[:, k] for k, a in enumerate("XYZ")} | {"intensity": intensity.astype(float)}
        e57.write_scan_raw(data)
        e57.close()
    elif suffix == ".las":
        las = laspy.LasData(laspy.LasHeader(point_format=1, version="1.2"))
        las.header.scales = [0.001, 0.001, 0.001]
        las.x, las.y, las.z = points.T
        las.intensity = intensity
        las.write(str(path))
    else:
        rows = "\n".join(f"{x:.5f} {y:.5f} {z:.5f} {i}" for (x, y, z), i in zip(points, intensity, strict=True))
        path.write_text(
            "VERSION .7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
            f"WIDTH {len(points)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(points)}\nDATA ascii\n{rows}\n"
        )
    data = PipelineData()
    stream = PointCloudSource(path=str(path), gravity="off").run(data)["frames"]
    grey = stream.point_colors
    assert grey is not None and np.allclose(grey[:, 0], grey[:, 2])
    expected, stretch = intensity_grey(intensity)
    assert np.allclose(np.sort(grey[:, 0]), np.sort(expected[:, 0]), atol=1e-3)
    assert stretch["high"] < 1100 and data.notes["pointcloud"]["colors_from_intensity"] == stretch
    assert np.percentile(grey[:, 0], 95) - np.percentile(grey[:, 0], 5) > 0.5  # the scan is not left dark
    off = PointCloudSource(path=str(path), gravity="off", intensity_as_color=False).run(PipelineData())["frames"]
    assert off.point_colors is None
    if suffix == ".las":
        las = laspy.read(str(path))
        las.intensity = np.zeros(len(points), np.uint16)
        las.write(str(path))
        assert PointCloudSource(path=str(path), gravity="off").run(PipelineData())["frames"].point_colors is None


def test_points_a_las_file_marks_as_noise_or_withheld_are_left_out(tmp_path):
    """Survey software classifies LAS points (ASPRS codes): returns from below the floor (7, low
    point) and from the air (18, high noise), and points flagged withheld, are not the room. They are
    left out and counted; the classes the file holds are noted; `drop_noise: false` keeps them; a
    file of noise only is a one-line error naming it."""
    points, _ = room_points()
    rng = np.random.default_rng(1)
    low = np.c_[rng.uniform(0, 5, (2000, 2)), rng.uniform(-3.0, -1.0, 2000)]  # multipath below the floor
    high = np.c_[rng.uniform(0, 5, (500, 2)), rng.uniform(5.0, 10.0, 500)]
    everything = np.vstack([points, low, high])
    classes = np.r_[np.where(points[:, 2] < 0.01, 2, 6), np.full(len(low), 7), np.full(len(high), 18)]
    withheld = np.zeros(len(everything), bool)
    withheld[rng.choice(len(points), 300, replace=False)] = True
    las = laspy.LasData(laspy.LasHeader(point_format=1, version="1.4"))
    las.header.scales = [0.001, 0.001, 0.001]
    las.x, las.y, las.z = everything.T
    las.classification, las.withheld = classes.astype(np.uint8), withheld
    path = tmp_path / "site.las"
    las.write(str(path))

    data = PipelineData()
    stream = PointCloudSource(path=str(path), gravity="off").run(data)["frames"]
    kept = (classes < 7) & ~withheld
    assert len(stream.points) == kept.sum() and np.allclose(stream.points, everything[kept], atol=2e-3)
    notes = data.notes["pointcloud"]
    assert notes["points"]["dropped_noise"] == len(low) + len(high) + 300
    counts = {"2": int((classes == 2).sum()), "6": int((classes == 6).sum()), "7": 2000, "18": 500}
    assert notes["las_classes"] == counts
    every = PointCloudSource(path=str(path), gravity="off", drop_noise=False).run(PipelineData())["frames"]
    assert len(every.points) == len(everything)

    las.classification = np.full(len(everything), 7, np.uint8)
    las.write(str(path))
    with pytest.raises(DataError) as err:
        PointCloudSource(path=str(path), gravity="off").run(PipelineData())
    assert str(path) in str(err.value) and "drop_noise" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("name", ["broken.e57", "broken.las", "broken.laz"])
def test_a_broken_scanner_file_is_a_one_line_error_naming_it(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(b"LASF" + bytes(range(256)) * 4)
    with pytest.raises(DataError) as err:
        PointCloudSource(path=str(path)).run(PipelineData())
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_without_the_scans_extra_the_error_says_what_to_install(tmp_path, monkeypatch):
    import importlib

    from stratamap.core.io import scans

    real = importlib.import_module

    def missing(name, *args):
        if name in ("pye57", "laspy"):
            raise ImportError(name)
        return real(name, *args)

    monkeypatch.setattr(scans.importlib, "import_module", missing)
    path = tmp_path / "site.e57"
    path.write_bytes(b"x" * 64)
    with pytest.raises(DataError, match=r"site\.e57: reading E57 scans needs pye57.*stratamap\[scans\]"):
        PointCloudSource(path=str(path)).run(PipelineData())


def _patched(data: bytes, at: int, fmt: str, value: int) -> bytes:
    import struct

    out = bytearray(data)
    struct.pack_into(fmt, out, at, value)
    return bytes(out)


def test_a_las_header_promising_more_than_the_file_holds_is_refused_before_reading(tmp_path):
    """Counts laspy and the LAZ decoder trust, damaged: billions of variable-length records (laspy read
    for hours), a point count past the file's end, LASzip chunks of a billion points and a chunk
    table of billions of chunks (the decoder aborted the process asking for 38 and 57 GB)."""
    import struct

    header = laspy.LasHeader(point_format=3, version="1.2")
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.random.default_rng(0).uniform(0, 1, (500, 3)).T
    for suffix in (".las", ".laz"):
        las.write(str(tmp_path / f"ok{suffix}"))
    plain, packed = (tmp_path / "ok.las").read_bytes(), (tmp_path / "ok.laz").read_bytes()
    header_size, offset = struct.unpack_from("<HI", packed, 94)
    table = struct.unpack_from("<q", packed, offset)[0]
    cases = {
        "vlrs.las": (_patched(plain, 100, "<I", 3_000_000_000), "variable-length records"),
        "points.las": (_patched(plain, 107, "<I", 520_094_196), "promises 520094196 points"),
        "chunk.laz": (_patched(packed, header_size + 54 + 12, "<I", 1_124_123_472), "LASzip chunks"),
        "table.laz": (_patched(packed, table + 4, "<I", 3_589_080_462), "chunk table"),
    }
    for name, (data, message) in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(DataError, match=message):
            PointCloudSource(path=str(path)).run(PipelineData())


def test_a_pcd_viewpoint_is_where_its_scanner_stood(tmp_path):
    """PCL's VIEWPOINT header line (tx ty tz qw qx qy qz) is the scanner's position, as an E57 pose is:
    the room, its origin outside, is seen from there; a VIEWPOINT that is no seven numbers is refused."""
    from stratamap.core.io.pointcloud import write_point_cloud

    points, colors = room_points()
    path = write_point_cloud(tmp_path / "room.pcd", points + SHIFT, colors / 255.0, binary=True)
    station = STATIONS[0] + SHIFT
    line = "VIEWPOINT {:g} {:g} {:g} 1 0 0 0".format(*station).encode()
    path.write_bytes(path.read_bytes().replace(b"VIEWPOINT 0 0 0 1 0 0 0", line, 1))
    stream = PointCloudSource(path=str(path), gravity="off").run(PipelineData())["frames"]
    assert np.allclose(stream.metadata["sensor_positions"], [station])
    out = tmp_path / "room"
    report = Pipeline(load_pipeline(REPO / "configs" / "scan.yaml", [f"source.params.path={path}"])).run(out)
    check_room(report, out)
    bad = tmp_path / "bad.pcd"
    bad.write_bytes(path.read_bytes().replace(line, b"VIEWPOINT 1 2 three", 1))
    with pytest.raises(DataError, match=r"bad\.pcd: header line \d+: VIEWPOINT '1 2 three'"):
        PointCloudSource(path=str(bad)).run(PipelineData())


def test_an_obj_of_vertices_only_is_read_as_its_points(tmp_path):
    """A cloud stored as an OBJ of `v x y z r g b` lines and no faces (as some scanners and
    photogrammetry tools export one) is read as its points and colours, not refused as a mesh without
    triangles; it has no sensor position, as a mesh has none."""
    points, colors = room_points()
    rows = np.c_[points + SHIFT, colors / 255.0]
    path = tmp_path / "cloud.obj"
    path.write_text("".join("v {:.5f} {:.5f} {:.5f} {:.4f} {:.4f} {:.4f}\n".format(*row) for row in rows))
    stream = PointCloudSource(path=str(path), gravity="off").run(PipelineData())["frames"]
    assert np.allclose(stream.points, points + SHIFT, atol=1e-5)
    assert np.allclose(stream.point_colors, colors / 255.0, atol=3e-3)
    assert stream.metadata["sensor_origin"] is False
    out = tmp_path / "room"
    report = Pipeline(load_pipeline(REPO / "configs" / "scan.yaml", [f"source.params.path={path}"])).run(out)
    check_room(report, out)
