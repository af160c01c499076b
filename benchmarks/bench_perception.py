"""Benchmark: stereo renderer, perception per frame vs the bare OpenCV matcher, depth accuracy.

Run with ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_perception.py``.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

import cv2
import numba
import numpy as np

from companion.perception import PerceptionConfig, StereoPerception
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import GroundPlane, Sphere, World
from protocols.camera import CameraModel
from protocols.frames import rotation_321
from protocols.stereo_frame import StereoFrame, decode, encode

__all__ = ["main"]

WORLD = World(
    spheres=(
        Sphere((10.0, 0.0, -7.0), 1.5),
        Sphere((13.0, -3.0, -6.0), 1.0, texture_seed=1),
        Sphere((15.0, 3.0, -8.0), 1.2, texture_seed=2),
    ),
    ground=GroundPlane(0.0),
)


def _poses(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """An approach on the paper's path: nearest surface from ~8 m to 2 m, slight attitude."""
    poses = []
    for i in range(n):
        surface_m = 8.0 - 6.0 * i / max(n - 1, 1)
        pos = np.array([10.0 - 1.5 - surface_m, 0.2 * math.sin(i), -7.0])
        R = rotation_321(math.radians(2 * math.sin(0.7 * i)), math.radians(-3.0), 0.05)
        poses.append((pos, R))
    return poses


def _ms(samples: list[float]) -> str:
    median_ms = 1e3 * statistics.median(samples)
    return f"median {median_ms:6.2f} ms, mean {1e3 * statistics.mean(samples):6.2f} ms"


def bench_renderer(n: int) -> None:
    renderer = StereoCameraRenderer(CameraModel())
    pos, R = _poses(1)[0]
    renderer.render(WORLD, pos, R)  # compile / load the numba cache
    times = []
    for i, (pos, R) in enumerate(_poses(n)):
        t0 = time.perf_counter()
        renderer.render(WORLD, pos, R, noise_seed=i)
        times.append(time.perf_counter() - t0)
    print(f"renderer 320x240, 3 spheres + ground, per stereo pair: {_ms(times)} (goal <= 3 ms)")


def bench_perception(width: int, height: int, n: int, repeats: int) -> None:
    camera = CameraModel(width_px=width, height_px=height)
    renderer = StereoCameraRenderer(camera)
    poses = _poses(n)
    payloads = []
    for i, (pos, R) in enumerate(poses):
        out = renderer.render(WORLD, pos, R, noise_seed=i)
        payloads.append(encode(StereoFrame(i, i, camera.intrinsics, out.left, out.right)))
    perception = StereoPerception()
    frame0 = decode(payloads[0])
    perception.process(frame0, *poses[0])
    # The bare matcher: the same OpenCV StereoBM with the same settings (range, block,
    # texture, uniqueness, speckle, left/right check) on the unpadded pair, nothing else.
    k = frame0.intrinsics
    bare = cv2.StereoBM_create(perception.num_disparities(k), perception.block_size(k))
    cfg = perception.config
    bare.setTextureThreshold(cfg.texture_threshold)
    bare.setUniquenessRatio(cfg.uniqueness_ratio)
    bare.setSpeckleWindowSize(cfg.speckle_window_px)
    bare.setSpeckleRange(cfg.speckle_range_px)
    bare.setDisp12MaxDiff(cfg.lr_max_diff_px)
    t_pipe, t_bare, n_obstacles, with_obstacles = [], [], 0, []
    for _ in range(repeats):
        for payload, (pos, R) in zip(payloads, poses, strict=True):
            frame = decode(payload)
            t0 = time.perf_counter()
            bare.compute(frame.left, frame.right)
            t_bare.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            result = perception.process(decode(payload), pos, R)
            t_pipe.append(time.perf_counter() - t0)
            n_obstacles += len(result.obstacles)
            with_obstacles.append(bool(result.obstacles))
    busy = [i for i, seen in enumerate(with_obstacles) if seen]
    busy_ratio = statistics.mean(t_pipe[i] for i in busy) / statistics.mean(t_bare[i] for i in busy)
    ratio = statistics.mean(t_pipe) / statistics.mean(t_bare)
    hz = 1.0 / statistics.mean(t_pipe)
    print(
        f"perception {width}x{height} (decode -> obstacle spheres): {_ms(t_pipe)}, {hz:5.1f} Hz; "
        f"bare StereoBM {_ms(t_bare)}; ratio {ratio:.2f} (goal <= 1.5); "
        f"{n_obstacles / len(t_pipe):.2f} obstacles/frame; "
        f"ratio on frames with obstacles ({len(busy)}/{len(t_pipe)}) {busy_ratio:.2f}"
    )


def bench_accuracy(n: int) -> None:
    camera = CameraModel()
    renderer = StereoCameraRenderer(camera)
    fb = camera.intrinsics.focal_baseline_m_px
    for name, config in (("StereoBM", PerceptionConfig()),):
        perception = StereoPerception(config)
        errors, covered, total, times = [], 0, 0, []
        for i, (pos, R) in enumerate(_poses(n)):
            out = renderer.render(WORLD, pos, R, noise_seed=i)
            frame = StereoFrame(i, i, camera.intrinsics, out.left, out.right)
            t0 = time.perf_counter()
            disparity = perception.disparity_fixed(frame).astype(np.float64) / 16.0
            times.append(time.perf_counter() - t0)
            obstacle = (out.depth_left_m >= 2.0) & (out.depth_left_m <= 4.0)
            valid = obstacle & (disparity > 0)
            errors.append(fb / disparity[valid] - out.depth_left_m[valid])
            covered += int(valid.sum())
            total += int(obstacle.sum())
        e = np.concatenate(errors)
        abs_cm = 100 * np.abs(e)
        print(
            f"depth accuracy {name:15s} on obstacle pixels at 2-4 m: "
            f"median |err| {np.median(abs_cm):.1f} cm, p95 {np.percentile(abs_cm, 95):.1f} cm, "
            f"RMSE {100 * np.sqrt(np.mean(e**2)):.1f} cm, bias {100 * np.mean(e):+.1f} cm, "
            f"valid {100 * covered / max(total, 1):.0f}% of {total} px; matcher {_ms(times)}"
        )


def main(argv: list[str] | None = None) -> None:
    """Print the figures issue 3 asks for."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=40, help="distinct frames per test")
    parser.add_argument("--repeats", type=int, default=3, help="passes over the frames")
    parser.add_argument("--only-perception", action="store_true", help="timing ratios only")
    args = parser.parse_args(argv)
    print(
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, "
        f"cv2 threads {cv2.getNumThreads()}, numba threads {numba.get_num_threads()}, "
        f"cpus {os.cpu_count()}"
    )
    if not args.only_perception:
        bench_renderer(args.frames * args.repeats)
    bench_perception(320, 240, args.frames, args.repeats)
    bench_perception(640, 480, args.frames, args.repeats)
    if not args.only_perception:
        bench_accuracy(args.frames)


if __name__ == "__main__":
    main()
