"""Eq. (12) and (16): compiled kernels against a literal matrix transcription and invariants."""

import dataclasses
import math

import numpy as np
import pytest

from plant_sim.dynamics import derivative, physics_constants, rk4_step, rotor_wrench
from plant_sim.flight_control import mix
from plant_sim.paper_frames import rotation_123
from plant_sim.params import QuadrotorParams


def _rr(theta, psi):
    """Eq. (5)."""
    ct, st, cp, sp = math.cos(theta), math.sin(theta), math.cos(psi), math.sin(psi)
    return np.array([[ct * cp, sp, 0.0], [-ct * sp, cp, 0.0], [st, 0.0, 1.0]])


def _reference_derivative(state, rotors, p: QuadrotorParams):
    """Eq. (12) and (16) written with numpy matrices exactly as printed."""
    m, g = p.mass_kg, p.gravity_mps2
    J = np.diag(p.inertia_kgm2)
    Kt, Kr = np.diag(p.drag_force_kgps), np.diag(p.drag_torque_kgm2ps)
    xi_dot, ang, ang_dot = state[3:6], state[6:9], state[9:12]
    phi, theta, psi = ang
    R = rotation_123(phi, theta, psi)
    F = np.array([0.0, 0.0, rotors.sum()])
    G = np.array([0.0, 0.0, g])
    xi_dd = -(1 / m) * R @ Kt @ np.linalg.inv(R) @ xi_dot - G + (1 / m) * R @ F
    f1, f2, f3, f4 = rotors
    c = p.rotor_torque_coeff_m
    d = p.arm_length_m
    T = np.array([d * (f2 - f4), d * (f3 - f1), c * (f1 - f2 + f3 - f4)])  # Eq. (14)
    Rr = _rr(theta, psi)
    Rri = np.linalg.inv(Rr)
    Ji = np.linalg.inv(J)
    h = 1e-6  # ∂R_r/∂θ and ∂R_r/∂ψ by central differences
    dRr_dtheta = (_rr(theta + h, psi) - _rr(theta - h, psi)) / (2 * h)
    dRr_dpsi = (_rr(theta, psi + h) - _rr(theta, psi - h)) / (2 * h)
    Om = Rr @ ang_dot
    ang_dd = (
        -Rri @ Ji @ Kr @ Rr @ ang_dot
        - Rri @ Ji @ np.cross(Om, J @ Om)
        - Rri @ (dRr_dtheta * ang_dot[1] + dRr_dpsi * ang_dot[2]) @ ang_dot
        + Rri @ Ji @ T
    )
    return np.concatenate([xi_dot, xi_dd, ang_dot, ang_dd])


def test_derivative_matches_literal_equations_at_random_states():
    p = QuadrotorParams()
    k = physics_constants(p)
    rng = np.random.default_rng(7)
    for _ in range(200):
        state = np.concatenate(
            [
                rng.uniform(-10, 10, 3),
                rng.uniform(-3, 3, 3),
                rng.uniform(-0.6, 0.6, 2),
                rng.uniform(-math.pi, math.pi, 1),
                rng.uniform(-2, 2, 3),
            ]
        )
        rotors = rng.uniform(0, p.rotor_thrust_max_n, 4)
        np.testing.assert_allclose(
            derivative(state, rotors, k),
            _reference_derivative(state, rotors, p),
            rtol=1e-6,
            atol=1e-7,
            err_msg=f"state={state}, rotors={rotors}",
        )


def test_free_fall_starts_at_g():
    k = physics_constants(QuadrotorParams())
    state = np.zeros(12)
    state[2] = 7.0
    np.testing.assert_allclose(derivative(state, np.zeros(4), k)[3:6], [0, 0, -9.81], atol=1e-15)


def test_torque_free_rotation_conserves_momentum_and_energy():
    """No drag, no torque: inertial angular momentum R·J·Ω and ½ΩᵀJΩ are invariants.

    This exercises the Ω×JΩ term and the Euler-rate coupling terms of Eq. (16).
    """
    p = dataclasses.replace(QuadrotorParams(), drag_torque_kgm2ps=(0.0, 0.0, 0.0))
    k = physics_constants(p)
    J = np.diag(p.inertia_kgm2)
    state = np.zeros(12)
    state[6:9] = (0.1, -0.2, 0.3)
    state[9:12] = (0.8, -0.5, 1.5)

    def invariants(s):
        om = _rr(s[7], s[8]) @ s[9:12]
        return rotation_123(*s[6:9]) @ J @ om, 0.5 * om @ J @ om

    h0, e0 = invariants(state)
    dt = 1e-3
    for _ in range(2000):  # 2 s, a few tumbles
        state = rk4_step(state, np.zeros(4), dt, k)
    h1, e1 = invariants(state)
    # RK4 global error ~ (ω dt)^4: far below these tolerances
    np.testing.assert_allclose(h1, h0, rtol=1e-7, atol=1e-12)
    assert e1 == pytest.approx(e0, rel=1e-7)


def test_mixer_inverts_eq14():
    k = physics_constants(QuadrotorParams())
    rng = np.random.default_rng(3)
    out = np.zeros(10)
    for _ in range(100):
        total = rng.uniform(4.0, 9.0)
        tau = rng.uniform(-0.05, 0.05, 3)
        saturated = mix(total, *tau, k, out)
        assert not saturated
        np.testing.assert_allclose(rotor_wrench(*out[:4], k), (total, *tau), atol=1e-12)


def test_mixer_clamps_to_rotor_limits():
    p = QuadrotorParams()
    k = physics_constants(p)
    out = np.zeros(10)
    assert mix(4 * p.rotor_thrust_max_n, 1.0, 0.0, 0.0, k, out)
    assert np.all(out[:4] <= p.rotor_thrust_max_n)
    assert np.all(out[:4] >= p.rotor_thrust_min_n)


def test_mixer_gives_up_yaw_before_thrust_roll_and_pitch():
    """A yaw demand beyond the rotors' reach is scaled down; the rest stays exact."""
    p = QuadrotorParams()
    k = physics_constants(p)
    out = np.zeros(10)
    total, tau_x, tau_y, tau_z = p.hover_thrust_n, 0.02, -0.03, 0.2  # 0.2 N·m: ~3 N/rotor
    assert mix(total, tau_x, tau_y, tau_z, k, out)
    got_total, got_x, got_y, got_z = rotor_wrench(*out[:4], k)
    np.testing.assert_allclose((got_total, got_x, got_y), (total, tau_x, tau_y), atol=1e-12)
    assert 0.0 < got_z < tau_z
    limits = (p.rotor_thrust_min_n, p.rotor_thrust_max_n)
    assert np.any(np.isclose(out[:4], limits[0]) | np.isclose(out[:4], limits[1]))
    assert np.all((out[:4] >= limits[0] - 1e-12) & (out[:4] <= limits[1] + 1e-12))
