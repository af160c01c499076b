"""Step 7b of the safety envelope: a staged vertical move flown straight along the vertical
where that is known free (issue 36 item 2).

Step 7 (:mod:`companion.guidance.envelope`) climbs or descends to a setpoint straight
above or below in stages along the heading at the path limit (12°), where the forward
camera looks. The vertical rate of a stage is the slope times the horizontal speed, and
the horizontal speed toward a carrot re-placed each frame settles at about ``k·c/2``
(ArduCopter's square-root controller less its velocity-loop lag; plant-sim's
``TargetShaper``): vertical-11 (stereo, a 5.8 m descent, traced per frame) descended at
0.10–0.15 m/s for 70 s although the column below had been seen free for 0.7 m (median;
3.2 m at the 90th percentile) from the stages' swing, with the camera's lower edge 33.5°
below the horizon.

:func:`vertical_leg` flies that column instead, while it is the better certified way down
(or up): the known-free distance ``F_z`` straight along the vertical, for the vehicle's
*horizontal disc* (``vehicle_radius_m`` all round: the section normal to a vertical path)
with no near-field excuse (below or above the vehicle is outside every forward camera's
view, so every sample must have been *seen* free, from the side), bounds

* the carrot: ``p + c·ẑ``, ``c = min(|Δz|, F_z − d_stop − margin)`` with ``d_stop = τ·v +
  v²/(2·a_z)`` at the vehicle's speed ``v`` (0 below ``min_advance_m``), and
* the speed: the largest ``v`` with ``τ·v + v²/(2·a_z) + margin ≤ F_z``, the envelope's
  invariant 2 along the vertical, stated to the autopilot as the climb or descent speed
  (``companion.link.speed_limit.climb_limit`` states a path steeper than 45° at the
  envelope's bound) instead of the stage's slope times a slow horizontal speed, floored
  at 0.1 m/s.

``a_z`` is :data:`VERTICAL_ACCEL_MPS2`, the vertical deceleration an autopilot is sure to
achieve. The leg is taken only when it advances farther along the vertical than the stage
would (the stage's carrot ``c_s`` rises or sinks ``c_s·sin e``) by at least
:data:`MIN_GAIN_M`.

Without such a leg, a **steeper stage** along the heading (:data:`STEEPER_STAGES_DEG`, no
steeper than ``asin(a_z/a)``: :func:`steeper_elevations_rad`) replaces the 12° one when
its own known-free distance (the forward section, the near field excused as for any path
the camera looks along) takes the carrot farther along the vertical by the same
:data:`MIN_GAIN_M`; its bound is the envelope's along it. The camera's view reaches 33.5°
below the horizon, so a descent's steeper stage is seen free as it is flown (vertical-11:
known free along 20° down 7.9 m at the median frame, along 30° 1.2 m).

A forward camera never sees above its own +3.5° edge, so a climb's column and steeper
climbs are seldom known free and climbs keep their 12° stages (vertical-107, stereo:
0.3 m, the body, known free straight up and along 30° on 90 % of frames).

Pure: the map is a query function; no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from companion.guidance.envelope_direction import staged

__all__ = [
    "MIN_GAIN_M",
    "STEEPER_STAGES_DEG",
    "VERTICAL_ACCEL_MPS2",
    "VerticalLeg",
    "steeper_elevations_rad",
    "vertical_leg",
    "vertical_step",
]

VERTICAL_ACCEL_MPS2 = 1.0
"""Vertical deceleration the envelope counts on for a vertical leg [m/s²]: ArduCopter's
default ``WPNAV_ACCEL_Z`` (100 cm/s², ``libraries/AC_WPNav/AC_WPNav.cpp``), the lowest of
the autopilots the companion flies (PX4: ``MPC_ACC_DOWN_MAX`` 3, ``MPC_ACC_UP_MAX`` 4)."""

STEEPER_STAGES_DEG = (20.0, 30.0)
"""Stage elevations tried beyond the path limit when no vertical leg is known free [deg]
(:func:`steeper_elevations_rad`): inside the forward camera's view below the horizon
(its lower edge 33.5° down), so a descent's steeper stage is seen free as it is flown."""

MIN_GAIN_M = 0.1
"""A vertical leg replaces the stage only when its carrot advances this much farther
along the vertical [m]: half a voxel, so the choice does not flip on map noise."""

FreeAlong = Callable[[np.ndarray, float], float]
"""``(unit_dir_ned, half_height_m) -> metres`` of known-free travel from the vehicle for
its section (the near field not excused)."""


@dataclass(frozen=True, eq=False)
class VerticalLeg:
    """A vertical leg: the direction ``(0, 0, ±1)``, its known-free distance ``free_m``
    [m], the carrot [m, NED] and the speed bound along it [m/s]."""

    direction: np.ndarray
    free_m: float
    carrot_ned_m: np.ndarray
    limit_mps: float


def vertical_leg(
    pos_ned_m: np.ndarray,
    target_ned_m: np.ndarray,
    speed_mps: float,
    stage_carrot_ned_m: np.ndarray,
    free_along: FreeAlong,
    *,
    vehicle_radius_m: float,
    latency_s: float,
    margin_m: float,
    min_advance_m: float,
    max_speed_mps: float,
) -> VerticalLeg | None:
    """The vertical leg toward ``target_ned_m`` when it advances farther than the stage
    (module docstring), else None.

    Parameters
    ----------
    pos_ned_m, target_ned_m : ndarray, shape (3,)
        Vehicle and guidance's setpoint [m, NED]; the caller has found the move staged.
    speed_mps : float
        The vehicle's speed [m/s].
    stage_carrot_ned_m : ndarray, shape (3,)
        The stage's carrot (step 4 along step 7's direction) [m, NED].
    free_along : callable
        ``(unit_dir_ned, half_height_m) -> metres`` of known-free travel for the vehicle's
        section, near field not excused (:data:`FreeAlong`).
    vehicle_radius_m : float
        Radius of the vehicle's horizontal disc [m].
    latency_s : float
        The latency budget ``τ`` [s].
    margin_m, min_advance_m, max_speed_mps : float
        The envelope's margin [m], least carrot [m] and speed cap [m/s].
    """
    finite = np.all(np.isfinite(target_ned_m)) and np.all(np.isfinite(pos_ned_m))
    dz = float(target_ned_m[2] - pos_ned_m[2])
    if not (finite and abs(dz) > 0.0 and math.isfinite(speed_mps)):
        return None
    direction = np.array([0.0, 0.0, math.copysign(1.0, dz)])
    stage_gain_m = abs(float(stage_carrot_ned_m[2] - pos_ned_m[2]))
    if abs(dz) < stage_gain_m + MIN_GAIN_M:
        return None  # the stage already gets (nearly) level with the target
    free_m = float(free_along(direction, vehicle_radius_m))
    v = max(float(speed_mps), 0.0)
    d_stop = latency_s * v + v * v / (2.0 * VERTICAL_ACCEL_MPS2)
    reach_m = min(abs(dz), free_m - d_stop - margin_m)
    if reach_m < max(min_advance_m, stage_gain_m + MIN_GAIN_M):
        return None
    limit = _speed_bound(free_m, latency_s, VERTICAL_ACCEL_MPS2, margin_m, max_speed_mps)
    carrot = np.asarray(pos_ned_m, dtype=float) + direction * reach_m
    return VerticalLeg(direction, free_m, carrot, limit)


def vertical_step(
    pos, target, speed_mps: float, chosen, free_distance, vehicle_radius_m: float,
    max_elev_rad: float, heading_rad: float | None, tau_s: float, cfg: Any,
):  # fmt: skip
    """Step 7b in the envelope's terms: ``chosen`` = (direction, free, carrot, limited,
    limit) of steps 1–5, returned as it is, or, when the move is staged
    (:func:`~companion.guidance.envelope_direction.staged`), replaced by the vertical leg's
    (:func:`vertical_leg`) or else a steeper stage's (module docstring). ``free_distance``
    is the envelope's map query, ``cfg`` its :class:`~companion.guidance.envelope.
    EnvelopeConfig`."""
    if not staged(target - pos, max_elev_rad, heading_rad, cfg.stage_horizontal_m):
        return chosen

    def free_along(unit: np.ndarray, half_height_m: float) -> float:
        section = (vehicle_radius_m, cfg.lookahead_m, half_height_m, vehicle_radius_m, 0.0)
        return float(free_distance(pos, unit, *section))

    leg = vertical_leg(
        pos, target, speed_mps, chosen[2], free_along, vehicle_radius_m=vehicle_radius_m,
        latency_s=tau_s, margin_m=cfg.margin_m, min_advance_m=cfg.min_advance_m,
        max_speed_mps=cfg.max_speed_mps,
    )  # fmt: skip
    if leg is not None:
        return leg.direction, leg.free_m, leg.carrot_ned_m, True, leg.limit_mps
    return _steeper_stage(pos, target, speed_mps, chosen, free_distance, vehicle_radius_m,
                          heading_rad, tau_s, cfg)  # fmt: skip


def steeper_elevations_rad(accel_mps2: float, max_elev_rad: float) -> tuple[float, ...]:
    """The stage elevations tried beyond the path limit [rad]: :data:`STEEPER_STAGES_DEG`
    no steeper than ``asin(a_z / a)`` (``a`` the envelope's braking deceleration): along
    such a path the vertical part of the stop at ``a_z`` is no longer than the path's stop
    at ``a`` (``(v sin e)²/(2 a_z) ≤ v² sin e/(2 a)``), so the speed bound along the path
    holds for the vertical too (30° at a_z = 1, a = 2 m/s²)."""
    steepest = math.asin(min(1.0, VERTICAL_ACCEL_MPS2 / accel_mps2))
    return tuple(
        e for e in map(math.radians, STEEPER_STAGES_DEG) if max_elev_rad < e <= steepest + 1e-12
    )


def _steeper_stage(pos, target, speed_mps, chosen, free_distance, radius_m, heading, tau, cfg):
    """A stage along the heading steeper than the path limit where its known-free distance
    takes the carrot farther along the vertical (by :data:`MIN_GAIN_M`), else ``chosen``."""
    if not (math.isfinite(speed_mps) and math.isfinite(heading)):
        return chosen
    dz = float(target[2] - pos[2])
    stage_gain = abs(float(chosen[2][2] - pos[2]))
    max_elev = math.asin(min(1.0, abs(float(chosen[0][2]))))
    d_stop = tau * speed_mps + speed_mps * speed_mps / (2.0 * cfg.accel_mps2)
    best, best_gain = chosen, stage_gain + MIN_GAIN_M
    for elev in steeper_elevations_rad(cfg.accel_mps2, max_elev):
        c = math.cos(elev)
        unit = np.array(
            [c * math.cos(heading), c * math.sin(heading), math.copysign(math.sin(elev), dz)]
        )
        section = (radius_m, cfg.lookahead_m, cfg.vehicle_half_height_m, radius_m, cfg.near_field_m)
        free_m = float(free_distance(pos, unit, *section))
        reach = min(abs(dz) / math.sin(elev), free_m - d_stop - cfg.margin_m)
        if reach < cfg.min_advance_m or reach * math.sin(elev) < best_gain:
            continue
        limit = _speed_bound(free_m, tau, cfg.accel_mps2, cfg.margin_m, cfg.max_speed_mps)
        best, best_gain = (unit, free_m, pos + unit * reach, True, limit), reach * math.sin(elev)
    return best


def _speed_bound(free_m, tau_s, accel_mps2, margin_m, max_speed_mps) -> float:
    """``τ·v + v²/(2a) + margin = F`` solved for ``v``, capped [m/s]."""
    room = free_m - margin_m
    if room <= 0.0:
        return 0.0
    v = accel_mps2 * (-tau_s + math.sqrt(tau_s * tau_s + 2.0 * room / accel_mps2))
    return min(v, max_speed_mps)
