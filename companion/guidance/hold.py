"""Where to hold when the inputs degrade: the braking point, never inside a boundary.

A hold for late inputs (:mod:`companion.failsafe`, ``Response.HOLD_POSITION``) is a
position target sent in the control mode. The vehicle cannot stop where it is: it stops
at the *braking point*, ``p + v̂·d_stop(|v|)`` with ``d_stop = τ·v + v²/(2a)`` (the
envelope's stopping rule with the latency budget ``τ``). A target behind it would make the
autopilot brake harder than it can and come back; one beyond would let it drift on.

Invariant 3 of the safety envelope (DESIGN.md): no target lies inside an inflated boundary
(the known-space map's collision safety boundaries, :mod:`companion.guidance.map_boundaries`).
So, in order:

1. The vehicle is inside a boundary (drift, a jump of the estimate, a late frame): the
   target is the way out of the deepest one, :func:`~companion.guidance.cone.escape_point`
   (radially out, ``clearance_m`` beyond its surface), as guidance's own escape
   (:attr:`HoldPlacement.ESCAPE`). If that point lies in another boundary (a wall is
   many overlapping pieces), the nearest point outside all of them, searched along a
   fixed set of directions (:attr:`HoldPlacement.NEAREST_OUT`, :func:`nearest_outside`).
   Only when nothing within ``search_m`` is outside: the current position
   (:attr:`HoldPlacement.CURRENT`), and never deeper.
2. The braking point is inside a boundary: the farthest point of the segment from the
   vehicle to it that is outside every boundary, i.e. on the path the vehicle is flying
   through space the envelope let it into (:attr:`HoldPlacement.SHORTENED`).
3. Otherwise the braking point itself (:attr:`HoldPlacement.BRAKING_POINT`).

Pure: arrays in, a point out.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.guidance.cone import SphereLike, escape_point
from companion.guidance.envelope import stopping_distance_m

__all__ = [
    "HoldPlacement",
    "HoldPoint",
    "clear_along_ray",
    "hold_point",
    "inside_any",
    "keep_target_out",
    "nearest_outside",
    "way_out",
]


class HoldPlacement(enum.Enum):
    """Where the hold target was put, and why."""

    BRAKING_POINT = "braking_point"
    SHORTENED = "shortened"  # braking point inside a boundary: short of it on the path
    ESCAPE = "escape"  # vehicle inside a boundary: out of it
    NEAREST_OUT = "nearest_out"  # the way out of one leads into another: nearest point out
    CURRENT = "current"  # vehicle inside and no way out found: where it is
    EXTENDED = "extended"  # vehicle inside: the carrot carried on along its ray to the outside


@dataclass(frozen=True)
class HoldPoint:
    """A hold target [m, NED] and where it was put."""

    pos_ned_m: tuple[float, float, float]
    placement: HoldPlacement

    @property
    def moved(self) -> bool:
        """The braking point was not used as it is (worth telling the operator once)."""
        return self.placement is not HoldPlacement.BRAKING_POINT


def _inside(point: np.ndarray, sphere: SphereLike) -> bool:
    centre = np.asarray(sphere.center_ned_m, dtype=float)
    return float(np.linalg.norm(point - centre)) < float(sphere.radius_m)


def inside_any(point_ned_m, boundaries: Sequence[SphereLike]) -> bool:
    """Whether ``point_ned_m`` lies in the open ball of any boundary."""
    p = np.asarray(point_ned_m, dtype=float)
    return any(_inside(p, b) for b in boundaries)


def _entry_fraction(a: np.ndarray, b: np.ndarray, sphere: SphereLike) -> float:
    """Smallest ``t ∈ [0, 1]`` with ``a + t(b − a)`` on the sphere, entering it (1 if never)."""
    c = np.asarray(sphere.center_ned_m, dtype=float)
    r = float(sphere.radius_m)
    d = b - a
    f = a - c
    qa = float(d @ d)
    if qa <= 0.0:
        return 1.0
    qb = 2.0 * float(f @ d)
    qc = float(f @ f) - r * r
    disc = qb * qb - 4.0 * qa * qc
    if disc <= 0.0:
        return 1.0
    t = (-qb - math.sqrt(disc)) / (2.0 * qa)
    return t if 0.0 <= t <= 1.0 else 1.0


def hold_point(
    pos_ned_m,
    vel_ned_mps,
    boundaries: Sequence[SphereLike],
    *,
    latency_s: float,
    accel_mps2: float,
    clearance_m: float = 0.0,
    standoff_m: float = 0.05,
    search_m: float = 4.0,
) -> HoldPoint:
    """The hold target for a vehicle at ``pos_ned_m`` flying ``vel_ned_mps`` (module doc).

    Parameters
    ----------
    pos_ned_m, vel_ned_mps : array_like, shape (3,)
        Newest position [m] and velocity [m/s], NED.
    boundaries : sequence of SphereLike
        Inflated collision safety boundaries (centre, radius) [m, NED].
    latency_s : float
        Latency budget ``τ`` of the stopping rule [s].
    accel_mps2 : float
        Braking deceleration [m/s²].
    clearance_m : float
        Escape distance beyond a boundary's surface [m] (guidance's
        ``escape_clearance_m``).
    standoff_m : float
        A shortened target stays this far before the boundary along the path [m].
    search_m : float
        How far :func:`nearest_outside` looks for a way out when the radial one is
        blocked [m].
    """
    pos = np.asarray(pos_ned_m, dtype=float)
    vel = np.asarray(vel_ned_mps, dtype=float)
    if not np.all(np.isfinite(vel)):
        vel = np.zeros(3)  # no usable velocity: hold where it is
    if inside_any(pos, boundaries):
        return way_out(
            pos, boundaries, clearance_m=clearance_m, reference_ned=vel, search_m=search_m
        )
    speed = float(np.linalg.norm(vel))
    if speed < 1e-6:
        return HoldPoint(_tuple(pos), HoldPlacement.BRAKING_POINT)
    brake = pos + vel / speed * stopping_distance_m(speed, latency_s, accel_mps2)
    t = min((_entry_fraction(pos, brake, b) for b in boundaries), default=1.0)
    if t >= 1.0:
        return HoldPoint(_tuple(brake), HoldPlacement.BRAKING_POINT)
    length = float(np.linalg.norm(brake - pos))
    t = max(0.0, t - standoff_m / length)
    return HoldPoint(_tuple(pos + t * (brake - pos)), HoldPlacement.SHORTENED)


def way_out(
    pos_ned_m,
    boundaries: Sequence[SphereLike],
    *,
    clearance_m: float = 0.0,
    reference_ned=None,
    search_m: float = 4.0,
) -> HoldPoint:
    """The way out for a vehicle inside a boundary (step 1 of the module docstring).

    The deepest boundary's radial escape ``clearance_m`` beyond its surface
    (:func:`~companion.guidance.cone.escape_point`, sliding along ``reference_ned`` when
    given) when that point is outside every boundary (:attr:`HoldPlacement.ESCAPE`); else
    the nearest point outside all of them, the radial way preferred
    (:attr:`HoldPlacement.NEAREST_OUT`, :func:`nearest_outside`); else, nothing within
    ``search_m`` being outside, where the vehicle is (:attr:`HoldPlacement.CURRENT`), never
    deeper. No latency or braking enters: the vehicle is already where it must not be.
    A vehicle outside every boundary is where it is (:attr:`HoldPlacement.CURRENT`).
    """
    pos = np.asarray(pos_ned_m, dtype=float)
    containing = [b for b in boundaries if _inside(pos, b)]
    if not containing:
        return HoldPoint(_tuple(pos), HoldPlacement.CURRENT)
    deepest = max(
        containing,
        key=lambda b: (
            float(b.radius_m) - float(np.linalg.norm(pos - np.asarray(b.center_ned_m, dtype=float)))
        ),
    )
    reference = np.zeros(3) if reference_ned is None else np.asarray(reference_ned, dtype=float)
    out = escape_point(pos, deepest, clearance_m=clearance_m, reference_ned=reference)
    if not inside_any(out, boundaries):
        return HoldPoint(_tuple(out), HoldPlacement.ESCAPE)
    nearest = nearest_outside(
        pos, boundaries, clearance_m=clearance_m, search_m=search_m, prefer_ned=out - pos
    )
    if nearest is None:
        return HoldPoint(_tuple(pos), HoldPlacement.CURRENT)
    return HoldPoint(_tuple(nearest), HoldPlacement.NEAREST_OUT)


@dataclass(frozen=True)
class _Ball:
    center_ned_m: tuple[float, float, float]
    radius_m: float


def _fibonacci_directions(n: int) -> np.ndarray:
    """``n`` unit vectors spread evenly over the sphere (golden-angle spiral), read-only."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    ring = np.sqrt(1.0 - z * z)
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    dirs = np.stack([ring * np.cos(phi), ring * np.sin(phi), z], axis=1)
    dirs.flags.writeable = False
    return dirs


#: search directions of :func:`nearest_outside`: ~14° apart
_DIRECTIONS = _fibonacci_directions(200)


def nearest_outside(
    pos_ned_m,
    boundaries: Sequence[SphereLike],
    *,
    clearance_m: float = 0.0,
    search_m: float = 4.0,
    step_m: float = 0.05,
    prefer_ned=None,
) -> np.ndarray | None:
    """The nearest point [m, NED] at least ``clearance_m`` outside every boundary.

    Looked for along 200 directions spread over the sphere, in steps of ``step_m`` out to
    ``search_m``: the first step at which a direction's point is clear, the shortest such
    step over all directions (resolution ``step_m`` in distance, ~14° in direction). Among
    points at the shortest distance, the one most along ``prefer_ned`` (e.g. the radial
    escape from the deepest boundary); ties by the fixed direction order, so the answer is
    deterministic. With ``clearance_m > 0`` and nothing found, the search is repeated for
    a point merely outside (clearance 0). ``None`` when nothing within ``search_m`` is.
    """
    pos = np.asarray(pos_ned_m, dtype=float)
    if not inside_any(pos, [_Ball(b.center_ned_m, b.radius_m + clearance_m) for b in boundaries]):
        return pos.copy()
    centres = np.array([np.asarray(b.center_ned_m, dtype=float) for b in boundaries])
    radii = np.array([float(b.radius_m) for b in boundaries])
    near = np.linalg.norm(centres - pos, axis=1) - radii < search_m + clearance_m
    centres, radii = centres[near], radii[near]
    prefer = np.zeros(3) if prefer_ned is None else np.asarray(prefer_ned, dtype=float)
    norm = float(np.linalg.norm(prefer))
    along = _DIRECTIONS @ (prefer / norm) if norm > 1e-9 and math.isfinite(norm) else None
    n_steps = int(search_m / step_m)
    for clearance in (clearance_m, 0.0) if clearance_m > 0.0 else (0.0,):
        reach = radii + clearance
        for k in range(1, n_steps + 1):  # outward, so the first clear step is the nearest
            points = pos + _DIRECTIONS * (k * step_m)  # (dirs, 3)
            dist = np.linalg.norm(points[:, None, :] - centres[None, :, :], axis=-1)
            clear = np.flatnonzero(np.all(dist >= reach, axis=1))
            if clear.size:
                pick = clear[0] if along is None else clear[np.argmax(along[clear])]
                return points[pick].copy()
    return None


def keep_target_out(
    pos_ned_m,
    target_ned_m,
    boundaries: Sequence[SphereLike],
    *,
    free_m: float,
    clearance_m: float = 0.0,
    standoff_m: float = 0.05,
    step_m: float = 0.02,
) -> HoldPoint | None:
    """Any target guidance sends, moved out of the boundaries (invariant 3), or None.

    The safety envelope shortens guidance's carrot to space seen free and pitches it into
    the camera's view; either can leave it inside an inflated boundary although guidance's
    own setpoint was outside (a carrot shortened on the way out of a boundary the vehicle
    strayed into, a known-space path pitched against a sphere). So, for a ``target_ned_m``
    inside a boundary:

    * the vehicle is outside every boundary: the farthest point of the segment from the
      vehicle to the target that is ``standoff_m`` before the first boundary it enters
      (:attr:`HoldPlacement.SHORTENED`): the autopilot flies a straight line to it, and
      that line stays out;
    * the vehicle is inside: the target carried on along the same ray to ``standoff_m``
      past the point where it leaves every boundary, provided that point is within
      ``free_m``, the known-free distance the envelope measured along the ray
      (:attr:`HoldPlacement.EXTENDED`, :func:`clear_along_ray`); else :func:`way_out` (the
      deepest boundary's radial escape or the nearest point outside all of them), never
      deeper.

    ``None`` when the target is outside every boundary (it stands as it is).

    Parameters
    ----------
    pos_ned_m, target_ned_m : array_like, shape (3,)
        Vehicle position and the target after the envelope [m, NED].
    boundaries : sequence of SphereLike
        Inflated collision safety boundaries [m, NED].
    free_m : float
        Known-free distance along the ray to the target [m] (the envelope's).
    clearance_m : float
        Escape distance beyond a boundary's surface for :func:`hold_point` [m].
    standoff_m : float
        Distance kept from a boundary's surface along the ray [m].
    step_m : float
        Resolution of the exit along the ray [m] (:func:`clear_along_ray`).
    """
    pos = np.asarray(pos_ned_m, dtype=float)
    target = np.asarray(target_ned_m, dtype=float)
    if not inside_any(target, boundaries):
        return None
    length = float(np.linalg.norm(target - pos))
    if not inside_any(pos, boundaries):
        t = min((_entry_fraction(pos, target, b) for b in boundaries), default=1.0)
        t = max(0.0, t - standoff_m / length) if length > 0.0 else 0.0
        return HoldPoint(_tuple(pos + t * (target - pos)), HoldPlacement.SHORTENED)
    if length > 1e-6 and math.isfinite(free_m):
        unit = (target - pos) / length
        s = clear_along_ray(pos, unit, length, boundaries, standoff_m, step_m)
        if s + standoff_m <= free_m:
            return HoldPoint(_tuple(pos + unit * (s + standoff_m)), HoldPlacement.EXTENDED)
    return way_out(pos, boundaries, clearance_m=clearance_m)


def clear_along_ray(
    pos_ned_m,
    unit_ned,
    start_m: float,
    boundaries: Sequence[SphereLike],
    standoff_m: float,
    step_m: float = 0.02,
) -> float:
    """The least ``s = start_m + k·step_m`` (``k`` = 0, 1, …) with the stretch
    ``pos + unit·[s, s + standoff_m]`` outside the open ball of every boundary [m].

    Each ball cuts the interval ``(t_in, t_out)`` from the ray (the roots of
    ``|pos + t·unit − c|² = r²``); widened to ``(t_in − standoff_m, t_out)`` it holds
    every ``s`` whose stretch meets the ball. One pass over them sorted by entry moves
    ``s`` to the first step at or past the exit of each one it lies in; a later interval
    can only begin later, so ``s`` never has to come back. A ball the ray only touches
    (no two distinct roots) cuts nothing: the open ball is not entered.

    This is the answer of the 2 cm march it replaced (two ``inside_any`` calls per step,
    up to ~400 steps on the frame path), computed in closed form: the same steps, so
    the same flights (``tests/test_hold_point.py`` compares them on random clusters).
    ``step_m = 0`` gives the exact exit instead; it moves the target up to a step nearer
    the boundary's surface and changes the fast corridor-3m flight (the trajectory, not
    the safety of any one target: docs/safety-envelope.md).
    """
    pos = np.asarray(pos_ned_m, dtype=float)
    unit = np.asarray(unit_ned, dtype=float)
    spans = []
    for b in boundaries:
        f = pos - np.asarray(b.center_ned_m, dtype=float)
        half_b = float(f @ unit)
        disc = half_b * half_b - (float(f @ f) - float(b.radius_m) ** 2)
        if disc > 0.0:
            root = math.sqrt(disc)
            spans.append((-half_b - root - standoff_m, -half_b + root))
    start = float(start_m)
    s = start
    for t_in, t_out in sorted(spans):
        if t_in < s < t_out:
            s = t_out if step_m <= 0.0 else start + math.ceil((t_out - start) / step_m) * step_m
    return s


def _tuple(p: np.ndarray) -> tuple[float, float, float]:
    return (float(p[0]), float(p[1]), float(p[2]))
