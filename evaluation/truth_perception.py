"""Ground-truth depth for lockstep runs: the renderer's exact depth instead of a matcher.

Monte Carlo flies every scene two ways (issue 13): with the stereo matcher, as the
companion flies, and with *ground-truth* perception, which separates what guidance and the
safety envelope do from what the matcher misses. :class:`TruthDepthSource` is a depth
source (:mod:`companion.depth_source`'s contract) whose disparity comes from the left eye's
true depth (:meth:`StereoCameraRenderer.render_depth
<plant_sim.stereo_camera.StereoCameraRenderer.render_depth>`, the exact ray-cast geometry)
as ``round(16 · f·b / depth)`` instead of OpenCV's block matchers. The harness hands it to
the mission (``Mission(..., depth_source=...)``), so everything downstream — obstacle
pixels, blobs, boundary spheres, the depth map the known-space model folds in — is the
companion's own code, unchanged.

It stands in for the companion's matcher (:class:`~companion.stereo_bm.PaddedStereoBM`
with the same :class:`~companion.perception.PerceptionConfig`) and keeps what that matcher
cannot do: a pixel whose match would lie left of the right image (``x − d < 0``: outside
the right camera's view) is unmatched, and no far claim is trusted in the matcher's blind
band. The sky is matched at infinity (disparity 0), so beyond the blind band it certifies
free space up to the known-space range, as a perfect matcher would.

The truth for a frame is handed over with :meth:`TruthDepthSource.provide` before the
pipeline processes that frame; a frame without its truth is an error, never stale depth.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from companion.depth_source import DISP_SCALE as _DISP_SCALE
from companion.depth_source import DepthMap, depth_from_disparity
from companion.perception import PerceptionConfig
from companion.stereo_bm import PaddedStereoBM
from protocols.stereo_frame import PixelEncoding, StereoFrame

__all__ = ["TruthDepthSource", "truth_disparity_fixed"]

_INT16_MAX = float(np.iinfo(np.int16).max)


def truth_disparity_fixed(depth_m: np.ndarray, focal_baseline_m_px: float) -> np.ndarray:
    """Exact int16 disparity (1/16 px, OpenCV's convention) of a true depth map.

    Parameters
    ----------
    depth_m : numpy.ndarray, shape (H, W)
        Depth along the optical axis [m]; ``inf`` for sky, NaN or <= 0 where unknown.
    focal_baseline_m_px : float
        ``f·b`` [m·px] (Eq. 27: depth = f·b / disparity).

    Returns
    -------
    numpy.ndarray, int16
        ``round(16 · f·b / depth)`` (0 for sky, saturated at the int16 maximum for a
        surface nearer than ``16 · f·b / 32767``); -16 (unmatched) where the depth is not
        positive or the match would lie left of the right image (``x − d < 0``).
    """
    depth = np.asarray(depth_m)
    if depth.ndim != 2:
        raise ValueError(f"depth_m must be 2-D, got shape {depth.shape}")
    if depth.dtype not in (np.float32, np.float64):
        depth = depth.astype(np.float64)
    out = np.empty(depth.shape, np.int16)
    _truth_disparity(depth, float(_DISP_SCALE * focal_baseline_m_px), out)
    return out


@numba.njit(cache=True)
def _truth_disparity(depth, fb16, out):
    """:func:`truth_disparity_fixed` in one pass: ``out = min(rint(fb16 / depth), int16
    max)``, -16 where the depth is not positive or ``out > 16 x`` (``x − d < 0``)."""
    for y in range(depth.shape[0]):
        for x in range(depth.shape[1]):
            z = np.float64(depth[y, x])
            d = -_DISP_SCALE
            if z > 0.0:  # False for NaN
                v = min(np.rint(fb16 / z), _INT16_MAX)
                if v <= _DISP_SCALE * x:  # else outside the right camera's view
                    d = np.int16(v)
            out[y, x] = d


class TruthDepthSource:
    """A depth source on true disparities (module docstring).

    ``compute(frame)`` is :func:`~companion.depth_source.depth_from_disparity` of
    :func:`truth_disparity_fixed` of the depth handed over with :meth:`provide` for that
    frame: Eq. 27 within the configured ``max_range_m``, +inf for a match beyond it right of
    the matcher's blind band in a far region of at least ``min_far_fraction`` of the image,
    NaN elsewhere. The frame's pixels are not read (the harness sends blank images).

    Parameters
    ----------
    config : PerceptionConfig
        The companion's perception settings: range, far-region gate and the matcher whose
        blind band the truth keeps.
    """

    def __init__(self, config: PerceptionConfig) -> None:
        self.config = config
        self._stands_in_for = PaddedStereoBM(config)  # for its blind band only
        self._truth: tuple[int, np.ndarray] | None = None

    def provide(self, sequence: int, depth_left_m: np.ndarray) -> None:
        """The true depth [m] of the left image of frame ``sequence`` (next to be processed)."""
        self._truth = (int(sequence), depth_left_m)

    def disparity_fixed(self, frame: StereoFrame) -> np.ndarray:
        """True disparity of ``frame`` (int16, 1/16 px, -16 where a perfect matcher fails)."""
        if frame.encoding is not PixelEncoding.MONO8:
            raise ValueError(f"unsupported pixel encoding {frame.encoding!r} (stereo pairs only)")
        if self._truth is None or self._truth[0] != frame.sequence:
            have = None if self._truth is None else self._truth[0]
            raise RuntimeError(
                f"TruthDepthSource: no true depth for frame {frame.sequence} "
                f"(provide() was last given frame {have})"
            )
        depth = self._truth[1]
        k = frame.intrinsics
        if depth.shape != (k.height_px, k.width_px):
            raise ValueError(f"true depth shape {depth.shape} != frame {(k.height_px, k.width_px)}")
        return truth_disparity_fixed(depth, k.focal_baseline_m_px)

    def compute(self, frame: StereoFrame) -> DepthMap:
        """The frame's depth map (:mod:`companion.depth_source` contract) from its truth."""
        disp = self.disparity_fixed(frame)
        k = frame.intrinsics
        return depth_from_disparity(
            disp,
            k.focal_baseline_m_px,
            self.config.max_range_m,
            self._stands_in_for.blind_band_px(k),
            math.ceil(self.config.min_far_fraction * disp.size),
        )
