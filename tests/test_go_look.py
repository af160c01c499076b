"""One bounded look at a goal held only by a blind spot (companion.guidance.go_look; issue 36,
passages goal_surface-22): the viewpoint's closed-form geometry, the look's phases, and,
on a map, that from the viewpoint no piece hides the goal any more."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest

from companion.core.mission import Mission
from companion.guidance.go_look import (
    BLOCKED,
    SEEN_FREE,
    UNSEEN,
    GoLookConfig,
    LookPhase,
    LookState,
    held_by_blind_spot_only,
    look_step,
    look_viewpoint,
    look_yaw_rad,
)
from companion.guidance.map_boundaries import map_boundaries
from companion.guidance.modes import Mode
from companion.known_space import FREE, OCCUPIED, KnownSpace
from companion.pipeline import AvoidancePipeline, PoseAtCapture

CFG = GoLookConfig()


@dataclass(frozen=True)
class _Ball:
    center_ned_m: tuple[float, float, float]
    radius_m: float
    goal_gap_m: float = 1.0


def _off(point, *offset_m: float) -> np.ndarray:
    return np.asarray(point, dtype=float) + np.array(offset_m)


def _always(_a, _b) -> int:
    return SEEN_FREE


def _swing_deg(pos, goal, view) -> float:
    """Signed swing about the goal from the vehicle's bearing to the view's [deg]."""
    a = math.atan2(pos[1] - goal[1], pos[0] - goal[0])
    b = math.atan2(view[1] - goal[1], view[0] - goal[0])
    return math.degrees(math.remainder(b - a, 2.0 * math.pi))


def _wall(goal, s_m: float, west_m: float, east_m: float) -> np.ndarray:
    """OCCUPIED voxel centres every 0.2 m on a line across the axis ``s_m`` north of the
    goal, from ``west_m`` to ``east_m`` east of it, at its height."""
    east = np.arange(west_m, east_m + 1e-9, 0.2)
    return np.column_stack(
        [np.full_like(east, goal[0] + s_m), goal[1] + east, np.full_like(east, goal[2])]
    )


def test_the_viewpoint_is_the_nearest_that_sees_past_the_walls_edge_closed_form():
    """A wall s north of the goal reaching w either side of the axis; the vehicle ρ north.
    From a point swung α about the goal the line of sight passes the edge voxel (s, w) by
    R·sin(α − φ) (R = √(s² + w²), φ = atan2(w, s)), so the goal is seen once that exceeds
    sight_clear: the first 5° step past α_min = φ + asin(sight_clear / R), on whichever
    circle (ρ·f, f ∈ {0.75, 1, 1.25}) is nearest the vehicle: ρ·√(1 + f² − 2f·cos α)."""
    goal = np.array([0.0, 0.0, -6.0])
    rho, s, w = 5.0, 1.8, 2.3
    pos = _off(goal, rho, 0.0, 0.0)
    wall = _wall(goal, s, -w, w)
    view = look_viewpoint(pos, goal, wall, [], _always, CFG)
    big_r, phi = math.hypot(s, w), math.atan2(w, s)
    alpha_min = math.degrees(phi + math.asin(CFG.sight_clear_m / big_r))
    alpha = math.radians(CFG.step_deg * math.ceil(alpha_min / CFG.step_deg))
    f = min((0.75, 1.0, 1.25), key=lambda f: 1.0 + f * f - 2.0 * f * math.cos(alpha))
    expected = _off(goal, rho * f * math.cos(alpha), rho * f * math.sin(alpha), 0.0)
    np.testing.assert_allclose(view, expected, atol=1e-9, err_msg="nearest sighted candidate")
    assert _swing_deg(pos, goal, view) > 0.0, "a tie goes to the positive swing (east here)"
    assert view[2] == pos[2], "the look keeps the vehicle's height"
    # one step less swing on the same circle and the edge would hide the goal
    back = alpha - math.radians(CFG.step_deg)
    nearer = _off(goal, rho * f * math.cos(back), rho * f * math.sin(back), 0.0)
    only_nearer = look_viewpoint(
        pos, goal, wall, [], lambda a, b: SEEN_FREE if np.allclose(b, nearer) else BLOCKED, CFG
    )
    assert only_nearer is None


def test_a_wall_off_to_one_side_is_looked_past_on_its_short_side():
    """A wall reaching 3.6 m west of the line of sight but 1.2 m east: the look swings
    east (the shorter way round the wall's edge)."""
    goal = np.array([0.0, 0.0, -6.0])
    pos = _off(goal, 5.0, 0.0, 0.0)
    view = look_viewpoint(pos, goal, _wall(goal, 1.8, -3.6, 1.2), [], _always, CFG)
    assert view is not None and view[1] > 0.0


def test_no_viewpoint_when_none_is_reachable_near_or_outside_the_spheres():
    goal = np.array([0.0, 0.0, -6.0])
    pos = _off(goal, 5.0, 0.0, 0.0)
    wall = _wall(goal, 1.8, -2.3, 2.3)
    assert look_viewpoint(pos, goal, wall, [], lambda a, b: BLOCKED, CFG) is None
    short = GoLookConfig(max_look_m=3.0)  # the first sighted candidate is ~4.5 m away
    assert look_viewpoint(pos, goal, wall, [], _always, short) is None
    # a boundary sphere round both candidate sides: every sighted view inside it
    big = _Ball((float(goal[0] + 1.8), 0.0, -6.0), 6.0)
    assert look_viewpoint(pos, goal, wall, [big], _always, CFG) is None
    # a sphere only on the east side: the look goes west instead
    east = _Ball((float(goal[0] + 2.5), 4.0, -6.0), 2.5)
    view = look_viewpoint(pos, goal, wall, [east], _always, CFG)
    assert view is not None and view[1] < 0.0


def test_a_view_seen_free_wins_over_a_nearer_one_not_yet_seen():
    """The question is the straight move from the vehicle; a move seen free wins over a
    nearer one not yet seen (still flown, looked at first, when it is the only one), and
    a move with a surface seen in its way is never taken."""
    goal = np.array([0.0, 0.0, -6.0])
    pos = _off(goal, 5.0, 0.0, 0.0)
    wall = _wall(goal, 1.8, -3.0, 2.3)  # east is the shorter way round
    asked = []

    def west_seen(a, b):
        asked.append((np.array(a), np.array(b)))
        return SEEN_FREE if b[1] < 0.0 else UNSEEN

    view = look_viewpoint(pos, goal, wall, [], west_seen, CFG)
    assert view is not None and view[1] < 0.0
    assert all(np.array_equal(a, pos) for a, _ in asked)
    unseen = look_viewpoint(pos, goal, wall, [], lambda a, b: UNSEEN, CFG)
    assert unseen is not None and unseen[1] > 0.0, "none seen free: the nearest not seen"
    east_blocked = look_viewpoint(
        pos, goal, wall, [], lambda a, b: BLOCKED if b[1] > 0.0 else UNSEEN, CFG
    )
    assert east_blocked is not None and east_blocked[1] < 0.0


def test_held_by_blind_spot_only_is_every_holding_sphere_clear_of_its_surface():
    goal = (0.0, 0.0, 0.0)
    inflate = 0.65
    blind = _Ball((0.5, 0.0, 0.0), 1.0, goal_gap_m=1.7)
    near = _Ball((0.5, 0.0, 0.0), 1.0, goal_gap_m=0.5)
    away = _Ball((5.0, 0.0, 0.0), 1.0, goal_gap_m=0.1)  # does not hold the goal
    assert held_by_blind_spot_only([blind, away], goal, inflate)
    assert not held_by_blind_spot_only([blind, near], goal, inflate)  # surely blocked
    assert not held_by_blind_spot_only([away], goal, inflate)  # not held at all


GOAL = (0.0, 0.0, -6.0)
VIEW = np.array([3.0, 3.0, -6.0])


def _step(state, t, *, pos=(5.0, 0.0, -6.0), goal=GOAL, blind=True, held=True, holding=False):
    return look_step(
        state, time_s=t, pos_ned_m=pos, goal_ned_m=goal, blind_only=blind, held=held,
        holding=holding, viewpoint=lambda: VIEW, config=CFG,
    )  # fmt: skip


def test_a_look_starts_only_when_guidance_holds_for_a_goal_held_by_a_blind_spot():
    s = _step(LookState(), 0.0, holding=False)
    assert s.phase is LookPhase.NONE
    assert _step(s, 0.1, holding=True, blind=False).phase is LookPhase.NONE  # surely blocked
    s = _step(s, 0.2, holding=True)
    assert s.phase is LookPhase.LOOKING and s.viewpoint_ned_m == tuple(VIEW)
    np.testing.assert_array_equal(s.steer_to(GOAL), VIEW)
    none = look_step(
        LookState(), time_s=0.0, pos_ned_m=(5.0, 0.0, -6.0), goal_ned_m=GOAL, blind_only=True,
        held=True, holding=True, viewpoint=lambda: None, config=CFG,
    )  # fmt: skip
    assert none.phase is LookPhase.DONE, "no viewpoint: no look, the stop stands"
    np.testing.assert_array_equal(none.steer_to(GOAL), GOAL)


def test_a_look_resolves_when_no_boundary_holds_the_goal_within_one_time_bound_per_goal():
    s = _step(_step(LookState(), 0.0, holding=True), 1.0)
    assert s.phase is LookPhase.LOOKING
    s = _step(s, 2.0, held=False)
    assert s.phase is LookPhase.DONE and s.resolved
    np.testing.assert_array_equal(s.steer_to(GOAL), GOAL)
    # held again within the look's time (a frame's map let the goal go, the next held
    # it: goal_surface-22): another viewpoint, the same start time, counted
    again = _step(s, 3.0, holding=True)
    assert again.phase is LookPhase.LOOKING and again.views == 2 and again.since_s == 0.0
    done = _step(again, 4.0, held=False)
    assert done.phase is LookPhase.DONE and done.resolved
    late = _step(done, CFG.look_time_s, holding=True)  # past the look's time: no more
    assert late.phase is LookPhase.DONE
    other = _step(late, 30.0, goal=(9.0, 9.0, -6.0), holding=True)  # a new goal: afresh
    assert other.phase is LookPhase.LOOKING and other.views == 1


@pytest.mark.parametrize(
    ("why", "kwargs", "t_end"),
    [
        ("time", {}, CFG.look_time_s),
        ("held on the way to every viewpoint", {"holding": True}, 0.5 * CFG.max_views),
        ("surely blocked after all", {"blind": False}, 0.5),
    ],
)
def test_a_look_ends_unresolved_bounded(why, kwargs, t_end):
    s = _step(LookState(), 0.0, holding=True)
    t = 0.0
    while s.phase is LookPhase.LOOKING and t < 100.0:
        t += 0.5
        s = _step(s, t, **kwargs)
    assert s.phase is LookPhase.DONE and not s.resolved, why
    assert t == pytest.approx(t_end), why


def test_a_hold_on_the_way_chooses_the_next_viewpoint_from_where_the_vehicle_stands():
    """goal_surface-22 (stereo, with the direction-keeping tilt limit) and -206: surfaces
    seen on the way put the first viewpoint inside a boundary, guidance held, and the one
    look ended 4 s after it began. The next viewpoint is chosen from where the vehicle
    stands; the look's time bound runs from its start; no viewpoint left ends it."""
    views = iter([VIEW, np.array([2.0, -3.0, -6.0]), None])

    def step(state, t, **kw):
        return look_step(
            state, time_s=t, pos_ned_m=kw.get("pos", (4.0, 1.0, -6.0)), goal_ned_m=GOAL,
            blind_only=True, held=True, holding=kw.get("holding", False),
            viewpoint=lambda: next(views), config=CFG,
        )  # fmt: skip

    s = step(LookState(), 0.0, holding=True)
    assert s.phase is LookPhase.LOOKING and s.views == 1
    s = step(s, 4.0, holding=True)  # held on the way
    assert s.phase is LookPhase.LOOKING and s.viewpoint_ned_m == (2.0, -3.0, -6.0)
    assert s.views == 2 and s.since_s == 0.0
    np.testing.assert_array_equal(s.steer_to(GOAL), (2.0, -3.0, -6.0))
    s = step(s, 5.0)
    assert s.phase is LookPhase.LOOKING
    s = step(s, 6.0, holding=True)  # held again, no viewpoint qualifies from here
    assert s.phase is LookPhase.DONE and not s.resolved
    np.testing.assert_array_equal(s.steer_to(GOAL), GOAL)


def test_a_look_ends_after_dwelling_at_the_viewpoint_with_the_goal_still_held():
    s = _step(LookState(), 0.0, holding=True)
    s = _step(s, 1.0, pos=tuple(_off(VIEW, 0.3, 0.0, 0.0)))  # arrived (0.3 m < arrive_m)
    assert s.phase is LookPhase.LOOKING and s.arrived_s == 1.0
    s = _step(s, 1.0 + CFG.dwell_s - 0.1, pos=tuple(VIEW))
    assert s.phase is LookPhase.LOOKING
    s = _step(s, 1.0 + CFG.dwell_s, pos=tuple(VIEW))
    assert s.phase is LookPhase.DONE and not s.resolved


def test_from_the_viewpoint_the_map_no_longer_holds_the_goal_behind_a_thin_wall():
    """goal_surface-22's shape on a map: a wall 4.6 m wide, 1 voxel thick, the goal 1.7 m
    behind its face, never seen. From in front the wall's pieces hold it (the blind
    spot, not the surface); the viewpoint chosen sees past the wall's edge, and once the
    goal's voxel is seen free from there no boundary holds it."""
    space = KnownSpace()
    pos = np.array([0.1, 0.1, -6.1])  # a voxel centre
    space.mark_vehicle(pos)
    c = space.config
    o = space.origin_vox
    i = math.floor(-3.0 / c.voxel_m) - o[0]  # the face 3 m south of the vehicle
    j0, j1 = (math.floor(e / c.voxel_m) - o[1] for e in (0.1 - 2.3, 0.1 + 2.3))
    k0, k1 = (math.floor(d / c.voxel_m) - o[2] for d in (-6.1 - 2.0, -6.1 + 2.0))
    space.grid[i, j0:j1, k0:k1] = OCCUPIED
    goal = np.array([-3.0 - 1.7 + 0.05, 0.1, -6.1])
    inflate = 0.65
    here = map_boundaries(space, pos, goal)
    assert space.state_at(goal) != int(FREE)
    assert held_by_blind_spot_only(here, goal, inflate)
    view = look_viewpoint(pos, goal, space.occupied_points_ned_m(), here, _always, CFG)
    assert view is not None
    assert np.linalg.norm(view - pos) <= CFG.max_look_m
    sight = goal - view
    occupied = space.occupied_points_ned_m()
    t = np.clip((occupied - view) @ sight / float(sight @ sight), 0.0, 1.0)
    passing_m = np.linalg.norm(occupied - (view + t[:, None] * sight), axis=1)
    assert passing_m.min() > CFG.sight_clear_m, "the line of sight passes the wall's edge"
    # seen from there (the goal's voxel FREE once looked at), no boundary holds it
    space.grid[tuple(np.floor(goal / c.voxel_m).astype(int) - o)] = FREE
    there = map_boundaries(space, view, goal)
    assert not any(np.linalg.norm(goal - np.asarray(b.center_ned_m)) < b.radius_m for b in there)


def test_near_the_viewpoint_the_vehicle_faces_the_goal():
    s = _step(LookState(), 0.0, holding=True)
    far = _off(VIEW, 0.0, -CFG.face_m - 0.1, 0.0)
    assert look_yaw_rad(s, far, GOAL, CFG) is None, "on the way: guidance's yaw"
    near = _off(VIEW, 0.0, -CFG.face_m + 0.1, 0.0)
    to_goal = np.asarray(GOAL) - near
    assert look_yaw_rad(s, near, GOAL, CFG) == pytest.approx(math.atan2(to_goal[1], to_goal[0]))
    done = _step(s, 1.0, held=False)
    assert look_yaw_rad(done, near, GOAL, CFG) is None, "not looking: guidance's yaw"


def _pipeline_before_a_wall(goal_behind_m: float):
    """A pipeline whose map holds a wall 3 m south of the vehicle (as in the test above),
    its guidance just held for the goal ``goal_behind_m`` behind the wall's face (the
    pipeline's wiring of the look, ``AvoidancePipeline._look_goal``)."""
    pipe = AvoidancePipeline(goal_ned_m=(-3.0 - goal_behind_m + 0.05, 0.1, -6.1))
    space = pipe.known_space
    pos = np.array([0.1, 0.1, -6.1])
    space.mark_vehicle(pos)
    c, o = space.config, space.origin_vox
    i = math.floor(-3.0 / c.voxel_m) - o[0]
    j0, j1 = (math.floor(e / c.voxel_m) - o[1] for e in (0.1 - 2.3, 0.1 + 2.3))
    k0, k1 = (math.floor(d / c.voxel_m) - o[2] for d in (-6.1 - 2.0, -6.1 + 2.0))
    space.grid[i, j0:j1, k0:k1] = OCCUPIED
    pipe.guidance.state = dataclasses.replace(pipe.guidance.state, mode=Mode.HOLD, unreachable=True)
    pose = PoseAtCapture(pos, np.zeros(3), np.eye(3))
    boundaries = map_boundaries(space, pos, pipe.goal_ned_m, pipe.boundary_config)
    return pipe, pose, boundaries


def test_the_pipeline_steers_guidance_to_the_viewpoint_for_a_blind_spot_goal_only():
    """Held for a goal 1.7 m behind the wall (its blind spot only): guidance's goal becomes
    the viewpoint, and the output names it. Held for a goal 0.4 m behind the face (within
    the inflation of the wall's surface): no look, guidance keeps the goal."""
    pipe, pose, boundaries = _pipeline_before_a_wall(1.7)
    steer = pipe._look_goal(10.0, pose, boundaries)
    assert pipe._look.phase is LookPhase.LOOKING
    np.testing.assert_array_equal(steer, pipe._look.viewpoint_ned_m)
    assert np.linalg.norm(steer - pipe.goal_ned_m) > 1.0
    near, pose, boundaries = _pipeline_before_a_wall(0.4)
    assert not held_by_blind_spot_only(boundaries, near.goal_ned_m, near.boundary_config.inflate_m)
    np.testing.assert_array_equal(near._look_goal(10.0, pose, boundaries), near.goal_ned_m)
    assert near._look.phase is LookPhase.NONE


def test_the_mission_says_when_a_look_starts_and_ends_once_each():
    """After "Holding (goal_unreachable)" the vehicle moves on: the operator hears why (a
    STATUSTEXT within MAVLink's 50 characters) and the log has the viewpoint."""
    mission = Mission([GOAL], goal_tolerance_m=0.5)
    said: list = []
    logged: list = []
    view = (-29.66, -19.43, -5.44)
    for look in (None, view, view, view, None, None):
        mission._report_look(SimpleNamespace(look_ned_m=look), 0, said, logged)
    assert [n.text for n in said] == ["Looking at goal from N-29.7 E-19.4 (blind spot)"]
    assert len(said[0].text) <= 50
    assert [(e.name, e.fields["viewpoint_ned_m"]) for e in logged] == [
        ("goal_look", list(view)),
        ("goal_look", None),
    ]
