"""A RealSense-like depth camera: the renderer's true depth with the errors such cameras make.

plant-sim publishes depth frames (``[camera] encoding = "depth16"``) made from the left
eye's exact ray-cast depth (:meth:`StereoCameraRenderer.render_depth
<plant_sim.stereo_camera.StereoCameraRenderer.render_depth>`) by :func:`depth16_from_truth`:

* **z²-proportional error.** An active stereo camera's error is a disparity error of about
  ``subpixel_rms_px`` (Intel quotes 0.08 px for D4xx), so the measured depth is
  ``f·b / (f·b / z + subpixel_rms_px · n)`` with ``n`` a unit-variance, near-normal draw
  per pixel (independent between pixels and frames; Irwin-Hall of four uniforms, so no
  error beyond 3.46 sigma), an RMS depth error of ``z² · subpixel_rms_px / (f·b)`` to
  first order (Intel, "Tuning depth
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

import numba
import numpy as np

from protocols.camera import StereoIntrinsics
from protocols.config import ConfigError, bounded, check_fields
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

    subpixel_rms_px: float = bounded(0.08, "px", ge=0)
    min_range_m: float = bounded(1.0, "m", gt=0)
    max_range_m: float = bounded(30.0, "m", gt=0)
    edge_rel_step: float = bounded(0.05, gt=0)
    edge_hole_px: int = bounded(1, "px", integer=True, ge=0)
    depth_scale_m: float = bounded(
        0.001, "m", ge=DEPTH16_SCALE_RANGE_M[0], le=DEPTH16_SCALE_RANGE_M[1]
    )

    def __post_init__(self) -> None:
        check_fields(self)
        if self.max_range_m <= self.min_range_m:
            raise ConfigError(
                f"must be above min_range_m ({self.min_range_m}), got {self.max_range_m}",
                key="max_range_m",
            )
        if self.max_range_m / self.depth_scale_m > 65535:
            raise ConfigError(
                f"{self.max_range_m} does not fit 16 bits of {self.depth_scale_m} m",
                key="max_range_m",
            )


_SEED_MASK = 0x7FFFFFFFFFFFFFFF  # a seed numba takes as int64


@numba.njit(cache=True)
def _splitmix64(x):
    """One step of SplitMix64 (Steele, Lea & Flood 2014): a well-mixed 64-bit hash."""
    x = x + np.uint64(0x9E3779B97F4A7C15)  # uint64 arithmetic wraps modulo 2**64
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@numba.njit(cache=True)
def _normal(seed, index):
    """An (approximately) standard normal draw for pixel ``index`` of frame ``seed``: the
    sum of the four 16-bit uniforms of one hash (Irwin-Hall, variance 4/12, rescaled to
    1; tails cut at 3.46 sigma). Deterministic, no generator state, integer work only."""
    h = _splitmix64(np.uint64(seed) * np.uint64(0x100000001B3) + np.uint64(index))
    total = 0.0
    for _ in range(4):
        total += np.float64(h & np.uint64(0xFFFF))
        h = h >> np.uint64(16)
    return (total / 65535.0 - 2.0) * 1.7320508075688772  # sqrt(12 / 4)


@numba.njit(cache=True)
def _is_edge(a, b, rel_step):
    """A depth edge between neighbours of depths ``a`` and ``b`` (inf: no surface)."""
    near = min(a, b)
    far = max(a, b)
    return near < np.inf and not far - near <= rel_step * near


@numba.njit(cache=True)
def _grow(mask, radius_px):
    """``mask`` (uint8) grown by ``radius_px`` in a square window: a row pass, then a
    column pass."""
    height, width = mask.shape
    rows = np.zeros((height, width), np.uint8)
    for y in range(height):
        for x in range(width):
            if mask[y, x]:
                for xx in range(max(0, x - radius_px), min(width, x + radius_px + 1)):
                    rows[y, xx] = 1
    out = np.zeros((height, width), np.uint8)
    for y in range(height):
        for x in range(width):
            if rows[y, x]:
                for yy in range(max(0, y - radius_px), min(height, y + radius_px + 1)):
                    out[yy, x] = 1
    return out


@numba.njit(cache=True)
def _depth16_kernel(z, fb, min_r, max_r, rel_step, hole_px, sigma_px, scale, seed, out):
    """:func:`depth16_from_truth`: mark the depth edges, grow them into holes, then measure
    every other pixel (module docstring)."""
    height, width = z.shape
    edge = np.zeros((height, width), np.uint8)
    for y in range(height):
        for x in range(width):
            a = z[y, x] if z[y, x] > 0.0 else np.inf  # NaN, <= 0: no surface
            if x + 1 < width:
                b = z[y, x + 1] if z[y, x + 1] > 0.0 else np.inf
                if _is_edge(a, b, rel_step):
                    edge[y, x] = 1
                    edge[y, x + 1] = 1
            if y + 1 < height:
                b = z[y + 1, x] if z[y + 1, x] > 0.0 else np.inf
                if _is_edge(a, b, rel_step):
                    edge[y, x] = 1
                    edge[y + 1, x] = 1
    holes = _grow(edge, hole_px) if hole_px > 0 else edge
    for y in range(height):
        for x in range(width):
            out[y, x] = 0
            depth = z[y, x]
            if holes[y, x] or not (min_r <= depth <= max_r) or fb > x * depth:
                continue  # a hole, out of range (NaN too), or outside the right imager's view
            disparity = fb / depth
            if sigma_px > 0.0:
                disparity += sigma_px * _normal(seed, y * width + x)
            if disparity <= 0.0:
                continue
            measured = fb / disparity
            if min_r <= measured <= max_r:
                out[y, x] = np.uint16(min(65535.0, np.rint(measured / scale)))


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
    z = np.ascontiguousarray(depth_true_m, dtype=np.float64)
    out = np.empty(z.shape, np.uint16)
    _depth16_kernel(
        z,
        float(intrinsics.focal_baseline_m_px),
        float(params.min_range_m),
        float(params.max_range_m),
        float(params.edge_rel_step),
        int(params.edge_hole_px),
        float(params.subpixel_rms_px),
        float(params.depth_scale_m),
        int(seed) & _SEED_MASK,
        out,
    )
    return out


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
