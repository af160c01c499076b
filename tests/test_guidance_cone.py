"""Collision cone geometry and the Eq. (28) aiming point against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.guidance.cone import (
    BoundarySphere,
    aiming_direction,
    aiming_point,
    collision_cone,
    contains_direction,
    escape_point,
    is_critical,
    segment_intersects_sphere,
    side_step_direction,
    tangent_circle_points,
)

# The paper's §6 scenario in NED, with the 1.5 m obstacle inflated to 2 m
# (arm length 0.25 m + 0.25 m margin).
START_NED_M = np.array([20.0, 0.0, -7.0])
OBSTACLE = BoundarySphere(center_ned_m=(10.0, 0.0, -7.0), radius_m=2.0)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _angle(a, b) -> float:
    c = float(np.dot(_unit(a), _unit(b)))
    return math.acos(min(max(c, -1.0), 1.0))


def _basis(axis):
    """Two unit vectors completing ``axis`` to an orthonormal basis (independent of cone.py)."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = _unit(np.cross(axis, helper))
    return e1, np.cross(axis, e1)


def _rotated(axis, angle_rad, roll_rad):
    """A unit vector at ``angle_rad`` from ``axis``, turned by ``roll_rad`` about it."""
    e1, e2 = _basis(axis)
    side = math.cos(roll_rad) * e1 + math.sin(roll_rad) * e2
    return math.cos(angle_rad) * axis + math.sin(angle_rad) * side


def _random_geometry(rng):
    apex = rng.uniform(-20.0, 20.0, 3)
    radius = rng.uniform(0.3, 3.0)
    distance = radius * rng.uniform(1.05, 12.0)
    center = apex + distance * _unit(rng.normal(size=3))
    return apex, BoundarySphere(center_ned_m=tuple(center), radius_m=radius)


# --- cone geometry --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("distance_m", "radius_m"), [(10.0, 2.0), (5.5, 2.0), (2.1, 2.0), (40.0, 0.5)]
)
def test_half_angle_and_tangent_circle_closed_forms(distance_m, radius_m):
    apex = np.array([1.0, -2.0, -5.0])
    axis = _unit([0.3, -0.8, 0.2])
    sphere = BoundarySphere(center_ned_m=tuple(apex + distance_m * axis), radius_m=radius_m)
    cone = collision_cone(apex, sphere)

    tangent = math.sqrt(distance_m**2 - radius_m**2)
    assert not cone.apex_inside
    np.testing.assert_allclose(cone.half_angle_rad, math.asin(radius_m / distance_m), rtol=1e-12)
    np.testing.assert_allclose(cone.distance_m, distance_m, rtol=1e-12)
    np.testing.assert_allclose(cone.axis_ned, axis, atol=1e-12)
    np.testing.assert_allclose(cone.tangent_length_m, tangent, rtol=1e-12)
    np.testing.assert_allclose(cone.circle_radius_m, radius_m * tangent / distance_m, rtol=1e-12)
    np.testing.assert_allclose(
        cone.circle_center_ned_m, apex + axis * tangent**2 / distance_m, atol=1e-12
    )
    np.testing.assert_allclose(cone.surface_distance_m, distance_m - radius_m, rtol=1e-12)


def test_paper_scenario_cone():
    cone = collision_cone(START_NED_M, OBSTACLE)
    np.testing.assert_allclose(cone.half_angle_rad, math.asin(0.2), rtol=1e-12)
    np.testing.assert_allclose(cone.axis_ned, [-1.0, 0.0, 0.0], atol=0)
    np.testing.assert_allclose(cone.circle_center_ned_m, [10.4, 0.0, -7.0], atol=1e-12)
    np.testing.assert_allclose(cone.circle_radius_m, 2.0 * math.sqrt(96.0) / 10.0, rtol=1e-12)


@pytest.mark.parametrize("roll_rad", np.linspace(0.0, 2.0 * math.pi, 7))
def test_inside_and_outside_on_constructed_velocities(roll_rad):
    apex = np.array([0.0, 0.0, 0.0])
    sphere = BoundarySphere(center_ned_m=(10.0, 0.0, 0.0), radius_m=2.0)
    cone = collision_cone(apex, sphere)
    alpha = math.asin(0.2)
    axis = np.array([1.0, 0.0, 0.0])
    for speed in (0.5, 3.0):
        inside = speed * _rotated(axis, alpha - 1e-3, roll_rad)
        outside = speed * _rotated(axis, alpha + 1e-3, roll_rad)
        assert is_critical(cone, inside), "velocity 1 mrad inside the cone edge"
        assert not is_critical(cone, outside), "velocity 1 mrad outside the cone edge"
        assert is_critical(cone, outside, margin_rad=2e-3), "margin widens the cone"
        assert not is_critical(cone, inside, margin_rad=-2e-3), "negative margin narrows it"
        assert not is_critical(cone, -inside), "flying away is never critical"
    assert is_critical(cone, [1.0, 0.0, 0.0])
    assert not contains_direction(cone, [0.0, 1.0, 0.0])


def test_zero_and_slow_velocity_are_not_critical():
    cone = collision_cone(START_NED_M, OBSTACLE)
    assert not is_critical(cone, [0.0, 0.0, 0.0])
    assert not is_critical(cone, [-0.1, 0.0, 0.0], min_speed_mps=0.2)
    assert is_critical(cone, [-0.3, 0.0, 0.0], min_speed_mps=0.2)
    assert not contains_direction(cone, [0.0, 0.0, 0.0])


def test_apex_inside_sphere_is_a_clear_state():
    sphere = BoundarySphere(center_ned_m=(10.0, 0.0, -7.0), radius_m=2.0)
    pos = np.array([11.2, 0.5, -6.0])  # 1.64 m from the centre
    cone = collision_cone(pos, sphere)
    assert cone.apex_inside
    assert cone.half_angle_rad == math.pi
    assert cone.tangent_length_m == 0.0
    assert cone.circle_radius_m == 0.0
    for vel in ([1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]):
        assert is_critical(cone, vel), "inside the boundary everything is critical"
    with pytest.raises(ValueError, match="escape_point"):
        aiming_point(cone, [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="inside"):
        tangent_circle_points(cone, 8)

    exit_ned = escape_point(pos, sphere, clearance_m=0.5)
    center = np.array(sphere.center_ned_m)
    np.testing.assert_allclose(np.linalg.norm(exit_ned - center), 2.5, rtol=1e-12)
    np.testing.assert_allclose(_unit(exit_ned - center), _unit(pos - center), atol=1e-12)

    # Exactly at the centre: a deterministic side-step (right of the velocity).
    at_center = escape_point(center, sphere, reference_ned=[-1.0, 0.0, 0.0])
    np.testing.assert_allclose(at_center, center + np.array([0.0, -2.0, 0.0]), atol=1e-12)

    # On the surface counts as inside (the sphere is already inflated).
    on_surface = collision_cone(center + np.array([2.0, 0.0, 0.0]), sphere)
    assert on_surface.apex_inside


# --- aiming point, Eq. (28) -----------------------------------------------------------


def test_aiming_point_lies_on_tangent_circle_and_is_nearest_the_velocity():
    rng = np.random.default_rng(20240528)
    phis = np.linspace(0.0, 2.0 * math.pi, 3600, endpoint=False)
    for _ in range(60):
        apex, sphere = _random_geometry(rng)
        cone = collision_cone(apex, sphere)
        center = np.array(sphere.center_ned_m)
        distance = np.linalg.norm(center - apex)
        radius = sphere.radius_m
        # Velocities inside and outside the cone, at any speed.
        theta = rng.uniform(0.0, 2.5 * cone.half_angle_rad)
        vel = rng.uniform(0.1, 5.0) * _rotated(cone.axis_ned, theta, rng.uniform(0, 2 * math.pi))
        aim = aiming_point(cone, vel)

        scale = max(distance, 1.0)
        np.testing.assert_allclose(
            np.linalg.norm(aim - apex), math.sqrt(distance**2 - radius**2), rtol=1e-9
        )
        assert abs(np.dot(aim - center, aim - apex)) < 1e-9 * scale**2, "tangent: ⊥ radius"
        np.testing.assert_allclose(np.linalg.norm(aim - center), radius, rtol=1e-9)

        # Closed form: the nearest tangent direction is |θ - α| from the velocity.
        np.testing.assert_allclose(
            _angle(aim - apex, vel), abs(theta - cone.half_angle_rad), atol=1e-7
        )
        # Brute force over the circle, parametrised independently of the module.
        e1, e2 = _basis(cone.axis_ned)
        ring = cone.circle_center_ned_m + cone.circle_radius_m * (
            np.outer(np.cos(phis), e1) + np.outer(np.sin(phis), e2)
        )
        ring_dirs = (ring - apex) / np.linalg.norm(ring - apex, axis=1)[:, None]
        ring_angles = np.arccos(np.clip(ring_dirs @ _unit(vel), -1.0, 1.0))
        assert _angle(aim - apex, vel) <= ring_angles.min() + 1e-9, "no sampled point is nearer"


def test_paper_head_on_tie_break_is_a_right_hand_horizontal_side_step():
    cone = collision_cone(START_NED_M, OBSTACLE)
    expected = np.array([10.4, -2.0 * math.sqrt(96.0) / 10.0, -7.0])  # west, same altitude
    for vel in ([-2.0, 0.0, 0.0], [-0.01, 0.0, 0.0], [0.0, 0.0, 0.0]):
        np.testing.assert_allclose(aiming_point(cone, vel), expected, atol=1e-12)
    # Deterministic: the same answer every call.
    first = aiming_point(cone, [-2.0, 0.0, 0.0])
    for _ in range(5):
        assert np.array_equal(aiming_point(cone, [-2.0, 0.0, 0.0]), first)
    # Within the tie angle a small sideways velocity does not flip the side ...
    nudged = [-2.0, 2.0 * math.tan(math.radians(0.5)), 0.0]  # 0.5° to the east
    np.testing.assert_allclose(
        aiming_point(cone, nudged, tie_angle_rad=math.radians(1.0)), expected, atol=1e-12
    )
    # ... beyond it, Eq. (28) follows the velocity to its side.
    east_side = aiming_point(cone, nudged, tie_angle_rad=math.radians(0.25))
    assert east_side[1] > 0.0
    np.testing.assert_allclose(east_side[2], -7.0, atol=1e-12)


@pytest.mark.parametrize(
    ("heading", "right"),
    [
        ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),  # north → east
        ([0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]),  # east → south
        ([-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]),  # south → west
        ([0.0, -1.0, 0.0], [1.0, 0.0, 0.0]),  # west → north
    ],
)
def test_side_step_is_right_of_the_heading(heading, right):
    np.testing.assert_allclose(side_step_direction(heading, heading), right, atol=1e-12)
    # Climbing or descending head-on: still horizontal, still to the right.
    axis = _unit(np.asarray(heading) + np.array([0.0, 0.0, -0.5]))
    u = side_step_direction(axis, axis)
    np.testing.assert_allclose(u, right, atol=1e-12)
    assert abs(float(u @ axis)) < 1e-12


def test_side_step_fallbacks_for_vertical_approach():
    down = np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(side_step_direction(down, down), [0.0, 1.0, 0.0], atol=1e-12)
    # East reference with an east axis cannot use east: a × down = (0,1,0)×(0,0,1) = +x.
    east = np.array([0.0, 1.0, 0.0])
    u = side_step_direction([0.0, 0.0, -1.0], east)
    np.testing.assert_allclose(u, [1.0, 0.0, 0.0], atol=1e-12)


def test_aiming_direction_is_unit_and_normal_to_axis():
    rng = np.random.default_rng(7)
    for _ in range(30):
        apex, sphere = _random_geometry(rng)
        cone = collision_cone(apex, sphere)
        u = aiming_direction(cone, rng.normal(size=3))
        np.testing.assert_allclose(np.linalg.norm(u), 1.0, rtol=1e-12)
        assert abs(float(u @ cone.axis_ned)) < 1e-12


def test_tangent_circle_samples_start_at_aiming_point_and_get_worse():
    rng = np.random.default_rng(3)
    apex, sphere = _random_geometry(rng)
    cone = collision_cone(apex, sphere)
    vel = _rotated(cone.axis_ned, 0.5 * cone.half_angle_rad, 1.0)
    points = tangent_circle_points(cone, 36, reference_ned=vel)
    assert points.shape == (36, 3)
    np.testing.assert_allclose(points[0], aiming_point(cone, vel), atol=1e-12)
    center = np.array(sphere.center_ned_m)
    np.testing.assert_allclose(np.linalg.norm(points - center, axis=1), sphere.radius_m, rtol=1e-9)
    angles = [_angle(p - apex, vel) for p in points]
    assert np.all(np.diff(angles) >= -1e-9), "ordered nearest first"


def test_segment_intersects_sphere():
    sphere = BoundarySphere(center_ned_m=(10.0, 0.0, -7.0), radius_m=2.0)
    assert segment_intersects_sphere([20.0, 0.0, -7.0], [0.0, 0.0, -7.0], sphere)
    assert not segment_intersects_sphere([20.0, 2.5, -7.0], [0.0, 2.5, -7.0], sphere)
    assert not segment_intersects_sphere([20.0, 0.0, -7.0], [13.0, 0.0, -7.0], sphere)
    assert segment_intersects_sphere([10.5, 0.0, -7.0], [10.5, 0.0, -7.0], sphere)


@pytest.mark.parametrize(
    ("center", "radius"),
    [((0.0, 0.0), 1.0), ((0.0, 0.0, math.nan), 1.0), ((0.0, 0.0, 0.0), 0.0), ((0, 0, 0), -1)],
)
def test_boundary_sphere_rejects_bad_values(center, radius):
    with pytest.raises(ValueError, match=r"center_ned_m|radius_m"):
        BoundarySphere(center_ned_m=center, radius_m=radius)
