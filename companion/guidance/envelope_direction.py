"""Directions the safety envelope measures known-free space along (steps 1, 2, 5 and 7).

Pure geometry over NED unit vectors, split out of :mod:`companion.guidance.envelope`
(its module docstring numbers the steps): the path direction with its elevation clamped
and vertical moves staged along the heading (steps 1 and 7), whether the camera looks
along a direction (step 2), and the direction a braking vehicle's bound is stated along
(step 5).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["CLIMB_SLACK_MPS", "brake_direction", "looked_along", "path_direction", "staged"]

CLIMB_SLACK_MPS = 0.1
"""Vertical speed a climb or descent may run beyond the path's slope [m/s]: the least
climb or descent speed the companion states (``companion.link.speed_limit``'s
``ClimbLimitPolicy``, floored at 0.1 m/s since ArduPilot ignores a speed ≤ 0). Slow along
a staged 12° path (0.3 m/s: 0.064 m/s of climb), ArduCopter climbs at that floor, 18–19°;
see :func:`brake_direction`."""


def path_direction(
    to_setpoint: np.ndarray, max_elev_rad: float, heading_rad: float | None, stage_m: float
) -> np.ndarray:
    """Unit direction to the setpoint with its elevation clamped (steps 1 and 7): a steep
    move whose horizontal part is shorter than ``stage_m`` climbs or descends along the
    vehicle's heading (where the camera looks) when one is given."""
    dist = math.sqrt(float(to_setpoint @ to_setpoint))
    u = to_setpoint / dist
    horiz_m = math.hypot(float(to_setpoint[0]), float(to_setpoint[1]))
    elev = math.atan2(-float(to_setpoint[2]), horiz_m)  # NED: up is −z
    if abs(elev) <= max_elev_rad:
        return u
    if heading_rad is not None and horiz_m < stage_m:
        h = (math.cos(heading_rad), math.sin(heading_rad))
    elif horiz_m < 1e-6 * dist:
        return u
    else:
        h = (float(to_setpoint[0]) / horiz_m, float(to_setpoint[1]) / horiz_m)
    return _at_elevation(h, math.copysign(max_elev_rad, elev))


def staged(
    to_setpoint: np.ndarray, max_elev_rad: float, heading_rad: float | None, stage_m: float
) -> bool:
    """Whether :func:`path_direction` stages this move (step 7): steeper than
    ``max_elev_rad``, its horizontal part shorter than ``stage_m``, a heading given."""
    dist = math.sqrt(float(to_setpoint @ to_setpoint))
    if heading_rad is None or not dist > 0.0:
        return False
    horiz_m = math.hypot(float(to_setpoint[0]), float(to_setpoint[1]))
    elev = math.atan2(-float(to_setpoint[2]), horiz_m)
    return abs(elev) > max_elev_rad and horiz_m < stage_m


def looked_along(unit: np.ndarray, heading_rad: float | None, look_half_angle_deg: float) -> bool:
    """Step 2: the camera looks along ``unit`` (its horizontal bearing within
    ``look_half_angle_deg`` of the heading). True without a heading (the caller states
    none) and for a path with no horizontal part (nothing to turn toward)."""
    horiz_m = math.hypot(float(unit[0]), float(unit[1]))
    if heading_rad is None or horiz_m < 1e-6:
        return True
    cos_off = float(unit[0]) * math.cos(heading_rad) + float(unit[1]) * math.sin(heading_rad)
    return cos_off >= horiz_m * math.cos(math.radians(look_half_angle_deg))


def brake_direction(vel_ned_mps: np.ndarray, max_elev_rad: float) -> np.ndarray:
    """The unit direction a braking vehicle's speed bound is stated along (step 5).

    Its velocity, except for the part of a climb or descent that only the climb
    statement's floor explains: a velocity steeper than ``max_elev_rad`` whose vertical
    speed beyond that slope is at most :data:`CLIMB_SLACK_MPS` is taken at the path's
    elevation (same bearing). Such a vehicle flies a staged path slowly and climbs at the
    floor (vertical-215, ground truth, traced per frame: 0.30 m/s at 18–19.5° toward a
    12° stage; along the velocity, above the camera's view, only the body's own 0.3 m was
    known free, the bound stated 0 m/s, 15 frames "over" it). What that slack adds over a
    stop is at most ``CLIMB_SLACK_MPS`` × the stop's duration (τ + v/a: 0.085 m at the
    1.4 m/s the near field allows), inside the section's half-height (0.2 m), so the
    section along the clamped direction holds the stop. A steeper climb or descent (a
    vertical speed the statement does not explain) keeps its own direction: what lies
    there was not seen, and the bound says so.
    """
    speed = math.sqrt(float(vel_ned_mps @ vel_ned_mps))
    unit = vel_ned_mps / speed
    horiz_mps = math.hypot(float(vel_ned_mps[0]), float(vel_ned_mps[1]))
    up_mps = -float(vel_ned_mps[2])
    beyond_mps = abs(up_mps) - horiz_mps * math.tan(max_elev_rad)
    if beyond_mps <= 0.0 or beyond_mps > CLIMB_SLACK_MPS or horiz_mps < 1e-9:
        return unit
    h = (float(vel_ned_mps[0]) / horiz_mps, float(vel_ned_mps[1]) / horiz_mps)
    return _at_elevation(h, math.copysign(max_elev_rad, up_mps))


def _at_elevation(bearing_unit: tuple[float, float], elev_rad: float) -> np.ndarray:
    """The unit vector of horizontal bearing ``bearing_unit`` at ``elev_rad`` up [NED]."""
    c = math.cos(elev_rad)
    return np.array([bearing_unit[0] * c, bearing_unit[1] * c, -math.sin(elev_rad)], dtype=float)
