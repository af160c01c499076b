"""Pinhole stereo camera model, disparity ↔ depth (paper Eq. 24–27, Table 1) and camera frames.

Frames
------
* Camera optical frame (per eye): x right, y down, z forward (along the optical axis), metres.
* Body FRD: x forward, y right, z down. The camera looks along body +x, so
  ``v_frd = R_FRD_FROM_CAM @ v_cam`` with ``R_FRD_FROM_CAM = [[0,0,1],[1,0,0],[0,1,0]]``.
* The rectified pair sits on the body y axis: the left eye (the reference image) at body
  ``y = -b/2``, the right eye at ``y = +b/2`` (paper Fig. 3, Eq. 24–25).
* NED: ``p_ned = pos_ned_m + R_ned_from_frd @ p_frd`` (MAVLink LOCAL_NED, see
  :mod:`protocols.frames`).

Pixels
------
Pixel centres sit at integer ``(u, v)`` (u = column, v = row). The image spans
``[-0.5, W - 0.5]``, so the principal point of a symmetric field of view is
``((W - 1) / 2, (H - 1) / 2)`` and the focal length follows from the FOV:
``fx = (W / 2) / tan(hfov / 2)`` (≈ 359.37 px at 320 px and 48°, so
``f·b ≈ 71.87 m·px``, Table 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "R_FRD_FROM_CAM",
    "CameraModel",
    "StereoIntrinsics",
    "backproject_px",
    "depth_from_disparity",
    "disparity_from_depth",
    "eye_offset_frd_m",
    "points_cam_from_ned",
    "points_frd_from_cam",
    "points_ned_from_cam",
    "project_cam",
]

#: Camera optical frame (x right, y down, z forward) → body FRD.
R_FRD_FROM_CAM = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
R_FRD_FROM_CAM.flags.writeable = False


def _check_finite_positive(name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")


@dataclass(frozen=True)
class StereoIntrinsics:
    """Intrinsics of a rectified stereo pair, as carried by every stereo frame.

    Attributes
    ----------
    width_px, height_px : int
        Image size [px].
    fx_px, fy_px : float
        Focal lengths [px].
    cx_px, cy_px : float
        Principal point [px] (pixel centres at integers).
    baseline_m : float
        Distance between the two optical centres [m].
    """

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    baseline_m: float

    def __post_init__(self) -> None:
        for name in ("width_px", "height_px"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value > 0):
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        for name in ("fx_px", "fy_px", "baseline_m"):
            _check_finite_positive(name, getattr(self, name))
        for name in ("cx_px", "cy_px"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value!r}")

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view [deg]: ``2 atan((W / 2) / fx)`` (inverse of CameraModel)."""
        return math.degrees(2.0 * math.atan2(self.width_px / 2.0, self.fx_px))

    @property
    def focal_baseline_m_px(self) -> float:
        """``fx · b`` [m·px]: depth [m] = this / disparity [px] (Eq. 27)."""
        return self.fx_px * self.baseline_m

    def K(self) -> np.ndarray:
        """3×3 intrinsic matrix of either eye."""
        return np.array(
            [[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]]
        )


@dataclass(frozen=True)
class CameraModel:
    """Stereo camera from resolution, field of view and baseline (paper Table 1 text).

    Attributes
    ----------
    width_px, height_px : int
        Image size [px]; default 320 × 240.
    hfov_deg, vfov_deg : float
        Full horizontal / vertical field of view [deg]; default 48° × 36.9°.
    baseline_m : float
        Stereo baseline [m]; default 0.2.
    """

    width_px: int = 320
    height_px: int = 240
    hfov_deg: float = 48.0
    vfov_deg: float = 36.9
    baseline_m: float = 0.2

    def __post_init__(self) -> None:
        for name in ("width_px", "height_px"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value > 0):
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        for name in ("hfov_deg", "vfov_deg"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 < value < 180.0):
                raise ValueError(f"{name} must be in (0, 180) deg, got {value!r}")
        _check_finite_positive("baseline_m", self.baseline_m)

    @property
    def fx_px(self) -> float:
        """Horizontal focal length [px]: ``(W / 2) / tan(hfov / 2)``."""
        return (self.width_px / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def fy_px(self) -> float:
        """Vertical focal length [px]: ``(H / 2) / tan(vfov / 2)``."""
        return (self.height_px / 2.0) / math.tan(math.radians(self.vfov_deg) / 2.0)

    @property
    def cx_px(self) -> float:
        """Principal point column [px]: ``(W - 1) / 2``."""
        return (self.width_px - 1) / 2.0

    @property
    def cy_px(self) -> float:
        """Principal point row [px]: ``(H - 1) / 2``."""
        return (self.height_px - 1) / 2.0

    @property
    def intrinsics(self) -> StereoIntrinsics:
        """The derived :class:`StereoIntrinsics` (what a stereo frame carries)."""
        return StereoIntrinsics(
            width_px=self.width_px,
            height_px=self.height_px,
            fx_px=self.fx_px,
            fy_px=self.fy_px,
            cx_px=self.cx_px,
            cy_px=self.cy_px,
            baseline_m=self.baseline_m,
        )


def depth_from_disparity(disparity_px, intrinsics: StereoIntrinsics) -> np.ndarray:
    """Eq. (27): depth ``z = f·b / (u_L − u_R)`` [m]; ``inf`` where disparity ≤ 0.

    Parameters
    ----------
    disparity_px : array_like
        Disparity ``u_L − u_R`` [px] (left image is the reference).
    intrinsics : StereoIntrinsics
        Supplies ``fx`` and the baseline.

    Returns
    -------
    numpy.ndarray
        Depth along the optical axis [m], same shape as ``disparity_px``.
    """
    d = np.asarray(disparity_px, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = intrinsics.focal_baseline_m_px / d
    return np.where(d > 0.0, z, np.inf)


def disparity_from_depth(depth_m, intrinsics: StereoIntrinsics) -> np.ndarray:
    """Eq. (26): disparity ``f·b / z`` [px]; 0 for infinite depth."""
    z = np.asarray(depth_m, dtype=float)
    with np.errstate(divide="ignore"):
        return intrinsics.focal_baseline_m_px / z


def backproject_px(u_px, v_px, depth_m, intrinsics: StereoIntrinsics) -> np.ndarray:
    """Pixels with depth → points in the (left) camera optical frame, shape (..., 3) [m]."""
    z = np.asarray(depth_m, dtype=float)
    x = (np.asarray(u_px, dtype=float) - intrinsics.cx_px) * z / intrinsics.fx_px
    y = (np.asarray(v_px, dtype=float) - intrinsics.cy_px) * z / intrinsics.fy_px
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def project_cam(points_cam_m, intrinsics: StereoIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Points in a camera optical frame (..., 3) → pixel coordinates ``(u_px, v_px)``."""
    p = np.asarray(points_cam_m, dtype=float)
    u = intrinsics.cx_px + intrinsics.fx_px * p[..., 0] / p[..., 2]
    v = intrinsics.cy_px + intrinsics.fy_px * p[..., 1] / p[..., 2]
    return u, v


def eye_offset_frd_m(baseline_m: float, eye: str = "left") -> np.ndarray:
    """Optical centre of ``eye`` ('left' or 'right') in body FRD [m]: ``(0, ∓b/2, 0)``."""
    if eye == "left":
        return np.array([0.0, -baseline_m / 2.0, 0.0])
    if eye == "right":
        return np.array([0.0, baseline_m / 2.0, 0.0])
    raise ValueError(f"eye must be 'left' or 'right', got {eye!r}")


def points_frd_from_cam(points_cam_m, baseline_m: float, eye: str = "left") -> np.ndarray:
    """Points (..., 3) in an eye's optical frame → body FRD [m]."""
    p = np.asarray(points_cam_m, dtype=float)
    return p @ R_FRD_FROM_CAM.T + eye_offset_frd_m(baseline_m, eye)


def points_ned_from_cam(
    points_cam_m,
    pos_ned_m,
    R_ned_from_frd,
    baseline_m: float,
    eye: str = "left",
) -> np.ndarray:
    """Points (..., 3) in an eye's optical frame → LOCAL_NED [m] for the given vehicle pose.

    Parameters
    ----------
    points_cam_m : array_like, shape (..., 3)
        Points in the optical frame of ``eye`` (x right, y down, z forward).
    pos_ned_m : array_like, shape (3,)
        Vehicle (body origin) position in NED at the frame's capture time.
    R_ned_from_frd : array_like, shape (3, 3)
        Body FRD → NED rotation at the capture time (e.g. :func:`protocols.frames.rotation_321`).
    baseline_m : float
        Stereo baseline.
    eye : {'left', 'right'}
        Which optical frame ``points_cam_m`` is expressed in.
    """
    R = np.asarray(R_ned_from_frd, dtype=float)
    p_frd = points_frd_from_cam(points_cam_m, baseline_m, eye)
    return p_frd @ R.T + np.asarray(pos_ned_m, dtype=float)


def points_cam_from_ned(
    points_ned_m,
    pos_ned_m,
    R_ned_from_frd,
    baseline_m: float,
    eye: str = "left",
) -> np.ndarray:
    """Inverse of :func:`points_ned_from_cam`: NED points (..., 3) → an eye's optical frame."""
    R = np.asarray(R_ned_from_frd, dtype=float)
    p_frd = (np.asarray(points_ned_m, dtype=float) - np.asarray(pos_ned_m, dtype=float)) @ R
    return (p_frd - eye_offset_frd_m(baseline_m, eye)) @ R_FRD_FROM_CAM
