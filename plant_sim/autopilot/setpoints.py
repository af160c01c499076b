"""SET_POSITION_TARGET_LOCAL_NED decoding: type_mask semantics and coordinate frames (pure).

Standard MAVLink semantics: a set type_mask bit means "ignore this field". Bits 0–2 x, y, z;
3–5 vx, vy, vz; 6–8 afx, afy, afz; 9 force; 10 yaw; 11 yaw_rate. Position-only is 3576
(0b1101_1111_1000), position + yaw 2552, velocity-only 3527. Position and velocity are used
all-or-nothing per group, like ArduCopter; a partial group is refused. Acceleration fields
are ignored (the plant's tracker has no acceleration input), acceleration-only targets are
refused. Frames: LOCAL_NED (1); LOCAL_OFFSET_NED (7: position relative to the vehicle,
velocity NED); BODY_NED (8) and BODY_OFFSET_NED (9: position and velocity in the vehicle's
heading frame, position relative to the vehicle), as ArduCopter reads them.

SET_POSITION_TARGET_GLOBAL_INT (:func:`decode_global_target`) takes the same type_mask;
latitude/longitude in degE7 are projected onto LOCAL_NED around the origin, altitude frames
GLOBAL_INT (AMSL) and GLOBAL_RELATIVE_ALT_INT (above home). Every target is range-checked
(:func:`check_target_range`): a position more than ``MAX_TARGET_RANGE_M`` from home or a
speed over ``MAX_TARGET_SPEED_MPS`` is refused, never flown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from plant_sim.autopilot.geodesy import FlatEarth, valid_lat_lon_e7
from plant_sim.autopilot.modes import GuidedTarget
from protocols.mavlink_modes import (
    MASK_ACCEL,
    MASK_POS,
    MASK_VEL,
    MASK_YAW,
    MASK_YAW_RATE,
)

__all__ = [
    "MASK_ACCEL",
    "MASK_POS",
    "MASK_VEL",
    "MASK_YAW",
    "MASK_YAW_RATE",
    "MAX_TARGET_RANGE_M",
    "MAX_TARGET_SPEED_MPS",
    "SetpointError",
    "VehiclePose",
    "check_target_range",
    "decode_global_target",
    "decode_position_target",
    "type_mask_for",
]


MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_LOCAL_OFFSET_NED = 7
MAV_FRAME_BODY_NED = 8
MAV_FRAME_BODY_OFFSET_NED = 9
MAV_FRAME_GLOBAL_INT = 5
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = 6

#: Targets farther than this from home are refused (a geofence-like sanity bound) [m]
MAX_TARGET_RANGE_M = 10_000.0
#: Velocity targets faster than this are refused [m/s]
MAX_TARGET_SPEED_MPS = 50.0
#: Yaw-rate targets faster than this are refused [rad/s] (ArduCopter's ATC_RATE_Y_MAX: 360°/s)
MAX_TARGET_YAW_RATE_RADPS = 2.0 * math.pi

_FRAMES = {
    MAV_FRAME_LOCAL_NED: "LOCAL_NED",
    MAV_FRAME_LOCAL_OFFSET_NED: "LOCAL_OFFSET_NED",
    MAV_FRAME_BODY_NED: "BODY_NED",
    MAV_FRAME_BODY_OFFSET_NED: "BODY_OFFSET_NED",
}


class SetpointError(ValueError):
    """A SET_POSITION_TARGET_LOCAL_NED cannot be used; the message says why."""


@dataclass(frozen=True)
class VehiclePose:
    """Where the vehicle is, for relative frames."""

    pos_ned_m: tuple[float, float, float]
    yaw_rad: float


def _rotate_heading(vec: tuple[float, float, float], yaw_rad: float) -> tuple[float, float, float]:
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return (c * vec[0] - s * vec[1], s * vec[0] + c * vec[1], vec[2])


def decode_position_target(
    type_mask: int,
    coordinate_frame: int,
    pos: tuple[float, float, float],
    vel: tuple[float, float, float],
    yaw_rad: float,
    yaw_rate_radps: float,
    pose: VehiclePose,
) -> GuidedTarget:
    """Turn the fields of SET_POSITION_TARGET_LOCAL_NED into a LOCAL_NED :class:`GuidedTarget`.

    Raises
    ------
    SetpointError
        For an unsupported frame, a partial position/velocity group, non-finite used
        fields, or a target that uses nothing.
    """
    if coordinate_frame not in _FRAMES:
        raise SetpointError(f"unsupported coordinate_frame {coordinate_frame}")
    use_pos = _group(type_mask, MASK_POS, "position")
    use_vel = _group(type_mask, MASK_VEL, "velocity")
    use_yaw = not type_mask & MASK_YAW
    use_yaw_rate = not type_mask & MASK_YAW_RATE
    use_accel = (type_mask & MASK_ACCEL) != MASK_ACCEL
    if not (use_pos or use_vel or use_yaw or use_yaw_rate):
        if use_accel:
            raise SetpointError("acceleration-only targets are not supported")
        raise SetpointError(f"type_mask {type_mask} ignores every field")
    for name, values, used in (
        ("position", pos, use_pos),
        ("velocity", vel, use_vel),
        ("yaw", (yaw_rad,), use_yaw),
        ("yaw_rate", (yaw_rate_radps,), use_yaw_rate),
    ):
        if used and not all(math.isfinite(v) for v in values):
            raise SetpointError(f"{name} is not finite: {values}")
    body = coordinate_frame in (MAV_FRAME_BODY_NED, MAV_FRAME_BODY_OFFSET_NED)
    relative = coordinate_frame != MAV_FRAME_LOCAL_NED
    pos_ned = None
    if use_pos:
        p = _rotate_heading(pos, pose.yaw_rad) if body else tuple(float(v) for v in pos)
        if relative:
            p = tuple(a + b for a, b in zip(pose.pos_ned_m, p, strict=True))
        pos_ned = p
    vel_ned = None
    if use_vel:
        vel_ned = _rotate_heading(vel, pose.yaw_rad) if body else tuple(float(v) for v in vel)
    yaw = None
    if use_yaw:
        yaw = float(yaw_rad) + (pose.yaw_rad if body else 0.0)
        yaw = (yaw + math.pi) % (2.0 * math.pi) - math.pi
    return GuidedTarget(
        pos_ned_m=pos_ned,
        vel_ned_mps=vel_ned,
        yaw_rad=yaw,
        yaw_rate_radps=float(yaw_rate_radps) if use_yaw_rate else None,
    )


def check_target_range(target: GuidedTarget, home_ned_m) -> None:
    """Raise :class:`SetpointError` for a target outside the sane envelope around home."""
    if target.pos_ned_m is not None:
        d = math.dist(target.pos_ned_m, home_ned_m)
        if not d <= MAX_TARGET_RANGE_M:
            raise SetpointError(f"position {d:.0f} m from home (limit {MAX_TARGET_RANGE_M:g} m)")
    if target.vel_ned_mps is not None:
        speed = math.hypot(*target.vel_ned_mps)
        if not speed <= MAX_TARGET_SPEED_MPS:
            raise SetpointError(f"speed {speed:g} m/s (limit {MAX_TARGET_SPEED_MPS:g} m/s)")
    if target.yaw_rate_radps is not None and not (
        abs(target.yaw_rate_radps) <= MAX_TARGET_YAW_RATE_RADPS
    ):
        raise SetpointError(f"yaw rate {target.yaw_rate_radps:g} rad/s")


def decode_global_target(
    type_mask: int,
    coordinate_frame: int,
    lat_lon_e7: tuple[int, int],
    alt_m: float,
    vel: tuple[float, float, float],
    yaw_rad: float,
    yaw_rate_radps: float,
    pose: VehiclePose,
    earth: FlatEarth,
    home_down_m: float,
) -> GuidedTarget:
    """SET_POSITION_TARGET_GLOBAL_INT → LOCAL_NED :class:`GuidedTarget` (velocity in NED).

    Raises
    ------
    SetpointError
        For an unsupported frame, an invalid latitude/longitude or what
        :func:`decode_position_target` refuses.
    """
    if coordinate_frame not in (MAV_FRAME_GLOBAL_INT, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
        raise SetpointError(f"unsupported coordinate_frame {coordinate_frame}")
    pos = (0.0, 0.0, 0.0)
    if _group(type_mask, MASK_POS, "position"):
        lat_e7, lon_e7 = lat_lon_e7
        if not valid_lat_lon_e7(lat_e7, lon_e7) or not math.isfinite(alt_m):
            raise SetpointError(f"invalid location {lat_e7}, {lon_e7}, {alt_m!r}")
        north, east = earth.ned_from_lat_lon(lat_e7 * 1e-7, lon_e7 * 1e-7)
        ref_down = earth.alt_amsl_m if coordinate_frame == MAV_FRAME_GLOBAL_INT else home_down_m
        pos = (north, east, ref_down - alt_m)
    return decode_position_target(
        type_mask, MAV_FRAME_LOCAL_NED, pos, vel, yaw_rad, yaw_rate_radps, pose
    )


def _group(type_mask: int, bits: int, name: str) -> bool:
    ignored = type_mask & bits
    if ignored == bits:
        return False
    if ignored == 0:
        return True
    raise SetpointError(
        f"type_mask {type_mask} ignores only part of the {name} fields (all or none)"
    )


def type_mask_for(*, pos: bool, vel: bool, yaw: bool, yaw_rate: bool) -> int:
    """The type_mask that uses exactly the named groups (acceleration ignored)."""
    mask = MASK_ACCEL
    if not pos:
        mask |= MASK_POS
    if not vel:
        mask |= MASK_VEL
    if not yaw:
        mask |= MASK_YAW
    if not yaw_rate:
        mask |= MASK_YAW_RATE
    return mask
