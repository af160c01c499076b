"""Stereo perception: detection range, boundary spheres, frames, false positives, config."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from companion.perception import Matcher, PerceptionConfig, PerceptionResult, StereoPerception
from companion.stereo_bm import configured_bm
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import Box, GroundPlane, Sphere, World
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
    """Conformance for each matcher offered: the nearest obstacle's boundary contains the
    sphere."""
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
    assert len(perception.source._matchers) == 2  # the main and the near-range matcher, reused
    assert (a.sequence, a.capture_ns) == (3, 3000)
    np.testing.assert_array_equal(a.obstacles[0].center_ned_m, b.obstacles[0].center_ned_m)
    assert a.obstacles[0].radius_m == b.obstacles[0].radius_m
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.obstacles[0].radius_m = 1.0
    with pytest.raises(ValueError):
        a.obstacles[0].center_ned_m[0] = 0.0


def test_config_from_dict():
    cfg = PerceptionConfig.from_dict({"threshold_m": 5.0, "matcher": "bm"})
    assert cfg.threshold_m == 5.0 and cfg.matcher is Matcher.BM
    with pytest.raises(ValueError, match="retired"):
        PerceptionConfig(matcher="sgbm_3way")
    with pytest.raises(TypeError, match="threshhold_m"):
        PerceptionConfig.from_dict({"threshhold_m": 5.0})
    with pytest.raises(ValueError, match="threshold_m"):
        PerceptionConfig(threshold_m=-1.0)
    with pytest.raises(ValueError, match="block_size_px"):
        PerceptionConfig(block_size_px=8)
    with pytest.raises(ValueError):
        PerceptionConfig(matcher="census")


def test_speckle_range_is_in_pixels():
    """StereoBM compares the speckle range with its 1/16 px fixed-point disparities without
    scaling it: the configured pixels reach OpenCV times 16 (the default, 3/16 px, is the
    raw 3 the matcher was tuned with)."""
    for range_px, fixed in ((0.1875, 3), (1.0, 16), (2.5, 40), (0.0, 0)):
        cfg = PerceptionConfig(speckle_range_px=range_px)
        assert configured_bm(cfg, 48, 9, 320).getSpeckleRange() == fixed, range_px
    assert configured_bm(PerceptionConfig(), 48, 9, 320).getSpeckleRange() == 3
    for bad in (-1.0, math.nan, "3", 1e12, math.inf):
        with pytest.raises(ValueError, match="speckle_range_px"):
            PerceptionConfig(speckle_range_px=bad)


@pytest.mark.parametrize(
    ("name", "bad"),
    [
        ("speckle_window_px", -5),
        ("speckle_window_px", 10**30),  # reached OpenCV (and the speckle kernel) per frame
        ("speckle_window_px", 2.5),
        ("texture_threshold", 2**31),
        ("uniqueness_ratio", True),
        ("lr_max_diff_px", -2),
    ],
)
def test_matcher_integer_settings_are_checked_at_configuration(name, bad):
    with pytest.raises(ValueError, match=name):
        PerceptionConfig(**{name: bad})


def test_threshold_is_configurable(renderer):
    """A 6 m threshold reports the paper's obstacle at 5 m; the default 4 m does not."""
    pos = np.array([10.0 - 1.5 - 5.0, 0.0, -7.0])
    world = World(spheres=(PAPER_SPHERE,))
    assert _see(renderer, StereoPerception(), world, pos, LEVEL).obstacles == ()
    far = _see(renderer, StereoPerception(PerceptionConfig(threshold_m=6.0)), world, pos, LEVEL)
    assert len(far.obstacles) == 1


# --- compiled kernels against the numpy formulation they replace ---------------------------


def _reference_fit(xs, ys, n_grid, disp, fx, fy, cx, cy, fb, cap_depth_m, max_half_angle):
    """The blind-spot sphere fit written with numpy (the pre-numba implementation)."""
    xn = (xs - cx) * (1.0 / fx)
    yn = (ys - cy) * (1.0 / fy)
    norm = np.sqrt(xn * xn + yn * yn + 1.0)
    range_m = (fb * norm) / disp
    bearings = np.stack((xn / norm, yn / norm, 1.0 / norm), axis=1)
    rank = int(0.01 * (len(range_m) - 1))
    nearest_m = float(np.partition(range_m, rank)[rank])
    grid = bearings[:n_grid]
    cap = range_m[:n_grid] <= nearest_m + max(cap_depth_m, 0.03 * nearest_m)
    axis = (grid[cap] if np.any(cap) else grid).sum(axis=0)
    axis /= math.sqrt(float(axis @ axis))
    cos_min = min(1.0, max(-1.0, float((bearings @ axis).min())))
    sin_a = math.sin(min(math.acos(cos_min), max_half_angle))
    radius_fit_m = nearest_m * sin_a / (1.0 - sin_a)
    center = axis * (nearest_m + radius_fit_m)
    offsets = bearings * range_m[:, None] - center
    farthest_m = math.sqrt(float(np.einsum("ij,ij->i", offsets, offsets).max()))
    return nearest_m, center, max(radius_fit_m, farthest_m)


@pytest.mark.parametrize("seed", range(20))
def test_compiled_sphere_fit_equals_numpy_reference(seed):
    from companion.perception import _fit_sphere

    rng = np.random.default_rng(seed)
    n = int(rng.integers(16, 3000))
    n_grid = int(rng.integers(1, n + 1))
    xs = 2 * rng.integers(0, 320, n)
    ys = 2 * rng.integers(0, 240, n)
    # Mostly a smooth surface, a few outliers, sometimes a far cap (no grid sample in it).
    disp = rng.uniform(18.0, 60.0) + rng.normal(0.0, 2.0, n).clip(-10.0, 10.0)
    if seed % 3 == 0:
        disp[:n_grid] = 15.0
    args = (xs, ys, n_grid, disp, 320.0, 321.0, 319.5, 239.5, 21.6, 0.1, math.radians(64.0))
    nearest, center, radius = _fit_sphere(*args)
    ref_nearest, ref_center, ref_radius = _reference_fit(*args)
    assert nearest == ref_nearest  # the same order statistic
    np.testing.assert_allclose(center, ref_center, rtol=1e-12, atol=1e-12)
    assert radius == pytest.approx(ref_radius, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("stride", [1, 2, 3])
def test_region_samples_and_seeds_equal_numpy_reference(stride):
    import cv2

    from companion.perception import _blob_seeds, _region_contour, _region_samples

    rng = np.random.default_rng(stride)
    h, w = 40, 50
    disp = rng.integers(-16, 900, (h, w)).astype(np.int16)
    near = (rng.random((h, w)) < 0.5).astype(np.uint8)
    disp_px = disp.astype(np.float32) / 16.0
    # Two overlapping-box regions (values 1 and 2) in a padded fill mask.
    fill = np.zeros((h + 2, w + 2), np.uint8)
    yy, xx = np.mgrid[0:h, 0:w]
    fill[1:-1, 1:-1][(xx - 20) ** 2 + (yy - 18) ** 2 < 15**2] = 1
    fill[1:-1, 1:-1][((xx - 38) ** 2 + (yy - 25) ** 2 < 10**2) & (fill[1:-1, 1:-1] == 0)] = 2
    for value in (1, 2):
        ys_r, xs_r = np.nonzero(fill[1:-1, 1:-1] == value)
        x0, y0 = int(xs_r.min()), int(ys_r.min())
        rect = (x0, y0, int(xs_r.max()) - x0 + 1, int(ys_r.max()) - y0 + 1)
        region = fill[y0 + 1 : y0 + rect[3] + 1, x0 + 1 : x0 + rect[2] + 1] == value
        edge = _region_contour(fill, value, rect) if stride > 1 else np.zeros((0, 2), np.int32)
        xs, ys, d, n_grid, n_near = _region_samples(
            fill, value, x0, y0, rect[2], rect[3], stride, edge, near, disp_px
        )
        gy, gx = np.nonzero(region[::stride, ::stride])
        ref_xs = np.concatenate((gx * stride, edge[:, 0])) + x0
        ref_ys = np.concatenate((gy * stride, edge[:, 1])) + y0
        assert n_grid == len(gx)
        np.testing.assert_array_equal(xs, ref_xs)
        np.testing.assert_array_equal(ys, ref_ys)
        np.testing.assert_array_equal(d, disp_px[ref_ys, ref_xs].astype(np.float64))
        assert n_near == np.count_nonzero(region & (near[y0 : y0 + rect[3], x0 : x0 + rect[2]] > 0))
        if stride > 1:
            contours, _ = cv2.findContours(
                region.view(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
            )
            assert len(edge) == sum(len(c) for c in contours)
    # Seeds: the first largest disparity of each label in raster order (ties included).
    n_labels, labels = cv2.connectedComponents(near, connectivity=8)
    tied = np.minimum(disp, 400).astype(np.int16)
    seed_x, seed_y = _blob_seeds(labels, tied, n_labels)
    for label in range(1, n_labels):
        iy, ix = np.unravel_index(int(np.argmax(np.where(labels == label, tied, -1))), tied.shape)
        if tied[iy, ix] >= 0:  # (perception's blobs are near pixels: disparity > 0)
            assert (seed_x[label], seed_y[label]) == (ix, iy)


# --- what the camera cannot see: the depth map and its unknowns (issue 14) -------------------


def _right_eye_view(renderer, world, pos, R) -> np.ndarray:
    """True depth seen by the right eye: the left eye's render moved one baseline right."""
    right_eye = pos + R @ np.array([0.0, CAMERA.baseline_m, 0.0])
    return renderer.render(world, right_eye, R).depth_left_m


def test_depth_map_is_eq27_where_known_and_counts_add_up(renderer, perception):
    """Known depth is f·b/d: within one pixel of disparity of the truth on the sphere."""
    world = World(spheres=(PAPER_SPHERE,), ground=GroundPlane(0.0))
    pos = np.array([10.0 - 1.5 - 3.0, 0.0, -7.0])
    result = _see(renderer, perception, world, pos, LEVEL)
    truth = renderer.render(world, pos, LEVEL).depth_left_m
    depth = result.depth_m
    assert depth.shape == truth.shape and depth.dtype == np.float32
    assert not depth.flags.writeable
    fb = CAMERA.intrinsics.focal_baseline_m_px
    sphere = truth < 4.5
    known = sphere & np.isfinite(depth)
    assert known.sum() >= 0.9 * sphere.sum(), "the textured sphere is matched almost everywhere"
    # |Δz| = z²/(f·b)·|Δd|: one pixel of disparity error at most, on 99 % of the pixels.
    tol = truth[known] ** 2 / fb * 1.0
    assert np.mean(np.abs(depth[known] - truth[known]) <= tol) >= 0.99
    c = result.counts
    assert c.n_valid + c.n_unmatched + c.n_beyond_range == depth.size
    assert c.n_valid == np.count_nonzero(np.isfinite(depth))
    assert result.unknown_fraction == pytest.approx(np.isnan(depth).mean())


def test_sky_and_far_ground_have_no_finite_depth(renderer, perception):
    """Nothing beyond max_range_m gets a finite depth: a match there is +inf ("nothing
    nearer along this ray", what the known-space map needs to certify the space ahead at
    altitude), unmatched sky is NaN, and no +inf lies in the blind band."""
    world = World(ground=GroundPlane(0.0))
    pos = np.array([0.0, 0.0, -2.0])
    R = rotation_321(0.0, math.radians(-4.0), 0.0)  # nose down a little: ground to ~30 m
    result = _see(renderer, perception, world, pos, R)
    truth = renderer.render(world, pos, R).depth_left_m
    depth = result.depth_m
    max_range = perception.config.max_range_m
    finite = np.isfinite(depth)
    assert np.max(depth[finite]) <= max_range
    assert not np.any(finite[np.isinf(truth)]), "sky must never get a depth"
    # Margin of two pixels of disparity around max_range: the matcher's error there.
    fb = CAMERA.intrinsics.focal_baseline_m_px
    beyond = truth > fb / (fb / max_range - 2.0)
    assert beyond.any() and not np.any(finite[beyond])
    assert np.isinf(depth[beyond]).any()  # matched far ground: known, nothing nearer
    assert not np.any(np.isinf(depth[:, : result.blind_band_px]))
    assert result.counts.n_beyond_range + result.counts.n_unmatched > np.count_nonzero(beyond)
    assert result.unknown_fraction == pytest.approx(np.isnan(depth).mean())


def test_textureless_view_is_all_unknown(perception):
    flat = np.full((240, 320), 128, dtype=np.uint8)
    result = perception.process(
        StereoFrame(0, 0, CAMERA.intrinsics, flat, flat), np.zeros(3), LEVEL
    )
    assert np.all(np.isnan(result.depth_m))
    assert result.counts.n_valid == 0 and result.unknown_fraction == 1.0


def test_only_what_the_right_camera_cannot_see_is_unknown(renderer, perception):
    """A wall-sized sphere at 2.5 m filling the view: the unmatched band on the left is what
    the right eye cannot see (true disparity > column), not the matcher's 64 columns."""
    world = World(spheres=(Sphere((10.0, 0.0, -7.0), 7.5),), ground=None)
    pos = np.array([0.0, 0.0, -7.0])
    result = _see(renderer, perception, world, pos, LEVEL)
    truth = renderer.render(world, pos, LEVEL).depth_left_m
    fb = CAMERA.intrinsics.focal_baseline_m_px
    cols = np.arange(CAMERA.width_px)[None, :]
    hidden = fb / truth > cols  # the right camera sees column x - d < 0: outside its view
    assert np.all(np.isnan(result.depth_m[hidden]))
    n_band = 64  # an unpadded StereoBM searching down to 1.2 m computes nothing here
    seen = ~hidden
    seen[:, n_band:] = False  # inside the old blind band and visible to both cameras
    assert seen.sum() >= 30 * CAMERA.height_px  # ~36 columns at 2.5 m (d ≈ 28 px)
    assert np.mean(np.isfinite(result.depth_m[seen])) >= 0.8


@pytest.mark.parametrize("wall_m", [2.5, 4.4, 6.9, 12.0])
def test_every_column_that_can_hold_an_obstacle_pixel_is_searched(renderer, perception, wall_m):
    """A textured wall filling the view: every column where the right camera sees it a
    margin inside its edge (disparity <= x - 6 px, the band gate) is ranged, from the first
    such column on, for walls nearer than the obstacle stage's reach (threshold 4 m +
    extent 3 m). The leftmost columns the main pass leaves unsearched could see nothing
    within reach, and are unmatched there; a wall beyond reach is ranged right of them."""
    wall = Box((wall_m + 0.1, 0.0, -7.0), (0.2, 40.0, 40.0))
    world = World(boxes=(wall,), ground=None)
    pos = np.array([0.0, 0.0, -7.0])
    out = renderer.render(world, pos, LEVEL)
    frame = StereoFrame(0, 0, CAMERA.intrinsics, out.left, out.right)
    result = perception.process(frame, pos, LEVEL)
    k = CAMERA.intrinsics
    cfg = perception.config
    unsearched = perception.source.unsearched_columns(k)
    reach_px = k.focal_baseline_m_px / (cfg.threshold_m + cfg.extent_margin_m)
    margin_px = 4 + 2  # half the 9 px block + the edge margin: the band gate's
    assert unsearched > 0
    assert unsearched - 1 - margin_px < reach_px  # its last column sees only beyond reach
    main = perception.source.disparity_fixed(frame)
    assert np.all(main[:, :unsearched] < 0)  # (the coarse pass may still fill them)
    d_px = k.focal_baseline_m_px / wall_m
    first = max(math.floor(d_px) + 1 + margin_px, unsearched)
    band = (slice(8, -8), slice(first, 64))  # the bare matcher's blind band, recovered
    ranged = np.isfinite(result.depth_m[band])
    per_column = ranged.mean(axis=0)
    assert per_column.min() >= 0.9, (first + np.argmin(per_column), per_column.min())
    rel = np.abs(result.depth_m[band][ranged] / out.depth_left_m[band][ranged] - 1.0)
    assert np.median(rel) < 0.2 / d_px  # a fifth of a pixel of disparity (Eq. 27)


def _first_detected_deg(renderer, perception, world, pos, yaws_deg):
    for i, yaw in enumerate(yaws_deg):
        R = rotation_321(0.0, 0.0, math.radians(yaw))
        if _see(renderer, perception, world, pos, R, seq=i).obstacles:
            return yaw
    return None


def _first_in_both_views_deg(renderer, world, pos, yaws_deg):
    for yaw in yaws_deg:
        R = rotation_321(0.0, 0.0, math.radians(yaw))
        left = renderer.render(world, pos, R).depth_left_m
        right = _right_eye_view(renderer, world, pos, R)
        if np.isfinite(left).any() and np.isfinite(right).any():
            return yaw
    return None


@pytest.mark.parametrize("side", [-1.0, 1.0])
def test_sphere_entering_the_view_is_detected_within_1_deg(renderer, perception, side):
    """A sphere at 3 m comes into view as the vehicle yaws towards it (side -1: it enters
    from the left edge): detected no later than 1° after both cameras see it."""
    radius, surface_m = 0.5, 3.0
    world = World(spheres=(Sphere((surface_m + radius, 0.0, -7.0), radius),), ground=None)
    pos = np.array([0.0, 0.0, -7.0])
    # side -1: yaw right (positive) so the sphere drifts in from the left edge, and back.
    start = -side * 45.0
    yaws = start + side * np.arange(0.0, 30.0, 0.25)
    entered = _first_in_both_views_deg(renderer, world, pos, yaws)
    detected = _first_detected_deg(renderer, perception, world, pos, yaws)
    assert entered is not None and detected is not None
    assert abs(detected - entered) <= 1.0, f"in both views at {entered}°, detected {detected}°"


@pytest.mark.parametrize("surface_m", [0.5, 0.8, 1.0, 1.3])
@pytest.mark.parametrize("radius_m", [0.3, 1.5])
def test_too_near_for_the_main_range_is_never_reported_farther(
    renderer, perception, surface_m, radius_m
):
    """Nearer than min_range_m (64 px of disparity): the coarse near pass ranges it; the
    nearest obstacle is at most its true range plus the coarse pass's resolution (two
    full-resolution pixels of disparity)."""
    world = World(
        spheres=(Sphere((surface_m + radius_m, 0.0, -7.0), radius_m),), ground=GroundPlane(0.0)
    )
    result = _see(renderer, perception, world, np.array([0.0, 0.0, -7.0]), LEVEL)
    assert result.obstacles, "a surface at arm's length must be an obstacle"
    fb = CAMERA.intrinsics.focal_baseline_m_px
    d_true = fb / surface_m
    assert result.obstacles[0].nearest_range_m <= fb / (d_true - 2.0)
    assert result.counts.n_too_near > 0


# --- robustness: degradations neither hide a sphere nor invent one (issue 14) ----------------


def _load_benchmark(name: str):
    """A benchmark module by path (benchmarks/ is not a package)."""
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"_bench_{name}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def degradations():
    return _load_benchmark("bench_degradations")


_CASES = [
    "clean",
    "noise σ10",
    "noise σ20",
    "gain ×0.7",
    "misrect 2 px",
    "blur h 4 px",
    "blur v 4 px",
    "JPEG 30",
    "low-texture sphere",
]


@pytest.mark.slow
@pytest.mark.parametrize("case", _CASES)
def test_degraded_images_neither_hide_nor_invent_a_sphere(perception, degradations, case):
    """The paper's sphere 3 m ahead is inside the reported boundary in >= 19 of 20 frames;
    200 empty frames (ground and sky) under the same degradation give <= 1 false obstacle."""
    params, material = degradations.CASES[case]
    inside, nearest = degradations.sphere_inside_frames(perception, params, material, 20)
    assert inside >= 19, f"{case}: sphere inside the boundary in {inside}/20 frames {nearest}"
    false = degradations.empty_scene_false_frames(perception, params, 200)
    assert false <= 1, f"{case}: false obstacles in {false}/200 empty frames"


def test_textureless_wall_is_reported_as_unknown_ahead_with_its_edges(renderer, perception):
    """A textureless wall 3 m ahead filling the view: nothing is matched on it, so it is
    unknown (never free); where its edges are in view they are ranged at 3 m."""
    from plant_sim.world import Box, Material

    pos = np.array([0.0, 0.0, -7.0])
    wall = Box((3.1, 0.0, -7.0), (0.2, 40.0, 40.0), material=Material.TEXTURELESS)
    result = _see(renderer, perception, World(boxes=(wall,), ground=None), pos, LEVEL)
    truth = renderer.render(World(boxes=(wall,), ground=None), pos, LEVEL).depth_left_m
    np.testing.assert_allclose(truth, 3.0, rtol=1e-5)  # a plane 3 m ahead fills the view
    known = np.isfinite(result.depth_m)
    assert known.mean() < 0.05, "a textureless wall gives (almost) no depth"
    # Never reported farther than it is (nothing behind it can be seen).
    assert np.all(result.depth_m[known] <= truth[known] * 1.1)
    # A narrower wall: its vertical edges against the sky are matched at the wall's depth.
    narrow = Box((3.1, 0.0, -7.0), (0.2, 2.0, 1.5), material=Material.TEXTURELESS)
    result = _see(renderer, perception, World(boxes=(narrow,), ground=None), pos, LEVEL)
    truth = renderer.render(World(boxes=(narrow,), ground=None), pos, LEVEL).depth_left_m
    on_wall = np.isfinite(truth)
    edges = on_wall & np.isfinite(result.depth_m)
    assert edges.sum() > 100
    np.testing.assert_allclose(result.depth_m[edges], 3.0, rtol=0.05)
    assert result.obstacles and result.obstacles[0].nearest_range_m == pytest.approx(3.0, abs=0.15)


# --- real images: Middlebury 2014 motorcycle (issue 14) --------------------------------------


def test_middlebury_motorcycle_near_mask_at_3m():
    """On real images (the Middlebury motorcycle at 320 × 240, depth = f·b / d with the
    rig's focal length and baseline; see benchmarks/bench_middlebury.py): the near mask at
    3 m has precision >= 0.95 and recall >= 0.90 over the pixels both cameras see, and
    every near pixel the right camera cannot see is unknown."""
    middlebury = _load_benchmark("bench_middlebury")
    frame, gt = middlebury.motorcycle_frame()
    result = StereoPerception().process(frame, np.zeros(3), LEVEL)
    scores = middlebury.near_mask_scores(result.depth_m, gt, frame.intrinsics, 3.0)
    assert 0.3 < scores.near_fraction < 0.8  # the mask is meaningful: neither empty nor all
    assert scores.precision >= 0.95, scores
    assert scores.recall >= 0.90, scores
    assert scores.n_hidden_near > 1000 and scores.n_hidden_near_reported == 0, scores
    assert scores.bad2 <= 0.1, scores


def test_middlebury_scores_against_the_ground_truth_itself():
    """The scorer on the ground truth as the depth map: perfect scores (a check of the
    scorer), and the near pixels the right camera cannot see are counted as reported."""
    middlebury = _load_benchmark("bench_middlebury")
    frame, gt = middlebury.motorcycle_frame()
    fb = frame.intrinsics.focal_baseline_m_px
    depth = (fb / gt).astype(np.float32)
    scores = middlebury.near_mask_scores(depth, gt, frame.intrinsics, 3.0)
    assert (scores.precision, scores.recall, scores.iou, scores.bad2) == (1.0, 1.0, 1.0, 0.0)
    assert scores.n_hidden_near_reported == scores.n_hidden_near > 0
    # Rectified pair: the right image at x - d matches the left image (the doffs shift).
    ys, xs = np.nonzero(np.isfinite(gt) & (gt <= np.arange(gt.shape[1])[None, :] - 5))
    pick = slice(None, None, 97)
    left = frame.left[ys[pick], xs[pick]].astype(float)
    right = frame.right[ys[pick], np.round(xs[pick] - gt[ys[pick], xs[pick]]).astype(int)]
    assert np.median(np.abs(left - right)) <= 8.0


@pytest.mark.parametrize("shape", ["wall", "pole"])
def test_textured_wall_and_pole_become_obstacles(renderer, perception, shape):
    """The obstacle model on the renderer's new shapes: a textured wall across the path and
    a pole 3 m ahead are reported at their range, and the boundary holds the surface point
    straight ahead (the wall) or the pole's axis at camera height."""
    from plant_sim.world import Box, Cylinder

    pos = np.array([0.0, 0.0, -7.0])
    if shape == "wall":
        world = World(boxes=(Box((3.1, 0.0, -7.0), (0.2, 12.0, 10.0)),), ground=GroundPlane(0.0))
        surface_m, inside = 3.0, np.array([3.0, 0.0, -7.0])
    else:
        world = World(cylinders=(Cylinder((3.15, 0.3, -5.0), 0.15, 10.0),), ground=None)
        surface_m, inside = 3.0, np.array([3.15, 0.3, -7.0])
    result = _see(renderer, perception, world, pos, LEVEL)
    assert result.obstacles
    nearest = result.obstacles[0]
    assert nearest.nearest_range_m == pytest.approx(surface_m, abs=0.15)
    assert any(np.linalg.norm(o.center_ned_m - inside) <= o.radius_m for o in result.obstacles)


@pytest.mark.parametrize("size", [(1, 1), (5, 1), (8, 4), (2, 9), (33, 200), (321, 17)])
def test_any_frame_size_gives_a_depth_map_not_an_error(perception, size):
    """Tiny and odd frames (smaller than a matching block, narrower than the disparity
    range): a depth map of the frame's shape, unknown where nothing can be matched."""
    width, height = size
    k = CameraModel(width_px=width, height_px=height).intrinsics
    rng = np.random.default_rng(width * 1000 + height)
    for left, right in (
        (rng.integers(0, 256, (height, width), dtype=np.uint8),) * 2,
        (np.zeros((height, width), np.uint8), np.full((height, width), 255, np.uint8)),
    ):
        result = perception.process(StereoFrame(0, 0, k, left, right), np.zeros(3), LEVEL)
        assert result.depth_m.shape == (height, width)
        c = result.counts
        assert c.n_valid + c.n_unmatched + c.n_beyond_range == width * height
    flat = np.full((height, width), 90, np.uint8)
    result = perception.process(StereoFrame(0, 0, k, flat, flat), np.zeros(3), LEVEL)
    assert result.obstacles == () and np.all(np.isnan(result.depth_m))
