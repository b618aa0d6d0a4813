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
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from stratamap.core.atomic import write_json
from stratamap.core.errors import MapFormatError
from stratamap.core.map.layers import (
    MAP_FORMAT,
    MAP_FORMAT_VERSION,
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


def _mesh_arrays(prefix: str, mesh: trimesh.Trimesh, out: dict[str, np.ndarray]) -> None:
    out[f"{prefix}.vertices"] = np.asarray(mesh.vertices, dtype=np.float64)
    out[f"{prefix}.faces"] = np.asarray(mesh.faces, dtype=np.int64)
    if mesh.visual is not None and mesh.visual.kind == "vertex":
        out[f"{prefix}.vertex_colors"] = np.asarray(mesh.visual.vertex_colors, dtype=np.uint8)
    elif mesh.visual is not None and mesh.visual.kind == "face":
        out[f"{prefix}.face_colors"] = np.asarray(mesh.visual.face_colors, dtype=np.uint8)


def _mesh_from(prefix: str, arrays: Any) -> trimesh.Trimesh:
    kwargs: dict[str, Any] = {}
    if f"{prefix}.vertex_colors" in arrays:
        kwargs["vertex_colors"] = arrays[f"{prefix}.vertex_colors"]
    if f"{prefix}.face_colors" in arrays:
        kwargs["face_colors"] = arrays[f"{prefix}.face_colors"]
    return trimesh.Trimesh(arrays[f"{prefix}.vertices"], arrays[f"{prefix}.faces"], process=False, **kwargs)


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def _load_npz(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise MapFormatError(f"{path}: listed in the manifest but missing")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except Exception as exc:  # zipfile / numpy raise several types for corrupt files
        raise MapFormatError(f"{path}: cannot be read as .npz ({exc})") from exc


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


def _geometry_from(arrays: dict[str, np.ndarray]) -> Geometry:
    return Geometry(
        points=arrays["points"],
        colors=arrays.get("colors"),
        normals=arrays.get("normals"),
        mesh=_mesh_from("mesh", arrays) if "mesh.vertices" in arrays else None,
        voxel_size=float(arrays["voxel_size"]) if "voxel_size" in arrays else None,
    )


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
    m = LayeredMap(
        vocabulary=Vocabulary.from_dict(manifest["vocabulary"]),
        provenance=dict(manifest.get("provenance", {})),
        metadata=dict(manifest.get("metadata", {})),
    )
    layers = manifest.get("layers", {})
    if "occupancy" in layers:
        arrays = _load_npz(directory / layers["occupancy"]["file"])
        grids = OccupancyMaps()
        for key in sorted(k for k in arrays if k.endswith(".data")):
            name = key[: -len(".data")]
            meta = json.loads(str(arrays[f"{name}.meta"]))
            grids[name] = OccupancyGrid(arrays[key], meta["resolution"], tuple(meta["origin"]), meta["frame_id"])
        m.occupancy = grids
    for name in ("geometry", "augmented"):
        if name in layers:
            setattr(m, name, _geometry_from(_load_npz(directory / layers[name]["file"])))
    if "semantics" in layers:
        arrays = _load_npz(directory / layers["semantics"]["file"])
        vocab = Vocabulary.from_dict(layers["semantics"]["vocabulary"])
        m.semantics = Semantics(arrays["class_ids"], arrays["instance_ids"], vocab, arrays.get("plane_ids"))
    if "instances" in layers:
        path = directory / layers["instances"]["file"]
        if not path.is_file():
            raise MapFormatError(f"{path}: listed in the manifest but missing")
        records = json.loads(path.read_text())
        arrays = _load_npz(directory / layers["instances"]["arrays"])
        insts = ObjectInstances()
        for rec in records:
            key = str(rec["id"])
            completion = None
            if rec["completion"] is not None:
                c = rec["completion"]
                completion = Completion(
                    mesh=_mesh_from(f"{key}.completion.mesh", arrays),
                    pose=np.array(c["pose"]),
                    completer=c["completer"],
                    model_id=c["model_id"],
                    scale=np.array(c["scale"]),
                    score=c["score"],
                    parts=[
                        Part(p["name"], _mesh_from(f"{key}.part.{k}.mesh", arrays), np.array(p["pose"]))
                        for k, p in enumerate(c["parts"])
                    ],
                    joints=[Joint.from_dict(j) for j in c["joints"]],
                )
            insts.add(
                ObjectInstance(
                    id=rec["id"],
                    class_name=rec["class"],
                    points=arrays[f"{key}.points"],
                    colors=arrays.get(f"{key}.colors"),
                    box=OrientedBox.from_dict(rec["box"]),
                    score=rec["score"],
                    completion=completion,
                    attributes=rec["attributes"],
                )
            )
        m.instances = insts
    if "contact_graph" in layers:
        path = directory / layers["contact_graph"]["file"]
        if not path.is_file():
            raise MapFormatError(f"{path}: listed in the manifest but missing")
        m.contact_graph = ContactGraph.from_dict(json.loads(path.read_text()))
    return m
