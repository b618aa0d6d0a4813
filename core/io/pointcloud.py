"""Point-cloud files, reader beside writer: PLY, PCD, XYZ-style text and NPY, each checked against what
its header promises.

A reader never hands back fewer or more points than the file declares, nor zeros where the file is cut:
a truncated or malformed file is a :class:`DataError` that names the file and says what was expected and
what was found (``the header promises 112586 vertex rows (1351032 bytes), the file holds 675516 bytes``).

* PLY: ``ascii``, ``binary_little_endian`` and ``binary_big_endian``; every element of the header is
  checked (rows, values per row, list lengths, face indices within the vertices), the ``vertex`` element
  is returned.
* PCD (v0.5-0.7): ``DATA ascii`` and ``binary`` are parsed here; ``binary_compressed`` is checked here
  (header, the sizes of its LZF block) and decompressed by Open3D.
* Text (``.xyz``, ``.xyzrgb``, ``.xyzn``, ``.pts``): one point per line, every line with the same number
  of values; ``.pts`` may start with the point count.
* NPY: an (N, 3|4|6|7) integer or float array (xyz[, label] or xyz rgb[, label]).
* Laser scanners' E57 and LAS/LAZ files, through their libraries (:mod:`stratamap.core.io.scans`).

Coordinates may hold NaN (organized clouds mark pixels without a return so); what to do with them is the
caller's choice.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stratamap.core.atomic import write_bytes
from stratamap.core.errors import DataError
from stratamap.core.io import brief
from stratamap.core.io.scans import SCAN_SUFFIXES, read_e57, read_las

PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
PLY_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
PCD_TYPES = {("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8", ("U", 1): "u1", ("U", 2): "u2"}
PCD_TYPES |= {("U", 4): "u4", ("U", 8): "u8", ("F", 4): "f4", ("F", 8): "f8"}
PCD_DATA = ("ascii", "binary", "binary_compressed")
PCD_KEYS = ("VERSION", "FIELDS", "COLUMNS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
TEXT_SUFFIXES = (".xyz", ".xyzrgb", ".xyzn", ".pts")
SUFFIXES = (".ply", ".pcd", *TEXT_SUFFIXES, ".npy")
#: Values per line of each text format, and what they hold.
TEXT_COLUMNS = {
    ".xyz": {3: "xyz", 4: "xyz label", 6: "xyz rgb", 7: "xyz rgb label"},
    ".xyzrgb": {6: "xyz rgb", 7: "xyz rgb label"},
    ".xyzn": {6: "xyz normals"},
    ".pts": {3: "xyz", 4: "xyz intensity", 6: "xyz rgb", 7: "xyz intensity rgb"},
}
NPY_COLUMNS = TEXT_COLUMNS[".xyz"]
_MAX_HEADER = 1 << 20  # bytes; a longer header is not a point-cloud header
_PADDING = b" \t\r\n\x00"
_MAX_POINT_BYTES = (
    1 << 20
)  # a PCD point larger than this is a corrupt COUNT  # trailing bytes a writer may leave after a binary body


@dataclass
class CloudData:
    """What a point-cloud file holds: coordinates, colors and every other per-point field by name."""

    points: np.ndarray  # (N, 3) float64; NaN/inf kept as read
    colors: np.ndarray | None = None  # (N, 3) float64, nominally in [0, 1]
    fields: dict[str, np.ndarray] = field(default_factory=dict)  # (N,) or (N, k) per name, e.g. "label"
    #: (width, height) of an organized cloud (a PCD whose HEIGHT is over 1: one point per pixel of a
    #: camera's image, so in that camera's frame); None for an unorganized one.
    image_size: tuple[int, int] | None = None
    #: Where the scanner stood for each scan, (K, 3) in the file's frame (E57 scans' poses); an empty
    #: array when the file says no position (LAS); None when it says nothing (the file's origin, as a
    #: scanner's or camera's own frame).
    sensor_positions: np.ndarray | None = None
    #: Per point, which of ``sensor_positions`` saw it (E57: the scan holding it); None when unknown.
    sensor_ids: np.ndarray | None = None


# --------------------------------------------------------------------------------------------- headers


@dataclass
class PlyProperty:
    name: str
    type: str  # PLY type name as written
    dtype: np.dtype  # value type (native byte order)
    count_type: str | None = None  # list properties: type of the length
    count_dtype: np.dtype | None = None


@dataclass
class PlyElement:
    name: str
    count: int
    properties: list[PlyProperty] = field(default_factory=list)

    @property
    def fixed(self) -> bool:
        return all(p.count_dtype is None for p in self.properties)

    def row_dtype(self, order: str) -> np.dtype:
        return np.dtype([(p.name, p.dtype.newbyteorder(order)) for p in self.properties])

    def describe(self) -> str:
        return " ".join(p.name if p.count_dtype is None else f"{p.name}[]" for p in self.properties)


@dataclass
class PlyHeader:
    format: str  # ascii | binary_little_endian | binary_big_endian
    elements: list[PlyElement]
    body_offset: int  # first byte after end_header

    def element(self, name: str) -> PlyElement | None:
        return next((e for e in self.elements if e.name == name), None)


@dataclass
class PcdHeader:
    fields: list[str]
    sizes: list[int]
    types: list[str]
    counts: list[int]
    width: int
    height: int
    points: int
    data: str  # ascii | binary | binary_compressed
    body_offset: int
    #: VIEWPOINT: where the sensor stood, tx ty tz qw qx qy qz in the cloud's frame (PCL's "acquisition
    #: viewpoint"); None when the header has none.
    viewpoint: tuple[float, ...] | None = None

    def dtype(self, order: str = "<") -> np.dtype:
        return np.dtype(
            [
                (
                    name if name != "_" else f"_{k}",
                    np.dtype(PCD_TYPES[(t, s)]).newbyteorder(order),
                    (c,) if c > 1 else (),
                )
                for k, (name, s, t, c) in enumerate(zip(self.fields, self.sizes, self.types, self.counts))
            ]
        )

    @property
    def values_per_point(self) -> int:
        return sum(self.counts)


def _header_text(data: bytes, end: int, path: Path, kind: str) -> list[str]:
    try:
        text = data[:end].decode("ascii")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: the {kind} header holds non-ASCII bytes at byte {exc.start}") from None
    return text.replace("\r\n", "\n").split("\n")


def _int(value: str, path: Path, line: int, what: str, minimum: int = 0) -> int:
    try:
        n = int(value)
    except ValueError:
        raise DataError(f"{path}: header line {line}: {what} must be an integer, got {value!r}") from None
    if n < minimum:
        raise DataError(f"{path}: header line {line}: {what} must be at least {minimum}, got {n}")
    return n


def parse_ply_header(data: bytes, path: Path) -> PlyHeader:
    """The format and elements a PLY header declares, checked for consistency (not yet against the body)."""
    if not re.match(rb"ply\r?\n", data):
        raise DataError(f"{path}: not a PLY file (it does not start with a 'ply' line)")
    m = re.search(rb"(?:^|\n)end_header[ \t]*\r?\n", data[:_MAX_HEADER])
    if m is None:
        raise DataError(f"{path}: no 'end_header' line: not a PLY file, or its header is cut")
    lines = _header_text(data, m.start(), path, "PLY")
    fmt: str | None = None
    elements: list[PlyElement] = []
    for n, raw in enumerate(lines[1:], 2):
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        key = words[0]
        if key == "format":
            if len(words) != 3 or words[1] not in PLY_FORMATS:
                raise DataError(
                    f"{path}: header line {n}: expected 'format ascii|binary_little_endian|binary_big_endian 1.0', "
                    f"got {raw.strip()[:80]!r}"
                )
            if fmt is not None:
                raise DataError(f"{path}: header line {n}: a second 'format' line")
            fmt = words[1]
        elif key == "element":
            if len(words) != 3:
                raise DataError(f"{path}: header line {n}: expected 'element NAME COUNT', got {raw.strip()[:80]!r}")
            if any(e.name == words[1] for e in elements):
                raise DataError(f"{path}: header line {n}: element {words[1]!r} declared twice")
            elements.append(PlyElement(words[1], _int(words[2], path, n, f"the row count of element {words[1]!r}")))
        elif key == "property":
            if not elements:
                raise DataError(f"{path}: header line {n}: a property before any element")
            el = elements[-1]
            if len(words) == 3 and words[1] in PLY_TYPES:
                prop = PlyProperty(words[2], words[1], np.dtype(PLY_TYPES[words[1]]))
            elif len(words) == 5 and words[1] == "list" and words[2] in PLY_TYPES and words[3] in PLY_TYPES:
                if np.dtype(PLY_TYPES[words[2]]).kind not in "iu":
                    raise DataError(f"{path}: header line {n}: a list length must be an integer type, got {words[2]}")
                prop = PlyProperty(
                    words[4], words[3], np.dtype(PLY_TYPES[words[3]]), words[2], np.dtype(PLY_TYPES[words[2]])
                )
            else:
                raise DataError(
                    f"{path}: header line {n}: expected 'property TYPE NAME' or 'property list TYPE TYPE NAME' "
                    f"with a type among {', '.join(sorted(set(PLY_TYPES)))}, got {raw.strip()[:80]!r}"
                )
            if any(p.name == prop.name for p in el.properties):
                raise DataError(f"{path}: header line {n}: property {prop.name!r} of {el.name!r} declared twice")
            el.properties.append(prop)
        else:
            raise DataError(f"{path}: header line {n}: unexpected {raw.strip()[:80]!r}")
    if fmt is None:
        raise DataError(f"{path}: the header has no 'format' line")
    for el in elements:
        if not el.properties and el.count:
            raise DataError(f"{path}: element {el.name!r} has {el.count} rows but no properties")
    return PlyHeader(fmt, elements, m.end())


def parse_pcd_header(data: bytes, path: Path) -> PcdHeader:
    """The fields, sizes and point count a PCD header declares, checked for consistency."""
    m = re.search(rb"(?:^|\n)DATA[ \t]+[^\r\n]*\r?\n", data[:_MAX_HEADER])
    if m is None:
        if not re.match(rb"(#[^\n]*\n|\s*\n)*(VERSION|FIELDS)", data[:_MAX_HEADER]):
            raise DataError(f"{path}: not a PCD file (no VERSION or FIELDS line at its start)")
        raise DataError(f"{path}: no 'DATA ascii|binary|binary_compressed' line: the PCD header is cut or malformed")
    lines = _header_text(data, m.end(), path, "PCD")
    entries: dict[str, tuple[int, list[str]]] = {}
    for n, raw in enumerate(lines, 1):
        words = raw.split()
        if not words or words[0].startswith("#"):
            continue
        key = words[0].upper()
        if key not in PCD_KEYS:
            raise DataError(f"{path}: header line {n}: unexpected {raw.strip()[:80]!r}")
        key = "FIELDS" if key == "COLUMNS" else key
        if key in entries:
            raise DataError(f"{path}: header line {n}: a second {key} line")
        entries[key] = (n, words[1:])

    def values(key: str, required: bool = True) -> tuple[int, list[str]] | None:
        if key not in entries:
            if required:
                raise DataError(f"{path}: the PCD header has no {key} line")
            return None
        line, vals = entries[key]
        if not vals:
            raise DataError(f"{path}: header line {line}: {key} without values")
        return line, vals

    line, names = values("FIELDS")  # type: ignore[misc]
    named = [f for f in names if f != "_"]
    if len(set(named)) != len(named):
        raise DataError(f"{path}: header line {line}: a field is named twice in {' '.join(names)}")
    line_s, sizes_s = values("SIZE")  # type: ignore[misc]
    line_t, types = values("TYPE")  # type: ignore[misc]
    counts_entry = values("COUNT", required=False)
    line_c, counts_s = counts_entry if counts_entry else (line, ["1"] * len(names))
    for key, ln, vals in (("SIZE", line_s, sizes_s), ("TYPE", line_t, types), ("COUNT", line_c, counts_s)):
        if len(vals) != len(names):
            raise DataError(f"{path}: header line {ln}: {key} has {len(vals)} values for {len(names)} FIELDS")
    sizes = [_int(s, path, line_s, "SIZE", 1) for s in sizes_s]
    counts = [_int(c, path, line_c, "COUNT", 1) for c in counts_s]
    if sum(s * c for s, c in zip(sizes, counts)) > _MAX_POINT_BYTES:
        raise DataError(f"{path}: header line {line_c}: COUNT {' '.join(counts_s)} makes points over 1 MiB each")
    types = [t.upper() for t in types]
    for name, s, t in zip(names, sizes, types):
        if (t, s) not in PCD_TYPES:
            raise DataError(
                f"{path}: header line {line_t}: field {name!r} has TYPE {t} SIZE {s}; expected I or U with SIZE "
                "1, 2, 4 or 8, or F with SIZE 4 or 8"
            )
    ln, width_s = values("WIDTH")  # type: ignore[misc]
    width = _int(width_s[0], path, ln, "WIDTH")
    height_entry = values("HEIGHT", required=False)
    height = _int(height_entry[1][0], path, height_entry[0], "HEIGHT") if height_entry else 1
    points_entry = values("POINTS", required=False)
    points = _int(points_entry[1][0], path, points_entry[0], "POINTS") if points_entry else width * height
    if points != width * height:
        raise DataError(
            f"{path}: the header says POINTS {points} but WIDTH x HEIGHT is {width} x {height} = {width * height}"
        )
    ln, data_s = values("DATA")  # type: ignore[misc]
    if data_s[0].lower() not in PCD_DATA:
        raise DataError(f"{path}: header line {ln}: DATA {data_s[0]!r}; expected one of {', '.join(PCD_DATA)}")
    for axis in "xyz":
        if axis not in names:
            raise DataError(f"{path}: no {axis!r} field (FIELDS {' '.join(names)}); a point cloud needs x, y and z")
        if counts[names.index(axis)] != 1:
            raise DataError(f"{path}: field {axis!r} has COUNT {counts[names.index(axis)]}, expected 1")
    viewpoint = None
    viewpoint_entry = values("VIEWPOINT", required=False)
    if viewpoint_entry:
        ln, numbers = viewpoint_entry
        try:
            viewpoint = tuple(float(v) for v in numbers)
        except ValueError:
            viewpoint = ()
        if len(viewpoint) != 7 or not np.all(np.isfinite(viewpoint)):
            raise DataError(f"{path}: header line {ln}: VIEWPOINT {' '.join(numbers)!r}; expected tx ty tz qw qx qy qz")
    return PcdHeader(names, sizes, types, counts, width, height, points, data_s[0].lower(), m.end(), viewpoint)


# --------------------------------------------------------------------------------------------- bodies


def _trailing(data: bytes, offset: int, path: Path, promised: str) -> None:
    rest = data[offset:]
    if rest.strip(_PADDING):
        raise DataError(
            f"{path}: {len(rest)} bytes follow the {promised} the header promises (a wrong count in the header, "
            "or two files joined?)"
        )


def _truncated(path: Path, promised: str, found: str) -> DataError:
    return DataError(f"{path}: truncated or corrupt: the header promises {promised}, the file holds {found}")


def _ply_binary(data: bytes, header: PlyHeader, path: Path) -> dict[str, dict[str, np.ndarray]]:
    order = PLY_FORMATS[header.format]
    offset = header.body_offset
    out: dict[str, dict[str, np.ndarray]] = {}
    for el in header.elements:
        if el.fixed:
            dt = el.row_dtype(order)
            need, avail = el.count * dt.itemsize, len(data) - offset
            if avail < need:
                raise _truncated(
                    path,
                    f"{el.count} {el.name} rows ({need} bytes of {header.format} data)",
                    f"{avail} bytes after the header for them ({avail // max(dt.itemsize, 1)} whole rows)",
                )
            rows = np.frombuffer(data, dt, el.count, offset)
            out[el.name] = {p.name: rows[p.name] for p in el.properties}
            offset += need
        else:
            out[el.name], offset = _ply_binary_lists(data, offset, el, order, path)
    promised = " and ".join(f"{e.count} {e.name} rows" for e in header.elements)
    _trailing(data, offset, path, promised)
    return out


def _ply_binary_lists(
    data: bytes, offset: int, el: PlyElement, order: str, path: Path
) -> tuple[dict[str, np.ndarray], int]:
    if len(el.properties) == 1 and el.count:  # the usual faces: one list of equal length in every row
        p = el.properties[0]
        cdt, idt = p.count_dtype.newbyteorder(order), p.dtype.newbyteorder(order)  # type: ignore[union-attr]
        if offset + cdt.itemsize <= len(data):
            n = int(np.frombuffer(data, cdt, 1, offset)[0])
            if 0 <= n <= len(data):
                row = np.dtype([("n", cdt), ("v", idt, (n,))])
                if len(data) - offset >= el.count * row.itemsize:
                    rows = np.frombuffer(data, row, el.count, offset)
                    if np.all(rows["n"] == n):
                        return {p.name: rows["v"].reshape(el.count, n)}, offset + el.count * row.itemsize
    values: dict[str, list] = {p.name: [] for p in el.properties}
    for r in range(el.count):
        for p in el.properties:
            if p.count_dtype is None:
                dt = p.dtype.newbyteorder(order)
                if offset + dt.itemsize > len(data):
                    raise _truncated(path, f"{el.count} {el.name} rows", f"{r} whole rows")
                values[p.name].append(np.frombuffer(data, dt, 1, offset)[0])
                offset += dt.itemsize
                continue
            cdt, idt = p.count_dtype.newbyteorder(order), p.dtype.newbyteorder(order)
            if offset + cdt.itemsize > len(data):
                raise _truncated(path, f"{el.count} {el.name} rows", f"{r} whole rows")
            n = int(np.frombuffer(data, cdt, 1, offset)[0])
            offset += cdt.itemsize
            if n < 0:
                raise DataError(f"{path}: {el.name} row {r + 1}: list {p.name!r} has negative length {n}")
            if offset + n * idt.itemsize > len(data):
                raise _truncated(path, f"{el.count} {el.name} rows", f"{r} whole rows")
            values[p.name].append(np.frombuffer(data, idt, n, offset))
            offset += n * idt.itemsize
    return {k: _stack(v) for k, v in values.items()}, offset


def _stack(values: list) -> np.ndarray:
    if values and isinstance(values[0], np.ndarray):
        lengths = {len(v) for v in values}
        if len(lengths) == 1:
            return np.stack(values)
        return np.array(values, dtype=object)
    return np.array(values)


def _numbers(tokens: list[bytes], rows: list[tuple[int, list[bytes]]], path: Path) -> np.ndarray:
    """Tokens as float64, or a DataError naming the line of the first one that is not a number."""
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        for line, toks in rows:
            for t in toks:
                try:
                    float(t)
                except ValueError:
                    raise DataError(f"{path}:{line}: {t[:40].decode('ascii', 'replace')!r} is not a number") from None
        raise DataError(f"{path}: a value is not a number") from None


def _check_integers(values: np.ndarray, dtype: np.dtype, where: str, path: Path) -> np.ndarray:
    if dtype.kind not in "iu" or values.size == 0:
        return values.astype(dtype)
    info = np.iinfo(dtype)
    bad = ~np.isfinite(values) | (values != np.round(values)) | (values < info.min) | (values > info.max)
    if bad.any():
        k = int(np.flatnonzero(bad.reshape(-1))[0])
        row = k // (values.size // len(values)) + 1 if values.ndim > 1 else k + 1
        raise DataError(f"{path}: {where}, row {row}: {values.reshape(-1)[k].item():g} is not a {dtype.name} value")
    return values.astype(dtype)


def _ascii_rows(data: bytes, offset: int) -> list[tuple[int, list[bytes]]]:
    """Non-blank lines after the header as (line number, tokens)."""
    first = data.count(b"\n", 0, offset) + 1
    return [(first + k, ln.split()) for k, ln in enumerate(data[offset:].split(b"\n")) if ln.strip()]


def _ply_ascii(data: bytes, header: PlyHeader, path: Path) -> dict[str, dict[str, np.ndarray]]:
    rows = _ascii_rows(data, header.body_offset)
    at = 0
    out: dict[str, dict[str, np.ndarray]] = {}
    for el in header.elements:
        block = rows[at : at + el.count]
        if len(block) < el.count:
            cut = bool(block) and el.fixed and len(block[-1][1]) != len(el.properties)
            found = f"{len(block) - 1} rows and a cut one" if cut else f"{len(block)} rows"
            raise _truncated(path, f"{el.count} {el.name} rows", found)
        at += el.count
        if el.fixed:
            nprops = len(el.properties)
            for k, (line, toks) in enumerate(block):
                if len(toks) != nprops:
                    if at == len(rows) and k == len(block) - 1:
                        raise _truncated(
                            path, f"{el.count} {el.name} rows", f"{k} rows and a cut one (the last line, {line})"
                        )
                    raise DataError(
                        f"{path}:{line}: {el.name} row {k + 1} of {el.count} has {len(toks)} values, expected "
                        f"{nprops} ({el.describe()})"
                    )
            flat = _numbers([t for _, toks in block for t in toks], block, path).reshape(el.count, nprops)
            out[el.name] = {
                p.name: _check_integers(flat[:, j], p.dtype, f"{el.name} property {p.name!r} ({p.type})", path)
                for j, p in enumerate(el.properties)
            }
            continue
        values: dict[str, list] = {p.name: [] for p in el.properties}
        for k, (line, toks) in enumerate(block):
            nums = _numbers(toks, [(line, toks)], path)
            i = 0
            for p in el.properties:
                where = f"line {line}: {el.name} row {k + 1} property {p.name!r}"
                if p.count_dtype is None:
                    if i >= len(nums):
                        raise DataError(f"{path}:{line}: {el.name} row {k + 1} has too few values ({el.describe()})")
                    values[p.name].append(_check_integers(nums[i : i + 1], p.dtype, where, path)[0])
                    i += 1
                    continue
                if i >= len(nums):
                    raise DataError(f"{path}:{line}: {el.name} row {k + 1} has too few values ({el.describe()})")
                n = int(_check_integers(nums[i : i + 1], p.count_dtype, where + " (list length)", path)[0])
                if i + 1 + n > len(nums):
                    raise DataError(
                        f"{path}:{line}: {el.name} row {k + 1}: list {p.name!r} promises {n} values, the line has "
                        f"{len(nums) - i - 1}"
                    )
                values[p.name].append(_check_integers(nums[i + 1 : i + 1 + n], p.dtype, where, path))
                i += 1 + n
            if i != len(nums):
                raise DataError(
                    f"{path}:{line}: {el.name} row {k + 1} has {len(nums)} values, {len(nums) - i} more than its "
                    f"properties ({el.describe()}) take"
                )
        out[el.name] = {k: _stack(v) for k, v in values.items()}
    if at < len(rows):
        raise DataError(
            f"{path}:{rows[at][0]}: {len(rows) - at} more rows than the "
            + " and ".join(f"{e.count} {e.name} rows" for e in header.elements)
            + " the header promises"
        )
    return out


def _check_faces(elements: dict[str, dict[str, np.ndarray]], vertices: int, path: Path) -> None:
    for name in ("vertex_indices", "vertex_index"):
        faces = elements.get("face", {}).get(name)
        if faces is None or faces.size == 0:
            continue
        flat = np.concatenate([np.asarray(f).reshape(-1) for f in faces]) if faces.dtype == object else faces
        flat = np.asarray(flat).reshape(-1)
        if flat.size and (flat.min() < 0 or flat.max() >= vertices):
            bad = flat[(flat < 0) | (flat >= vertices)][0]
            raise DataError(
                f"{path}: a face uses vertex index {bad}, but there are {vertices} vertices (0..{vertices - 1})"
            )


def read_ply(data: bytes, path: Path) -> dict[str, np.ndarray]:
    """The ``vertex`` element's scalar properties by name, verified against the header."""
    header = parse_ply_header(data, path)
    vertex = header.element("vertex")
    if vertex is None:
        raise DataError(f"{path}: no 'vertex' element in the header (elements: {[e.name for e in header.elements]})")
    for axis in "xyz":
        prop = next((p for p in vertex.properties if p.name == axis), None)
        if prop is None or prop.count_dtype is not None:
            raise DataError(f"{path}: the vertex element has no scalar {axis!r} property ({vertex.describe()})")
    elements = _ply_ascii(data, header, path) if header.format == "ascii" else _ply_binary(data, header, path)
    _check_faces(elements, vertex.count, path)
    return {p.name: elements["vertex"][p.name] for p in vertex.properties if p.count_dtype is None}


def read_pcd(data: bytes, path: Path) -> tuple[PcdHeader, dict[str, np.ndarray] | None]:
    """The header and each field's values (``None`` for ``binary_compressed``: verified, not decompressed)."""
    header = parse_pcd_header(data, path)
    try:
        dt = header.dtype()
    except ValueError as exc:  # e.g. a field named like the padding fields numpy needs distinct names for
        raise DataError(f"{path}: FIELDS {' '.join(header.fields)} cannot be laid out ({brief(exc)})") from exc
    if header.data == "ascii":
        rows = _ascii_rows(data, header.body_offset)
        nvals = header.values_per_point
        for k, (line, toks) in enumerate(rows[: header.points]):
            if len(toks) != nvals:
                if k == len(rows) - 1 and len(rows) <= header.points:
                    raise _truncated(
                        path,
                        f"{header.points} points (POINTS {header.points})",
                        f"{k} rows and a cut one (the last line, {line})",
                    )
                raise DataError(
                    f"{path}:{line}: point {k + 1} of {header.points} has {len(toks)} values, expected {nvals} "
                    f"(FIELDS {' '.join(header.fields)})"
                )
        if len(rows) < header.points:
            cut = bool(rows) and len(rows[-1][1]) != nvals
            found = f"{len(rows) - 1} rows and a cut one" if cut else f"{len(rows)} rows"
            raise _truncated(path, f"{header.points} points (POINTS {header.points})", found)
        if len(rows) > header.points:
            raise DataError(
                f"{path}:{rows[header.points][0]}: {len(rows) - header.points} more rows than the POINTS "
                f"{header.points} the header promises"
            )
        flat = _numbers([t for _, toks in rows for t in toks], rows, path).reshape(header.points, nvals)
        out: dict[str, np.ndarray] = {}
        col = 0
        for name, s, t, c in zip(header.fields, header.sizes, header.types, header.counts):
            vals = flat[:, col : col + c] if c > 1 else flat[:, col]
            col += c
            if name == "_":
                continue
            if name in ("rgb", "rgba") and s == 4 and c == 1 and t == "F":
                out[name] = vals.astype(np.float32).view(np.uint32)  # the packed color's bits
                continue
            out[name] = _check_integers(vals, np.dtype(PCD_TYPES[(t, s)]), f"field {name!r} ({t}{s})", path)
        return header, out
    body = len(data) - header.body_offset
    if header.data == "binary":
        need = header.points * dt.itemsize
        if body < need:
            raise _truncated(
                path,
                f"{header.points} points of {dt.itemsize} bytes ({need} bytes of binary data)",
                f"{body} bytes after the header ({body // max(dt.itemsize, 1)} whole points)",
            )
        _trailing(data, header.body_offset + need, path, f"{header.points} points")
        rows = np.frombuffer(data, dt, header.points, header.body_offset)
        return header, {name: rows[name] for name in dt.names if not name.startswith("_")}
    if body < 8:
        raise _truncated(path, "a binary_compressed block (8 bytes of sizes, then LZF data)", f"{body} bytes")
    compressed, uncompressed = struct.unpack_from("<II", data, header.body_offset)
    if uncompressed != header.points * dt.itemsize:
        raise DataError(
            f"{path}: the compressed block unpacks to {uncompressed} bytes, but {header.points} points of "
            f"{dt.itemsize} bytes need {header.points * dt.itemsize} (a corrupt header or block)"
        )
    if header.points and compressed == 0:
        raise DataError(f"{path}: the compressed block is empty but the header promises {header.points} points")
    if 8 + compressed > body:
        raise _truncated(path, f"a compressed block of {compressed} bytes", f"{body - 8} bytes after the header")
    return header, None


# --------------------------------------------------------------------------------------------- readers


def _colors(values: list[np.ndarray]) -> np.ndarray:
    arr = np.stack(values, axis=1)
    if arr.dtype == np.uint16:
        return arr.astype(np.float64) / 65535.0
    out = arr.astype(np.float64)
    if arr.dtype.kind in "iu" or (out.size and np.nanmax(np.where(np.isfinite(out), out, 0)) > 1.0):
        out /= 255.0
    return out


def _unpack_rgb(packed: np.ndarray) -> np.ndarray:
    """PCL's packed colors (0xAARRGGBB in 4 bytes, stored as U 4 or as the bits of an F 4) as (N, 3) in [0, 1]."""
    packed = np.ascontiguousarray(packed).astype(packed.dtype.newbyteorder("="))
    v = packed.view(np.uint32) if packed.dtype.kind == "f" else packed.astype(np.uint32)
    return np.stack([(v >> 16) & 255, (v >> 8) & 255, v & 255], axis=1).astype(np.float64) / 255.0


def _from_columns(columns: dict[str, np.ndarray], path: Path) -> CloudData:
    points = np.stack([np.asarray(columns[a], dtype=np.float64) for a in "xyz"], axis=1)
    colors = None
    used = {"x", "y", "z"}
    for names in (("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green", "diffuse_blue")):
        if all(n in columns for n in names):
            colors = _colors([columns[n] for n in names])
            used |= set(names)
            break
    if colors is None:
        for name in ("rgb", "rgba"):
            if name in columns and columns[name].ndim == 1 and columns[name].dtype.itemsize == 4:
                colors = _unpack_rgb(columns[name])
                used.add(name)
                break
    fields = {k: np.asarray(v) for k, v in columns.items() if k not in used}
    return CloudData(points, colors, fields)


def _read_compressed_pcd(path: Path, header: PcdHeader) -> CloudData:
    import open3d as o3d

    try:
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):  # its warnings become our error
            cloud = o3d.t.io.read_point_cloud(str(path))
    except RuntimeError as exc:
        raise DataError(f"{path}: cannot be read as a point cloud ({brief(exc)})") from exc
    got = len(cloud.point.positions) if "positions" in cloud.point else 0
    if got != header.points:
        raise DataError(
            f"{path}: the binary_compressed block is corrupt: the header promises {header.points} points, "
            f"{got} could be unpacked"
        )
    points = cloud.point.positions.numpy().astype(np.float64)
    colors = None
    if "colors" in cloud.point:
        c = cloud.point.colors.numpy()
        colors = _colors([c[:, k] for k in range(3)])
    fields = {}
    for key in cloud.point:
        if key not in ("positions", "colors"):
            arr = cloud.point[key].numpy()
            fields[key] = arr.reshape(-1) if arr.ndim == 2 and arr.shape[1] == 1 else arr
    return CloudData(points, colors, fields)


def _read_text(path: Path, label_field: str) -> CloudData:
    suffix = path.suffix.lower()
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DataError(f"{path}: cannot be read ({brief(exc)})") from exc
    rows = [(n, ln.split()) for n, ln in enumerate(data.split(b"\n"), 1) if ln.strip() and not ln.lstrip()[:1] == b"#"]
    if not rows:
        raise DataError(f"{path}: empty: no points")
    promised = None
    if suffix == ".pts" and len(rows[0][1]) == 1:
        promised = _int(rows[0][1][0].decode("ascii", "replace"), path, rows[0][0], "the point count")
        rows = rows[1:]
        if not rows:
            raise DataError(f"{path}: the first line promises {promised} points, the file has none")
    layouts = TEXT_COLUMNS[suffix]
    ncols = len(rows[0][1])
    if ncols not in layouts:
        options = ", ".join(f"{k} ({v})" for k, v in layouts.items())
        raise DataError(f"{path}:{rows[0][0]}: {ncols} values per line; a {suffix} file has {options}")
    for k, (line, toks) in enumerate(rows):
        if len(toks) != ncols:
            cut = ": the file is cut" if k == len(rows) - 1 else ""
            raise DataError(f"{path}:{line}: {len(toks)} values, expected {ncols} ({layouts[ncols]}) as above{cut}")
    if promised is not None and promised != len(rows):
        raise DataError(f"{path}: the first line promises {promised} points, the file has {len(rows)}")
    arr = _numbers([t for _, toks in rows for t in toks], rows, path).reshape(len(rows), ncols)
    return _from_layout(arr, layouts[ncols], label_field)


def _from_layout(arr: np.ndarray, layout: str, label_field: str) -> CloudData:
    cols = layout.split()
    out = CloudData(arr[:, :3].astype(np.float64))
    at = 3
    for name in cols[1:]:
        if name in ("rgb", "normals"):
            block = arr[:, at : at + 3].astype(np.float64)
            at += 3
            if name == "rgb":
                finite = block[np.isfinite(block)]
                out.colors = block / 255.0 if finite.size and finite.max() > 1.0 else block
            else:
                out.fields["normals"] = block
        else:
            out.fields[label_field if name == "label" else name] = arr[:, at]
            at += 1
    return out


def _read_npy(path: Path, label_field: str) -> CloudData:
    fmt = np.lib.format
    try:
        with open(path, "rb") as fh:
            version = fmt.read_magic(fh)
            if version == (1, 0):
                shape, _fortran, dtype = fmt.read_array_header_1_0(fh)
            elif version == (2, 0):
                shape, _fortran, dtype = fmt.read_array_header_2_0(fh)
            else:
                raise DataError(f"{path}: .npy format version {version[0]}.{version[1]} is not supported")
            offset = fh.tell()
    except DataError:
        raise
    except Exception as exc:  # numpy's header parser raises ValueError, SyntaxError, tokenize errors, ...
        raise DataError(f"{path}: not a .npy array file ({brief(exc, True)})") from exc
    if dtype.hasobject or dtype.kind not in "iuf" or dtype.names:
        raise DataError(f"{path}: expected an integer or float array, got dtype {dtype}")
    if len(shape) != 2 or shape[1] not in NPY_COLUMNS:
        raise DataError(f"{path}: expected an (N, 3|4|6|7) array (xyz[, label] or xyz rgb[, label]), got {shape}")
    need = int(np.prod(shape)) * dtype.itemsize
    body = path.stat().st_size - offset
    if body != need:
        raise DataError(
            f"{path}: {'truncated: ' if body < need else ''}the header promises a {shape} {dtype} array "
            f"({need} bytes), the file holds {body} bytes of data"
        )
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as exc:  # the header was checked; this is the library's word on the rest
        raise DataError(f"{path}: cannot be read as .npy ({brief(exc, True)})") from exc
    return _from_layout(arr, NPY_COLUMNS[shape[1]], label_field)


def read_point_cloud(path: str | Path, label_field: str = "label") -> CloudData:
    """Points, colors (in [0, 1]) and other per-point fields of a PLY, PCD, XYZ-style, NPY, E57 or LAS file,
    verified against the file's header; a text or NPY label column is returned as ``label_field``."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: point cloud file not found")
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES + SCAN_SUFFIXES:
        known = ", ".join(SUFFIXES + SCAN_SUFFIXES)
        raise DataError(f"{path}: unsupported point cloud format {suffix!r} (use {known})")
    if path.stat().st_size == 0:
        raise DataError(f"{path}: empty file")
    if suffix == ".e57":
        points, colors, positions, scan_of_point, intensity = read_e57(path)
        fields = {} if intensity is None else {"intensity": intensity}
        cloud = CloudData(points, colors, fields, sensor_positions=positions, sensor_ids=scan_of_point)
    elif suffix in (".las", ".laz"):
        points, colors, fields = read_las(path)
        cloud = CloudData(points, colors, fields, sensor_positions=np.zeros((0, 3)))
    elif suffix == ".npy":
        cloud = _read_npy(path, label_field)
    elif suffix in TEXT_SUFFIXES:
        cloud = _read_text(path, label_field)
    else:
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise DataError(f"{path}: cannot be read ({brief(exc)})") from exc
        if suffix == ".ply":
            cloud = _from_columns(read_ply(data, path), path)
        else:
            header, columns = read_pcd(data, path)
            cloud = _read_compressed_pcd(path, header) if columns is None else _from_columns(columns, path)
            if header.height > 1:
                cloud.image_size = (header.width, header.height)
            if header.viewpoint is not None and any(header.viewpoint[:3]):
                cloud.sensor_positions = np.array([header.viewpoint[:3]])  # at the origin: as without one
    if len(cloud.points) == 0:
        raise DataError(f"{path}: the header declares no points")
    return cloud


# --------------------------------------------------------------------------------------------- writers


def _ply_type(dtype: np.dtype) -> str:
    names = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint"}
    names |= {"f4": "float", "f8": "double"}
    key = dtype.str[1:]
    if key not in names:
        raise ValueError(f"no PLY type for dtype {dtype}")
    return names[key]


def _columns_for_writing(
    points: np.ndarray, colors: np.ndarray | None, fields: dict[str, np.ndarray] | None
) -> list[tuple[str, np.ndarray]]:
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {points.shape}")
    if points.dtype.kind != "f":
        points = points.astype(np.float64)
    cols = [(a, points[:, k]) for k, a in enumerate("xyz")]
    if colors is not None:
        c = np.asarray(colors)
        c8 = c if c.dtype == np.uint8 else np.round(np.clip(np.asarray(c, float), 0, 1) * 255).astype(np.uint8)
        cols += [(n, c8[:, k]) for k, n in enumerate(("red", "green", "blue"))]
    for name, values in (fields or {}).items():
        v = np.asarray(values)
        if v.shape != (len(points),):
            raise ValueError(f"field {name!r} must have one value per point, got shape {v.shape}")
        cols.append((name, v))
    return cols


def _narrow(name: str, values: np.ndarray) -> np.ndarray:
    """64-bit integers as 32-bit ones (PLY has none wider), when every value fits."""
    if values.dtype.kind not in "iu" or values.dtype.itemsize < 8:
        return values
    target = np.dtype(np.int32 if values.dtype.kind == "i" else np.uint32)
    info = np.iinfo(target)
    if values.size and (values.min() < info.min or values.max() > info.max):
        raise ValueError(f"field {name!r} has values beyond 32 bits; PLY has no 64-bit integers")
    return values.astype(target)


def _format_rows(cols: list[tuple[str, np.ndarray]]) -> bytes:
    parts = [
        np.char.mod("%d", v) if v.dtype.kind in "iu" else np.array([repr(float(x)) for x in v.astype(np.float64)])
        for _, v in cols
    ]
    if not parts or not len(parts[0]):
        return b""
    lines = [" ".join(row) for row in zip(*parts)]
    return ("\n".join(lines) + "\n").encode("ascii")


def _packed_rows(cols: list[tuple[str, np.ndarray]], types: list[np.dtype]) -> bytes:
    """The columns as little-endian binary rows of the given types."""
    rows = np.empty(len(cols[0][1]), np.dtype([(name, t) for (name, _), t in zip(cols, types)]))
    for name, v in cols:
        rows[name] = v
    return rows.tobytes()


def write_ply(
    path: str | Path,
    points: np.ndarray,
    colors: np.ndarray | None = None,
    fields: dict[str, np.ndarray] | None = None,
    binary: bool = True,
) -> Path:
    """A PLY point cloud (atomically): x y z in the points' float type, uchar red green blue, then ``fields``."""
    cols = [(name, _narrow(name, v)) for name, v in _columns_for_writing(points, colors, fields)]
    lines = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", "comment written by stratamap"]
    lines.append(f"element vertex {len(cols[0][1])}")
    lines += [f"property {_ply_type(v.dtype)} {name}" for name, v in cols]
    header = ("\n".join([*lines, "end_header"]) + "\n").encode("ascii")
    if binary:
        types = [np.dtype(PLY_TYPES[_ply_type(v.dtype)]).newbyteorder("<") for _, v in cols]
        return write_bytes(path, header + _packed_rows(cols, types))
    return write_bytes(path, header + _format_rows(cols))


def write_pcd(
    path: str | Path,
    points: np.ndarray,
    colors: np.ndarray | None = None,
    fields: dict[str, np.ndarray] | None = None,
    binary: bool = True,
    organized: tuple[int, int] | None = None,
) -> Path:
    """A PCD v0.7 point cloud (atomically): x y z, a packed ``rgb`` (U 4) when there are colors, then
    ``fields``; ``organized`` = (width, height) for an image-shaped cloud."""
    cols = _columns_for_writing(points, None, fields)
    n = len(cols[0][1])
    if colors is not None:
        c = np.asarray(colors)
        c8 = c if c.dtype == np.uint8 else np.round(np.clip(np.asarray(c, float), 0, 1) * 255).astype(np.uint8)
        packed = (c8[:, 0].astype(np.uint32) << 16) | (c8[:, 1].astype(np.uint32) << 8) | c8[:, 2].astype(np.uint32)
        cols.insert(3, ("rgb", packed))
    width, height = organized or (n, 1)
    if width * height != n:
        raise ValueError(f"organized {width}x{height} does not hold {n} points")
    for _, v in cols:
        if v.dtype.kind not in "iuf":
            raise ValueError(f"no PCD type for dtype {v.dtype}")
    header = "\n".join(
        [
            "# .PCD v0.7 - Point Cloud Data file format (written by stratamap)",
            "VERSION 0.7",
            "FIELDS " + " ".join(name for name, _ in cols),
            "SIZE " + " ".join(str(v.dtype.itemsize) for _, v in cols),
            "TYPE " + " ".join({"i": "I", "u": "U", "f": "F"}[v.dtype.kind] for _, v in cols),
            "COUNT " + " ".join("1" for _ in cols),
            f"WIDTH {width}",
            f"HEIGHT {height}",
            "VIEWPOINT 0 0 0 1 0 0 0",
            f"POINTS {n}",
            f"DATA {'binary' if binary else 'ascii'}",
        ]
    )
    if binary:
        types = [v.dtype.newbyteorder("<") for _, v in cols]
        return write_bytes(path, (header + "\n").encode("ascii") + _packed_rows(cols, types))
    return write_bytes(path, (header + "\n").encode("ascii") + _format_rows(cols))


def write_point_cloud(
    path: str | Path,
    points: np.ndarray,
    colors: np.ndarray | None = None,
    fields: dict[str, np.ndarray] | None = None,
    binary: bool = True,
) -> Path:
    """Write by suffix: .ply, .pcd (binary or ASCII), .npy or .xyz (columns xyz[ rgb][ label])."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".ply":
        return write_ply(path, points, colors, fields, binary)
    if suffix == ".pcd":
        return write_pcd(path, points, colors, fields, binary)
    if suffix not in (".npy", ".xyz"):
        raise ValueError(f"cannot write {suffix!r} point clouds (use .ply, .pcd, .npy or .xyz)")
    blocks = [np.asarray(points, np.float64)]
    if colors is not None:
        blocks.append(np.asarray(colors, np.float64))
    if fields:
        if set(fields) != {"label"}:
            raise ValueError(f"{suffix} files hold only a 'label' column besides xyz and rgb, got {sorted(fields)}")
        blocks.append(np.asarray(fields["label"], np.float64).reshape(-1, 1))
    arr = np.hstack(blocks)
    if suffix == ".npy":
        import io

        buf = io.BytesIO()
        np.save(buf, arr)
        return write_bytes(path, buf.getvalue())
    return write_bytes(path, _format_rows([(str(k), arr[:, k]) for k in range(arr.shape[1])]))
