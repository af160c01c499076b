"""ArduCopter flight modes and the pure mode logic that turns them into setpoints.

:class:`FlightModeMachine` owns the autopilot's discrete state (mode, armed, landed, takeoff
and RTL phases, the GUIDED target) and produces the :class:`~plant_sim.vehicle.Setpoint` the
flight controller tracks. It reads the vehicle through :class:`Kinematics` and time as
simulation seconds passed in by the caller: no sockets, no clocks.

Physical meaning of each mode in the SIL (there is no RC transmitter):

* GUIDED — tracks SET_POSITION_TARGET_LOCAL_NED targets; position targets persist. With
  ``guided_shaping`` (SIM_GUID_SHAPE 1) they are approached along a path shaped like
  ArduCopter's position controller (WPNAV_SPEED, WPNAV_ACCEL, WPNAV_SPEED_UP/DN,
  WPNAV_ACCEL_Z, PSC_JERK_XY/Z: :mod:`plant_sim.autopilot.shaping`) and
  MAV_CMD_DO_CHANGE_SPEED replaces the speed limit until the position sub-mode restarts
  (mode entry, end of a takeoff), as ArduCopter's ``pva_control_start``. This is the
  default; with SIM_GUID_SHAPE 0 the target goes straight to the LQ loop and
  DO_CHANGE_SPEED is refused.
  Velocity targets expire after ``guided_velocity_timeout_s`` (GUID_TIMEOUT) into a
  brake-and-hold; NAV_TAKEOFF climbs at ``takeoff_climb_mps``.
  Entering GUIDED decelerates at WPNAV_ACCEL and holds.
* BRAKE — decelerates at 7.5 m/s² (ArduCopter's BRAKE_MODE_DECEL_RATE), then holds the
  point where it stopped.
* LOITER (centred sticks) — decelerates by LOIT_ACC_MAX·|v|/LOIT_SPEED at once and, after
  LOIT_BRK_DELAY, by a braking deceleration rising at LOIT_BRK_JERK to LOIT_BRK_DECEL;
  then holds.
* Every deceleration is at most what the airframe can do at its tilt limit (ANGLE_MAX):
  ``0.8·g·tan(ANGLE_MAX)``.
* STABILIZE — centred sticks: level attitude at hover throttle, which in this drag-only
  world decays to zero velocity; modelled as zero-velocity hold.
* LAND — descend at ``land_speed_mps`` over the current north/east; disarm on touchdown.
* RTL — climb to ``rtl_alt_m`` above home (if lower), fly to home, then LAND.
* AUTO — refused: the mission is always empty.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace

from plant_sim.autopilot.integrator import VelocityIntegrator
from plant_sim.autopilot.shaping import BrakeProfile, ShapingLimits, TargetShaper
from plant_sim.vehicle import Setpoint, VehicleState
from protocols.mavlink_modes import ArduCopterMode

__all__ = [
    "ARMABLE_MODES",
    "FORCE_ARM_MAGIC",
    "FlightMode",
    "FlightModeMachine",
    "GuidedTarget",
    "Kinematics",
    "LandedState",
    "ModeTimings",
]

#: COMPONENT_ARM_DISARM param2 that bypasses the arming and disarming checks (ArduPilot).
FORCE_ARM_MAGIC = 21196


class FlightMode(enum.IntEnum):
    """The ArduCopter custom modes plant-sim flies (numbers: protocols.mavlink_modes)."""

    STABILIZE = ArduCopterMode.STABILIZE
    AUTO = ArduCopterMode.AUTO
    GUIDED = ArduCopterMode.GUIDED
    LOITER = ArduCopterMode.LOITER
    RTL = ArduCopterMode.RTL
    LAND = ArduCopterMode.LAND
    BRAKE = ArduCopterMode.BRAKE


#: Modes from which the motors may be armed (ArduCopter refuses AUTO, RTL, LAND, BRAKE).
ARMABLE_MODES = frozenset({FlightMode.STABILIZE, FlightMode.GUIDED, FlightMode.LOITER})


class LandedState(enum.IntEnum):
    """MAV_LANDED_STATE of EXTENDED_SYS_STATE."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


class _Phase(enum.Enum):
    """What the current mode is doing."""

    IDLE = enum.auto()  # disarmed, or armed on the ground waiting
    HOLD = enum.auto()  # holding a fixed position
    BRAKE = enum.auto()  # commanding zero velocity until stopped
    TAKEOFF = enum.auto()  # climbing along a ramp
    GUIDED_POS = enum.auto()  # tracking a GUIDED position target
    GUIDED_VEL = enum.auto()  # tracking a GUIDED velocity target (times out)
    RTL_CLIMB = enum.auto()
    RTL_RETURN = enum.auto()
    DESCEND = enum.auto()  # LAND, or RTL's final descent


@dataclass(frozen=True)
class ModeTimings:
    """Speeds and timeouts of the mode logic (ArduCopter parameter equivalents)."""

    guided_velocity_timeout_s: float = 3.0  # GUID_TIMEOUT [s]
    disarm_delay_s: float = 10.0  # DISARM_DELAY [s]
    land_speed_mps: float = 0.5  # LAND_SPEED [m/s]
    takeoff_climb_mps: float = 1.5  # [m/s]
    rtl_alt_m: float = 15.0  # RTL_ALT [m above home]
    land_detect_s: float = 1.0  # ground contact this long → landed [s]
    face_target_min_dist_m: float = 2.0  # turn to face a target farther than this
    face_velocity_min_mps: float = 0.5  # turn to face a velocity faster than this
    # GUIDED position-target shaping (ArduCopter defaults; parameters in comments)
    guided_limits: ShapingLimits = ShapingLimits(  # noqa: RUF009 (frozen: shared is safe)
        speed_ne_mps=10.0,  # WPNAV_SPEED 1000 cm/s
        speed_up_mps=2.5,  # WPNAV_SPEED_UP 250 cm/s
        speed_down_mps=1.5,  # WPNAV_SPEED_DN 150 cm/s
        accel_ne_mps2=2.5,  # WPNAV_ACCEL 250 cm/s²
        accel_d_mps2=1.0,  # WPNAV_ACCEL_Z 100 cm/s²
        jerk_ne_mps3=5.0,  # PSC_JERK_XY 5 m/s³
        jerk_d_mps3=5.0,  # PSC_JERK_Z 5 m/s³
    )
    brake: BrakeProfile = BrakeProfile(7.5, 5.0)  # noqa: RUF009 BRAKE mode: 750 cm/s²
    loiter: BrakeProfile = BrakeProfile(  # noqa: RUF009 LOITER, centred sticks
        decel_mps2=2.5,  # LOIT_BRK_DECEL 250 cm/s²
        jerk_mps3=5.0,  # LOIT_BRK_JERK 500 cm/s³
        delay_s=1.0,  # LOIT_BRK_DELAY 1 s
        drag_per_s=0.4,  # LOIT_ACC_MAX / LOIT_SPEED = 500 / 1250 1/s
    )
    max_decel_mps2: float = math.inf  # what the airframe can do: 0.8·g·tan(ANGLE_MAX)
    # The jerk the airframe follows [m/s³]: the paper's attitude loop (Eq. 31, dominant
    # pole ≈ −1.4 1/s) tilts ~5× slower than ArduCopter's, so a reference whose
    # acceleration changes faster is not followed and the vehicle overshoots its speed.
    # Calibrated on ArduCopter SITL's WPNAV_SPEED 100 leg (top speed 1.01–1.10 m/s;
    # plant-sim 1.07): the reference's jerk is min(PSC_JERK_XY, this).
    airframe_jerk_mps3: float = 2.0
    saturated_lead_m: float = 0.5  # a tilt-saturated vehicle this far behind holds the path
    # GUIDED position targets through the shaping above (SIM_GUID_SHAPE 1, the default,
    # as ArduCopter flies them; the lockstep harness flies the same) or straight to the LQ
    # loop (0: the airframe's own limits, DO_CHANGE_SPEED refused)
    guided_shaping: bool = True
    # the position controller's velocity integrator (not mode logic: the service and the
    # lockstep put it on the plant whenever the timings are derived from the parameters)
    velocity_integrator: VelocityIntegrator = VelocityIntegrator()  # noqa: RUF009 (frozen)


@dataclass(frozen=True)
class Kinematics:
    """What the mode logic reads of the vehicle (LOCAL_NED, MAVLink heading)."""

    time_s: float
    pos_ned_m: tuple[float, float, float]
    vel_ned_mps: tuple[float, float, float]
    yaw_rad: float
    on_ground: bool
    tilt_saturated: bool = False  # the controller is at its tilt limit (cannot follow)

    @classmethod
    def of(cls, state: VehicleState, error_ned_m=None) -> Kinematics:
        """The vehicle ``state`` as the autopilot's estimate has it: its position moved by
        ``error_ned_m`` [m, NED] (none: the truth)."""
        p = state.pos_ned_m if error_ned_m is None else state.pos_ned_m + error_ned_m
        v = state.vel_ned_mps
        return cls(
            time_s=state.time_s,
            pos_ned_m=(float(p[0]), float(p[1]), float(p[2])),
            vel_ned_mps=(float(v[0]), float(v[1]), float(v[2])),
            yaw_rad=state.yaw_rad,
            on_ground=state.on_ground,
            tilt_saturated=state.tilt_saturated,
        )


@dataclass(frozen=True)
class GuidedTarget:
    """A decoded GUIDED target in LOCAL_NED; None fields are not controlled."""

    pos_ned_m: tuple[float, float, float] | None = None
    vel_ned_mps: tuple[float, float, float] | None = None
    yaw_rad: float | None = None
    yaw_rate_radps: float | None = None


def _hspeed(v: tuple[float, float, float]) -> float:
    return math.hypot(v[0], v[1])


class FlightModeMachine:
    """Mode, arming and GUIDED-target logic of an ArduCopter, in simulation time.

    Commands (:meth:`arm`, :meth:`set_mode`, ...) return ``None`` on success or a short
    refusal reason for a STATUSTEXT. :meth:`update` advances timers and phases and returns
    notices (e.g. ``"Land complete"``); :attr:`setpoint` is what the controller must track
    and :attr:`armed` whether the rotors run.

    Parameters
    ----------
    timings : ModeTimings
    home_ned_m : home position, LOCAL_NED [m] (RTL target, takeoff altitude reference).
    ground_down_m : NED down of the ground, or None without ground.
    mode, armed : initial mode and arming state.
    kin : initial vehicle state.
    """

    def __init__(
        self,
        timings: ModeTimings,
        *,
        home_ned_m: tuple[float, float, float],
        ground_down_m: float | None,
        mode: FlightMode,
        armed: bool,
        kin: Kinematics,
    ) -> None:
        self.timings = timings
        self.home_ned_m = tuple(float(v) for v in home_ned_m)
        self._ground_down_m = ground_down_m
        self.mode = FlightMode(mode)
        self.armed = bool(armed)
        self.landed = kin.on_ground or not armed
        self._ground_since_s: float | None = kin.time_s if kin.on_ground else None
        self._idle_since_s = kin.time_s
        self._phase = _Phase.IDLE
        self._ref_down_m = kin.pos_ned_m[2]
        self._ref_time_s = kin.time_s
        self._ref_ne_m = (kin.pos_ned_m[0], kin.pos_ned_m[1])
        self._goal_down_m = kin.pos_ned_m[2]
        self._vel_target_time_s = -math.inf
        self._yaw_rad: float | None = kin.yaw_rad
        self.setpoint = Setpoint(pos_ned_m=kin.pos_ned_m, yaw_rad=kin.yaw_rad)
        self._target_yaw: tuple[float | None, float | None] = (kin.yaw_rad, None)
        self.shaper = TargetShaper(timings.guided_limits)
        self.shaper.reset(kin.pos_ned_m, kin.vel_ned_mps)
        self._shaper_time_s = kin.time_s
        self.speed_override: dict[str, float] = {}  # DO_CHANGE_SPEED: field → value
        if self.armed and not self.landed:
            self._enter_mode(kin)

    # ---- queries -------------------------------------------------------------------
    @property
    def landed_state(self) -> LandedState:
        """MAV_LANDED_STATE from the physics and the phase."""
        if self.landed:
            return LandedState.ON_GROUND
        if self._phase is _Phase.TAKEOFF:
            return LandedState.TAKEOFF
        if self._phase is _Phase.DESCEND:
            return LandedState.LANDING
        return LandedState.IN_AIR

    @property
    def reported_target(self) -> Setpoint:
        """What POSITION_TARGET_LOCAL_NED reports: in GUIDED with a position target, the
        target itself (as ArduCopter reports its guided target), not the shaped path the
        controller is on its way along; otherwise what the controller tracks."""
        if self._phase is _Phase.GUIDED_POS and self.timings.guided_shaping:
            yaw, yaw_rate = self._target_yaw
            return Setpoint(
                pos_ned_m=self.shaper.target_ned_m,
                yaw_rad=self._yaw_rad if yaw is None else yaw,
                yaw_rate_radps=yaw_rate,
            )
        return self.setpoint

    # ---- commands ------------------------------------------------------------------
    def arm(
        self, kin: Kinematics, *, force: bool = False, checks_enabled: bool = True
    ) -> str | None:
        """Arm the motors; returns a refusal reason or None."""
        if self.armed:
            return None
        if not force and checks_enabled and self.mode not in ARMABLE_MODES:
            return f"Arm: Mode {self.mode.name} not armable"
        self.armed = True
        self._idle_since_s = kin.time_s
        if self.landed:
            self.home_ned_m = (kin.pos_ned_m[0], kin.pos_ned_m[1], kin.pos_ned_m[2])
            self._phase = _Phase.IDLE
            self._set(pos=kin.pos_ned_m, yaw=kin.yaw_rad)
        else:
            self._enter_mode(kin)
        return None

    def disarm(self, kin: Kinematics, *, force: bool = False) -> str | None:
        """Disarm the motors (in the air only with ``force``); returns a refusal or None."""
        if not self.armed:
            return None
        if not force and not self.landed:
            return "Disarm: vehicle in the air (use force)"
        self.armed = False
        self._phase = _Phase.IDLE
        return None

    def set_mode(self, mode: FlightMode, kin: Kinematics) -> str | None:
        """Switch mode; returns a refusal reason or None."""
        mode = FlightMode(mode)
        if mode is FlightMode.AUTO:
            return "Mode change to AUTO failed: no mission"
        self.mode = mode
        self._enter_mode(kin)
        return None

    def takeoff(self, alt_m: float, kin: Kinematics) -> str | None:
        """NAV_TAKEOFF to ``alt_m`` above home (GUIDED, armed, landed)."""
        if self.mode is not FlightMode.GUIDED:
            return f"Takeoff: not in GUIDED (mode {self.mode.name})"
        if not self.armed:
            return "Takeoff: motors not armed"
        if not self.landed:
            return "Takeoff: already flying"
        if not (math.isfinite(alt_m) and alt_m > 0.0):
            return f"Takeoff: bad altitude {alt_m!r}"
        self.landed = False
        self._ground_since_s = None
        self._goal_down_m = self.home_ned_m[2] - alt_m
        self._start_ramp(kin, (kin.pos_ned_m[0], kin.pos_ned_m[1]))
        self._phase = _Phase.TAKEOFF
        return None

    def guided_target(self, target: GuidedTarget, kin: Kinematics) -> str | None:
        """Accept a GUIDED target (SET_POSITION_TARGET_LOCAL_NED); refusal or None."""
        if self.mode is not FlightMode.GUIDED:
            return f"Guided target ignored: mode {self.mode.name}"
        if not self.armed or self.landed:
            return "Guided target ignored: not flying (arm and take off first)"
        yaw = target.yaw_rad
        if target.pos_ned_m is not None:
            if self.timings.guided_shaping:
                if self._phase is not _Phase.GUIDED_POS:
                    # ArduCopter's pos_control_start: limits back to the parameters
                    self.speed_override = {}
                    self._start_shaping(kin, self._guided_limits())
                self.shaper.go_to(target.pos_ned_m)
            self._phase = _Phase.GUIDED_POS
            if yaw is None and target.yaw_rate_radps is None:
                dn = target.pos_ned_m[0] - kin.pos_ned_m[0]
                de = target.pos_ned_m[1] - kin.pos_ned_m[1]
                if math.hypot(dn, de) > self.timings.face_target_min_dist_m:
                    yaw = math.atan2(de, dn)
        elif target.vel_ned_mps is not None:
            self._phase = _Phase.GUIDED_VEL
            self._vel_target_time_s = kin.time_s
            v = target.vel_ned_mps
            if (
                yaw is None
                and target.yaw_rate_radps is None
                and _hspeed(v) > self.timings.face_velocity_min_mps
            ):
                yaw = math.atan2(v[1], v[0])
        else:
            # yaw / yaw-rate only: keep what is tracked, change the heading
            self._target_yaw = (yaw, target.yaw_rate_radps)
            self.setpoint = Setpoint(
                pos_ned_m=self.setpoint.pos_ned_m,
                vel_ned_mps=self.setpoint.vel_ned_mps,
                yaw_rad=yaw,
                yaw_rate_radps=target.yaw_rate_radps,
            )
            return None
        if target.pos_ned_m is not None:
            self._target_yaw = (yaw, target.yaw_rate_radps)
            if self.timings.guided_shaping:
                self._follow_shaper()
            else:  # the target straight to the LQ loop: the airframe's own limits
                self._set(pos=target.pos_ned_m, yaw=yaw, yaw_rate=target.yaw_rate_radps)
            return None
        self._set(vel=target.vel_ned_mps, yaw=yaw, yaw_rate=target.yaw_rate_radps)
        return None

    def change_speed(self, kind: str, speed_mps: float) -> str | None:
        """MAV_CMD_DO_CHANGE_SPEED: ``kind`` is ``"ne"`` (param1 0 or 1), ``"up"`` (2) or
        ``"down"`` (3); applies to GUIDED's position controller until it restarts, as
        ArduCopter's ``ModeGuided::set_speed_xy_cms`` & co. Refusal or None."""
        if not (math.isfinite(speed_mps) and speed_mps > 0.0):
            return f"Change speed: bad speed {speed_mps!r}"
        if not self.timings.guided_shaping:
            return "Change speed: GUIDED flies at the airframe's limits (SIM_GUID_SHAPE 0)"
        if self.mode is not FlightMode.GUIDED:
            return f"Change speed: not in GUIDED (mode {self.mode.name})"
        field = {"ne": "speed_ne_mps", "up": "speed_up_mps", "down": "speed_down_mps"}[kind]
        self.speed_override[field] = float(speed_mps)
        # ArduCopter's set_speed_up_cms restores the default descent speed, and
        # set_speed_down_cms the default climb speed (mode_guided.cpp): one at a time
        other = {"up": "speed_down_mps", "down": "speed_up_mps"}.get(kind)
        if other is not None:
            self.speed_override.pop(other, None)
        self.shaper.set_limits(self._guided_limits())
        return None

    def _guided_limits(self) -> ShapingLimits:
        t = self.timings
        limits = replace(t.guided_limits, **self.speed_override)
        return replace(
            limits,
            accel_ne_mps2=min(limits.accel_ne_mps2, t.max_decel_mps2),
            jerk_ne_mps3=min(limits.jerk_ne_mps3, t.airframe_jerk_mps3),
            jerk_d_mps3=min(limits.jerk_d_mps3, t.airframe_jerk_mps3),
        )

    # ---- time ----------------------------------------------------------------------
    def update(self, kin: Kinematics) -> list[str]:
        """Advance phases and timers to ``kin.time_s``; returns notices for STATUSTEXT."""
        notices: list[str] = []
        t = self.timings
        # landing detector
        if kin.on_ground:
            if self._ground_since_s is None:
                self._ground_since_s = kin.time_s
        else:
            self._ground_since_s = None
        was_landed = self.landed
        if self._phase is not _Phase.TAKEOFF and self._ground_since_s is not None:
            if kin.time_s - self._ground_since_s >= t.land_detect_s:
                self.landed = True
        elif not kin.on_ground and self._height_above_ground(kin) > 0.3:
            self.landed = False
        if self.landed and not was_landed:
            self._idle_since_s = kin.time_s
            if self.armed and self._phase is _Phase.DESCEND:
                self.armed = False
                self._phase = _Phase.IDLE
                notices.append("Land complete, disarming")
            else:
                self._phase = _Phase.IDLE
                self._set(pos=kin.pos_ned_m, yaw=kin.yaw_rad)
        if not self.armed:
            self._phase = _Phase.IDLE
            return notices
        if self.landed and self._phase is _Phase.IDLE:
            if kin.time_s - self._idle_since_s >= t.disarm_delay_s:
                self.armed = False
                notices.append("Disarming: landed and idle")
            return notices
        if self.landed and self._phase is _Phase.DESCEND:
            self.armed = False
            self._phase = _Phase.IDLE
            notices.append("Land complete, disarming")
            return notices

        phase = self._phase
        if phase is _Phase.BRAKE or (phase is _Phase.GUIDED_POS and t.guided_shaping):
            self._step_shaper(kin)
            if phase is _Phase.BRAKE and not self.shaper.stopping:
                self._phase = _Phase.HOLD
                self._set(pos=tuple(self.shaper.pos_ned_m), yaw=self._yaw_rad)
        elif phase is _Phase.TAKEOFF:
            down = self._ramp_down(kin.time_s, t.takeoff_climb_mps)
            self._set(pos=(*self._ref_ne_m, down), vel=None, yaw=self._yaw_rad)
            if down == self._goal_down_m and abs(kin.pos_ned_m[2] - down) < 0.1:
                self._phase = _Phase.HOLD
                notices.append("Takeoff complete")
        elif phase is _Phase.GUIDED_VEL:
            if kin.time_s - self._vel_target_time_s > t.guided_velocity_timeout_s:
                notices.append("Guided velocity target timed out, braking")
                self._brake(kin)
        elif phase is _Phase.RTL_CLIMB:
            down = self._ramp_down(kin.time_s, t.takeoff_climb_mps)
            self._set(pos=(*self._ref_ne_m, down), yaw=self._yaw_rad)
            if down == self._goal_down_m and abs(kin.pos_ned_m[2] - down) < 0.2:
                self._rtl_return(kin)
        elif phase is _Phase.RTL_RETURN:
            dn = self.home_ned_m[0] - kin.pos_ned_m[0]
            de = self.home_ned_m[1] - kin.pos_ned_m[1]
            if math.hypot(dn, de) < 0.5 and _hspeed(kin.vel_ned_mps) < 0.3:
                notices.append("RTL: home reached, landing")
                self._descend(kin)
        elif phase is _Phase.DESCEND:
            down = self._ramp_down(kin.time_s, t.land_speed_mps)
            self._set(
                pos=(*self._ref_ne_m, down),
                vel=(0.0, 0.0, t.land_speed_mps) if down != self._goal_down_m else None,
                yaw=self._yaw_rad,
            )
        return notices

    # ---- internals -----------------------------------------------------------------
    def _height_above_ground(self, kin: Kinematics) -> float:
        if self._ground_down_m is None:
            return math.inf
        return self._ground_down_m - kin.pos_ned_m[2]

    def _set(self, *, pos=None, vel=None, yaw=None, yaw_rate=None, acc=None) -> None:
        if yaw is not None:
            self._yaw_rad = yaw
        self.setpoint = Setpoint(
            pos_ned_m=pos, vel_ned_mps=vel, yaw_rad=yaw, yaw_rate_radps=yaw_rate, acc_ned_mps2=acc
        )

    def _start_ramp(self, kin: Kinematics, ne: tuple[float, float]) -> None:
        self._ref_ne_m = ne
        self._ref_down_m = kin.pos_ned_m[2]
        self._ref_time_s = kin.time_s
        self._yaw_rad = kin.yaw_rad

    def _ramp_down(self, time_s: float, speed_mps: float) -> float:
        """Reference down coordinate moving from the ramp start towards the goal."""
        travel = speed_mps * max(0.0, time_s - self._ref_time_s)
        start, goal = self._ref_down_m, self._goal_down_m
        if goal >= start:
            return min(goal, start + travel)
        return max(goal, start - travel)

    def _start_shaping(self, kin: Kinematics, limits: ShapingLimits) -> None:
        """Put the shaped reference on the vehicle, with ``limits``."""
        self.shaper.set_limits(limits)
        self.shaper.reset(kin.pos_ned_m, kin.vel_ned_mps)
        self._shaper_time_s = kin.time_s
        self._target_yaw = (self._yaw_rad, None)

    def _step_shaper(self, kin: Kinematics) -> None:
        dt = kin.time_s - self._shaper_time_s
        self._shaper_time_s = kin.time_s
        behind = None
        if kin.tilt_saturated:
            lead = math.dist(self.shaper.pos_ned_m, kin.pos_ned_m)
            if lead > self.timings.saturated_lead_m:
                behind = kin.pos_ned_m
        self.shaper.step(dt, hold_ahead_ned_m=behind, vehicle_vel_ned_mps=kin.vel_ned_mps)
        self._follow_shaper()

    def _follow_shaper(self) -> None:
        """Track the shaped reference: its position, its velocity and acceleration as
        feed-forward (the LQ tracker's ``x_d``, ``u_d``)."""
        yaw, yaw_rate = self._target_yaw
        self._set(
            pos=tuple(self.shaper.pos_ned_m),
            vel=tuple(self.shaper.vel_ned_mps),
            acc=tuple(self.shaper.acc_ned_mps2),
            yaw=yaw,
            yaw_rate=yaw_rate,
        )

    def _brake(self, kin: Kinematics, profile: BrakeProfile | None = None) -> None:
        """Decelerate by ``profile`` (default: GUIDED's WPNAV_ACCEL and jerk), then hold."""
        t = self.timings
        if profile is None:
            limits = self._guided_limits()
            profile = BrakeProfile(limits.accel_ne_mps2, limits.jerk_ne_mps3)
        profile = replace(
            profile,
            decel_mps2=min(profile.decel_mps2, t.max_decel_mps2),
            jerk_mps3=min(profile.jerk_mps3, t.airframe_jerk_mps3),
        )
        self._phase = _Phase.BRAKE
        self._start_shaping(kin, self._guided_limits())
        self._target_yaw = (kin.yaw_rad, None)
        self.shaper.stop(profile)
        self._follow_shaper()

    def _descend(self, kin: Kinematics) -> None:
        self._phase = _Phase.DESCEND
        self._start_ramp(kin, (kin.pos_ned_m[0], kin.pos_ned_m[1]))
        if self._ground_down_m is None:
            self._goal_down_m = math.inf
        else:
            # aim 1 m into the ground so touchdown is firm; the ground stops the vehicle
            self._goal_down_m = self._ground_down_m + 1.0
        self._set(pos=kin.pos_ned_m, vel=(0.0, 0.0, self.timings.land_speed_mps), yaw=kin.yaw_rad)

    def _rtl_return(self, kin: Kinematics) -> None:
        self._phase = _Phase.RTL_RETURN
        home = self.home_ned_m
        dn, de = home[0] - kin.pos_ned_m[0], home[1] - kin.pos_ned_m[1]
        yaw = math.atan2(de, dn) if math.hypot(dn, de) > 2.0 else kin.yaw_rad
        self._set(pos=(home[0], home[1], self._goal_down_m), yaw=yaw)

    def _enter_mode(self, kin: Kinematics) -> None:
        """Set the phase and setpoint for entering ``self.mode`` from ``kin``."""
        if not self.armed:
            self._phase = _Phase.IDLE
            return
        if self.landed:
            if self.mode in (FlightMode.LAND, FlightMode.RTL):
                self._phase = _Phase.DESCEND  # already down: disarms at the next update
            else:
                self._phase = _Phase.IDLE
                self._set(pos=kin.pos_ned_m, yaw=kin.yaw_rad)
            return
        mode = self.mode
        if mode is FlightMode.LAND:
            self._descend(kin)
        elif mode is FlightMode.RTL:
            floor_down = self.home_ned_m[2] - self.timings.rtl_alt_m
            self._start_ramp(kin, (kin.pos_ned_m[0], kin.pos_ned_m[1]))
            self._goal_down_m = min(floor_down, kin.pos_ned_m[2])
            self._phase = _Phase.RTL_CLIMB
            self._set(pos=kin.pos_ned_m, yaw=kin.yaw_rad)
        elif mode is FlightMode.BRAKE:
            self._brake(kin, self.timings.brake)
        elif mode is FlightMode.LOITER:
            self._brake(kin, self.timings.loiter)
        else:  # GUIDED, STABILIZE: stop, then hold
            self.speed_override = {}
            self._brake(kin)
