"""Per-frame companion CPU with depth frames vs stereo pairs (issue 35), at 320×240 and 640×480.

The companion's per-frame work, in process and on one thread: decode the payload
(:mod:`protocols.stereo_frame`), then :class:`~companion.pipeline.AvoidancePipeline` —
perception (the matcher for a pair; the depth-camera source for a depth frame), the
known-space update, map boundaries, guidance and the envelope. Frames are the paper's
approach (vehicle 15 → 12.5 m north at 7 m altitude facing the obstacle), rendered once:
the stereo pair as plant-sim's camera renders it, the depth frame as plant-sim's
RealSense-like depth camera makes it from the same view (DEPTH16 with its noise, the left
picture beside it). CPU is the thread's CPU time (``time.thread_time_ns``), so other load
on the machine inflates it less than wall time; the median and 90th percentile per frame
are printed, and the ratio depth / stereo of the medians; and what plant-sim's depth
camera model (noise, holes, DEPTH16) costs per frame on top of the render.

Usage: ``.venv/bin/python benchmarks/bench_depth_camera.py [--frames 60] [--json]``
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from companion.depth_camera import DepthCameraConfig  # noqa: E402
from companion.perception import PerceptionConfig  # noqa: E402
from companion.pipeline import AvoidancePipeline, PoseAtCapture  # noqa: E402
from plant_sim.depth_camera import DepthNoiseParams, depth_frame  # noqa: E402
from plant_sim.stereo_camera import StereoCameraRenderer  # noqa: E402
from plant_sim.world import paper_world  # noqa: E402
from protocols.camera import CameraModel  # noqa: E402
from protocols.frames import rotation_321  # noqa: E402
from protocols.stereo_frame import StereoFrame, decode, encode  # noqa: E402

YAW = np.pi  # facing south, towards the obstacle at north 10 m


def _payloads(width: int, height: int, n: int) -> tuple[list, list, list]:
    """(stereo payloads, depth payloads, poses) of ``n`` views along the approach."""
    model = CameraModel(width_px=width, height_px=height)
    renderer = StereoCameraRenderer(model)
    R = rotation_321(0.0, 0.0, YAW)
    stereo, depth, poses = [], [], []
    for i in range(n):
        pos = np.array([15.0 - 2.5 * i / max(1, n - 1), 0.0, -7.0])
        out = renderer.render(paper_world(), pos, R, noise_seed=i)
        capture_ns = i * 33_333_333
        stereo.append(encode(StereoFrame(i, capture_ns, model.intrinsics, out.left, out.right)))
        frame = depth_frame(
            i, capture_ns, model.intrinsics, out.depth_left_m, out.left, DepthNoiseParams()
        )
        depth.append(encode(frame))
        poses.append(PoseAtCapture(pos, np.array([-1.0, 0.0, 0.0]), R))
    return stereo, depth, poses


def _noise_model_ms(width: int, height: int, n: int = 20) -> float:
    """Median thread CPU [ms] of plant-sim's depth camera model (noise, holes, DEPTH16)
    on one rendered view: what a depth frame adds to plant-sim's camera per frame."""
    model = CameraModel(width_px=width, height_px=height)
    out = StereoCameraRenderer(model).render(
        paper_world(), np.array([14.0, 0.0, -7.0]), rotation_321(0.0, 0.0, YAW)
    )
    times = []
    for i in range(n + 1):
        t0 = time.thread_time_ns()
        depth_frame(i, 0, model.intrinsics, out.depth_left_m, out.left, DepthNoiseParams())
        times.append((time.thread_time_ns() - t0) / 1e6)
    return float(np.median(times[1:]))


def _cpu_per_frame_ms(payloads: list, poses: list, warmup: int = 3) -> np.ndarray:
    """Thread CPU time [ms] of decode + pipeline per frame (after ``warmup`` frames)."""
    pipeline = AvoidancePipeline(
        (0.0, 0.0, -7.0),
        PerceptionConfig(depth_camera=DepthCameraConfig(min_range_m=1.0)),
    )
    times = []
    for i, (payload, pose) in enumerate(zip(payloads, poses, strict=True)):
        t0 = time.thread_time_ns()
        pipeline.process(decode(payload), pose)
        if i >= warmup:
            times.append((time.thread_time_ns() - t0) / 1e6)
    return np.array(times)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    import cv2

    cv2.setNumThreads(1)
    rows = []
    for width, height in ((320, 240), (640, 480)):
        stereo, depth, poses = _payloads(width, height, args.frames)
        row = {"size": f"{width}x{height}", "frames": args.frames - 3}
        for name, payloads in (("stereo", stereo), ("depth16", depth)):
            ms = _cpu_per_frame_ms(payloads, poses)
            row[f"{name}_p50_ms"] = round(float(np.median(ms)), 2)
            row[f"{name}_p90_ms"] = round(float(np.percentile(ms, 90)), 2)
        row["depth_over_stereo"] = round(row["depth16_p50_ms"] / row["stereo_p50_ms"], 3)
        row["plant_noise_model_ms"] = round(_noise_model_ms(width, height), 2)
        rows.append(row)
        if not args.json:
            print(
                f"{row['size']}: stereo pair {row['stereo_p50_ms']} ms (p90 "
                f"{row['stereo_p90_ms']}), depth frame {row['depth16_p50_ms']} ms (p90 "
                f"{row['depth16_p90_ms']}) per frame of companion CPU; depth / stereo = "
                f"{row['depth_over_stereo']}; plant-sim's depth camera model "
                f"{row['plant_noise_model_ms']} ms per frame"
            )
    if args.json:
        print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
