"""plant-sim's MAVLink input: receive, rate-limit, queue and handle each message.

The message handlers of :class:`plant_sim.service.PlantService` (a mixin of it, split out
by concern: the service's loop, physics and telemetry stay in :mod:`plant_sim.service`).
Messages are rate-limited per peer (:mod:`plant_sim.autopilot.ratelimit`) and queued for
the next autopilot tick, as a real autopilot's scheduler runs them (TIMESYNC and HEARTBEAT
at once); one handler's exception is caught, counted by message type, logged once per
kind and, for a command, answered with MAV_RESULT_FAILED. Commands, modes and setpoints go
through the flavour strategy (:mod:`plant_sim.autopilot.flavours`); the parameter list is
sent a few parameters per tick whatever the number of requests.
"""

from __future__ import annotations

import logging
import math
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from plant_sim.autopilot import commands as cmds
from plant_sim.autopilot.modes import FORCE_ARM_MAGIC, GuidedTarget, Kinematics
from plant_sim.autopilot.setpoints import (
    SetpointError,
    VehiclePose,
    check_target_range,
    decode_global_target,
    decode_position_target,
)
from plant_sim.autopilot.telemetry import MESSAGE_IDS
from plant_sim.vehicle import VehicleState

__all__ = ["MessageHandlers"]

_log = logging.getLogger("plant_sim")

_KNOWN_MSG_IDS = frozenset(MESSAGE_IDS.values())
_NAME_BY_ID = {v: k for k, v in MESSAGE_IDS.items()}
# pilot sticks and proximity data: ArduPilot's / PX4's own avoidance (pilot_flight)
_PILOT_MESSAGES = frozenset({"OBSTACLE_DISTANCE", "RC_CHANNELS_OVERRIDE", "MANUAL_CONTROL"})
# messages handled at once (not queued for the next tick)
_IMMEDIATE = frozenset({"TIMESYNC", "HEARTBEAT"})
# parameters sent per autopilot tick while a PARAM_REQUEST_LIST is served (50 Hz: 1000/s)
_PARAMS_PER_TICK = 20
# the inbox holds at most this many messages for the next tick; the oldest are dropped
_INBOX_MAX = 2000


class MessageHandlers:
    """The service's MAVLink input (a mixin of :class:`~plant_sim.service.PlantService`).

    Owns ``_inbox`` (messages for the next tick), ``_param_sends`` (running parameter
    transfers), ``limiter`` and ``handler_errors``; reads and drives the service's
    ``link``, ``machine``, ``flavour``, ``pilot``, ``params``, ``scheduler``,
    ``telemetry`` and ``counters``.
    """

    def _receive(self) -> None:
        now = time.monotonic()
        for msg in self.link.poll():
            if not self._addressed_to_us(msg):
                self.counters["foreign"] += 1
                continue
            mtype = msg.get_type()
            if not self.limiter.allow((msg.get_srcSystem(), msg.get_srcComponent()), mtype, now):
                self._log_once(f"rate:{mtype}", "rate limit: dropping %s floods", mtype)
                continue
            if mtype in _IMMEDIATE:
                self._dispatch_safely(msg, None, None)
            else:
                if len(self._inbox) >= _INBOX_MAX:
                    self._inbox.pop(0)
                    self.counters["inbox_overflow"] += 1
                self._inbox.append(msg)

    def _dispatch_safely(self, msg, kin: Kinematics | None, snap: VehicleState | None) -> None:
        """Run one handler; an exception is counted, logged once per kind, never fatal."""
        try:
            self._dispatch(msg, kin, snap)
        except Exception as exc:  # a handler bug must not take the autopilot down
            mtype = msg.get_type()
            kind = f"{mtype}:{type(exc).__name__}"
            self.handler_errors[kind] = self.handler_errors.get(kind, 0) + 1
            self._log_once(
                f"handler:{kind}",
                "handler for %s failed (%s: %s); message dropped",
                mtype,
                type(exc).__name__,
                exc,
            )
            if mtype in ("COMMAND_LONG", "COMMAND_INT") and snap is not None:
                src = (msg.get_srcSystem(), msg.get_srcComponent())
                failed = cmds.CommandOutcome(cmds.MavResult.FAILED, "Command failed")
                self._ack(int(getattr(msg, "command", 0)) & 0xFFFF, failed, src, snap)

    def _log_once(self, kind: str, fmt: str, *args) -> None:
        """Log the first occurrence of ``kind`` at WARNING, later ones at DEBUG."""
        seen = self._refusal_last_text
        if f"log:{kind}" in seen:
            _log.debug(fmt, *args)
            return
        seen[f"log:{kind}"] = 0.0
        _log.warning(fmt, *args)

    def _addressed_to_us(self, msg) -> bool:
        sysid = getattr(msg, "target_system", 0)
        if sysid not in (0, self.link.system_id):
            return False
        compid = getattr(msg, "target_component", 0)
        return compid in (0, self.link.component_id)

    def _dispatch(self, msg, kin: Kinematics | None, snap: VehicleState | None) -> None:
        mtype = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if mtype == "TIMESYNC":
            if msg.tc1 == 0:
                now_ns = round(self.quad.time_s * 1e9)
                self.link.send(mavlink.MAVLink_timesync_message(now_ns, msg.ts1))
            return
        if mtype == "HEARTBEAT":
            return
        assert kin is not None and snap is not None
        if mtype in ("COMMAND_LONG", "COMMAND_INT"):
            self._command(msg, kin, snap, src)
        elif mtype == "SET_MODE":
            outcome = self.flavour.set_mode(msg.base_mode, msg.custom_mode, kin)
            self._ack(mavlink.MAVLINK_MSG_ID_SET_MODE, outcome, src, snap)
        elif mtype in ("SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT"):
            self._position_target(msg, kin)
        elif mtype in _PILOT_MESSAGES:
            reason = self.pilot.on_message(msg, self._tick_wall_s)
            if reason is not None:
                self._refusal(f"pilot:{mtype}", reason, kin.time_s)
        elif mtype == "PARAM_REQUEST_LIST":
            # one transfer per requester; repeated requests while it runs change nothing
            self._param_sends.setdefault(src, 0)
        elif mtype == "PARAM_REQUEST_READ":
            index = msg.param_index
            if index == -1:
                index = self.params.index_of(_param_name(msg.param_id))
            if index is None or not 0 <= index < len(self.params):
                name = _param_name(msg.param_id)
                self._refusal("param_read", f"Unknown parameter {name}", kin.time_s)
            else:
                self._param_value(index)
        elif mtype == "PARAM_SET":
            self._param_set(msg)
        elif mtype == "MISSION_REQUEST_LIST":
            self.link.send(
                mavlink.MAVLink_mission_count_message(src[0], src[1], 0, msg.mission_type)
            )
        elif mtype == "MISSION_CLEAR_ALL":
            self.link.send(
                mavlink.MAVLink_mission_ack_message(
                    src[0], src[1], mavlink.MAV_MISSION_ACCEPTED, msg.mission_type
                )
            )
        elif mtype == "MISSION_COUNT":
            ok = msg.count == 0
            if not ok:
                self._refusal("mission", "Missions are not supported", kin.time_s)
            self.link.send(
                mavlink.MAVLink_mission_ack_message(
                    src[0],
                    src[1],
                    mavlink.MAV_MISSION_ACCEPTED if ok else mavlink.MAV_MISSION_UNSUPPORTED,
                    msg.mission_type,
                )
            )
        elif mtype == "REQUEST_DATA_STREAM":
            rate = float(msg.req_message_rate)
            if not 0.0 <= rate <= self.config.autopilot_rate_hz:
                self._refusal("stream", f"REQUEST_DATA_STREAM: bad rate {rate:g}", kin.time_s)
                return
            self.scheduler.request_data_stream(
                msg.req_stream_id, float(msg.req_message_rate), bool(msg.start_stop), kin.time_s
            )

    def _command(self, msg, kin: Kinematics, snap: VehicleState, src) -> None:
        self.counters["commands"] += 1
        frame = None
        if msg.get_type() == "COMMAND_INT":
            frame = msg.frame
            params = (
                msg.param1,
                msg.param2,
                msg.param3,
                msg.param4,
                float(msg.x),
                float(msg.y),
                msg.z,
            )
        else:
            params = (
                msg.param1,
                msg.param2,
                msg.param3,
                msg.param4,
                msg.param5,
                msg.param6,
                msg.param7,
            )
        outcome = self.flavour.command(msg.command, params, kin)
        if outcome is None:
            outcome = self._prearm(msg.command, params)
        if outcome is None:
            outcome = cmds.handle_command(
                msg.command,
                params,
                self.machine,
                kin,
                arming_checks=self.params.value("ARMING_CHECK") != 0,
                known_message_ids=_KNOWN_MSG_IDS,
                frame=frame,
                earth=self.telemetry.earth,
            )
        self._ack(msg.command, outcome, src, snap)
        if outcome.set_interval is not None:
            msg_id, interval_us = outcome.set_interval
            self.scheduler.set_interval_us(msg_id, interval_us, kin.time_s)
        if outcome.send_message_id is not None:
            name = _NAME_BY_ID[outcome.send_message_id]
            self.link.send(self._build(name, snap, time.time()))
        self._apply_machine()

    def _prearm(self, command: int, params) -> cmds.CommandOutcome | None:
        """ArduCopter's proximity pre-arm check on an arm request (None: not refused)."""
        if command != cmds.MavCmd.COMPONENT_ARM_DISARM or params[0] != 1 or self.machine.armed:
            return None
        if math.isfinite(params[1]) and round(params[1]) == FORCE_ARM_MAGIC:
            return None
        reason = self.pilot.prearm_failure(self.params, self._tick_wall_s)
        if reason is None:
            return None
        return cmds.CommandOutcome(cmds.MavResult.FAILED, f"Arm: {reason}")

    def _ack(self, command: int, outcome: cmds.CommandOutcome, src, snap: VehicleState) -> None:
        if outcome.text:
            self._refusal(f"command:{command}", outcome.text, snap.time_s)
        if outcome.result is cmds.MavResult.UNSUPPORTED:
            _log.info("command %d from %s unsupported", command, src)
        self.link.send(
            mavlink.MAVLink_command_ack_message(command, int(outcome.result), 0, 0, src[0], src[1])
        )

    def _position_target(self, msg, kin: Kinematics) -> None:
        """SET_POSITION_TARGET_LOCAL_NED or _GLOBAL_INT: decode, range-check, fly."""
        self.counters["setpoints"] += 1
        pose = VehiclePose(kin.pos_ned_m, kin.yaw_rad)
        vel = (msg.vx, msg.vy, msg.vz)
        home = self.machine.home_ned_m
        try:
            if msg.get_type() == "SET_POSITION_TARGET_GLOBAL_INT":
                target: GuidedTarget = decode_global_target(
                    msg.type_mask,
                    msg.coordinate_frame,
                    (msg.lat_int, msg.lon_int),
                    msg.alt,
                    vel,
                    msg.yaw,
                    msg.yaw_rate,
                    pose,
                    self.telemetry.earth,
                    home[2],
                )
            else:
                target = decode_position_target(
                    msg.type_mask,
                    msg.coordinate_frame,
                    (msg.x, msg.y, msg.z),
                    vel,
                    msg.yaw,
                    msg.yaw_rate,
                    pose,
                )
            check_target_range(target, home)
        except SetpointError as exc:
            self.counters["setpoints_refused"] += 1
            self._refusal("decode", f"Target refused: {exc}", kin.time_s)
            return
        reason = self.flavour.setpoint(target, kin)
        if reason is not None:
            self.counters["setpoints_refused"] += 1
            self._refusal("guided", reason, kin.time_s)

    def _send_param_batch(self) -> None:
        """Serve running PARAM_REQUEST_LIST transfers, a few parameters per tick in all."""
        budget = _PARAMS_PER_TICK
        n = len(self.params)
        while budget > 0 and self._param_sends:
            src, index = next(iter(self._param_sends.items()))
            del self._param_sends[src]
            stop = min(n, index + budget)
            for i in range(index, stop):
                self._param_value(i)
            budget -= stop - index
            if stop < n:
                self._param_sends[src] = stop  # back of the queue: requesters take turns

    def _param_value(self, index: int) -> None:
        spec, value = self.params.entry(index)
        self.link.send(
            mavlink.MAVLink_param_value_message(
                spec.name.encode("ascii"), value, int(spec.type), len(self.params), index
            )
        )

    def _param_set(self, msg) -> None:
        name = _param_name(msg.param_id)
        reason = self.params.set(name, float(msg.param_value))
        if reason is not None:
            self._refusal("param_set", reason, self.quad.time_s)
        index = self.params.index_of(name)
        if index is not None:
            self._param_value(index)  # echo: the new value, or the unchanged one if refused
        if reason is None:
            self.machine.timings = self._timings()
            self.machine.timings.velocity_integrator.apply_to(self.quad)
            self.flavour.params_changed(self.params)
            _log.info("param %s set to %g", name, self.params.value(name))


def _param_name(param_id) -> str:
    """A PARAM_* name as printable ASCII (hostile bytes become ``?``; NUL ends it)."""
    if isinstance(param_id, bytes):
        param_id = param_id.decode("ascii", "replace")
    name = param_id.split("\x00", 1)[0]
    return "".join(c if " " <= c <= "~" else "?" for c in name)
