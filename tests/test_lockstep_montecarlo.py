"""Monte Carlo sample in the suite: fixed seeds, zero collisions, every goal reached."""

import numpy as np
import pytest

from plant_sim.lockstep.montecarlo import run_batch, summarize
from plant_sim.lockstep.scenes import random_scene

SEEDS = range(100, 112)


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


@pytest.mark.slow
def test_monte_carlo_sample_has_no_collision():
    verdicts = run_batch(SEEDS, jobs=2)
    summary = summarize(verdicts)
    assert summary["collision_rate"] == 0.0, summary["failed_seeds"]
    assert summary["goal_reached_rate"] == 1.0, summary["failures_by_cause"]
    # at least half the scenes put an obstacle in the way
    assert np.mean([v.avoidance_time_s > 0 for v in verdicts]) >= 0.5
