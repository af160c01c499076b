"""Compile every numba kernel into numba's cache before the first flight (``stereo-avoid
compile``; ``scripts/setup.sh`` runs it).

On a fresh install the kernels are compiled at their first call: ~70 s of CPU, most of it
the stereo renderer, paid by whichever process starts first (plant-sim's first frame, a
Monte Carlo worker, the first test). Compiled once here, every process loads them from
the cache (``__pycache__`` beside the sources, or ``$NUMBA_CACHE_DIR``) in a few seconds.
The renderer and the companion's kernels compile in two processes at once; the rest (the
plant's dynamics and control, ground-truth depth) follows in this one, by flying a
fraction of a second of a scene with each perception, and plant-sim's vehicle loop.
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor

__all__ = ["compile_kernels"]


def _renderer() -> None:
    """The stereo renderer, on a frame with every kind of shape and material, and the
    depth camera's noise model on its depth."""
    import numpy as np

    from plant_sim.depth_camera import DepthNoiseParams, depth16_from_truth
    from plant_sim.stereo_camera import StereoCameraRenderer
    from plant_sim.world import Box, Cylinder, Material, Sphere, World
    from protocols.camera import CameraModel

    materials = tuple(Material)
    world = World(
        spheres=(Sphere((8.0, -2.0, -1.0), 1.0),),
        boxes=tuple(Box((8.0, 0.0, -1.0), (0.5, 1.0, 2.0), 1, m) for m in materials),
        cylinders=(Cylinder((8.0, 2.0, -1.0), 0.3, 2.0),),
    )
    camera = CameraModel()
    out = StereoCameraRenderer(camera).render(world, np.zeros(3), np.eye(3), noise_seed=0)
    depth16_from_truth(out.depth_left_m, camera.intrinsics, DepthNoiseParams(), 0)


def _companion() -> None:
    """The companion's perception, known-space and proximity kernels (their own warm-ups)."""
    from companion.known_space import KnownSpace
    from companion.perception import StereoPerception
    from companion.proximity.stream import warm_up as warm_up_proximity

    StereoPerception()
    KnownSpace()
    warm_up_proximity()


def _plant() -> None:
    """The vehicle stepped as plant-sim steps it (the lockstep harness steps it watching)."""
    from plant_sim.vehicle import Quadrotor

    Quadrotor().step(2)


def _timed(step: Callable[[], None]) -> float:
    start = time.monotonic()
    step()
    return time.monotonic() - start


def compile_kernels(jobs: int = 2, log: Callable[[str], None] = print) -> float:
    """Compile (or load from the cache) every kernel; return the wall time [s].

    ``jobs`` > 1 compiles the renderer and the companion's kernels in separate processes at
    once. ``log`` receives a line per step.
    """
    from evaluation.mc_scene import warm_up

    start = time.monotonic()
    steps = {"stereo renderer": _renderer, "companion perception and known space": _companion}
    if jobs > 1:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=min(jobs, 2), mp_context=context) as pool:
            futures = {name: pool.submit(_timed, step) for name, step in steps.items()}
            for name, future in futures.items():
                log(f"compile: {name}: {future.result():.1f} s")
    else:
        for name, step in steps.items():
            log(f"compile: {name}: {_timed(step):.1f} s")
    log(f"compile: dynamics, control and the lockstep harness: {_timed(warm_up):.1f} s")
    log(f"compile: plant-sim's vehicle loop: {_timed(_plant):.1f} s")
    total = time.monotonic() - start
    log(f"compile: every kernel is in numba's cache ({total:.1f} s)")
    return total
