"""Frame conventions: the paper's z-up inertial frame and 1-2-3 Euler angles ↔ MAVLink NED/FRD.

The paper (Park & Kim, §2, Eq. 4) uses an inertial frame with z up, a body frame with
z up (thrust along +z_body) and 1-2-3 Euler angles, ``R = Rx(φ) Ry(θ) Rz(ψ)`` (body →
inertial). Every interface outside the plant's dynamics uses MAVLink LOCAL_NED (x north,
y east, z down) and FRD body axes with 3-2-1 Euler angles, ``R = Rz(yaw) Ry(pitch)
Rx(roll)`` (body FRD → NED).

The two are related by ``T = diag(1, -1, -1)``: ``p_ned = T p_paper`` and
``R_ned = T R_paper T``. Conversions between Euler conventions always go through the
rotation matrix; nothing here flips angle signs by hand.
"""

from __future__ import annotations

import math

import numpy as np

#: Unit quaternion (w, x, y, z).
Quat = tuple[float, float, float, float]

__all__ = [
    "T_PAPER_NED",
    "Quat",
    "euler123_from_rotation",
    "euler321_from_rotation",
    "mavlink_euler_from_paper_euler",
    "ned_from_paper",
    "paper_euler_from_mavlink_euler",
    "paper_from_ned",
    "quat_from_euler321",
    "quat_slerp",
    "rotation_123",
    "rotation_321",
    "rotation_from_quat",
    "rotation_ned_from_paper",
    "rx",
    "ry",
    "rz",
]

#: Change of basis between the paper's z-up frame and NED (its own inverse).
T_PAPER_NED = np.diag([1.0, -1.0, -1.0])


def rx(angle_rad: float) -> np.ndarray:
    """Rotation about x by ``angle_rad`` (active, right-handed)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def ry(angle_rad: float) -> np.ndarray:
    """Rotation about y by ``angle_rad`` (active, right-handed)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rz(angle_rad: float) -> np.ndarray:
    """Rotation about z by ``angle_rad`` (active, right-handed)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_123(phi_rad: float, theta_rad: float, psi_rad: float) -> np.ndarray:
    """Paper Eq. (4): body → inertial rotation ``Rx(φ) Ry(θ) Rz(ψ)`` (z-up frames)."""
    return rx(phi_rad) @ ry(theta_rad) @ rz(psi_rad)


def euler123_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`rotation_123`: (φ, θ, ψ) in rad, θ in [-π/2, π/2].

    From Eq. (4): ``R[0,2] = sθ``, ``R[1,2] = -sφ cθ``, ``R[2,2] = cφ cθ``,
    ``R[0,0] = cθ cψ``, ``R[0,1] = -cθ sψ``.
    """
    theta = math.asin(max(-1.0, min(1.0, float(R[0, 2]))))
    phi = math.atan2(-float(R[1, 2]), float(R[2, 2]))
    psi = math.atan2(-float(R[0, 1]), float(R[0, 0]))
    return phi, theta, psi


def rotation_321(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """MAVLink attitude: body FRD → NED rotation ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    return rz(yaw_rad) @ ry(pitch_rad) @ rx(roll_rad)


def euler321_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`rotation_321`: (roll, pitch, yaw) in rad, pitch in [-π/2, π/2]."""
    pitch = -math.asin(max(-1.0, min(1.0, float(R[2, 0]))))
    roll = math.atan2(float(R[2, 1]), float(R[2, 2]))
    yaw = math.atan2(float(R[1, 0]), float(R[0, 0]))
    return roll, pitch, yaw


def ned_from_paper(vec_paper: np.ndarray) -> np.ndarray:
    """Map a vector (position, velocity, ...) from the paper's z-up frame to NED."""
    v = np.asarray(vec_paper, dtype=float)
    return v * np.array([1.0, -1.0, -1.0])


def paper_from_ned(vec_ned: np.ndarray) -> np.ndarray:
    """Map a vector from NED to the paper's z-up frame (the same involution)."""
    return ned_from_paper(vec_ned)


def rotation_ned_from_paper(R_paper: np.ndarray) -> np.ndarray:
    """Body FLU(z-up) → inertial z-up rotation to body FRD → NED: ``T R T``."""
    return T_PAPER_NED @ np.asarray(R_paper, dtype=float) @ T_PAPER_NED


def mavlink_euler_from_paper_euler(
    phi_rad: float, theta_rad: float, psi_rad: float
) -> tuple[float, float, float]:
    """Paper 1-2-3 angles (z-up) → MAVLink (roll, pitch, yaw) 3-2-1 in NED/FRD."""
    R_ned = rotation_ned_from_paper(rotation_123(phi_rad, theta_rad, psi_rad))
    return euler321_from_rotation(R_ned)


def paper_euler_from_mavlink_euler(
    roll_rad: float, pitch_rad: float, yaw_rad: float
) -> tuple[float, float, float]:
    """MAVLink (roll, pitch, yaw) 3-2-1 in NED/FRD → paper 1-2-3 angles (z-up)."""
    R_paper = rotation_ned_from_paper(rotation_321(roll_rad, pitch_rad, yaw_rad))  # T = T⁻¹
    return euler123_from_rotation(R_paper)


def quat_from_euler321(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Quat:
    """Unit quaternion of ``Rz(yaw) Ry(pitch) Rx(roll)`` (MAVLink ATTITUDE)."""
    cr, sr = math.cos(roll_rad / 2), math.sin(roll_rad / 2)
    cp, sp = math.cos(pitch_rad / 2), math.sin(pitch_rad / 2)
    cy, sy = math.cos(yaw_rad / 2), math.sin(yaw_rad / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def rotation_from_quat(q: Quat) -> np.ndarray:
    """Rotation matrix (body → NED) of a unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_slerp(q0: Quat, q1: Quat, u: float) -> Quat:
    """Spherical linear interpolation, ``u`` in [0, 1], along the shorter arc."""
    dot = sum(a * b for a, b in zip(q0, q1, strict=True))
    if dot < 0.0:
        q1 = (-q1[0], -q1[1], -q1[2], -q1[3])
        dot = -dot
    if dot > 0.9995:  # nearly parallel: normalised lerp is exact to 1e-7
        q = tuple(a + u * (b - a) for a, b in zip(q0, q1, strict=True))
    else:
        theta = math.acos(min(1.0, dot))
        s0 = math.sin((1 - u) * theta) / math.sin(theta)
        s1 = math.sin(u * theta) / math.sin(theta)
        q = tuple(s0 * a + s1 * b for a, b in zip(q0, q1, strict=True))
    n = math.sqrt(sum(c * c for c in q))
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)
