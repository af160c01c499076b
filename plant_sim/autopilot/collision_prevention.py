"""PX4's Collision Prevention in Position mode, on the pilot's velocity setpoint.

Pure: the pilot's desired horizontal velocity, the vehicle's yaw and the 72 body-frame
bins of :meth:`plant_sim.autopilot.proximity.ProximityReceiver.px4_bins` in, the
constrained velocity out. Follows ``src/lib/collision_prevention/CollisionPrevention.cpp``
(``_calculateConstrainedSetpoint``, ``_checkSetpointDirectionFeasability``,
``_adaptSetpointDirection``, ``_getVelocityCompensationAcceleration``) and
``math::trajectory::computeMaxSpeedFromDistance``. What is implemented:

* Active when ``CP_DIST > 0``. The distance kept is ``max(CP_DIST, min_distance)``.
* **No data at all** (every bin without data, or the stream older than 0.5 s): no
  horizontal movement ("No obstacle data, not moving...").
* **Direction without data**: a setpoint pointing into a bin without data is refused
  (zero) unless ``CP_GO_NO_DATA = 1`` — and even then not into a bin that has had data
  before (``_data_fov[i]``, set in ``_addObstacleSensorData`` when a bin takes a reading
  that is not ``UINT16_MAX`` and never cleared; ``_checkSetpointDirectionFeasibility``):
  with ``CP_GO_NO_DATA = 1`` PX4 flies into directions the companion has never reported
  (a textureless wall from the start), not into ones it reported and then lost.
* **Guidance**: the setpoint's direction may turn by up to ``CP_GUIDE_ANG`` toward the
  bin of least cost (deviation cost ``CP_DIST · 50 · |Δbin|`` [cm] minus the mean of
  the bin and its neighbours and the bin's own distance; unknown bins never chosen,
  counted as ``CP_DIST`` in the mean).
* **Speed per bin with data**: the component of the velocity toward the bin is at most
  ``computeMaxSpeedFromDistance(MPC_JERK_MAX, MPC_ACC_HOR, d − CP_DIST − v·(CP_DELAY +
  age), 0)``, ``age`` the data's age when the obstacle is within the sensor's range.

Difference from PX4 (named): PX4 ≥ 1.15 constrains the *acceleration* setpoint of its
acceleration-based Position mode (``MPC_POS_MODE 4``), turning the speed bound into an
acceleration ``MPC_XY_VEL_P_ACC · (v_max − v)``; plant-sim's Position mode is velocity
based, so the same bound limits the velocity setpoint directly (PX4's older
``modifySetpoint(Vector2f &original_setpoint, …)`` did the same).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plant_sim.autopilot.params import ParamSpec, ParamTable, ParamType
from plant_sim.autopilot.proximity import PX4_BINS
from protocols.config import Checked, bounded

__all__ = [
    "CP_PARAM_SPECS",
    "CpParams",
    "constrain_velocity",
    "cp_params",
    "max_speed_from_distance",
]

_BIN_DEG = 360.0 / PX4_BINS

#: PX4's Collision Prevention and manual-position parameters (collisionprevention_params.yaml,
#: mc_pos_control_params.c: names, units, defaults, ranges).
CP_PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("CP_DIST", ParamType.REAL32, -1.0, -1.0, 15.0),  # m, < 0: disabled
    ParamSpec("CP_DELAY", ParamType.REAL32, 0.4, 0.0, 1.0),  # s
    ParamSpec("CP_GUIDE_ANG", ParamType.REAL32, 30.0, 0.0, 90.0),  # deg
    ParamSpec("CP_GO_NO_DATA", ParamType.INT32, 0, 0, 1),  # bool
    ParamSpec("MPC_VEL_MANUAL", ParamType.REAL32, 10.0, 3.0, 20.0),  # m/s
    ParamSpec("MPC_ACC_HOR", ParamType.REAL32, 3.0, 2.0, 15.0),  # m/s²
    ParamSpec("MPC_JERK_MAX", ParamType.REAL32, 8.0, 0.5, 500.0),  # m/s³
)


@dataclass(frozen=True)
class CpParams(Checked):
    """:data:`CP_PARAM_SPECS` in SI units."""

    dist_m: float = bounded(-1.0, "m")  # CP_DIST; <= 0: Collision Prevention off
    delay_s: float = bounded(0.4, "s", ge=0)  # CP_DELAY
    guide_deg: float = bounded(30.0, "deg", ge=0, le=180)  # CP_GUIDE_ANG
    go_no_data: bool = False
    accel_mps2: float = bounded(3.0, "m/s²", gt=0)  # MPC_ACC_HOR
    jerk_mps3: float = bounded(8.0, "m/s³", gt=0)  # MPC_JERK_MAX

    @property
    def active(self) -> bool:
        return self.dist_m > 0.0


def cp_params(table: ParamTable) -> CpParams:
    """:class:`CpParams` from the parameter table (PX4 flavour)."""
    return CpParams(
        dist_m=table.value("CP_DIST"),
        delay_s=table.value("CP_DELAY"),
        guide_deg=table.value("CP_GUIDE_ANG"),
        go_no_data=table.value("CP_GO_NO_DATA") == 1,
        accel_mps2=table.value("MPC_ACC_HOR"),
        jerk_mps3=table.value("MPC_JERK_MAX"),
    )


def max_speed_from_distance(jerk: float, accel: float, distance: float, final: float) -> float:
    """``math::trajectory::computeMaxSpeedFromDistance``: the speed from which a jerk- and
    acceleration-limited stop ends at ``final`` [m/s] after ``distance`` [m]."""
    b = 4.0 * accel * accel / jerk
    c = -2.0 * accel * max(distance, 0.0) - final * final
    return max(0.5 * (-b + math.sqrt(b * b - 4.0 * c)), final)


def constrain_velocity(
    desired_ne_mps: tuple[float, float],
    yaw_rad: float,
    bins_m: np.ndarray,
    range_m: float,
    age_s: float,
    params: CpParams,
    fov: np.ndarray | None = None,
) -> tuple[float, float]:
    """The pilot's velocity setpoint [m/s, NE] after Collision Prevention (module doc);
    ``fov`` the bins that have had data (None: every bin)."""
    if not params.active:
        return desired_ne_mps
    known = np.isfinite(bins_m)
    if not known.any():
        return (0.0, 0.0)  # no obstacle data: not moving
    speed = math.hypot(*desired_ne_mps)
    if speed < 1e-3:
        return desired_ne_mps
    body = math.degrees(math.atan2(desired_ne_mps[1], desired_ne_mps[0]) - yaw_rad) % 360.0
    index = int(body // _BIN_DEG) % PX4_BINS
    index = _adapt_direction(index, bins_m, params)
    if not known[index] and (not params.go_no_data or fov is None or fov[index]):
        return (0.0, 0.0)  # no data that way (CP_GO_NO_DATA, _data_fov)
    if index != int(body // _BIN_DEG) % PX4_BINS:
        heading = yaw_rad + math.radians(index * _BIN_DEG)
        vel = (speed * math.cos(heading), speed * math.sin(heading))
    else:
        vel = desired_ne_mps
    keep_m = params.dist_m
    for i in np.flatnonzero(known):
        distance = float(bins_m[i])
        angle = yaw_rad + math.radians(i * _BIN_DEG)
        ux, uy = math.cos(angle), math.sin(angle)
        along = vel[0] * ux + vel[1] * uy
        if along <= 0.0:
            continue
        delay_m = along * params.delay_s
        if distance < range_m:
            delay_m += along * max(age_s, 0.0)
        stop_m = max(0.0, distance - keep_m - delay_m)
        v_max = max_speed_from_distance(params.jerk_mps3, params.accel_mps2, stop_m, 0.0)
        if along > v_max:
            vel = (vel[0] - ux * (along - v_max), vel[1] - uy * (along - v_max))
    return vel


def _adapt_direction(index: int, bins_m: np.ndarray, params: CpParams) -> int:
    """``_adaptSetpointDirection``: the bin of least cost within ±CP_GUIDE_ANG."""
    guide = int(params.guide_deg // _BIN_DEG)
    best_cost, best = math.inf, index
    cp_cm = params.dist_m * 100.0
    for i in range(index - guide, index + guide + 1):
        b = i % PX4_BINS
        if not math.isfinite(bins_m[b]):
            continue
        window = [bins_m[j % PX4_BINS] for j in (i - 1, i, i + 1)]
        mean_cm = sum(d * 100.0 if math.isfinite(d) else cp_cm for d in window) / 3.0
        cost = cp_cm * 0.5 * abs(i - index) - mean_cm - bins_m[b] * 100.0
        if cost < best_cost:
            best_cost, best = cost, b
    return best
