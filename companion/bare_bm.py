"""OpenCV ``StereoBM`` as it comes, as a depth source (:mod:`companion.depth_source`).

No padding, no prefilter of its own, no coarse pass: the leftmost ``numDisparities``
columns are never searched and are reported unknown (its blind band), and everything
nearer than ``min_range_m`` is missed. It is the benchmarks' baseline ("the bare matcher")
and the smallest example of a depth source: a new matcher is a module like this one.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cv2
import numpy as np

from companion.depth_source import DISP_SCALE, DepthMap, depth_from_disparity
from companion.stereo_bm import configured_bm
from protocols.stereo_frame import PixelEncoding, StereoFrame

if TYPE_CHECKING:
    from companion.perception import PerceptionConfig

__all__ = ["BareStereoBM"]

_REFERENCE_WIDTH_PX = 320  # the paper's camera: a 9 px block there, scaled with the width


class BareStereoBM:
    """``cv2.StereoBM`` with the perception config's range, block and gates, unpadded.

    Parameters
    ----------
    config : PerceptionConfig
        Uses ``min_range_m`` (search range), ``max_range_m``, ``block_size_px``,
        ``texture_threshold``, ``uniqueness_ratio``, ``speckle_*``, ``lr_max_diff_px`` and
        ``min_far_fraction``.
    """

    def __init__(self, config: PerceptionConfig):
        self.config = config
        self._matchers: dict[tuple[int, int, int], cv2.StereoBM] = {}

    def num_disparities(self, width_px: int, focal_baseline_m_px: float) -> int:
        """Search range [px]: ``f·b / min_range_m`` rounded up to 16, at most the width
        rounded down to 16 (OpenCV refuses more)."""
        n = 16 * max(1, math.ceil(focal_baseline_m_px / self.config.min_range_m / 16.0))
        return max(16, min(n, 16 * (width_px // 16)))

    def block_size(self, width_px: int) -> int:
        """Matching block [px, odd]: ``block_size_px`` or 9 px at 320 px, scaled."""
        if self.config.block_size_px is not None:
            return self.config.block_size_px
        return int(min(max(round(9 * width_px / _REFERENCE_WIDTH_PX) | 1, 5), 255))

    def compute(self, frame: StereoFrame) -> DepthMap:
        """The frame's depth map; its unsearched left columns are unknown."""
        if frame.encoding is not PixelEncoding.MONO8:
            raise ValueError(f"unsupported pixel encoding {frame.encoding!r}")
        height, width = frame.left.shape
        k = frame.intrinsics
        n_disp = self.num_disparities(width, k.focal_baseline_m_px)
        block = self.block_size(width)
        if height < block or width < n_disp + block:
            # OpenCV refuses a pair smaller than its window: nothing is matched.
            disp = np.full((height, width), -DISP_SCALE, np.int16)
        else:
            matcher = self.opencv_matcher(width, k.focal_baseline_m_px)
            disp = matcher.compute(frame.left, frame.right)
        return depth_from_disparity(
            disp,
            k.focal_baseline_m_px,
            self.config.max_range_m,
            n_disp + block // 2,
            math.ceil(self.config.min_far_fraction * disp.size),
        )

    def opencv_matcher(self, width_px: int, focal_baseline_m_px: float) -> cv2.StereoBM:
        """The configured ``cv2.StereoBM`` for this geometry (built once, then reused)."""
        cfg = self.config
        n_disp = self.num_disparities(width_px, focal_baseline_m_px)
        block = self.block_size(width_px)
        key = (n_disp, block, width_px)
        matcher = self._matchers.get(key)
        if matcher is None:
            matcher = self._matchers[key] = configured_bm(cfg, n_disp, block, width_px)
        return matcher
