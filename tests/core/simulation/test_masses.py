"""Masses of exported objects: the material of a class's objects, not a solid block of their box
(the demo's box-completed table weighed 381 kg)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
import trimesh

from stratamap.core.map.layers import Completion, LayeredMap, ObjectInstance, ObjectInstances, OrientedBox
from stratamap.core.registry import default_registry
from stratamap.core.simulation.kinematics import build_tree
from stratamap.core.stages import PipelineData
from tests.core.simulation.test_physics import box_object, graph_of


def _exporter(name: str):
    """The installed exporter, without the room's slabs or settling (no room in these scenes)."""
    return default_registry().get("exporters", name).cls(bodies={"structure": False, "rest": False})


def _scene() -> PipelineData:
    instances = ObjectInstances(
        [
            box_object(1, "table", (1.6, 0.9, 0.75), (0.0, 0.0, 0.0)),
            box_object(2, "chair", (0.5, 0.5, 0.9), (1.5, 0.0, 0.0)),
            box_object(3, "cabinet", (0.8, 0.5, 0.9), (0.0, 1.5, 0.0)),
        ]
    )
    layered = LayeredMap()
    layered.instances = instances
    layered.contact_graph = graph_of(instances, {})
    return PipelineData(map=layered)


def _masses(exporter, tmp_path) -> dict[str, float]:
    """Mass of each object's link or body, by name, as the exported file gives it."""
    files = exporter.export(_scene(), tmp_path)
    root = ET.parse(next(f for f in files if f.suffix in (".urdf", ".sdf", ".xml"))).getroot()
    out = {}
    for element in root.iter():
        name = element.get("name", "")
        if not name.startswith(("table_", "chair_", "cabinet_")):
            continue
        mass = element.find("inertial/mass")
        if mass is not None:  # URDF: <mass value=...>; SDF: <mass>text</mass>
            out[name] = float(mass.get("value") or mass.text)
        inertial = element.find("inertial")
        if inertial is not None and inertial.get("mass") is not None:  # MJCF
            out[name] = float(inertial.get("mass"))
    return out


@pytest.mark.parametrize("exporter", ["urdf", "mjcf", "sdf"])
def test_every_exporter_gives_furniture_a_plausible_mass(tmp_path, exporter):
    masses = _masses(_exporter(exporter), tmp_path)
    assert set(masses) == {"table_1", "chair_2", "cabinet_3"}, masses
    assert 10.0 <= masses["table_1"] <= 60.0  # a dining table, not 300 kg of solid wood
    assert 3.0 <= masses["chair_2"] <= 15.0
    assert 20.0 <= masses["cabinet_3"] <= 80.0  # a hollow carcass


def _top_and_legs() -> trimesh.Trimesh:
    """A table model of its parts: a 30 mm top on four 60 mm legs, 1.2 x 0.8 x 0.75 m."""
    top = trimesh.creation.box(extents=(1.2, 0.8, 0.03))
    top.apply_translation((0, 0, 0.735))
    legs = []
    for x in (-0.55, 0.55):
        for y in (-0.35, 0.35):
            leg = trimesh.creation.box(extents=(0.06, 0.06, 0.72))
            leg.apply_translation((x, y, 0.36))
            legs.append(leg)
    return trimesh.util.concatenate([top, *legs])


def test_a_model_of_the_parts_weighs_its_material():
    """A completion that is a real model (a top and legs) weighs its own volume of material: the
    class's fill caps a box completion, it does not thin out a model that is already thin."""
    from stratamap.core.map.priors import CLASS_BODIES

    mesh = _top_and_legs()
    assert mesh.is_volume
    box = OrientedBox(np.array([0.0, 0.0, 0.375]), 0.0, np.array([1.2, 0.8, 0.75]))
    inst = ObjectInstance(1, "table", np.asarray(mesh.vertices), box, completion=Completion(mesh, np.eye(4), "test"))
    (link,) = build_tree(ObjectInstances([inst]), None).links
    assert link.inertial.mass == pytest.approx(CLASS_BODIES["table"].density * mesh.volume, rel=1e-6)
    # A per-class density override sets the material's density; the fill still applies to a box.
    (boxed,) = build_tree(
        ObjectInstances([box_object(1, "table", (1.6, 0.9, 0.75), (0, 0, 0))]), None, {"table": 300}
    ).links
    m, (x, y, z) = boxed.inertial.mass, (1.6, 0.9, 0.75)
    assert m == pytest.approx(300 * CLASS_BODIES["table"].fill * x * y * z, rel=1e-6)
    # The box's inertia at that mass (simulators reject a tensor that does not fit the mass).
    np.testing.assert_allclose(
        np.diag(boxed.inertial.inertia), m / 12 * np.array([y * y + z * z, x * x + z * z, x * x + y * y]), rtol=1e-6
    )


def test_a_slab_is_solid_whatever_its_class():
    from stratamap.core.map.priors import SOLID_THICKNESS, class_body, material_volume

    assert material_volume(0.6 * 0.4 * 0.02, (0.6, 0.4, 0.02), class_body("cabinet").fill) == pytest.approx(0.0048)
    assert material_volume(0.36, (0.8, 0.5, 0.9), class_body("cabinet").fill) == pytest.approx(0.36 * 0.18)
    assert min((0.6, 0.4, SOLID_THICKNESS)) == SOLID_THICKNESS
    assert class_body("unheard-of class").fill < 1.0  # an unknown object is no solid block either
