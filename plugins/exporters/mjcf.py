"""Exporter ``mjcf``: the scene as a MuJoCo model (``scene.xml``), meshes beside it
(written by :mod:`stratamap.core.simulation.mjcf`): static furniture, room slabs, free movable
objects placed at rest, hinge and slide joints."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import ClassVar

from pydantic import Field

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.simulation.mjcf import write_mjcf
from stratamap.core.simulation.rest import RestPlan, rest_offsets
from stratamap.core.simulation.structure import room_structure
from stratamap.core.stages import warn_renamed
from stratamap.plugins.exporters._sections import (
    Bodies,
    bodies_section,
    renamed_bodies,
)


class MJCFConfig(StageConfig):
    filename: str = Field(default="scene.xml", description="Name of the MJCF file in the export folder.")
    mesh_dir: str = Field(default="mjcf_meshes", description="Sub-folder for the collision and visual meshes.")
    bodies: Bodies = bodies_section()
    hinge_holding: float = Field(
        default=2.0,
        ge=0.0,
        description=(
            "Hinge dry friction as a multiple of gravity's torque on the part, so lids and doors stay where they are "
            "(0: swing freely)."
        ),
    )
    timestep: float = Field(default=0.002, gt=0.0, description="Simulation timestep, seconds.")

    renamed: ClassVar[Mapping[str, str]] = renamed_bodies("free_classes")


class MJCFExporter(Exporter[MJCFConfig]):
    """The scene as a MuJoCo MJCF model: static furniture, free movable objects, hinge/slide joints."""

    name = "mjcf"
    Config = MJCFConfig
    requires = frozenset({"instances"})
    optional = frozenset({"contact_graph", "geometry", "semantics"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg = self.config
        warn_renamed(self)
        bodies = cfg.bodies
        assert data.map.instances is not None
        statics = room_structure(data.map) if bodies.structure else []
        graph = data.map.contact_graph
        plan = rest_offsets(data.map.instances, graph, bodies.movable_classes, statics) if bodies.rest else RestPlan()
        self.note("rest", plan.to_dict())
        return write_mjcf(
            data.map.instances,
            out_dir,
            filename=cfg.filename,
            mesh_dir=cfg.mesh_dir,
            free_classes=bodies.movable_classes,
            density=bodies.density,
            hinge_holding=cfg.hinge_holding,
            timestep=cfg.timestep,
            graph=graph,
            statics=statics,
            plan=plan,
        )


@hookimpl
def stratamap_register_exporters():
    return [MJCFExporter]
