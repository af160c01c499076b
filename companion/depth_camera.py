"""Depth-camera depth source: a camera's own depth (RealSense, OAK-D, ZED) into the contract.

A depth camera computes depth on the camera, so the companion runs no matcher: a
:class:`~protocols.stereo_frame.DepthFrame` (``DEPTH16`` or ``DEPTH32F``, depth along the
left imager's optical axis) becomes the :class:`~companion.depth_source.DepthMap` that
obstacles and the known-space map already consume. The frame's encoding selects this source
(:class:`companion.perception.StereoPerception`); nothing is chosen by hand.

Per pixel, with ``z`` the camera's depth [m], ``f·b`` the frame's focal length × baseline
and ``σ(z) = z² · subpixel_rms_px / (f·b)`` the camera's RMS depth error (Intel's D4xx
depth-RMS formula, "Tuning depth cameras for best performance", Intel RealSense white
paper; the error grows with z² because it is a constant disparity error)::

    no data (DEPTH16 0, DEPTH32F NaN or 0)         NaN  unknown, never free
    z < min_range_m (nearer than the camera ranges) NaN  unknown
    16·f·b / z >= d_far (in range)                 z    finite; disparity round(16·f·b / z)
    beyond range, z − 3 σ(z) > range, outside
      the blind band, in a far region large enough +inf "nothing nearer along this ray"
    any other beyond-range return                   NaN  (a far return the source cannot trust)

where the range is ``min(max_range_m, max_rel_error · f·b / subpixel_rms_px)`` (beyond it
one sigma exceeds ``max_rel_error`` of the depth) and ``d_far = ceil(16·f·b / range)``.
``disparity_fixed`` is the depth's equivalent disparity at the frame's baseline in
OpenCV's 1/16 px: ``round(16·f·b / z)`` where finite (so ``|16·f·b / depth − disparity|
<= 1/2``, exact up to that rounding), ``floor`` for beyond-range returns, -16 where there
is no data. The blind band (``ceil(f·b / min_range_m)`` columns, at most the width) is
where the right imager cannot see a surface at the camera's minimum range: the camera
leaves it without data for near surfaces (RealSense's "left invalid depth band"), so no
pixel there claims free space and known space never takes it for open sky.

Pure: no clock, no I/O; one numba pass over the pixels.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from companion.depth_source import DISP_SCALE, DepthMap, ValidityCounts, drop_small_far_blocks
from protocols.camera import StereoIntrinsics
from protocols.config import ConfigError, bounded, check_fields, dataclass_from_mapping
from protocols.stereo_frame import DepthFrame, PixelEncoding

__all__ = ["DepthCameraConfig", "DepthCameraSource", "depth_plane_m"]

_TRUST_SIGMAS = 3.0  # a far return is trusted when it lies 3 σ beyond the range
_INT16_MAX = 32767


@dataclass(frozen=True)
class DepthCameraConfig:
    """What the companion assumes about a depth camera (defaults: Intel RealSense D435/D455).

    Attributes
    ----------
    min_range_m : float
        Nearest depth the camera measures [m] (D435 min-z ≈ 0.28 m at 848 × 480, D455
        ≈ 0.52 m); nearer returns are unknown, and it sets the blind band.
    max_range_m : float
        Farthest depth taken as a range [m]; farther returns at most say "nothing nearer"
        (+inf). Must be at least the known-space ``max_range_m`` (checked by the companion
        config), since +inf frees the ray up to the known-space range.
    subpixel_rms_px : float
        The camera's RMS disparity error [px]: ``σ(z) = z² · subpixel_rms_px / (f·b)``
        (Intel quotes 0.08 px for D4xx on a well-textured target; 0.1–0.2 outdoors).
    max_rel_error : float
        Largest ``σ(z) / z`` taken as a range; beyond it a return is a far return.
    min_far_fraction : float
        Smallest connected region of trusted far returns, as a fraction of the image area,
        reported +inf; smaller ones are unknown (as the matchers'
        ``PerceptionConfig.min_far_fraction``). 0 disables.
    """

    min_range_m: float = bounded(0.3, "m", gt=0)
    max_range_m: float = bounded(10.0, "m", gt=0)
    subpixel_rms_px: float = bounded(0.08, "px", gt=0)
    max_rel_error: float = bounded(0.05, gt=0)
    min_far_fraction: float = bounded(0.01, ge=0, lt=1)

    def __post_init__(self) -> None:
        check_fields(self)
        if self.max_range_m <= self.min_range_m:
            raise ConfigError(
                f"must be above min_range_m {self.min_range_m}, got {self.max_range_m}",
                key="max_range_m",
            )

    @classmethod
    def from_dict(
        cls, values: Mapping[str, Any], where: str = "perception.depth_camera"
    ) -> DepthCameraConfig:
        """Build from a mapping (``[perception.depth_camera]``); unknown keys and values
        out of bounds raise :class:`~protocols.config.ConfigError` naming the key."""
        return dataclass_from_mapping(cls, values, where)

    def range_m(self, intrinsics: StereoIntrinsics) -> float:
        """The farthest depth taken as a range for this camera [m] (module docstring)."""
        noise_limit_m = self.max_rel_error * intrinsics.focal_baseline_m_px / self.subpixel_rms_px
        return min(self.max_range_m, noise_limit_m)

    def depth_sigma_m(self, depth_m, intrinsics: StereoIntrinsics):
        """The camera's RMS depth error at ``depth_m`` [m]: ``z² · subpixel / (f·b)``."""
        return np.square(depth_m) * (self.subpixel_rms_px / intrinsics.focal_baseline_m_px)

    def blind_band_px(self, intrinsics: StereoIntrinsics) -> int:
        """Left columns where the right imager cannot see a surface at ``min_range_m``."""
        band = math.ceil(intrinsics.focal_baseline_m_px / self.min_range_m)
        return min(intrinsics.width_px, band)


def depth_plane_m(frame: DepthFrame) -> np.ndarray:
    """The frame's depth in metres (float32), NaN where the camera has no data."""
    encoding = PixelEncoding(frame.encoding)
    if encoding is PixelEncoding.DEPTH16:
        depth = frame.depth.astype(np.float32) * np.float32(frame.depth_scale_m)
    elif encoding is PixelEncoding.DEPTH32F:
        depth = np.array(frame.depth, dtype=np.float32)
    else:
        raise ValueError(f"not a depth frame: pixel encoding {encoding!r}")
    depth[~(depth > 0.0)] = np.nan
    return depth


class DepthCameraSource:
    """A depth camera's depth as a :class:`~companion.depth_source.DepthSource` (module
    docstring). ``compute`` raises ``ValueError`` for a stereo pair (MONO8).

    Parameters
    ----------
    config : DepthCameraConfig, optional
        The camera's range and noise.
    """

    def __init__(self, config: DepthCameraConfig | None = None) -> None:
        self.config = config if config is not None else DepthCameraConfig()
        _warm_up()

    def compute(self, frame: DepthFrame) -> DepthMap:
        """The contract's depth map of one depth frame."""
        return _depth_map(frame, self.config)


def _depth_map(frame: DepthFrame, cfg: DepthCameraConfig) -> DepthMap:
    """:meth:`DepthCameraSource.compute` (module docstring)."""
    encoding = PixelEncoding(frame.encoding)
    if not encoding.is_depth or not isinstance(frame, DepthFrame):
        raise ValueError(f"unsupported pixel encoding {encoding!r}: not a depth frame")
    k = frame.intrinsics
    fb = k.focal_baseline_m_px
    range_m = cfg.range_m(k)
    d_far = max(1, math.ceil(DISP_SCALE * fb / range_m))
    band = cfg.blind_band_px(k)
    depth = np.empty(frame.depth.shape, np.float32)
    disp = np.empty(frame.depth.shape, np.int16)
    height, width = depth.shape
    blocks = np.zeros(((height + 1) // 2, (width + 1) // 2), np.uint8)
    scale = frame.depth_scale_m if encoding is PixelEncoding.DEPTH16 else 1.0
    n_valid, n_unmatched, n_far = _depth_kernel(
        frame.depth,
        float(scale),
        float(DISP_SCALE * fb),
        float(cfg.min_range_m),
        float(range_m),
        int(d_far),
        float(_TRUST_SIGMAS * cfg.subpixel_rms_px / fb),
        int(band),
        depth,
        disp,
        blocks,
    )
    min_area = math.ceil(cfg.min_far_fraction * depth.size)
    n_unmatched += drop_small_far_blocks(depth, blocks, n_far, min_area)
    depth.flags.writeable = False
    counts = ValidityCounts(
        n_valid=int(n_valid),
        n_unmatched=int(n_unmatched),
        n_beyond_range=int(depth.size - n_valid - n_unmatched),
    )
    return DepthMap(disp, depth, counts, int(band), float(range_m))


@functools.cache
def _warm_up() -> None:
    """Run :meth:`DepthCameraSource.compute` once per process on tiny frames of both
    encodings, with writeable planes (lockstep) and read-only ones (decoded from the wire):
    compiles the kernel, or loads it from numba's cache, before the first real frame."""
    k = StereoIntrinsics(2, 2, 1.0, 1.0, 1.0, 1.0, 1.0)
    for plane, encoding in (
        (np.full((2, 2), 1000, np.uint16), PixelEncoding.DEPTH16),
        (np.ones((2, 2), np.float32), PixelEncoding.DEPTH32F),
    ):
        scale = 0.001 if encoding is PixelEncoding.DEPTH16 else 1.0
        for writeable in (True, False):
            plane = plane.copy()
            plane.flags.writeable = writeable
            _depth_map(DepthFrame(0, 0, k, plane, encoding, scale), DepthCameraConfig())


@numba.njit(cache=True)
def _depth_kernel(raw, scale, fb16, min_range, range_m, d_far, trust_c, band, depth, disp, blocks):
    """One pass of :meth:`DepthCameraSource.compute` (module docstring's table): writes
    ``depth`` and ``disp``, counts the trusted far pixels per 2 × 2 block into ``blocks``;
    returns (valid, unmatched, trusted far) pixel counts. Untrusted far returns count as
    neither valid nor unmatched (they are beyond range)."""
    n_valid = 0
    n_unmatched = 0
    n_far = 0
    for y in range(raw.shape[0]):
        for x in range(raw.shape[1]):
            z = np.float64(raw[y, x]) * scale
            if not z > 0.0 or not z < np.inf or z < min_range or fb16 / z > _INT16_MAX:
                depth[y, x] = np.nan
                disp[y, x] = -DISP_SCALE
                n_unmatched += 1
                continue
            dv = fb16 / z
            if dv >= d_far:
                depth[y, x] = np.float32(z)
                disp[y, x] = np.int16(np.rint(dv))
                n_valid += 1
                continue
            disp[y, x] = np.int16(math.floor(dv))
            if x >= band and z - trust_c * z * z > range_m:
                depth[y, x] = np.inf
                blocks[y // 2, x // 2] += 1
                n_far += 1
            else:
                depth[y, x] = np.nan
    return n_valid, n_unmatched, n_far
