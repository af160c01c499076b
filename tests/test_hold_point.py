"""``companion.guidance.hold``: the nearest point out of overlapping boundaries
(``nearest_outside``, ``way_out``) and any target kept out of them (``keep_target_out``,
``clear_along_ray``), against closed forms (a ball, two balls, a wall of pieces), against
the 2 cm march ``clear_along_ray`` replaced, and over random clusters."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from companion.guidance.hold import (
    HoldPlacement,
    clear_along_ray,
    hold_point,
    inside_any,
    keep_target_out,
    nearest_outside,
    way_out,
)

STEP_M = 0.05
# 200 directions ~14° apart: a direction off the best by up to ~7° costs 1/cos(7°) ≈ 0.8 %
ANGLE_SLACK = 1.0 / math.cos(math.radians(8.0))


@dataclass(frozen=True)
class Ball:
    center_ned_m: tuple[float, float, float]
    radius_m: float


def test_one_ball_nearest_out_is_radial_within_the_search_resolution():
    ball = Ball((0.0, 0.0, -7.0), 1.5)
    pos = np.array([0.3, 0.2, -7.1])
    out = nearest_outside(pos, [ball], step_m=STEP_M)
    depth = 1.5 - float(np.linalg.norm(pos - ball.center_ned_m))  # closed form: straight out
    moved = float(np.linalg.norm(out - pos))
    assert depth <= moved <= depth * ANGLE_SLACK + STEP_M, (depth, moved)
    assert not inside_any(out, [ball])


def test_two_overlapping_balls_closed_form_distance():
    # balls r = 1 at y = ±0.5 meet on the circle y = 0 of radius sqrt(1 - 0.5²); from
    # (0, 0.1, 0) the nearest point out of both lies on it: sqrt(0.75 + 0.1²) = 0.872 m
    pair = [Ball((0.0, 0.5, 0.0), 1.0), Ball((0.0, -0.5, 0.0), 1.0)]
    pos = np.array([0.0, 0.1, 0.0])
    out = nearest_outside(pos, pair, step_m=STEP_M)
    moved = float(np.linalg.norm(out - pos))
    best = math.sqrt(0.75 + 0.1**2)
    assert best <= moved <= best * ANGLE_SLACK + STEP_M, moved
    assert not inside_any(out, pair)


def test_a_wall_of_pieces_is_left_through_its_nearer_face_with_clearance():
    # a wall in the plane x = 0: balls r = 0.8 every 0.4 m along y and z (thickness
    # ≈ 2 × 0.8 wherever the balls overlap); vehicle 0.3 m in front of the centre plane
    grid = np.arange(-2.0, 2.01, 0.4)
    wall = [Ball((0.0, y, z), 0.8) for y in grid for z in grid]
    pos = np.array([0.3, 0.1, 0.05])
    out = nearest_outside(pos, wall, clearance_m=0.2, step_m=STEP_M, prefer_ned=(1.0, 0.0, 0.0))
    assert out[0] > 0.8  # out through the face it was nearer (clearance: checked below)
    assert float(np.linalg.norm(out - pos)) <= (0.8 + 0.2 - 0.3) * ANGLE_SLACK + STEP_M
    assert not inside_any(out, [Ball(b.center_ned_m, b.radius_m + 0.2 - 1e-9) for b in wall])


def test_clearance_is_given_up_before_the_way_out_is():
    # a ball whose way out with 0.5 m of clearance lies beyond a 1 m search, without it inside
    ball = Ball((0.0, 0.0, 0.0), 1.0)
    out = nearest_outside((0.2, 0.0, 0.0), [ball], clearance_m=0.5, search_m=1.0)
    assert out is not None and not inside_any(out, [ball])
    assert nearest_outside((0.0, 0.0, 0.0), [ball], search_m=0.5) is None


def test_the_preferred_direction_breaks_ties():
    ball = Ball((0.0, 0.0, 0.0), 1.0)
    for prefer in ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0)):
        out = nearest_outside((0.0, 0.0, 0.0), [ball], prefer_ned=prefer)
        cos_off = float(np.dot(out / np.linalg.norm(out), prefer))
        assert cos_off > math.cos(math.radians(15)), cos_off  # directions ~14° apart


@pytest.mark.parametrize("seed", range(20))
def test_hold_targets_from_inside_random_clusters_are_outside_or_where_it_is(seed):
    rng = np.random.default_rng(seed)
    balls = [Ball(tuple(rng.uniform(-1.5, 1.5, 3)), float(rng.uniform(0.4, 1.2))) for _ in range(8)]
    pos = np.asarray(balls[0].center_ned_m) + rng.uniform(-0.2, 0.2, 3)
    hp = hold_point(pos, (0.0, 0.0, 0.0), balls, latency_s=0.15, accel_mps2=2.0, clearance_m=0.2)
    assert hp.placement in (HoldPlacement.ESCAPE, HoldPlacement.NEAREST_OUT)
    assert not inside_any(hp.pos_ned_m, balls)


# --- keep_target_out: every target guidance sends, outside every boundary (invariant 3) ---

UNIT = Ball((0.0, 0.0, 0.0), 1.0)


def test_a_target_outside_every_boundary_stands():
    assert keep_target_out([-3.0, 0, 0], [-1.2, 0.5, 0], [UNIT], free_m=5.0) is None


def test_a_target_inside_is_shortened_to_the_standoff_before_the_entry_point():
    # closed form: the segment from x = -3 enters the unit ball at x = -1
    kept = keep_target_out([-3.0, 0, 0], [0.5, 0, 0], [UNIT], free_m=5.0, standoff_m=0.05)
    assert kept.placement is HoldPlacement.SHORTENED
    np.testing.assert_allclose(kept.pos_ned_m, [-1.05, 0, 0], atol=1e-9)


def test_shortening_stops_before_the_first_of_two_boundaries_on_the_way():
    near = Ball((0.0, 0.0, 0.0), 1.0)
    far = Ball((2.5, 0.0, 0.0), 1.0)  # the target lies in the far one, the path crosses near
    kept = keep_target_out([-3.0, 0, 0], [2.5, 0, 0], [far, near], free_m=9.0, standoff_m=0.05)
    np.testing.assert_allclose(kept.pos_ned_m, [-1.05, 0, 0], atol=1e-9)


def test_from_inside_the_carrot_is_carried_on_along_its_ray_to_the_outside():
    # vehicle 0.5 m from the centre of the unit ball, carrot shortened to 0.8: the ray
    # leaves the ball at x = 1; the target is the standoff beyond, within the 2 cm step
    kept = keep_target_out([0.5, 0, 0], [0.8, 0, 0], [UNIT], free_m=2.0, standoff_m=0.05)
    assert kept.placement is HoldPlacement.EXTENDED
    x, y, z = kept.pos_ned_m
    assert 1.05 - 1e-9 <= x <= 1.05 + 0.02 + 1e-9 and y == z == 0.0, kept


def test_the_exit_along_a_chord_is_the_closed_form_root():
    # from (0, 0.6, 0) along +x the unit ball's chord ends at x = sqrt(1 - 0.36) = 0.8;
    # a second ball 0.035 m beyond that exit is nearer than the standoff: passed as well
    second = Ball((0.8 + 0.035 + 0.5, 0.6, 0.0), 0.5)
    ray = ([0.0, 0.6, 0.0], [1.0, 0.0, 0.0], 0.21)
    assert clear_along_ray(*ray, [UNIT], 0.05, step_m=0.0) == pytest.approx(0.8, abs=1e-12)
    s = clear_along_ray(*ray, [UNIT, second], 0.05, step_m=0.0)
    assert s == pytest.approx(0.8 + 0.035 + 1.0, abs=1e-12)
    # on 2 cm steps from 0.21 m: the first step past each exit, 0.81 then 1.85
    assert clear_along_ray(*ray, [UNIT], 0.05) == pytest.approx(0.81, abs=1e-9)
    assert clear_along_ray(*ray, [UNIT, second], 0.05) == pytest.approx(1.85, abs=1e-9)


def _march_exit(pos, unit, start_m, balls, standoff_m, step_m=0.02, limit_m=20.0):
    """The 2 cm march keep_target_out used before the closed form: the first step whose
    point and the point ``standoff_m`` beyond are both outside every ball."""
    s = start_m
    while s <= limit_m:
        if not (
            inside_any(pos + unit * s, balls) or inside_any(pos + unit * (s + standoff_m), balls)
        ):
            return s
        s += step_m
    return math.inf


def _stretch_meets_a_ball(pos, unit, s, balls, standoff_m=0.05):
    return any(inside_any(pos + unit * t, balls) for t in np.linspace(s, s + standoff_m, 11))


@pytest.mark.parametrize("seed", range(10))
def test_the_closed_form_exit_agrees_with_the_march_on_random_clusters(seed):
    # Balls of 0.4-1.2 m, the vehicle inside one: on the march's 2 cm steps the closed
    # form is the march's answer (flights unchanged); exact (step 0) it is never later
    # than the march, its stretch is outside every ball, and no earlier stretch is (5 mm
    # grid): the least exit.
    rng = np.random.default_rng([seed, 36])
    balls = [Ball(tuple(rng.uniform(-2.0, 2.0, 3)), float(rng.uniform(0.4, 1.2))) for _ in range(6)]
    for _ in range(60):
        ball = balls[int(rng.integers(len(balls)))]  # the vehicle inside one of them
        pos = np.array(ball.center_ned_m) + rng.uniform(-0.5, 0.5, 3) * ball.radius_m
        unit = rng.normal(size=3)
        unit /= np.linalg.norm(unit)
        start = float(rng.uniform(0.0, 1.0))
        marched = _march_exit(pos, unit, start, balls, 0.05)
        stepped = clear_along_ray(pos, unit, start, balls, 0.05, step_m=0.02)
        assert stepped == pytest.approx(marched, abs=1e-9), (seed, stepped, marched)
        exact = clear_along_ray(pos, unit, start, balls, 0.05, step_m=0.0)
        assert exact <= marched + 1e-9, (seed, exact, marched)
        assert not _stretch_meets_a_ball(pos, unit, exact + 1e-9, balls), (seed, exact)
        for s in np.arange(start, exact - 0.005, 0.005):
            assert _stretch_meets_a_ball(pos, unit, s, balls), (seed, s, exact)


@pytest.mark.parametrize("seed", range(5))
def test_the_way_out_is_the_holds_way_out_without_latency_or_speed(seed):
    rng = np.random.default_rng([seed, 361])
    balls = [Ball(tuple(rng.uniform(-2.0, 2.0, 3)), float(rng.uniform(0.4, 1.2))) for _ in range(5)]
    for _ in range(30):
        pos = rng.uniform(-2.5, 2.5, 3)
        out = way_out(pos, balls, clearance_m=0.3)
        if not inside_any(pos, balls):
            assert out.placement is HoldPlacement.CURRENT
            np.testing.assert_array_equal(out.pos_ned_m, pos)
            continue
        held = hold_point(pos, np.zeros(3), balls, latency_s=0.5, accel_mps2=3.0, clearance_m=0.3)
        assert out == held
        assert out.placement is HoldPlacement.CURRENT or not inside_any(out.pos_ned_m, balls)


def test_from_inside_without_free_space_to_the_outside_the_way_out_is_the_escape():
    # the ray's exit (1.05 m) is beyond the 0.4 m seen free along it: the radial escape
    kept = keep_target_out(
        [0.0, 0.5, 0], [0.0, 0.6, 0], [UNIT], free_m=0.4, clearance_m=0.2, standoff_m=0.05
    )
    assert kept.placement is HoldPlacement.ESCAPE
    np.testing.assert_allclose(kept.pos_ned_m, [0.0, 1.2, 0.0], atol=1e-9)


@pytest.mark.parametrize("seed", range(20))
def test_kept_targets_are_outside_and_their_straight_path_too_over_random_clusters(seed):
    rng = np.random.default_rng([seed, 32])
    balls = [Ball(tuple(rng.uniform(-2.0, 2.0, 3)), float(rng.uniform(0.4, 1.2))) for _ in range(5)]
    for _ in range(50):
        pos, target = rng.uniform(-4.0, 4.0, 3), rng.uniform(-4.0, 4.0, 3)
        kept = keep_target_out(pos, target, balls, free_m=float(rng.uniform(0.0, 6.0)))
        if kept is None:
            assert not inside_any(target, balls)
            continue
        point = np.array(kept.pos_ned_m)
        if kept.placement is HoldPlacement.CURRENT:
            np.testing.assert_allclose(point, pos)  # no way out: never deeper
            continue
        assert not inside_any(point, balls), (seed, kept)
        if kept.placement is HoldPlacement.SHORTENED:  # the line flown stays out as well
            assert not any(
                inside_any(pos + t * (point - pos), balls) for t in np.linspace(0, 1, 41)
            )


def test_a_kept_out_target_is_said_once_per_episode():
    from types import SimpleNamespace

    from companion.core.mission import Mission

    mission = Mission([(0.0, 0.0, -7.0)], goal_tolerance_m=0.5)
    said = []
    for k, placement in enumerate(
        [HoldPlacement.SHORTENED] * 30 + [None] * 200 + [HoldPlacement.EXTENDED]
    ):
        out = SimpleNamespace(target_kept_out=placement, setpoint_ned_m=np.zeros(3))
        notices, events = [], []
        mission._report_kept_out(out, int(k / 30 * 1e9), notices, events)  # 30 Hz
        said += [
            (k, n.text, e.name, e.fields["placement"]) for n, e in zip(notices, events, strict=True)
        ]
    # the first of 30 consecutive frames, and again after more than 5 s without one
    assert said == [
        (0, "Target kept out of a boundary (shortened)", "target_kept_out", "shortened"),
        (230, "Target kept out of a boundary (extended)", "target_kept_out", "extended"),
    ]
