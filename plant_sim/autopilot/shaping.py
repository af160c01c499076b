"""Kinematic target shaping between an autopilot's mode logic and the paper's LQ loop.

A real autopilot never hands a far position target straight to its position loop. It
moves a *reference* (position, velocity, acceleration) towards the target along a path
bounded by a speed, an acceleration and a jerk, and the position loop tracks that
reference with the velocity as feed-forward. This module is that reference, pure and in
simulation seconds, so that plant-sim flies a GUIDED / OFFBOARD target, BRAKE and LOITER
the way the real autopilots do (issue 31).

What was followed (read in the autopilots' own sources, not copied):

* **ArduCopter GUIDED** (``ArduCopter/mode_guided.cpp``): a position target puts GUIDED in
  its ``Pos`` sub-mode; ``pva_control_start`` sets the position controller's limits to
  ``WPNAV_SPEED`` / ``WPNAV_ACCEL`` horizontally and ``WPNAV_SPEED_UP`` / ``_DN`` /
  ``WPNAV_ACCEL_Z`` vertically, each time that sub-mode (or the mode) starts;
  ``MAV_CMD_DO_CHANGE_SPEED`` calls ``set_speed_xy_cms`` / ``set_speed_up_cms`` /
  ``set_speed_down_cms``, which replace the limit until the sub-mode restarts.
* **AC_PosControl shaping** (``libraries/AP_Math/control.cpp``, ``shape_pos_vel_accel``):
  the velocity wanted is a square-root controller of the position error (linear near the
  target, ``sqrt(2·a·e)`` far from it) with gain ``k_v = jerk / accel``, capped at the
  speed limit; the acceleration wanted is ``k_v`` times the velocity error, capped at the
  acceleration limit; the acceleration then moves towards it at most at the jerk limit
  (``shape_accel``). The jerk is ``PSC_JERK_XY`` / ``PSC_JERK_Z`` (5 m/s³ by default).
  When the vehicle cannot follow (its tilt saturates), the reference does not run on ahead
  of it (ArduCopter's ``limit`` vectors in ``update_pos_vel_accel_xy``).
* **ArduCopter BRAKE** (``ArduCopter/mode_brake.cpp``): velocity to zero at
  ``BRAKE_MODE_DECEL_RATE`` (750 cm/s²), vertical speed at most ``BRAKE_MODE_SPEED_Z``
  (250 cm/s), then hold where it stopped.
* **ArduCopter LOITER** with centred sticks (``libraries/AC_WPNav/AC_Loiter.cpp``): the
  desired velocity decays by the stick "drag" ``LOIT_ACC_MAX·|v|/LOIT_SPEED`` and, after
  ``LOIT_BRK_DELAY``, by a braking deceleration that rises at ``LOIT_BRK_JERK`` to
  ``LOIT_BRK_DECEL``; then the position is held.
* **PX4** (``src/modules/flight_mode_manager/tasks/Auto`` and the position-smoothing
  library ``PositionSmoothing`` / ``VelocitySmoothing``): PX4's Auto modes and Hold
  approach a position along a jerk-limited trajectory at ``MPC_XY_CRUISE`` (5 m/s),
  ``MPC_ACC_HOR`` (3 m/s²), ``MPC_JERK_AUTO`` (4 m/s³); Hold decelerates at
  ``MPC_ACC_HOR``. OFFBOARD position setpoints are *not* smoothed: mc_pos_control takes
  the trajectory setpoint as it comes and, in OFFBOARD, bounds only the velocity, by
  ``MPC_XY_VEL_MAX`` / ``MPC_Z_VEL_MAX_UP`` / ``_DN``
  (``src/modules/mc_pos_control/MulticopterPositionControl.cpp``, ``Run()``), so
  plant-sim's PX4 flavour hands OFFBOARD targets straight to the position loop.

The shaping law here is this module's own: the square-root controller above, less the
lag of its velocity loop (the command's rate of change over ``k_v``, as ArduCopter's
``sqrt_controller_accel`` bias), planning to stop at 0.8 of the acceleration limit, so
that the jerk-limited reference stops at its target and not past it (tested).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

__all__ = [
    "BrakeProfile",
    "ShapingLimits",
    "TargetShaper",
    "sqrt_controller",
]


@dataclass(frozen=True)
class ShapingLimits:
    """Speed, acceleration and jerk bounds of the reference (SI units, all > 0)."""

    speed_ne_mps: float  # horizontal speed limit (WPNAV_SPEED, MPC_XY_CRUISE) [m/s]
    speed_up_mps: float  # climb speed limit (WPNAV_SPEED_UP, MPC_Z_V_AUTO_UP) [m/s]
    speed_down_mps: float  # descent speed limit (WPNAV_SPEED_DN, MPC_Z_V_AUTO_DN) [m/s]
    accel_ne_mps2: float  # horizontal acceleration (WPNAV_ACCEL, MPC_ACC_HOR) [m/s²]
    accel_d_mps2: float  # vertical acceleration (WPNAV_ACCEL_Z, MPC_ACC_UP_MAX) [m/s²]
    jerk_ne_mps3: float  # horizontal jerk (PSC_JERK_XY, MPC_JERK_AUTO) [m/s³]
    jerk_d_mps3: float  # vertical jerk (PSC_JERK_Z, MPC_JERK_AUTO) [m/s³]

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"ShapingLimits.{name} must be finite and > 0, got {value!r}")


@dataclass(frozen=True)
class BrakeProfile:
    """How a stop decelerates: at most ``decel_mps2`` (horizontal), reached at
    ``jerk_mps3``; plus a speed-proportional drag ``drag_per_s``·|v| from the start and the
    braking part only after ``delay_s`` (ArduCopter LOITER's stick release). BRAKE is
    ``delay_s = 0, drag_per_s = 0``."""

    decel_mps2: float  # [m/s²]
    jerk_mps3: float  # [m/s³]
    delay_s: float = 0.0  # [s]
    drag_per_s: float = 0.0  # [1/s]


class _Goal(enum.Enum):
    POSITION = enum.auto()  # approach ``target`` within the limits
    STOP = enum.auto()  # decelerate to rest by a BrakeProfile, then hold there


def sqrt_controller(error: float, k: float, accel: float) -> float:
    """The speed that closes ``error`` (≥ 0) and can still stop at ``accel``: ``k·error``
    near the target, ``sqrt(2·accel·(error − accel/(2k²)))`` beyond ``accel/k²`` (the two
    meet with equal value and slope there) [m/s]."""
    if error <= 0.0:
        return 0.0
    linear_end = accel / (k * k)
    if error <= linear_end:
        return k * error
    return math.sqrt(2.0 * accel * (error - 0.5 * linear_end))


def sqrt_controller_slope(error: float, k: float, accel: float) -> float:
    """d/d(error) of :func:`sqrt_controller` [1/s]."""
    if error <= 0.0:
        return 0.0
    linear_end = accel / (k * k)
    if error <= linear_end:
        return k
    return accel / math.sqrt(2.0 * accel * (error - 0.5 * linear_end))


def _closing_speed(error: float, closing_mps: float, k: float, accel: float) -> float:
    """The speed wanted towards a target ``error`` away, closing at ``closing_mps``: the
    square-root speed, less the lag of a velocity loop of gain ``k`` — the command's own
    rate of change ``slope·closing`` over ``k`` (ArduCopter's ``sqrt_controller_accel``
    bias) — so the jerk-limited reference stops at the target, not past it [m/s]."""
    return sqrt_controller(error, k, accel) - sqrt_controller_slope(error, k, accel) * (
        closing_mps / k
    )


def _toward(current: float, wanted: float, step: float) -> float:
    return current + max(-step, min(step, wanted - current))


class TargetShaper:
    """A jerk-limited reference (NED position, velocity, acceleration) for the LQ loop.

    :meth:`reset` puts the reference on the vehicle; :meth:`go_to` approaches a position
    target within :class:`ShapingLimits`; :meth:`stop` brings the velocity to zero by a
    :class:`BrakeProfile` and then holds where it stopped; :meth:`step` advances it by
    ``dt_s`` simulation seconds. Horizontal and vertical are shaped separately, like
    ArduCopter's NE and U controllers.

    Invariants (tested): the reference's horizontal speed never exceeds
    ``speed_ne_mps``, its climb and descent rates never exceed their limits, and a
    position target is reached without passing it.
    """

    #: The square-root controller plans to stop at this fraction of the acceleration
    #: limit, so the jerk-limited response (whose lag is ``accel/jerk``) does not overshoot.
    PLAN_DECEL_FRACTION = 0.8
    #: A step longer than this is taken in pieces of at most this [s] (the autopilot's
    #: 50 Hz tick is one piece); at most MAX_SUBSTEPS of them (100 s): a longer step is
    #: cut to that.
    SUBSTEP_S = 0.02
    MAX_SUBSTEPS = 5000

    def __init__(self, limits: ShapingLimits) -> None:
        self.limits = limits
        self.pos_ned_m = [0.0, 0.0, 0.0]
        self.vel_ned_mps = [0.0, 0.0, 0.0]
        self.acc_ned_mps2 = [0.0, 0.0, 0.0]
        self.target_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._goal = _Goal.POSITION
        self._brake: BrakeProfile | None = None
        self._stop_elapsed_s = 0.0
        self._brake_decel_mps2 = 0.0

    # ---- commands ---------------------------------------------------------------------
    def reset(self, pos_ned_m, vel_ned_mps) -> None:
        """Put the reference on the vehicle (position, velocity; zero acceleration) and
        hold there."""
        self.pos_ned_m = [float(v) for v in pos_ned_m]
        self.vel_ned_mps = [float(v) for v in vel_ned_mps]
        self.acc_ned_mps2 = [0.0, 0.0, 0.0]
        self.target_ned_m = tuple(self.pos_ned_m)
        self._goal = _Goal.POSITION

    def go_to(self, target_ned_m) -> None:
        """Approach ``target_ned_m`` from where the reference is now."""
        self.target_ned_m = tuple(float(v) for v in target_ned_m)
        self._goal = _Goal.POSITION

    def stop(self, profile: BrakeProfile) -> None:
        """Decelerate to rest by ``profile``, then hold the point where it stopped."""
        self._goal = _Goal.STOP
        self._brake = profile
        self._stop_elapsed_s = 0.0
        self._brake_decel_mps2 = 0.0

    def set_limits(self, limits: ShapingLimits) -> None:
        """New limits from the next step on (DO_CHANGE_SPEED, a parameter change)."""
        self.limits = limits

    @property
    def stopping(self) -> bool:
        """True while a :meth:`stop` is still decelerating."""
        return self._goal is _Goal.STOP

    # ---- time ---------------------------------------------------------------------------
    def step(self, dt_s: float, *, hold_ahead_ned_m=None, vehicle_vel_ned_mps=None) -> None:
        """Advance the reference by ``dt_s`` [s].

        ``hold_ahead_ned_m``, ``vehicle_vel_ned_mps``: the vehicle's position and velocity
        when it cannot follow (its tilt is saturated); the reference then does not move
        farther ahead of it and takes the vehicle's velocity along the lead, so it does
        not carry a speed the vehicle never reached into the approach of the target;
        across the lead it is shaped as before (it can still turn).
        """
        if not dt_s > 0.0:
            return
        # a clock jump longer than MAX_SUBSTEPS pieces is not walked (no huge pieces)
        dt_s = min(dt_s, self.MAX_SUBSTEPS * self.SUBSTEP_S)
        n = min(self.MAX_SUBSTEPS, math.ceil(dt_s / self.SUBSTEP_S - 1e-9))
        for _ in range(n):
            if self._goal is _Goal.STOP:
                self._step_stop(dt_s / n)
            else:
                self._step_position(dt_s / n, hold_ahead_ned_m, vehicle_vel_ned_mps)
        if self._goal is _Goal.POSITION and self.at_target:
            self.pos_ned_m = list(self.target_ned_m)  # arrived: hold exactly the target
            self.vel_ned_mps = [0.0, 0.0, 0.0]
            self.acc_ned_mps2 = [0.0, 0.0, 0.0]

    @property
    def at_target(self) -> bool:
        """The reference is (within 1 µm, 1 µm/s) at rest on its position target."""
        return math.dist(self.pos_ned_m, self.target_ned_m) < 1e-6 and (
            max(abs(v) for v in self.vel_ned_mps) < 1e-6
        )

    def _step_position(self, dt: float, hold_ahead, vehicle_vel=None) -> None:
        lim = self.limits
        p, v, a, t = self.pos_ned_m, self.vel_ned_mps, self.acc_ned_mps2, self.target_ned_m
        # horizontal: along the error, the square-root speed capped at the speed limit
        k = lim.jerk_ne_mps3 / lim.accel_ne_mps2
        en, ee = t[0] - p[0], t[1] - p[1]
        dist = math.hypot(en, ee)
        if dist > 1e-9:
            un, ue = en / dist, ee / dist
            closing = v[0] * un + v[1] * ue
            speed = _closing_speed(dist, closing, k, self.PLAN_DECEL_FRACTION * lim.accel_ne_mps2)
            speed = max(0.0, min(lim.speed_ne_mps, speed))  # never away from the target
            vn_w, ve_w = speed * un, speed * ue
        else:
            vn_w, ve_w = 0.0, 0.0
        an_w, ae_w = _limit2((vn_w - v[0]) * k, (ve_w - v[1]) * k, lim.accel_ne_mps2)
        dan, dae = _limit2(an_w - a[0], ae_w - a[1], lim.jerk_ne_mps3 * dt)
        a[0] += dan
        a[1] += dae
        # vertical (NED down): climb and descent limits differ
        kd = lim.jerk_d_mps3 / lim.accel_d_mps2
        ed = t[2] - p[2]
        # closing speed: the velocity's component towards the target (negative when the
        # reference moves away from it; not |v| with the error's sign, which read a
        # reference climbing towards a target above as moving away and kept it climbing)
        closing_d = _closing_speed(
            abs(ed), math.copysign(1.0, ed) * v[2], kd, self.PLAN_DECEL_FRACTION * lim.accel_d_mps2
        )
        vd_w = math.copysign(max(0.0, closing_d), ed)
        vd_w = max(-lim.speed_up_mps, min(lim.speed_down_mps, vd_w))
        ad_w = max(-lim.accel_d_mps2, min(lim.accel_d_mps2, (vd_w - v[2]) * kd))
        a[2] = _toward(a[2], ad_w, lim.jerk_d_mps3 * dt)
        self._integrate(dt, hold_ahead, vehicle_vel=vehicle_vel)

    def _step_stop(self, dt: float) -> None:
        lim, prof = self.limits, self._brake
        assert prof is not None
        v, a = self.vel_ned_mps, self.acc_ned_mps2
        self._stop_elapsed_s += dt
        if self._stop_elapsed_s >= prof.delay_s:
            self._brake_decel_mps2 = min(
                prof.decel_mps2, self._brake_decel_mps2 + prof.jerk_mps3 * dt
            )
        hspeed = math.hypot(v[0], v[1])
        decel = min(prof.decel_mps2, self._brake_decel_mps2 + prof.drag_per_s * hspeed)
        # horizontal: decelerate along -v, never reversing
        if hspeed > 0.0:
            dv = min(hspeed, decel * dt)
            v[0] -= dv * v[0] / hspeed
            v[1] -= dv * v[1] / hspeed
            a[0] = -decel * v[0] / max(hspeed, 1e-9)
            a[1] = -decel * v[1] / max(hspeed, 1e-9)
        # vertical: to zero at the vertical acceleration limit
        dvd = min(abs(v[2]), lim.accel_d_mps2 * dt)
        v[2] -= math.copysign(dvd, v[2])
        a[2] = 0.0
        self._integrate(dt, None, accelerate=False)
        if math.hypot(v[0], v[1]) < 1e-6 and abs(v[2]) < 1e-6:
            self.reset(self.pos_ned_m, (0.0, 0.0, 0.0))

    def _integrate(
        self, dt: float, hold_ahead, *, accelerate: bool = True, vehicle_vel=None
    ) -> None:
        lim = self.limits
        p, v, a = self.pos_ned_m, self.vel_ned_mps, self.acc_ned_mps2
        hs_before = math.hypot(v[0], v[1])
        dp = [v[i] * dt + (0.5 * a[i] * dt * dt if accelerate else 0.0) for i in range(3)]
        if hold_ahead is not None:
            # the vehicle cannot follow: no motion that takes the reference farther from it.
            # Only the part along the lead is stopped (ArduCopter's limit is a direction
            # too: AP_Math/control.cpp, update_vel_accel_xy removes the velocity change's
            # component along it), so a reference ahead of a vehicle at its top speed still
            # turns: sideways motion is left to shape (the paper airframe cruises with its
            # pitch at the tilt limit; stopping the whole step froze every avoidance turn).
            lead = [p[i] - float(hold_ahead[i]) for i in range(3)]
            norm = math.sqrt(sum(x * x for x in lead))
            u = [x / norm for x in lead] if norm > 1e-9 else [0.0, 0.0, 0.0]
            along = sum(dp[i] * u[i] for i in range(3))
            if along > 0.0:
                dp = [dp[i] - along * u[i] for i in range(3)]
                if vehicle_vel is not None:  # its speed along the lead: the vehicle's
                    v_along = sum((v[i] - float(vehicle_vel[i])) * u[i] for i in range(3))
                    for i in range(3):
                        v[i] -= v_along * u[i]
                a_along = sum(a[i] * u[i] for i in range(3))
                if a_along > 0.0:
                    for i in range(3):
                        a[i] -= a_along * u[i]
        for i in range(3):
            p[i] += dp[i]
            if accelerate:
                v[i] += a[i] * dt
        # never accelerate past the speed limit; above it (the limit was just lowered)
        # slow down at the acceleration limit, as the real position controller does
        hs = math.hypot(v[0], v[1])
        cap = max(lim.speed_ne_mps, hs_before - lim.accel_ne_mps2 * dt)
        if hs > cap:
            v[0] *= cap / hs
            v[1] *= cap / hs
            along = (a[0] * v[0] + a[1] * v[1]) / cap
            if along > 0.0:  # the feed-forward must not ask for more speed either
                a[0] -= along * v[0] / cap
                a[1] -= along * v[1] / cap
        vd = max(-lim.speed_up_mps, min(lim.speed_down_mps, v[2]))
        if vd != v[2]:
            v[2], a[2] = vd, 0.0


def _limit2(x: float, y: float, bound: float) -> tuple[float, float]:
    n = math.hypot(x, y)
    if n <= bound or n == 0.0:
        return x, y
    return x * bound / n, y * bound / n
