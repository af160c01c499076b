"""The room along the velocity (issue 36 item 5; envelope step 9).

The reproducer: the camera has seen a narrow corridor free along the path (north), nothing
beside it; the vehicle moves 10–14° off the path (after a turn, an avoidance or a gust),
so the carrot lies within step 8's 15° and no predicted path is checked. Along the path
8 m are free; along the velocity only the 1–2 m to the corridor's side. Before step 9 the
envelope stated the path's limit (6.55 m/s) and sent the far carrot: the autopilot
(plant-sim's :class:`~plant_sim.autopilot.shaping.TargetShaper`, ArduCopter's GUIDED
limits, the stated limit applied as DO_CHANGE_SPEED with the targets' latency) carried
the vehicle's section 0.09–0.28 m out of the space seen free. With step 9 the limit, and
the carrot when the stop no longer fits, drop in the same frame; the section stays inside
(within the shaper's few millimetres of rounding) and the vehicle goes on along the path.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from companion.guidance import envelope as envelope_module
from companion.guidance.envelope import (
    EnvelopeConfig,
    envelope_step,
    speed_limit_mps,
    stopping_distance_m,
)
from companion.guidance.velocity_bound import MIN_SPEED_MPS, velocity_room_m
from companion.perception import PerceptionConfig
from plant_sim.autopilot.shaping import ShapingLimits, TargetShaper

RADIUS_M = PerceptionConfig().vehicle_radius_m  # 0.35 m
ELEV_RAD = math.radians(12.0)
FRAME_S = 1.0 / 30.0
LATENCY_FRAMES = 3  # capture → the autopilot acting: 0.1 s, inside the 0.15 s budget
GUIDED = ShapingLimits(10.0, 2.5, 1.5, 2.5, 2.5, 2.0, 2.0)  # as tests/test_envelope_momentum.py
ALT_D_M = -5.0
GOAL = np.array([25.0, 0.0, ALT_D_M])
CFG = EnvelopeConfig()


def _corridor(half_width_m: float, north_end_m: float = 30.0, north_start_m: float = -1.0):
    """Known-free distance when only the corridor ``|east| ≤ half_width_m`` between
    ``north_start_m`` and ``north_end_m`` was seen free: the section (``radius_m``) must
    stay inside it; a ray from outside its sides may only come back in [m]."""

    def free(pos, unit, radius_m, limit_m, half_height_m, body_m, near_field_m):
        x, y = float(pos[0]), float(pos[1])
        side = half_width_m - radius_m
        t = min(limit_m, CFG.lookahead_m)
        if unit[1] > 1e-12:
            t = min(t, max(0.0, side - y) / unit[1])
        elif unit[1] < -1e-12:
            t = min(t, max(0.0, side + y) / -unit[1])
        if unit[0] > 1e-12:
            t = min(t, (north_end_m - radius_m - x) / unit[0])
        elif unit[0] < -1e-12:
            t = min(t, (x - north_start_m - radius_m) / -unit[0])
        return max(0.0, t)

    return free


def _vel(speed_mps: float, off_deg: float) -> np.ndarray:
    off = math.radians(off_deg)
    return np.array([speed_mps * math.cos(off), speed_mps * math.sin(off), 0.0])


def _step(vel, free, **kw):
    return envelope_step(
        pos_ned_m=np.array([0.0, 0.0, ALT_D_M]),
        vel_ned_mps=vel,
        setpoint_ned_m=GOAL,
        free_distance=free,
        vehicle_radius_m=RADIUS_M,
        max_path_elevation_rad=ELEV_RAD,
        **kw,
    )


def _without_step_9(monkeypatch):
    monkeypatch.setattr(envelope_module, "velocity_room_m", lambda *args: math.inf)


# (corridor half-width [m], speed [m/s], velocity off the path [deg]): 1.0–2.0 m free
# along the velocity, 8 m along the path; the first and third too fast to stop within it
OFF_PATH = [(0.6, 1.8, 12.0), (0.6, 1.5, 12.0), (0.7, 2.5, 10.0), (0.6, 1.2, 14.0)]


@pytest.mark.parametrize(("half_width_m", "speed_mps", "off_deg"), OFF_PATH)
def test_the_limit_and_the_carrot_follow_the_room_along_the_velocity(
    half_width_m, speed_mps, off_deg, monkeypatch
):
    """In the frame the velocity points off the path: the free distance along it is the
    corridor's side (closed form); a stop that no longer fits it brakes at the vehicle and
    states the bound along the velocity (without the margin: step 5's); one that fits
    keeps the path's carrot and limit. Without step 9 the path's limit (6.55 m/s) and the
    far carrot were sent in every case."""
    free = _corridor(half_width_m)
    vel = _vel(speed_mps, off_deg)
    out = _step(vel, free)
    _without_step_9(monkeypatch)
    before = _step(vel, free)
    v_path = speed_limit_mps(before.free_distance_m, CFG.latency_s, CFG.accel_mps2, CFG.margin_m)
    assert before.speed_limit_mps == pytest.approx(v_path) and before.speed_limit_mps > 6.0
    assert before.setpoint_ned_m[0] > 5.0 and not before.momentum_brake
    free_v = (half_width_m - RADIUS_M) / math.sin(math.radians(off_deg))
    assert out.velocity_free_m == pytest.approx(free_v, rel=1e-9)
    d_stop = stopping_distance_m(speed_mps, CFG.latency_s, CFG.accel_mps2)
    if d_stop + CFG.margin_m > free_v:  # braking: the carrot at the vehicle
        np.testing.assert_allclose(out.setpoint_ned_m, (0.0, 0.0, ALT_D_M), atol=1e-12)
        v0 = speed_limit_mps(free_v, CFG.latency_s, CFG.accel_mps2, 0.0)
        assert out.speed_limit_mps == pytest.approx(v0, rel=1e-9) and v0 >= speed_mps
        assert out.free_distance_m == pytest.approx(free_v, rel=1e-9)
        assert out.limited and not out.overspeed and not out.momentum_brake
    else:  # the stop fits: the path's carrot (it pulls the velocity back) and limit
        np.testing.assert_array_equal(out.setpoint_ned_m, before.setpoint_ned_m)
        assert out.speed_limit_mps == before.speed_limit_mps


def _fly(half_width_m, speed_mps, off_deg, seconds: float = 8.0):
    """Closed loop: the reference moving ``off_deg`` off the path at ``speed_mps`` toward
    an old target, the envelope's target and stated limit reaching it ``LATENCY_FRAMES``
    later (DO_CHANGE_SPEED as the lockstep's autopilot takes it, at least 0.1 m/s). Returns
    how far the section left the corridor [m] (≤ 0: inside), the frames over the stated
    limit by more than the tolerance, and the distance flown along the path [m]."""
    shaper = TargetShaper(GUIDED)
    vel = _vel(speed_mps, off_deg)
    shaper.reset((0.0, 0.0, ALT_D_M), vel)
    shaper.go_to(np.array([0.0, 0.0, ALT_D_M]) + 20.0 * vel / speed_mps)
    free = _corridor(half_width_m)
    in_flight, held, out_m, over = [], None, -math.inf, 0
    for _ in range(int(seconds / FRAME_S)):
        out = envelope_step(
            pos_ned_m=shaper.pos_ned_m,
            vel_ned_mps=shaper.vel_ned_mps,
            accel_ned_mps2=shaper.acc_ned_mps2,
            setpoint_ned_m=GOAL,
            free_distance=free,
            vehicle_radius_m=RADIUS_M,
            max_path_elevation_rad=ELEV_RAD,
            held_brake_ned_m=held,
        )
        held = out.brake_target_ned_m
        over += out.overspeed
        in_flight.append((out.setpoint_ned_m, out.speed_limit_mps))
        if len(in_flight) > LATENCY_FRAMES:
            target, limit = in_flight.pop(0)
            shaper.go_to(target)
            shaper.set_limits(dataclasses.replace(GUIDED, speed_ne_mps=min(max(limit, 0.1), 10.0)))
        shaper.step(FRAME_S)
        out_m = max(out_m, abs(shaper.pos_ned_m[1]) + RADIUS_M - half_width_m)
    return out_m, over, shaper.pos_ned_m[0]


def test_flown_closed_loop_the_section_stays_in_the_space_seen_free(monkeypatch):
    """Every case: the section stays inside the corridor (to the shaper's rounding,
    1 cm), no frame flies over the stated limit, and the vehicle is not frozen: it turns
    back onto the path and flies on, 15 m along it within 8 s. Without step 9 each case
    left the corridor by more than a third of the margin."""
    flown = [_fly(*case) for case in OFF_PATH]
    for case, (out_m, over, north_m) in zip(OFF_PATH, flown, strict=True):
        assert out_m <= 0.01 and over == 0 and north_m >= 15.0, (case, out_m, over, north_m)
    _without_step_9(monkeypatch)
    before = [_fly(*case)[0] for case in OFF_PATH]
    assert min(before) >= CFG.margin_m / 4, before


def test_at_rest_or_on_the_path_nothing_changes(monkeypatch):
    """Below 0.1 m/s there is no direction of motion (a vehicle at rest is never held by
    it); moving along the path, the velocity's room is the path's and the output is step
    1–5's, field for field."""
    free = _corridor(0.6)
    slow = _step(_vel(0.9 * MIN_SPEED_MPS, 60.0), free)
    ahead = _step(_vel(1.5, 0.0), free)
    assert slow.velocity_free_m == math.inf
    assert ahead.velocity_free_m == pytest.approx(ahead.free_distance_m)
    _without_step_9(monkeypatch)
    for out, vel in ((slow, _vel(0.9 * MIN_SPEED_MPS, 60.0)), (ahead, _vel(1.5, 0.0))):
        before = _step(vel, free)
        np.testing.assert_array_equal(out.setpoint_ned_m, before.setpoint_ned_m)
        assert out.speed_limit_mps == before.speed_limit_mps
        assert out.free_distance_m == before.free_distance_m


def test_velocity_room_follows_the_brake_direction():
    """The room is asked along the direction a brake's bound is stated along: a climb
    steeper than the path only by the stated climb floor is asked at the path's
    elevation; no (or a non-finite) velocity asks nothing."""
    asked = []

    def free_along(unit):
        asked.append(np.array(unit))
        return 2.0

    horiz = 0.3
    up = horiz * math.tan(ELEV_RAD) + 0.05  # 0.05 m/s above the 12° path
    assert velocity_room_m(np.array([horiz, 0.0, -up]), ELEV_RAD, free_along) == 2.0
    np.testing.assert_allclose(asked[-1], (math.cos(ELEV_RAD), 0.0, -math.sin(ELEV_RAD)))
    for still in ((0.0, 0.0, 0.0), (math.nan, 0.0, 0.0)):
        assert velocity_room_m(np.array(still), ELEV_RAD, free_along) == math.inf
    assert len(asked) == 1
