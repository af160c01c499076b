"""Geometry for drawing what the companion sees: pure numpy, no viewer, no I/O.

Everything is LOCAL_NED [m] unless a name says otherwise. Used by
:mod:`companion.viz.rerun_log`; tested against closed forms in ``tests/test_view_units.py``.
"""

from __future__ import annotations

import math

import numpy as np

from protocols.camera import StereoIntrinsics

__all__ = [
    "CLASS_NEAR",
    "CLASS_UNKNOWN",
    "CLASS_VALID",
    "cone_lines_ned_m",
    "depth_classes",
    "near_points_ned_m",
    "velocity_in_cone",
]

CLASS_VALID = 0  # matched, farther than the threshold
CLASS_NEAR = 1  # matched, nearer than the detection threshold: obstacle pixel
CLASS_UNKNOWN = 2  # unmatched (NaN): never free


def depth_classes(depth_m: np.ndarray, threshold_m: float) -> np.ndarray:
    """uint8 image: :data:`CLASS_NEAR` where depth < threshold, :data:`CLASS_UNKNOWN` where
    the depth is NaN (no match), :data:`CLASS_VALID` elsewhere (+inf: beyond range)."""
    d = np.asarray(depth_m)
    out = np.zeros(d.shape, dtype=np.uint8)
    with np.errstate(invalid="ignore"):
        out[d < threshold_m] = CLASS_NEAR
    out[np.isnan(d)] = CLASS_UNKNOWN
    return out


def near_points_ned_m(
    depth_m: np.ndarray,
    threshold_m: float,
    intrinsics: StereoIntrinsics,
    pos_ned_m,
    R_ned_from_frd,
    *,
    stride_px: int = 2,
) -> np.ndarray:
    """Obstacle pixels (depth < threshold) back-projected to NED, every ``stride_px``-th
    row and column; shape (n, 3). The left camera's optical frame (x right, y down, z
    forward) is body FRD (forward = z, right = x, down = y), offset by half the baseline
    to the left."""
    d = np.asarray(depth_m)[::stride_px, ::stride_px]
    with np.errstate(invalid="ignore"):
        v, u = np.nonzero(d < threshold_m)
    z = d[v, u].astype(float)
    u_px = u * stride_px
    v_px = v * stride_px
    x_right = (u_px - intrinsics.cx_px) * z / intrinsics.fx_px
    y_down = (v_px - intrinsics.cy_px) * z / intrinsics.fy_px
    frd = np.stack([z, x_right - intrinsics.baseline_m / 2.0, y_down], axis=-1)
    R = np.asarray(R_ned_from_frd, dtype=float)
    return np.asarray(pos_ned_m, dtype=float) + frd @ R.T


def _perpendicular_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def cone_lines_ned_m(
    apex_ned_m, center_ned_m, radius_m: float, *, n_circle: int = 32, n_rays: int = 8
) -> list[np.ndarray]:
    """The collision cone of a sphere seen from ``apex_ned_m``, as line strips.

    The cone is tangent to the sphere along a circle (paper Fig. 5): with ``d`` the
    distance apex → centre and ``r`` the radius, the circle lies ``d − r²/d`` from the apex
    along the axis with radius ``r·√(d² − r²)/d``. Returns the circle (closed) followed by
    ``n_rays`` generatrices apex → circle; empty when the apex is inside the sphere (no
    cone exists).
    """
    apex = np.asarray(apex_ned_m, dtype=float)
    c = np.asarray(center_ned_m, dtype=float)
    d = float(np.linalg.norm(c - apex))
    r = float(radius_m)
    if not (d > r > 0.0):
        return []
    axis = (c - apex) / d
    along = d - r * r / d
    rho = r * math.sqrt(d * d - r * r) / d
    e1, e2 = _perpendicular_basis(axis)
    centre = apex + axis * along
    ang = np.linspace(0.0, 2.0 * math.pi, n_circle + 1)
    circle = centre + rho * (np.outer(np.cos(ang), e1) + np.outer(np.sin(ang), e2))
    lines = [circle]
    for k in range(n_rays):
        a = 2.0 * math.pi * k / n_rays
        lines.append(np.stack([apex, centre + rho * (math.cos(a) * e1 + math.sin(a) * e2)]))
    return lines


def velocity_in_cone(apex_ned_m, vel_ned_mps, center_ned_m, radius_m: float) -> bool:
    """Is the velocity inside the collision cone (the paper's "critical" condition)?"""
    v = np.asarray(vel_ned_mps, dtype=float)
    rel = np.asarray(center_ned_m, dtype=float) - np.asarray(apex_ned_m, dtype=float)
    d = float(np.linalg.norm(rel))
    speed = float(np.linalg.norm(v))
    if d <= radius_m:
        return True
    if speed == 0.0:
        return False
    cos_angle = float(np.dot(v, rel)) / (speed * d)
    return cos_angle > math.sqrt(1.0 - (radius_m / d) ** 2)
