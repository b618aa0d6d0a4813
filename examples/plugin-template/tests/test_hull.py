"""The plugin passes stratamap's conformance kit, like every built-in stage."""

from stratamap_hull import HullCompleter

from stratamap.core.testing import example_data, parametrize_with_checks


@parametrize_with_checks([HullCompleter])
def test_conformance(stage_cls, check):
    check(stage_cls)


def test_every_object_gets_a_closed_hull():
    data = example_data({"instances"})
    out = HullCompleter().complete(data)["instances"]
    completed = out.completed()
    assert completed and all(i.completion.mesh.is_watertight for i in completed)
