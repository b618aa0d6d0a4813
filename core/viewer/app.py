"""The web viewer: a viser server showing a :class:`ViewerScene`, with layer controls and joint sliders.

viser (the viewer nerfstudio uses) serves a self-contained three.js client from the Python package,
so the viewer works offline. Every layer is a folder of the control panel; clicking an object (its
box or its completed model) shows what the map knows about it.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.errors import StratamapError
from stratamap.core.viewer.scene import (
    COLOR_MODES,
    MAX_DISPLAY_POINTS,
    OBJECT_VIEWS,
    ObjectView,
    ViewerScene,
    find_map_dir,
    load_scene,
    quaternion_wxyz,
    yaw_wxyz,
)

NO_TEXTURE = "off"
NO_SELECTION = "(none)"
HINT = "Click an object (its box or its model) or pick it here."


def import_viser() -> Any:
    """viser, or an error saying how to install it (it is an optional extra)."""
    try:
        import viser
    except ImportError as exc:
        raise StratamapError(f"the viewer needs viser ({exc}): pip install 'stratamap[viz]'") from exc
    return viser


def _rgb(color: np.ndarray) -> tuple[int, int, int]:
    r, g, b = (np.clip(np.asarray(color, float), 0.0, 1.0) * 255).round().astype(int)
    return int(r), int(g), int(b)


class MapViewer:
    """A running viewer of one map. ``url`` is where a browser opens it; :meth:`stop` ends it."""

    def __init__(self, scene: ViewerScene, host: str = "127.0.0.1", port: int = 8080):
        viser = import_viser()
        self.scene = scene
        self.server = viser.ViserServer(host=host, port=port, label="stratamap view", verbose=False)
        self.joint_values: dict[int, dict[str, float]] = {obj.id: {} for obj in scene.objects}
        self._lock = threading.Lock()
        self._part_handles: dict[tuple[int, str], Any] = {}
        self._texture_handles: dict[str, Any] = {}
        self._color_mode, self._object_view, self._models_shown = "rgb", "completed", True
        self.server.scene.set_up_direction("+z")
        # Plain lights, no image-based lighting or shadows: preparing an HDRI environment takes a software-rendered
        # browser (no GPU, as on a server or in CI) a quarter of a minute before the first picture.
        self.server.scene.configure_environment_map(hdri=None)
        self.server.scene.configure_default_lights(enabled=True, cast_shadow=False)
        self.server.scene.add_light_ambient("/lights/ambient", intensity=1.2)
        self._place_camera()
        self._add_scene()
        self._add_gui()

    @property
    def url(self) -> str:
        host = self.server.get_host()
        shown = "127.0.0.1" if host in ("0.0.0.0", "") else host
        return f"http://{shown}:{self.server.get_port()}"

    def stop(self, timeout: float = 5.0) -> None:
        """Stop serving; a server still closing connections after ``timeout`` seconds is left to the
        process's exit (its threads are daemons), so Ctrl-C always ends ``stratamap view`` promptly."""
        stopper = threading.Thread(target=self.server.stop, daemon=True)
        stopper.start()
        stopper.join(timeout)

    # ---------------------------------------------------------------- scene

    def _place_camera(self) -> None:
        """Look at the middle of the map from above one corner, far enough back to see all of it."""
        low, high = self.scene.bounds
        center = (low + high) / 2
        span = float(max(np.linalg.norm(high[:2] - low[:2]), 1.0))
        eye = center + np.array([-0.3, -0.5, 0.55]) * span
        self.server.initial_camera.position = tuple(float(v) for v in eye)
        self.server.initial_camera.look_at = tuple(float(v) for v in center)
        self.server.initial_camera.up = (0.0, 0.0, 1.0)

    def _add_scene(self) -> None:
        s, api = self.scene, self.server.scene
        self.mesh = None
        self.boxes, self.labels, self.pickers = [], [], []
        for obj in s.objects:
            self.boxes.append(
                api.add_line_segments(f"/instances/box_{obj.id}", obj.box_segments, _rgb(obj.color), thickness=0.012)
            )
            self.labels.append(api.add_label(f"/instances/label_{obj.id}", obj.title, position=obj.label_position))
            self._add_picker(obj)
            if obj.parts:
                self._add_model(obj)
        self.support = api.add_line_segments(
            "/contact_graph/support", s.support_edges.reshape(-1, 2, 3), (220, 30, 30), thickness=0.02
        )
        self.proximal = api.add_line_segments(
            "/contact_graph/proximal", s.proximal_edges.reshape(-1, 2, 3), (40, 90, 220), thickness=0.01, visible=False
        )
        for name, tex in s.textures.items():
            self._texture_handles[name] = api.add_image(
                f"/occupancy/{name}",
                tex.image,
                tex.width,
                tex.height,
                format="png",
                wxyz=yaw_wxyz(tex.yaw),
                position=tex.center,
                visible=False,
                cast_shadow=False,
                receive_shadow=False,
            )

    def _add_picker(self, obj: ObjectView) -> None:
        """A faint clickable box over the object, so that objects without a model can be picked too."""
        picker = self.server.scene.add_box(
            f"/instances/pick_{obj.id}",
            color=_rgb(obj.color),
            dimensions=tuple(float(v) for v in np.maximum(obj.box_size, 1e-3)),
            opacity=0.12,
            cast_shadow=False,
            receive_shadow=False,
            wxyz=yaw_wxyz(obj.box_yaw),
            position=obj.box_center,
        )
        picker.on_click(lambda _event, object_id=obj.id: self.select(object_id))
        self.pickers.append(picker)

    def _add_model(self, obj: ObjectView) -> None:
        api = self.server.scene
        assert obj.pose is not None
        api.add_frame(
            f"/completions/object_{obj.id}",
            show_axes=False,
            wxyz=quaternion_wxyz(obj.pose[:3, :3]),
            position=obj.pose[:3, 3],
        )
        poses = self._poses(obj)
        for part in obj.parts:
            pose = poses.get(part.name, np.eye(4))
            handle = api.add_mesh_simple(
                f"/completions/object_{obj.id}/{part.name}",
                part.vertices,
                part.faces,
                color=_rgb(obj.color),
                flat_shading=True,
                side="double",
                wxyz=quaternion_wxyz(pose[:3, :3]),
                position=pose[:3, 3],
            )
            handle.on_click(lambda _event, object_id=obj.id: self.select(object_id))
            self._part_handles[(obj.id, part.name)] = handle

    def _poses(self, obj: ObjectView) -> dict[str, np.ndarray]:
        return obj.part_poses(self.joint_values[obj.id])

    # ---------------------------------------------------------------- actions (GUI callbacks call these)

    def set_color_mode(self, mode: str) -> None:
        self._color_mode = mode
        self._refresh_points()

    def set_object_view(self, view: str) -> None:
        """``completed``: models in place of their objects' observed points; ``observed``: points only; ``both``."""
        self._object_view = view
        for handle in self._part_handles.values():
            handle.visible = view != "observed" and self._models_shown
        self._refresh_points()

    def set_models_shown(self, shown: bool) -> None:
        self._models_shown = shown
        self.set_object_view(self._object_view)

    def set_joint(self, object_id: int, joint: str, value: float) -> None:
        """Move one joint of a completed object and re-place its parts."""
        obj = self.scene.object(object_id)
        with self._lock:
            self.joint_values[object_id][joint] = float(value)
            poses = self._poses(obj)
            for part in obj.parts:
                handle = self._part_handles[(object_id, part.name)]
                pose = poses[part.name]
                handle.wxyz = quaternion_wxyz(pose[:3, :3])
                handle.position = pose[:3, 3]

    def set_texture(self, name: str) -> None:
        for texture, handle in self._texture_handles.items():
            handle.visible = texture == name

    def select(self, object_id: int | None) -> None:
        """Show an object's details in the panel (None clears it)."""
        title = NO_SELECTION if object_id is None else self.scene.object(object_id).title
        if self.selector.value != title:
            self.selector.value = title
        self.info.content = HINT if object_id is None else self.scene.info[object_id]

    def _refresh_points(self) -> None:
        mask = self.scene.visible_points(self._object_view)
        points, colors = self.scene.points[mask], self.scene.colors[self._color_mode][mask]
        shown = self.points_shown.value and len(points) > 0
        if len(points) == 0:  # viser draws no empty cloud: one point, hidden
            points, colors = np.zeros((1, 3), np.float32), np.zeros((1, 3), np.uint8)
        with self._lock:
            self.points = self.server.scene.add_point_cloud(
                "/geometry/points",
                points,
                colors,
                point_size=self.point_size.value,
                point_shape="square",
                visible=shown,
            )

    # ---------------------------------------------------------------- control panel

    def _add_gui(self) -> None:
        s, gui = self.scene, self.server.gui
        completed = sum(1 for obj in s.objects if obj.parts)
        where = f"`{s.source}`" if s.source is not None else "a map"
        gui.add_markdown(
            f"**stratamap map** {where}: {s.total_points} points ({len(s.points)} shown), {len(s.objects)} objects, "
            f"{completed} completed"
        )

        with gui.add_folder("Geometry"):
            self.points_shown = gui.add_checkbox("geometry points", True)
            self.point_size = gui.add_slider(
                "point size (m)", min=0.002, max=0.1, step=0.002, initial_value=round(s.point_size, 3)
            )
            mesh_shown = gui.add_checkbox("geometry mesh", False, disabled=s.mesh is None)
        with gui.add_folder("Semantics"):
            color_mode = gui.add_dropdown("colour points by", COLOR_MODES, initial_value="rgb")
        with gui.add_folder("Instances"):
            boxes_shown = gui.add_checkbox("instance boxes", True)
            labels_shown = gui.add_checkbox("class labels", True)
        with gui.add_folder("Completions"):
            object_view = gui.add_dropdown("objects shown as", OBJECT_VIEWS, initial_value="completed")
            models_shown = gui.add_checkbox("completed models", True)
            articulated = [obj for obj in s.objects if obj.joints]
            if articulated:
                with gui.add_folder("Joints (articulated parts)"):
                    for obj in articulated:
                        for joint in obj.joints:
                            slider = gui.add_slider(
                                f"{obj.title}: {joint.name}",
                                min=joint.lower,
                                max=joint.upper,
                                step=(joint.upper - joint.lower) / 100,
                                initial_value=min(max(0.0, joint.lower), joint.upper),
                            )
                            slider.on_update(
                                lambda event, object_id=obj.id, name=joint.name: self.set_joint(
                                    object_id, name, event.target.value
                                )
                            )
        with gui.add_folder("Contact graph"):
            support_shown = gui.add_checkbox("support edges", True)
            proximal_shown = gui.add_checkbox("proximal edges", False)
        with gui.add_folder("Occupancy and costmap"):
            texture = gui.add_dropdown(
                "ground texture", (NO_TEXTURE, *s.textures), initial_value=NO_TEXTURE, disabled=not s.textures
            )
        with gui.add_folder("Selected object"):
            self.selector = gui.add_dropdown(
                "object", (NO_SELECTION, *(obj.title for obj in s.objects)), initial_value=NO_SELECTION
            )
            self.info = gui.add_markdown(HINT)
        titles = {obj.title: obj.id for obj in s.objects}

        @self.points_shown.on_update
        def _(_: Any) -> None:
            self.points.visible = self.points_shown.value

        @self.point_size.on_update
        def _(_: Any) -> None:
            self.points.point_size = self.point_size.value

        @mesh_shown.on_update
        def _(_: Any) -> None:
            if self.mesh is None and s.mesh is not None:  # sent on first use: a room's surface is large
                self.mesh = self.server.scene.add_mesh_trimesh("/geometry/mesh", s.mesh)
            if self.mesh is not None:
                self.mesh.visible = mesh_shown.value

        @color_mode.on_update
        def _(_: Any) -> None:
            self.set_color_mode(color_mode.value)

        @boxes_shown.on_update
        def _(_: Any) -> None:
            for handle in (*self.boxes, *self.pickers):
                handle.visible = boxes_shown.value

        @labels_shown.on_update
        def _(_: Any) -> None:
            for handle in self.labels:
                handle.visible = labels_shown.value

        @object_view.on_update
        def _(_: Any) -> None:
            self.set_object_view(object_view.value)

        @models_shown.on_update
        def _(_: Any) -> None:
            self.set_models_shown(models_shown.value)

        @support_shown.on_update
        def _(_: Any) -> None:
            self.support.visible = support_shown.value

        @proximal_shown.on_update
        def _(_: Any) -> None:
            self.proximal.visible = proximal_shown.value

        @texture.on_update
        def _(_: Any) -> None:
            self.set_texture(texture.value)

        @self.selector.on_update
        def _(_: Any) -> None:
            self.select(titles.get(self.selector.value))

        self._refresh_points()


def open_viewer(
    path: str | Path, host: str = "127.0.0.1", port: int = 8080, max_points: int = MAX_DISPLAY_POINTS
) -> MapViewer:
    """Load the map at ``path`` (a run's output folder or a map folder) and serve it; returns the running viewer."""
    directory = find_map_dir(path)
    import_viser()  # fail before the (longer) map load when viser is missing
    _, scene = load_scene(directory, max_points)
    return MapViewer(scene, host, port)
