"""Range-aware occupancy: a hit from far is good to a pixel of disparity, not to a voxel.

The suite's Monte Carlo seed 102 (stop 41): voxels 0.52-0.92 m in front of a sphere's
true surface, hit from 7.7 m (one pixel of disparity is 0.89 m there), OCCUPIED for 200+
frames and the goal's `goal_unreachable` hold latched on them. A surface hit only from
far is not a surface *seen near* (``KnownSpace.seen_near``, what the latch asks for); a
real wall is seen near from its first near frames and stays occupied.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.known_space import FREE, OCCUPIED, KnownSpace, KnownSpaceConfig
from protocols.camera import CameraModel
from protocols.frames import rotation_321

pytestmark = pytest.mark.unit

K = CameraModel().intrinsics
LEVEL_NORTH = rotation_321(0.0, 0.0, 0.0)
VOXEL_M = KnownSpaceConfig().voxel_m
FB_PX_M = K.fx_px * K.baseline_m  # 71.9 px·m


def _wall(depth_m: float) -> np.ndarray:
    return np.full((K.height_px, K.width_px), depth_m, np.float32)


def test_the_near_range_is_where_a_pixel_of_disparity_is_a_voxel():
    space = KnownSpace()
    r = space.near_range_m(K)
    assert r == pytest.approx(math.sqrt(VOXEL_M * FB_PX_M), rel=1e-12)
    # the depth error of one pixel of disparity at that range, z²/(f·b), is one voxel
    assert r * r / FB_PX_M == pytest.approx(VOXEL_M, rel=1e-12)
    assert 3.7 < r < 3.9
    half = KnownSpace(KnownSpaceConfig(confirm_disparity_px=0.5))
    assert half.near_range_m(K) == pytest.approx(math.sqrt(2.0) * r, rel=1e-12)
    assert KnownSpace(KnownSpaceConfig(confirm_disparity_px=0.0)).near_range_m(K) == math.inf
    # the proximity sectors' far layer keeps the old occupancy
    assert space.far is not None and space.far.near_range_m(K) == math.inf


def test_a_far_biased_hit_is_occupied_but_not_a_surface_seen_near():
    """A wall 7.7 m away measured 0.7 m nearer (0.8 px of disparity) in every frame: the
    false surface is OCCUPIED (the proximity sectors still hear of something there), but
    not seen near, so nothing latches on it; seen from 3 m the rays pass through it to the
    true wall, which is seen near from its first near frames."""
    space = KnownSpace()
    pos = np.array([0.0, 0.0, -7.0])
    false_point = pos + np.array([7.01, 0.0, 0.0])
    for _ in range(10):
        space.integrate(_wall(7.0), K, pos, LEVEL_NORTH)
    assert space.state_at(false_point) == OCCUPIED
    assert not space.seen_near(false_point, 0.5)
    near_pos = pos + np.array([4.7, 0.0, 0.0])  # the true wall 3.0 m ahead
    true_point = near_pos + np.array([3.01, 0.0, 0.0])
    for n in range(2):
        space.integrate(_wall(3.0), K, near_pos, LEVEL_NORTH)
        assert space.seen_near(true_point, 0.5) == (n == 1)  # occupied on its second frame
    assert space.state_at(false_point) == FREE
    assert space.state_at(true_point) == OCCUPIED
    assert space.seen_near(true_point, 0.5)


def _wall_below(top_down_m: float, cam_down_m: float, depth_m: float) -> np.ndarray:
    """Depth image of a wall ``depth_m`` ahead whose top edge is at NED down
    ``top_down_m``, seen level from a camera at ``cam_down_m``; nothing matched above."""
    frame = np.full((K.height_px, K.width_px), np.inf, np.float32)
    row = K.cy_px + (top_down_m - cam_down_m) * K.fy_px / depth_m
    frame[max(0, math.ceil(row)) :, :] = depth_m
    return frame


def test_a_real_wall_stays_occupied_from_its_first_near_frames():
    """A wall 3 m ahead whose top edge is 5 cm above the camera: occupied and seen near
    after its first two frames, and every voxel of it stays so while the vehicle climbs
    0.4 m in 2 cm steps and the rays over the edge graze its top voxels in every frame."""
    space = KnownSpace()
    pos = np.array([0.0, 0.0, -7.0])
    top_m = pos[2] - 0.05
    for _ in range(2):
        space.integrate(_wall_below(top_m, pos[2], 3.1), K, pos, LEVEL_NORTH)
    occupied = space.grid == OCCUPIED
    assert occupied.sum() > 100
    assert np.all(space.near_hit[occupied] == 1)
    wall = space.occupied_points_ned_m()
    assert wall[:, 2].min() < top_m  # its top voxels reach above the edge: grazed
    for dz in np.arange(0.02, 0.42, 0.02):
        climbed = pos + np.array([0.0, 0.0, -dz])
        space.integrate(_wall_below(top_m, climbed[2], 3.1), K, climbed, LEVEL_NORTH)
        states = np.array([space.state_at(p) for p in wall])
        assert np.all(states == OCCUPIED), (dz, int(np.sum(states != OCCUPIED)), len(states))


def test_the_goal_unreachable_latch_asks_for_a_surface_seen_near():
    """The pipeline's latch (``AvoidancePipeline._goal_surely_blocked``): a goal 0.4 m in
    front of a surface seen only from 7.7 m is blocked by its boundary but not surely (the
    hold is not latched); the same surface hit from 3 m is."""
    from types import SimpleNamespace

    from companion.guidance.map_boundaries import (
        MapBoundaryConfig,
        goal_surely_blocked,
        map_boundaries,
    )
    from companion.pipeline import AvoidancePipeline

    space = KnownSpace()
    start = np.array([0.0, 0.0, -7.0])
    for _ in range(3):
        space.integrate(_wall(7.7), K, start, LEVEL_NORTH)
    goal = start + np.array([7.3, 0.0, 0.0])
    near_pos = start + np.array([4.7, 0.0, 0.0])  # within the 4 m detection range
    cfg = MapBoundaryConfig(detect_range_m=4.0, inflate_m=0.65)
    pipeline = SimpleNamespace(goal_ned_m=goal, boundary_config=cfg, known_space=space)
    boundaries = map_boundaries(space, near_pos, goal, cfg)
    assert goal_surely_blocked(boundaries, goal, cfg)
    assert not AvoidancePipeline._goal_surely_blocked(pipeline, boundaries)
    for _ in range(2):
        space.integrate(_wall(3.0), K, near_pos, LEVEL_NORTH)
    boundaries = map_boundaries(space, near_pos, goal, cfg)
    assert AvoidancePipeline._goal_surely_blocked(pipeline, boundaries)
