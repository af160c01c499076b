"""Pilot-flown LOITER (ArduCopter) and Position mode (PX4) with the autopilot's own avoidance.

Pure apart from the parts it owns; simulation time (``kin.time_s``) for the flight and
wall time (``now_wall_s``) for the link rules (stick expiry, proximity freshness).

While the sticks are deflected in LOITER (ArduCopter) or POSCTL (PX4), the pilot flies:
the horizontal velocity target is the sticks times ``LOIT_SPEED`` / ``MPC_VEL_MANUAL``
(body axes, turned by the heading), approached at ``LOIT_ACC_MAX`` / ``MPC_ACC_HOR``
(at most what the airframe can do at its tilt limit); that velocity then passes the
autopilot's avoidance — ArduCopter's simple avoidance (:mod:`.simple_avoid`) or PX4's
Collision Prevention (:mod:`.collision_prevention`) on the proximity data
(:mod:`.proximity`) — and, as in ArduCopter's ``AC_Loiter`` (the avoided velocity
becomes the loiter's desired velocity), the result is the new velocity state. The
setpoint is that velocity, with the horizontal position reference one tick ahead of the
vehicle (no position error accumulates to pull it past the avoidance's limit) and the
altitude reference moved by the throttle (kept within 1 m, the controller's leash); the
velocity's change is fed forward as acceleration (ArduCopter's position controller is
fed the shaped velocity and acceleration). Throttle climbs at up to ``PILOT_SPEED_UP``
(2.5 m/s), yaw turns at up to 90°/s. When the sticks centre, the mode
is entered again from the current state: ArduCopter's LOITER braking and hold
(:mod:`plant_sim.autopilot.modes`; no avoidance while braking, named simplification).

Not modelled: ArduCopter's stick-to-lean-angle shaping of AC_Loiter (its drag term and
``LOIT_ANG_MAX``; here the stick sets the velocity target directly), ALT_HOLD and
STABILIZE with pilot input (non-GPS avoidance), PX4's jerk-limited stick shaping.

Pre-arm (ArduCopter, ``PRX1_TYPE = 2``, ``ARMING_CHECK`` ≠ 0): without proximity data in
the last 0.5 s arming is refused with "PRX1: No Data" (``AP_Proximity::prearm_healthy``).
"""

from __future__ import annotations

import math

from plant_sim.autopilot.modes import FlightMode, FlightModeMachine, Kinematics
from plant_sim.autopilot.params import ParamTable
from plant_sim.autopilot.pilot_input import PilotInput, Sticks
from plant_sim.autopilot.pilot_rules import PilotRules
from plant_sim.autopilot.proximity import ProximityReceiver
from plant_sim.autopilot.simple_avoid import SimpleAvoid
from plant_sim.vehicle import Setpoint
from protocols.mavlink_modes import Px4Main

__all__ = ["PRX_NO_DATA_TEXT", "PilotFlight"]

PRX_NO_DATA_TEXT = "PRX1: No Data"
_LEASH_M = 1.0
_YAW_RATE_RADPS = math.radians(90.0)


class PilotFlight:
    """Sticks, proximity data and the avoidance that flies them (one per vehicle).

    Parameters
    ----------
    rules : PilotRules
        The flavour's limits, stick expiry and avoidance
        (:mod:`plant_sim.autopilot.pilot_rules`: ArduCopter's LOITER with simple avoidance,
        PX4's Position mode with Collision Prevention).
    """

    def __init__(self, rules: PilotRules) -> None:
        self.rules = rules
        self.sticks_in = PilotInput()
        self.proximity = ProximityReceiver()
        self.avoid = SimpleAvoid()
        self.setpoint: Setpoint | None = None  # what the pilot flies now (None: the mode)
        self._vel_ne = (0.0, 0.0)
        self._ref: list[float] = [0.0, 0.0, 0.0]
        self.limited_ticks = 0  # ticks in which avoidance changed the pilot's velocity

    # ---- input ---------------------------------------------------------------------
    def on_message(self, msg, now_wall_s: float) -> str | None:
        """RC_CHANNELS_OVERRIDE, MANUAL_CONTROL or OBSTACLE_DISTANCE; a refusal or None."""
        mtype = msg.get_type()
        if mtype == "OBSTACLE_DISTANCE":
            return self.proximity.on_message(msg, now_wall_s)
        if mtype == "RC_CHANNELS_OVERRIDE":
            return self.sticks_in.on_rc_override(msg, now_wall_s)
        if mtype == "MANUAL_CONTROL":
            return self.sticks_in.on_manual_control(msg, now_wall_s)
        return None

    def prearm_failure(self, params: ParamTable, now_wall_s: float) -> str | None:
        """ArduCopter's proximity pre-arm check: the reason, or None when it passes."""
        if not self.rules.prearm_checks_proximity(params):
            return None
        return None if self.proximity.fresh(now_wall_s) else PRX_NO_DATA_TEXT

    # ---- flight --------------------------------------------------------------------
    def pilot_mode(self, machine: FlightModeMachine, px4_main: Px4Main | None) -> bool:
        """The mode takes the pilot's sticks (LOITER; PX4: POSCTL), armed and flying."""
        if not machine.armed or machine.landed or machine.mode is not FlightMode.LOITER:
            return False
        return px4_main is None or px4_main is Px4Main.POSCTL

    def step(
        self,
        kin: Kinematics,
        machine: FlightModeMachine,
        px4_main: Px4Main | None,
        params: ParamTable,
        now_wall_s: float,
        dt: float,
    ) -> None:
        """One autopilot tick: update :attr:`setpoint` (None: the mode's own)."""
        self.rules.configure(self.sticks_in, self.proximity, params)
        sticks = self.sticks_in.sticks(now_wall_s)
        if not self.pilot_mode(machine, px4_main):
            self.setpoint = None
            return
        if sticks.centred:
            if self.setpoint is not None:
                self.setpoint = None
                machine.set_mode(FlightMode.LOITER, kin)  # brake and hold from here
            return
        if self.setpoint is None:
            self._vel_ne = (kin.vel_ned_mps[0], kin.vel_ned_mps[1])
            self._ref = list(kin.pos_ned_m)
        self._fly(kin, sticks, machine, params, now_wall_s, dt)

    def _fly(self, kin, sticks: Sticks, machine, params: ParamTable, now_wall_s, dt) -> None:
        speed, accel, climb = self.rules.limits(params, sticks)
        accel = min(accel, machine.timings.max_decel_mps2)
        c, s = math.cos(kin.yaw_rad), math.sin(kin.yaw_rad)
        target = (
            speed * (c * sticks.forward - s * sticks.right),
            speed * (s * sticks.forward + c * sticks.right),
        )
        dvn, dve = target[0] - self._vel_ne[0], target[1] - self._vel_ne[1]
        step = math.hypot(dvn, dve)
        if step > accel * dt:
            dvn, dve = dvn * accel * dt / step, dve * accel * dt / step
        vel = (self._vel_ne[0] + dvn, self._vel_ne[1] + dve)
        vel = self._avoid(vel, kin, params, now_wall_s, dt)
        # the velocity's change as acceleration feed-forward (ArduCopter's position
        # controller is fed the shaped velocity and acceleration), at most ``accel``
        an, ae = (vel[0] - self._vel_ne[0]) / dt, (vel[1] - self._vel_ne[1]) / dt
        a = math.hypot(an, ae)
        if a > accel:
            an, ae = an * accel / a, ae * accel / a
        self._vel_ne = vel
        vd = -sticks.up * climb
        # horizontally the velocity is tracked (the reference is where the vehicle will
        # be at the next tick: no position error builds up to pull it past a limit the
        # avoidance set); vertically the altitude reference moves with the throttle
        down = self._ref[2] + vd * dt
        down = kin.pos_ned_m[2] + max(-_LEASH_M, min(_LEASH_M, down - kin.pos_ned_m[2]))
        self._ref = [kin.pos_ned_m[0] + vel[0] * dt, kin.pos_ned_m[1] + vel[1] * dt, down]
        ref = self._ref
        self.setpoint = Setpoint(
            pos_ned_m=(ref[0], ref[1], ref[2]),
            vel_ned_mps=(vel[0], vel[1], vd),
            acc_ned_mps2=(an, ae, 0.0),
            yaw_rate_radps=sticks.yaw * _YAW_RATE_RADPS,
        )

    def _avoid(self, vel, kin: Kinematics, params: ParamTable, now_wall_s: float, dt: float):
        out = self.rules.avoid(vel, kin, self.proximity, self.avoid, params, now_wall_s, dt)
        if out != tuple(vel):
            self.limited_ticks += 1
        return (float(out[0]), float(out[1]))

    def stats(self) -> dict:
        return {
            "obstacle_distance_received": self.proximity.received,
            "obstacle_distance_dropped": self.proximity.dropped,
            "pilot_inputs": self.sticks_in.received,
            "pilot_inputs_refused": self.sticks_in.refused,
            "avoidance_limited_ticks": self.limited_ticks,
        }
