"""Depth sources: the contract every stereo matcher of the companion fulfils.

A depth source turns one rectified stereo pair into a depth map with its validity. It is the
seam between the matcher and everything after it (obstacles, the known-space map): a new
matcher is one module with one class that satisfies :class:`DepthSource`;
``tests/test_depth_source.py`` finds every class with ``compute(...) -> DepthMap`` and runs
the conformance suite against each (it fails on one it has no entry for).

Contract of ``compute(frame) -> DepthMap``
------------------------------------------

In
    A :class:`~protocols.stereo_frame.StereoFrame`: rectified left/right planes of one size
    (any size, however small), its :class:`~protocols.camera.StereoIntrinsics` (focal length
    ``f`` [px], principal point, baseline ``b`` [m]) and capture time. A pixel encoding the
    source cannot read raises ``ValueError`` (the service counts and drops the frame).

Out, a :class:`DepthMap` whose arrays have the frame's shape:

``disparity_fixed``
    int16, left-image disparity in 1/16 px (OpenCV's fixed point), negative = no match.
``depth_m``
    float32, read-only, depth along the left optical axis [m]:

    * ``16·f·b / disparity_fixed`` (Eq. 27) exactly where ``disparity_fixed >= d_far``
      (``d_far = ceil(16·f·b / max_range_m)``), and finite nowhere else — for a depth
      camera (a :class:`~protocols.stereo_frame.DepthFrame`: the camera measured the depth)
      the other way round: ``depth_m`` is the camera's depth and ``disparity_fixed`` its
      equivalent at the frame's baseline, ``round(16·f·b / depth_m)``;
    * ``+inf`` only where ``0 <= disparity_fixed < d_far`` and the source trusts the match
      as "nothing nearer than ``max_range_m`` along this ray" (known free space), never in
      the first ``blind_band_px`` columns;
    * NaN (unknown, never free) everywhere else: unmatched, refused by a gate, or a far
      match the source does not trust.

    A pixel whose surface the right camera cannot see (column ``x`` < its true disparity)
    is never finite: it cannot be measured.
``counts``
    :class:`ValidityCounts`; ``n_valid`` equals the finite pixels of ``depth_m`` and the
    three classes add up to the image area.
``blind_band_px``
    Left columns where the right camera cannot see a surface at the nearest range the source
    measures: an unmatched pixel there is never taken for open sky.
``trusted_range_m``
    The range a +inf pixel vouches for (the source's ``max_range_m``).

A source is a pure function of the frame (no clock, no I/O; the same frame gives the same
map) and may hold reusable state such as OpenCV matcher objects.

Implementations: :class:`companion.stereo_bm.PaddedStereoBM` (the default: padded
StereoBM, gates, a quarter-resolution near pass), :class:`companion.bare_bm.BareStereoBM`
(OpenCV StereoBM as it comes; the benchmarks' baseline) and, for depth frames (no
matcher), :class:`companion.depth_camera.DepthCameraSource`; the frame's pixel encoding
picks between the matcher and the depth camera (:class:`companion.perception.StereoPerception`).
The lockstep bench's ground truth (``evaluation.truth_perception.TruthDepthSource``) is a
source too, handed to the mission in the matcher's place."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import cv2
import numba
import numpy as np

from protocols.stereo_frame import StereoFrame

__all__ = [
    "DISP_SCALE",
    "DepthMap",
    "DepthSource",
    "ValidityCounts",
    "depth_from_disparity",
    "drop_small_far_blocks",
    "drop_small_far_regions",
]

DISP_SCALE = 16  # fixed-point disparities carry 4 fractional bits (OpenCV's convention)


@dataclass(frozen=True)
class ValidityCounts:
    """Pixel counts of one frame's depth map; the three classes add up to the image area.

    Attributes
    ----------
    n_valid : int
        Pixels with a finite depth, at most ``max_range_m``.
    n_unmatched : int
        No trusted match: textureless, occluded, inconsistent, outside the right camera's
        view, or an isolated far match.
    n_beyond_range : int
        Matched farther than ``max_range_m`` (sky, distant ground): ``depth_m`` +inf, no
        surface within range (NaN inside the blind band).
    n_too_near : int
        Of ``n_valid``: nearer than the main pass's range, ranged by a coarser pass only.
    n_coarse : int
        Of ``n_valid``: holes of the main pass within its range filled by a coarser pass.
    """

    n_valid: int
    n_unmatched: int
    n_beyond_range: int
    n_too_near: int = 0
    n_coarse: int = 0


@dataclass(frozen=True, eq=False)
class DepthMap:
    """One frame's depth and validity, as the module docstring's contract defines them.

    Attributes
    ----------
    disparity_fixed : numpy.ndarray
        ``(H, W)`` int16 disparity [1/16 px], negative where unmatched.
    depth_m : numpy.ndarray
        ``(H, W)`` float32 depth [m], read-only; NaN unknown, +inf matched beyond range.
    counts : ValidityCounts
        How many pixels are known, and why the others are not.
    blind_band_px : int
        Left columns the right camera cannot see at the source's nearest range [px].
    trusted_range_m : float
        How far a +inf pixel vouches for free space [m]: the source's ``max_range_m``
        (the known-space map frees no farther along such a ray).
    """

    disparity_fixed: np.ndarray
    depth_m: np.ndarray
    counts: ValidityCounts
    blind_band_px: int
    trusted_range_m: float


@runtime_checkable
class DepthSource(Protocol):
    """Anything that turns a rectified pair into a :class:`DepthMap` (module docstring)."""

    def compute(self, frame: StereoFrame) -> DepthMap:
        """The frame's depth map; ``ValueError`` for a pixel encoding it cannot read."""
        ...


def depth_from_disparity(
    disparity_fixed: np.ndarray,
    focal_baseline_m_px: float,
    max_range_m: float,
    blind_band_px: int,
    min_far_px: int = 0,
) -> DepthMap:
    """The contract's depth map of a plain disparity image (no gates of its own).

    Eq. 27 where the match is within ``max_range_m``, +inf for a match beyond it right of
    ``blind_band_px`` in a far region of at least ``min_far_px`` pixels
    (:func:`drop_small_far_regions`), NaN elsewhere. For sources whose matcher leaves
    nothing else to decide; ``disparity_fixed`` (int16, 1/16 px) is kept, not copied.
    """
    d_far = max(1, math.ceil(DISP_SCALE * focal_baseline_m_px / max_range_m))
    near = disparity_fixed >= d_far
    depth = np.full(disparity_fixed.shape, np.nan, np.float32)
    # Eq. 27 in float64, rounded once to float32 (as the matcher's compiled merge does)
    depth[near] = (DISP_SCALE * focal_baseline_m_px) / disparity_fixed[near]
    far = (disparity_fixed >= 0) & ~near
    far[:, :blind_band_px] = False
    depth[far] = np.inf
    n_dropped = drop_small_far_regions(depth, min_far_px)
    depth.flags.writeable = False
    n_valid = int(np.count_nonzero(near))
    n_unmatched = int(np.count_nonzero(disparity_fixed < 0)) + n_dropped
    counts = ValidityCounts(
        n_valid=n_valid,
        n_unmatched=n_unmatched,
        n_beyond_range=disparity_fixed.size - n_valid - n_unmatched,
    )
    return DepthMap(disparity_fixed, depth, counts, int(blind_band_px), float(max_range_m))


def drop_small_far_regions(depth: np.ndarray, min_area: int) -> int:
    """Set to NaN (unknown) every region of +inf pixels in ``depth`` with fewer than
    ``min_area`` pixels, in place; return how many pixels that made unknown.

    A far claim ("nothing nearer along this ray") certifies free space; noise on a
    textureless surface yields small islands of one-pixel disparity that must not.
    Regions are the 8-connected components of the 2 × 2 blocks holding a +inf pixel (a
    quarter of the pixels to label; pixels one block apart belong to one region), and a
    region's size is its count of +inf pixels.
    """
    if min_area <= 1 or depth.size == 0:
        return 0
    height, width = depth.shape
    blocks = np.zeros(((height + 1) // 2, (width + 1) // 2), np.uint8)
    return drop_small_far_blocks(depth, blocks, _far_per_block(depth, blocks), min_area)


def drop_small_far_blocks(depth: np.ndarray, blocks: np.ndarray, n_far: int, min_area: int) -> int:
    """:func:`drop_small_far_regions` for a caller that has counted the +inf pixels already:
    ``blocks`` (uint8, ``ceil(H / 2) × ceil(W / 2)``) holds the count per 2 × 2 block and
    ``n_far`` their total (a depth kernel counts them as it writes them)."""
    if min_area <= 1 or n_far == 0:
        return 0
    if n_far < min_area:  # every region is smaller than that: no need to label them
        depth[depth == np.inf] = np.nan
        return n_far
    n_labels, labels = cv2.connectedComponents((blocks > 0).view(np.uint8), connectivity=8)
    small = _small_labels(labels, blocks, n_labels, min_area)
    if not small.any():
        return 0
    return _drop_far(depth, labels, small)


@numba.njit(cache=True)
def _far_per_block(depth, blocks):
    """Count the +inf pixels of ``depth`` per 2 × 2 block into ``blocks``; return the total."""
    total = 0
    for y in range(depth.shape[0]):
        for x in range(depth.shape[1]):
            if depth[y, x] == np.inf:
                blocks[y // 2, x // 2] += 1
                total += 1
    return total


@numba.njit(cache=True)
def _small_labels(labels, blocks, n_labels, min_area):
    """uint8 flag per label: its blocks hold fewer than ``min_area`` +inf pixels (label 0,
    the blocks without one, is never flagged)."""
    area = np.zeros(n_labels, np.int64)
    for y in range(labels.shape[0]):
        for x in range(labels.shape[1]):
            area[labels[y, x]] += blocks[y, x]
    small = np.zeros(n_labels, np.uint8)
    for i in range(1, n_labels):
        small[i] = area[i] < min_area
    return small


@numba.njit(cache=True)
def _drop_far(depth, labels, small):
    """NaN for every +inf pixel of ``depth`` whose block's label is ``small``; the count.
    Visits the pixels of the flagged blocks only."""
    height, width = depth.shape
    n = 0
    for by in range(labels.shape[0]):
        for bx in range(labels.shape[1]):
            if small[labels[by, bx]]:
                for y in range(2 * by, min(2 * by + 2, height)):
                    for x in range(2 * bx, min(2 * bx + 2, width)):
                        if depth[y, x] == np.inf:
                            depth[y, x] = np.nan
                            n += 1
    return n
