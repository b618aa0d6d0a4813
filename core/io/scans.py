"""Laser scanners' files: E57 (ASTM E2807, what terrestrial scanners such as Faro's, Leica's and
Matterport's export) read with pye57 (libE57Format), and LAS/LAZ (ASPRS, mobile and airborne
mapping) read with laspy; both are the ``scans`` extra (``pip install 'stratamap[scans]'``).

An E57 file holds one or more scans, each with its points (cartesian or spherical, invalid returns
flagged) and the pose of the scanner that took it: the points are returned in the file's common
frame and the scanners' positions beside them (where each scan was seen from). A LAS file holds
points in a (usually georeferenced) frame with no scanner position. Colours are returned in [0, 1]
(8- or 16-bit in the file). Anything the libraries cannot read is a :class:`DataError` naming the file.
"""

from __future__ import annotations

import importlib
import struct
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.errors import DataError
from stratamap.core.io import brief

#: Suffixes read here.
SCAN_SUFFIXES = (".e57", ".las", ".laz")


def _library(name: str, path: Path, what: str) -> Any:
    try:
        return importlib.import_module(name)
    except ImportError:
        raise DataError(
            f"{path}: reading {what} needs {name}, which is not installed: pip install 'stratamap[scans]'"
        ) from None


def _e57_reason(exc: BaseException) -> str:
    """libE57Format's message without its debug dump (context, function names, source lines)."""
    return brief(Exception(str(exc).split("****")[0].strip() or type(exc).__name__), True).replace("Exception: ", "", 1)


def _unit_colors(rgb: np.ndarray) -> np.ndarray:
    """8-bit or 16-bit colour channels (the files use both) in [0, 1]."""
    rgb = np.asarray(rgb, np.float64)
    top = float(rgb.max()) if rgb.size else 0.0
    return np.clip(rgb / (65535.0 if top > 255.0 else 255.0), 0.0, 1.0)


def read_e57(
    path: str | Path,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray, np.ndarray | None]:
    """Every scan's valid points in the file's frame, their colours (None unless every scan has them),
    each scan's scanner position (K, 3), per point the index of the scan that holds it, and the
    points' intensities as stored (None unless every scan has them)."""
    path = Path(path)
    pye57 = _library("pye57", path, "E57 scans")
    try:
        e57 = pye57.E57(str(path))
        count = int(e57.scan_count)
    except Exception as exc:  # libE57Format raises its own types for every kind of damage
        raise DataError(f"{path}: cannot be read as E57 ({_e57_reason(exc)})") from exc
    if count == 0:
        raise DataError(f"{path}: the E57 file holds no scan")
    points, colors, intensities, positions = [], [], [], []
    try:
        for k in range(count):
            header = e57.get_header(k)
            fields = set(header.point_fields)
            has_color = {"colorRed", "colorGreen", "colorBlue"} <= fields
            has_intensity = "intensity" in fields
            data = e57.read_scan(
                k, colors=has_color, intensity=has_intensity, transform=True, ignore_missing_fields=True
            )
            xyz = np.c_[data["cartesianX"], data["cartesianY"], data["cartesianZ"]].astype(np.float64)
            points.append(xyz)
            colors.append(np.c_[data["colorRed"], data["colorGreen"], data["colorBlue"]] if has_color else None)
            intensities.append(np.asarray(data["intensity"], np.float64) if has_intensity else None)
            # A scan without a pose is in the file's frame already, its scanner at the origin.
            positions.append(np.asarray(header.translation, np.float64) if header.has_pose() else np.zeros(3))
    except Exception as exc:
        raise DataError(f"{path}: scan {k} cannot be read ({_e57_reason(exc)})") from exc
    finally:
        e57.close()
    xyz = np.concatenate(points) if points else np.zeros((0, 3))
    if len(xyz) == 0:
        raise DataError(f"{path}: its {count} scan(s) hold no valid point")
    rgb = None if any(c is None for c in colors) else _unit_colors(np.concatenate(colors))
    intensity = None if any(i is None for i in intensities) else np.concatenate(intensities)
    scan_of_point = np.repeat(np.arange(len(points)), [len(p) for p in points])
    return xyz, rgb, np.asarray(positions).reshape(-1, 3), scan_of_point, intensity


#: The LAS public header block's fields checked before laspy reads the file (ASPRS LAS 1.0-1.4).
# signature, version major and minor, header size, offset to points, VLRs, point format, record length, points
LAS_HEADER = struct.Struct("<4s20xBB68xHIIBHI")
LAS_MIN_HEADER = 227  # bytes of a LAS 1.0-1.2 public header block
VLR_HEADER = 54  # bytes before each variable-length record's payload
EVLR_HEADER = 60
LAZ_POINTS_PER_RECORD = 200_000
LAZ_MAX_CHUNK = 1_000_000  # points per LASzip chunk a small file may still declare


def check_las_header(path: Path) -> None:
    """The header's sizes and counts must fit the file: laspy trusts them, and a damaged header's
    count of variable-length records (a few billion) kept it reading for hours."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        _check_las_header(path, fh, size)


def _check_las_header(path: Path, fh: Any, size: int) -> None:
    head = fh.read(375)
    if len(head) < LAS_MIN_HEADER or head[:4] != b"LASF":
        raise DataError(f"{path}: not a LAS file (no 'LASF' header of {LAS_MIN_HEADER} bytes)")
    _, major, minor, header_size, offset, vlrs, point_format, record_length, points = LAS_HEADER.unpack_from(head)
    if major != 1 or minor > 4:
        raise DataError(f"{path}: LAS version {major}.{minor}; expected 1.0 to 1.4")
    if not LAS_MIN_HEADER <= header_size <= offset <= size:
        raise DataError(
            f"{path}: header of {header_size} bytes and points from byte {offset}, in a file of {size} bytes"
        )
    if vlrs * VLR_HEADER > offset - header_size:
        raise DataError(
            f"{path}: the header promises {vlrs} variable-length records, but {offset - header_size} bytes lie "
            "between the header and the points"
        )
    if major == 1 and minor == 4 and len(head) >= 255:
        evlr_start, evlrs, points_14 = struct.unpack_from("<QIQ", head, 235)
        points = points_14 or points
        if evlrs and (evlr_start > size or evlrs * EVLR_HEADER > size - evlr_start):
            raise DataError(f"{path}: the header promises {evlrs} extended records past the end of the file")
    compressed = bool(point_format & 0x80) or path.suffix.lower() == ".laz"
    if not compressed and points * record_length > size - offset:
        raise DataError(
            f"{path}: the header promises {points} points of {record_length} bytes "
            f"({points * record_length} bytes), the file holds {size - offset} after the header"
        )
    if compressed:
        # LAZ stores each chunk's first point whole (chunks of 50,000 points as written by LASzip and
        # lazrs); four times that per stored record is more than any real file holds.
        if points > LAZ_POINTS_PER_RECORD * max(size - offset, 0) // max(record_length, 1):
            raise DataError(
                f"{path}: the header promises {points} compressed points, more than its {size - offset} bytes of "
                "point data can hold"
            )
        _check_laszip_chunks(path, fh, header_size, vlrs, points)
        _check_chunk_table(path, fh, size, offset, points)


def _check_laszip_chunks(path: Path, fh: Any, header_size: int, vlrs: int, points: int) -> None:
    """The LASzip record's chunk size (points per chunk; 0xFFFFFFFF: variable) within what a file of
    ``points`` can use: the decoder allocates a whole chunk first, and a damaged size aborted it."""
    fh.seek(header_size)
    for _ in range(vlrs):
        head = fh.read(VLR_HEADER)
        if len(head) < VLR_HEADER:
            return
        user, record, length = head[2:18].rstrip(b"\0"), *struct.unpack_from("<HH", head, 18)
        payload = fh.read(length)
        if user == b"laszip encoded" and record == 22204 and len(payload) >= 16:
            (chunk,) = struct.unpack_from("<I", payload, 12)
            if chunk != 0xFFFFFFFF and chunk > max(points, LAZ_MAX_CHUNK):
                raise DataError(f"{path}: LASzip chunks of {chunk} points, in a file of {points} points")
            return


def _check_chunk_table(path: Path, fh: Any, size: int, offset: int, points: int) -> None:
    """LAZ's chunk table (its position is the first 8 bytes of the point data; version 0, then the
    number of chunks) holds at most a chunk per point: the LAZ decoder allocates what it says before
    reading it, and a damaged count aborted the process asking for 57 GB."""
    fh.seek(offset)
    raw = fh.read(8)
    if len(raw) < 8:
        raise DataError(f"{path}: the compressed point data ends before its chunk table's position")
    (table,) = struct.unpack("<q", raw)
    if table < 0:  # -1: written as a stream, no table
        return
    if not offset + 8 <= table <= size - 8:
        raise DataError(f"{path}: the chunk table lies at byte {table}, outside the point data (file: {size} bytes)")
    fh.seek(table)
    version, chunks = struct.unpack("<II", fh.read(8))
    if version != 0 or chunks > points + 1:
        raise DataError(
            f"{path}: the chunk table (version {version}) promises {chunks} chunks for {points} points; expected "
            "version 0 and at most a chunk per point"
        )


#: ASPRS classification codes (LAS 1.4, table 17) of points a scanner's software marked as noise.
LAS_NOISE_CLASSES = {7: "low point (noise)", 18: "high noise"}


def read_las(path: str | Path) -> tuple[np.ndarray, np.ndarray | None, dict[str, np.ndarray]]:
    """The points of a LAS or LAZ file (scaled and offset as its header says), their colours, if its
    point format has them, and per-point fields: ``intensity`` unless all are equal (every point
    format has the field; a file that records none holds zeros), ``classification`` (ASPRS codes)
    unless no point is classified (all 0 or 1), ``withheld`` where any point is flagged so. The
    header is checked against the file first."""
    path = Path(path)
    laspy = _library("laspy", path, "LAS/LAZ")
    check_las_header(path)
    try:
        las = laspy.read(str(path))
        xyz = np.c_[np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)].astype(np.float64)
        names = set(las.point_format.dimension_names)
        rgb = None
        if {"red", "green", "blue"} <= names:
            rgb = _unit_colors(np.c_[np.asarray(las.red), np.asarray(las.green), np.asarray(las.blue)])
        fields: dict[str, np.ndarray] = {}
        if "intensity" in names and len(las.points) and np.ptp(np.asarray(las.intensity)) > 0:
            fields["intensity"] = np.asarray(las.intensity, np.float64)
        if "classification" in names and np.any(np.asarray(las.classification) > 1):
            fields["classification"] = np.asarray(las.classification, np.uint8)
        if "withheld" in names and np.any(np.asarray(las.withheld)):
            fields["withheld"] = np.asarray(las.withheld, bool)
    except Exception as exc:  # laspy raises LaspyException, ValueError, struct.error, ... on damage
        hint = ""
        if path.suffix.lower() == ".laz" and "backend" in str(exc).lower():
            hint = "; a LAZ file needs a LAZ backend: pip install 'laspy[lazrs]'"
        raise DataError(f"{path}: cannot be read as LAS ({brief(exc, True)}){hint}") from exc
    if len(xyz) == 0:
        raise DataError(f"{path}: the LAS file holds no point")
    return xyz, rgb, fields
