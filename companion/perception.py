"""Stereo perception (paper §4–5): disparity → depth (Eq. 27) → obstacles → safety spheres in NED.

Pipeline for one rectified frame (:meth:`StereoPerception.process`):

1. Depth: a depth source (:mod:`companion.depth_source`: rectified pair in, disparity,
   depth and validity out) — by default :class:`~companion.stereo_bm.PaddedStereoBM`:
   OpenCV ``StereoBM`` on the pair padded so that every column that can hold an obstacle
   pixel is searched, gated by left/right consistency, uniqueness, texture and edge
   checks, plus a quarter-resolution pass for surfaces nearer than ``min_range_m`` (SGBM
   was retired, see :class:`Matcher`).
   The result is the **depth map** ``depth_m`` (NaN = unknown, see below).
2. Obstacle pixels: valid disparity ``d ≥ f·b / threshold_m`` (depth below the threshold,
   Eq. 27, compared in disparity space so no per-pixel division).
3. Noise filter: a morphological opening, then connected components
   (``cv2.connectedComponents``) smaller than ``min_blob_fraction`` of the image are
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
occluded, inconsistent), outside the right camera's view, an isolated far match, or nearer
than even the coarse pass reaches; +inf where matched beyond ``max_range_m``. Unknown is
never free: the known-space model of the safety envelope consumes this map;
:class:`ValidityCounts` says how many pixels are unknown and why. Obstacles are built only
from known depth; each says whether it was ``truncated`` by the image border (then its true
extent may be larger than estimated).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numba
import numpy as np

from companion.depth_camera import DepthCameraConfig, DepthCameraSource
from companion.depth_source import DISP_SCALE as _DISP_SCALE
from companion.depth_source import DepthMap, DepthSource, ValidityCounts
from companion.stereo_bm import PaddedStereoBM
from protocols.camera import StereoIntrinsics, points_ned_from_cam
from protocols.config import ConfigError, bounded, check_fields, dataclass_from_mapping
from protocols.stereo_frame import Frame, PixelEncoding

__all__ = [
    "DepthMap",
    "DepthSource",
    "Matcher",
    "Obstacle",
    "PerceptionConfig",
    "PerceptionResult",
    "StereoPerception",
    "ValidityCounts",
]

_REFERENCE_WIDTH_PX = 320  # the paper's camera; block size scales from it
_MIN_SIDE_CAP_PX = 20.0  # the size gate never asks for more than a 20 px square (at 320 px)
_NO_EDGE = np.zeros((0, 2), np.int32)  # no contour samples (stride 1: the grid is every pixel)
_MAX_SPECKLE_RANGE_PX = 1024.0  # beyond any disparity search; keeps 16 x it a C int for OpenCV


_C_INT_MAX = 2**31 - 1  # OpenCV takes the matcher's integer settings as C ints


def _depth_camera(values: Any, where: str) -> DepthCameraConfig:
    if isinstance(values, DepthCameraConfig):
        return values
    return DepthCameraConfig.from_dict(values, where)


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
        OpenCV speckle filter: a region of similar disparity smaller than this [px, at
        320 × 240; scaled with the image area] is refused. Sensor noise on a textureless
        surface forms such regions of up to ~220 px with random (often too far) disparity;
        200 px removed all of them in 30 frames of a textureless wall (100 px let 7 through).
    speckle_range_px : float
        OpenCV speckle filter: neighbours whose disparities differ by at most this [px] are
        one region. StereoBM applies it to its 1/16 px fixed-point output (it does not scale
        it, unlike SGBM), so it is passed as ``round(16 · speckle_range_px)``; the default
        3/16 px is the tuned value (the config took OpenCV's raw 3 as "px" before).
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
    position_uncertainty_m : float
        Least uncertainty of the position estimate [m]: the vehicle counts this much wider
        in boundaries, paths and the swept section (:mod:`companion.position_uncertainty`);
        the autopilot's stated accuracy (GPS_RAW_INT ``h_acc``) raises it.
    max_position_uncertainty_m : float
        Most widening the margins take [m]; a stated accuracy beyond it is reported as not
        covered.
    cap_depth_m : float
        Depth of the nearest cap whose mean bearing gives the centre direction [m]
        (at least 3 % of the nearest range).
    min_far_fraction : float
        Smallest connected region of beyond-range matches, as a fraction of the image area,
        whose pixels are reported +inf ("nothing nearer along this ray"); smaller ones are
        unknown. Noise on a textureless wall yields patches of one-pixel disparity (up to
        ~170 px at 320 × 240 over 60 frames): read as +inf, each would certify free space
        through the wall. Sky and distant ground are far larger regions. 0 disables.
    max_points : int
        Interior samples per obstacle for the boundary fit (its outer contour is always used
        whole), which bounds the per-obstacle cost.
    depth_camera : DepthCameraConfig
        Range and noise of a depth camera (``[perception.depth_camera]``), used for frames
        that carry the camera's own depth (:mod:`companion.depth_camera`); the matcher
        settings above are then unused.
    """

    threshold_m: float = bounded(4.0, "m", gt=0)
    matcher: Matcher = Matcher.BM
    min_range_m: float = bounded(1.5, "m", gt=0)
    near_range_m: float = bounded(0.4, "m", ge=0)
    max_range_m: float = bounded(20.0, "m", gt=0)
    block_size_px: int | None = bounded(None, "px", integer=True, ge=5, le=255, optional=True)
    uniqueness_ratio: int = bounded(10, "%", integer=True, ge=0, le=_C_INT_MAX)
    texture_threshold: int = bounded(10, integer=True, ge=0, le=_C_INT_MAX)
    # a speckle larger than the whole reference image (320 × 240) means nothing
    speckle_window_px: int = bounded(200, "px", integer=True, ge=0, le=320 * 240)
    speckle_range_px: float = bounded(0.1875, "px", ge=0, le=_MAX_SPECKLE_RANGE_PX)
    lr_max_diff_px: int = bounded(1, "px", integer=True, ge=-1, le=_C_INT_MAX)
    prefilter_sigma_px: float | None = bounded(None, "px", ge=0, optional=True)
    min_edge_ratio: float = bounded(0.1, ge=0, lt=1)
    opening_px: int = bounded(3, "px", integer=True, ge=1)
    min_blob_fraction: float = bounded(6e-4, gt=0)
    min_obstacle_size_m: float = bounded(0.15, "m", ge=0)
    continuity_rel: float = bounded(0.1, gt=0)
    extent_margin_m: float = bounded(3.0, "m", ge=0)
    max_half_angle_deg: float = bounded(64.0, "deg", gt=0, lt=90)
    vehicle_radius_m: float = bounded(0.35, "m", ge=0)
    safety_margin_m: float = bounded(0.3, "m", ge=0)
    position_uncertainty_m: float = bounded(0.0, "m", ge=0, le=5.0)
    max_position_uncertainty_m: float = bounded(0.5, "m", ge=0, le=5.0)
    max_points: int = bounded(1500, integer=True, ge=16)
    cap_depth_m: float = bounded(0.1, "m", ge=0)
    min_far_fraction: float = bounded(0.01, ge=0, lt=1)
    depth_camera: DepthCameraConfig = dataclasses.field(default_factory=DepthCameraConfig)

    def __post_init__(self) -> None:
        object.__setattr__(self, "matcher", Matcher(self.matcher))
        if not isinstance(self.depth_camera, DepthCameraConfig):
            raise TypeError(
                f"depth_camera must be a DepthCameraConfig, got {type(self.depth_camera).__name__}"
            )
        check_fields(self)
        for key, ok, bound in (
            ("max_range_m", self.max_range_m > self.threshold_m, "above threshold_m"),
            ("min_range_m", self.min_range_m < self.threshold_m, "below threshold_m"),
            ("near_range_m", self.near_range_m < self.min_range_m, "below min_range_m"),
        ):
            if not ok:
                raise ConfigError(f"must be {bound}, got {getattr(self, key)!r}", key=key)
        if self.block_size_px is not None and self.block_size_px % 2 == 0:
            raise ConfigError(f"must be odd, got {self.block_size_px}", key="block_size_px")

    @classmethod
    def from_dict(cls, values: Mapping[str, Any], where: str = "perception") -> PerceptionConfig:
        """Build from a mapping (e.g. a config file section); unknown keys and values out
        of bounds raise :class:`~protocols.config.ConfigError` naming the key."""
        depth_where = f"{where}.depth_camera"
        return dataclass_from_mapping(
            cls,
            values,
            where,
            {"depth_camera": lambda d: _depth_camera(d, depth_where)},
        )


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
    trusted_range_m : float
        How far a +inf pixel vouches for free space [m] (the depth source's range).
    """

    sequence: int
    capture_ns: int
    obstacles: tuple[Obstacle, ...]
    unknown_fraction: float
    depth_m: np.ndarray
    counts: ValidityCounts
    blind_band_px: int = 0
    trusted_range_m: float = math.inf


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
def _label_stats(labels, n_labels):
    """``cv2.connectedComponentsWithStats``' stats of the labels 1 .. ``n_labels`` - 1 of
    ``labels`` (int32): per label, the bounding box's left, top, width and height and the
    area (indexed by ``cv2.CC_STAT_*``); row 0 (the background) is zero, unused. One pass,
    several times cheaper than OpenCV's stats (which also sum centroids in double)."""
    stats = np.zeros((n_labels, 5), np.int32)
    right = np.full(n_labels, -1, np.int32)
    bottom = np.full(n_labels, -1, np.int32)
    for label in range(1, n_labels):
        stats[label, 0] = labels.shape[1]
        stats[label, 1] = labels.shape[0]
    for y in range(labels.shape[0]):
        for x in range(labels.shape[1]):
            label = labels[y, x]
            if label > 0:
                stats[label, 0] = min(stats[label, 0], x)
                stats[label, 1] = min(stats[label, 1], y)
                right[label] = max(right[label], x)
                bottom[label] = max(bottom[label], y)
                stats[label, 4] += 1
    for label in range(1, n_labels):
        stats[label, 2] = right[label] - stats[label, 0] + 1
        stats[label, 3] = bottom[label] - stats[label, 1] + 1
    return stats


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


@functools.cache
def _warm_up() -> None:
    """Run every per-obstacle step once per process, on a tiny input with the argument types
    :meth:`StereoPerception.process` uses: compiles (or loads from numba's cache) the kernels
    and pays OpenCV's first-call costs, so the first frame with an obstacle does not
    (~20 ms from numba's cache, ~1 ms in OpenCV)."""
    mask = np.zeros((4, 4), np.uint8)
    mask[1:3, 1:3] = 1
    cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n_labels, labels = cv2.connectedComponents(mask[1:3, 1:3], connectivity=8)
    _label_stats(labels, n_labels)
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


class StereoPerception:
    """Stereo or depth-camera frames → obstacles with safety boundaries in NED.

    Stateless apart from its depth source's reusable matchers: :meth:`process` is a
    function of its arguments (no clock, no I/O). The frame's pixel encoding picks the depth
    source: a stereo pair (MONO8) goes to the matcher ``source``, a depth frame (DEPTH16,
    DEPTH32F) to ``depth_camera`` (:class:`~companion.depth_camera.DepthCameraSource`).

    Parameters
    ----------
    config : PerceptionConfig, optional
        Detector settings.
    source : DepthSource, optional
        The matcher (:mod:`companion.depth_source` contract); by default
        :class:`~companion.stereo_bm.PaddedStereoBM` with ``config``'s settings.
    """

    def __init__(self, config: PerceptionConfig | None = None, source: DepthSource | None = None):
        self.config = config if config is not None else PerceptionConfig()
        self.source: DepthSource = source if source is not None else PaddedStereoBM(self.config)
        if not isinstance(self.source, DepthSource):
            raise TypeError(
                f"source must have compute(frame) -> DepthMap, got {type(self.source).__name__}"
            )
        self.depth_camera = DepthCameraSource(self.config.depth_camera)
        self._kernel = cv2.getStructuringElement(
            cv2.MORPH_RECT, (self.config.opening_px, self.config.opening_px)
        )
        _warm_up()

    def process(self, frame: Frame, pos_ned_m, R_ned_from_frd) -> PerceptionResult:
        """Detect obstacles in ``frame`` and place their safety spheres in NED.

        Parameters
        ----------
        frame : StereoFrame or DepthFrame
            Decoded rectified pair, or a depth camera's depth, with its intrinsics and
            capture time.
        pos_ned_m : array_like, shape (3,)
            Vehicle position in LOCAL_NED at ``frame.capture_ns`` [m].
        R_ned_from_frd : array_like, shape (3, 3)
            Body FRD → NED rotation at ``frame.capture_ns``.

        Returns
        -------
        PerceptionResult
        """
        k = frame.intrinsics
        is_depth = PixelEncoding(frame.encoding).is_depth
        depth_map = (self.depth_camera if is_depth else self.source).compute(frame)
        disp, depth_m = depth_map.disparity_fixed, depth_map.depth_m
        unknown_fraction = float(np.count_nonzero(np.isnan(depth_m))) / disp.size
        obstacles: tuple[Obstacle, ...] = ()
        blobs = self._near_blobs(disp, k.focal_baseline_m_px)
        if blobs is not None:
            regions, fill, near_half, disp_px = self._grow_regions(disp, k, *blobs)
            obstacles = tuple(
                sorted(
                    (
                        self._region_obstacle(
                            region,
                            disp.shape,
                            fill,
                            near_half,
                            disp_px,
                            k,
                            pos_ned_m,
                            R_ned_from_frd,
                        )
                        for region in regions
                    ),
                    key=lambda o: (o.nearest_range_m, tuple(o.center_ned_m)),
                )
            )
        return PerceptionResult(
            frame.sequence,
            frame.capture_ns,
            obstacles,
            unknown_fraction,
            depth_m,
            depth_map.counts,
            depth_map.blind_band_px,
            depth_map.trusted_range_m,
        )

    def _near_blobs(self, disp: np.ndarray, fb: float):
        """Blobs of pixels nearer than the threshold, on a 2x subsampled mask: (the mask,
        labels within its bounding box, their stats, the box's corner, the blobs kept,
        largest first); None when there is none."""
        cfg = self.config
        height, width = disp.shape
        # Integer disparities: d >= x  <=>  d >= ceil(x), compared in int16 (no float copy).
        near = (disp >= math.ceil(_DISP_SCALE * fb / cfg.threshold_m)).view(np.uint8)
        if cv2.countNonZero(near) == 0:  # the common empty frame: nothing to open or label
            return None
        if cfg.opening_px > 1:
            near = cv2.morphologyEx(near, cv2.MORPH_OPEN, self._kernel)
        # Blobs on a 2x subsampled mask: 4x cheaper labelling; areas count 4 pixels each.
        near_half = np.ascontiguousarray(near[::2, ::2])
        # Label only the bounding box of the mask (same components, same raster-order labels);
        # labels and stats are box-relative.
        bx, by, bw, bh = cv2.boundingRect(near_half)
        if bw == 0:
            return None
        n_labels, labels = cv2.connectedComponents(
            near_half[by : by + bh, bx : bx + bw], connectivity=8
        )
        stats = _label_stats(labels, n_labels)
        min_area = max(1, math.ceil(cfg.min_blob_fraction * width * height / 4.0))
        blobs = [i for i in range(1, n_labels) if stats[i, cv2.CC_STAT_AREA] >= min_area]
        if not blobs:
            return None
        # Largest blob first, so the obstacle numbering is deterministic and meaningful.
        blobs.sort(key=lambda i: (-stats[i, cv2.CC_STAT_AREA], i))
        return near_half, labels, stats, (bx, by), blobs

    def _grow_regions(self, disp, k: StereoIntrinsics, near_half, labels, stats, box, blobs):
        """Depth-continuous flood fill from each blob out to threshold + extent margin, on
        the same 2x subsampled grid as the blobs (a quarter of the pixels to convert and
        fill; the sphere fit samples at most ``max_points`` of them anyway). Returns the
        regions (fill value, rect, area), the fill mask, the mask and the disparities [px]."""
        cfg = self.config
        fb = k.focal_baseline_m_px
        width = disp.shape[1]
        bx, by = box
        d_far = fb / (cfg.threshold_m + cfg.extent_margin_m)
        disp_half = disp[::2, ::2]
        disp_px = disp_half.astype(np.float32)
        disp_px *= 1.0 / _DISP_SCALE
        # Invalid and far pixels stop the fill: d / 16 < float32(d_far), in integers.
        disp_px[disp_half < math.ceil(_DISP_SCALE * float(np.float32(d_far)))] = -1.0e6
        h_half, w_half = disp_px.shape
        fill = np.zeros((h_half + 2, w_half + 2), np.uint8)
        step_px = cfg.continuity_rel * fb / cfg.threshold_m
        regions: list[tuple[int, tuple[int, int, int, int], int]] = []
        bh, bw = labels.shape
        seed_x, seed_y = _blob_seeds(labels, disp_half[by : by + bh, bx : bx + bw], len(stats))
        for label in blobs:
            seed = (int(bx + seed_x[label]), int(by + seed_y[label]))  # nearest blob pixel
            # A square of side s at the blob's depth spans s·d/b pixels (d = f·b/z).
            # Capped: a near surface's coverage is patchy, mismatch clusters stay small.
            side_px = min(
                cfg.min_obstacle_size_m
                * disp_half[seed[1], seed[0]]
                / (_DISP_SCALE * k.baseline_m),
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
            if 2 * area < int(stats[label, cv2.CC_STAT_AREA]):
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
        return regions, fill, near_half, disp_px

    def _region_obstacle(
        self,
        region,
        shape,
        fill,
        near_half,
        disp_px,
        k: StereoIntrinsics,
        pos_ned_m,
        R_ned_from_frd,
    ) -> Obstacle:
        """The obstacle of one filled region: samples of it, and its boundary sphere."""
        value, (x0, y0, w, h), n_half = region
        height, width = shape
        # n_half (the fill's area) is the region's pixel count: later fills never overwrite.
        stride = _sample_stride(n_half, self.config.max_points)
        edge = _region_contour(fill, value, (x0, y0, w, h)) if stride > 1 else _NO_EDGE
        xs, ys, disp_samples, n_grid, n_near = _region_samples(
            fill, value, x0, y0, w, h, stride, edge, near_half, disp_px
        )
        truncated = bool(
            x0 <= 0 or y0 <= 0 or 2 * (x0 + w) >= width - 1 or 2 * (y0 + h) >= height - 1
        )
        return self._boundary(
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
