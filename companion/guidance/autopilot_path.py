"""Where the autopilot will fly a position target from the vehicle's present state.

The safety envelope (:mod:`companion.guidance.envelope`) certifies the *straight* path
from the vehicle toward guidance's target. An autopilot does not fly that line when the
vehicle is already moving another way: its position controller shapes a *reference*
(position, velocity, acceleration) bounded by an acceleration and a *jerk*, so after a
target switch at speed the reference first keeps its present acceleration and ramps it
round at the jerk limit. This module predicts that path, pure (no clock, no I/O), so the
envelope can certify it (issue 36, "momentum after a target switch").

What was followed (read in the autopilots' sources, not copied):

* **ArduCopter** ``AC_PosControl::input_pos_xyz`` / ``shape_pos_vel_accel``
  (``libraries/AP_Math/control.cpp``): the velocity wanted is a square-root controller
  of the position error, ``sqrt(2·a·e)`` far from the target and linear near it, with
  gain ``k = jerk / accel``, capped at the speed limit; the acceleration wanted is ``k``
  times the velocity error, capped at ``WPNAV_ACCEL``; the acceleration moves towards it
  at most at the jerk limit (``PSC_JERK_XY``, 5 m/s³ by default; less where the airframe
  tilts slower). A stop therefore takes ``τ + (a₀ + A)/j + v/A`` rather than ``v/(2A)``.
* **PX4** OFFBOARD position setpoints are not smoothed (``mc_pos_control``): its paths
  are shorter than this model's, so certifying the model's is conservative for PX4.

The model is deliberately simple: one 3-D vector law (the horizontal limits applied to
all three axes), the present acceleration held for the latency ``τ`` (the reference does
not know of the new target yet), and the vehicle on its reference. Its constants are the
envelope's (``accel_mps2``, ``jerk_mps3``), conservative defaults when the autopilot's own
are not known.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ReferenceLimits", "predict_path", "straight_stop_m"]

_DT_S = 0.05  # integration step of the prediction [s]
# the reference is at rest below this speed [m/s] and acceleration [m/s²]
_STOPPED_MPS = 0.03
_STOPPED_MPS2 = 0.1
_AT_TARGET_M = 0.05  # the reference is on its target within this [m]
_SAMPLE_SPACING_M = 0.2  # arc length between the path's samples [m]


@dataclass(frozen=True)
class ReferenceLimits:
    """Bounds of the autopilot's shaped reference (SI units, all > 0).

    Attributes
    ----------
    accel_mps2 : float
        Acceleration limit [m/s²] (WPNAV_ACCEL, MPC_ACC_HOR; the envelope's braking
        deceleration, which is at most it).
    jerk_mps3 : float
        Jerk limit [m/s³] (PSC_JERK_XY, MPC_JERK_AUTO, or what the airframe follows).
    speed_mps : float
        Speed limit [m/s] (the one the companion states, WPNAV_SPEED otherwise).
    """

    accel_mps2: float
    jerk_mps3: float
    speed_mps: float


def straight_stop_m(
    speed_mps: float, accel_along_mps2: float, latency_s: float, limits: ReferenceLimits
) -> float:
    """Distance a jerk-limited stop carries the vehicle along its velocity [m].

    Closed form of the 1-D stop: the acceleration ``a₀`` along the velocity is held for
    ``τ``, then ramps down at the jerk limit ``j`` towards ``−A`` (the speed may run out
    on the way), holds ``−A``, and ramps back to 0 once the speed left is what that ramp
    removes, ``A²/(2j)`` (begun at once when less is left). A reference that reverses
    instead of coming to rest (a target behind it) reaches less far, so this bounds the
    reach along the velocity. ``j → ∞`` and ``a₀ = 0`` give ``τ·v + v²/(2A)``.
    """
    A, j = limits.accel_mps2, limits.jerk_mps3
    a0 = min(max(float(accel_along_mps2), -A), A)
    v = max(float(speed_mps), 0.0)
    # latency: a0 held
    t0 = float(latency_s)
    if a0 < 0.0 and v + a0 * t0 <= 0.0:
        t = v / -a0
        return v * t + 0.5 * a0 * t * t
    d = v * t0 + 0.5 * a0 * t0 * t0
    v += a0 * t0
    # ramp a0 → −A at jerk j: v(t) = v + a0 t − j t²/2
    t1 = (a0 + A) / j
    t_zero = (a0 + math.sqrt(a0 * a0 + 2.0 * j * v)) / j  # v(t) = 0
    if t_zero <= t1:
        return d + v * t_zero + 0.5 * a0 * t_zero**2 - j * t_zero**3 / 6.0
    d += v * t1 + 0.5 * a0 * t1 * t1 - j * t1**3 / 6.0
    v += a0 * t1 - 0.5 * j * t1 * t1
    # hold −A, then ramp −A → 0 (removes A²/(2j) of speed over A/j)
    v_ramp = A * A / (2.0 * j)
    if v > v_ramp:
        d += (v * v - v_ramp * v_ramp) / (2.0 * A)
        v = v_ramp
    t3 = (A - math.sqrt(max(A * A - 2.0 * j * v, 0.0))) / j  # v − A t + j t²/2 = 0
    return d + v * t3 - 0.5 * A * t3 * t3 + j * t3**3 / 6.0


def _sqrt_speed(error_m: float, k: float, accel: float) -> float:
    """Square-root controller: ``k·e`` near the target, ``sqrt(2·a·(e − a/(2k²)))``
    beyond ``a/k²`` [m/s]."""
    linear_end = accel / (k * k)
    if error_m <= linear_end:
        return k * error_m
    return math.sqrt(2.0 * accel * (error_m - 0.5 * linear_end))


def _closing_speed(error_m: float, closing_mps: float, k: float, accel: float) -> float:
    """The speed wanted towards a target ``error_m`` away: the square-root speed less the
    lag of a velocity loop of gain ``k`` (ArduCopter's ``sqrt_controller_accel``), so
    the reference stops at the target rather than past it [m/s]."""
    linear_end = accel / (k * k)
    slope = k if error_m <= linear_end else accel / _sqrt_speed(error_m, k, accel)
    return _sqrt_speed(error_m, k, accel) - slope * closing_mps / k


def predict_path(
    pos_ned_m,
    vel_ned_mps,
    accel_ned_mps2,
    target_ned_m,
    latency_s: float,
    limits: ReferenceLimits,
    *,
    horizon_s: float = 3.5,
) -> np.ndarray:
    """Points of the path the autopilot flies to ``target_ned_m`` from the present state.

    Parameters
    ----------
    pos_ned_m, vel_ned_mps, accel_ned_mps2 : array_like, shape (3,)
        The vehicle's state [m, m/s, m/s², NED]; acceleration zero when not known.
    target_ned_m : array_like, shape (3,)
        The position target to be sent [m, NED].
    latency_s : float
        Until the autopilot acts on it [s]: the present acceleration is held meanwhile.
    limits : ReferenceLimits
    horizon_s : float
        Longest time predicted [s] (the path stops earlier once at rest).

    Returns
    -------
    ndarray, shape (n, 3)
        Points along the path every ~0.2 m of arc and its last point, the start excluded.
    """
    p = [float(x) for x in pos_ned_m]
    v = [float(x) for x in vel_ned_mps]
    a = [float(x) for x in accel_ned_mps2]
    tgt = [float(x) for x in target_ned_m]
    A, j, vmax = limits.accel_mps2, limits.jerk_mps3, limits.speed_mps
    k = j / A
    dt = _DT_S
    points: list[tuple[float, float, float]] = []
    arc = 0.0
    t = 0.0
    while t < horizon_s:
        if t >= latency_s:
            e = [tgt[i] - p[i] for i in range(3)]
            dist = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
            if dist > 1e-9:
                u = [e[i] / dist for i in range(3)]
                closing = v[0] * u[0] + v[1] * u[1] + v[2] * u[2]
                speed_w = min(vmax, max(0.0, _closing_speed(dist, closing, k, 0.8 * A)))
                vw = [speed_w * u[i] for i in range(3)]
            else:
                vw = [0.0, 0.0, 0.0]
            aw = [k * (vw[i] - v[i]) for i in range(3)]
            aw = _clip(aw, A)
            da = _clip([aw[i] - a[i] for i in range(3)], j * dt)
            a = [a[i] + da[i] for i in range(3)]
            a = _clip(a, A)
        step = [v[i] * dt + 0.5 * a[i] * dt * dt for i in range(3)]
        p = [p[i] + step[i] for i in range(3)]
        v = [v[i] + a[i] * dt for i in range(3)]
        arc += math.sqrt(step[0] ** 2 + step[1] ** 2 + step[2] ** 2)
        t += dt
        if arc >= _SAMPLE_SPACING_M:
            points.append((p[0], p[1], p[2]))
            arc = 0.0
        at_rest = _norm(v) < _STOPPED_MPS and _norm(a) < _STOPPED_MPS2
        if t > latency_s and at_rest and math.dist(p, tgt) < _AT_TARGET_M:
            break
    if not points or points[-1] != (p[0], p[1], p[2]):
        points.append((p[0], p[1], p[2]))
    return np.array(points, dtype=float)


def _norm(x) -> float:
    return math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])


def _clip(x, limit: float):
    n = _norm(x)
    if n <= limit or n == 0.0:
        return x
    s = limit / n
    return [x[0] * s, x[1] * s, x[2] * s]
