"""``stereo-avoid``: lockstep runs of the paper's §6 scenario and Monte Carlo batches.

Subcommands
-----------
``stereo-avoid paper [--out DIR] [--json]``
    Fly §6 (start (20, 0, −7), goal (0, 0, −7), obstacle (10, 0, −7) r 1.5 m), print
    progress and a verdict, write Fig. 6–11 as PNG and the time history as CSV.
``stereo-avoid fly --scenario FILE [--out DIR] [--json]``
    A plant-sim scenario file (``.toml``/``.json``: start, heading, goal, obstacles,
    airframe, camera) flown in lockstep like ``paper``
    (:mod:`evaluation.scene_files`); ``docker/config/scenario.toml`` is the paper's.
``stereo-avoid montecarlo --n N [--seed S] [--family F] [--perception stereo|truth|depth]
[--cluster ADDRESS | --jobs J] [--out DIR] [--resume [--allow-code-change]] [--json]``
    N random scenes (seeds S … S+N−1) as tasks on a Dask cluster: the scheduler at
    ADDRESS (``tcp://host:8786``), or a local cluster of J worker processes. Verdicts
    stream to DIR/results.jsonl as they finish, each with the fingerprint of the code that
    flew it (``--resume`` flies only the seeds not in it, and refuses seeds flown by other
    code unless ``--allow-code-change``), with a progress bar (rate, ETA); at the end a
    summary table (with the code that flew it) and figures in DIR, with the seed of every
    failure to replay. Families (``evaluation.scenes``):
    path, climb, goal_near, facing_away, or mixed (the default: the family of seed s is
    the (s mod 4)-th); and (``evaluation.passage_scenes``, issue 36) gap, corridor,
    goal_surface, vertical, or passages (their mix, by seed likewise), with a figure per
    family (outcomes, time to goal). ``--perception truth``: the renderer's exact depth
    instead of the stereo matcher (``evaluation.truth_perception``).
``stereo-avoid replay SEED [--family F] [--perception P] [--out DIR] [--json]``
    One random scene, with figures, exactly as Monte Carlo flew it (same verdict).
``stereo-avoid replay FILE.mcap [--rerun FILE.rrd|serve] [--json]``
    A companion recording (``companion --record``) through a fresh companion core with the
    recorded inputs and clock; exit 0 when every MAVLink output (setpoints included) is
    bit for bit the recorded one (:mod:`companion.record.replay`).
``stereo-avoid sil [--scenario FILE] [--speedup N] [--out DIR] [--json]``
    plant-sim and the companion as two processes over MAVLink and Zenoh on loopback;
    the same verdict and figures, from plant-sim's ground-truth log.
``stereo-avoid compile [--jobs J]``
    Compile every numba kernel into numba's cache (:mod:`evaluation.kernels`), so
    no process pays ~70 s of JIT at its first frame; ``scripts/setup.sh`` runs it.

``paper``, ``replay`` and ``sil`` take ``--rerun FILE.rrd|serve[:PORT]``: the run in Rerun
(:mod:`evaluation.view`; needs the optional ``view`` extra).
``stereo-avoid sil --autopilot arducopter-sitl [--scenario FILE] [--autopilot-params FILE]``
    the paper's scene (north from home at 7 m), or a plant-sim scenario moved so that its
    start is SITL's home (:mod:`evaluation.sitl_scene`), on ArduPilot's ArduCopter
    SITL, taken off by the companion, plant-sim as the camera only
    (:mod:`evaluation.sitl`).

Exit status: 0 when every run reached its goal without collision (montecarlo: every
scene ended safely, at the goal or in a reported stop, and none collided); for one run
(``paper``, ``fly``, ``replay SEED``, ``sil``) 3 when it ended in a safe stop (guidance reported a
hold and the vehicle came to rest, no collision: the goal is unreachable); 1 otherwise; 2
on a usage error.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from evaluation.harness import RunConfig, RunResult, run_scene
from evaluation.montecarlo import (
    ALL_FAMILIES,
    is_safe,
    run_config,
    scene_of,
    single_threaded,
    summarize,
)
from evaluation.report import write_run_report
from evaluation.scenes import Scene, paper_scene
from protocols.threads import configure_threads

__all__ = ["main"]


def _progress(stream):
    def report(sim_time_s: float, goal_distance_m: float) -> None:
        print(f"  t={sim_time_s:5.1f} s  distance to goal {goal_distance_m:5.2f} m", file=stream)
        stream.flush()

    return report


def _fly_scenario(args: argparse.Namespace) -> int:
    """``stereo-avoid fly --scenario FILE``: the file's scene and airframe in lockstep."""
    from evaluation.scene_files import scene_and_config
    from plant_sim.scenario import ScenarioError, load_scenario

    try:
        scenario = load_scenario(args.scenario)
        scene, cfg = scene_and_config(scenario, args.scenario.stem)
    except (ScenarioError, ValueError, OSError) as exc:
        print(f"stereo-avoid fly: {exc}", file=sys.stderr)
        return 2
    return _fly_and_report(scene, args.out, args.json, cfg, rerun=args.rerun)


def _fly_and_report(
    scene: Scene,
    out_dir: Path,
    as_json: bool,
    cfg: RunConfig | None = None,
    rerun: str | None = None,
) -> int:
    cfg = cfg or RunConfig()
    log = sys.stderr if as_json else sys.stdout
    print(f"flying scene '{scene.name}' in lockstep (simulation time)", file=log)
    view = None
    if rerun is not None:
        from evaluation.view import LockstepView, ViewOptionError

        try:
            view = LockstepView(rerun, scene, cfg)
        except ViewOptionError as exc:
            print(f"stereo-avoid: {exc}", file=sys.stderr)
            return 2
        print(f"Rerun: {view.target.describe()}", file=log)
    try:
        result: RunResult = run_scene(
            scene, cfg, progress=_progress(log), on_step=None if view is None else view.on_step
        )
    finally:
        if view is not None:
            view.close()
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


def _record_sink(results, bar, code: str) -> Callable[[dict], None]:
    """``on_record`` for a batch: append the record to ``results``, advance ``bar``, and warn
    (once per fingerprint) when a worker flew it with other code than this client's."""
    from evaluation.mc_results import verdict_from_record

    foreign: set[str] = set()

    def on_record(record: dict) -> None:
        other = record.get("code")
        if other != code and other not in foreign:  # a worker with other source
            foreign.add(other)
            print(
                f"\nwarning: worker {record.get('worker') or '?'} flies other code "
                f"({other}; this client is {code}): its verdicts are kept, marked and "
                "counted in the report",
                file=sys.stderr,
            )
        results.append(record)
        verdict = verdict_from_record(record)
        bar.update(collided=verdict.collided, safe=is_safe(verdict))

    return on_record


def _have_dask() -> bool:
    """Whether the [eval] extra (Dask) is installed; if not, says which module is missing."""
    try:
        import evaluation.mc_cluster  # noqa: F401
    except ModuleNotFoundError as exc:
        print(
            f"stereo-avoid montecarlo: {exc.name or exc} is missing: Monte Carlo runs on Dask, "
            "in the [eval] extra (pip install 'stereo-avoid[eval]', or bash scripts/setup.sh)",
            file=sys.stderr,
        )
        return False
    return True


def _montecarlo(args: argparse.Namespace) -> int:
    if not _have_dask():
        return 2
    from evaluation.mc_cluster import dask_client, fly_on_cluster
    from evaluation.mc_progress import ProgressBar
    from evaluation.mc_provenance import code_counts, code_fingerprint
    from evaluation.mc_report import write_report
    from evaluation.mc_results import BatchSpec, ResultsFile, ResultsFileError

    if args.allow_code_change and not args.resume:
        print(
            "stereo-avoid montecarlo: --allow-code-change only applies with --resume",
            file=sys.stderr,
        )
        return 2
    log = sys.stderr if args.json else sys.stdout
    spec = BatchSpec(args.seed, args.n, args.family, args.perception, args.max_time_s)
    out = args.out or Path(
        f"runs/montecarlo/{args.family}-{args.perception}-s{args.seed}-n{args.n}"
    )
    code = code_fingerprint()
    try:
        results = ResultsFile(
            out,
            spec,
            resume=args.resume,
            code=code,
            allow_code_change=args.allow_code_change,
        )
    except ResultsFileError as exc:
        print(f"stereo-avoid montecarlo: {exc}", file=sys.stderr)
        return 2
    with results:
        pending = results.pending
        where = args.cluster or f"a local Dask cluster of {args.jobs} workers"
        print(
            f"Monte Carlo: {args.n} scenes ({args.family}, {args.perception} perception), "
            f"{len(results.records)} already in {results.path}, {len(pending)} to fly on "
            f"{where}",
            file=log,
        )
        bar = ProgressBar(args.n, len(results.records), log)
        t0 = time.monotonic()
        on_record = _record_sink(results, bar, code)
        if pending:
            with dask_client(args.cluster, n_workers=args.jobs) as client:
                fly_on_cluster(
                    client,
                    pending,
                    family=args.family,
                    perception=args.perception,
                    max_time_s=args.max_time_s,
                    on_record=on_record,
                )
        bar.close()
        wall_s = time.monotonic() - t0
        verdicts = results.verdicts()
        codes = code_counts(results.records.values())
    summary = summarize(verdicts)
    throughput = (
        {"scenes": len(pending), "wall_s": wall_s, "scenes_per_min": 60 * len(pending) / wall_s}
        if pending
        else None
    )
    table = write_report(
        out,
        verdicts,
        summary,
        family=args.family,
        perception=args.perception,
        throughput=throughput,
        code_counts=codes,
    )
    if args.json:
        print(json.dumps({**summary, "throughput": throughput, "code": codes}, indent=2))
    else:
        print(table)
        print(f"report               {out}/summary.txt, *.png")
    ok = summary["collisions"] == 0 and not summary["unsafe_seeds"]
    return 0 if ok else 1


def _replay(args: argparse.Namespace) -> int:
    """``replay TARGET``: an integer is a Monte Carlo seed (flown again in lockstep), a
    ``.mcap`` file a companion recording (replayed through a fresh core)."""
    if args.target.endswith(".mcap"):
        from evaluation.view import replay_recording

        return replay_recording(Path(args.target), args.rerun, args.json)
    try:
        seed = int(args.target)
    except ValueError:
        print(
            f"stereo-avoid replay: {args.target!r} is neither a seed (an integer) nor a "
            "companion recording (FILE.mcap)",
            file=sys.stderr,
        )
        return 2
    single_threaded()  # as every Monte Carlo worker flies it: the same verdict
    out = args.out or Path(f"runs/replay-{seed}")
    cfg = run_config(args.perception, args.max_time_s)
    return _fly_and_report(scene_of(seed, args.family), out, args.json, cfg, args.rerun)


_FAMILIES = list(ALL_FAMILIES)
_PERCEPTIONS = ["stereo", "truth", "depth"]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stereo-avoid", description=__doc__.split("\n")[0].split(": ", 1)[1]
    )
    sub = parser.add_subparsers(dest="command", required=True)
    paper = sub.add_parser("paper", help="fly the paper's §6 scenario in lockstep")
    paper.add_argument("--out", type=Path, default=Path("runs/paper"), help="output folder")
    paper.add_argument("--json", action="store_true", help="print the verdict as JSON")
    paper.add_argument(
        "--perception",
        choices=_PERCEPTIONS,
        default="stereo",
        help="stereo matcher (default), ground truth, or a RealSense-like depth camera",
    )
    fly = sub.add_parser("fly", help="fly a plant-sim scenario file in lockstep")
    fly.add_argument(
        "--scenario", type=Path, required=True, help="plant-sim scenario (.toml or .json)"
    )
    fly.add_argument("--out", type=Path, default=Path("runs/fly"), help="output folder")
    fly.add_argument("--json", action="store_true", help="print the verdict as JSON")
    _add_montecarlo(sub.add_parser("montecarlo", help="random scenes on a Dask cluster"))
    replay = sub.add_parser(
        "replay", help="fly one Monte Carlo scene again by its seed, or replay FILE.mcap"
    )
    replay.add_argument(
        "target",
        metavar="SEED|FILE.mcap",
        help="Monte Carlo seed (an integer), or a recording of `companion --record`",
    )
    replay.add_argument("--out", type=Path, default=None, help="output folder")
    replay.add_argument("--json", action="store_true", help="print the verdict as JSON")
    replay.add_argument("--family", choices=_FAMILIES, default="mixed", help="scene family")
    replay.add_argument(
        "--perception", choices=_PERCEPTIONS, default="stereo", help="as in montecarlo"
    )
    replay.add_argument(
        "--max-time-s", type=float, default=None, help="as in montecarlo (default 90 s)"
    )
    sil = sub.add_parser("sil", help="plant-sim + companion as processes on loopback")
    _add_sil(sil)
    compile_ = sub.add_parser(
        "compile", help="compile every numba kernel into its cache (setup runs it once)"
    )
    compile_.add_argument(
        "--jobs", type=int, default=2, help="processes compiling at once (default 2)"
    )
    for p in (paper, fly, replay, sil):
        p.add_argument(
            "--rerun",
            metavar="FILE.rrd|serve[:PORT]",
            help="log the run to Rerun: a .rrd file or a live web viewer (default port 9090); "
            "needs the optional 'view' extra",
        )
    return parser


def _add_montecarlo(mc: argparse.ArgumentParser) -> None:
    """``stereo-avoid montecarlo``: batch size, cluster, output and scene options."""
    mc.add_argument("--n", type=int, default=20, help="number of scenes")
    mc.add_argument("--seed", type=int, default=0, help="first seed")
    mc.add_argument(
        "--jobs",
        type=int,
        default=os.cpu_count() or 1,
        help="worker processes of the local cluster (without --cluster)",
    )
    mc.add_argument(
        "--cluster",
        metavar="ADDRESS",
        default=None,
        help="Dask scheduler to run on (tcp://host:8786); default: a local cluster",
    )
    mc.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default runs/montecarlo/FAMILY-PERCEPTION-sSEED-nN)",
    )
    mc.add_argument(
        "--resume", action="store_true", help="finish the run in --out: skip finished seeds"
    )
    mc.add_argument(
        "--allow-code-change",
        action="store_true",
        help="with --resume: finish a batch whose finished seeds were flown by other code "
        "(refused by default; the report lists which code flew which seeds)",
    )
    mc.add_argument("--json", action="store_true", help="print the summary as JSON")
    mc.add_argument(
        "--family", choices=_FAMILIES, default="mixed", help="scene family (mixed: by seed)"
    )
    mc.add_argument(
        "--perception",
        choices=_PERCEPTIONS,
        default="stereo",
        help="stereo matcher (default), ground truth (the renderer's exact depth) or a "
        "RealSense-like depth camera (depth16 frames with its noise; no matcher)",
    )
    mc.add_argument(
        "--max-time-s",
        type=float,
        default=None,
        help="simulation time limit per scene (default 90 s; shorter for smoke runs)",
    )


def _add_sil(sil: argparse.ArgumentParser) -> None:
    """``stereo-avoid sil``: scenario, pace, output and which autopilot flies it."""
    sil.add_argument("--scenario", type=Path, default=None, help="plant-sim scenario file")
    sil.add_argument("--speedup", type=float, default=4.0, help="simulation speed-up")
    sil.add_argument("--out", type=Path, default=Path("runs/sil"), help="output folder")
    sil.add_argument("--json", action="store_true", help="print the verdict as JSON")
    sil.add_argument(
        "--autopilot",
        choices=["plant-sim", "plant-sim-px4", "arducopter-sitl"],
        default="plant-sim",
        help="plant-sim as an ArduCopter (default) or as a PX4 (plant-sim-px4: the "
        "companion's OFFBOARD path), or ArduPilot's ArduCopter SITL (the binary "
        "named by $ARDUCOPTER_SITL; none ships with this project) with plant-sim as the "
        "camera only; "
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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``stereo-avoid`` console script."""
    try:
        configure_threads()
    except ValueError as exc:
        print(f"stereo-avoid: configuration error: {exc}", file=sys.stderr)
        return 2
    args = _parser().parse_args(argv)
    if args.command == "paper":
        cfg = run_config(args.perception)
        return _fly_and_report(paper_scene(), args.out, args.json, cfg, rerun=args.rerun)
    if args.command == "fly":
        return _fly_scenario(args)
    if args.command == "sil":
        from evaluation.sil_report import fly_sil_and_report, fly_sitl_and_report

        if args.autopilot == "arducopter-sitl":
            out = args.out if args.out != Path("runs/sil") else Path("runs/sitl")
            return fly_sitl_and_report(
                args.speedup, out, args.json, tuple(args.autopilot_params), args.scenario
            )
        if args.autopilot_params:
            print("stereo-avoid sil: --autopilot-params needs --autopilot", file=sys.stderr)
            return 2
        plant_args = ("--autopilot-flavour", "px4") if args.autopilot == "plant-sim-px4" else ()
        companion_args = ("--rerun", args.rerun) if args.rerun else ()
        return fly_sil_and_report(
            args.scenario, args.speedup, args.out, args.json, plant_args, companion_args
        )
    if args.command == "replay":
        return _replay(args)
    if args.command == "compile":
        from evaluation.kernels import compile_kernels

        if args.jobs < 1:
            print("stereo-avoid compile: --jobs must be >= 1", file=sys.stderr)
            return 2
        compile_kernels(args.jobs)
        return 0
    if args.n < 1 or args.jobs < 1:
        print("stereo-avoid: --n and --jobs must be >= 1", file=sys.stderr)
        return 2
    if args.max_time_s is not None and not args.max_time_s > 0:
        print("stereo-avoid: --max-time-s must be > 0", file=sys.stderr)
        return 2
    return _montecarlo(args)


if __name__ == "__main__":
    sys.exit(main())
