"""Synthetic stereo camera: geometry against closed forms, determinism, noise."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from plant_sim.stereo_camera import RenderParams, StereoCameraRenderer
from plant_sim.world import GroundPlane, Sphere, World, paper_world
from protocols.camera import R_FRD_FROM_CAM, CameraModel
from protocols.frames import rotation_321

CAMERA = CameraModel()
POS = np.array([0.0, 0.0, -7.0])
LEVEL = np.eye(3)


@pytest.fixture(scope="module")
def renderer() -> StereoCameraRenderer:
    return StereoCameraRenderer(CAMERA)


def _analytic_depth(world: World, pos, R, camera: CameraModel) -> np.ndarray:
    """Left-eye depth by closed-form ray/sphere and ray/plane intersection (numpy)."""
    k = camera.intrinsics
    u, v = np.meshgrid(np.arange(k.width_px), np.arange(k.height_px))
    rays_cam = np.stack(((u - k.cx_px) / k.fx_px, (v - k.cy_px) / k.fy_px, np.ones(u.shape)), -1)
    d = rays_cam @ (R @ R_FRD_FROM_CAM).T  # ray directions in NED
    eye = pos + R @ np.array([0.0, -k.baseline_m / 2, 0.0])
    depth = np.full(u.shape, np.inf)
    for s in world.spheres:
        oc = eye - np.asarray(s.center_ned_m)
        a = np.einsum("...i,...i", d, d)
        b = d @ oc
        c = oc @ oc - s.radius_m**2
        disc = b * b - a * c
        t = np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0))) / a, np.inf)
        depth = np.minimum(depth, np.where(t > 0, t, np.inf))
    if world.ground is not None:
        with np.errstate(divide="ignore"):
            t = (world.ground.down_m - eye[2]) / d[..., 2]
        depth = np.minimum(depth, np.where(d[..., 2] > 0, t, np.inf))
    return depth


def _on_axis_sphere(distance_m: float, radius_m: float) -> World:
    """Sphere centred on the left eye's optical axis, ``distance_m`` ahead of it."""
    return World(
        spheres=(Sphere((distance_m, -CAMERA.baseline_m / 2, -7.0), radius_m),), ground=None
    )


def test_true_depth_matches_closed_form(renderer):
    world = World(
        spheres=(Sphere((6.0, 0.5, -7.2), 1.5), Sphere((9.0, -2.5, -6.0), 1.0, texture_seed=3)),
        ground=GroundPlane(0.0),
    )
    R = rotation_321(math.radians(4), math.radians(-12), math.radians(8))
    out = renderer.render(world, POS, R)
    expected = _analytic_depth(world, POS, R, CAMERA)
    finite = np.isfinite(expected)
    assert 0.3 < finite.mean() < 1.0  # both hits and sky in view
    np.testing.assert_array_equal(np.isfinite(out.depth_left_m), finite)
    np.testing.assert_allclose(out.depth_left_m[finite], expected[finite], rtol=1e-5)


@pytest.mark.parametrize("surface_m", [2.5, 3.5, 6.0])
def test_disparity_at_sphere_centre_is_fb_over_z(renderer, surface_m):
    radius = 1.5
    out = renderer.render(_on_axis_sphere(surface_m + radius, radius), POS, LEVEL, noise_seed=1)
    # The optical axis passes between pixels (159.5, 119.5): the four central pixels.
    centre = out.depth_left_m[119:121, 159:161]
    np.testing.assert_allclose(centre, surface_m, rtol=2e-4)
    matcher = cv2.StereoBM_create(numDisparities=64, blockSize=9)
    disparity = matcher.compute(out.left, out.right).astype(np.float32) / 16.0
    measured = float(np.median(disparity[117:123, 157:163]))
    expected = CAMERA.intrinsics.focal_baseline_m_px / surface_m
    assert measured == pytest.approx(expected, abs=0.5)


def test_angular_size_of_sphere(renderer):
    distance, radius = 8.0, 1.5
    out = renderer.render(_on_axis_sphere(distance, radius), POS, LEVEL)
    half_angle = math.asin(radius / distance)
    k = CAMERA.intrinsics
    row = np.isfinite(out.depth_left_m[120])  # row 120 is 0.5 px below the axis
    cols = np.flatnonzero(row)
    half_width_px = (cols[-1] - cols[0] + 1) / 2.0
    assert half_width_px == pytest.approx(k.fx_px * math.tan(half_angle), abs=1.0)
    col = np.flatnonzero(np.isfinite(out.depth_left_m[:, 160]))
    assert (col[-1] - col[0] + 1) / 2.0 == pytest.approx(k.fy_px * math.tan(half_angle), abs=1.0)


def test_ground_straight_down_and_sky():
    renderer = StereoCameraRenderer(CameraModel(width_px=64, height_px=48))
    world = World(ground=GroundPlane(down_m=0.0))
    down = rotation_321(0.0, math.radians(-90.0), 0.0)
    out = renderer.render(world, [0.0, 0.0, -5.0], down)
    np.testing.assert_allclose(out.depth_left_m[23:25, 31:33], 5.0, rtol=1e-5)
    up = rotation_321(0.0, math.radians(90.0), 0.0)
    assert np.all(np.isinf(renderer.render(world, [0.0, 0.0, -5.0], up).depth_left_m))


@pytest.mark.parametrize("size", [(64, 48), (640, 480), (321, 17)])
def test_any_resolution(size):
    cam = CameraModel(width_px=size[0], height_px=size[1])
    out = StereoCameraRenderer(cam).render(paper_world(), [3.0, 0.0, -7.0], LEVEL)
    for image in (out.left, out.right):
        assert image.shape == (size[1], size[0]) and image.dtype == np.uint8
    assert out.depth_left_m.shape == (size[1], size[0])


def test_deterministic_and_seeded_noise(renderer):
    world = paper_world()
    pos = np.array([5.0, 0.0, -7.0])
    a = renderer.render(world, pos, LEVEL, noise_seed=5)
    b = StereoCameraRenderer(CAMERA).render(world, pos, LEVEL, noise_seed=5)
    c = renderer.render(world, pos, LEVEL, noise_seed=6)
    np.testing.assert_array_equal(a.left, b.left)
    np.testing.assert_array_equal(a.right, b.right)
    assert not np.array_equal(a.left, c.left)
    diff = a.left.astype(float) - c.left.astype(float)
    # Two independent draws of noise with σ = 2 differ with σ = 2·√2 (rounding adds a little).
    assert np.std(diff) == pytest.approx(2.0 * math.sqrt(2.0), rel=0.15)
    quiet = StereoCameraRenderer(CAMERA, RenderParams(noise_std=0.0))
    q1 = quiet.render(world, pos, LEVEL, noise_seed=1)
    q2 = quiet.render(world, pos, LEVEL, noise_seed=2)
    np.testing.assert_array_equal(q1.left, q2.left)


def test_obstacle_is_textured_for_matching(renderer):
    out = renderer.render(_on_axis_sphere(4.5, 1.5), POS, LEVEL, noise_seed=0)
    patch = out.left[100:140, 140:180].astype(float)
    assert patch.std() > 12.0  # block matching needs contrast on the surface
    assert out.left[5, 5] != out.left[5, 6] or out.left[5, 5] > 150  # sky: bright, noisy


def test_world_validation():
    with pytest.raises(ValueError, match="radius_m"):
        Sphere((0.0, 0.0, 0.0), -1.0)
    with pytest.raises(ValueError, match="center_ned_m"):
        Sphere((0.0, float("nan"), 0.0), 1.0)
    with pytest.raises(TypeError, match="Sphere"):
        World(spheres=("sphere",))
    assert paper_world().spheres[0].surface_distance_m([20.0, 0.0, -7.0]) == pytest.approx(8.5)
