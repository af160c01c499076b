"""Full nonlinear quadrotor dynamics, Eq. (12) and (16), and a fixed-step RK4 integrator.

All quantities here are in the paper's frames: inertial z up, body z up (thrust along
+z_body), 1-2-3 Euler angles ``R = Rx(φ) Ry(θ) Rz(ψ)`` (Eq. 4). Nothing outside
``plant_sim`` sees these frames; :mod:`plant_sim.paper_frames` converts to NED/FRD.

State vector (12,), paper frame, SI units::

    [x, y, z, ẋ, ẏ, ż, φ, θ, ψ, φ̇, θ̇, ψ̇]

Input: the four rotor thrusts ``F1..F4`` [N] (front, right, rear, left of Fig. 1, so that
Eq. 14 gives roll torque ``d(F2 − F4)`` and pitch torque ``d(F3 − F1)``).

The per-step kernels are plain scalar arithmetic compiled with numba: numpy on
3-vectors costs ~460 µs per RK4 step on these machines, this ~2 µs (DESIGN.md).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from plant_sim.params import QuadrotorParams

__all__ = [
    "STATE_SIZE",
    "PhysicsConstants",
    "derivative",
    "physics_constants",
    "rk4_step",
    "rotor_wrench",
]

STATE_SIZE = 12


class PhysicsConstants(NamedTuple):
    """Plain-float view of :class:`QuadrotorParams` that compiled kernels accept."""

    m: float
    Jx: float
    Jy: float
    Jz: float
    ktx: float
    kty: float
    ktz: float
    krx: float
    kry: float
    krz: float
    d: float
    c: float
    g: float
    f_min: float
    f_max: float
    # the air's velocity in the paper's frame [m/s] (plant_sim.disturbance): drag acts on
    # the velocity relative to it; not a vehicle parameter, the controller never reads it
    wind_x: float = 0.0
    wind_y: float = 0.0
    wind_z: float = 0.0


def physics_constants(p: QuadrotorParams) -> PhysicsConstants:
    """Flatten ``p`` into the tuple the compiled kernels take (in still air)."""
    return PhysicsConstants(
        float(p.mass_kg),
        *map(float, p.inertia_kgm2),
        *map(float, p.drag_force_kgps),
        *map(float, p.drag_torque_kgm2ps),
        float(p.arm_length_m),
        float(p.rotor_torque_coeff_m),
        float(p.gravity_mps2),
        float(p.rotor_thrust_min_n),
        float(p.rotor_thrust_max_n),
    )


@numba.njit(cache=True)
def rotor_wrench(
    f1: float, f2: float, f3: float, f4: float, k: PhysicsConstants
) -> tuple[float, float, float, float]:
    """Eq. (9) and (14): total thrust ``ΣF_i`` and body torques from the rotor thrusts."""
    total = f1 + f2 + f3 + f4
    tau_x = k.d * (f2 - f4)
    tau_y = k.d * (f3 - f1)
    tau_z = k.c * (f1 - f2 + f3 - f4)  # T_i = c F_i; rotors 1, 3 spin the other way to 2, 4
    return total, tau_x, tau_y, tau_z


@numba.njit(cache=True)
def derivative(state: np.ndarray, rotors_n: np.ndarray, k: PhysicsConstants) -> np.ndarray:
    """Time derivative of the state, Eq. (12) and (16) in full (no small-angle shortcut)."""
    vx, vy, vz = state[3], state[4], state[5]
    phi, theta, psi = state[6], state[7], state[8]
    dphi, dtheta, dpsi = state[9], state[10], state[11]
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)

    # Eq. (4), R = R_t^{B→I}
    r00, r01, r02 = ct * cp, -ct * sp, st
    r10, r11, r12 = sf * st * cp + cf * sp, -sf * st * sp + cf * cp, -sf * ct
    r20, r21, r22 = -cf * st * cp + sf * sp, cf * st * sp + sf * cp, cf * ct

    total, tau_x, tau_y, tau_z = rotor_wrench(rotors_n[0], rotors_n[1], rotors_n[2], rotors_n[3], k)

    # Eq. (12): ξ̈ = −(1/m) R K_t Rᵀ ξ̇ − G + (1/m) R F, the drag on the air-relative
    # velocity ξ̇ − w (w = 0 in still air, the paper's case)
    ax_, ay_, az_ = vx - k.wind_x, vy - k.wind_y, vz - k.wind_z
    ub = r00 * ax_ + r10 * ay_ + r20 * az_  # body air velocity V = Rᵀ (ξ̇ − w)
    vb = r01 * ax_ + r11 * ay_ + r21 * az_
    wb = r02 * ax_ + r12 * ay_ + r22 * az_
    fbx, fby, fbz = k.ktx * ub, k.kty * vb, k.ktz * wb
    inv_m = 1.0 / k.m
    ax = (-(r00 * fbx + r01 * fby + r02 * fbz) + r02 * total) * inv_m
    ay = (-(r10 * fbx + r11 * fby + r12 * fbz) + r12 * total) * inv_m
    az = (-(r20 * fbx + r21 * fby + r22 * fbz) + r22 * total) * inv_m - k.g

    # Eq. (5): Ω = R_r φ̇
    p = ct * cp * dphi + sp * dtheta
    q = -ct * sp * dphi + cp * dtheta
    r = st * dphi + dpsi
    # Ω̇ = J⁻¹ (T − K_r Ω − Ω × JΩ), Eq. (13)–(15)
    hx, hy, hz = k.Jx * p, k.Jy * q, k.Jz * r
    dp = (tau_x - k.krx * p - (q * hz - r * hy)) / k.Jx
    dq = (tau_y - k.kry * q - (r * hx - p * hz)) / k.Jy
    dr = (tau_z - k.krz * r - (p * hy - q * hx)) / k.Jz
    # (∂R_r/∂θ θ̇ + ∂R_r/∂ψ ψ̇) φ̇, the Euler-rate coupling term of Eq. (16)
    c0 = -st * cp * dtheta * dphi - ct * sp * dpsi * dphi + cp * dpsi * dtheta
    c1 = st * sp * dtheta * dphi - ct * cp * dpsi * dphi - sp * dpsi * dtheta
    c2 = ct * dtheta * dphi
    # φ̈ = R_r⁻¹ (Ω̇ − Ṙ_r φ̇), with R_r⁻¹ written out (singular only at θ = ±90°)
    w0, w1, w2 = dp - c0, dq - c1, dr - c2
    a = cp * w0 - sp * w1  # = cθ φ̈
    ddtheta = sp * w0 + cp * w1
    ddphi = a / ct
    ddpsi = w2 - st * ddphi

    out = np.empty(12)
    out[0], out[1], out[2] = vx, vy, vz
    out[3], out[4], out[5] = ax, ay, az
    out[6], out[7], out[8] = dphi, dtheta, dpsi
    out[9], out[10], out[11] = ddphi, ddtheta, ddpsi
    return out


@numba.njit(cache=True)
def rk4_step(
    state: np.ndarray, rotors_n: np.ndarray, dt_s: float, k: PhysicsConstants
) -> np.ndarray:
    """One classical fourth-order Runge–Kutta step with the rotor thrusts held constant."""
    k1 = derivative(state, rotors_n, k)
    k2 = derivative(state + 0.5 * dt_s * k1, rotors_n, k)
    k3 = derivative(state + 0.5 * dt_s * k2, rotors_n, k)
    k4 = derivative(state + dt_s * k3, rotors_n, k)
    return state + (dt_s / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
