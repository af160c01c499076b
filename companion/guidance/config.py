"""Guidance parameters: aiming-point planner, mode switching and obstacle memory.

None of these numbers is in the paper (§5 gives the cone and Eq. 28 only); each is a
named assumption with its unit. Boundary spheres arrive already inflated (vehicle radius +
margin), and the detection threshold (4 m in §6) is perception's parameter, not ours.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from protocols.config import (
    ConfigError,
    UnknownKeyError,
    bounded,
    check_fields,
    dataclass_from_mapping,
)

__all__ = ["GuidanceConfig", "UnknownGuidanceKeyError"]


#: a guidance configuration mapping named a key that does not exist (also a TypeError)
UnknownGuidanceKeyError = UnknownKeyError


@dataclass(frozen=True)
class GuidanceConfig:
    """Tuning of the companion's guidance (all angles in radians, times in sim seconds).

    Attributes
    ----------
    n_candidates : int
        Aiming-point candidates sampled on each tangent circle (72 → 5° apart). The first
        is the exact Eq. (28) point; the rest are the fallbacks when it is blocked.
    tie_angle_rad : float
        A reference direction within this angle of an obstacle's axis is head-on: the
        deterministic right-hand side-step decides (see ``cone`` module docstring).
        5°: several times the angular error of a perceived centre at the 4 m threshold
        (up to ~1.5° with the camera pitched 15° nose-down), so noise never picks the side.
        While the side is kept, a committed aiming direction climbing or descending by
        less than this is levelled before Eq. (28) (the same noise, vertically).
    cone_margin_rad : float
        Extra half-angle when testing a candidate against the *other* obstacles' cones.
    min_speed_mps : float
        Below this speed the velocity has no usable direction and the direction to the
        goal stands in for it (so a hovering vehicle does not start into an obstacle).
    exit_margin_rad : float
        Hysteresis: avoidance ends only once the reference is outside the active cone
        by this angle (or the obstacle is behind) ...
    min_clear_time_s : float
        ... continuously for this long [s, simulation time].
    setpoint_extension_m : float
        The position setpoint is the aiming direction extended past the tangent point by
        this much [m], so the position loop does not brake at the tangent point.
    min_setpoint_distance_m, max_setpoint_distance_m : float
        Clamp of the setpoint distance from the vehicle along the aiming direction [m].
    escape_clearance_m : float
        Inside a boundary sphere, the escape setpoint lies this far outside it [m].
    goal_clearance_m : float
        An obstacle whose (inflated) surface is farther than ``|goal - p| +
        goal_clearance_m`` and that does not block the straight path to the goal is not
        a threat: the vehicle stops at the goal before reaching it [m]. 0: the boundary
        already carries the vehicle radius and the safety margin, so a real surface just
        past the goal needs no go-around.
    goal_standoff_m : float
        An unreachable goal (inside a boundary) is replaced by the point this far before
        the boundary on the straight path to it, where the vehicle holds [m].
    yaw_min_distance_m : float
        Below this horizontal distance to the setpoint the previous yaw is held [m].
    merge_distance_m : float
        A detection whose centre is within this distance of a remembered obstacle's centre
        (or inside it) updates it instead of creating a new one [m].
    memory_timeout_s : float
        An obstacle unseen for longer than this is forgotten, unless its surface is
        within ``forget_distance_m`` [s, simulation time].
    forget_distance_m : float
        An unseen obstacle behind the vehicle (centre behind the plane normal to the
        velocity) whose surface is farther than this is forgotten [m].
    max_tracks : int
        Most obstacles remembered; the least recently seen go first.
    confirm_n, confirm_m : int
        A new obstacle is avoided once detected in ``confirm_n`` of ``confirm_m`` frames
        (default 2 of 3) ...
    confirm_immediate_m : float
        ... or at its first detection when its surface is nearer than this [m] (2.0: the
        stopping distance from the fast profile's 3 m/s plus margin; the paper's cruise
        needs 0.5 m).
    max_aim_elevation_rad : float
        Aiming directions steeper than this are not candidates (12°: the safety
        envelope's steepest path, inside the camera's ±18.5° vertical view).
    vertical_weight : float
        The planner ranks aiming directions by their angle to the reference with vertical
        components scaled by this (3: a level detour wins over a climb of a third of its
        angle; 1 is Eq. 28 exactly). Several spheres per obstacle (the map's pieces) make
        the free direction nearest the velocity tilt by where the pieces fall; a
        multirotor keeps its altitude unless climbing is clearly shorter.
    stall_timeout_s : float
        No progress toward the goal for this long outside a HOLD, flying guidance's
        setpoints (a failsafe hold or a pilot's mode does not count) → a latched, reported
        HOLD (``NO_PROGRESS``) where the vehicle is [s, simulation time]; 0 disables.
        A detour that never gets nearer (circling a goal next to an obstacle, a way ahead
        that stays unseen) ends in a stop the pilot is told of, not endless wandering.
        30 s: a long detour (round a 10 m wall at 0.85 m/s) gets nearer within ~15 s.
    stall_progress_m : float
        Progress is the distance to the goal falling this far below its best so far [m];
        within this distance of the goal (arrived) the count stands still (hovering at
        the goal is not a stall; circling past it without arriving still is).
    near_goal_stall_s : float
        Once within ``near_goal_m`` of the goal but not within ``stall_progress_m`` of it
        (arrived, the mission's default tolerance), this long without getting
        ``0.2 · stall_progress_m`` nearer than the nearest so far → the same latched
        ``NO_PROGRESS`` HOLD [s], whether the vehicle stays or turns away on a detour.
        Hovering 0.9 m short of a goal the envelope cannot certify (straight above) is a
        stall the pilot is told of, not a silent hover until the battery runs out. 20 s:
        a staged climb swings a few metres sideways and back to look at its last stage
        (ground-truth vertical-7: 12 s from its nearest point, 0.84 m, to the goal; 10 s
        stopped it 1.9 m short).
    near_goal_m : float
        Where the near-goal rule takes over [m]: 1.5 m, three times ``stall_progress_m``,
        two vehicle lengths; a goal this close is reached straight or round a small
        obstacle within seconds, not by a long detour (ground-truth vertical-19 came
        within 1.05 m below its goal, then looped 30 s round the wall beside it). A goal
        0.7 m behind a thin wall is ≥ 1.65 m away at the wall's boundary, outside it.
    detour_reach_step_m : float
        While avoiding (``AVOID``), a step whose horizontal distance from where the best
        distance last improved exceeds the farthest so far by this much restarts the
        ``stall_timeout_s`` count [m]: a detour along a wall toward its end (or back past
        its start toward the other end) does not stall, one that paces to and fro over
        ground it has covered does, whatever its altitude or its wobble does.
    max_detour_s : float
        The longest a detour may go on without getting ``stall_progress_m`` nearer the goal,
        reaching farther or not [s]; then the ``NO_PROGRESS`` HOLD. Every flight thus ends
        at the goal or in a reported stop within a bound. 60 s: round the end of a 30 m
        wall from its middle (15 m out, ~15 m back behind it at 0.85 m/s) gets nearer
        within ~35 s.
    known_path_progress_m : float
        A path through known-free space (:mod:`companion.guidance.known_path`) replaces the
        cone rule's aiming point only when its end lies at least this much nearer the goal
        than the vehicle [m] (1.0: twice ``stall_progress_m``, so flying it is progress).
    """

    n_candidates: int = bounded(72, integer=True, ge=1)
    tie_angle_rad: float = bounded(math.radians(5.0), "rad", ge=0, lt=0.5 * math.pi)
    cone_margin_rad: float = bounded(0.0, "rad", ge=0)
    min_speed_mps: float = bounded(0.2, "m/s", ge=0)
    exit_margin_rad: float = bounded(math.radians(5.0), "rad", ge=0)
    min_clear_time_s: float = bounded(0.3, "s", ge=0)
    setpoint_extension_m: float = bounded(1.0, "m", ge=0)
    min_setpoint_distance_m: float = bounded(2.0, "m", ge=0)
    max_setpoint_distance_m: float = bounded(10.0, "m", ge=0)
    escape_clearance_m: float = bounded(0.5, "m", ge=0)
    goal_clearance_m: float = bounded(0.0, "m", ge=0)
    goal_standoff_m: float = bounded(0.5, "m", ge=0)
    yaw_min_distance_m: float = bounded(0.5, "m", ge=0)
    merge_distance_m: float = bounded(1.0, "m", ge=0)
    memory_timeout_s: float = bounded(10.0, "s", ge=0)
    forget_distance_m: float = bounded(2.0, "m", ge=0)
    max_tracks: int = bounded(16, integer=True, ge=1)
    confirm_n: int = bounded(2, integer=True, ge=1, le=30)
    confirm_m: int = bounded(3, integer=True, ge=1, le=30)
    confirm_immediate_m: float = bounded(2.0, "m", ge=0)
    # also the safety envelope's path-elevation clamp: it must clamp something
    max_aim_elevation_rad: float = bounded(math.radians(12.0), "rad", gt=0, le=0.5 * math.pi)
    vertical_weight: float = bounded(3.0, gt=0)
    stall_timeout_s: float = bounded(30.0, "s", ge=0)
    stall_progress_m: float = bounded(0.5, "m", ge=0)
    near_goal_stall_s: float = bounded(20.0, "s", ge=0)
    near_goal_m: float = bounded(1.5, "m", ge=0)
    detour_reach_step_m: float = bounded(1.0, "m", gt=0)
    max_detour_s: float = bounded(60.0, "s", ge=0)
    known_path_progress_m: float = bounded(1.0, "m", ge=0)

    def __post_init__(self) -> None:
        check_fields(self)
        if self.confirm_n > self.confirm_m:
            raise ConfigError(
                f"must be <= confirm_m ({self.confirm_m}), got {self.confirm_n}", key="confirm_n"
            )
        if self.max_setpoint_distance_m < self.min_setpoint_distance_m:
            raise ConfigError(
                f"must be >= min_setpoint_distance_m ({self.min_setpoint_distance_m!r}), "
                f"got {self.max_setpoint_distance_m!r}",
                key="max_setpoint_distance_m",
            )

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> GuidanceConfig:
        """Build a config from a mapping (e.g. a parsed config file), defaults elsewhere.

        Raises
        ------
        UnknownGuidanceKeyError
            If ``values`` names a key that is not a field; the message names it and lists
            the valid keys.
        ConfigError
            If a value is out of its declared bounds (the message names ``guidance.<key>``
            and the bound).
        """
        return dataclass_from_mapping(cls, values, "guidance")
