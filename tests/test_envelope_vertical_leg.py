"""Step 7b: a staged vertical move flies straight along the vertical where that is known
free, at the speed whose stop fits there (issue 36 item 2).

Passage scene vertical-11 (stereo, a 5.8 m descent, traced per frame): the stages
descended at 0.10–0.15 m/s (the 12° slope times a slow horizontal speed, or the 0.1 m/s
floor of the stated descent speed) although the column below had been seen free for
0.7 m (median) to 3.2 m (90th percentile). The map below answers per direction: along the
vertical what the test says, along any other direction a stage's 1.0 m (a climb's near
field) or more.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.guidance.config import GuidanceConfig
from companion.guidance.envelope import EnvelopeConfig, envelope_step
from companion.guidance.vertical_leg import (
    MIN_GAIN_M,
    VERTICAL_ACCEL_MPS2,
    steeper_elevations_rad,
    vertical_leg,
)
from companion.link.speed_limit import SPEED_TYPE_CLIMB, SPEED_TYPE_DESCENT, Pacing, climb_limit
from companion.perception import PerceptionConfig

CFG = EnvelopeConfig()
RADIUS_M = PerceptionConfig().vehicle_radius_m
ELEV_RAD = GuidanceConfig().max_aim_elevation_rad
SECTION = {"vehicle_radius_m": RADIUS_M, "max_path_elevation_rad": ELEV_RAD}
POS = np.array([3.0, -2.0, -8.0])
EAST = 0.5 * math.pi


def _map(vertical_m: float, other_m: float = 1.0, steeper_m: float = 0.3):
    """Known-free metres: ``vertical_m`` straight up or down, ``steeper_m`` along a
    direction steeper than the path limit, ``other_m`` elsewhere; records each query's
    (direction, half-height, body, near field)."""
    calls = []

    def free(pos, direction, radius_m, limit_m, half_height_m, body_m, near_field_m):
        u = np.asarray(direction, dtype=float)
        calls.append((u.copy(), half_height_m, body_m, near_field_m))
        horizontal = math.hypot(u[0], u[1])
        if horizontal < 1e-9:
            return min(vertical_m, limit_m)
        steeper = abs(u[2]) > math.sin(ELEV_RAD) + 1e-9
        return min(steeper_m if steeper else other_m, limit_m)

    free.calls = calls
    return free


def _limit_closed_form(free_m: float, tau_s: float) -> float:
    """τ·v + v²/(2a_z) + margin = F solved for v."""
    a = VERTICAL_ACCEL_MPS2
    return a * (-tau_s + math.sqrt(tau_s**2 + 2.0 * (free_m - CFG.margin_m) / a))


def _step(goal, free, vel=(0.0, 0.0, 0.0), heading=EAST, pos=POS):
    return envelope_step(
        **SECTION, pos_ned_m=pos, vel_ned_mps=vel, setpoint_ned_m=goal,
        free_distance=free, heading_rad=heading,
    )  # fmt: skip


@pytest.mark.parametrize("rise_m", [-5.0, 4.0])  # a descent, a climb
@pytest.mark.parametrize("free_m", [1.2, 2.0, 3.5])
def test_a_known_free_column_is_flown_straight_at_the_speed_its_stop_fits(rise_m, free_m):
    goal = POS + np.array([0.04, -0.03, -rise_m])
    out = _step(goal, _map(free_m))
    sign = -math.copysign(1.0, rise_m)
    np.testing.assert_allclose(out.path_dir_ned, (0.0, 0.0, sign), atol=0.0)
    # carrot straight along the vertical, the margin short of the known-free end
    np.testing.assert_allclose(
        out.setpoint_ned_m, POS + np.array([0.0, 0.0, sign * (free_m - CFG.margin_m)]), atol=1e-12
    )
    assert out.free_distance_m == free_m and out.limited
    limit = _limit_closed_form(free_m, CFG.latency_s)
    assert out.speed_limit_mps == pytest.approx(limit, rel=1e-12)
    # invariant 2 along the vertical, at the autopilot's vertical deceleration
    stop_m = CFG.latency_s * limit + limit**2 / (2.0 * VERTICAL_ACCEL_MPS2)
    assert stop_m + CFG.margin_m == pytest.approx(free_m, abs=1e-9)


def test_the_column_is_queried_as_the_vehicles_disc_with_nothing_excused():
    free = _map(2.0)
    _step(POS + np.array([0.0, 0.0, 5.0]), free)
    vertical = [c for c in free.calls if math.hypot(c[0][0], c[0][1]) < 1e-9]
    assert vertical, "the column below was not queried"
    for _, half_height_m, body_m, near_field_m in vertical:
        assert half_height_m == RADIUS_M  # a disc, not the forward section's 0.2 m height
        assert body_m == RADIUS_M and near_field_m == 0.0  # below is never in the view


@pytest.mark.parametrize("rise_m", [-5.0, 4.0])
def test_an_unseen_column_keeps_the_stage(rise_m):
    """Only the body's own bubble known along the vertical (a forward camera's usual
    case above it): the stage along the heading at the path limit stands."""
    goal = POS + np.array([0.02, 0.0, -rise_m])
    out = _step(goal, _map(0.3, other_m=3.0))
    expected = (0.0, math.cos(ELEV_RAD), -math.copysign(math.sin(ELEV_RAD), rise_m))
    np.testing.assert_allclose(out.path_dir_ned, expected, atol=1e-12)
    assert float(np.linalg.norm(out.setpoint_ned_m - POS)) == pytest.approx(3.0 - CFG.margin_m)


def test_the_leg_is_taken_only_when_it_goes_farther_than_the_stage():
    """The stage's carrot along 12° gets ``c·sin 12°`` lower; the leg must beat that by
    ``MIN_GAIN_M``. Stage free 5 m: 4.7 m of carrot, 0.98 m lower; the column known free
    1.3 m (1.0 m of carrot) is not enough, 1.45 m (1.15 m) is."""
    goal = POS + np.array([0.0, 0.0, 5.0])
    stage_gain = (5.0 - CFG.margin_m) * math.sin(ELEV_RAD)
    short = _step(goal, _map(stage_gain + CFG.margin_m + 0.5 * MIN_GAIN_M, other_m=5.0))
    assert math.hypot(*short.path_dir_ned[:2]) == pytest.approx(math.cos(ELEV_RAD))
    longer = _step(goal, _map(stage_gain + CFG.margin_m + 1.5 * MIN_GAIN_M, other_m=5.0))
    np.testing.assert_allclose(longer.path_dir_ned, (0.0, 0.0, 1.0), atol=0.0)


def test_moving_the_carrot_leaves_room_for_the_vertical_stop():
    vel = np.array([0.3, 0.0, 0.5])
    speed = float(np.linalg.norm(vel))
    out = _step(POS + np.array([0.0, 0.0, 5.0]), _map(3.0, 3.0, 3.0), vel=vel)
    d_stop = CFG.latency_s * speed + speed**2 / (2.0 * VERTICAL_ACCEL_MPS2)
    assert out.setpoint_ned_m[2] - POS[2] == pytest.approx(3.0 - d_stop - CFG.margin_m)


def test_the_carrot_never_passes_the_goals_altitude():
    goal = POS + np.array([0.3, 0.0, 1.5])
    out = _step(goal, _map(8.0, other_m=0.6))
    np.testing.assert_allclose(out.setpoint_ned_m, POS + np.array([0.0, 0.0, 1.5]), atol=1e-12)


def test_a_goal_off_the_column_or_without_a_heading_is_not_a_vertical_leg():
    far = POS + np.array([3.0, 0.0, 3.0])  # 45° down, 3 m aside: a normal clamped path
    out = _step(far, _map(8.0))
    assert math.hypot(*out.path_dir_ned[:2]) == pytest.approx(math.cos(ELEV_RAD))
    free = _map(8.0)
    plain = _step(POS + np.array([0.02, 0.0, 3.0]), free, heading=None)
    assert all(c[1] == CFG.vehicle_half_height_m for c in free.calls)  # no disc query
    # the old rule: the 12° path along the 2 cm offset's bearing (north)
    np.testing.assert_allclose(
        plain.path_dir_ned, (math.cos(ELEV_RAD), 0.0, math.sin(ELEV_RAD)), atol=1e-12
    )


@pytest.mark.parametrize("rise_m", [-5.0, 4.0])
def test_the_stated_vertical_speed_is_the_columns_bound_not_the_floor(rise_m):
    """What goes to the autopilot (``climb_limit``, DO_CHANGE_SPEED 2 or 3): the leg's
    bound, rounded down to the horizontal statement's 0.25 m/s steps, far above the
    0.1 m/s floor a slow stage states (slope × 0.3 m/s flown = 0.064 m/s)."""
    goal = POS + np.array([0.02, 0.0, -rise_m])
    pacing = Pacing()
    out = _step(goal, _map(2.5), vel=(0.3, 0.0, 0.0))
    stated_mps = pacing.quantize(out.speed_limit_mps)
    kind, vertical_mps = climb_limit(out.path_dir_ned, stated_mps, out.speed_mps)
    assert kind == (SPEED_TYPE_CLIMB if rise_m > 0 else SPEED_TYPE_DESCENT)
    assert vertical_mps == stated_mps
    assert vertical_mps >= 1.25  # 2.5 m known free: v = 1.54 m/s at a_z = 1 m/s², τ 0.15 s
    assert vertical_mps <= _limit_closed_form(2.5, CFG.latency_s)


@pytest.mark.parametrize(
    "target", [(np.nan, 0.0, 1.0), (0.0, 0.0, np.nan), (0.0, 0.0, 0.0), (0.0, 0.0, 0.05)]
)
def test_no_leg_for_bad_or_level_targets(target):
    leg = vertical_leg(
        np.zeros(3), np.asarray(target), 0.0, np.zeros(3), lambda u, h: 5.0,
        vehicle_radius_m=RADIUS_M, latency_s=0.15, margin_m=0.3, min_advance_m=0.15,
        max_speed_mps=10.0,
    )  # fmt: skip
    assert leg is None


def test_steeper_stages_stop_where_the_vertical_stop_fits_the_paths():
    """``(v sin e)²/(2 a_z) ≤ v² sin e/(2 a)`` ⟺ ``sin e ≤ a_z/a``: 30° at the default
    2 m/s², none beyond 14.5° at 4 m/s², both tried at 1 m/s²."""
    deg = [round(math.degrees(e), 9) for e in steeper_elevations_rad(CFG.accel_mps2, ELEV_RAD)]
    assert deg == [20.0, 30.0]
    assert steeper_elevations_rad(4.0, ELEV_RAD) == ()
    assert len(steeper_elevations_rad(1.0, ELEV_RAD)) == 2
    for e in steeper_elevations_rad(CFG.accel_mps2, ELEV_RAD):
        v = 1.7
        vertical_stop = (v * math.sin(e)) ** 2 / (2.0 * VERTICAL_ACCEL_MPS2)
        assert vertical_stop <= v * v / (2.0 * CFG.accel_mps2) * math.sin(e) + 1e-12


@pytest.mark.parametrize("steeper_m", [1.5, 3.0, 6.0])
def test_a_descent_seen_free_steeper_descends_along_the_steepest_stage_that_gains(steeper_m):
    """Column below unseen (0.3 m), 2 m free along the 12° stage, ``steeper_m`` along 20°
    and 30° down the heading (in the camera's view): the stage whose carrot sinks farthest
    is flown, at the envelope's bound along it; its carrot stays in known-free space."""
    goal = POS + np.array([0.02, 0.0, 5.0])
    out = _step(goal, _map(0.3, other_m=2.0, steeper_m=steeper_m))
    gains = {
        e: min(5.0 / math.sin(math.radians(e)), (f - CFG.margin_m)) * math.sin(math.radians(e))
        for e, f in ((12.0, 2.0), (20.0, steeper_m), (30.0, steeper_m))
    }
    best = max(gains, key=gains.get)
    elev = math.radians(best)
    np.testing.assert_allclose(out.path_dir_ned, (0.0, math.cos(elev), math.sin(elev)), atol=1e-12)
    assert out.setpoint_ned_m[2] - POS[2] == pytest.approx(gains[best])
    assert out.free_distance_m == min(steeper_m, 2.0) if best == 12.0 else steeper_m
    a, tau = CFG.accel_mps2, CFG.latency_s
    limit = a * (-tau + math.sqrt(tau**2 + 2.0 * (out.free_distance_m - CFG.margin_m) / a))
    assert out.speed_limit_mps == pytest.approx(limit, rel=1e-12)
    if best != 12.0:  # the stated descent speed grows with the slope: tan e × the speed flown
        _, stated = climb_limit(out.path_dir_ned, 1.0, 0.5)
        assert stated == pytest.approx(0.5 * math.tan(elev))
