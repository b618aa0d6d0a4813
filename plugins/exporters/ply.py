"""Exporter ``ply``: the geometry layer as a PLY file (the mesh when there is one, else the colored points)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.atomic import atomic_path
from stratamap.core.lazy import lazy_module

trimesh = lazy_module("trimesh")


class PLYConfig(StageConfig):
    filename: str = Field(default="geometry.ply", description="File name in the export folder.")
    content: Literal["auto", "mesh", "points"] = Field(
        default="auto", description="auto: the mesh if the geometry has one, else the points."
    )
    layer: Literal["geometry", "augmented"] = Field(default="geometry", description="Which 3D layer to write.")
    binary: bool = Field(default=True, description="Binary little-endian PLY (smaller, faster); false for ASCII.")


class PLYExporter(Exporter[PLYConfig]):
    """Writes the geometry (or augmented) layer as a PLY mesh or point cloud."""

    name = "ply"
    Config = PLYConfig
    optional = frozenset({"geometry", "augmented"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg = self.config
        geom = data.map.get(cfg.layer)
        if geom is None:
            self.warn(f"no {cfg.layer} layer; {cfg.filename} not written")
            return []
        use_mesh = cfg.content == "mesh" or (cfg.content == "auto" and geom.mesh is not None)
        if use_mesh and geom.mesh is None:
            self.warn(f"the {cfg.layer} layer has no mesh; writing its points")
            use_mesh = False
        if use_mesh:
            obj = geom.mesh
        else:
            colors = None if geom.colors is None else (np.clip(geom.colors, 0, 1) * 255).astype(np.uint8)
            obj = trimesh.PointCloud(geom.points, colors=colors)
        path = out_dir / cfg.filename
        with atomic_path(path) as tmp:
            obj.export(tmp, file_type="ply", encoding="binary" if cfg.binary else "ascii")
        return [path]


@hookimpl
def stratamap_register_exporters():
    return [PLYExporter]
