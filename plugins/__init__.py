"""stratamap's built-in plugins: one folder per stage kind (and ``observers/``), one entry per plugin in each.

``BUILTIN_PLUGINS`` is the one list of them; :mod:`stratamap.core.registry` registers these
modules in code, through the same hooks third-party plugins implement (entry points are for
third-party distributions only).
"""

BUILTIN_PLUGINS: tuple[str, ...] = (
    "stratamap.plugins.sources.synthetic",
    "stratamap.plugins.sources.tum",
    "stratamap.plugins.sources.pointcloud",
    "stratamap.plugins.sources.rosbag",
    "stratamap.plugins.sources.redwood",
    "stratamap.plugins.sources.scannet",
    "stratamap.plugins.sources.urdf_scan",
    "stratamap.plugins.sources.recordings",
    "stratamap.plugins.segmenters.oracle",
    "stratamap.plugins.segmenters.clusters",
    "stratamap.plugins.segmenters.onnx_panoptic",
    "stratamap.plugins.segmenters.plane_crf",
    "stratamap.plugins.segmenters.detector",
    "stratamap.plugins.mappers.tsdf",
    "stratamap.plugins.mappers.points",
    "stratamap.plugins.mappers.semantic_tsdf",
    "stratamap.plugins.mappers.instance_clusters",
    "stratamap.plugins.mappers.occupancy",
    "stratamap.plugins.mappers.contact_graph",
    "stratamap.plugins.mappers.physical_check",
    "stratamap.plugins.completers.bbox",
    "stratamap.plugins.completers.icp_match",
    "stratamap.plugins.completers.plane_box_match",
    "stratamap.plugins.completers.pcn",
    "stratamap.plugins.completers.fronts",
    "stratamap.plugins.exporters.urdf",
    "stratamap.plugins.exporters.nav2_map",
    "stratamap.plugins.exporters.ply",
    "stratamap.plugins.exporters.costmap",
    "stratamap.plugins.exporters.scene_graph",
    "stratamap.plugins.exporters.mjcf",
    "stratamap.plugins.exporters.sdf",
    "stratamap.plugins.exporters.usd",
    "stratamap.plugins.exporters.glb",
    "stratamap.plugins.exporters.ros2_bag",
    "stratamap.plugins.observers.rerun",
)
