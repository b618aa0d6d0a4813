"""Exporter ``usd``: the scene as a USD stage with UsdPhysics (Isaac Sim, Isaac Lab, OmniGibson),
written by :mod:`stratamap.core.simulation.usd`: the same scene as the URDF (static floor and
walls, a rigid body per link with its mesh, convex colliders and mass, free movables at rest,
articulated completions as articulations with revolute and prismatic joints, limits and drives),
metres, z up, in one file with the meshes inside it (``.usda`` text by default, ``.usdc`` binary).

Needs ``usd-core`` (``pip install 'stratamap[usd]'``), imported only when the stage runs.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, field_validator

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.simulation.scene import scene_tree
from stratamap.core.simulation.usd import USD_SUFFIXES, load_pxr, write_usd
from stratamap.plugins.exporters._sections import Bodies, bodies_section


class USDConfig(StageConfig):
    filename: str = Field(
        default="scene.usda",
        description="Name of the USD file in the export folder: .usda (text), .usdc or .usd (binary crate).",
    )
    bodies: Bodies = bodies_section()
    hinge_damping: float = Field(
        default=1.0,
        ge=0.0,
        description="Damping of the drive on every revolute joint, N m s/rad (written per degree, as USD takes it).",
    )
    slide_damping: float = Field(
        default=5.0, ge=0.0, description="Damping of the drive on every prismatic joint, N s/m."
    )
    friction: float = Field(
        default=0.8, ge=0.0, description="Static and dynamic friction coefficient of every collider."
    )

    @field_validator("filename")
    @classmethod
    def _usd_file_name(cls, filename: str) -> str:
        name = Path(filename)
        if name.suffix not in USD_SUFFIXES or name.name != filename:
            raise ValueError(f"must be a file name ending in {', '.join(USD_SUFFIXES)}, got {filename!r}")
        return filename


class USDExporter(Exporter[USDConfig]):
    """The scene as a USD stage with UsdPhysics: rigid bodies, colliders, articulations, joints."""

    name = "usd"
    Config = USDConfig
    requires = frozenset({"instances"})
    optional = frozenset({"contact_graph", "geometry", "semantics"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg = self.config
        load_pxr()  # before the rest plan: a missing extra is said at once
        bodies = cfg.bodies
        tree, plan = scene_tree(
            data.map, bodies.movable_classes, bodies.density, structure=bodies.structure, rest=bodies.rest
        )
        self.note("rest", plan.to_dict())
        path = write_usd(
            tree,
            out_dir / cfg.filename,
            hinge_damping=cfg.hinge_damping,
            slide_damping=cfg.slide_damping,
            friction=cfg.friction,
        )
        return [path]


@hookimpl
def stratamap_register_exporters():
    return [USDExporter]
