"""scripts/build_aws_library.py: a Gazebo world's COLLADA model comes out in metres, z up, in its
texture's colours (the worlds keep textures outside the mesh folder, and model in centimetres)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
from PIL import Image

SCRIPT = Path(__file__).resolve().parents[3] / "scripts" / "build_aws_library.py"

#: Two 2 m x 1 m quads side by side (centimetres, z up), each mapped to one half of a texture that
#: lies in ../materials/textures/, as the AWS RoboMaker worlds lay out their models.
DAE = """<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit meter="0.01" name="centimeter"/><up_axis>{up}</up_axis></asset>
  <library_images><image id="tex"><init_from>../materials/textures/halves.png</init_from></image></library_images>
  <library_effects><effect id="fx"><profile_COMMON>
    <newparam sid="surf"><surface type="2D"><init_from>tex</init_from></surface></newparam>
    <newparam sid="samp"><sampler2D><source>surf</source></sampler2D></newparam>
    <technique sid="common"><lambert><diffuse><texture texture="samp" texcoord="UV"/></diffuse></lambert></technique>
  </profile_COMMON></effect></library_effects>
  <library_materials><material id="mat"><instance_effect url="#fx"/></material></library_materials>
  <library_geometries><geometry id="quads"><mesh>
    <source id="pos"><float_array id="pos-a" count="24">
      0 0 0 100 0 0 100 100 0 0 100 0  100 0 0 200 0 0 200 100 0 100 100 0</float_array>
      <technique_common><accessor source="#pos-a" count="8" stride="3">
        <param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/>
      </accessor></technique_common></source>
    <source id="uv"><float_array id="uv-a" count="16">
      0.25 0.5 0.25 0.5 0.25 0.5 0.25 0.5  0.75 0.5 0.75 0.5 0.75 0.5 0.75 0.5</float_array>
      <technique_common><accessor source="#uv-a" count="8" stride="2">
        <param name="S" type="float"/><param name="T" type="float"/>
      </accessor></technique_common></source>
    <vertices id="verts"><input semantic="POSITION" source="#pos"/></vertices>
    <triangles material="mat" count="4">
      <input semantic="VERTEX" source="#verts" offset="0"/><input semantic="TEXCOORD" source="#uv" offset="1"/>
      <p>0 0 1 1 2 2  0 0 2 2 3 3  4 4 5 5 6 6  4 4 6 6 7 7</p>
    </triangles>
  </mesh></geometry></library_geometries>
  <library_visual_scenes><visual_scene id="scene"><node id="n">
    <instance_geometry url="#quads"><bind_material><technique_common>
      <instance_material symbol="mat" target="#mat"><bind_vertex_input semantic="UV" input_semantic="TEXCOORD"/>
      </instance_material></technique_common></bind_material></instance_geometry>
  </node></visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#scene"/></scene>
</COLLADA>
"""


def _script():
    spec = importlib.util.spec_from_file_location("build_aws_library", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _model(folder: Path, up: str) -> Path:
    (folder / "meshes").mkdir(parents=True)
    (folder / "materials" / "textures").mkdir(parents=True)
    texture = Image.new("RGB", (32, 32), (200, 30, 30))
    texture.paste((30, 30, 200), (16, 0, 32, 32))
    texture.save(folder / "materials" / "textures" / "halves.png")
    dae = folder / "meshes" / "unit_visual.DAE"
    dae.write_text(DAE.format(up=up))
    return dae


def test_a_centimetre_collada_model_comes_out_in_metres_in_its_textures_colours(tmp_path):
    mesh = _script().convert(_model(tmp_path / "unit", "Z_UP"))
    np.testing.assert_allclose(mesh.extents, [2.0, 1.0, 0.0], atol=1e-6)
    colours = np.asarray(mesh.visual.face_colors)[:, :3].astype(int)
    left = mesh.triangles_center[:, 0] < 1.0
    assert (np.abs(colours[left] - [200, 30, 30]) <= 2).all()
    assert (np.abs(colours[~left] - [30, 30, 200]) <= 2).all()


def test_a_y_up_model_is_turned_z_up(tmp_path):
    mesh = _script().convert(_model(tmp_path / "unit", "Y_UP"))
    np.testing.assert_allclose(mesh.extents, [2.0, 0.0, 1.0], atol=1e-6)
