"""Exports a simulator keeps at rest: the shipped configs with each completer, their MJCF simulated
in MuJoCo and their URDF in PyBullet (free bodies loaded free), walls and floor in both.

The suite runs a representative subset at half resolution and few frames; the full matrix
(office and kitchen x bbox, icp_match, plane_box_match, and every other config that writes an
MJCF) is the same check, run by hand (see docs/algorithms/exporters.md)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

from stratamap.core.config import load_pipeline
from stratamap.core.pipeline import Pipeline
from tests.conftest import REPO

COMPLETERS = ("bbox", "icp_match", "plane_box_match")


def run_config(name: str, completer: str | None, out: Path, frames: int = 40) -> tuple[Path, dict]:
    """configs/NAME.yaml with its completer swapped for ``completer``, half-resolution images and
    ``frames`` frames; returns the export folder and the report."""
    config = yaml.safe_load((REPO / "configs" / f"{name}.yaml").read_text())
    params = config["source"]["params"]
    if "scene_file" in params:
        scene = yaml.safe_load((REPO / "configs" / params.pop("scene_file")).read_text())
        params["scene"] = scene
    scene = params["scene"]
    scene["camera"] = {**scene.get("camera", {}), "width": 320, "height": 240}
    if "frames" in params:
        params["frames"] = frames
    else:
        scene["trajectory"] = {**scene.get("trajectory", {}), "frames": frames}
    if completer is not None:
        (stage,) = [s for s in config["stages"] if s["plugin"] in COMPLETERS]
        stage["plugin"], stage["params"] = completer, {}
    out.mkdir(parents=True, exist_ok=True)
    path = out / "pipeline.yaml"
    path.write_text(yaml.safe_dump(config))
    report = Pipeline(load_pipeline(path)).run(out / "run")
    return out / "run" / "export", report


def check_urdf(path: Path, report: dict, require_free: bool = True) -> dict:
    """Walls and floor are links; every floating joint's object loads free in PyBullet and rests;
    every object of a movable class is free or, in the report, static with a reason."""
    pytest.importorskip("pybullet")
    from stratamap.core.simulation.bullet import settle

    robot = ET.parse(path).getroot()
    links = {el.get("name") for el in robot.findall("link")}
    assert "floor" in links and any(name.startswith("wall_") for name in links), sorted(links)[:20]
    floating = {j.find("child").get("link") for j in robot.findall("joint") if j.get("type") == "floating"}
    assert floating or not require_free, "no free body in the URDF"
    rest = report["notes"]["urdf"]["rest"]
    assert rest["free_bodies"] == len(floating)
    assert all(reason for reason in rest["static"].values())
    result = settle(path, seconds=2.0)
    assert set(result["displacement_m"]) == floating
    assert result["max_displacement_m"] < 0.02, sorted(result["displacement_m"].items(), key=lambda kv: -kv[1])[:3]
    return result


def check_mjcf(path: Path) -> dict:
    """Loads in MuJoCo, walls and floor are geoms, and no free body moves more than 2 cm in 2 s."""
    mujoco = pytest.importorskip("mujoco")
    from stratamap.core.simulation.physics import settle

    model = mujoco.MjModel.from_xml_path(str(path))
    geoms = {mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in range(model.ngeom)}
    assert "floor" in geoms and any((g or "").startswith("wall_") for g in geoms)
    result = settle(path, seconds=2.0)
    assert result["free_bodies"] > 0
    assert result["max_displacement_m"] < 0.02, sorted(result["displacement_m"].items(), key=lambda kv: -kv[1])[:3]
    return result


@pytest.mark.parametrize(("config", "completer"), [("office", "bbox"), ("kitchen", "plane_box_match")])
def test_shipped_scene_with_completer_rests_in_mujoco_and_pybullet(config, completer, tmp_path):
    export, report = run_config(config, completer, tmp_path)
    check_mjcf(export / "scene.xml")
    check_urdf(export / "scene.urdf", report)
    sdf = ET.parse(export / "scene.sdf").getroot()
    room = sdf.find("world/model[@name='room']")
    assert room is not None and room.find("link[@name='floor']") is not None


def test_demo_urdf_rests_in_pybullet(tmp_path):
    """The demo has no physical check: its box completions of chairs pushed under the table overlap
    the table's box, so those stay static (with the reason in the report); whatever is free rests."""
    export, report = run_config("demo", None, tmp_path, frames=24)
    check_urdf(export / "scene.urdf", report, require_free=False)
