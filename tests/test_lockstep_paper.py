"""The paper's §6 scenario flown in lockstep: plant, camera, perception and guidance."""

import math

import numpy as np
import pytest

from companion.known_space import KnownSpaceConfig
from evaluation.harness import RunConfig
from protocols.camera import CameraModel

pytestmark = pytest.mark.lockstep
SHARED_FLIGHT = "paper"  # conftest.py's paper_flight, flown once with test_lockstep_envelope


@pytest.fixture(scope="module")
def paper_run(paper_flight):
    """The §6 flight (conftest.py: its companion-death tails fly on copies)."""
    return paper_flight


def test_goal_reached_without_collision(paper_run):
    v = paper_run.verdict
    assert v.reached_goal, v
    assert v.final_goal_distance_m < 0.5
    assert not v.collided
    assert v.overspeed_frames == 0, v  # the companion's overspeed warning never fires
    assert v.targets_inside_boundary == 0, v  # invariant 3: no target inside a boundary
    # vehicle centre to the true obstacle surface: at least the vehicle's radius with
    # propellers (0.35 m, the collision distance) plus the 0.3 m safety margin
    assert v.min_surface_distance_m >= RunConfig().collision_distance_m + 0.3, v


def test_commanded_tilt_within_15_deg(paper_run):
    v = paper_run.verdict
    assert v.max_roll_cmd_deg <= 15.0 + 1e-9
    assert v.max_pitch_cmd_deg <= 15.0 + 1e-9
    assert v.max_pitch_cmd_deg == pytest.approx(15.0, abs=1e-6)  # the limit is used


def test_avoidance_flag_rises_near_4m_and_falls_once_passed(paper_run):
    h = paper_run.history
    flag = h.column("avoid_flag")
    surface = h.column("nearest_surface_m")
    north = h.column("north_m")
    edges = np.flatnonzero(np.diff(flag))
    assert len(edges) == 2, f"flag toggled {len(edges)} times"  # one pulse, no chatter
    rise, fall = edges[0] + 1, edges[1] + 1
    assert flag[rise] == 1.0 and flag[fall] == 0.0
    # rises when the surface comes within the 4 m threshold. The threshold is on depth
    # (Eq. 27, along the optical axis); cruising pitched 15° nose-down, the obstacle sits
    # 15° off-axis, so depth 4 m is a range of 4 / cos 15° = 4.14 m, plus one frame. The
    # boundaries come from the map, whose occupied voxels are within 4 m by their centre
    # (up to half a voxel's diagonal before the surface point in them), and a surface hit
    # one pixel of disparity too near (z² / f·b at that range) is in the map as well.
    ranged_m = 4.0 / np.cos(np.radians(15.0))
    voxel_m = KnownSpaceConfig().voxel_m
    one_px_m = ranged_m**2 / CameraModel().intrinsics.focal_baseline_m_px
    latest_m = ranged_m + 0.05 + 0.5 * np.sqrt(3.0) * voxel_m + one_px_m
    assert 3.7 <= surface[rise] <= latest_m, (surface[rise], latest_m)
    # falls only after the vehicle has passed the obstacle's centre (north = 10 m)
    assert north[fall] < 10.0 + 1.5, north[fall]
    assert flag[-1] == 0.0


def test_avoids_sideways_at_constant_altitude(paper_run):
    """One horizontal side-step of more than 2 m, to one side only; altitude stays within
    0.5 m of 7 m.

    The side is the map's: the boundaries are cut from the voxels the left eye saw, with
    the matcher's noise in them, so the approach is not an exact tie and the aiming point
    is on the side away from the boundaries' centre (only an exact tie falls to the
    documented tie-break, right of the velocity: with ground-truth depth, west).
    """
    h = paper_run.history
    east, down = h.column("east_m"), h.column("down_m")
    step_m, other_m = sorted((-east.min(), east.max()), reverse=True)
    assert step_m > 2.0 and other_m < 0.05, (east.min(), east.max())
    # 0.02 m with the committed reference levelled (avoidance._level_small_tilt); 0.58-0.67 m
    # without it, once plant-sim's velocity integrator or the climb statement was in
    assert np.max(np.abs(down + 7.0)) < 0.5


def test_vehicle_faces_where_it_goes(paper_run):
    """Yaw follows the horizontal velocity while moving (camera looks ahead)."""
    h = paper_run.history
    vn, ve, yaw = h.column("vn_mps"), h.column("ve_mps"), np.radians(h.column("yaw_deg"))
    moving = np.hypot(vn, ve) > 0.5
    course = np.arctan2(ve, vn)
    err = np.degrees(np.abs(np.angle(np.exp(1j * (course - yaw)))))
    assert np.median(err[moving]) < 10.0
    assert math.isclose(h.column("yaw_deg")[0], 180.0, abs_tol=1e-6)
