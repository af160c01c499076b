"""Frame conventions: paper z-up / 1-2-3 Euler ↔ MAVLink NED/FRD / 3-2-1 Euler."""

import math

import numpy as np
import pytest

from plant_sim import paper_frames
from protocols import frames

RNG_SEED = 20261122


def _random_angles(rng, n, max_pitch=1.48):
    return np.column_stack(
        [
            rng.uniform(-math.pi, math.pi, n),
            rng.uniform(-max_pitch, max_pitch, n),
            rng.uniform(-math.pi, math.pi, n),
        ]
    )


def test_position_round_trip_and_axes():
    rng = np.random.default_rng(RNG_SEED)
    for p in rng.uniform(-1e3, 1e3, (200, 3)):
        np.testing.assert_allclose(
            paper_frames.paper_from_ned(paper_frames.ned_from_paper(p)), p, atol=1e-12
        )
    # the paper's §6 start (20, 0, 7) z-up is NED (20, 0, -7)
    np.testing.assert_array_equal(paper_frames.ned_from_paper([20.0, 0.0, 7.0]), [20.0, 0.0, -7.0])


def test_rotation_123_matches_eq4_closed_form():
    phi, theta, psi = 0.3, -0.2, 1.1
    sf, cf, st, ct, sp, cp = (
        math.sin(phi),
        math.cos(phi),
        math.sin(theta),
        math.cos(theta),
        math.sin(psi),
        math.cos(psi),
    )
    eq4 = np.array(
        [
            [ct * cp, -ct * sp, st],
            [sf * st * cp + cf * sp, -sf * st * sp + cf * cp, -sf * ct],
            [-cf * st * cp + sf * sp, cf * st * sp + sf * cp, cf * ct],
        ]
    )
    np.testing.assert_allclose(paper_frames.rotation_123(phi, theta, psi), eq4, atol=1e-15)


def test_euler_round_trips_to_1e12():
    rng = np.random.default_rng(RNG_SEED)
    for phi, theta, psi in _random_angles(rng, 500):
        got = paper_frames.euler123_from_rotation(paper_frames.rotation_123(phi, theta, psi))
        np.testing.assert_allclose(got, (phi, theta, psi), atol=1e-12)
        roll, pitch, yaw = paper_frames.mavlink_euler_from_paper_euler(phi, theta, psi)
        back = paper_frames.paper_euler_from_mavlink_euler(roll, pitch, yaw)
        np.testing.assert_allclose(back, (phi, theta, psi), atol=1e-12)
    for roll, pitch, yaw in _random_angles(rng, 500):
        got = frames.euler321_from_rotation(frames.rotation_321(roll, pitch, yaw))
        np.testing.assert_allclose(got, (roll, pitch, yaw), atol=1e-12)


def test_rotation_conjugation_maps_vectors_consistently():
    """R_ned·v_frd must equal T·(R_paper·(T·v_frd)): the same physical rotation."""
    rng = np.random.default_rng(RNG_SEED + 1)
    for phi, theta, psi in _random_angles(rng, 100):
        R_paper = paper_frames.rotation_123(phi, theta, psi)
        R_ned = paper_frames.rotation_ned_from_paper(R_paper)
        v_frd = rng.normal(size=3)
        np.testing.assert_allclose(
            R_ned @ v_frd,
            paper_frames.ned_from_paper(R_paper @ paper_frames.paper_from_ned(v_frd)),
            atol=1e-12,
        )
        np.testing.assert_allclose(R_ned @ R_ned.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R_ned) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize(
    ("paper", "mavlink"),
    [
        # level, paper ψ = +90° (counter-clockwise seen from above) is NED yaw −90° (west)
        ((0.0, 0.0, math.pi / 2), (0.0, 0.0, -math.pi / 2)),
        # paper θ > 0 tilts thrust toward +x (north): nose down, MAVLink pitch < 0
        ((0.0, 0.2, 0.0), (0.0, -0.2, 0.0)),
        # paper φ > 0 tilts thrust toward −y_paper = +east: right wing down, roll > 0
        ((0.2, 0.0, 0.0), (0.2, 0.0, 0.0)),
    ],
)
def test_known_attitudes(paper, mavlink):
    np.testing.assert_allclose(
        paper_frames.mavlink_euler_from_paper_euler(*paper), mavlink, atol=1e-15
    )


def test_thrust_direction_of_known_attitudes():
    """Body thrust (−z FRD) of a nose-down MAVLink attitude points forward-and-up in NED."""
    R = frames.rotation_321(0.0, -0.2, 0.0)
    thrust_ned = R @ np.array([0.0, 0.0, -1.0])
    assert thrust_ned[0] == pytest.approx(math.sin(0.2))  # pushes north
    assert thrust_ned[2] == pytest.approx(-math.cos(0.2))  # and up


def test_quaternion_of_mavlink_attitude_is_the_same_rotation():
    """The companion interpolates ATTITUDE as quaternions: same convention as rotation_321."""
    rng = np.random.default_rng(RNG_SEED + 2)
    for roll, pitch, yaw in _random_angles(rng, 300):
        q = frames.quat_from_euler321(roll, pitch, yaw)
        assert sum(c * c for c in q) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(
            frames.rotation_from_quat(q), frames.rotation_321(roll, pitch, yaw), atol=1e-12
        )


def test_slerp_ends_and_midpoint():
    q0 = frames.quat_from_euler321(0.0, 0.0, 0.2)
    q1 = frames.quat_from_euler321(0.0, 0.0, 1.0)
    np.testing.assert_allclose(frames.quat_slerp(q0, q1, 0.0), q0, atol=1e-12)
    np.testing.assert_allclose(frames.quat_slerp(q0, q1, 1.0), q1, atol=1e-12)
    mid = frames.rotation_from_quat(frames.quat_slerp(q0, q1, 0.5))
    np.testing.assert_allclose(mid, frames.rotation_321(0.0, 0.0, 0.6), atol=1e-12)
    # the shorter arc across ±180°: halfway between 170° and −170° is 180°
    a = frames.quat_from_euler321(0.0, 0.0, math.radians(170))
    b = frames.quat_from_euler321(0.0, 0.0, math.radians(-170))
    _, _, yaw = frames.euler321_from_rotation(
        frames.rotation_from_quat(frames.quat_slerp(a, b, 0.5))
    )
    assert abs(math.remainder(yaw - math.pi, 2 * math.pi)) < 1e-9
