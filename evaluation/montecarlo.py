"""Monte Carlo over random scenes: each seed flown in lockstep, as a task on a Dask cluster.

Each seed is flown by :mod:`evaluation.mc_scene` (the same verdict wherever it flies).
Batches run on a local Dask cluster or a remote one (:mod:`evaluation.mc_cluster`), stream
their verdicts to a JSONL file as they finish (:mod:`evaluation.mc_results`) and
end with a report (:mod:`evaluation.mc_report`).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from evaluation.harness import Verdict
from evaluation.mc_scene import (
    error_verdict,
    fly_record,
    fly_seed,
    run_config,
    scene_of,
    single_threaded,
)
from evaluation.passage_scenes import PASSAGE_FAMILIES
from evaluation.scenes import FAMILIES

#: every ``family`` a batch takes: the mixes, then the single families
ALL_FAMILIES: tuple[str, ...] = ("mixed", "passages", *FAMILIES, *PASSAGE_FAMILIES)

__all__ = [
    "ALL_FAMILIES",
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
    many single-threaded worker processes (:mod:`~evaluation.mc_cluster`)."""
    if family not in ALL_FAMILIES:
        raise ValueError(f"unknown scene family {family!r}; valid: {list(ALL_FAMILIES)}")
    run_config(perception, max_time_s)  # validates
    seeds = list(seeds)
    verdicts: dict[int, Verdict] = {}
    if jobs <= 1:
        for seed in seeds:
            verdicts[seed] = fly_seed(seed, family, perception, max_time_s)
            if progress is not None:
                progress(len(verdicts), len(seeds), verdicts[seed])
    else:
        from evaluation.mc_cluster import dask_client, fly_on_cluster
        from evaluation.mc_results import verdict_from_record

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
