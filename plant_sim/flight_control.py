"""Flight controller of §3: feedback linearization + LQ tracker, position and attitude loops.

Position subsystem: the translational dynamics of Eq. (12) are linearized by cancelling
gravity and the drag term, leaving ``ξ̈ = a`` per axis; the LQ tracker (gains of Eq. 34)
gives ``a``; the thrust direction ``R e3 = [sθ, −sφ cθ, cφ cθ]`` of the 1-2-3 rotation
then yields the virtual inputs (φ_d, θ_d), clamped to ±15° (§6.1). Total thrust keeps the
vertical channel exactly linearized with the *actual* attitude: ``U1 = m a_z / (cφ cθ)``.
With 1-2-3 angles the thrust direction does not depend on ψ, so the virtual inputs hold
for any commanded yaw; the yaw command (MAVLink NED yaw) is converted into the paper's ψ
for the current roll and pitch so that the vehicle's NED heading equals the command.

Attitude subsystem: Eq. (16) is linearized by choosing the body torque
``T = J (R_r v + Ṙ_r φ̇) + K_r Ω + Ω × JΩ`` so that ``φ̈ = v``; the LQ tracker (gains of
Eq. 31) gives ``v``; the torques and total thrust become rotor thrusts by inverting
Eq. (14), clamped to the rotor limits.

Frames are the paper's (z up) throughout; the caller converts from NED.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from plant_sim.dynamics import PhysicsConstants

__all__ = [
    "OUT_PHI_D",
    "OUT_PSI_D",
    "OUT_ROTORS",
    "OUT_ROTOR_SAT",
    "OUT_SIZE",
    "OUT_THETA_D",
    "OUT_TILT_SAT",
    "OUT_TOTAL_THRUST",
    "control_law",
    "mix",
    "paper_yaw_for_ned_heading",
]

# Layout of the controller's output vector.
OUT_ROTORS = slice(0, 4)  # F1..F4 [N], after clamping
OUT_PHI_D = 4  # commanded φ [rad], after the tilt clamp
OUT_THETA_D = 5  # commanded θ [rad], after the tilt clamp
OUT_PSI_D = 6  # commanded ψ [rad]
OUT_TOTAL_THRUST = 7  # total thrust asked for, before rotor clamping [N]
OUT_TILT_SAT = 8  # 1.0 when the ±max tilt clamp was active
OUT_ROTOR_SAT = 9  # 1.0 when a rotor thrust was clamped
OUT_SIZE = 10


@numba.njit(cache=True)
def _wrap_pi(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


@numba.njit(cache=True)
def paper_yaw_for_ned_heading(yaw_ned_rad: float, phi_rad: float, theta_rad: float) -> float:
    """ψ (1-2-3, z-up) whose MAVLink 3-2-1 NED yaw equals ``yaw_ned_rad`` at this φ, θ.

    MAVLink yaw is ``atan2(R_ned[1,0], R_ned[0,0])`` with ``R_ned = T R T``, i.e.
    ``atan2(−(sφ sθ cψ + cφ sψ), cθ cψ)``; solving for ψ gives the closed form below.
    At φ = θ = 0 it reduces to ψ = −yaw.
    """
    sy, cy = math.sin(yaw_ned_rad), math.cos(yaw_ned_rad)
    return math.atan2(
        -sy * math.cos(theta_rad) - cy * math.sin(phi_rad) * math.sin(theta_rad),
        cy * math.cos(phi_rad),
    )


@numba.njit(cache=True)
def mix(
    total_n: float, tau_x: float, tau_y: float, tau_z: float, k: PhysicsConstants, out: np.ndarray
) -> bool:
    """Invert Eq. (14) into rotor thrusts ``out[0:4]``, clamped; True if any was clamped."""
    base = 0.25 * total_n
    rx = tau_x / (2.0 * k.d)
    ry = tau_y / (2.0 * k.d)
    rz = tau_z / (4.0 * k.c)
    out[0] = base - ry + rz
    out[1] = base + rx - rz
    out[2] = base + ry + rz
    out[3] = base - rx - rz
    saturated = False
    for i in range(4):
        if out[i] > k.f_max:
            out[i] = k.f_max
            saturated = True
        elif out[i] < k.f_min:
            out[i] = k.f_min
            saturated = True
    return saturated


@numba.njit(cache=True)
def control_law(
    state: np.ndarray,
    pos_sp_m: np.ndarray,
    vel_sp_mps: np.ndarray,
    yaw_sp_ned_rad: float,
    gains_pos: np.ndarray,
    gains_att: np.ndarray,
    max_tilt_rad: float,
    min_vertical_accel_mps2: float,
    k: PhysicsConstants,
    out: np.ndarray,
) -> None:
    """One controller update; writes rotor thrusts and internals into ``out`` (OUT_* layout).

    Parameters
    ----------
    state : (12,) paper-frame state (see :mod:`plant_sim.dynamics`).
    pos_sp_m : (3,) paper-frame position target; NaN on an axis leaves it uncontrolled.
    vel_sp_mps : (3,) paper-frame velocity target (feed-forward); NaN means 0.
    yaw_sp_ned_rad : MAVLink NED heading to hold.
    gains_pos, gains_att : (3, 2) per-axis ``[k_angle_or_pos, k_rate]`` from the LQ design.
    """
    phi, theta, psi = state[6], state[7], state[8]
    dphi, dtheta, dpsi = state[9], state[10], state[11]
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)

    # ---- position subsystem: LQ tracker on ξ̈ = a (Eq. 22 with x_d = [y_d, 0], u_d = 0)
    a_des = np.empty(3)
    for i in range(3):
        e = 0.0 if math.isnan(pos_sp_m[i]) else state[i] - pos_sp_m[i]
        v_d = 0.0 if math.isnan(vel_sp_mps[i]) else vel_sp_mps[i]
        a_des[i] = -gains_pos[i, 0] * e - gains_pos[i, 1] * (state[3 + i] - v_d)

    # feedback linearization of Eq. (12): add back G and (1/m) R K_t Rᵀ ξ̇
    r00, r01, r02 = ct * cp, -ct * sp, st
    r10, r11, r12 = sf * st * cp + cf * sp, -sf * st * sp + cf * cp, -sf * ct
    r20, r21, r22 = -cf * st * cp + sf * sp, cf * st * sp + sf * cp, cf * ct
    vx, vy, vz = state[3], state[4], state[5]
    fbx = k.ktx * (r00 * vx + r10 * vy + r20 * vz)
    fby = k.kty * (r01 * vx + r11 * vy + r21 * vz)
    fbz = k.ktz * (r02 * vx + r12 * vy + r22 * vz)
    ax = a_des[0] + (r00 * fbx + r01 * fby + r02 * fbz) / k.m
    ay = a_des[1] + (r10 * fbx + r11 * fby + r12 * fbz) / k.m
    az = a_des[2] + (r20 * fbx + r21 * fby + r22 * fbz) / k.m + k.g
    az = max(az, min_vertical_accel_mps2)

    # virtual inputs from the thrust direction [sθ, −sφ cθ, cφ cθ] ∥ a
    phi_d = math.atan2(-ay, az)
    theta_d = math.atan2(ax, math.sqrt(ay * ay + az * az))
    tilt_sat = False
    if abs(phi_d) > max_tilt_rad:
        phi_d = math.copysign(max_tilt_rad, phi_d)
        tilt_sat = True
    if abs(theta_d) > max_tilt_rad:
        theta_d = math.copysign(max_tilt_rad, theta_d)
        tilt_sat = True
    total = k.m * az / max(cf * ct, 0.5)
    psi_d = paper_yaw_for_ned_heading(yaw_sp_ned_rad, phi, theta)

    # ---- attitude subsystem: LQ tracker on φ̈ = v, then FL of Eq. (16)
    v0 = -gains_att[0, 0] * (phi - phi_d) - gains_att[0, 1] * dphi
    v1 = -gains_att[1, 0] * (theta - theta_d) - gains_att[1, 1] * dtheta
    v2 = -gains_att[2, 0] * _wrap_pi(psi - psi_d) - gains_att[2, 1] * dpsi
    p = ct * cp * dphi + sp * dtheta
    q = -ct * sp * dphi + cp * dtheta
    r = st * dphi + dpsi
    c0 = -st * cp * dtheta * dphi - ct * sp * dpsi * dphi + cp * dpsi * dtheta
    c1 = st * sp * dtheta * dphi - ct * cp * dpsi * dphi - sp * dpsi * dtheta
    c2 = ct * dtheta * dphi
    # Ω̇ wanted = R_r v + Ṙ_r φ̇
    wd0 = ct * cp * v0 + sp * v1 + c0
    wd1 = -ct * sp * v0 + cp * v1 + c1
    wd2 = st * v0 + v2 + c2
    hx, hy, hz = k.Jx * p, k.Jy * q, k.Jz * r
    tau_x = k.Jx * wd0 + k.krx * p + (q * hz - r * hy)
    tau_y = k.Jy * wd1 + k.kry * q + (r * hx - p * hz)
    tau_z = k.Jz * wd2 + k.krz * r + (p * hy - q * hx)

    rotor_sat = mix(total, tau_x, tau_y, tau_z, k, out)
    out[OUT_PHI_D] = phi_d
    out[OUT_THETA_D] = theta_d
    out[OUT_PSI_D] = psi_d
    out[OUT_TOTAL_THRUST] = total
    out[OUT_TILT_SAT] = 1.0 if tilt_sat else 0.0
    out[OUT_ROTOR_SAT] = 1.0 if rotor_sat else 0.0
