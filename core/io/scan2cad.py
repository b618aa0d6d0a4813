"""Scan2CAD's annotation file (``full_annotations.json``), read for one ScanNet scan.

The file is a list with one record per scan::

    {"id_scan": "scene0000_00",
     "trs": {"translation": [x, y, z], "rotation": [w, x, y, z], "scale": [sx, sy, sz]},
     "aligned_models": [
        {"catid_cad": "03001627", "id_cad": "<ShapeNet model id>",
         "trs": {"translation": ..., "rotation": ..., "scale": ...},
         "bbox": [hx, hy, hz], "center": [cx, cy, cz], "sym": "__SYM_NONE"}, ...]}

Scan2CAD's own tools read it so: the scan's ``trs`` takes the ScanNet scan's points (the frame of
its ``.sens`` poses and ``_vh_clean_2.ply``) to Scan2CAD's world, each model's ``trs`` (T R S, the
rotation a unit quaternion w, x, y, z) takes the points of the ShapeNet ``model_normalized.obj``
to the same world; ``center`` and ``bbox`` are the centre and half extents of the model's box in
ShapeNet's frame; ``sym`` its symmetry about ShapeNet's up axis (+y): ``__SYM_NONE``,
``__SYM_ROTATE_UP_2``, ``__SYM_ROTATE_UP_4`` or ``__SYM_ROTATE_UP_INF``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.documents import read_data_text
from stratamap.core.errors import DataError

SYMMETRIES = {"__SYM_NONE": 1, "__SYM_ROTATE_UP_2": 2, "__SYM_ROTATE_UP_4": 4, "__SYM_ROTATE_UP_INF": 36}
"""Each symmetry and how many turns about the up axis the benchmark tries (36 for a round one)."""


def trs_matrix(trs: Any, where: str) -> np.ndarray:
    """A Scan2CAD ``trs`` record as the 4x4 matrix T R S."""
    if not isinstance(trs, dict):
        raise DataError(f"{where}: trs must be a mapping of translation, rotation, scale")
    try:
        t = np.asarray(trs["translation"], float).reshape(3)
        q = np.asarray(trs["rotation"], float).reshape(4)
        s = np.asarray(trs["scale"], float).reshape(3)
    except KeyError as exc:
        raise DataError(f"{where}: trs has no {exc.args[0]!r}") from None
    except (TypeError, ValueError):
        raise DataError(
            f"{where}: trs needs translation [x, y, z], rotation [w, x, y, z] and scale [sx, sy, sz]"
        ) from None
    norm = float(np.linalg.norm(q))
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(s)) and np.isfinite(norm)) or norm < 1e-9:
        raise DataError(f"{where}: trs holds a non-finite value or a zero rotation quaternion")
    if np.any(s <= 0):
        raise DataError(f"{where}: trs scale must be positive, got {s.tolist()}")
    w, x, y, z = q / norm
    rot = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    out = np.eye(4)
    out[:3, :3] = rot * s[None, :]
    out[:3, 3] = t
    return out


@dataclass
class AlignedModel:
    """One annotated CAD model of a scan, in the ScanNet scan's frame."""

    catid: str
    cad_id: str
    #: (4, 4) ShapeNet model frame -> the ScanNet scan's frame (inverse scan trs @ model trs).
    cad_to_scan: np.ndarray
    center: np.ndarray  # (3,) box centre, ShapeNet frame
    half_extents: np.ndarray  # (3,) ShapeNet frame
    sym: str

    def to_dict(self) -> dict[str, Any]:
        return {
            "catid": self.catid,
            "cad_id": self.cad_id,
            "cad_to_scan": self.cad_to_scan.tolist(),
            "center": self.center.tolist(),
            "half_extents": self.half_extents.tolist(),
            "sym": self.sym,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> AlignedModel:
        return cls(
            d["catid"],
            d["cad_id"],
            np.asarray(d["cad_to_scan"], float),
            np.asarray(d["center"], float),
            np.asarray(d["half_extents"], float),
            d["sym"],
        )


def read_scan2cad(path: str | Path, scan_id: str) -> list[AlignedModel]:
    """The aligned models Scan2CAD annotates for ``scan_id`` (a DataError if the file has no record
    of it or a record is malformed)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: Scan2CAD annotation file not found")
    try:
        doc = json.loads(read_data_text(path, "Scan2CAD annotations"))
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: corrupt JSON ({exc})") from None
    if not isinstance(doc, list):
        raise DataError(f"{path}: expected a list of per-scan records (Scan2CAD's full_annotations.json)")
    record = next((r for r in doc if isinstance(r, dict) and r.get("id_scan") == scan_id), None)
    if record is None:
        raise DataError(f"{path}: no record with id_scan {scan_id!r} ({len(doc)} scans annotated)")
    where = f"{path}: scan {scan_id}"
    scan_to_world = trs_matrix(record.get("trs"), where)
    world_to_scan = np.linalg.inv(scan_to_world)
    models = record.get("aligned_models", [])
    if not isinstance(models, list):
        raise DataError(f"{where}: aligned_models must be a list")
    out = []
    for k, m in enumerate(models):
        here = f"{where}: aligned_models[{k}]"
        if not isinstance(m, dict):
            raise DataError(f"{here}: expected a mapping")
        missing = [key for key in ("catid_cad", "id_cad", "trs", "bbox", "center", "sym") if key not in m]
        if missing:
            raise DataError(f"{here}: missing {', '.join(missing)}")
        if m["sym"] not in SYMMETRIES:
            raise DataError(f"{here}: sym must be one of {', '.join(SYMMETRIES)}, got {m['sym']!r}")
        try:
            center = np.asarray(m["center"], float).reshape(3)
            half = np.abs(np.asarray(m["bbox"], float).reshape(3))
        except (TypeError, ValueError):
            raise DataError(f"{here}: center and bbox must be [x, y, z]") from None
        out.append(
            AlignedModel(
                str(m["catid_cad"]),
                str(m["id_cad"]),
                world_to_scan @ trs_matrix(m["trs"], here),
                center,
                half,
                m["sym"],
            )
        )
    return out
