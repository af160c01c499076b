"""Speed limit to the autopilot: DO_CHANGE_SPEED encoding and the sending policy."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.speed_limit import (
    SPEED_TYPE_CLIMB,
    SPEED_TYPE_DESCENT,
    SpeedLimitPolicy,
    change_speed_command,
    climb_limit,
)


def test_change_speed_command_is_ground_speed_in_mps():
    msg = change_speed_command(2.5, 1, 1)
    assert msg.command == mavlink.MAV_CMD_DO_CHANGE_SPEED == 178
    assert (msg.param1, msg.param2, msg.param3) == (1.0, 2.5, -1.0)
    assert (msg.target_system, msg.target_component) == (1, 1)


def test_limit_is_rounded_down_and_floored():
    p = SpeedLimitPolicy()
    assert p.quantize(2.49) == 2.25
    assert p.quantize(2.5) == 2.5
    assert p.quantize(0.0) == p.min_mps  # ArduPilot ignores speeds <= 0


def test_decreases_go_out_at_once_increases_are_paced_and_kept_alive():
    p = SpeedLimitPolicy()
    assert p.due(3.0, 0.0) == 3.0
    p.sent(3.0, 0.0)
    assert p.due(3.1, 0.1) is None  # same step
    assert p.due(1.3, 0.1) == 1.25  # lower: at once
    p.sent(1.25, 0.1)
    assert p.due(4.0, 0.3) is None  # higher: not before raise_period_s
    assert p.due(4.0, 0.1 + p.raise_period_s) == 4.0
    p.sent(4.0, 0.6)
    assert p.due(4.0, 0.6 + p.keepalive_s - 0.01) is None
    assert p.due(4.0, 0.6 + p.keepalive_s) == 4.0  # keep-alive (GUIDED re-entry resets it)
    p.reset()
    assert p.due(4.0, 0.7) == 4.0


@pytest.mark.parametrize("limit", [0.3, 1.0, 5.26])
def test_sent_speed_never_exceeds_the_limit(limit):
    assert SpeedLimitPolicy().quantize(limit) <= limit


def test_climb_and_descent_commands_are_speed_types_2_and_3():
    assert change_speed_command(0.4, 1, 1, SPEED_TYPE_CLIMB).param1 == 2.0
    assert change_speed_command(0.4, 1, 1, SPEED_TYPE_DESCENT).param1 == 3.0


def _unit(elevation_deg: float) -> tuple[float, float, float]:
    e = math.radians(elevation_deg)
    return (math.cos(e), 0.0, -math.sin(e))  # NED: up is negative down


@pytest.mark.parametrize("elevation_deg", [3.0, 8.0, 12.0, 18.5, -12.0])
def test_the_stated_climb_keeps_the_flown_slope_within_the_path(elevation_deg):
    # at the limits on both axes the flown slope is atan(v_up / v_horizontal): the path's
    kind, up = climb_limit(_unit(elevation_deg), 3.0)
    assert kind == (SPEED_TYPE_CLIMB if elevation_deg > 0 else SPEED_TYPE_DESCENT)
    assert math.degrees(math.atan2(up, 3.0)) == pytest.approx(abs(elevation_deg), abs=1e-9)
    # and while speeding up the climb is bounded by the speed flown (ArduCopter's vertical
    # axis is quicker than its horizontal one): |v_up| <= tan(e)·|v| -> slope <= asin(tan e)
    _, up_slow = climb_limit(_unit(elevation_deg), 3.0, speed_mps=1.0)
    assert up_slow == pytest.approx(math.tan(math.radians(abs(elevation_deg))))


def test_level_bad_and_vertical_paths():
    assert climb_limit((1.0, 0.0, 0.0), 3.0) is None  # level: nothing stated
    assert climb_limit((0.0, 0.0, 0.0), 3.0) is None
    assert climb_limit((math.nan, 0.0, -0.2), 3.0) is None
    # straight up (no heading): the envelope's limit along the path, not the speed flown
    assert climb_limit((0.0, 0.0, -1.0), 1.5, speed_mps=0.0) == (SPEED_TYPE_CLIMB, 1.5)


def test_climb_statements_are_paced_switch_at_once_and_reset_with_the_policy():
    p = SpeedLimitPolicy()
    climb = p.climb
    up = _unit(10.0)
    assert climb.due(up, 3.0, None, 0.0) == (SPEED_TYPE_CLIMB, pytest.approx(0.5))  # 0.529
    climb.sent(SPEED_TYPE_CLIMB, 0.5, 0.0)
    assert climb.due(up, 3.0, None, 0.1) is None
    assert climb.due(up, 3.0, 1.0, 0.1) == (SPEED_TYPE_CLIMB, pytest.approx(0.15))  # at once
    climb.sent(SPEED_TYPE_CLIMB, 0.15, 0.1)
    assert climb.due(up, 3.0, 3.0, 0.2) is None  # higher: paced like the horizontal limit
    assert climb.due(up, 3.0, 3.0, 0.6) == (SPEED_TYPE_CLIMB, pytest.approx(0.5))
    assert climb.due(_unit(-10.0), 3.0, 3.0, 0.61) == (SPEED_TYPE_DESCENT, pytest.approx(0.5))
    climb.sent(SPEED_TYPE_DESCENT, 0.5, 0.61)
    assert climb.due((1.0, 0.0, 0.0), 3.0, 3.0, 5.0) is None  # level: the last one stays
    p.reset()  # GUIDED re-entered: ArduCopter restored its defaults, state again
    assert climb.last_kind is None and climb.due(_unit(-10.0), 3.0, 3.0, 5.0) is not None
