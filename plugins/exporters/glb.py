"""Exporter ``glb``: the augmented scene (or the geometry) as binary glTF for viewers, y-up."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.atomic import atomic_path
from stratamap.core.lazy import lazy_module

trimesh = lazy_module("trimesh")

#: stratamap's z-up world to glTF's y-up (x right, y up, z toward the viewer).
Z_UP_TO_Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])


class GLBConfig(StageConfig):
    filename: str = Field(default="scene.glb", description="File name in the export folder.")
    layer: Literal["augmented", "geometry"] = Field(
        default="augmented", description="Which 3D layer to write (falls back to geometry)."
    )
    objects_separately: bool = Field(
        default=True, description="Completed objects as separate named nodes (selectable in viewers)."
    )


class GLBExporter(Exporter[GLBConfig]):
    """The augmented scene as a GLB file (rotated to glTF's y-up), completed objects as named nodes."""

    name = "glb"
    Config = GLBConfig
    optional = frozenset({"geometry", "augmented", "instances"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg = self.config
        geom = data.map.get(cfg.layer) or data.map.geometry
        scene = trimesh.Scene()
        insts = data.map.instances
        completed = insts.completed() if insts is not None else []
        if geom is not None and geom.mesh is not None:
            mesh = geom.mesh
            if (
                cfg.objects_separately
                and cfg.layer == "augmented"
                and completed
                and data.map.geometry is not None
                and data.map.geometry.mesh is not None
            ):
                # The augmented mesh is the kept observed mesh followed by the models: keep them apart.
                n_models = sum(len(i.completion.mesh.faces) for i in completed)  # type: ignore[union-attr]
                mesh = trimesh.Trimesh(
                    mesh.vertices,
                    mesh.faces[: len(mesh.faces) - n_models],
                    vertex_colors=mesh.visual.vertex_colors if mesh.visual.kind == "vertex" else None,
                    process=False,
                )
                mesh.remove_unreferenced_vertices()
            scene.add_geometry(mesh, node_name="scene", geom_name="scene")
        elif geom is not None and len(geom):
            colors = None if geom.colors is None else (np.clip(geom.colors, 0, 1) * 255).astype(np.uint8)
            scene.add_geometry(trimesh.PointCloud(geom.points, colors=colors), node_name="scene_points")
        if cfg.objects_separately:
            for inst in completed:
                world = inst.completion.world_mesh()  # type: ignore[union-attr]
                scene.add_geometry(
                    world, node_name=f"{inst.class_name}_{inst.id}", geom_name=f"{inst.class_name}_{inst.id}"
                )
        if not scene.geometry:
            self.warn("nothing to export: no geometry and no completed objects")
            return []
        scene.apply_transform(Z_UP_TO_Y_UP)
        path = out_dir / cfg.filename
        with atomic_path(path) as tmp:
            tmp.write_bytes(scene.export(file_type="glb"))
        return [path]


@hookimpl
def stratamap_register_exporters():
    return [GLBExporter]
