"""The companion as a pure, clock-injected core: inputs in, outputs out, no I/O.

:class:`CompanionCore` owns every decision the companion makes; the process around it
(:mod:`companion.service`) only moves bytes. Its inputs and outputs are the typed events
of :mod:`companion.core.events`; each input carries the host's monotonic time, which is
the core's only clock (wall time: heartbeats, link loss, TIMESYNC, mode requests,
setpoint keep-alive). Per input:

* :class:`~companion.core.events.MavlinkReceived`: autopilot heartbeat (flavour, mode
  watch, takeoff), LOCAL_POSITION_NED and ATTITUDE into the pose history on the frame
  clock, TIMESYNC, COMMAND_ACKs, PARAM_VALUE (WPNAV_SPEED); a twin's heartbeat or another
  source's setpoints (:mod:`companion.takeover`).
* :class:`~companion.core.events.Tick`: the timers (OBSTACLE_DISTANCE included: from
  start-up, in every mode, :mod:`companion.proximity.sender`), then the failsafe on the
  frame clock.
* :class:`~companion.core.events.FrameReceived`: pose at the frame's capture time → the
  :class:`~companion.core.mission.Mission` (waypoints around the same
  :class:`~companion.pipeline.AvoidancePipeline` the lockstep harness runs) → setpoint
  (when in control and healthy), speed limit, reports, OBSTACLE_DISTANCE (the sectors of
  the known-space map, :mod:`companion.proximity.sectors`), status.

Outputs are MAVLink messages to send, setpoints, events and status documents, returned in
order by :meth:`CompanionCore.step`. Log lines go to the ``companion`` logger.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.clock_model import (
    BootTime,
    BootTimeMonitor,
    ClockModel,
    FrameClock,
    SyncResult,
    SyncSample,
)
from companion.config import CompanionConfig
from companion.core.events import (
    Event,
    FrameProcessed,
    FrameReceived,
    Input,
    MavlinkReceived,
    Output,
    SendMavlink,
    SendSetpoint,
    Status,
    Tick,
)
from companion.core.mission import Mission
from companion.failsafe import FailsafeMonitor, Health, Response
from companion.guidance.hold import hold_point, inside_any
from companion.guidance.latency import DataAgeWindow
from companion.link.flavour import (
    Flavour,
    control_mode,
    detect_flavour,
    is_autopilot_heartbeat,
    mode_name,
    profile_for,
)
from companion.link.messages import (
    CompanionState,
    command_long,
    heartbeat_message,
    mav_state,
    obstacle_distance_message,
    set_message_interval,
    set_mode_command,
    statustext_messages,
    timesync_reply,
    timesync_request,
)
from companion.link.mode_watch import ControlPhase, ModeWatch
from companion.link.setpoints import PositionTarget, SetpointPolicy, position_target_message
from companion.link.speed_limit import SpeedLimitPolicy, change_speed_command
from companion.link.takeoff import (
    TakeoffCommand,
    TakeoffEvent,
    TakeoffNotice,
    TakeoffSequence,
    TakeoffSettings,
    TakeoffStep,
)
from companion.pose_history import PoseHistory, PoseStatus
from companion.proximity.sender import ProximitySender
from companion.status import status_document
from companion.takeover import SETPOINT_MESSAGES, TakeoverGuard
from protocols.stereo_frame import StereoFrame

__all__ = ["STREAMS", "CompanionCore"]

_log = logging.getLogger("companion")

#: telemetry streams the core requests with SET_MESSAGE_INTERVAL
STREAMS = (
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    mavlink.MAVLINK_MSG_ID_ATTITUDE,
)
_SEV_INFO = mavlink.MAV_SEVERITY_INFO
_SEV_WARNING = mavlink.MAV_SEVERITY_WARNING
_REBOOT_BACKSTEP_MS = 500  # time_boot_ms going back this far: the autopilot restarted
_LISTEN_BEFORE_STEERING_S = 2.5  # > 2 heartbeat periods of another companion [s wall]
_WPNAV_SPEED = "WPNAV_SPEED"  # ArduCopter's horizontal speed limit parameter [cm/s]
_MAX_TIMESYNC_PENDING = 32  # our outstanding TIMESYNC requests (replies must match one)
_IN_CONTROL_STATES = frozenset({mavlink.MAV_STATE_ACTIVE, mavlink.MAV_STATE_CRITICAL})
_COUNTERS = (
    "frames_processed",
    "frames_stale",
    "pose_empty",
    "pose_too_old",
    "pose_too_new",
    "pose_extrapolated",
    "telemetry_unmapped",
    "setpoints_sent",
    "hold_commands",
    "link_losses",
    "autopilot_restarts",
    "mode_releases",
    "mode_requests",
    "mode_holds",
    "hold_targets_moved",
    "pipeline_errors",
    "speed_limits_sent",
    "speed_limits_accepted",
    "speed_limits_refused",
    "overspeed_frames",
    "frames_during_takeoff",
    "frames_implausible_time",
    "telemetry_implausible_time",
    "telemetry_out_of_range",
    "timesync_unmatched",
    "handler_errors",
    "takeover_refusals",
    "mavlink_sent",
)


class CompanionCore:
    """Every decision of the companion, stepped by :meth:`step` (no sockets, no clock).

    Parameters
    ----------
    config : CompanionConfig
    instance_id : int
        This companion's random 32-bit id (in its heartbeat's ``custom_mode``; see
        :mod:`companion.takeover`). Passed in so that a replay is deterministic.
    report_pipeline : bool
        Also return a :class:`~companion.core.events.FrameProcessed` per processed frame
        (a viewer is attached); off: nothing is built for it.
    """

    def __init__(
        self, config: CompanionConfig, instance_id: int, *, report_pipeline: bool = False
    ) -> None:
        self.config = config
        self.report_pipeline = report_pipeline
        link = config.link
        self._signing = link.signing_key is not None
        self.clock = ClockModel(link.frame_clock)
        fs = config.failsafe
        self.poses = PoseHistory(
            horizon_ns=round(fs.pose_history_s * 1e9),
            max_extrapolation_ns=round(fs.max_pose_extrapolation_s * 1e9),
        )
        self.failsafe = _failsafe_monitor(config)
        self.modes = ModeWatch(request_mode=link.request_mode, prestream_s=link.px4_prestream_s)
        self.policy: SetpointPolicy | None = None
        self.speed_policy = SpeedLimitPolicy()
        self._overspeed_notice_s = -math.inf
        self.counters: dict[str, int] = dict.fromkeys(_COUNTERS, 0)
        self.instance_id = instance_id
        self.takeover = TakeoverGuard((link.system_id, link.component_id), instance_id)
        self._takeover_blocked = False
        self._listen_until_s = math.inf  # no steering before the link was heard a while
        self._timesync_pending: list[int] = []
        self._handler_error_kinds: set[str] = set()
        self._reset_vehicle_state()
        self._link_up = False
        self._last_rx_s = -math.inf
        self._next_heartbeat_s = 0.0
        self._next_timesync_s = 0.0
        self._drop_log_s: dict[str, float] = {}
        self._last_mode_request = None
        self._silent_since_s: float | None = None
        self._silence_reported_s = -math.inf
        self.fatal: str | None = None  # terminal error (a refused takeoff): stop the process
        self._text_id = 0  # id of the last chunked STATUSTEXT (1..255)
        self._now_ns = 0
        self._now_s = 0.0
        self._out: list[Output] = []
        # OBSTACLE_DISTANCE from start-up, whatever the link, mode or phase
        self.proximity = ProximitySender(config.proximity) if config.proximity.enabled else None

    # ---- what the adapters read ----------------------------------------------------
    @property
    def link_up(self) -> bool:
        """An autopilot message arrived within the link timeout."""
        return self._link_up

    @property
    def autopilot_seen(self) -> bool:
        """An autopilot heartbeat arrived since the (re)connection."""
        return self.policy is not None

    @property
    def flying(self) -> bool:
        """The companion steers or holds the vehicle (frames are needed)."""
        return self.modes.phase in (ControlPhase.ACTIVE, ControlPhase.HOLD)

    def frame_time_plausible(self, capture_ns: int, now_ns: int) -> bool | None:
        """Capture time within the window around the clock model's now (any thread)."""
        window_ns = round(self.config.failsafe.frame_time_window_s * 1e9)
        return self.clock.frame_time_plausible(
            capture_ns, now_ns, self._telemetry_newest_ns, window_ns
        )

    def stats(self) -> dict[str, Any]:
        """Counters and state for the exit statistics."""
        return {
            **self.counters,
            "phase": self.modes.phase.value,
            "flavour": None if self.policy is None else self.policy.flavour.value,
            "clock_rate": round(self.clock.autopilot.rate, 3),
            "waypoint": self.mission.waypoint,
            "takeoff": None if self.takeoff is None else self.takeoff.step.value,
            "obstacle_distance_sent": None if self.proximity is None else self.proximity.sent,
        }

    def progress_text(self) -> str:
        """One line for the periodic progress log (time, position, phase, mode, health)."""
        newest = self.poses.newest_ns
        pos = "-"
        if newest is not None:
            lookup = self.poses.at(newest)
            if lookup.pose is not None:
                p = lookup.pose.pos_ned_m
                pos = f"({p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f})"
        mode = self.modes.mode_text()
        if self.takeoff is not None and self.takeoff.busy and self.takeoff.custom_mode is not None:
            mode = mode_name(self.takeoff.flavour, self.takeoff.custom_mode)
        phase = (
            f"takeoff:{self.takeoff.step.value}"
            if self.takeoff is not None and self.takeoff.busy
            else self.modes.phase.value
        )
        return (
            f"t={'-' if newest is None else f'{newest * 1e-9:.1f}s'} pos={pos} phase={phase} "
            f"mode={mode} health={self.failsafe.status.health.value} "
            f"frames {self.counters['frames_processed']} setpoints "
            f"{self.counters['setpoints_sent']}; {self._pipeline_text()}"
        )

    def _pipeline_text(self) -> str:
        """Rate, data age p50/p99, latency budget, speed limit and mode requests."""
        f = self._pipeline_figures()

        def num(value, fmt: str) -> str:
            return "-" if value is None else format(value, fmt)

        return (
            f"processing {num(f['rate_hz'], '.1f')} Hz, data age p50 "
            f"{num(f['data_age_p50_ms'], '.0f')} p99 {num(f['data_age_p99_ms'], '.0f')} ms, "
            f"latency budget {f['latency_budget_s']:.2f} s, speed limit "
            f"{num(f['speed_limit_mps'], '.1f')} m/s, mode requests "
            f"{self.counters['mode_requests']}{self._proximity_text()}"
        )

    def _proximity_text(self) -> str:
        if self.proximity is None:
            return ", OBSTACLE_DISTANCE off"
        p = self.proximity.figures(self._now_s)
        return (
            f", OBSTACLE_DISTANCE {p['sent']} at {p['rate_hz']:.1f} Hz (sectors: "
            f"{p['obstacle_sectors']} obstacle, {p['clear_sectors']} clear, "
            f"{p['unknown_sectors']} unknown)"
        )

    # ---- per-connection state ------------------------------------------------------
    def _reset_vehicle_state(self) -> None:
        cfg = self.config
        self.mission = Mission(
            cfg.waypoints_ned_m,
            cfg.goal_tolerance_m,
            cfg.perception,
            cfg.guidance,
            cfg.known_space,
            cfg.envelope,
        )
        self.clock.autopilot.reset()
        self.poses.clear()
        self.modes.reset()
        self.policy = None
        self.failsafe = _failsafe_monitor(cfg)
        self._hold = Response.STEER  # the hold the companion commands (failsafe)
        self._hold_target: PositionTarget | None = None  # latched at a hold's start
        self._hold_moved_told = False  # "hold target moved out of a boundary" said
        self._boundaries: tuple = ()  # the last processed frame's boundaries
        self._last_boot_ms: int | None = None
        self._wpnav_speed_mps: float | None = None  # the autopilot's own speed limit
        self._next_param_request_s = 0.0
        self._param_requests = 0
        self._telemetry_newest_ns: int | None = None  # read by the Zenoh thread too
        self.boot_time = BootTimeMonitor(backstep_ms=_REBOOT_BACKSTEP_MS)
        self._newest_frame_ns: int | None = None  # processed
        env = cfg.envelope
        self.data_age = DataAgeWindow(
            env.latency_s, env.latency_window_s, env.latency_percentile, env.unmeasured_latency_s
        )
        # the frame whose command left in the last step: (capture_ns, host ns at the
        # step's start, its data age then [s]); its age is taken at the next input
        self._age_pending: tuple[int, int, float] | None = None
        self._speed_limit_mps: float | None = None  # the envelope's, last processed frame
        self._newest_seen_ns: int | None = None  # newest frame-clock stamp observed
        self._last_capture_ns: int | None = None
        self._streams_acked = 0  # accepted SET_MESSAGE_INTERVAL since the last request
        self._next_stream_request_s = 0.0
        self._engaged = False  # a guidance setpoint was sent since the last reset
        self.takeoff: TakeoffSequence | None = None  # --takeoff-alt, until finished
        self._held_heartbeat: tuple[Flavour, int] | None = None  # for ModeWatch after takeoff

    # ---- inputs ------------------------------------------------------------------
    def step(self, event: Input) -> list[Output]:
        """Handle one input; returns what the adapters must do, in order."""
        self._now_ns = event.now_ns
        self._now_s = event.now_ns * 1e-9
        self._out = []
        self._measure_data_age()
        if isinstance(event, Tick):
            self._timers(self._now_s)
            self._check_failsafe(self._now_s)
        elif isinstance(event, MavlinkReceived):
            self._receive(event.message, self._now_s)
        elif isinstance(event, FrameReceived):
            self._on_frame(event.frame, event.received_ns)
            self._check_failsafe(self._now_s)
        else:
            raise TypeError(f"not a companion core input: {event!r}")
        out, self._out = self._out, []
        return out

    # ---- MAVLink input -------------------------------------------------------------
    def _receive(self, msg, now_s: float) -> None:
        target_sys = self.config.link.target_system
        target_comp = self.config.link.target_component
        try:
            self._on_message(msg, now_s, target_sys, target_comp)
        except Exception as exc:  # one handler's bug must not stop the companion
            self._handler_error(msg, exc)

    def _handler_error(self, msg, exc: Exception) -> None:
        self.counters["handler_errors"] += 1
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
                self.takeover.on_twin_heartbeat(
                    now_s,
                    msg.custom_mode,
                    msg.system_status in _IN_CONTROL_STATES,
                    # the same test as for the twin's heartbeat: a companion in its hold is
                    # still in control (else both yield and nobody steers)
                    mav_state(self._state()) in _IN_CONTROL_STATES,
                )
                self._check_takeover(now_s)
            return
        if mtype in SETPOINT_MESSAGES and getattr(msg, "target_system", 0) == target_sys:
            self.takeover.on_foreign_setpoint(now_s, src)
            self._check_takeover(now_s)
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
        if self._takeoff_busy() and not (
            mtype == "LOCAL_POSITION_NED" and not _in_range((msg.z,), _MAX_POS_M)
        ):
            self._takeoff_input(msg, mtype, now_s)
        if mtype == "LOCAL_POSITION_NED":
            pos, vel = (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz)
            if not _in_range(pos, _MAX_POS_M) or not _in_range(vel, _MAX_SPEED_MPS):
                self._count_drop("telemetry_out_of_range", "LOCAL_POSITION_NED", pos + vel)
            elif self._check_boot_time(msg.time_boot_ms, now_s):
                t = self.clock.frame_ns_from_boot_ms(msg.time_boot_ms)
                if t is None:
                    self.counters["telemetry_unmapped"] += 1
                elif self.poses.add_position(t, pos, vel):
                    self._observe(t)
                    self._telemetry_seen(t)
        elif mtype == "ATTITUDE":
            angles = (msg.roll, msg.pitch, msg.yaw)
            if not _in_range(angles, 2.0 * math.pi):
                self._count_drop("telemetry_out_of_range", "ATTITUDE", angles)
            elif self._check_boot_time(msg.time_boot_ms, now_s):
                t = self.clock.frame_ns_from_boot_ms(msg.time_boot_ms)
                if t is None:
                    self.counters["telemetry_unmapped"] += 1
                elif self.poses.add_attitude(t, *angles):
                    self._observe(t)
                    self._telemetry_seen(t)
        elif mtype == "TIMESYNC":
            self._on_timesync(msg, now_s)
        elif mtype == "COMMAND_ACK":
            self._on_ack(msg, now_s)
        elif mtype == "STATUSTEXT":
            _log.info("autopilot: %s", _statustext(msg))
        elif mtype == "PARAM_VALUE":
            self._on_param_value(msg)

    def _on_param_value(self, msg) -> None:
        """WPNAV_SPEED [cm/s]: the ceiling of every speed limit we state (ArduPilot)."""
        name = (
            msg.param_id
            if isinstance(msg.param_id, str)
            else msg.param_id.decode("ascii", "replace")
        )
        value = float(msg.param_value)
        if name.split("\x00", 1)[0] != _WPNAV_SPEED or not (math.isfinite(value) and value > 0):
            return
        if self._wpnav_speed_mps is None:
            _log.info(
                "autopilot WPNAV_SPEED %.2f m/s: stated speed limits stay below it", value / 100.0
            )
        self._wpnav_speed_mps = value / 100.0

    def _telemetry_seen(self, t_ns: int) -> None:
        """The newest autopilot telemetry stamp on the frame clock: the clock's "now"."""
        if self._telemetry_newest_ns is None or t_ns > self._telemetry_newest_ns:
            self._telemetry_newest_ns = t_ns

    def _observe(self, t_ns: int) -> None:
        if self._newest_seen_ns is None or t_ns > self._newest_seen_ns:
            self._newest_seen_ns = t_ns

    def _check_boot_time(self, time_boot_ms: int, now_s: float) -> bool:
        """Plausible autopilot time (True), an implausible stamp (dropped, False), or a
        confirmed reboot (state reset, then True: the stamp starts the new time base)."""
        last = self.boot_time.last_ms
        verdict = self.boot_time.check(time_boot_ms, now_s, self.clock.autopilot.rate)
        if verdict is BootTime.DROP:
            self._count_drop("telemetry_implausible_time", "time_boot_ms", (last, time_boot_ms))
            return False
        if verdict is BootTime.REBOOT:
            self._autopilot_restarted(now_s, f"time_boot_ms {last} → {time_boot_ms}")
            self.boot_time.check(time_boot_ms, now_s, self.clock.autopilot.rate)
        self._last_boot_ms = self.boot_time.last_ms
        return True

    def _count_drop(self, counter: str, what: str, values) -> None:
        self.counters[counter] += 1
        self._drop_log(
            counter, "%s: dropped %s %s (%d so far)", counter, what, values, self.counters[counter]
        )

    def _steering(self, now_s: float) -> bool:
        """Our setpoints are flown now: the autopilot in a mode we steer, healthy inputs,
        and alone on the link."""
        return (
            self.modes.steering
            and self.failsafe.status.health.ok
            and self.policy is not None
            and self._may_steer(now_s)
        )

    def _may_steer(self, now_s: float) -> bool:
        """Alone on the link, and it was heard long enough to know (wall seconds)."""
        return not self._takeover_blocked and now_s >= self._listen_until_s

    def _check_takeover(self, now_s: float) -> None:
        """Refuse to steer, loudly, while another setpoint source is around."""
        state = self.takeover.state(now_s)
        if state.blocked == self._takeover_blocked:
            return
        self._takeover_blocked = state.blocked
        if state.blocked:
            self.counters["takeover_refusals"] += 1
            _log.error("not steering: %s; waiting until we are alone", state.reason)
            self._notice("Avoidance refused: another setpoint source", _SEV_WARNING)
            self._event("takeover", blocked=True, reason=state.reason)
        else:
            _log.warning(
                "no other setpoint source for %.0f s: steering allowed again", self.takeover.quiet_s
            )
            self._notice("Avoidance: alone again, steering allowed")
            self._event("takeover", blocked=False, reason="")

    def _on_link_alive(self, now_s: float) -> None:
        self._last_rx_s = now_s
        self._silent_since_s = None
        if not self._link_up:
            self._link_up = True
            # listen before steering: another companion's heartbeat (1 Hz, forwarded by the
            # autopilot) must have had a chance to arrive (companion.takeover)
            self._listen_until_s = now_s + _LISTEN_BEFORE_STEERING_S
            self._event("link_up", url=self.config.link.url)
            _log.info("autopilot link up on %s", self.config.link.url)
            self._next_stream_request_s = now_s
            self._next_timesync_s = now_s

    def _autopilot_restarted(self, now_s: float, why: str) -> None:
        self.counters["autopilot_restarts"] += 1
        _log.warning("autopilot restarted (%s): starting over", why)
        self._event("autopilot_restart", reason=why)
        self._reset_vehicle_state()
        self._next_stream_request_s = now_s

    def _on_heartbeat(self, msg, now_s: float) -> None:
        flavour = detect_flavour(msg.autopilot)
        if self.policy is None:  # first heartbeat since the (re)start
            cfg = self.config.link
            self.policy = SetpointPolicy(
                flavour,
                ardupilot_period_s=cfg.ardupilot_setpoint_period_s,
                px4_rate_hz=cfg.px4_setpoint_rate_hz,
            )
            self._event("autopilot", flavour=flavour.value, mode=msg.custom_mode)
            _log.info(
                "autopilot found: %s (system %d), control mode %s",
                flavour.value,
                msg.get_srcSystem(),
                control_mode(flavour).name,
            )
            if cfg.takeoff_alt_m > 0:
                self.takeoff = TakeoffSequence(
                    flavour,
                    TakeoffSettings(
                        cfg.takeoff_alt_m,
                        tolerance_m=cfg.takeoff_tolerance_m,
                        climb_timeout_s=cfg.takeoff_timeout_s,
                        ready_timeout_s=cfg.takeoff_ready_timeout_s,
                    ),
                    now_s,
                )
        if self._takeoff_busy():
            assert self.takeoff is not None
            self._held_heartbeat = (flavour, msg.custom_mode)
            armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            self.takeoff.on_heartbeat(now_s, msg.custom_mode, armed)
            self._drive_takeoff(now_s)
            return
        self._mode_heartbeat(flavour, msg.custom_mode, now_s)

    def _mode_heartbeat(self, flavour: Flavour, custom_mode: int, now_s: float) -> None:
        before = self.modes.phase
        for notice in self.modes.on_heartbeat(now_s, flavour, custom_mode):
            self._notice(notice)
        self._after_phase_change(before, now_s)

    # ---- takeoff (--takeoff-alt) ---------------------------------------------------
    def _takeoff_busy(self) -> bool:
        return self.takeoff is not None and self.takeoff.busy

    def _takeoff_input(self, msg, mtype: str, now_s: float) -> None:
        """Feed the takeoff sequence what it watches (heartbeats go via _on_heartbeat)."""
        seq = self.takeoff
        assert seq is not None
        if mtype == "EXTENDED_SYS_STATE":
            seq.on_landed_state(now_s, msg.landed_state)
        elif mtype == "LOCAL_POSITION_NED":
            seq.on_position(now_s, msg.time_boot_ms * 1e-3, msg.z)
        elif mtype == "HOME_POSITION":
            seq.on_home_amsl(msg.altitude * 1e-3)
        elif mtype == "GLOBAL_POSITION_INT" and seq.home_amsl_m is None:
            seq.on_home_amsl((msg.alt - msg.relative_alt) * 1e-3)
        elif mtype == "STATUSTEXT":
            seq.on_statustext(_statustext(msg))
        elif mtype == "SYS_STATUS":
            seq.on_sys_status(
                now_s,
                msg.onboard_control_sensors_present,
                msg.onboard_control_sensors_health,
            )
        elif mtype == "COMMAND_ACK" and self._ack_is_ours(msg):
            seq.on_ack(now_s, msg.command, msg.result)
        else:
            return
        self._drive_takeoff(now_s)

    def _ack_is_ours(self, msg) -> bool:
        """COMMAND_ACK addressed to us (0 = not filled in by a MAVLink 1 sender)."""
        cfg = self.config.link
        return getattr(msg, "target_system", 0) in (0, cfg.system_id) and getattr(
            msg, "target_component", 0
        ) in (0, cfg.component_id)

    def _drive_takeoff(self, now_s: float) -> None:
        """Carry out the sequence's actions; start steering when it is over."""
        seq = self.takeoff
        if seq is None:
            return
        cfg = self.config.link
        for action in seq.pop_actions():
            if isinstance(action, TakeoffCommand):
                if action.name != "REQUEST_MESSAGE":
                    _log.info(
                        "takeoff: sending %s (attempt %d)", action.name, action.confirmation + 1
                    )
                self._send(
                    command_long(
                        cfg.target_system,
                        cfg.target_component,
                        action.command,
                        *action.params,
                        confirmation=action.confirmation,
                    )
                )
            elif isinstance(action, TakeoffNotice):
                self._notice(action.text, action.severity)
            elif isinstance(action, TakeoffEvent):
                self._event("takeoff", **action.fields)
        if seq.step is TakeoffStep.FAILED and self.fatal is None:
            self.fatal = f"takeoff failed: {seq.reason}"
            _log.error("%s; not steering, stopping", self.fatal)
        elif seq.step in (TakeoffStep.DONE, TakeoffStep.SKIPPED) and self._held_heartbeat:
            flavour, custom_mode = self._held_heartbeat
            self._held_heartbeat = None
            self._mode_heartbeat(flavour, custom_mode, now_s)  # engage at once

    def _after_phase_change(self, before: ControlPhase, now_s: float) -> None:
        after = self.modes.phase
        if after is before:
            return
        self._event(
            "phase",
            phase=after.value,
            mode=self.modes.mode_text(),
            setpoints_sent=self.counters["setpoints_sent"],
        )
        if after is ControlPhase.RELEASED:
            self.counters["mode_releases"] += 1
        if after in (ControlPhase.ACTIVE, ControlPhase.PRESTREAM) and self.policy is not None:
            self.policy.reset()  # first setpoint goes out at once
            self.speed_policy.reset()  # ArduCopter resets its speed on entering GUIDED
            self._resend_now(now_s)

    def _on_timesync(self, msg, now_s: float) -> None:
        now_ns = self._now_ns
        if msg.tc1 == 0:  # the autopilot asks for our time
            self._send(timesync_reply(now_ns, msg.ts1))
            return
        if msg.ts1 not in self._timesync_pending:
            self.counters["timesync_unmatched"] += 1  # not an answer to a request of ours
            return
        self._timesync_pending.remove(msg.ts1)
        result = self.clock.autopilot.add_sample(SyncSample(msg.ts1, msg.tc1, now_ns))
        if result is SyncResult.REBOOT:
            self._autopilot_restarted(now_s, "TIMESYNC went backwards")

    def _on_ack(self, msg, now_s: float) -> None:
        accepted = msg.result == mavlink.MAV_RESULT_ACCEPTED
        if msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            if accepted:
                self._streams_acked += 1
            return
        if msg.command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            key = "speed_limits_accepted" if accepted else "speed_limits_refused"
            self.counters[key] += 1
            if not accepted and self.counters[key] == 1:
                _log.info("autopilot refuses DO_CHANGE_SPEED (result %d): the carrot alone "
                          "bounds the speed", msg.result)  # fmt: skip
            return
        if msg.command == mavlink.MAV_CMD_DO_SET_MODE:
            before = self.modes.phase
            if accepted:
                mode = self._last_mode_request
                if mode is not None:
                    for notice in self.modes.on_mode_accepted(now_s, mode.custom_mode):
                        self._notice(notice)
            else:
                result = mavlink.enums["MAV_RESULT"].get(msg.result)
                for notice in self.modes.on_mode_refused(
                    now_s, result.name if result else str(msg.result)
                ):
                    self._notice(notice, _SEV_WARNING)
            self._after_phase_change(before, now_s)

    # ---- timers --------------------------------------------------------------------
    def _timers(self, now_s: float) -> None:
        cfg = self.config.link
        if now_s >= self._next_heartbeat_s:
            self._send(heartbeat_message(self._state(), self.instance_id))
            self._check_takeover(now_s)
            self._next_heartbeat_s = now_s + cfg.heartbeat_period_s
        if self.proximity is not None and self.proximity.due(now_s):
            self._send_proximity_now(now_s)
        if self._link_up and now_s - self._last_rx_s > self.config.failsafe.link_timeout_s:
            self._link_lost(now_s)
        if not self._link_up:
            self._report_silence(now_s)
            return
        if now_s >= self._next_timesync_s:
            stamp = self._now_ns
            self._timesync_pending.append(stamp)
            del self._timesync_pending[:-_MAX_TIMESYNC_PENDING]
            self._send(timesync_request(stamp))
            self._next_timesync_s = now_s + cfg.timesync_period_s
        if now_s >= self._next_stream_request_s and self._streams_acked < len(STREAMS):
            self._streams_acked = 0
            for msg_id in STREAMS:
                self._send(
                    set_message_interval(
                        cfg.target_system, cfg.target_component, msg_id, cfg.telemetry_rate_hz
                    )
                )
            self._next_stream_request_s = now_s + 1.0
        if self._takeoff_busy():
            assert self.takeoff is not None
            self.takeoff.tick(now_s)
            self._drive_takeoff(now_s)
        before = self.modes.phase
        request = self.modes.tick(now_s)
        if request is not None:
            self._request_mode(request)
        self._after_phase_change(before, now_s)
        policy = self.policy
        if policy is not None and (
            policy.due(now_s) or (policy.last is None and self._must_stream())
        ):
            self._resend_now(now_s)

    def _must_stream(self) -> bool:
        flavour = self.modes.flavour
        return (
            flavour is not None
            and profile_for(flavour).streams_setpoints
            and (self.modes.steering or self.modes.streaming_hold)
        )

    def _link_lost(self, now_s: float) -> None:
        self._link_up = False
        self.counters["link_losses"] += 1
        _log.warning(
            "autopilot link lost: nothing for %.1f s (wall); stopped commanding, waiting",
            now_s - self._last_rx_s,
        )
        self._event("link_lost", silent_s=round(now_s - self._last_rx_s, 3))
        self._reset_vehicle_state()

    def _request_mode(self, request) -> None:
        cfg = self.config.link
        self._last_mode_request = request
        self.counters["mode_requests"] += 1
        _log.info("requesting %s", request.name)
        self._send(set_mode_command(cfg.target_system, cfg.target_component, request))

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
            self.counters["mavlink_sent"],
            hint,
        )
        self._event("no_autopilot", silent_s=round(silent, 1), signing=self._signing)

    # ---- frames --------------------------------------------------------------------
    def _on_frame(self, frame: StereoFrame, recv_ns: int) -> None:
        if self.frame_time_plausible(frame.capture_ns, self._now_ns) is False:
            # frames never move the clock nor reset the mission: only telemetry may
            self._count_drop("frames_implausible_time", "frame", (frame.sequence, frame.capture_ns))
            return
        if self._takeoff_busy():
            self._frame_during_takeoff(frame)
            return
        if self._last_capture_ns is not None and frame.capture_ns <= self._last_capture_ns:
            self.counters["frames_stale"] += 1
            return
        lookup = self.poses.at(frame.capture_ns)
        if not lookup.status.usable:
            self.counters[f"pose_{lookup.status.value}"] += 1
            self._drop_log(
                lookup.status.value,
                "frame %d dropped: no pose at its capture time (%s; %d so far)",
                frame.sequence,
                lookup.status.value,
                self.counters[f"pose_{lookup.status.value}"],
            )
            return
        if lookup.status is PoseStatus.EXTRAPOLATED:
            self.counters["pose_extrapolated"] += 1
        self._last_capture_ns = frame.capture_ns
        self._observe(frame.capture_ns)
        pose = lookup.pose
        assert pose is not None
        # Whether the vehicle flies what this frame yields (not in our failsafe hold, a
        # pilot's mode or beside another source): time it does not, guidance does not
        # count as its own lack of progress.
        steering = self._steering(self._now_s)
        age_s = self._frame_age_s(frame.capture_ns)
        try:
            result = self.mission.step(
                frame, pose, steering=steering, latency_s=self.data_age.budget_s(age_s)
            )
        except Exception as exc:  # a bad frame must never stop the companion (cv2.error too)
            self.counters["pipeline_errors"] += 1
            self._drop_log("pipeline", "frame %d: pipeline error %s", frame.sequence, exc)
            return
        out = result.output
        self._processed(frame.capture_ns, out, age_s, pose.pos_ned_m)
        self._check_failsafe(self._now_s)
        sent = False
        target = PositionTarget(tuple(float(x) for x in out.setpoint_ned_m), float(out.yaw_rad))
        if self._steering(self._now_s):
            assert self.policy is not None
            if self.policy.on_new_target(target, self._now_s):
                self._send_target(target, self._now_s, frame.capture_ns)
                sent = True
            self._state_speed_limit(out.envelope.speed_limit_mps, self._now_s)
        self._check_overspeed(out)
        for notice in result.notices:
            self._notice(notice.text, _SEV_WARNING if notice.warning else _SEV_INFO)
        self._out.extend(result.events)
        self._send_proximity_frame(frame.capture_ns, pose)
        host_capture = frame.capture_ns if self.clock.frame_clock is FrameClock.HOST else None
        document = status_document(
            out,
            state=self._state().value,
            phase=self.modes.phase.value,
            autopilot_mode=self.modes.mode_text(),
            health=self.failsafe.status.health.value,
            pose=lookup.status.value,
            pos_ned_m=[round(float(x), 4) for x in pose.pos_ned_m],
            waypoint=result.waypoint,
            setpoint_sent=sent,
            pipeline=self._pipeline_figures(out.envelope.latency_s),
            mode_requests=self.counters["mode_requests"],
            proximity=None if self.proximity is None else self.proximity.figures(self._now_s),
        )
        self._out.append(Status(document, recv_ns, self._now_ns, host_capture))
        if self.report_pipeline:  # a viewer is attached (companion.viz)
            pipeline = self.mission.pipeline
            self._out.append(
                FrameProcessed(frame, pose, result, pipeline.goal_ned_m, pipeline.known_space, sent)
            )

    def _frame_during_takeoff(self, frame: StereoFrame) -> None:
        self._observe(frame.capture_ns)
        self.counters["frames_during_takeoff"] += 1  # not steering before the climb
        assert self.takeoff is not None
        self.takeoff.on_frame(self._now_s)
        if self._newest_frame_ns is None or frame.capture_ns > self._newest_frame_ns:
            self._newest_frame_ns = frame.capture_ns  # the camera works: health
        self._drive_takeoff(self._now_s)

    def _processed(self, capture_ns: int, out, age_s: float | None, pos_ned_m) -> None:
        """A frame went through the mission: health, its data age to take at the next
        input, the figures, and a hold target kept out of the boundaries it showed."""
        self.counters["frames_processed"] += 1
        self._newest_frame_ns = capture_ns
        self._age_pending = (capture_ns, self._now_ns, 0.0 if age_s is None else age_s)
        self._speed_limit_mps = float(out.envelope.speed_limit_mps)
        self._boundaries = tuple(out.boundaries)
        self._recheck_hold_target(pos_ned_m)

    # ---- the latency budget (issue 32) ---------------------------------------------
    def _frame_age_s(self, capture_ns: int) -> float | None:
        """Age of a frame's data now [s, frame clock] (None: no clock yet)."""
        now_frame = self.clock.now_frame_ns(self._now_ns, self._newest_seen_ns)
        return None if now_frame is None else (now_frame - capture_ns) * 1e-9

    def _frame_clock_rate(self) -> float:
        """Frame-clock seconds per host second (plant-sim at --speedup N: N)."""
        if self.clock.frame_clock is FrameClock.HOST:
            return 1.0
        rate = self.clock.autopilot.rate
        return min(max(rate, 0.01), 1000.0) if math.isfinite(rate) else 1.0

    def _measure_data_age(self) -> None:
        """The last frame's command left during its step: its data age is its age at the
        step's start plus the host time since then (this input's ``now_ns``, which the
        service steps right after carrying a frame's outputs out) on the frame clock."""
        if self._age_pending is None:
            return
        capture_ns, started_ns, age_at_start_s = self._age_pending
        self._age_pending = None
        compute_s = (self._now_ns - started_ns) * 1e-9 * self._frame_clock_rate()
        self.data_age.add(capture_ns, age_at_start_s + compute_s)

    def _pipeline_figures(self, latency_s: float | None = None) -> dict[str, Any]:
        """Processing rate, data age p50/p99, latency budget and speed limit (status)."""
        stats = self.data_age.stats()

        def ms(value: float | None) -> float | None:
            return None if value is None else round(value * 1e3, 1)

        return {
            "rate_hz": None if stats.rate_hz is None else round(stats.rate_hz, 2),
            "data_age_p50_ms": ms(stats.p50_s),
            "data_age_p99_ms": ms(stats.p99_s),
            "latency_budget_s": round(
                self.data_age.budget_s() if latency_s is None else latency_s, 4
            ),
            "speed_limit_mps": None
            if self._speed_limit_mps is None
            else round(self._speed_limit_mps, 3),
            "ages_rejected": self.data_age.rejected,
            "ages_clamped": self.data_age.clamped,
        }

    def _state_speed_limit(self, limit_mps: float, now_s: float) -> None:
        """ArduPilot: the envelope's speed limit as MAV_CMD_DO_CHANGE_SPEED (see
        :mod:`companion.link.speed_limit`); other autopilots: the carrot alone."""
        flavour = self.modes.flavour
        if flavour is None or not profile_for(flavour).states_speed_limit:
            return
        if self._wpnav_speed_mps is None:
            # DO_CHANGE_SPEED overrides WPNAV_SPEED (no clip): never state a speed before we
            # know the pilot's own limit, so that ours can only lower it (the carrot bounds
            # the speed meanwhile)
            if now_s >= self._next_param_request_s and self._param_requests < 5:
                self._param_requests += 1
                if self._param_requests == 5:
                    _log.warning(
                        "autopilot does not report %s: no speed limit stated, the carrot "
                        "alone bounds the speed",
                        _WPNAV_SPEED,
                    )
                self._next_param_request_s = now_s + 2.0
                cfg = self.config.link
                self._send(
                    mavlink.MAVLink_param_request_read_message(
                        cfg.target_system, cfg.target_component, _WPNAV_SPEED.encode(), -1
                    )
                )
            return
        speed = self.speed_policy.due(min(limit_mps, self._wpnav_speed_mps), now_s)
        if speed is None:
            return
        cfg = self.config.link
        self._send(change_speed_command(speed, cfg.target_system, cfg.target_component))
        self.speed_policy.sent(speed, now_s)
        self.counters["speed_limits_sent"] += 1

    def _check_overspeed(self, out) -> None:
        """Warn (log + STATUSTEXT, at most every 5 s) when telemetry exceeds the limit."""
        env = out.envelope
        if not env.overspeed:
            return
        self.counters["overspeed_frames"] += 1
        now_s = self._now_s
        if now_s - self._overspeed_notice_s >= 5.0:
            self._overspeed_notice_s = now_s
            self._notice(
                f"Speed {env.speed_mps:.1f} m/s above limit {env.speed_limit_mps:.1f} m/s",
                _SEV_WARNING,
            )

    def _send_target(self, target: PositionTarget, now_s: float, frame_ns: int | None) -> None:
        cfg = self.config.link
        ap_ns = None
        if frame_ns is not None:
            ap_ns = self.clock.frame_to_autopilot_ns(frame_ns)
        if ap_ns is None:
            ap_ns = (self._last_boot_ms or 0) * 1_000_000
        msg = position_target_message(
            target, ap_ns // 1_000_000, cfg.target_system, cfg.target_component
        )
        self._out.append(SendSetpoint(msg, target))
        self.counters["mavlink_sent"] += 1
        assert self.policy is not None
        self.policy.sent(target, now_s)
        self.counters["setpoints_sent"] += 1
        if not self._engaged:
            self._engaged = True
            self._event(
                "steering",
                setpoint_ned_m=list(target.pos_ned_m),
                autopilot_time_s=None if self._last_boot_ms is None else self._last_boot_ms / 1e3,
            )

    def _resend_now(self, now_s: float) -> None:
        """Keep-alive / PX4 stream / hold: (re)send the appropriate target."""
        if self.policy is None or not self._may_steer(now_s):
            return
        if self.modes.streaming_hold or (self.modes.steering and self._hold is not Response.STEER):
            target = self._hold_target or self._current_hold()
        elif self.modes.steering and not self.failsafe.status.health.ok and self._must_stream():
            target = self._current_hold()
        elif self.modes.steering and (self.failsafe.status.health.ok or self.policy.last is None):
            target = self.policy.last
            if target is None and self._must_stream():
                target = self._current_hold()
        else:
            return
        if target is not None:
            self._send_target(target, now_s, None)

    def _current_hold(self) -> PositionTarget | None:
        """Hold where the vehicle is (out of a boundary it is in), no braking point."""
        return self._hold_point_target(moving=False)

    def _hold_point_target(self, *, moving: bool = True) -> PositionTarget | None:
        """The braking point of the newest pose, never inside a boundary
        (:func:`companion.guidance.hold.hold_point`); says so once per hold if moved."""
        newest = self.poses.newest_ns
        if newest is None:
            return None
        lookup = self.poses.at(newest)
        if lookup.pose is None:
            return None
        pose = lookup.pose
        point = hold_point(
            pose.pos_ned_m,
            pose.vel_ned_mps if moving else (0.0, 0.0, 0.0),
            self._boundaries,
            latency_s=self.data_age.budget_s(),
            accel_mps2=self.config.envelope.accel_mps2,
            clearance_m=self.config.guidance.escape_clearance_m,
        )
        if point.moved and not self._hold_moved_told:
            self._hold_moved_told = True
            self.counters["hold_targets_moved"] += 1
            self._notice(f"Hold target kept out of a boundary ({point.placement.value})")
            self._event(
                "hold_target_moved",
                placement=point.placement.value,
                setpoint_ned_m=[round(x, 3) for x in point.pos_ned_m],
                pos_ned_m=[round(float(x), 3) for x in pose.pos_ned_m],
            )
        return PositionTarget(point.pos_ned_m, pose.yaw_rad)

    def _recheck_hold_target(self, pos_ned_m) -> None:
        """In a position hold, a frame that shows the vehicle or its target inside a
        boundary (drift, a late frame) moves the target out at once."""
        if self._hold is not Response.HOLD_POSITION or self._hold_target is None:
            return
        if not (
            inside_any(pos_ned_m, self._boundaries)
            or inside_any(self._hold_target.pos_ned_m, self._boundaries)
        ):
            return
        target = self._hold_point_target()
        if target is not None and target != self._hold_target:
            self._hold_target = target
            if self.modes.steering and self.policy is not None and self._may_steer(self._now_s):
                self._send_target(target, self._now_s, None)

    def _send_proximity_frame(self, capture_ns: int, pose) -> None:
        """OBSTACLE_DISTANCE of the map this frame updated, stamped with its capture time,
        seen from the newest telemetry pose (where the vehicle is now, not where it was
        when the frame was taken: the frame's processing time is not added to the
        autopilot's reaction) or, without a newer one, from the frame's pose."""
        if self.proximity is None:
            return
        newest = self.poses.newest_ns
        if newest is not None and newest > capture_ns:
            lookup = self.poses.at(newest)
            if lookup.pose is not None:
                pose = lookup.pose
        sectors = self.proximity.on_frame(
            self.mission.pipeline.known_space, pose.pos_ned_m, pose.yaw_rad, self._now_s
        )
        self._send(obstacle_distance_message(capture_ns // 1000, sectors))

    def _send_proximity_now(self, now_s: float) -> None:
        """OBSTACLE_DISTANCE between frames: the map at the newest pose (all unknown
        without one), stamped with the newest depth's capture time (frame clock)."""
        assert self.proximity is not None
        pose = None
        newest = self.poses.newest_ns
        if newest is not None:
            pose = self.poses.at(newest).pose
        sectors = self.proximity.on_timer(
            self.mission.pipeline.known_space,
            None if pose is None else pose.pos_ned_m,
            None if pose is None else pose.yaw_rad,
            now_s,
        )
        stamp_ns = self._last_capture_ns if self._last_capture_ns is not None else newest
        self._send(obstacle_distance_message(max(stamp_ns or 0, 0) // 1000, sectors))

    # ---- failsafe ------------------------------------------------------------------
    def _check_failsafe(self, now_s: float) -> None:
        """Late inputs: a position hold in the control mode; lost inputs: the autopilot's
        hold mode (the last resort); healthy for the settle time: steer again."""
        now_frame = self.clock.now_frame_ns(self._now_ns, self._newest_seen_ns)
        changed = self.failsafe.update(now_frame, self._newest_frame_ns, self.poses.newest_ns)
        if self.modes.flavour is None:
            return  # (during a takeoff the health is tracked for the status line only)
        response = self.failsafe.response
        if response is self._hold or Response.STEER < response < self._hold:
            return
        if response is Response.STEER:
            self._end_hold(now_s)
            return
        status = self.failsafe.status
        if not self._engaged or status.health in (Health.NO_FRAMES, Health.NO_CLOCK):
            if changed is not None:
                _log.info("not steering yet: %s", changed.value)
            return
        before = self.modes.phase
        if self._hold is Response.STEER:
            self.counters["hold_commands"] += 1
            self._hold_moved_told = False
            self._hold_target = None
        self._hold = response
        self._hold_target = self._hold_target or self._hold_point_target()
        request = None
        if response is Response.HOLD_MODE:
            self.counters["mode_holds"] += 1
            request = self.modes.set_hold(now_s, True)
        what = request.name if request is not None else "hold position"
        ages = f"frames {_age(status.frame_age_s)}, telemetry {_age(status.telemetry_age_s)}"
        self._notice(f"Failsafe {status.health.value}: {what}", _SEV_WARNING)
        _log.warning("failsafe %s (%s): commanding %s", status.health.value, ages, what)
        self._event(
            "hold",
            reason=status.health.value,
            command=what,
            frame_age_s=status.frame_age_s,
            telemetry_age_s=status.telemetry_age_s,
            newest_frame_ns=self._newest_frame_ns,
            now_frame_ns=now_frame,
            setpoint_ned_m=None
            if self._hold_target is None
            else [round(x, 3) for x in self._hold_target.pos_ned_m],
        )
        if request is not None:
            self._request_mode(request)
        else:
            self._resend_now(now_s)
        self._after_phase_change(before, now_s)

    def _end_hold(self, now_s: float) -> None:
        """Healthy for the settle time: guidance's setpoints again (the control mode)."""
        before, was = self.modes.phase, self._hold
        self._hold, self._hold_target = Response.STEER, None
        request = self.modes.set_hold(now_s, False)
        if was is not Response.STEER:
            self._notice("Frames and telemetry healthy: avoidance resumes")
            self._event("resume")
            if self.policy is not None:
                self.policy.reset()  # the next guidance setpoint goes out at once
        if request is not None:
            self._request_mode(request)
        self._after_phase_change(before, now_s)

    # ---- reporting -----------------------------------------------------------------
    def _state(self) -> CompanionState:
        if not self._link_up:
            return CompanionState.LINK_LOST if self.counters["link_losses"] else CompanionState.BOOT
        if not self._may_steer(self._now_s):
            return CompanionState.STANDBY
        if self.modes.phase is ControlPhase.HOLD or self._hold is not Response.STEER:
            return CompanionState.HOLD
        if self.modes.steering and self.failsafe.status.health.ok:
            return CompanionState.ACTIVE
        if self._newest_frame_ns is None:
            return CompanionState.BOOT
        return CompanionState.STANDBY

    def _notice(self, text: str, severity: int = _SEV_INFO) -> None:
        """STATUSTEXT to the ground station; longer than 50 characters: MAVLink 2 chunks."""
        _log.info("STATUSTEXT: %s", text)
        if len(text) > 50:
            self._text_id = self._text_id % 255 + 1
        for msg in statustext_messages(text, severity, self._text_id or 1):
            self._send(msg)

    def _event(self, name: str, **fields: Any) -> None:
        self._out.append(Event(name, fields))

    def _send(self, message) -> None:
        self._out.append(SendMavlink(message))
        self.counters["mavlink_sent"] += 1

    def _drop_log(self, key: str, fmt: str, *args: Any) -> None:
        now = self._now_s
        if now - self._drop_log_s.get(key, -math.inf) >= 2.0:
            self._drop_log_s[key] = now
            _log.warning(fmt, *args)


_MAX_POS_M = 1e5  # |LOCAL_NED| beyond this is not a position of a multirotor
_MAX_SPEED_MPS = 300.0


def _in_range(values, bound: float) -> bool:
    return all(math.isfinite(v) and abs(v) <= bound for v in values)


def _statustext(msg) -> str:
    """The STATUSTEXT's text, printable ASCII only (raw bytes never reach the log)."""
    text = msg.text if isinstance(msg.text, str) else msg.text.decode("ascii", "replace")
    text = text.split("\x00", 1)[0]
    return "".join(c if " " <= c <= "~" else "?" for c in text)


def _failsafe_monitor(config: CompanionConfig) -> FailsafeMonitor:
    fs = config.failsafe
    return FailsafeMonitor(
        fs.frame_timeout_s,
        fs.telemetry_timeout_s,
        fs.resume_after_s,
        frame_loss_s=fs.frame_loss_s,
        telemetry_loss_s=fs.telemetry_loss_s,
    )


def _age(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f} s"
