"""The learned completer ``pcn``: the shipped network, the leave-families-out rule, and completion
that reaches into what the sensor did not see on a family the network never trained on."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys

import numpy as np
import onnxruntime as ort
import pytest
import trimesh
from scipy.spatial import cKDTree

from stratamap.core.errors import ConfigError
from stratamap.core.evaluation.completion import shape_distances
from stratamap.core.geometry.boxes import gravity_aligned_box
from stratamap.core.map.layers import ObjectInstance, ObjectInstances
from stratamap.core.stages import PipelineData
from stratamap.core.synthetic.models import FAMILIES, make_model
from stratamap.core.synthetic.placement import FAMILY_WEIGHTS
from stratamap.plugins.completers.bbox import BBoxCompleter
from stratamap.plugins.completers.pcn import SHIPPED, PCNCompleter
from stratamap.plugins.completers.pcn.data import CLASSES, COARSE_POINTS, DENSE_POINTS, INPUT_POINTS, render_partial
from stratamap.plugins.completers.pcn.training_shapes import TRAINING_FAMILIES, make_training_model
from tests.conftest import REPO

SIDECAR = SHIPPED.with_suffix(".json")


def test_the_shipped_network_loads_in_plain_onnxruntime_with_the_documented_shapes():
    session = ort.InferenceSession(str(SHIPPED), providers=["CPUExecutionProvider"])
    inputs = {i.name: i.shape for i in session.get_inputs()}
    assert inputs == {"points": ["batch", INPUT_POINTS, 3], "class_onehot": ["batch", len(CLASSES)]}
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.5, 0.5, (2, INPUT_POINTS, 3)).astype(np.float32)
    onehot = np.eye(len(CLASSES), dtype=np.float32)[[0, 1]]
    coarse, dense = session.run(["coarse", "dense"], {"points": points, "class_onehot": onehot})
    assert coarse.shape == (2, COARSE_POINTS, 3) and dense.shape == (2, DENSE_POINTS, 3)
    assert np.isfinite(dense).all()
    sidecar = json.loads(SIDECAR.read_text())
    assert sidecar["sha256"] == hashlib.sha256(SHIPPED.read_bytes()).hexdigest()
    assert sidecar["classes"] == list(CLASSES)
    assert sidecar["outputs"]["dense"] == ["batch", DENSE_POINTS, 3]
    assert SHIPPED.stat().st_size < 20e6
    assert 0.0 < sidecar["heldout_chamfer_l1_m"] < 0.1


def test_no_benchmark_family_was_trained_on():
    """Leave families out: the training families are not generator families, and the sidecar says so."""
    assert not set(TRAINING_FAMILIES) & set(FAMILIES)
    used_by_scenes = {f for weights in FAMILY_WEIGHTS.values() for fams in weights.values() for f in fams}
    assert used_by_scenes <= set(FAMILIES)
    sidecar = json.loads(SIDECAR.read_text())
    assert set(sidecar["training_families"]) == set(TRAINING_FAMILIES)
    assert set(sidecar["heldout_families"]) == set(FAMILIES)
    for family in TRAINING_FAMILIES:  # every training family builds, deterministically, in the canonical frame
        a, b = make_training_model(family, 3, 1), make_training_model(family, 3, 1)
        assert np.allclose(a.mesh().vertices, b.mesh().vertices)
        assert a.bounds[0][2] == pytest.approx(0.0, abs=1e-9)


def observed_instance(family: str, seed: int, views: int) -> tuple[trimesh.Trimesh, ObjectInstance]:
    """A held-out-family model at (1, 2) turned 0.7 rad, seen from ``views`` viewpoints with Kinect noise."""
    truth = make_model(family, seed, 0).mesh()
    truth.apply_transform(trimesh.transformations.rotation_matrix(0.7, [0, 0, 1]))
    points = render_partial(truth, np.random.default_rng(seed), views)
    truth.apply_translation((1.0, 2.0, 0.0))
    points = points + (1.0, 2.0, 0.0)
    return truth, ObjectInstance(1, FAMILIES[family][0], points, gravity_aligned_box(points))


def complete(completer, inst: ObjectInstance) -> tuple[PipelineData, dict]:
    data = PipelineData()
    data.map.instances = ObjectInstances([inst])
    out = completer.run(data)
    return data, out


@pytest.mark.parametrize("family", ["rectangular_table", "cabinet", "sofa"])
def test_pcn_completes_a_held_out_family_into_what_was_not_seen(family):
    """One partial view of a model of a family the network never saw: the completion covers the
    whole true surface much better than the observation does (it fills in the unseen side), and
    lies closer to the true shape than the gravity-aligned box of the observation."""
    truth, inst = observed_instance(family, 5, views=1)
    truth_pts = np.asarray(trimesh.sample.sample_surface(truth, 4000, seed=0)[0])
    data, out = complete(PCNCompleter(), inst)
    completion = out["instances"][1].completion
    assert completion is not None and completion.completer == "pcn"
    assert inst.completion is None  # the input layer is untouched
    done = np.asarray(trimesh.sample.sample_surface(completion.world_mesh(), 4000, seed=0)[0])
    # Completeness: mean distance from the true surface to the nearest completed / observed point.
    completeness = cKDTree(done).query(truth_pts)[0].mean()
    seen_completeness = cKDTree(inst.points).query(truth_pts)[0].mean()
    assert completeness < 0.75 * seen_completeness, (completeness, seen_completeness)
    _, boxed = complete(BBoxCompleter(), inst)
    box_pts = np.asarray(trimesh.sample.sample_surface(boxed["instances"][1].completion.world_mesh(), 4000, seed=0)[0])
    pcn, box = shape_distances(done, truth_pts), shape_distances(box_pts, truth_pts)
    assert pcn["chamfer_l1"] < box["chamfer_l1"], (pcn, box)
    assert pcn["chamfer_l1"] < 0.08, pcn
    assert data.notes["pcn"]["seconds_per_object"] > 0


def test_classes_without_a_slot_follow_class_agnostic():
    _, inst = observed_instance("monitor", 2, views=2)
    assert inst.class_name not in CLASSES
    _, out = complete(PCNCompleter(), inst)
    assert out["instances"][1].completion is not None
    assert out["instances"][1].attributes["pcn"]["slot"] == "other"
    stage = PCNCompleter(class_agnostic=False)
    data = PipelineData()
    data.map.instances = ObjectInstances([inst])
    out = stage.run(data)
    assert out["instances"][1].completion is None
    assert any("no 'monitor' slot" in w for w in data.warnings)


def test_a_missing_model_file_is_a_config_error(tmp_path):
    _, inst = observed_instance("stool", 1, views=1)
    with pytest.raises(ConfigError, match="does not exist"):
        complete(PCNCompleter(model=str(tmp_path / "nope.onnx")), inst)
    broken = tmp_path / "broken.onnx"
    broken.write_bytes(b"not a network")
    with pytest.raises(ConfigError, match="not a loadable ONNX"):
        complete(PCNCompleter(model=str(broken)), inst)


def test_stratamap_plugins_lists_pcn():
    result = subprocess.run(
        [sys.executable, "-m", "stratamap.core.cli", "plugins"], cwd=REPO, capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr
    assert "pcn" in result.stdout.split()


@pytest.mark.slow
def test_training_is_reproducible_from_a_seed(tmp_path):
    """Two tiny trainings with one seed give the same losses and the same held-out Chamfer."""
    pytest.importorskip("torch")
    runs = []
    for name in ("a", "b"):
        out = tmp_path / name / "pcn.onnx"
        args = ["--steps", "4", "--models-per-family", "1", "--views", "1", "--heldout-per-family", "1"]
        result = subprocess.run(
            [sys.executable, str(REPO / "scripts" / "train_pcn.py"), *args, "--eval-every", "2", "--out", str(out)],
            cwd=REPO,
            capture_output=True,
            text=True,
            env={**os.environ, "PYTHONHASHSEED": "0"},
        )
        assert result.returncode == 0, result.stderr[-2000:]
        runs.append(json.loads(out.with_suffix(".json").read_text()))
    a, b = runs
    assert [c["train_loss"] for c in a["curve"]] == [c["train_loss"] for c in b["curve"]]
    assert a["heldout_chamfer_l1_m"] == b["heldout_chamfer_l1_m"]
    assert a["sha256"] == b["sha256"] or a["final_train_loss"] == b["final_train_loss"]
