"""COMMAND_LONG / COMMAND_INT / SET_MODE handling: one outcome per command (pure).

:func:`handle_command` maps a command onto the :class:`FlightModeMachine` and returns a
:class:`CommandOutcome`: the MAV_RESULT for the single COMMAND_ACK, a STATUSTEXT for every
refusal, and requests the service carries out (send a message now, change a stream
interval). Anything not listed is MAV_RESULT_UNSUPPORTED. Retransmissions are handled like
first transmissions (arming an armed vehicle is ACCEPTED), so a client that lost an ACK
gets one again.

Every parameter is validated before it is used (finite, in range, a known enum value): a
hostile or corrupt command gets a COMMAND_ACK that is not ACCEPTED and a STATUSTEXT, never
an exception. DO_REPOSITION ("fly here" of a ground station) follows ArduCopter: denied
outside GUIDED unless the change-mode flag is set, latitude/longitude checked, altitude
frames GLOBAL (AMSL) and GLOBAL_RELATIVE_ALT (above home).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from plant_sim.autopilot.geodesy import FlatEarth, valid_lat_lon_e7
from plant_sim.autopilot.modes import (
    FORCE_ARM_MAGIC,
    FlightMode,
    FlightModeMachine,
    GuidedTarget,
    Kinematics,
)
from plant_sim.autopilot.setpoints import SetpointError, check_target_range

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
    DO_CHANGE_SPEED = 178
    DO_REPOSITION = 192
    COMPONENT_ARM_DISARM = 400
    GET_HOME_POSITION = 410
    SET_MESSAGE_INTERVAL = 511
    REQUEST_MESSAGE = 512
    REQUEST_AUTOPILOT_CAPABILITIES = 520


SUPPORTED_COMMANDS = frozenset(int(c) for c in MavCmd)

_MSG_ID_AUTOPILOT_VERSION = 148
_MSG_ID_HOME_POSITION = 242
#: MAV_DO_REPOSITION_FLAGS_CHANGE_MODE
REPOSITION_CHANGE_MODE = 1
#: MAV_FRAME values with an altitude above mean sea level / above home
_FRAMES_AMSL = frozenset({0, 5})  # GLOBAL, GLOBAL_INT
_FRAMES_RELATIVE = frozenset({3, 6})  # GLOBAL_RELATIVE_ALT(_INT)
#: NAV_TAKEOFF altitudes above this are refused [m above home]
MAX_TAKEOFF_ALT_M = 1000.0


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


def _as_int(value: float, lo: int, hi: int) -> int | None:
    """``value`` as an integer in [lo, hi], or None if it is not finite or out of range."""
    if not math.isfinite(value):
        return None
    n = round(value)
    return n if lo <= n <= hi else None


def _bad(command: str, name: str, value: float) -> CommandOutcome:
    return _refuse(MavResult.DENIED, f"{command}: bad {name} {value!r}")


def handle_command(
    command: int,
    params: tuple[float, float, float, float, float, float, float],
    machine: FlightModeMachine,
    kin: Kinematics,
    *,
    arming_checks: bool,
    known_message_ids: frozenset[int],
    frame: int | None = None,
    earth: FlatEarth | None = None,
) -> CommandOutcome:
    """Execute ``command`` with ``params`` (param1..param7; COMMAND_INT x, y, z as 5–7).

    Parameters
    ----------
    known_message_ids : ids that REQUEST_MESSAGE / SET_MESSAGE_INTERVAL can serve.
    frame : MAV_FRAME of a COMMAND_INT (x, y in degE7), None for COMMAND_LONG (param5/6
        in degrees, altitude above home).
    earth : the geodetic projection of LOCAL_NED (needed by DO_REPOSITION).
    """
    p1, p2, _p3, _p4, _p5, _p6, p7 = params
    if command == MavCmd.COMPONENT_ARM_DISARM:
        arm = _as_int(p1, 0, 1)
        if arm is None or p1 != arm:
            return _bad("ARM_DISARM", "param1", p1)
        force = math.isfinite(p2) and round(p2) == FORCE_ARM_MAGIC
        if arm == 1:
            reason = machine.arm(kin, force=force, checks_enabled=arming_checks)
        else:
            reason = machine.disarm(kin, force=force)
        return _ok() if reason is None else _refuse(MavResult.FAILED, reason)
    if command == MavCmd.NAV_TAKEOFF:
        if not (math.isfinite(p7) and 0.0 < p7 <= MAX_TAKEOFF_ALT_M):
            return _bad("Takeoff", "altitude", p7)
        reason = machine.takeoff(p7, kin)
        return _ok() if reason is None else _refuse(MavResult.FAILED, reason)
    if command == MavCmd.NAV_LAND:
        return _mode(FlightMode.LAND, machine, kin)
    if command == MavCmd.NAV_RETURN_TO_LAUNCH:
        return _mode(FlightMode.RTL, machine, kin)
    if command == MavCmd.DO_SET_MODE:
        base = _as_int(p1, 0, 255)
        if base is None:
            return _bad("DO_SET_MODE", "base mode", p1)
        if not base & CUSTOM_MODE_ENABLED:
            return _refuse(MavResult.DENIED, "DO_SET_MODE: only custom modes are supported")
        return _custom_mode(p2, machine, kin)
    if command == MavCmd.DO_CHANGE_SPEED:
        kind = _as_int(p1, 0, 3)
        if kind is None or p1 != kind:
            return _bad("Change speed", "speed type", p1)
        if not math.isfinite(p2):
            return _bad("Change speed", "speed", p2)
        reason = machine.change_speed(("ne", "ne", "up", "down")[kind], p2)
        return _ok() if reason is None else _refuse(MavResult.FAILED, reason)
    if command == MavCmd.DO_REPOSITION:
        if earth is None:
            return CommandOutcome(MavResult.UNSUPPORTED)
        return _reposition(params, frame, machine, kin, earth)
    if command in (MavCmd.SET_MESSAGE_INTERVAL, MavCmd.REQUEST_MESSAGE):
        name = MavCmd(command).name
        msg_id = _as_int(p1, 0, 2**24 - 1)
        if msg_id is None or msg_id not in known_message_ids:
            return _refuse(MavResult.DENIED, f"{name}: message {p1!r} not available")
        if command == MavCmd.REQUEST_MESSAGE:
            return _ok(send_message_id=msg_id)
        if not math.isfinite(p2) or (p2 < 0 and p2 != -1) or p2 > 1e9:
            return _refuse(MavResult.DENIED, f"{name}: bad interval {p2!r}")
        return _ok(set_interval=(msg_id, float(p2)))
    if command == MavCmd.REQUEST_AUTOPILOT_CAPABILITIES:
        return _ok(send_message_id=_MSG_ID_AUTOPILOT_VERSION)
    if command == MavCmd.GET_HOME_POSITION:
        return _ok(send_message_id=_MSG_ID_HOME_POSITION)
    return CommandOutcome(MavResult.UNSUPPORTED)


def _reposition(params, frame, machine, kin, earth: FlatEarth) -> CommandOutcome:
    """MAV_CMD_DO_REPOSITION as ArduCopter: a GUIDED position target from a global point."""
    p1, p2, _p3, p4, x, y, alt = params
    flags = _as_int(p2, 0, 2**31 - 1)
    if flags is None:
        return _bad("Reposition", "flags", p2)
    change_mode = bool(flags & REPOSITION_CHANGE_MODE)
    if machine.mode is not FlightMode.GUIDED and not change_mode:
        return _refuse(MavResult.DENIED, f"Reposition: not in GUIDED (mode {machine.mode.name})")
    if not (math.isfinite(x) and math.isfinite(y)):
        return _bad("Reposition", "position", (x, y))
    if frame is None:  # COMMAND_LONG: degrees, altitude above home
        lat_e7, lon_e7, frame = round(x * 1e7), round(y * 1e7), 3
    else:
        lat_e7, lon_e7 = round(x), round(y)
    if not valid_lat_lon_e7(lat_e7, lon_e7) or not math.isfinite(alt):
        return _bad("Reposition", "location", (lat_e7, lon_e7, alt))
    if frame in _FRAMES_AMSL:
        down = earth.alt_amsl_m - alt
    elif frame in _FRAMES_RELATIVE:
        down = machine.home_ned_m[2] - alt
    else:
        return _refuse(MavResult.DENIED, f"Reposition: unsupported frame {frame}")
    north, east = earth.ned_from_lat_lon(lat_e7 * 1e-7, lon_e7 * 1e-7)
    yaw = math.radians(p4) if math.isfinite(p4) else None
    target = GuidedTarget(pos_ned_m=(north, east, down), yaw_rad=yaw)
    try:
        check_target_range(target, machine.home_ned_m)
    except SetpointError as exc:
        return _refuse(MavResult.DENIED, f"Reposition: {exc}")
    del p1  # ground speed: the plant flies at its own limits
    if machine.mode is not FlightMode.GUIDED:
        reason = machine.set_mode(FlightMode.GUIDED, kin)
        if reason is not None:
            return _refuse(MavResult.FAILED, reason)
    reason = machine.guided_target(target, kin)
    return _ok() if reason is None else _refuse(MavResult.FAILED, reason)


def handle_set_mode(
    base_mode: int, custom_mode: int, machine: FlightModeMachine, kin: Kinematics
) -> CommandOutcome:
    """Legacy SET_MODE message (acknowledged like ArduPilot: COMMAND_ACK command=11)."""
    if not base_mode & CUSTOM_MODE_ENABLED:
        return _refuse(MavResult.DENIED, "SET_MODE: only custom modes are supported")
    return _custom_mode(float(custom_mode), machine, kin)


def _custom_mode(value: float, machine: FlightModeMachine, kin: Kinematics) -> CommandOutcome:
    number = _as_int(value, 0, 2**32 - 1)
    try:
        mode = FlightMode(number)
    except ValueError:
        return _refuse(MavResult.DENIED, f"Unknown flight mode {value!r}")
    return _mode(mode, machine, kin)


def _mode(mode: FlightMode, machine: FlightModeMachine, kin: Kinematics) -> CommandOutcome:
    reason = machine.set_mode(mode, kin)
    return _ok() if reason is None else _refuse(MavResult.FAILED, reason)
