"""Model libraries (the "CAD database"): the on-disk format, and loaders for users' own models.

Native format (``stratamap models build`` writes it)::

    DIR/models.json             {"format": "stratamap.library", "version": 1, "models": [...]}
    DIR/meshes/<model id>/<part>.ply

Each model record: ``id``, ``class``, ``family``, ``params`` (the sampled parameters),
``bounds`` ([[xmin, ymin, zmin], [xmax, ymax, zmax]] in the canonical frame: +z up, front along
-y, origin at the bottom center), ``feature_planes`` (rows ``[nx, ny, nz, d, area]`` of the
largest horizontal and vertical planar surfaces, ``n.x + d = 0``), ``support_surfaces``,
``parts`` (``name``, ``file``, ``link``, ``albedo``, ``semantic``) and ``joints`` (``name``,
``type``, ``parent``, ``child``, ``origin`` 4x4 child-in-parent at q = 0, ``axis``, ``lower``,
``upper``). Part meshes are stored in the model frame at joint positions 0.

The same loader reads

* a folder of OBJ/STL/GLB/PLY files with ``classes.csv`` (columns ``file,class`` and optionally
  ``id``) or ``classes.json`` (``{"file": "class"}`` or a list of ``{"file", "class", "id"}``);
* PartNet-Mobility folders (``mobility.urdf`` + ``textured_objs/`` + ``meta.json``), turned to
  face -y; one such folder or a folder of them;
* a ShapeNet-layout folder (``SYNSET/MODEL_ID/models/model_normalized.obj``, as ShapeNetCore v2
  ships it; ``taxonomy.json`` beside the synsets is optional), synsets mapped to classes by
  :data:`SHAPENET_CLASSES`, the y-up models turned z-up and, having no units, scaled to their
  class's typical height; the synsets and models it cannot use are listed in ``problems``;
* a single ``.urdf`` file (``package://`` URIs resolved through ``package.xml``), as one
  articulated model; missing meshes fall back to collision geometry and are reported.

Part colours come from the models themselves (:func:`mesh_face_colors`): a mesh's own per-face or
per-vertex colours, its texture sampled at each face (the image box-filtered first, so a face takes
the mean colour of its neighbourhood), its material's diffuse colour (MTL ``Kd``), else the URDF
``<material><color>`` of its visual, else :data:`NEUTRAL_ALBEDO`. PartNet-Mobility folders shipped
without their texture images take each face's colour from the nearest of the coloured point
samples every PartNet-Mobility object carries (``point_sample/*rgba*.txt``).
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.atomic import atomic_directory, check_output_folder, write_json
from stratamap.core.documents import read_data_text
from stratamap.core.errors import DataError
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import Joint

trimesh = lazy_module("trimesh")

LIBRARY_FORMAT = "stratamap.library"
LIBRARY_VERSION = 1
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".glb", ".gltf", ".off")

#: PartNet-Mobility ``model_cat`` -> stratamap class.
PARTNET_CLASSES = {
    "Chair": "chair",
    "StorageFurniture": "cabinet",
    "Table": "table",
    "Refrigerator": "fridge",
    "Microwave": "microwave",
    "Oven": "oven",
    "Display": "monitor",
    "Laptop": "laptop",
    "Box": "box",
    "Bottle": "bottle",
    "Mug": "cup",
    "Dishwasher": "cabinet",
}

#: ShapeNet synset id -> stratamap class, for the synsets whose objects the default vocabulary
#: names (Scan2CAD's eight categories among them). Synsets not listed here (bed 02818832, bathtub
#: 02808440, trash bin 02747177, lamp, airplane, ...) have no class and are skipped when loading.
SHAPENET_CLASSES = {
    "03001627": "chair",
    "04379243": "table",
    "02933112": "cabinet",
    "02871439": "shelf",  # bookshelf
    "04256520": "sofa",
    "03211117": "monitor",  # display
    "03761084": "microwave",
    "03642806": "laptop",
    "02876657": "bottle",
    "03797390": "cup",  # mug
    "03991062": "plant",  # pot (potted plants)
    "02828884": "bench",
}
#: Names of common synsets that are not loaded, so a skipped folder is reported by what it holds.
SHAPENET_NAMES = {
    "02818832": "bed",
    "02808440": "bathtub",
    "02747177": "trash bin",
    "03636649": "lamp",
    "04004475": "printer",
    "02691156": "airplane",
    "02958343": "car",
    "04530566": "vessel",
    "04090263": "rifle",
    "03467517": "guitar",
}
SHAPENET_MESH = Path("models") / "model_normalized.obj"

#: Colour of parts whose source gives none (a light, slightly warm grey, like unpainted furniture).
NEUTRAL_ALBEDO = (0.72, 0.71, 0.68)
#: Texture images are box-filtered to at most this many cells a side before faces sample them.
TEXTURE_CELLS = 32

Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
#: PartNet-Mobility URDFs are z-up in their base frame (the base joint turns the y-up meshes) and
#: face -x; a quarter turn about z brings the front to -y, stratamap's canonical front.
PARTNET_TO_CANONICAL = np.array([[0.0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])


@dataclass
class LibraryPart:
    name: str
    link: str = "body"
    albedo: tuple[float, float, float] = (0.6, 0.6, 0.6)
    semantic: str = ""
    file: Path | None = None
    mesh: trimesh.Trimesh | None = None  # loaded on first use when ``file`` is set
    #: (F, 3) colour of each face in [0, 1] when the source colours faces differently (textures,
    #: several materials); ``albedo`` is then their area-weighted mean.
    face_colors: np.ndarray | None = None

    def load(self) -> trimesh.Trimesh:
        if self.mesh is None:
            if self.file is None:
                raise DataError(f"part {self.name!r} has neither a mesh nor a file")
            if not self.file.is_file():
                raise DataError(f"{self.file}: mesh file of part {self.name!r} is missing")
            try:
                loaded = trimesh.load(self.file, force="mesh", process=False)
            except Exception as exc:
                raise DataError(f"{self.file}: cannot be read as a mesh ({exc})") from exc
            if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
                raise DataError(f"{self.file}: contains no triangles")
            self.mesh = loaded
        return self.mesh


@dataclass
class LibraryModel:
    id: str
    class_name: str
    family: str
    params: dict[str, Any]
    parts: list[LibraryPart]
    joints: list[Joint] = field(default_factory=list)
    bounds: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))
    feature_planes: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    support_surfaces: list[list[float]] = field(default_factory=list)
    source: str = "stratamap"

    @property
    def size(self) -> np.ndarray:
        return self.bounds[1] - self.bounds[0]

    def mesh(self) -> trimesh.Trimesh:
        """The whole model in its canonical frame (parts concatenated)."""
        return trimesh.util.concatenate([p.load() for p in self.parts])

    def to_record(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "class": self.class_name,
            "family": self.family,
            "params": self.params,
            "bounds": np.asarray(self.bounds).tolist(),
            "feature_planes": np.round(np.asarray(self.feature_planes), 6).tolist(),
            "support_surfaces": [list(map(float, s)) for s in self.support_surfaces],
            "parts": [
                {
                    "name": p.name,
                    "file": p.file.name if p.file else None,
                    "link": p.link,
                    "albedo": list(p.albedo),
                    "semantic": p.semantic,
                }
                for p in self.parts
            ],
            "joints": [j.to_dict() for j in self.joints],
            "source": self.source,
        }


@dataclass
class ModelLibrary:
    models: list[LibraryModel]
    root: Path | None = None
    problems: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.models)

    def __iter__(self):
        return iter(self.models)

    def get(self, model_id: str) -> LibraryModel:
        for m in self.models:
            if m.id == model_id:
                return m
        raise KeyError(f"no model {model_id!r} in the library")

    def by_class(self, class_name: str) -> list[LibraryModel]:
        return [m for m in self.models if m.class_name == class_name]

    def classes(self) -> list[str]:
        return sorted({m.class_name for m in self.models})

    def families(self) -> list[str]:
        return sorted({m.family for m in self.models})

    def content_hash(self) -> str:
        """A key that changes whenever a model record or a mesh file changes (for caches)."""
        h = hashlib.sha256()
        for m in self.models:
            h.update(json.dumps(m.to_record(), sort_keys=True).encode())
            for p in m.parts:
                if p.file is not None and p.file.is_file():
                    st = p.file.stat()
                    h.update(f"{p.file.name}:{st.st_size}:{st.st_mtime_ns}".encode())
        return h.hexdigest()[:16]

    @classmethod
    def load(cls, path: str | Path, up_axis: str = "z") -> ModelLibrary:
        """Load a native library, a folder of meshes with a class table, or PartNet-Mobility folders."""
        path = Path(path)
        if not path.exists():
            raise DataError(f"{path}: model library not found")
        if path.is_file() and path.suffix.lower() == ".urdf":
            model = model_from_urdf(path, path.stem, "object", "urdf")
            lib = ModelLibrary([model], root=path.parent)
            lib.problems.extend(f"{path}: {w}" for w in model.params.get("warnings", []))
            return lib
        if (path / "models.json").is_file():
            return _load_native(path)
        if (path / "mobility.urdf").is_file():
            return _load_partnet_folders([path])
        subdirs = sorted(p for p in path.iterdir() if p.is_dir() and (p / "mobility.urdf").is_file())
        if subdirs:
            return _load_partnet_folders(subdirs, root=path)
        if (path / "classes.csv").is_file() or (path / "classes.json").is_file():
            return _load_mesh_folder(path, up_axis)
        if _is_shapenet(path):
            return load_shapenet(path)
        raise DataError(
            f"{path}: not a model library: expected models.json (stratamap), mobility.urdf folders "
            "(PartNet-Mobility), SYNSET/MODEL/models/model_normalized.obj folders (ShapeNet), or mesh files "
            "with classes.csv / classes.json"
        )


# ------------------------------------------------------------------------------------------
# Derived descriptors


def feature_planes(mesh: trimesh.Trimesh, min_area: float = 0.01, max_planes: int = 12) -> np.ndarray:
    """Largest horizontal and vertical planar surfaces: rows ``[nx, ny, nz, d, area]``."""
    if len(mesh.faces) == 0:
        return np.zeros((0, 5))
    normals = np.asarray(mesh.face_normals)
    areas = np.asarray(mesh.area_faces)
    centers = np.asarray(mesh.triangles_center)
    horizontal = np.abs(normals[:, 2]) > 0.95
    vertical = np.abs(normals[:, 2]) < 0.05
    keep = (horizontal | vertical) & (areas > 0)
    if not keep.any():
        return np.zeros((0, 5))
    n = normals[keep].copy()
    n[horizontal[keep]] = np.sign(n[horizontal[keep], 2:3]) * np.array([0, 0, 1.0])
    # Quantize the normal direction (5 degrees) and offset (1 cm) to group coplanar faces.
    ang = np.round(np.degrees(np.arctan2(n[:, 1], n[:, 0])) / 5.0).astype(np.int64)
    ang[np.abs(n[:, 2]) > 0.5] = 10_000 * np.sign(n[np.abs(n[:, 2]) > 0.5, 2]).astype(np.int64)
    d = -np.einsum("ij,ij->i", n, centers[keep])
    dq = np.round(d / 0.01).astype(np.int64)
    keys = np.stack([ang, dq], 1)
    uniq, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    a = areas[keep]
    total = np.bincount(inv, weights=a)
    nsum = np.stack([np.bincount(inv, weights=n[:, k] * a) for k in range(3)], 1)
    dsum = np.bincount(inv, weights=d * a)
    norm = np.linalg.norm(nsum, axis=1, keepdims=True)
    valid = norm[:, 0] > 1e-12
    nsum, dsum, total, norm = nsum[valid], dsum[valid], total[valid], norm[valid]
    normal = nsum / norm
    rows = np.c_[normal, dsum / total, total]
    rows = rows[total >= min_area]
    order = np.lexsort((rows[:, 3], -rows[:, 4]))
    return rows[order][:max_planes]


def _canonicalize(parts: list[LibraryPart], joints: list[Joint], root_link: str) -> np.ndarray:
    """Translate parts so the origin is the bottom center; returns the bounds after the shift."""
    meshes = [p.load() for p in parts]
    lo = np.min([m.bounds[0] for m in meshes], 0)
    hi = np.max([m.bounds[1] for m in meshes], 0)
    shift = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    for m in meshes:
        m.apply_translation(shift)
    for j in joints:
        if j.parent == root_link:
            j.origin = j.origin.copy()
            j.origin[:3, 3] += shift
    return np.array([lo + shift, hi + shift])


# ------------------------------------------------------------------------------------------
# Native format


def model_to_library(model: Any) -> LibraryModel:
    """A procedural :class:`~stratamap.core.synthetic.models.Model` as a library entry (in memory)."""
    mesh = model.mesh()
    return LibraryModel(
        id=model.id,
        class_name=model.class_name,
        family=model.family,
        params=model.params,
        parts=[LibraryPart(p.name, p.link, tuple(p.albedo), p.semantic, mesh=p.mesh) for p in model.parts],
        joints=list(model.joints),
        bounds=np.asarray(model.bounds),
        feature_planes=feature_planes(mesh),
        support_surfaces=[list(s) for s in model.support_surfaces],
    )


def write_library(
    models: Iterable[LibraryModel], out: str | Path, progress: Callable[[int], None] | None = None
) -> Path:
    """Write models in the native format; an earlier library in ``out`` is replaced atomically as a
    whole, and a folder with anything else in it is refused (a ConfigError), never emptied."""
    out = check_output_folder(out, lambda folder: (folder / "models.json").is_file(), "model library")
    with atomic_directory(out) as staging:
        records = []
        for k, m in enumerate(models):
            folder = staging / "meshes" / m.id
            folder.mkdir(parents=True, exist_ok=True)
            for p in m.parts:
                name = f"{p.name}.ply"
                p.load().export(folder / name, file_type="ply", encoding="binary")
                p.file = out / "meshes" / m.id / name
            rec = m.to_record()
            for prec in rec["parts"]:
                prec["file"] = f"meshes/{m.id}/{prec['name']}.ply"
            records.append(rec)
            if progress is not None:
                progress(k + 1)
        write_json(
            staging / "models.json", {"format": LIBRARY_FORMAT, "version": LIBRARY_VERSION, "models": records}, indent=1
        )
    return out


def build_library(
    out: str | Path,
    per_family: int,
    seed: int = 0,
    families: list[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ModelLibrary:
    """Sample ``per_family`` models of every family and write them as a native library."""
    from stratamap.core.synthetic.models import FAMILIES, make_model

    names = families or list(FAMILIES)
    unknown = sorted(set(names) - set(FAMILIES))
    if unknown:
        raise DataError(f"unknown model families {unknown}; families are {sorted(FAMILIES)}")
    total = len(names) * per_family
    models = (model_to_library(make_model(f, seed, i)) for f in names for i in range(per_family))
    write_library(models, out, None if progress is None else (lambda k: progress(k, total)))
    return ModelLibrary.load(out)


def _load_native(path: Path) -> ModelLibrary:
    index = path / "models.json"
    try:
        doc = json.loads(read_data_text(index, "model library index"))
    except json.JSONDecodeError as exc:
        raise DataError(f"{index}: corrupt JSON ({exc})") from exc
    if doc.get("format") != LIBRARY_FORMAT or doc.get("version") != LIBRARY_VERSION:
        raise DataError(
            f"{index}: format {doc.get('format')!r} v{doc.get('version')} is not {LIBRARY_FORMAT!r} v{LIBRARY_VERSION}"
        )
    lib = ModelLibrary([], root=path)
    for k, rec in enumerate(doc.get("models", [])):
        try:
            parts = [
                LibraryPart(
                    p["name"],
                    p.get("link", "body"),
                    tuple(p.get("albedo", (0.6, 0.6, 0.6))),
                    p.get("semantic", ""),
                    file=path / p["file"],
                )
                for p in rec["parts"]
            ]
            lib.models.append(
                LibraryModel(
                    id=rec["id"],
                    class_name=rec["class"],
                    family=rec.get("family", ""),
                    params=rec.get("params", {}),
                    parts=parts,
                    joints=[Joint.from_dict(j) for j in rec.get("joints", [])],
                    bounds=np.array(rec["bounds"], float),
                    feature_planes=np.array(rec.get("feature_planes", []), float).reshape(-1, 5),
                    support_surfaces=rec.get("support_surfaces", []),
                    source=rec.get("source", "stratamap"),
                )
            )
        except (KeyError, TypeError, ValueError) as exc:
            lib.problems.append(f"{index}: model #{k} ({rec.get('id', '?')}) is malformed: {exc!r}; skipped")
    return lib


# ------------------------------------------------------------------------------------------
# A user's folder of meshes


def _read_class_table(path: Path) -> list[dict[str, str]]:
    if (path / "classes.csv").is_file():
        text = read_data_text(path / "classes.csv", "class table")
        rows = list(csv.DictReader(io.StringIO(text, newline="")))
        if rows and not {"file", "class"} <= set(rows[0]):
            raise DataError(f"{path / 'classes.csv'}: needs columns 'file' and 'class', has {list(rows[0])}")
        return rows
    try:
        doc = json.loads(read_data_text(path / "classes.json", "class table"))
    except json.JSONDecodeError as exc:
        raise DataError(f"{path / 'classes.json'}: corrupt JSON ({exc})") from None
    if isinstance(doc, dict):
        return [{"file": f, "class": c} for f, c in doc.items()]
    return list(doc)


def _load_mesh_folder(path: Path, up_axis: str) -> ModelLibrary:
    lib = ModelLibrary([], root=path)
    for row in _read_class_table(path):
        file = path / row["file"]
        model_id = row.get("id") or Path(row["file"]).stem
        if file.suffix.lower() not in MESH_SUFFIXES:
            lib.problems.append(f"{file}: unsupported mesh format (use one of {', '.join(MESH_SUFFIXES)}); skipped")
            continue
        try:
            part, mesh = _coloured_part(file)
            if up_axis == "y":
                mesh.apply_transform(Y_UP_TO_Z_UP)
            elif up_axis != "z":
                raise DataError(f"up_axis must be 'z' or 'y', got {up_axis!r}")
            scale_text = (row.get("scale") or "").strip()
            if scale_text:
                try:
                    metres_per_unit = float(scale_text)
                except ValueError:
                    metres_per_unit = float("nan")
                if not np.isfinite(metres_per_unit) or metres_per_unit <= 0:
                    raise DataError(
                        f"{path}: row of {row['file']!r}: scale must be a positive number, got {scale_text!r}"
                    )
                mesh.apply_scale(metres_per_unit)
            bounds = _canonicalize([part], [], "body")
        except DataError as exc:
            lib.problems.append(f"{exc}; skipped")
            continue
        model = LibraryModel(
            model_id,
            row["class"],
            row.get("family", row["class"]),
            {"units": "m"} if scale_text else {},
            [part],
            [],
            bounds,
            feature_planes(mesh),
            source=str(file),
        )
        if not scale_text:
            model = normalise_size(model)
            if "units" in model.params and model.params["units"] != "m":
                lib.problems.append(
                    f"{file}: {model.params['units']}; give a scale column in classes.csv (metres per unit) to override"
                )
        lib.models.append(model)
    return lib


# ------------------------------------------------------------------------------------------
# ShapeNet


def _is_synset(name: str) -> bool:
    return len(name) == 8 and name.isdigit()


def _is_shapenet(path: Path) -> bool:
    """A ShapeNet root (synset folders) or one synset's folder (model folders holding the mesh)."""
    if _is_synset(path.name) and any((m / SHAPENET_MESH).is_file() for m in path.iterdir() if m.is_dir()):
        return True
    return any(p.is_dir() and _is_synset(p.name) for p in path.iterdir())


def _shapenet_taxonomy(root: Path) -> dict[str, str]:
    """synset id -> its first name in ``taxonomy.json`` (ShapeNetCore v2 ships one), when present."""
    file = root / "taxonomy.json"
    if not file.is_file():
        return {}
    try:
        doc = json.loads(read_data_text(file, "ShapeNet taxonomy"))
    except json.JSONDecodeError as exc:
        raise DataError(f"{file}: corrupt JSON ({exc})") from None
    if not isinstance(doc, list):
        raise DataError(f"{file}: expected a list of {{synsetId, name}} records")
    return {
        str(r["synsetId"]): str(r.get("name", "")).split(",")[0] for r in doc if isinstance(r, dict) and "synsetId" in r
    }


def _coloured_part(file: Path) -> tuple[LibraryPart, Any]:
    """A mesh file as a library part with its colours (mean albedo; per-face colours where they
    vary), and its mesh as a plain triangle mesh for the caller to turn and scale."""
    part = LibraryPart("mesh", file=file)
    mesh = part.load()
    colors = mesh_face_colors(mesh)
    if colors is not None:
        part.albedo = mean_color(mesh, colors)
        part.face_colors = None if np.ptp(colors, axis=0).max() < 1e-3 else colors.astype(np.float32)
    part.mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    return part, part.mesh


def load_shapenet_model(file: Path, synset: str, model_id: str, class_name: str) -> LibraryModel:
    """One ShapeNet ``model_normalized.obj`` as a library model: turned from y up to z up, origin at
    its bottom centre, scaled from ShapeNet's unitless normalisation (unit box diagonal) to the
    class's typical height. ``params["cad_to_model"]`` is the 4x4 that takes a point of the file
    (ShapeNet's frame, the one Scan2CAD's alignments use) to the model's frame."""
    part, mesh = _coloured_part(file)
    mesh.apply_transform(Y_UP_TO_Z_UP)
    lo = mesh.bounds[0].copy()
    bounds = _canonicalize([part], [], "body")
    shift = bounds[0] - lo
    model = LibraryModel(
        f"shapenet_{synset}_{model_id}",
        class_name,
        f"shapenet_{synset}",
        {"synset": synset, "shapenet_id": model_id, "units": None},
        [part],
        [],
        bounds,
        feature_planes(mesh),
        source=str(file),
    )
    normalise_size(model, unitless=True)
    factor = float(model.params.get("scale_to_metres", 1.0))
    to_model = np.diag([factor, factor, factor, 1.0])
    to_model[:3, 3] = factor * shift
    model.params["cad_to_model"] = np.round(to_model @ Y_UP_TO_Z_UP, 9).tolist()
    return model


def load_shapenet(path: str | Path) -> ModelLibrary:
    """A ShapeNet-layout folder (``SYNSET/MODEL_ID/models/model_normalized.obj``; or one synset's
    folder) as a library. Synsets without a class in :data:`SHAPENET_CLASSES`, model folders
    without the mesh and meshes that cannot be read are skipped, each reported in ``problems``."""
    path = Path(path)
    if _is_synset(path.name) and not any(_is_synset(p.name) for p in path.iterdir() if p.is_dir()):
        root, synsets = path.parent, [path]
    else:
        root, synsets = path, sorted(p for p in path.iterdir() if p.is_dir() and _is_synset(p.name))
    names = {**SHAPENET_NAMES, **_shapenet_taxonomy(root)}
    lib = ModelLibrary([], root=path)
    for folder in synsets:
        synset = folder.name
        models = sorted(p for p in folder.iterdir() if p.is_dir())
        class_name = SHAPENET_CLASSES.get(synset)
        if class_name is None:
            what = f" ({names[synset]})" if names.get(synset) else ""
            lib.problems.append(
                f"{folder}: synset {synset}{what} has no stratamap class (SHAPENET_CLASSES); {len(models)} models "
                "skipped"
            )
            continue
        for model_dir in models:
            file = model_dir / SHAPENET_MESH
            if not file.is_file():
                lib.problems.append(f"{model_dir}: no {SHAPENET_MESH.as_posix()}; skipped")
                continue
            try:
                lib.models.append(load_shapenet_model(file, synset, model_dir.name, class_name))
            except DataError as exc:
                lib.problems.append(f"{exc}; skipped")
    if not lib.models and not lib.problems:
        raise DataError(f"{path}: no SYNSET/MODEL_ID/{SHAPENET_MESH.as_posix()} found")
    return lib


#: Units a mesh without declared units may be in (metres per unit), tried when its size is implausible in metres.
GUESSED_UNITS = {"mm": 0.001, "cm": 0.01, "in": 0.0254, "dm": 0.1}


def rescale_model(model: LibraryModel, factor: float) -> LibraryModel:
    """Scale a model (parts, joints, bounds, descriptors) by ``factor`` about its origin, in place."""
    if factor == 1.0:
        return model
    for p in model.parts:
        mesh = p.load().copy()
        mesh.apply_scale(factor)
        p.mesh = mesh
    for j in model.joints:
        j.origin = j.origin.copy()
        j.origin[:3, 3] *= factor
        if j.type == "prismatic":
            j.lower, j.upper = j.lower * factor, j.upper * factor
    model.bounds = np.asarray(model.bounds, float) * factor
    model.feature_planes = feature_planes(model.mesh())
    model.support_surfaces = [[v * factor for v in surface] for surface in model.support_surfaces]
    return model


def normalise_size(model: LibraryModel, unitless: bool = False) -> LibraryModel:
    """Bring a model to metres. ``unitless`` sources (PartNet-Mobility) are scaled to their class's
    typical height; a mesh whose height is implausible for its class in metres is read in the first
    of :data:`GUESSED_UNITS` that makes it plausible, else scaled to the typical height. What was
    done is kept in ``params["units"]`` and ``params["scale_to_metres"]``."""
    from stratamap.core.map.priors import plausible_heights, typical_height

    height = float(model.size[2])
    target, span = typical_height(model.class_name), plausible_heights(model.class_name)
    if target is None or span is None or height <= 0:
        return model
    factor, how = 1.0, "m"
    if unitless:
        factor, how = target / height, f"no units: scaled to the typical {model.class_name} height {target:.2f} m"
    elif not span[0] <= height <= span[1]:
        guesses = [(name, f) for name, f in GUESSED_UNITS.items() if span[0] <= height * f <= span[1]]
        if guesses:
            name, factor = guesses[0]
            how = f"read as {name} ({height:.3g} units tall is implausible in metres for a {model.class_name})"
        else:
            factor = target / height
            how = f"{height:.3g} units tall; scaled to the typical {model.class_name} height {target:.2f} m"
    if factor != 1.0:
        rescale_model(model, factor)
    if unitless:
        model.params["scale_to_metres"] = round(factor, 6)
    elif factor != 1.0:
        model.params.update({"units": how, "scale_to_metres": round(factor, 6)})
    return model


# ------------------------------------------------------------------------------------------
# PartNet-Mobility


def model_from_urdf(
    urdf_path: Path,
    model_id: str,
    class_name: str,
    family: str,
    transform: np.ndarray | None = None,
    semantics: dict[str, str] | None = None,
    package_roots: dict[str, Path] | None = None,
    links: list[str] | None = None,
    sample_colors: tuple[np.ndarray, np.ndarray] | None = None,
) -> LibraryModel:
    """An articulated URDF as a library model: one part per visual mesh (in the root frame at
    q = 0, then ``transform``), the URDF's joints, origin at the bottom center. Missing meshes
    fall back to collision geometry; every problem is kept in ``params["warnings"]``.

    ``links`` keeps only the subtrees under these links (one cabinet of a whole kitchen), merged
    into the model's root link. Parts take the colours their meshes carry, else their URDF
    material's; ``sample_colors`` (points in the mesh files' own frame, RGB in [0, 1]) colours each
    face from its nearest samples instead (PartNet-Mobility objects whose textures are absent)."""
    from stratamap.core.io.urdf import read_urdf

    urdf = read_urdf(urdf_path, package_roots)
    transform = np.eye(4) if transform is None else transform
    poses = urdf.link_poses()
    parent_of = {j.child: j.parent for j in urdf.joints}
    if links:
        unknown = [name for name in links if name not in urdf.links]
        if unknown:
            raise DataError(f"{urdf_path}: no link named {unknown[:5]}; links are e.g. {sorted(urdf.links)[:12]}")
        children: dict[str, list[str]] = {}
        for j in urdf.joints:
            children.setdefault(j.parent, []).append(j.child)
        selected, stack = set(links), list(links)
        while stack:
            for child in children.get(stack.pop(), []):
                if child not in selected:
                    selected.add(child)
                    stack.append(child)
        tops = {name for name in selected if parent_of.get(name) not in selected}
    else:
        selected, tops = set(urdf.links), {urdf.root}
    material_colors = urdf_visual_colors(urdf_path)
    parts: list[LibraryPart] = []
    for link, visuals in urdf.links.items():
        if link not in selected:
            continue
        declared = material_colors.get(link, [])
        for k, vis in enumerate(visuals):
            mesh = vis.mesh.copy()
            face_colors = None
            if sample_colors is not None and Path(vis.source).is_file():
                face_colors = colors_from_samples(Path(vis.source), *sample_colors)
            if face_colors is None:
                face_colors = mesh_face_colors(mesh)
            # Colours are kept per face; the geometry itself goes on without visuals (concatenating
            # textured meshes would pack their images into atlases for nothing).
            mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
            mesh.apply_transform(transform @ poses[link])
            if face_colors is not None:
                albedo = mean_color(mesh, face_colors)
            elif len(declared) == len(visuals) and declared[k] is not None:
                albedo = declared[k]
            else:
                albedo = NEUTRAL_ALBEDO
            uniform = face_colors is None or np.ptp(face_colors, axis=0).max() < 1e-3
            parts.append(
                LibraryPart(
                    f"{link}_{k}",
                    "body" if link in tops else link,
                    albedo,
                    (semantics or {}).get(link, ""),
                    mesh=mesh,
                    face_colors=None if uniform else face_colors.astype(np.float32),
                )
            )
    if not parts:
        raise DataError(f"{urdf_path}: no link has a usable mesh" + (f" under {links}" if links else ""))
    joints = []
    for j in urdf.joints:
        if j.child not in selected or j.parent not in selected:
            continue
        origin = transform @ poses[j.parent] @ j.origin if j.parent in tops else j.origin
        joints.append(
            Joint(
                j.name,
                j.type,
                "body" if j.parent in tops else j.parent,
                "body" if j.child in tops else j.child,
                origin,
                j.axis,
                j.lower,
                j.upper,
            )
        )
    bounds = _canonicalize(parts, joints, "body")
    mesh = trimesh.util.concatenate([p.load() for p in parts])
    params: dict[str, Any] = {"urdf": str(urdf_path)}
    if links:
        params["links"] = list(links)
    if urdf.warnings:
        params["warnings"] = list(urdf.warnings)
    return LibraryModel(
        model_id, class_name, family, params, parts, joints, bounds, feature_planes(mesh), source=str(urdf_path)
    )


# ------------------------------------------------------------------------------------------
# Colours


def mean_color(mesh: trimesh.Trimesh, face_colors: np.ndarray) -> tuple[float, float, float]:
    """Area-weighted mean of per-face colours."""
    area = np.asarray(mesh.area_faces, dtype=float)
    weights = area if area.sum() > 0 else np.ones(len(area))
    mean = (np.asarray(face_colors, float) * weights[:, None]).sum(0) / weights.sum()
    return tuple(float(v) for v in np.round(np.clip(mean, 0.0, 1.0), 4))  # type: ignore[return-value]


def mesh_face_colors(mesh: trimesh.Trimesh) -> np.ndarray | None:
    """(F, 3) colours in [0, 1] that a loaded mesh carries (face or vertex colours, a texture sampled
    at each face's UV centroid, a material's diffuse colour), or None when it carries none. A glTF
    (PBR) material's base colour is its texture times its base colour factor, as glTF defines it."""
    visual = getattr(mesh, "visual", None)
    kind = getattr(visual, "kind", None)
    n = len(mesh.faces)
    if kind == "face":
        return np.asarray(visual.face_colors, float)[:, :3] / 255.0
    if kind == "vertex":
        return np.asarray(visual.vertex_colors, float)[mesh.faces][:, :, :3].mean(1) / 255.0
    if kind != "texture":
        return None
    material = getattr(visual, "material", None)
    # SimpleMaterial (OBJ/MTL) holds its texture as `image`, PBRMaterial (glTF, COLLADA) as `baseColorTexture`.
    image = getattr(material, "image", None)
    if image is None:
        image = getattr(material, "baseColorTexture", None)
    uv = getattr(visual, "uv", None)
    if image is not None and uv is not None and len(uv) == len(mesh.vertices):
        colors = sample_texture(image, np.asarray(uv, float), np.asarray(mesh.faces))
        factor = getattr(material, "baseColorFactor", None)
        if factor is not None:
            colors = colors * np.asarray(trimesh.visual.color.to_rgba(factor), float)[:3] / 255.0
        return colors
    color = getattr(material, "main_color", None)
    if color is None:
        return None
    return np.tile(np.asarray(color, float)[:3] / 255.0, (n, 1))


def sample_texture(image: Any, uv: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The colour of a texture at each face's UV centroid, the image box-filtered to at most
    :data:`TEXTURE_CELLS` cells a side (a face takes the mean colour around it, not one texel)."""
    from PIL import Image

    rgb = image.convert("RGB")
    cells = (min(rgb.width, TEXTURE_CELLS), min(rgb.height, TEXTURE_CELLS))
    pixels = np.asarray(rgb.resize(cells, Image.Resampling.BOX), dtype=float) / 255.0
    h, w = pixels.shape[:2]
    center = uv[faces].mean(1)
    # UVs repeat outside [0, 1] (tiled textures); v runs up the image.
    u, v = np.mod(center[:, 0], 1.0), np.mod(center[:, 1], 1.0)
    col = np.clip((u * w).astype(int), 0, w - 1)
    row = np.clip(((1.0 - v) * h).astype(int), 0, h - 1)
    return pixels[row, col]


def colors_from_samples(mesh_file: Path, points: np.ndarray, colors: np.ndarray, k: int = 6) -> np.ndarray | None:
    """Each face of ``mesh_file`` (in the file's own frame) coloured by the mean of its ``k``
    nearest coloured samples; None when the file cannot be read."""
    from scipy.spatial import cKDTree

    from stratamap.core.io.mesh import read_mesh

    try:
        raw = read_mesh(mesh_file, "visual mesh")
    except DataError:
        return None
    centers = np.asarray(raw.vertices)[np.asarray(raw.faces)].mean(1)
    _, idx = cKDTree(points).query(centers, k=min(k, len(points)))
    idx = idx.reshape(len(centers), -1)
    return colors[idx].mean(1)


def urdf_visual_colors(path: Path) -> dict[str, list[tuple[float, float, float] | None]]:
    """link -> the ``<material><color rgba>`` of each of its visuals with geometry (None where a
    visual names no colour); named materials may be defined once at the top level."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError):
        return {}

    def rgb(material: ET.Element | None) -> tuple[float, float, float] | None:
        color = material.find("color") if material is not None else None
        try:
            values = [float(v) for v in (color.get("rgba", "") if color is not None else "").split()]
        except ValueError:
            return None
        return tuple(float(np.clip(v, 0, 1)) for v in values[:3]) if len(values) == 4 else None  # type: ignore[return-value]

    named = {m.get("name"): rgb(m) for m in root.findall("material")}
    out: dict[str, list[tuple[float, float, float] | None]] = {}
    for link in root.findall("link"):
        colors = []
        for vis in link.findall("visual"):
            if vis.find("geometry") is None:
                continue
            material = vis.find("material")
            colors.append(rgb(material) or (named.get(material.get("name")) if material is not None else None))
        out[link.get("name", "")] = colors
    return out


def partnet_sample_colors(folder: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """The coloured point samples of a PartNet-Mobility object whose texture images are absent
    (points in its mesh files' frame, RGB in [0, 1]); None when its images are there or no
    samples are."""
    if (folder / "images").is_dir():
        return None
    files = sorted((folder / "point_sample").glob("*rgba*.txt"))
    if not files:
        return None
    try:
        data = np.loadtxt(files[0], ndmin=2)
    except ValueError as exc:
        raise DataError(f"{files[0]}: expected rows of x y z nx ny nz r g b a ({exc})") from exc
    if data.shape[1] < 9 or len(data) == 0:
        raise DataError(f"{files[0]}: expected rows of x y z nx ny nz r g b a, got {data.shape[1]} columns")
    return data[:, :3], np.clip(data[:, 6:9] / 255.0, 0.0, 1.0)


def load_partnet(folder: Path) -> LibraryModel:
    """One PartNet-Mobility object as a library model in the canonical frame, with its joints."""
    folder = Path(folder)
    meta: dict[str, Any] = {}
    if (folder / "meta.json").is_file():
        try:
            meta = json.loads(read_data_text(folder / "meta.json"))
        except json.JSONDecodeError as exc:
            raise DataError(f"{folder / 'meta.json'}: corrupt JSON ({exc})") from None
    category = meta.get("model_cat", "")
    semantics = {}
    if (folder / "semantics.txt").is_file():
        for line in read_data_text(folder / "semantics.txt").splitlines():
            bits = line.split()
            if len(bits) >= 3:
                semantics[bits[0]] = bits[2]
    model = model_from_urdf(
        folder / "mobility.urdf",
        f"partnet_{folder.name}",
        PARTNET_CLASSES.get(category, category.lower() or "object"),
        f"partnet_{category or 'unknown'}",
        PARTNET_TO_CANONICAL,
        semantics,
        sample_colors=partnet_sample_colors(folder),
    )
    # PartNet-Mobility meshes have no units (chair 179 is 1.61 tall as shipped): the model is scaled
    # to its class's typical height; "units": None still tells scene specs they may draw another.
    model.params.update({"partnet_id": folder.name, "category": category, "units": None})
    return normalise_size(model, unitless=True)


def _load_partnet_folders(folders: list[Path], root: Path | None = None) -> ModelLibrary:
    lib = ModelLibrary([], root=root or (folders[0] if folders else None))
    for folder in folders:
        try:
            model = load_partnet(folder)
        except DataError as exc:
            lib.problems.append(f"{exc}; skipped")
            continue
        lib.problems.extend(f"{folder}: {w}" for w in model.params.get("warnings", []))
        lib.models.append(model)
    return lib
