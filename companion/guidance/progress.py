"""Every stall reported: progress toward the goal and the holds that end a stall
(guidance's last phase).

When the distance to the goal has not fallen ``stall_progress_m`` below its
best for ``stall_timeout_s`` outside a HOLD, guidance holds where the vehicle is
(``NO_PROGRESS``, latched until the goal changes): a way that stays unseen or a detour
that circles or paces never ends in wandering until the battery runs out. The timer runs
from the first step toward a goal and restarts in any other HOLD; once the vehicle has
come within ``near_goal_m`` of the goal its own, shorter rule counts instead.

"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from companion.guidance._vec import norm3
from companion.guidance.modes import Mode, Reason

__all__ = ["Progress", "hold", "watch_progress"]

_MAX_STEP_GAP_S = 0.5  # a longer gap between steps is time guidance did not steer


@dataclass(frozen=True)
class Progress:
    """Progress toward one goal: the best distance to it so far, the guidance time spent
    since without getting ``stall_progress_m`` nearer, and whether guidance gave up
    (``NO_PROGRESS``, latched until the goal changes).

    ``near_best_m``/``near_stuck_s`` are the near-goal rule's best distance and count,
    ``origin_ne_m`` the horizontal position (north, east) where the best distance last
    improved, ``reach_m`` the farthest a detour has gone from there (horizontally, in
    steps of ``detour_reach_step_m``), ``since_best_s`` the steering time since then,
    reaching farther or not (``max_detour_s``), and ``unreachable`` the latched
    ``GOAL_UNREACHABLE`` hold.
    """

    goal_ned_m: tuple[float, float, float]
    best_distance_m: float
    stuck_s: float = 0.0
    stalled: bool = False
    near_best_m: float = math.inf
    near_stuck_s: float = 0.0
    origin_ne_m: tuple[float, float] = (0.0, 0.0)
    reach_m: float = 0.0
    since_best_s: float = 0.0
    unreachable: bool = False


def watch_progress(
    state,
    f,
    goal: tuple[float, float, float],
    d,
    cfg,
    steering: bool,
    surely_blocked: bool = True,
) -> Progress:
    """Every stall ends in a latched, reported HOLD (until the goal changes).

    * ``GOAL_UNREACHABLE`` entered while the goal is surely blocked (``surely_blocked``)
      stays held for this goal: the map's pieces change from frame to frame, and a goal
      that left every confirmed sphere for one frame must not release the stop into a
      go-around (issue 36).
    * ``NO_PROGRESS``: ``stall_timeout_s`` of steering outside a HOLD without getting
      ``stall_progress_m`` nearer the goal. The count restarts in other HOLDs and on each
      step of an ``AVOID`` detour that *reaches farther*: whose horizontal distance from
      where the best distance last improved exceeds the farthest so far by
      ``detour_reach_step_m`` (a detour still going somewhere: along a wall toward its
      end, or back past its start toward the other end), but never after ``max_detour_s``
      without getting nearer. A detour that paces to and fro over ground it has covered
      earns nothing, whatever its altitude or its wobble across the wall does (stereo
      gap-0 paced 66 s along its wall, east -6 to +9 m, ±0.5 m toward and away from it,
      its altitude wandering 2 m: new 1 m columns kept restarting the count until the
      90 s limit ended it as a timeout; its reach stops growing at 54 s).
    * Near the goal: once within ``near_goal_m`` of it, its own rule counts instead
      (``near_goal_stall_s`` without getting ``0.2 · stall_progress_m`` nearer than the
      nearest so far, detour or not), standing still within ``stall_progress_m``
      (arrived: hovering at the goal is not a stall; circling past it is). The rule stays
      with the vehicle when it turns away: ground-truth vertical-19 came within 1.05 m
      below its goal, then flew a 30 s loop round the wall beside it (a detour reaching
      farther) and met the 90 s limit as a timeout; it now stops at 88.6 s. A staged
      climb's swing out and back (vertical-7, 12 s) fits within ``near_goal_stall_s``.

    A gap between steps (no frames) and a step the vehicle does not fly (``steering``
    false: a failsafe hold, a pilot's mode) do not count.
    """
    progress = state.progress
    dist = norm3(np.asarray(goal) - f.pos)
    origin = (float(f.pos[0]), float(f.pos[1]))
    if progress is None or progress.goal_ned_m != goal:
        return Progress(goal, dist, origin_ne_m=origin)
    if progress.stalled:
        hold(d, Reason.NO_PROGRESS)
        return progress
    if progress.unreachable:
        hold(d, Reason.GOAL_UNREACHABLE)
        return progress
    if d.mode is Mode.HOLD and d.reason is Reason.GOAL_UNREACHABLE and surely_blocked:
        return dataclasses.replace(progress, unreachable=True)
    if dist <= progress.best_distance_m - cfg.stall_progress_m or d.mode is Mode.HOLD:
        return Progress(goal, min(dist, progress.best_distance_m), origin_ne_m=origin)
    dt = f.time_s - state.time_s if state.time_s is not None else 0.0
    dt = dt if steering and dt <= _MAX_STEP_GAP_S else 0.0  # time guidance steered
    if dist <= cfg.near_goal_m or progress.near_best_m <= cfg.near_goal_m:
        return _near_goal(progress, dist, dt, d, cfg)
    reach_m = progress.reach_m
    stuck_s = progress.stuck_s + dt
    since_best_s = progress.since_best_s + dt
    if d.mode is Mode.AVOID and dt > 0.0:
        away_m = math.hypot(
            origin[0] - progress.origin_ne_m[0], origin[1] - progress.origin_ne_m[1]
        )
        if away_m >= reach_m + cfg.detour_reach_step_m:
            reach_m = away_m
            stuck_s = 0.0  # a detour still going somewhere new
    timed_out = stuck_s >= cfg.stall_timeout_s or since_best_s >= cfg.max_detour_s
    stalled = cfg.stall_timeout_s > 0.0 and timed_out
    if stalled:
        hold(d, Reason.NO_PROGRESS)
    return dataclasses.replace(
        progress,
        stuck_s=stuck_s,
        stalled=stalled,
        reach_m=reach_m,
        since_best_s=since_best_s,
    )


def _near_goal(progress: Progress, dist: float, dt: float, d, cfg) -> Progress:
    """The near-goal rule of :func:`watch_progress`."""
    if dist <= cfg.stall_progress_m:  # arrived (the mission's tolerance): stands still
        return dataclasses.replace(progress, near_best_m=min(dist, progress.near_best_m))
    if dist <= progress.near_best_m - 0.2 * cfg.stall_progress_m:
        return dataclasses.replace(progress, near_best_m=dist, near_stuck_s=0.0)
    near_stuck_s = progress.near_stuck_s + dt
    stalled = cfg.stall_timeout_s > 0.0 and near_stuck_s >= cfg.near_goal_stall_s
    if stalled:
        hold(d, Reason.NO_PROGRESS)
    return dataclasses.replace(progress, near_stuck_s=near_stuck_s, stalled=stalled)


def hold(d, reason: Reason) -> None:
    d.mode, d.reason = Mode.HOLD, reason
    d.aim, d.aim_dir = None, None
