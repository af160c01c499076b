"""Stereo perception (paper §4–5): disparity → depth (Eq. 27) → obstacles → safety spheres in NED.

Pipeline for one rectified frame (:meth:`StereoPerception.process`):

1. Disparity with OpenCV ``StereoBM`` (SGBM was retired, see :class:`Matcher`), one
   matcher object per image geometry, built once and reused. The pair is padded by the
   disparity range on the left (and half a block on the other sides) so that every column is
   searched: OpenCV computes nothing in the leftmost ``numDisparities`` columns of an unpadded
   pair (64 px ≈ 10° at 320 px), although only what lies outside the right camera's view
   (at 3 m the 0.2 m baseline hides ≈ 3.8°) is physically unmatchable. Left/right
   consistency (``disp12MaxDiff``) and uniqueness refuse occluded and ambiguous pixels.
   Both images are first smoothed by a Gaussian whose width follows the sensor noise
   estimated in the frame, and a pixel on a near-horizontal edge (whose match depends on
   perfect rectification) is refused. A coarse pass at a quarter of the resolution ranges
   surfaces nearer than ``min_range_m`` (which the main pass would miss or alias to a larger
   depth) down to ``near_range_m``, and fills the main pass's holes.
   The result is the **depth map** ``depth_m`` (NaN = unknown, see below).
2. Obstacle pixels: valid disparity ``d ≥ f·b / threshold_m`` (depth below the threshold,
   Eq. 27, compared in disparity space so no per-pixel division).
3. Noise filter: a morphological opening, then connected components
   (``cv2.connectedComponentsWithStats``) smaller than ``min_blob_fraction`` of the image are
   dropped, so isolated noisy pixels never become obstacles.
4. Extent: each surviving blob is flood-filled over the disparity image along depth-continuous
   neighbours (relative step ≤ ``continuity_rel``) out to ``threshold_m + extent_margin_m``.
   The threshold decides *whether* there is an obstacle; the fill recovers *how big* it is
   (the part of a sphere beyond 4 m still belongs to it). Blobs whose fills meet are one
   obstacle; depth discontinuities separate obstacles that touch in the image.
5. Back-projection of the region's pixels to the left camera frame and, with the vehicle pose
   at the frame's capture time, to NED (:mod:`protocols.camera`).
6. Collision safety boundary (Fig. 4): the camera sees only the front of an obstacle; the blind
   spot behind it counts as obstacle. Model the obstacle as the sphere that fills the visible
   cone: with ``α`` the angular half-width of the region about its mean bearing and ``r`` the
   range to its nearest surface, a sphere of radius ``R`` at distance ``D`` has
   ``sin α = R / D`` and ``r = D − R``, so ``R = r sin α / (1 − sin α)`` and the centre is
   pushed ``R`` behind the nearest surface along the mean bearing. The raw radius is the larger
   of ``R`` and the distance from that centre to the farthest measured point (so the sphere
   encloses every point); the boundary adds ``vehicle_radius_m + safety_margin_m``.

The per-obstacle steps (seed search, region sampling, sphere fit) are small numba kernels,
one pass over the pixels or samples each instead of a dozen numpy temporaries; they are
compiled (or loaded from numba's cache) when the first :class:`StereoPerception` is built.

Unknown space: :class:`PerceptionResult` carries ``depth_m`` (float32, depth along the
optical axis [m]) with NaN wherever the depth is not known: unmatched (textureless,
occluded, inconsistent), outside the right camera's view, beyond ``max_range_m``, or nearer
than even the coarse pass reaches. Unknown is never free: the known-space model of the safety
envelope consumes this map; :class:`ValidityCounts` says how many pixels are unknown and
why. Obstacles are built only from known depth; each says whether it was ``truncated`` by
the image border (then its true extent may be larger than estimated).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
from dataclasses import dataclass
from typing import Any

import cv2
import numba
import numpy as np

from protocols.camera import StereoIntrinsics, points_ned_from_cam
from protocols.stereo_frame import PixelEncoding, StereoFrame

__all__ = [
    "Matcher",
    "Obstacle",
    "PerceptionConfig",
    "PerceptionResult",
    "StereoPerception",
    "ValidityCounts",
]

_DISP_SCALE = 16  # OpenCV disparities are fixed point with 4 fractional bits
_REFERENCE_WIDTH_PX = 320  # the paper's camera; block size scales from it
_PREFILTER_BASE_PX = 1.0  # Gaussian prefilter sigma on a clean image [px]
_NOISE_FLOOR = 3.0  # [grey levels] above which the prefilter grows
_PREFILTER_PER_NOISE = 0.1  # Gaussian prefilter sigma [px] per grey level of noise above it
_PREFILTER_MAX_PX = 2.0
_MIN_SIDE_CAP_PX = 20.0  # the size gate never asks for more than a 20 px square (at 320 px)
_EDGE_MARGIN_PX = 2  # matches this close to the right image's left edge are unknown [px]
_NEAR_SCALE = 4  # the coarse pass runs at a quarter of the resolution
_NEAR_BLOCK_PX = 5  # its block (20 px at full resolution)
_NEAR_TEXTURE = 400  # its StereoBM texture threshold (sum of |x-Sobel| over the block)
_NEAR_UNIQUENESS = 50  # its uniqueness margin [%]
_NEAR_SPECKLE_PX = 10  # its speckle window [coarse px]
_NEAR_HALO_PX = 41  # main-pass matches this close to a too-near surface are unknown [px]
_NEAR_HALO = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (_NEAR_HALO_PX, _NEAR_HALO_PX))
_NO_EDGE = np.zeros((0, 2), np.int32)  # no contour samples (stride 1: the grid is every pixel)


class Matcher(enum.Enum):
    """OpenCV stereo matcher.

    Only ``StereoBM`` is offered. ``sgbm_3way`` (``cv2.StereoSGBM`` 3-way) was retired in
    issue 14: it is denser on real images (Middlebury motorcycle recall 0.97 at 3 m) but
    fails the robustness suite (``benchmarks/bench_degradations.py``): its smoothness term
    turns noise, gain mismatch and misrectification into coherent false surfaces (false
    obstacles in 107-193 of 200 empty frames) and it is ~1.7x slower.
    """

    BM = "bm"  # cv2.StereoBM with the padding, gates and coarse pass of this module

    @classmethod
    def _missing_(cls, value):
        if value == "sgbm_3way":
            raise ValueError(
                "matcher 'sgbm_3way' was retired (it fails the robustness suite of "
                "benchmarks/bench_degradations.py); use 'bm'"
            )
        return None


@dataclass(frozen=True)
class PerceptionConfig:
    """Settings of the stereo obstacle detector.

    Attributes
    ----------
    threshold_m : float
        Detection threshold on depth [m] (paper §5: 4 m ⇔ disparity ≥ 18 px at 320 px).
    matcher : Matcher
        OpenCV matcher.
    min_range_m : float
        Nearest depth the matcher searches [m]; sets ``num_disparities`` (rounded up to 16).
    near_range_m : float
        Nearest depth of the coarse pass [m] (quarter resolution, searched up to
        ``f·b / near_range_m``): it catches what is nearer than ``min_range_m`` instead of
        letting the main pass alias it to a larger depth; 0 disables it.
    max_range_m : float
        Farthest depth reported [m]: a match beyond it (disparity below ``f·b / max_range_m``,
        where one pixel of disparity error is metres of depth) has no depth, only the fact
        that nothing is nearer along its ray: ``depth_m`` is +inf there (NaN within
        ``blind_band_px`` of the left edge, where it may be a false match).
    block_size_px : int or None
        Matching block size [px, odd]; ``None`` scales 9 px at 320 px width to the image.
    uniqueness_ratio : int
        OpenCV uniqueness margin [%].
    texture_threshold : int
        StereoBM texture threshold (ignored by SGBM).
    speckle_window_px : int
        OpenCV speckle filter region size [px].
    speckle_range_px : int
        OpenCV speckle filter disparity range [px].
    prefilter_sigma_px : float or None
        Gaussian prefilter of both images before matching [px]; ``None`` adapts it to the
        sensor noise estimated in each frame (1 px on a clean image, ~1.7 px at σ 10,
        ~2.7 px at σ 20 grey levels): it lifts faint texture above the noise.
    min_edge_ratio : float
        A pixel whose block has less than this ratio of horizontal to vertical gradient (a
        near-horizontal edge) is unknown: its match depends on perfect rectification. 0
        disables the check.
    lr_max_diff_px : int
        Left/right consistency: largest difference [px] between a pixel's disparity and the
        one the right image's best match points back with (OpenCV ``disp12MaxDiff``); a pixel
        the right camera cannot see (occluded, or outside its view) fails it. -1 disables.
    opening_px : int
        Kernel size of the morphological opening of the obstacle mask [px]; 1 disables it.
    min_blob_fraction : float
        Smallest obstacle blob as a fraction of the image area (6e-4 ≈ 46 px at 320 × 240).
    min_obstacle_size_m : float
        Smallest obstacle reported [m]: a blob of near pixels covering less than a square of
        this side at its depth is dropped (mismatch clusters from noise, JPEG blocks or
        aliasing are a few pixels across; 0.15 m spans 13 px at 4 m; never more than a
        20 px square is asked for).
    continuity_rel : float
        Largest relative disparity step between neighbours inside one obstacle.
    extent_margin_m : float
        How far beyond ``threshold_m`` an obstacle's extent is followed [m].
    max_half_angle_deg : float
        Cap on the angular half-width used in the sphere fit [deg] (bounds ``R`` for walls).
    vehicle_radius_m : float
        Vehicle radius added to the boundary [m] (Table 2 arm 0.25 m + propeller; assumed).
    safety_margin_m : float
        Extra clearance added to the boundary [m] (assumed).
    cap_depth_m : float
        Depth of the nearest cap whose mean bearing gives the centre direction [m]
        (at least 3 % of the nearest range).
    max_points : int
        Interior samples per obstacle for the boundary fit (its outer contour is always used
        whole), which bounds the per-obstacle cost.
    """

    threshold_m: float = 4.0
    matcher: Matcher = Matcher.BM
    min_range_m: float = 1.5
    near_range_m: float = 0.4
    max_range_m: float = 20.0
    block_size_px: int | None = None
    uniqueness_ratio: int = 10
    texture_threshold: int = 10
    speckle_window_px: int = 100
    speckle_range_px: int = 3
    lr_max_diff_px: int = 1
    prefilter_sigma_px: float | None = None
    min_edge_ratio: float = 0.1
    opening_px: int = 3
    min_blob_fraction: float = 6e-4
    min_obstacle_size_m: float = 0.15
    continuity_rel: float = 0.1
    extent_margin_m: float = 3.0
    max_half_angle_deg: float = 64.0
    vehicle_radius_m: float = 0.35
    safety_margin_m: float = 0.3
    max_points: int = 1500
    cap_depth_m: float = 0.1

    def __post_init__(self) -> None:
        object.__setattr__(self, "matcher", Matcher(self.matcher))
        positive = ("threshold_m", "min_range_m", "min_blob_fraction", "continuity_rel")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and positive, got {value!r}")
        for name in (
            "extent_margin_m",
            "vehicle_radius_m",
            "safety_margin_m",
            "cap_depth_m",
            "min_obstacle_size_m",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        if not (math.isfinite(self.max_range_m) and self.max_range_m > self.threshold_m):
            raise ValueError(
                f"max_range_m {self.max_range_m!r} must be finite and above threshold_m "
                f"{self.threshold_m}"
            )
        if not (math.isfinite(self.near_range_m) and 0.0 <= self.near_range_m < self.min_range_m):
            raise ValueError(
                f"near_range_m {self.near_range_m!r} must be in [0, min_range_m {self.min_range_m})"
            )
        if self.prefilter_sigma_px is not None and not (
            math.isfinite(self.prefilter_sigma_px) and self.prefilter_sigma_px >= 0.0
        ):
            raise ValueError(f"prefilter_sigma_px must be >= 0, got {self.prefilter_sigma_px!r}")
        if not (math.isfinite(self.min_edge_ratio) and 0.0 <= self.min_edge_ratio < 1.0):
            raise ValueError(f"min_edge_ratio must be in [0, 1), got {self.min_edge_ratio!r}")
        if self.lr_max_diff_px < -1:
            raise ValueError(f"lr_max_diff_px must be >= -1, got {self.lr_max_diff_px}")
        if self.min_range_m >= self.threshold_m:
            raise ValueError(
                f"min_range_m {self.min_range_m} must be below threshold_m {self.threshold_m}"
            )
        if self.block_size_px is not None and not (
            5 <= self.block_size_px <= 255 and self.block_size_px % 2 == 1
        ):
            raise ValueError(f"block_size_px must be odd in 5..255, got {self.block_size_px}")
        if self.max_points < 16:
            raise ValueError(f"max_points must be >= 16, got {self.max_points}")
        if self.opening_px < 1:
            raise ValueError(f"opening_px must be >= 1, got {self.opening_px}")
        if not 0.0 < self.max_half_angle_deg < 90.0:
            raise ValueError(
                f"max_half_angle_deg must be in (0, 90), got {self.max_half_angle_deg}"
            )

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> PerceptionConfig:
        """Build from a mapping (e.g. a config file section); unknown keys are an error.

        Raises
        ------
        TypeError
            Naming every key that is not a field.
        """
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise TypeError(
                f"unknown perception config key(s) {unknown}; valid keys: {sorted(names)}"
            )
        return cls(**values)


@dataclass(frozen=True, eq=False)
class Obstacle:
    """One detected obstacle and its collision safety boundary.

    Attributes
    ----------
    center_ned_m : numpy.ndarray
        Boundary sphere centre in LOCAL_NED [m], shape (3,), read-only.
    radius_m : float
        Boundary radius [m]: ``raw_radius_m + vehicle_radius_m + safety_margin_m``.
    raw_radius_m : float
        Estimated obstacle radius [m] (blind spot included, every measured point enclosed).
    nearest_range_m : float
        Range from the left camera to the obstacle's nearest measured surface [m].
    n_pixels : int
        Pixels of the obstacle's region (its surface out to ``threshold + extent_margin``).
    n_near_pixels : int
        Of those, pixels nearer than the threshold after filtering.
    truncated : bool
        The region touches the image border or the unmatched left band: the obstacle may
        extend beyond what was seen.
    """

    center_ned_m: np.ndarray
    radius_m: float
    raw_radius_m: float
    nearest_range_m: float
    n_pixels: int
    n_near_pixels: int
    truncated: bool


@dataclass(frozen=True, eq=False)
class PerceptionResult:
    """Everything one frame says about obstacles.

    Attributes
    ----------
    sequence : int
        The frame's sequence number.
    capture_ns : int
        The frame's capture time [ns] (the pose used is the one at this time).
    obstacles : tuple of Obstacle
        Sorted by ``nearest_range_m`` (nearest first).
    unknown_fraction : float
        Fraction of the image whose ``depth_m`` is unknown (NaN): never free space.
    depth_m : numpy.ndarray
        ``(H, W)`` float32 depth along the left camera's optical axis [m] (Eq. 27,
        ``f·b / d``), read-only; NaN = unknown: unmatched (textureless, occluded, failed
        the left/right or uniqueness checks), outside the right camera's view, or too near
        to measure; +inf = matched beyond ``max_range_m``: nothing nearer along that ray
        (never within ``blind_band_px`` of the left edge, where that is NaN).
    counts : ValidityCounts
        How many pixels are known, and why the others are not.
    blind_band_px : int
        Left image columns where the right camera cannot see a surface at the nearest
        range the matcher measures (its disparity range plus half a block): depth there may
        be known, but an unmatched pixel is never "open sky" (companion.known_space).
    """

    sequence: int
    capture_ns: int
    obstacles: tuple[Obstacle, ...]
    unknown_fraction: float
    depth_m: np.ndarray
    counts: ValidityCounts
    blind_band_px: int = 0


@dataclass(frozen=True)
class ValidityCounts:
    """Pixel counts of one frame's depth map; the four add up to the image area.

    Attributes
    ----------
    n_valid : int
        Pixels with a depth in ``[min_range_m, max_range_m]`` (roughly: the matcher's range).
    n_unmatched : int
        No match: textureless, occluded, inconsistent, or outside the right camera's view.
    n_beyond_range : int
        Matched farther than ``max_range_m`` (sky, distant ground): ``depth_m`` +inf, no
        surface within range (NaN inside the blind band).
    n_too_near : int
        Of ``n_valid``: nearer than ``min_range_m``, ranged by the coarse pass only.
    n_coarse : int
        Of ``n_valid``: holes of the main pass within its range filled by the coarse pass.
    """

    n_valid: int
    n_unmatched: int
    n_beyond_range: int
    n_too_near: int
    n_coarse: int


def _sample_stride(n_pixels: int, max_points: int) -> int:
    """Grid stride for about ``max_points`` samples of a region of ``n_pixels`` pixels."""
    return max(1, math.ceil(math.sqrt(n_pixels / max_points)))


def _region_contour(fill: np.ndarray, value: int, rect: tuple[int, int, int, int]) -> np.ndarray:
    """Outer contour pixels (x, y) of fill region ``value`` in ``rect``, shape (n, 2), int32.

    Coordinates are relative to the rect's corner; ``fill`` is the flood-fill mask (one pixel
    of padding on every side).
    """
    x0, y0, w, h = rect
    region = (fill[y0 + 1 : y0 + h + 1, x0 + 1 : x0 + w + 1] == value).view(np.uint8)
    contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return np.concatenate([c.reshape(-1, 2) for c in contours], axis=0)


@numba.njit(cache=True)
def _blob_seeds(labels, disp, n_labels):
    """Nearest pixel of every label: its largest disparity, the first in raster order on ties.

    ``labels`` (int32) and ``disp`` (int16, the same shape) cover the same box; returns
    (seed_x, seed_y) indexed by label, box-relative (label 0, the background, is unused).
    Equals ``argmax(where(labels == label, disp, -1))`` over the label's bounding box, since a
    blob's pixels are near ones (disparity > 0).
    """
    best = np.full(n_labels, -1, np.int32)
    seed_x = np.zeros(n_labels, np.intp)
    seed_y = np.zeros(n_labels, np.intp)
    for y in range(labels.shape[0]):
        for x in range(labels.shape[1]):
            label = labels[y, x]
            if label > 0 and disp[y, x] > best[label]:
                best[label] = disp[y, x]
                seed_x[label] = x
                seed_y[label] = y
    return seed_x, seed_y


@numba.njit(cache=True)
def _region_samples(fill, value, x0, y0, w, h, stride, edge, near, disp_px):
    """Sample points of one flood-fill region and its count of near pixels.

    The region is ``fill[y0 + 1 + j, x0 + 1 + i] == value`` for ``0 <= i < w, 0 <= j < h``
    (``fill`` has one pixel of padding). Samples are the regular grid of the rect with step
    ``stride`` (raster order, as ``np.nonzero(region[::stride, ::stride])``), then the
    rect-relative outer contour points ``edge`` (shape (m, 2), x then y; empty when
    ``stride == 1``: the grid is then every pixel). The grid carries the mean bearing and the
    nearest range; the contour carries the angular extremes and the farthest points exactly.

    Returns
    -------
    xs, ys : int arrays
        Sample coordinates in the ``fill``-less image (``near``/``disp_px`` indices).
    disp : float64 array
        ``disp_px`` at the samples [px].
    n_grid : int
        The first ``n_grid`` samples are the grid.
    n_near : int
        Region pixels that are set in ``near``.
    """
    n_max = ((h + stride - 1) // stride) * ((w + stride - 1) // stride) + edge.shape[0]
    xs = np.empty(n_max, np.intp)
    ys = np.empty(n_max, np.intp)
    n = 0
    n_near = 0
    for j in range(h):
        on_grid_row = j % stride == 0
        for i in range(w):
            if fill[y0 + 1 + j, x0 + 1 + i] == value:
                if near[y0 + j, x0 + i]:
                    n_near += 1
                if on_grid_row and i % stride == 0:
                    xs[n] = x0 + i
                    ys[n] = y0 + j
                    n += 1
    n_grid = n
    for e in range(edge.shape[0]):
        xs[n] = x0 + edge[e, 0]
        ys[n] = y0 + edge[e, 1]
        n += 1
    disp = np.empty(n)
    for s in range(n):
        disp[s] = disp_px[ys[s], xs[s]]
    return xs[:n], ys[:n], disp, n_grid, n_near


@numba.njit(cache=True, error_model="numpy")
def _fit_sphere(xs, ys, n_grid, disp, fx, fy, cx, cy, fb, cap_depth_m, max_half_angle_rad):
    """Blind-spot sphere (Fig. 4, see the module docstring) of sampled region pixels.

    ``xs``, ys`` are pixel coordinates, ``disp`` their disparities [px] (all > 0), the first
    ``n_grid`` samples the regular grid (they alone give the centre bearing); ``fx .. cy``
    the left camera's intrinsics [px], ``fb`` focal length × baseline [m·px]. One pass per
    quantity over the points, no temporaries but the bearings and ranges.

    Returns
    -------
    nearest_m : float
        1st percentile of the ranges [m] (the nearest surface, robust to a few outliers).
    center_cam : numpy.ndarray
        Sphere centre in the left camera frame [m], shape (3,).
    raw_radius_m : float
        ``max(R, distance from the centre to the farthest point)`` [m].
    """
    n = xs.shape[0]
    inv_fx = 1.0 / fx
    inv_fy = 1.0 / fy
    bearings = np.empty((n, 3))
    range_m = np.empty(n)
    for s in range(n):
        xn = (xs[s] - cx) * inv_fx
        yn = (ys[s] - cy) * inv_fy
        norm = math.sqrt(xn * xn + yn * yn + 1.0)
        range_m[s] = (fb * norm) / disp[s]  # Eq. (27) depth times ray length
        bearings[s, 0] = xn / norm
        bearings[s, 1] = yn / norm
        bearings[s, 2] = 1.0 / norm
    rank = int(0.01 * (n - 1))
    nearest_m = np.partition(range_m, rank)[rank]
    # Centre bearing: the mean bearing of the nearest cap (grid samples within cap_depth_m
    # of the nearest surface); a sphere's nearest cap is centred on the camera→centre line,
    # so this stays unbiased when the image border cuts the silhouette. No cap: whole grid.
    cap_m = nearest_m + max(cap_depth_m, 0.03 * nearest_m)
    axis = np.zeros(3)
    in_cap = 0
    for s in range(n_grid):
        if range_m[s] <= cap_m:
            in_cap += 1
            for c in range(3):
                axis[c] += bearings[s, c]
    if in_cap == 0:
        for s in range(n_grid):
            for c in range(3):
                axis[c] += bearings[s, c]
    axis /= math.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
    # Angular half-width about the axis: the widest sample.
    cos_min = np.inf
    for s in range(n):
        cos_s = bearings[s, 0] * axis[0] + bearings[s, 1] * axis[1] + bearings[s, 2] * axis[2]
        cos_min = min(cos_min, cos_s)
    half_angle = min(math.acos(min(1.0, max(-1.0, cos_min))), max_half_angle_rad)
    sin_a = math.sin(half_angle)
    radius_fit_m = nearest_m * sin_a / (1.0 - sin_a)
    center_cam = axis * (nearest_m + radius_fit_m)
    # Enclose every measured point.
    farthest_sq = 0.0
    for s in range(n):
        d_sq = 0.0
        for c in range(3):
            d = bearings[s, c] * range_m[s] - center_cam[c]
            d_sq += d * d
        farthest_sq = max(farthest_sq, d_sq)
    return nearest_m, center_cam, max(radius_fit_m, math.sqrt(farthest_sq))


@numba.njit(cache=True)
def _merge_depth(disp, coarse, has_coarse, top, d_far, fb16, depth, too_near, far_from_col):
    """Coarse pass into the main disparity (both int16, 1/16 px, negative = unmatched), in
    place, and the depth map ``fb16 / disp``: NaN where unmatched; a match below ``d_far``
    (farther than the range) is +inf from column ``far_from_col`` on (nothing nearer than
    the range along that ray) and NaN left of it, where a far match cannot be told from a
    false match into the band the right camera cannot see.

    Returns (n_valid, n_unmatched, n_coarse, n_too_near); ``too_near`` (uint8) marks the
    pixels the coarse pass ranged nearer than the main range (``> top``).
    """
    n_valid = 0
    n_unmatched = 0
    n_coarse = 0
    n_too_near = 0
    for y in range(disp.shape[0]):
        for x in range(disp.shape[1]):
            d = disp[y, x]
            if has_coarse:
                c = coarse[y, x]
                if c > top and c > d:
                    d = c
                    too_near[y, x] = 1
                    n_too_near += 1
                elif d < 0 and c >= 0:
                    d = c
                    n_coarse += 1
                disp[y, x] = d
            if d >= d_far:
                depth[y, x] = fb16 / d
                n_valid += 1
            elif d >= 0 and x >= far_from_col:
                depth[y, x] = np.inf
            else:
                depth[y, x] = np.nan
                if d < 0:
                    n_unmatched += 1
    return n_valid, n_unmatched, n_coarse, n_too_near


@functools.cache
def _warm_up() -> None:
    """Run every per-obstacle step once per process, on a tiny input with the argument types
    :meth:`StereoPerception.process` uses: compiles (or loads from numba's cache) the kernels
    and pays OpenCV's first-call costs, so the first frame with an obstacle does not
    (~20 ms from numba's cache, ~1 ms in OpenCV)."""
    mask = np.zeros((4, 4), np.uint8)
    mask[1:3, 1:3] = 1
    cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    _, labels, _, _ = cv2.connectedComponentsWithStats(mask[1:3, 1:3], connectivity=8)
    disp = np.full((3, 3), 16, np.int16)
    _blob_seeds(labels, disp[1:, 1:], 2)  # a strided view, like the labelled box
    fill = np.zeros((4, 4), np.uint8)
    disp_px = np.ones((2, 2), np.float32)
    cv2.floodFill(
        disp_px,
        fill,
        (0, 0),
        0,
        loDiff=0.5,
        upDiff=0.5,
        flags=8 | cv2.FLOODFILL_MASK_ONLY | (1 << 8),
    )
    for edge in (_NO_EDGE, _region_contour(fill, 1, (0, 0, 2, 2))):
        xs, ys, disp_s, n_grid, _ = _region_samples(
            fill, 1, 0, 0, 2, 2, 1, edge, mask[1:3, 1:3].copy(), disp_px
        )
    _fit_sphere(2 * xs, 2 * ys, n_grid, disp_s, 1.0, 1.0, 0.0, 0.0, 1.0, 0.1, 1.0)
    main = np.full((6, 8), -16, np.int16)[1:5, 2:6]  # a view, like the cropped matcher output
    _merge_depth(
        main,
        main.copy(),
        True,
        16,
        1,
        16.0,
        np.empty((4, 4), np.float32),
        np.zeros((4, 4), np.uint8),
        2,
    )


def _padded(image: np.ndarray, pad_x: int, pad_y: int) -> np.ndarray:
    """``image`` with ``pad_x`` black columns on the left and ``pad_y`` replicated rows/columns
    on the other sides.

    OpenCV's matchers compute nothing in the leftmost ``numDisparities`` columns and the
    half-block border; on the padded pair every real pixel is searched over the full range,
    and a match into the black band (outside the right camera's view) has no texture to lock
    on, fails the left/right check, or is refused by :meth:`StereoPerception.disparity_fixed`.
    """
    out = cv2.copyMakeBorder(image, pad_y, pad_y, pad_x, pad_y, cv2.BORDER_REPLICATE)
    out[:, :pad_x] = 0
    return out


def noise_sigma(image: np.ndarray) -> float:
    """Sensor noise standard deviation of a grey image [grey levels] (Immerkær 1996: the mean
    absolute response to a Laplacian-difference mask that cancels smooth image structure)."""
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    # A central third of the rows is plenty for one number, at a third of the cost.
    rows = image.shape[0]
    response = cv2.filter2D(image[rows // 3 : 2 * rows // 3 + 2], cv2.CV_32F, kernel)[1:-1, 1:-1]
    return float(math.sqrt(math.pi / 2.0) / 6.0 * cv2.mean(np.abs(response))[0])


def _horizontal_edges(image: np.ndarray, block: int, ratio: float) -> np.ndarray:
    """Pixels whose block has less than ``ratio`` times as much horizontal as vertical
    gradient: near-horizontal edges, which only a perfect rectification matches right."""
    dx, dy = cv2.spatialGradient(image)  # 3x3 Sobel, both directions in one pass
    gx = cv2.convertScaleAbs(dx)
    gy = cv2.convertScaleAbs(dy)
    ax = cv2.blur(gx, (block, block))
    ay = cv2.blur(gy, (block, block))
    # ax < ratio·ay as ax / ratio < ay in uint8: where ax / ratio saturates, ay (<= 255)
    # cannot exceed it, which is the right answer.
    return cv2.compare(cv2.convertScaleAbs(ax, alpha=1.0 / ratio), ay, cv2.CMP_LT).view(bool)


def _auto_block_size(width_px: int) -> int:
    size = round(9 * width_px / _REFERENCE_WIDTH_PX)
    return int(min(max(size | 1, 5), 255))


class StereoPerception:
    """Stereo frames → obstacles with safety boundaries in NED.

    Holds the OpenCV matcher(s), built once per image geometry and reused across frames;
    otherwise stateless: :meth:`process` is a function of its arguments (no clock, no I/O).

    Parameters
    ----------
    config : PerceptionConfig, optional
        Detector settings.
    """

    def __init__(self, config: PerceptionConfig | None = None):
        self.config = config if config is not None else PerceptionConfig()
        self._matchers: dict[tuple[int, int, int], cv2.StereoMatcher] = {}
        self._kernel = cv2.getStructuringElement(
            cv2.MORPH_RECT, (self.config.opening_px, self.config.opening_px)
        )
        _warm_up()

    def num_disparities(self, intrinsics: StereoIntrinsics) -> int:
        """Disparity search range [px]: ``f·b / min_range_m`` rounded up to a multiple of 16."""
        d_max = intrinsics.focal_baseline_m_px / self.config.min_range_m
        return int(16 * max(1, math.ceil(d_max / 16.0)))

    def block_size(self, intrinsics: StereoIntrinsics) -> int:
        """Matching block size [px] for this image width."""
        return self.config.block_size_px or _auto_block_size(intrinsics.width_px)

    def _matcher(self, intrinsics: StereoIntrinsics) -> tuple[cv2.StereoMatcher, int, int]:
        cfg = self.config
        n_disp = self.num_disparities(intrinsics)
        block = self.block_size(intrinsics)
        key = (intrinsics.width_px, n_disp, block)
        matcher = self._matchers.get(key)
        if matcher is None:
            matcher = cv2.StereoBM_create(numDisparities=n_disp, blockSize=block)
            matcher.setTextureThreshold(cfg.texture_threshold)
            matcher.setUniquenessRatio(cfg.uniqueness_ratio)
            matcher.setSpeckleWindowSize(cfg.speckle_window_px)
            matcher.setSpeckleRange(cfg.speckle_range_px)
            matcher.setDisp12MaxDiff(cfg.lr_max_diff_px)
            self._matchers[key] = matcher
        return matcher, n_disp, block

    def disparity_fixed(self, frame: StereoFrame) -> np.ndarray:
        """Disparity of the frame's left image: int16, 1/16 px units, negative where unmatched.

        The pair is padded before matching so that every column is searched (see
        :func:`_padded`); a pixel whose match would lie left of the right image (outside the
        right camera's view) is unmatched.
        """
        if frame.encoding is not PixelEncoding.MONO8:
            raise ValueError(f"unsupported pixel encoding {frame.encoding!r}")
        matcher, n_disp, block = self._matcher(frame.intrinsics)
        height, width = frame.left.shape
        left, right = self._prefiltered(frame)
        # Half a block on each side; more on a frame shorter than a block (OpenCV refuses it).
        pad_x, pad_y = n_disp, max(block // 2, (block + 2 - height) // 2)
        out = matcher.compute(_padded(left, pad_x, pad_y), _padded(right, pad_x, pad_y))
        disp = out[pad_y : pad_y + height, pad_x : pad_x + width]
        if self.config.min_edge_ratio > 0.0:
            # Aperture: along a near-horizontal edge a match is only as good as the
            # rectification (a 2 px vertical error on a 5° edge shifts it by 23 px).
            disp[_horizontal_edges(left, block, self.config.min_edge_ratio)] = -_DISP_SCALE
        # The right camera sees column x - d only if x - d >= 0; a match whose right block
        # reaches into the black band (x - d < half a block + _EDGE_MARGIN_PX) leans on it
        # and is as likely wrong as right: unknown too.
        margin = block // 2 + _EDGE_MARGIN_PX
        n_band = min(n_disp + margin, width)
        band = disp[:, :n_band]
        limit = _DISP_SCALE * (np.arange(n_band, dtype=np.int16) - margin)
        band[band > limit] = -_DISP_SCALE
        return disp

    def prefilter_sigma_px(self, frame: StereoFrame) -> tuple[float, float]:
        """Gaussian prefilter sigmas (x, y) [px] for this frame: ``prefilter_sigma_px`` if
        set, else from the left image's estimated sensor noise (:func:`noise_sigma`)."""
        cfg = self.config
        if cfg.prefilter_sigma_px is not None:
            return cfg.prefilter_sigma_px, cfg.prefilter_sigma_px
        noise = noise_sigma(frame.left)
        extra = min(_PREFILTER_PER_NOISE * max(0.0, noise - _NOISE_FLOOR), _PREFILTER_MAX_PX)
        return _PREFILTER_BASE_PX + extra, _PREFILTER_BASE_PX + extra

    def _prefiltered(self, frame: StereoFrame) -> tuple[np.ndarray, np.ndarray]:
        sx, sy = self.prefilter_sigma_px(frame)
        if max(sx, sy) < 0.3:
            return frame.left, frame.right
        # Kernels of ±2 sigma: OpenCV's fixed-point path for uint8 (the tails carry < 5 %).
        ksize = (2 * math.ceil(2.0 * sx) + 1, 2 * math.ceil(2.0 * sy) + 1)
        return tuple(  # type: ignore[return-value]
            cv2.GaussianBlur(im, ksize, sigmaX=sx, sigmaY=sy, borderType=cv2.BORDER_REPLICATE)
            for im in (frame.left, frame.right)
        )

    def coarse_disparity_fixed(self, frame: StereoFrame) -> np.ndarray | None:
        """Coarse pass: full-resolution int16 disparity (1/16 px, each coarse pixel repeated
        over its 4 × 4 block), -16 where unmatched; ``None`` when disabled.

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
            matcher.setSpeckleRange(1)
            matcher.setDisp12MaxDiff(max(cfg.lr_max_diff_px, 0))
            self._matchers[key] = matcher
        pad_y = max(_NEAR_BLOCK_PX // 2, (_NEAR_BLOCK_PX + 2 - h4) // 2)
        small = [
            _padded(cv2.resize(im, (w4, h4), interpolation=cv2.INTER_AREA), n_disp, pad_y)
            for im in (frame.left, frame.right)
        ]
        coarse = matcher.compute(small[0], small[1])[pad_y : pad_y + h4, n_disp : n_disp + w4]
        band = coarse[:, : min(n_disp, w4)]
        band[band > _DISP_SCALE * np.arange(band.shape[1], dtype=np.int16)] = -_DISP_SCALE
        coarse = np.ascontiguousarray(coarse)
        np.multiply(coarse, _NEAR_SCALE, out=coarse, where=coarse >= 0)
        up = cv2.resize(
            coarse, (_NEAR_SCALE * w4, _NEAR_SCALE * h4), interpolation=cv2.INTER_NEAREST
        )
        if up.shape == (height, width):
            return up
        out = np.full((height, width), -_DISP_SCALE, np.int16)
        out[: _NEAR_SCALE * h4, : _NEAR_SCALE * w4] = up
        return out

    def process(self, frame: StereoFrame, pos_ned_m, R_ned_from_frd) -> PerceptionResult:
        """Detect obstacles in ``frame`` and place their safety spheres in NED.

        Parameters
        ----------
        frame : StereoFrame
            Decoded rectified pair with its intrinsics and capture time.
        pos_ned_m : array_like, shape (3,)
            Vehicle position in LOCAL_NED at ``frame.capture_ns`` [m].
        R_ned_from_frd : array_like, shape (3, 3)
            Body FRD → NED rotation at ``frame.capture_ns``.

        Returns
        -------
        PerceptionResult
        """
        cfg = self.config
        k = frame.intrinsics
        disp = self.disparity_fixed(frame)
        height, width = disp.shape
        fb = k.focal_baseline_m_px
        coarse = self.coarse_disparity_fixed(frame)
        # columns the right camera cannot see at the nearest measured range
        band_px = self.num_disparities(k) + (cfg.block_size_px or _auto_block_size(width)) // 2
        depth_m, counts = self._merge(disp, coarse, fb, self.num_disparities(k), band_px)
        unknown_fraction = float(np.count_nonzero(np.isnan(depth_m))) / disp.size

        def result(obstacles: tuple[Obstacle, ...]) -> PerceptionResult:
            return PerceptionResult(
                frame.sequence,
                frame.capture_ns,
                obstacles,
                unknown_fraction,
                depth_m,
                counts,
                band_px,
            )

        # Integer disparities: d >= x  <=>  d >= ceil(x), compared in int16 (no float copy).
        near = (disp >= math.ceil(_DISP_SCALE * fb / cfg.threshold_m)).view(np.uint8)
        if cv2.countNonZero(near) == 0:  # the common empty frame: nothing to open or label
            return result(())
        if cfg.opening_px > 1:
            near = cv2.morphologyEx(near, cv2.MORPH_OPEN, self._kernel)
        # Blobs on a 2x subsampled mask: 4x cheaper labelling; areas count 4 pixels each.
        near_half = np.ascontiguousarray(near[::2, ::2])
        # Label only the bounding box of the mask (same components, same raster-order labels);
        # stats are shifted back to the half-resolution image, labels stay box-relative.
        bx, by, bw, bh = cv2.boundingRect(near_half)
        if bw == 0:
            return result(())
        n_labels, labels, stats, _ = cv2.connectedComponentsWithStats(
            near_half[by : by + bh, bx : bx + bw], connectivity=8
        )
        min_area = max(1, math.ceil(cfg.min_blob_fraction * width * height / 4.0))
        blobs = [i for i in range(1, n_labels) if stats[i, cv2.CC_STAT_AREA] >= min_area]
        if not blobs:
            return result(())

        # Depth-continuous flood fill from each blob out to threshold + extent margin, on
        # the same 2x subsampled grid as the blobs: a quarter of the pixels to convert and
        # fill, and the sphere fit samples at most ``max_points`` of them anyway.
        d_far = fb / (cfg.threshold_m + cfg.extent_margin_m)
        disp_half = disp[::2, ::2]
        disp_px = disp_half.astype(np.float32)
        disp_px *= 1.0 / _DISP_SCALE
        # Invalid and far pixels stop the fill: d / 16 < float32(d_far), in integers.
        disp_px[disp_half < math.ceil(_DISP_SCALE * float(np.float32(d_far)))] = -1.0e6
        h_half, w_half = disp_px.shape
        fill = np.zeros((h_half + 2, w_half + 2), np.uint8)
        step_px = cfg.continuity_rel * fb / cfg.threshold_m
        b_m = k.baseline_m
        regions: list[tuple[int, tuple[int, int, int, int], int]] = []
        seed_x, seed_y = _blob_seeds(labels, disp_half[by : by + bh, bx : bx + bw], n_labels)
        # Largest blob first, so the obstacle numbering is deterministic and meaningful.
        for label in sorted(blobs, key=lambda i: (-stats[i, cv2.CC_STAT_AREA], i)):
            seed = (int(bx + seed_x[label]), int(by + seed_y[label]))  # nearest blob pixel
            # A square of side s at the blob's depth spans s·d/b pixels (d = f·b/z).
            # Capped: a near surface's coverage is patchy, mismatch clusters stay small.
            side_px = min(
                cfg.min_obstacle_size_m * disp_half[seed[1], seed[0]] / (_DISP_SCALE * b_m),
                _MIN_SIDE_CAP_PX * width / _REFERENCE_WIDTH_PX,
            )
            if 4 * stats[label, cv2.CC_STAT_AREA] < side_px * side_px:
                continue  # smaller than the smallest obstacle reported: a mismatch cluster
            if fill[seed[1] + 1, seed[0] + 1] or len(regions) >= 254:
                continue  # same surface as an earlier blob (one obstacle), or too many
            value = len(regions) + 1
            flags = 8 | cv2.FLOODFILL_MASK_ONLY | (value << 8)
            area, _, _, rect = cv2.floodFill(
                disp_px, fill, seed, 0, loDiff=step_px, upDiff=step_px, flags=flags
            )
            blob_area = int(stats[label, cv2.CC_STAT_AREA])
            if 2 * area < blob_area:
                # The nearest pixel was a lone wrong match (no depth-continuous neighbours):
                # fill again from the blob's pixel of median disparity.
                x, y, w, h = (int(v) for v in stats[label, :4])
                ys, xs = np.nonzero(labels[y : y + h, x : x + w] == label)
                d = disp_half[by + y + ys, bx + x + xs]
                pick = int(np.argsort(d, kind="stable")[len(d) // 2])
                seed = (int(bx + x + xs[pick]), int(by + y + ys[pick]))
                if not fill[seed[1] + 1, seed[0] + 1]:
                    area, _, _, rect = cv2.floodFill(
                        disp_px, fill, seed, 0, loDiff=step_px, upDiff=step_px, flags=flags
                    )
            regions.append((value, rect, int(area)))

        obstacles = []
        for value, rect, n_half in regions:
            x0, y0, w, h = rect
            # n_half (the fill's area) is the region's pixel count: later fills never overwrite.
            stride = _sample_stride(n_half, cfg.max_points)
            edge = _region_contour(fill, value, rect) if stride > 1 else _NO_EDGE
            xs, ys, disp_samples, n_grid, n_near = _region_samples(
                fill, value, x0, y0, w, h, stride, edge, near_half, disp_px
            )
            truncated = bool(
                x0 <= 0 or y0 <= 0 or 2 * (x0 + w) >= width - 1 or 2 * (y0 + h) >= height - 1
            )
            obstacles.append(
                self._boundary(
                    2 * xs,
                    2 * ys,
                    n_grid,
                    disp_samples,
                    k,
                    pos_ned_m,
                    R_ned_from_frd,
                    4 * n_half,
                    4 * n_near,
                    truncated,
                )
            )
        obstacles.sort(key=lambda o: (o.nearest_range_m, tuple(o.center_ned_m)))
        return result(tuple(obstacles))

    def _merge(
        self,
        disp: np.ndarray,
        coarse: np.ndarray | None,
        fb: float,
        n_disp: int,
        band_px: int,
    ) -> tuple[np.ndarray, ValidityCounts]:
        """Merge the coarse pass into ``disp`` (in place) and make the depth map.

        Holes of the main pass within its range take the coarse disparity; where the coarse
        pass sees a surface nearer than the main range (the main pass missed it or aliased
        it to a smaller disparity) it wins, and main-pass matches within ``_NEAR_HALO_PX``
        of it are unknown (as likely aliased as right). One compiled pass over the pixels.
        """
        d_far = max(1, math.ceil(_DISP_SCALE * fb / self.config.max_range_m))
        depth = np.empty(disp.shape, np.float32)
        too_near = np.zeros(disp.shape, np.uint8)
        has_coarse = coarse is not None
        n_valid, n_unmatched, n_coarse, n_too_near = _merge_depth(
            disp,
            coarse if has_coarse else disp,
            has_coarse,
            _DISP_SCALE * (n_disp - 1),
            d_far,
            float(_DISP_SCALE * fb),
            depth,
            too_near,
            band_px,
        )
        if n_too_near:
            halo = cv2.dilate(too_near, _NEAR_HALO).view(bool) & (too_near == 0)
            halo &= disp >= 0
            n_halo = int(np.count_nonzero(halo))
            if n_halo:
                n_valid -= int(np.count_nonzero(halo & (disp >= d_far)))
                n_unmatched += n_halo
                disp[halo] = -_DISP_SCALE
                depth[halo] = np.nan
        depth.flags.writeable = False
        counts = ValidityCounts(
            n_valid=n_valid,
            n_unmatched=n_unmatched,
            n_beyond_range=disp.size - n_valid - n_unmatched,
            n_too_near=n_too_near,
            n_coarse=n_coarse,
        )
        return depth, counts

    def _boundary(
        self,
        xs: np.ndarray,
        ys: np.ndarray,
        n_grid: int,
        disp_px: np.ndarray,
        k: StereoIntrinsics,
        pos_ned_m,
        R_ned_from_frd,
        n_pixels: int,
        n_near: int,
        truncated: bool,
    ) -> Obstacle:
        """Safety sphere of one region (Fig. 4 blind-spot model, see the module docstring)."""
        cfg = self.config
        nearest_m, center_cam, raw_radius_m = _fit_sphere(
            xs,
            ys,
            n_grid,
            disp_px,
            float(k.fx_px),
            float(k.fy_px),
            float(k.cx_px),
            float(k.cy_px),
            float(k.focal_baseline_m_px),
            float(cfg.cap_depth_m),
            math.radians(cfg.max_half_angle_deg),
        )
        center_ned = points_ned_from_cam(center_cam, pos_ned_m, R_ned_from_frd, k.baseline_m)
        center_ned.flags.writeable = False
        return Obstacle(
            center_ned_m=center_ned,
            radius_m=raw_radius_m + cfg.vehicle_radius_m + cfg.safety_margin_m,
            raw_radius_m=raw_radius_m,
            nearest_range_m=nearest_m,
            n_pixels=n_pixels,
            n_near_pixels=n_near,
            truncated=truncated,
        )
