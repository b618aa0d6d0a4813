"""Naming by the trained model (``clusters`` ``naming: model``, plugins/segmenters/clusters/model.py):
the shipped ONNX model names clear furniture of a small synthetic fused map, stays ``object`` below
its threshold with its score, reads deterministic features, runs without scikit-learn, and a missing
or corrupt model is a one-line DataError naming the file."""

from __future__ import annotations

import functools
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stratamap.core.errors import DataError
from stratamap.core.map.layers import Geometry, Semantics
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.stages import PipelineData
from stratamap.plugins.segmenters.clusters import ClustersSegmenter
from stratamap.plugins.segmenters.clusters.features import feature_names, instance_features
from stratamap.plugins.segmenters.clusters.model import SHIPPED, NamingModel, load_model
from tests.plugins.segmenters.test_layout_planes import chair, room_shell, solids, table

VOCAB = Vocabulary.default()


def furnished_map() -> tuple[PipelineData, np.ndarray, np.ndarray]:
    """A 2 cm fused map of a room with a table, a chair and a cabinet against a wall, each voted its
    class by a detector's masks (instances 1-3); the floor, walls and ceiling voted theirs."""
    cabinet = [("cabinet", (1.5, 0.0, 0.0), (2.3, 0.5, 0.8))]
    furniture, names = solids(table(2.5, 2.0) + chair(3.6, 2.0) + cabinet, 0.02)
    shell = room_shell(0.02, around=furniture)
    points = np.concatenate([p for _, p in shell] + [furniture])
    names = np.concatenate([np.full(len(p), n) for n, p in shell] + [names])
    classes = np.array([VOCAB.id(n) for n in names], np.int32)
    instances = np.zeros(len(points), np.int32)
    for iid, name in enumerate(("table", "chair", "cabinet"), start=1):
        instances[names == name] = iid
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=0.02)
    data.map.semantics = Semantics(classes, instances, VOCAB)
    return data, points, names


def named(threshold: float = 0.4, **params) -> tuple[dict, np.ndarray]:
    if not params:
        return _named_at(threshold)
    return _named(threshold, **params)


@functools.lru_cache(maxsize=4)
def _named_at(threshold: float) -> tuple[dict, np.ndarray]:
    """``_named`` at the default parameters, run once per threshold in a test process (the tests
    only read its output)."""
    return _named(threshold)


def _named(threshold: float, **params) -> tuple[dict, np.ndarray]:
    data, points, names = furnished_map()
    out = ClustersSegmenter(
        keep_instances=True, recognize=True, naming="model", naming_threshold=threshold, **params
    ).run(data)
    return out, names


def class_of(out: dict, names: np.ndarray, name: str) -> object:
    """The instance holding most of the points of the true object ``name``."""
    iid = np.bincount(out["semantics"].instance_ids[names == name]).argmax()
    return next(inst for inst in out["instances"] if inst.id == iid)


def test_the_shipped_model_names_a_table_a_chair_and_a_cabinet():
    out, names = named()
    for name in ("table", "chair", "cabinet"):
        inst = class_of(out, names, name)
        assert inst.class_name == name, (name, inst.class_name, inst.attributes["naming"])
        naming = inst.attributes["naming"]
        assert naming["by"] == "model" and 0.4 <= naming["score"] <= 1.0, naming


def test_below_the_threshold_an_instance_is_object_with_its_score():
    out, names = named()
    scores = {inst.id: inst.attributes["naming"]["score"] for inst in out["instances"]}
    # Just above the cabinet's own score: it falls below, what scored higher keeps its class.
    cabinet = class_of(out, names, "cabinet")
    threshold = scores[cabinet.id] + 1e-4
    assert threshold <= 1.0
    out, names = named(threshold)
    inst = class_of(out, names, "cabinet")
    assert inst.class_name == "object"
    assert inst.attributes["naming"]["by"] == "model"
    assert inst.attributes["naming"]["score"] == pytest.approx(scores[cabinet.id], abs=1e-4)
    assert "naming_threshold" in inst.attributes["naming"]["why"]
    for other in out["instances"]:
        # Scores are kept to 4 decimals: one rounded up to the threshold may lie just under it.
        if other.attributes["naming"]["score"] >= threshold + 1e-4:
            assert other.class_name != "object"


def test_rules_stay_the_default_and_the_model_changes_no_rule_naming():
    data, _, names = furnished_map()
    out = ClustersSegmenter(keep_instances=True, recognize=True).run(data)
    assert all(inst.attributes["naming"]["by"] != "model" for inst in out["instances"])
    assert all("score" not in inst.attributes["naming"] for inst in out["instances"])


def test_rules_then_model_names_what_the_rules_left_object_and_keeps_voted_names():
    def run(naming: str) -> tuple[dict, np.ndarray]:
        data, _, names = furnished_map()
        data.map.semantics.class_ids[names == "cabinet"] = VOCAB.id("object")  # no votes on the cabinet
        return ClustersSegmenter(keep_instances=True, recognize=False, naming=naming).run(data), names

    rules, names = run("rules")
    both, _ = run("rules_then_model")
    assert class_of(rules, names, "cabinet").class_name == "object"
    cabinet = class_of(both, names, "cabinet")
    assert cabinet.class_name == "cabinet", cabinet.attributes["naming"]
    assert cabinet.attributes["naming"]["by"] == "model" and cabinet.attributes["naming"]["score"] >= 0.4
    for name in ("table", "chair"):  # what the rules named keeps their name and their reason
        kept, ruled = class_of(both, names, name), class_of(rules, names, name)
        assert kept.class_name == ruled.class_name == name
        assert kept.attributes["naming"] == ruled.attributes["naming"]


def test_rules_then_model_renames_what_the_shape_alone_named_never_what_votes_named(monkeypatch):
    from stratamap.plugins.segmenters.clusters import model as naming

    shipped = load_model(str(SHIPPED))

    class TableEverywhere:
        """The shipped model's classes and features; every instance scores table 0.7 (allowed by the
        class facts for the cabinet's size), so that which instances the pass opens shows."""

        classes, vote_classes = shipped.classes, shipped.vote_classes

        def scores(self, features: np.ndarray) -> np.ndarray:
            row = np.full(len(self.classes), 0.3 / (len(self.classes) - 1), np.float32)
            row[self.classes.index("table")] = 0.7
            return np.tile(row, (len(features), 1))

    def run(naming_mode: str) -> tuple[dict, np.ndarray]:
        data, _, names = furnished_map()
        data.map.semantics.class_ids[names == "cabinet"] = VOCAB.id("object")  # no votes: named by shape
        return ClustersSegmenter(keep_instances=True, recognize=True, naming=naming_mode).run(data), names

    rules, names = run("rules")
    assert class_of(rules, names, "cabinet").attributes["naming"]["by"] == "shape"
    monkeypatch.setattr(naming, "load_model", lambda sidecar: TableEverywhere())
    both, _ = run("rules_then_model")
    cabinet = class_of(both, names, "cabinet")
    assert cabinet.class_name == "table" and cabinet.attributes["naming"]["by"] == "model"
    assert "(was cabinet)" in cabinet.attributes["naming"]["why"]
    chair = class_of(both, names, "chair")  # voted chair: the votes' name stays
    assert chair.class_name == class_of(rules, names, "chair").class_name == "chair"
    assert chair.attributes["naming"] == class_of(rules, names, "chair").attributes["naming"]


def test_rules_then_model_leaves_object_below_the_threshold():
    data, _, names = furnished_map()
    data.map.semantics.class_ids[names == "cabinet"] = VOCAB.id("object")
    out = ClustersSegmenter(keep_instances=True, recognize=False, naming="rules_then_model", naming_threshold=1.0).run(
        data
    )
    cabinet = class_of(out, names, "cabinet")
    assert cabinet.class_name == "object" and "naming_threshold" in cabinet.attributes["naming"]["why"]


def test_features_are_deterministic_and_named():
    from stratamap.plugins.segmenters.clusters.passes import PASSES

    def features() -> tuple[list[int], np.ndarray]:
        data, _, _ = furnished_map()
        seg = ClustersSegmenter(keep_instances=True, recognize=True, naming="model")
        lab = seg._labelling(data)
        for name in seg.config.passes[: seg.config.passes.index("name_by_model")]:
            PASSES[name].run(lab)
        return instance_features(lab, load_model(str(SHIPPED)).vote_classes)

    ids, first = features()
    again_ids, again = features()
    assert ids == again_ids and len(ids) >= 3
    assert first.dtype == np.float32 and np.array_equal(first, again)
    assert first.shape[1] == len(feature_names(load_model(str(SHIPPED)).vote_classes))
    assert np.isfinite(first).all()


@pytest.mark.slow
def test_the_runtime_does_not_import_scikit_learn():
    code = (
        "import sys\n"
        "from tests.plugins.segmenters.test_clusters_naming import named\n"
        "out, _ = named()\n"
        "assert any(i.attributes['naming']['by'] == 'model' for i in out['instances'])\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('sklearn', 'skl2onnx')))\n"
    )
    root = Path(__file__).resolve().parents[3]
    done = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().splitlines()[-1] == "[]", done.stdout


def copied_model(tmp_path: Path) -> Path:
    for name in ("naming.json", "naming.onnx"):
        shutil.copy(SHIPPED.parent / name, tmp_path / name)
    return tmp_path / "naming.json"


def test_a_missing_model_file_is_a_one_line_data_error_naming_it(tmp_path):
    sidecar = copied_model(tmp_path)
    (tmp_path / "naming.onnx").unlink()
    with pytest.raises(DataError) as err:
        named(naming_model=str(sidecar))
    message = str(err.value)
    assert str(tmp_path / "naming.onnx") in message and "\n" not in message


@pytest.mark.parametrize("keep_sha", [True, False])
def test_a_corrupt_model_file_is_a_one_line_data_error_naming_it(tmp_path, keep_sha):
    sidecar = copied_model(tmp_path)
    (tmp_path / "naming.onnx").write_bytes(b"not an onnx model")
    if not keep_sha:  # without a digest to compare, onnxruntime's own check must catch it
        side = json.loads(sidecar.read_text())
        del side["sha256"]
        sidecar.write_text(json.dumps(side))
    with pytest.raises(DataError) as err:
        NamingModel(sidecar)
    message = str(err.value)
    assert str(tmp_path / "naming.onnx") in message and "\n" not in message


def test_a_corrupt_sidecar_is_a_one_line_data_error_naming_it(tmp_path):
    sidecar = copied_model(tmp_path)
    sidecar.write_text("{ not json")
    with pytest.raises(DataError) as err:
        NamingModel(sidecar)
    assert str(sidecar) in str(err.value) and "\n" not in str(err.value)


def test_the_models_fallback_names_no_class_the_class_facts_rule_out():
    from stratamap.plugins.segmenters.clusters.model import _best_fitting
    from stratamap.plugins.segmenters.clusters.shapes import Shape, ruled_out

    classes = ["cabinet", "fridge", "object", "counter"]
    # A 0.3 m thing hung on a wall at 1.4 m: no fridge, whatever the model says.
    small = Shape(0.22, 0.17, 0.28, 1.44, 0.2, True, False, True)
    # A fridge's size hung at 2 m, its top at 3.3 m: no fridge whose feet went unseen reaches that.
    hung = Shape(0.43, 0.3, 1.31, 2.0, 0.7, True, False, True)
    # A counter run with a tap and racks over its worktop: taller and longer than the priors' counter,
    # still a counter (what segmentation joined to it does not make it something else).
    run = Shape(4.4, 1.0, 1.7, 0.0, 2.4, True, False, True)
    assert ruled_out("fridge", small) and not ruled_out("cabinet", small)
    assert ruled_out("fridge", hung) and not ruled_out("cabinet", hung)
    assert not ruled_out("counter", run) and not ruled_out("fridge", Shape(0.6, 0.6, 1.8, 0.0, 1.0, True, True, True))
    assert classes[_best_fitting(classes, np.array([0.02, 0.9, 0.08, 0.0]), small)] == "object"
    assert classes[_best_fitting(classes, np.array([0.0, 0.95, 0.01, 0.04]), hung)] == "object"
    assert classes[_best_fitting(classes, np.array([0.0, 0.01, 0.01, 0.98]), run)] == "counter"
    # The counter it is too small for gives way to the next class, a small wall cabinet.
    assert classes[_best_fitting(classes, np.array([0.3, 0.0, 0.1, 0.6]), small)] == "cabinet"
    assert classes[_best_fitting(classes, np.array([0.0, 0.0, 0.3, 0.7]), run)] == "counter"
    assert _best_fitting(["counter", "fridge"], np.array([0.1, 0.9]), small) is None


def test_the_models_fallback_names_no_chair_longer_than_one_chair_can_be():
    from stratamap.plugins.segmenters.clusters.model import _best_fitting
    from stratamap.plugins.segmenters.clusters.shapes import Shape, ruled_out

    # The real kitchen's short counter run seen as its front, 1.67 m long: the model called it a chair.
    run_front = Shape(1.67, 0.37, 1.48, 0.0, 1.1, True, False, True)
    chair = Shape(0.55, 0.5, 0.85, 0.0, 0.5, False, False, False, seat=True)
    assert ruled_out("chair", run_front) and not ruled_out("chair", chair)
    # Classes whose objects come in any length keep no longest side: a long counter run stays one.
    assert not ruled_out("counter", run_front)
    classes = ["chair", "object", "counter"]
    assert classes[_best_fitting(classes, np.array([0.86, 0.1, 0.04]), run_front)] == "object"


def test_the_models_fallback_names_nothing_on_the_floor_lower_than_its_class():
    from stratamap.plugins.segmenters.clusters.shapes import Shape, ruled_out

    # A bag on the floor by a wall, 0.14 m high: its whole height is seen, and no cabinet is that low.
    bag = Shape(0.42, 0.26, 0.14, 0.0, 0.26, True, False, True)
    assert ruled_out("cabinet", bag) and ruled_out("chair", bag)
    # The same 0.14 m hung at a chair's seat height is a seat whose legs went unseen, not ruled out.
    seat = Shape(0.49, 0.44, 0.17, 0.3, 0.35, False, True, True)
    assert not ruled_out("chair", seat)


def test_a_tall_unit_is_too_tall_for_a_counter_not_for_a_cabinet():
    from stratamap.plugins.segmenters.clusters.shapes import Shape, fits_class, taller_than_class

    # The real SUN RGB-D frame's filing cabinet, named cabinet by its shape: the model may not call it
    # a counter (the pass renames a shape's name only to a class the object is not too tall for).
    filing = Shape(1.46, 0.67, 1.74, 0.0, 1.2, True, True, True)
    assert taller_than_class("counter", filing) and not taller_than_class("cabinet", filing)
    assert fits_class("cabinet", filing) and not fits_class("counter", filing)
