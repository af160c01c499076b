"""Stating the safety envelope's speed limit to the autopilot (MAV_CMD_DO_CHANGE_SPEED).

ArduCopter in GUIDED applies ``MAV_CMD_DO_CHANGE_SPEED`` (param1 = 1 ground speed,
param2 = m/s) to its position controller's horizontal speed limit
(``ModeGuided::set_speed_xy_cms`` → ``AC_PosControl::set_max_speed_accel_NE_cm``, no clip
to WPNAV_SPEED), and resets it to WPNAV_SPEED each time GUIDED is entered — so the limit
is re-sent as a keep-alive, not only on change. A position target nearer than the
stopping distance (the carrot) bounds the speed for every autopilot anyway; PX4 gets no
command (its offboard position control ignores DO_CHANGE_SPEED), the carrot is its bound.

Pure policy (:class:`SpeedLimitPolicy`, wall seconds of the host): the limit is rounded
*down* to ``step_mps`` and floored at ``min_mps`` (ArduPilot ignores a speed ≤ 0); a lower
limit goes out at once, a higher one at most every ``raise_period_s`` (a limit that
rises and falls with every frame must not flood the link), and the current one every
``keepalive_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.messages import command_long

__all__ = ["SpeedLimitPolicy", "change_speed_command"]

SPEED_TYPE_GROUND = 1.0


def change_speed_command(
    speed_mps: float, target_system: int, target_component: int
) -> mavlink.MAVLink_command_long_message:
    """COMMAND_LONG MAV_CMD_DO_CHANGE_SPEED: ground speed ``speed_mps``, throttle unchanged."""
    return command_long(
        target_system,
        target_component,
        mavlink.MAV_CMD_DO_CHANGE_SPEED,
        SPEED_TYPE_GROUND,
        float(speed_mps),
        -1.0,  # throttle: no change
    )


@dataclass
class SpeedLimitPolicy:
    """When to (re)state the speed limit; see the module docstring."""

    step_mps: float = 0.25
    min_mps: float = 0.25
    raise_period_s: float = 0.5
    keepalive_s: float = 2.0
    last_sent_mps: float | None = None
    last_sent_s: float | None = None

    def quantize(self, limit_mps: float) -> float:
        """``limit_mps`` rounded down to ``step_mps``, at least ``min_mps`` [m/s]."""
        steps = math.floor(max(float(limit_mps), 0.0) / self.step_mps + 1e-9)
        return max(self.min_mps, steps * self.step_mps)

    def due(self, limit_mps: float, now_s: float) -> float | None:
        """The speed to send now, or None."""
        q = self.quantize(limit_mps)
        if self.last_sent_mps is None or self.last_sent_s is None:
            return q
        since = now_s - self.last_sent_s
        if q < self.last_sent_mps:
            return q
        if q > self.last_sent_mps and since >= self.raise_period_s:
            return q
        if since >= self.keepalive_s:
            return self.last_sent_mps if q >= self.last_sent_mps else q
        return None

    def sent(self, speed_mps: float, now_s: float) -> None:
        """Record that ``speed_mps`` went out at ``now_s``."""
        self.last_sent_mps = speed_mps
        self.last_sent_s = now_s

    def reset(self) -> None:
        """Forget what was sent (a new autopilot or a re-entered control mode)."""
        self.last_sent_mps = self.last_sent_s = None
