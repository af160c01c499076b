"""The default depth source: OpenCV ``StereoBM`` on the padded pair, gated, plus a coarse
near pass (fulfils :mod:`companion.depth_source`'s contract).

1. Both images are smoothed by a Gaussian whose width follows the sensor noise estimated in
   the frame (faint texture lifted above the noise).
2. The main pass: ``StereoBM`` searching down to ``min_range_m``, on the pair padded on the
   left (and by half a block on the other sides) so that every column that can hold an
   obstacle pixel is searched: OpenCV computes nothing in the leftmost ``numDisparities``
   columns of an unpadded pair, although only what lies outside the right camera's view
   (at 3 m the 0.2 m baseline hides ≈ 3.8°) is physically unmatchable. The few leftmost
   columns that can only see beyond the obstacle stage's reach stay unsearched, unknown
   (:meth:`PaddedStereoBM.unsearched_columns`). Left/right consistency (``disp12MaxDiff``)
   and uniqueness refuse occluded and ambiguous pixels; OpenCV's speckle filter runs on the
   frame's pixels (:mod:`companion.speckle`); a pixel on a near-horizontal edge (whose match
   depends on perfect rectification) and a match leaning on the black padding are refused.
3. A coarse pass at a quarter of the resolution ranges surfaces nearer than ``min_range_m``
   (which the main pass would miss or alias to a larger depth) down to ``near_range_m``,
   and fills the main pass's holes; main-pass matches around a too-near surface are unknown.
   A too-near claim where the main pass matched too must beat that match at full
   resolution, or it is dropped (a repetitive texture's copy one period away:
   :mod:`companion.near_alias`).
4. Depth by Eq. 27 in one compiled pass; a small island of beyond-range matches (noise on a
   textureless wall) is unknown, not "+inf, nothing nearer".
"""

from __future__ import annotations

import functools
import math
from typing import Protocol

import cv2
import numba
import numpy as np

from companion.depth_source import DISP_SCALE as _DISP_SCALE
from companion.depth_source import (
    DepthMap,
    ValidityCounts,
    drop_small_far_blocks,
    drop_small_far_regions,
)
from companion.near_alias import settle_near_claims
from companion.speckle import filter_speckles
from protocols.camera import StereoIntrinsics
from protocols.stereo_frame import PixelEncoding, StereoFrame

__all__ = [
    "MatcherSettings",
    "PaddedStereoBM",
    "configured_bm",
    "noise_sigma",
    "speckle_params",
    "speckle_window_px",
]


class MatcherSettings(Protocol):
    """What the matcher reads of its configuration (the perception config provides it:
    :class:`companion.perception.PerceptionConfig` documents each field)."""

    threshold_m: float  # detection threshold on depth [m]
    extent_margin_m: float  # how far past the threshold matches still matter [m]
    min_range_m: float  # nearest depth matched [m]
    near_range_m: float  # nearest depth the coarse pass catches [m]; <= 0: no coarse pass
    max_range_m: float  # farthest depth reported [m]
    block_size_px: int | None  # StereoBM block [px]; None: scaled from the image width
    uniqueness_ratio: int  # StereoBM uniqueness margin [%]
    texture_threshold: int  # StereoBM texture threshold
    speckle_window_px: int  # speckle filter region [px at the reference width]
    speckle_range_px: float  # speckle filter neighbour difference [px]
    lr_max_diff_px: int  # left/right check [px]; < 0: off
    prefilter_sigma_px: float | None  # Gaussian prefilter [px]; None: from the noise
    min_edge_ratio: float  # gate on edge strength
    min_far_fraction: float  # smallest far region kept [fraction of the image]


_REFERENCE_WIDTH_PX = 320  # the paper's camera; block size scales from it
_PREFILTER_BASE_PX = 1.0  # Gaussian prefilter sigma on a clean image [px]
_NOISE_FLOOR = 3.0  # [grey levels] above which the prefilter grows
_PREFILTER_PER_NOISE = 0.1  # Gaussian prefilter sigma [px] per grey level of noise above it
_PREFILTER_MAX_PX = 2.0
_EDGE_MARGIN_PX = 2  # matches this close to the right image's left edge are unknown [px]
_NEAR_SCALE = 4  # the coarse pass runs at a quarter of the resolution
_NEAR_BLOCK_PX = 5  # its block (20 px at full resolution)
_NEAR_TEXTURE = 400  # its StereoBM texture threshold (sum of |x-Sobel| over the block)
_NEAR_UNIQUENESS = 50  # its uniqueness margin [%]
_NEAR_SPECKLE_PX = 10  # its speckle window [coarse px]
_NEAR_HALO_PX = 41  # main-pass matches this close to a too-near surface are unknown [px]
_NEAR_HALO = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (_NEAR_HALO_PX, _NEAR_HALO_PX))
_NO_EDGES = np.zeros(0, np.int32)  # the edge gate is off
_NO_COARSE = np.zeros((0, 0), np.int16)  # the coarse pass is off


def speckle_window_px(window_at_reference_px: int, width_px: int) -> int:
    """OpenCV speckle window [px] for an image ``width_px`` wide: the configured window (at
    the 320 px reference) scaled with the image area (a noise speckle covers a fixed part
    of the field of view)."""
    return round(window_at_reference_px * (width_px / _REFERENCE_WIDTH_PX) ** 2)


def _padded(image: np.ndarray, pad_x: int, pad_y: int) -> np.ndarray:
    """``image`` with ``pad_x`` black columns on the left and ``pad_y`` replicated rows/columns
    on the other sides.

    OpenCV's matchers compute nothing in the leftmost ``numDisparities`` columns and the
    half-block border (the first computed column is ``numDisparities + block // 2 - 1``);
    on the padded pair every real pixel right of those the pad leaves out is searched over
    the full range, and a match into the black band (outside the right camera's view) has
    no texture to lock on, fails the left/right check, or is refused by
    :meth:`PaddedStereoBM.disparity_fixed`.
    """
    out = cv2.copyMakeBorder(image, pad_y, pad_y, pad_x, pad_y, cv2.BORDER_REPLICATE)
    out[:, :pad_x] = 0
    return out


def _padded_output(shape: tuple[int, int], pad_x: int, pad_y: int, write) -> np.ndarray:
    """:func:`_padded` of the ``shape`` image that ``write(dst)`` writes into ``dst`` (an
    OpenCV filter's output argument): written in place, no copy of it into the padding."""
    height, width = shape
    out = np.empty((height + 2 * pad_y, pad_x + width + pad_y), np.uint8)
    inner = out[pad_y : pad_y + height, pad_x : pad_x + width]
    write(inner)
    out[pad_y : pad_y + height, pad_x + width :] = inner[:, width - 1 :]
    out[:pad_y, pad_x:] = out[pad_y, pad_x:]
    out[pad_y + height :, pad_x:] = out[pad_y + height - 1, pad_x:]
    out[:, :pad_x] = 0
    return out


def noise_sigma(image: np.ndarray) -> float:
    """Sensor noise standard deviation of a grey image [grey levels] (Immerkær 1996: the mean
    absolute response to a Laplacian-difference mask that cancels smooth image structure)."""
    # A central third of the rows is plenty for one number, at a third of the cost.
    rows, cols = image.shape
    top, bottom = rows // 3, min(2 * rows // 3 + 2, rows)
    n = (bottom - top - 2) * (cols - 2)
    if n <= 0:
        return 0.0
    # The integer sum is exact; times 1 / n, as cv2.mean of the float32 response has it.
    mean = float(_abs_laplacian_sum(image, top, bottom)) * (1.0 / n)
    return float(math.sqrt(math.pi / 2.0) / 6.0 * mean)


@numba.njit(cache=True)
def _abs_laplacian_sum(image, top, bottom):
    """Sum of |[[1, -2, 1], [-2, 4, -2], [1, -2, 1]] * image| over rows ``top + 1`` to
    ``bottom - 2`` and every column but the first and the last (all integers: exact)."""
    total = 0
    for y in range(top + 1, bottom - 1):
        above, here, below = image[y - 1], image[y], image[y + 1]
        for x in range(1, image.shape[1] - 1):
            corners = np.int64(above[x - 1]) + above[x + 1] + below[x - 1] + below[x + 1]
            edges = np.int64(above[x]) + here[x - 1] + here[x + 1] + below[x]
            total += abs(corners - 2 * edges + 4 * np.int64(here[x]))
    return total


def _edge_table(ratio: float, block: int) -> np.ndarray:
    """Per horizontal block sum ``sx`` (of the saturated 3x3 Sobel magnitudes over a
    ``block`` x ``block`` window), the least vertical block sum ``sy`` that makes the window
    a near-horizontal edge, which only a perfect rectification matches right
    (:func:`_gate` refuses it): horizontal gradient < ``ratio`` x vertical.

    The comparison is the one ``cv2.blur`` means (``round(s / n)``, exact in integers for
    the odd ``n = block²``) compared as ``convertScaleAbs(ax, alpha=1 / ratio) < ay``
    (uint8; where ``ax / ratio`` saturates no ``ay`` exceeds it). Int32; ``2**30``: never.
    """
    n = block * block
    grey = np.arange(256, dtype=np.uint8).reshape(1, -1)
    scaled = cv2.convertScaleAbs(grey, alpha=1.0 / ratio).reshape(-1).astype(np.int64)
    sx = np.arange(255 * n + 1, dtype=np.int64)
    ax = (2 * sx + n) // (2 * n)  # round(sx / n): n is odd, so never a tie
    # round(sy / n) >= m  <=>  sy >= n·m - n // 2
    least = n * (scaled[ax] + 1) - n // 2
    return np.where(scaled[ax] >= 255, 2**30, least).astype(np.int32)


@numba.njit(cache=True)
def _reflect101(i, n):
    """OpenCV's BORDER_REFLECT_101 index of ``i`` in ``range(n)`` (``gfedcb|abcdefgh|gfedcba``)."""
    if n == 1:
        return 0
    while i < 0 or i >= n:
        i = -i if i < 0 else 2 * n - 2 - i
    return i


@numba.njit(cache=True)
def _abs_sobel(image):
    """``|dx|``, ``|dy|`` of ``image`` (uint8) by the 3x3 Sobel kernels, saturated to uint8,
    borders reflected (``cv2.spatialGradient`` then ``cv2.convertScaleAbs``, bit for bit).
    Separable, row by row, in branch-free loops the compiler vectorises."""
    height, width = image.shape
    adx = np.empty((height, width), np.uint8)
    ady = np.empty((height, width), np.uint8)
    smooth = np.empty(width + 2, np.int32)  # [1 2 1] down the column, one column of border
    diff = np.empty(width + 2, np.int32)  # [-1 0 1] down the column
    xm, xp = _reflect101(-1, width), _reflect101(width, width)
    for y in range(height):
        above = image[_reflect101(y - 1, height)]
        here = image[y]
        below = image[_reflect101(y + 1, height)]
        for x in range(width):
            smooth[x + 1] = np.int32(above[x]) + 2 * np.int32(here[x]) + below[x]
            diff[x + 1] = np.int32(below[x]) - above[x]
        smooth[0], diff[0] = smooth[xm + 1], diff[xm + 1]
        smooth[width + 1], diff[width + 1] = smooth[xp + 1], diff[xp + 1]
        out_x, out_y = adx[y], ady[y]
        for x in range(width):
            dx = smooth[x + 2] - smooth[x]
            dy = diff[x] + 2 * diff[x + 1] + diff[x + 2]
            out_x[x] = min(abs(dx), 255)
            out_y[x] = min(abs(dy), 255)
    return adx, ady


def configured_bm(
    config: MatcherSettings, n_disp: int, block_px: int, width_px: int, *, speckle: bool = True
) -> cv2.StereoBM:
    """``cv2.StereoBM`` with the perception config's gates (texture, uniqueness, speckle
    window scaled to ``width_px``, left/right check) for ``n_disp`` disparities; without
    its speckle filter if not ``speckle`` (the caller filters: :func:`speckle_params`)."""
    matcher = cv2.StereoBM_create(numDisparities=n_disp, blockSize=block_px)
    matcher.setTextureThreshold(config.texture_threshold)
    matcher.setUniquenessRatio(config.uniqueness_ratio)
    window, range_fixed = speckle_params(config, width_px)
    matcher.setSpeckleWindowSize(window if speckle else 0)
    matcher.setSpeckleRange(range_fixed)
    matcher.setDisp12MaxDiff(config.lr_max_diff_px)
    return matcher


def speckle_params(config: MatcherSettings, width_px: int) -> tuple[int, int]:
    """The speckle filter's (largest speckle [px], neighbour difference [1/16 px]) for an
    image ``width_px`` wide, as ``cv2.filterSpeckles`` takes them. (StereoBM compares the
    range with its 1/16 px fixed-point disparities as they are, unlike SGBM.)"""
    window = speckle_window_px(config.speckle_window_px, width_px)
    return window, round(_DISP_SCALE * config.speckle_range_px)


def _auto_block_size(width_px: int) -> int:
    size = round(9 * width_px / _REFERENCE_WIDTH_PX)
    return int(min(max(size | 1, 5), 255))


@numba.njit(cache=True)
def _quarter(image, out):
    """``out`` = ``image`` (uint8, exactly 4x as large) averaged over 4 × 4 blocks: OpenCV's
    integer-scale INTER_AREA resize (the sum / 16, rounded half to even), bit for bit."""
    for ys in range(out.shape[0]):
        for xs in range(out.shape[1]):
            total = 0
            for y in range(_NEAR_SCALE * ys, _NEAR_SCALE * ys + _NEAR_SCALE):
                row = image[y]
                for x in range(_NEAR_SCALE * xs, _NEAR_SCALE * xs + _NEAR_SCALE):
                    total += row[x]
            mean = total >> 4
            rest = total & 15
            if rest > 8 or (rest == 8 and mean & 1):
                mean += 1
            out[ys, xs] = mean


@numba.njit(cache=True)
def _coarse_row(small, n_band, y, row):
    """``row`` = the coarse pass's full-resolution disparity along row ``y`` (1/16 px): the
    match of ``small`` (its quarter-resolution pass, 1/16 coarse px) at (y // 4, x // 4),
    times 4; -16 outside ``small`` or where the match reaches left of the right image (a
    coarse column ``< n_band`` whose disparity exceeds it), negative as it is where
    unmatched."""
    ys = y // _NEAR_SCALE
    for x in range(row.shape[0]):
        xs = x // _NEAR_SCALE
        c = -_DISP_SCALE
        if ys < small.shape[0] and xs < small.shape[1]:
            c = small[ys, xs]
            if xs < n_band and c > _DISP_SCALE * xs:
                c = -_DISP_SCALE
            elif c >= 0:
                c = _NEAR_SCALE * c
        row[x] = c


@numba.njit(cache=True)
def _gate(disp, image, block, least_sy, band_limit):
    """The main pass's gates on ``disp`` (int16, 1/16 px), in place: -16 where ``image``'s
    block around the pixel is a near-horizontal edge (its horizontal Sobel sum ``sx`` and
    vertical ``sy`` over the ``block`` x ``block`` window, borders reflected, have
    ``sy >= least_sy[sx]``, :func:`_edge_table`; skipped when ``least_sy`` is empty) and in
    column ``x`` of the left band where the disparity exceeds ``band_limit[x]`` (the match
    leans on the black band)."""
    height, width = disp.shape
    n_band = min(band_limit.shape[0], width)
    for y in range(height):
        row = disp[y]
        for x in range(n_band):
            if row[x] > band_limit[x]:
                row[x] = -_DISP_SCALE
    if least_sy.shape[0] == 0:
        return
    radius = block // 2
    adx, ady = _abs_sobel(image)
    col_x = np.zeros(width, np.int32)  # window sums down each column, at row y
    col_y = np.zeros(width, np.int32)
    for k in range(-radius, radius + 1):
        _add_row(col_x, adx[_reflect101(k, height)], 1)
        _add_row(col_y, ady[_reflect101(k, height)], 1)
    sum_x = np.empty(width, np.int32)  # window sums at row y
    sum_y = np.empty(width, np.int32)
    prefix = np.empty(width + 2 * radius + 1, np.int32)
    for y in range(height):
        if y > 0:
            enter, leave = _reflect101(y + radius, height), _reflect101(y - radius - 1, height)
            _add_row(col_x, adx[enter], 1)
            _add_row(col_x, adx[leave], -1)
            _add_row(col_y, ady[enter], 1)
            _add_row(col_y, ady[leave], -1)
        _row_window_sums(col_x, radius, prefix, sum_x)
        _row_window_sums(col_y, radius, prefix, sum_y)
        row = disp[y]
        for x in range(width):
            if sum_y[x] >= least_sy[sum_x[x]]:
                row[x] = -_DISP_SCALE


@numba.njit(cache=True)
def _add_row(total, row, sign):
    """``total += sign · row`` (int32 += uint8), a loop the compiler vectorises."""
    for x in range(total.shape[0]):
        total[x] += sign * np.int32(row[x])


@numba.njit(cache=True)
def _row_window_sums(col, radius, prefix, out):
    """``out[x]`` = the sum of ``col[x - radius .. x + radius]``, borders reflected;
    ``prefix`` (``len(col) + 2·radius + 1``) is scratch for the running sums. (The offsets
    are slices, not index arithmetic, so the loops stay free of negative-index checks.)"""
    width = col.shape[0]
    total = 0
    prefix[0] = 0
    for k in range(radius):
        total += col[_reflect101(k - radius, width)]
        prefix[k + 1] = total
    inner = prefix[radius + 1 : radius + 1 + width]
    for x in range(width):
        total += col[x]
        inner[x] = total
    for k in range(radius):
        total += col[_reflect101(width + k, width)]
        prefix[radius + width + k + 1] = total
    ahead = prefix[2 * radius + 1 :]
    for x in range(width):
        out[x] = ahead[x] - prefix[x]


@numba.njit(cache=True)
def _merge_depth(disp, coarse, n_band, top, d_far, fb16, out, far_from_col):
    """Coarse pass into the main disparity (int16, 1/16 px, negative = unmatched), in place,
    and the depth map ``fb16 / disp``: NaN where unmatched; a match below ``d_far`` (farther
    than the range) is +inf from column ``far_from_col`` on (nothing nearer than the range
    along that ray) and NaN left of it, where a far match cannot be told from a false match
    into the band the right camera cannot see.

    ``coarse`` is the quarter-resolution pass (:func:`_coarse_row`; no rows: none). ``out``
    is (depth (float32), too_near (uint8, zero), blocks (uint8, zero)): ``too_near`` marks
    the pixels the coarse pass ranged nearer than the main range (``> top``), ``blocks``
    counts the +inf pixels per 2 × 2 block (for :func:`drop_small_far_blocks`).

    Returns (n_valid, n_unmatched, n_coarse, n_too_near, n_far).
    """
    depth, too_near, blocks = out
    has_coarse = coarse.shape[0] > 0
    n_valid = 0
    n_unmatched = 0
    n_coarse = 0
    n_too_near = 0
    n_far = 0
    row = np.empty(disp.shape[1], np.int64)  # the coarse pass along the row
    for y in range(disp.shape[0]):
        if has_coarse and y % _NEAR_SCALE == 0:
            _coarse_row(coarse, n_band, y, row)
        disp_y, depth_y, too_near_y, blocks_y = disp[y], depth[y], too_near[y], blocks[y // 2]
        for x in range(disp.shape[1]):
            d = disp_y[x]
            if has_coarse:
                c = row[x]
                if c > top and c > d:
                    d = c
                    too_near_y[x] = 1
                    n_too_near += 1
                elif d < 0 and c >= 0:
                    d = c
                    if d >= d_far:  # counted only where it gives a depth (n_valid)
                        n_coarse += 1
                disp_y[x] = d
            if d >= d_far:
                depth_y[x] = fb16 / d
                n_valid += 1
            elif d >= 0 and x >= far_from_col:
                depth_y[x] = np.inf
                blocks_y[x // 2] += 1
                n_far += 1
            else:
                depth_y[x] = np.nan
                if d < 0:
                    n_unmatched += 1
    return n_valid, n_unmatched, n_coarse, n_too_near, n_far


@functools.cache
def _warm_up() -> None:
    """Compile (or load from numba's cache) the gate, merge, alias and far-region kernels once per
    process, with the argument types :meth:`PaddedStereoBM.compute` uses."""
    far = np.full((2, 8), np.inf, np.float32)
    far[:, 4:7] = np.nan  # a region of 8 +inf pixels and one of 2: the second is dropped
    drop_small_far_regions(far, 5)
    main = np.full((6, 8), -16, np.int16)[1:5, 2:6]
    decoded = np.zeros((2, 8, 8), np.uint8)
    decoded.flags.writeable = False  # a decoded frame's planes are read-only views
    for image in (decoded[0], np.zeros((8, 8), np.uint8)):
        noise_sigma(image)
        _quarter(image, np.zeros((4, 6), np.uint8)[1:3, 1:3])
    # the prefiltered left image is a view into its padded array (writeable, strided)
    for image in (decoded[0][1:5, 2:6], np.zeros((6, 8), np.uint8)[1:5, 2:6]):
        filter_speckles(main, -16, 2, 3)
        _gate(main, image, 3, np.zeros(9 * 255 + 1, np.int32), np.zeros(2, np.int16))
        _gate(main, image, 3, _NO_EDGES, np.zeros(2, np.int16))
    coarse = np.full((3, 4), -16, np.int16)[1:, 1:3]
    for small in (coarse, _NO_COARSE):
        out = (np.empty((4, 4), np.float32), np.zeros((4, 4), np.uint8), np.zeros((2, 2), np.uint8))
        _merge_depth(main, small, 1, 16, 1, 16.0, out, 2)
    view = np.zeros((6, 8), np.uint8)[1:5, 2:6]  # the prefiltered pair: padded views
    settle_near_claims(coarse, 0, main, view, view, 1)


class PaddedStereoBM:
    """Padded, gated StereoBM with a quarter-resolution near pass (module docstring).

    Holds the OpenCV matchers and small lookup tables, built once per image geometry and
    reused; otherwise :meth:`compute` is a function of the frame.

    Parameters
    ----------
    config : MatcherSettings
        The matcher settings (range, block, gates) of the perception config.
    """

    def __init__(self, config: MatcherSettings):
        self.config = config
        self._matchers: dict[tuple, cv2.StereoMatcher] = {}
        self._tables: dict[tuple, np.ndarray] = {}
        _warm_up()

    def _table(self, key: tuple, make) -> np.ndarray:
        """The lookup table ``make()`` for ``key``, built once (the kernels only read it)."""
        table = self._tables.get(key)
        if table is None:
            table = self._tables[key] = make()
        return table

    def compute(self, frame: StereoFrame) -> DepthMap:
        """The frame's depth map (:mod:`companion.depth_source` contract)."""
        k = frame.intrinsics
        coarse = self.coarse_pass_fixed(frame)
        n_disp = self.num_disparities(k)
        if coarse is None:  # no claim to settle (a subclass may replace disparity_fixed)
            disp = self.disparity_fixed(frame)
        else:
            # a claim nearer than the main range must beat the main pass's own match there
            # (companion.near_alias), scored on the images the main pass matched
            disp, left, right = self._main_pass(frame)
            settle_near_claims(
                coarse[0],
                _DISP_SCALE * (n_disp - 1) // _NEAR_SCALE,
                disp,
                left,
                right,
                self.block_size(k) // 2,
            )
        band_px = self.blind_band_px(k)
        depth_m, counts = self._merge(disp, coarse, k.focal_baseline_m_px, n_disp, band_px)
        return DepthMap(disp, depth_m, counts, band_px, float(self.config.max_range_m))

    def num_disparities(self, intrinsics: StereoIntrinsics) -> int:
        """Disparity search range [px]: ``f·b / min_range_m`` rounded up to a multiple of 16."""
        d_max = intrinsics.focal_baseline_m_px / self.config.min_range_m
        return int(16 * max(1, math.ceil(d_max / 16.0)))

    def block_size(self, intrinsics: StereoIntrinsics) -> int:
        """Matching block size [px] for this image width."""
        return self.config.block_size_px or _auto_block_size(intrinsics.width_px)

    def blind_band_px(self, intrinsics: StereoIntrinsics) -> int:
        """Left columns the right camera cannot see at the main pass's nearest range [px]
        (the search range plus half a block): no far claim is trusted there."""
        return self.num_disparities(intrinsics) + self.block_size(intrinsics) // 2

    def unsearched_columns(self, intrinsics: StereoIntrinsics) -> int:
        """How many leftmost columns the main pass leaves unsearched (unknown): those that
        can hold no pixel the obstacle stage uses, less half a block.

        Column ``x`` holds a match only where the right camera sees it a margin inside its
        edge (disparity ≤ ``x - margin`` px, :meth:`disparity_fixed`), so the columns left
        of ``ceil(f·b / reach) + margin`` can only see surfaces beyond the obstacle stage's
        reach (``threshold_m + extent_margin_m``: 7 m, 10.3 px, column 17 at the paper's
        camera). Searching them would cost a tenth of the matcher's time for far-space
        evidence in the outer 2° of the view. The search starts half a block before that
        column, so that the first column that can hold an obstacle pixel is matched among
        searched neighbours, as with the full padding.
        """
        cfg = self.config
        block = self.block_size(intrinsics)
        reach_px = intrinsics.focal_baseline_m_px / (cfg.threshold_m + cfg.extent_margin_m)
        wanted = math.ceil(reach_px) + _EDGE_MARGIN_PX  # + margin - half a block
        # OpenCV's first computed column is numDisparities + half a block - 1
        return min(wanted, self.num_disparities(intrinsics) + block // 2 - 1)

    def _matcher(self, intrinsics: StereoIntrinsics) -> tuple[cv2.StereoMatcher, int, int]:
        cfg = self.config
        n_disp = self.num_disparities(intrinsics)
        block = self.block_size(intrinsics)
        key = (intrinsics.width_px, n_disp, block)
        width = intrinsics.width_px
        matcher = self._matchers.get(key)
        if matcher is None:
            # its speckle filter runs on the frame's pixels alone (disparity_fixed)
            matcher = configured_bm(cfg, n_disp, block, width, speckle=False)
            self._matchers[key] = matcher
        return matcher, n_disp, block

    def disparity_fixed(self, frame: StereoFrame) -> np.ndarray:
        """Disparity of the frame's left image: int16, 1/16 px units, negative where unmatched.

        The pair is padded before matching so that every column right of
        :meth:`unsearched_columns` is searched (see :func:`_padded`); a pixel whose match
        would lie left of the right image (outside the right camera's view) is unmatched.
        """
        return self._main_pass(frame)[0]

    def _main_pass(self, frame: StereoFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`disparity_fixed` and the prefiltered left and right images it matched
        (views of the frame's size into the padded pair)."""
        if frame.encoding is not PixelEncoding.MONO8:
            raise ValueError(f"unsupported pixel encoding {frame.encoding!r}")
        matcher, n_disp, block = self._matcher(frame.intrinsics)
        height, width = frame.left.shape
        # Half a block on each side; more on a frame shorter than a block (OpenCV refuses it).
        pad_y = max(block // 2, (block + 2 - height) // 2)
        # OpenCV computes nothing left of padded column n_disp + block // 2 - 1
        pad_x = n_disp + block // 2 - 1 - self.unsearched_columns(frame.intrinsics)
        left_padded, right_padded = self._prefiltered(frame, pad_x, pad_y)
        left = left_padded[pad_y : pad_y + height, pad_x : pad_x + width]
        right = right_padded[pad_y : pad_y + height, pad_x : pad_x + width]
        out = matcher.compute(left_padded, right_padded)
        disp = out[pad_y : pad_y + height, pad_x : pad_x + width]
        # OpenCV's speckle filter (companion.speckle: 0.8 of StereoBM's own time here), on
        # the frame's pixels: StereoBM leaves those of the padding unmatched
        window, range_fixed = speckle_params(self.config, width)
        if window > 0:
            filter_speckles(disp, -_DISP_SCALE, window, range_fixed)
        ratio = self.config.min_edge_ratio
        least_sy = _NO_EDGES
        if ratio > 0.0:
            # Aperture: along a near-horizontal edge a match is only as good as the
            # rectification (a 2 px vertical error on a 5° edge shifts it by 23 px).
            least_sy = self._table(("edge", ratio, block), lambda: _edge_table(ratio, block))
        # The right camera sees column x - d only if x - d >= 0; a match whose right block
        # reaches into the black band (x - d < half a block + _EDGE_MARGIN_PX) leans on it
        # and is as likely wrong as right: unknown too.
        margin = block // 2 + _EDGE_MARGIN_PX
        n_band = min(n_disp + margin, width)
        limit = self._table(
            ("band", n_band, margin),
            lambda: _DISP_SCALE * (np.arange(n_band, dtype=np.int16) - margin),
        )
        _gate(disp, left, block, least_sy, limit)
        return disp, left, right

    def prefilter_sigma_px(self, frame: StereoFrame) -> tuple[float, float]:
        """Gaussian prefilter sigmas (x, y) [px] for this frame: ``prefilter_sigma_px`` if
        set, else from the left image's estimated sensor noise (:func:`noise_sigma`)."""
        cfg = self.config
        if cfg.prefilter_sigma_px is not None:
            return cfg.prefilter_sigma_px, cfg.prefilter_sigma_px
        noise = noise_sigma(frame.left)
        extra = min(_PREFILTER_PER_NOISE * max(0.0, noise - _NOISE_FLOOR), _PREFILTER_MAX_PX)
        return _PREFILTER_BASE_PX + extra, _PREFILTER_BASE_PX + extra

    def _prefiltered(
        self, frame: StereoFrame, pad_x: int = 0, pad_y: int = 0
    ) -> tuple[np.ndarray, np.ndarray]:
        """The frame's prefiltered images, padded (:func:`_padded`) by ``pad_x``, ``pad_y``."""
        sx, sy = self.prefilter_sigma_px(frame)
        if max(sx, sy) < 0.3:
            return _padded(frame.left, pad_x, pad_y), _padded(frame.right, pad_x, pad_y)
        # Kernels of ±2 sigma: OpenCV's fixed-point path for uint8 (the tails carry < 5 %).
        ksize = (2 * math.ceil(2.0 * sx) + 1, 2 * math.ceil(2.0 * sy) + 1)

        def blur(image: np.ndarray) -> np.ndarray:
            return _padded_output(
                image.shape,
                pad_x,
                pad_y,
                lambda dst: cv2.GaussianBlur(
                    image, ksize, dst=dst, sigmaX=sx, sigmaY=sy, borderType=cv2.BORDER_REPLICATE
                ),
            )

        return blur(frame.left), blur(frame.right)

    def coarse_pass_fixed(self, frame: StereoFrame) -> tuple[np.ndarray, int] | None:
        """Coarse pass at its own resolution: (int16 disparity in 1/16 coarse px, negative
        where unmatched; its disparity range ``n`` [coarse px]), ``None`` when disabled. A
        match in coarse column ``x < n`` above ``16·x`` reaches left of the right image and
        is read as unmatched (:func:`_coarse_row`).

        The pair is matched at a quarter of the resolution (disparities are a quarter too, so
        a 48-disparity search reaches 4 × 48 px at full resolution at 1/16 of the cost) with
        the same padding and left/right check, and strict texture and uniqueness gates (its
        4 × 4 averaging makes faint texture and sky seams look matchable). It ranges what is
        nearer than the main pass can (``min_range_m``) down to ``near_range_m``, and fills
        the main pass's holes (faint texture it cannot lock on at full resolution).
        """
        cfg = self.config
        if cfg.near_range_m <= 0.0:
            return None
        k = frame.intrinsics
        height, width = frame.left.shape
        w4, h4 = width // _NEAR_SCALE, height // _NEAR_SCALE
        n_main = self.num_disparities(k)
        d_max = k.focal_baseline_m_px / cfg.near_range_m / _NEAR_SCALE
        n_disp = int(16 * max(1, math.ceil(d_max / 16.0)))
        if w4 < 8 or h4 < 8 or _NEAR_SCALE * n_disp <= n_main:
            return None
        key = ("near", n_disp)
        matcher = self._matchers.get(key)
        if matcher is None:
            matcher = cv2.StereoBM_create(numDisparities=n_disp, blockSize=_NEAR_BLOCK_PX)
            matcher.setTextureThreshold(_NEAR_TEXTURE)
            matcher.setUniquenessRatio(_NEAR_UNIQUENESS)
            matcher.setSpeckleWindowSize(_NEAR_SPECKLE_PX)
            matcher.setSpeckleRange(1)  # 1/16 coarse px (StereoBM does not scale it)
            matcher.setDisp12MaxDiff(max(cfg.lr_max_diff_px, 0))
            self._matchers[key] = matcher
        pad_y = max(_NEAR_BLOCK_PX // 2, (_NEAR_BLOCK_PX + 2 - h4) // 2)

        def quarter(image: np.ndarray) -> np.ndarray:
            if (height, width) == (_NEAR_SCALE * h4, _NEAR_SCALE * w4):
                return _padded_output((h4, w4), n_disp, pad_y, lambda dst: _quarter(image, dst))
            return _padded_output(
                (h4, w4),
                n_disp,
                pad_y,
                lambda dst: cv2.resize(image, (w4, h4), dst=dst, interpolation=cv2.INTER_AREA),
            )

        small = [quarter(frame.left), quarter(frame.right)]
        coarse = matcher.compute(small[0], small[1])[pad_y : pad_y + h4, n_disp : n_disp + w4]
        return coarse, n_disp

    def _merge(
        self,
        disp: np.ndarray,
        coarse: tuple[np.ndarray, int] | None,
        fb: float,
        n_disp: int,
        band_px: int,
    ) -> tuple[np.ndarray, ValidityCounts]:
        """Merge the coarse pass (:meth:`coarse_pass_fixed`) into ``disp`` (in place) and
        make the depth map.

        Holes of the main pass within its range take the coarse disparity; where the coarse
        pass sees a surface nearer than the main range (the main pass missed it or aliased
        it to a smaller disparity) it wins, and main-pass matches within ``_NEAR_HALO_PX``
        of it are unknown (as likely aliased as right). One compiled pass over the pixels.
        """
        d_far = max(1, math.ceil(_DISP_SCALE * fb / self.config.max_range_m))
        fb16 = float(_DISP_SCALE * fb)
        small, n_near = coarse if coarse is not None else (_NO_COARSE, 0)
        height, width = disp.shape
        depth = np.empty(disp.shape, np.float32)
        too_near = np.zeros(disp.shape, np.uint8)
        blocks = np.zeros(((height + 1) // 2, (width + 1) // 2), np.uint8)
        n_valid, n_unmatched, n_coarse, n_too_near, n_far = _merge_depth(
            disp,
            small,
            n_near,
            _DISP_SCALE * (n_disp - 1),
            d_far,
            fb16,
            (depth, too_near, blocks),
            band_px,
        )
        n_halo = 0
        if n_too_near:
            halo = cv2.dilate(too_near, _NEAR_HALO).view(bool) & (too_near == 0)
            halo &= disp >= 0
            n_halo = int(np.count_nonzero(halo))
            if n_halo:
                n_valid -= int(np.count_nonzero(halo & (disp >= d_far)))
                n_unmatched += n_halo
                disp[halo] = -_DISP_SCALE
                depth[halo] = np.nan
        # A small island of beyond-range matches is noise (a textureless wall), not sky.
        min_area = math.ceil(self.config.min_far_fraction * disp.size)
        if n_halo:  # the halo made some +inf pixels unknown: count them again
            n_unmatched += drop_small_far_regions(depth, min_area)
        else:
            n_unmatched += drop_small_far_blocks(depth, blocks, n_far, min_area)
        depth.flags.writeable = False
        counts = ValidityCounts(
            n_valid=n_valid,
            n_unmatched=n_unmatched,
            n_beyond_range=disp.size - n_valid - n_unmatched,
            n_too_near=n_too_near,
            n_coarse=n_coarse,
        )
        return depth, counts
