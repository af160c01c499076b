"""Monte Carlo sample in the suite: fixed seeds of every scene family, zero collisions,
every run ends at the goal or in a reported stop.

Each seed is flown in this process, one test per seed (``fly_seed``, the function every
Dask worker flies a seed with: the same verdict, tests/test_montecarlo_cluster.py), so
pytest-xdist spreads the seeds over its workers and the fast loop starts no process.
"""

import math

import numpy as np
import pytest

from evaluation.montecarlo import fly_seed, is_safe
from evaluation.scenes import FAMILIES, family_scene, mixed_scene, random_scene

SEEDS = range(100, 108)
# The boundary a sphere is steered around: its radius plus the vehicle's (0.35 m) and the
# safety margin (0.3 m), companion.perception's inflation.
BOUNDARY_INFLATION_M = 0.65


def _line_clearance_m(scene) -> float:
    """Least distance from the straight line start -> goal to a sphere's boundary [m]."""
    start, goal = np.array(scene.start_ned_m), np.array(scene.goal_ned_m)
    leg = goal - start
    clearances = []
    for sphere in scene.world.spheres:
        centre = np.array(sphere.center_ned_m)
        t = np.clip(np.dot(centre - start, leg) / np.dot(leg, leg), 0.0, 1.0)
        to_line_m = np.linalg.norm(start + t * leg - centre)
        clearances.append(to_line_m - sphere.radius_m - BOUNDARY_INFLATION_M)
    return min(clearances, default=math.inf)


def test_random_scenes_are_reproducible_and_valid():
    for seed in range(50):
        a, b = random_scene(seed), random_scene(seed)
        assert a == b
        assert 1 <= len(a.world.spheres) <= 3
        for s in a.world.spheres:
            assert 0.5 <= s.radius_m <= 2.0
            assert s.surface_distance_m(a.start_ned_m) >= 6.0 - 1e-9
            assert s.surface_distance_m(a.goal_ned_m) >= 3.0 - 1e-9
    assert random_scene(1) != random_scene(2)


def test_scene_families_are_reproducible_and_what_they_say():
    for seed in range(40):
        for family in FAMILIES:
            assert family_scene(seed, family) == family_scene(seed, family)
        assert mixed_scene(seed) == family_scene(seed, FAMILIES[seed % 4])
        start = np.array(family_scene(seed, "climb").start_ned_m)
        goal = np.array(family_scene(seed, "climb").goal_ned_m)
        climb_m = abs(goal[2] - start[2])
        assert 2.0 - 1e-9 <= climb_m <= 5.0 + 1e-9 or goal[2] in (-3.0, -14.0)
        assert math.degrees(math.atan2(climb_m, np.linalg.norm(goal[:2] - start[:2]))) <= 11.4
        near = family_scene(seed, "goal_near")
        assert 0.0 <= near.world.spheres[-1].surface_distance_m(near.goal_ned_m) <= 1.5 + 1e-9
        away = family_scene(seed, "facing_away")
        heading = math.atan2(*(np.subtract(away.goal_ned_m, away.start_ned_m)[[1, 0]]))
        assert math.cos(away.start_yaw_rad - heading) == pytest.approx(-1.0)
        assert 1.5 - 1e-9 <= away.world.spheres[-1].surface_distance_m(away.start_ned_m) <= 2.6
    with pytest.raises(ValueError, match="valid"):
        family_scene(0, "spiral")


def test_most_scenes_of_the_sample_put_an_obstacle_in_the_way():
    """The sample tests avoidance: the straight line to the goal crosses a boundary in at
    least half its scenes (in all 8 today)."""
    crossing = [_line_clearance_m(mixed_scene(seed)) < 0.0 for seed in SEEDS]
    assert np.mean(crossing) >= 0.5, crossing


@pytest.mark.slow
@pytest.mark.own_flight
@pytest.mark.parametrize("seed", SEEDS)
def test_monte_carlo_sample_has_no_collision(seed):
    v = fly_seed(seed)  # mixed: two of each family over the sample
    print(v)
    assert not v.collided, v
    assert is_safe(v), v  # the goal, or a stop guidance reported
    assert v.min_surface_distance_m >= 0.35, v
    # invariant 3 of the envelope: no target (carrot or hold) inside a boundary guidance
    # had; before keep_target_out seeds 103 and 105 sent 39 and 16 (2-12 cm deep)
    assert v.targets_inside_boundary == 0, v
    # invariant 2 of the envelope, issue 31's bar: the companion's overspeed warning never
    # fires (seeds 101 and 107 had 1 and 5 frames before the climb and descent statements)
    assert v.overspeed_frames == 0, v


# The nearest passes found by the 1000-scene ground-truth Monte Carlo runs (flown past a
# sphere's flank the map had seen free through voxel corners, or not at all): 762 collided
# (0.2497 m), the others passed at 0.27-0.32 m.
NEAREST_PASSES = (323, 487, 762, 771)


@pytest.mark.slow
@pytest.mark.own_flight
@pytest.mark.parametrize("seed", NEAREST_PASSES)
def test_the_nearest_passes_of_the_monte_carlo_keep_their_distance(seed):
    v = fly_seed(seed, perception="truth")
    assert not v.collided and v.failure is None, v
    # the collision distance (0.35 m) plus half a voxel: these are the sample's
    # nearest passes, kept so that a change that brings them nearer shows
    assert v.min_surface_distance_m >= 0.35 + 0.1, v
