"""Flight controller of §3: feedback linearization + LQ tracker, position and attitude loops.

Position subsystem: the translational dynamics of Eq. (12) are linearized by cancelling
gravity and the drag term, leaving ``ξ̈ = a`` per axis; the LQ tracker (gains of Eq. 34)
gives ``a``. The virtual inputs are the roll and pitch that point the thrust along ``a``,
taken in the frame of the commanded heading (what "roll" and "pitch" mean on the vehicle
and in MAVLink) and limited there to ±15° (§6.1) by shortening the horizontal
acceleration, its direction kept (:func:`limit_tilt`); the commanded attitude
``Rz(yaw) Ry(pitch) Rx(roll)`` is then expressed as the paper's 1-2-3 angles (φ_d, θ_d,
ψ_d) through the rotation matrix. (Clamping the paper's φ, θ directly would bound the tilt
about the inertial axes instead, letting a vehicle heading 45° tilt ~21° along its nose.)
Total thrust keeps the vertical channel exactly linearized with the *actual* attitude:
``U1 = m a_z / (cφ cθ)``.

Attitude subsystem: Eq. (16) is linearized by choosing the body torque
``T = J (R_r v + Ṙ_r φ̇) + K_r Ω + Ω × JΩ`` so that ``φ̈ = v``; the LQ tracker (gains of
Eq. 31) gives ``v``; the torques and total thrust become rotor thrusts by inverting
Eq. (14), clamped to the rotor limits.

Velocity-loop integrator (not in the paper; ArduCopter's, off by default): the LQ tracker
is a PD on position, so a steady disturbance (wind: the FL cancels the drag of the ground
velocity, not of the air velocity) leaves a constant offset ``d/k_p``. ArduCopter's
position controller (``AC_PosControl::update_xy_controller``) is a cascade, position P →
velocity PID → acceleration, whose velocity integrator (``PSC_VELXY_I``, default 1.0, its
sum limited to ``PSC_VELXY_IMAX``, default 1000 cm/s², as a 2-D vector: ``AC_PID_2D``)
removes that offset. The LQ tracker ``a = u_d − k_p e − k_d (v − v_d)`` is the same
cascade with a velocity target ``v_t = v_d − (k_p/k_d) e`` and velocity gain ``k_d``;
:func:`velocity_integrator` adds ``I``, ``İ = k_i (v_t − v)``, limited to ``imax`` and not
grown while the tilt is saturated (ArduCopter's ``limit`` flag). Closed loop per axis
(attitude lag neglected): ``s³ + k_d s² + (k_p + k_i) s + k_i k_p / k_d``. With the gains
zero (the paper flavour) the law is the paper's exactly.

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
    "limit_tilt",
    "mix",
    "velocity_integrator",
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
def mix(
    total_n: float, tau_x: float, tau_y: float, tau_z: float, k: PhysicsConstants, out: np.ndarray
) -> bool:
    """Invert Eq. (14) into rotor thrusts ``out[0:4]`` within the rotor limits.

    Yaw torque has the lowest priority, as in ArduCopter's mixer: when the exact inverse
    would push a rotor past a limit, the yaw part is scaled down until every rotor fits;
    only if thrust, roll and pitch alone do not fit are the rotors clamped. Returns True
    when anything was reduced or clamped. (A 1 rad heading error asks for ~2 N of
    differential thrust per rotor; a plain clamp would then spend the roll, pitch and
    thrust authority on yaw and the vehicle would sag.)
    """
    base = 0.25 * total_n
    rx = tau_x / (2.0 * k.d)
    ry = tau_y / (2.0 * k.d)
    rz = tau_z / (4.0 * k.c)
    out[0] = base - ry
    out[1] = base + rx
    out[2] = base + ry
    out[3] = base - rx
    saturated = False
    yaw_scale = 1.0
    for i in range(4):
        if out[i] > k.f_max or out[i] < k.f_min:
            yaw_scale = 0.0  # no room at all: clamp below
            break
        yaw_i = rz if i % 2 == 0 else -rz  # rotors 1, 3 (+), 2, 4 (-)
        if out[i] + yaw_i > k.f_max:
            yaw_scale = min(yaw_scale, (k.f_max - out[i]) / yaw_i)
        elif out[i] + yaw_i < k.f_min:
            yaw_scale = min(yaw_scale, (k.f_min - out[i]) / yaw_i)
    if yaw_scale < 1.0:
        saturated = True
    for i in range(4):
        out[i] += yaw_scale * (rz if i % 2 == 0 else -rz)
        if out[i] > k.f_max:
            out[i] = k.f_max
            saturated = True
        elif out[i] < k.f_min:
            out[i] = k.f_min
            saturated = True
    return saturated


@numba.njit(cache=True)
def _drag_lag_lead(axis: int, gains_att: np.ndarray, k: PhysicsConstants) -> float:
    """Gain on the horizontal acceleration feed-forward that makes the vehicle realize it.

    A horizontal acceleration is a tilt, and the tilt follows its command through the
    attitude loop ``k_p/(s² + k_d s + k_p)`` (Eq. 31), whose lag to a ramp is
    ``τ = k_d/k_p`` (0.89 s with the paper's gains). The feedback linearization cancels
    the drag ``(k_t/m)·v`` through the same loop, so while the vehicle accelerates at
    ``a`` the cancellation is ``(k_t/m)·τ·a`` short and a commanded ``u_d`` is realized
    at only ``1/(1 + (k_t/m)·τ)`` of itself (0.27 for Table 2's airframe): the position
    feedback makes up the rest from a tracking error, which is what carried the paper
    airframe ~0.2 m past a shaped target (issue 31). Commanding ``u_d·(1 + (k_t/m)·τ)``
    restores unit gain at low frequency (the realized acceleration then follows
    ``u_d`` through ``k_p(1 + cτ)/(s² + (k_d + c)s + k_p(1 + cτ))``, c = k_t/m; tested).
    Used only on a feed-forward (a shaped reference's acceleration), never on feedback.
    """
    if gains_att[axis, 0] <= 0.0:
        return 1.0
    drag_per_s = (k.ktx if axis == 0 else k.kty) / k.m
    return 1.0 + drag_per_s * gains_att[axis, 1] / gains_att[axis, 0]


#: The integrator holds its sum while the shaped reference accelerates faster than this
#: [m/s²]. The paper's attitude loop lags ~5x ArduCopter's (τ = k_d/k_p = 0.89 s, see
#: _drag_lag_lead), so while the reference speeds up the vehicle trails it by decimetres
#: ArduCopter's airframes do not, and integrating that lag wound the sum up: the fast
#: airframe then overshot its stated 3.5 m/s limit by 0.3 m/s (0.16 m/s at PSC_VELXY_I
#: 0.5). A steady disturbance (wind) is still integrated in cruise and in the hover, where
#: the reference's acceleration is zero.
_I_HOLD_ACCEL_MPS2 = 0.05


@numba.njit(cache=True)
def velocity_integrator(
    state: np.ndarray,
    pos_sp_m: np.ndarray,
    vel_sp_mps: np.ndarray,
    acc_sp_mps2: np.ndarray,
    gains_pos: np.ndarray,
    vel_i: np.ndarray,
    vel_i_gain: np.ndarray,
    vel_i_max: np.ndarray,
    dt_s: float,
    tilt_saturated: bool,
) -> None:
    """Advance the velocity-loop integrator ``vel_i`` (3,) [m/s²] by ``dt_s`` (see the module
    docstring). ``vel_i_gain`` and ``vel_i_max`` are ``[horizontal, vertical]`` [1/s², m/s²];
    the horizontal sum is limited as a vector. While ``tilt_saturated`` the horizontal sum
    may only shrink, and while the reference accelerates (``acc_sp_mps2`` above
    ``_I_HOLD_ACCEL_MPS2`` on an axis) that axis's sum is held (see below)."""
    new = np.zeros(3)
    for i in range(3):
        gain = vel_i_gain[0] if i < 2 else vel_i_gain[1]
        if gain <= 0.0 or math.isnan(pos_sp_m[i]) or gains_pos[i, 1] <= 0.0:
            new[i] = 0.0
            continue
        if not math.isnan(acc_sp_mps2[i]) and abs(acc_sp_mps2[i]) > _I_HOLD_ACCEL_MPS2:
            new[i] = vel_i[i]
            continue
        e = state[i] - pos_sp_m[i]
        v_d = 0.0 if math.isnan(vel_sp_mps[i]) else vel_sp_mps[i]
        v_target = v_d - gains_pos[i, 0] / gains_pos[i, 1] * e
        new[i] = vel_i[i] + gain * (v_target - state[3 + i]) * dt_s
    horizontal = math.sqrt(new[0] * new[0] + new[1] * new[1])
    if horizontal > vel_i_max[0]:
        new[0] *= vel_i_max[0] / horizontal
        new[1] *= vel_i_max[0] / horizontal
        horizontal = vel_i_max[0]
    if not tilt_saturated or horizontal <= math.sqrt(vel_i[0] * vel_i[0] + vel_i[1] * vel_i[1]):
        vel_i[0] = new[0]
        vel_i[1] = new[1]
    vel_i[2] = max(-vel_i_max[1], min(vel_i_max[1], new[2]))


@numba.njit(cache=True)
def _within_tilt(a_fwd: float, a_right: float, a_up: float, tan_max: float) -> bool:
    """Pitch ``atan(|a_fwd| / a_up)`` and roll ``atan(|a_right| / √(a_fwd² + a_up²))``
    (heading frame, ``a_up`` > 0) both within ``atan(tan_max)``."""
    lim = tan_max * a_up * (1.0 + 1e-12)
    return abs(a_fwd) <= lim and (
        a_right * a_right <= tan_max * tan_max * (a_fwd * a_fwd + a_up * a_up) * (1.0 + 1e-12)
    )


@numba.njit(cache=True)
def _tilt_scale(a_fwd: float, a_right: float, a_up: float, tan_max: float) -> float:
    """The largest factor ``s`` ≤ 1 that brings the horizontal acceleration (``a_fwd``,
    ``a_right``) within the tilt limit (:func:`_within_tilt`), its direction kept [-]."""
    scale = 1.0
    if abs(a_fwd) > tan_max * a_up:
        scale = tan_max * a_up / abs(a_fwd)
    excess = a_right * a_right - tan_max * tan_max * a_fwd * a_fwd
    if excess > 0.0:
        scale = min(scale, tan_max * a_up / math.sqrt(excess))
    return scale


@numba.njit(cache=True)
def limit_tilt(
    a_fwd: float, a_right: float, a_up: float, tan_max: float
) -> tuple[float, float, bool]:
    """Bring the horizontal acceleration (heading frame [m/s²], ``a_up`` > 0) within the
    roll and pitch limit ``atan(tan_max)`` by shortening it, its direction kept.

    The limit shortens what the position loop asks for; it never turns it. Clamping roll
    and pitch each on its own (the first version) pushed at heading ± 45° whenever both
    saturated, whatever the wanted direction: the paper airframe at its drag-limited top
    speed, heading 20° off its line, drifted 1.6 m off it; 45° off a steady target in the
    Monte Carlo's climb-105. ArduCopter limits the lean angle as a vector too
    (``limit_accel_xy`` in ``libraries/AP_Math/control.cpp``, a length limit).

    Returns ``(a_fwd, a_right, limited)``.
    """
    if _within_tilt(a_fwd, a_right, a_up, tan_max):
        return a_fwd, a_right, False
    s = _tilt_scale(a_fwd, a_right, a_up, tan_max)
    return a_fwd * s, a_right * s, True


@numba.njit(cache=True)
def control_law(
    state: np.ndarray,
    pos_sp_m: np.ndarray,
    vel_sp_mps: np.ndarray,
    acc_sp_mps2: np.ndarray,
    yaw_sp_ned_rad: float,
    gains_pos: np.ndarray,
    gains_att: np.ndarray,
    max_tilt_rad: float,
    min_vertical_accel_mps2: float,
    k: PhysicsConstants,
    out: np.ndarray,
    vel_i: np.ndarray,
) -> None:
    """One controller update; writes rotor thrusts and internals into ``out`` (OUT_* layout).

    Parameters
    ----------
    state : (12,) paper-frame state (see :mod:`plant_sim.dynamics`).
    pos_sp_m : (3,) paper-frame position target; NaN on an axis leaves it uncontrolled.
    vel_sp_mps : (3,) paper-frame velocity target (feed-forward); NaN means 0.
    acc_sp_mps2 : (3,) paper-frame acceleration feed-forward ``u_d`` of Eq. (22) (the
        second derivative of a shaped reference); NaN means 0. Its horizontal part is
        commanded through :func:`_drag_lag_lead`.
    yaw_sp_ned_rad : MAVLink NED heading to hold.
    gains_pos, gains_att : (3, 2) per-axis ``[k_angle_or_pos, k_rate]`` from the LQ design.
    vel_i : (3,) the velocity-loop integrator's sum [m/s², paper frame], added to the
        position loop's acceleration (:func:`velocity_integrator`; zeros: the paper's law).
    """
    phi, theta, psi = state[6], state[7], state[8]
    dphi, dtheta, dpsi = state[9], state[10], state[11]
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)

    # ---- position subsystem: LQ tracker on ξ̈ = a (Eq. 22, x_d = [y_d, ẏ_d], u_d = ÿ_d)
    a_des = np.empty(3)
    for i in range(3):
        e = 0.0 if math.isnan(pos_sp_m[i]) else state[i] - pos_sp_m[i]
        v_d = 0.0 if math.isnan(vel_sp_mps[i]) else vel_sp_mps[i]
        u_d = 0.0 if math.isnan(acc_sp_mps2[i]) else acc_sp_mps2[i]
        if i < 2:
            u_d *= _drag_lag_lead(i, gains_att, k)
        a_des[i] = u_d - gains_pos[i, 0] * e - gains_pos[i, 1] * (state[3 + i] - v_d)
        if vel_i[i] != 0.0 and not math.isnan(pos_sp_m[i]):
            a_des[i] += vel_i[i]

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

    # virtual inputs: roll and pitch of the thrust direction ∥ a in the frame of the
    # commanded heading (MAVLink 3-2-1 convention), limited there, then expressed as the
    # paper's 1-2-3 angles through the rotation matrix R_ned = Rz(yaw) Ry(pitch) Rx(roll)
    cy, sy = math.cos(yaw_sp_ned_rad), math.sin(yaw_sp_ned_rad)
    a_north, a_east, a_down = ax, -ay, -az
    a_fwd = cy * a_north + sy * a_east
    a_right = -sy * a_north + cy * a_east
    # the tilt limit shortens the acceleration asked for, its direction kept
    a_fwd, a_right, tilt_sat = limit_tilt(a_fwd, a_right, -a_down, math.tan(max_tilt_rad))
    # thrust direction in the heading frame is (−sθ cφ, sφ, −cθ cφ) for MAVLink (φ, θ)
    roll_d = math.atan2(a_right, math.sqrt(a_fwd * a_fwd + a_down * a_down))
    pitch_d = math.atan2(-a_fwd, -a_down)
    if abs(roll_d) > max_tilt_rad:
        roll_d = math.copysign(max_tilt_rad, roll_d)
        tilt_sat = True
    if abs(pitch_d) > max_tilt_rad:
        pitch_d = math.copysign(max_tilt_rad, pitch_d)
        tilt_sat = True
    cr, sr = math.cos(roll_d), math.sin(roll_d)
    cpt, spt = math.cos(pitch_d), math.sin(pitch_d)
    n00, n01, n02 = cy * cpt, cy * spt * sr - sy * cr, cy * spt * cr + sy * sr
    n12, n22 = sy * spt * cr - cy * sr, cpt * cr
    # R_paper = T R_ned T, T = diag(1, −1, −1); then the 1-2-3 angles of Eq. (4)
    phi_d = math.atan2(-n12, n22)
    theta_d = math.asin(max(-1.0, min(1.0, -n02)))
    psi_d = math.atan2(n01, n00)
    total = k.m * az / max(cf * ct, 0.5)

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
