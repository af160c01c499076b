"""Monte Carlo sample in the suite: fixed seeds of every scene family, zero collisions,
every run ends at the goal or in a reported stop."""

import math

import numpy as np
import pytest

from evaluation.montecarlo import run_batch, summarize
from evaluation.scenes import FAMILIES, family_scene, mixed_scene, random_scene

SEEDS = range(100, 108)


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


@pytest.mark.slow
def test_monte_carlo_sample_has_no_collision():
    verdicts = run_batch(SEEDS, jobs=2)  # mixed: two of each family
    summary = summarize(verdicts)
    assert summary["collision_rate"] == 0.0, summary["failed_seeds"]
    assert summary["safe_outcome_rate"] == 1.0, summary["failures_by_cause"]
    assert all(v.min_surface_distance_m >= 0.35 for v in verdicts)
    # invariant 3 of the envelope: no target (carrot or hold) inside a boundary guidance
    # had; before keep_target_out seeds 103 and 105 sent 39 and 16 (2-12 cm deep)
    assert [v.targets_inside_boundary for v in verdicts] == [0] * len(verdicts), verdicts
    # Not asserted: overspeed_frames == 0 (issue 31's bar). Seeds 101 and 107 have 1 and 5
    # frames where the envelope's free distance collapses to its 0.3 m bubble while the
    # autopilot climbs or descends steeper than the camera sees (see
    # tests/test_lockstep_speed_bound.py, _STEEP_CLIMB); open, reported.
    # at least half the scenes put an obstacle in the way
    assert np.mean([v.avoidance_time_s > 0 for v in verdicts]) >= 0.5


# The nearest passes found by the 1000-scene ground-truth Monte Carlo runs (flown past a
# sphere's flank the map had seen free through voxel corners, or not at all): 762 collided
# (0.2497 m), the others passed at 0.27-0.32 m.
NEAREST_PASSES = (323, 487, 762, 771)


@pytest.mark.slow
def test_the_nearest_passes_of_the_monte_carlo_keep_their_distance():
    verdicts = run_batch(NEAREST_PASSES, perception="truth")
    for v in verdicts:
        assert not v.collided and v.failure is None, v
        # the collision distance (0.35 m) plus half a voxel: these are the sample's
        # nearest passes, kept so that a change that brings them nearer shows
        assert v.min_surface_distance_m >= 0.35 + 0.1, v
