"""Which way a staged vertical move faces (issue 36; the envelope's step 7).

A setpoint straight above or below the vehicle cannot be flown straight: the forward
camera never sees the column free, so the safety envelope climbs (or descends) to it in
stages along the vehicle's *heading* at the path's elevation limit, where the camera
looks (:mod:`companion.guidance.envelope`, step 7). Guidance has no bearing to face for
such a setpoint and keeps its last yaw. When that heading points into a boundary (a wall
beside the column, turned toward while avoiding it), every stage ends inside it, the
target is shortened to the vehicle (``hold.keep_target_out``) and nothing turns the
camera: the vehicle hovers until the no-progress rule stops it (passage scene
vertical-123, traced per frame: 28 s at yaw 52°, the stage 0.68 m long inside the wall's
boundary).

:func:`stage_yaw_rad` keeps the yaw while its stage is clear of every boundary, and
otherwise turns to the bearing nearest "away from the boundary in the way" whose stage is
clear. Pure: positions and spheres in, a yaw out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["STAGE_REACH_M", "stage_yaw_rad", "staged_move"]

_BEARINGS = 16  # candidate bearings, 22.5° apart, tried nearest "away" first
# the stage's length checked [m]: the envelope's near field (1.05 m: a climb above the
# camera's view is certified no farther) and half a metre of the next stage
STAGE_REACH_M = 1.5
# a setpoint nearer than this above or below is not staged for [m]: the goal's arrival
# tolerance (a goal beside a wall, arrived at, keeps facing it)
_MIN_RISE_M = 0.5


def staged_move(
    pos_ned_m, goal_ned_m, elevation_rad: float, reach_m: float = STAGE_REACH_M
) -> bool:
    """Whether the move to ``goal_ned_m`` is a staged vertical one: the goal at least
    0.5 m above or below, steeper than ``elevation_rad``, and within ``reach_m``
    horizontally (a stage's reach: the stages swing the vehicle up to about the envelope's
    ``stage_horizontal_m`` off the column, and back).

    Such a move's velocity is the stages' swing, not a way to the goal: guidance takes
    the direction to the goal as its threat reference there (issue 36, passage scenes
    vertical-7 and vertical-19, stereo, traced per frame: a 0.2 m/s swing toward a wall
    2 m beside the column, nearer than a goal 4 m below, made it a threat; the avoidance
    led round the wall's end and back for 40-50 s until ``NO_PROGRESS``). The envelope
    still certifies each stage (known free, its speed bound) and step 3 still escapes a
    boundary entered.
    """
    to_goal = np.asarray(goal_ned_m, dtype=float) - np.asarray(pos_ned_m, dtype=float)
    dz = abs(float(to_goal[2]))
    horiz_m = math.hypot(float(to_goal[0]), float(to_goal[1]))
    return dz >= _MIN_RISE_M and horiz_m <= reach_m and dz > horiz_m * math.tan(elevation_rad)


def _stage_blocked(pos: np.ndarray, unit: np.ndarray, reach_m: float, spheres) -> int | None:
    """Index of the first sphere (not holding ``pos``) that the segment ``pos → pos +
    reach_m·unit`` enters, or None."""
    for i, (centre, radius) in enumerate(spheres):
        f = centre - pos
        if float(f @ f) <= radius * radius:
            continue  # the vehicle is inside: the escape rules decide, not the stage
        t = min(max(float(f @ unit), 0.0), reach_m)
        closest = f - t * unit
        if float(closest @ closest) < radius * radius:
            return i
    return None


def stage_yaw_rad(
    pos_ned_m,
    setpoint_ned_m,
    yaw_rad: float,
    spheres: Sequence[tuple[Sequence[float], float]],
    elevation_rad: float,
    reach_m: float = STAGE_REACH_M,
) -> float | None:
    """The yaw [rad] for a stage toward a setpoint straight above or below, or None to keep
    ``yaw_rad``.

    Parameters
    ----------
    pos_ned_m, setpoint_ned_m : array_like, shape (3,)
        Vehicle and setpoint [m, NED].
    yaw_rad : float
        The yaw held now [rad].
    spheres : sequence of (centre [m, NED], radius [m])
        Inflated boundaries.
    elevation_rad : float
        The stage's climb or descent angle (the path's elevation limit) [rad].
    reach_m : float
        Length of the stage checked [m] (``STAGE_REACH_M``).

    Returns
    -------
    float or None
        None when the setpoint is not steeper than ``elevation_rad`` or less than 0.5 m
        above or below, or the stage along ``yaw_rad`` is clear; else the first of 16
        bearings, ordered by their angle from the bearing that points away from the
        boundary in the way, whose stage is clear; None when none is.
    """
    pos = np.asarray(pos_ned_m, dtype=float)
    to_setpoint = np.asarray(setpoint_ned_m, dtype=float) - pos
    dz = float(to_setpoint[2])
    steep = abs(dz) > math.hypot(to_setpoint[0], to_setpoint[1]) * math.tan(elevation_rad)
    if not (steep and abs(dz) >= _MIN_RISE_M and math.isfinite(yaw_rad)):
        return None
    balls = [(np.asarray(c, dtype=float), float(r)) for c, r in spheres]
    ce, se = math.cos(elevation_rad), math.copysign(math.sin(elevation_rad), dz)

    def unit(bearing: float) -> np.ndarray:
        return np.array([ce * math.cos(bearing), ce * math.sin(bearing), se])

    blocking = _stage_blocked(pos, unit(yaw_rad), reach_m, balls)
    if blocking is None:
        return None
    away = pos - balls[blocking][0]
    away_rad = (
        math.atan2(float(away[1]), float(away[0]))
        if math.hypot(*away[:2]) > 1e-9
        else (yaw_rad + math.pi)
    )
    step = 2.0 * math.pi / _BEARINGS
    for k in sorted(range(-_BEARINGS // 2 + 1, _BEARINGS // 2 + 1), key=lambda k: (abs(k), k)):
        bearing = math.remainder(away_rad + k * step, 2.0 * math.pi)
        if _stage_blocked(pos, unit(bearing), reach_m, balls) is None:
            return bearing
    return None
