"""Lockstep's autopilot (evaluation.lockstep_autopilot): the companion's targets and speed
statements reach plant-sim's GUIDED as the networked companion sends them to ArduPilot,
at the next autopilot tick."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evaluation.lockstep_autopilot import LockstepAutopilot, autopilot_params
from plant_sim.vehicle import Quadrotor

pytestmark = pytest.mark.unit

START = (20.0, 0.0, -7.0)


def _autopilot(**kw) -> tuple[Quadrotor, LockstepAutopilot]:
    quad = Quadrotor(pos_ned_m=START, yaw_rad=math.pi, ground_down_m=0.0)
    params = autopilot_params(quad.control.max_tilt_deg, kw.pop("params", {}))
    return quad, LockstepAutopilot(quad, params, ground_down_m=0.0, **kw)


def _tick(quad: Quadrotor, ap: LockstepAutopilot) -> None:
    quad.step(ap.next_tick_step() - round(quad.time_s / quad.dt_s))
    ap.tick(quad, np.zeros(3))


def test_the_speed_limit_is_stated_rounded_down_and_never_above_wpnav_speed():
    quad, ap = _autopilot(params={"WPNAV_SPEED": 300.0})
    ap.command((12.0, 0.0, -7.0), math.pi, 1.37, 0.0)
    _tick(quad, ap)
    assert ap.machine.shaper.limits.speed_ne_mps == pytest.approx(1.25)  # 0.25 m/s steps
    ap.command((12.0, 0.0, -7.0), math.pi, 9.0, 0.6)  # raised after 0.5 s, to WPNAV_SPEED
    _tick(quad, ap)
    assert ap.machine.shaper.limits.speed_ne_mps == pytest.approx(3.0)
    assert ap.stats.speed_limits_sent == 2 and ap.stats.speed_limits_refused == 0


def test_without_the_speed_statement_guided_flies_at_wpnav_speed():
    quad, ap = _autopilot(state_speed_limit=False)
    ap.command((12.0, 0.0, -7.0), math.pi, 0.5, 0.0)
    _tick(quad, ap)
    assert ap.machine.shaper.limits.speed_ne_mps == pytest.approx(10.0)  # WPNAV_SPEED
    assert ap.stats.speed_limits_sent == 0


def test_a_target_is_taken_at_the_next_tick_and_a_repeat_is_not_resent():
    quad, ap = _autopilot()
    _tick(quad, ap)  # tick 0: nothing sent yet, the vehicle holds
    ap.command((12.0, 0.0, -7.0), math.pi, 1.0, quad.time_s)
    assert ap.machine.reported_target.pos_ned_m != (12.0, 0.0, -7.0)  # not before a tick
    _tick(quad, ap)
    assert ap.machine.reported_target.pos_ned_m == (12.0, 0.0, -7.0)
    ap.command((12.005, 0.0, -7.0), math.pi, 1.0, quad.time_s)  # < 2 cm, < 0.5 s: not sent
    assert ap.stats.targets_sent == 1 and ap.last_target_ned_m == (12.0, 0.0, -7.0)


def test_an_autopilot_rate_that_does_not_divide_the_physics_rate_is_refused():
    with pytest.raises(ValueError, match="divide the physics rate"):
        _autopilot(rate_hz=30.0)
    with pytest.raises(ValueError, match="WPNAV_SPED"):
        _autopilot(params={"WPNAV_SPED": 100.0})
