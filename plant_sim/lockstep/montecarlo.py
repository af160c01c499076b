"""Monte Carlo over random scenes: each seed flown in lockstep, on all cores."""

from __future__ import annotations

import multiprocessing
import os
from collections import Counter
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

import numpy as np

from plant_sim.lockstep.harness import RunConfig, Verdict, run_scene
from plant_sim.lockstep.scenes import FAMILIES, family_scene, mixed_scene

__all__ = ["fly_seed", "run_batch", "scene_of", "summarize"]


def scene_of(seed: int, family: str = "mixed"):
    """The scene Monte Carlo flies for ``seed``: ``family`` ("mixed": by seed, see
    :func:`~plant_sim.lockstep.scenes.mixed_scene`)."""
    return mixed_scene(seed) if family == "mixed" else family_scene(seed, family)


def fly_seed(seed: int, family: str = "mixed") -> Verdict:
    """Fly the random scene of ``seed`` (in ``family``) with the default configuration."""
    return run_scene(scene_of(seed, family), RunConfig()).verdict


def _init_worker() -> None:
    # one BLAS/OpenCV/numba thread per worker: the pool already uses every core
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    import cv2
    import numba

    cv2.setNumThreads(1)
    numba.set_num_threads(1)


def run_batch(
    seeds: Iterable[int],
    *,
    jobs: int = 1,
    progress: Callable[[int, int, Verdict], None] | None = None,
    family: str = "mixed",
) -> list[Verdict]:
    """Fly every seed; verdicts in seed order. ``jobs`` > 1 uses worker processes."""
    if family != "mixed" and family not in FAMILIES:
        raise ValueError(f"unknown scene family {family!r}; valid: mixed, {list(FAMILIES)}")
    seeds = list(seeds)
    verdicts: dict[int, Verdict] = {}
    if jobs <= 1:
        for seed in seeds:
            verdicts[seed] = fly_seed(seed, family)
            if progress is not None:
                progress(len(verdicts), len(seeds), verdicts[seed])
    else:
        # spawn, not fork: a forked child inherits whatever locks the parent's other
        # threads hold at that instant (Zenoh, numba, OpenCV, pytest plugins); in a full
        # test run two forked workers hung forever at 0 % CPU
        spawn = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(
            max_workers=jobs, mp_context=spawn, initializer=_init_worker
        ) as pool:
            futures = {pool.submit(fly_seed, seed, family): seed for seed in seeds}
            for future in as_completed(futures):
                verdict = future.result()
                verdicts[futures[future]] = verdict
                if progress is not None:
                    progress(len(verdicts), len(seeds), verdict)
    return [verdicts[s] for s in seeds]


def summarize(verdicts: list[Verdict]) -> dict[str, Any]:
    """Rates, the minimum-separation distribution, time in avoidance, failures by cause."""
    n = len(verdicts)
    sep = np.array([v.min_surface_distance_m for v in verdicts])
    avoid = np.array([v.avoidance_time_s for v in verdicts])
    causes = Counter(v.failure or "goal not reached" for v in verdicts if not v.passed)
    # a safe outcome: the goal, or a stop reported by guidance (HOLD), without a collision
    safe = [v.passed or (v.failure == "hold" and not v.collided) for v in verdicts]
    by_family: dict[str, dict[str, int]] = {}
    for v, ok in zip(verdicts, safe, strict=True):
        fam = by_family.setdefault(v.scene.rsplit("-", 1)[0], {"runs": 0, "safe": 0})
        fam["runs"] += 1
        fam["safe"] += int(ok)
    return {
        "runs": n,
        "goal_reached_rate": sum(v.reached_goal for v in verdicts) / n,
        "safe_outcome_rate": sum(safe) / n,
        "by_family": by_family,
        "collision_rate": sum(v.collided for v in verdicts) / n,
        "min_separation_m": {
            "min": float(sep.min()),
            "p5": float(np.percentile(sep, 5)),
            "median": float(np.median(sep)),
            "max": float(sep.max()),
        },
        "avoidance_time_s": {"mean": float(avoid.mean()), "max": float(avoid.max())},
        "failures_by_cause": dict(causes),
        "failed_seeds": [v.seed for v in verdicts if not v.passed],
        "verdicts": [v.__dict__ for v in verdicts],
    }
