"""The lockstep harness's compiled bookkeeping and its ground-truth perception (issue 17/13):
``Quadrotor.step_watching`` equals stepping one step at a time and reading tilt and
clearance in Python; true disparity follows Eq. 27 exactly; perception on the ground-truth
depth source sees the paper's sphere where it is, and the harness hands that source to the
mission (no swap after construction); the progress bar's rate and ETA."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest

from companion.perception import PerceptionConfig, StereoPerception
from evaluation.harness import RunConfig, _start, nearest_surface_m
from evaluation.mc_progress import ProgressBar, format_duration
from evaluation.scenes import paper_scene
from evaluation.truth_perception import TruthDepthSource, truth_disparity_fixed
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.vehicle import Quadrotor, Setpoint
from protocols.camera import CameraModel
from protocols.stereo_frame import StereoFrame


def test_step_watching_equals_stepping_and_reading_one_step_at_a_time():
    scene = paper_scene()
    centres = np.array([s.center_ned_m for s in scene.world.spheres])
    radii = np.array([s.radius_m for s in scene.world.spheres])
    a, b = (Quadrotor(pos_ned_m=scene.start_ned_m, yaw_rad=math.pi) for _ in range(2))
    for q in (a, b):  # a hard start: full tilt toward the sphere
        q.set_setpoint(Setpoint(pos_ned_m=(9.0, 0.4, -7.0), yaw_rad=math.pi))
    max_roll = max_pitch = 0.0
    min_surface = math.inf
    for _ in range(400):
        a.step(1)
        roll, pitch = a.tilt_cmd_rad()
        max_roll, max_pitch = max(max_roll, abs(roll)), max(max_pitch, abs(pitch))
        min_surface = min(min_surface, nearest_surface_m(scene.world, a.pos_ned_m))
    watched = b.step_watching(400, centres, radii)
    sa, sb = a.snapshot(), b.snapshot()  # bit-identical state, read through the public API
    for name in ("pos_ned_m", "vel_ned_mps", "body_rates_frd_radps", "rotor_thrusts_n"):
        np.testing.assert_array_equal(getattr(sa, name), getattr(sb, name), err_msg=name)
    assert (sa.roll_rad, sa.pitch_rad, sa.yaw_rad) == (sb.roll_rad, sb.pitch_rad, sb.yaw_rad)
    assert a.time_s == b.time_s
    assert watched[0] == pytest.approx(max_roll, abs=1e-12)
    assert watched[1] == pytest.approx(max_pitch, abs=1e-12)
    assert watched[2] == pytest.approx(min_surface, abs=1e-12)
    assert math.radians(14.9) < watched[1] <= math.radians(15.0) + 1e-9  # the tilt limit
    assert b.step_watching(0, centres, radii) == (0.0, 0.0, math.inf)
    with pytest.raises(ValueError, match="radii"):
        b.step_watching(1, centres, radii[:0])


def test_true_disparity_is_eq27_rounded_with_the_right_camera_s_view():
    fb = 71.87  # f·b [m·px] of the paper's camera
    depth = np.array([[4.0, 4.0, 4.0, 4.0], [np.inf, np.nan, -1.0, 0.5]], np.float32)
    depth = np.repeat(depth, 100, axis=1)  # 400 columns: x = 0..399
    disp = truth_disparity_fixed(depth, fb)
    assert disp.dtype == np.int16
    d4 = round(16 * fb / 4.0)  # 287 (1/16 px) = 17.97 px
    assert disp[0, 399] == d4
    assert np.all(disp[0, : math.ceil(d4 / 16)] == -16)  # x - d < 0: the right eye misses it
    assert np.all(disp[0, math.ceil(d4 / 16) :] == d4)
    assert np.all(disp[1, :100] == 0)  # sky: at infinity
    assert np.all(disp[1, 100:300] == -16)  # NaN, negative: no depth
    assert disp[1, 399] == round(16 * fb / 0.5)
    np.testing.assert_allclose(16 * fb / disp[0, 100:], 4.0, rtol=2e-3)  # 1/16 px rounding


def test_true_disparity_saturates_and_takes_any_float_depth():
    """A surface nearer than 16·f·b / 32767 saturates at the int16 maximum (never wraps);
    float64 and float32 depth give the same disparities."""
    fb = 71.87
    depth = np.full((2, 3000), 1e-4)  # d = 16 · 71.87 / 1e-4 px ≫ int16 range
    depth[1] = 7.5
    disp = truth_disparity_fixed(depth, fb)
    assert np.all(disp[0, 2048:] == np.iinfo(np.int16).max)  # 32767/16 = 2048 columns
    assert np.all(disp[0, :2047] == -16)  # beyond the right camera's view there
    np.testing.assert_array_equal(disp, truth_disparity_fixed(depth.astype(np.float32), fb))
    assert disp[1, 2999] == round(16 * fb / 7.5)


def test_truth_perception_places_the_paper_sphere_where_it_is():
    scene = paper_scene()
    cam = CameraModel()
    renderer = StereoCameraRenderer(cam)
    pos = np.array([15.0, 0.0, -7.0])  # 3.5 m from the surface, facing it (yaw pi)
    R = np.diag([-1.0, -1.0, 1.0])
    depth = renderer.render_depth(scene.world, pos, R)
    frame = StereoFrame(7, 0, cam.intrinsics, *(np.zeros_like(depth, np.uint8),) * 2)
    source = TruthDepthSource(PerceptionConfig())
    truth = StereoPerception(source=source)
    with pytest.raises(RuntimeError, match="no true depth for frame 7"):
        truth.process(frame, pos, R)
    source.provide(7, depth)
    seen = truth.process(frame, pos, R)
    assert len(seen.obstacles) == 1
    obstacle = seen.obstacles[0]
    assert obstacle.nearest_range_m == pytest.approx(3.5, abs=0.05)
    sphere = scene.world.spheres[0]
    # the safety sphere encloses the true one's visible cap
    reach = np.linalg.norm(np.subtract(obstacle.center_ned_m, sphere.center_ned_m))
    assert reach + sphere.radius_m <= obstacle.radius_m + 0.05
    # the stereo matcher on the rendered pair sees the same obstacle, nearly
    render = renderer.render(scene.world, pos, R, noise_seed=7)
    stereo = StereoPerception().process(
        StereoFrame(7, 0, cam.intrinsics, render.left, render.right), pos, R
    )
    assert stereo.obstacles[0].nearest_range_m == pytest.approx(3.5, abs=0.3)
    assert RunConfig(truth_perception=True).truth_perception


@pytest.mark.parametrize("truth", [False, True])
def test_the_harness_hands_the_mission_its_depth_source(truth):
    """Ground truth is the mission's depth source from construction, with the run's
    perception settings; without it the mission keeps the companion's matcher."""
    cfg = RunConfig(truth_perception=truth, perception=PerceptionConfig(max_range_m=9.0))
    _, mission, _ = _start(paper_scene(), cfg)
    source = mission.pipeline.perception.source
    assert isinstance(source, TruthDepthSource) is truth
    assert source.config is cfg.perception


def test_progress_bar_rate_eta_and_log_lines():
    now = [100.0]
    out = io.StringIO()
    bar = ProgressBar(10, 4, out, tty=False, log_every_s=30.0, clock=lambda: now[0])
    assert math.isnan(bar.rate_per_min)
    now[0] = 130.0
    bar.update(collided=False, safe=True)  # 1 scene in 30 s this session (resumed at 4)
    assert bar.rate_per_min == pytest.approx(2.0)
    assert bar.eta_s == pytest.approx(150.0)  # 5 left at 2/min
    now[0] = 140.0
    bar.update(collided=True, safe=False)  # within 30 s of the last line: not printed
    assert "6/10" not in out.getvalue()
    assert "5/10" in out.getvalue() and "ETA 0:02:30" in out.getvalue()
    for _ in range(4):
        bar.update(collided=False, safe=True)
    bar.close()
    last = out.getvalue().splitlines()[-1]
    assert "10/10 100%" in last and "collisions 1" in last and "unsafe 1" in last
    assert out.getvalue().count("10/10") == 1
    assert format_duration(3725) == "1:02:05" and format_duration(math.nan) == "--:--"
