"""The paper's §6 scenario and the suite's Monte Carlo sample flown in lockstep with a
RealSense-like depth camera (issue 35): depth frames with z²-proportional error, holes at
depth edges and no data beyond range, through the companion's depth-camera source (no
matcher); guidance, envelope and known space unchanged."""

import numpy as np
import pytest
from test_lockstep_montecarlo import SEEDS

from evaluation.harness import run_scene
from evaluation.montecarlo import fly_seed, is_safe, run_config
from evaluation.scenes import paper_scene
from plant_sim.depth_camera import CameraEncoding, DepthNoiseParams
from plant_sim.params import QuadrotorParams


@pytest.fixture(scope="module")
def depth_run():
    cfg = run_config("depth")
    assert cfg.camera_encoding is CameraEncoding.DEPTH16
    assert cfg.depth_noise.subpixel_rms_px == DepthNoiseParams().subpixel_rms_px > 0.0
    return run_scene(paper_scene(), cfg)


def test_paper_scene_with_depth_frames_reaches_the_goal_without_collision(depth_run):
    v = depth_run.verdict
    assert v.reached_goal and v.failure is None, v
    assert v.final_goal_distance_m < 0.5
    assert not v.collided
    # as with the stereo pair: the arm length plus the 0.3 m safety margin
    assert v.min_surface_distance_m >= QuadrotorParams().arm_length_m + 0.3, v
    assert v.max_roll_cmd_deg <= 15.0 + 1e-9 and v.max_pitch_cmd_deg <= 15.0 + 1e-9


def test_paper_scene_with_depth_frames_avoids_once(depth_run):
    """One avoidance pulse that rises within the 4 m threshold (plus a frame, a voxel and
    the camera's error at that range) and falls after the obstacle's centre."""
    h = depth_run.history
    flag = h.column("avoid_flag")
    edges = np.flatnonzero(np.diff(flag))
    assert len(edges) == 2, f"flag toggled {len(edges)} times"
    rise, fall = edges[0] + 1, edges[1] + 1
    surface = h.column("nearest_surface_m")
    assert 3.0 <= surface[rise] <= 4.0 / np.cos(np.radians(15.0)) + 0.05 + 0.2 + 0.2
    assert h.column("north_m")[fall] < 10.0 + 1.5


@pytest.mark.slow
@pytest.mark.own_flight
@pytest.mark.parametrize("seed", SEEDS)
def test_monte_carlo_sample_with_depth_frames_has_no_collision(seed):
    """Each seed of the sample in this process (one test per seed: pytest-xdist spreads
    them; no Dask cluster)."""
    v = fly_seed(seed, perception="depth")
    print("depth-camera Monte Carlo sample:", v)
    assert not v.collided, v
    assert is_safe(v), v  # the goal, or a stop guidance reported
    assert v.min_surface_distance_m >= 0.35, v
