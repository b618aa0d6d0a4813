"""Throughput of the `tsdf` mapper against bare Open3D TSDF integration of the same frames.

Renders a synthetic 640x480 office walk once (kept in memory, so reading and rendering are not
timed), then times, alternating, (a) bare Open3D: VoxelBlockGrid integration of every frame plus
point-cloud and mesh extraction, and (b) stratamap's `tsdf` mapper with panoptic label fusion
(oracle labels) producing geometry, semantics and instances. Both at 2 cm voxels. Reports frames
per second of each and the ratio (b)/(a); the target is >= 0.6 (label fusion costs at most 40%).
Both use the mapper's voxel-block settings (block resolution and initial block count).
Last line: JSON.

    python benchmarks/mapping_throughput.py [--frames 60] [--repeats 2]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import open3d as o3d
import open3d.core as o3c

from stratamap.core.geometry.transforms import invert
from stratamap.core.stages import PipelineData
from stratamap.core.synthetic import SceneSpec, SyntheticWorld
from stratamap.plugins.mappers.tsdf import TSDFMapper
from stratamap.plugins.segmenters.oracle import OracleSegmenter


def bare_open3d(
    frames, intrinsics, voxel: float, depth_max: float, trunc: float, block_resolution: int, block_count: int
) -> int:
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"),
        attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)),
        voxel_size=voxel,
        block_resolution=block_resolution,
        block_count=block_count,
        device=o3c.Device("CPU:0"),
    )
    K = o3c.Tensor(intrinsics.matrix, o3c.float64)
    for f in frames:
        ext = o3c.Tensor(invert(f.pose), o3c.float64)
        depth = o3d.t.geometry.Image(o3c.Tensor(f.depth))
        color = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(f.rgb, dtype=np.float32) / 255.0))
        coords = vbg.compute_unique_block_coordinates(depth, K, ext, 1.0, depth_max, trunc)
        vbg.integrate(coords, depth, color, K, K, ext, 1.0, depth_max, trunc)
    pcd = vbg.extract_point_cloud()
    vbg.extract_triangle_mesh()
    return len(pcd.point.positions)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--voxel", type=float, default=0.02)
    args = parser.parse_args()

    spec = SceneSpec.model_validate(
        {
            "type": "office",
            "seed": 0,
            "trajectory": {"type": "walk", "frames": args.frames},
            "noise": {"depth": "kinect"},
        }
    )
    world = SyntheticWorld(spec)
    stream = world.stream()
    stream.frames = list(stream.frames)  # render once, outside the timings
    data = PipelineData(stream=stream, ground_truth=world.ground_truth())
    data.ground_truth.frame_labels = list(data.ground_truth.frame_labels)
    data.frame_labels = OracleSegmenter().run(data)["frame_labels"]
    mapper = TSDFMapper(voxel_size=args.voxel)
    cfg = mapper.config

    t_bare, t_full = [], []
    for _ in range(args.repeats):  # alternate so both see the same machine load
        t0 = time.perf_counter()
        bare_open3d(
            stream.frames,
            stream.intrinsics,
            args.voxel,
            cfg.depth_max,
            cfg.truncation_voxels,
            cfg.block_resolution,
            cfg.block_count,
        )
        t_bare.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        out = mapper.run(data)
        t_full.append(time.perf_counter() - t0)
    fps_bare = args.frames / min(t_bare)
    fps_full = args.frames / min(t_full)
    print(
        f"bare Open3D integration: {fps_bare:.2f} frames/s; stratamap tsdf with panoptic fusion: {fps_full:.2f} "
        "frames/s"
    )
    print(f"(objects mapped: {len(out['instances'])}, map points: {len(out['geometry'])})")
    print(
        json.dumps(
            {
                "fps_open3d": round(fps_bare, 3),
                "fps_stratamap": round(fps_full, 3),
                "ratio": round(fps_full / fps_bare, 3),
                "frames": args.frames,
                "voxel_size": args.voxel,
                "resolution": [640, 480],
            }
        )
    )


if __name__ == "__main__":
    main()
