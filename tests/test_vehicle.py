"""Closed-loop behaviour of the paper's quadrotor under FL + LQ control (NED interface)."""

import dataclasses
import math

import numpy as np
import pytest

from plant_sim.params import ControlParams, QuadrotorParams
from plant_sim.vehicle import Quadrotor, Setpoint
from protocols import frames

P = QuadrotorParams()
MG = P.mass_kg * P.gravity_mps2


def test_hover_is_an_exact_equilibrium():
    q = Quadrotor(pos_ned_m=(0.0, 0.0, -7.0))
    q.run_until(10.0)
    s = q.snapshot()
    assert s.rotor_thrusts_n.sum() == pytest.approx(MG, rel=1e-9)
    np.testing.assert_allclose(s.rotor_thrusts_n, MG / 4, rtol=1e-9)
    assert np.linalg.norm(s.pos_ned_m - (0.0, 0.0, -7.0)) < 1e-3
    assert s.time_s == pytest.approx(10.0)


def test_rotors_off_falls_at_g_to_drag_terminal_speed():
    q = Quadrotor(pos_ned_m=(0.0, 0.0, -100.0), ground_down_m=None, armed=False)
    dt = q.dt_s
    q.step(1)
    # first step from rest: Δz = ½ g dt² (RK4 is exact for the quadratic start, up to drag)
    assert q.vel_ned_mps[2] == pytest.approx(P.gravity_mps2 * dt, rel=0.01)
    q.run_until(3.0)  # 18 drag time constants m/k_tz = 0.1625 s
    terminal = P.mass_kg * P.gravity_mps2 / P.drag_force_kgps[2]
    assert q.vel_ned_mps[2] == pytest.approx(terminal, rel=1e-6)
    np.testing.assert_allclose(q.vel_ned_mps[:2], 0.0, atol=1e-12)


def test_ground_stops_a_disarmed_vehicle():
    q = Quadrotor(pos_ned_m=(0.0, 0.0, -2.0), armed=False)
    q.run_until(3.0)
    s = q.snapshot()
    assert s.on_ground
    assert s.pos_ned_m[2] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(s.vel_ned_mps, 0.0, atol=1e-12)


def test_paper_leg_without_obstacle():
    """(20, 0, −7) → (0, 0, −7): the §6 leg with no obstacle.

    Measured with the default parameters: the ±15° pitch limit saturates for ~21 s at a
    cruise speed of 0.854 m/s (drag-limited: m g tan15° ≈ k_t v), the vehicle is within
    0.1 m after ~25.9 s and altitude stays within 0.3 mm of 7 m.
    """
    q = Quadrotor(pos_ned_m=(20.0, 0.0, -7.0))
    q.set_setpoint(Setpoint(pos_ned_m=(0.0, 0.0, -7.0)))
    max_tilt_rad = math.radians(15.0)
    steps = q.control.steps_per_control
    settled_at = None
    max_alt_err = 0.0
    max_cmd = 0.0
    while q.time_s < 45.0:
        q.step(steps)
        s = q.snapshot()
        max_cmd = max(max_cmd, abs(s.roll_cmd_rad), abs(s.pitch_cmd_rad))
        assert np.all(s.rotor_thrusts_n <= P.rotor_thrust_max_n)
        assert np.all(s.rotor_thrusts_n >= P.rotor_thrust_min_n)
        assert not s.rotor_saturated, f"rotor limit hit at t={s.time_s:.2f}"
        max_alt_err = max(max_alt_err, abs(s.pos_ned_m[2] + 7.0))
        err = np.linalg.norm(s.pos_ned_m - (0.0, 0.0, -7.0))
        if err < 0.1 and settled_at is None:
            settled_at = s.time_s
        elif err >= 0.1:
            settled_at = None
    assert max_cmd <= max_tilt_rad + 1e-12
    assert max_cmd == pytest.approx(max_tilt_rad, abs=1e-9)  # the limit did engage
    assert settled_at is not None
    assert 22.0 < settled_at < 30.0, settled_at
    assert max_alt_err < 0.01
    assert np.linalg.norm(q.pos_ned_m - (0.0, 0.0, -7.0)) < 0.01


def test_yaw_step_90_deg():
    """A 90° heading step in hover: tracked in ~3 s, the position moves less than 1 cm."""
    q = Quadrotor(pos_ned_m=(0.0, 0.0, -7.0))
    q.set_setpoint(Setpoint(pos_ned_m=(0.0, 0.0, -7.0), yaw_rad=math.pi / 2))
    max_excursion = 0.0
    while q.time_s < 8.0:
        q.step(q.control.steps_per_control)
        max_excursion = max(max_excursion, np.linalg.norm(q.pos_ned_m - (0.0, 0.0, -7.0)))
    s = q.snapshot()
    assert s.yaw_rad == pytest.approx(math.pi / 2, abs=1e-3)
    assert max_excursion < 0.01


@pytest.mark.parametrize("yaw_deg", [0.0, 45.0, 135.0, -100.0, 180.0])
def test_tilt_clamp_is_on_vehicle_roll_and_pitch_at_any_heading(yaw_deg):
    """A far diagonal target saturates MAVLink roll and pitch at exactly ±15°, whatever
    the heading, and the commanded attitude keeps the commanded heading."""
    yaw = math.radians(yaw_deg)
    q = Quadrotor(pos_ned_m=(0.0, 0.0, -7.0), yaw_rad=yaw)
    q.set_setpoint(Setpoint(pos_ned_m=(30.0, 40.0, -7.0), yaw_rad=yaw))
    q.run_until(0.5)
    s = q.snapshot()
    assert s.tilt_saturated
    limit = math.radians(15.0)
    assert max(abs(s.roll_cmd_rad), abs(s.pitch_cmd_rad)) == pytest.approx(limit, abs=1e-12)
    np.testing.assert_allclose(q.tilt_cmd_rad(), (s.roll_cmd_rad, s.pitch_cmd_rad), atol=1e-12)
    assert abs(s.roll_cmd_rad) <= limit + 1e-12
    assert abs(s.pitch_cmd_rad) <= limit + 1e-12
    assert math.remainder(s.yaw_cmd_rad - yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
    # the commanded thrust leans toward the target: its horizontal part points into the
    # quadrant of (30, 40) seen from the vehicle
    thrust_ned = frames.rotation_321(s.roll_cmd_rad, s.pitch_cmd_rad, s.yaw_cmd_rad) @ [0, 0, -1]
    assert thrust_ned[0] > 0 and thrust_ned[1] > 0


def test_unsaturated_thrust_direction_equals_desired_acceleration():
    """Small step, tilt not saturated: thrust direction ∥ (a_des + g) in NED at any yaw."""
    q = Quadrotor(pos_ned_m=(0.0, 0.0, -7.0), yaw_rad=math.radians(60))
    q.set_setpoint(Setpoint(pos_ned_m=(0.3, -0.2, -7.0)))
    q.step(1)
    s = q.snapshot()
    assert not s.tilt_saturated
    k1 = 2**0.5  # Eq. (34) position gain; at rest only the position term acts
    a_des = -k1 * (s.pos_ned_m - np.array([0.3, -0.2, -7.0])) - np.array([0, 0, P.gravity_mps2])
    thrust_ned = frames.rotation_321(s.roll_cmd_rad, s.pitch_cmd_rad, s.yaw_cmd_rad) @ [0, 0, -1]
    np.testing.assert_allclose(thrust_ned, a_des / np.linalg.norm(a_des), atol=1e-4)


def test_velocity_setpoint_tracks_speed_and_direction():
    q = Quadrotor(pos_ned_m=(0.0, 0.0, -7.0))
    q.set_setpoint(Setpoint(vel_ned_mps=(0.0, 0.5, 0.0)))
    q.run_until(10.0)
    np.testing.assert_allclose(q.vel_ned_mps, (0.0, 0.5, 0.0), atol=1e-3)


def test_takeoff_from_ground():
    q = Quadrotor(pos_ned_m=(0.0, 0.0, 0.0))
    q.run_until(1.0)
    assert q.snapshot().on_ground
    q.set_setpoint(Setpoint(pos_ned_m=(0.0, 0.0, -7.0)))
    q.run_until(15.0)
    assert q.pos_ned_m[2] == pytest.approx(-7.0, abs=0.05)


def test_setpoint_rejects_nan():
    with pytest.raises(ValueError, match="pos_ned_m"):
        Setpoint(pos_ned_m=(0.0, math.nan, 0.0))


def test_faster_control_rate_gives_the_same_trajectory():
    """Halving the physics step changes the leg by far less than the 0.1 m arrival bound."""
    a = Quadrotor(pos_ned_m=(5.0, 0.0, -7.0))
    b = Quadrotor(
        control=dataclasses.replace(ControlParams(), physics_rate_hz=800, control_rate_hz=800),
        pos_ned_m=(5.0, 0.0, -7.0),
    )
    for q in (a, b):
        q.set_setpoint(Setpoint(pos_ned_m=(0.0, 0.0, -7.0)))
        q.run_until(4.0)
    np.testing.assert_allclose(a.pos_ned_m, b.pos_ned_m, atol=5e-3)
