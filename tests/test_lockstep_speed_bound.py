"""The stated speed is the flown speed (issue 36 item 5): at the fast airframe, on every
frame of the lockstep walls, corridors and the Monte Carlo sample, the measured speed is at
most the envelope's stated limit plus the overspeed tolerance (0.3 m/s)."""

from __future__ import annotations

import numpy as np
import pytest
from test_lockstep_wall import assert_safe_stop

from companion.guidance.envelope import EnvelopeConfig
from evaluation.harness import RunConfig, run_scene
from evaluation.passage_scenes import corridor_scene, gap_scene, passage_scene
from evaluation.scenes import Scene, mixed_scene, wall_scene
from plant_sim.profiles import profile
from plant_sim.world import Box, World

TOLERANCE_MPS = EnvelopeConfig().overspeed_tolerance_mps  # 0.3 m/s, the bound
MC_SAMPLE_SEEDS = range(100, 108)  # tests/test_lockstep_montecarlo.py's sample


def _wall(name: str, height_m: float, goal_ned_m) -> Scene:
    """tests/test_lockstep_walls.py's 9.6 m wide wall across the path at north 10 m."""
    wall = Box(center_ned_m=(10.0, 0.0, -7.0), size_m=(0.3, 9.6, height_m))
    return Scene(name, (15.0, 0.0, -7.0), goal_ned_m, World(boxes=(wall,)))


SCENES = {
    "low-wall": lambda: _wall("low-wall", 1.2, (4.0, 0.0, -7.0)),
    "goal-beyond-wall": lambda: _wall("goal-beyond-wall", 6.0, (7.85, 0.0, -7.0)),
    "corridor-3m": lambda: corridor_scene(3.0),
    "corridor-2.5m": lambda: corridor_scene(2.5),
    "gap-3m": lambda: gap_scene(3.0),
    **{f"mc-{s}": (lambda s=s: mixed_scene(s)) for s in MC_SAMPLE_SEEDS},
}


def _fast_run(scene: Scene, max_time_s: float = 40.0):
    fast = profile("fast")
    cfg = RunConfig(vehicle=fast.vehicle, control=fast.control, max_time_s=max_time_s)
    return run_scene(scene, cfg)


# The steep climb of seed 101 (issue 31): ArduCopter shapes north/east and down apart, so
# it climbed at 28° toward a carrot within guidance's 12° and, braking, the envelope looked
# along a velocity above the camera's view and stated 0 m/s. The companion now states the
# climb and descent speeds too (companion.link.speed_limit.climb_limit); this scene runs
# with the others. (Seed 104's one-frame map flicker (issue 36) does not occur with the
# autopilot in the loop and issue 36's path rule.)
@pytest.mark.slow
@pytest.mark.own_flight
@pytest.mark.parametrize("name", sorted(SCENES))
def test_speed_never_exceeds_the_stated_limit_at_the_fast_airframe(name):
    _assert_within_the_stated_limit(name, _fast_run(SCENES[name]()))


# A staged climb beside a wall (issue 36, the vertical family): the goal 5.5 m straight
# above, the stages 12° up along the heading. ArduCopter climbs at the least climb speed
# stated (0.1 m/s) while the stage is flown slowly, steeper than the path and above the
# camera's view; at the paper airframe the bound stated along that velocity while
# braking was 0 m/s on 15 frames of this scene (docs/safety-envelope.md). The first 25 s
# hold the stages, the turns and the brakes between them; at the fast airframe main
# (dc01db0) flew them within the bound too (worst 0.10 m/s over): a guard, not a
# reproducer.
@pytest.mark.slow
@pytest.mark.own_flight
def test_speed_never_exceeds_the_stated_limit_on_a_staged_climb_at_the_fast_airframe():
    result = _fast_run(passage_scene(215, "vertical"), max_time_s=25.0)
    _assert_within_the_stated_limit("vertical-215", result)


@pytest.fixture(scope="module")
def textureless_wall_run():
    """The textureless wall at the fast airframe: one flight for the speed bound and the
    stop (tests/test_lockstep_wall.py flies it at the paper's airframe)."""
    return _fast_run(wall_scene())


@pytest.mark.slow
def test_speed_never_exceeds_the_stated_limit_before_a_textureless_wall(textureless_wall_run):
    _assert_within_the_stated_limit("textureless-wall", textureless_wall_run)


@pytest.mark.slow
def test_the_fast_airframe_stops_before_a_textureless_wall(textureless_wall_run):
    """As tests/test_lockstep_wall.py at the paper's airframe: stopped short of the wall
    within 8 s (the flight is deterministic, so its first 8 s are those of an 8 s run), and
    the run ends in a reported stop."""
    assert_safe_stop(textureless_wall_run, by_time_s=8.0)
    assert textureless_wall_run.verdict.failure == "hold", textureless_wall_run.verdict


def _assert_within_the_stated_limit(name: str, result) -> None:
    h = result.history
    speed, limit = h.column("speed_mps"), h.column("speed_limit_mps")
    over = speed - limit
    worst = int(np.argmax(over))
    assert over[worst] <= TOLERANCE_MPS, (
        f"{name}: {int(np.sum(over > TOLERANCE_MPS))} of {len(over)} frames over the limit; "
        f"worst at t={h.column('time_s')[worst]:.2f} s: {speed[worst]:.2f} m/s against "
        f"{limit[worst]:.2f} m/s (free {h.column('free_distance_m')[worst]:.2f} m)"
    )
    assert not result.verdict.collided, result.verdict
