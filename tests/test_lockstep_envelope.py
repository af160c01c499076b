"""The safety envelope in closed loop: the companion dies (SIGKILL) at 20 evenly spaced
times of the paper's flight, plain and fast profile; the autopilot holds the last setpoint
and the vehicle must stop clear of the obstacle (surface distance ≥ 0.35 m)."""

from __future__ import annotations

import numpy as np
import pytest

from companion.guidance.envelope import EnvelopeConfig
from companion.perception import PerceptionConfig
from evaluation.harness import RunConfig, run_scene
from evaluation.scenes import paper_scene
from plant_sim.profiles import profile, terminal_speed_mps
from plant_sim.world import paper_world

COLLISION_M = 0.35  # vehicle centre to surface: its radius with propellers
N_KILLS = 20


def _flight_with_kills(name: str, flight_time_s: float):
    p = profile(name)
    cfg = RunConfig(vehicle=p.vehicle, control=p.control)
    return run_scene(paper_scene(), cfg, kill_times_s=np.linspace(0.0, flight_time_s, N_KILLS))


@pytest.fixture(scope="module")
def paper_kills():
    return _flight_with_kills("paper", 25.0)  # the flight takes ~26.6 s


@pytest.fixture(scope="module")
def fast_kills():
    return _flight_with_kills("fast", 15.0)  # the flight takes ~15.9 s


@pytest.mark.parametrize("which", ["paper_kills", "fast_kills"])
def test_companion_death_at_any_time_ends_in_a_stop_clear_of_the_obstacle(which, request):
    run = request.getfixturevalue(which)
    assert run.verdict.passed, run.verdict
    assert len(run.kills) == N_KILLS
    # the kills span the whole flight (its length moves with perception and guidance)
    assert run.kills[-1].stop_s >= 0.9 * run.verdict.sim_time_s, run.verdict
    for kill in run.kills:
        assert kill.stopped, kill
        assert kill.min_surface_distance_m >= COLLISION_M, kill
        # it stops where it was told: at the last setpoint, not at the far goal (within
        # 0.35 m: "stopped" is < 0.05 m/s for 1 s, and the LQ position loop's slow pole,
        # -0.47 1/s, creeps the last decimetres after that)
        np.testing.assert_allclose(
            kill.end_pos_ned_m, kill.last_setpoint_ned_m, atol=0.35, err_msg=str(kill)
        )


@pytest.mark.parametrize("which", ["paper_kills", "fast_kills"])
def test_every_setpoint_lies_in_known_free_space_and_in_true_free_space(which, request):
    """|setpoint − p| ≤ F − margin (the carrot rule), and the setpoint is at least the
    vehicle radius away from the true surface (the map never called an obstacle free)."""
    h = request.getfixturevalue(which).history
    pos = np.column_stack([h.column("north_m"), h.column("east_m"), h.column("down_m")])
    sp = np.column_stack(
        [h.column("setpoint_north_m"), h.column("setpoint_east_m"), h.column("setpoint_down_m")]
    )
    reach = np.linalg.norm(sp - pos, axis=1)
    room = np.maximum(h.column("free_distance_m") - EnvelopeConfig().margin_m, 0.0)
    assert np.all(reach <= room + 1e-9), np.max(reach - room)
    sphere = paper_world().spheres[0]
    surface = np.array([sphere.surface_distance_m(x) for x in sp])
    assert surface.min() >= PerceptionConfig().vehicle_radius_m, surface.min()


def test_fast_profile_flies_faster_than_the_paper_and_within_the_stopping_bound(fast_kills):
    v = fast_kills.verdict
    h = fast_kills.history
    speed = h.column("speed_mps")
    assert terminal_speed_mps(profile("fast")) >= 5.0
    assert speed.max() > 2.0 * terminal_speed_mps(profile("paper"))
    assert v.max_pitch_cmd_deg <= profile("fast").control.max_tilt_deg + 1e-9
    # the paper profile's sideways step survives at speed
    assert h.column("east_m").min() < -2.0
