"""How each autopilot flies the pilot's sticks: limits, stick expiry, proximity and avoidance.

Strategies of :class:`~plant_sim.autopilot.pilot_flight.PilotFlight`, one per flavour (a
flavour strategy of :mod:`plant_sim.autopilot.flavours` names its rules in
``pilot_rules``), so the pilot's flight never branches on the flavour. Pure: parameters
from the table, time passed in.

- ArduCopter (:class:`ArduCopterPilotRules`): LOITER at ``LOIT_SPEED`` /
  ``LOIT_ACC_MAX``, throttle at ``PILOT_SPEED_UP`` / ``PILOT_SPEED_DN``, sticks expire after
  ``RC_OVERRIDE_TIME``, proximity faces low-passed at ``PRX_FILT``, simple avoidance
  (:mod:`.simple_avoid`), and the proximity pre-arm check (``AP_Proximity::prearm_healthy``).
- PX4 (:class:`Px4PilotRules`): Position mode at ``MPC_VEL_MANUAL`` / ``MPC_ACC_HOR``,
  climb ``MPC_Z_VEL_MAX_UP`` 3 m/s and sink ``MPC_Z_VEL_MAX_DN`` 1 m/s (PX4 defaults),
  manual control lost after 3 s (``COM_RC_LOSS_T``'s default), Collision Prevention
  (:mod:`.collision_prevention`) on the 72 bins; no proximity pre-arm check.
"""

from __future__ import annotations

from plant_sim.autopilot.collision_prevention import constrain_velocity, cp_params
from plant_sim.autopilot.modes import Kinematics
from plant_sim.autopilot.params import ParamTable
from plant_sim.autopilot.pilot_input import PilotInput, Sticks
from plant_sim.autopilot.proximity import ProximityReceiver
from plant_sim.autopilot.simple_avoid import SimpleAvoid, avoid_params

__all__ = ["ArduCopterPilotRules", "PilotRules", "Px4PilotRules"]

_PX4_CLIMB_MPS = 3.0  # MPC_Z_VEL_MAX_UP
_PX4_SINK_MPS = 1.0  # MPC_Z_VEL_MAX_DN
_PX4_STICK_TIMEOUT_S = 3.0  # COM_RC_LOSS_T


class PilotRules:
    """The contract of a flavour's pilot rules (each method pure)."""

    #: ALT_HOLD takes the sticks as lean angles (ArduCopter); PX4 has no such mode here
    flies_alt_hold: bool = False

    def prearm_checks_proximity(self, params: ParamTable) -> bool:
        """Arming needs fresh proximity data."""
        raise NotImplementedError

    def configure(self, sticks: PilotInput, proximity: ProximityReceiver, params: ParamTable):
        """Apply the parameters that set stick expiry and proximity filtering (each tick)."""
        raise NotImplementedError

    def limits(self, params: ParamTable, sticks: Sticks) -> tuple[float, float, float]:
        """``(speed_mps, accel_mps2, climb_mps)``: the horizontal speed at full stick, the
        acceleration toward it and the vertical speed at full throttle (up or down as the
        sticks say)."""
        raise NotImplementedError

    def avoid(
        self,
        vel_ne_mps: tuple[float, float],
        kin: Kinematics,
        proximity: ProximityReceiver,
        simple_avoid: SimpleAvoid,
        params: ParamTable,
        now_wall_s: float,
        dt: float,
    ) -> tuple[float, ...]:
        """The pilot's horizontal velocity after the autopilot's own avoidance [m/s, NED]."""
        raise NotImplementedError


class ArduCopterPilotRules(PilotRules):
    """ArduCopter's LOITER (and ALT_HOLD) with simple avoidance."""

    flies_alt_hold = True

    def prearm_checks_proximity(self, params: ParamTable) -> bool:
        return params.value("PRX1_TYPE") != 0 and params.value("ARMING_CHECK") != 0

    def configure(self, sticks: PilotInput, proximity: ProximityReceiver, params: ParamTable):
        sticks.timeout_s = params.value("RC_OVERRIDE_TIME")
        proximity.filter_hz = params.value("PRX_FILT")

    def limits(self, params: ParamTable, sticks: Sticks) -> tuple[float, float, float]:
        speed = params.value("LOIT_SPEED") / 100.0
        accel = params.value("LOIT_ACC_MAX") / 100.0
        up = params.value("PILOT_SPEED_UP") / 100.0
        down = params.value("PILOT_SPEED_DN") / 100.0 or up
        return speed, accel, up if sticks.up > 0 else down

    def avoid(self, vel_ne_mps, kin, proximity, simple_avoid, params, now_wall_s, dt):
        faces = proximity.ardupilot_faces(now_wall_s)
        return simple_avoid.adjust(
            vel_ne_mps, kin.yaw_rad, faces, avoid_params(params), kin.time_s, dt
        )


class Px4PilotRules(PilotRules):
    """PX4's Position mode with Collision Prevention."""

    def prearm_checks_proximity(self, params: ParamTable) -> bool:
        return False

    def configure(self, sticks: PilotInput, proximity: ProximityReceiver, params: ParamTable):
        sticks.timeout_s = _PX4_STICK_TIMEOUT_S

    def limits(self, params: ParamTable, sticks: Sticks) -> tuple[float, float, float]:
        climb = _PX4_CLIMB_MPS if sticks.up > 0 else _PX4_SINK_MPS
        return params.value("MPC_VEL_MANUAL"), params.value("MPC_ACC_HOR"), climb

    def avoid(self, vel_ne_mps, kin, proximity, simple_avoid, params, now_wall_s, dt):
        bins, range_m = proximity.px4_bins(now_wall_s, kin.yaw_rad)
        age_s = proximity.age_s(now_wall_s)
        fov = proximity.px4_fov
        return constrain_velocity(
            vel_ne_mps, kin.yaw_rad, bins, range_m, age_s, cp_params(params), fov
        )
