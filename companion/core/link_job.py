"""Link and heartbeats: every autopilot message enters here, link up / lost / silent.

A mixin of :class:`~companion.core.CompanionCore` (one job of the core; the state it owns
is listed in its class docstring). Messages from our own system and component are a twin
companion's (:mod:`companion.takeover`); setpoints to our autopilot from another source
block steering; the autopilot's own messages are dispatched to the job that reads them.
Pure: wall time comes with each input.
"""

from __future__ import annotations

import logging

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.core.telemetry_job import MAX_POS_M, Restarted, in_range
from companion.link.flavour import control_mode, detect_flavour, is_autopilot_heartbeat
from companion.link.messages import heartbeat_message, mav_state
from companion.takeover import SETPOINT_MESSAGES

_log = logging.getLogger("companion")

_LISTEN_BEFORE_STEERING_S = 2.5  # > 2 heartbeat periods of another companion [s wall]
_IN_CONTROL_STATES = frozenset({mavlink.MAV_STATE_ACTIVE, mavlink.MAV_STATE_CRITICAL})

__all__ = ["LinkJob", "statustext"]


class LinkJob:
    """The link: autopilot messages in, link up and lost, the autopilot found.

    Owns ``_link_up``, ``_last_rx_s``, ``_listen_until_s``, ``_next_heartbeat_s``,
    ``_silent_since_s``, ``_silence_reported_s``, ``_handler_error_kinds``.
    """

    def _receive(self, msg, now_s: float) -> None:
        target_sys = self.config.link.target_system
        target_comp = self.config.link.target_component
        try:
            self._on_message(msg, now_s, target_sys, target_comp)
        except Exception as exc:  # one handler's bug must not stop the companion
            self._handler_error(msg, exc)

    def _handler_error(self, msg, exc: Exception) -> None:
        self.counters.handler_errors += 1
        kind = f"{msg.get_type()}:{type(exc).__name__}"
        if kind not in self._handler_error_kinds:
            self._handler_error_kinds.add(kind)
            _log.error(
                "handling %s failed (%s: %s); message dropped", kind, type(exc).__name__, exc
            )

    def _on_message(self, msg, now_s: float, target_sys: int, target_comp: int) -> None:
        mtype = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        cfg = self.config.link
        if src == (cfg.system_id, cfg.component_id):
            if mtype == "HEARTBEAT":
                self.modes.on_twin_heartbeat(
                    now_s,
                    msg.custom_mode,
                    msg.system_status in _IN_CONTROL_STATES,
                    # the same test as for the twin's heartbeat: a companion in its hold is
                    # still in control (else both yield and nobody steers)
                    mav_state(self._state()) in _IN_CONTROL_STATES,
                )
            return
        if mtype in SETPOINT_MESSAGES and getattr(msg, "target_system", 0) == target_sys:
            self.modes.on_foreign_setpoint(now_s, src)
            return
        if msg.get_srcSystem() != target_sys:
            return
        from_autopilot = msg.get_srcComponent() == target_comp
        if mtype == "HEARTBEAT":
            if from_autopilot and is_autopilot_heartbeat(msg.autopilot, msg.type):
                self._on_link_alive(now_s)
                self._on_heartbeat(msg, now_s)
            return
        if not from_autopilot:
            return
        self._on_link_alive(now_s)
        if self.takeoff_job.busy and not (
            mtype == "LOCAL_POSITION_NED" and not in_range((msg.z,), MAX_POS_M)
        ):
            self._engage(self.takeoff_job.on_message(msg, mtype, now_s), now_s)
        if mtype == "LOCAL_POSITION_NED":
            self._restarted(self.telemetry.on_local_position(msg, now_s, self._now_ns), now_s)
        elif mtype == "ATTITUDE":
            self._restarted(self.telemetry.on_attitude(msg, now_s), now_s)
        elif mtype == "GPS_RAW_INT":
            self.telemetry.on_gps_raw(msg, now_s)
        elif mtype == "TIMESYNC":
            sample = self.streams.on_timesync(msg, self._now_ns)
            if sample is not None:
                self._restarted(self.telemetry.on_sync_sample(sample), now_s)
        elif mtype == "COMMAND_ACK":
            self._on_ack(msg, now_s)
        elif mtype == "STATUSTEXT":
            _log.info("autopilot: %s", statustext(msg))
        elif mtype == "PARAM_VALUE":
            self.params.on_param_value(msg)

    def _on_ack(self, msg, now_s: float) -> None:
        """COMMAND_ACK to the job whose command it answers."""
        accepted = msg.result == mavlink.MAV_RESULT_ACCEPTED
        if msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            self.streams.on_stream_ack(accepted)
        elif msg.command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            self.setpoints.on_speed_ack(accepted, msg.result)
        elif msg.command == mavlink.MAV_CMD_DO_SET_MODE:
            result = mavlink.enums["MAV_RESULT"].get(msg.result)
            text = result.name if result else str(msg.result)
            self._after_phase_change(self.modes.on_mode_ack(accepted, text, now_s), now_s)

    def _on_link_alive(self, now_s: float) -> None:
        self._last_rx_s = now_s
        self._silent_since_s = None
        if not self._link_up:
            self._link_up = True
            # listen before steering: another companion's heartbeat (1 Hz, forwarded by the
            # autopilot) must have had a chance to arrive (companion.takeover)
            self._listen_until_s = now_s + _LISTEN_BEFORE_STEERING_S
            self.out.event("link_up", url=self.config.link.url)
            _log.info("autopilot link up on %s", self.config.link.url)
            self.streams.link_up(now_s)

    def _restarted(self, restarted: Restarted | None, now_s: float) -> None:
        """The telemetry job saw the autopilot restart (and started its new time base):
        everything else learnt about the vehicle goes, the streams are asked for again."""
        if restarted is None:
            return
        why = restarted.reason
        self.counters.autopilot_restarts += 1
        _log.warning("autopilot restarted (%s): starting over", why)
        self.out.event("autopilot_restart", reason=why)
        self._reset_vehicle_state(telemetry=False)
        self.streams.request_streams_now(now_s)

    def _on_heartbeat(self, msg, now_s: float) -> None:
        flavour = detect_flavour(msg.autopilot)
        if self.setpoints.policy is None:  # first heartbeat since the (re)start
            cfg = self.config.link
            self.setpoints.found(flavour)
            self.out.event("autopilot", flavour=flavour.value, mode=msg.custom_mode)
            _log.info(
                "autopilot found: %s (system %d), control mode %s",
                flavour.value,
                msg.get_srcSystem(),
                control_mode(flavour).name,
            )
            if cfg.takeoff_alt_m > 0:
                self.takeoff_job.start(flavour, now_s)
        if self.takeoff_job.busy:
            armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            engage = self.takeoff_job.on_heartbeat(flavour, msg.custom_mode, armed, now_s)
            self._engage(engage, now_s)
            return
        self._after_phase_change(self.modes.on_heartbeat(flavour, msg.custom_mode, now_s), now_s)

    def _heartbeat_timer(self, now_s: float) -> None:
        """Our heartbeat when due (and the twin rule re-checked with it)."""
        if now_s >= self._next_heartbeat_s:
            self.out.send(heartbeat_message(self._state(), self.instance_id))
            self.modes.check_takeover(now_s)
            self._next_heartbeat_s = now_s + self.config.link.heartbeat_period_s

    def _link_loss_timer(self, now_s: float) -> None:
        """The link is lost after ``link_timeout_s`` of silence [s wall]."""
        if self._link_up and now_s - self._last_rx_s > self.config.failsafe.link_timeout_s:
            self._link_lost(now_s)

    def _link_lost(self, now_s: float) -> None:
        self._link_up = False
        self.counters.link_losses += 1
        _log.warning(
            "autopilot link lost: nothing for %.1f s (wall); stopped commanding, waiting",
            now_s - self._last_rx_s,
        )
        self.out.event("link_lost", silent_s=round(now_s - self._last_rx_s, 3))
        self._reset_vehicle_state()

    def _report_silence(self, now_s: float) -> None:
        """No autopilot: say so every few seconds, with the likely causes."""
        if self._silent_since_s is None:
            self._silent_since_s = now_s
            return
        silent = now_s - self._silent_since_s
        if silent < 3.0 or now_s - self._silence_reported_s < 5.0:
            return
        self._silence_reported_s = now_s
        hint = (
            "MAVLink signing is on: an autopilot with another key (or none) ignores every "
            "message we send"
            if self._signing
            else "check the URL and that the autopilot sends to us"
        )
        _log.error(
            "no message from autopilot %d/%d on %s for %.0f s (%d sent): %s",
            self.config.link.target_system,
            self.config.link.target_component,
            self.config.link.url,
            silent,
            self.counters.mavlink_sent,
            hint,
        )
        self.out.event("no_autopilot", silent_s=round(silent, 1), signing=self._signing)


def statustext(msg) -> str:
    """The STATUSTEXT's text, printable ASCII only (raw bytes never reach the log)."""
    text = msg.text if isinstance(msg.text, str) else msg.text.decode("ascii", "replace")
    text = text.split("\x00", 1)[0]
    return "".join(c if " " <= c <= "~" else "?" for c in text)
