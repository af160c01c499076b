"""Benchmark: perception under image degradations (issue 14's robustness table).

For each case (clean, sensor noise σ 10 and 20, right gain ×0.7, 2 px vertical
misrectification, horizontal and vertical motion blur, JPEG quality 30, a low-texture
sphere) and every matcher offered:

* the paper's sphere (r 1.5 m) with its nearest surface 3 m ahead, 20 frames (noise seed and
  a small attitude jitter per frame): in how many is it inside a reported boundary sphere;
* an empty scene (textured ground 2.2 m below, sky), 200 frames at random positions and
  headings: in how many is any obstacle reported.

Run with ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_degradations.py``.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from companion.perception import Matcher, PerceptionConfig, StereoPerception
from plant_sim.stereo_camera import RenderParams, StereoCameraRenderer
from plant_sim.world import GroundPlane, Material, Sphere, World
from protocols.camera import CameraModel
from protocols.frames import rotation_321
from protocols.stereo_frame import StereoFrame

__all__ = ["CASES", "empty_scene_false_frames", "main", "sphere_inside_frames"]

#: name → (render parameters, sphere material)
CASES: dict[str, tuple[RenderParams, Material]] = {
    "clean": (RenderParams(), Material.TEXTURED),
    "noise σ10": (RenderParams(noise_std=10.0), Material.TEXTURED),
    "noise σ20": (RenderParams(noise_std=20.0), Material.TEXTURED),
    "gain ×0.7": (RenderParams(gain_right=0.7), Material.TEXTURED),
    "misrect 2 px": (RenderParams(misrect_v_px=2.0), Material.TEXTURED),
    "blur h 4 px": (RenderParams(blur_h_px=4.0), Material.TEXTURED),
    "blur v 4 px": (RenderParams(blur_v_px=4.0), Material.TEXTURED),
    "JPEG 30": (RenderParams(jpeg_quality=30), Material.TEXTURED),
    "low-texture sphere": (RenderParams(), Material.LOW_TEXTURE),
}

_CAMERA = CameraModel()
_SURFACE_M = 3.0
_RADIUS_M = 1.5


def _contains(obstacle, sphere: Sphere) -> bool:
    gap = np.linalg.norm(obstacle.center_ned_m - np.asarray(sphere.center_ned_m))
    return bool(gap + sphere.radius_m <= obstacle.radius_m)


def sphere_inside_frames(
    perception: StereoPerception, params: RenderParams, material: Material, n: int = 20
) -> tuple[int, list[float]]:
    """Frames (of ``n``) whose reported boundary contains the sphere; nearest ranges [m]."""
    renderer = StereoCameraRenderer(_CAMERA, params)
    sphere = Sphere((10.0, 0.0, -7.0), _RADIUS_M, material=material)
    world = World(spheres=(sphere,), ground=GroundPlane(0.0))
    pos = np.array([10.0 - _RADIUS_M - _SURFACE_M, 0.0, -7.0])
    inside, nearest = 0, []
    for i in range(n):
        R = rotation_321(
            math.radians(2.0 * math.sin(i)), math.radians(1.5 * math.cos(0.7 * i)), 0.0
        )
        out = renderer.render(world, pos, R, noise_seed=i)
        result = perception.process(
            StereoFrame(i, i, _CAMERA.intrinsics, out.left, out.right), pos, R
        )
        inside += any(_contains(o, sphere) for o in result.obstacles)
        nearest.append(min((o.nearest_range_m for o in result.obstacles), default=math.nan))
    return inside, nearest


def empty_scene_false_frames(
    perception: StereoPerception, params: RenderParams, n: int = 200, seed: int = 11
) -> int:
    """Frames (of ``n``) of ground and sky in which any obstacle is reported."""
    renderer = StereoCameraRenderer(_CAMERA, params)
    world = World(ground=GroundPlane(0.0))
    rng = np.random.default_rng(seed)
    false = 0
    for i in range(n):
        R = rotation_321(
            *np.radians([rng.uniform(-5, 5), rng.uniform(-3, 3), rng.uniform(-180, 180)])
        )
        pos = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), -2.2])
        out = renderer.render(world, pos, R, noise_seed=i)
        result = perception.process(
            StereoFrame(i, i, _CAMERA.intrinsics, out.left, out.right), pos, R
        )
        false += bool(result.obstacles)
    return false


def main(argv: list[str] | None = None) -> None:
    """Print the degradation table for every matcher offered."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=20, help="sphere frames per case")
    parser.add_argument("--empty", type=int, default=200, help="empty-scene frames per case")
    parser.add_argument("--case", action="append", help="only these cases (repeatable)")
    args = parser.parse_args(argv)
    cases = {k: v for k, v in CASES.items() if not args.case or k in args.case}
    print(
        f"sphere r {_RADIUS_M} m, nearest surface {_SURFACE_M} m: inside boundary / "
        f"{args.frames} frames (median nearest range); empty scene: frames with a false "
        f"obstacle / {args.empty}"
    )
    for matcher in Matcher:
        perception = StereoPerception(PerceptionConfig(matcher=matcher))
        print(f"matcher {matcher.value}")
        for name, (params, material) in cases.items():
            inside, nearest = sphere_inside_frames(perception, params, material, args.frames)
            false = empty_scene_false_frames(perception, params, args.empty)
            seen = [r for r in nearest if math.isfinite(r)]
            median_m = float(np.median(seen)) if seen else math.nan
            print(
                f"  {name:20s} inside {inside:3d}/{args.frames} (nearest {median_m:5.2f} m)"
                f"   false {false:3d}/{args.empty}",
                flush=True,
            )


if __name__ == "__main__":
    main()
