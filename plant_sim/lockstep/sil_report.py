"""``stereo-avoid sil`` reporting: run :func:`~plant_sim.lockstep.sil.run_sil`, print
progress and the verdict (text or JSON), write the history CSV, figures and verdict.json."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

from plant_sim.lockstep.harness import RunConfig
from plant_sim.lockstep.plots import write_figures
from plant_sim.lockstep.sil import SilOptions, run_sil
from plant_sim.scenario import load_scenario, paper_scenario

__all__ = ["fly_sil_and_report"]


def fly_sil_and_report(scenario: Path | None, speedup: float, out_dir: Path, as_json: bool) -> int:
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
            SilOptions(scenario_path=scenario, speedup=speedup, out_dir=out_dir), progress
        )
    except (RuntimeError, TimeoutError, OSError) as exc:
        print(f"stereo-avoid sil: {exc}", file=sys.stderr)
        return 1
    sc = load_scenario(scenario) if scenario else paper_scenario()
    cfg = RunConfig()
    csv_path = out_dir / "history.csv"
    result.history.write_csv(csv_path)
    figures = write_figures(
        result.history,
        sc.world,
        sc.goal_ned_m or (0.0, 0.0, -7.0),
        out_dir,
        max_tilt_deg=sc.control.max_tilt_deg,
        rotor_limits_n=(sc.vehicle.rotor_thrust_min_n, sc.vehicle.rotor_thrust_max_n),
        detect_threshold_m=cfg.perception.threshold_m,
    )
    verdict = dataclasses.asdict(result.verdict)
    verdict["passed"] = result.verdict.passed
    (out_dir / "verdict.json").write_text(json.dumps(verdict, indent=2) + "\n")
    if as_json:
        print(json.dumps(verdict, indent=2))
    else:
        print("verdict:", "PASS" if result.verdict.passed else "FAIL")
        for key, value in verdict.items():
            print(f"  {key:24s} {value}")
        print(f"history: {csv_path}")
        print(f"truth:   {result.truth_path}")
        for path in figures:
            print(f"figure:  {path}")
    return 0 if result.verdict.passed else 1
