"""Momentum after a target switch at speed (issue 36; envelope step 8).

The reproducer: a vehicle moving (and still accelerating) toward a seen-free direction,
guidance switches its target sideways past a post. The straight line to the new target is
free, so steps 1–5 alone send a far carrot; the autopilot's jerk-limited reference
(plant-sim's own :class:`~plant_sim.autopilot.shaping.TargetShaper`, ArduCopter's GUIDED
limits: WPNAV_ACCEL 2.5 m/s², jerk 2 m/s³) carries the vehicle on, curving into the post.
Without step 8 it comes within the collision distance (0.35 m: the vehicle's radius) in
20 of the grid's 144 cases (−0.20 m the worst); with it the closest is 0.40 m.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from companion.guidance import envelope as envelope_module
from companion.guidance.autopilot_path import ReferenceLimits, predict_path, straight_stop_m
from companion.guidance.envelope import EnvelopeConfig, envelope_step
from companion.perception import PerceptionConfig
from plant_sim.autopilot.shaping import ShapingLimits, TargetShaper

RADIUS_M = PerceptionConfig().vehicle_radius_m  # 0.35 m: also the collision distance
ELEV_RAD = math.radians(12.0)
FRAME_S = 1.0 / 30.0
LATENCY_FRAMES = 3  # capture → the autopilot acting: 0.1 s, inside the 0.15 s budget
# ArduCopter GUIDED as plant-sim flies it: WPNAV_ACCEL 2.5 m/s², jerk min(PSC_JERK_XY, the
# airframe's 2 m/s³)
GUIDED = ShapingLimits(10.0, 2.5, 1.5, 2.5, 2.5, 2.0, 2.0)
ALT_D_M = -5.0


def _free_among(balls, lookahead_m: float = 12.0):
    """Known-free distance with everything outside ``balls`` seen free: the ray's first
    contact of the vehicle's section (radius ``radius_m``) with a ball [m]."""

    def free(pos, unit, radius_m, limit_m, half_height_m, body_m, near_field_m):
        best = min(limit_m, lookahead_m)
        for centre, r in balls:
            f = np.asarray(pos, dtype=float) - centre
            b = float(f @ unit)
            disc = b * b - (float(f @ f) - (r + radius_m) ** 2)
            if disc <= 0.0:
                continue
            root = math.sqrt(disc)
            if -b + root > 0.0:
                best = min(best, max(0.0, -b - root))
        return best

    return free


def _fly_switch(balls, speed_mps, accel_mps2, new_target, seconds=6.0, free=None, trace=None):
    """Closed loop from north at ``speed_mps`` accelerating at ``accel_mps2`` toward a far
    target (the old one), the target switched to ``new_target`` at t = 0, the brake's
    target passed back each frame as the pipeline does; returns the closest approach to a
    ball's surface [m] and the frames step 8 braked (``trace``: a list that receives
    ``(pos, output)`` per frame)."""
    shaper = TargetShaper(GUIDED)
    shaper.reset((0.0, 0.0, ALT_D_M), (speed_mps, 0.0, 0.0))
    shaper.acc_ned_mps2 = [accel_mps2, 0.0, 0.0]
    shaper.go_to((8.0, 0.0, ALT_D_M))
    free = _free_among(balls) if free is None else free
    in_flight: list[np.ndarray] = []
    closest, brakes, held = math.inf, 0, None
    for _ in range(int(seconds / FRAME_S)):
        out = envelope_step(
            pos_ned_m=shaper.pos_ned_m,
            vel_ned_mps=shaper.vel_ned_mps,
            accel_ned_mps2=shaper.acc_ned_mps2,
            setpoint_ned_m=new_target,
            free_distance=free,
            vehicle_radius_m=RADIUS_M,
            max_path_elevation_rad=ELEV_RAD,
            held_brake_ned_m=held,
        )
        held = out.brake_target_ned_m
        if trace is not None:
            trace.append((np.array(shaper.pos_ned_m), out))
        brakes += out.momentum_brake
        in_flight.append(out.setpoint_ned_m)
        if len(in_flight) > LATENCY_FRAMES:
            shaper.go_to(in_flight.pop(0))
        shaper.step(FRAME_S)
        pos = np.array(shaper.pos_ned_m)
        closest = min(closest, min(float(np.linalg.norm(pos - c)) - r for c, r in balls))
    return closest, brakes


# Posts 0.4 m in radius, 0.9 m east of the line flown, 3 or 4 m ahead (the straight lines
# north and east both clear them); switched at 0.6–1.5 m/s and 1–2.5 m/s² toward east or
# north-east. (A wider grid, v 0.6–2.0 m/s, a 0–2.5 m/s², posts 2–4 m ahead and 0.9–1.2 m
# aside, 144 cases: 20 collide without step 8, down to −0.20 m; with it the least is 0.40 m.)
SWITCHES = [
    (v, a, (n, e), new)
    for v, a, n, e, new in itertools.product(
        (0.6, 0.9, 1.5), (1.0, 2.5), (3.0, 4.0), (0.9,), ((0.0, 10.0), (4.0, 8.0))
    )
]


def _case(v, a, post, new):
    balls = [(np.array([post[0], post[1], ALT_D_M]), 0.4)]
    return balls, v, a, np.array([new[0], new[1], ALT_D_M])


def test_a_switch_at_speed_keeps_out_of_the_collision_distance(monkeypatch):
    """The reproducer reproduces: with the straight-line rules alone (step 8 switched
    off) the switches collide; with step 8 every one stays outside the vehicle's radius of
    every surface, and the rule fired in each that collided without it."""
    with_rule = [_fly_switch(*_case(*c)) for c in SWITCHES]
    monkeypatch.setattr(envelope_module, "_momentum_clear", lambda *args: True)
    without = np.array([_fly_switch(*_case(*c))[0] for c in SWITCHES])
    collided = without < RADIUS_M
    assert collided.sum() >= len(SWITCHES) // 3 and without.min() < 0.0, without.round(3)
    closest = np.array([r[0] for r in with_rule])
    assert closest.min() >= RADIUS_M, [
        (c, round(d, 3)) for c, d in zip(SWITCHES, closest, strict=True) if d < RADIUS_M
    ]
    assert all(r[1] > 0 for r, hit in zip(with_rule, collided, strict=True) if hit)


def test_the_momentum_brake_stops_at_the_stopping_point_and_states_the_bound_along_v():
    """At the switch: the target is the jerk-limited stopping point along the velocity
    (the closed form, inside the free distance less the margin), the direction and the
    bound stated are those along the velocity, and ``momentum_brake`` says why."""
    balls, v, a, new = _case(0.9, 2.5, (3.0, 0.9), (0.0, 10.0))
    free = _free_among(balls)
    pos = np.array([0.0, 0.0, ALT_D_M])
    common = dict(
        pos_ned_m=pos,
        vel_ned_mps=(v, 0.0, 0.0),
        setpoint_ned_m=new,
        free_distance=free,
        vehicle_radius_m=RADIUS_M,
        max_path_elevation_rad=ELEV_RAD,
    )
    out = envelope_step(**common, accel_ned_mps2=(a, 0.0, 0.0))
    assert out.momentum_brake and out.limited
    cfg = EnvelopeConfig()
    lim = ReferenceLimits(cfg.accel_mps2, cfg.jerk_mps3, 10.0)
    free_v = free(pos, np.array([1.0, 0.0, 0.0]), RADIUS_M, cfg.lookahead_m, 0, 0, 0)
    stop_m = min(straight_stop_m(v, a, cfg.latency_s, lim), free_v - cfg.margin_m)
    np.testing.assert_allclose(out.setpoint_ned_m, pos + np.array([stop_m, 0.0, 0.0]), atol=1e-12)
    np.testing.assert_allclose(out.brake_target_ned_m, out.setpoint_ned_m, atol=0.0)
    np.testing.assert_allclose(out.path_dir_ned, (1.0, 0.0, 0.0), atol=1e-12)
    assert out.free_distance_m == pytest.approx(free_v, abs=1e-9)
    # the same command straight ahead (within 15° of v and a) is steps 4–5's, not braked
    ahead = envelope_step(
        **{**common, "setpoint_ned_m": (8.0, 0.0, ALT_D_M)}, accel_ned_mps2=(a, 0, 0)
    )
    assert not ahead.momentum_brake


@pytest.mark.parametrize(
    "garbage", [(math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (1.0, 2.0), (1e12, 0.0, 0.0)]
)
def test_a_hostile_acceleration_is_not_believed(garbage):
    """A non-finite or malformed acceleration counts as none; a huge one (velocities of
    frames close together) is believed only up to 2 g, so it neither crashes step 8 nor
    flings its prediction kilometres away."""
    balls, v, _, new = _case(0.9, 2.5, (3.0, 0.9), (0.0, 10.0))
    common = dict(
        pos_ned_m=np.array([0.0, 0.0, ALT_D_M]),
        vel_ned_mps=(v, 0.0, 0.0),
        setpoint_ned_m=new,
        free_distance=_free_among(balls),
        vehicle_radius_m=RADIUS_M,
        max_path_elevation_rad=ELEV_RAD,
    )
    out = envelope_step(**common, accel_ned_mps2=garbage)
    assert np.all(np.isfinite(out.setpoint_ned_m)) and math.isfinite(out.speed_limit_mps)
    if all(math.isfinite(x) for x in garbage) and len(garbage) == 3 and garbage[0] < 1e6:
        return
    capped = (2.0 * 9.81, 0.0, 0.0) if garbage[0] == 1e12 else None
    same = envelope_step(**common, accel_ned_mps2=capped)
    np.testing.assert_array_equal(out.setpoint_ned_m, same.setpoint_ned_m)
    assert out.momentum_brake == same.momentum_brake


@pytest.mark.parametrize(
    ("speed", "accel", "latency"),
    [(0.0, 0.0, 0.15), (1.0, 0.0, 0.15), (2.0, 0.0, 0.3), (0.9, 2.5, 0.15), (1.5, -1.0, 0.1),
     (0.5, -2.5, 0.15), (3.0, 1.0, 0.0)],
)  # fmt: skip
def test_straight_stop_matches_the_integrated_jerk_limited_stop(speed, accel, latency):
    """The closed form against a fine integration of the same stop: ``a₀`` held for
    ``τ``, ramped to ``−A`` at ``j``, held, ramped back to 0 once the speed left is what
    that ramp removes (``A²/(2j)``)."""
    lim = ReferenceLimits(accel_mps2=2.5, jerk_mps3=2.0, speed_mps=10.0)
    A, j, dt = lim.accel_mps2, lim.jerk_mps3, 1e-5
    v, a, d, t, ramp_out = speed, accel, 0.0, 0.0, False
    while v > 0.0 or t < latency:
        if t >= latency:
            ramp_out = ramp_out or (a <= -A and v <= A * A / (2.0 * j))
            a = min(a + j * dt, 0.0) if ramp_out else max(a - j * dt, -A)
        d += v * dt + 0.5 * a * dt * dt
        v += a * dt
        t += dt
        if t > latency and v <= 0.0:
            break
    assert straight_stop_m(speed, accel, latency, lim) == pytest.approx(d, abs=2e-3)


def test_straight_stop_without_jerk_limit_is_the_envelope_stop():
    """``j → ∞`` and ``a₀ = 0``: ``τ·v + v²/(2A)`` (the envelope's step 3)."""
    lim = ReferenceLimits(accel_mps2=2.0, jerk_mps3=1e9, speed_mps=10.0)
    for v in (0.5, 1.0, 3.0):
        expected = 0.15 * v + v * v / 4.0
        assert straight_stop_m(v, 0.0, 0.15, lim) == pytest.approx(expected, rel=1e-6)


def test_predicted_brake_lies_between_the_instant_and_the_jerk_limited_stop():
    """A target at the vehicle: the path's reach along ``v`` is at least the stop at once
    (``τ·v + v²/(2A)``) and at most the jerk-limited closed form."""
    lim = ReferenceLimits(accel_mps2=2.0, jerk_mps3=2.0, speed_mps=10.0)
    for v, a in ((0.5, 0.0), (1.0, 0.0), (2.0, 0.0), (0.9, 2.0), (1.5, 1.0)):
        path = predict_path((0, 0, 0), (v, 0, 0), (a, 0, 0), (0, 0, 0), 0.15, lim)
        reach = float(path[:, 0].max())
        assert 0.15 * v + v * v / 4.0 - 0.02 <= reach <= straight_stop_m(v, a, 0.15, lim)


@pytest.mark.parametrize("distance_m", [0.3, 1.0, 2.0, 5.0])
def test_predicted_path_to_a_target_ahead_ends_on_it(distance_m):
    """From rest the path ends on the target (within 5 cm) and does not pass it by more
    than 5 cm: the square-root speed with its lag taken off stops there."""
    lim = ReferenceLimits(accel_mps2=2.0, jerk_mps3=2.0, speed_mps=10.0)
    path = predict_path(
        (0, 0, 0), (0, 0, 0), (0, 0, 0), (distance_m, 0, 0), 0.15, lim, horizon_s=10.0
    )
    assert path[-1, 0] == pytest.approx(distance_m, abs=0.05)
    assert path[:, 0].max() <= distance_m + 0.05
    np.testing.assert_allclose(path[:, 1:], 0.0, atol=1e-12)


def test_a_momentum_brake_is_said_once_per_episode_and_counted():
    """The operator hears of it once per episode (again after 5 s without one), with the
    speed, the bound along the velocity and guidance's target."""
    from types import SimpleNamespace

    from companion.core.mission import Mission

    mission = Mission([(0.0, 0.0, -7.0)], goal_tolerance_m=0.5)
    said = []
    for k, braked in enumerate([True] * 30 + [False] * 200 + [True]):
        envelope = SimpleNamespace(
            momentum_brake=braked, speed_mps=1.72, speed_limit_mps=0.9, free_distance_m=1.1
        )
        guidance = SimpleNamespace(setpoint_ned_m=np.array([0.0, 10.0, -5.0]))
        out = SimpleNamespace(envelope=envelope, guidance=guidance)
        notices, events = [], []
        mission._report_momentum(out, int(k / 30 * 1e9), notices, events)  # 30 Hz
        said += [
            (k, n.text, e.name, e.fields["speed_mps"]) for n, e in zip(notices, events, strict=True)
        ]
    text = "Braking: way to target not seen free at 1.7 m/s"
    assert said == [(0, text, "momentum_brake", 1.72), (230, text, "momentum_brake", 1.72)]
    assert len(text) <= 50  # one STATUSTEXT


def _ray_excess_m(path, pos, free):
    """The score step 8 used before: each predicted point against the known-free distance
    along the ray from ``pos`` to it (rays that cut the corners of a curved path)."""
    worst = -math.inf
    for q in path:
        d = q - pos
        s = float(np.linalg.norm(d))
        if s >= EnvelopeConfig().min_advance_m:
            worst = max(worst, s - free(pos, d / s, RADIUS_M, 12.0, 0.2, RADIUS_M, 1.05))
    return worst


# A turn away at 1 m/s: an obstacle 3 m ahead, guidance turns east, and a thin post stands
# inside the turn (0.7 m east of the line flown, 1.8 m ahead): the straight line east and
# the path the autopilot flies round the turn (which runs out to ~1.45 m north) both clear
# it, but rays from the vehicle to the path's later points pass through it.
TURN_AWAY = [(np.array([3.0, 0.0, ALT_D_M]), 0.5), (np.array([0.7, 1.8, ALT_D_M]), 0.1)]


def test_a_turn_away_whose_path_stays_free_is_certified_not_braked():
    """Scored by the space the predicted path sweeps, the turn is certified: no brake,
    guidance's target is sent, and flown closed loop it passes outside the vehicle's
    radius of both obstacles; scored by rays from the vehicle (step 8 before) the same
    path would leave free space by metres and brake."""
    free = _free_among(TURN_AWAY)
    pos = np.array([0.0, 0.0, ALT_D_M])
    new = np.array([0.0, 10.0, ALT_D_M])
    cfg = EnvelopeConfig()
    lim = ReferenceLimits(cfg.accel_mps2, cfg.jerk_mps3, 10.0)
    path = predict_path(pos, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0), new, cfg.latency_s, lim)
    assert _ray_excess_m(path, pos, free) > 1.0
    assert envelope_module._excess_m(path, pos, free, RADIUS_M, cfg) <= 0.0
    out = envelope_step(
        pos_ned_m=pos,
        vel_ned_mps=(1.0, 0.0, 0.0),
        accel_ned_mps2=(0.0, 0.0, 0.0),
        setpoint_ned_m=new,
        free_distance=free,
        vehicle_radius_m=RADIUS_M,
        max_path_elevation_rad=ELEV_RAD,
    )
    assert not out.momentum_brake and out.brake_target_ned_m is None
    np.testing.assert_allclose(out.setpoint_ned_m, new, atol=1e-12)
    closest, brakes = _fly_switch(TURN_AWAY, 1.0, 0.0, new)
    assert brakes == 0
    assert closest >= RADIUS_M + 0.1


def _seen_up_to(balls, north_m: float):
    """Known-free distance with everything beyond ``north_m`` north unknown (not yet seen)
    and ``balls`` occupied [m]."""
    among = _free_among(balls)

    def free(pos, unit, radius_m, limit_m, half_height_m, body_m, near_field_m):
        best = among(pos, unit, radius_m, limit_m, half_height_m, body_m, near_field_m)
        if unit[0] > 1e-9:
            best = min(best, max(0.0, (north_m - radius_m - pos[0]) / unit[0]))
        return best

    return free


@pytest.mark.parametrize(
    ("accel_mps2", "seen_north_m"), [(2.5, 12.0), (2.5, 7.0), (0.0, 1.6), (0.0, 1.3)]
)
def test_the_brake_holds_its_stopping_point_inside_space_seen_free(accel_mps2, seen_north_m):
    """The brake of the reproducer's switch (0.9 m/s north accelerating at ``accel_mps2``,
    a post 3 m ahead, 0.9 m east, guidance turning east), flown closed loop with space seen
    free only up to ``seen_north_m`` (each at least the start's own stop, which an
    earlier envelope would have kept; 1.3 m leaves less room than the stop): each
    brake's target is where the jerk-limited stop ends (the closed form) or, when that is
    not seen free, the farthest point along the velocity that is (less the margin; the
    vehicle's position when that is under ``min_advance_m``); it is held (the same point
    frame after frame) until released, lies outside every obstacle by the vehicle's
    radius, and never in unknown space; the vehicle stays outside the collision distance
    and its section short of the unknown (0.1 m: the prediction's accuracy)."""
    balls = [(np.array([3.0, 0.9, ALT_D_M]), 0.4)]
    free = _seen_up_to(balls, seen_north_m)
    cfg = EnvelopeConfig()
    lim = ReferenceLimits(cfg.accel_mps2, cfg.jerk_mps3, 10.0)
    trace: list = []
    closest, brakes = _fly_switch(
        balls, 0.9, accel_mps2, np.array([0.0, 10.0, ALT_D_M]), free=free, trace=trace
    )
    assert brakes > 0 and closest >= RADIUS_M
    held, episodes = None, 0
    for pos, out in trace:
        target = out.brake_target_ned_m
        if target is None:
            held = None
            continue
        if held is not None:
            np.testing.assert_array_equal(target, held)  # held, not re-targeted
            continue
        held, episodes = target, episodes + 1
        vel_dir = out.path_dir_ned  # the velocity's direction while braking
        speed = out.speed_mps
        along = float((target - pos) @ vel_dir)
        np.testing.assert_allclose(target, pos + along * vel_dir, atol=1e-9)
        free_v = free(pos, vel_dir, RADIUS_M, cfg.lookahead_m, 0, 0, 0)
        room = free_v - cfg.margin_m
        # inside space seen free with the margin, or the vehicle's own position
        assert along == 0.0 or cfg.min_advance_m <= along <= room + 1e-9
        assert along <= straight_stop_m(speed, 2.0, out.latency_s, lim) + 1e-9
        for centre, r in balls:
            assert float(np.linalg.norm(target - centre)) >= r + RADIUS_M
    assert episodes >= 1
    # the vehicle never flew into the unknown (beyond what was seen, less its radius)
    flown_north = max(float(pos[0]) for pos, _ in trace)
    assert flown_north <= seen_north_m - RADIUS_M + 0.1


@pytest.mark.parametrize(("speed", "accel"), [(0.6, 0.0), (0.9, 0.0), (1.5, 0.0), (2.0, -1.0)])
def test_the_prediction_comes_to_rest_at_the_closed_form_stopping_point(speed, accel):
    """The brake's target is the closed-form stop (``τ·v`` + the jerk ramps + ``v²/(2A)``);
    the path the autopilot flies to it from the same state ends on it (within 5 cm, the
    prediction's accuracy at a target), so the held target is where the stop ends."""
    cfg = EnvelopeConfig()
    lim = ReferenceLimits(cfg.accel_mps2, cfg.jerk_mps3, 10.0)
    stop_m = straight_stop_m(speed, accel, cfg.latency_s, lim)
    assert stop_m >= cfg.latency_s * speed + speed * speed / (2.0 * cfg.accel_mps2) - 0.02
    path = predict_path(
        (0, 0, 0), (speed, 0, 0), (accel, 0, 0), (stop_m, 0, 0), cfg.latency_s, lim, horizon_s=10
    )
    assert path[-1, 0] == pytest.approx(stop_m, abs=0.05)
    np.testing.assert_allclose(path[:, 1:], 0.0, atol=1e-12)


def test_a_held_brake_stands_until_stopped_replaced_or_no_longer_free():
    """``held_brake_ned_m``: kept while the vehicle moves and the way to it stays seen
    free (also when step 5 would brake at the vehicle); released once the vehicle has
    stopped or a certified carrot is sent; replaced by a new stopping point when
    something is seen in the way or it lies behind the motion; ignored when not three
    finite numbers."""
    balls, v, a, new = _case(0.9, 2.5, (3.0, 0.9), (0.0, 10.0))
    free = _free_among(balls)
    pos = np.array([0.0, 0.0, ALT_D_M])
    held = pos + np.array([1.5, 0.0, 0.0])
    common = dict(
        pos_ned_m=pos,
        setpoint_ned_m=new,
        free_distance=free,
        vehicle_radius_m=RADIUS_M,
        max_path_elevation_rad=ELEV_RAD,
        accel_ned_mps2=(a, 0.0, 0.0),
    )
    kept = envelope_step(**common, vel_ned_mps=(v, 0, 0), held_brake_ned_m=held)
    assert kept.momentum_brake
    np.testing.assert_array_equal(kept.setpoint_ned_m, held)
    np.testing.assert_array_equal(kept.brake_target_ned_m, held)
    # stopped: released; guidance's carrot (certified at rest) is sent
    stopped = envelope_step(
        **{**common, "accel_ned_mps2": None}, vel_ned_mps=(0.05, 0, 0), held_brake_ned_m=held
    )
    assert stopped.brake_target_ned_m is None and not stopped.momentum_brake
    assert stopped.setpoint_ned_m[1] > 1.0
    # a certified carrot (straight ahead along v and a) replaces it
    ahead = envelope_step(
        **{**common, "setpoint_ned_m": (8.0, 0.0, ALT_D_M)},
        vel_ned_mps=(v, 0, 0),
        held_brake_ned_m=held,
    )
    assert ahead.brake_target_ned_m is None and not ahead.momentum_brake
    # something seen in the way: a new stopping point short of it
    blocked = _free_among([*balls, (np.array([1.2, 0.0, ALT_D_M]), 0.2)])
    moved = envelope_step(
        **{**common, "free_distance": blocked}, vel_ned_mps=(v, 0, 0), held_brake_ned_m=held
    )
    assert moved.brake_target_ned_m is not None
    assert not np.array_equal(moved.brake_target_ned_m, held)
    room = blocked(pos, np.array([1.0, 0.0, 0.0]), RADIUS_M, 12.0, 0, 0, 0) - 0.3
    assert float(moved.brake_target_ned_m[0] - pos[0]) <= room + 1e-9
    # left behind the motion (not a brake of it): a new stopping point ahead
    behind = envelope_step(
        **common, vel_ned_mps=(v, 0, 0), held_brake_ned_m=pos - np.array([1.0, 0.0, 0.0])
    )
    assert behind.brake_target_ned_m is not None and behind.brake_target_ned_m[0] > pos[0]
    for garbage in ((math.nan, 0.0, ALT_D_M), (1.0, 2.0), (-1.0, 0.0, ALT_D_M)):
        out = envelope_step(**common, vel_ned_mps=(v, 0, 0), held_brake_ned_m=garbage)
        assert np.all(np.isfinite(out.setpoint_ned_m))
        np.testing.assert_array_equal(
            out.setpoint_ned_m, envelope_step(**common, vel_ned_mps=(v, 0, 0)).setpoint_ned_m
        )


@pytest.mark.parametrize(("seen_north_m", "held"), [(0.6, False), (0.8, True), (1.0, True)])
def test_a_brake_with_no_room_ahead_brakes_at_the_vehicle_and_is_not_held(seen_north_m, held):
    """Space seen free along the velocity ends so near that the stopping point has less
    than ``min_advance_m`` of room: the brake's target is the vehicle's position, not
    held (held, it would pull the vehicle back to where it was as it moves on); with room,
    the point ahead (free distance less the margin) is sent and held."""
    balls = [(np.array([3.0, 0.9, ALT_D_M]), 0.4)]
    free = _seen_up_to(balls, seen_north_m)
    pos = np.array([0.0, 0.0, ALT_D_M])
    out = envelope_step(
        pos_ned_m=pos,
        vel_ned_mps=(0.9, 0.0, 0.0),
        accel_ned_mps2=(2.5, 0.0, 0.0),
        setpoint_ned_m=(0.0, 10.0, ALT_D_M),
        free_distance=free,
        vehicle_radius_m=RADIUS_M,
        max_path_elevation_rad=ELEV_RAD,
    )
    cfg = EnvelopeConfig()
    room = seen_north_m - RADIUS_M - cfg.margin_m
    assert out.momentum_brake
    if held:
        np.testing.assert_allclose(out.setpoint_ned_m, pos + np.array([room, 0, 0]), atol=1e-9)
        np.testing.assert_array_equal(out.brake_target_ned_m, out.setpoint_ned_m)
    else:
        np.testing.assert_array_equal(out.setpoint_ned_m, pos)
        assert out.brake_target_ned_m is None
