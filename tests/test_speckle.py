"""The compiled speckle filter (companion.speckle) against OpenCV's ``cv2.filterSpeckles``,
bit for bit: random maps of every shape and setting, and StereoBM's own output."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.perception import PerceptionConfig
from companion.speckle import filter_speckles
from companion.stereo_bm import _padded, configured_bm, speckle_params


def _random_map(rng, shape, n_levels, invalid_fraction, new_val):
    disp = rng.integers(new_val + 1, new_val + 1 + n_levels, shape).astype(np.int16)
    disp[rng.random(shape) < invalid_fraction] = new_val
    return disp


@pytest.mark.parametrize("shape", [(1, 1), (1, 17), (17, 1), (23, 31), (60, 80)])
@pytest.mark.parametrize("new_val", [-16, 0])
def test_equals_opencv_on_random_maps(shape, new_val):
    rng = np.random.default_rng([shape[0], shape[1], new_val + 16])
    for trial in range(40):
        disp = _random_map(rng, shape, int(rng.integers(1, 60)), rng.random(), new_val)
        max_size = int(rng.integers(0, 80))
        max_diff = int(rng.integers(0, 12))
        expected = disp.copy()
        cv2.filterSpeckles(expected, new_val, max_size, max_diff)
        got = disp.copy()
        removed = filter_speckles(got, new_val, max_size, max_diff)
        np.testing.assert_array_equal(
            got, expected, err_msg=f"trial {trial}: size {max_size}, diff {max_diff}"
        )
        assert removed == np.count_nonzero((disp != new_val) & (got == new_val))


def test_an_empty_map_is_left_alone():
    """(OpenCV refuses an empty map; ours removes nothing from it.)"""
    for shape in ((0, 5), (5, 0)):
        assert filter_speckles(np.zeros(shape, np.int16), -16, 10, 1) == 0


def test_a_window_larger_than_the_map_removes_every_region_without_a_huge_buffer():
    disp = np.arange(12, dtype=np.int16).reshape(3, 4)
    assert filter_speckles(disp, -16, 2**40, 1) == 12
    assert np.all(disp == -16)


def test_a_region_of_exactly_max_size_is_a_speckle_and_one_more_pixel_is_not():
    """OpenCV's rule: a region of at most ``max_size`` pixels is removed."""
    disp = np.full((5, 9), -16, np.int16)
    disp[1:3, 1:4] = 100  # 6 pixels, one region (differences 0)
    disp[1:3, 5:8] = 200
    disp[3, 7] = 201  # 7 pixels: the neighbour differs by 1 <= max_diff
    out = disp.copy()
    assert filter_speckles(out, -16, 6, 1) == 6
    assert np.all(out[1:3, 1:4] == -16)
    np.testing.assert_array_equal(out[1:4, 5:8], disp[1:4, 5:8])


@pytest.mark.parametrize("max_size", [12, 13])
def test_branches_joined_below_by_small_steps_are_one_region(max_size):
    """A U of 13 pixels: two arms the raster pass meets as separate regions, joined by the
    bottom row further down, with neighbours 1 apart (a ramp). One region of 13: removed
    by a window of 13, kept by 12."""
    disp = np.full((6, 7), -16, np.int16)
    disp[0:5, 1] = [4, 3, 2, 1, 0]  # left arm, descending to the join
    disp[4, 2:5] = [1, 2, 3]  # the bottom
    disp[0:5, 5] = [8, 7, 6, 5, 4]  # right arm
    out = disp.copy()
    removed = filter_speckles(out, -16, max_size, 1)
    expected = disp.copy()
    cv2.filterSpeckles(expected, -16, max_size, 1)
    np.testing.assert_array_equal(out, expected)
    assert removed == (13 if max_size >= 13 else 0)


def test_equals_stereobm_own_filter_on_its_output():
    """StereoBM without its speckle filter, then ours on the frame's pixels, equals StereoBM
    with its own (what PaddedStereoBM relies on)."""
    rng = np.random.default_rng(7)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (240, 400), dtype=np.uint8), (0, 0), 1.2)
    left = texture[:, 40:360].copy()
    right = texture[:, 52:372].copy()  # a plane at 12 px disparity, plus noise
    left = np.clip(left + rng.normal(0, 6, left.shape), 0, 255).astype(np.uint8)
    right = np.clip(right + rng.normal(0, 6, right.shape), 0, 255).astype(np.uint8)
    cfg = PerceptionConfig()
    window, range_fixed = speckle_params(cfg, 320)
    pad_x, pad_y = 48, 4
    pair = _padded(left, pad_x, pad_y), _padded(right, pad_x, pad_y)
    crop = (slice(pad_y, pad_y + 240), slice(pad_x, pad_x + 320))
    expected = configured_bm(cfg, 48, 9, 320).compute(*pair)[crop]
    got = configured_bm(cfg, 48, 9, 320, speckle=False).compute(*pair)[crop].copy()
    removed = filter_speckles(got, -16, window, range_fixed)
    assert removed > 100  # the noise makes speckles: the test has something to check
    np.testing.assert_array_equal(got, expected)
