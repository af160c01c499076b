"""Following a known-space path, and when it leads instead of the cone (issue 36).

The search itself is :mod:`companion.guidance.known_path` (numba kernels over the map's
arrays); this module is the Python around it: a path found is followed while it stays
valid (:func:`follow_known_path`), the cone rule's way is checked against the surfaces the
map has seen (:func:`way_blocked`), and :func:`prefer_known_path` decides which of the two
guidance flies. Pure: the map is passed in as its arrays, no clock or I/O.

When the path wins over the cone (:func:`prefer_known_path`)
------------------------------------------------------------
The paper's cone and aiming point lead; the path leads only where the cone rule fails,
on evidence from the map, never because it is a little shorter (§6 keeps its shape: a
single sphere is gone round the way the paper goes round it). The path must get at least
``min_progress_m`` (``GuidanceConfig.known_path_progress_m``) nearer the goal, and then
leads when

* the cone rule found **no admissible direction** (else guidance holds, as before);
* the cone rule's direction is **blocked in known space** (:func:`way_blocked`): the
  vehicle's body, moving straight to the cone's carrot, would meet a surface the map has
  seen (OCCUPIED; its radius, no margin), and the path leads another way (its first leg
  more than 45° from the cone's direction). The cone rule sees only the boundaries within
  the detection threshold (4 m, the paper's); the map has seen the wall beyond them, so
  a carrot that leads out of a corridor into its wall is known to end in a surface. When
  both lead the same way (§6: the carrot grazes the far part of the one sphere, not yet
  a boundary, and the path goes round the same side) the paper's rule stays;
* the straight path to the goal is blocked by the obstacle avoided, the path's first leg
  points **into a cone** of that obstacle (the cone closes a way the map shows open) and
  the path ends **past that obstacle** (nearer the goal than every one of its spheres'
  centres), and one of: the path (plus the straight line from its end to the goal) is
  ``min_progress_m`` shorter than the cone's way (vehicle → aiming point → goal); it
  passes *between* two of the obstacle's spheres (seen from above, it crosses the segment
  joining their centres: an opening); or it reaches the goal and the cone's direction
  **leads away** from it (no component along its first leg: round the far end of a wall
  while the known way goes through it). A path that only leads up to the obstacle's face,
  or goes round it the way the cone does (§6: one sphere, the two ways round less than a
  right angle apart), does not replace the paper's rule;
* once flown, the path is kept (hysteresis) while it still gets ``min_progress_m`` nearer
  the goal, so guidance does not flip between the two rules frame by frame.

Cost: a path found is followed (:func:`follow_known_path`) for up to ``replan_frames``
frames while every voxel of its rest still passes the search's test, instead of being
searched again (``benchmarks/bench_guidance_path.py``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable

import numpy as np

from companion.guidance.known_path import (
    KnownPath,
    KnownPathConfig,
    _body_meets_surface,
    _follow,
    _offset_tables,
    _offsets,
    _sphere_array,
    plan_known_path,
)
from companion.guidance.openings import warm_up as _warm_up_openings
from companion.known_space import FREE, OCCUPIED

#: the path's first leg and the cone's direction lead different ways beyond this angle
_APART_RAD = math.radians(45.0)

__all__ = [
    "follow_known_path",
    "prefer_known_path",
    "warm_up",
    "way_blocked",
]


def follow_known_path(
    path: KnownPath,
    grid: np.ndarray,
    origin_vox: np.ndarray,
    voxel_m: float,
    pos_ned_m,
    goal_ned_m,
    *,
    spheres: Iterable = (),
    config: KnownPathConfig | None = None,
) -> KnownPath | None:
    """An earlier search's ``path`` from where the vehicle is now, without a search, when
    it is still valid in the map as it is now; None: search again.

    Valid: the vehicle is within ``rejoin_m`` of one of its voxels, every voxel from there
    to the path's end passes the search's own test (seen free, the clearance from surfaces,
    outside every sphere, the section seen free beyond the near field), and a first leg is
    seen in a straight line (module docstring). The path returned starts at the vehicle
    and goes on from its nearest voxel (the one after it when that is nearer the vehicle
    than to it: the vehicle has passed it); ``expanded`` is 0.
    """
    cfg = KnownPathConfig() if config is None else config
    pos = np.asarray(pos_ned_m, dtype=float).reshape(3)
    goal = np.asarray(goal_ned_m, dtype=float).reshape(3)
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(goal))):
        raise ValueError("pos_ned_m and goal_ned_m must be finite")
    rows = np.asarray(path.waypoints_ned_m, dtype=float)
    occ, sec = _offset_tables(cfg, float(voxel_m))
    k0, leg = _follow(
        grid, np.asarray(origin_vox, dtype=np.int64), float(voxel_m), pos, rows,
        _sphere_array(spheres), occ, sec, cfg.near_field_m, cfg.leg_max_m, cfg.rejoin_m,
    )  # fmt: skip
    if k0 < 0 or leg < 0:
        return None
    if k0 + 1 < rows.shape[0] and leg > k0:
        passed = np.linalg.norm(rows[k0 + 1] - pos) < np.linalg.norm(rows[k0 + 1] - rows[k0])
        k0 += int(passed)
    waypoints = np.vstack([pos, rows[k0:]])
    waypoints.setflags(write=False)
    leg_end = rows[leg].copy()
    leg_end.setflags(write=False)
    return KnownPath(
        waypoints_ned_m=waypoints,
        leg_end_ned_m=leg_end,
        reaches_goal=path.reaches_goal,
        end_to_goal_m=float(np.linalg.norm(waypoints[-1] - goal)),
        length_m=float(np.sum(np.linalg.norm(np.diff(waypoints, axis=0), axis=1))),
        expanded=0,
    )


def way_blocked(
    grid: np.ndarray,
    origin_vox: np.ndarray,
    voxel_m: float,
    start_ned_m,
    end_ned_m,
    *,
    config: KnownPathConfig | None = None,
) -> bool:
    """Whether the vehicle's body moving straight from ``start_ned_m`` to ``end_ned_m``
    meets a surface the map has seen: an OCCUPIED voxel whose face lies within
    ``section_radius_m`` (the vehicle's radius, no margin) of a point of the segment. The
    cone rule's direction is then *blocked in known space* (module docstring, "When the
    path wins over the cone"). TENTATIVE (one frame's hit) and UNKNOWN voxels do not block:
    the safety envelope stops the vehicle before unknown space, and the cone rule stays
    the primary one wherever the map has not seen a surface in its way.
    """
    cfg = KnownPathConfig() if config is None else config
    a = np.asarray(start_ned_m, dtype=float).reshape(3)
    b = np.asarray(end_ned_m, dtype=float).reshape(3)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("start_ned_m and end_ned_m must be finite")
    body = _body_table(cfg.section_radius_m, float(voxel_m))
    return bool(
        _body_meets_surface(
            grid, np.asarray(origin_vox, dtype=np.int64), float(voxel_m), a, b, body
        )
    )


@functools.cache
def _body_table(radius_m: float, voxel_m: float) -> np.ndarray:
    return _offsets(radius_m, radius_m, voxel_m, face=True)


def prefer_known_path(
    path: KnownPath | None,
    pos_ned_m: np.ndarray,
    goal_ned_m: np.ndarray,
    *,
    cone_has_direction: bool,
    cones: Iterable,
    kept: bool,
    min_progress_m: float,
    cone_way_m: float = math.inf,
    cone_blocked: bool = False,
    cone_dir_ned: np.ndarray | None = None,
) -> bool:
    """Whether guidance flies ``path`` rather than the cone rule's aiming point (module
    docstring, "When the path wins over the cone").

    Parameters
    ----------
    path : KnownPath or None
    pos_ned_m, goal_ned_m : ndarray, shape (3,)
        Vehicle and goal [m, NED].
    cone_has_direction : bool
        The cone rule found an admissible aiming direction.
    cones : iterable of CollisionCone
        The cones of the obstacle being avoided (the overlapping cluster).
    kept : bool
        The path was flown at the previous step.
    min_progress_m : float
    cone_way_m : float
        Length of the cone rule's way: vehicle → aiming point → goal [m] (a lower bound on
        it; the path must be ``min_progress_m`` shorter).
    cone_blocked : bool
        The cone rule's carrot is blocked in known space (:func:`way_blocked`): the path
        leads if its first leg and ``cone_dir_ned`` are more than 45° apart.
    cone_dir_ned : ndarray, shape (3,), optional
        The cone rule's direction (unit): the path leads when it reaches the goal and the
        cone's direction leads away from it (no component along its first leg).
    """
    if path is None:
        return False
    progress = float(np.linalg.norm(goal_ned_m - pos_ned_m)) - path.end_to_goal_m
    if progress < min_progress_m:
        return False
    if kept or not cone_has_direction:
        return True
    leg = np.asarray(path.leg_end_ned_m) - pos_ned_m
    if cone_blocked and (cone_dir_ned is None or _apart(leg, cone_dir_ned)):
        return True
    cones = list(cones)
    into_cone = any(_inside_cone(c, leg) for c in cones)
    past = all(
        path.end_to_goal_m < float(np.linalg.norm(np.asarray(c.center_ned_m) - goal_ned_m))
        for c in cones
    )
    shorter = path.length_m + path.end_to_goal_m <= cone_way_m - min_progress_m
    away = cone_dir_ned is not None and path.reaches_goal and float(leg @ cone_dir_ned) <= 0.0
    return into_cone and past and (shorter or away or _between_pieces(path, cones))


def _apart(leg: np.ndarray, direction: np.ndarray) -> bool:
    """The path's first leg and the cone rule's direction lead different ways: more than
    ``_APART_RAD`` apart."""
    norm = float(np.linalg.norm(leg)) * float(np.linalg.norm(direction))
    return norm > 0.0 and float(leg @ direction) < math.cos(_APART_RAD) * norm


def _between_pieces(path: KnownPath, cones: list) -> bool:
    """The path passes between two of the obstacle's spheres: seen from above, it crosses
    the segment joining their centres (an opening, not the way round the outline)."""
    if len(cones) < 2:
        return False
    c = np.array([np.asarray(k.center_ned_m)[:2] for k in cones])
    i, j = np.triu_indices(len(c), k=1)
    a, b = c[i], c[j]  # (pairs, 2)
    w = np.asarray(path.waypoints_ned_m)[:, :2]
    p, q = w[:-1], w[1:]  # (segments, 2)

    def cross(o, u, v):  # z of (u - o) × (v - o), broadcast (segments, pairs)
        return (u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1]) - (u[..., 1] - o[..., 1]) * (
            v[..., 0] - o[..., 0]
        )

    P, Q = p[:, None, :], q[:, None, :]
    A, B = a[None, :, :], b[None, :, :]
    d1, d2 = cross(A, B, P), cross(A, B, Q)
    d3, d4 = cross(P, Q, A), cross(P, Q, B)
    return bool(np.any((d1 * d2 < 0.0) & (d3 * d4 < 0.0)))


def _inside_cone(cone, d: np.ndarray) -> bool:
    if cone.apex_inside:
        return True
    norm = float(np.linalg.norm(d))
    return norm > 0.0 and float(d @ cone.axis_ned) / norm > math.cos(cone.half_angle_rad)


@functools.cache
def warm_up() -> None:
    """Compile (or load from numba's cache) the search kernels once per process."""
    grid = np.full((12, 12, 12), FREE, np.int8)
    grid[6, 3:9, :] = OCCUPIED
    origin = np.zeros(3, np.int64)
    path = plan_known_path(grid, origin, 0.2, (0.3, 1.2, 1.2), (2.1, 1.2, 1.2))
    if path is not None:
        follow_known_path(path, grid, origin, 0.2, (0.35, 1.2, 1.2), (2.1, 1.2, 1.2))
    way_blocked(grid, origin, 0.2, (0.3, 1.2, 1.2), (2.1, 1.2, 1.2))
    _warm_up_openings()
