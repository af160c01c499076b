"""Extended obstacles in lockstep: walls become several bounded boundary spheres (map
pieces), not one growing sphere — no 8 m climb over a 1.2 m wall, and a goal 2 m beyond a
wall is reached (or the stop is reported) instead of looking "inside" a 12 m sphere."""

from __future__ import annotations

import math

import pytest

from companion.known_space import KnownSpaceConfig
from evaluation.harness import RunConfig, run_scene
from evaluation.scenes import Scene
from plant_sim.params import QuadrotorParams
from plant_sim.world import Box, World

START_NED_M = (15.0, 0.0, -7.0)
WALL_NORTH_M = 10.0
WALL_THICKNESS_M = 0.3
SAFE_M = QuadrotorParams().arm_length_m + 0.3  # arm length + safety margin, as §6
_KS = KnownSpaceConfig()
# the most a boundary sphere reaches beyond the real surface: a whole piece (half the
# cube's diagonal), half the blind-spot depth, vehicle radius + margin (0.35 + 0.3)
SPHERE_REACH_M = 0.5 * math.sqrt(3.0) * _KS.piece_vox * _KS.voxel_m + 0.5 * _KS.blind_depth_m + 0.65


def _wall_scene(name: str, height_m: float, goal_ned_m) -> Scene:
    wall = Box(center_ned_m=(WALL_NORTH_M, 0.0, -7.0), size_m=(WALL_THICKNESS_M, 9.6, height_m))
    return Scene(
        name=name, start_ned_m=START_NED_M, goal_ned_m=goal_ned_m, world=World(boxes=(wall,))
    )


@pytest.fixture(scope="module")
def low_wall():
    """A 9.6 m wide, 1.2 m high wall across the path (its top 0.6 m above it)."""
    return run_scene(_wall_scene("low-wall", 1.2, (4.0, 0.0, -7.0)), RunConfig(max_time_s=60.0))


@pytest.fixture(scope="module")
def goal_beyond_wall():
    """The 9.6 × 6 m wall of the issue, the goal 2 m beyond its far face."""
    goal = (WALL_NORTH_M - 0.5 * WALL_THICKNESS_M - 2.0, 0.0, -7.0)
    return run_scene(_wall_scene("goal-beyond-wall", 6.0, goal), RunConfig(max_time_s=60.0))


def test_a_low_wall_is_passed_with_a_bounded_climb(low_wall):
    v, h = low_wall.verdict, low_wall.history
    assert v.reached_goal and not v.collided, v
    assert v.targets_inside_boundary == 0, v  # invariant 3
    assert v.min_surface_distance_m >= SAFE_M, v
    # climb above the start: at most the wall's top above the path plus what a piece's
    # sphere adds (the old single growing sphere climbed 8 m)
    climb_m = START_NED_M[2] - h.column("down_m").min()
    assert climb_m <= 0.6 + SPHERE_REACH_M, climb_m
    # it went round the wall's end or over its top: never through
    passed_end = h.column("east_m").min() < -4.8 or h.column("east_m").max() > 4.8
    assert passed_end or climb_m > 0.6


def test_a_goal_two_metres_beyond_a_wall_is_reached_or_reported(goal_beyond_wall):
    v, h = goal_beyond_wall.verdict, goal_beyond_wall.history
    assert not v.collided and v.min_surface_distance_m >= SAFE_M, v
    assert v.targets_inside_boundary == 0, v  # invariant 3
    assert v.reached_goal or (v.failure == "hold" and v.hold_reason == "goal_unreachable"), v
    assert START_NED_M[2] - h.column("down_m").min() <= SPHERE_REACH_M
