"""One bounded look at a goal held only by a blind spot, from a side no surface hides it.

The collision safety boundary of a piece covers the blind spot behind it as the vehicle
sees it (paper Fig. 4; :mod:`companion.guidance.map_boundaries`): an unseen goal within
``inflate_m + blind_depth_m`` of a piece's seen surface, *behind* it along the line of
sight (:func:`~companion.guidance.map_boundaries.in_shadow`), may be inside the obstacle,
and guidance stops short of it (``GOAL_UNREACHABLE``, :mod:`companion.guidance.goal_stop`).
Seen from straight in front, a thin wall and a solid block look the same. Issue 36,
passages goal_surface-22 (stereo): the goal 1.70 m behind a wall 4.7 m wide and 0.3 m
thick; one cell of depth error put the nearest occupied voxel 1.71 m from the goal,
inside the 1.85 m threshold, and the vehicle stopped 4.8 m short; with ground truth's
surface 1.9 m away it flew on. A pilot would look round the edge first.

So before a ``GOAL_UNREACHABLE`` hold stands for a goal held *only* by a blind spot (every
boundary holding it keeps ``inflate_m`` from its seen surface: not
:func:`~companion.guidance.map_boundaries.goal_surely_blocked`), guidance flies once to a
*viewpoint* from which the straight line of sight to the goal passes no surface seen, and
looks at the goal from there:

* **Viewpoint** (:func:`look_viewpoint`, pure geometry): on horizontal circles about the
  goal, at the vehicle's height, of radius the vehicle's horizontal distance from the
  goal times 1, 0.75 and 1.25 (no nearer the goal than ``min_view_m``), swung from the
  vehicle's bearing in steps of ``step_deg`` up to ``max_swing_deg`` either way. A
  candidate qualifies when (a) it is within ``max_look_m`` of the vehicle, (b) the line
  of sight from it to the goal passes every OCCUPIED voxel centre near the goal by more
  than ``sight_clear_m`` (a piece's bounding sphere is too coarse here: at a thin wall's
  edge it reaches ~0.8 m past the last voxel, and only a view from beside the wall, in
  space never seen, would pass it), (c) it lies outside every boundary sphere, and (d)
  the caller's ``reachable`` finds no surface seen in the way of the straight move there.
  Of those, one whose move is seen free for the vehicle's section (the pipeline asks the
  known-space map) is taken before one whose move is not yet seen: goal_surface-22's map
  knew only 2.2-3.3 m to either side of the stop point free, and every view past the
  wall's edge lay 3.3-6 m away. A move not yet seen is flown like any goal's: guidance
  faces its setpoint, so the camera looks before the vehicle moves, and the safety
  envelope puts every carrot only into space seen free (invariant 1). The straight move
  may graze a boundary sphere (a wall's edge piece, grown by its blind spot): guidance
  steers round it by the cone rule like any goal. Then the nearest to the vehicle; ties
  to the smaller swing, then to the positive swing (clockwise seen from above in NED).
* **The look** (:func:`look_step`, a frozen state per goal): started on the first frame
  guidance holds for a goal held only by a blind spot; guidance steers to the viewpoint
  as its goal (the cone rule, the path search and the safety envelope unchanged: carrots
  only into space seen free, the stated speed bound, never inside a margin); within
  ``face_m`` of the viewpoint the vehicle faces the goal (:func:`look_yaw_rad`), so the
  camera looks at it. It *resolves* when no boundary holds the goal any more (the goal's
  voxel seen free, or no piece hides it from where the vehicle is): guidance steers to
  the goal again. It *ends unresolved* after ``look_time_s``, after ``dwell_s`` within
  ``arrive_m`` of the viewpoint with the goal still held, when guidance holds on the way
  (any reason) to the last of ``max_views`` viewpoints (a hold on the way to an earlier
  one chooses the next from where the vehicle stands), or when the goal turns out surely
  blocked; guidance then steers to the goal and stops short of it as before, the stop
  reported. One look per goal: a new goal
  starts afresh.

A goal inside the inflated boundary of a seen surface is never looked at: its hold is
latched as before (:mod:`companion.guidance.progress`), no go-around.

Pure: no clock (time is the caller's simulation time), no I/O; the map enters as its
OCCUPIED voxel centres and the ``reachable`` callable.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from protocols.config import Checked, bounded

__all__ = [
    "BLOCKED",
    "SEEN_FREE",
    "UNSEEN",
    "GoLookConfig",
    "LookPhase",
    "LookState",
    "Move",
    "held_by_blind_spot_only",
    "look_step",
    "look_viewpoint",
    "look_yaw_rad",
]

_RADIUS_FACTORS = (1.0, 0.75, 1.25)  # candidate circles, × the vehicle's distance [-]


class Move(enum.Enum):
    """How a straight move to a viewpoint stands on the map."""

    SEEN_FREE = "seen_free"
    """Seen free for the vehicle's section."""
    UNSEEN = "unseen"
    """Not yet seen free, but no surface seen in its way."""
    BLOCKED = "blocked"
    """A surface seen in its way."""


SEEN_FREE, UNSEEN, BLOCKED = Move.SEEN_FREE, Move.UNSEEN, Move.BLOCKED

ReachableFn = Callable[[np.ndarray, np.ndarray], Move]
"""``(start_ned_m, end_ned_m) → SEEN_FREE | UNSEEN | BLOCKED``: the straight move."""


@dataclass(frozen=True)
class GoLookConfig(Checked):
    """Where to look from and for how long (module docstring).

    Attributes
    ----------
    max_look_m : float
        Farthest viewpoint from the vehicle [m].
    max_swing_deg : float
        Farthest swing about the goal from the vehicle's bearing, either way [deg].
    step_deg : float
        Swing between candidates [deg].
    min_view_m : float
        No viewpoint nearer the goal than this, horizontally [m].
    sight_clear_m : float
        The line of sight passes every OCCUPIED voxel centre by this much [m] (half a
        voxel, and a voxel of margin: a surface moves by a voxel from frame to frame).
    look_time_s : float
        The look ends unresolved after this long [s].
    arrive_m : float
        At the viewpoint within this distance [m].
    dwell_s : float
        At the viewpoint this long with the goal still held ends the look [s].
    face_m : float
        Within this distance of the viewpoint the vehicle faces the goal [m].
    max_views : int
        Viewpoints tried in one look: when guidance holds on the way to one (newly seen
        surfaces put it inside a boundary, or left no free direction to it), the next is
        chosen from where the vehicle stands, all within one ``look_time_s`` [-].
    """

    max_look_m: float = bounded(6.0, "m", gt=0)
    max_swing_deg: float = bounded(90.0, "deg", gt=0, le=180)
    step_deg: float = bounded(5.0, "deg", gt=0, le=90)
    min_view_m: float = bounded(2.0, "m", gt=0)
    sight_clear_m: float = bounded(0.3, "m", ge=0)
    look_time_s: float = bounded(25.0, "s", gt=0)
    arrive_m: float = bounded(0.5, "m", gt=0)
    dwell_s: float = bounded(3.0, "s", ge=0)
    face_m: float = bounded(1.5, "m", ge=0)
    max_views: int = bounded(3, integer=True, ge=1, le=10)


def held_by_blind_spot_only(boundaries: Sequence, goal_ned_m, inflate_m: float) -> bool:
    """Whether a boundary holds the goal and none holds it for certain: every sphere
    holding it keeps ``inflate_m`` from its piece's seen surface (``goal_gap_m``), so only
    the blind spot behind a piece holds it
    (:func:`~companion.guidance.map_boundaries.goal_surely_blocked` is False)."""
    goal = np.asarray(goal_ned_m, dtype=float)
    holding = [
        b
        for b in boundaries
        if float(np.linalg.norm(goal - np.asarray(b.center_ned_m))) < float(b.radius_m)
    ]
    return bool(holding) and all(float(b.goal_gap_m) >= inflate_m for b in holding)


def _sees_goal(view: np.ndarray, goal: np.ndarray, occupied: np.ndarray, clear_m: float) -> bool:
    """No OCCUPIED voxel centre (rows of ``occupied``) within ``clear_m`` of the line of
    sight from ``view`` to ``goal``."""
    if occupied.shape[0] == 0:
        return True
    sight = goal - view
    length_sq = float(sight @ sight)
    if length_sq <= 0.0:
        return True
    t = np.clip((occupied - view) @ sight / length_sq, 0.0, 1.0)
    nearest = view + t[:, None] * sight[None, :]
    return bool(np.min(np.sum((occupied - nearest) ** 2, axis=1)) > clear_m * clear_m)


def look_viewpoint(
    pos_ned_m,
    goal_ned_m,
    occupied_ned_m,
    spheres: Sequence,
    reachable: ReachableFn,
    config: GoLookConfig | None = None,
) -> np.ndarray | None:
    """The viewpoint for a look at the goal (module docstring), or None when none qualifies.

    Parameters
    ----------
    pos_ned_m, goal_ned_m : array_like, shape (3,)
        Vehicle and goal [m, NED].
    occupied_ned_m : array_like, shape (n, 3)
        Centres of the map's OCCUPIED voxels near the goal: what may hide it [m, NED].
    spheres : sequence of SphereLike
        The inflated boundary spheres: a viewpoint lies outside every one.
    reachable : callable(start_ned_m, end_ned_m) -> Move
        How the straight move stands: ``SEEN_FREE``, ``UNSEEN`` or ``BLOCKED``.
    config : GoLookConfig, optional
    """
    cfg = GoLookConfig() if config is None else config
    pos = np.asarray(pos_ned_m, dtype=float)
    goal = np.asarray(goal_ned_m, dtype=float)
    occupied = np.asarray(occupied_ned_m, dtype=float).reshape(-1, 3)
    rel = pos[:2] - goal[:2]
    rho = math.hypot(float(rel[0]), float(rel[1]))
    bearing = math.atan2(float(rel[1]), float(rel[0])) if rho > 1e-9 else 0.0
    n_steps = math.floor(cfg.max_swing_deg / cfg.step_deg + 1e-9)
    candidates = []
    for factor in _RADIUS_FACTORS:
        radius = max(rho * float(factor), cfg.min_view_m)
        for k in range(1, n_steps + 1):
            for side in (1, -1):
                a = bearing + side * math.radians(k * cfg.step_deg)
                view = np.array(
                    [goal[0] + radius * math.cos(a), goal[1] + radius * math.sin(a), pos[2]]
                )
                travel = float(np.linalg.norm(view - pos))
                if travel <= cfg.max_look_m:
                    candidates.append((round(travel, 3), k, -side, view))
    candidates.sort(key=lambda c: c[:3])
    unseen = None
    for _, _, _, view in candidates:
        if not _sees_goal(view, goal, occupied, cfg.sight_clear_m):
            continue
        if any(_inside(view, s) for s in spheres):
            continue
        way = reachable(pos, view)
        if way is Move.SEEN_FREE:
            return view
        if way is Move.UNSEEN and unseen is None:
            unseen = view
    return unseen


def _inside(point: np.ndarray, sphere) -> bool:
    return float(np.linalg.norm(point - np.asarray(sphere.center_ned_m))) < float(sphere.radius_m)


class LookPhase(enum.Enum):
    """Where one goal's look stands."""

    NONE = "none"
    """Not looked yet."""
    LOOKING = "looking"
    """Steering to the viewpoint."""
    DONE = "done"
    """Looked (resolved or not), or no viewpoint qualified: no second look."""


@dataclass(frozen=True)
class LookState:
    """One goal's look: its phase, viewpoint [m, NED], start and arrival times [s]."""

    goal_ned_m: tuple[float, float, float] | None = None
    phase: LookPhase = LookPhase.NONE
    viewpoint_ned_m: tuple[float, float, float] | None = None
    since_s: float = 0.0
    arrived_s: float | None = None
    resolved: bool = False
    views: int = 0  # viewpoints chosen in this look

    def steer_to(self, goal_ned_m) -> np.ndarray:
        """Guidance's goal this frame: the viewpoint while looking, else the goal."""
        if self.phase is LookPhase.LOOKING and self.viewpoint_ned_m is not None:
            return np.array(self.viewpoint_ned_m)
        return np.asarray(goal_ned_m, dtype=float)


def look_step(
    state: LookState,
    *,
    time_s: float,
    pos_ned_m,
    goal_ned_m,
    blind_only: bool,
    held: bool,
    holding: bool,
    viewpoint: Callable[[], np.ndarray | None],
    config: GoLookConfig | None = None,
) -> LookState:
    """Advance the look by one frame (module docstring).

    Parameters
    ----------
    time_s : float
        Simulation time [s].
    blind_only : bool
        The goal is held by a blind spot only (:func:`held_by_blind_spot_only`).
    held : bool
        A boundary holds the goal (surely or not).
    holding : bool
        Guidance's last step held: for the goal (``GOAL_UNREACHABLE``) before a look, for
        any reason while looking.
    viewpoint : callable() -> ndarray or None
        :func:`look_viewpoint` bound to this frame (called only when a look starts).
    """
    cfg = GoLookConfig() if config is None else config
    goal = tuple(float(x) for x in goal_ned_m)
    if state.goal_ned_m != goal:
        state = LookState(goal_ned_m=goal)
    if state.phase is LookPhase.NONE:
        if not (holding and blind_only):
            return state
        return _next_view(LookState(goal_ned_m=goal, since_s=float(time_s)), goal, viewpoint)
    if state.phase is LookPhase.DONE:
        # resolved, then held again (a frame's map let the goal go, the next held it):
        # another viewpoint, within the same look's time and count
        again = state.resolved and holding and blind_only and state.views < cfg.max_views
        if again and time_s - state.since_s < cfg.look_time_s:
            return _next_view(state, goal, viewpoint)
        return state
    if not held:
        return replace(state, phase=LookPhase.DONE, resolved=True, arrived_s=None)
    pos = np.asarray(pos_ned_m, dtype=float)
    at_view = float(np.linalg.norm(pos - np.asarray(state.viewpoint_ned_m))) <= cfg.arrive_m
    arrived_s = (state.arrived_s if state.arrived_s is not None else time_s) if at_view else None
    ended = (
        not blind_only
        or time_s - state.since_s >= cfg.look_time_s
        or (arrived_s is not None and time_s - arrived_s >= cfg.dwell_s)
    )
    if holding and not ended:  # held on the way: the next viewpoint, from here
        if state.views < cfg.max_views:
            return _next_view(state, goal, viewpoint)
        return LookState(goal_ned_m=goal, phase=LookPhase.DONE)
    if ended:
        return LookState(goal_ned_m=goal, phase=LookPhase.DONE)
    return LookState(
        goal_ned_m=goal,
        phase=LookPhase.LOOKING,
        viewpoint_ned_m=state.viewpoint_ned_m,
        since_s=state.since_s,
        arrived_s=arrived_s,
        views=state.views,
    )


def _next_view(state: LookState, goal: tuple, viewpoint: Callable) -> LookState:
    """The look goes on to a viewpoint chosen from where the vehicle stands now, its start
    time kept; none qualifies: the look is over, unresolved."""
    view = viewpoint()
    if view is None:
        return LookState(goal_ned_m=goal, phase=LookPhase.DONE)
    return LookState(
        goal_ned_m=goal,
        phase=LookPhase.LOOKING,
        viewpoint_ned_m=tuple(float(x) for x in view),
        since_s=state.since_s,
        views=state.views + 1,
    )


def look_yaw_rad(
    state: LookState, pos_ned_m, goal_ned_m, config: GoLookConfig | None = None
) -> float | None:
    """The yaw facing the goal [rad, NED] while looking within ``face_m`` of the
    viewpoint (the camera looks at the goal); None otherwise (guidance's yaw stands)."""
    cfg = GoLookConfig() if config is None else config
    if state.phase is not LookPhase.LOOKING or state.viewpoint_ned_m is None:
        return None
    pos = np.asarray(pos_ned_m, dtype=float)
    if float(np.linalg.norm(pos - np.asarray(state.viewpoint_ned_m))) > cfg.face_m:
        return None
    to_goal = np.asarray(goal_ned_m, dtype=float) - pos
    if math.hypot(float(to_goal[0]), float(to_goal[1])) < 1e-6:
        return None
    return math.atan2(float(to_goal[1]), float(to_goal[0]))
