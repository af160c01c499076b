"""Monte Carlo over random scenes: each seed flown in lockstep, as a task on a Dask cluster.

A seed is a pure function of ``(seed, family, perception)``: the same verdict in this
process, on any worker of any cluster, and in ``stereo-avoid replay SEED`` (every one of
them flies it with one numba and one OpenCV thread, :func:`single_threaded`). Batches run
on a local Dask cluster or a remote one (:mod:`plant_sim.lockstep.mc_cluster`), stream
their verdicts to a JSONL file as they finish (:mod:`plant_sim.lockstep.mc_results`) and
end with a report (:mod:`plant_sim.lockstep.mc_report`).
"""

from __future__ import annotations

import math
import os
import socket
import time
from collections import Counter
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from companion.depth_camera import DepthCameraConfig
from companion.perception import PerceptionConfig
from plant_sim.depth_camera import CameraEncoding, DepthNoiseParams
from plant_sim.lockstep.harness import RunConfig, Verdict, run_scene
from plant_sim.lockstep.mc_provenance import code_fingerprint
from plant_sim.lockstep.mc_results import PERCEPTIONS, verdict_to_record
from plant_sim.lockstep.scenes import FAMILIES, family_scene, mixed_scene

__all__ = [
    "error_verdict",
    "fly_record",
    "fly_seed",
    "is_safe",
    "run_batch",
    "run_config",
    "scene_of",
    "single_threaded",
    "summarize",
]


def scene_of(seed: int, family: str = "mixed"):
    """The scene Monte Carlo flies for ``seed``: ``family`` ("mixed": by seed, see
    :func:`~plant_sim.lockstep.scenes.mixed_scene`)."""
    return mixed_scene(seed) if family == "mixed" else family_scene(seed, family)


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
    (:func:`~plant_sim.lockstep.mc_provenance.code_fingerprint`, computed where it flew). A
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


def run_batch(
    seeds: Iterable[int],
    *,
    jobs: int = 1,
    progress: Callable[[int, int, Verdict], None] | None = None,
    family: str = "mixed",
    perception: str = "stereo",
    max_time_s: float | None = None,
) -> list[Verdict]:
    """Fly every seed; verdicts in seed order. ``jobs`` > 1: a local Dask cluster of that
    many single-threaded worker processes (:mod:`~plant_sim.lockstep.mc_cluster`)."""
    if family != "mixed" and family not in FAMILIES:
        raise ValueError(f"unknown scene family {family!r}; valid: mixed, {list(FAMILIES)}")
    run_config(perception, max_time_s)  # validates
    seeds = list(seeds)
    verdicts: dict[int, Verdict] = {}
    if jobs <= 1:
        for seed in seeds:
            verdicts[seed] = fly_seed(seed, family, perception, max_time_s)
            if progress is not None:
                progress(len(verdicts), len(seeds), verdicts[seed])
    else:
        from plant_sim.lockstep.mc_cluster import dask_client, fly_on_cluster
        from plant_sim.lockstep.mc_results import verdict_from_record

        def collect(record: dict[str, Any]) -> None:
            verdict = verdict_from_record(record)
            verdicts[verdict.seed] = verdict
            if progress is not None:
                progress(len(verdicts), len(seeds), verdict)

        with dask_client(n_workers=jobs) as client:
            fly_on_cluster(
                client,
                seeds,
                family=family,
                perception=perception,
                max_time_s=max_time_s,
                on_record=collect,
            )
    return [verdicts[s] for s in seeds]


def is_safe(verdict: Verdict) -> bool:
    """A safe outcome: the goal, or a stop reported by guidance (HOLD), without a collision."""
    return verdict.passed or verdict.safe_stop


def summarize(verdicts: list[Verdict]) -> dict[str, Any]:
    """Rates, the minimum-separation distribution, time in avoidance, failures by cause."""
    n = len(verdicts)
    if n == 0:
        raise ValueError("summarize: no verdicts")
    sep = np.array([v.min_surface_distance_m for v in verdicts], dtype=float)
    sep = sep[np.isfinite(sep)]
    avoid = np.array([v.avoidance_time_s for v in verdicts])
    causes = Counter(v.failure or "goal not reached" for v in verdicts if not v.passed)
    safe = [is_safe(v) for v in verdicts]
    by_family: dict[str, dict[str, int]] = {}
    for v, ok in zip(verdicts, safe, strict=True):
        fam = by_family.setdefault(v.scene.rsplit("-", 1)[0], {"runs": 0, "safe": 0})
        fam["runs"] += 1
        fam["safe"] += int(ok)
    sep_stats = (
        {
            "min": float(sep.min()),
            "p5": float(np.percentile(sep, 5)),
            "median": float(np.median(sep)),
            "max": float(sep.max()),
        }
        if sep.size
        else {"min": math.nan, "p5": math.nan, "median": math.nan, "max": math.nan}
    )
    return {
        "runs": n,
        "goal_reached": sum(v.reached_goal and not v.collided for v in verdicts),
        "safe_stops": sum(v.failure == "hold" and not v.collided for v in verdicts),
        "collisions": sum(v.collided for v in verdicts),
        "goal_reached_rate": sum(v.reached_goal for v in verdicts) / n,
        "safe_outcome_rate": sum(safe) / n,
        "by_family": by_family,
        "collision_rate": sum(v.collided for v in verdicts) / n,
        "min_separation_m": sep_stats,
        "avoidance_time_s": {"mean": float(avoid.mean()), "max": float(avoid.max())},
        "failures_by_cause": dict(causes),
        "failed_seeds": [v.seed for v in verdicts if not v.passed],
        "unsafe_seeds": [v.seed for v, ok in zip(verdicts, safe, strict=True) if not ok],
        "collision_seeds": [v.seed for v in verdicts if v.collided],
        "verdicts": [v.__dict__ for v in verdicts],
    }
