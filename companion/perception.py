"""Stereo perception (paper §4–5): disparity → depth (Eq. 27) → obstacles → safety spheres in NED.

Pipeline for one rectified frame (:meth:`StereoPerception.process`):

1. Disparity with OpenCV (``StereoBM`` by default; ``StereoSGBM`` 3-way selectable), one
   matcher object per image geometry, built once and reused.
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

Unknown space: pixels without a valid disparity (textureless, occluded, or the left band of
``num_disparities`` columns the right image cannot see) are never treated as free. They are
never obstacles either (there is no range to put them at); instead :class:`PerceptionResult`
reports ``unknown_fraction`` so the caller can refuse to fly into what it cannot see, and each
obstacle says whether it was ``truncated`` by the image border or the unmatched band (then its
true extent may be larger than estimated).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from protocols.camera import StereoIntrinsics, points_ned_from_cam
from protocols.stereo_frame import PixelEncoding, StereoFrame

__all__ = [
    "Matcher",
    "Obstacle",
    "PerceptionConfig",
    "PerceptionResult",
    "StereoPerception",
]

_DISP_SCALE = 16  # OpenCV disparities are fixed point with 4 fractional bits
_REFERENCE_WIDTH_PX = 320  # the paper's camera; block size scales from it


class Matcher(enum.Enum):
    """OpenCV stereo matcher."""

    BM = "bm"  # cv2.StereoBM: fastest, fewest false near pixels (default)
    SGBM_3WAY = "sgbm_3way"  # cv2.StereoSGBM MODE_SGBM_3WAY: denser, ~1.7x slower


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
    opening_px : int
        Kernel size of the morphological opening of the obstacle mask [px]; 1 disables it.
    min_blob_fraction : float
        Smallest obstacle blob as a fraction of the image area (6e-4 ≈ 46 px at 320 × 240).
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
    min_range_m: float = 1.2
    block_size_px: int | None = None
    uniqueness_ratio: int = 10
    texture_threshold: int = 10
    speckle_window_px: int = 100
    speckle_range_px: int = 2
    opening_px: int = 3
    min_blob_fraction: float = 6e-4
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
        for name in ("extent_margin_m", "vehicle_radius_m", "safety_margin_m", "cap_depth_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
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
        Fraction of the image without a valid disparity (never free space).
    """

    sequence: int
    capture_ns: int
    obstacles: tuple[Obstacle, ...]
    unknown_fraction: float


def _sample_region(
    region: np.ndarray, max_points: int, n: int | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """Pixel coordinates (x, y, n_grid) of a region: a regular grid, then its outer contour.

    The contour carries the angular extremes and the farthest points exactly; the grid
    (stride chosen for about ``max_points`` samples) carries the mean bearing and the
    nearest range; the first ``n_grid`` samples are the grid. Keeps the per-obstacle cost flat
    however large the obstacle looks. ``n`` is the region's pixel count when already known.
    """
    if n is None:
        n = int(np.count_nonzero(region))
    stride = max(1, math.ceil(math.sqrt(n / max_points)))
    gy, gx = np.nonzero(region[::stride, ::stride])
    if stride == 1:
        return gx.astype(np.intp), gy.astype(np.intp), len(gx)
    contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    edge = np.concatenate([c.reshape(-1, 2) for c in contours], axis=0)
    xs = np.concatenate((gx * stride, edge[:, 0])).astype(np.intp)
    ys = np.concatenate((gy * stride, edge[:, 1])).astype(np.intp)
    return xs, ys, len(gx)


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

    def num_disparities(self, intrinsics: StereoIntrinsics) -> int:
        """Disparity search range [px]: ``f·b / min_range_m`` rounded up to a multiple of 16."""
        d_max = intrinsics.focal_baseline_m_px / self.config.min_range_m
        n = 16 * math.ceil(d_max / 16.0)
        return int(min(n, 16 * ((intrinsics.width_px - 1) // 16)))

    def _matcher(self, intrinsics: StereoIntrinsics) -> tuple[cv2.StereoMatcher, int]:
        cfg = self.config
        n_disp = self.num_disparities(intrinsics)
        block = cfg.block_size_px or _auto_block_size(intrinsics.width_px)
        key = (intrinsics.width_px, n_disp, block)
        matcher = self._matchers.get(key)
        if matcher is None:
            if cfg.matcher is Matcher.BM:
                matcher = cv2.StereoBM_create(numDisparities=n_disp, blockSize=block)
                matcher.setTextureThreshold(cfg.texture_threshold)
            else:
                matcher = cv2.StereoSGBM_create(
                    minDisparity=0,
                    numDisparities=n_disp,
                    blockSize=block,
                    P1=8 * block * block,
                    P2=32 * block * block,
                    mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
                )
            matcher.setUniquenessRatio(cfg.uniqueness_ratio)
            matcher.setSpeckleWindowSize(cfg.speckle_window_px)
            matcher.setSpeckleRange(cfg.speckle_range_px)
            self._matchers[key] = matcher
        return matcher, n_disp

    def disparity_fixed(self, frame: StereoFrame) -> np.ndarray:
        """Raw OpenCV disparity of the frame: int16, 1/16 px units, negative where invalid."""
        if frame.encoding is not PixelEncoding.MONO8:
            raise ValueError(f"unsupported pixel encoding {frame.encoding!r}")
        matcher, _ = self._matcher(frame.intrinsics)
        return matcher.compute(frame.left, frame.right)

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
        matcher, n_disp = self._matcher(k)
        if frame.encoding is not PixelEncoding.MONO8:
            raise ValueError(f"unsupported pixel encoding {frame.encoding!r}")
        disp = matcher.compute(frame.left, frame.right)
        height, width = disp.shape
        fb = k.focal_baseline_m_px
        valid = disp >= 0
        unknown_fraction = 1.0 - float(np.count_nonzero(valid)) / disp.size

        # Integer disparities: d >= x  <=>  d >= ceil(x), compared in int16 (no float copy).
        near = (disp >= math.ceil(_DISP_SCALE * fb / cfg.threshold_m)).view(np.uint8)
        if cv2.countNonZero(near) == 0:  # the common empty frame: nothing to open or label
            return PerceptionResult(frame.sequence, frame.capture_ns, (), unknown_fraction)
        if cfg.opening_px > 1:
            near = cv2.morphologyEx(near, cv2.MORPH_OPEN, self._kernel)
        # Blobs on a 2x subsampled mask: 4x cheaper labelling; areas count 4 pixels each.
        near_half = np.ascontiguousarray(near[::2, ::2])
        # Label only the bounding box of the mask (same components, same raster-order labels);
        # stats are shifted back to the half-resolution image, labels stay box-relative.
        bx, by, bw, bh = cv2.boundingRect(near_half)
        if bw == 0:
            return PerceptionResult(frame.sequence, frame.capture_ns, (), unknown_fraction)
        n_labels, labels, stats, _ = cv2.connectedComponentsWithStats(
            near_half[by : by + bh, bx : bx + bw], connectivity=8
        )
        min_area = max(1, math.ceil(cfg.min_blob_fraction * width * height / 4.0))
        blobs = [i for i in range(1, n_labels) if stats[i, cv2.CC_STAT_AREA] >= min_area]
        if not blobs:
            return PerceptionResult(frame.sequence, frame.capture_ns, (), unknown_fraction)

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
        regions: list[tuple[int, tuple[int, int, int, int], int]] = []
        # Largest blob first, so the obstacle numbering is deterministic and meaningful.
        for label in sorted(blobs, key=lambda i: (-stats[i, cv2.CC_STAT_AREA], i)):
            lx0, ly0, w, h = stats[label, :4]
            x0 = lx0 + bx
            y0 = ly0 + by
            sub_disp = np.where(
                labels[ly0 : ly0 + h, lx0 : lx0 + w] == label,
                disp_half[y0 : y0 + h, x0 : x0 + w],
                -1,
            )
            iy, ix = np.unravel_index(int(np.argmax(sub_disp)), sub_disp.shape)
            seed = (int(x0 + ix), int(y0 + iy))  # nearest pixel of the blob
            if fill[seed[1] + 1, seed[0] + 1] or len(regions) >= 254:
                continue  # same surface as an earlier blob (one obstacle), or too many
            value = len(regions) + 1
            flags = 8 | cv2.FLOODFILL_MASK_ONLY | (value << 8)
            area, _, _, rect = cv2.floodFill(
                disp_px, fill, seed, 0, loDiff=step_px, upDiff=step_px, flags=flags
            )
            regions.append((value, rect, int(area)))

        # Columns the right image cannot see at the largest disparity, plus half a block.
        band_px = n_disp + (cfg.block_size_px or _auto_block_size(width)) // 2
        obstacles = []
        for value, (x0, y0, w, h), n_half in regions:
            region = (fill[y0 + 1 : y0 + h + 1, x0 + 1 : x0 + w + 1] == value).view(np.uint8)
            n_near = 4 * int(np.count_nonzero(region & near_half[y0 : y0 + h, x0 : x0 + w]))
            # n_half (the fill's area) is the region's pixel count: later fills never overwrite.
            xs, ys, n_grid = _sample_region(region, self.config.max_points, n_half)
            xs += x0
            ys += y0
            truncated = bool(
                2 * x0 <= band_px + 2
                or y0 <= 0
                or 2 * (x0 + w) >= width - 1
                or 2 * (y0 + h) >= height - 1
            )
            obstacles.append(
                self._boundary(
                    2 * xs,
                    2 * ys,
                    n_grid,
                    disp_px[ys, xs].astype(np.float64),
                    k,
                    pos_ned_m,
                    R_ned_from_frd,
                    4 * n_half,
                    n_near,
                    truncated,
                )
            )
        obstacles.sort(key=lambda o: (o.nearest_range_m, tuple(o.center_ned_m)))
        return PerceptionResult(
            frame.sequence, frame.capture_ns, tuple(obstacles), unknown_fraction
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
        xn = (xs - k.cx_px) * (1.0 / k.fx_px)
        yn = (ys - k.cy_px) * (1.0 / k.fy_px)
        norm = np.sqrt(xn * xn + yn * yn + 1.0)
        range_m = (k.focal_baseline_m_px * norm) / disp_px  # Eq. (27) depth times ray length
        bearings = np.empty((len(xs), 3))
        bearings[:, 0] = xn / norm
        bearings[:, 1] = yn / norm
        bearings[:, 2] = 1.0 / norm
        # Nearest surface: the 1st percentile of the ranges, robust to a few outliers.
        rank = int(0.01 * (len(range_m) - 1))
        nearest_m = float(np.partition(range_m, rank)[rank])
        # Centre bearing: the mean bearing of the nearest cap (grid samples within
        # cap_depth_m of the nearest surface). A sphere's nearest cap is centred on the
        # camera→centre line, so this stays unbiased when the image border cuts the
        # silhouette (a pitched camera), where the mean over the whole region does not.
        grid_bearings = bearings[:n_grid]
        cap = range_m[:n_grid] <= nearest_m + max(cfg.cap_depth_m, 0.03 * nearest_m)
        axis = (grid_bearings[cap] if np.any(cap) else grid_bearings).sum(axis=0)
        axis /= math.sqrt(float(axis @ axis))
        cos_min = min(1.0, max(-1.0, float((bearings @ axis).min())))
        half_angle = min(math.acos(cos_min), math.radians(cfg.max_half_angle_deg))
        mean_bearing = axis
        sin_a = math.sin(half_angle)
        radius_fit_m = nearest_m * sin_a / (1.0 - sin_a)
        center_cam = mean_bearing * (nearest_m + radius_fit_m)
        offsets = np.multiply(bearings, range_m[:, None])
        offsets -= center_cam
        farthest_m = math.sqrt(float(np.einsum("ij,ij->i", offsets, offsets).max()))
        raw_radius_m = max(radius_fit_m, farthest_m)
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
