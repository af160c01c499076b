"""plant-sim's proximity driver, simple avoidance, Collision Prevention and pilot sticks
against ArduPilot's and PX4's rules and closed forms (pure, no processes)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from plant_sim.autopilot.collision_prevention import (
    CpParams,
    constrain_velocity,
    max_speed_from_distance,
)
from plant_sim.autopilot.pilot_input import PilotInput
from plant_sim.autopilot.proximity import PROXIMITY_TIMEOUT_S, Face, ProximityReceiver
from plant_sim.autopilot.simple_avoid import (
    AvoidParams,
    SimpleAvoid,
    adjust_roll_pitch,
    sqrt_controller,
)

M = mavlink


def _obstacle_distance(distances_cm, *, inc=5.0, offset=0.0, frame=M.MAV_FRAME_BODY_FRD):
    d = list(distances_cm) + [65535] * (72 - len(distances_cm))
    return M.MAVLink_obstacle_distance_message(0, 0, d, 0, 20, 620, inc, offset, frame)


def _wall_sectors(d_m: float, alpha_deg: float) -> list[int]:
    """72 × 5° sectors of a wall at distance d whose normal points to bearing α (body)."""
    out = []
    for k in range(72):
        off = abs((5.0 * k - alpha_deg + 180.0) % 360.0 - 180.0)
        out.append(round(100 * d_m / math.cos(math.radians(off))) if off < 80 else 621)
    return [min(v, 621) for v in out]


# ---- the proximity driver -------------------------------------------------------------


def test_ardupilot_faces_keep_the_nearest_reading_of_each_45_degree_face():
    rx = ProximityReceiver()
    assert rx.on_message(_obstacle_distance(_wall_sectors(3.0, 30.0)), 10.0) is None
    faces = rx.ardupilot_faces(10.1)
    nearest = min(faces, key=lambda f: f.distance_m)
    assert nearest.distance_m == pytest.approx(3.0)
    assert math.degrees(nearest.bearing_rad) == pytest.approx(30.0)
    # only faces that see the wall within the 6.2 m range (|θ − 30°| < acos(3 / 6.2))
    reach_deg = math.degrees(math.acos(3.0 / 6.2))
    for f in faces:
        assert abs((math.degrees(f.bearing_rad) - 30.0 + 180.0) % 360.0 - 180.0) < reach_deg
    assert len({round(math.degrees(f.bearing_rad) / 45.0) % 8 for f in faces}) == len(faces)
    assert rx.ardupilot_faces(10.0 + PROXIMITY_TIMEOUT_S + 0.01) == []  # No Data


def test_ardupilot_ignores_unknown_zero_and_out_of_range_and_the_frame_field():
    rx = ProximityReceiver()
    msg = _obstacle_distance([65535, 0, 10, 621, 300], frame=M.MAV_FRAME_LOCAL_NED)
    rx.on_message(msg, 0.0)
    faces = rx.ardupilot_faces(0.0)
    assert [(round(math.degrees(f.bearing_rad)), f.distance_m) for f in faces] == [(20, 3.0)]


def test_ardupilot_faces_lag_an_approach_by_v_over_2_pi_prx_filt():
    """PRX_FILT (0.25 Hz): closing at v, a face's filtered distance lags the reading by
    v / (2π·fc) (the discrete filter's ramp error is exactly v·dt·(1 − α)/α = v·RC); a
    face last set 1 s ago or more restarts from the reading; PRX_FILT 0 is the reading."""
    v, rate_hz = 2.0, 20.0
    for filter_hz, lag_m in ((0.25, v / (2.0 * math.pi * 0.25)), (0.0, 0.0)):
        rx = ProximityReceiver()
        rx.filter_hz = filter_hz
        for i in range(200):  # 10 s: many time constants (0.64 s)
            t = i / rate_hz
            rx.on_message(_obstacle_distance([round(100 * (5.0 - v * t / 5.0))]), t)
        d_now = 5.0 - v * (199 / rate_hz) / 5.0  # the last reading [m]
        (face,) = rx.ardupilot_faces(199 / rate_hz)
        v_reading = v / 5.0  # the readings close at v / 5 here (they stay within range)
        expect = d_now + lag_m * v_reading / v
        assert face.distance_m == pytest.approx(expect, abs=0.01 + 0.005 * expect)
    rx = ProximityReceiver()
    rx.on_message(_obstacle_distance([500]), 0.0)
    rx.on_message(_obstacle_distance([65535]), 0.1)  # the face reset: no reading
    rx.on_message(_obstacle_distance([300]), 1.2)  # set 1.2 s after its last reading
    assert rx.ardupilot_faces(1.2)[0].distance_m == pytest.approx(3.0)
    rx.on_message(_obstacle_distance([200]), 1.25)  # 50 ms later: filtered
    alpha = 0.05 / (0.05 + 1.0 / (2.0 * math.pi * 0.25))
    assert rx.ardupilot_faces(1.25)[0].distance_m == pytest.approx(3.0 - alpha * 1.0)


def test_px4_bins_map_the_message_and_local_ned_is_turned_by_yaw():
    rx = ProximityReceiver()
    rx.on_message(_obstacle_distance([300] + [65535] * 71), 0.0)
    bins, range_m = rx.px4_bins(0.1, yaw_rad=0.0)
    assert range_m == pytest.approx(6.2)
    assert bins[0] == pytest.approx(3.0) and np.isinf(bins[1:]).all()
    north = [65535] * 72
    north[0] = 300  # an obstacle due north, in a LOCAL_NED message
    rx.on_message(_obstacle_distance(north, frame=M.MAV_FRAME_LOCAL_NED), 0.0)
    bins, _ = rx.px4_bins(0.0, yaw_rad=math.radians(90.0))  # heading east
    assert np.flatnonzero(np.isfinite(bins)).tolist() == [54]  # 270° body: on the left


def test_bad_messages_are_dropped_and_counted():
    rx = ProximityReceiver()
    assert rx.on_message(_obstacle_distance([300], inc=0.0), 0.0) is not None
    assert rx.on_message(_obstacle_distance([300], offset=math.nan), 0.0) is not None
    assert rx.dropped == 2 and rx.received == 0 and not rx.fresh(0.0)


# ---- ArduCopter's simple avoidance ----------------------------------------------------


@pytest.mark.parametrize("error", [0.2, 0.9, 1.0, 3.0, 10.0])
def test_sqrt_controller_is_linear_then_constant_deceleration(error):
    p, a = 1.0, 1.0
    expect = error * p if error <= a / p**2 else math.sqrt(2 * a * (error - a / (2 * p**2)))
    assert sqrt_controller(error, p, a, 0.0) == pytest.approx(expect)
    assert sqrt_controller(-error, p, a, 0.0) == pytest.approx(-expect)


def test_slide_limits_only_the_component_toward_the_obstacle():
    """Wall 3 m ahead (north, vehicle facing north), margin 2 m: the northward speed is
    capped at sqrt_controller(1 m, 1, 1 m/s²) = 1 m/s; eastward speed is kept."""
    avoid = SimpleAvoid()
    params = AvoidParams(proximity=True, margin_m=2.0, accel_max_mps2=0.0)
    out = avoid.adjust((5.0, 2.0), 0.0, [Face(0.0, 3.0)], params, 0.0, 0.02)
    assert out == pytest.approx((1.0, 2.0))
    assert avoid.active


def test_stop_does_not_turn_the_velocity_and_stops_inside_the_margin():
    params = AvoidParams(proximity=True, margin_m=2.0, stop=True, accel_max_mps2=0.0)
    out = SimpleAvoid().adjust((5.0, 2.0), 0.0, [Face(0.0, 1.95)], params, 0.0, 0.02)
    assert out == (0.0, 0.0)
    far = SimpleAvoid().adjust((0.0, 3.0), 0.0, [Face(0.0, 4.0)], params, 0.0, 0.02)
    assert far == (0.0, 3.0)  # moving parallel to the wall: the path never nears it


def test_inside_the_margin_it_backs_away_at_most_backup_speed():
    params = AvoidParams(proximity=True, margin_m=2.0, accel_max_mps2=0.0)
    out = SimpleAvoid().adjust((0.0, 0.0), 0.0, [Face(0.0, 1.0)], params, 0.0, 0.02)
    assert out == pytest.approx((-0.75, 0.0))  # AVOID_BACKUP_SPD
    # a small breach backs away at sqrt_controller(breach, kP, 0.4 · accel), ArduPilot's
    # calc_backup_velocity_2D: linear kP·breach below 0.4 m, √(2·0.4·(b − 0.2)) above
    for face_m, speed in ((1.7, 0.3), (1.4, math.sqrt(2 * 0.4 * (0.6 - 0.2)))):
        out = SimpleAvoid().adjust((0.0, 0.0), 0.0, [Face(0.0, face_m)], params, 0.0, 0.02)
        assert out == pytest.approx((-speed, 0.0)), face_m


def test_avoid_accel_max_limits_the_change_of_velocity():
    avoid = SimpleAvoid()
    params = AvoidParams(proximity=True, margin_m=2.0, accel_max_mps2=3.0)
    out = avoid.adjust((5.0, 0.0), 0.0, [Face(0.0, 3.0)], params, 0.0, 0.1)
    assert out == pytest.approx((5.0 - 3.0 * 0.1, 0.0))


def test_without_proximity_or_data_nothing_changes():
    faces = [Face(0.0, 2.5)]
    assert SimpleAvoid().adjust((5.0, 0.0), 0.0, faces, AvoidParams(), 0.0, 0.02) == (5.0, 0.0)
    on = AvoidParams(proximity=True)
    assert SimpleAvoid().adjust((5.0, 0.0), 0.0, [], on, 0.0, 0.02) == (5.0, 0.0)


def test_alt_hold_leans_away_by_45_deg_times_closeness_capped_at_avoid_angle_max():
    """AC_Avoid::adjust_roll_pitch: a face at d < AVOID_DIST_MAX (5 m) leans the vehicle
    away by 45°·(1 − d/5), at most min(AVOID_ANGLE_MAX, 0.75·ANGLE_MAX), added to the
    pilot's lean; the total at most ANGLE_MAX."""
    on = AvoidParams(proximity=True)  # AVOID_ANGLE_MAX 10°, AVOID_DIST_MAX 5 m
    big = math.radians(35.0)
    deg = math.radians
    # ahead at 4.5 m: 4.5° nose up; the pilot's 3° forward becomes 1.5° up
    r, p = adjust_roll_pitch(0.0, -deg(3.0), big, [Face(0.0, 4.5)], on)
    assert (r, p) == pytest.approx((0.0, deg(4.5 - 3.0)))
    # ahead at 2.5 m: 22.5° asked, 10° given: the pilot's 20° forward is left at 10°
    r, p = adjust_roll_pitch(0.0, -deg(20.0), big, [Face(0.0, 2.5)], on)
    assert (r, p) == pytest.approx((0.0, -deg(10.0)))
    # at 45° right, 4 m: 9° away, along the bearing (roll left and pitch up alike)
    r, p = adjust_roll_pitch(0.0, 0.0, big, [Face(deg(45.0), 4.0)], on)
    assert (r, p) == pytest.approx((-deg(9.0) / math.sqrt(2), deg(9.0) / math.sqrt(2)))
    # walls on both sides at once: the left and right leans cancel (positive + negative)
    both = [Face(deg(90.0), 3.0), Face(deg(270.0), 3.0)]
    assert adjust_roll_pitch(0.0, 0.0, big, both, on) == pytest.approx((0.0, 0.0))
    # 0.75·ANGLE_MAX caps a small airframe's lean: ANGLE_MAX 8° → 6°
    r, p = adjust_roll_pitch(0.0, 0.0, deg(8.0), [Face(0.0, 1.0)], on)
    assert p == pytest.approx(deg(6.0))
    # the total at most ANGLE_MAX: 33° back-roll pilot + 10° avoidance → 35°
    r, p = adjust_roll_pitch(0.0, deg(33.0), big, [Face(0.0, 1.0)], on)
    assert p == pytest.approx(big)
    # nothing beyond AVOID_DIST_MAX, nothing without proximity avoidance
    assert adjust_roll_pitch(0.1, -0.2, big, [Face(0.0, 5.0)], on) == (0.1, -0.2)
    assert adjust_roll_pitch(0.1, -0.2, big, [Face(0.0, 1.0)], AvoidParams()) == (0.1, -0.2)


# ---- PX4's Collision Prevention ------------------------------------------------------


def test_max_speed_from_distance_tends_to_sqrt_2ad_for_a_large_jerk():
    assert max_speed_from_distance(1e9, 3.0, 6.0, 0.0) == pytest.approx(6.0, rel=1e-6)
    v = max_speed_from_distance(8.0, 3.0, 6.0, 0.0)
    # PX4's jerk-limited stop from v covers v²/(2a) + 2·a·v/j: exactly the 6 m
    assert v * v / 6.0 + 2.0 * 3.0 * v / 8.0 == pytest.approx(6.0, rel=1e-6)


def test_cp_keeps_cp_dist_and_refuses_unknown_directions():
    cp = CpParams(dist_m=2.0, delay_s=0.0, accel_mps2=3.0, jerk_mps3=1e9, guide_deg=0.0)
    bins = np.full(72, 8.01)
    bins[0] = 4.0  # 4 m ahead
    out = constrain_velocity((8.0, 0.0), 0.0, bins, 6.2, 0.0, cp)
    assert out == pytest.approx((math.sqrt(2 * 3.0 * 2.0), 0.0), rel=1e-6)
    bins[0] = np.inf  # ahead unknown: CP_GO_NO_DATA 0 refuses
    assert constrain_velocity((8.0, 0.0), 0.0, bins, 6.2, 0.0, cp) == (0.0, 0.0)
    assert constrain_velocity((8.0, 0.0), 0.0, np.full(72, np.inf), 6.2, 0.0, cp) == (0.0, 0.0)
    off = CpParams(dist_m=-1.0)
    assert constrain_velocity((8.0, 0.0), 0.0, np.full(72, np.inf), 6.2, 0.0, off) == (8.0, 0.0)
    # CP_GO_NO_DATA 1: into a bin that never had data, yes; into one that had, no
    go = dataclasses.replace(cp, go_no_data=True)
    fov = np.ones(72, dtype=bool)
    fov[0] = False
    assert constrain_velocity((1.0, 0.0), 0.0, bins, 6.2, 0.0, go, fov) == (1.0, 0.0)
    fov[0] = True
    assert constrain_velocity((1.0, 0.0), 0.0, bins, 6.2, 0.0, go, fov) == (0.0, 0.0)
    assert constrain_velocity((1.0, 0.0), 0.0, bins, 6.2, 0.0, cp, ~fov) == (0.0, 0.0)
    # and never without any data at all ("No obstacle data, not moving")
    none = np.full(72, np.inf)
    assert constrain_velocity((1.0, 0.0), 0.0, none, 6.2, 0.0, go, ~fov) == (0.0, 0.0)


def test_px4_bins_that_had_a_reading_stay_in_the_field_of_view():
    """PX4's _data_fov: a bin joins when it takes a reading, and stays after it reverts
    to UINT16_MAX (unknown) or the stream times out."""
    rx = ProximityReceiver()
    rx.on_message(_obstacle_distance([300] * 3 + [65535] * 69), 0.0)
    rx.px4_bins(0.0, 0.0)
    assert rx.px4_fov.sum() > 0 and not rx.px4_fov[36]
    seen = rx.px4_fov.copy()
    rx.on_message(_obstacle_distance([65535] * 72), 0.1)
    bins, _ = rx.px4_bins(0.1, 0.0)
    assert not np.isfinite(bins).any() and np.array_equal(rx.px4_fov, seen)


def test_cp_guidance_turns_toward_the_open_bin_within_cp_guide_ang():
    cp = CpParams(dist_m=2.0, delay_s=0.0, guide_deg=30.0, jerk_mps3=1e9)
    bins = np.full(72, 6.0)
    bins[[69, 70, 71, 0, 1, 2]] = 3.0  # an obstacle ahead
    bins[3:6] = 8.01  # open 15°–30° to the right
    out = constrain_velocity((3.0, 0.0), 0.0, bins, 6.2, 0.0, cp)
    heading = math.degrees(math.atan2(out[1], out[0]))
    assert 15.0 <= heading <= 35.0, heading
    assert math.hypot(*out) < 3.0  # and slowed for the obstacle's flank


# ---- pilot sticks -----------------------------------------------------------------------


def test_rc_override_and_manual_control_give_the_same_sticks():
    pilot = PilotInput(timeout_s=3.0)
    rc = M.MAVLink_rc_channels_override_message(1, 1, 1500, 1000, 1500, 1500, 0, 0, 0, 0)
    pilot.on_rc_override(rc, 0.0)
    assert pilot.sticks(0.1).forward == pytest.approx(1.0)  # pitch stick low = forward
    mc = M.MAVLink_manual_control_message(1, 1000, -500, 500, 0, 0)
    pilot.on_manual_control(mc, 0.0)
    s = pilot.sticks(0.1)
    assert s.forward == pytest.approx(1.0) and s.right == pytest.approx(-(0.5 - 0.04) / 0.96)
    assert s.up == 0.0 and s.yaw == 0.0
    assert pilot.sticks(3.5).centred  # RC_OVERRIDE_TIME
    bad = M.MAVLink_manual_control_message(1, 5000, 0, 500, 0, 0)
    assert pilot.on_manual_control(bad, 4.0) is not None and pilot.refused == 1
