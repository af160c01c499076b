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

   Invariants 1 and 3 together: the vehicle is moved back out *through space seen free*,
   and a direction the camera has not looked along is first looked at, then flown
   (DESIGN.md). Given the map's question (:class:`WayCheck`: is the straight move from
   the vehicle to a point seen free for its section, with the envelope's look rule?), a
   way out counts only when its move is: the radial escape when it is, else the nearest
   point out of every boundary whose move is (every direction's nearest point out,
   nearest first, :func:`ways_outside`). A way that is seen free only thanks to the
   near-field excuse of a looked-along move is flown facing it
   (:attr:`HoldPoint.look_yaw_rad`). When no way out is seen free as the camera looks
   now, but one would be once looked along, the vehicle holds where it is and turns to
   look along the first such way (:attr:`HoldPlacement.UNSEEN` with ``look_yaw_rad``);
   when none would be even then, it holds where it is (:attr:`HoldPlacement.UNSEEN`,
   reported): inside the margin but not touching is better than a move into space
   nobody has seen. Without a check (no map) the ways out are not checked.
2. The braking point is inside a boundary: the farthest point of the segment from the
   vehicle to it that is outside every boundary, i.e. on the path the vehicle is flying
   through space the envelope let it into (:attr:`HoldPlacement.SHORTENED`).
3. Otherwise the braking point itself (:attr:`HoldPlacement.BRAKING_POINT`).

Pure: arrays in, a point out.
"""

from __future__ import annotations

import enum
import itertools
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from companion.guidance.cone import SphereLike, escape_point
from companion.guidance.envelope import FreeDistanceFn, stopping_distance_m

__all__ = [
    "HoldPlacement",
    "HoldPoint",
    "WayCheck",
    "clear_along_ray",
    "hold_point",
    "inside_any",
    "keep_target_out",
    "nearest_outside",
    "way_out",
    "ways_outside",
]


@dataclass(frozen=True)
class WayCheck:
    """The known-space map's question for a way back out of a boundary: is the straight
    move from one point to another seen free for the vehicle's section?

    The check the envelope makes of a path (:mod:`companion.guidance.envelope`, step 2):
    ``free_distance`` (its :data:`~companion.guidance.envelope.FreeDistanceFn`, i.e.
    :meth:`~companion.known_space.KnownSpace.free_distance_m`) must reach the move's
    length with the section ``radius_m`` wide and ``half_height_m`` high, the vehicle's
    own centre excused within ``radius_m``. The section's unseen rim within
    ``near_field_m`` is excused only on a move the camera looks along: its horizontal
    bearing within ``look_half_angle_deg`` of ``heading_rad`` (or no horizontal part, or
    no heading stated), as the envelope's look rule; off it the whole section must be
    seen free.
    """

    free_distance: FreeDistanceFn
    radius_m: float  # the vehicle's section, half-width [m]
    half_height_m: float  # the vehicle's section, half-height [m]
    near_field_m: float = 0.0  # unseen rim excused this near on a looked-along move [m]
    heading_rad: float | None = None  # where the camera looks now [rad, NED]; None: along
    look_half_angle_deg: float = 24.0  # the camera looks along a bearing this near [deg]

    def looked_along(self, start_ned_m, end_ned_m) -> bool:
        """Whether the camera looks along the move now (the envelope's look rule)."""
        leg = np.asarray(end_ned_m, dtype=float) - np.asarray(start_ned_m, dtype=float)
        horiz_m = math.hypot(float(leg[0]), float(leg[1]))
        if self.heading_rad is None or horiz_m < 1e-6:
            return True
        cos_off = float(leg[0]) * math.cos(self.heading_rad) + float(leg[1]) * math.sin(
            self.heading_rad
        )
        return cos_off >= horiz_m * math.cos(math.radians(self.look_half_angle_deg))

    def seen_free(self, start_ned_m, end_ned_m, *, looked: bool | None = None) -> bool:
        """Whether the move is seen free; ``looked``: as if the camera looked along it
        (True), or not (False); None: as it looks now (:meth:`looked_along`)."""
        start = np.asarray(start_ned_m, dtype=float)
        leg = np.asarray(end_ned_m, dtype=float) - start
        length = float(np.linalg.norm(leg))
        if not length > 1e-9:
            return True
        if looked is None:
            looked = self.looked_along(start, start + leg)
        near_field_m = self.near_field_m if looked else 0.0
        free = self.free_distance(
            start, leg / length, self.radius_m, length, self.half_height_m, self.radius_m,
            near_field_m,
        )  # fmt: skip
        return float(free) >= length


def _bearing_rad(start: np.ndarray, end: np.ndarray) -> float | None:
    """Horizontal bearing of the move [rad, NED]; None for a (near) vertical one."""
    north, east = float(end[0] - start[0]), float(end[1] - start[1])
    return math.atan2(east, north) if math.hypot(north, east) > 1e-6 else None


class HoldPlacement(enum.Enum):
    """Where the hold target was put, and why."""

    BRAKING_POINT = "braking_point"
    SHORTENED = "shortened"  # braking point inside a boundary: short of it on the path
    ESCAPE = "escape"  # vehicle inside a boundary: out of it
    NEAREST_OUT = "nearest_out"  # the way out of one leads into another: nearest point out
    CURRENT = "current"  # vehicle inside and no way out found: where it is
    # vehicle inside, and every way out crosses space not seen free: where it is
    UNSEEN = "no_way_out_seen_free"
    EXTENDED = "extended"  # vehicle inside: the carrot carried on along its ray to the outside


@dataclass(frozen=True)
class HoldPoint:
    """A hold target [m, NED] and where it was put."""

    pos_ned_m: tuple[float, float, float]
    placement: HoldPlacement
    # the yaw to send with it [rad, NED]: facing a way out the camera must look along (to
    # be seen free before it is flown, or while it is flown); None: the caller's yaw
    look_yaw_rad: float | None = None

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
    way_check: WayCheck | None = None,
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
    way_check : WayCheck, optional
        The map's question for a way out of a boundary (:func:`way_out`); None: unchecked.
    """
    pos = np.asarray(pos_ned_m, dtype=float)
    vel = np.asarray(vel_ned_mps, dtype=float)
    if not np.all(np.isfinite(vel)):
        vel = np.zeros(3)  # no usable velocity: hold where it is
    if inside_any(pos, boundaries):
        return way_out(
            pos,
            boundaries,
            clearance_m=clearance_m,
            reference_ned=vel,
            search_m=search_m,
            way_check=way_check,
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
    way_check: WayCheck | None = None,
) -> HoldPoint:
    """The way out for a vehicle inside a boundary (step 1 of the module docstring).

    The deepest boundary's radial escape ``clearance_m`` beyond its surface
    (:func:`~companion.guidance.cone.escape_point`, sliding along ``reference_ned`` when
    given) when that point is outside every boundary (:attr:`HoldPlacement.ESCAPE`); else
    the nearest point outside all of them, the radial way preferred
    (:attr:`HoldPlacement.NEAREST_OUT`, :func:`ways_outside`); else, nothing within
    ``search_m`` being outside, where the vehicle is (:attr:`HoldPlacement.CURRENT`), never
    deeper. No latency or braking enters: the vehicle is already where it must not be.
    A vehicle outside every boundary is where it is (:attr:`HoldPlacement.CURRENT`).

    With ``way_check`` (:class:`WayCheck`) a way out counts only when its move is seen
    free as the camera looks now (invariants 1 and 3: back out *through space seen
    free*): the radial escape first, then every direction's nearest point out, nearest
    first. Seen free only thanks to the near field of a looked-along move: flown facing
    it (``look_yaw_rad``). None seen free now, but one once looked along: where the
    vehicle is, facing the first such way (:attr:`HoldPlacement.UNSEEN` with
    ``look_yaw_rad``); none even then: where it is (:attr:`HoldPlacement.UNSEEN`).
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
    ways = ways_outside(
        pos, boundaries, clearance_m=clearance_m, search_m=search_m, prefer_ned=out - pos
    )
    if not inside_any(out, boundaries):
        ways = itertools.chain([(out, HoldPlacement.ESCAPE)], ways)
    if way_check is None:
        first = next(ways, None)
        if first is None:
            return HoldPoint(_tuple(pos), HoldPlacement.CURRENT)
        return HoldPoint(_tuple(first[0]), first[1])
    tried = []
    for point, placement in ways:  # as the camera looks now
        tried.append(point)
        if way_check.seen_free(pos, point):
            looked_only = way_check.looked_along(pos, point) and not way_check.seen_free(
                pos, point, looked=False
            )
            look = _bearing_rad(pos, point) if looked_only else None
            return HoldPoint(_tuple(point), placement, look)
    if not tried:
        return HoldPoint(_tuple(pos), HoldPlacement.CURRENT)
    for point in tried:  # once looked along: turn to look first
        if not way_check.looked_along(pos, point) and way_check.seen_free(pos, point, looked=True):
            return HoldPoint(_tuple(pos), HoldPlacement.UNSEEN, _bearing_rad(pos, point))
    return HoldPoint(_tuple(pos), HoldPlacement.UNSEEN)


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
#: steps along every direction tested at once by :func:`ways_outside` (cost only)
_STEP_BLOCK = 8


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
    The first of :func:`ways_outside`.
    """
    first = next(
        ways_outside(
            pos_ned_m,
            boundaries,
            clearance_m=clearance_m,
            search_m=search_m,
            step_m=step_m,
            prefer_ned=prefer_ned,
        ),
        None,
    )
    return None if first is None else first[0]


def ways_outside(
    pos_ned_m,
    boundaries: Sequence[SphereLike],
    *,
    clearance_m: float = 0.0,
    search_m: float = 4.0,
    step_m: float = 0.05,
    prefer_ned=None,
) -> Iterator[tuple[np.ndarray, HoldPlacement]]:
    """Every direction's nearest point [m, NED] outside every boundary, nearest first
    (each with :attr:`HoldPlacement.NEAREST_OUT`).

    The search of :func:`nearest_outside` carried on: each of the 200 directions yields
    its first step that is at least ``clearance_m`` outside every boundary, in order of
    that step (points at one step by ``prefer_ned``, then the fixed direction order);
    then, with ``clearance_m > 0``, the same for points merely outside (clearance given
    up before the way out is). Lazy: a caller that takes the first point pays for the
    search up to it only. A vehicle already ``clearance_m`` outside every boundary yields
    its own position alone.
    """
    pos = np.asarray(pos_ned_m, dtype=float)
    if not inside_any(pos, [_Ball(b.center_ned_m, b.radius_m + clearance_m) for b in boundaries]):
        yield pos.copy(), HoldPlacement.NEAREST_OUT
        return
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
        open_dirs = np.arange(len(_DIRECTIONS))  # directions with no clear step yet
        # outward, so a direction's first clear step is its nearest point out; the steps
        # are tested _STEP_BLOCK at a time (the same points, fewer numpy calls)
        for k0 in range(1, n_steps + 1, _STEP_BLOCK):
            ks = np.arange(k0, min(k0 + _STEP_BLOCK, n_steps + 1), dtype=float)
            points = pos + _DIRECTIONS[open_dirs][None, :, :] * (ks * step_m)[:, None, None]
            dist = np.linalg.norm(points[:, :, None, :] - centres[None, None, :, :], axis=-1)
            is_clear = np.all(dist >= reach, axis=2)  # (steps, open dirs)
            taken = np.zeros(open_dirs.size, dtype=bool)
            for row in range(ks.size):
                clear = np.flatnonzero(is_clear[row] & ~taken)  # by direction index
                if not clear.size:
                    continue
                taken[clear] = True
                if along is not None:
                    clear = clear[np.argsort(-along[open_dirs[clear]], kind="stable")]
                for pick in clear:
                    yield points[row, pick].copy(), HoldPlacement.NEAREST_OUT
            open_dirs = open_dirs[~taken]
            if not open_dirs.size:
                break


def keep_target_out(
    pos_ned_m,
    target_ned_m,
    boundaries: Sequence[SphereLike],
    *,
    free_m: float,
    clearance_m: float = 0.0,
    standoff_m: float = 0.05,
    step_m: float = 0.02,
    way_check: WayCheck | None = None,
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
    way_check : WayCheck, optional
        The map's question for :func:`way_out` (None: its ways out are not checked).
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
    return way_out(pos, boundaries, clearance_m=clearance_m, way_check=way_check)


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
