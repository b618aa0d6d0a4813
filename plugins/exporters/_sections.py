"""Config sections the exporters share, so that one setting has one name in every exporter.

* ``bodies`` (``urdf``, ``mjcf``, ``sdf``, ``usd``): which classes are free bodies, their
  density, the rest plan and the room's static slabs;
* ``inflation`` (``costmap``, ``ros2_bag``): Nav2's inflation of obstacles.

The flat names of the release before (``movable_classes`` in urdf, ``free_classes`` in mjcf,
``dynamic_classes`` in sdf, ``inscribed_radius``, ...) are read into their section for one more
release: a config lists them in ``renamed`` (``core/stages.py``: ``StageConfig``), and the stage
warns when it runs, naming the old key and the new one.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from stratamap.core.simulation.kinematics import DEFAULT_MOVABLE_CLASSES


class Section(BaseModel):
    """A nested section of a stage's config: unknown keys are errors, values immutable (as StageConfig)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class Bodies(Section):
    """How the objects of a simulator export become bodies."""

    movable_classes: list[str] = Field(
        default_factory=lambda: list(DEFAULT_MOVABLE_CLASSES),
        description=(
            "Classes exported as free bodies, placed at rest on their support (URDF: a floating joint on world; "
            "MJCF: a free joint; SDF: a non-static model; USD: a dynamic rigid body); the others are fixed."
        ),
    )
    density: dict[str, float] = Field(
        default_factory=dict,
        description=(
            "Per-class material density overrides, kg/m^3; a mass is the density times the material's volume, at "
            "most the class's fill of its box (core/map/priors.py CLASS_BODIES: a table is a top and legs)."
        ),
    )
    rest: bool = Field(
        default=True,
        description="Place free bodies to rest on their support (a few mm of settling; static where they cannot).",
    )
    structure: bool = Field(
        default=True,
        description=(
            "Add floor, walls and ceiling from the map as static bodies (URDF: box links; MJCF: world geoms; "
            "SDF: the model 'room'; USD: box colliders)."
        ),
    )


class Inflation(Section):
    """Nav2's inflation: cost decays from obstacles as ``252 * exp(-k (d - inscribed_radius))``."""

    inscribed_radius: float = Field(
        default=0.2, ge=0.0, description="Robot's inscribed radius, metres (cells this close to an obstacle are 253)."
    )
    inflation_radius: float = Field(default=0.55, gt=0.0, description="Inflation radius, metres (Nav2's default 0.55).")
    cost_scaling_factor: float = Field(
        default=10.0, gt=0.0, description="Exponential decay rate k of the inflation (Nav2's default 10)."
    )


def bodies_section() -> Any:
    return Field(
        default_factory=Bodies,
        description="Which objects are free bodies, their density, the rest plan and the room's static slabs.",
    )


def inflation_section() -> Any:
    return Field(
        default_factory=Inflation,
        description="Inflation of obstacles into costs, as Nav2's inflation layer (the costmap exporter's too).",
    )


def renamed_bodies(classes_key: str) -> dict[str, str]:
    """The flat keys a simulator exporter had before ``bodies``, ``classes_key`` being its own
    name for the movable classes."""
    return {classes_key: "bodies.movable_classes", **{k: f"bodies.{k}" for k in ("density", "rest", "structure")}}


#: The flat keys the costmap and ros2_bag exporters had before ``inflation``.
RENAMED_INFLATION: dict[str, str] = {k: f"inflation.{k}" for k in Inflation.model_fields}
