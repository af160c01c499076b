"""The stop short of an unreachable goal and an obstacle's map pieces (guidance step 6).

When the goal lies inside a confirmed boundary sphere, guidance steers
to the *stop point* instead, ``goal_standoff_m`` before the straight path to the goal
enters the goal's obstacle, and holds there (``GOAL_UNREACHABLE``, latched while the
goal stays inside): a stable, reported stop outside the obstacle, never a go-around. The
goal's obstacle is every sphere holding the goal and, transitively, every sphere whose
surface comes within ``goal_standoff_m`` of one of theirs: an obstacle arrives as
several map pieces, and the piece holding the goal (its blind spot) lies behind pieces
that do not. Stopping short of the goal's piece alone put the stop point inside a front
piece whenever one covered it; guidance then held wherever the vehicle was with another
reason, so the place and the reported reason of the stop hung on which pieces the last
frames had confirmed (frame timing, CPU load). Now the stop point lies outside every
confirmed sphere (any sphere holding it would be within ``goal_standoff_m`` of the one
the path enters), and the reason for holding short of a goal inside an obstacle is
always ``GOAL_UNREACHABLE``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from companion.guidance._vec import norm3
from companion.guidance.modes import Mode, Reason

__all__ = ["hold_at_stop_point", "inside_ball", "same_obstacle", "stop_point"]


def stop_point(pos: np.ndarray, goal: np.ndarray, tracks, cfg) -> np.ndarray | None:
    """The stop point short of a goal inside a confirmed boundary (module docstring), or
    None when the goal is outside every one."""
    holding = [i for i, t in enumerate(tracks) if inside_ball(goal, t.sphere)]
    if not holding:
        return None
    obstacle = same_obstacle(tracks, holding, gap_m=cfg.goal_standoff_m)
    return _stop_short(pos, goal, [tracks[i] for i in obstacle], cfg.goal_standoff_m)


def _stop_short(pos: np.ndarray, goal: np.ndarray, blocking, standoff_m: float) -> np.ndarray:
    """Where to stop on the way to an unreachable goal: ``standoff_m`` before the segment
    ``pos → goal`` first enters one of the ``blocking`` spheres (``pos`` if already in)."""
    d = goal - pos
    length = norm3(d)
    if length <= 1e-9:
        return pos.copy()
    u = d / length
    t_stop = length
    for track in blocking:
        c = np.asarray(track.sphere.center_ned_m) - pos
        r = float(track.sphere.radius_m)
        b = float(c @ u)
        disc = b * b - (float(c @ c) - r * r)
        if disc < 0.0:
            continue
        t_stop = min(t_stop, b - math.sqrt(disc))
    return pos + u * max(t_stop - standoff_m, 0.0)


def inside_ball(point: np.ndarray, ball) -> bool:
    return norm3(point - np.asarray(ball.center_ned_m)) < float(ball.radius_m)


def same_obstacle(tracks, seeds: Iterable[int], gap_m: float = 0.0) -> list[int]:
    """Indices of the spheres touching the ``seeds``' (or within ``gap_m`` of them),
    transitively: one obstacle's map pieces.

    The active obstacle is kept while the straight path to the goal crosses any of its
    pieces, and passing it clears all of them at once. Deciding on the active piece alone
    released the avoidance while the goal path still crossed a neighbouring piece; the
    velocity, turning back to the goal, entered that piece's cone and the avoidance
    restarted (the flag of Fig. 11 chattered).
    """
    centers = [np.asarray(t.sphere.center_ned_m) for t in tracks]
    radii = [float(t.sphere.radius_m) for t in tracks]
    group = set(seeds)
    frontier = sorted(group)
    while frontier:
        a = frontier.pop()
        for j in range(len(tracks)):
            if j not in group and norm3(centers[a] - centers[j]) <= radii[a] + radii[j] + gap_m:
                group.add(j)
                frontier.append(j)
    return sorted(group)


def hold_at_stop_point(state, f, d, cfg) -> None:
    """The goal is unreachable and ``f.goal`` is the stop point before its obstacle: HOLD
    (``GOAL_UNREACHABLE``) once within ``goal_standoff_m`` of it, and while held for it."""
    if (state.mode is Mode.HOLD and state.unreachable) or f.goal_dist < cfg.goal_standoff_m:
        d.mode, d.reason = Mode.HOLD, Reason.GOAL_UNREACHABLE
        d.aim, d.aim_dir = None, None
