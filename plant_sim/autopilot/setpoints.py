"""SET_POSITION_TARGET_LOCAL_NED decoding: type_mask semantics and coordinate frames (pure).

Standard MAVLink semantics: a set type_mask bit means "ignore this field". Bits 0–2 x, y, z;
3–5 vx, vy, vz; 6–8 afx, afy, afz; 9 force; 10 yaw; 11 yaw_rate. Position-only is 3576
(0b1101_1111_1000), position + yaw 2552, velocity-only 3527. Position and velocity are used
all-or-nothing per group, like ArduCopter; a partial group is refused. Acceleration fields
are ignored (the plant's tracker has no acceleration input), acceleration-only targets are
refused. Frames: LOCAL_NED (1); LOCAL_OFFSET_NED (7: position relative to the vehicle,
velocity NED); BODY_NED (8) and BODY_OFFSET_NED (9: position and velocity in the vehicle's
heading frame, position relative to the vehicle), as ArduCopter reads them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from plant_sim.autopilot.modes import GuidedTarget

__all__ = [
    "MASK_ACCEL",
    "MASK_POS",
    "MASK_VEL",
    "MASK_YAW",
    "MASK_YAW_RATE",
    "SetpointError",
    "VehiclePose",
    "decode_position_target",
    "type_mask_for",
]

MASK_POS = 0b0000_0000_0111
MASK_VEL = 0b0000_0011_1000
MASK_ACCEL = 0b0001_1100_0000
MASK_FORCE = 0b0010_0000_0000
MASK_YAW = 0b0100_0000_0000
MASK_YAW_RATE = 0b1000_0000_0000

MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_LOCAL_OFFSET_NED = 7
MAV_FRAME_BODY_NED = 8
MAV_FRAME_BODY_OFFSET_NED = 9
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
