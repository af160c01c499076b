"""Stereo perception: detection range, boundary spheres, frames, false positives, config."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from companion.perception import Matcher, PerceptionConfig, PerceptionResult, StereoPerception
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import GroundPlane, Sphere, World
from protocols.camera import CameraModel
from protocols.frames import rotation_321
from protocols.stereo_frame import StereoFrame, decode, encode

CAMERA = CameraModel()
LEVEL = np.eye(3)
PAPER_SPHERE = Sphere((10.0, 0.0, -7.0), 1.5)  # the paper's obstacle (DESIGN.md)
TOL_M = 0.3


@pytest.fixture(scope="module")
def renderer() -> StereoCameraRenderer:
    return StereoCameraRenderer(CAMERA)


@pytest.fixture(scope="module")
def perception() -> StereoPerception:
    return StereoPerception()


def _see(renderer, perception, world, pos, R, seq=0) -> PerceptionResult:
    """Render, encode and decode a frame (the wire path), then run perception."""
    out = renderer.render(world, pos, R, noise_seed=seq)
    frame = StereoFrame(seq, 1_000 * seq, CAMERA.intrinsics, out.left, out.right)
    return perception.process(decode(encode(frame)), pos, R)


def _contains(obstacle, sphere: Sphere) -> bool:
    gap = np.linalg.norm(obstacle.center_ned_m - np.asarray(sphere.center_ned_m))
    return gap + sphere.radius_m <= obstacle.radius_m


def test_paper_obstacle_first_reported_within_4m(renderer, perception):
    """Approach head-on in 5 cm steps: nothing beyond 4 m, a report by 4 m − 0.3 m."""
    world = World(spheres=(PAPER_SPHERE,))
    first_m = None
    for i, surface_m in enumerate(np.arange(5.0, 3.65, -0.05)):
        pos = np.array([10.0 - 1.5 - surface_m, 0.0, -7.0])
        result = _see(renderer, perception, world, pos, LEVEL, seq=i)
        if surface_m > 4.0 + 1e-9:
            assert result.obstacles == (), f"reported at {surface_m:.2f} m"
        elif result.obstacles and first_m is None:
            first_m = surface_m
    assert first_m is not None and first_m >= 4.0 - TOL_M, first_m


@pytest.mark.parametrize("surface_m", [2.5, 3.0, 3.5])
def test_paper_obstacle_boundary(renderer, perception, surface_m):
    pos = np.array([10.0 - 1.5 - surface_m, 0.0, -7.0])
    result = _see(renderer, perception, World(spheres=(PAPER_SPHERE,)), pos, LEVEL)
    assert len(result.obstacles) == 1
    obstacle = result.obstacles[0]
    err = np.linalg.norm(obstacle.center_ned_m - np.asarray(PAPER_SPHERE.center_ned_m))
    assert err <= TOL_M, f"centre {obstacle.center_ned_m} off by {err:.2f} m"
    assert _contains(obstacle, PAPER_SPHERE)
    assert obstacle.nearest_range_m == pytest.approx(surface_m, abs=0.1)
    assert 1.5 - TOL_M <= obstacle.raw_radius_m <= 1.5 + 0.5
    cfg = perception.config
    assert obstacle.radius_m == pytest.approx(
        obstacle.raw_radius_m + cfg.vehicle_radius_m + cfg.safety_margin_m
    )
    assert obstacle.n_near_pixels <= obstacle.n_pixels


@pytest.mark.parametrize("matcher", list(Matcher))
def test_every_matcher_gives_a_conservative_boundary(renderer, matcher):
    """Conformance for each matcher: the nearest obstacle's boundary contains the sphere.

    SGBM smears the sphere's disparity onto the background beside it (foreground fattening),
    so its sphere is larger and its centre further off than BM's; it must still be safe.
    """
    perception = StereoPerception(PerceptionConfig(matcher=matcher))
    pos = np.array([10.0 - 1.5 - 3.0, 0.0, -7.0])
    result = _see(renderer, perception, World(spheres=(PAPER_SPHERE,)), pos, LEVEL)
    nearest = result.obstacles[0]
    assert nearest.nearest_range_m == pytest.approx(3.0, abs=0.1)
    assert _contains(nearest, PAPER_SPHERE)


@pytest.mark.parametrize(
    ("roll_deg", "pitch_deg", "yaw_deg", "az_deg", "el_deg"),
    [
        (0.0, -10.0, 40.0, 8.0, 5.0),  # nose down, facing north-east, obstacle right and up
        (6.0, 12.0, -120.0, -5.0, -6.0),  # rolled, nose up, facing south-west, left and down
        (-4.0, 20.0, 170.0, 3.0, -9.0),
    ],
)
def test_off_axis_obstacle_from_yawed_and_pitched_vehicle(
    renderer, perception, roll_deg, pitch_deg, yaw_deg, az_deg, el_deg
):
    """Catches frame bugs: place the sphere by bearing in the body frame, check it in NED."""
    R = rotation_321(*np.radians([roll_deg, pitch_deg, yaw_deg]))
    pos = np.array([12.0, -4.0, -6.0])
    az, el = math.radians(az_deg), math.radians(el_deg)
    direction_frd = np.array(
        [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)]
    )
    radius, centre_range = 0.8, 3.3 + 0.8
    centre = pos + R @ direction_frd * centre_range
    sphere = Sphere(tuple(centre), radius)
    result = _see(renderer, perception, World(spheres=(sphere,), ground=GroundPlane(0.0)), pos, R)
    assert len(result.obstacles) == 1
    obstacle = result.obstacles[0]
    assert np.linalg.norm(obstacle.center_ned_m - centre) <= TOL_M, obstacle.center_ned_m - centre
    assert _contains(obstacle, sphere)


def test_two_spheres_side_by_side(renderer, perception):
    pos = np.array([0.0, 0.0, -7.0])
    spheres = (Sphere((4.0, -0.75, -7.0), 0.5), Sphere((4.0, 0.75, -7.0), 0.5, texture_seed=4))
    result = _see(renderer, perception, World(spheres=spheres), pos, LEVEL)
    assert len(result.obstacles) == 2
    for sphere in spheres:
        errors = [np.linalg.norm(o.center_ned_m - sphere.center_ned_m) for o in result.obstacles]
        assert min(errors) <= TOL_M
    assert all(
        _contains(
            min(result.obstacles, key=lambda o: np.linalg.norm(o.center_ned_m - s.center_ned_m)), s
        )
        for s in spheres
    )


def test_ground_and_sky_with_noise_never_become_obstacles(renderer, perception):
    """200 noisy frames of textured ground (nearest ≥ 6 m) and sky: zero obstacles."""
    world = World(ground=GroundPlane(0.0))
    rng = np.random.default_rng(11)
    for seq in range(200):
        R = rotation_321(
            *np.radians([rng.uniform(-5, 5), rng.uniform(-3, 3), rng.uniform(-180, 180)])
        )
        pos = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), -2.2])
        result = _see(renderer, perception, world, pos, R, seq=seq)
        assert result.obstacles == (), f"frame {seq}: {result.obstacles}"


def test_random_noise_images_give_no_obstacles(perception):
    """Uncorrelated noise in the two eyes: spurious matches are isolated, never obstacles."""
    rng = np.random.default_rng(5)
    for seq in range(20):
        left = rng.integers(0, 256, (240, 320), dtype=np.uint8)
        right = rng.integers(0, 256, (240, 320), dtype=np.uint8)
        result = perception.process(
            StereoFrame(seq, 0, CAMERA.intrinsics, left, right), np.zeros(3), LEVEL
        )
        assert result.obstacles == ()


def test_textureless_view_is_unknown_not_free(perception):
    flat = np.full((240, 320), 128, dtype=np.uint8)
    result = perception.process(
        StereoFrame(0, 0, CAMERA.intrinsics, flat, flat), np.zeros(3), LEVEL
    )
    assert result.obstacles == ()
    assert result.unknown_fraction > 0.99


def test_results_are_deterministic_frozen_and_matcher_reused(renderer):
    perception = StereoPerception()
    pos = np.array([5.5, 0.0, -7.0])
    a = _see(renderer, perception, World(spheres=(PAPER_SPHERE,)), pos, LEVEL, seq=3)
    b = _see(renderer, perception, World(spheres=(PAPER_SPHERE,)), pos, LEVEL, seq=3)
    assert len(perception._matchers) == 1
    assert (a.sequence, a.capture_ns) == (3, 3000)
    np.testing.assert_array_equal(a.obstacles[0].center_ned_m, b.obstacles[0].center_ned_m)
    assert a.obstacles[0].radius_m == b.obstacles[0].radius_m
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.obstacles[0].radius_m = 1.0
    with pytest.raises(ValueError):
        a.obstacles[0].center_ned_m[0] = 0.0


def test_config_from_dict():
    cfg = PerceptionConfig.from_dict({"threshold_m": 5.0, "matcher": "sgbm_3way"})
    assert cfg.threshold_m == 5.0 and cfg.matcher is Matcher.SGBM_3WAY
    with pytest.raises(TypeError, match="threshhold_m"):
        PerceptionConfig.from_dict({"threshhold_m": 5.0})
    with pytest.raises(ValueError, match="threshold_m"):
        PerceptionConfig(threshold_m=-1.0)
    with pytest.raises(ValueError, match="block_size_px"):
        PerceptionConfig(block_size_px=8)
    with pytest.raises(ValueError):
        PerceptionConfig(matcher="census")


def test_threshold_is_configurable(renderer):
    """A 6 m threshold reports the paper's obstacle at 5 m; the default 4 m does not."""
    pos = np.array([10.0 - 1.5 - 5.0, 0.0, -7.0])
    world = World(spheres=(PAPER_SPHERE,))
    assert _see(renderer, StereoPerception(), world, pos, LEVEL).obstacles == ()
    far = _see(renderer, StereoPerception(PerceptionConfig(threshold_m=6.0)), world, pos, LEVEL)
    assert len(far.obstacles) == 1
