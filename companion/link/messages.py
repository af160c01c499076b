"""Builders of the messages the companion sends (pure: message objects, no I/O).

HEARTBEAT as ``MAV_TYPE_ONBOARD_CONTROLLER`` whose ``system_status`` (MAV_STATE) follows
the companion's health, COMMAND_LONGs (SET_MESSAGE_INTERVAL, DO_SET_MODE, arm, takeoff),
STATUSTEXT, TIMESYNC and OBSTACLE_DISTANCE.
"""

from __future__ import annotations

import enum

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.flavour import ModeRequest
from companion.proximity.sectors import ProximitySectors
from protocols.statustext import statustext_chunks

__all__ = [
    "CompanionState",
    "command_long",
    "heartbeat_message",
    "mav_state",
    "obstacle_distance_message",
    "set_message_interval",
    "set_mode_command",
    "statustext_message",
    "statustext_messages",
    "timesync_reply",
    "timesync_request",
]

_M = mavlink


class CompanionState(enum.Enum):
    """Health summary published in the heartbeat (and the status JSON)."""

    BOOT = "boot"  # starting: no autopilot or no frames yet
    STANDBY = "standby"  # healthy but not steering (waiting for a mode, pilot in control)
    ACTIVE = "active"  # steering
    HOLD = "hold"  # failsafe hold commanded
    LINK_LOST = "link_lost"  # autopilot silent


def mav_state(state: CompanionState) -> int:
    """MAV_STATE for a :class:`CompanionState`."""
    return {
        CompanionState.BOOT: _M.MAV_STATE_BOOT,
        CompanionState.STANDBY: _M.MAV_STATE_STANDBY,
        CompanionState.ACTIVE: _M.MAV_STATE_ACTIVE,
        CompanionState.HOLD: _M.MAV_STATE_CRITICAL,
        CompanionState.LINK_LOST: _M.MAV_STATE_CRITICAL,
    }[state]


def heartbeat_message(
    state: CompanionState, instance_id: int = 0
) -> mavlink.MAVLink_heartbeat_message:
    """Our HEARTBEAT; ``custom_mode`` carries this process's random instance id, so a second
    companion on the same ids can be told from an echo of our own (companion.takeover)."""
    return _M.MAVLink_heartbeat_message(
        _M.MAV_TYPE_ONBOARD_CONTROLLER,
        _M.MAV_AUTOPILOT_INVALID,
        0,
        instance_id & 0xFFFFFFFF,
        mav_state(state),
        3,
    )


def command_long(
    target_system: int, target_component: int, command: int, *params: float, confirmation=0
) -> mavlink.MAVLink_command_long_message:
    p = [float(x) for x in params] + [0.0] * (7 - len(params))
    return _M.MAVLink_command_long_message(
        target_system, target_component, command, confirmation, *p
    )


def set_message_interval(
    target_system: int, target_component: int, message_id: int, rate_hz: float
) -> mavlink.MAVLink_command_long_message:
    """MAV_CMD_SET_MESSAGE_INTERVAL (511): ``message_id`` at ``rate_hz`` (interval in µs)."""
    interval_us = 1e6 / rate_hz if rate_hz > 0 else -1.0
    return command_long(
        target_system, target_component, _M.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, interval_us
    )


def set_mode_command(
    target_system: int, target_component: int, mode: ModeRequest
) -> mavlink.MAVLink_command_long_message:
    """MAV_CMD_DO_SET_MODE (176): base_mode and custom_mode (ArduPilot) or main and sub
    mode (PX4), see :attr:`ModeRequest.command_params`."""
    return command_long(
        target_system, target_component, _M.MAV_CMD_DO_SET_MODE, *mode.command_params
    )


def statustext_message(text: str, severity: int) -> mavlink.MAVLink_statustext_message:
    """One STATUSTEXT (the first 50 characters); see :func:`statustext_messages`."""
    return _M.MAVLink_statustext_message(severity, text[:50].encode("ascii", "replace"))


def statustext_messages(
    text: str, severity: int, text_id: int
) -> list[mavlink.MAVLink_statustext_message]:
    """STATUSTEXT(s) carrying the whole ``text``: MAVLink 2 chunks (``id`` = ``text_id``,
    ``chunk_seq``) when it is longer than 50 characters (:mod:`protocols.statustext`)."""
    return [
        _M.MAVLink_statustext_message(severity, chunk, tid, seq)
        for tid, seq, chunk in statustext_chunks(text, text_id)
    ]


def timesync_request(host_ns: int) -> mavlink.MAVLink_timesync_message:
    """TIMESYNC request: tc1 = 0, ts1 = our time [ns]."""
    return _M.MAVLink_timesync_message(0, int(host_ns))


def timesync_reply(host_ns: int, their_ts1: int) -> mavlink.MAVLink_timesync_message:
    """Answer a peer's TIMESYNC request with our time."""
    return _M.MAVLink_timesync_message(int(host_ns), int(their_ts1))


def obstacle_distance_message(
    time_usec: int, sectors: ProximitySectors
) -> mavlink.MAVLink_obstacle_distance_message:
    """OBSTACLE_DISTANCE (MAV_FRAME_BODY_FRD) carrying ``sectors``
    (:mod:`companion.proximity.sectors`: sector ``k`` centred on body bearing
    ``angle_offset + k · increment_f``; ``UINT16_MAX`` unknown, max + 1 cm clear)."""
    return _M.MAVLink_obstacle_distance_message(
        int(time_usec),
        _M.MAV_DISTANCE_SENSOR_UNKNOWN,
        [int(d) for d in sectors.distances_cm],
        0,  # increment [deg, integer]: 0, the float increment_f is used
        int(sectors.min_distance_cm),
        int(sectors.max_distance_cm),
        float(sectors.increment_deg),
        float(sectors.angle_offset_deg),
        _M.MAV_FRAME_BODY_FRD,
    )
