"""Collision cone geometry and the aiming point of Eq. (28) (Park & Kim §5, Fig. 4 and 5).

Every vector is MAVLink LOCAL_NED (x north, y east, z down): positions in metres,
velocities in m/s, directions unit-less.

Geometry
--------
A collision safety boundary is a sphere with centre ``c`` and radius ``R`` (already
inflated by the vehicle radius and a safety margin; perception's business). Seen from the
vehicle at ``p`` with ``D = |c - p| > R`` it defines the *collision cone*: apex ``p``,
unit axis ``a = (c - p) / D``, half-angle ``α = asin(R / D)``. The cone's generators touch
the sphere on the *tangent circle*: centre ``p + a (D² - R²) / D``, radius
``R √(D² - R²) / D``, in the plane normal to ``a``. Every tangent point ``x`` lies at the
tangent length ``L = √(D² - R²)`` from ``p`` and satisfies ``(x - c)·(x - p) = 0``.

The obstacle is *critical* when the velocity makes an angle smaller than ``α`` with ``a``.

Aiming point, Eq. (28)
----------------------
The paper takes, among the tangent points ``C``, the one nearest the velocity vector.
Read as the design fixes it (DESIGN.md §"Perception and guidance" 5): the tangent point
whose *direction* from the vehicle is nearest the velocity direction. Writing a tangent
point as ``x(u) = c_t + r_t u`` with ``u ⊥ a`` a unit vector, its direction is
``cos α · a + sin α · u`` and the angle to the velocity ``v`` is smallest for
``u = v⊥ / |v⊥|``, ``v⊥ = v - (v·a) a``: a closed form, no search.

Tie-break (head-on)
-------------------
When ``v`` is (anti-)parallel to ``a`` within ``tie_angle_rad`` (the paper's own scenario:
vehicle at NED (20, 0, -7) flying toward (0, 0, -7) past an obstacle at (10, 0, -7)),
every tangent point is equally near. The tie is broken by a **horizontal side-step to the
right of the reference direction**: ``u`` is the right-hand horizontal normal of the
reference, ``(-h_e, h_n, 0) / |h|`` for the horizontal part ``h = (h_n, h_e)``, projected
onto the plane normal to ``a``. The vehicle therefore keeps its altitude and passes the
obstacle on its right (for the paper's south-bound flight, to the west, ``y < 0``). The
reference is the velocity, or the cone axis when the velocity is zero; when it has no
horizontal part (a vertical approach) the side-step is to the east ``(0, 1, 0)``; if that
is parallel to the axis, ``a × (0, 0, 1)`` and finally north ``(1, 0, 0)`` are used.

Inside the boundary
-------------------
With the vehicle on or inside a boundary sphere (``D ≤ R``) there is no cone: every
direction is unsafe. :class:`CollisionCone` then reports ``apex_inside`` with a
half-angle of ``π`` (every direction is "inside"), :func:`aiming_point` refuses, and
:func:`escape_point` gives the way out: radially away from the centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from companion.guidance._vec import cross3, norm3
from protocols.config import vec3

__all__ = [
    "BoundarySphere",
    "CollisionCone",
    "SphereLike",
    "aiming_direction",
    "aiming_point",
    "circle_units",
    "collision_cone",
    "contains_direction",
    "escape_point",
    "is_critical",
    "segment_intersects_sphere",
    "side_step_direction",
    "tangent_circle_points",
]

#: Relative size below which a vector counts as zero (directions, perpendicular parts).
_EPS = 1e-9


class SphereLike(Protocol):
    """Anything with a centre in LOCAL_NED [m] and a radius [m] (a boundary sphere)."""

    @property
    def center_ned_m(self) -> tuple[float, float, float]: ...

    @property
    def radius_m(self) -> float: ...


@dataclass(frozen=True)
class BoundarySphere:
    """A collision safety boundary: a sphere already inflated by vehicle radius + margin.

    Attributes
    ----------
    center_ned_m : tuple of 3 float
        Centre in LOCAL_NED [m].
    radius_m : float
        Radius [m], finite and > 0.
    """

    center_ned_m: tuple[float, float, float]
    radius_m: float

    def __post_init__(self) -> None:
        try:
            center = tuple(float(x) for x in self.center_ned_m)
        except (TypeError, ValueError) as exc:
            raise ValueError(self._bad_center()) from exc
        if len(center) != 3 or not all(math.isfinite(x) for x in center):
            raise ValueError(self._bad_center())
        radius = float(self.radius_m)
        if not (math.isfinite(radius) and radius > 0.0):
            raise ValueError(f"radius_m must be finite and positive, got {self.radius_m!r}")
        object.__setattr__(self, "center_ned_m", center)
        object.__setattr__(self, "radius_m", radius)

    def _bad_center(self) -> str:
        # formatted only on failure: a repr per sphere and frame is most of the cost
        return f"center_ned_m must be 3 finite numbers, got {self.center_ned_m!r}"

    @classmethod
    def of(cls, sphere: SphereLike) -> BoundarySphere:
        """Return ``sphere`` as a :class:`BoundarySphere` (any object with the two fields)."""
        if isinstance(sphere, cls):
            return sphere
        return cls(center_ned_m=sphere.center_ned_m, radius_m=sphere.radius_m)

    def surface_distance_m(self, point_ned_m) -> float:
        """Distance from ``point_ned_m`` to the surface [m], negative inside."""
        d = np.asarray(point_ned_m, dtype=float) - np.asarray(self.center_ned_m)
        return norm3(d) - self.radius_m


def _frozen(vec: np.ndarray) -> np.ndarray:
    vec.setflags(write=False)
    return vec


@dataclass(frozen=True, eq=False)
class CollisionCone:
    """The collision cone from the vehicle to one boundary sphere (read-only arrays).

    Attributes
    ----------
    apex_ned_m : ndarray, shape (3,)
        Vehicle position, the apex [m, NED].
    center_ned_m : ndarray, shape (3,)
        Sphere centre [m, NED].
    radius_m : float
        Sphere radius ``R`` [m].
    distance_m : float
        Apex-to-centre distance ``D`` [m].
    axis_ned : ndarray, shape (3,)
        Unit vector from the apex to the centre (north ``(1, 0, 0)`` if ``D = 0``).
    half_angle_rad : float
        ``asin(R / D)`` outside the sphere; ``π`` when the apex is on or inside it.
    apex_inside : bool
        True when ``D ≤ R``: no cone exists, every direction counts as inside.
    """

    apex_ned_m: np.ndarray
    center_ned_m: np.ndarray
    radius_m: float
    distance_m: float
    axis_ned: np.ndarray
    half_angle_rad: float
    apex_inside: bool

    @property
    def surface_distance_m(self) -> float:
        """``D - R`` [m]: distance from the apex to the sphere surface (negative inside)."""
        return self.distance_m - self.radius_m

    @property
    def tangent_length_m(self) -> float:
        """``√(D² - R²)`` [m]: apex to any tangent point (0 when inside)."""
        return math.sqrt(max(self.distance_m**2 - self.radius_m**2, 0.0))

    @property
    def circle_center_ned_m(self) -> np.ndarray:
        """Centre of the tangent circle, ``apex + a (D² - R²) / D`` [m, NED]."""
        if self.apex_inside:
            return self.apex_ned_m.copy()
        return self.apex_ned_m + self.axis_ned * (self.tangent_length_m**2 / self.distance_m)

    @property
    def circle_radius_m(self) -> float:
        """Radius of the tangent circle, ``R √(D² - R²) / D`` [m] (0 when inside)."""
        if self.apex_inside:
            return 0.0
        return self.radius_m * self.tangent_length_m / self.distance_m


def collision_cone(apex_ned_m, sphere: SphereLike) -> CollisionCone:
    """Build the collision cone from the vehicle at ``apex_ned_m`` to ``sphere``.

    Parameters
    ----------
    apex_ned_m : array_like, shape (3,)
        Vehicle position [m, NED].
    sphere : SphereLike
        Boundary sphere (``center_ned_m`` [m, NED], ``radius_m`` [m]).

    Returns
    -------
    CollisionCone
        Half-angle ``asin(R / D)``; when ``D ≤ R`` the cone is flagged ``apex_inside``
        with half-angle ``π``.
    """
    return _collision_cone(np.array(vec3(apex_ned_m, "apex_ned_m")), sphere)


def _collision_cone(apex: np.ndarray, sphere: SphereLike) -> CollisionCone:
    """:func:`collision_cone` for an apex already checked: a float array of shape (3,),
    owned by the cone (frozen here)."""
    center = np.asarray(sphere.center_ned_m, dtype=float)
    radius = float(sphere.radius_m)
    offset = center - apex
    distance = norm3(offset)
    axis = offset / distance if distance > 0.0 else np.array([1.0, 0.0, 0.0])
    inside = distance <= radius
    half_angle = math.pi if inside else math.asin(radius / distance)
    return CollisionCone(
        apex_ned_m=_frozen(apex),
        center_ned_m=_frozen(center),
        radius_m=radius,
        distance_m=distance,
        axis_ned=_frozen(axis),
        half_angle_rad=half_angle,
        apex_inside=inside,
    )


def contains_direction(cone: CollisionCone, direction_ned, *, margin_rad: float = 0.0) -> bool:
    """Whether ``direction_ned`` points inside the cone widened by ``margin_rad``.

    Inside means an angle to the axis strictly smaller than ``half_angle_rad + margin_rad``
    (a generator itself is not inside). A zero direction is never inside; any non-zero
    direction is inside when the apex is inside the sphere.
    """
    return _contains_direction(cone, np.array(vec3(direction_ned, "direction_ned")), margin_rad)


def _contains_direction(cone: CollisionCone, d: np.ndarray, margin_rad: float) -> bool:
    """:func:`contains_direction` for a direction already checked (float, shape (3,))."""
    norm = norm3(d)
    if norm <= 0.0:
        return False
    if cone.apex_inside:
        return True
    limit = cone.half_angle_rad + margin_rad
    if limit >= math.pi:
        return True
    if limit <= 0.0:
        return False
    return float(d @ cone.axis_ned) / norm > math.cos(limit)


def is_critical(
    cone: CollisionCone, vel_ned_mps, *, margin_rad: float = 0.0, min_speed_mps: float = 0.0
) -> bool:
    """Paper §5: the obstacle is critical when the velocity lies inside its collision cone.

    Parameters
    ----------
    cone : CollisionCone
        Cone from the vehicle's position.
    vel_ned_mps : array_like, shape (3,)
        Vehicle velocity [m/s, NED].
    margin_rad : float
        Widens (> 0) or narrows (< 0) the cone for the test [rad].
    min_speed_mps : float
        At or below this speed the velocity has no direction and the obstacle is not
        critical (a hovering vehicle is on no collision course).

    Returns
    -------
    bool
        True inside the (widened) cone, and always when the apex is inside the sphere.
    """
    if cone.apex_inside:
        return True
    v = np.array(vec3(vel_ned_mps, "vel_ned_mps"))
    if norm3(v) <= max(min_speed_mps, 0.0):
        return False
    return contains_direction(cone, v, margin_rad=margin_rad)


def side_step_direction(reference_ned, axis_ned) -> np.ndarray:
    """The head-on tie-break: unit vector normal to ``axis_ned``, right of the reference.

    Parameters
    ----------
    reference_ned : array_like, shape (3,)
        Direction of travel (velocity); zero means "use the axis".
    axis_ned : array_like, shape (3,)
        Unit cone axis (vehicle → centre).

    Returns
    -------
    ndarray, shape (3,)
        The horizontal right-hand normal of the reference, ``(-h_e, h_n, 0) / |h|``,
        projected onto the plane normal to the axis and normalised. Fallbacks (module
        docstring): east for a vertical reference, then ``a × down``, then north.
    """
    axis = np.asarray(axis_ned, dtype=float)
    ref = np.asarray(reference_ned, dtype=float)
    if norm3(ref) <= _EPS:
        ref = axis
    h_n, h_e = float(ref[0]), float(ref[1])
    h_norm = math.hypot(h_n, h_e)
    scale = max(norm3(ref), 1.0)
    if h_norm > _EPS * scale:
        right = np.array([-h_e / h_norm, h_n / h_norm, 0.0])
    else:
        right = np.array([0.0, 1.0, 0.0])
    for candidate in (right, cross3(axis, np.array([0.0, 0.0, 1.0])), np.array([1.0, 0.0, 0.0])):
        u = candidate - float(candidate @ axis) * axis
        norm = norm3(u)
        if norm > 1e-6:
            return u / norm
    # Unreachable for a unit axis: east, a × down and north cannot all be parallel to it.
    raise ValueError(f"axis_ned must be a unit vector, got {axis_ned!r}")


def aiming_direction(
    cone: CollisionCone, reference_ned, *, tie_angle_rad: float = 0.0
) -> np.ndarray:
    """Unit vector ``u ⊥ axis`` locating the Eq. (28) point on the tangent circle.

    ``u = v⊥ / |v⊥|`` for the reference (velocity) ``v``; the side-step tie-break of
    :func:`side_step_direction` when ``v`` is within ``tie_angle_rad`` of the axis or of
    its opposite, or is zero.

    Returns
    -------
    ndarray, shape (3,)
        Unit vector normal to ``cone.axis_ned``.
    """
    return _aiming_direction(cone, np.array(vec3(reference_ned, "reference_ned")), tie_angle_rad)


def _aiming_direction(cone: CollisionCone, v: np.ndarray, tie_angle_rad: float) -> np.ndarray:
    """:func:`aiming_direction` for a reference already checked (float, shape (3,))."""
    axis = cone.axis_ned
    speed = norm3(v)
    if speed <= _EPS:
        return side_step_direction(axis, axis)
    v_perp = v - float(v @ axis) * axis
    perp = norm3(v_perp)
    if perp <= max(math.sin(min(max(tie_angle_rad, 0.0), 0.5 * math.pi)), _EPS) * speed:
        return side_step_direction(v, axis)
    return v_perp / perp


def aiming_point(cone: CollisionCone, vel_ned_mps, *, tie_angle_rad: float = 0.0) -> np.ndarray:
    """Eq. (28): the tangent point whose direction is nearest the velocity direction.

    Parameters
    ----------
    cone : CollisionCone
        Cone from the vehicle's position; the apex must be outside the sphere.
    vel_ned_mps : array_like, shape (3,)
        Vehicle velocity [m/s, NED]; zero is allowed (tie-break relative to the axis).
    tie_angle_rad : float
        A velocity within this angle of the axis counts as head-on and takes the
        documented side-step tie-break (module docstring). 0 means exact ties only.

    Returns
    -------
    ndarray, shape (3,)
        Aiming point [m, NED] on the tangent circle.

    Raises
    ------
    ValueError
        If the apex is on or inside the sphere (use :func:`escape_point`).
    """
    if cone.apex_inside:
        raise ValueError(
            "the vehicle is on or inside the boundary sphere: no tangent circle; use escape_point"
        )
    u = aiming_direction(cone, vel_ned_mps, tie_angle_rad=tie_angle_rad)
    return cone.circle_center_ned_m + cone.circle_radius_m * u


def circle_units(axis_ned: np.ndarray, first_ned: np.ndarray, n_points: int) -> np.ndarray:
    """Unit vectors ``⊥ axis`` at angles 0, +δ, -δ, +2δ, … from ``first_ned`` (δ = 2π/n).

    Positive angles turn right-handed about the axis. Shared by
    :func:`tangent_circle_points` and the planner; returns an ``(n_points, 3)`` array, or
    ``(..., n_points, 3)`` for stacks of axes and first vectors ``(..., 3)`` (the planner's
    circles at once, the same numbers as one at a time).
    """
    k = np.arange(n_points)
    steps = (k + 1) // 2
    signs = np.where(k % 2 == 1, 1.0, -1.0)
    phi = signs * steps * (2.0 * math.pi / n_points)
    a, f = axis_ned, first_ned
    second = np.stack(  # a × first, as cross3, over the leading axes
        [
            a[..., 1] * f[..., 2] - a[..., 2] * f[..., 1],
            a[..., 2] * f[..., 0] - a[..., 0] * f[..., 2],
            a[..., 0] * f[..., 1] - a[..., 1] * f[..., 0],
        ],
        axis=-1,
    ).astype(float)
    return (
        np.cos(phi)[:, None] * first_ned[..., None, :] + np.sin(phi)[:, None] * second[..., None, :]
    )


def tangent_circle_points(
    cone: CollisionCone, n_points: int, *, reference_ned=None, tie_angle_rad: float = 0.0
) -> np.ndarray:
    """Sample the tangent circle, nearest the reference direction first.

    Parameters
    ----------
    cone : CollisionCone
        Cone with the apex outside the sphere.
    n_points : int
        Number of samples (≥ 1), spaced 2π / n_points around the axis.
    reference_ned : array_like, shape (3,), optional
        Velocity to order by; the first sample is then the Eq. (28) point. None orders
        from the head-on side-step.
    tie_angle_rad : float
        As in :func:`aiming_point`.

    Returns
    -------
    ndarray, shape (n_points, 3)
        Points [m, NED] at circle angles 0, +δ, -δ, +2δ, … from the aiming point; the
        angle between each direction and the reference grows (weakly) down the rows.
    """
    if cone.apex_inside:
        raise ValueError("the vehicle is on or inside the boundary sphere: no tangent circle")
    if n_points < 1:
        raise ValueError(f"n_points must be >= 1, got {n_points}")
    ref = np.zeros(3) if reference_ned is None else reference_ned
    first = aiming_direction(cone, ref, tie_angle_rad=tie_angle_rad)
    units = circle_units(cone.axis_ned, first, n_points)
    return cone.circle_center_ned_m[None, :] + cone.circle_radius_m * units


def escape_point(
    pos_ned_m,
    sphere: SphereLike,
    *,
    clearance_m: float = 0.0,
    reference_ned=None,
    slide_m: float = 0.0,
) -> np.ndarray:
    """The way out of a boundary sphere: radially away from its centre, sliding along it.

    Parameters
    ----------
    pos_ned_m : array_like, shape (3,)
        Vehicle position [m, NED].
    sphere : SphereLike
        The boundary sphere the vehicle is in (or near).
    clearance_m : float
        Distance beyond the surface [m].
    reference_ned : array_like, shape (3,), optional
        Direction of travel (velocity or commanded direction). Its part tangent to the
        sphere sets the slide direction; when the vehicle is exactly at the centre, the
        escape direction is the side-step of :func:`side_step_direction` (north axis).
    slide_m : float
        How far to move the exit point along the tangent part of ``reference_ned`` [m]:
        a vehicle that strayed into a boundary while going around it keeps going around
        instead of backing out radially. The point stays outside the sphere.

    Returns
    -------
    ndarray, shape (3,)
        ``c + r̂ (R + clearance_m) + t̂ slide_m`` [m, NED], with ``r̂ = (p - c)/|p - c|``
        and ``t̂`` the unit tangent part of the reference (omitted when it has none).
    """
    pos = np.array(vec3(pos_ned_m, "pos_ned_m"))
    center = np.asarray(sphere.center_ned_m, dtype=float)
    ref = np.zeros(3) if reference_ned is None else np.asarray(reference_ned, dtype=float)
    away = pos - center
    norm = norm3(away)
    direction = away / norm if norm > _EPS else side_step_direction(ref, np.array([1.0, 0.0, 0.0]))
    exit_ned = center + direction * (float(sphere.radius_m) + clearance_m)
    tangent = ref - float(ref @ direction) * direction
    t_norm = norm3(tangent)
    if slide_m > 0.0 and t_norm > _EPS * max(norm3(ref), 1.0):
        exit_ned = exit_ned + tangent * (slide_m / t_norm)
    return exit_ned


def segment_intersects_sphere(start_ned_m, end_ned_m, sphere: SphereLike) -> bool:
    """Whether the segment from ``start_ned_m`` to ``end_ned_m`` enters the open ball.

    The closest point of the segment to the centre is strictly closer than the radius.
    """
    a = np.asarray(start_ned_m, dtype=float)
    b = np.asarray(end_ned_m, dtype=float)
    c = np.asarray(sphere.center_ned_m, dtype=float)
    ab = b - a
    length_sq = float(ab @ ab)
    t = 0.0 if length_sq <= 0.0 else min(max(float((c - a) @ ab) / length_sq, 0.0), 1.0)
    closest = a + t * ab
    return norm3(c - closest) < float(sphere.radius_m)
