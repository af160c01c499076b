"""Benchmark: the known-space path search's cost per frame in lockstep passage flights.

Flies passage scenes (:mod:`evaluation.passage_scenes`: the fixed 3 m gap and corridor,
and seeded ones) in the lockstep harness and times every call guidance makes to the
pipeline's known-space path (``Pipeline._known_path``: a search, or the last path reused)
and every search itself (``plan_known_path``), in thread CPU time, so other processes on a
shared machine do not count (the wall time per call is printed too: on a loaded machine
it is what the frame waits). Prints, per scene and over all: calls, searches, the mean,
p95 and max per call and per search [ms], the expansions per search, and the outcome.
Run with ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_guidance_path.py``
(``--perception truth`` for ground-truth depth, faster; ``--max-time-s`` to shorten).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import companion.pipeline as pipeline_module
from evaluation.harness import run_scene
from evaluation.mc_scene import run_config, single_threaded
from evaluation.passage_scenes import corridor_scene, gap_scene, passage_scene

__all__ = ["main"]

_SCENES = ("gap", "corridor", "corridor:9", "corridor:5", "gap:0")


def _scene(name: str):
    if name == "gap":
        return gap_scene()
    if name == "corridor":
        return corridor_scene()
    family, seed = name.split(":")
    return passage_scene(int(seed), family)


def _stats(values: list[float]) -> str:
    if not values:
        return "none"
    v = np.asarray(values)
    return f"mean {v.mean():.2f}  p95 {np.percentile(v, 95):.2f}  max {v.max():.2f}"


def main(argv: list[str] | None = None) -> int:
    """Print the path search's cost per frame and per search [ms, thread CPU time]."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--scenes", nargs="*", default=list(_SCENES), help="gap, corridor, FAMILY:SEED"
    )
    parser.add_argument("--perception", choices=("stereo", "truth"), default="stereo")
    parser.add_argument("--max-time-s", type=float, default=60.0)
    args = parser.parse_args(argv)
    single_threaded()
    searches: list[tuple[float, int]] = []
    calls: list[float] = []
    walls: list[float] = []
    plan = pipeline_module.plan_known_path
    ask = pipeline_module.AvoidancePipeline._known_path

    def timed_plan(*a, **kw):
        t0 = time.thread_time()
        path = plan(*a, **kw)
        searches.append(((time.thread_time() - t0) * 1e3, 0 if path is None else path.expanded))
        return path

    def timed_ask(self, *a, **kw):
        t0, w0 = time.thread_time(), time.perf_counter()
        path = ask(self, *a, **kw)
        calls.append((time.thread_time() - t0) * 1e3)
        walls.append((time.perf_counter() - w0) * 1e3)
        return path

    pipeline_module.plan_known_path = timed_plan
    pipeline_module.AvoidancePipeline._known_path = timed_ask
    all_calls: list[float] = []
    all_searches: list[float] = []
    print(f"known-space path per frame, {args.perception} perception [ms, thread CPU time]")
    try:
        for name in args.scenes:
            calls.clear()
            walls.clear()
            searches.clear()
            cfg = run_config(args.perception, args.max_time_s)
            verdict = run_scene(_scene(name), cfg, record_history=False).verdict
            ms = [s[0] for s in searches]
            expanded = [s[1] for s in searches]
            print(
                f"{name:>12}: {verdict.outcome} at {verdict.sim_time_s:.1f} s, "
                f"{verdict.frames} frames; {len(calls)} calls ({_stats(calls)}); "
                f"{len(ms)} searches ({_stats(ms)}; expansions max "
                f"{max(expanded, default=0)}); wall per call: {_stats(walls)}"
            )
            all_calls += calls
            all_searches += ms
    finally:
        pipeline_module.plan_known_path = plan
        pipeline_module.AvoidancePipeline._known_path = ask
    print(
        f"{'all':>12}: {len(all_calls)} calls ({_stats(all_calls)}); "
        f"{len(all_searches)} searches ({_stats(all_searches)})"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
