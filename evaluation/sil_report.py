"""``stereo-avoid sil`` reporting: run :func:`~evaluation.sil.run_sil`, print
progress, then the verdict and files through :func:`~evaluation.report.write_run_report`."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from evaluation.harness import RunConfig
from evaluation.report import write_run_report
from evaluation.sil import SilOptions, run_sil
from plant_sim.scenario import (
    ScenarioError,
    load_scenario,
    paper_scenario,
    read_scenario_data,
    scenario_from_dict,
)

if TYPE_CHECKING:
    from evaluation.sitl import SitlResult
    from evaluation.sitl_scene import SitlScene

__all__ = ["fly_sil_and_report", "fly_sitl_and_report"]


def fly_sil_and_report(
    scenario: Path | None,
    speedup: float,
    out_dir: Path,
    as_json: bool,
    plant_args: tuple[str, ...] = (),
    companion_args: tuple[str, ...] = (),
) -> int:
    """Fly, report, write files; exit status 0 when passed, 1 otherwise, 2 on bad input."""
    log = sys.stderr if as_json else sys.stdout
    if not speedup > 0:
        print("stereo-avoid sil: --speedup must be > 0", file=sys.stderr)
        return 2

    def progress(text: str) -> None:
        print(f"  {text}", file=log)
        log.flush()

    print(f"flying SIL at {speedup:g}x: plant-sim + companion on loopback", file=log)
    try:
        result = run_sil(
            SilOptions(
                scenario_path=scenario,
                speedup=speedup,
                out_dir=out_dir,
                plant_args=plant_args,
                companion_args=companion_args,
            ),
            progress,
        )
    except (RuntimeError, TimeoutError, OSError) as exc:
        print(f"stereo-avoid sil: {exc}", file=sys.stderr)
        return 1
    sc = load_scenario(scenario) if scenario else paper_scenario()
    logs = [("truth", result.truth_path), ("tlog", out_dir / "plant_sim.tlog")]
    return write_run_report(
        result.verdict,
        result.history,
        world=sc.world,
        goal_ned_m=sc.goal_ned_m or (0.0, 0.0, -7.0),
        out_dir=out_dir,
        vehicle=sc.vehicle,
        control=sc.control,
        detect_threshold_m=RunConfig().perception.threshold_m,
        as_json=as_json,
        stdout=sys.stdout,
        other_files=[(label, path) for label, path in logs if path is not None],
    )


def fly_sitl_and_report(
    speedup: float,
    out_dir: Path,
    as_json: bool,
    params_files: tuple[Path, ...] = (),
    scenario: Path | None = None,
) -> int:
    """``stereo-avoid sil --autopilot arducopter-sitl``: fly the paper's scene (or
    ``scenario``, placed so that its start is SITL's home: :mod:`~evaluation.sitl_scene`)
    on ArduPilot's ArduCopter SITL (plant-sim as the camera only), report like the
    plant-sim SIL run plus the speed figures; exit status as :func:`write_run_report`'s,
    2 on bad input."""
    from evaluation.sitl import (
        SITL_HOWTO,
        SitlOptions,
        find_arducopter_sitl,
        run_sitl_sil,
    )
    from evaluation.sitl_scene import paper_sitl_scene

    log = sys.stderr if as_json else sys.stdout
    binary = find_arducopter_sitl()
    if binary is None:
        print(f"stereo-avoid sil: {SITL_HOWTO}", file=sys.stderr)
        return 2
    for path in params_files:
        if not path.is_file():
            print(f"stereo-avoid sil: parameter file {path} not found", file=sys.stderr)
            return 2
    try:
        scene = paper_sitl_scene() if scenario is None else _sitl_scene_of(scenario, log)
    except ScenarioError as exc:
        print(f"stereo-avoid sil: {exc}", file=sys.stderr)
        return 2

    def progress(text: str) -> None:
        print(f"  {text}", file=log)
        log.flush()

    what = "the paper's scene" if scenario is None else str(scenario)
    print(f"flying {what} on ArduCopter SITL ({binary}) at {speedup:g}x", file=log)
    try:
        options = SitlOptions(
            binary=binary,
            out_dir=out_dir,
            speedup=speedup,
            params_files=params_files,
            scene=scene,
            scene_name="paper-sitl" if scenario is None else f"{scenario.stem}-sitl",
        )
        result = run_sitl_sil(options, progress)
    except ValueError as exc:
        print(f"stereo-avoid sil: {exc}", file=sys.stderr)
        return 2
    except (RuntimeError, TimeoutError, OSError) as exc:
        print(f"stereo-avoid sil: {exc}", file=sys.stderr)
        return 1
    return _report_sitl(result, scene, out_dir, as_json, log)


def _report_sitl(
    result: SitlResult, scene: SitlScene, out_dir: Path, as_json: bool, log: TextIO
) -> int:
    """Verdict, figures and files of a SITL run (:func:`write_run_report`) plus its speed
    figures; the exit status."""
    sc = scenario_from_dict({})
    sil = result.sil
    status = write_run_report(
        sil.verdict,
        sil.history,
        world=scenario_from_dict(scene.scenario).world,
        goal_ned_m=scene.goal_ned_m,
        out_dir=out_dir,
        vehicle=sc.vehicle,
        control=sc.control,
        detect_threshold_m=RunConfig().perception.threshold_m,
        as_json=False,
        stdout=log,
        other_files=[("truth", sil.truth_path), ("figures", out_dir / "sitl_figures.json")],
    )
    if as_json:  # one document: the verdict with the SITL figures
        fields = json.loads((out_dir / "verdict.json").read_text())
        print(json.dumps({**fields, "figures": result.figures}, indent=2), file=sys.stdout)
    else:
        for key, value in result.figures.items():
            print(f"  {key:24s} {value}", file=sys.stdout)
    return status


def _sitl_scene_of(path: Path, log: TextIO) -> SitlScene:
    """The scenario file at ``path`` placed in SITL's world; says how it was moved and what
    SITL decides for itself. A :class:`ScenarioError` names the file."""
    from evaluation.sitl_scene import sitl_scene

    data = read_scenario_data(path)
    try:
        scene = sitl_scene(data)
    except ScenarioError as exc:
        raise ScenarioError(f"{path}: {exc}") from None
    north, east = scene.shift_ne_m
    print(
        f"  scene moved by N{north:+g} E{east:+g} m so that its start is SITL's home; "
        f"takeoff to {scene.takeoff_alt_m:g} m, heading {scene.heading_deg:g} deg, goal "
        f"N{scene.goal_ned_m[0]:g} E{scene.goal_ned_m[1]:g} D{scene.goal_ned_m[2]:g}",
        file=log,
    )
    if scene.not_applied:
        print(
            f"  not applied (ArduCopter SITL decides these itself): {', '.join(scene.not_applied)}",
            file=log,
        )
    return scene
