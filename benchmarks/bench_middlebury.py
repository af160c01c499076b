"""Benchmark: perception on real images, the Middlebury 2014 "motorcycle" pair.

The pair ships with scikit-image (``skimage.data.stereo_motorcycle``: 741 × 500, a quarter
of the original resolution, with ground-truth disparity and calibration f = 994.978 px,
baseline 193.001 mm, principal-point offset doffs = 31.086 px). How it becomes a frame of
our camera, so that "near mask at 3 m" is a depth in metres:

1. Grey images (``cv2.COLOR_RGB2GRAY``).
2. Common principal point: Middlebury's two cameras have principal points ``doffs`` apart,
   so depth is ``f·b / (d + doffs)``. Shifting the right image ``doffs`` px to the left
   (bilinear) makes the disparity the geometric one, ``d' = d + doffs``, and depth
   ``f·b / d'`` (Eq. 27), the form our frames and perception use.
3. 4:3 crop, columns 0..666 (the right image's shifted-in border is cut away), then
   ``INTER_AREA`` down to the paper's 320 × 240: ``s = 320 / 667`` (rows 240 / 500, equal to
   0.05 %). Disparities scale by ``s``; the ground truth is resampled nearest-neighbour.
4. Intrinsics: ``fx = fy = 994.978 · s`` (477.4 px), principal point at the image centre,
   baseline 0.193 m, so ``f·b = 92.13 m·px``: the paper camera's depth scaling (Eq. 27)
   with this rig's focal length and baseline. The scene then spans 2.1 m (front wheel) to
   5 m (back wall): a near mask at 2.5 / 3 / 4 m holds 41 / 58 / 82 % of the pixels both
   cameras see, and perception's 4 m threshold and 1.2 m minimum range mean what they mean
   on our camera (80 disparities instead of 64).

Scores are over the pixels both cameras see (finite ground truth and ``gt ≤ column``); the
near pixels the right camera cannot see (``gt > column``) must all be unknown (NaN).
Precision and recall are those of the near mask ``depth_m < T`` against ``f·b / gt < T``
(unknown counts as not near); density is the known fraction, bad-2 the fraction of known
pixels more than 2 px of disparity from the truth.

Run with ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_middlebury.py``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass

import cv2
import numpy as np

from companion.perception import Matcher, PerceptionConfig, StereoPerception
from companion.stereo_bm import configured_bm
from protocols.camera import StereoIntrinsics
from protocols.stereo_frame import StereoFrame

__all__ = ["NearMaskScores", "main", "motorcycle_frame", "near_mask_scores"]

_F_PX = 994.978  # skimage's calibration for the 741 × 500 images
_DOFFS_PX = 31.086
_BASELINE_M = 0.193001
_CROP_W = 667  # 4:3 of 500 rows
_W, _H = 320, 240


def motorcycle_frame() -> tuple[StereoFrame, np.ndarray]:
    """The motorcycle pair as a 320 × 240 frame, and its ground-truth disparity [px]
    (``(H, W)`` float32, NaN where unknown), following the module docstring."""
    from skimage import data  # test dependency

    left_rgb, right_rgb, gt = data.stereo_motorcycle()
    left = cv2.cvtColor(left_rgb, cv2.COLOR_RGB2GRAY)
    right = cv2.cvtColor(right_rgb, cv2.COLOR_RGB2GRAY)
    shift = np.float32([[1.0, 0.0, -_DOFFS_PX], [0.0, 1.0, 0.0]])
    right = cv2.warpAffine(right, shift, (right.shape[1], right.shape[0]), flags=cv2.INTER_LINEAR)
    gt = np.where(np.isfinite(gt), gt + _DOFFS_PX, np.nan).astype(np.float32)
    s = _W / _CROP_W
    left, right, gt = (a[:, :_CROP_W] for a in (left, right, gt))
    left = cv2.resize(left, (_W, _H), interpolation=cv2.INTER_AREA)
    right = cv2.resize(right, (_W, _H), interpolation=cv2.INTER_AREA)
    gt = cv2.resize(gt, (_W, _H), interpolation=cv2.INTER_NEAREST) * np.float32(s)
    intrinsics = StereoIntrinsics(
        width_px=_W,
        height_px=_H,
        fx_px=_F_PX * s,
        fy_px=_F_PX * s,
        cx_px=(_W - 1) / 2.0,
        cy_px=(_H - 1) / 2.0,
        baseline_m=_BASELINE_M,
    )
    return StereoFrame(0, 0, intrinsics, left, right), gt


@dataclass(frozen=True)
class NearMaskScores:
    """Near-mask and disparity scores of one depth map (see the module docstring)."""

    precision: float
    recall: float
    iou: float
    near_fraction: float  # of the pixels both cameras see, the truly near ones
    n_hidden_near: int  # near pixels the right camera cannot see
    n_hidden_near_reported: int  # of those, with a known depth (must be 0)
    density: float  # known fraction of the pixels both cameras see
    bad2: float  # of the known ones, > 2 px of disparity off


def near_mask_scores(
    depth_m: np.ndarray, gt_px: np.ndarray, intrinsics: StereoIntrinsics, threshold_m: float
) -> NearMaskScores:
    """Score ``depth_m`` (NaN = unknown) against the ground-truth disparity ``gt_px``."""
    fb = intrinsics.focal_baseline_m_px
    cols = np.arange(gt_px.shape[1])[None, :]
    has_gt = np.isfinite(gt_px)
    gt_safe = np.where(has_gt, gt_px, 1.0)
    both = has_gt & (gt_safe <= cols)
    truly_near = has_gt & (fb / np.maximum(gt_safe, 1e-6) < threshold_m)
    known = np.isfinite(depth_m)
    said_near = known & (np.where(known, depth_m, np.inf) < threshold_m)
    tp = int(np.count_nonzero(said_near & truly_near & both))
    fp = int(np.count_nonzero(said_near & ~truly_near & both))
    fn = int(np.count_nonzero(~said_near & truly_near & both))
    hidden_near = truly_near & ~both
    k = known & both
    disp = fb / np.where(k, depth_m, 1.0)
    return NearMaskScores(
        precision=tp / max(tp + fp, 1),
        recall=tp / max(tp + fn, 1),
        iou=tp / max(tp + fp + fn, 1),
        near_fraction=float(np.count_nonzero(truly_near & both)) / max(np.count_nonzero(both), 1),
        n_hidden_near=int(np.count_nonzero(hidden_near)),
        n_hidden_near_reported=int(np.count_nonzero(hidden_near & known)),
        density=float(np.count_nonzero(k)) / max(np.count_nonzero(both), 1),
        bad2=float(np.count_nonzero(np.abs(disp - gt_px)[k] > 2.0)) / max(np.count_nonzero(k), 1),
    )


def _bare_matcher(perception: StereoPerception, intrinsics: StereoIntrinsics):
    """The OpenCV matcher with perception's settings, on the unpadded pair."""
    source = perception.source
    return configured_bm(
        perception.config,
        source.num_disparities(intrinsics),
        source.block_size(intrinsics),
        intrinsics.width_px,
    )


def main(argv: list[str] | None = None) -> None:
    """Print the Middlebury table for every matcher offered."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=30, help="timed runs per matcher")
    args = parser.parse_args(argv)
    frame, gt = motorcycle_frame()
    k = frame.intrinsics
    print(
        f"Middlebury 2014 motorcycle at {k.width_px}x{k.height_px}, f·b = "
        f"{k.focal_baseline_m_px:.2f} m·px (depth = f·b / d); scores over pixels both "
        f"cameras see"
    )
    for matcher in Matcher:
        perception = StereoPerception(PerceptionConfig(matcher=matcher))
        bare = _bare_matcher(perception, k)
        result = perception.process(frame, np.zeros(3), np.eye(3))
        t_pipe, t_bare = [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            bare.compute(frame.left, frame.right)
            t_bare.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            perception.process(frame, np.zeros(3), np.eye(3))
            t_pipe.append(time.perf_counter() - t0)
        for threshold_m in (2.5, 3.0, 4.0):
            s = near_mask_scores(result.depth_m, gt, k, threshold_m)
            print(
                f"  {matcher.value:9s} near < {threshold_m:.1f} m ({100 * s.near_fraction:3.0f} % "
                f"near): precision {s.precision:.3f} recall {s.recall:.3f} IoU {s.iou:.3f}; "
                f"hidden near px reported {s.n_hidden_near_reported}/{s.n_hidden_near}"
            )
        print(
            f"  {matcher.value:9s} density {s.density:.3f}, bad-2 {s.bad2:.3f}; per frame "
            f"{1e3 * statistics.median(t_pipe):.1f} ms (bare matcher "
            f"{1e3 * statistics.median(t_bare):.1f} ms, ratio "
            f"{statistics.median(t_pipe) / statistics.median(t_bare):.2f})"
        )


if __name__ == "__main__":
    main()
