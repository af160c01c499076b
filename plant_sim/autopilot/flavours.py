"""Autopilot flavours as strategies: what plant-sim does differently as ArduCopter or PX4.

Pure. The service (:mod:`plant_sim.service`) holds one :class:`AutopilotFlavour`, chosen by
``--autopilot-flavour`` (:func:`flavour_for`), and never branches on the flavour itself;
the companion's counterpart is :class:`companion.link.flavour.AutopilotProfile`. Both
flavours drive the same :class:`~plant_sim.autopilot.modes.FlightModeMachine` (the flight
logic); a flavour owns:

* its extra parameters (ArduCopter's AVOID_*/PRX*, PX4's COM_OF_LOSS_T, MIS_TAKEOFF_ALT
  and CP_*) and the mode it starts in (PX4: Hold);
* the HEARTBEAT (autopilot type and ``custom_mode`` numbering) and the mode's name in logs;
* mode requests (SET_MODE, DO_SET_MODE: ArduCopter reads param2 as the custom mode, PX4
  param2/param3 as main/sub mode) and the commands PX4 handles its own way (NAV_TAKEOFF
  with an AMSL altitude, NAV_LAND, NAV_RETURN_TO_LAUNCH);
* setpoints (ArduCopter flies them in GUIDED; PX4 counts them for the offboard stream
  and flies them in OFFBOARD only) and the per-tick rules (PX4's offboard loss);
* which pilot mode the sticks fly (:class:`~plant_sim.autopilot.pilot_flight.PilotFlight`
  reads PX4's main mode, None for ArduCopter).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from plant_sim.autopilot import commands as cmds
from plant_sim.autopilot.collision_prevention import CP_PARAM_SPECS
from plant_sim.autopilot.integrator import NO_VELOCITY_INTEGRATOR
from plant_sim.autopilot.modes import (
    FlightMode,
    FlightModeMachine,
    GuidedTarget,
    Kinematics,
    ModeTimings,
)
from plant_sim.autopilot.params import ParamSpec, ParamTable
from plant_sim.autopilot.px4 import PX4_PARAM_SPECS, Px4Main, Px4Modes, rules_from_params
from plant_sim.autopilot.simple_avoid import AVOID_PARAM_SPECS
from plant_sim.autopilot.telemetry import TelemetryBuilder
from protocols.mavlink_modes import px4_custom_mode

__all__ = [
    "FLAVOUR_NAMES",
    "ArduCopterFlavour",
    "AutopilotFlavour",
    "Px4Flavour",
    "flavour_class",
    "flavour_for",
    "param_specs_for",
]

#: the names ``--autopilot-flavour`` accepts
FLAVOUR_NAMES = ("ardupilot", "px4")


class AutopilotFlavour:
    """The contract of a flavour (ArduCopter's behaviour is the default of each hook).

    Every call is simulation time (``kin.time_s``); none does I/O.
    """

    name = "ardupilot"
    #: parameters beside the common ArduCopter-named ones
    param_specs: tuple[ParamSpec, ...] = AVOID_PARAM_SPECS
    #: the pilot's sticks and proximity follow PX4's rules (Position mode, CP_*)
    px4_pilot = False

    def __init__(self, machine: FlightModeMachine) -> None:
        self.machine = machine

    @classmethod
    def timings(cls, timings: ModeTimings) -> ModeTimings:
        """The mode logic's timings as this autopilot flies them: ArduCopter shapes a GUIDED
        position target (:mod:`plant_sim.autopilot.shaping`)."""
        return timings

    # ---- what the service reads ----------------------------------------------------
    def heartbeat(self, telemetry: TelemetryBuilder) -> mavlink.MAVLink_heartbeat_message:
        """This autopilot's HEARTBEAT."""
        return telemetry.heartbeat(self.machine)

    def mode_name(self) -> str:
        """The flight mode's name (logs, truth CSV)."""
        return self.machine.mode.name

    @property
    def pilot_main(self) -> Px4Main | None:
        """PX4's main mode for the pilot's sticks; None: ArduCopter's modes decide."""
        return None

    # ---- inputs --------------------------------------------------------------------
    def set_mode(self, base_mode: int, custom_mode: int, kin: Kinematics) -> cmds.CommandOutcome:
        """The legacy SET_MODE message."""
        return cmds.handle_set_mode(base_mode, custom_mode, self.machine, kin)

    def command(
        self, command: int, params: Sequence[float], kin: Kinematics
    ) -> cmds.CommandOutcome | None:
        """A command this flavour handles its own way; None: the common handling."""
        return None

    def setpoint(self, target: GuidedTarget, kin: Kinematics) -> str | None:
        """A decoded position target; returns a refusal or None."""
        return self.machine.guided_target(target, kin)

    def update(self, kin: Kinematics, notices: list[str], home_amsl_m: float) -> list[str]:
        """After the machine's own update; returns warnings for STATUSTEXT."""
        return []

    def params_changed(self, params: ParamTable) -> None:
        """A parameter was set: re-read what this flavour takes from the table."""


class ArduCopterFlavour(AutopilotFlavour):
    """ArduCopter: custom modes as in ``mode.h``, GUIDED targets, AVOID_*/PRX* parameters."""


class Px4Flavour(AutopilotFlavour):
    """PX4: packed main/sub modes, offboard rules, AMSL takeoff (:mod:`plant_sim.autopilot.px4`).

    Parameters
    ----------
    machine : the flight logic.
    kin : the vehicle now; PX4 starts in Hold (AUTO_LOITER).
    home_amsl_m : AMSL altitude of home [m].
    params : the parameter table (COM_OF_LOSS_T, MIS_TAKEOFF_ALT).
    """

    name = "px4"
    param_specs = PX4_PARAM_SPECS + CP_PARAM_SPECS
    px4_pilot = True

    @classmethod
    def timings(cls, timings: ModeTimings) -> ModeTimings:
        """OFFBOARD position setpoints unshaped: PX4's mc_pos_control takes an offboard
        trajectory setpoint as it comes (no smoothing; MPC_XY_CRUISE, MPC_ACC_HOR and
        MPC_JERK_AUTO shape its Auto modes, not OFFBOARD) and in OFFBOARD overrides the
        speed constraints with MPC_XY_VEL_MAX, MPC_Z_VEL_MAX_UP/DN
        (src/modules/mc_pos_control/MulticopterPositionControl.cpp, Run()); its P-PID
        cascade is the paper's LQ loop here, without its velocity integrator
        (MPC_XY_VEL_I_ACC is not modelled)."""
        return dataclasses.replace(
            timings, guided_shaping=False, velocity_integrator=NO_VELOCITY_INTEGRATOR
        )

    def __init__(
        self, machine: FlightModeMachine, kin: Kinematics, home_amsl_m: float, params: ParamTable
    ) -> None:
        super().__init__(machine)
        machine.set_mode(FlightMode.LOITER, kin)  # PX4 starts in Hold
        self.px4 = Px4Modes(machine, home_amsl_m, rules_from_params(params))

    def heartbeat(self, telemetry: TelemetryBuilder) -> mavlink.MAVLink_heartbeat_message:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.machine.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        state = mavlink.MAV_STATE_ACTIVE if self.machine.armed else mavlink.MAV_STATE_STANDBY
        return mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR,
            mavlink.MAV_AUTOPILOT_PX4,
            base,
            self.px4.custom_mode,
            state,
            3,
        )

    def mode_name(self) -> str:
        return self.px4.name

    @property
    def pilot_main(self) -> Px4Main | None:
        return self.px4.main

    def set_mode(self, base_mode: int, custom_mode: int, kin: Kinematics) -> cmds.CommandOutcome:
        if not base_mode & cmds.CUSTOM_MODE_ENABLED:
            return cmds.CommandOutcome(cmds.MavResult.DENIED, "Only custom modes are supported")
        ok, text, temporary = self.px4.set_mode(custom_mode, kin)
        if ok:
            return cmds.CommandOutcome(cmds.MavResult.ACCEPTED, text)
        result = cmds.MavResult.TEMPORARILY_REJECTED if temporary else cmds.MavResult.DENIED
        return cmds.CommandOutcome(result, text)

    def command(
        self, command: int, params: Sequence[float], kin: Kinematics
    ) -> cmds.CommandOutcome | None:
        """PX4's handling of the mode, takeoff, land and RTL commands."""
        px4 = self.px4
        if command == cmds.MavCmd.DO_SET_MODE:
            base, main, sub = params[0], params[1], params[2]
            if not all(math.isfinite(x) for x in (base, main, sub)):
                return cmds.CommandOutcome(cmds.MavResult.DENIED, "DO_SET_MODE: bad parameters")
            # PX4 (Commander) reads param2/param3 as uint8 main/sub mode
            custom = px4_custom_mode(int(main) & 0xFF, int(sub) & 0xFF)
            return self.set_mode(int(base), custom, kin)
        if command == cmds.MavCmd.NAV_TAKEOFF:
            return _outcome(px4.takeoff(params[6], kin))
        if command == cmds.MavCmd.NAV_LAND:
            return _outcome(px4.land(kin))
        if command == cmds.MavCmd.NAV_RETURN_TO_LAUNCH:
            return _outcome(px4.rtl(kin))
        return None

    def setpoint(self, target: GuidedTarget, kin: Kinematics) -> str | None:
        return self.px4.setpoint(target, kin)

    def update(self, kin: Kinematics, notices: list[str], home_amsl_m: float) -> list[str]:
        self.px4.home_amsl_m = home_amsl_m
        return self.px4.update(kin, notices)

    def params_changed(self, params: ParamTable) -> None:
        self.px4.rules = rules_from_params(params)


def _outcome(reason: str | None) -> cmds.CommandOutcome:
    result = cmds.MavResult.ACCEPTED if reason is None else cmds.MavResult.DENIED
    return cmds.CommandOutcome(result, reason)


def param_specs_for(name: str) -> tuple[ParamSpec, ...]:
    """The extra parameters of flavour ``name`` (the table is built before the flavour)."""
    return Px4Flavour.param_specs if name == "px4" else ArduCopterFlavour.param_specs


def flavour_class(name: str) -> type[AutopilotFlavour]:
    """The strategy class of ``--autopilot-flavour name`` (one of :data:`FLAVOUR_NAMES`)."""
    classes = {"ardupilot": ArduCopterFlavour, "px4": Px4Flavour}
    if name not in classes:
        raise ValueError(f"autopilot flavour must be one of {FLAVOUR_NAMES}, got {name!r}")
    return classes[name]


def flavour_for(
    name: str, machine: FlightModeMachine, kin: Kinematics, home_amsl_m: float, params: ParamTable
) -> AutopilotFlavour:
    """The strategy of ``--autopilot-flavour name`` (one of :data:`FLAVOUR_NAMES`)."""
    if name == "px4":
        return Px4Flavour(machine, kin, home_amsl_m, params)
    if name == "ardupilot":
        return ArduCopterFlavour(machine)
    raise ValueError(f"autopilot flavour must be one of {FLAVOUR_NAMES}, got {name!r}")
