"""The lockstep harness flies a waypoint mission through the companion's Mission."""

from __future__ import annotations

import numpy as np

from evaluation.harness import RunConfig, run_scene
from evaluation.scenes import Scene
from plant_sim.world import World

TOLERANCE_M = 0.5


def test_three_waypoint_mission_visits_each_in_order():
    """Start (0, 0, −7) → (6, 0, −7) → (6, 5, −6) → goal (1, 5, −6), NED metres, over the
    ground plane: every waypoint is passed within the tolerance, in order, and the goal
    ends the run (turning toward each new leg is looked at before it is flown)."""
    wps = ((6.0, 0.0, -7.0), (6.0, 5.0, -6.0), (1.0, 5.0, -6.0))
    scene = Scene(
        name="waypoints",
        start_ned_m=(0.0, 0.0, -7.0),
        via_ned_m=wps[:2],
        goal_ned_m=wps[2],
        world=World(),
    )
    result = run_scene(scene, RunConfig(max_time_s=60.0))
    v = result.verdict
    assert v.reached_goal and not v.collided, v
    h = result.history
    pos = np.column_stack([h.column("north_m"), h.column("east_m"), h.column("down_m")])
    start = 0
    for k, wp in enumerate(wps):
        near = np.flatnonzero(np.linalg.norm(pos[start:] - wp, axis=1) < TOLERANCE_M)
        assert near.size, f"waypoint {k} {wp} never reached after sample {start}"
        start += int(near[0])
    assert np.linalg.norm(pos[-1] - wps[-1]) < TOLERANCE_M
