"""Models keep their own colours from every mesh format a user's library may hold."""

from __future__ import annotations

import csv

import numpy as np
import trimesh
from PIL import Image

from stratamap.core.library.models import ModelLibrary, mesh_face_colors


def _two_colour_box(factor: list[float] | None = None) -> trimesh.Trimesh:
    """A box whose faces' UVs fall in the left (red) or right (blue) half of a glTF base colour texture."""
    box = trimesh.creation.box(extents=[0.4, 0.4, 0.8])
    corners = box.vertices[box.faces].reshape(-1, 3)  # a vertex per face corner: each face takes its own UV
    mesh = trimesh.Trimesh(corners, np.arange(len(corners)).reshape(-1, 3), process=False)
    left = mesh.triangles_center[:, 0] < 0
    uv = np.where(np.repeat(left, 3)[:, None], [0.25, 0.5], [0.75, 0.5])
    texture = Image.new("RGB", (64, 64), (230, 20, 20))
    texture.paste((20, 20, 230), (32, 0, 64, 64))
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=texture, baseColorFactor=factor)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    return mesh


def test_a_gltf_models_base_colour_texture_colours_its_faces(tmp_path):
    """glTF keeps a texture as its PBR material's base colour, not as an MTL image: a GLB model
    came out white (the material's default colour) before this was read."""
    _two_colour_box().export(tmp_path / "unit.glb")
    with open(tmp_path / "classes.csv", "w", newline="") as fh:
        csv.writer(fh).writerows([["file", "class"], ["unit.glb", "cabinet"]])
    lib = ModelLibrary.load(tmp_path)
    part = lib.models[0].parts[0]
    colours = part.face_colors
    assert colours is not None, "the two-colour texture was read as one colour"
    red, blue = np.array([230, 20, 20]) / 255, np.array([20, 20, 230]) / 255
    near = lambda c: np.linalg.norm(colours - c, axis=1) < 0.05  # noqa: E731
    assert near(red).any() and near(blue).any()
    assert (near(red) | near(blue)).all()


def test_a_base_colour_factor_tints_the_texture():
    mesh = trimesh.load(
        trimesh.util.wrap_as_stream(_two_colour_box([0.5, 0.5, 0.5, 1.0]).export(file_type="glb")),
        file_type="glb",
        force="mesh",
    )
    colours = mesh_face_colors(mesh)
    assert colours is not None and np.abs(colours.max(axis=0) - 115 / 255).min() < 0.02
