"""Benchmark: the known-space update per 320 × 240 depth frame (budget 2 ms), the boundary
spheres built from it each frame, and a free-distance query.

Depth frames come from the stereo perception of rendered pairs along the paper's approach
(the same input the companion integrates). Run with
``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_known_space.py``.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from companion.guidance.map_boundaries import map_boundaries
from companion.known_space import KnownSpace, KnownSpaceConfig
from companion.perception import StereoPerception
from evaluation.scenes import paper_scene
from plant_sim.stereo_camera import StereoCameraRenderer
from protocols.camera import CameraModel
from protocols.frames import rotation_321
from protocols.stereo_frame import StereoFrame

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Print the update cost [ms/frame] and the free-distance query cost [µs]."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--stride", type=int, default=KnownSpaceConfig().pixel_stride)
    args = parser.parse_args(argv)
    scene = paper_scene()
    camera = CameraModel()
    renderer = StereoCameraRenderer(camera)
    perception = StereoPerception()
    R = rotation_321(0.0, math.radians(-10.0), math.pi)
    frames = []
    for i in range(args.frames):
        pos = np.array([18.0 - 0.1 * i, 0.0, -7.0])
        render = renderer.render(scene.world, pos, R, noise_seed=i)
        frame = StereoFrame(i, i, camera.intrinsics, render.left, render.right)
        frames.append((pos, perception.process(frame, pos, R)))
    space = KnownSpace(KnownSpaceConfig(pixel_stride=args.stride))
    update_ms = []
    spheres_ms = []
    n_spheres = []
    goal = np.asarray(scene.goal_ned_m)
    for pos, seen in frames:
        t0 = time.perf_counter()
        rays = space.integrate(seen.depth_m, camera.intrinsics, pos, R)
        t1 = time.perf_counter()
        spheres = map_boundaries(space, pos, goal)
        t2 = time.perf_counter()
        update_ms.append((t1 - t0) * 1e3)
        if spheres:
            spheres_ms.append((t2 - t1) * 1e3)
            n_spheres.append(len(spheres))
    query_us = []
    for _ in range(200):
        t0 = time.perf_counter()
        free = space.free_distance_m(frames[-1][0], (-1.0, 0.0, 0.0), 0.35, 10.0)
        query_us.append((time.perf_counter() - t0) * 1e6)
    print(f"known-space update, 320x240, stride {args.stride} ({rays} rays cast):")
    print(
        f"  median {statistics.median(update_ms):.2f} ms  p95 "
        f"{np.percentile(update_ms, 95):.2f} ms  max {max(update_ms):.2f} ms  (budget 2 ms)"
    )
    if spheres_ms:
        print(
            f"boundary spheres from the map, {len(spheres_ms)} frames with obstacles "
            f"({min(n_spheres)}-{max(n_spheres)} spheres): median "
            f"{statistics.median(spheres_ms):.2f} ms  p95 {np.percentile(spheres_ms, 95):.2f} ms"
            f"  max {max(spheres_ms):.2f} ms; update + spheres median "
            f"{statistics.median(update_ms) + statistics.median(spheres_ms):.2f} ms (budget 2 ms)"
        )
    print(
        f"free-distance query: median {statistics.median(query_us):.0f} µs; "
        f"free ahead {free:.2f} m (true surface {frames[-1][0][0] - 11.5:.2f} m ahead)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
