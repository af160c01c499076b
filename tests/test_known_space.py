"""Known-space map: ray-cast free distance against analytic geometry, memory rules, costs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.known_space import (
    FREE,
    OCCUPIED,
    TENTATIVE,
    UNKNOWN,
    KnownSpace,
    KnownSpaceConfig,
)
from protocols.camera import R_FRD_FROM_CAM, CameraModel
from protocols.frames import rotation_321

CAMERA = CameraModel()
K = CAMERA.intrinsics
LEVEL_NORTH = rotation_321(0.0, 0.0, 0.0)  # body FRD = NED: camera looks north
VOXEL_M = KnownSpaceConfig().voxel_m


def _rays_cam() -> np.ndarray:
    """Unit-depth ray of every pixel in the camera frame, shape (H, W, 3) (z = 1)."""
    u, v = np.meshgrid(np.arange(K.width_px), np.arange(K.height_px))
    return np.stack([(u - K.cx_px) / K.fx_px, (v - K.cy_px) / K.fy_px, np.ones(u.shape)], -1)


def _sphere_depth(center_ned_m, radius_m, pos_ned_m, R_ned_from_frd) -> np.ndarray:
    """Exact depth image of one sphere seen by the left eye; +inf where the ray misses."""
    cam = np.asarray(pos_ned_m) + R_ned_from_frd @ np.array([0.0, -K.baseline_m / 2, 0.0])
    d = _rays_cam() @ (R_ned_from_frd @ R_FRD_FROM_CAM).T  # NED directions, depth-1 scale
    oc = cam - np.asarray(center_ned_m)
    a = np.einsum("hwi,hwi->hw", d, d)
    b = 2.0 * d @ oc
    c = oc @ oc - radius_m**2
    disc = b * b - 4 * a * c
    t = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2 * a)
    return np.where(disc >= 0.0, t, np.inf).astype(np.float32)


def _wall_depth(distance_m: float) -> np.ndarray:
    return np.full((K.height_px, K.width_px), distance_m, np.float32)


def test_config_rejects_unknown_key_and_bad_values():
    with pytest.raises(TypeError, match="voxel_size"):
        KnownSpaceConfig.from_dict({"voxel_size": 0.1})
    with pytest.raises(ValueError):
        KnownSpaceConfig(voxel_m=0.0)
    with pytest.raises(ValueError):
        KnownSpaceConfig(pixel_stride=0)
    with pytest.raises(ValueError, match="free_core_m"):
        KnownSpaceConfig(free_core_m=0.0)


@pytest.mark.parametrize("radius_m", [0.0, 0.35])
def test_free_distance_to_a_wall_is_its_distance_less_the_clearance(radius_m):
    """Fronto-parallel wall 5 m ahead: free along the axis up to 5 m − hit_clear_m."""
    space = KnownSpace()
    pos = np.array([0.05, 0.05, -7.05])
    for _ in range(2):  # a surface is an obstacle once hit in two frames
        space.integrate(_wall_depth(5.0), K, pos, LEVEL_NORTH)
    expected = 5.0 - space.config.hit_clear_m
    free = space.free_distance_m(pos, (1.0, 0.0, 0.0), radius_m, 20.0)
    assert free == pytest.approx(expected, abs=1.5 * VOXEL_M), free
    # the wall itself is occupied, the space behind it unknown
    assert space.state_at(pos + np.array([5.0 + 0.01, 0.0, 0.0])) == OCCUPIED
    assert space.state_at(pos + np.array([6.0, 0.0, 0.0])) == UNKNOWN


@pytest.mark.parametrize("radius_m", [0.0, 0.2, 0.35])
def test_free_distance_to_a_sphere_matches_the_disc_geometry(radius_m):
    """A disc of radius r on the axis of a sphere (R, centre D ahead) first meets its
    surface at D − √(R² − r²); known-free space stops hit_clear_m before it."""
    space = KnownSpace()
    pos = np.array([0.0, 0.0, -7.0])
    center, big_r = pos + np.array([6.0, 0.0, 0.0]), 1.5
    space.integrate(_sphere_depth(center, big_r, pos, LEVEL_NORTH), K, pos, LEVEL_NORTH)
    surface_s = 6.0 - math.sqrt(big_r**2 - radius_m**2)
    free = space.free_distance_m(pos, (1.0, 0.0, 0.0), radius_m, 20.0)
    assert surface_s - space.config.hit_clear_m - 2 * VOXEL_M <= free <= surface_s, free
    # beside the sphere (outside its silhouette) the view is free to max range (18°: the
    # line passes 0.35 m clear of the sphere, and its voxels are inside the left eye's
    # ±24° view from 0.9 m on, inside the start bubble)
    side = np.array([math.cos(math.radians(18)), math.sin(math.radians(18)), 0.0])
    assert space.free_distance_m(pos, side, 0.0, 20.0) >= space.config.max_range_m - VOXEL_M


def test_a_disc_wider_than_the_view_near_the_camera_is_not_free():
    """The top of a 0.7 m disc enters the ±18.4° vertical view only 2.1 m ahead: before
    that it is outside the field of view (unknown) once it leaves the start bubble."""
    space = KnownSpace()
    pos = np.array([0.0, 0.0, -7.0])
    space.integrate(_wall_depth(30.0), K, pos, LEVEL_NORTH)
    enters_view_m = 0.7 / math.tan(math.radians(CAMERA.vfov_deg / 2))
    assert enters_view_m == pytest.approx(2.1, abs=0.05)
    bubble_m = math.sqrt(space.config.start_free_radius_m**2 - 0.7**2)
    free = space.free_distance_m(pos, (1.0, 0.0, 0.0), 0.7, 20.0)
    assert free <= bubble_m + VOXEL_M < enters_view_m, free


def test_unmatched_pixels_and_unseen_directions_are_not_free():
    """All-NaN frame looking down (no sky rule): only the start bubble is free."""
    space = KnownSpace()
    pos = np.array([0.0, 0.0, -7.0])
    down45 = rotation_321(0.0, math.radians(-50.0), 0.0)
    space.integrate(np.full((K.height_px, K.width_px), np.nan, np.float32), K, pos, down45)
    # the disc's rim leaves the start bubble at √(R² − r²); voxels add up to one edge
    bubble = math.sqrt(space.config.start_free_radius_m**2 - 0.35**2) + VOXEL_M
    for direction in [(1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0)]:
        assert space.free_distance_m(pos, direction, 0.35, 20.0) <= bubble
    # seen free ahead (a far wall) but nothing seen east: east stays bounded by the bubble
    space2 = KnownSpace()
    space2.integrate(_wall_depth(30.0), K, pos, LEVEL_NORTH)
    assert space2.free_distance_m(pos, (1, 0, 0), 0.35, 20.0) >= 7.0
    assert space2.free_distance_m(pos, (0, 1, 0), 0.35, 20.0) <= bubble


def test_open_sky_rule_only_above_the_horizon_and_outside_the_blind_band():
    cfg = KnownSpaceConfig()
    space = KnownSpace(cfg)
    pos = np.array([0.0, 0.0, -7.0])
    nan = np.full((K.height_px, K.width_px), np.nan, np.float32)
    far_ground = nan.copy()
    far_ground[-4:, :] = 50.0  # matched far below the horizon: the sky reaches that far
    space.integrate(far_ground, K, pos, LEVEL_NORTH, blind_band_px=70)  # level: half is sky
    up = np.array([math.cos(math.radians(8)), 0.0, -math.sin(math.radians(8))])
    assert space.free_distance_m(pos, up, 0.0, 20.0) >= cfg.max_range_m - VOXEL_M
    down = np.array([math.cos(math.radians(12)), 0.0, math.sin(math.radians(12))])
    assert space.free_distance_m(pos, down, 0.0, 20.0) < 2.0
    # blind band: the left 70 columns (about 24° … 13° left) are never sky
    left = np.array([math.cos(math.radians(18)), -math.sin(math.radians(18)), -0.1])
    assert space.free_distance_m(pos, left, 0.0, 20.0) < 2.0
    # a matched pixel high in a column stops the sky below it in that column
    space3 = KnownSpace(cfg)
    masked = nan.copy()
    masked[0, :] = 50.0  # a far matched row at the top: the rows below are not sky
    space3.integrate(masked, K, pos, LEVEL_NORTH, blind_band_px=70)
    assert space3.free_distance_m(pos, up, 0.0, 20.0) < 2.0


def test_open_sky_reaches_no_farther_than_the_columns_topmost_matched_point():
    """A textureless wall taller than the view is not sky: the sky above the last matched
    ground ends there, and a column with nothing matched has no sky at all."""
    pos = np.array([0.0, 0.0, -7.0])
    up = np.array([math.cos(math.radians(2)), 0.0, -math.sin(math.radians(2))])
    nan = np.full((K.height_px, K.width_px), np.nan, np.float32)
    nothing = KnownSpace()
    nothing.integrate(nan, K, pos, LEVEL_NORTH)  # the wall fills the view
    assert nothing.free_distance_m(pos, up, 0.0, 20.0) < 2.0
    near_ground = nan.copy()
    near_ground[-4:, :] = 4.0  # the foot of a wall: ground matched 4 m ahead (depth)
    wall = KnownSpace()
    wall.integrate(near_ground, K, pos, LEVEL_NORTH)
    # the bottom rows look 18° down: the matched ground lies ~4 m ahead horizontally
    reach = wall.free_distance_m(pos, up, 0.0, 20.0)
    assert 2.0 < reach <= 4.0, reach


def test_occupied_persists_until_seen_free_again():
    space = KnownSpace()
    pos = np.array([0.0, 0.0, -7.0])
    wall_point = pos + np.array([4.0 + 0.01, 0.0, 0.0])
    for _ in range(2):  # a surface is an obstacle once hit in two frames
        space.integrate(_wall_depth(4.0), K, pos, LEVEL_NORTH)
    assert space.state_at(wall_point) == OCCUPIED
    # turn away (east) and see a far wall; then see nothing at all: still occupied
    east = rotation_321(0.0, 0.0, math.pi / 2)
    space.integrate(_wall_depth(30.0), K, pos, east)
    space.integrate(np.full((K.height_px, K.width_px), np.nan, np.float32), K, pos, LEVEL_NORTH)
    assert space.state_at(wall_point) == OCCUPIED
    # the open-sky rule never clears an obstacle
    assert space.free_distance_m(pos, (1, 0, 0), 0.0, 20.0) < 4.0
    # a matched ray through it (the wall moved away) clears it
    space.integrate(_wall_depth(30.0), K, pos, LEVEL_NORTH)
    assert space.state_at(wall_point) == FREE


def test_the_grid_follows_the_vehicle_and_keeps_what_stays_inside():
    space = KnownSpace()
    pos = np.array([0.0, 0.0, -7.0])
    for _ in range(2):  # a surface is an obstacle once hit in two frames
        space.integrate(_wall_depth(4.0), K, pos, LEVEL_NORTH)
    wall_point = pos + np.array([4.01, 0.0, 0.0])
    half_xy = space.config.size_xy_vox * VOXEL_M / 2
    space.mark_vehicle(pos + np.array([0.0, 0.6 * half_xy, 0.0]))  # shifts the grid east
    assert space.state_at(wall_point) == OCCUPIED
    space.mark_vehicle(pos + np.array([0.0, 3.0 * half_xy, 0.0]))  # the wall falls off the grid
    assert space.state_at(wall_point) == UNKNOWN


def test_vehicle_position_is_free_and_start_bubble():
    space = KnownSpace()
    pos = np.array([3.0, -2.0, -5.0])
    down50 = rotation_321(0.0, math.radians(-50.0), 0.0)  # no sky in view
    space.integrate(np.full((K.height_px, K.width_px), np.nan, np.float32), K, pos, down50)
    r = space.config.start_free_radius_m
    for d in [(1, 0, 0), (0, -1, 0), (0, 0, 1)]:
        assert space.state_at(pos + 0.9 * r * np.array(d)) == FREE
        assert space.state_at(pos + np.array([r + 2 * VOXEL_M]) * np.array(d)) == UNKNOWN


def test_perception_depth_contract_nan_is_unknown():
    """``PerceptionResult.depth_m``: Eq. (27) depth where matched, NaN where the right
    camera cannot see the surface (true disparity beyond the pixel's column)."""
    from companion.perception import StereoPerception
    from plant_sim.stereo_camera import StereoCameraRenderer
    from plant_sim.world import paper_world
    from protocols.stereo_frame import StereoFrame

    pos = np.array([16.0, 0.0, -7.0])
    R = rotation_321(0.0, math.radians(-10.0), math.pi)
    render = StereoCameraRenderer(CAMERA).render(paper_world(), pos, R, noise_seed=3)
    frame = StereoFrame(0, 0, K, render.left, render.right)
    seen = StereoPerception().process(frame, pos, R)
    depth, truth = seen.depth_m, render.depth_left_m
    assert depth.shape == truth.shape and depth.dtype == np.float32
    assert not depth.flags.writeable
    assert seen.blind_band_px > 0
    cols = np.arange(depth.shape[1])[None, :]
    hidden = K.focal_baseline_m_px / truth > cols  # outside the right camera's view
    assert hidden.sum() > 100
    assert np.all(np.isnan(depth[hidden]))
    near = np.isfinite(depth) & (truth < 8.0)
    assert near.sum() > 1000
    rel = np.abs(depth[near] - truth[near]) / truth[near]
    assert np.median(rel) < 0.02, np.median(rel)
    assert np.isnan(depth).mean() == pytest.approx(seen.unknown_fraction, abs=1e-9)


def test_no_creep_into_unseen_space():
    """Carrots taken from the map (free − 0.3 m margin, at least 0.15 m) never carry the
    vehicle out of the start bubble when nothing else was seen: the vehicle does not
    make its own surroundings free."""
    space = KnownSpace()
    pos = np.array([0.0, 0.0, -7.0])
    down50 = rotation_321(0.0, math.radians(-50.0), 0.0)
    nan = np.full((K.height_px, K.width_px), np.nan, np.float32)
    start = pos.copy()
    for direction in ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]):
        for _ in range(50):
            space.integrate(nan, K, pos, down50)
            free = space.free_distance_m(pos, direction, 0.35, 10.0, 0.2, 0.35, 0.8)
            reach = free - 0.3
            if reach < 0.15:
                break
            pos = pos + reach * np.array(direction)
        assert np.linalg.norm(pos - start) <= space.config.start_free_radius_m


def test_near_field_excuses_unseen_rim_but_never_an_obstacle():
    space = KnownSpace(KnownSpaceConfig(start_free_radius_m=0.0))
    pos = np.array([0.1, 0.1, -7.1])
    space.integrate(_wall_depth(30.0), K, pos, LEVEL_NORTH)  # sees north, nothing beside
    strict = space.free_distance_m(pos, (1, 0, 0), 0.35, 10.0, 0.2)
    excused = space.free_distance_m(pos, (1, 0, 0), 0.35, 10.0, 0.2, 0.35, 1.05)
    assert strict <= 0.1 < 7.0 <= excused
    # an obstacle where the rim passes 0.5 m ahead stops it although it is in the near field
    space.grid[space.grid.shape[0] // 2 + 2, :, :] = 2  # a wall of occupied voxels
    wall_north_m = (space.origin_vox[0] + space.grid.shape[0] // 2 + 2) * VOXEL_M
    blocked = space.free_distance_m(pos, (1, 0, 0), 0.35, 10.0, 0.2, 0.35, 1.05)
    assert blocked <= wall_north_m - pos[0]


def test_near_field_is_not_excused_where_an_obstacle_may_be():
    """The unseen rim beside the path is excused only outside the spheres where an
    obstacle may be (a boundary's piece and its blind spot): beside a sphere whose far
    side was seen, the unseen near flank is taken as part of it."""
    space = KnownSpace(KnownSpaceConfig(start_free_radius_m=0.0))
    pos = np.array([0.1, 0.1, -7.1])
    space.integrate(_wall_depth(30.0), K, pos, LEVEL_NORTH)  # sees north, nothing beside
    args = ((1, 0, 0), 0.35, 10.0, 0.2, 0.35, 1.05)
    assert space.free_distance_m(pos, *args) >= 7.0
    # a sphere of 0.5 m whose surface reaches 0.15 m into the rim's path 0.6 m ahead, east
    solid = np.array([[pos[0] + 0.6, pos[1] + 0.35 + 0.5 - 0.15, pos[2], 0.5]])
    free = space.free_distance_m(pos, *args, solid_ned_m=solid)
    # the rim enters the sphere at √(0.5² − 0.35²) = 0.36 m before its centre, within a
    # half-voxel step
    assert 0.6 - math.sqrt(0.5**2 - 0.35**2) - 0.5 * VOXEL_M <= free < 0.6, free
    # a sphere out of the tube's way changes nothing
    away = solid + np.array([[0.0, 1.0, 0.0, 0.0]])
    assert space.free_distance_m(pos, *args, solid_ned_m=away) >= 7.0
    with pytest.raises(ValueError, match="finite"):
        space.free_distance_m(pos, *args, solid_ned_m=[[np.nan, 0.0, 0.0, 1.0]])


def test_a_one_frame_hit_is_tentative_and_confirmed_by_a_second_frame():
    space = KnownSpace()
    pos = np.array([0.0, 0.0, -7.0])
    wall_point = pos + np.array([3.01, 0.0, 0.0])
    space.integrate(_wall_depth(3.0), K, pos, LEVEL_NORTH)
    assert space.state_at(wall_point) == TENTATIVE  # not free, not yet an obstacle
    assert space.free_distance_m(pos, (1, 0, 0), 0.0, 10.0) < 3.0
    space.integrate(_wall_depth(30.0), K, pos, LEVEL_NORTH)  # a false match: seen through
    assert space.state_at(wall_point) == FREE
    space.integrate(_wall_depth(3.0), K, pos, LEVEL_NORTH)
    space.integrate(_wall_depth(3.0), K, pos, LEVEL_NORTH)
    assert space.state_at(wall_point) == OCCUPIED


def test_an_obstacle_passed_at_close_range_stays_in_the_way():
    """Flying north past the flank of a sphere (R 0.6 m, its surface 0.3 m beside the
    path): the tube of the vehicle's radius (0.35 m) meets the sphere where its side line
    enters it, x = c − √(R² − (0.9 − 0.35)²), and known-free space must end there in
    every frame. The rays at the edge of the view graze the sphere's flank in every
    frame on their way to farther surfaces; before a frame's hits won over its own free
    rays, and occupied voxels were cleared only through their core, the flank was erased
    as fast as it was seen (Monte Carlo truth seed 323 passed such a sphere at 0.27 m)."""
    space = KnownSpace()
    centre_north_m, big_r, offset_m, tube_m = 2.5, 0.6, 0.9, 0.35
    centre = np.array([centre_north_m, -offset_m, -7.0])
    meets_m = centre_north_m - math.sqrt(big_r**2 - (offset_m - tube_m) ** 2)
    checked = 0
    for north_m in np.arange(0.0, 2.0, 0.03):  # 0.9 m/s at 30 frames/s
        pos = np.array([north_m, 0.0, -7.0])
        space.integrate(_sphere_depth(centre, big_r, pos, LEVEL_NORTH), K, pos, LEVEL_NORTH)
        if space.frames < 3:
            continue  # the first frames: still tentative
        free = space.free_distance_m(pos, (1.0, 0.0, 0.0), tube_m, 20.0, 0.2, tube_m, 1.05)
        assert pos[0] + free <= meets_m + VOXEL_M, (north_m, free)
        checked += 1
    assert checked > 50


@pytest.mark.parametrize(
    ("state", "hit_near", "core_name", "block_uv"),
    [
        (OCCUPIED, 1, "clear_core_m", (40, 37)),
        (OCCUPIED, 0, "clear_core_m", (40, 37)),
        (UNKNOWN, 0, "free_core_m", (36, 36)),
    ],
)
def test_a_ray_frees_only_the_voxels_whose_core_it_crosses(state, hit_near, core_name, block_uv):
    """One matched ray (depth 30 m) through a block of occupied (or never seen) voxels
    3 m away frees exactly those whose centre it passes within ``clear_core_m``
    (``free_core_m``); the rest keep their state. A ray through a voxel's corner saw the
    corner, not the surface point that made it occupied, nor the inside of an obstacle
    whose limb it grazed. Whether the occupied voxels were hit from near (range-aware
    occupancy) does not change the core."""
    cfg = KnownSpaceConfig(start_free_radius_m=0.0, sky_min_elevation_deg=90.0)  # no sky
    space = KnownSpace(cfg)
    pos = np.array([0.0, 0.0, -7.0])
    depth = np.full((K.height_px, K.width_px), np.nan, np.float32)
    space.integrate(depth, K, pos, LEVEL_NORTH)  # places the grid, marks nothing
    stride = space.config.pixel_stride
    bu, bv = (n * stride for n in block_uv)  # a block below the centre
    depth[bv : bv + stride, bu : bu + stride] = 30.0
    cam_ned = pos + np.array([0.0, -K.baseline_m / 2, 0.0])
    ray_cam = np.array(
        [
            (bu + 0.5 * (stride - 1) - K.cx_px) / K.fx_px,
            (bv + 0.5 * (stride - 1) - K.cy_px) / K.fy_px,
            1.0,
        ]
    )
    ray = R_FRD_FROM_CAM @ ray_cam  # camera → FRD = NED here (level, facing north)
    ray /= np.linalg.norm(ray)
    near = np.floor((cam_ned + 3.0 * ray) / VOXEL_M).astype(int) - space.origin_vox
    block = tuple(slice(c - 2, c + 3) for c in near)
    space.grid[block] = state
    space.near_hit[block] = hit_near
    space.integrate(depth, K, pos, LEVEL_NORTH)
    idx = np.stack(np.meshgrid(*(np.arange(s.start, s.stop) for s in block), indexing="ij"), -1)
    centres = (idx + space.origin_vox + 0.5) * VOXEL_M - cam_ned
    off_ray_m = np.linalg.norm(centres - (centres @ ray)[..., None] * ray, axis=-1)
    cleared = space.grid[block] == FREE
    core = getattr(space.config, core_name)
    assert np.array_equal(cleared, off_ray_m <= core), off_ray_m[cleared != (off_ray_m <= core)]
    assert 0 < cleared.sum() < cleared.size
    assert np.all(space.grid[block][~cleared] == state)
    # some voxels the ray crossed were left alone (old rule: every voxel crossed is freed)
    along = cam_ned + np.arange(0.0, 6.0, 1e-3)[:, None] * ray
    crossed = np.zeros(cleared.shape, bool)
    for v in np.unique(np.floor(along / VOXEL_M).astype(int) - space.origin_vox, axis=0):
        rel = v - np.array([s.start for s in block])
        if np.all((rel >= 0) & (rel < 5)):
            crossed[tuple(rel)] = True
    assert np.any(crossed & ~cleared), "the ray crossed no voxel outside its core"


def test_free_distance_sees_a_voxel_between_the_centre_and_the_rim():
    """A single occupied voxel half-way between the path and the rim of a 0.35 m tube
    (0.175 m beside it) stops the tube: the section is sampled at most a voxel apart."""
    space = KnownSpace()
    pos = np.array([0.1, 0.1, -7.1])  # a voxel centre
    space.integrate(_wall_depth(30.0), K, pos, LEVEL_NORTH)
    space.integrate(_wall_depth(30.0), K, pos, LEVEL_NORTH)
    assert space.free_distance_m(pos, (1, 0, 0), 0.35, 6.0, 0.2, 0.35, 1.05) >= 6.0
    for east_m in (0.2, -0.2):  # the voxel centred 0.2 m east / west of the path
        grid = space.grid.copy()
        vox = np.floor((pos + np.array([3.0, east_m, 0.0])) / VOXEL_M).astype(int)
        space.grid[tuple(vox - space.origin_vox)] = OCCUPIED
        free = space.free_distance_m(pos, (1, 0, 0), 0.35, 6.0, 0.2, 0.35, 1.05)
        assert free < 3.0, (east_m, free)
        space.grid = grid
