"""The known-space path search (companion/guidance/known_path.py, path_rules.py) against
closed forms: the shortest way round a known block, no path through unknown space, an
opening refused below 2 × (vehicle radius + margin) and passed above it, inflated boundaries
avoided."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from companion.guidance import GuidanceConfig, GuidanceState, Mode, Reason, guidance_step
from companion.guidance.cone import BoundarySphere, collision_cone, contains_direction
from companion.guidance.known_path import KnownPath, KnownPathConfig, plan_known_path
from companion.guidance.path_rules import follow_known_path, prefer_known_path, way_blocked
from companion.known_space import FREE, OCCUPIED, TENTATIVE, UNKNOWN

VOXEL_M = 0.2
CFG = KnownPathConfig(leg_max_m=20.0)
CLEARANCE_M = CFG.clearance_m  # 0.35 m vehicle + 0.3 m margin
ORIGIN = np.zeros(3, np.int64)


def _open_grid(nx=80, ny=80, nz=12) -> np.ndarray:
    return np.full((nx, ny, nz), FREE, np.int8)


def _centre(i: float, j: float, k: float) -> np.ndarray:
    return (np.array([i, j, k], dtype=float) + 0.5) * VOXEL_M


def _face_distance_m(points: np.ndarray, grid: np.ndarray) -> float:
    """Least distance from ``points`` to the face of an OCCUPIED voxel (centre distance
    minus half a voxel, the search's measure)."""
    occ = (np.argwhere(grid == OCCUPIED) + 0.5) * VOXEL_M
    d = np.linalg.norm(points[:, None, :] - occ[None, :, :], axis=2)
    return float(d.min()) - 0.5 * VOXEL_M


def _wall_round_length_m(a: float, t: float, w: float, c: float) -> float:
    """Shortest path in the plane from (−a, 0) to (a, 0) round a wall x ∈ [−t/2, t/2],
    y ∈ [−w, w] kept ``c`` away from it: tangent to the corner's circle of radius c, the
    arc to its top, along y = w + c, and the mirror image."""
    dx, dy = a - 0.5 * t, w
    d = math.hypot(dx, dy)
    alpha = math.atan2(dy, dx) + math.asin(c / d)  # heading of the tangent
    return 2.0 * (math.sqrt(d * d - c * c) + c * alpha) + t


def test_shortest_path_round_a_known_block_matches_the_closed_form():
    grid = _open_grid()
    grid[39:41, 30:50, :] = OCCUPIED  # wall 0.4 m thick, 4 m wide, full height
    pos, goal = _centre(30, 40, 6), _centre(50, 40, 6)
    pos[1] = goal[1] = 8.0  # the wall's mid-line (it spans y 6.0 to 10.0)
    path = plan_known_path(grid, ORIGIN, VOXEL_M, pos, goal, config=CFG)
    assert path is not None and path.reaches_goal
    # the wall occupies x ∈ [7.8, 8.2], y ∈ [6, 10]; start and goal 2.1 m either side
    exact = _wall_round_length_m(a=goal[0] - 8.0, t=0.4, w=2.0, c=CLEARANCE_M)
    # a 26-connected grid path is at most 8 % longer than the straight one it follows
    # (octile), and the voxelised clearance can shorten the way by half a voxel a corner
    assert exact - 2 * VOXEL_M <= path.length_m <= 1.0824 * exact + 2 * VOXEL_M, (
        path.length_m,
        exact,
    )
    assert _face_distance_m(path.waypoints_ned_m[1:], grid) >= CLEARANCE_M - 1e-9
    levels = {round(float(z), 6) for z in path.waypoints_ned_m[:, 2]}
    assert levels == {round(float(pos[2]), 6)}, "a wall of full height is gone round level"


def test_no_path_through_unknown_space():
    grid = _open_grid()
    grid[45:47, :, :] = UNKNOWN  # an unseen slab across the whole box
    pos, goal = _centre(30, 40, 6), _centre(60, 40, 6)
    path = plan_known_path(grid, ORIGIN, VOXEL_M, pos, goal, config=CFG)
    assert path is not None and not path.reaches_goal
    # the partial path ends at the edge of what is known, the section's width before it
    assert np.all(path.waypoints_ned_m[:, 0] < 45 * VOXEL_M)
    assert path.waypoints_ned_m[-1, 0] == pytest.approx(43.5 * VOXEL_M, abs=VOXEL_M)
    assert path.end_to_goal_m == pytest.approx(goal[0] - path.waypoints_ned_m[-1, 0], abs=0.3)


@pytest.mark.parametrize("opening_vox", [5, 6, 7, 8, 10])
def test_an_opening_passes_only_when_the_vehicle_and_both_margins_fit(opening_vox):
    grid = _open_grid()
    grid[40, :, :] = OCCUPIED
    grid[40, 40 : 40 + opening_vox, :] = FREE
    width_m = opening_vox * VOXEL_M
    pos = _centre(30, 40 + 0.5 * opening_vox - 0.5, 6)
    goal = _centre(52, 40 + 0.5 * opening_vox - 0.5, 6)
    path = plan_known_path(grid, ORIGIN, VOXEL_M, pos, goal, config=CFG)
    # an opening narrower than 2 × clearance is refused; the voxel grid passes one that is
    # at least one voxel wider (the path's voxel centres need face distance ≥ clearance)
    if width_m < 2.0 * CLEARANCE_M:
        assert path is None or not path.reaches_goal, width_m
    if width_m >= 2.0 * CLEARANCE_M + VOXEL_M:
        assert path is not None and path.reaches_goal, width_m
        assert _face_distance_m(path.waypoints_ned_m[1:], grid) >= CLEARANCE_M - 1e-9
        # through the opening, not round a wall that has no end in the box
        crossing = path.waypoints_ned_m[np.argmin(np.abs(path.waypoints_ned_m[:, 0] - 8.1))]
        assert 8.0 <= crossing[1] <= 8.0 + width_m


def test_inflated_boundaries_are_obstacles_too():
    grid = _open_grid()
    pos, goal = _centre(30, 40, 6), _centre(50, 40, 6)
    ball = BoundarySphere(center_ned_m=tuple(0.5 * (pos + goal)), radius_m=1.5)
    path = plan_known_path(grid, ORIGIN, VOXEL_M, pos, goal, spheres=[ball], config=CFG)
    assert path is not None and path.reaches_goal
    d = np.linalg.norm(path.waypoints_ned_m[1:] - np.asarray(ball.center_ned_m), axis=1)
    assert d.min() >= ball.radius_m
    # round a disc of radius R whose centre is d from start and goal (in the plane, the
    # vertical weight keeps the search level): two tangents √(d² − R²) and the arc
    # between their points, R (π − 2 acos(R/d))
    r, d = ball.radius_m, float(np.linalg.norm(goal - pos)) / 2.0
    exact = 2.0 * math.sqrt(d * d - r * r) + r * (math.pi - 2.0 * math.acos(r / d))
    assert exact - VOXEL_M <= path.length_m <= 1.0824 * exact + 2 * VOXEL_M


def test_first_leg_is_the_farthest_point_seen_in_a_straight_line():
    grid = _open_grid()
    pos, goal = _centre(20, 40, 6), _centre(60, 40, 6)
    leg = KnownPathConfig(leg_max_m=3.0)
    path = plan_known_path(grid, ORIGIN, VOXEL_M, pos, goal, config=leg)
    assert path is not None and path.reaches_goal
    assert path.length_m == pytest.approx(goal[0] - pos[0], abs=1e-9)
    to_leg = np.asarray(path.leg_end_ned_m) - pos
    assert np.linalg.norm(to_leg) == pytest.approx(3.0, abs=VOXEL_M)
    assert to_leg[1] == pytest.approx(0.0) and to_leg[2] == pytest.approx(0.0)


def test_a_vehicle_walled_in_by_unknown_space_has_no_path():
    grid = np.full((40, 40, 12), UNKNOWN, np.int8)
    pos = _centre(20, 20, 6)
    grid[20, 20, 6] = FREE
    assert plan_known_path(grid, ORIGIN, VOXEL_M, pos, _centre(30, 20, 6), config=CFG) is None


def _round_the_wall():
    grid = _open_grid()
    grid[39:41, 30:50, :] = OCCUPIED
    pos, goal = _centre(30, 40, 6), _centre(50, 40, 6)
    pos[1] = goal[1] = 8.0
    leg = KnownPathConfig(leg_max_m=3.0)
    path = plan_known_path(grid, ORIGIN, VOXEL_M, pos, goal, config=leg)
    assert path is not None and path.reaches_goal
    return grid, goal, leg, path


def test_a_followed_path_is_the_rest_of_the_search_and_its_leg_the_searchs_own():
    grid, goal, leg, path = _round_the_wall()
    rows = path.waypoints_ned_m
    for k in (3, 10, len(rows) // 2):
        pos = rows[k] + np.array([0.05, -0.04, 0.03])  # beside a voxel of the path
        followed = follow_known_path(path, grid, ORIGIN, VOXEL_M, pos, goal, config=leg)
        assert followed is not None and followed.expanded == 0 and followed.reaches_goal
        np.testing.assert_allclose(followed.waypoints_ned_m[0], pos)
        # the rest is the search's path from the vehicle's voxel (or the next one) on
        tail = followed.waypoints_ned_m[1:]
        start = len(rows) - len(tail)
        assert start in (k, k + 1), (start, k)
        np.testing.assert_allclose(tail, rows[start:])
        assert followed.end_to_goal_m == pytest.approx(path.end_to_goal_m, abs=1e-9)
        # what a new search from there finds: the same length to go, the same leg reach
        fresh = plan_known_path(grid, ORIGIN, VOXEL_M, pos, goal, config=leg)
        assert followed.length_m == pytest.approx(fresh.length_m, abs=2 * VOXEL_M)
        leg_m = np.linalg.norm(np.asarray(followed.leg_end_ned_m) - pos)
        assert 0.0 < leg_m <= leg.leg_max_m + 1e-9
        assert leg_m >= np.linalg.norm(np.asarray(fresh.leg_end_ned_m) - pos) - 2 * VOXEL_M


def test_a_path_is_not_followed_once_the_map_or_the_vehicle_leaves_it():
    grid, goal, leg, path = _round_the_wall()
    rows = path.waypoints_ned_m
    pos = rows[5].copy()
    assert follow_known_path(path, grid, ORIGIN, VOXEL_M, pos, goal, config=leg) is not None
    # a surface seen within the clearance of a voxel ahead (not on the path itself)
    ahead = np.floor(rows[-8] / VOXEL_M).astype(int)
    blocked = grid.copy()
    blocked[ahead[0], ahead[1] + 3, ahead[2]] = OCCUPIED
    assert follow_known_path(path, blocked, ORIGIN, VOXEL_M, pos, goal, config=leg) is None
    # a voxel of the rest no longer seen free
    unseen = grid.copy()
    unseen[tuple(ahead)] = UNKNOWN
    assert follow_known_path(path, unseen, ORIGIN, VOXEL_M, pos, goal, config=leg) is None
    # an inflated boundary across it
    ball = BoundarySphere(center_ned_m=tuple(rows[-8]), radius_m=0.5)
    assert (
        follow_known_path(path, grid, ORIGIN, VOXEL_M, pos, goal, spheres=[ball], config=leg)
        is None
    )
    # the vehicle farther than rejoin_m from every voxel of it
    away = pos + np.array([0.0, 0.0, leg.rejoin_m + 0.3])
    assert follow_known_path(path, grid, ORIGIN, VOXEL_M, away, goal, config=leg) is None


def test_config_refuses_unknown_keys_and_bad_values():
    with pytest.raises(TypeError, match="nope"):
        KnownPathConfig.from_dict({"nope": 1.0})
    with pytest.raises(ValueError):
        KnownPathConfig(vertical_weight=0.5)
    with pytest.raises(ValueError):
        KnownPathConfig(max_expansions=0)
    with pytest.raises(ValueError):
        KnownPathConfig(replan_frames=0)


# --- when guidance flies the path (prefer_known_path, guidance_step's known_path) -------


def _fake_path(leg_end, end, goal) -> KnownPath:
    """A path from the origin whose first leg ends at ``leg_end`` and which ends at ``end``."""
    pts = np.array([(0.0, 0.0, 0.0), leg_end, end], dtype=float)
    return KnownPath(
        waypoints_ned_m=pts,
        leg_end_ned_m=np.array(leg_end, dtype=float),
        reaches_goal=False,
        end_to_goal_m=float(np.linalg.norm(np.subtract(goal, end))),
        length_m=float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1))),
        expanded=0,
    )


GOAL = (20.0, 0.0, 0.0)
# two boundaries overlapping across the straight path: §5 goes round both (sideways: over
# their seam is steeper than the 12° aiming limit), vehicle → aiming point → goal 22.2 m
PINCH = [BoundarySphere((8.0, s * 2.0, 0.0), 3.2) for s in (1.0, -1.0)]


def _step(path, spheres=PINCH, state=None):
    plan = None if path is False else (lambda pos, goal, spheres: path)
    return guidance_step(
        GuidanceState() if state is None else state,
        time_s=0.0,
        pos_ned_m=(0.0, 0.0, 0.0),
        vel_ned_mps=(1.0, 0.0, 0.0),
        goal_ned_m=GOAL,
        detections=spheres,
        known_path=plan,
        config=GuidanceConfig(confirm_n=1, confirm_m=1),  # avoided at first sight
    )


def test_without_a_map_search_the_cone_rule_alone_decides():
    _, out = _step(False)
    assert out.mode is Mode.AVOID and out.reason is Reason.CRITICAL
    to_setpoint = np.asarray(out.setpoint_ned_m)
    for sphere in PINCH:  # round the pinch, outside every cone
        cone = collision_cone(np.zeros(3), sphere)  # (on its tangent: 1 mrad of rounding)
        assert not contains_direction(cone, to_setpoint, margin_rad=-1e-3)


def test_a_path_past_the_obstacle_through_a_closed_cone_is_flown():
    path = _fake_path((3.0, 0.0, 0.0), (12.0, 0.0, 0.0), GOAL)
    state, out = _step(path)
    assert out.mode is Mode.AVOID and out.reason is Reason.KNOWN_PATH
    np.testing.assert_allclose(out.setpoint_ned_m, path.leg_end_ned_m)
    assert out.avoidance_flag and state.on_known_path


def test_a_path_up_to_the_obstacle_face_does_not_replace_the_way_round():
    path = _fake_path((3.0, 0.0, 0.0), (4.6, 0.0, 0.0), GOAL)  # not past the spheres
    _, out = _step(path)
    assert out.reason is Reason.CRITICAL
    # one sphere (§6's case): a path past it, no shorter than the cone's way round it
    path = _fake_path((3.0, 0.0, 0.0), (12.0, 0.0, 0.0), GOAL)
    path = dataclasses.replace(path, length_m=path.length_m + 3.0)
    _, out = _step(path, [BoundarySphere((8.0, 0.0, 0.0), 3.2)])
    assert out.reason is Reason.CRITICAL
    # two spheres, the same path between them (an opening): flown
    _, out = _step(path)
    assert out.reason is Reason.KNOWN_PATH


def test_a_path_that_gets_no_nearer_is_not_flown_and_nothing_free_holds():
    pos = np.zeros(3)
    spheres = [
        BoundarySphere(tuple(pos + 3.0 * s * np.eye(3)[a]), 2.5)
        for a in range(3)
        for s in (1.0, -1.0)
    ]
    short = _fake_path((0.4, 0.0, 0.0), (0.5, 0.0, 0.0), GOAL)  # 0.5 m nearer < 1 m
    _, out = _step(short, spheres)
    assert out.mode is Mode.HOLD and out.reason is Reason.NO_FREE_DIRECTION
    onward = _fake_path((0.4, 0.0, 0.0), (1.6, 0.0, 0.0), GOAL)
    _, out = _step(onward, spheres)
    assert out.reason is Reason.KNOWN_PATH
    np.testing.assert_allclose(out.setpoint_ned_m, onward.leg_end_ned_m)


def test_prefer_known_path_rules():
    pos, goal = np.zeros(3), np.array(GOAL)
    cones = [collision_cone(pos, s) for s in PINCH]
    through = _fake_path((3.0, 0.0, 0.0), (12.0, 0.0, 0.0), GOAL)
    beside = _fake_path((0.0, 3.0, 0.0), (12.0, 0.0, 0.0), GOAL)  # leg outside every cone
    common = {"cones": cones, "min_progress_m": 1.0}
    assert not prefer_known_path(None, pos, goal, cone_has_direction=False, kept=False, **common)
    assert prefer_known_path(through, pos, goal, cone_has_direction=True, kept=False, **common)
    assert not prefer_known_path(beside, pos, goal, cone_has_direction=True, kept=False, **common)
    assert prefer_known_path(beside, pos, goal, cone_has_direction=True, kept=True, **common)
    assert prefer_known_path(beside, pos, goal, cone_has_direction=False, kept=False, **common)


def test_a_way_is_blocked_only_by_a_surface_seen_within_the_vehicles_radius():
    grid = _open_grid()
    grid[40, 30:50, :] = OCCUPIED  # a wall across x = 8.0–8.2 m, y 6–10 m
    radius = CFG.section_radius_m
    a = _centre(30, 40, 6)
    # straight into it, and past its end by less than the radius (face distance)
    assert way_blocked(grid, ORIGIN, VOXEL_M, a, a + np.array([4.0, 0.0, 0.0]), config=CFG)
    end_y = 10.0 + radius - 0.1  # the wall ends at y = 10.0
    b = np.array([12.0, end_y, a[2]])
    assert way_blocked(grid, ORIGIN, VOXEL_M, np.array([4.0, end_y, a[2]]), b, config=CFG)
    # beside its end by more than the radius plus a voxel: clear
    clear_y = 10.0 + radius + VOXEL_M + 0.05
    b = np.array([12.0, clear_y, a[2]])
    assert not way_blocked(grid, ORIGIN, VOXEL_M, np.array([4.0, clear_y, a[2]]), b, config=CFG)
    # short of it by the radius plus a voxel: clear; through unknown or one frame's hit:
    # not blocked (not seen)
    assert not way_blocked(grid, ORIGIN, VOXEL_M, a, a + np.array([1.2, 0.0, 0.0]), config=CFG)
    grid[40, 30:50, :] = UNKNOWN
    assert not way_blocked(grid, ORIGIN, VOXEL_M, a, a + np.array([4.0, 0.0, 0.0]), config=CFG)
    grid[40, 30:50, :] = TENTATIVE
    assert not way_blocked(grid, ORIGIN, VOXEL_M, a, a + np.array([4.0, 0.0, 0.0]), config=CFG)


def test_the_path_leads_where_the_cone_is_blocked_or_leads_away_from_it():
    pos, goal = np.zeros(3), np.array(GOAL)
    cones = [collision_cone(pos, s) for s in PINCH]
    common = {"cones": cones, "min_progress_m": 1.0, "kept": False, "cone_has_direction": True}
    beside = _fake_path((0.0, 3.0, 0.0), (12.0, 0.0, 0.0), GOAL)  # leg outside every cone
    assert not prefer_known_path(beside, pos, goal, **common)
    assert prefer_known_path(beside, pos, goal, cone_blocked=True, **common)
    # blocked, but the path leads the cone's way (within 45°): the paper's rule stays
    leg = np.asarray(beside.leg_end_ned_m) / 3.0
    turn = np.array([math.sin(math.radians(40.0)), math.cos(math.radians(40.0)), 0.0])
    assert not prefer_known_path(beside, pos, goal, cone_blocked=True, cone_dir_ned=leg, **common)
    assert not prefer_known_path(beside, pos, goal, cone_blocked=True, cone_dir_ned=turn, **common)
    turn = np.array([math.sin(math.radians(50.0)), math.cos(math.radians(50.0)), 0.0])
    assert prefer_known_path(beside, pos, goal, cone_blocked=True, cone_dir_ned=turn, **common)
    # a blocked cone does not make a path that gets no nearer worth flying
    short = _fake_path((0.4, 0.0, 0.0), (0.5, 0.0, 0.0), GOAL)
    assert not prefer_known_path(short, pos, goal, cone_blocked=True, **common)
    # one sphere (§6): a path round it no shorter than the cone's way round the other side
    single = [collision_cone(pos, BoundarySphere((8.0, 0.0, 0.0), 3.2))]
    one = {**common, "cones": single, "cone_way_m": 22.0}
    c = single[0]
    half = c.half_angle_rad
    cone_dir = np.array([math.cos(half), math.sin(half), 0.0])  # its tangent to the right
    leg = 3.0 * np.array([math.cos(half - 0.05), -math.sin(half - 0.05), 0.0])  # into it, left
    path = dataclasses.replace(
        _fake_path(tuple(leg), (12.0, 0.0, 0.0), GOAL), reaches_goal=True, length_m=50.0
    )
    assert not prefer_known_path(path, pos, goal, cone_dir_ned=cone_dir, **one)
    # the cone's direction turned away from the known way (round the far end of a wall)
    away = np.array([-0.1, 1.0, 0.0]) / math.hypot(0.1, 1.0)
    assert prefer_known_path(path, pos, goal, cone_dir_ned=away, **one)
    # ... but only a path that reaches the goal is a known way to it
    partial = dataclasses.replace(path, reaches_goal=False)
    assert not prefer_known_path(partial, pos, goal, cone_dir_ned=away, **one)
