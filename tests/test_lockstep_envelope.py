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


SHARED_FLIGHT = "paper"  # conftest.py's paper_flight, flown once with test_lockstep_paper


@pytest.fixture(scope="module")
def paper_kills(paper_flight):
    """The paper profile is the default configuration: conftest.py's §6 flight, whose
    companion deaths are at the same 20 times up to 26.5 s (the flight takes ~26.7 s)."""
    return paper_flight


@pytest.fixture(scope="module")
def fast_kills():
    return _flight_with_kills("fast", 15.8)  # the flight takes ~16.8 s


@pytest.mark.parametrize("which", ["paper_kills", "fast_kills"])
def test_companion_death_at_any_time_ends_in_a_stop_clear_of_the_obstacle(which, request):
    run = request.getfixturevalue(which)
    assert run.verdict.passed, run.verdict
    # the companion's overspeed warning never fires with the envelope on (issue 31)
    assert run.verdict.overspeed_frames == 0, run.verdict
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


# ---- conformance with ArduCopter SITL (docs/autopilots.md; the rows without the companion
# are tests/test_autopilot_shaping.py's CONFORMANCE) ---------------------------------------
#: ArduCopter SITL, default WPNAV_SPEED, the companion with the safety envelope (its speed
#: limit stated by DO_CHANGE_SPEED): top speed and least surface distance, and plant-sim's
#: tolerance on each. Top speed: +0.5 m/s above, because lockstep flies on the envelope's
#: 0.15 s latency floor while the SITL runs (3x speed-up, a loaded machine) had larger
#: measured data ages, and the limit at a given free distance F rises as the latency τ
#: falls: v = a(−τ + sqrt(τ² + 2(F − margin)/a)) is 3.56 m/s at F = 4 m, τ = 0.15 s and
#: 3.13 m/s at τ = 0.4 s (a = 2 m/s², margin 0.3 m). Clearance: ±0.2 m (SITL's own spread
#: over four runs of one scene was 1.31–1.72 m).
SITL_WITH_ENVELOPE = {
    "top_speed_mps": ((2.5, 3.2), (0.3, 0.5)),
    "clearance_m": ((1.0, 1.5), (0.2, 0.2)),
}


def test_conformance_with_the_envelope_at_default_wpnav_speed(fast_kills):
    """plant-sim's ArduCopter GUIDED (default WPNAV_SPEED, shaping on), the fast airframe
    (the one the SITL rows use), the companion with the envelope stating its limit."""
    v = fast_kills.verdict
    measured = {
        "top_speed_mps": float(fast_kills.history.column("speed_mps").max()),
        "clearance_m": v.min_surface_distance_m,
    }
    for name, ((lo, hi), (below, above)) in SITL_WITH_ENVELOPE.items():
        assert lo - below <= measured[name] <= hi + above, (name, measured[name], (lo, hi))
    assert v.passed and v.overspeed_frames == 0, v
