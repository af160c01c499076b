"""The paper's §6 flown with the position accuracy ArduPilot SITL states (issue 31).

No ArduCopter binary runs here, so plant-sim carries what SITL would change for the
companion. One thing SITL does that plant-sim does not by default: its simulated GPS
states ``h_acc = v_acc = SIM_GPS_ACC`` (0.3 m) with no error at all
(``libraries/SITL/SIM_GPS.cpp``), and the companion widens every margin by the stated
accuracy (:mod:`companion.position_uncertainty`). This flight checks the §6 verdict
survives that widening: still the goal, one avoidance pulse, no overspeed, no target
inside a boundary, and the closest approach further out by about the widening.
"""

import dataclasses

import numpy as np
import pytest

from evaluation.harness import run_scene
from evaluation.scenes import paper_scene
from plant_sim.disturbance import DisturbanceConfig, EstimateConfig
from plant_sim.params import QuadrotorParams

pytestmark = pytest.mark.slow

SITL_GPS_ACC_M = 0.3  # SIM_GPS_ACC's default (ArduPilot libraries/SITL/SITL.cpp)
PAPER_CLOSEST_M = 1.26  # the §6 closest approach with nothing stated (README, docs/results.md)


@pytest.fixture(scope="module")
def sitl_like_run():
    stated = DisturbanceConfig(estimate=EstimateConfig(stated_floor_m=SITL_GPS_ACC_M))
    scene = dataclasses.replace(paper_scene(), disturbance=stated)
    return run_scene(scene)


def test_paper_scene_with_sitl_stated_accuracy_reaches_the_goal(sitl_like_run):
    v = sitl_like_run.verdict
    assert v.reached_goal and v.failure is None and not v.collided, v
    assert v.overspeed_frames == 0 and v.targets_inside_boundary == 0, v
    # the vehicle (arm + 0.3 m margin) widened by the stated 0.3 m never touched
    assert v.min_surface_distance_m >= QuadrotorParams().arm_length_m + 0.3 + SITL_GPS_ACC_M, v
    # the widening moves the pass outward, by no more than the widening and the vehicle's
    # own lateral tracking (the paper airframe's 0.85 m/s drag limit: a few tenths)
    assert PAPER_CLOSEST_M + 0.1 <= v.min_surface_distance_m <= PAPER_CLOSEST_M + 0.7, v


def test_paper_scene_with_sitl_stated_accuracy_avoids_once(sitl_like_run):
    flag = sitl_like_run.history.column("avoid_flag")
    edges = np.flatnonzero(np.diff(flag))
    assert len(edges) == 2, f"flag toggled {len(edges)} times"
    assert sitl_like_run.history.column("north_m")[edges[1] + 1] < 10.0 + 1.5
