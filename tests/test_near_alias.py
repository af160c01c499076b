"""The near pass's alias check (companion.near_alias): a repetitive wall far away is never
ranged at arm's length, a real surface at arm's length still is (issue 34's phantom near
pixels)."""

from __future__ import annotations

import numpy as np
import pytest

from companion.near_alias import _bt_cost, _half_pixel_span, settle_near_claims
from companion.perception import StereoPerception
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import Box, GroundPlane, World
from protocols.camera import CameraModel
from protocols.frames import rotation_321
from protocols.stereo_frame import StereoFrame, decode, encode

CAMERA = CameraModel()
FB = CAMERA.intrinsics.focal_baseline_m_px  # f·b [m·px]: depth = FB / disparity
SOUTH = rotation_321(0.0, 0.0, np.pi)  # level, looking south
WALL = Box((10.0, 0.0, -7.0), (0.2, 30.0, 14.0))  # tests/test_proximity_sil.py's wall
WALL_FACE_N_M = 10.1
MIN_RANGE_M = 1.5  # PerceptionConfig.min_range_m: nearer is the near pass's alone


@pytest.fixture(scope="module")
def renderer() -> StereoCameraRenderer:
    return StereoCameraRenderer(CAMERA)


@pytest.fixture(scope="module")
def perception() -> StereoPerception:
    return StereoPerception()


def _depth(renderer, perception, north_m: float, seed: int):
    """Perception's depth map and the true depth of the wall seen from ``north_m``."""
    pos = np.array([north_m, 0.0, -7.0])
    world = World(boxes=(WALL,), ground=GroundPlane(0.0))
    out = renderer.render(world, pos, SOUTH, noise_seed=seed)
    frame = decode(encode(StereoFrame(seed, 1_000 * seed, CAMERA.intrinsics, out.left, out.right)))
    return perception.process(frame, pos, SOUTH), out.depth_left_m


# The wall's coarse texture octave repeats every 32 × 0.12 m = 3.84 m; from these points one
# period is an almost whole number of quarter-resolution pixels (43.7 + 2.3 = 46.0 at 7.9 m;
# 28.15, 26.1 farther), where the near pass locked on the copy before the check: 27-43 k
# pixels at 0.39-0.68 m, on every noise seed (measured).
@pytest.mark.parametrize("north_m", [18.0, 23.0, 24.0])
def test_a_repetitive_wall_far_away_is_never_ranged_at_arms_length(renderer, perception, north_m):
    for seed in range(2):
        result, truth = _depth(renderer, perception, north_m, seed)
        known = np.isfinite(result.depth_m)
        phantom = known & (result.depth_m < MIN_RANGE_M)
        assert not phantom.any(), (
            f"from {north_m} m north (wall at {north_m - WALL_FACE_N_M:.1f} m): "
            f"{np.count_nonzero(phantom)} px ranged at "
            f"{np.nanmin(result.depth_m[phantom]):.2f} m"
        )
        assert result.counts.n_too_near == 0
        # What is ranged is ranged right: within a pixel of disparity of the truth (the
        # wall-ground seam and its half-block of mixed pixels excepted).
        wrong = known & (np.abs(FB / result.depth_m - FB / truth) > 1.0)
        assert np.count_nonzero(wrong) <= 0.01 * np.count_nonzero(known)
        # the wall is still seen where its copies are told apart (the far side of the view)
        on_wall = np.isclose(truth, north_m - WALL_FACE_N_M, rtol=1e-3)
        assert np.count_nonzero(known & on_wall) >= 0.3 * np.count_nonzero(on_wall)


@pytest.mark.parametrize("surface_m", [0.5, 0.7, 1.0, 1.3])
def test_the_same_wall_at_arms_length_is_still_ranged(renderer, perception, surface_m):
    """The check does not cost a real near surface its range: the wall filling the view
    at 0.5-1.3 m is ranged by the near pass over at least 15 % of the image (measured
    without the check: 24-69 %, 0.2-0.5 % more than with it), 95 % of it within two
    full-resolution pixels of disparity (the coarse pass's resolution, 1.6 % at 1.3 m;
    the rest is the near pass's own aliasing at 0.5 m, the same without the check)."""
    result, truth = _depth(renderer, perception, WALL_FACE_N_M + surface_m, 0)
    np.testing.assert_allclose(truth, surface_m, rtol=1e-3)  # the wall fills the view
    near = np.isfinite(result.depth_m) & (result.depth_m < MIN_RANGE_M)
    assert np.count_nonzero(near) >= 0.15 * truth.size
    err_px = np.abs(FB / result.depth_m[near] - FB / surface_m)
    assert np.quantile(err_px, 0.95) <= 2.0, np.quantile(err_px, [0.5, 0.95, 0.99, 1.0])


# ---- the kernel on closed forms ---------------------------------------------------------


def _spans(image: np.ndarray):
    return _half_pixel_span(np.ascontiguousarray(image, dtype=np.uint8))


def test_bt_cost_is_zero_for_a_ramp_at_any_sub_pixel_shift():
    """Birchfield-Tomasi: a linear ramp shifted by half a pixel costs nothing at either
    neighbouring integer disparity (the absolute difference would be half the slope)."""
    x = np.arange(64, dtype=float)
    left = np.tile(40.0 + 2.0 * x, (16, 1))
    right = np.tile(40.0 + 2.0 * (x + 6.5), (16, 1))  # disparity 6.5 px
    lspan, rspan = _spans(left), _spans(right)
    for d in (6, 7):
        assert _bt_cost(lspan, rspan, 8, 32, d, 4) == 0.0
    sad_6 = np.abs(left[:, 28:37] - right[:, 22:31]).mean()
    assert sad_6 == pytest.approx(1.0)  # what plain SAD charges the true match
    # 3.5 px off: 7 grey levels, less the half pixel (1 grey level) the measure forgives
    assert _bt_cost(lspan, rspan, 8, 32, 3, 4) == pytest.approx(6.0)


def test_bt_cost_skips_columns_outside_the_images():
    image = _spans(np.full((9, 20), 100, np.uint8))
    assert _bt_cost(image, image, 4, 2, 30, 4) == -1.0  # every right column left of 0
    assert _bt_cost(image, image, 4, 2, 0, 4) == 0.0


def _pair(texture: np.ndarray, d_px: int) -> tuple[np.ndarray, np.ndarray]:
    """A rectified pair of a fronto-parallel ``texture`` at integer disparity ``d_px``: the
    right image's column ``x - d`` shows what the left's column ``x`` shows."""
    width = texture.shape[1] - d_px
    return texture[:, :width].copy(), texture[:, d_px:].copy()


def _claims(shape, d_coarse_px: float) -> np.ndarray:
    """A coarse pass claiming every pixel at ``d_coarse_px`` [coarse px]."""
    return np.full((shape[0] // 4, shape[1] // 4), round(16 * d_coarse_px), np.int16)


CLAIM_ABOVE = 16 * 47 // 4  # the default main range, 48 px, in 1/16 coarse px


def test_a_claim_one_period_away_is_ambiguous_and_unknown():
    """A texture repeating every 120 px at 10 px of disparity: the copy at 130 px matches as
    well as the truth; claim and main match are both dropped (unknown)."""
    rng = np.random.default_rng(1)
    tile = rng.integers(20, 236, size=(64, 120)).astype(np.uint8)
    left, right = _pair(np.tile(tile, (1, 4)), 10)
    disp = np.full(left.shape, 16 * 10, np.int16)
    coarse = _claims(left.shape, 130 / 4)
    kept, dropped, ambiguous = settle_near_claims(coarse, CLAIM_ABOVE, disp, left, right, 4)
    assert kept == 0 and dropped == 0 and ambiguous == np.count_nonzero(coarse < 0) > 0
    settled = np.repeat(np.repeat(coarse < 0, 4, 0), 4, 1)
    height, width = settled.shape
    assert np.all(disp[:height, :width][settled] == -16)
    assert np.all(disp[:height, :width][~settled] == 16 * 10)


def test_a_true_near_claim_beats_the_main_passs_alias_and_a_false_one_loses():
    """Random (non-repeating) texture at 150 px of disparity (0.48 m): the claim stands
    against a main-pass match at 20 px. The same texture at 20 px: a claim at 150 px
    is dropped and the main match kept."""
    rng = np.random.default_rng(2)
    texture = rng.integers(20, 236, size=(64, 480)).astype(np.uint8)
    left, right = _pair(texture, 150)
    disp = np.full(left.shape, 16 * 20, np.int16)
    coarse = _claims(left.shape, 150 / 4)
    kept, dropped, ambiguous = settle_near_claims(coarse, CLAIM_ABOVE, disp, left, right, 4)
    assert kept > 0 and dropped == 0 and ambiguous == 0
    assert np.all(disp == 16 * 20)  # the merge lets the standing claim win

    left, right = _pair(texture, 20)
    disp = np.full(left.shape, 16 * 20, np.int16)
    coarse = _claims(left.shape, 150 / 4)
    kept, dropped, ambiguous = settle_near_claims(coarse, CLAIM_ABOVE, disp, left, right, 4)
    assert kept == 0 and ambiguous == 0 and dropped > 0
    assert np.all(disp == 16 * 20)


def test_a_claim_the_main_pass_did_not_rival_is_left_alone():
    rng = np.random.default_rng(3)
    left = rng.integers(0, 256, size=(32, 64)).astype(np.uint8)
    disp = np.full(left.shape, -16, np.int16)
    coarse = _claims(left.shape, 40.0)
    before = coarse.copy()
    assert settle_near_claims(coarse, CLAIM_ABOVE, disp, left, left, 4) == (0, 0, 0)
    np.testing.assert_array_equal(coarse, before)
