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

ALT_HOLD (ArduCopter, armed and airborne; ``ArduCopter/mode_althold.cpp``): the sticks
are lean angles, ``ANGLE_MAX`` at full deflection with a circular limit and the lateral
tilt turned into an Euler roll (``Mode::get_pilot_desired_lean_angles``); simple
avoidance then leans the vehicle away from near faces
(:func:`~plant_sim.autopilot.simple_avoid.adjust_roll_pitch`). Nothing holds the
position: the lean is flown as the acceleration it gives at constant altitude, forward
``−g·tan(pitch)`` and right ``g·tan(roll)/cos(pitch)``, less the airframe's drag on the
ground velocity (``drag_per_s``: the controller's feedback linearization cancels drag, so
it is put back), and the velocity so integrated is the setpoint (as in LOITER above).
Centred sticks level the vehicle and it drifts to rest on its drag.

Not modelled: ArduCopter's stick-to-lean-angle shaping of AC_Loiter (its drag term and
``LOIT_ANG_MAX``; here the stick sets the velocity target directly) and what
``AC_Loiter::calc_desired_velocity`` then hands the position controller
(``set_pos_vel_accel_NE_cm``): a position target integrated from the avoided velocity,
not re-anchored on the vehicle, and the pilot's acceleration as feed-forward, *not* limited
by avoidance ("TODO: We need to also limit the _desired_accel" in ArduPilot's source) —
here the vehicle tracks the avoided velocity with its own change as feed-forward, so a
held stick does not push against the avoidance's stop as it may on ArduCopter; STABILIZE with pilot
input, ALT_HOLD's throttle-limited lean angle (``get_althold_lean_angle_max``), PX4's
jerk-limited stick shaping.

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
from plant_sim.autopilot.simple_avoid import SimpleAvoid, adjust_roll_pitch, avoid_params
from plant_sim.vehicle import Setpoint
from protocols.mavlink_modes import Px4Main

__all__ = ["PRX_NO_DATA_TEXT", "PilotFlight"]

PRX_NO_DATA_TEXT = "PRX1: No Data"
_LEASH_M = 1.0
_YAW_RATE_RADPS = math.radians(90.0)
_G_MPS2 = 9.80665


class PilotFlight:
    """Sticks, proximity data and the avoidance that flies them (one per vehicle).

    Parameters
    ----------
    rules : PilotRules
        The flavour's limits, stick expiry and avoidance
        (:mod:`plant_sim.autopilot.pilot_rules`: ArduCopter's LOITER with simple avoidance,
        PX4's Position mode with Collision Prevention).
    drag_per_s : float
        The airframe's horizontal drag over its mass [1/s] (ALT_HOLD's lean).
    """

    def __init__(self, rules: PilotRules, drag_per_s: float = 0.0) -> None:
        self.rules = rules
        self.drag_per_s = drag_per_s
        self.sticks_in = PilotInput()
        self.proximity = ProximityReceiver()
        self.avoid = SimpleAvoid()
        self.setpoint: Setpoint | None = None  # what the pilot flies now (None: the mode)
        self._vel_ne = (0.0, 0.0)
        self._ref: list[float] = [0.0, 0.0, 0.0]
        self.limited_ticks = 0  # ticks in which avoidance changed the pilot's velocity
        self.stale_ticks = 0  # pilot-flown ticks without fresh proximity data (0.5 s rule)

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
        """The mode takes the pilot's sticks (LOITER, ALT_HOLD where the rules fly it; PX4:
        POSCTL), armed and flying."""
        if not machine.armed or machine.landed:
            return False
        if machine.mode is FlightMode.ALT_HOLD:
            return self.rules.flies_alt_hold
        return machine.mode is FlightMode.LOITER and (
            px4_main is None or px4_main is Px4Main.POSCTL
        )

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
        if machine.mode is FlightMode.ALT_HOLD:
            if self.setpoint is None:
                self._vel_ne = (kin.vel_ned_mps[0], kin.vel_ned_mps[1])
                self._ref = list(kin.pos_ned_m)
            self._lean(kin, sticks, params, now_wall_s, dt)
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
        self._track(kin, vel, (an, ae), -sticks.up * climb, sticks.yaw, dt)

    def _lean(self, kin, sticks: Sticks, params: ParamTable, now_wall_s: float, dt) -> None:
        """ALT_HOLD: the sticks' lean angles, leaned away from near faces, flown as the
        acceleration they give (module docstring)."""
        angle_max = math.radians(params.value("ANGLE_MAX") / 100.0)
        roll, pitch = sticks.right * angle_max, -sticks.forward * angle_max
        total = math.hypot(roll, pitch)
        if total > angle_max:
            roll, pitch = roll * angle_max / total, pitch * angle_max / total
        roll = math.atan(math.cos(pitch) * math.tan(roll))  # lateral tilt → Euler roll
        if not self.proximity.fresh(now_wall_s):
            self.stale_ticks += 1
        faces = self.proximity.ardupilot_faces(now_wall_s)
        adjusted = adjust_roll_pitch(roll, pitch, angle_max, faces, avoid_params(params))
        if adjusted != (roll, pitch):
            self.limited_ticks += 1
        roll, pitch = adjusted
        fwd, right = -_G_MPS2 * math.tan(pitch), _G_MPS2 * math.tan(roll) / math.cos(pitch)
        c, s = math.cos(kin.yaw_rad), math.sin(kin.yaw_rad)
        v = kin.vel_ned_mps
        an = c * fwd - s * right - self.drag_per_s * v[0]
        ae = s * fwd + c * right - self.drag_per_s * v[1]
        vel = (v[0] + an * dt, v[1] + ae * dt)
        up = params.value("PILOT_SPEED_UP") / 100.0
        climb = up if sticks.up > 0 else (params.value("PILOT_SPEED_DN") / 100.0 or up)
        self._track(kin, vel, (an, ae), -sticks.up * climb, sticks.yaw, dt)

    def _track(self, kin, vel, acc_ne, vd: float, yaw_stick: float, dt: float) -> None:
        """The setpoint that flies horizontal velocity ``vel`` with feed-forward
        ``acc_ne`` and climbs at ``-vd``, turning at the yaw stick's rate."""
        self._vel_ne = vel
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
            acc_ned_mps2=(acc_ne[0], acc_ne[1], 0.0),
            yaw_rate_radps=yaw_stick * _YAW_RATE_RADPS,
        )

    def _avoid(self, vel, kin: Kinematics, params: ParamTable, now_wall_s: float, dt: float):
        if not self.proximity.fresh(now_wall_s):
            self.stale_ticks += 1
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
            "proximity_stale_ticks": self.stale_ticks,
        }
