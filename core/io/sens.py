"""ScanNet's ``.sens`` files: the raw RGB-D streams ScanNet is distributed as, read without exporting
them to folders first (ScanNet's own SensReader writes color/, depth/, pose/ and intrinsic/ from them).

Layout (little-endian; ScanNet's ``SensReader/src/sensorData.h``, version 4):

* header: ``uint32`` version (4); ``uint64`` length and the sensor's name; four 4x4 ``float32``
  matrices (colour intrinsics, colour extrinsics, depth intrinsics, depth extrinsics); ``int32``
  colour compression (0 raw RGB, 1 PNG, 2 JPEG) and depth compression (0 raw, 1 zlib of ``uint16``,
  2 OCCI: not read); ``uint32`` colour width, colour height, depth width, depth height;
  ``float32`` depth shift (depth units per metre, 1000 in ScanNet); ``uint64`` frame count;
* per frame: a 4x4 ``float32`` camera-to-world pose (``-inf`` where tracking was lost); ``uint64``
  colour and depth timestamps (microseconds; 0 when not recorded); ``uint64`` colour and depth byte
  counts, then the bytes.

IMU records may follow the frames; they are not read. The frames' positions are indexed once (the
frame headers only) and each frame is decoded when asked for. Every count and size is checked
against the file: a cut or malformed file is a :class:`DataError` naming it and what was expected.
"""

from __future__ import annotations

import io
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from stratamap.core.atomic import atomic_path
from stratamap.core.errors import DataError
from stratamap.core.io import brief

VERSION = 4
COLOR_COMPRESSION = {0: "raw", 1: "png", 2: "jpeg"}
DEPTH_COMPRESSION = {0: "raw_ushort", 1: "zlib_ushort", 2: "occi_ushort"}
_FRAME_HEADER = struct.Struct("<16f4Q")


@dataclass
class SensFile:
    """A ``.sens`` file's header and where each frame's colour and depth bytes lie."""

    path: Path
    sensor_name: str
    intrinsic_color: np.ndarray
    extrinsic_color: np.ndarray
    intrinsic_depth: np.ndarray
    extrinsic_depth: np.ndarray
    color_compression: str
    depth_compression: str
    color_size: tuple[int, int]  # width, height
    depth_size: tuple[int, int]
    depth_shift: float
    poses: list[np.ndarray] = field(default_factory=list)  # camera to world, as stored
    timestamps: list[int] = field(default_factory=list)  # the depth images', microseconds
    frames: list[tuple[int, int, int, int]] = field(default_factory=list)  # colour offset, size, depth offset, size

    def __len__(self) -> int:
        return len(self.frames)


def _read(fh, size: int, path: Path, what: str) -> bytes:
    data = fh.read(size)
    if len(data) != size:
        raise DataError(f"{path}: truncated: {what} needs {size} bytes, the file holds {len(data)} more")
    return data


def read_sens(path: str | Path) -> SensFile:
    """The header and the frame index of a ``.sens`` file (frame headers only; images stay on disk)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: .sens file not found")
    try:
        fh = open(path, "rb")
    except OSError as exc:
        raise DataError(f"{path}: cannot be read ({brief(exc)})") from exc
    with fh:
        (version,) = struct.unpack("<I", _read(fh, 4, path, "the version"))
        if version != VERSION:
            raise DataError(f"{path}: .sens version {version}; expected {VERSION} (ScanNet's)")
        (name_length,) = struct.unpack("<Q", _read(fh, 8, path, "the sensor name's length"))
        if name_length > 4096:
            raise DataError(f"{path}: a sensor name of {name_length} bytes; not a .sens header")
        name = _read(fh, name_length, path, "the sensor name").decode("utf-8", "replace")
        matrices = np.frombuffer(_read(fh, 4 * 64, path, "the calibration matrices"), "<f4").reshape(4, 4, 4)
        color_kind, depth_kind, cw, ch, dw, dh, shift, count = struct.unpack(
            "<2i4IfQ", _read(fh, 36, path, "the image formats")
        )
        if color_kind not in COLOR_COMPRESSION:
            raise DataError(f"{path}: colour compression {color_kind}; expected 0 (raw), 1 (PNG) or 2 (JPEG)")
        if depth_kind not in (0, 1):
            kind = DEPTH_COMPRESSION.get(depth_kind, str(depth_kind))
            raise DataError(f"{path}: depth compression {kind}; expected 0 (raw) or 1 (zlib)")
        if not (0 < cw <= 16384 and 0 < ch <= 16384 and 0 < dw <= 16384 and 0 < dh <= 16384):
            raise DataError(f"{path}: image sizes colour {cw}x{ch}, depth {dw}x{dh}; expected 1 to 16384 pixels")
        if not np.isfinite(shift) or shift <= 0:
            raise DataError(f"{path}: depth shift {shift}; expected depth units per metre (ScanNet: 1000)")
        if not np.all(np.isfinite(matrices[2, :3, :3])):
            raise DataError(f"{path}: the depth intrinsics are not finite")
        sens = SensFile(
            path,
            name,
            *[m.astype(np.float64) for m in matrices],
            COLOR_COMPRESSION[color_kind],
            DEPTH_COMPRESSION[depth_kind],
            (cw, ch),
            (dw, dh),
            float(shift),
        )
        size = path.stat().st_size
        for k in range(count):
            head = fh.read(_FRAME_HEADER.size)
            if len(head) != _FRAME_HEADER.size:
                raise DataError(f"{path}: truncated: the header promises {count} frames, frame {k} is cut")
            values = _FRAME_HEADER.unpack(head)
            _, stamp_depth, color_bytes, depth_bytes = values[16:]
            start = fh.tell()
            if start + color_bytes + depth_bytes > size:
                raise DataError(f"{path}: truncated: the header promises {count} frames, frame {k} is cut")
            sens.poses.append(np.asarray(values[:16], np.float64).reshape(4, 4))
            sens.timestamps.append(int(stamp_depth))
            sens.frames.append((start, color_bytes, start + color_bytes, depth_bytes))
            fh.seek(color_bytes + depth_bytes, io.SEEK_CUR)
    if not sens.frames:
        raise DataError(f"{path}: no frames")
    return sens


def read_sens_frame(sens: SensFile, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``k``'s colour (H x W x 3 ``uint8``) and depth (``uint16``, ``depth_shift`` units per metre)."""
    color_at, color_bytes, depth_at, depth_bytes = sens.frames[k]
    with open(sens.path, "rb") as fh:
        fh.seek(color_at)
        color = fh.read(color_bytes)
        fh.seek(depth_at)
        depth = fh.read(depth_bytes)
    cw, ch = sens.color_size
    dw, dh = sens.depth_size
    where = f"{sens.path}: frame {k}"
    if sens.color_compression == "raw":
        if len(color) != cw * ch * 3:
            raise DataError(f"{where}: {len(color)} colour bytes; raw RGB of {cw}x{ch} needs {cw * ch * 3}")
        rgb = np.frombuffer(color, np.uint8).reshape(ch, cw, 3)
    else:
        try:
            image = Image.open(io.BytesIO(color))
            image.load()
        except Exception as exc:  # Pillow raises many types for a damaged image
            raise DataError(f"{where}: its colour image cannot be decoded ({brief(exc, True)})") from exc
        rgb = np.asarray(image.convert("RGB"))
        if rgb.shape[:2] != (ch, cw):
            raise DataError(f"{where}: a {rgb.shape[1]}x{rgb.shape[0]} colour image; the header says {cw}x{ch}")
    if sens.depth_compression == "zlib_ushort":
        try:  # at most one byte more than the image needs: a corrupt stream cannot inflate without bound
            depth = zlib.decompressobj().decompress(depth, dw * dh * 2 + 1)
        except zlib.error as exc:
            raise DataError(f"{where}: its depth image cannot be decompressed ({brief(exc)})") from exc
    if len(depth) != dw * dh * 2:
        raise DataError(f"{where}: {len(depth)} depth bytes; {dw}x{dh} 16-bit depth needs {dw * dh * 2}")
    return rgb, np.frombuffer(depth, "<u2").reshape(dh, dw)


def write_sens(
    path: str | Path,
    frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    intrinsic_depth: np.ndarray,
    depth_shift: float = 1000.0,
    color_size: tuple[int, int] | None = None,
    intrinsic_color: np.ndarray | None = None,
    timestamps: list[int] | None = None,
) -> Path:
    """Write (rgb ``uint8``, depth in metres, camera-to-world pose) frames as a version 4 ``.sens``
    file: colour as JPEG (resized to ``color_size``, as ScanNet's colour differs from its depth),
    depth as zlib-compressed ``uint16`` at ``depth_shift`` units per metre; atomically."""
    path = Path(path)
    first_rgb, first_depth, _ = frames[0]
    dh, dw = first_depth.shape
    cw, ch = color_size or (first_rgb.shape[1], first_rgb.shape[0])
    K_depth = np.eye(4)
    K_depth[: np.asarray(intrinsic_depth).shape[0], : np.asarray(intrinsic_depth).shape[1]] = intrinsic_depth
    K_color = K_depth if intrinsic_color is None else np.asarray(intrinsic_color, float)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        name = b"StructureSensor"
        fh.write(struct.pack("<IQ", VERSION, len(name)) + name)
        for m in (K_color, np.eye(4), K_depth, np.eye(4)):
            fh.write(np.asarray(m, "<f4").tobytes())
        fh.write(struct.pack("<2i4IfQ", 2, 1, cw, ch, dw, dh, depth_shift, len(frames)))
        for k, (rgb, depth, pose) in enumerate(frames):
            buf = io.BytesIO()
            Image.fromarray(rgb).resize((cw, ch)).save(buf, format="JPEG", quality=95)
            color = buf.getvalue()
            raw = np.clip(np.round(np.nan_to_num(depth) * depth_shift), 0, 65535).astype("<u2")
            packed = zlib.compress(raw.tobytes())
            stamp = timestamps[k] if timestamps is not None else 0
            fh.write(np.asarray(pose, "<f4").tobytes())
            fh.write(struct.pack("<4Q", stamp, stamp, len(color), len(packed)) + color + packed)
    return path
