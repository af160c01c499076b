"""Safety envelope: carrot inside known-free space, speed limit from the stopping distance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.guidance.config import GuidanceConfig
from companion.guidance.envelope import (
    EnvelopeConfig,
    envelope_step,
    speed_limit_mps,
    stopping_distance_m,
)
from companion.perception import PerceptionConfig

CFG = EnvelopeConfig()
# the vehicle's section and path limit come from perception and guidance (one value each)
SECTION = {
    "vehicle_radius_m": PerceptionConfig().vehicle_radius_m,
    "max_path_elevation_rad": GuidanceConfig().max_aim_elevation_rad,
}


def _const_free(free_m: float):
    calls = []

    def free(pos, direction, radius_m, limit_m, half_height_m, body_m, near_field_m):
        calls.append((np.array(pos), np.array(direction), radius_m, limit_m, half_height_m))
        return min(free_m, limit_m)

    free.calls = calls
    return free


def test_stopping_distance_closed_form():
    # τ v + v²/(2a): 0.15·2 + 4/4 = 1.3 m
    assert stopping_distance_m(2.0, 0.15, 2.0) == pytest.approx(1.3)
    assert stopping_distance_m(0.0, 0.15, 2.0) == 0.0


@pytest.mark.parametrize("free_m", [0.31, 1.0, 4.0, 8.0, 30.0])
def test_speed_limit_is_the_inverse_of_the_stopping_distance(free_m):
    v = speed_limit_mps(free_m, CFG.latency_s, CFG.accel_mps2, CFG.margin_m)
    assert v > 0.0
    assert stopping_distance_m(v, CFG.latency_s, CFG.accel_mps2) + CFG.margin_m == (
        pytest.approx(free_m, rel=1e-12)
    )
    assert speed_limit_mps(CFG.margin_m, CFG.latency_s, CFG.accel_mps2, CFG.margin_m) == 0.0
    # faster than the limit does not fit, slower does
    over = stopping_distance_m(1.01 * v, CFG.latency_s, CFG.accel_mps2) + CFG.margin_m
    assert over > free_m


@pytest.mark.parametrize("speed_mps", [0.0, 0.85, 2.0, 4.0])
@pytest.mark.parametrize("free_m", [0.2, 1.0, 3.0, 6.0])
def test_carrot_plus_stopping_distance_stays_inside_known_free_space(speed_mps, free_m):
    pos = np.array([20.0, 0.0, -7.0])
    goal = np.array([0.0, 0.0, -7.0])
    out = envelope_step(
        **SECTION,
        pos_ned_m=pos,
        vel_ned_mps=(-speed_mps, 0.0, 0.0),
        setpoint_ned_m=goal,
        free_distance=_const_free(free_m),
    )
    reach = float(np.linalg.norm(out.setpoint_ned_m - pos))
    d_stop = stopping_distance_m(speed_mps, CFG.latency_s, CFG.accel_mps2)
    assert out.limited
    assert reach + d_stop + CFG.margin_m <= free_m + 1e-9 or reach == 0.0
    assert reach == pytest.approx(max(0.0, free_m - d_stop - CFG.margin_m), abs=CFG.min_advance_m)
    # on the straight line to the goal, never beyond it
    np.testing.assert_allclose(out.setpoint_ned_m[1:], pos[1:], atol=1e-12)
    assert out.setpoint_ned_m[0] <= pos[0]
    assert out.free_distance_m == free_m
    assert out.overspeed == (speed_mps > out.speed_limit_mps + CFG.overspeed_tolerance_mps)


def test_goal_inside_known_free_space_is_the_setpoint():
    pos = np.array([0.0, 0.0, -7.0])
    goal = np.array([2.0, 1.0, -7.0])
    out = envelope_step(
        **SECTION,
        pos_ned_m=pos,
        vel_ned_mps=(0, 0, 0),
        setpoint_ned_m=goal,
        free_distance=_const_free(8.0),
    )
    assert not out.limited
    np.testing.assert_array_equal(out.setpoint_ned_m, goal)
    assert out.speed_limit_mps == pytest.approx(
        speed_limit_mps(8.0, CFG.latency_s, CFG.accel_mps2, CFG.margin_m)
    )


def test_steep_climb_is_tilted_to_the_path_elevation_limit():
    pos = np.array([0.0, 0.0, -7.0])
    goal = np.array([3.0, 0.0, -17.0])  # 73° up
    free = _const_free(2.0)
    out = envelope_step(
        **SECTION, pos_ned_m=pos, vel_ned_mps=(0, 0, 0), setpoint_ned_m=goal, free_distance=free
    )
    u = out.path_dir_ned
    elev = math.degrees(math.atan2(-u[2], math.hypot(u[0], u[1])))
    assert elev == pytest.approx(math.degrees(SECTION["max_path_elevation_rad"]))
    assert u[0] > 0 and u[1] == 0.0
    # the query used the vehicle's section
    _, _, radius, _, half_height = free.calls[-1]
    assert (radius, half_height) == (SECTION["vehicle_radius_m"], CFG.vehicle_half_height_m)


def test_too_little_room_brakes_at_the_current_position():
    pos = np.array([1.0, 2.0, -3.0])
    out = envelope_step(
        **SECTION,
        pos_ned_m=pos,
        vel_ned_mps=(0.5, 0, 0),
        setpoint_ned_m=(10.0, 2.0, -3.0),
        free_distance=_const_free(CFG.margin_m + 0.05),
    )
    np.testing.assert_array_equal(out.setpoint_ned_m, pos)
    assert out.limited
    # braking, the bound keeps no margin: 2·(−0.15 + √(0.0225 + 0.35)) = 0.92 m/s, whose
    # stop ends at the edge of the 0.35 m seen free; at 0.5 m/s the stop (0.14 m) fits
    assert out.speed_limit_mps == pytest.approx(2.0 * (-0.15 + math.sqrt(0.0225 + 0.35)))
    assert not out.overspeed


def _free_by_direction(free_of):
    """A map whose free distance depends on the direction only: ``free_of(unit) -> m``."""

    def free(pos, direction, radius_m, limit_m, half_height_m, body_m, near_field_m):
        return min(free_of(np.asarray(direction)), limit_m)

    return free


NORTH_OPEN = _free_by_direction(lambda u: 8.0 if u[0] > 0.9 else 1.0)  # 8 m ahead, 1 m aside


def test_a_turn_at_speed_brakes_first_and_states_the_bound_of_the_way_it_moves():
    """3 m/s north (8 m free), guidance turns east (1 m free, 1.4 m/s there): the vehicle
    cannot take the new direction at this speed, so it brakes (carrot at the vehicle) and
    the stated bound is the one along its motion, which its speed obeys."""
    pos = np.array([0.0, 0.0, -7.0])
    out = envelope_step(
        **SECTION,
        pos_ned_m=pos,
        vel_ned_mps=(3.0, 0.0, 0.0),
        setpoint_ned_m=(0.0, 5.0, -7.0),
        free_distance=NORTH_OPEN,
    )
    np.testing.assert_array_equal(out.setpoint_ned_m, pos)
    np.testing.assert_allclose(out.path_dir_ned, (1.0, 0.0, 0.0))
    assert out.free_distance_m == 8.0
    v8 = speed_limit_mps(8.0, CFG.latency_s, CFG.accel_mps2, 0.0)  # braking: no margin
    assert out.speed_limit_mps == pytest.approx(v8)
    assert out.speed_mps <= out.speed_limit_mps and not out.overspeed
    # slow enough for the new direction: it turns, with that direction's bound
    slow = envelope_step(
        **SECTION,
        pos_ned_m=pos,
        vel_ned_mps=(0.5, 0.0, 0.0),
        setpoint_ned_m=(0.0, 5.0, -7.0),
        free_distance=NORTH_OPEN,
    )
    assert slow.speed_limit_mps == pytest.approx(
        speed_limit_mps(1.0, CFG.latency_s, CFG.accel_mps2, CFG.margin_m)
    )
    assert slow.path_dir_ned[1] == pytest.approx(1.0)


def test_a_hold_entered_at_speed_states_the_bound_it_brakes_in():
    """The setpoint is the vehicle's position (a latched hold) at 2 m/s: the bound is the
    one along the motion (was 0 m/s: every hold at speed read as an overspeed)."""
    pos = np.array([0.0, 0.0, -7.0])
    out = envelope_step(
        **SECTION,
        pos_ned_m=pos,
        vel_ned_mps=(2.0, 0.0, 0.0),
        setpoint_ned_m=pos,
        free_distance=NORTH_OPEN,
    )
    np.testing.assert_array_equal(out.setpoint_ned_m, pos)
    assert out.speed_limit_mps == pytest.approx(
        speed_limit_mps(8.0, CFG.latency_s, CFG.accel_mps2, 0.0)
    )
    assert not out.overspeed


def test_space_shrinking_ahead_at_speed_is_reported_as_overspeed():
    """Everything ahead 1 m free at 3 m/s (something new seen): brake, and the stated
    bound (1.72 m/s: the stop in 1 m, the margin being the brake's reserve) is honest, so
    the speed is reported over it."""
    pos = np.array([0.0, 0.0, -7.0])
    out = envelope_step(
        **SECTION,
        pos_ned_m=pos,
        vel_ned_mps=(3.0, 0.0, 0.0),
        setpoint_ned_m=(10.0, 0.0, -7.0),
        free_distance=_const_free(1.0),
    )
    np.testing.assert_array_equal(out.setpoint_ned_m, pos)
    assert out.speed_limit_mps == pytest.approx(
        speed_limit_mps(1.0, CFG.latency_s, CFG.accel_mps2, 0.0)
    )
    assert out.overspeed


@pytest.mark.parametrize("speed_mps", [0.31, 0.5, 0.8])
def test_a_drop_to_the_body_bubble_while_slow_states_a_stop_that_fits(speed_mps):
    """Known-free space ahead drops to the body's own 0.3 m (the margin) at a slow speed
    (a staged climb entering the voxel layer above, vertical-123 stereo): the vehicle
    brakes, and the bound stated is the fastest speed whose stop ends inside those 0.3 m,
    0.84 m/s, not 0 m/s; its own stop fits, so it is not reported over it."""
    pos = np.array([0.0, 0.0, -7.0])
    out = envelope_step(
        **SECTION,
        pos_ned_m=pos,
        vel_ned_mps=(speed_mps, 0.0, 0.0),
        setpoint_ned_m=(10.0, 0.0, -7.0),
        free_distance=_const_free(CFG.margin_m),
    )
    np.testing.assert_array_equal(out.setpoint_ned_m, pos)  # it brakes
    v_fit = speed_limit_mps(CFG.margin_m, CFG.latency_s, CFG.accel_mps2, 0.0)
    assert out.speed_limit_mps == pytest.approx(v_fit)
    assert stopping_distance_m(v_fit, CFG.latency_s, CFG.accel_mps2) == pytest.approx(CFG.margin_m)
    assert stopping_distance_m(speed_mps, CFG.latency_s, CFG.accel_mps2) <= CFG.margin_m
    assert not out.overspeed


def _blind_column(free_m: float):
    """``free_m`` known free along every direction up to the path limit, the body's own
    0.3 m steeper and straight up and down (step 7b flies a column or a steeper stage
    known free, tests/test_envelope_vertical_leg.py)."""

    def free(pos, direction, radius_m, limit_m, half_height_m, body_m, near_field_m):
        elev = math.atan2(abs(float(direction[2])), math.hypot(direction[0], direction[1]))
        steeper = elev > SECTION["max_path_elevation_rad"] + 1e-9
        return min(0.3 if steeper else free_m, limit_m)

    return free


@pytest.mark.parametrize("rise_m", [5.0, -4.0])
def test_a_goal_straight_above_or_below_is_flown_in_stages_along_the_heading(rise_m):
    """Straight up or down (2 cm aside) facing east, the column itself not seen free: the
    path climbs or descends at the path limit along the heading, where the camera looks,
    and the carrot stops inside the known-free space (a stage); without a heading the old
    purely vertical path."""
    pos = np.array([0.0, 0.0, -7.0])
    goal = pos + np.array([0.02, 0.0, -rise_m])
    elev = SECTION["max_path_elevation_rad"]
    out = envelope_step(
        **SECTION, pos_ned_m=pos, vel_ned_mps=(0, 0, 0), setpoint_ned_m=goal,
        free_distance=_blind_column(3.0), heading_rad=0.5 * math.pi,
    )  # fmt: skip
    expected = (0.0, math.cos(elev), -math.copysign(math.sin(elev), rise_m))
    np.testing.assert_allclose(out.path_dir_ned, expected, atol=1e-12)
    reach = float(np.linalg.norm(out.setpoint_ned_m - pos))
    assert reach == pytest.approx(3.0 - CFG.margin_m)  # the stage ends in known-free space
    assert out.limited
    # a stage never takes the vehicle past the goal's altitude: 0.6 m to go, 10 m free
    near = goal + np.array([0.0, 0.0, math.copysign(0.6, rise_m)])
    out = envelope_step(
        **SECTION, pos_ned_m=near, vel_ned_mps=(0, 0, 0), setpoint_ned_m=goal,
        free_distance=_blind_column(10.0), heading_rad=0.5 * math.pi,
    )  # fmt: skip
    assert abs(out.setpoint_ned_m[2] - near[2]) < 0.6
    assert np.sign(out.setpoint_ned_m[2] - near[2]) == np.sign(goal[2] - near[2])
    above = pos - np.array([0.0, 0.0, rise_m])
    plain = envelope_step(
        **SECTION, pos_ned_m=pos, vel_ned_mps=(0, 0, 0), setpoint_ned_m=above,
        free_distance=_const_free(3.0),
    )  # fmt: skip
    np.testing.assert_allclose(plain.path_dir_ned, (0.0, 0.0, -math.copysign(1.0, rise_m)))


def test_config_rejects_unknown_keys_and_bad_values():
    with pytest.raises(TypeError, match="latency_ms"):
        EnvelopeConfig.from_dict({"latency_ms": 5})
    with pytest.raises(ValueError):
        EnvelopeConfig(accel_mps2=0.0)
    with pytest.raises(ValueError):
        EnvelopeConfig(margin_m=-1.0)


def test_companion_config_sections_for_the_map_and_the_envelope():
    from companion.config import ConfigError, config_from_dict

    cfg = config_from_dict({"envelope": {"accel_mps2": 3.0}, "known_space": {"voxel_m": 0.1}})
    assert cfg.envelope.accel_mps2 == 3.0 and cfg.known_space.voxel_m == 0.1
    with pytest.raises(ConfigError, match="accel"):
        config_from_dict({"envelope": {"accel": 3.0}})
