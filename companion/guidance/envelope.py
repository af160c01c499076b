"""The safety envelope (DESIGN.md): only into space seen free, never faster than it can stop.

Guidance (the paper's Fig. 5: goal, or Eq. 28's aiming direction) says *where* to go; this
module decides *how far* the position target may lie and *how fast* the vehicle may fly,
from the known-space map (:mod:`companion.known_space`). Pure: the map is passed in as a
query function, there is no clock or I/O.

Per frame, with ``p`` the vehicle position, ``v`` its speed and ``s`` guidance's setpoint:

1. **Path direction.** ``u = (s - p) / |s - p|`` with its elevation clamped to
   ``±max_path_elevation_rad`` (guidance's aiming limit: vertical motion limited to what
   the camera's ±18.5° view covers; the horizontal part is kept). A purely vertical ``u``
   is not clamped: its free distance is what the map says (usually only the vehicle's
   own bubble).
2. **Known-free distance** ``F`` along ``u`` for the vehicle's section
   (``vehicle_radius_m`` wide, the radius perception inflates boundaries by: one vehicle
   size; ``vehicle_half_height_m`` high; ``KnownSpace.free_distance_m``), up to
   ``lookahead_m``. **The near field needs a look** (issue 36): unseen space beside the
   path within ``near_field_m`` is excused only while the camera looks along the path
   (its horizontal bearing within ``look_half_angle_deg`` of the heading). The excuse
   stands for space no forward camera could show from here: whatever reaches into the
   rim there from farther out is in the view and seen. A path off the heading has not
   been looked along: its whole section must be seen free, so the carrot stays where it
   was, and guidance's yaw (step 6) turns the camera first (windy stereo seed 147).
3. **Stopping distance** at the current speed: ``d_stop(v) = τ·v + v²/(2·accel_mps2)``
   (reaction over the frame → command → autopilot latency ``τ``, then constant braking).
   ``τ`` is the measured latency budget passed in (:mod:`companion.guidance.latency`: a
   high percentile of the data ages of recent commands), never below ``latency_s``.
4. **Carrot**: the position target is ``p + c·u`` with
   ``c = min(|s - p|, F - d_stop(v) - margin_m)``, set to 0 below ``min_advance_m``
   (then the target is the vehicle's own position: brake). The autopilot holds the last
   target if the companion dies; flying to it and stopping there stays inside known-free
   space by ``margin_m``.
   Never the far goal when the goal lies beyond what was seen.
5. **Speed limit** stated to the autopilot: the largest ``v`` with
   ``τ·v + v²/(2·accel_mps2) + margin_m ≤ F``, i.e.
   ``v = a·(−τ + √(τ² + 2(F − margin)/a))``, capped at ``max_speed_mps``; ``overspeed``
   is raised when the measured speed exceeds it by ``overspeed_tolerance_mps``.
   **Braking** (issue 36): when the vehicle is faster than the limit along ``u`` (guidance
   turned onto a path with less free space, a hold was entered at speed, or the space ahead
   shrank), the carrot is the vehicle's own position (step 4 gives ``c = 0``) and the bound
   stated is the one along the *velocity*, the way the vehicle actually moves while it
   brakes: the known-free distance ``F_v`` along ``v/|v|`` and its limit, so the stated
   speed is the flown speed. When ``F_v`` itself shrank below the stopping distance
   (something new ahead), the limit is below the speed and ``overspeed`` reports it. A
   climb steeper than the path only by the least climb speed the companion states is
   measured at the path's elevation (:func:`~companion.guidance.envelope_direction.
   brake_direction`: the slack's rise over a stop stays inside the section's height).
   The bound stated while braking keeps no margin (the brake's reserve): a drop of ``F_v``
   to the body's own bubble (a staged climb entering the unseen voxel layer above,
   vertical-123) states the fastest speed whose stop still ends in space seen free; only
   a stop that no longer fits there (something new nearer) reads as overspeed.
7. **Vertical moves in stages** (issue 36): a setpoint steeper than
   ``max_path_elevation_rad`` whose horizontal distance is below ``stage_horizontal_m``
   (a goal straight above or below) is climbed to, or descended to, along the vehicle's
   heading at the path limit, where the camera looks, so each stage is certified like any
   other path and ends inside space seen free; a stage is never longer than ``|s − p|``,
   so it climbs less than ``|s − p| · sin e < |Δz|`` and never passes the setpoint's
   altitude; then a short level move (no heading: ``s − p``'s horizontal part). **7b**:
   straight along the vertical where known free farther (:mod:`~.vertical_leg`).
6. **Look before moving**: the yaw guidance commands faces ``u`` (not the carrot, which
   may be at the vehicle), so a vehicle that must travel where it has not looked turns
   first; the carrot grows only as the view fills the map with free space.
8. **Momentum** (issue 36): steps 4–5 certify the straight line to the carrot, but an
   autopilot whose reference is jerk-limited (ArduCopter's ``shape_pos_vel_accel``) keeps
   its present acceleration after a target switch and ramps it round, carrying the
   vehicle on the way it was going. When the carrot lies more than 15° off the velocity
   (≥ 0.1 m/s) or the acceleration (≥ 1 m/s²), the path the autopilot flies to it from
   ``(p, v, a)`` is predicted (:mod:`companion.guidance.autopilot_path`, ``accel_mps2``
   and ``jerk_mps3``, the acceleration held over ``τ``) and the space it sweeps must be
   known free: each leg ``q_i → q_{i+1}`` of it within the known-free distance of the
   vehicle's section (widened by the prediction's 0.1 m) from ``q_i`` along the leg, 0.1 m
   of tolerance, the rim allowed in unseen space outside every obstacle's extent within
   ``near_field_m`` of each leg's start as in step 2 (a score that follows the path, so
   a turn away round an obstacle is judged by where it goes, not by rays from ``p`` that
   cut its corners). If not, and the brake's own predicted path leaves that space by
   less, the vehicle brakes to its
   **stopping point**: where the jerk-limited stop from ``(p, v, a)`` along ``v`` ends
   (:func:`~companion.guidance.autopilot_path.straight_stop_m`, ArduCopter's own brake
   target), no farther than the known-free distance along ``v`` less ``margin_m`` (the
   vehicle's position when that leaves less than ``min_advance_m``). The target is
   *held* (``brake_target_ned_m``, passed back as ``held_brake_ned_m``), also through
   frames where step 5 would brake, until the vehicle has stopped (< 0.1 m/s), a
   certified carrot replaces it, or the way to it is no longer known free (then a new
   stopping point): re-targeting a brake at a moving vehicle each frame does not stop
   a laggy airframe. The bound stated is the one along ``v`` (as in step 5's braking)
   and ``momentum_brake`` reports it (the core counts it and tells the operator). When
   braking would carry it farther out (a velocity toward less free space than the turn),
   the carrot stands. The cases that found it: docs/safety-envelope.md.
9. **The room along the velocity** (issue 36 item 5): moving at ≥ 0.1 m/s, the stop must
   also fit ``F_v``. When steps 5 and 8 did not brake and ``d_stop + margin > F_v`` (a
   velocity swung off the path toward space little seen free), the frame brakes as step
   5 does (:mod:`companion.guidance.velocity_bound`); ``F_v`` is measured once a frame.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from companion.guidance.autopilot_path import ReferenceLimits, predict_path, straight_stop_m
from companion.guidance.envelope_direction import brake_direction, looked_along, path_direction
from companion.guidance.velocity_bound import MIN_SPEED_MPS, stop_fits, velocity_room_m
from companion.guidance.vertical_leg import vertical_step
from protocols.config import Checked, bounded, dataclass_from_mapping

__all__ = [
    "EnvelopeConfig",
    "EnvelopeOutput",
    "envelope_step",
    "speed_limit_mps",
    "stopping_distance_m",
]

FreeDistanceFn = Callable[..., float]
"""``(pos_ned_m, unit_dir_ned, radius_m, limit_m, half_height_m, body_m, near_field_m)``
→ known-free metres (:meth:`companion.known_space.KnownSpace.free_distance_m`, with the
pipeline's obstacle extents bound: :func:`companion.guidance.map_boundaries.solid_extent`)."""


_BRAKE_MIN_SPEED_MPS = MIN_SPEED_MPS  # below: no direction of motion to state a bound for
# Step 8 (momentum): a carrot more than this angle off the velocity (at or above this speed)
# or the acceleration (at or above this) is certified along the path flown to it, not only straight.
_MOMENTUM_MIN_SPEED_MPS = 0.1
_MOMENTUM_MIN_ACCEL_MPS2 = 1.0
_MOMENTUM_COS = math.cos(math.radians(15.0))
# not braked for when leaving known-free space by less: twice the prediction's accuracy [m]
_MOMENTUM_TOLERANCE_M = 0.1
_LEG_SLACK_M = 0.2  # a leg is queried this far past its end (the map answers in half voxels) [m]
# a held brake target this far behind the motion is not its stop (overshoot ≤ ~0.4 m) [m]
_BRAKE_PASSED_M = 0.5
# the largest acceleration step 8 believes [m/s²]: 2 g, beyond any multirotor's reference
_MOMENTUM_MAX_ACCEL_MPS2 = 19.62


@dataclass(frozen=True)
class EnvelopeConfig(Checked):
    """Parameters of the safety envelope (named assumptions, SI units).

    Attributes
    ----------
    latency_s : float
        Capture → command acting on the vehicle [s]: a frame period (33 ms), perception
        and link (≤ 15 ms p99) and the autopilot's reaction, rounded up. The *floor* of the
        latency budget: the companion measures the data age of its commands and budgets
        more when they are older (:mod:`companion.guidance.latency`).
    latency_window_s : float
        Data ages of the frames captured this long before the newest are forgotten [s,
        frame clock], (0, 60].
    latency_percentile : float
        The percentile of the window's data ages that is budgeted, [50, 100].
    unmeasured_latency_s : float
        Latency the data age does not contain, added to it [s], [0, 1]: the autopilot's
        reaction after a setpoint arrives and up to a frame period (0.1: the floor 0.15 s
        less the ≤ 50 ms age of an idle companion).
    accel_mps2 : float
        Braking deceleration the autopilot achieves [m/s²]. 2.0: below the paper
        vehicle's g·tan 15° = 2.63 and ArduCopter's default WPNAV_ACCEL 2.5 m/s².
    margin_m : float
        Distance kept from the edge of known-free space after stopping [m].
    vehicle_half_height_m : float
        Half-height of the section swept through known-free space [m] (body, propellers
        and a few centimetres of height-hold error). The forward camera's ±18.5° view
        covers it 0.6 m ahead.
    near_field_m : float
        Within this distance ahead the section's rim may lie in unseen (never occupied)
        space outside every obstacle's extent: the left eye (0.1 m left of the centre)
        sees 0.35 m to the right only from (0.35 + 0.1) / tan 24° = 1.0 m ahead (see
        :mod:`companion.known_space`) [m].
    min_advance_m : float
        A carrot nearer than this is not sent: the target is the vehicle's position
        (brake) [m]. Keeps the vehicle from creeping into unseen space by the width of
        its own free bubble, one frame at a time.
    max_speed_mps : float
        Speed limit cap [m/s].
    lookahead_m : float
        Longest free-distance query [m] (the map's range is 8 m).
    overspeed_tolerance_mps : float
        Measured speed above the limit by more than this raises ``overspeed`` [m/s].
    stage_horizontal_m : float
        A setpoint steeper than the path limit and nearer than this horizontally is
        climbed to (or descended to) along the vehicle's heading (step 7) [m].
    look_half_angle_deg : float
        The near-field excuse holds only for a path whose horizontal bearing lies within
        this angle of the heading [deg] (step 2): half the paper camera's 48° HFOV, the
        path's own line in the view.
    jerk_mps3 : float
        Jerk limit of the autopilot's shaped reference [m/s³] (step 8). 2.0: below
        ArduCopter's PSC_JERK_XY (5 m/s³) and PX4's MPC_JERK_AUTO (4 m/s³) defaults and
        the jerk plant-sim's airframes follow (``airframe_jerk_mps3``); a lower jerk
        predicts longer stops, so the default errs on the safe side.
    """

    latency_s: float = bounded(0.15, "s", ge=0)
    latency_window_s: float = bounded(2.5, "s", gt=0, le=60)
    latency_percentile: float = bounded(95.0, "%", ge=50, le=100)
    unmeasured_latency_s: float = bounded(0.1, "s", ge=0, le=1)
    accel_mps2: float = bounded(2.0, "m/s²", gt=0)
    margin_m: float = bounded(0.3, "m", ge=0)
    vehicle_half_height_m: float = bounded(0.2, "m", ge=0)
    near_field_m: float = bounded(1.05, "m", ge=0)
    min_advance_m: float = bounded(0.15, "m", ge=0)
    max_speed_mps: float = bounded(10.0, "m/s", ge=0)
    lookahead_m: float = bounded(12.0, "m", ge=0)
    overspeed_tolerance_mps: float = bounded(0.3, "m/s", ge=0)
    stage_horizontal_m: float = bounded(1.0, "m", ge=0)
    jerk_mps3: float = bounded(2.0, "m/s³", gt=0)
    look_half_angle_deg: float = bounded(24.0, "deg", ge=0, le=180)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> EnvelopeConfig:
        """Build from a mapping; unknown keys raise ``TypeError`` naming them."""
        return dataclass_from_mapping(cls, values, "envelope")


@dataclass(frozen=True, eq=False)
class EnvelopeOutput:
    """The command after the envelope.

    Attributes
    ----------
    setpoint_ned_m : ndarray, shape (3,)
        Position target actually sent [m, NED] (the carrot), read-only.
    path_dir_ned : ndarray, shape (3,)
        Unit direction of travel after the elevation clamp (zero when none).
    free_distance_m : float
        Known-free distance along it for the vehicle's disc [m].
    stopping_distance_m : float
        ``d_stop`` at the measured speed [m].
    speed_limit_mps : float
        The speed bound for ``free_distance_m`` [m/s].
    speed_mps : float
        Measured speed [m/s].
    limited : bool
        The carrot is nearer than guidance's setpoint (what lies beyond was not seen free).
    overspeed : bool
        Measured speed above the limit (plus tolerance).
    latency_s : float
        The latency ``τ`` budgeted in the stopping rule [s] (the measured budget, at
        least ``EnvelopeConfig.latency_s``).
    momentum_brake : bool
        Step 8 braked: the path the autopilot would fly from the present state to the
        carrot was not seen free, so the target is the brake's.
    brake_target_ned_m : ndarray, shape (3,) or None
        While step 8's brake holds (at speed): the stopping point sent [m, NED],
        read-only, to be passed back as ``held_brake_ned_m`` with the next frame; None
        otherwise.
    velocity_free_m : float
        Step 9: the known-free distance along the velocity [m]; ``inf`` below 0.1 m/s.
    """

    setpoint_ned_m: np.ndarray
    path_dir_ned: np.ndarray
    free_distance_m: float
    stopping_distance_m: float
    speed_limit_mps: float
    speed_mps: float
    limited: bool
    overspeed: bool
    latency_s: float = 0.15
    momentum_brake: bool = False
    brake_target_ned_m: np.ndarray | None = None
    velocity_free_m: float = math.inf


def stopping_distance_m(speed_mps: float, latency_s: float, accel_mps2: float) -> float:
    """Distance to stop from ``speed_mps``: ``τ·v + v²/(2a)`` [m]."""
    v = max(float(speed_mps), 0.0)
    return latency_s * v + v * v / (2.0 * accel_mps2)


def speed_limit_mps(free_m: float, latency_s: float, accel_mps2: float, margin_m: float) -> float:
    """Largest speed whose stopping distance plus ``margin_m`` fits in ``free_m`` [m/s].

    Solves ``τ·v + v²/(2a) + margin = F`` for ``v ≥ 0``: ``v = a(−τ + √(τ² + 2(F−m)/a))``;
    0 when ``F ≤ margin``.
    """
    room = float(free_m) - margin_m
    if room <= 0.0:
        return 0.0
    a = accel_mps2
    return a * (-latency_s + math.sqrt(latency_s * latency_s + 2.0 * room / a))


def _budget_s(cfg: EnvelopeConfig, latency_s: float | None) -> float:
    """The latency budget passed in, never below ``cfg.latency_s`` (nor NaN) [s]."""
    if latency_s is not None and math.isfinite(latency_s) and latency_s > cfg.latency_s:
        return float(latency_s)
    return cfg.latency_s


def _free_m(
    free_distance: FreeDistanceFn, pos, unit, vehicle_radius_m: float, cfg, looked: bool = True
) -> float:
    """Known-free distance along ``unit`` for the vehicle's section [m]; the near field's
    unseen rim excused only when ``looked`` (step 2)."""
    section = (vehicle_radius_m, cfg.lookahead_m, cfg.vehicle_half_height_m)
    near_field_m = cfg.near_field_m if looked else 0.0
    return float(free_distance(pos, unit, *section, vehicle_radius_m, near_field_m))


def _carrot(pos, target, direction, room_m: float, cfg) -> tuple[np.ndarray, bool]:
    """Step 4: the carrot along ``direction`` with ``room_m`` of known-free space left
    after stopping, and whether it falls short of ``target``."""
    to_setpoint = target - pos
    dist = math.sqrt(float(to_setpoint @ to_setpoint))
    reach = min(dist, max(0.0, room_m))
    if reach < min(cfg.min_advance_m, dist):
        reach = 0.0
    clamped = not np.allclose(direction * dist, to_setpoint, atol=1e-9)
    limited = clamped or reach < dist - 1e-9
    return (pos + direction * reach if limited else target.copy()), limited


def _limit_mps(free_m: float, tau_s: float, cfg: EnvelopeConfig) -> float:
    """The speed bound for ``free_m`` of known-free space, capped [m/s]."""
    return min(speed_limit_mps(free_m, tau_s, cfg.accel_mps2, cfg.margin_m), cfg.max_speed_mps)


def _brake_limit_mps(free_m: float, tau_s: float, cfg: EnvelopeConfig) -> float:
    """The bound stated while braking (steps 5, 8, 9): no margin (the brake's reserve) [m/s]."""
    return min(speed_limit_mps(free_m, tau_s, cfg.accel_mps2, 0.0), cfg.max_speed_mps)


def _path_and_carrot(pos, target, motion, free_distance, radius_m, max_elev_rad, heading, cfg):
    """Steps 1, 2, 4, 7 and 7b for ``motion`` = (speed, τ, d_stop): the path direction, its
    known-free distance, the carrot, whether it is short of ``target``, the speed bound."""
    speed, tau, d_stop = motion
    to_setpoint = target - pos
    if float(to_setpoint @ to_setpoint) < 1e-12:
        return np.zeros(3), 0.0, target.copy(), False, _limit_mps(0.0, tau, cfg)
    direction = path_direction(to_setpoint, max_elev_rad, heading, cfg.stage_horizontal_m)
    looked = looked_along(direction, heading, cfg.look_half_angle_deg)
    free = _free_m(free_distance, pos, direction, radius_m, cfg, looked)
    carrot, limited = _carrot(pos, target, direction, free - d_stop - cfg.margin_m, cfg)
    chosen = (direction, free, carrot, limited, _limit_mps(free, tau, cfg))
    return vertical_step(
        pos, target, speed, chosen, free_distance, radius_m, max_elev_rad, heading, tau, cfg
    )


def _along(x: np.ndarray, to_carrot: np.ndarray, reach_m: float, floor: float) -> bool:
    """``x`` (a velocity or an acceleration) is below ``floor`` or within
    ``_MOMENTUM_COS`` of the direction to the carrot."""
    size = math.sqrt(float(x @ x))
    return size < floor or float(x @ to_carrot) >= _MOMENTUM_COS * size * reach_m


def _momentum_clear(
    pos, vel, acc, carrot, free_distance, tau_s, limit_mps, cfg, vehicle_radius_m, brake_target
) -> bool:
    """Step 8: whether to send ``carrot`` rather than brake. True when the path the
    autopilot flies from ``(pos, vel, acc)`` to it stays inside known-free space (its
    swept section, :func:`_excess_m`), or when the brake (``brake_target()``, the held or
    predicted stopping point) would leave that space by more. Only a carrot off the
    velocity or the acceleration is predicted: one ahead along both (or a target at the
    vehicle) is covered by steps 4–5."""
    to_carrot = carrot - pos
    reach = math.sqrt(float(to_carrot @ to_carrot))
    if reach < 1e-6:
        return True
    if all(
        _along(x, to_carrot, reach, floor)
        for x, floor in ((vel, _MOMENTUM_MIN_SPEED_MPS), (acc, _MOMENTUM_MIN_ACCEL_MPS2))
    ):
        return True
    limits = _reference_limits(vel, limit_mps, cfg)

    def excess(target) -> float:
        path = predict_path(pos, vel, acc, target, tau_s, limits)
        return _excess_m(path, pos, free_distance, vehicle_radius_m, cfg)

    to_carrot_excess = excess(carrot)
    return to_carrot_excess <= _MOMENTUM_TOLERANCE_M or excess(brake_target()) >= to_carrot_excess


def _reference_limits(vel, limit_mps: float, cfg: EnvelopeConfig) -> ReferenceLimits:
    """The autopilot's reference bounds as the envelope assumes them (its speed limit the
    one stated, or the present speed when that is higher)."""
    speed = math.sqrt(float(vel @ vel))
    return ReferenceLimits(cfg.accel_mps2, cfg.jerk_mps3, max(limit_mps, speed, 0.1))


def _stopping_point(pos, vel, acc, free_distance, tau_s, cfg, vehicle_radius_m) -> np.ndarray:
    """The brake's target [m, NED]: where the autopilot's own stop from ``(p, v, a)``
    comes to rest along ``v`` (:func:`~companion.guidance.autopilot_path.straight_stop_m`:
    ``a``'s part along ``v`` held over ``τ``, then the jerk-limited ramp to the braking
    deceleration), but no farther than the known-free distance along ``v`` less
    ``margin_m``; the vehicle's position when that leaves less than ``min_advance_m``
    (or it is not moving). ArduCopter brakes the same way, to a stopping point
    (``AC_PosControl::get_stopping_point_xy_cm``), not to where it is."""
    speed = math.sqrt(float(vel @ vel))
    if speed < _BRAKE_MIN_SPEED_MPS:
        return pos.copy()
    unit = vel / speed
    limits = _reference_limits(vel, 0.0, cfg)
    reach = straight_stop_m(speed, float(acc @ unit), tau_s, limits)
    room = _free_m(free_distance, pos, unit, vehicle_radius_m, cfg) - cfg.margin_m
    reach = min(reach, room)
    return pos + unit * reach if reach >= cfg.min_advance_m else pos.copy()


def _held_brake(held_ned_m, pos, vel, free_distance, cfg, vehicle_radius_m):
    """The brake target held from the last frame while it still stands [m, NED], or None:
    released once the vehicle has stopped (below ``_BRAKE_MIN_SPEED_MPS``), and dropped
    when it is not three finite numbers, lies more than ``_BRAKE_PASSED_M`` behind the
    vehicle's motion, or the straight way to it is no longer known free with
    ``margin_m`` to spare (within the prediction's tolerance)."""
    speed_mps = math.sqrt(float(vel @ vel))
    if held_ned_m is None or speed_mps < _BRAKE_MIN_SPEED_MPS:
        return None
    held = np.asarray(held_ned_m, dtype=float).reshape(-1)
    if held.shape != (3,) or not np.all(np.isfinite(held)):
        return None
    to_held = held - pos
    if float(to_held @ vel) < -_BRAKE_PASSED_M * speed_mps:
        return None  # left behind (not a brake of this motion): a new stopping point
    dist = math.sqrt(float(to_held @ to_held))
    if dist < cfg.min_advance_m:
        return held.copy()
    room = _free_m(free_distance, pos, to_held / dist, vehicle_radius_m, cfg) - cfg.margin_m
    return held.copy() if dist <= room + _MOMENTUM_TOLERANCE_M else None


def _measured_accel(accel_ned_mps2) -> np.ndarray:
    """Step 8's acceleration [m/s², NED]: zero when none is known or it is not three
    finite numbers; its size at most ``_MOMENTUM_MAX_ACCEL_MPS2`` (a velocity difference
    over frames close together is noisy, and the prediction holds it over the latency)."""
    if accel_ned_mps2 is None:
        return np.zeros(3)
    acc = np.asarray(accel_ned_mps2, dtype=float).reshape(-1)
    if acc.shape != (3,) or not np.all(np.isfinite(acc)):
        return np.zeros(3)
    size = math.sqrt(float(acc @ acc))
    return acc * (_MOMENTUM_MAX_ACCEL_MPS2 / size) if size > _MOMENTUM_MAX_ACCEL_MPS2 else acc


def _excess_m(path, pos, free_distance, vehicle_radius_m, cfg) -> float:
    """How far the path leaves known-free space, following the path itself: each leg
    ``q_i → q_{i+1}`` (from ``pos``) against the known-free distance of the vehicle's
    section (widened by the prediction's accuracy) from ``q_i`` along the leg, so a path
    that curves round an obstacle is judged by the space it sweeps, not by rays from
    ``pos`` that cut its corners. Each leg's centre must lie in FREE voxels (beyond the
    body allowance at ``pos``), and its rim too except within ``near_field_m`` of the
    leg's start, where unseen space outside every obstacle's extent is allowed — the
    allowance the straight check gives its first metre (the camera never sees the
    section's rim that near; a turn's legs run beside the view). The margin is kept by
    where it stops, the carrot. ≤ 0 when every leg lies inside [m]."""
    worst = -math.inf
    start = np.asarray(pos, dtype=float)
    # the section widened by the prediction's accuracy: the path is not flown exactly
    radius = vehicle_radius_m + _MOMENTUM_TOLERANCE_M
    for q in path:
        leg = q - start
        length = math.sqrt(float(leg @ leg))
        if length < 1e-6:
            continue
        body = max(0.0, vehicle_radius_m - math.dist(start, pos))
        limit = min(length + _LEG_SLACK_M, cfg.lookahead_m)
        free = float(
            free_distance(
                start, leg / length, radius, limit, cfg.vehicle_half_height_m, body,
                cfg.near_field_m,
            )
        )  # fmt: skip
        worst = max(worst, length - free)
        start = q
    return worst


def _brake_steps(
    pos, vel, chosen, free_distance, tau, cfg, vehicle_radius_m, accel, held_brake, along_v
):
    """Steps 5 and 8 on ``chosen`` = (carrot, limited, direction, free, limit): brake when
    too fast for the path's free space (5) or when the autopilot's way to the carrot is
    not seen free (8); ``along_v`` = (path elevation limit, ``F_v`` measured along
    :func:`brake_direction`). Returns them as sent, whether step 8 braked, and the brake
    target to hold next frame (None when there is none, or it is at the vehicle)."""
    carrot, limited, direction, free, limit = chosen
    speed = math.sqrt(float(vel @ vel))
    acc = _measured_accel(accel)
    held = _held_brake(held_brake, pos, vel, free_distance, cfg, vehicle_radius_m)

    @functools.cache
    def brake_target() -> np.ndarray:
        if held is not None:
            return held
        return _stopping_point(pos, vel, acc, free_distance, tau, cfg, vehicle_radius_m)

    momentum = speed <= limit and not _momentum_clear(
        pos, vel, acc, carrot, free_distance, tau, limit, cfg, vehicle_radius_m, brake_target
    )
    brake = None
    if (speed > limit or momentum) and speed >= _BRAKE_MIN_SPEED_MPS:
        # Too fast for the path (or its free space shrank, or the way to the carrot is
        # not seen free): brake, the bound stated for the way the vehicle moves. Step 8's
        # brake holds the stopping point (also through step 5's frames) until the vehicle
        # stopped or a certified carrot replaces it; step 5's alone targets the vehicle.
        if momentum or held is not None:
            brake = brake_target()
            carrot, limited = brake.copy(), True
        max_elev_rad, free = along_v  # F_v: measured along brake_direction at this speed
        direction = brake_direction(vel, max_elev_rad)
        limit = _brake_limit_mps(free, tau, cfg)
    elif momentum:
        carrot, limited = pos.copy(), True
    if brake is not None:
        brake.setflags(write=False)
    # a stopping point at the vehicle (no room ahead) is not held: held, it would pull the
    # vehicle back while it moves on (a climb along an unseen vertical velocity); re-taken
    # at the vehicle each frame, it brakes as step 5 does
    hold = brake is not None and math.dist(brake, pos) >= cfg.min_advance_m
    return carrot, limited, direction, free, limit, momentum, brake if hold else None


def envelope_step(
    *,
    pos_ned_m,
    vel_ned_mps,
    setpoint_ned_m,
    free_distance: FreeDistanceFn,
    vehicle_radius_m: float,
    max_path_elevation_rad: float,
    config: EnvelopeConfig | None = None,
    latency_s: float | None = None,
    heading_rad: float | None = None,
    accel_ned_mps2=None,
    held_brake_ned_m=None,
) -> EnvelopeOutput:
    """Bound guidance's setpoint by known-free space and the stopping distance.

    Parameters
    ----------
    pos_ned_m, vel_ned_mps : array_like, shape (3,)
        Vehicle position [m] and velocity [m/s] at the frame's capture time, NED.
    setpoint_ned_m : array_like, shape (3,)
        Guidance's position setpoint [m, NED] (goal, aiming-direction point or hold).
    free_distance : callable
        ``(pos, unit_dir, radius_m, limit_m) -> metres`` of known-free travel, e.g.
        :meth:`companion.known_space.KnownSpace.free_distance_m`.
    vehicle_radius_m : float
        Half-width of the section swept through known-free space [m] (``PerceptionConfig``'s).
    max_path_elevation_rad : float
        Steepest climb or descent of the path [rad]: guidance's aiming-elevation limit
        (``GuidanceConfig.max_aim_elevation_rad``, inside the camera's vertical view).
    config : EnvelopeConfig, optional
    latency_s : float, optional
        The latency budget ``τ`` [s] (:meth:`~companion.guidance.latency.DataAgeWindow.
        budget_s`); never below ``config.latency_s`` (used when None or not finite).
    heading_rad : float, optional
        The vehicle's heading [rad] (step 7's stages climb along it).
    accel_ned_mps2 : array_like, shape (3,), optional
        The vehicle's acceleration [m/s², NED] for step 8's prediction; zero when None.
    held_brake_ned_m : array_like, shape (3,), optional
        The last frame's ``brake_target_ned_m``: a brake keeps it as its target while the
        vehicle moves and the way to it stays known free (step 8).
    """
    cfg = EnvelopeConfig() if config is None else config
    pos, vel = np.asarray(pos_ned_m, dtype=float), np.asarray(vel_ned_mps, dtype=float)
    target = np.asarray(setpoint_ned_m, dtype=float)
    speed = math.sqrt(float(vel @ vel))
    tau = _budget_s(cfg, latency_s)
    d_stop = stopping_distance_m(speed, tau, cfg.accel_mps2)
    free_v = velocity_room_m(
        vel, max_path_elevation_rad,
        lambda unit: _free_m(free_distance, pos, unit, vehicle_radius_m, cfg))  # fmt: skip
    direction, free, carrot, limited, limit = _path_and_carrot(
        pos, target, (speed, tau, d_stop), free_distance, vehicle_radius_m,
        max_path_elevation_rad, heading_rad, cfg)  # fmt: skip
    braked = speed > limit
    carrot, limited, direction, free, limit, momentum, brake = _brake_steps(
        pos, vel, (carrot, limited, direction, free, limit), free_distance, tau, cfg,
        vehicle_radius_m, accel_ned_mps2, held_brake_ned_m,
        (max_path_elevation_rad, free_v))  # fmt: skip
    if not (braked or momentum) and not stop_fits(d_stop, cfg.margin_m, free_v):  # step 9
        carrot, limited, free = pos.copy(), True, free_v
        direction = brake_direction(vel, max_path_elevation_rad)
        limit = _brake_limit_mps(free_v, tau, cfg)
    carrot.setflags(write=False)
    direction.setflags(write=False)
    return EnvelopeOutput(
        setpoint_ned_m=carrot,
        path_dir_ned=direction,
        free_distance_m=free,
        stopping_distance_m=d_stop,
        speed_limit_mps=limit,
        speed_mps=speed,
        limited=limited,
        overspeed=speed > limit + cfg.overspeed_tolerance_mps,
        latency_s=tau,
        momentum_brake=momentum,
        brake_target_ned_m=brake,
        velocity_free_m=free_v,
    )
