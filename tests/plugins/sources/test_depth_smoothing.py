"""A depth camera's organized cloud is smoothed in inverse depth before mapping (KinectFusion's
bilateral filter), with the camera's own disparity step: far surfaces stop being staircases, edges
stay, and clouds whose depths do not come in steps are left as read."""

from __future__ import annotations

import numpy as np

from stratamap.core.io.pointcloud import write_pcd
from stratamap.core.stages import PipelineData
from stratamap.plugins.sources.pointcloud import PointCloudSource

#: A Kinect's inverse-depth step (1/m): depth steps of 3.6 cm at 3.5 m.
KINECT_STEP = 0.0029


def _camera_frame(scene, width: int = 240, height: int = 180, yaw_deg: float = 0.0, eye: float = 1.0):
    """An organized cloud (camera's optical frame: x right, y down, z forward; NaN where nothing is
    hit) of ``scene`` (an Open3D raycasting scene, z up) from ``eye`` m above the origin, looking
    level along +y turned ``yaw_deg`` toward +x, 60 degrees wide."""
    import open3d as o3d

    focal = width / 2 / np.tan(np.radians(30.0))
    u, v = np.meshgrid(np.arange(width) + 0.5 - width / 2, np.arange(height) + 0.5 - height / 2)
    rays = np.stack([u / focal, v / focal, np.ones_like(u)], -1).reshape(-1, 3)  # optical frame, depth 1
    yaw = np.radians(yaw_deg)
    forward = np.array([np.sin(yaw), np.cos(yaw), 0.0])
    right = np.array([np.cos(yaw), -np.sin(yaw), 0.0])
    down = np.cross(forward, right)
    to_world = np.stack([right, down, forward], 1)
    directions = rays @ to_world.T
    origin = np.array([0.0, 0.0, eye])
    cast = np.hstack([np.tile(origin, (len(rays), 1)), directions]).astype(np.float32)
    t = scene.cast_rays(o3d.core.Tensor(cast))["t_hit"].numpy().astype(np.float64)
    depth = np.where(np.isfinite(t), t, np.nan)  # the ray's z in the optical frame is 1: t is depth
    return rays * depth[:, None]


def _scene(*boxes):
    """Open3D raycasting scene of axis-aligned boxes ``(min corner, size)``."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    for corner, size in boxes:
        mesh = o3d.geometry.TriangleMesh.create_box(*size).translate(corner)
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene


def _quantized(points: np.ndarray, step: float = KINECT_STEP) -> np.ndarray:
    """The points with their depth rounded to whole steps of inverse depth, as a Kinect reports it."""
    depth = points[:, 2]
    stepped = 1.0 / (np.round((1.0 / depth) / step) * step)
    return points * (stepped / depth)[:, None]


def _read(path, **params) -> tuple[np.ndarray, dict]:
    data = PipelineData()
    out = PointCloudSource(path=str(path), gravity="off", **params).run(data)
    return out["frames"].points, data.notes["pointcloud"]


def test_a_far_wall_seen_in_disparity_steps_is_a_plane_again(tmp_path):
    """A wall 2.8-4.3 m deep in the image, its depth in a Kinect's steps (2.3-5.4 cm there): read with the
    defaults, its points lie within a third of their raw scatter of the wall's plane; the note says
    which step was found; ``smooth_depth: off`` reads the points as written."""
    # Turned 20 degrees from the wall's normal, the wall's distance runs across the image.
    yaw = np.radians(20.0)
    truth = _camera_frame(_scene(((-9.0, 3.2, -1.0), (18.0, 0.1, 4.0))), yaw_deg=20.0)
    assert np.isfinite(truth).all()
    normal = np.array([-np.sin(yaw), 0.0, np.cos(yaw)])  # the wall's normal (world +y) in the optical frame
    offset = float(np.median(truth @ normal))
    assert 2.5 < truth[:, 2].min() and truth[:, 2].max() < 4.5
    raw = _quantized(truth)
    path = write_pcd(tmp_path / "wall.pcd", raw, organized=(240, 180))
    raw_scatter = np.sqrt(np.mean((raw @ normal - offset) ** 2))
    assert raw_scatter > 0.008

    smoothed, note = _read(path)
    scatter = np.sqrt(np.mean((smoothed @ normal - offset) ** 2))
    assert scatter < 0.3 * raw_scatter, (scatter, raw_scatter)
    assert note["depth_smoothing"]["applied"] is True
    assert abs(note["depth_smoothing"]["inverse_depth_step"] - KINECT_STEP) < 1e-4

    as_read, note = _read(path, smooth_depth="off")
    assert np.allclose(as_read, raw, atol=1e-5)
    assert "depth_smoothing" not in note


def test_smoothing_keeps_a_boxs_edge_off_the_wall_behind_it(tmp_path):
    """A box 0.3 m before a wall 3 m away: smoothing moves no point into the gap between them (no
    flying pixels at the box's outline), and both surfaces stay where they are."""
    # The box is taller than the eye: only its front is seen.
    scene = _scene(((-6.0, 3.0, -1.0), (12.0, 0.1, 4.0)), ((-0.3, 2.4, 0.0), (0.6, 0.3, 1.4)))
    yaw = np.radians(15.0)  # turned, so that depth runs across the image
    truth = _camera_frame(scene, yaw_deg=15.0)
    path = write_pcd(tmp_path / "box.pcd", _quantized(truth), organized=(240, 180))
    smoothed, note = _read(path)
    assert note["depth_smoothing"]["applied"] is True
    y = -np.sin(yaw) * smoothed[:, 0] + np.cos(yaw) * smoothed[:, 2]  # each point's world y
    on_box = np.abs(y - 2.4) < 0.06
    on_wall = np.abs(y - 3.0) < 0.12
    assert on_box.sum() > 1000 and on_wall.sum() > 10000
    assert np.all(on_box | on_wall), np.sort(y[~(on_box | on_wall)])[:10]


def test_a_cloud_whose_depths_do_not_come_in_disparity_steps_is_left_as_read(tmp_path):
    """A rendered frame (every depth distinct) and a time-of-flight camera's (whole millimetres) are
    no disparity camera's: their points are not moved, and the note says why."""
    rng = np.random.default_rng(0)
    truth = _camera_frame(_scene(((-6.0, 3.2, -1.0), (12.0, 0.1, 4.0))))
    noisy = truth * (1.0 + rng.normal(0.0, 0.002, len(truth)))[:, None]
    path = write_pcd(tmp_path / "rendered.pcd", noisy, organized=(240, 180))
    points, note = _read(path)
    assert np.allclose(points, noisy, atol=1e-5)
    assert note["depth_smoothing"]["applied"] is False
    assert "even steps" in note["depth_smoothing"]["reason"]

    # Depths in whole millimetres (a time-of-flight camera's) come in steps, but not even in inverse depth.
    millimetres = truth * (np.round(truth[:, 2], 3) / truth[:, 2])[:, None]
    path = write_pcd(tmp_path / "tof.pcd", millimetres, organized=(240, 180))
    points, note = _read(path)
    assert np.allclose(points, millimetres, atol=1e-5)
    assert "even steps" in note["depth_smoothing"]["reason"]


def test_a_camera_cloud_stored_without_its_image_grid_is_smoothed_alike(tmp_path):
    """The stepped wall's frame stored unorganized, its invalid pixels dropped (as mOSD's test43.pcd):
    each point's pixel is found from its ray, and it comes out as the organized frame does."""
    truth = _camera_frame(_scene(((-9.0, 3.2, -1.0), (18.0, 0.1, 4.0))), yaw_deg=20.0)
    raw = _quantized(truth)
    keep = np.random.default_rng(1).random(len(raw)) > 0.1  # a tenth of the pixels invalid, dropped
    unorganized, note = _read(write_pcd(tmp_path / "flat.pcd", raw[keep]))
    assert note["depth_smoothing"]["applied"] is True
    reference, _ = _read(
        write_pcd(tmp_path / "grid_holes.pcd", np.where(keep[:, None], raw, np.nan), organized=(240, 180))
    )
    assert reference.shape == unorganized.shape  # the source drops the invalid pixels, in order
    assert np.abs(unorganized - reference).max() < 1e-4
    assert np.abs(unorganized - raw[keep]).max() > 0.005  # it did move them
