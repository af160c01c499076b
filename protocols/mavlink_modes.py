"""MAVLink numbers both sides must agree on: autopilot modes and setpoint type masks.

ArduCopter custom modes (``HEARTBEAT.custom_mode``, ArduCopter ``mode.h``), PX4's packed
``custom_mode`` (main mode in bits 16–23, sub mode in bits 24–31; PX4
``px4_custom_mode.h``), and the SET_POSITION_TARGET_* ``type_mask`` bits (a set bit means
"ignore this field"; MAVLink POSITION_TARGET_TYPEMASK). The companion speaks them to any
autopilot; plant-sim implements them. No other module defines these numbers.
"""

from __future__ import annotations

import enum

__all__ = [
    "MASK_ACCEL",
    "MASK_FORCE",
    "MASK_POS",
    "MASK_VEL",
    "MASK_YAW",
    "MASK_YAW_RATE",
    "TYPE_MASK_POSITION",
    "TYPE_MASK_POSITION_YAW",
    "ArduCopterMode",
    "Px4Main",
    "Px4Sub",
    "px4_custom_mode",
    "px4_split",
]


class ArduCopterMode(enum.IntEnum):
    """ArduCopter flight modes (HEARTBEAT.custom_mode)."""

    STABILIZE = 0
    ACRO = 1
    ALT_HOLD = 2
    AUTO = 3
    GUIDED = 4
    LOITER = 5
    RTL = 6
    CIRCLE = 7
    LAND = 9
    POSHOLD = 16
    BRAKE = 17
    GUIDED_NOGPS = 20
    SMART_RTL = 21


class Px4Main(enum.IntEnum):
    """PX4_CUSTOM_MAIN_MODE."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7
    RATTITUDE = 8


class Px4Sub(enum.IntEnum):
    """PX4_CUSTOM_SUB_MODE_AUTO."""

    NONE = 0
    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6


def px4_custom_mode(main: int, sub: int = 0) -> int:
    """PX4's HEARTBEAT ``custom_mode``: main mode in bits 16–23, sub mode in bits 24–31."""
    return (int(main) & 0xFF) << 16 | (int(sub) & 0xFF) << 24


def px4_split(custom_mode: int) -> tuple[int, int]:
    """(main, sub) of a PX4 ``custom_mode``."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


# SET_POSITION_TARGET_* type_mask bit groups (bits set = ignored)
MASK_POS = 0b0000_0000_0111  # x, y, z
MASK_VEL = 0b0000_0011_1000  # vx, vy, vz
MASK_ACCEL = 0b0001_1100_0000  # afx, afy, afz
MASK_FORCE = 0b0010_0000_0000  # afx.. are forces
MASK_YAW = 0b0100_0000_0000
MASK_YAW_RATE = 0b1000_0000_0000

#: position + yaw: velocity, acceleration and yaw rate ignored (2552)
TYPE_MASK_POSITION_YAW = MASK_VEL | MASK_ACCEL | MASK_YAW_RATE
#: position only (3576)
TYPE_MASK_POSITION = TYPE_MASK_POSITION_YAW | MASK_YAW
