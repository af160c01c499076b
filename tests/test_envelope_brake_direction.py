"""The bound a braking vehicle states is along the way it moves (issue 36, vertical family).

Traced per frame (vertical-215, ground truth): a staged climb toward a goal straight
above flies ~0.3 m/s toward a carrot 12° up along the heading; ArduCopter climbs at the
least climb speed the companion states (0.1 m/s), so the velocity runs at 18–19.5°,
above the camera's view. When the envelope braked, it measured known-free space along
that velocity: only the body's own 0.3 m, a bound of 0 m/s, "overspeed" on 15 frames of a
flight that never left space seen free by more than the section's height.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.guidance.envelope import EnvelopeConfig, envelope_step
from companion.guidance.envelope_direction import CLIMB_SLACK_MPS, brake_direction
from companion.link.speed_limit import ClimbLimitPolicy, SpeedLimitPolicy

ELEV_RAD = math.radians(12.0)
TAN_E = math.tan(ELEV_RAD)


def _vel(horizontal_mps: float, up_mps: float, bearing_deg: float = 0.0) -> np.ndarray:
    b = math.radians(bearing_deg)
    return np.array([horizontal_mps * math.cos(b), horizontal_mps * math.sin(b), -up_mps])


def _elev_deg(u) -> float:
    return math.degrees(math.atan2(-u[2], math.hypot(u[0], u[1])))


def test_the_slack_is_the_least_climb_speed_the_companion_states():
    assert ClimbLimitPolicy().pacing.min_mps == CLIMB_SLACK_MPS
    assert SpeedLimitPolicy().climb.pacing.min_mps == CLIMB_SLACK_MPS


@pytest.mark.parametrize("sign", [1.0, -1.0])  # climb, descent
@pytest.mark.parametrize("horizontal_mps", [0.1, 0.3, 1.0])
def test_a_climb_steeper_by_the_slack_is_measured_at_the_path_elevation(sign, horizontal_mps):
    up = sign * (horizontal_mps * TAN_E + CLIMB_SLACK_MPS)
    u = brake_direction(_vel(horizontal_mps, up, 30.0), ELEV_RAD)
    assert _elev_deg(u) == pytest.approx(sign * 12.0, abs=1e-9)
    assert math.degrees(math.atan2(u[1], u[0])) == pytest.approx(30.0, abs=1e-9)
    assert np.linalg.norm(u) == pytest.approx(1.0, abs=1e-12)
    # what the slack adds over the stop from the speed the near field allows (1.4 m/s)
    # stays inside the section's half-height
    cfg = EnvelopeConfig()
    v = 1.4
    assert CLIMB_SLACK_MPS * (cfg.latency_s + v / cfg.accel_mps2) < cfg.vehicle_half_height_m


@pytest.mark.parametrize(
    "vel",
    [
        _vel(0.3, 0.3 * TAN_E + CLIMB_SLACK_MPS + 0.02),  # steeper than the slack explains
        _vel(0.0, 0.5),  # straight up
        _vel(0.5, 0.05),  # within the path's slope
        _vel(0.5, -0.5),  # a steep descent
    ],
)
def test_any_other_velocity_keeps_its_own_direction(vel):
    u = brake_direction(vel, ELEV_RAD)
    np.testing.assert_allclose(u, vel / np.linalg.norm(vel), atol=1e-12)


def _free_seen_at_12_deg_north(pos, unit, radius_m, limit_m, half_height_m, body_m, near_m):
    """The near field's 1.0 m along north at ≤ 12.5° up, the body's 0.3 m elsewhere."""
    north = unit[0] / max(math.hypot(unit[0], unit[1]), 1e-12)
    flat_enough = _elev_deg(unit) <= 12.5 and north > 0.999
    return min(limit_m, 1.0 if flat_enough else 0.3)


def test_braking_on_a_slow_staged_climb_states_a_bound_it_flies_within():
    """Guidance turned east (unseen: 0.3 m), the vehicle climbs north at 0.4 m/s, 22°:
    step 5 brakes; the bound is the one along the 12° north direction the stage had
    certified, above the speed, not 0 m/s."""
    vel = _vel(0.37, 0.37 * TAN_E + 0.09)
    out = envelope_step(
        pos_ned_m=np.zeros(3), vel_ned_mps=vel, setpoint_ned_m=np.array([0.0, 3.0, -0.5]),
        free_distance=_free_seen_at_12_deg_north, vehicle_radius_m=0.35,
        max_path_elevation_rad=ELEV_RAD, heading_rad=0.0,
    )  # fmt: skip
    assert out.free_distance_m == pytest.approx(1.0)
    assert _elev_deg(out.path_dir_ned) == pytest.approx(12.0, abs=1e-9)
    assert out.speed_limit_mps > out.speed_mps and not out.overspeed
    np.testing.assert_allclose(out.setpoint_ned_m, np.zeros(3), atol=1e-12)  # it brakes


def test_a_climb_the_statement_does_not_explain_still_reads_as_overspeed():
    vel = _vel(0.8, 1.2)  # 56° up, 1.44 m/s: nothing was stated that lets it climb so
    out = envelope_step(
        pos_ned_m=np.zeros(3), vel_ned_mps=vel, setpoint_ned_m=np.array([0.0, 3.0, -0.5]),
        free_distance=_free_seen_at_12_deg_north, vehicle_radius_m=0.35,
        max_path_elevation_rad=ELEV_RAD, heading_rad=0.0,
    )  # fmt: skip
    np.testing.assert_allclose(out.path_dir_ned, vel / np.linalg.norm(vel), atol=1e-12)
    assert out.free_distance_m == pytest.approx(0.3)
    # its stop (0.73 m) does not fit in the 0.3 m seen free along it: over the bound
    assert out.speed_limit_mps == pytest.approx(2.0 * (-0.15 + math.sqrt(0.0225 + 0.3)))
    assert out.overspeed
