"""What model matching needs from a library, computed once and cached on disk.

For every model: surface samples at a fixed density, its box, feature planes, and a compact
global shape descriptor that can also be computed from a partial observation, so a library of
thousands of models is ranked with one vectorized distance computation (the *shortlist*) before
any expensive alignment. The cache is a single ``.npz`` keyed by the library's content hash.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stratamap.core.lazy import lazy_module
from stratamap.core.library.models import LibraryModel, ModelLibrary

spatial = lazy_module("scipy.spatial")

trimesh = lazy_module("trimesh")

DESCRIPTOR_VERSION = 2
HEIGHT_BINS = 8
RADIAL_BINS = 6


def shape_descriptor(points: np.ndarray, size: np.ndarray | None = None) -> np.ndarray:
    """A descriptor of points in an object frame (origin at the bottom center, z up).

    Log box size (3), and the distribution of points over normalized height (8 bins) and over
    normalized horizontal radius (6 bins): both change little when only part of an object is seen.
    """
    pts = np.asarray(points, dtype=np.float64)
    if size is None:
        size = pts.max(0) - pts.min(0)
    size = np.maximum(np.asarray(size, float), 1e-3)
    h = np.clip((pts[:, 2] - pts[:, 2].min()) / size[2], 0, 0.999)
    hist_h = np.bincount((h * HEIGHT_BINS).astype(int), minlength=HEIGHT_BINS).astype(float)
    center = (pts[:, :2].max(0) + pts[:, :2].min(0)) / 2
    r = np.linalg.norm(pts[:, :2] - center, axis=1) / max(np.linalg.norm(size[:2]) / 2, 1e-3)
    hist_r = np.bincount(np.clip(r * RADIAL_BINS, 0, RADIAL_BINS - 1).astype(int), minlength=RADIAL_BINS).astype(float)
    hist_h /= max(hist_h.sum(), 1)
    hist_r /= max(hist_r.sum(), 1)
    sorted_xy = np.sort(size[:2])[::-1]  # yaw-free: length >= width
    return np.concatenate([np.log([sorted_xy[0], sorted_xy[1], size[2]]), hist_h, 0.5 * hist_r])


@dataclass
class IndexedModel:
    id: str
    class_name: str
    family: str
    samples: np.ndarray  # (N, 3) surface samples, canonical frame
    size: np.ndarray  # (3,)
    planes: np.ndarray  # (K, 5)
    descriptor: np.ndarray
    _tree: spatial.cKDTree | None = field(default=None, repr=False)

    @property
    def tree(self) -> spatial.cKDTree:
        if self._tree is None:
            self._tree = spatial.cKDTree(self.samples)
        return self._tree


class ModelIndex:
    """Per-class arrays of model descriptors and sizes, with samples and trees per model."""

    def __init__(
        self, library: ModelLibrary, spacing: float = 0.02, max_samples: int = 3000, cache_dir: str | Path | None = None
    ):
        self.library = library
        self.spacing = spacing
        self.max_samples = max_samples
        self.problems: list[str] = list(library.problems)
        self.models: dict[str, IndexedModel] = {}
        key = hashlib.sha256(
            f"{library.content_hash()}:{spacing}:{max_samples}:{DESCRIPTOR_VERSION}".encode()
        ).hexdigest()[:20]
        cache = Path(cache_dir) / f"index-{key}.npz" if cache_dir is not None else None
        if cache is not None and cache.is_file():
            self._load(cache)
        else:
            self._build()
            if cache is not None:
                self._save(cache)
        self._by_class: dict[str, tuple[list[str], np.ndarray, np.ndarray]] = {}
        for m in self.models.values():
            self._by_class.setdefault(m.class_name, ([], [], []))  # type: ignore[arg-type]
        for cls in list(self._by_class):
            ids = sorted(i for i, m in self.models.items() if m.class_name == cls)
            self._by_class[cls] = (
                ids,
                np.array([self.models[i].descriptor for i in ids]),
                np.array([self.models[i].size for i in ids]),
            )

    def _build(self) -> None:
        for model in self.library:
            try:
                mesh = model.mesh()
            except Exception as exc:  # a broken file must not stop the index
                self.problems.append(f"model {model.id}: cannot load its mesh ({exc}); skipped")
                continue
            self.models[model.id] = self._index(model, mesh)

    def _index(self, model: LibraryModel, mesh: trimesh.Trimesh) -> IndexedModel:
        count = int(np.clip(mesh.area / self.spacing**2, 256, self.max_samples))
        seed = int(hashlib.sha256(model.id.encode()).hexdigest()[:8], 16)
        samples = np.asarray(trimesh.sample.sample_surface(mesh, count, seed=seed)[0], dtype=np.float64)
        size = np.asarray(model.size, float)
        return IndexedModel(
            model.id,
            model.class_name,
            model.family,
            samples,
            size,
            np.asarray(model.feature_planes, float),
            shape_descriptor(samples, size),
        )

    def _save(self, path: Path) -> None:
        from stratamap.core.atomic import atomic_path

        arrays: dict[str, np.ndarray] = {"ids": np.array(list(self.models))}
        for i, m in enumerate(self.models.values()):
            arrays[f"{i}.samples"] = m.samples.astype(np.float32)
            arrays[f"{i}.meta"] = np.array([m.class_name, m.family])
            arrays[f"{i}.size"] = m.size
            arrays[f"{i}.planes"] = m.planes
            arrays[f"{i}.descriptor"] = m.descriptor
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    def _load(self, path: Path) -> None:
        with np.load(path, allow_pickle=False) as z:
            for i, mid in enumerate(z["ids"].tolist()):
                cls, fam = z[f"{i}.meta"].tolist()
                self.models[mid] = IndexedModel(
                    mid,
                    cls,
                    fam,
                    z[f"{i}.samples"].astype(np.float64),
                    z[f"{i}.size"],
                    z[f"{i}.planes"],
                    z[f"{i}.descriptor"],
                )

    def classes(self) -> list[str]:
        return sorted(self._by_class)

    def candidates(self, class_name: str) -> list[str]:
        return list(self._by_class.get(class_name, ([], None, None))[0])

    def shortlist(self, class_name: str, descriptor: np.ndarray, k: int | None) -> list[str]:
        """Models of the class ranked by descriptor distance (one vectorized computation), top ``k``."""
        ids, descs, _ = self._by_class.get(class_name, ([], np.zeros((0, 1)), None))
        if not ids:
            return []
        d = np.linalg.norm(descs - descriptor[None, :], axis=1)
        order = np.lexsort((np.arange(len(ids)), d))
        if k is not None:
            order = order[:k]
        return [ids[i] for i in order]
