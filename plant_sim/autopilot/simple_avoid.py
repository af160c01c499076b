"""ArduCopter's simple avoidance (AC_Avoid) on proximity data, for LOITER's pilot velocity.

Pure: the desired horizontal velocity, the vehicle's yaw and ArduPilot's proximity faces
(:meth:`plant_sim.autopilot.proximity.ProximityReceiver.ardupilot_faces`) in, the limited
velocity out; time is passed in. Follows ``libraries/AC_Avoidance/AC_Avoid.cpp``
(``adjust_velocity``, ``adjust_velocity_proximity``, ``limit_velocity_2D``,
``get_max_speed``, ``calc_backup_velocity``, ``limit_accel``) and
``AC_AttitudeControl::sqrt_controller``. What is implemented:

* ``AVOID_ENABLE`` bit 1 (2, "UseProximitySensor") with ``PRX1_TYPE = 2`` (MAVLink) and
  fresh data; otherwise the velocity passes unchanged.
* Per face with a reading (its nearest point, body frame): **slide** (``AVOID_BEHAVE 0``)
  limits the velocity's component toward the point to
  ``sqrt_controller(distance − AVOID_MARGIN, kP, accel)``; **stop** (``AVOID_BEHAVE 1``)
  applies the same limit only to points the straight path to the stopping point (plus the
  margin and 2 cm) passes within the margin of, and stops outright inside the margin —
  the velocity is not turned. ``kP`` is ``PSC_POSXY_P`` (1.0); ``accel`` is
  ``min(LOIT_ACC_MAX, AC_AVOID_ACCEL_CMSS_MAX = 1 m/s²)``.
* **Back-up** inside the margin by more than ``AVOID_BACKUP_DZ``: away from the point at
  ``sqrt_controller(breach, kP, 0.4 · accel)``, at most ``AVOID_BACKUP_SPD``; the pilot keeps
  any larger velocity in that direction per axis (the quadrant rule, one obstacle per
  quadrant's maximum).
* ``AVOID_ACCEL_MAX``: the avoidance's change of velocity is limited to this [m/s²]
  (0: unlimited), restarting from the pilot's velocity 200 ms after avoidance last acted.

* **ALT_HOLD** (:func:`adjust_roll_pitch`, ``AC_Avoid::adjust_roll_pitch`` and
  ``get_proximity_roll_pitch_norm``, called by ``ModeAltHold::run`` while flying): each
  face nearer than ``AVOID_DIST_MAX`` (5 m) leans the vehicle away by
  ``45° · (1 − d / AVOID_DIST_MAX)`` (roll ``−sin(bearing)``, pitch ``+cos(bearing)``
  parts; per axis the largest positive and the most negative are summed), the lean at most
  ``min(AVOID_ANGLE_MAX, 0.75 · ANGLE_MAX)`` (10°), added to the pilot's and the total at
  most ``ANGLE_MAX``. There is no margin and no stopping distance: a pilot leaning harder
  than the avoidance's 10° flies on; a gentler lean comes to rest where the two cancel.

Not implemented: the fence and beacon sources, the vertical (3-D) limits and
``AVOID_ALT_MIN``, STABILIZE's avoidance (the same lean, plant-sim does not fly
STABILIZE from sticks), the boundary's line segments between faces (each face is its
nearest point) and BendyRuler / Dijkstra path planning (``OA_TYPE``).
With unknown sectors (``UINT16_MAX``) ArduPilot has no reading, exactly as for a clear
sector: it flies into space the camera could not match (a textureless wall).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from plant_sim.autopilot.params import ParamSpec, ParamTable, ParamType
from plant_sim.autopilot.proximity import Face
from protocols.config import Checked, bounded

__all__ = [
    "AVOID_PARAM_SPECS",
    "AvoidParams",
    "SimpleAvoid",
    "adjust_roll_pitch",
    "avoid_params",
    "sqrt_controller",
]

_AVOID_ACCEL_MAX_CAP_MPS2 = 1.0  # AC_AVOID_ACCEL_CMSS_MAX 100 cm/s²
_ACCEL_TIMEOUT_S = 0.2  # AC_AVOID_ACCEL_TIMEOUT_MS
_AVOID_ANGLE_MAX_PERCENT = 0.75  # AC_AVOID_ANGLE_MAX_PERCENT: the pilot can override
_BACKUP_ACCEL_SCALE = 0.4  # calc_backup_velocity_2D: get_max_speed(kP, 0.4 · accel, …)
_PROXIMITY_BIT = 2  # AVOID_ENABLE bit 1: UseProximitySensor
_PRX_TYPE_MAVLINK = 2

#: ArduCopter's parameters behind simple avoidance and pilot flight (names, units, defaults
#: and ranges from AC_Avoid.cpp, AP_Proximity_Params.cpp, AC_PosControl.cpp, RC_Channel).
AVOID_PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("PRX1_TYPE", ParamType.INT8, 0, 0, 20),  # 0 none, 2 MAVLink
    ParamSpec("PRX_FILT", ParamType.REAL32, 0.25, 0.0, 20.0),  # Hz, per-face low-pass
    ParamSpec("AVOID_ENABLE", ParamType.INT8, 3, 0, 7),  # bitmask: 1 fence, 2 proximity
    ParamSpec("AVOID_MARGIN", ParamType.REAL32, 2.0, 1.0, 10.0),  # m
    ParamSpec("AVOID_BEHAVE", ParamType.INT8, 0, 0, 1),  # 0 slide, 1 stop
    ParamSpec("AVOID_BACKUP_SPD", ParamType.REAL32, 0.75, 0.0, 2.0),  # m/s
    ParamSpec("AVOID_ACCEL_MAX", ParamType.REAL32, 3.0, 0.0, 9.0),  # m/s²
    ParamSpec("AVOID_BACKUP_DZ", ParamType.REAL32, 0.1, 0.0, 2.0),  # m
    ParamSpec("AVOID_ANGLE_MAX", ParamType.INT16, 1000, 0, 4500),  # cdeg, non-GPS modes
    ParamSpec("AVOID_DIST_MAX", ParamType.REAL32, 5.0, 1.0, 30.0),  # m, non-GPS modes
    ParamSpec("PSC_POSXY_P", ParamType.REAL32, 1.0, 0.5, 2.0),  # 1/s
    ParamSpec("PILOT_SPEED_UP", ParamType.INT16, 250, 50, 500),  # cm/s
    ParamSpec("PILOT_SPEED_DN", ParamType.INT16, 0, 0, 500),  # cm/s, 0: PILOT_SPEED_UP
    ParamSpec("RC_OVERRIDE_TIME", ParamType.REAL32, 3.0, 0.0, 120.0),  # s
)


@dataclass(frozen=True)
class AvoidParams(Checked):
    """:data:`AVOID_PARAM_SPECS` in SI units."""

    proximity: bool = False  # PRX1_TYPE == 2 and AVOID_ENABLE has the proximity bit
    margin_m: float = bounded(2.0, "m", gt=0)  # AVOID_MARGIN
    stop: bool = False  # AVOID_BEHAVE 1
    backup_speed_mps: float = bounded(0.75, "m/s", ge=0)  # AVOID_BACKUP_SPD
    accel_max_mps2: float = bounded(3.0, "m/s²", ge=0)  # AVOID_ACCEL_MAX; 0: no limit
    backup_deadzone_m: float = bounded(0.1, "m", ge=0)  # AVOID_BACKUP_DZ
    kp: float = bounded(1.0, "1/s", gt=0)  # PSC_POSXY_P
    loiter_accel_mps2: float = bounded(5.0, "m/s²", gt=0)  # LOIT_ACC_MAX
    angle_max_rad: float = bounded(math.radians(10.0), "rad", ge=0)  # AVOID_ANGLE_MAX (ALT_HOLD)
    dist_max_m: float = bounded(5.0, "m", gt=0)  # AVOID_DIST_MAX (ALT_HOLD)


def avoid_params(table: ParamTable) -> AvoidParams:
    """:class:`AvoidParams` from the parameter table (ArduPilot flavour)."""
    return AvoidParams(
        proximity=table.value("PRX1_TYPE") == _PRX_TYPE_MAVLINK
        and int(table.value("AVOID_ENABLE")) & _PROXIMITY_BIT != 0,
        margin_m=table.value("AVOID_MARGIN"),
        stop=table.value("AVOID_BEHAVE") == 1,
        backup_speed_mps=table.value("AVOID_BACKUP_SPD"),
        accel_max_mps2=table.value("AVOID_ACCEL_MAX"),
        backup_deadzone_m=table.value("AVOID_BACKUP_DZ"),
        kp=table.value("PSC_POSXY_P"),
        loiter_accel_mps2=table.value("LOIT_ACC_MAX") / 100.0,
        angle_max_rad=math.radians(table.value("AVOID_ANGLE_MAX") / 100.0),
        dist_max_m=table.value("AVOID_DIST_MAX"),
    )


def adjust_roll_pitch(
    roll_rad: float,
    pitch_rad: float,
    vehicle_angle_max_rad: float,
    faces: list[Face],
    params: AvoidParams,
) -> tuple[float, float]:
    """ALT_HOLD's avoidance: the pilot's roll and pitch [rad] leaned away from the faces
    nearer than ``AVOID_DIST_MAX`` (module docstring; ``AC_Avoid::adjust_roll_pitch``)."""
    if not params.proximity or params.angle_max_rad <= 0.0 or vehicle_angle_max_rad <= 0.0:
        return roll_rad, pitch_rad
    roll_pos = roll_neg = pitch_pos = pitch_neg = 0.0
    for face in faces:
        d = face.distance_m
        if d < 0.0 or d >= params.dist_max_m:
            continue
        lean = 1.0 - d / params.dist_max_m  # distance_to_lean_norm
        roll = -math.sin(face.bearing_rad) * lean
        pitch = math.cos(face.bearing_rad) * lean
        roll_pos, roll_neg = max(roll_pos, roll), min(roll_neg, roll)
        pitch_pos, pitch_neg = max(pitch_pos, pitch), min(pitch_neg, pitch)
    r = (roll_pos + roll_neg) * math.radians(45.0)
    p = (pitch_pos + pitch_neg) * math.radians(45.0)
    limit = min(params.angle_max_rad, vehicle_angle_max_rad * _AVOID_ANGLE_MAX_PERCENT)
    n = math.hypot(r, p)
    if n > limit:
        r, p = r * limit / n, p * limit / n
    r, p = r + roll_rad, p + pitch_rad
    n = math.hypot(r, p)
    if n > vehicle_angle_max_rad:
        r, p = r * vehicle_angle_max_rad / n, p * vehicle_angle_max_rad / n
    return r, p


def sqrt_controller(error: float, p: float, second_ord_lim: float, dt: float) -> float:
    """``AC_AttitudeControl::sqrt_controller``: linear ``p · error`` near zero, the square
    root of constant deceleration beyond ``second_ord_lim / p²``; never more than the
    error in one step ``dt``."""
    if second_ord_lim <= 0.0 or p == 0.0:
        rate = math.sqrt(2.0 * second_ord_lim * abs(error)) if p == 0.0 else error * p
        rate = math.copysign(rate, error)
    else:
        linear = second_ord_lim / (p * p)
        if error > linear:
            rate = math.sqrt(2.0 * second_ord_lim * (error - linear / 2.0))
        elif error < -linear:
            rate = -math.sqrt(2.0 * second_ord_lim * (-error - linear / 2.0))
        else:
            rate = error * p
    if dt > 0.0:
        rate = max(-abs(error) / dt, min(abs(error) / dt, rate))
    return rate


def _stopping_distance(kp: float, accel: float, speed: float) -> float:
    """``AC_Avoid::get_stopping_distance`` [m]."""
    if kp <= 0.0 or accel <= 0.0 or speed == 0.0:
        return 0.0
    if speed < accel / kp:
        return speed / kp
    return accel / (2.0 * kp * kp) + speed * speed / (2.0 * accel)


class SimpleAvoid:
    """AC_Avoid's proximity limits with its acceleration-limit memory (one per vehicle)."""

    def __init__(self) -> None:
        self._prev_vel: tuple[float, float] | None = None
        self._last_limit_s = -math.inf
        self.active = False  # avoidance changed the velocity at the last call

    def adjust(
        self,
        desired_ne_mps: tuple[float, float],
        yaw_rad: float,
        faces: list[Face],
        params: AvoidParams,
        time_s: float,
        dt: float,
    ) -> tuple[float, float]:
        """The pilot's desired velocity [m/s, NE] after simple avoidance."""
        self.active = False
        if not params.proximity or not faces:
            return desired_ne_mps
        c, s = math.cos(yaw_rad), math.sin(yaw_rad)
        # earth → body (ArduPilot's earth_to_body2D)
        vx = c * desired_ne_mps[0] + s * desired_ne_mps[1]
        vy = -s * desired_ne_mps[0] + c * desired_ne_mps[1]
        accel = min(params.loiter_accel_mps2, _AVOID_ACCEL_MAX_CAP_MPS2)
        moving = vx != 0.0 or vy != 0.0
        stop_x = stop_y = 0.0
        if moving and params.stop:
            speed = math.hypot(vx, vy)
            scale = (0.02 + params.margin_m + _stopping_distance(params.kp, accel, speed)) / speed
            stop_x, stop_y = vx * scale, vy * scale
        backups: list[tuple[float, float]] = []
        for face in faces:
            ox = face.distance_m * math.cos(face.bearing_rad)
            oy = face.distance_m * math.sin(face.bearing_rad)
            dist = face.distance_m
            if dist <= 0.0:
                continue
            breach = params.margin_m - dist
            if breach > params.backup_deadzone_m:
                # calc_backup_velocity_2D: at 0.4 of the avoidance's acceleration
                back = abs(sqrt_controller(breach, params.kp, _BACKUP_ACCEL_SCALE * accel, dt))
                backups.append((-ox / dist * back, -oy / dist * back))
            if not moving:
                continue
            if params.stop:
                if not _segment_passes_within((stop_x, stop_y), (ox, oy), params.margin_m):
                    continue
                if dist <= params.margin_m:
                    vx = vy = 0.0
                    continue
            limit = max(dist - params.margin_m, 0.0)
            vx, vy = _limit_toward((vx, vy), (ox / dist, oy / dist), limit, params, accel, dt)
        vx, vy = self._back_up((vx, vy), backups, params)
        out = (c * vx - s * vy, s * vx + c * vy)  # body → earth
        return self._limit_accel(desired_ne_mps, out, params, time_s, dt)

    @staticmethod
    def _back_up(vel, backups, params: AvoidParams) -> tuple[float, float]:
        """Per quadrant the largest back-up component, summed, capped at the back-up speed;
        the pilot keeps a larger velocity in that direction (per axis)."""
        if not backups or params.backup_speed_mps <= 0.0:
            return vel
        quads: dict[tuple[bool, bool], list[float]] = {}
        for bx, by in backups:
            q = quads.setdefault((bx >= 0.0, by >= 0.0), [0.0, 0.0])
            q[0] = max(q[0], bx) if bx >= 0.0 else min(q[0], bx)
            q[1] = max(q[1], by) if by >= 0.0 else min(q[1], by)
        bx = sum(q[0] for q in quads.values())
        by = sum(q[1] for q in quads.values())
        n = math.hypot(bx, by)
        if n > params.backup_speed_mps:
            bx, by = bx / n * params.backup_speed_mps, by / n * params.backup_speed_mps
        vx, vy = vel
        if bx != 0.0:
            vx = max(vx, bx) if bx > 0.0 else min(vx, bx)
        if by != 0.0:
            vy = max(vy, by) if by > 0.0 else min(vy, by)
        return vx, vy

    def _limit_accel(self, original, modified, params: AvoidParams, time_s: float, dt: float):
        """``AC_Avoid::limit_accel``: avoidance changes the velocity by at most
        ``AVOID_ACCEL_MAX`` [m/s²]."""
        if modified == tuple(original):
            return modified
        self.active = True
        if params.accel_max_mps2 <= 0.0 or dt <= 0.0:
            self._last_limit_s = time_s
            return modified
        if self._prev_vel is None or time_s - self._last_limit_s > _ACCEL_TIMEOUT_S:
            self._prev_vel = (float(original[0]), float(original[1]))
        self._last_limit_s = time_s
        ax = (modified[0] - self._prev_vel[0]) / dt
        ay = (modified[1] - self._prev_vel[1]) / dt
        a = math.hypot(ax, ay)
        if a > params.accel_max_mps2:
            k = params.accel_max_mps2 / a
            modified = (self._prev_vel[0] + ax * k * dt, self._prev_vel[1] + ay * k * dt)
        self._prev_vel = modified
        return modified


def _limit_toward(vel, unit, limit_m: float, params: AvoidParams, accel: float, dt: float):
    """``limit_velocity_2D``: the component of ``vel`` along ``unit`` at most the speed
    that stops within ``limit_m``."""
    max_speed = sqrt_controller(limit_m, params.kp, accel, dt)
    along = vel[0] * unit[0] + vel[1] * unit[1]
    if along > max_speed:
        return vel[0] + unit[0] * (max_speed - along), vel[1] + unit[1] * (max_speed - along)
    return vel


def _segment_passes_within(end, point, margin_m: float) -> bool:
    """The segment from the vehicle (origin) to ``end`` passes within ``margin_m`` of
    ``point`` (stop behaviour: "roughly intersects the boundary")."""
    ex, ey = end
    seg2 = ex * ex + ey * ey
    if seg2 == 0.0:
        return math.hypot(*point) <= margin_m
    t = max(0.0, min(1.0, (point[0] * ex + point[1] * ey) / seg2))
    return math.hypot(point[0] - t * ex, point[1] - t * ey) <= margin_m
