"""MAVLink's frame conventions: LOCAL_NED, FRD body axes, 3-2-1 Euler angles, quaternions.

Every interface outside the plant's dynamics uses MAVLink LOCAL_NED (x north, y east,
z down) and FRD body axes with 3-2-1 Euler angles, ``R = Rz(yaw) Ry(pitch) Rx(roll)``
(body FRD → NED), as ATTITUDE carries them. Conversions go through the rotation matrix;
nothing here flips angle signs by hand. The paper's z-up frame, which only plant-sim's
dynamics uses, is :mod:`plant_sim.paper_frames`.
"""

from __future__ import annotations

import math

import numpy as np

#: Unit quaternion (w, x, y, z).
Quat = tuple[float, float, float, float]

__all__ = [
    "Quat",
    "euler321_from_rotation",
    "quat_from_euler321",
    "quat_slerp",
    "rotation_321",
    "rotation_from_quat",
    "rx",
    "ry",
    "rz",
]

#: Change of basis between the paper's z-up frame and NED (its own inverse).


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


def rotation_321(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """MAVLink attitude: body FRD → NED rotation ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    return rz(yaw_rad) @ ry(pitch_rad) @ rx(roll_rad)


def euler321_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`rotation_321`: (roll, pitch, yaw) in rad, pitch in [-π/2, π/2]."""
    pitch = -math.asin(max(-1.0, min(1.0, float(R[2, 0]))))
    roll = math.atan2(float(R[2, 1]), float(R[2, 2]))
    yaw = math.atan2(float(R[1, 0]), float(R[0, 0]))
    return roll, pitch, yaw


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
