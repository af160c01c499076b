"""SET_POSITION_TARGET_LOCAL_NED encoding (position + yaw) and when to send it.

Pure. ``type_mask`` bits mean "ignore this field" (MAVLink POSITION_TARGET_TYPEMASK):
a position + yaw target ignores velocity, acceleration/force and yaw rate, which is
``2552``; position only (yaw ignored too) is ``3576``.

Sending policy (:class:`SetpointPolicy`, times in wall seconds of the host):

* PX4 (OFFBOARD): a continuous stream above 2 Hz, before OFFBOARD is requested and for as
  long as it is held — every new target goes out at once, and the last one is repeated at
  ``px4_rate_hz`` in between.
* ArduPilot (GUIDED; position targets persist): on change (beyond ``change_pos_m`` or
  ``change_yaw_rad``) and every ``ardupilot_period_s`` as a keep-alive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.flavour import Flavour, profile_for
from protocols.mavlink_modes import TYPE_MASK_POSITION, TYPE_MASK_POSITION_YAW

__all__ = [
    "TYPE_MASK_POSITION",
    "TYPE_MASK_POSITION_YAW",
    "PositionTarget",
    "SetpointPolicy",
    "position_target_message",
]

_M = mavlink


@dataclass(frozen=True)
class PositionTarget:
    """A LOCAL_NED position [m] and heading [rad] (0 north, +π/2 east)."""

    pos_ned_m: tuple[float, float, float]
    yaw_rad: float

    def __post_init__(self) -> None:
        if len(self.pos_ned_m) != 3 or not all(
            math.isfinite(x) for x in (*self.pos_ned_m, self.yaw_rad)
        ):
            raise ValueError(f"non-finite position target {self!r}")

    def differs(self, other: PositionTarget | None, pos_m: float, yaw_rad: float) -> bool:
        if other is None:
            return True
        d = math.dist(self.pos_ned_m, other.pos_ned_m)
        dyaw = abs(math.remainder(self.yaw_rad - other.yaw_rad, math.tau))
        return d > pos_m or dyaw > yaw_rad


def position_target_message(
    target: PositionTarget, time_boot_ms: int, target_system: int, target_component: int
) -> mavlink.MAVLink_set_position_target_local_ned_message:
    """SET_POSITION_TARGET_LOCAL_NED, MAV_FRAME_LOCAL_NED, position + yaw (type_mask 2552)."""
    n, e, d = target.pos_ned_m
    return mavlink.MAVLink_set_position_target_local_ned_message(
        int(time_boot_ms) & 0xFFFFFFFF,
        target_system,
        target_component,
        mavlink.MAV_FRAME_LOCAL_NED,
        TYPE_MASK_POSITION_YAW,
        float(n),
        float(e),
        float(d),
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        math.remainder(float(target.yaw_rad), math.tau),
        0.0,
    )


class SetpointPolicy:
    """Decides when the current target goes on the wire (see the module docstring)."""

    def __init__(
        self,
        flavour: Flavour,
        *,
        ardupilot_period_s: float = 0.5,
        px4_rate_hz: float = 20.0,
        change_pos_m: float = 0.02,
        change_yaw_rad: float = math.radians(0.5),
    ) -> None:
        if not px4_rate_hz > 2.0:
            raise ValueError("PX4 needs setpoints faster than 2 Hz")
        self.flavour = flavour
        self._stream = profile_for(flavour).streams_setpoints
        self.period_s = 1.0 / px4_rate_hz if self._stream else ardupilot_period_s
        self._change_pos_m = change_pos_m
        self._change_yaw_rad = change_yaw_rad
        self._last: PositionTarget | None = None
        self._last_sent_s = -math.inf

    def reset(self) -> None:
        """Forget what was sent (after a mode change or reconnection: send at once)."""
        self._last = None
        self._last_sent_s = -math.inf

    def on_new_target(self, target: PositionTarget, now_s: float) -> bool:
        """A frame produced ``target``: send it now?"""
        if self._stream:
            return True
        return target.differs(self._last, self._change_pos_m, self._change_yaw_rad) or (
            now_s - self._last_sent_s >= self.period_s
        )

    def due(self, now_s: float) -> bool:
        """Is a periodic re-send of the last target due?"""
        return self._last is not None and now_s - self._last_sent_s >= self.period_s

    @property
    def last(self) -> PositionTarget | None:
        return self._last

    def sent(self, target: PositionTarget, now_s: float) -> None:
        self._last = target
        self._last_sent_s = now_s
