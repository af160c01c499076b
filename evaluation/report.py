"""Write and print what a run produced: history CSV, Fig. 6–11, verdict.json, a verdict.

Shared by ``stereo-avoid paper``/``replay`` (lockstep) and ``stereo-avoid sil``.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

from evaluation.harness import Verdict
from evaluation.history import History
from evaluation.plots import write_figures
from plant_sim.params import ControlParams, QuadrotorParams
from plant_sim.world import World

__all__ = ["write_run_report"]


def write_run_report(
    verdict: Verdict,
    history: History,
    *,
    world: World,
    goal_ned_m: Sequence[float],
    out_dir: Path,
    vehicle: QuadrotorParams,
    control: ControlParams,
    detect_threshold_m: float,
    as_json: bool,
    stdout: TextIO,
    other_files: Sequence[tuple[str, Path]] = (),
) -> int:
    """Write ``history.csv``, the figures and ``verdict.json`` into ``out_dir``; print the
    verdict (JSON with ``as_json``, else text with the files). Returns the exit status:
    0 when the goal was reached without collision, 3 for a safe stop (guidance reported a
    hold and the vehicle came to rest without a collision: the goal is unreachable), 1
    otherwise."""
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path = out_dir / "history.csv"
    history.write_csv(csv_path)
    figures = write_figures(
        history,
        world,
        goal_ned_m,
        out_dir,
        max_tilt_deg=control.max_tilt_deg,
        rotor_limits_n=(vehicle.rotor_thrust_min_n, vehicle.rotor_thrust_max_n),
        detect_threshold_m=detect_threshold_m,
    )
    fields = dataclasses.asdict(verdict)
    fields["passed"] = verdict.passed
    fields["outcome"] = verdict.outcome
    (out_dir / "verdict.json").write_text(json.dumps(fields, indent=2) + "\n")
    if as_json:
        print(json.dumps(fields, indent=2), file=stdout)
    else:
        print("verdict:", verdict.outcome, file=stdout)
        for key, value in fields.items():
            print(f"  {key:24s} {value}", file=stdout)
        print(f"history: {csv_path}", file=stdout)
        for label, path in other_files:
            print(f"{label + ':':8s} {path}", file=stdout)
        for path in figures:
            print(f"figure:  {path}", file=stdout)
    return 0 if verdict.passed else 3 if verdict.safe_stop else 1
