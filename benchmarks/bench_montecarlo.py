"""Monte Carlo throughput (issue 17): where a lockstep frame's time goes, and scenes/min.

Prints figures; asserts nothing. Run::

    .venv/bin/python benchmarks/bench_montecarlo.py [--scenes 20] [--jobs 2] [--seeds 2 13 18]

1. **Per-frame breakdown** of the §6 scene and of cluttered Monte Carlo scenes (several
   obstacles: many map pieces, boundary spheres and cones per frame), flown in this
   process with one numba and one OpenCV thread (as a Monte Carlo worker runs):
   exclusive time per stage — render,
   the stereo matcher (OpenCV's block matchers, both passes), the rest of the depth map
   (prefilter, merge, depth), the rest of perception, the known-space update, the map's
   boundary spheres, guidance (obstacle memory, collision cones, aiming-point planner,
   the rest), the envelope, the plant's physics, the history and the harness's own
   bookkeeping (everything else inside ``run_scene``) — in CPU time
   (``time.thread_time``: what the machine's load does not inflate) and wall time.
   Stages are measured by wrapping the named functions for the duration of the run.
   With ground-truth perception, "render" is the depth-only ray cast and "matcher" the
   conversion of the true depth to disparities.
2. **§6 lockstep wall time** (``stereo-avoid paper`` without the figures).
3. **Throughput**: ``--scenes`` Monte Carlo scenes on a local Dask cluster of ``--jobs``
   workers, scenes/min, with stereo and with ground-truth perception.

The machine is shared: the load average is printed beside the figures; CPU times are the
figures to compare between runs, wall times scale with the load.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import os
import time
from collections import defaultdict
from collections.abc import Callable, Iterator

# one BLAS thread, as in every process of this project (DESIGN.md performance budget)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2
import numba

import companion.pipeline
from companion.guidance import Guidance, avoidance
from companion.known_space import KnownSpace
from companion.perception import StereoPerception
from companion.stereo_bm import PaddedStereoBM
from evaluation import harness
from evaluation.harness import RunConfig, run_scene
from evaluation.montecarlo import run_config, scene_of
from evaluation.scenes import Scene, paper_scene
from evaluation.truth_perception import TruthDepthSource
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.vehicle import Quadrotor

STAGES = (
    "render",
    "matcher",
    "depth map (rest)",
    "perception (rest)",
    "known space",
    "map boundaries",
    "guidance: memory",
    "guidance: cones",
    "guidance: planner",
    "guidance (rest)",
    "envelope",
    "physics",
    "history",
    "harness bookkeeping",
)

#: Cluttered Monte Carlo seeds (3–4 obstacles: goal_near-2, climb-13, goal_near-18).
CLUTTERED_SEEDS = (2, 13, 18)


class StageClock:
    """Exclusive CPU and wall time per stage; a nested stage's time is not its parent's."""

    def __init__(self) -> None:
        self.cpu_s: dict[str, float] = defaultdict(float)
        self.wall_s: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._stack: list[list[float]] = []  # [cpu of children, wall of children]

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        cpu0, wall0 = time.thread_time(), time.perf_counter()
        self._stack.append([0.0, 0.0])
        try:
            yield
        finally:
            child_cpu, child_wall = self._stack.pop()
            cpu, wall = time.thread_time() - cpu0, time.perf_counter() - wall0
            self.cpu_s[name] += cpu - child_cpu
            self.wall_s[name] += wall - child_wall
            self.calls[name] += 1
            if self._stack:
                self._stack[-1][0] += cpu
                self._stack[-1][1] += wall

    def wrap(self, name: str, fn: Callable) -> Callable:
        @functools.wraps(fn)
        def timed(*args, **kwargs):
            with self.stage(name):
                return fn(*args, **kwargs)

        return timed


@contextlib.contextmanager
def instrumented(clock: StageClock) -> Iterator[None]:
    """Wrap the stages' functions (class and module attributes) while the block runs."""
    targets = [
        (StereoCameraRenderer, "render", "render"),
        (StereoCameraRenderer, "render_depth", "render"),  # ground truth: depth only
        (PaddedStereoBM, "disparity_fixed", "matcher"),
        (PaddedStereoBM, "coarse_pass_fixed", "matcher"),
        (TruthDepthSource, "disparity_fixed", "matcher"),  # ground truth: depth → disparity
        (TruthDepthSource, "compute", "depth map (rest)"),
        (PaddedStereoBM, "compute", "depth map (rest)"),  # prefilter, merge, depth
        (StereoPerception, "process", "perception (rest)"),
        (KnownSpace, "integrate", "known space"),
        (KnownSpace, "mark_vehicle", "known space"),
        (companion.pipeline, "map_boundaries", "map boundaries"),
        (avoidance, "update_memory", "guidance: memory"),
        (avoidance, "collision_cone", "guidance: cones"),  # before issue 17's speed work
        (avoidance, "_collision_cone", "guidance: cones"),
        (avoidance, "overlapping_cluster", "guidance: planner"),
        (avoidance, "choose_aiming_point", "guidance: planner"),
        (Guidance, "step", "guidance (rest)"),
        (companion.pipeline, "envelope_step", "envelope"),  # with its free-distance query
        (Quadrotor, "step", "physics"),
        (Quadrotor, "step_watching", "physics"),  # physics + per-step clearance and tilt
        (harness, "_record", "history"),
    ]
    saved = []
    for owner, attr, stage in targets:
        if not hasattr(owner, attr):  # renamed elsewhere: that stage falls into the rest
            continue
        original = getattr(owner, attr)
        saved.append((owner, attr, original))
        setattr(owner, attr, clock.wrap(stage, original))
    try:
        yield
    finally:
        for owner, attr, original in reversed(saved):
            setattr(owner, attr, original)


def profile_scenes(scenes: list[Scene], config: RunConfig) -> tuple[StageClock, int, float]:
    """Fly ``scenes`` under :func:`instrumented`; (clock, frames, simulated seconds)."""
    clock = StageClock()
    frames = 0
    sim_s = 0.0
    with instrumented(clock):
        for scene in scenes:
            with clock.stage("harness bookkeeping"):
                verdict = run_scene(scene, config, record_history=False).verdict
            frames += verdict.frames
            sim_s += verdict.sim_time_s
    return clock, frames, sim_s


def print_breakdown(title: str, clock: StageClock, frames: int, sim_s: float) -> None:
    total_cpu = sum(clock.cpu_s.values())
    total_wall = sum(clock.wall_s.values())
    print(f"\n{title}: {frames} frames, {sim_s:.0f} s simulated")
    print(f"  {'stage':22s} {'CPU ms/frame':>12s} {'share':>6s} {'wall ms/frame':>13s}")
    for name in STAGES:
        cpu, wall = clock.cpu_s.get(name, 0.0), clock.wall_s.get(name, 0.0)
        print(
            f"  {name:22s} {1e3 * cpu / frames:12.2f} {100 * cpu / total_cpu:5.1f}% "
            f"{1e3 * wall / frames:13.2f}"
        )
    print(
        f"  {'total':22s} {1e3 * total_cpu / frames:12.2f} {100.0:5.1f}% "
        f"{1e3 * total_wall / frames:13.2f}"
    )
    print(
        f"  real-time factor {sim_s / total_cpu:.1f}x per core (CPU), "
        f"{sim_s / total_wall:.1f}x (wall)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--seeds",
        type=int,
        nargs="*",
        default=list(CLUTTERED_SEEDS),
        help="Monte Carlo seeds to profile (default: cluttered ones)",
    )
    parser.add_argument(
        "--scenes", type=int, default=20, help="scenes for the throughput (0: skip it)"
    )
    parser.add_argument("--jobs", type=int, default=2, help="Monte Carlo workers")
    parser.add_argument(
        "--perception",
        choices=["stereo", "truth", "both"],
        default="both",
        help="which breakdowns to print",
    )
    args = parser.parse_args()
    numba.set_num_threads(1)
    cv2.setNumThreads(1)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")

    run_scene(paper_scene(), RunConfig(max_time_s=1.0))  # caches, imports
    clock, frames, sim_s = profile_scenes([paper_scene()], RunConfig())
    print_breakdown("§6 paper scene, stereo perception", clock, frames, sim_s)
    for perception in ("stereo", "truth") if args.perception == "both" else (args.perception,):
        if not args.seeds:
            break
        cfg = run_config(perception)
        run_scene(scene_of(0), dataclasses.replace(cfg, max_time_s=1.0))  # caches, imports
        scenes = [scene_of(seed) for seed in args.seeds]
        clock, frames, sim_s = profile_scenes(scenes, cfg)
        print_breakdown(f"{perception} perception, seeds {args.seeds}", clock, frames, sim_s)

    t0 = time.perf_counter()
    verdict = run_scene(paper_scene(), RunConfig()).verdict
    print(
        f"\n§6 lockstep: {time.perf_counter() - t0:.2f} s wall for {verdict.sim_time_s:.1f} s "
        f"simulated (goal reached: {verdict.reached_goal})"
    )

    if args.scenes < 1:
        return
    from evaluation.mc_cluster import dask_client, fly_on_cluster

    with dask_client(n_workers=args.jobs) as client:  # cluster start-up and warm-up excluded
        for perception in ("stereo", "truth"):
            done: list[dict] = []
            t0 = time.perf_counter()
            fly_on_cluster(
                client,
                range(2000, 2000 + args.scenes),
                family="mixed",
                perception=perception,
                on_record=done.append,
            )
            wall = time.perf_counter() - t0
            print(
                f"\nMonte Carlo, {perception}: {args.scenes} scenes on a local Dask cluster of "
                f"{args.jobs} workers in {wall:.1f} s: {60.0 * args.scenes / wall:.1f} "
                f"scenes/min (load average {os.getloadavg()[0]:.1f})"
            )


if __name__ == "__main__":
    main()
