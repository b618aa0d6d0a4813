"""`clusters` as named passes run in a configured order (issue 65, step 2): the order is the
``passes`` parameter, a list that cannot run is a one-line error naming that key, and leaving a
pass out is the same as its switch turned off."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.config import validate
from stratamap.core.errors import ConfigError
from stratamap.core.map.layers import Geometry, Semantics
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.stages import PipelineData
from stratamap.plugins.segmenters.clusters import DEFAULT_PASSES, ClustersConfig, ClustersSegmenter
from tests.conftest import REPO
from tests.plugins.segmenters.test_layout_planes import room_shell, solids, table

VOCAB = Vocabulary.default()


def pipeline(passes: list[str]) -> dict:
    return {
        "source": {"plugin": "synthetic"},
        "stages": [{"plugin": "points"}, {"plugin": "clusters", "params": {"passes": passes}}],
    }


def test_the_default_order_is_every_pass_once():
    from stratamap.plugins.segmenters.clusters.passes import PASSES

    assert ClustersConfig().passes == list(DEFAULT_PASSES) == list(PASSES)


@pytest.mark.parametrize(
    "passes, message",
    [
        (["layout", "segmnet", "join_supports", "instances"], "unknown pass 'segmnet'"),
        (["layout", "segment", "segment", "join_supports", "instances"], "pass 'segment' is listed twice"),
        (["segment", "layout", "join_supports", "instances"], "pass 'segment' needs 'layout' before it"),
        (["layout", "segment", "join_supports"], "must include 'instances'"),
    ],
)
def test_a_pass_list_that_cannot_run_is_a_one_line_error_naming_passes(passes, message):
    with pytest.raises(ConfigError) as error:
        validate(pipeline(passes))
    text = str(error.value)
    assert "stages[1].params.passes" in text and message in text, text
    assert len(text.strip().splitlines()) == 1, text


def test_a_shorter_list_in_order_validates():
    kept = [p for p in DEFAULT_PASSES if p not in ("drop_strays", "trim_feet")]
    validate(pipeline(kept))


def cup_ring_scene() -> PipelineData:
    """A table with a cup whose mask took a 6 cm ring of the table top along (test_clusters' scene)."""
    spacing = 0.03
    objects, names = solids(table(3.0, 2.5) + [("cup", (3.45, 2.45, 0.75), (3.55, 2.55, 0.87))], spacing)
    layout = room_shell(spacing, around=objects)
    points = np.concatenate([p for _, p in layout] + [objects])
    names = np.concatenate([np.full(len(p), n) for n, p in layout] + [names])
    classes = np.array([VOCAB.id(n) for n in names], np.int32)
    ids = np.zeros(len(points), np.int32)
    ids[names == "table"], ids[names == "cup"] = 1, 2
    top = (names == "table") & (np.abs(points[:, 2] - 0.75) < 1e-6)
    ring = top & (np.abs(points[:, :2] - (3.5, 2.5)).max(axis=1) <= 0.12)
    classes[ring], ids[ring] = VOCAB.id("cup"), 2
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=spacing)
    data.map.semantics = Semantics(classes, ids, VOCAB)
    return data


def test_leaving_a_pass_out_is_its_switch_turned_off():
    def run(**params) -> np.ndarray:
        return ClustersSegmenter(keep_instances=True, **params).run(cup_ring_scene())["semantics"].instance_ids

    default, switched_off = run(), run(trim_feet=False)
    assert (default != switched_off).any()  # the pass does something on this scene
    left_out = run(passes=[p for p in DEFAULT_PASSES if p != "trim_feet"])
    np.testing.assert_array_equal(left_out, switched_off)


def test_no_module_of_the_package_is_over_400_lines():
    folder = REPO / "plugins" / "segmenters" / "clusters"
    lengths = {p.name: len(p.read_text().splitlines()) for p in folder.glob("*.py")}
    assert len(lengths) > 10 and max(lengths.values()) <= 400, lengths


def test_no_class_name_in_the_package_code():
    """Class facts are data (core/map/priors.py, the vocabulary): no string in the package's code, its
    docstrings aside, names a class of the default vocabulary."""
    import ast

    names = set(VOCAB.names)
    found = []
    for path in sorted((REPO / "plugins" / "segmenters" / "clusters").glob("*.py")):
        tree = ast.parse(path.read_text())
        docstrings = {
            id(node.body[0].value)
            for node in ast.walk(tree)
            if isinstance(node, ast.Module | ast.FunctionDef | ast.ClassDef)
            and node.body
            and isinstance(node.body[0], ast.Expr)
            and isinstance(node.body[0].value, ast.Constant)
        }
        found += [
            f"{path.name}:{node.lineno} {node.value!r}"
            for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and node.value in names and id(node) not in docstrings
        ]
    assert len(names) > 10 and not found, found
