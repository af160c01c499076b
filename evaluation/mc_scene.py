"""One Monte Carlo scene: the scene of a seed, the configuration it flies with, and its verdict.

A seed is a pure function of ``(seed, family, perception)``: the same verdict in this
process, on any worker of any cluster, and in ``stereo-avoid replay SEED`` (every one of
them flies it with one numba and one OpenCV thread, :func:`single_threaded`). The batch
(:mod:`evaluation.montecarlo`) and the cluster (:mod:`evaluation.mc_cluster`) both fly
seeds through here.
"""

from __future__ import annotations

import math
import os
import socket
import time
from typing import Any

from companion.depth_camera import DepthCameraConfig
from companion.perception import PerceptionConfig
from evaluation.harness import RunConfig, Verdict, run_scene
from evaluation.mc_provenance import code_fingerprint
from evaluation.mc_results import PERCEPTIONS, verdict_to_record
from evaluation.passage_scenes import PASSAGE_FAMILIES, passage_scene, passages_scene
from evaluation.scenes import family_scene, mixed_scene
from plant_sim.depth_camera import CameraEncoding, DepthNoiseParams

__all__ = [
    "error_verdict",
    "fly_record",
    "fly_seed",
    "run_config",
    "scene_of",
    "single_threaded",
    "warm_up",
]


def scene_of(seed: int, family: str = "mixed"):
    """The scene Monte Carlo flies for ``seed``: ``family`` ("mixed": by seed, see
    :func:`~evaluation.scenes.mixed_scene`; "passages" and the passage families of
    :mod:`evaluation.passage_scenes`)."""
    if family == "mixed":
        return mixed_scene(seed)
    if family == "passages":
        return passages_scene(seed)
    if family in PASSAGE_FAMILIES:
        return passage_scene(seed, family)
    return family_scene(seed, family)


def run_config(perception: str = "stereo", max_time_s: float | None = None) -> RunConfig:
    """The configuration Monte Carlo flies with: the defaults, ``perception`` "stereo" (the
    companion's matcher), "truth" (the renderer's exact depth) or "depth" (a RealSense-like
    depth camera with its noise, plant_sim.depth_camera; the companion is told its minimum
    range), and ``max_time_s`` if given (a shorter horizon for smoke runs; default
    :class:`RunConfig`'s)."""
    if perception not in PERCEPTIONS:
        raise ValueError(f"perception must be one of {PERCEPTIONS}, got {perception!r}")
    kw: dict[str, Any] = {"truth_perception": perception == "truth"}
    if perception == "depth":
        noise = DepthNoiseParams()
        kw["camera_encoding"] = CameraEncoding.DEPTH16
        kw["depth_noise"] = noise
        kw["perception"] = PerceptionConfig(
            depth_camera=DepthCameraConfig(min_range_m=noise.min_range_m)
        )
    if max_time_s is not None:
        kw["max_time_s"] = max_time_s
    return RunConfig(**kw)


def single_threaded() -> None:
    """One BLAS, OpenCV and numba thread in this process (thread) — how every Monte Carlo
    scene is flown: workers already fill the cores, and one thread count for all makes a
    seed's verdict independent of where it runs."""
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    import cv2
    import numba

    cv2.setNumThreads(1)
    numba.set_num_threads(1)  # per calling thread in numba: call it in the task's thread


def warm_up() -> None:
    """Fly a fraction of a second of a scene with each perception in this process: imports,
    numba's compiled kernels (from its cache) and OpenCV's matchers are ready afterwards
    (``stereo-avoid compile``; each Monte Carlo worker as it joins)."""
    single_threaded()
    for truth in (False, True):
        run_scene(scene_of(0), RunConfig(max_time_s=0.1, truth_perception=truth))


def fly_seed(
    seed: int, family: str = "mixed", perception: str = "stereo", max_time_s: float | None = None
) -> Verdict:
    """Fly the random scene of ``seed`` (in ``family``) with :func:`run_config`."""
    single_threaded()
    cfg = run_config(perception, max_time_s)
    return run_scene(scene_of(seed, family), cfg, record_history=False).verdict


def fly_record(
    seed: int, family: str = "mixed", perception: str = "stereo", max_time_s: float | None = None
) -> dict[str, Any]:
    """:func:`fly_seed` as a results record (a Dask task): the verdict, the perception, the
    worker (host:pid) and the fingerprint of the code that flew it
    (:func:`~evaluation.mc_provenance.code_fingerprint`, computed where it flew). A
    scene that raises is an ``"error"`` verdict, not a lost task."""
    wall_start = time.perf_counter()
    try:
        verdict = fly_seed(seed, family, perception, max_time_s)
    except Exception as exc:  # one broken scene must not end a 100k batch: it is reported
        message = f"{type(exc).__name__}: {exc}"
        verdict = error_verdict(seed, message, time.perf_counter() - wall_start)
    return verdict_to_record(
        verdict,
        perception=perception,
        worker=f"{socket.gethostname()}:{os.getpid()}",
        code=code_fingerprint(),
    )


def error_verdict(seed: int, message: str, wall_time_s: float = 0.0) -> Verdict:
    """The verdict of a seed that could not be flown (an exception, a lost worker)."""
    return Verdict(
        scene=f"seed-{seed}",
        seed=seed,
        reached_goal=False,
        collided=False,
        min_surface_distance_m=math.nan,
        max_roll_cmd_deg=math.nan,
        max_pitch_cmd_deg=math.nan,
        avoidance_time_s=0.0,
        sim_time_s=0.0,
        wall_time_s=round(wall_time_s, 3),
        final_goal_distance_m=math.nan,
        frames=0,
        failure="error",
        hold_reason=message,
    )
