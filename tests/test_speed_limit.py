"""Speed limit to the autopilot: DO_CHANGE_SPEED encoding and the sending policy."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.speed_limit import SpeedLimitPolicy, change_speed_command


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
