"""``stereo-avoid``: lockstep runs of the paper's §6 scenario and Monte Carlo batches.

Subcommands
-----------
``stereo-avoid paper [--out DIR] [--json]``
    Fly §6 (start (20, 0, −7), goal (0, 0, −7), obstacle (10, 0, −7) r 1.5 m), print
    progress and a verdict, write Fig. 6–11 as PNG and the time history as CSV.
``stereo-avoid montecarlo --n N --seed S [--jobs J] [--family F] [--json]``
    N random scenes (seeds S … S+N−1) on J processes; a summary table or JSON, with the
    seed of every failure so it can be replayed with ``stereo-avoid replay SEED``.
    Families (``plant_sim.lockstep.scenes``): path, climb, goal_near, facing_away, or
    mixed (the default: the family of seed s is the (s mod 4)-th).
``stereo-avoid replay SEED [--family F] [--out DIR] [--json]``
    One random scene, with figures, exactly as Monte Carlo flew it.
``stereo-avoid sil [--scenario FILE] [--speedup N] [--out DIR] [--json]``
    plant-sim and the companion as two processes over MAVLink and Zenoh on loopback;
    the same verdict and figures, from plant-sim's ground-truth log.
``stereo-avoid sil --autopilot arducopter-sitl [--autopilot-params FILE] [--speedup K]``
    the paper's scene (north from home at 7 m) on ArduPilot's ArduCopter SITL, taken off
    by the companion, plant-sim as the camera only (:mod:`plant_sim.lockstep.sitl`).

Exit status: 0 when every run reached its goal without collision, 1 otherwise, 2 on a
usage error.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from plant_sim.lockstep.harness import RunConfig, RunResult, run_scene
from plant_sim.lockstep.montecarlo import run_batch, scene_of, summarize
from plant_sim.lockstep.report import write_run_report
from plant_sim.lockstep.scenes import FAMILIES, Scene, paper_scene

__all__ = ["main"]


def _progress(stream):
    def report(sim_time_s: float, goal_distance_m: float) -> None:
        print(f"  t={sim_time_s:5.1f} s  distance to goal {goal_distance_m:5.2f} m", file=stream)
        stream.flush()

    return report


def _fly_and_report(scene: Scene, out_dir: Path, as_json: bool) -> int:
    cfg = RunConfig()
    log = sys.stderr if as_json else sys.stdout
    print(f"flying scene '{scene.name}' in lockstep (simulation time)", file=log)
    result: RunResult = run_scene(scene, cfg, progress=_progress(log))
    return write_run_report(
        result.verdict,
        result.history,
        world=scene.world,
        goal_ned_m=scene.goal_ned_m,
        out_dir=out_dir,
        vehicle=cfg.vehicle,
        control=cfg.control,
        detect_threshold_m=cfg.perception.threshold_m,
        as_json=as_json,
        stdout=sys.stdout,
    )


def _montecarlo(args: argparse.Namespace) -> int:
    log = sys.stderr if args.json else sys.stdout

    def progress(done: int, total: int, verdict) -> None:
        status = "ok" if verdict.passed else f"FAIL ({verdict.failure or 'goal not reached'})"
        print(f"  [{done:4d}/{total}] seed {verdict.seed:6d} {status}", file=log)
        log.flush()

    verdicts = run_batch(
        range(args.seed, args.seed + args.n), jobs=args.jobs, progress=progress, family=args.family
    )
    summary = summarize(verdicts)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"runs                 {summary['runs']}")
        print(f"goal reached rate    {summary['goal_reached_rate']:.3f}")
        print(f"safe outcome rate    {summary['safe_outcome_rate']:.3f} (goal or reported hold)")
        fams = "  ".join(f"{k} {v['safe']}/{v['runs']}" for k, v in summary["by_family"].items())
        print(f"safe by family       {fams}")
        print(f"collision rate       {summary['collision_rate']:.3f}")
        sep = summary["min_separation_m"]
        print(
            "min separation [m]   "
            f"min {sep['min']:.2f}  p5 {sep['p5']:.2f}  median {sep['median']:.2f}"
        )
        print(f"avoidance time [s]   mean {summary['avoidance_time_s']['mean']:.2f}")
        print(f"failures by cause    {summary['failures_by_cause'] or 'none'}")
        if summary["failed_seeds"]:
            print(
                "replay a failure     stereo-avoid replay "
                f"{summary['failed_seeds'][0]} --family {args.family}"
            )
    return 0 if summary["failed_seeds"] == [] else 1


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stereo-avoid", description=__doc__.split("\n")[0].split(": ", 1)[1]
    )
    sub = parser.add_subparsers(dest="command", required=True)
    paper = sub.add_parser("paper", help="fly the paper's §6 scenario in lockstep")
    paper.add_argument("--out", type=Path, default=Path("runs/paper"), help="output folder")
    paper.add_argument("--json", action="store_true", help="print the verdict as JSON")
    mc = sub.add_parser("montecarlo", help="random scenes on all cores")
    mc.add_argument("--n", type=int, default=20, help="number of scenes")
    mc.add_argument("--seed", type=int, default=0, help="first seed")
    mc.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="processes")
    mc.add_argument("--json", action="store_true", help="print the summary as JSON")
    families = ["mixed", *FAMILIES]
    mc.add_argument(
        "--family", choices=families, default="mixed", help="scene family (mixed: by seed)"
    )
    replay = sub.add_parser("replay", help="fly one Monte Carlo scene by its seed")
    replay.add_argument("seed", type=int)
    replay.add_argument("--out", type=Path, default=None, help="output folder")
    replay.add_argument("--json", action="store_true", help="print the verdict as JSON")
    replay.add_argument("--family", choices=families, default="mixed", help="scene family")
    sil = sub.add_parser("sil", help="plant-sim + companion as processes on loopback")
    sil.add_argument("--scenario", type=Path, default=None, help="plant-sim scenario file")
    sil.add_argument("--speedup", type=float, default=4.0, help="simulation speed-up")
    sil.add_argument("--out", type=Path, default=Path("runs/sil"), help="output folder")
    sil.add_argument("--json", action="store_true", help="print the verdict as JSON")
    sil.add_argument(
        "--autopilot",
        choices=["plant-sim", "plant-sim-px4", "arducopter-sitl"],
        default="plant-sim",
        help="plant-sim as an ArduCopter (default) or as a PX4 (plant-sim-px4: the "
        "companion's OFFBOARD path), or ArduPilot's ArduCopter SITL ($ARDUCOPTER_SITL or "
        "../shared/ardupilot-sitl/arducopter) with plant-sim as the camera only; "
        "--speedup is then SITL's",
    )
    sil.add_argument(
        "--autopilot-params",
        type=Path,
        action="append",
        default=[],
        metavar="FILE",
        help="extra SITL parameter file (NAME VALUE lines, e.g. WPNAV_SPEED 100), repeatable",
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``stereo-avoid`` console script."""
    args = _parser().parse_args(argv)
    if args.command == "paper":
        return _fly_and_report(paper_scene(), args.out, args.json)
    if args.command == "sil":
        from plant_sim.lockstep.sil_report import fly_sil_and_report, fly_sitl_and_report

        if args.autopilot == "arducopter-sitl":
            if args.scenario is not None:
                print("stereo-avoid sil: --scenario is for plant-sim", file=sys.stderr)
                return 2
            out = args.out if args.out != Path("runs/sil") else Path("runs/sitl")
            return fly_sitl_and_report(args.speedup, out, args.json, tuple(args.autopilot_params))
        if args.autopilot_params:
            print("stereo-avoid sil: --autopilot-params needs --autopilot", file=sys.stderr)
            return 2
        plant_args = ("--autopilot-flavour", "px4") if args.autopilot == "plant-sim-px4" else ()
        return fly_sil_and_report(args.scenario, args.speedup, args.out, args.json, plant_args)
    if args.command == "replay":
        out = args.out or Path(f"runs/replay-{args.seed}")
        return _fly_and_report(scene_of(args.seed, args.family), out, args.json)
    if args.n < 1 or args.jobs < 1:
        print("stereo-avoid: --n and --jobs must be >= 1", file=sys.stderr)
        return 2
    return _montecarlo(args)


if __name__ == "__main__":
    sys.exit(main())
