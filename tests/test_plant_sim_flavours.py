"""Conformance of plant-sim's autopilot flavours (``plant_sim.autopilot.flavours``) to the
companion's profiles of the same autopilots (``companion.link.flavour.PROFILES``).

Every :class:`AutopilotFlavour` subclass is found by discovery, not by a list. Each must:
announce itself in HEARTBEAT as the autopilot the companion detects; accept the
companion's control mode as the companion sends it (DO_SET_MODE parameters, after a setpoint
stream where the profile streams) and fly its setpoints there; accept the companion's
failsafe hold mode and brake in it; and name its modes as the companion does.
"""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.flavour import detect_flavour, profile_for
from plant_sim.autopilot import commands as cmds
from plant_sim.autopilot import flavours
from plant_sim.autopilot.flavours import (
    FLAVOUR_NAMES,
    AutopilotFlavour,
    flavour_for,
    param_specs_for,
)
from plant_sim.autopilot.modes import (
    FlightMode,
    FlightModeMachine,
    GuidedTarget,
    Kinematics,
    ModeTimings,
)
from plant_sim.autopilot.params import ParamTable
from plant_sim.autopilot.telemetry import TelemetryBuilder, VehicleIdentity


def _all_subclasses(cls) -> set[type]:
    found = set(cls.__subclasses__())
    for sub in list(found):
        found |= _all_subclasses(sub)
    return found


STRATEGIES = sorted(
    (c for c in _all_subclasses(AutopilotFlavour) if c.__module__ == flavours.__name__),
    key=lambda c: c.name,
)


def _kin(t: float, pos=(0.0, 0.0, -7.0), vel=(0.0, 0.0, 0.0)) -> Kinematics:
    return Kinematics(t, pos, vel, 0.0, False)


def _flying(name: str):
    params = ParamTable(extra_specs=param_specs_for(name))
    machine = FlightModeMachine(
        ModeTimings(),
        home_ned_m=(0.0, 0.0, 0.0),
        ground_down_m=0.0,
        mode=FlightMode.LOITER,
        armed=True,
        kin=_kin(0.0),
    )
    return flavour_for(name, machine, _kin(0.0), 488.0, params)


def test_every_strategy_is_selectable_by_name_and_every_name_has_one():
    assert {c.name for c in STRATEGIES} == set(FLAVOUR_NAMES)
    for cls in STRATEGIES:
        assert type(_flying(cls.name)) is cls
    with pytest.raises(ValueError, match="autopilot flavour"):
        _flying("inav")


@pytest.mark.parametrize("name", FLAVOUR_NAMES)
def test_the_companion_recognises_the_heartbeat(name):
    flavour = _flying(name)
    hb = flavour.heartbeat(_telemetry())
    assert hb.type == mavlink.MAV_TYPE_QUADROTOR
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    profile = profile_for(detect_flavour(hb.autopilot))
    assert profile.flavour.value == name
    assert profile.mode_name(hb.custom_mode) == flavour.mode_name()


@pytest.mark.parametrize("name", FLAVOUR_NAMES)
def test_the_companions_control_and_hold_modes_are_accepted_and_flown(name):
    """DO_SET_MODE as the companion sends it: control mode (after the stream it needs),
    a setpoint flown there, then the failsafe hold mode, which brakes to a stop."""
    flavour = _flying(name)
    profile = profile_for(detect_flavour(flavour.heartbeat(_telemetry()).autopilot))
    target = GuidedTarget(pos_ned_m=(5.0, 0.0, -7.0))
    if profile.streams_setpoints:
        for k in range(20):
            flavour.setpoint(target, _kin(0.05 * k))
    outcome = _do_set_mode(flavour, profile.control_mode, _kin(1.0))
    assert outcome.result is cmds.MavResult.ACCEPTED, outcome
    assert flavour.mode_name() == profile.control_mode.name
    assert flavour.setpoint(target, _kin(1.0)) is None
    assert flavour.machine.reported_target.pos_ned_m == target.pos_ned_m
    moving = _kin(1.5, pos=(1.0, 0.0, -7.0), vel=(1.5, 0.0, 0.0))
    outcome = _do_set_mode(flavour, profile.hold_mode, moving)
    assert outcome.result is cmds.MavResult.ACCEPTED, outcome
    assert flavour.mode_name() == profile.hold_mode.name
    assert flavour.machine.mode in (FlightMode.BRAKE, FlightMode.LOITER)
    for k in range(1, 101):  # 2 s of the autopilot's ticks: the brake ends in a hold
        flavour.machine.update(_kin(1.5 + 0.02 * k, pos=(1.0, 0.0, -7.0)))
    held = flavour.machine.reported_target.pos_ned_m
    # stopped ahead of where the hold began (braking from 1.5 m/s at most 0.8·g·tan 15° =
    # 2.1 m/s², jerk-limited: BRAKE in 1.2 m, PX4's Hold with LOITER's softer braking in
    # 1.7 m), well short of the target at 5 m
    assert 1.0 < held[0] < 3.0, held
    flavour.machine.update(_kin(3.6, pos=(1.0, 0.0, -7.0)))
    assert flavour.machine.reported_target.pos_ned_m == held  # holding


def _telemetry() -> TelemetryBuilder:
    return TelemetryBuilder(VehicleIdentity(47.0, 8.0, 488.0))


def _do_set_mode(flavour: AutopilotFlavour, request, kin: Kinematics) -> cmds.CommandOutcome:
    params = (*request.command_params, 0.0, 0.0, 0.0, 0.0, 0.0)[:7]
    outcome = flavour.command(cmds.MavCmd.DO_SET_MODE, params, kin)
    if outcome is None:  # the common handling (ArduCopter)
        outcome = cmds.handle_command(
            cmds.MavCmd.DO_SET_MODE,
            params,
            flavour.machine,
            kin,
            arming_checks=False,
            known_message_ids=frozenset(),
        )
    return outcome
