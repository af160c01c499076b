"""Synthetic stereo camera: geometry against closed forms, determinism, noise."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from plant_sim.stereo_camera import RenderParams, StereoCameraRenderer
from plant_sim.world import Box, Cylinder, GroundPlane, Material, Sphere, World, paper_world
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


# --- shapes, materials and degradations (issue 14) -------------------------------------------


def _analytic_shapes_depth(world: World, pos, R, camera: CameraModel) -> np.ndarray:
    """Left-eye depth of boxes (slabs) and vertical cylinders (side and caps), numpy."""
    k = camera.intrinsics
    u, v = np.meshgrid(np.arange(k.width_px), np.arange(k.height_px))
    rays_cam = np.stack(((u - k.cx_px) / k.fx_px, (v - k.cy_px) / k.fy_px, np.ones(u.shape)), -1)
    d = rays_cam @ (R @ R_FRD_FROM_CAM).T
    eye = pos + R @ np.array([0.0, -k.baseline_m / 2, 0.0])
    depth = _analytic_depth(World(spheres=world.spheres, ground=world.ground), pos, R, camera)
    with np.errstate(divide="ignore", invalid="ignore"):
        for b in world.boxes:
            lo = np.asarray(b.center_ned_m) - 0.5 * np.asarray(b.size_m) - eye
            hi = np.asarray(b.center_ned_m) + 0.5 * np.asarray(b.size_m) - eye
            t1, t2 = lo / d, hi / d
            t_near = np.nanmax(np.minimum(t1, t2), axis=-1)
            t_far = np.nanmin(np.maximum(t1, t2), axis=-1)
            hit = (t_near <= t_far) & (t_near > 0)
            depth = np.minimum(depth, np.where(hit, t_near, np.inf))
        for c in world.cylinders:
            o = eye - np.asarray(c.center_ned_m)
            a = d[..., 0] ** 2 + d[..., 1] ** 2
            bb = o[0] * d[..., 0] + o[1] * d[..., 1]
            cc = o[0] ** 2 + o[1] ** 2 - c.radius_m**2
            disc = bb * bb - a * cc
            t = (-bb - np.sqrt(np.maximum(disc, 0))) / a
            side = (disc >= 0) & (t > 0) & (np.abs(o[2] + t * d[..., 2]) <= c.height_m / 2)
            depth = np.minimum(depth, np.where(side, t, np.inf))
            for cap in (-c.height_m / 2, c.height_m / 2):
                t = (cap - o[2]) / d[..., 2]
                r2 = (o[0] + t * d[..., 0]) ** 2 + (o[1] + t * d[..., 1]) ** 2
                depth = np.minimum(depth, np.where((t > 0) & (r2 <= c.radius_m**2), t, np.inf))
    return depth


def test_box_and_cylinder_depth_match_closed_form(renderer):
    world = World(
        spheres=(Sphere((9.0, 3.0, -7.0), 1.0),),
        boxes=(Box((6.0, -1.5, -7.0), (0.3, 3.0, 4.0)), Box((12.0, 0.0, -6.0), (1.0, 8.0, 2.0))),
        cylinders=(Cylinder((5.0, 1.2, -6.0), 0.25, 6.0), Cylinder((8.0, -3.0, -8.5), 0.8, 1.0)),
        ground=GroundPlane(0.0),
    )
    R = rotation_321(math.radians(3), math.radians(-6), math.radians(-4))
    out = renderer.render(world, POS, R)
    expected = _analytic_shapes_depth(world, POS, R, CAMERA)
    finite = np.isfinite(expected)
    np.testing.assert_array_equal(np.isfinite(out.depth_left_m), finite)
    np.testing.assert_allclose(out.depth_left_m[finite], expected[finite], rtol=1e-5)
    # Every shape is in view (a depth no other shape or the ground gives).
    for d_m in (6.0 - 0.15, 11.5):
        assert np.any(np.isclose(out.depth_left_m, d_m, atol=0.02))


def test_world_surface_distance_and_validation():
    box = Box((10.0, 0.0, -7.0), (0.2, 10.0, 10.0))
    pole = Cylinder((10.0, 5.0, -5.0), 0.5, 10.0)
    world = World(boxes=(box,), cylinders=(pole,))
    assert box.surface_distance_m((5.0, 0.0, -7.0)) == pytest.approx(4.9)
    assert box.surface_distance_m((10.0, 0.0, -7.0)) == pytest.approx(-0.1)
    assert pole.surface_distance_m((10.0, 5.0, -12.0)) == pytest.approx(2.0)
    assert pole.surface_distance_m((13.0, 9.0, -5.0)) == pytest.approx(4.5)
    assert world.surface_distance_m((0.0, 0.0, -7.0)) == pytest.approx(9.9)
    assert World().surface_distance_m((0.0, 0.0, 0.0)) == math.inf
    with pytest.raises(ValueError, match="size_m"):
        Box((0.0, 0.0, 0.0), (1.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="height_m"):
        Cylinder((0.0, 0.0, 0.0), 1.0, -1.0)
    with pytest.raises(ValueError):
        Sphere((0.0, 0.0, 0.0), 1.0, material="shiny")
    with pytest.raises(TypeError, match="Box"):
        World(boxes=(Sphere((0.0, 0.0, 0.0), 1.0),))


@pytest.mark.parametrize("shape", ["sphere", "box"])
def test_materials_set_the_texture_contrast(shape):
    """Patch contrast scales with Material.contrast (1, 0.12, 0): the texture's spread about
    the smooth shading."""
    renderer = StereoCameraRenderer(CAMERA, RenderParams(noise_std=0.0))
    spread = {}
    for material in Material:
        if shape == "sphere":
            obstacle = {"spheres": (Sphere((4.5, -0.1, -7.0), 1.5, material=material),)}
        else:
            obstacle = {"boxes": (Box((3.0, 0.0, -7.0), (0.2, 6.0, 6.0), material=material),)}
        out = renderer.render(World(ground=None, **obstacle), POS, LEVEL)
        patch = out.left[100:140, 140:180].astype(float)
        smooth = cv2.GaussianBlur(patch, (0, 0), 6.0)
        spread[material] = float(np.std(patch - smooth)) + float(np.std(np.diff(patch, axis=1)))
    assert spread[Material.TEXTURED] > 6.0
    ratio = spread[Material.LOW_TEXTURE] / spread[Material.TEXTURED]
    assert 0.05 <= ratio <= 0.25, ratio  # 0.12 in contrast; 8-bit rounding adds a little
    assert spread[Material.TEXTURELESS] <= 1.0


def test_degradations_gain_misrectification_blur_jpeg():
    world = paper_world()
    pos = np.array([5.0, 0.0, -7.0])
    clean = StereoCameraRenderer(CAMERA, RenderParams(noise_std=0.0)).render(world, pos, LEVEL)

    def render(**kw):
        return StereoCameraRenderer(CAMERA, RenderParams(noise_std=0.0, **kw)).render(
            world, pos, LEVEL
        )

    gain = render(gain_right=0.7)
    np.testing.assert_array_equal(gain.left, clean.left)
    ratio = gain.right.astype(float).sum() / clean.right.astype(float).sum()
    assert ratio == pytest.approx(0.7, abs=0.01)
    shifted = render(misrect_v_px=2.0)
    np.testing.assert_array_equal(shifted.right[2:], clean.right[:-2])  # 2 px lower, exactly
    np.testing.assert_array_equal(shifted.left, clean.left)
    for axis, kw in ((1, {"blur_h_px": 5.0}), (0, {"blur_v_px": 5.0})):
        blurred = render(**kw)
        # A 5 px line kernel: the gradient along it drops, across it much less.
        along = np.abs(np.diff(blurred.left.astype(float), axis=axis)).mean()
        across = np.abs(np.diff(blurred.left.astype(float), axis=1 - axis)).mean()
        along_clean = np.abs(np.diff(clean.left.astype(float), axis=axis)).mean()
        assert along < 0.6 * along_clean and along < across
    jpeg = render(jpeg_quality=30)
    err = np.abs(jpeg.left.astype(float) - clean.left.astype(float))
    assert 0.5 < err.mean() < 8.0  # lossy, but the same picture
    np.testing.assert_array_equal(jpeg.left, render(jpeg_quality=30).left)  # deterministic
    noisy = StereoCameraRenderer(CAMERA, RenderParams(noise_std=10.0, blur_h_px=3.0))
    a = noisy.render(world, pos, LEVEL, noise_seed=1)
    b = noisy.render(world, pos, LEVEL, noise_seed=2)
    diff = a.left.astype(float) - b.left.astype(float)
    assert np.std(diff) == pytest.approx(10.0 * math.sqrt(2.0), rel=0.1)  # noise after blur
    with pytest.raises(ValueError, match="jpeg_quality"):
        RenderParams(jpeg_quality=101)
    with pytest.raises(ValueError, match="gain_right"):
        RenderParams(gain_right=0.0)


def test_scenario_options_for_shapes_materials_and_degradations():
    from plant_sim.scenario import ScenarioError, scenario_from_dict

    scenario = scenario_from_dict(
        {
            "obstacles": [
                {"shape": "box", "center_ned_m": [5, 0, -5], "size_m": [0.2, 12, 10]},
                {"center_ned_m": [10, 0, -7], "radius_m": 1.5, "material": "low_texture"},
                {
                    "shape": "cylinder",
                    "center_ned_m": [14, 2, -5],
                    "radius_m": 0.15,
                    "height_m": 10,
                },
            ],
            "camera": {"jpeg_quality": 30, "misrect_v_px": 2.0, "gain_right": 0.7},
        }
    )
    world = scenario.world
    assert world.boxes == (Box((5.0, 0.0, -5.0), (0.2, 12.0, 10.0)),)
    assert world.spheres[0].material is Material.LOW_TEXTURE
    assert world.cylinders[0].height_m == 10.0
    render = scenario.camera.render
    assert (render.jpeg_quality, render.misrect_v_px, render.gain_right) == (30, 2.0, 0.7)
    for bad, match in (
        ({"obstacles": [{"shape": "cone", "center_ned_m": [0, 0, 0]}]}, "shape"),
        ({"obstacles": [{"shape": "box", "center_ned_m": [0, 0, 0]}]}, "size_m"),
        ({"obstacles": [{"center_ned_m": [0, 0, 0], "radius_m": 1, "material": "x"}]}, "material"),
        ({"camera": {"blur_h_px": -1.0}}, "blur_h_px"),
    ):
        with pytest.raises(ScenarioError, match=match):
            scenario_from_dict(bad)
