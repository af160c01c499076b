"""COMMAND_LONG / COMMAND_INT / SET_MODE handling: one outcome per command (pure).

:func:`handle_command` maps a command onto the :class:`FlightModeMachine` and returns a
:class:`CommandOutcome`: the MAV_RESULT for the single COMMAND_ACK, a STATUSTEXT for every
refusal, and requests the service carries out (send a message now, change a stream
interval). Anything not listed is MAV_RESULT_UNSUPPORTED. Retransmissions are handled like
first transmissions (arming an armed vehicle is ACCEPTED), so a client that lost an ACK
gets one again.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from plant_sim.autopilot.modes import (
    FORCE_ARM_MAGIC,
    FlightMode,
    FlightModeMachine,
    Kinematics,
)

__all__ = [
    "CUSTOM_MODE_ENABLED",
    "SUPPORTED_COMMANDS",
    "CommandOutcome",
    "MavCmd",
    "MavResult",
    "handle_command",
    "handle_set_mode",
]

#: MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
CUSTOM_MODE_ENABLED = 1


class MavResult(enum.IntEnum):
    """MAV_RESULT."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4


class MavCmd(enum.IntEnum):
    """The MAV_CMD values this autopilot implements."""

    NAV_RETURN_TO_LAUNCH = 20
    NAV_LAND = 21
    NAV_TAKEOFF = 22
    DO_SET_MODE = 176
    COMPONENT_ARM_DISARM = 400
    GET_HOME_POSITION = 410
    SET_MESSAGE_INTERVAL = 511
    REQUEST_MESSAGE = 512
    REQUEST_AUTOPILOT_CAPABILITIES = 520


SUPPORTED_COMMANDS = frozenset(int(c) for c in MavCmd)

_MSG_ID_AUTOPILOT_VERSION = 148
_MSG_ID_HOME_POSITION = 242


@dataclass(frozen=True)
class CommandOutcome:
    """Result of one command: the ACK's result, a STATUSTEXT, and requests to the service."""

    result: MavResult
    text: str | None = None  # STATUSTEXT (refusals, notable events)
    send_message_id: int | None = None  # REQUEST_MESSAGE & co: send this message once
    set_interval: tuple[int, float] | None = None  # (message id, interval_us) to apply


def _ok(text: str | None = None, **kw) -> CommandOutcome:
    return CommandOutcome(MavResult.ACCEPTED, text, **kw)


def _refuse(result: MavResult, text: str) -> CommandOutcome:
    return CommandOutcome(result, text)


def handle_command(
    command: int,
    params: tuple[float, float, float, float, float, float, float],
    machine: FlightModeMachine,
    kin: Kinematics,
    *,
    arming_checks: bool,
    known_message_ids: frozenset[int],
) -> CommandOutcome:
    """Execute ``command`` with ``params`` (param1..param7; COMMAND_INT x, y, z as 5–7).

    Parameters
    ----------
    known_message_ids : ids that REQUEST_MESSAGE / SET_MESSAGE_INTERVAL can serve.
    """
    p1, p2, _p3, _p4, _p5, _p6, p7 = params
    if command == MavCmd.COMPONENT_ARM_DISARM:
        force = math.isfinite(p2) and round(p2) == FORCE_ARM_MAGIC  # MAVSDK sends NaN
        if p1 == 1.0:
            reason = machine.arm(kin, force=force, checks_enabled=arming_checks)
            return _ok() if reason is None else _refuse(MavResult.FAILED, reason)
        if p1 == 0.0:
            reason = machine.disarm(kin, force=force)
            return _ok() if reason is None else _refuse(MavResult.FAILED, reason)
        return _refuse(MavResult.DENIED, f"ARM_DISARM: bad param1 {p1}")
    if command == MavCmd.NAV_TAKEOFF:
        reason = machine.takeoff(p7, kin)
        return _ok() if reason is None else _refuse(MavResult.FAILED, reason)
    if command == MavCmd.NAV_LAND:
        return _mode(FlightMode.LAND, machine, kin)
    if command == MavCmd.NAV_RETURN_TO_LAUNCH:
        return _mode(FlightMode.RTL, machine, kin)
    if command == MavCmd.DO_SET_MODE:
        if not int(p1) & CUSTOM_MODE_ENABLED:
            return _refuse(MavResult.DENIED, "DO_SET_MODE: only custom modes are supported")
        return _custom_mode(p2, machine, kin)
    if command == MavCmd.SET_MESSAGE_INTERVAL:
        msg_id = round(p1)
        if msg_id not in known_message_ids:
            return _refuse(
                MavResult.DENIED, f"SET_MESSAGE_INTERVAL: message {msg_id} not streamable"
            )
        if not math.isfinite(p2) or (p2 < 0 and p2 != -1):
            return _refuse(MavResult.DENIED, f"SET_MESSAGE_INTERVAL: bad interval {p2}")
        return _ok(set_interval=(msg_id, float(p2)))
    if command == MavCmd.REQUEST_MESSAGE:
        msg_id = round(p1)
        if msg_id not in known_message_ids:
            return _refuse(MavResult.DENIED, f"REQUEST_MESSAGE: message {msg_id} not available")
        return _ok(send_message_id=msg_id)
    if command == MavCmd.REQUEST_AUTOPILOT_CAPABILITIES:
        return _ok(send_message_id=_MSG_ID_AUTOPILOT_VERSION)
    if command == MavCmd.GET_HOME_POSITION:
        return _ok(send_message_id=_MSG_ID_HOME_POSITION)
    return CommandOutcome(MavResult.UNSUPPORTED)


def handle_set_mode(
    base_mode: int, custom_mode: int, machine: FlightModeMachine, kin: Kinematics
) -> CommandOutcome:
    """Legacy SET_MODE message (acknowledged like ArduPilot: COMMAND_ACK command=11)."""
    if not base_mode & CUSTOM_MODE_ENABLED:
        return _refuse(MavResult.DENIED, "SET_MODE: only custom modes are supported")
    return _custom_mode(float(custom_mode), machine, kin)


def _custom_mode(value: float, machine: FlightModeMachine, kin: Kinematics) -> CommandOutcome:
    try:
        mode = FlightMode(round(value))
    except ValueError:
        return _refuse(MavResult.DENIED, f"Unknown flight mode {value:g}")
    return _mode(mode, machine, kin)


def _mode(mode: FlightMode, machine: FlightModeMachine, kin: Kinematics) -> CommandOutcome:
    reason = machine.set_mode(mode, kin)
    return _ok() if reason is None else _refuse(MavResult.FAILED, reason)
