"""Flights with a starved companion (issue 32 item 5): shared by the 1× and 3× test files.

The companion runs with a quarter of one core (:mod:`evaluation.starve`: a cgroup CPU quota
where the machine allows it, else pinned beside spinning processes) against plant-sim at
real time or 3× (SITL's ``--speedup 3`` on a busy machine was the evidence in issue 32:
frame age and compute time count 3× in the autopilot's clock). Verdicts:

* no collision (centre to surface below the vehicle's radius with propellers, 0.35 m);
* the goal reached, or a reported safe stop;
* never inside the margin of a boundary (vehicle radius + safety margin) after the first
  sighting — the vehicle starts clear of everything, so over the whole flight;
* at most 2 mode requests beyond engage/release (plant-sim starts airborne in GUIDED, so
  engaging needs none).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.perception import PerceptionConfig
from evaluation.scene_files import scenario_data
from evaluation.scenes import family_scene, paper_scene
from evaluation.sil import SilOptions, SilResult, run_sil
from evaluation.starve import available

CORE_FRACTION = 0.25
COLLISION_M = 0.35
_P = PerceptionConfig()
MARGIN_M = _P.vehicle_radius_m + _P.safety_margin_m
MAX_EXTRA_MODE_REQUESTS = 2

#: tests/test_sitl_arducopter.py's WALL_BEHIND_SCENARIO (the loaded-machine evidence of
#: issue 32), started airborne: plant-sim needs no takeoff
WALL_BEHIND = {
    "goal_ned_m": [0.0, 0.0, -6.0],
    "start": {"pos_ned_m": [16.0, 1.0, -6.0], "yaw_deg": 0.0, "airborne": True},
    "obstacles": [{"shape": "box", "center_ned_m": [6.0, 0.0, -4.0], "size_m": [0.4, 6.0, 8.0]}],
}
SCENES = {
    "paper": scenario_data(paper_scene()),
    "wall_behind": WALL_BEHIND,
    "climb-2": scenario_data(family_scene(2, "climb")),
    "facing_away-3": scenario_data(family_scene(3, "facing_away")),
}


def skip_unless_starvable() -> None:
    mechanism, why = available()
    if mechanism is None:
        pytest.skip(why)


def fly_starved(name: str, speedup: float, tmp_path: Path) -> SilResult:
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(SCENES[name]), encoding="utf-8")
    options = SilOptions(
        scenario_path=path,
        speedup=speedup,
        out_dir=tmp_path / "out",
        max_time_s=120.0,
        companion_core_fraction=CORE_FRACTION,
    )
    return run_sil(options, progress=print)


def check(result: SilResult) -> None:
    v = result.verdict
    stats = result.companion_stats or {}
    logs = (result.truth_path.parent / "companion.log").read_text()[-6000:]
    where = f"{v}\nstarved: {result.starvation}\nstats: {stats}\ncompanion log tail:\n{logs}"
    assert result.starvation is not None, where
    assert not v.collided and v.min_surface_distance_m >= COLLISION_M, where
    assert v.reached_goal or v.failure == "hold", where
    assert v.min_surface_distance_m >= MARGIN_M, where
    assert stats.get("mode_requests", 0) <= MAX_EXTRA_MODE_REQUESTS, where
