"""One bounded look at a goal held only by a blind spot (companion.guidance.go_look; issue 36,
passages goal_surface-22): the viewpoint's closed-form geometry, the look's phases, and,
on a map, that from the viewpoint no piece hides the goal any more."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from companion.guidance.go_look import (
    GoLookConfig,
    LookPhase,
    LookState,
    held_by_blind_spot_only,
    look_step,
    look_viewpoint,
)
from companion.guidance.map_boundaries import in_shadow, map_boundaries
from companion.known_space import FREE, OCCUPIED, KnownSpace

CFG = GoLookConfig()


@dataclass(frozen=True)
class _Ball:
    center_ned_m: tuple[float, float, float]
    radius_m: float
    goal_gap_m: float = 1.0


def _off(point, *offset_m: float) -> np.ndarray:
    return np.asarray(point, dtype=float) + np.array(offset_m)


def _always(_a, _b) -> bool:
    return True


def _swing_deg(pos, goal, view) -> float:
    """Signed swing about the goal from the vehicle's bearing to the view's [deg]."""
    a = math.atan2(pos[1] - goal[1], pos[0] - goal[0])
    b = math.atan2(view[1] - goal[1], view[0] - goal[0])
    return math.degrees(math.remainder(b - a, 2.0 * math.pi))


def test_the_viewpoint_is_the_nearest_that_sees_past_one_piece_closed_form():
    """One piece of radius r at s from the goal on the line to the vehicle (ρ away): from a
    point swung α about the goal the line of sight passes the centroid at s·sin α, so the
    goal is seen once s·sin α > r + sight_clear; the first 5° step past it, on whichever
    circle (ρ·f, f ∈ {0.75, 1, 1.25}) is nearest the vehicle: ρ·√(1 + f² − 2f·cos α)."""
    goal = np.array([0.0, 0.0, -6.0])
    rho, s, r = 5.0, 1.8, 0.9
    pos = _off(goal, rho, 0.0, 0.0)
    piece = (_off(goal, s, 0.0, 0.0), r)
    view = look_viewpoint(pos, goal, [piece], [], _always, CFG)
    alpha_min = math.degrees(math.asin((r + CFG.sight_clear_m) / s))
    alpha = math.radians(CFG.step_deg * math.ceil(alpha_min / CFG.step_deg))
    f = min((0.75, 1.0, 1.25), key=lambda f: 1.0 + f * f - 2.0 * f * math.cos(alpha))
    expected = _off(goal, rho * f * math.cos(alpha), rho * f * math.sin(alpha), 0.0)
    np.testing.assert_allclose(view, expected, atol=1e-9, err_msg="nearest sighted candidate")
    assert _swing_deg(pos, goal, view) > 0.0, "a tie goes to the positive swing (east here)"
    assert view[2] == pos[2], "the look keeps the vehicle's height"
    assert not in_shadow(view, goal, piece[0], r + CFG.sight_clear_m)
    # one step less swing and the piece would still hide the goal
    back = alpha - math.radians(CFG.step_deg)
    nearer = _off(goal, rho * f * math.cos(back), rho * f * math.sin(back), 0.0)
    assert in_shadow(nearer, goal, piece[0], r + CFG.sight_clear_m)


def test_a_wall_off_to_one_side_is_looked_past_on_its_short_side():
    """Pieces of a wall reaching 3.6 m west of the line of sight but 1.2 m east: the look
    swings east (the shorter way round the wall's edge)."""
    goal = np.array([0.0, 0.0, -6.0])
    pos = _off(goal, 5.0, 0.0, 0.0)
    wall = [(_off(goal, 1.8, e, 0.0), 0.85) for e in (-3.6, -2.4, -1.2, 0.0, 1.2)]
    view = look_viewpoint(pos, goal, wall, [], _always, CFG)
    assert view is not None and view[1] > 0.0
    assert all(not in_shadow(view, goal, c, r + CFG.sight_clear_m) for c, r in wall)


def test_no_viewpoint_when_none_is_reachable_near_or_outside_the_spheres():
    goal = np.array([0.0, 0.0, -6.0])
    pos = _off(goal, 5.0, 0.0, 0.0)
    piece = [(_off(goal, 1.8, 0.0, 0.0), 0.9)]
    assert look_viewpoint(pos, goal, piece, [], lambda a, b: False, CFG) is None
    short = GoLookConfig(max_look_m=1.0)  # the first sighted candidate is ~3.4 m away
    assert look_viewpoint(pos, goal, piece, [], _always, short) is None
    # a boundary sphere round both candidate sides: every sighted view inside it
    big = _Ball((float(goal[0] + 1.8), 0.0, -6.0), 6.0)
    assert look_viewpoint(pos, goal, piece, [big], _always, CFG) is None
    # a sphere only on the east side: the look goes west instead
    east = _Ball((float(goal[0] + 3.0), 3.0, -6.0), 2.0)
    view = look_viewpoint(pos, goal, piece, [east], _always, CFG)
    assert view is not None and view[1] < 0.0


def test_the_reachability_question_is_the_straight_move_from_the_vehicle():
    goal = np.array([0.0, 0.0, -6.0])
    pos = _off(goal, 5.0, 0.0, 0.0)
    asked = []

    def reachable(a, b):
        asked.append((np.array(a), np.array(b)))
        return b[1] < 0.0  # only the west side is seen free

    view = look_viewpoint(pos, goal, [(_off(goal, 1.8, 0.0, 0.0), 0.9)], [], reachable, CFG)
    assert view is not None and view[1] < 0.0
    assert all(np.array_equal(a, pos) for a, _ in asked)


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


def test_a_look_resolves_when_no_boundary_holds_the_goal_and_happens_once_per_goal():
    s = _step(_step(LookState(), 0.0, holding=True), 1.0)
    assert s.phase is LookPhase.LOOKING
    s = _step(s, 2.0, held=False)
    assert s.phase is LookPhase.DONE and s.resolved
    np.testing.assert_array_equal(s.steer_to(GOAL), GOAL)
    again = _step(s, 3.0, holding=True)  # held again later: no second look
    assert again.phase is LookPhase.DONE
    other = _step(again, 4.0, goal=(9.0, 9.0, -6.0), holding=True)  # a new goal: afresh
    assert other.phase is LookPhase.LOOKING


@pytest.mark.parametrize(
    ("why", "kwargs", "t_end"),
    [
        ("time", {}, CFG.look_time_s),
        ("held on the way", {"holding": True}, 0.5),
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
    spot, not the surface); from the viewpoint chosen, no boundary holds it."""
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
    near = space.pieces(goal, 8.0, goal)
    pieces = list(zip(near.centroid_ned_m, near.radius_m.tolist(), strict=True))
    view = look_viewpoint(pos, goal, pieces, here, _always, CFG)
    assert view is not None
    assert np.linalg.norm(view - pos) <= CFG.max_look_m
    there = map_boundaries(space, view, goal)
    assert not any(np.linalg.norm(goal - np.asarray(b.center_ned_m)) < b.radius_m for b in there)
