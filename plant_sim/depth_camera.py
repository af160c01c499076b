"""A RealSense-like depth camera: the renderer's true depth with the errors such cameras make.

plant-sim publishes depth frames (``[camera] encoding = "depth16"``) made from the left
eye's exact ray-cast depth (:meth:`StereoCameraRenderer.render_depth
<plant_sim.stereo_camera.StereoCameraRenderer.render_depth>`) by :func:`depth16_from_truth`:

* **z²-proportional error.** An active stereo camera's error is a disparity error of about
  ``subpixel_rms_px`` (Intel quotes 0.08 px for D4xx), so the measured depth is
  ``f·b / (f·b / z + subpixel_rms_px · n)`` with ``n`` standard normal per pixel, an RMS
  depth error of ``z² · subpixel_rms_px / (f·b)`` to first order (Intel, "Tuning depth
  cameras for best performance"; the formula ``companion.depth_camera`` assumes).
* **Holes at depth edges.** Where neighbouring depths differ by more than ``edge_rel_step``
  (or one of them has no surface) the matcher's window straddles two surfaces; the camera
  leaves those pixels, and ``edge_hole_px`` around them, without data (0), where a real
  RealSense leaves holes or "flying pixels" (which its own filters remove).
* **Invalid beyond range and nearer than the minimum range**, and in the **left band** the
  right imager cannot see (column ``x`` < disparity ``f·b / z``): 0, as RealSense reports.
  The sky has no surface: 0.

Pure: a function of the truth, the intrinsics and a seed (the frame's sequence).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from protocols.camera import StereoIntrinsics
from protocols.config import check_numbers
from protocols.stereo_frame import DEPTH16_SCALE_RANGE_M, DepthFrame, PixelEncoding

__all__ = ["CameraEncoding", "DepthNoiseParams", "depth16_from_truth", "depth_frame"]


@dataclass(frozen=True)
class DepthNoiseParams:
    """The simulated depth camera's errors (module docstring); defaults RealSense-like.

    Attributes
    ----------
    subpixel_rms_px : float
        RMS disparity error [px] (D4xx: 0.08); 0 gives the exact depth, quantised.
    min_range_m : float
        Nearest depth reported [m]. Default 1.0 m: the paper's 0.2 m baseline at 320 px
        (``f·b`` = 71.9 m·px) with a 72 px disparity search, a RealSense-like 22 % of the
        width (a D435 searches 126 of 848 px). The companion's
        ``[perception.depth_camera] min_range_m`` should say the same.
    max_range_m : float
        Farthest depth reported [m]; beyond it 0.
    edge_rel_step : float
        A relative depth step between 4-neighbours above this is a depth edge.
    edge_hole_px : int
        Pixels around a depth edge left without data (0: only the edge pixels).
    depth_scale_m : float
        Metres per DEPTH16 unit (RealSense's default depth units: 1 mm).
    """

    subpixel_rms_px: float = 0.08
    min_range_m: float = 1.0
    max_range_m: float = 30.0
    edge_rel_step: float = 0.05
    edge_hole_px: int = 1
    depth_scale_m: float = 0.001

    def __post_init__(self) -> None:
        check_numbers(self, ("subpixel_rms_px", "edge_hole_px"))
        check_numbers(
            self, ("min_range_m", "max_range_m", "edge_rel_step", "depth_scale_m"), positive=True
        )
        if self.max_range_m <= self.min_range_m:
            raise ValueError(
                f"max_range_m {self.max_range_m} must be above min_range_m {self.min_range_m}"
            )
        if not isinstance(self.edge_hole_px, int):
            raise ValueError(f"edge_hole_px must be an integer, got {self.edge_hole_px!r}")
        low, high = DEPTH16_SCALE_RANGE_M
        if not low <= self.depth_scale_m <= high:
            raise ValueError(f"depth_scale_m must be in [{low}, {high}], got {self.depth_scale_m}")
        if self.max_range_m / self.depth_scale_m > 65535:
            raise ValueError(
                f"max_range_m {self.max_range_m} does not fit 16 bits of {self.depth_scale_m} m"
            )


def _edges(depth_m: np.ndarray, rel_step: float) -> np.ndarray:
    """Pixels with a 4-neighbour whose depth differs by more than ``rel_step`` of the nearer,
    or where one of the two has a surface and the other none (inf/NaN)."""
    z = np.where(np.isfinite(depth_m) & (depth_m > 0.0), depth_m, np.inf)
    edge = np.zeros(z.shape, bool)
    for axis in (0, 1):
        a = z[:-1, :] if axis == 0 else z[:, :-1]
        b = z[1:, :] if axis == 0 else z[:, 1:]
        near = np.minimum(a, b)
        far = np.maximum(a, b)
        with np.errstate(invalid="ignore"):
            step = np.isfinite(near) & ~(far - near <= rel_step * near)
        if axis == 0:
            edge[:-1, :] |= step
            edge[1:, :] |= step
        else:
            edge[:, :-1] |= step
            edge[:, 1:] |= step
    return edge


def _dilate(mask: np.ndarray, radius_px: int) -> np.ndarray:
    """``mask`` grown by ``radius_px`` in the 8-neighbourhood (a square window)."""
    out = mask.copy()
    height, width = mask.shape
    for dy in range(-radius_px, radius_px + 1):
        for dx in range(-radius_px, radius_px + 1):
            src = mask[max(0, -dy) : height - max(0, dy), max(0, -dx) : width - max(0, dx)]
            out[max(0, dy) : height - max(0, -dy), max(0, dx) : width - max(0, -dx)] |= src
    return out


def depth16_from_truth(
    depth_true_m: np.ndarray,
    intrinsics: StereoIntrinsics,
    params: DepthNoiseParams,
    seed: int,
) -> np.ndarray:
    """The DEPTH16 plane (uint16 units of ``params.depth_scale_m``, 0 = no data) a
    RealSense-like camera reports for the true depth ``depth_true_m`` (module docstring).

    Parameters
    ----------
    depth_true_m : numpy.ndarray, shape (H, W)
        True depth along the left imager's optical axis [m]; inf or NaN: no surface.
    intrinsics : StereoIntrinsics
        The left imager and the baseline (``f·b`` scales the error and the left band).
    params : DepthNoiseParams
    seed : int
        Noise seed (the frame's sequence): the same inputs give the same plane.
    """
    z = np.asarray(depth_true_m, dtype=np.float64)
    fb = intrinsics.focal_baseline_m_px
    valid = np.isfinite(z) & (z >= params.min_range_m) & (z <= params.max_range_m)
    disparity_px = np.where(valid, fb / np.where(valid, z, 1.0), 0.0)
    columns = np.arange(z.shape[1])[None, :]
    valid &= disparity_px <= columns  # the right imager sees the surface
    if params.subpixel_rms_px > 0.0:
        rng = np.random.default_rng(seed)
        disparity_px = disparity_px + params.subpixel_rms_px * rng.standard_normal(z.shape)
        valid &= disparity_px > 0.0
    holes = _edges(z, params.edge_rel_step)
    if params.edge_hole_px > 0:
        holes = _dilate(holes, params.edge_hole_px)
    valid &= ~holes
    measured_m = np.where(valid, fb / np.where(valid, disparity_px, 1.0), 0.0)
    valid &= (measured_m >= params.min_range_m) & (measured_m <= params.max_range_m)
    units = np.rint(np.where(valid, measured_m, 0.0) / params.depth_scale_m)
    return np.clip(units, 0, 65535).astype(np.uint16)


class CameraEncoding(enum.Enum):
    """What plant-sim's camera publishes (``[camera] encoding``)."""

    MONO8 = "mono8"  # a rectified stereo pair; the companion matches it
    DEPTH16 = "depth16"  # a RealSense-like depth camera: millimetres, 0 = no data
    DEPTH32F = "depth32f"  # the same depth as float32 metres, NaN = no data


def depth_frame(
    sequence: int,
    capture_ns: int,
    intrinsics: StereoIntrinsics,
    depth_true_m: np.ndarray,
    left: np.ndarray | None,
    params: DepthNoiseParams,
    encoding: CameraEncoding = CameraEncoding.DEPTH16,
) -> DepthFrame:
    """The depth frame the simulated depth camera publishes for one view: the plane of
    :func:`depth16_from_truth` (seeded with ``sequence``), as DEPTH16 or DEPTH32F, with the
    left image for the viewer."""
    plane = depth16_from_truth(depth_true_m, intrinsics, params, sequence)
    if encoding is CameraEncoding.DEPTH16:
        return DepthFrame(
            sequence,
            capture_ns,
            intrinsics,
            plane,
            PixelEncoding.DEPTH16,
            params.depth_scale_m,
            left,
        )
    if encoding is CameraEncoding.DEPTH32F:
        metres = plane.astype(np.float32) * np.float32(params.depth_scale_m)
        metres[plane == 0] = np.nan
        return DepthFrame(
            sequence, capture_ns, intrinsics, metres, PixelEncoding.DEPTH32F, 1.0, left
        )
    raise ValueError(f"not a depth encoding: {encoding!r}")
