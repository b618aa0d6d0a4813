"""A ShapeNet-layout folder as a model library: classes from the synsets, z up, metres, what is
skipped and why (also from `stratamap models info`), and icp_match completing with it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import trimesh

from stratamap.core.geometry.boxes import gravity_aligned_box
from stratamap.core.library.models import ModelLibrary
from stratamap.core.map.layers import ObjectInstance, ObjectInstances
from stratamap.core.map.priors import typical_height
from stratamap.core.stages import PipelineData
from stratamap.plugins.completers.icp_match import ICPMatchCompleter
from tests.core.evaluation import scannet_fixtures as fx


@pytest.fixture()
def shapenet(tmp_path):
    root = fx.write_shapenet(tmp_path / "ShapeNetCore.v2")
    # What a real download also holds: a synset without a stratamap class, a model folder without
    # its mesh, a mesh that is no mesh.
    plane = root / "02691156" / "p1" / "models"
    plane.mkdir(parents=True)
    trimesh.creation.box([1, 0.2, 1]).export(plane / "model_normalized.obj")
    (root / fx.CHAIR / "empty").mkdir()
    broken = root / fx.TABLE / "broken" / "models"
    broken.mkdir(parents=True)
    (broken / "model_normalized.obj").write_text("this is not an OBJ file\n")
    return root


def test_a_shapenet_folder_loads_z_up_at_class_heights(shapenet):
    lib = ModelLibrary.load(shapenet)
    assert sorted(m.id for m in lib) == ["shapenet_03001627_chair1", "shapenet_04379243_table1"]
    assert lib.classes() == ["chair", "table"]
    chair = lib.get("shapenet_03001627_chair1")
    assert chair.size[2] == pytest.approx(typical_height("chair"), rel=1e-6)
    # ShapeNet's y up became z up: the chair's back (at ShapeNet's -z) stands at the model's +y side,
    # and the origin is the bottom centre.
    mesh = chair.mesh()
    assert mesh.bounds[0][2] == pytest.approx(0.0, abs=1e-9)
    top = mesh.vertices[mesh.vertices[:, 2] > 0.9 * chair.size[2]]
    assert top[:, 1].mean() > 0.1
    # cad_to_model takes the file's points onto the model's.
    raw = trimesh.load(shapenet / fx.CHAIR / "chair1" / "models" / "model_normalized.obj", force="mesh")
    moved = trimesh.transform_points(raw.vertices, np.asarray(chair.params["cad_to_model"]))
    assert np.allclose(np.sort(moved, axis=0), np.sort(np.asarray(mesh.vertices), axis=0), atol=1e-6)
    problems = "\n".join(lib.problems)
    assert "synset 02691156 (airplane) has no stratamap class" in problems and "1 models skipped" in problems
    assert "empty: no models/model_normalized.obj; skipped" in problems
    assert "broken" in problems
    # One synset's folder loads too.
    assert [m.class_name for m in ModelLibrary.load(shapenet / fx.CHAIR)] == ["chair"]


def test_models_info_reports_classes_counts_and_what_was_skipped(shapenet):
    proc = subprocess.run(
        [sys.executable, "-m", "stratamap.core.cli", "models", "info", str(shapenet)], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    assert "2 models of 2 classes (chair, table); 3 skipped" in proc.stdout
    assert "shapenet_03001627" in proc.stdout
    skipped = [line for line in proc.stderr.splitlines() if line.startswith("skipped:")]
    assert len(skipped) == 3 and any("02691156 (airplane)" in line for line in skipped)


def test_icp_match_completes_a_fused_object_from_a_shapenet_library(shapenet):
    lib = ModelLibrary.load(shapenet)
    chair = lib.get("shapenet_03001627_chair1")
    pose = np.eye(4)
    pose[:3, :3] = trimesh.transformations.rotation_matrix(0.6, [0, 0, 1])[:3, :3]
    pose[:3, 3] = (2.0, 1.5, 0.0)
    mesh = chair.mesh().copy()
    mesh.apply_transform(pose)
    points, faces = trimesh.sample.sample_surface(mesh, 6000, seed=0)
    view = np.array([np.cos(2.8), np.sin(2.8), 0.3])
    seen = points[mesh.face_normals[faces] @ view > 0.1]
    data = PipelineData()
    data.map.instances = ObjectInstances([ObjectInstance(1, "chair", seen, gravity_aligned_box(seen))])
    out = ICPMatchCompleter(library=str(shapenet)).run(data)
    completion = out["instances"][1].completion
    assert completion is not None and completion.model_id == "shapenet_03001627_chair1"
    center = completion.pose @ np.append(completion.mesh.bounds.mean(0), 1.0)
    assert np.linalg.norm(center[:3] - mesh.bounds.mean(0)) < 0.05
