"""Scenes on a real autopilot and how a networked run ends (pure parts, no processes):

* :mod:`evaluation.sitl_scene` moves a plant-sim scenario so that its start is
  ArduCopter SITL's home, and refuses what SITL cannot fly;
* a SIL/SITL run judged from the truth log ends in a reported stop by the lockstep's own
  rule (guidance HOLD, slower than 0.05 m/s for 2 s), with the hold's reason.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from evaluation.harness import HOLD_REST_S, HOLD_REST_SPEED_MPS, Verdict
from evaluation.sil import _hold_intervals, _read_truth, verdict_from_truth
from evaluation.sitl_scene import SITL_HOME_LAT_LON_ALT, paper_sitl_scene, sitl_scene
from plant_sim.scenario import ScenarioError, scenario_from_dict


def test_a_scenario_is_moved_so_that_its_start_is_home_and_nothing_else_changes():
    data = {
        "goal_ned_m": [5.0, -10.0, -4.0],
        "start": {"pos_ned_m": [5.0, 3.0, -4.0], "yaw_deg": -90.0, "airborne": True},
        "obstacles": [
            {"shape": "box", "center_ned_m": [5.0, -4.0, -3.0], "size_m": [6.0, 0.3, 6.0]},
            {"center_ned_m": [1.0, 1.0, -2.0], "radius_m": 0.7, "material": "low_texture"},
        ],
        "camera": {"noise_std": 4.0},
        "profile": "fast",
    }
    before = json.dumps(data)
    scene = sitl_scene(data)
    assert json.dumps(data) == before  # the caller's data is not touched
    assert scene.shift_ne_m == (-5.0, -3.0)
    assert scene.goal_ned_m == (0.0, -13.0, -4.0)
    assert scene.takeoff_alt_m == 4.0
    assert scene.heading_deg == -90.0
    lat, lon, alt = SITL_HOME_LAT_LON_ALT
    assert scene.home_arg() == f"{lat},{lon},{alt:g},270"
    moved = scenario_from_dict(scene.scenario)  # plant-sim reads what SITL flies
    assert moved.start.pos_ned_m == (0.0, 0.0, -4.0)
    (box,), (sphere,) = moved.world.boxes, moved.world.spheres
    np.testing.assert_allclose(box.center_ned_m, (0.0, -7.0, -3.0))
    np.testing.assert_allclose(sphere.center_ned_m, (-4.0, -2.0, -2.0))
    assert sphere.radius_m == 0.7 and sphere.material.value == "low_texture"
    assert moved.camera.render.noise_std == 4.0
    # what ArduCopter decides itself is named, not silently dropped
    assert scene.not_applied == ("profile", "start.airborne")


def test_relative_geometry_is_kept_for_every_obstacle():
    """Goal minus obstacle and start minus obstacle are the same before and after."""
    data = {
        "goal_ned_m": [-3.0, 12.0, -5.0],
        "start": {"pos_ned_m": [7.5, -2.5, -5.0]},
        "obstacles": [
            {"shape": "cylinder", "center_ned_m": [2.0, 5.0, -4.0], "radius_m": 0.3, "height_m": 8},
            {"center_ned_m": [0.0, 3.0, -5.0], "radius_m": 1.0},
        ],
    }
    scene = sitl_scene(data)
    for before, after in zip(data["obstacles"], scene.scenario["obstacles"], strict=True):
        np.testing.assert_allclose(
            np.subtract(data["goal_ned_m"], before["center_ned_m"]),
            np.subtract(scene.goal_ned_m, after["center_ned_m"]),
        )
        np.testing.assert_allclose(
            np.subtract(data["start"]["pos_ned_m"], before["center_ned_m"]),
            np.subtract(scene.scenario["start"]["pos_ned_m"], after["center_ned_m"]),
        )


def test_the_default_scenario_is_the_paper_flown_from_home_facing_the_goal():
    scene = sitl_scene({})
    assert scene.goal_ned_m == (-20.0, 0.0, -7.0) and scene.takeoff_alt_m == 7.0
    assert scene.heading_deg == 180.0 and scene.not_applied == ()
    (sphere,) = scenario_from_dict(scene.scenario).world.spheres
    assert sphere.center_ned_m == (-10.0, 0.0, -7.0) and sphere.radius_m == 1.5
    paper = paper_sitl_scene()  # `sil --autopilot arducopter-sitl` without --scenario
    assert paper.goal_ned_m == (20.0, 0.0, -7.0) and paper.home_arg() is None


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"goal_ned_m": False}, "needs a goal"),
        ({"ground": {"down_m": 2.0}}, "ground.down_m is 2 m"),
        ({"start": {"pos_ned_m": [20.0, 0.0, -0.5]}}, "takes off to the start's height"),
        ({"obstacles": [{"center_ned_m": [1.0, 2.0], "radius_m": 1.0}]}, "center_ned_m"),
        ({"camera": {"fps": 30}}, "camera.fps"),
    ],
)
def test_what_sitl_cannot_fly_is_refused_with_the_reason(data, match):
    with pytest.raises(ScenarioError, match=match):
        sitl_scene(data)


# ---- how a run judged from the truth log ends ---------------------------------------


def _truth(t, speed_n, pos_n=None, surface=5.0):
    t = np.asarray(t, float)
    n = len(t)
    return {
        "time_s": t,
        "pos_n_m": np.zeros(n) if pos_n is None else np.asarray(pos_n, float),
        "pos_e_m": np.zeros(n),
        "pos_d_m": np.full(n, -7.0),
        "vel_n_mps": np.asarray(speed_n, float),
        "vel_e_mps": np.zeros(n),
        "vel_d_mps": np.zeros(n),
        "surface_distance_m": np.full(n, surface),
        "roll_cmd_rad": np.zeros(n),
        "pitch_cmd_rad": np.zeros(n),
    }


def _verdict(truth, holds, goal=(50.0, 0.0, -7.0)) -> Verdict:
    return verdict_from_truth(
        truth,
        scene="s",
        goal_ned_m=goal,
        t0_s=0.0,
        avoid_intervals=[],
        frames=0,
        wall_time_s=0.0,
        hold_intervals=holds,
    )


def test_a_reported_hold_ends_the_run_once_at_rest_for_the_lockstep_time():
    dt = 0.02
    t = np.arange(0.0, 20.0, dt)
    speed = np.where(t < 6.0, 1.0, 0.0)  # braking done at 6 s
    holds = [(4.0, math.inf, "goal_unreachable")]
    v = _verdict(_truth(t, speed), holds)
    assert v.failure == "hold" and v.hold_reason == "goal_unreachable"
    assert v.safe_stop and not v.passed
    assert v.outcome == "SAFE STOP (goal_unreachable)"
    assert v.sim_time_s == pytest.approx(6.0 + HOLD_REST_S, abs=dt)
    # just above the rest speed, the same hold is never "at rest": a timeout
    slow = np.where(t < 6.0, 1.0, 1.01 * HOLD_REST_SPEED_MPS)
    v = _verdict(_truth(t, slow), holds)
    assert v.failure == "timeout" and not v.safe_stop and v.outcome == "FAIL (timeout)"


def test_rest_outside_a_hold_or_a_hold_released_too_early_is_no_stop():
    t = np.arange(0.0, 20.0, 0.02)
    speed = np.where((t > 3.0) & (t < 8.0), 0.0, 1.0)  # 5 s at rest
    assert _verdict(_truth(t, speed), []).failure == "timeout"  # no hold reported
    released = [(2.0, 4.0, "no_progress")]  # only 1 s of the rest inside the hold
    assert _verdict(_truth(t, speed), released).failure == "timeout"
    assert _verdict(_truth(t, speed), [(2.0, 6.0, "no_progress")]).hold_reason == "no_progress"


def test_a_collision_or_the_goal_before_the_rest_decides_the_verdict():
    t = np.arange(0.0, 20.0, 0.02)
    speed = np.where(t < 6.0, 1.0, 0.0)
    holds = [(4.0, math.inf, "goal_unreachable")]
    truth = _truth(t, speed)
    truth["surface_distance_m"] = np.where(t > 7.0, 0.1, 5.0)  # inside 0.25 m at 7 s
    v = _verdict(truth, holds)
    assert v.collided and v.failure == "collision" and not v.safe_stop
    pos = np.minimum(t, 6.0)  # arrives at 6 m north, the goal, while holding
    v = _verdict(_truth(t, speed, pos_n=pos), holds, goal=(6.0, 0.0, -7.0))
    assert v.passed and v.outcome == "PASS"


def test_hold_intervals_come_from_guidance_holds_only():
    events = [
        ("hold", {"reason": "stale_frames", "command": "BRAKE"}),  # a failsafe: no capture time
        ("resume", {}),
        ("hold", {"reason": "no_progress", "capture_s": 10.0}),
        ("hold", {"reason": "goal_unreachable", "capture_s": 12.0}),  # new reason, still held
        ("hold_end", {"reason": "critical", "capture_s": 15.0}),
        ("avoidance", {"active": True, "capture_s": 16.0}),
        ("hold", {"reason": "goal_unreachable", "capture_s": 20.0}),
    ]
    assert _hold_intervals(events) == [
        (10.0, 12.0, "no_progress"),
        (12.0, 15.0, "goal_unreachable"),
        (20.0, math.inf, "goal_unreachable"),
    ]


def test_a_truth_log_being_written_is_read_up_to_its_last_whole_row(tmp_path):
    path = tmp_path / "truth.csv"
    path.write_text("time_s,pos_n_m,mode\n0.0,1.0,GUIDED\n0.02,1.5,GUIDED\n0.04,2.")
    truth = _read_truth(path)
    np.testing.assert_array_equal(truth["time_s"], [0.0, 0.02])
    np.testing.assert_array_equal(truth["pos_n_m"], [1.0, 1.5])
