"""A textureless wall across the paper's path, in lockstep with the safety envelope
(issue 14): the camera matches nothing on it, so the space ahead stays unknown and the
vehicle must stop at least 0.5 m before it, at the paper's speed and at the fast profile."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.known_space import KnownSpaceConfig
from evaluation.harness import RunConfig, run_scene
from evaluation.scenes import wall_scene
from plant_sim.profiles import profile

STOP_CLEARANCE_M = 0.5  # issue 14: safe stop at least this far before the wall
WALL_FACE_NORTH_M = 10.1


def _run(profile_name: str, known_space: KnownSpaceConfig, max_time_s: float):
    p = profile(profile_name)
    cfg = RunConfig(
        vehicle=p.vehicle, control=p.control, known_space=known_space, max_time_s=max_time_s
    )
    return run_scene(wall_scene(), cfg)


def assert_safe_stop(result, by_time_s: float = math.inf):
    """Stopped short of the wall without reaching the goal, and at rest over the last
    second flown by ``by_time_s`` [s of simulation time]."""
    v, h = result.verdict, result.history
    assert not v.collided and not v.reached_goal, v
    assert v.min_surface_distance_m >= STOP_CLEARANCE_M, v
    assert h.column("north_m").min() >= WALL_FACE_NORTH_M + STOP_CLEARANCE_M
    flown = h.column("time_s") <= by_time_s + 1e-9
    assert np.all(h.column("speed_mps")[flown][-30:] < 0.1), "stopped, not crawling on"


@pytest.mark.slow
@pytest.mark.own_flight
def test_stop_before_a_textureless_wall():
    """Perception reports the wall unknown (no depth, no far claim through it), known space
    takes no sky through it (no ground is matched in its columns), the envelope never flies
    into unknown space: the vehicle stops short of the wall. Default configuration. (The
    fast airframe's stop is checked on tests/test_lockstep_speed_bound.py's flight of this
    scene, the first 8 s of which are this test's flight at that airframe.)"""
    assert_safe_stop(_run("paper", KnownSpaceConfig(), 8.0))
