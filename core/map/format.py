"""The on-disk map format (version 1). ``LayeredMap.save``/``load`` are the public entry points.

A map directory holds ``manifest.json`` and one file per present layer::

    manifest.json        {"format": "stratamap.map", "version": 1, "vocabulary", "provenance",
                          "metadata", "layers": {layer: {"file": ...}}}
    occupancy.npz        per grid NAME: NAME.data (int8 HxW), NAME.meta (JSON: resolution, origin, frame_id)
    geometry.npz         points, colors?, normals?, mesh.vertices?, mesh.faces?, mesh.vertex_colors?
    semantics.npz        class_ids, instance_ids (, plane_ids)
    instances.json       per object: id, class, box, score, attributes, completion metadata
    instances.npz        per object ID: ID.points, ID.colors?, ID.completion.mesh.*, ID.part.K.mesh.*
    contact_graph.json   node-link JSON of the support and proximal graphs
    augmented.npz        like geometry.npz

Arrays are stored uncompressed-exact (npz), so a save/load round trip is lossless. The whole
directory is written to a staging folder and swapped in by rename, so a crash never leaves a
manifest that points at missing or partial files.
"""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.atomic import write_json
from stratamap.core.errors import MapFormatError
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import (
    MAP_FORMAT,
    MAP_FORMAT_VERSION,
    MAP_LAYERS,
    Completion,
    ContactGraph,
    Geometry,
    Joint,
    LayeredMap,
    ObjectInstance,
    ObjectInstances,
    OccupancyGrid,
    OccupancyMaps,
    OrientedBox,
    Part,
    Semantics,
)
from stratamap.core.map.vocabulary import Vocabulary

trimesh = lazy_module("trimesh")


def _mesh_arrays(prefix: str, mesh: trimesh.Trimesh, out: dict[str, np.ndarray]) -> None:
    out[f"{prefix}.vertices"] = np.asarray(mesh.vertices, dtype=np.float64)
    out[f"{prefix}.faces"] = np.asarray(mesh.faces, dtype=np.int64)
    if mesh.visual is not None and mesh.visual.kind == "vertex":
        out[f"{prefix}.vertex_colors"] = np.asarray(mesh.visual.vertex_colors, dtype=np.uint8)
    elif mesh.visual is not None and mesh.visual.kind == "face":
        out[f"{prefix}.face_colors"] = np.asarray(mesh.visual.face_colors, dtype=np.uint8)


def _mesh_from(prefix: str, arrays: _Arrays) -> trimesh.Trimesh:
    """A mesh from ``PREFIX.vertices`` and ``PREFIX.faces`` (and their colors), checked: faces index vertices."""
    dims: dict[str, tuple[int, str]] = {}
    vertices = arrays.get(f"{prefix}.vertices", "f", ("V", 3), dims, finite=True)
    faces = arrays.get(f"{prefix}.faces", "iu", ("F", 3), dims)
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        bad = faces[(faces < 0) | (faces >= len(vertices))][0]
        raise MapFormatError(
            f"{arrays.path}: array {prefix + '.faces'!r} indexes vertex {bad}, but {prefix + '.vertices'!r} holds "
            f"{len(vertices)} vertices"
        )
    kwargs: dict[str, Any] = {}
    vertex_colors = arrays.get(f"{prefix}.vertex_colors", np.uint8, ("V", (3, 4)), dims, required=False)
    face_colors = arrays.get(f"{prefix}.face_colors", np.uint8, ("F", (3, 4)), dims, required=False)
    if vertex_colors is not None:
        kwargs["vertex_colors"] = vertex_colors
    if face_colors is not None:
        kwargs["face_colors"] = face_colors
    return trimesh.Trimesh(vertices, faces, process=False, **kwargs)


#: Timestamp of every member of the .npz files written: fixed, so that equal maps give equal bytes.
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """An uncompressed .npz as ``numpy.savez`` writes it, but reproducible byte for byte: members in sorted
    order with a fixed timestamp, so that saving a map, or a map loaded from it, gives identical files."""
    with open(path, "wb") as fh, zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name in sorted(arrays):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_DATE)
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(arrays[name]), allow_pickle=False)


def _brief(exc: BaseException, with_type: bool = False, limit: int = 300) -> str:
    """A library exception's message on one line, shortened (map errors name the file and fit on one line)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    text = f"{type(exc).__name__}: {text}" if with_type else text
    return text if len(text) <= limit else text[: limit - 3] + "..."


_KINDS = {"f": "float", "iu": "integer", "U": "string", "fiu": "number"}


class _Arrays:
    """The arrays of one .npz file, handed out only with the dtype and shape the format specifies;
    anything else is a MapFormatError that names the file, the array and what was expected."""

    def __init__(self, path: Path, arrays: dict[str, np.ndarray]):
        self.path, self.arrays = path, arrays
        self.used: set[str] = set()

    def __contains__(self, key: str) -> bool:
        return key in self.arrays

    def get(
        self,
        key: str,
        kind: str | type,
        shape: tuple,
        dims: dict[str, tuple[int, str]] | None = None,
        required: bool = True,
        finite: bool = False,
    ) -> Any:
        """Array ``key`` of dtype kind(s) ``kind`` (or exactly that dtype) and ``shape``: per axis an int,
        a tuple of allowed ints, None (any), or a name that must be the same length wherever it appears
        in ``dims``."""
        if key not in self.arrays:
            if required:
                raise MapFormatError(f"{self.path}: no array {key!r}; the map format requires it")
            return None
        self.used.add(key)
        a = self.arrays[key]
        if isinstance(kind, str):
            if a.dtype.kind not in kind:
                raise MapFormatError(
                    f"{self.path}: array {key!r} has dtype {a.dtype}, expected {_KINDS.get(kind, kind)} values"
                )
        elif a.dtype != np.dtype(kind):
            raise MapFormatError(f"{self.path}: array {key!r} has dtype {a.dtype}, expected {np.dtype(kind)}")
        dims = {} if dims is None else dims
        ok = a.ndim == len(shape)
        expected = []
        for axis, want in enumerate(shape):
            got = a.shape[axis] if ok else None
            if isinstance(want, str):
                if want in dims:
                    expected.append(f"{dims[want][0]} (as {dims[want][1]!r})")
                    ok = ok and got == dims[want][0]
                else:
                    expected.append(want)
                    if ok:
                        dims[want] = (int(got), key)  # type: ignore[arg-type]
            elif isinstance(want, tuple):
                expected.append("|".join(map(str, want)))
                ok = ok and got in want
            else:
                expected.append("any" if want is None else str(want))
                ok = ok and (want is None or got == want)
        if not ok:
            raise MapFormatError(
                f"{self.path}: array {key!r} has shape {a.shape}, expected ({', '.join(expected)}"
                f"{',' if len(shape) == 1 else ''})"
            )
        if finite and a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            bad = int((~np.isfinite(a)).sum())
            raise MapFormatError(f"{self.path}: array {key!r} holds {bad} NaN or infinite values")
        return a

    def check_all_used(self) -> None:
        extra = sorted(set(self.arrays) - self.used)
        if extra:
            shown = ", ".join(repr(k) for k in extra[:5]) + (", ..." if len(extra) > 5 else "")
            raise MapFormatError(f"{self.path}: unexpected arrays {shown} (not part of map format version 1)")


def _load_npz(path: Path) -> _Arrays:
    if not path.is_file():
        raise MapFormatError(f"{path}: listed in the manifest but missing")
    try:
        with np.load(path, allow_pickle=False) as data:
            if not hasattr(data, "files"):
                raise MapFormatError(f"{path}: a single .npy array, expected an .npz archive of named arrays")
            return _Arrays(path, {k: data[k] for k in data.files})
    except MapFormatError:
        raise
    except Exception as exc:  # zipfile / numpy raise several types for corrupt files
        raise MapFormatError(f"{path}: cannot be read as .npz ({_brief(exc, True)})") from exc


def _read_json(path: Path) -> Any:
    if not path.is_file():
        raise MapFormatError(f"{path}: listed in the manifest but missing")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise MapFormatError(f"{path}: corrupt JSON ({_brief(exc)})") from exc
    except OSError as exc:
        raise MapFormatError(f"{path}: cannot be read ({_brief(exc)})") from exc


@contextmanager
def _reading(path: Path, what: str = "") -> Iterator[None]:
    """Turn what a layer type's constructor raises on malformed content into a MapFormatError naming the file."""
    try:
        yield
    except MapFormatError:
        raise
    except KeyError as exc:
        raise MapFormatError(f"{path}: {what}{': ' if what else ''}missing key {exc.args[0]!r}") from exc
    except (TypeError, ValueError, IndexError, AttributeError, OverflowError) as exc:
        raise MapFormatError(f"{path}: {what}{': ' if what else ''}{_brief(exc)}") from exc
    except Exception as exc:
        if type(exc).__module__.startswith("networkx"):
            raise MapFormatError(f"{path}: {what}{': ' if what else ''}{_brief(exc)}") from exc
        raise


def _mapping(value: Any, path: Path, what: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise MapFormatError(f"{path}: {what} must be a JSON object, got {type(value).__name__}")
    return value


def _vocabulary(value: Any, path: Path, what: str) -> Vocabulary:
    d = _mapping(value, path, what)
    names, things = d.get("names"), d.get("is_thing")
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names) or not names:
        raise MapFormatError(f"{path}: {what}.names must be a non-empty list of class names")
    if not isinstance(things, list) or len(things) != len(names) or not all(isinstance(t, bool) for t in things):
        raise MapFormatError(f"{path}: {what}.is_thing must be a list of {len(names)} true/false values")
    with _reading(path, what):
        return Vocabulary.from_dict(d)


def _number(value: Any, path: Path, what: str, positive: bool = False) -> float:
    try:
        ok = not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value)
    except OverflowError:  # an integer beyond float range
        ok = False
    if not ok:
        raise MapFormatError(f"{path}: {what} must be a finite number, got {value!r}"[:300])
    if positive and value <= 0:
        raise MapFormatError(f"{path}: {what} must be positive, got {value!r}")
    return float(value)


def _matrix(value: Any, path: Path, what: str, shape: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != shape or not np.all(np.isfinite(arr)):
        raise MapFormatError(f"{path}: {what} must be {'x'.join(map(str, shape))} finite numbers, got {value!r}"[:300])
    return arr


def _geometry_arrays(geom: Geometry) -> dict[str, np.ndarray]:
    arrays: dict[str, np.ndarray] = {"points": geom.points}
    if geom.colors is not None:
        arrays["colors"] = geom.colors
    if geom.normals is not None:
        arrays["normals"] = geom.normals
    if geom.mesh is not None:
        _mesh_arrays("mesh", geom.mesh, arrays)
    if geom.voxel_size is not None:
        arrays["voxel_size"] = np.array(geom.voxel_size)
    return arrays


def _geometry_from(arrays: _Arrays) -> Geometry:
    dims: dict[str, tuple[int, str]] = {}
    points = arrays.get("points", "f", ("N", 3), dims, finite=True)
    colors = arrays.get("colors", "f", ("N", 3), dims, required=False)
    normals = arrays.get("normals", "f", ("N", 3), dims, required=False)
    if any(k.startswith("mesh.") for k in arrays.arrays):
        mesh = _mesh_from("mesh", arrays)
    else:
        mesh = None
    voxel = arrays.get("voxel_size", "fiu", (), required=False)
    voxel_size = None if voxel is None else _number(voxel.item(), arrays.path, "array 'voxel_size'", positive=True)
    arrays.check_all_used()
    with _reading(arrays.path):
        return Geometry(points=points, colors=colors, normals=normals, mesh=mesh, voxel_size=voxel_size)


def _occupancy_from(arrays: _Arrays) -> OccupancyMaps:
    names = sorted(k[: -len(".data")] for k in arrays.arrays if k.endswith(".data"))
    grids = OccupancyMaps()
    for name in names:
        data = arrays.get(f"{name}.data", np.int8, (None, None))
        meta_arr = arrays.get(f"{name}.meta", "U", ())
        try:
            meta = json.loads(str(meta_arr))
        except json.JSONDecodeError as exc:
            raise MapFormatError(f"{arrays.path}: array {name + '.meta'!r} is not JSON ({_brief(exc)})") from exc
        meta = _mapping(meta, arrays.path, f"grid {name!r} meta")
        resolution = _number(meta.get("resolution"), arrays.path, f"grid {name!r} resolution", positive=True)
        origin = _matrix(meta.get("origin"), arrays.path, f"grid {name!r} origin", (3,))
        frame = meta.get("frame_id", "map")
        if not isinstance(frame, str):
            raise MapFormatError(f"{arrays.path}: grid {name!r} frame_id must be a string, got {frame!r}")
        with _reading(arrays.path, f"grid {name!r}"):
            grids[name] = OccupancyGrid(data, resolution, tuple(origin), frame)
    arrays.check_all_used()
    return grids


def _semantics_from(arrays: _Arrays, vocab: Vocabulary, points: int | None) -> Semantics:
    dims: dict[str, tuple[int, str]] = {}
    class_ids = arrays.get("class_ids", "iu", ("N",), dims)
    instance_ids = arrays.get("instance_ids", "iu", ("N",), dims)
    plane_ids = arrays.get("plane_ids", "iu", ("N",), dims, required=False)
    arrays.check_all_used()
    if points is not None and len(class_ids) != points:
        raise MapFormatError(
            f"{arrays.path}: {len(class_ids)} labels for the {points} points of the geometry layer (one per point)"
        )
    if class_ids.size and (class_ids.min() < 0 or class_ids.max() >= len(vocab)):
        raise MapFormatError(
            f"{arrays.path}: class ids range {class_ids.min()}..{class_ids.max()}, the vocabulary has {len(vocab)} "
            f"classes (0..{len(vocab) - 1})"
        )
    for key, ids in (("instance_ids", instance_ids), ("plane_ids", plane_ids)):
        if ids is not None and ids.size and (ids.min() < -(2**31) or ids.max() >= 2**31):
            raise MapFormatError(f"{arrays.path}: array {key!r} has values beyond 32-bit integers")
    return Semantics(class_ids, instance_ids, vocab, plane_ids)


_INSTANCE_KEYS = ("id", "class", "box", "score", "attributes", "completion")
_COMPLETION_KEYS = ("completer", "model_id", "pose", "scale", "score", "parts", "joints")


def _instances_from(records: Any, arrays: _Arrays, path: Path) -> ObjectInstances:
    if not isinstance(records, list):
        raise MapFormatError(f"{path}: expected a JSON list of objects, got {type(records).__name__}")
    insts = ObjectInstances()
    for n, rec in enumerate(records):
        rec = _mapping(rec, path, f"entry {n}")
        missing = [k for k in _INSTANCE_KEYS if k not in rec]
        if missing:
            raise MapFormatError(f"{path}: entry {n} lacks {', '.join(missing)}")
        oid = rec["id"]
        if isinstance(oid, bool) or not isinstance(oid, int):
            raise MapFormatError(f"{path}: entry {n}: id must be an integer, got {oid!r}")
        if oid in insts:
            raise MapFormatError(f"{path}: entry {n}: object id {oid} appears twice")
        what = f"object {oid}"
        if not isinstance(rec["class"], str):
            raise MapFormatError(f"{path}: {what}: class must be a string, got {rec['class']!r}")
        score = _number(rec["score"], path, f"{what} score")
        attributes = _mapping(rec["attributes"], path, f"{what} attributes")
        box = _mapping(rec["box"], path, f"{what} box")
        with _reading(path, f"{what} box"):
            center = _matrix(box["center"], path, f"{what} box center", (3,))
            size = _matrix(box["size"], path, f"{what} box size", (3,))
            obox = OrientedBox(center, _number(box["yaw"], path, f"{what} box yaw"), size)
        dims: dict[str, tuple[int, str]] = {}
        points = arrays.get(f"{oid}.points", "f", ("N", 3), dims, finite=True)
        colors = arrays.get(f"{oid}.colors", "f", ("N", 3), dims, required=False)
        completion = None
        if rec["completion"] is not None:
            c = _mapping(rec["completion"], path, f"{what} completion")
            missing = [k for k in _COMPLETION_KEYS if k not in c]
            if missing:
                raise MapFormatError(f"{path}: {what} completion lacks {', '.join(missing)}")
            if not isinstance(c["parts"], list) or not isinstance(c["joints"], list):
                raise MapFormatError(f"{path}: {what} completion: parts and joints must be lists")
            with _reading(path, f"{what} completion"):
                parts = []
                for k, p in enumerate(c["parts"]):
                    p = _mapping(p, path, f"{what} part {k}")
                    if not isinstance(p.get("name"), str):
                        raise MapFormatError(f"{path}: {what} part {k}: name must be a string")
                    pose = _matrix(p.get("pose"), path, f"{what} part {k} pose", (4, 4))
                    parts.append(Part(p["name"], _mesh_from(f"{oid}.part.{k}.mesh", arrays), pose))
                joints = [Joint.from_dict(_mapping(j, path, f"{what} joint {k}")) for k, j in enumerate(c["joints"])]
                completion = Completion(
                    mesh=_mesh_from(f"{oid}.completion.mesh", arrays),
                    pose=_matrix(c["pose"], path, f"{what} completion pose", (4, 4)),
                    completer=str(c["completer"]),
                    model_id=c["model_id"],
                    scale=_matrix(c["scale"], path, f"{what} completion scale", (3,)),
                    score=_number(c["score"], path, f"{what} completion score"),
                    parts=parts,
                    joints=joints,
                )
        with _reading(path, what):
            insts.add(
                ObjectInstance(
                    id=oid,
                    class_name=rec["class"],
                    points=points,
                    colors=colors,
                    box=obox,
                    score=score,
                    completion=completion,
                    attributes=attributes,
                )
            )
    arrays.check_all_used()
    return insts


def _layer_file(layers: dict[str, Any], layer: str, key: str, directory: Path, manifest: Path) -> Path:
    """The file a manifest entry names: a plain file name inside the map folder."""
    name = layers[layer].get(key)
    if not isinstance(name, str) or not name or name in (".", "..") or "/" in name or "\\" in name:
        raise MapFormatError(
            f"{manifest}: layers.{layer}.{key} must be a file name inside the map folder, got {name!r}"
        )
    return directory / name


def write_layers(m: LayeredMap, directory: Path) -> dict[str, Any]:
    """Write every present layer into ``directory`` and return the manifest describing them."""
    layers: dict[str, dict[str, str]] = {}
    if m.occupancy:
        arrays: dict[str, np.ndarray] = {}
        for name, grid in m.occupancy.items():
            arrays[f"{name}.data"] = grid.data
            arrays[f"{name}.meta"] = np.array(
                json.dumps({"resolution": grid.resolution, "origin": list(grid.origin), "frame_id": grid.frame_id})
            )
        _save_npz(directory / "occupancy.npz", arrays)
        layers["occupancy"] = {"file": "occupancy.npz"}
    for name in ("geometry", "augmented"):
        geom = getattr(m, name)
        if geom is not None:
            _save_npz(directory / f"{name}.npz", _geometry_arrays(geom))
            layers[name] = {"file": f"{name}.npz"}
    if m.semantics is not None:
        _save_npz(
            directory / "semantics.npz",
            {
                "class_ids": m.semantics.class_ids,
                "instance_ids": m.semantics.instance_ids,
                **({"plane_ids": m.semantics.plane_ids} if m.semantics.plane_ids is not None else {}),
            },
        )
        layers["semantics"] = {"file": "semantics.npz", "vocabulary": m.semantics.vocabulary.to_dict()}
    if m.instances is not None:
        records, arrays = [], {}
        for inst in m.instances:
            key = str(inst.id)
            arrays[f"{key}.points"] = inst.points
            if inst.colors is not None:
                arrays[f"{key}.colors"] = inst.colors
            rec: dict[str, Any] = {
                "id": inst.id,
                "class": inst.class_name,
                "box": inst.box.to_dict(),
                "score": inst.score,
                "attributes": inst.attributes,
                "completion": None,
            }
            c = inst.completion
            if c is not None:
                _mesh_arrays(f"{key}.completion.mesh", c.mesh, arrays)
                for k, part in enumerate(c.parts):
                    _mesh_arrays(f"{key}.part.{k}.mesh", part.mesh, arrays)
                rec["completion"] = {
                    "completer": c.completer,
                    "model_id": c.model_id,
                    "pose": c.pose.tolist(),
                    "scale": c.scale.tolist(),
                    "score": c.score,
                    "parts": [{"name": p.name, "pose": np.asarray(p.pose).tolist()} for p in c.parts],
                    "joints": [j.to_dict() for j in c.joints],
                }
            records.append(rec)
        write_json(directory / "instances.json", records)
        _save_npz(directory / "instances.npz", arrays)
        layers["instances"] = {"file": "instances.json", "arrays": "instances.npz"}
    if m.contact_graph is not None:
        write_json(directory / "contact_graph.json", m.contact_graph.to_dict())
        layers["contact_graph"] = {"file": "contact_graph.json"}
    return {
        "format": MAP_FORMAT,
        "version": MAP_FORMAT_VERSION,
        "vocabulary": m.vocabulary.to_dict(),
        "provenance": dict(m.provenance),
        "metadata": m.metadata,
        "layers": layers,
    }


def read_layers(manifest: dict[str, Any], directory: Path) -> LayeredMap:
    """The map ``manifest`` describes; a malformed manifest or layer file is a MapFormatError naming the file
    and what was expected (missing arrays or keys, wrong dtypes or shapes, out-of-range indices, bad JSON)."""
    mpath = directory / "manifest.json"
    manifest = _mapping(manifest, mpath, "the manifest")
    if "vocabulary" not in manifest:
        raise MapFormatError(f"{mpath}: no 'vocabulary'")
    vocab = _vocabulary(manifest["vocabulary"], mpath, "vocabulary")
    provenance = _mapping(manifest.get("provenance", {}), mpath, "provenance")
    if not all(isinstance(v, str) for v in provenance.values()):
        raise MapFormatError(f"{mpath}: provenance must map layer names to plugin names (strings)")
    metadata = _mapping(manifest.get("metadata", {}), mpath, "metadata")
    layers = _mapping(manifest.get("layers", {}), mpath, "layers")
    unknown = sorted(k for k in layers if k not in MAP_LAYERS)
    if unknown:
        raise MapFormatError(f"{mpath}: unknown layers {unknown}; version 1 has {', '.join(MAP_LAYERS)}")
    for name, entry in layers.items():
        _mapping(entry, mpath, f"layers.{name}")
    m = LayeredMap(vocabulary=vocab, provenance=dict(provenance), metadata=dict(metadata))

    def npz(layer: str, key: str = "file") -> _Arrays:
        return _load_npz(_layer_file(layers, layer, key, directory, mpath))

    if "occupancy" in layers:
        m.occupancy = _occupancy_from(npz("occupancy"))
    for name in ("geometry", "augmented"):
        if name in layers:
            setattr(m, name, _geometry_from(npz(name)))
    if "semantics" in layers:
        sem_vocab = _vocabulary(layers["semantics"].get("vocabulary"), mpath, "layers.semantics.vocabulary")
        points = None if m.geometry is None else len(m.geometry.points)
        m.semantics = _semantics_from(npz("semantics"), sem_vocab, points)
    if "instances" in layers:
        path = _layer_file(layers, "instances", "file", directory, mpath)
        records = _read_json(path)
        m.instances = _instances_from(records, npz("instances", "arrays"), path)
    if "contact_graph" in layers:
        path = _layer_file(layers, "contact_graph", "file", directory, mpath)
        graph = _mapping(_read_json(path), path, "the contact graph")
        for key in ("support", "proximal"):
            _mapping(graph.get(key), path, key)
        with _reading(path):
            m.contact_graph = ContactGraph.from_dict(graph)
    return m
