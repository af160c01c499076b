"""The paper's z-up inertial frame and 1-2-3 Euler angles ↔ MAVLink NED/FRD (plant-sim only).

The paper (Park & Kim, §2, Eq. 4) uses an inertial frame with z up, a body frame with
z up (thrust along +z_body) and 1-2-3 Euler angles, ``R = Rx(φ) Ry(θ) Rz(ψ)`` (body →
inertial). The two are related by ``T = diag(1, -1, -1)``: ``p_ned = T p_paper`` and
``R_ned = T R_paper T``. Conversions between Euler conventions always go through the
rotation matrix; nothing here flips angle signs by hand. Only plant-sim's dynamics work in
this frame; everything on the wire is NED (:mod:`protocols.frames`).
"""

from __future__ import annotations

import math

import numpy as np

from protocols.frames import euler321_from_rotation, rotation_321, rx, ry, rz

__all__ = [
    "T_PAPER_NED",
    "euler123_from_rotation",
    "mavlink_euler_from_paper_euler",
    "ned_from_paper",
    "paper_euler_from_mavlink_euler",
    "paper_from_ned",
    "rotation_123",
    "rotation_ned_from_paper",
]

T_PAPER_NED = np.diag([1.0, -1.0, -1.0])


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
