"""plant-sim vehicle profiles: the paper's stays the default, "fast" reaches ≥ 5 m/s."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant_sim.params import ControlParams, QuadrotorParams
from plant_sim.profiles import profile, terminal_speed_mps
from plant_sim.scenario import ScenarioError, scenario_from_dict
from plant_sim.vehicle import Quadrotor, Setpoint


def test_paper_profile_is_table_2_and_the_scenario_default():
    assert profile("paper").vehicle == QuadrotorParams()
    assert profile("paper").control == ControlParams()
    sc = scenario_from_dict({})
    assert sc.vehicle == QuadrotorParams() and sc.control == ControlParams()
    # drag-limited cruise of §6: m g tan 15° / k_t = 0.85 m/s
    assert terminal_speed_mps(profile("paper")) == pytest.approx(0.854, abs=1e-3)


def test_scenario_selects_a_profile_and_overrides_single_fields():
    sc = scenario_from_dict({"profile": "fast", "control": {"max_tilt_deg": 30.0}})
    assert sc.vehicle == profile("fast").vehicle
    assert sc.control.max_tilt_deg == 30.0
    assert sc.control.q_position == ControlParams().q_position
    with pytest.raises(ScenarioError, match="valid"):
        scenario_from_dict({"profile": "warp"})


def test_fast_profile_reaches_5_mps_toward_a_far_target():
    p = profile("fast")
    quad = Quadrotor(p.vehicle, p.control, pos_ned_m=(0.0, 0.0, -7.0), yaw_rad=0.0)
    quad.set_setpoint(Setpoint(pos_ned_m=(100.0, 0.0, -7.0), yaw_rad=0.0))
    speeds = []
    while quad.time_s < 3.0:
        quad.step(p.control.steps_per_control)
        speeds.append(float(np.linalg.norm(quad.vel_ned_mps)))
    assert max(speeds) >= 5.0
    assert terminal_speed_mps(p) == pytest.approx(
        0.65 * 9.81 * math.tan(math.radians(35.0)) / 0.3, rel=1e-12
    )
