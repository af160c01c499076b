"""The position estimate's uncertainty: what plant-sim states (GPS_RAW_INT h_acc) and how
the companion widens its margins by it (issue 31 item 4)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.perception import PerceptionConfig
from companion.pipeline import AvoidancePipeline, PoseAtCapture
from companion.position_uncertainty import NO_WIDENING, widening
from evaluation.scenes import paper_scene
from plant_sim.autopilot.telemetry import TelemetryBuilder, VehicleIdentity
from plant_sim.disturbance import DisturbanceConfig, Disturbances, EstimateConfig
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.vehicle import Quadrotor
from protocols.camera import CameraModel
from protocols.stereo_frame import StereoFrame


# ---- the widening rule -------------------------------------------------------------------
@pytest.mark.parametrize(
    ("stated", "floor", "widen", "covered"),
    [
        (None, 0.0, 0.0, True),  # nothing stated, nothing configured
        (None, 0.12, 0.12, True),  # the configured floor
        (0.05, 0.12, 0.12, True),  # a better stated accuracy never narrows the floor
        (0.231, 0.0, 0.24, True),  # rounded up to whole centimetres
        (0.5, 0.0, 0.5, True),  # exactly the most the margins take
        (2.5, 0.0, 0.5, False),  # a GPS without RTK: not covered, widened by the most
        (math.nan, 0.1, 0.1, True),  # garbage is "not stated"
        (-1.0, 0.0, 0.0, True),
    ],
)
def test_widening_is_the_larger_of_floor_and_stated_bounded_by_the_most(
    stated, floor, widen, covered
):
    w = widening(stated, floor, 0.5)
    assert w.widen_m == pytest.approx(widen, abs=1e-12), w
    assert w.covered is covered
    assert w.stated_m == (
        stated if stated is not None and stated >= 0 and stated == stated else None
    )


def test_no_widening_is_the_default_of_a_pipeline_output():
    assert widening(None, 0.0, 0.5) == NO_WIDENING


# ---- what plant-sim states -----------------------------------------------------------------
def test_stated_accuracy_follows_the_simulated_error():
    """h: root sum of squares of the wander's σ, the jump size (jumps on) and the drift
    accumulated so far; v: the vertical wander's σ and vertical drift; (0, 0) undisturbed."""
    calm = Disturbances(DisturbanceConfig(seed=1))
    assert calm.stated_accuracy_m == (0.0, 0.0)
    est = EstimateConfig(
        wander_std_m=0.1,
        wander_vertical_std_m=0.05,
        drift_ned_mps=(0.003, 0.004, 0.001),
        jump_m=0.2,
        jump_every_s=40.0,
    )
    d = Disturbances(DisturbanceConfig(estimate=est, seed=3))
    assert d.stated_accuracy_m[0] == pytest.approx(math.hypot(0.1, 0.2), rel=1e-12)
    d.advance(100.0)  # 100 s of drift: 0.5 m horizontal, 0.1 m vertical
    h, v = d.stated_accuracy_m
    assert h == pytest.approx(math.sqrt(0.1**2 + 0.2**2 + 0.5**2), rel=1e-6)
    assert v == pytest.approx(math.hypot(0.05, 0.1), rel=1e-6)
    no_jumps = Disturbances(
        DisturbanceConfig(estimate=EstimateConfig(wander_std_m=0.1, jump_m=0.2))
    )
    assert no_jumps.stated_accuracy_m[0] == pytest.approx(0.1)  # jump_every_s inf: none


def test_a_stated_floor_is_what_sitl_states_without_any_error():
    """ArduPilot SITL states SIM_GPS_ACC (0.3 m) for h_acc and v_acc with no wander at all:
    ``stated_floor_m`` gives that, and a larger simulated error still shows through."""
    sitl_like = Disturbances(DisturbanceConfig(estimate=EstimateConfig(stated_floor_m=0.3)))
    assert sitl_like.stated_accuracy_m == (0.3, 0.3)
    assert sitl_like.estimate_error_ned_m == (0.0, 0.0, 0.0)
    worse = EstimateConfig(wander_std_m=0.4, wander_vertical_std_m=0.1, stated_floor_m=0.3)
    assert Disturbances(DisturbanceConfig(estimate=worse)).stated_accuracy_m == (0.4, 0.3)


def test_gps_raw_int_carries_the_stated_accuracy_in_mm():
    builder = TelemetryBuilder(VehicleIdentity(47.0, 8.0, 500.0))
    snap = Quadrotor(pos_ned_m=(0.0, 0.0, -7.0)).snapshot()
    msg = builder.gps_raw(snap, (0.2236, 0.05))
    assert (msg.h_acc, msg.v_acc) == (224, 50)
    assert builder.gps_raw(snap).h_acc == 0  # undisturbed: none stated


# ---- the companion widens every margin ------------------------------------------------------
def _fly_three_frames(h_acc_m, config=None):
    """Three frames 3.5 m before the paper's sphere, facing it, with ``h_acc_m`` stated."""
    scene = paper_scene()
    cam = CameraModel()
    renderer = StereoCameraRenderer(cam)
    pipeline = AvoidancePipeline(scene.goal_ned_m, perception=config)
    pos = np.array([15.0, 0.0, -7.0])
    R = np.diag([-1.0, -1.0, 1.0])
    pose = PoseAtCapture(pos, np.zeros(3), R, h_acc_m=h_acc_m)
    out = None
    for seq in range(3):
        render = renderer.render(scene.world, pos, R, noise_seed=seq)
        frame = StereoFrame(seq, seq * 33_000_000, cam.intrinsics, render.left, render.right)
        out = pipeline.process(frame, pose, steering=False)
    return pipeline, out


def test_a_stated_accuracy_widens_boundaries_paths_and_the_swept_section():
    """The same map, with h_acc 0.2 m stated: every boundary 0.2 m larger (radius), the
    known-space path's clearance and section and the envelope's section 0.2 m wider, so
    the known-free distance ahead can only shrink."""
    base_pipe, base = _fly_three_frames(None)
    wide_pipe, wide = _fly_three_frames(0.2)
    assert base.widening == NO_WIDENING and wide.widening.widen_m == pytest.approx(0.2)
    r_base = sorted(b.radius_m for b in base.boundaries)
    r_wide = sorted(b.radius_m for b in wide.boundaries)
    assert r_base and len(r_base) == len(r_wide)
    np.testing.assert_allclose(np.subtract(r_wide, r_base), 0.2, atol=1e-9)
    assert wide_pipe.vehicle_radius_m == pytest.approx(base_pipe.vehicle_radius_m + 0.2)
    kp_b, kp_w = base_pipe.known_path_config, wide_pipe.known_path_config
    assert kp_w.clearance_m - kp_b.clearance_m == pytest.approx(0.2)
    assert kp_w.section_radius_m - kp_b.section_radius_m == pytest.approx(0.2)
    assert wide.envelope.free_distance_m <= base.envelope.free_distance_m


def test_an_accuracy_beyond_the_margins_is_reported_not_covered():
    pipe, out = _fly_three_frames(2.0, PerceptionConfig(max_position_uncertainty_m=0.4))
    assert not out.widening.covered and out.widening.stated_m == 2.0
    assert pipe.widen_m == pytest.approx(0.4)
