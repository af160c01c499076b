"""Conformance of each autopilot profile (companion.link.flavour.PROFILES) to its contract.

Each profile is checked against the numbers its autopilot documents (DESIGN.md: ArduCopter
GUIDED 4, BRAKE 17; PX4 OFFBOARD main mode 6 << 16, setpoints streamed > 2 Hz before and
after the switch, Hold = AUTO_LOITER 4 << 16 | 3 << 24 from PX4's ``px4_custom_mode.h``),
and the companion's parts are checked to follow the profile: mode watch, setpoint policy
and takeoff behave as the profile says, for every profile.
"""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.flavour import PROFILES, Flavour, detect_flavour, profile_for
from companion.link.mode_watch import ControlPhase, ModeWatch
from companion.link.setpoints import PositionTarget, SetpointPolicy
from companion.link.takeoff import TakeoffCommand, TakeoffSequence, TakeoffSettings

ALL = sorted(PROFILES.values(), key=lambda p: p.flavour.value)
IDS = [p.flavour.value for p in ALL]

# what each autopilot's documentation says (the contract the profiles must meet)
EXPECTED = {
    Flavour.ARDUPILOT: {"control": (4, "GUIDED"), "hold": (17, "BRAKE"), "stream": False},
    Flavour.PX4: {
        "control": (6 << 16, "OFFBOARD"),
        "hold": (4 << 16 | 3 << 24, "AUTO_LOITER"),
        "stream": True,
    },
    Flavour.GENERIC: {"control": (4, "GUIDED"), "hold": (17, "BRAKE"), "stream": False},
}


def test_every_flavour_has_a_profile_and_heartbeats_select_it():
    assert set(PROFILES) == set(Flavour)
    assert profile_for(detect_flavour(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)).flavour is (
        Flavour.ARDUPILOT
    )
    assert profile_for(detect_flavour(mavlink.MAV_AUTOPILOT_PX4)).flavour is Flavour.PX4
    assert profile_for(detect_flavour(mavlink.MAV_AUTOPILOT_GENERIC)).flavour is (Flavour.GENERIC)


@pytest.mark.parametrize("profile", ALL, ids=IDS)
def test_mode_numbers_names_and_do_set_mode_parameters(profile):
    expected = EXPECTED[profile.flavour]
    ctrl = profile.control_mode
    assert (ctrl.custom_mode, ctrl.name) == expected["control"]
    assert profile.mode_name(ctrl.custom_mode) == ctrl.name
    assert profile.same_mode(ctrl.custom_mode, ctrl)
    assert not profile.same_mode(ctrl.custom_mode + (1 << 16 if profile.packed_modes else 1), ctrl)
    assert ctrl.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if profile.packed_modes:  # PX4 reads param2 = main mode, param3 = sub mode
        assert ctrl.command_params[1:] == (6.0, 0.0)
    else:
        assert ctrl.command_params[1] == float(ctrl.custom_mode)
    hold = profile.hold_mode
    if expected["hold"] is None:
        assert hold is None
    else:
        assert (hold.custom_mode, hold.name) == expected["hold"]
        assert profile.mode_name(hold.custom_mode) == hold.name
        assert profile.same_mode(hold.custom_mode, hold)
        assert not profile.same_mode(ctrl.custom_mode, hold)
        if profile.packed_modes:
            assert hold.command_params[1:] == (4.0, 3.0)  # main AUTO, sub AUTO_LOITER


@pytest.mark.parametrize("profile", ALL, ids=IDS)
def test_mode_watch_enters_the_control_mode_as_the_profile_says(profile):
    """Streaming profiles pre-stream before requesting the mode and may steer meanwhile;
    the others request the mode and steer only once it is confirmed."""
    watch = ModeWatch(request_mode=True, prestream_s=1.2)
    watch.on_heartbeat(0.0, profile.flavour, 0)  # some other mode
    streams = EXPECTED[profile.flavour]["stream"]
    assert profile.streams_setpoints is streams
    assert watch.phase is (ControlPhase.PRESTREAM if streams else ControlPhase.REQUESTED)
    assert watch.steering is streams
    request = watch.tick(0.1)
    assert (request is None) is streams  # pre-stream first
    if streams:
        request = watch.tick(1.3)
    assert request == profile.control_mode
    watch.on_heartbeat(1.5, profile.flavour, profile.control_mode.custom_mode)
    assert watch.phase is ControlPhase.ACTIVE and watch.steering
    hold_request = watch.set_hold(2.0, True)
    assert hold_request == profile.hold_mode
    assert watch.streaming_hold is streams
    watch.on_heartbeat(2.5, profile.flavour, profile.hold_mode.custom_mode)
    assert watch.phase is ControlPhase.HOLD  # the hold mode is ours, not a takeover
    assert watch.set_hold(3.0, False) == profile.control_mode  # released: control mode
    watch.on_heartbeat(3.5, profile.flavour, profile.control_mode.custom_mode)
    assert watch.phase is ControlPhase.ACTIVE


@pytest.mark.parametrize("profile", ALL, ids=IDS)
def test_setpoint_policy_follows_the_streaming_rule(profile):
    policy = SetpointPolicy(profile.flavour, ardupilot_period_s=0.5, px4_rate_hz=20.0)
    target = PositionTarget((1.0, 2.0, -7.0), 0.0)
    policy.sent(target, 0.0)
    if profile.streams_setpoints:
        assert policy.period_s == pytest.approx(1 / 20.0)  # > 2 Hz
        assert policy.on_new_target(target, 0.01)  # every frame's target goes out
    else:
        assert policy.period_s == pytest.approx(0.5)  # keep-alive of a persisting target
        assert not policy.on_new_target(target, 0.01)  # unchanged: not re-sent yet
        assert policy.on_new_target(PositionTarget((1.5, 2.0, -7.0), 0.0), 0.01)
    assert policy.due(0.6)


@pytest.mark.parametrize("profile", ALL, ids=IDS)
def test_takeoff_mode_and_altitude_reference(profile):
    """On the ground: GUIDED first (ArduPilot, generic) or arm at once (PX4); the home
    altitude is requested where NAV_TAKEOFF's altitude is AMSL (PX4)."""
    seq = TakeoffSequence(profile.flavour, TakeoffSettings(7.0, require_frames=False), 0.0)
    requested = {int(a.params[0]) for a in seq.pop_actions() if isinstance(a, TakeoffCommand)}
    assert (mavlink.MAVLINK_MSG_ID_HOME_POSITION in requested) is profile.takeoff_alt_amsl
    seq.on_landed_state(0.1, mavlink.MAV_LANDED_STATE_ON_GROUND)
    seq.on_home_amsl(100.0)
    seq.on_position(0.1, 0.1, 0.0)
    seq.on_heartbeat(0.2, 0, False)  # disarmed in mode 0
    commands = []
    for t in (0.3, 0.4):
        seq.tick(t)
        commands += [a for a in seq.pop_actions() if isinstance(a, TakeoffCommand)]
    first = commands[0]
    if profile.takeoff_mode is None:
        assert first.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM
    else:
        assert first.command == mavlink.MAV_CMD_DO_SET_MODE
        assert first.params[1] == float(profile.takeoff_mode.custom_mode)
    assert profile.takeoff_alt_amsl is (profile.flavour is Flavour.PX4)


def test_only_ardupilot_states_a_speed_limit():
    """DO_CHANGE_SPEED below WPNAV_SPEED is ArduPilot's; elsewhere the carrot bounds it."""
    assert {p.flavour for p in ALL if p.states_speed_limit} == {Flavour.ARDUPILOT}
