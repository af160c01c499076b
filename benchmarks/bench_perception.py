"""Benchmark: stereo renderer, perception per frame vs the bare OpenCV matcher, depth accuracy.

Run with ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_perception.py``; with
``--threads``, the thread-count table (issue 32 item 7; run it without ``NUMBA_NUM_THREADS``).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import statistics
import subprocess
import sys
import time

import cv2
import numba
import numpy as np

from companion.bare_bm import BareStereoBM
from companion.perception import PerceptionConfig, StereoPerception
from companion.stereo_bm import noise_sigma
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


def _bare_matcher(config: PerceptionConfig, k, min_range_m: float) -> cv2.StereoBM:
    """The bare matcher: OpenCV StereoBM with perception's settings (block, texture,
    uniqueness, speckle, left/right check) searching down to ``min_range_m``, nothing else,
    on the unpadded pair (the leftmost ``numDisparities`` columns stay unsearched)."""
    source = BareStereoBM(dataclasses.replace(config, min_range_m=min_range_m))
    return source.opencv_matcher(k.width_px, k.focal_baseline_m_px)


def _clocks() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


def bench_perception(width: int, height: int, n: int, repeats: int, stages: bool) -> None:
    """Wall and CPU time per frame of the whole perception (decode -> obstacle spheres)
    against two bare matchers on the same frames: the same full-resolution search range
    (down to ``min_range_m``) and the 1.2 m range the issue measured its baseline with."""
    camera = CameraModel(width_px=width, height_px=height)
    renderer = StereoCameraRenderer(camera)
    poses = _poses(n)
    payloads = []
    for i, (pos, R) in enumerate(poses):
        out = renderer.render(WORLD, pos, R, noise_seed=i)
        payloads.append(encode(StereoFrame(i, i, camera.intrinsics, out.left, out.right)))
    perception = StereoPerception()
    cfg = perception.config
    frame0 = decode(payloads[0])
    perception.process(frame0, *poses[0])
    k = frame0.intrinsics
    bares = {
        f"bare {cfg.min_range_m} m": _bare_matcher(cfg, k, cfg.min_range_m),
        "bare 1.2 m": _bare_matcher(cfg, k, 1.2),
    }
    wall: dict[str, list[float]] = {name: [] for name in ("perception", *bares)}
    cpu: dict[str, list[float]] = {name: [] for name in wall}
    n_obstacles = 0
    for _ in range(repeats):
        for payload, (pos, R) in zip(payloads, poses, strict=True):
            frame = decode(payload)
            for name, bare in bares.items():
                w0, c0 = _clocks()
                bare.compute(frame.left, frame.right)
                w1, c1 = _clocks()
                wall[name].append(w1 - w0)
                cpu[name].append(c1 - c0)
            w0, c0 = _clocks()
            result = perception.process(decode(payload), pos, R)
            w1, c1 = _clocks()
            wall["perception"].append(w1 - w0)
            cpu["perception"].append(c1 - c0)
            n_obstacles += len(result.obstacles)
    mean_ms = {name: 1e3 * statistics.mean(v) for name, v in wall.items()}
    mean_cpu_ms = {name: 1e3 * statistics.mean(v) for name, v in cpu.items()}
    per_frame = n_obstacles / len(cpu["perception"])
    print(
        f"perception {width}x{height} (decode -> obstacle spheres), {per_frame:.2f} "
        f"obstacles/frame, load average {os.getloadavg()[0]:.1f}:"
    )
    print(
        f"  wall {_ms(wall['perception'])} = {1e3 / mean_ms['perception']:5.1f} Hz; "
        f"CPU {mean_cpu_ms['perception']:6.2f} ms/frame (all threads)"
    )
    for name in bares:
        print(
            f"  {name:12s} wall {mean_ms[name]:6.2f} ms, CPU {mean_cpu_ms[name]:6.2f} ms; "
            f"perception / it: wall {mean_ms['perception'] / mean_ms[name]:.2f}, "
            f"CPU {mean_cpu_ms['perception'] / mean_cpu_ms[name]:.2f} (goal <= 1.5)"
        )
    if stages:
        _print_stages(perception, payloads, poses)


def _print_stages(perception: StereoPerception, payloads, poses) -> None:
    """CPU time per stage of the default depth source, then the obstacle stage."""
    source = perception.source
    t: dict[str, list[float]] = {}

    def timed(name, f, *args):
        c0 = time.process_time()
        out = f(*args)
        t.setdefault(name, []).append(time.process_time() - c0)
        return out

    for payload, (pos, R) in zip(payloads, poses, strict=True):
        frame = decode(payload)
        timed("noise estimate", noise_sigma, frame.left)
        timed("prefilter", source._prefiltered, frame)
        timed("main pass (prefilter, padded BM, gates)", source.disparity_fixed, frame)
        timed("near pass", source.coarse_pass_fixed, frame)
        timed("depth source total", source.compute, frame)
        timed("perception total", perception.process, frame, pos, R)
    for name, v in t.items():
        print(f"    {name:42s} CPU {1e3 * statistics.mean(v):6.2f} ms")


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
            disparity = perception.source.disparity_fixed(frame).astype(np.float64) / 16.0
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


def _busy_neighbours(n: int) -> list[subprocess.Popen]:
    """``n`` processes spinning at nice 19: the camera driver and logger of a real
    companion computer (they still take a core whenever it is free)."""
    spin = "import os; os.nice(19)\nwhile True: pass"
    return [subprocess.Popen([sys.executable, "-c", spin]) for _ in range(n)]


def _median_ms(f, n: int) -> float:
    times = []
    for i in range(n):
        t0 = time.perf_counter()
        f(i)
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def bench_threads(n: int) -> None:
    """Issue 32 item 7: renderer (numba) and perception (OpenCV) per 320x240 frame with 1
    and 2 threads, alone and beside a busy neighbour on every other core."""
    camera = CameraModel()
    renderer = StereoCameraRenderer(camera)
    poses = _poses(n)
    frames = []
    for i, (pos, R) in enumerate(poses):
        out = renderer.render(WORLD, pos, R, noise_seed=i)
        frames.append(StereoFrame(i, i, camera.intrinsics, out.left, out.right))
    perception = StereoPerception()
    perception.process(frames[0], *poses[0])
    pool = numba.config.NUMBA_NUM_THREADS
    print(f"threads table, 320x240, median of {n} frames (numba pool {pool} threads):")
    print("  neighbour  threads  renderer ms  perception ms  load")
    for busy in (0, max(1, (os.cpu_count() or 2) - 1)):
        neighbours = _busy_neighbours(busy)
        try:
            time.sleep(0.5 if busy else 0.0)
            for threads in (1, 2):
                numba.set_num_threads(min(threads, pool))
                cv2.setNumThreads(threads)
                render_ms = _median_ms(lambda i: renderer.render(WORLD, *poses[i % n]), n)
                perceive_ms = _median_ms(
                    lambda i: perception.process(frames[i % n], *poses[i % n]), n
                )
                print(
                    f"  {'busy x' + str(busy) if busy else 'none':9s}  {threads:7d}  "
                    f"{render_ms:11.2f}  {perceive_ms:13.2f}  {os.getloadavg()[0]:4.1f}"
                )
        finally:
            for proc in neighbours:
                proc.kill()
                proc.wait()


def main(argv: list[str] | None = None) -> None:
    """Print the figures issue 3 asks for."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=40, help="distinct frames per test")
    parser.add_argument("--repeats", type=int, default=3, help="passes over the frames")
    parser.add_argument("--only-perception", action="store_true", help="timing ratios only")
    parser.add_argument("--stages", action="store_true", help="CPU time per stage")
    parser.add_argument(
        "--threads",
        action="store_true",
        help="only the threads table: 1 vs 2 threads, alone and beside a busy neighbour",
    )
    parser.add_argument(
        "--cv-threads",
        type=int,
        help="OpenCV threads (1: CPU times free of its thread pool's spinning, the ratio "
        "that holds under load; default: OpenCV's own choice)",
    )
    args = parser.parse_args(argv)
    if args.cv_threads is not None:
        cv2.setNumThreads(args.cv_threads)
    print(
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, "
        f"cv2 threads {cv2.getNumThreads()}, numba threads {numba.get_num_threads()}, "
        f"cpus {os.cpu_count()}"
    )
    if args.threads:
        bench_threads(args.frames)
        return
    if not args.only_perception:
        bench_renderer(args.frames * args.repeats)
    bench_perception(320, 240, args.frames, args.repeats, args.stages)
    bench_perception(640, 480, args.frames, args.repeats, args.stages)
    if not args.only_perception:
        bench_accuracy(args.frames)


if __name__ == "__main__":
    main()
