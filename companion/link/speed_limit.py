"""Stating the safety envelope's speed limit to the autopilot (MAV_CMD_DO_CHANGE_SPEED).

ArduCopter in GUIDED applies ``MAV_CMD_DO_CHANGE_SPEED`` (param1 = 1 ground speed,
param2 = m/s) to its position controller's horizontal speed limit
(``ModeGuided::set_speed_xy_cms`` → ``AC_PosControl::set_max_speed_accel_NE_cm``, no clip
to WPNAV_SPEED), and resets it to WPNAV_SPEED each time GUIDED is entered — so the limit
is re-sent as a keep-alive, not only on change. A position target nearer than the
stopping distance (the carrot) bounds the speed for every autopilot anyway; PX4 gets no
command (its offboard position control ignores DO_CHANGE_SPEED), the carrot is its bound.

The climb or descent speed is stated too (param1 = 2 climb, 3 descent:
``GCS_MAVLINK_Copter::handle_MAV_CMD_DO_CHANGE_SPEED`` → ``ModeGuided::set_speed_up_cms`` /
``set_speed_down_cms``). ArduCopter shapes N/E and D apart, each axis at its own limit, so
with only the horizontal one stated a climb toward a carrot 12° up ran at 28–38° (climbing
at WPNAV_SPEED_UP while the horizontal was held back): along a velocity the camera did not
see, and the envelope, looking along it while braking, stated 0 m/s (issue 31).
:func:`climb_limit` states the vertical speed that keeps the flown slope within the path's
(the path's tan elevation × the horizontal limit or the speed flown, the lower). ArduCopter's
``set_speed_up_cms`` resets the descent speed to WPNAV_SPEED_DN (and ``set_speed_down_cms``
the climb speed to WPNAV_SPEED_UP): only the one the path needs is stated, a level path
states none and keeps the last (``ArduCopter/mode_guided.cpp``, ArduPilot master 2025).

Pure policy (:class:`SpeedLimitPolicy`, wall seconds of the host): the limit is rounded
*down* to ``step_mps`` and floored at ``min_mps`` (ArduPilot ignores a speed ≤ 0); a lower
limit goes out at once, a higher one at most every ``raise_period_s`` (a limit that
rises and falls with every frame must not flood the link), and the current one every
``keepalive_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.messages import command_long

__all__ = ["ClimbLimitPolicy", "Pacing", "SpeedLimitPolicy", "change_speed_command", "climb_limit"]

SPEED_TYPE_GROUND = 1.0
SPEED_TYPE_CLIMB = 2.0
SPEED_TYPE_DESCENT = 3.0
_LEVEL_SIN = math.sin(math.radians(0.5))  # a path this flat states no vertical speed


def change_speed_command(
    speed_mps: float,
    target_system: int,
    target_component: int,
    speed_type: float = SPEED_TYPE_GROUND,
) -> mavlink.MAVLink_command_long_message:
    """COMMAND_LONG MAV_CMD_DO_CHANGE_SPEED: ``speed_mps`` of ``speed_type`` (ground,
    climb or descent), throttle unchanged."""
    return command_long(
        target_system,
        target_component,
        mavlink.MAV_CMD_DO_CHANGE_SPEED,
        float(speed_type),
        float(speed_mps),
        -1.0,  # throttle: no change
    )


def climb_limit(
    path_dir_ned, horizontal_mps: float, speed_mps: float | None = None
) -> tuple[float, float] | None:
    """The vertical speed to state for a path along ``path_dir_ned`` (unit, NED):
    ``(SPEED_TYPE_CLIMB or SPEED_TYPE_DESCENT, m/s)``, or None for a level path.

    It is the path's |tan elevation| × the horizontal limit ``horizontal_mps``, and no
    more than × the vehicle's speed ``speed_mps`` when given: ArduCopter's vertical axis
    reaches its speed sooner than the horizontal one (the attitude loop lags), so a vehicle
    speeding up toward a carrot 8° up climbed at 24° in its first second. Bounded by the
    speed already flown, the climb never outpaces the horizontal motion: the slope stays
    within the path's (the bound is raised, paced, as the vehicle speeds up). A path
    steeper than 45° (a goal straight above, no heading) states the horizontal limit: the
    envelope's bound along that path."""
    north, east, down = (float(x) for x in path_dir_ned)
    if not all(math.isfinite(x) for x in (north, east, down, horizontal_mps)):
        return None
    norm = math.sqrt(north * north + east * east + down * down)
    if norm < 1e-9 or abs(down) < _LEVEL_SIN * norm:
        return None
    horizontal = math.hypot(north, east)
    reference_mps = max(0.0, float(horizontal_mps))
    if abs(down) < horizontal and speed_mps is not None and math.isfinite(speed_mps):
        reference_mps = min(reference_mps, max(0.0, float(speed_mps)))
    tan_elevation = abs(down) / max(horizontal, abs(down))
    kind = SPEED_TYPE_DESCENT if down > 0.0 else SPEED_TYPE_CLIMB
    return kind, reference_mps * tan_elevation


@dataclass
class Pacing:
    """When to (re)state a speed limit; see the module docstring."""

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


@dataclass
class ClimbLimitPolicy:
    """When to (re)state the climb or descent speed (:func:`climb_limit`): the same pacing
    as the horizontal limit, with a finer step (vertical limits are a fraction of it); a
    change between climb and descent goes out at once (ArduCopter resets the other)."""

    pacing: Pacing = field(default_factory=lambda: Pacing(step_mps=0.05, min_mps=0.1))
    last_kind: float | None = None

    def due(
        self, path_dir_ned, horizontal_mps: float, speed_mps: float | None, now_s: float
    ) -> tuple[float, float] | None:
        """``(speed type, m/s)`` to send now, or None."""
        wanted = climb_limit(path_dir_ned, horizontal_mps, speed_mps)
        if wanted is None:
            return None
        kind, speed_mps = wanted
        if kind != self.last_kind:
            self.pacing.reset()
        speed = self.pacing.due(speed_mps, now_s)
        return None if speed is None else (kind, speed)

    def sent(self, kind: float, speed_mps: float, now_s: float) -> None:
        """Record that ``speed_mps`` of ``kind`` went out at ``now_s``."""
        self.last_kind = kind
        self.pacing.sent(speed_mps, now_s)

    def reset(self) -> None:
        """Forget what was sent (GUIDED re-entered: ArduCopter restored its defaults)."""
        self.last_kind = None
        self.pacing.reset()


@dataclass
class SpeedLimitPolicy(Pacing):
    """When to (re)state the horizontal speed limit, and (``climb``) the vertical one."""

    climb: ClimbLimitPolicy = field(default_factory=ClimbLimitPolicy)

    def reset(self) -> None:
        """Forget what was sent, both limits (a new autopilot or GUIDED re-entered)."""
        super().reset()
        self.climb.reset()
