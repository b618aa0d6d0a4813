"""Observer ``rerun``: a run as a rerun recording (``.rrd``), open it with ``rerun FILE.rrd``.

What is logged, and when (entity paths under ``world/`` are in the map frame, z up):

- ``world/camera``: pose and pinhole of every input frame (timeline ``frame``), with the frame's
  images ``rgb`` and ``depth`` and, once the segmenter has run, its segmentation ``classes``
  (labelled by the annotation context at ``world``) and ``instances``;
- ``world/input/points``: a source's static point cloud;
- ``world/map/points/rgb``, ``classes``, ``instances``: the fused map's points by colour, class and
  instance; ``world/map/mesh``: the reconstructed mesh, when the mapper made one;
- ``world/objects/boxes``: object boxes labelled ``class id``; ``world/objects/completions/<id>``:
  each completed object's model in place; ``world/objects/support``: arrows from each supporting
  object to the objects it supports;
- ``occupancy/<layer>``: each occupancy layer as a top-down image (north up).

Map layers are logged on timeline ``stage`` (0: the source, then one step per stage) as each stage
produces them, so scrubbing it replays how the map was built. Content is deterministic for a fixed
input: the recording id derives from the pipeline, and no wall-clock timeline or property is logged.
"""

from __future__ import annotations

import contextlib
import json
import uuid
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core.atomic import atomic_path
from stratamap.core.errors import PluginError
from stratamap.core.geometry.transforms import matrix_to_quat_xyzw
from stratamap.core.hookspecs import Observer, ObserverConfig, hookimpl
from stratamap.core.map.colors import id_colors

INSTALL_HINT = "pip install 'stratamap[viz]'"
#: Occupancy values (-1 unknown, 0 free .. 100 occupied) as grey levels, as map_saver draws them.
UNKNOWN_GREY = 205
MAP_LAYERS_LOGGED = ("geometry", "semantics", "instances", "contact_graph", "occupancy", "augmented")


class RerunConfig(ObserverConfig):
    path: str = Field(
        default="recording.rrd",
        description="Recording file; a relative path is written inside the run's output folder, an absolute one as is.",
    )
    frame_stride: int = Field(
        default=1, ge=1, description="Log every Nth input frame (pose, images, segmentation); 1 logs them all."
    )
    images: bool = Field(
        default=True, description="Log the input frames' rgb and depth images (poses are always logged)."
    )
    recording_id: str | None = Field(
        default=None,
        description="Recording id shown by the viewer; by default derived from the pipeline, so equal runs share it.",
    )


def _rerun() -> Any:
    try:
        import rerun
    except ImportError:
        raise PluginError(f"observer 'rerun' needs the rerun SDK: {INSTALL_HINT}") from None
    return rerun


def palette(ids: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours for integer ids, as report.html draws them."""
    return (id_colors(ids) * 255).round().astype(np.uint8)


def occupancy_image(grid: Any) -> np.ndarray:
    """An occupancy grid as a grey image, first row the map's top (highest y): free white, occupied black."""
    data = np.asarray(grid.data, dtype=np.int16)
    image = np.full(data.shape, UNKNOWN_GREY, dtype=np.uint8)
    known = data >= 0
    image[known] = np.round(254 - np.clip(data[known], 0, 100) * 2.54).astype(np.uint8)
    return np.flipud(image)


class RerunObserver(Observer[RerunConfig]):
    """Record the run for the rerun viewer: frames, poses, segmentation, map, objects, completions, occupancy."""

    name = "rerun"
    Config = RerunConfig

    def __init__(self, config: RerunConfig | None = None, **params: Any):
        super().__init__(config, **params)
        self._rr = _rerun()  # fails before the run starts when the SDK is missing
        self._stream: Any = None
        self._pending: contextlib.ExitStack | None = None  # the atomic write of a file outside the output
        self._logged: dict[str, int] = {}  # layer -> id() of the value last logged
        self._frame_indices: set[int] = set()
        self.path: Path | None = None

    # ---------------------------------------------------------------------------------- hooks

    @hookimpl
    def stratamap_pipeline_start(self, pipeline: Any) -> None:
        rr = self._rr
        target = Path(self.config.path).expanduser()
        if not target.is_absolute():
            target = Path(pipeline.out_dir) / target
        self.path = target
        target.parent.mkdir(parents=True, exist_ok=True)
        self._pending = contextlib.ExitStack()
        writing = self._pending.enter_context(atomic_path(target))
        self._stream = rr.RecordingStream("stratamap", recording_id=self._recording_id(pipeline), send_properties=False)
        self._stream.set_log_time_enabled(False)  # wall-clock timelines would make equal runs differ
        self._stream.set_log_tick_enabled(False)
        self._stream.save(writing)
        self._logged.clear()
        self._frame_indices.clear()
        self._stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    @hookimpl
    def stratamap_stage_end(self, pipeline: Any, stage: Any, index: int, seconds: float) -> None:
        if self._stream is None or pipeline.data is None:
            return
        data = pipeline.data
        if stage.kind == "sources":
            self._log_vocabulary(data)
            self._log_input(data)
        if data.frame_labels is not None and self._logged.get("frame_labels") != id(data.frame_labels):
            self._logged["frame_labels"] = id(data.frame_labels)
            self._log_segmentation(data.frame_labels)
        self._log_map(data, step=index + 1)

    @hookimpl
    def stratamap_pipeline_end(self, pipeline: Any, report: dict) -> None:
        if self._stream is None or pipeline.data is None:
            return
        self._log_vocabulary(pipeline.data)  # the ground truth's vocabulary, once the run settled it
        self._finish(success=True)

    def close(self) -> None:
        self._finish(success=False)

    # ---------------------------------------------------------------------------------- logging

    def _recording_id(self, pipeline: Any) -> str:
        if self.config.recording_id:
            return self.config.recording_id
        spec = pipeline.validated.spec.model_dump(mode="json")
        return str(uuid.uuid5(uuid.NAMESPACE_URL, "stratamap:" + json.dumps(spec, sort_keys=True)))

    def _finish(self, success: bool) -> None:
        if self._stream is not None:
            self._stream.flush()
            self._stream.disconnect()  # closes the file before it is renamed into place
            self._stream = None
        if self._pending is not None:
            pending, self._pending = self._pending, None
            if success:
                pending.close()
            else:  # a failed run: the partial recording is removed, not renamed into place
                pending.__exit__(RuntimeError, RuntimeError("the run failed"), None)

    def _at(self, timeline: str, step: int) -> None:
        self._stream.reset_time()
        self._stream.set_time(timeline, sequence=int(step))

    def _log_vocabulary(self, data: Any) -> None:
        rr = self._rr
        vocabulary = data.ground_truth.vocabulary if data.ground_truth is not None else data.map.vocabulary
        if data.map.semantics is not None:
            vocabulary = data.map.semantics.vocabulary
        colors = palette(np.arange(len(vocabulary.names)))
        context = [
            rr.AnnotationInfo(id=i, label=name, color=tuple(int(c) for c in colors[i]))
            for i, name in enumerate(vocabulary.names)
        ]
        self._stream.log("world", rr.AnnotationContext(context), static=True)
        # instance ids are not classes: an empty context keeps the class labels off them
        self._stream.log("world/camera/instances", rr.AnnotationContext([]), static=True)

    def _log_input(self, data: Any) -> None:
        rr, stream = self._rr, data.stream
        if stream is None:
            return
        if stream.points is not None and len(stream.points):
            colors = None if stream.point_colors is None else (np.asarray(stream.point_colors) * 255).astype(np.uint8)
            self._stream.log("world/input/points", rr.Points3D(np.asarray(stream.points, np.float32), colors=colors))
        intr = stream.intrinsics
        if intr is not None:
            pinhole = rr.Pinhole(
                image_from_camera=intr.matrix, resolution=[intr.width, intr.height], camera_xyz=rr.ViewCoordinates.RDF
            )
            self._stream.log("world/camera", pinhole, static=True)
        frames = stream.frames
        for position in range(0, len(frames), self.config.frame_stride):
            frame = frames[position]
            self._frame_indices.add(int(frame.index))
            self._at("frame", frame.index)
            if frame.pose is not None:
                pose = np.asarray(frame.pose, dtype=np.float64)
                self._stream.log("world/camera", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
            if self.config.images:
                self._stream.log("world/camera/rgb", rr.Image(np.asarray(frame.rgb, dtype=np.uint8)))
                self._stream.log("world/camera/depth", rr.DepthImage(np.asarray(frame.depth, np.float32), meter=1.0))

    def _log_segmentation(self, labels: Any) -> None:
        rr = self._rr
        for seg in labels.frames:
            if not seg.labelled or (self._frame_indices and int(seg.frame_index) not in self._frame_indices):
                continue
            self._at("frame", seg.frame_index)
            self._stream.log("world/camera/classes", rr.SegmentationImage(np.asarray(seg.class_ids, np.uint16)))
            instances = np.asarray(seg.instance_ids, dtype=np.int64)
            self._stream.log(
                "world/camera/instances", rr.SegmentationImage(np.clip(instances, 0, 65535).astype(np.uint16))
            )

    def _changed(self, data: Any, layer: str) -> bool:
        value = data.map.get(layer)
        if value is None or self._logged.get(layer) == id(value):
            return False
        self._logged[layer] = id(value)
        return True

    def _log_map(self, data: Any, step: int) -> None:
        changed = {layer for layer in MAP_LAYERS_LOGGED if self._changed(data, layer)}
        if not changed:
            return
        self._at("stage", step)
        if changed & {"geometry", "semantics"}:
            self._log_geometry(data)
        if changed & {"instances", "contact_graph"}:
            self._log_objects(data)
        if "occupancy" in changed:
            self._log_occupancy(data)
        if "augmented" in changed and data.map.augmented is not data.map.geometry:
            augmented = data.map.augmented
            colors = None if augmented.colors is None else (augmented.colors * 255).astype(np.uint8)
            self._stream.log(
                "world/map/augmented", self._rr.Points3D(augmented.points.astype(np.float32), colors=colors)
            )

    def _log_geometry(self, data: Any) -> None:
        rr, geometry, semantics = self._rr, data.map.geometry, data.map.semantics
        if geometry is None:
            return
        points = geometry.points.astype(np.float32)
        if geometry.colors is not None:
            self._stream.log(
                "world/map/points/rgb", rr.Points3D(points, colors=(geometry.colors * 255).astype(np.uint8))
            )
        if semantics is not None and len(semantics) == len(points):
            self._stream.log("world/map/points/classes", rr.Points3D(points, class_ids=semantics.class_ids))
            self._stream.log("world/map/points/instances", rr.Points3D(points, colors=palette(semantics.instance_ids)))
        mesh = geometry.mesh
        if mesh is not None and len(mesh.faces):
            colors = None
            visual = getattr(mesh, "visual", None)
            if visual is not None and getattr(visual, "kind", None) == "vertex":
                colors = np.asarray(visual.vertex_colors)[:, :3]
            self._stream.log(
                "world/map/mesh",
                rr.Mesh3D(
                    vertex_positions=np.asarray(mesh.vertices, np.float32),
                    triangle_indices=np.asarray(mesh.faces, np.uint32),
                    vertex_colors=colors,
                ),
            )

    def _log_objects(self, data: Any) -> None:
        rr, instances = self._rr, data.map.instances
        if instances is None:
            return
        vocabulary = data.map.semantics.vocabulary if data.map.semantics is not None else data.map.vocabulary
        objects = list(instances)
        class_ids = [vocabulary.id(o.class_name) if o.class_name in vocabulary else 0 for o in objects]
        boxes = rr.Boxes3D(
            centers=[o.box.center for o in objects],
            half_sizes=[o.box.size / 2 for o in objects],
            quaternions=[matrix_to_quat_xyzw(o.box.pose[:3, :3]) for o in objects],
            labels=[f"{o.class_name} {o.id}" for o in objects],
            class_ids=class_ids,
        )
        self._stream.log("world/objects/boxes", boxes)
        self._stream.log("world/objects/completions", rr.Clear(recursive=True))  # drop models of an earlier step
        for obj, class_id in zip(objects, class_ids):
            if obj.completion is None:
                continue
            mesh = obj.completion.world_mesh()
            self._stream.log(
                f"world/objects/completions/{obj.id}",
                rr.Mesh3D(
                    vertex_positions=np.asarray(mesh.vertices, np.float32),
                    triangle_indices=np.asarray(mesh.faces, np.uint32),
                    class_ids=[class_id],
                ),
            )
        self._log_support(data, {o.id: o for o in objects})

    def _log_support(self, data: Any, objects: dict[int, Any]) -> None:
        graph = data.map.contact_graph
        if graph is None:
            return
        pairs = [
            (objects[parent], objects[child])
            for parent, child in graph.support.edges()
            if isinstance(parent, (int, np.integer))
            and isinstance(child, (int, np.integer))
            and int(parent) in objects
            and int(child) in objects
        ]
        if not pairs:
            return
        origins = np.array([p.box.center for p, _ in pairs])
        vectors = np.array([c.box.center for _, c in pairs]) - origins
        self._stream.log("world/objects/support", self._rr.Arrows3D(origins=origins, vectors=vectors))

    def _log_occupancy(self, data: Any) -> None:
        for layer, grid in sorted(data.map.occupancy.items()):
            self._stream.log(f"occupancy/{layer}", self._rr.Image(occupancy_image(grid)))


@hookimpl
def stratamap_register_observers():
    return [RerunObserver]
