"""Every stall reported: progress toward the goal and the holds that end a stall
(guidance's last phase).

When the distance to the goal has not fallen ``stall_progress_m`` below its
best for ``stall_timeout_s`` outside a HOLD, guidance holds where the vehicle is
(``NO_PROGRESS``, latched until the goal changes): a way that stays unseen or a detour
that circles never ends in wandering until the battery runs out. The timer runs from the
first step toward a goal, restarts in any other HOLD and stands still within
``2 · stall_progress_m`` of the goal.

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
    ``detour_cells`` the cells (``detour_cell_m`` cubes) visited since the best distance
    improved, ``since_best_s`` the steering time since then, new cells or not
    (``max_detour_s``), and ``unreachable`` the latched ``GOAL_UNREACHABLE`` hold.
    """

    goal_ned_m: tuple[float, float, float]
    best_distance_m: float
    stuck_s: float = 0.0
    stalled: bool = False
    near_best_m: float = math.inf
    near_stuck_s: float = 0.0
    detour_cells: frozenset[tuple[int, int, int]] = frozenset()
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
      step of an ``AVOID`` detour into a cell not visited since the best distance (a detour
      still going somewhere: along a wall toward its end), but never after ``max_detour_s``
      without getting nearer. Cells are columns (north, east): a detour that paces to and
      fro along a wall while its altitude wanders revisits them (stereo gap-0 paced 80 s,
      each pass 1-2 m higher or lower; its ±0.5 m wobble across the wall still finds
      new columns, and it still meets the 90 s limit as a timeout). Within
      ``2 · stall_progress_m`` of the goal its own rule counts instead
      (``near_goal_stall_s`` without getting ``0.2 · stall_progress_m`` nearer), standing
      still within ``stall_progress_m`` (arrived: hovering at the goal is
      not a stall; circling past it is). A gap between steps (no frames) and a step the
      vehicle does not fly (``steering`` false: a failsafe hold, a pilot's mode) do not
      count.
    """
    progress = state.progress
    dist = norm3(np.asarray(goal) - f.pos)
    if progress is None or progress.goal_ned_m != goal:
        return Progress(goal, dist)
    if progress.stalled:
        hold(d, Reason.NO_PROGRESS)
        return progress
    if progress.unreachable:
        hold(d, Reason.GOAL_UNREACHABLE)
        return progress
    if d.mode is Mode.HOLD and d.reason is Reason.GOAL_UNREACHABLE and surely_blocked:
        return dataclasses.replace(progress, unreachable=True)
    if dist <= progress.best_distance_m - cfg.stall_progress_m or d.mode is Mode.HOLD:
        return Progress(goal, min(dist, progress.best_distance_m))
    dt = f.time_s - state.time_s if state.time_s is not None else 0.0
    dt = dt if steering and dt <= _MAX_STEP_GAP_S else 0.0  # time guidance steered
    if dist <= 2.0 * cfg.stall_progress_m:
        return _near_goal(progress, dist, dt, d, cfg)
    cells = progress.detour_cells
    stuck_s = progress.stuck_s + dt
    since_best_s = progress.since_best_s + dt
    if d.mode is Mode.AVOID and dt > 0.0:
        cell = tuple(math.floor(float(x) / cfg.detour_cell_m) for x in f.pos[:2])
        if cell not in cells:
            cells = cells | {cell}
            stuck_s = 0.0  # a detour still going somewhere new
    timed_out = stuck_s >= cfg.stall_timeout_s or since_best_s >= cfg.max_detour_s
    stalled = cfg.stall_timeout_s > 0.0 and timed_out
    if stalled:
        hold(d, Reason.NO_PROGRESS)
    return dataclasses.replace(
        progress,
        stuck_s=stuck_s,
        stalled=stalled,
        detour_cells=cells,
        since_best_s=since_best_s,
        near_best_m=math.inf,
        near_stuck_s=0.0,
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
