"""Aiming point among several obstacles: the free tangent direction nearest the velocity.

Extends Eq. (28) to several boundary spheres seen from one vehicle position. Candidates
are sampled on every obstacle's tangent circle (``n_candidates`` each, the first being that
obstacle's exact Eq. (28) point) and ranked by the angle between their direction and the
reference direction (the velocity). A candidate is **rejected** when its point lies inside
another boundary sphere or its direction lies inside another obstacle's collision cone
(widened by ``cone_margin_rad``); the best remaining one is taken. The free directions are
bounded by the union of the cones, so this is the free direction nearest the velocity, up
to the sampling; with one obstacle it is exactly Eq. (28). Nothing free (the cones cover
every sampled direction) → None, which the caller turns into a HOLD.

Ranking ties (the head-on case) are broken deterministically: angles are compared to 1e-9
in cosine, then the candidate nearer the horizontal plane wins (keep altitude), then the
obstacle order given, then the sample order (the right-hand side-step first, see
:mod:`companion.guidance.cone`). A reference within ``tie_angle_rad`` of the axis of a
cone that contains it (the nearest such, by surface distance) is snapped onto that axis
first, so near-head-on noise cannot flip the side.

Several spheres per obstacle (the map's pieces, :mod:`companion.guidance.map_boundaries`)
make two refinements worth having, both off by default (then the above is exact):

* ``vertical_weight`` > 1 ranks by the angle after scaling the vertical components of the
  candidate and the reference by it: among nearly equal detours the level one wins, as a
  multirotor pilot would fly it. A lumpy union of pieces otherwise tilts the nearest free
  direction up or down by the accident of where the pieces' cubes fall.
* ``cluster_tie``: when the reference's azimuth is within ``tie_angle_rad`` of the
  azimuth of the cluster's mean axis (the candidate cones' axes weighted by their solid
  angle) and its elevation within the widest cone's half-angle of the axis's, the
  approach is head-on to the cluster as a whole: candidates to the right of the reference
  (its right-hand horizontal normal, as the single-sphere tie-break) are ranked first.
  The side no longer depends on which piece happened to be seen first, nor on whether
  the first pieces seen lie a little above or below the path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.guidance.cone import CollisionCone, _aiming_direction, circle_units

__all__ = ["AimChoice", "choose_aiming_point", "overlapping_cluster"]


@dataclass(frozen=True, eq=False)
class AimChoice:
    """The chosen aiming point.

    Attributes
    ----------
    aiming_point_ned_m : ndarray, shape (3,)
        Point on the tangent circle of ``cones[cone_index]`` [m, NED].
    direction_ned : ndarray, shape (3,)
        Unit vector from the vehicle to the aiming point.
    distance_m : float
        Vehicle to aiming point [m] (that cone's tangent length).
    cone_index : int
        Index into the ``cones`` given of the obstacle whose circle holds the point.
    n_rejected : int
        Better-ranked candidates that were rejected (0: the first choice was free).
    """

    aiming_point_ned_m: np.ndarray
    direction_ned: np.ndarray
    distance_m: float
    cone_index: int
    n_rejected: int


def overlapping_cluster(
    cones: Sequence[CollisionCone], seeds: Sequence[int], *, margin_rad: float = 0.0
) -> list[int]:
    """Indices of the cones connected to ``seeds`` through overlapping cones (sorted).

    Two cones (same apex) overlap when the angle between their axes is smaller than the
    sum of their half-angles plus ``margin_rad``. The union of a cluster is what the
    vehicle has to go around, so its tangent circles hold the candidates.
    """
    cluster = set(seeds)
    frontier = list(seeds)
    if not cones:
        return sorted(cluster)
    # every pair at once: the angle between the axes and the overlap limit, (n, n)
    axes = np.array([cone.axis_ned for cone in cones])
    half_angles = np.array([cone.half_angle_rad for cone in cones])
    axis_angle_rad = np.arccos(np.clip(axes @ axes.T, -1.0, 1.0))
    limit_rad = half_angles[:, None] + half_angles[None, :] + margin_rad
    overlaps = (limit_rad >= math.pi) | (axis_angle_rad < limit_rad)
    while frontier:
        i = frontier.pop()
        for j in np.flatnonzero(overlaps[i]).tolist():
            if j not in cluster:
                cluster.add(j)
                frontier.append(j)
    return sorted(cluster)


def choose_aiming_point(
    cones: Sequence[CollisionCone],
    reference_ned,
    *,
    n_candidates: int = 72,
    tie_angle_rad: float = 0.0,
    cone_margin_rad: float = 0.0,
    candidate_indices: Sequence[int] | None = None,
    max_elevation_rad: float | None = None,
    vertical_weight: float = 1.0,
    cluster_tie: bool = False,
) -> AimChoice | None:
    """Choose the free tangent point whose direction is nearest the reference direction.

    Parameters
    ----------
    cones : sequence of CollisionCone
        Cones from one vehicle position (same apex), apex outside every sphere; at least
        one. Every cone contributes candidates and rejects others'.
    reference_ned : array_like, shape (3,)
        Direction of travel (velocity [m/s, NED]); zero means the axis of the cone with the
        nearest surface (the head-on tie-break then applies).
    n_candidates : int
        Samples per tangent circle.
    tie_angle_rad : float
        Head-on tolerance (module docstring).
    cone_margin_rad : float
        Widening of the other cones in the rejection test [rad].
    candidate_indices : sequence of int, optional
        Cones whose tangent circles supply candidates (default: all). Every cone still
        rejects candidates. :func:`overlapping_cluster` gives a sensible set.
    max_elevation_rad : float, optional
        Candidates climbing or descending more steeply are rejected (the safety envelope
        flies no path steeper than the camera's view covers, so such an aiming point
        would be flown clamped, into the obstacle).
    vertical_weight : float
        Ranking weight of vertical deviation (module docstring; 1: Eq. 28 exactly).
    cluster_tie : bool
        Head-on to the candidate cones' cluster: right-hand candidates first (module
        docstring).

    Returns
    -------
    AimChoice or None
        None when every candidate is rejected.

    Raises
    ------
    ValueError
        No cones, cones with different apexes, or an apex inside a sphere.
    """
    apex = _check_cones(cones, n_candidates, vertical_weight)
    ref = np.asarray(reference_ned, dtype=float)
    ref_norm = math.sqrt(float(ref @ ref))
    ref_hat = _reference_direction(cones, ref, ref_norm, tie_angle_rad)
    generators = range(len(cones)) if candidate_indices is None else list(candidate_indices)
    if len(generators) == 0:
        raise ValueError("candidate_indices must name at least one cone")
    c = _Candidates.on(cones, generators, ref_hat, tie_angle_rad, n_candidates)
    free = _free(cones, apex, c, cone_margin_rad, max_elevation_rad)

    cos_q = _closeness_q(c.dirs, ref_hat, vertical_weight)
    vert_q = np.round(np.abs(c.units[:, 2]) * 1e9)
    left = np.zeros(len(c.pts), dtype=np.int8)
    if cluster_tie and ref_norm > 1e-9 and _head_on(cones, generators, ref, tie_angle_rad):
        right = np.array([-ref[1], ref[0], 0.0]) / math.hypot(float(ref[0]), float(ref[1]))
        left = (c.dirs @ right < -1e-9).astype(np.int8)
    order = np.lexsort((c.sample, c.owner, vert_q, -cos_q, left))
    free_ranked = np.flatnonzero(free[order])
    if free_ranked.size == 0:
        return None
    rank = int(free_ranked[0])
    best = int(order[rank])
    return AimChoice(
        aiming_point_ned_m=c.pts[best],
        direction_ned=c.dirs[best],
        distance_m=float(c.dists[best]),
        cone_index=int(c.owner[best]),
        n_rejected=rank,
    )


def _closeness_q(dirs: np.ndarray, ref_hat: np.ndarray, vertical_weight: float) -> np.ndarray:
    """Cosine of each direction with the reference, vertical deviation weighted by
    ``vertical_weight`` (1: Eq. 28 exactly), quantised to 1e-9 so that ties are exact."""
    if vertical_weight == 1.0:
        return np.round((dirs @ ref_hat) * 1e9)
    scale = np.array([1.0, 1.0, vertical_weight])
    dirs_w = dirs * scale
    dirs_w /= np.linalg.norm(dirs_w, axis=1)[:, None]
    ref_w = ref_hat * scale
    return np.round((dirs_w @ (ref_w / np.linalg.norm(ref_w))) * 1e9)


def _check_cones(cones, n_candidates: int, vertical_weight: float) -> np.ndarray:
    """The shared apex of ``cones``; ValueError for what :func:`choose_aiming_point` refuses."""
    if not cones:
        raise ValueError("choose_aiming_point needs at least one collision cone")
    apex = cones[0].apex_ned_m
    for cone in cones:
        if cone.apex_inside:
            raise ValueError("the vehicle is inside a boundary sphere: escape first")
        if cone.apex_ned_m is not apex and not np.array_equal(cone.apex_ned_m, apex):
            raise ValueError("all cones must share the vehicle position as apex")
    if n_candidates < 1:
        raise ValueError(f"n_candidates must be >= 1, got {n_candidates}")
    if not (math.isfinite(vertical_weight) and vertical_weight > 0.0):
        raise ValueError(f"vertical_weight must be finite and > 0, got {vertical_weight!r}")
    return apex


def _reference_direction(cones, ref: np.ndarray, ref_norm: float, tie_angle_rad: float):
    """Unit reference: the velocity, or the axis of the most urgent cone it is head-on to
    (within ``tie_angle_rad``), or with no velocity that cone's axis."""
    by_urgency = sorted(range(len(cones)), key=lambda i: (cones[i].surface_distance_m, i))
    if ref_norm <= 1e-9:
        return cones[by_urgency[0]].axis_ned
    ref_hat = ref / ref_norm
    cos_tie = math.cos(tie_angle_rad)
    for i in by_urgency:
        cos_axis = float(ref_hat @ cones[i].axis_ned)
        if cos_axis >= cos_tie and cos_axis > math.cos(cones[i].half_angle_rad):
            return cones[i].axis_ned
    return ref_hat


@dataclass(frozen=True, eq=False)
class _Candidates:
    """Samples of every generator's tangent circle, flattened (generator-major)."""

    pts: np.ndarray  # points on the circles [m, NED]
    units: np.ndarray  # their unit offsets from the circle centres
    owner: np.ndarray  # cone index of each sample
    sample: np.ndarray  # sample index on its circle
    offsets: np.ndarray  # apex to point [m]
    dists_sq: np.ndarray
    dists: np.ndarray
    dirs: np.ndarray  # unit directions from the apex

    @classmethod
    def on(cls, cones, generators, ref_hat, tie_angle_rad: float, n: int) -> _Candidates:
        firsts = np.array([_aiming_direction(cones[i], ref_hat, tie_angle_rad) for i in generators])
        units = circle_units(np.array([cones[i].axis_ned for i in generators]), firsts, n)
        # tangent circle of each generator: centre apex + a L²/D, radius R L / D
        circle_centers = np.array([cones[i].circle_center_ned_m for i in generators])
        circle_radii = np.array([cones[i].circle_radius_m for i in generators])
        pts = (circle_centers[:, None, :] + circle_radii[:, None, None] * units).reshape(-1, 3)
        offsets = pts - cones[0].apex_ned_m[None, :]
        dists_sq = np.einsum("ij,ij->i", offsets, offsets)
        dists = np.sqrt(dists_sq)
        return cls(
            pts=pts,
            units=units.reshape(-1, 3),
            owner=np.repeat(np.asarray(generators), n),
            sample=np.tile(np.arange(n), len(generators)),
            offsets=offsets,
            dists_sq=dists_sq,
            dists=dists,
            dirs=offsets / dists[:, None],
        )


def _free(
    cones, apex: np.ndarray, c: _Candidates, cone_margin_rad: float, max_elevation_rad
) -> np.ndarray:
    """Candidates no other cone rejects and, with ``max_elevation_rad``, not steeper than
    that. Rejection by every other cone at once, (candidates, cones): a direction inside
    its (widened) cone, or a point inside its ball. Both from the apex: with o = x - p and
    q = c - p, |x - c|² = |o|² - 2 o·q + |q|² (a few metres, so exact to ~1e-15 m²)."""
    axes = np.array([cone.axis_ned for cone in cones])
    to_centers = np.array([cone.center_ned_m for cone in cones]) - apex[None, :]
    radii = np.array([cone.radius_m for cone in cones])
    limits = np.array([cone.half_angle_rad for cone in cones]) + cone_margin_rad
    other = c.owner[:, None] != np.arange(len(cones))[None, :]
    wide = limits >= math.pi  # covers every direction
    in_cone = ((c.dirs @ axes.T) > np.cos(np.where(wide, 0.0, limits))[None, :]) | wide[None, :]
    dist_sq = (
        c.dists_sq[:, None]
        - 2.0 * (c.offsets @ to_centers.T)
        + np.einsum("ij,ij->i", to_centers, to_centers)[None, :]
    )
    in_ball = dist_sq < (radii**2)[None, :]
    free = ~np.any(other & (in_cone | in_ball), axis=1)
    if max_elevation_rad is not None:
        free &= np.abs(c.dirs[:, 2]) <= math.sin(max_elevation_rad) + 1e-12
    return free


def _head_on(cones, generators, ref: np.ndarray, tie_angle_rad: float) -> bool:
    """The velocity points at the generators' cluster (its half-angle-weighted mean axis)
    within ``tie_angle_rad`` in azimuth and within the widest cone in elevation."""
    weights = [1.0 - math.cos(min(cones[i].half_angle_rad, 0.5 * math.pi)) for i in generators]
    mean_axis = sum(w * cones[i].axis_ned for w, i in zip(weights, generators, strict=True))
    horizontal = math.hypot(float(ref[0]), float(ref[1]))
    mean_h = math.hypot(float(mean_axis[0]), float(mean_axis[1]))
    if horizontal <= 1e-9 or mean_h <= 1e-9:
        return False
    azimuth = math.atan2(
        float(ref[0] * mean_axis[1] - ref[1] * mean_axis[0]),
        float(ref[0] * mean_axis[0] + ref[1] * mean_axis[1]),
    )
    elevation = math.atan2(-float(mean_axis[2]), mean_h) - math.atan2(-float(ref[2]), horizontal)
    widest = max(cones[i].half_angle_rad for i in generators)
    return abs(azimuth) <= tie_angle_rad and abs(elevation) < widest
