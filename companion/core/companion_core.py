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

The work is split by job, one component each in ``companion/core/*_job.py``: each owns
its state, takes typed inputs and returns typed decisions, and this class composes them
and routes each input (see :class:`CompanionCore`). Counters are one typed record
(:class:`~companion.core.counters.CoreCounters`); outputs collect in an
:class:`~companion.core.outbox.Outbox`.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.clock_model import ClockModel, FrameClock
from companion.config import CompanionConfig
from companion.core.counters import CoreCounters
from companion.core.events import (
    FrameProcessed,
    FrameReceived,
    Input,
    MavlinkReceived,
    Output,
    Status,
    Tick,
)
from companion.core.failsafe_job import FailsafeJob, HoldView
from companion.core.frame_job import FrameJob
from companion.core.link_job import LinkJob, statustext
from companion.core.mission import Mission
from companion.core.modes_job import ModesJob, PhaseChange
from companion.core.outbox import Outbox
from companion.core.param_job import ParamJob
from companion.core.proximity_job import ProximityJob
from companion.core.setpoint_job import SetpointJob
from companion.core.status_job import StatusJob
from companion.core.streams_job import STREAMS, StreamsJob
from companion.core.takeoff_job import Engage, TakeoffJob
from companion.core.telemetry_job import MAX_POS_M, Restarted, TelemetryJob, in_range
from companion.failsafe import Response
from companion.link.flavour import (
    control_mode,
    detect_flavour,
    is_autopilot_heartbeat,
    profile_for,
)
from companion.link.messages import CompanionState, mav_state
from companion.link.mode_watch import ControlPhase
from companion.link.setpoints import PositionTarget
from companion.phase_times import Phase, PhaseClocks, PhaseTimes
from companion.pose_history import PoseHistory, PoseLookup
from companion.proximity.sender import ProximitySender
from companion.takeover import SETPOINT_MESSAGES
from protocols.stereo_frame import StereoFrame

_log = logging.getLogger("companion")

_IN_CONTROL_STATES = frozenset({mavlink.MAV_STATE_ACTIVE, mavlink.MAV_STATE_CRITICAL})

__all__ = ["STREAMS", "CompanionCore"]


class CompanionCore:
    """Every decision of the companion, stepped by :meth:`step` (no sockets, no clock).

    Composes the jobs, one component each (each module docstring names what it owns,
    takes and returns): :mod:`~companion.core.link_job` (link up/lost, our heartbeat),
    :mod:`~companion.core.telemetry_job` (poses on the frame clock, boot time, stated
    accuracy; a ``Restarted`` out), :mod:`~companion.core.streams_job` (streams,
    TIMESYNC; a ``SyncSample`` out), :mod:`~companion.core.param_job` (WPNAV_SPEED),
    :mod:`~companion.core.modes_job` (modes and takeover; a ``PhaseChange`` out),
    :mod:`~companion.core.takeoff_job` (an ``Engage`` out),
    :mod:`~companion.core.frame_job` (the mission, the latency budget; a ``MissionStep``
    out), :mod:`~companion.core.setpoint_job` (setpoints, speed limit),
    :mod:`~companion.core.failsafe_job` (holds; the ``Response`` to start or end out),
    :mod:`~companion.core.proximity_job` (OBSTACLE_DISTANCE) and
    :mod:`~companion.core.status_job` (state, figures). This class decides what crosses
    between them (which target to send when, a hold's mode request, a restart's reset)
    and routes each input.

    Parameters
    ----------
    config : CompanionConfig
    instance_id : int
        This companion's random 32-bit id (in its heartbeat's ``custom_mode``; see
        :mod:`companion.takeover`). Passed in so that a replay is deterministic.
    report_pipeline : bool
        Also return a :class:`~companion.core.events.FrameProcessed` per processed frame
        (a viewer is attached); off: nothing is built for it.
    phase_clocks : PhaseClocks, optional
        The service's clocks to time each phase with (None: counted only).
    """

    def __init__(
        self,
        config: CompanionConfig,
        instance_id: int,
        *,
        report_pipeline: bool = False,
        phase_clocks: PhaseClocks | None = None,
    ) -> None:
        self.config = config
        self.phases = PhaseTimes(phase_clocks)  # where the work goes (companion.phase_times)
        self.report_pipeline = report_pipeline
        self.instance_id = instance_id
        self.counters = CoreCounters()
        self.out = Outbox(self.counters)
        self._now_ns = 0
        self._now_s = 0.0
        link, fs = config.link, config.failsafe
        self.link = LinkJob(link, fs, instance_id, self.out, self.counters)  # a component
        # telemetry (poses, frame clock), streams and TIMESYNC
        self.telemetry = TelemetryJob(link, fs, self.out, self.counters)  # a component
        self.frames = FrameJob(config, self.out, self.counters, self.phases)  # a component
        self.streams = StreamsJob(link, self.out, self.counters)  # a component
        self.params = ParamJob(link, self.out)  # a component: WPNAV_SPEED
        # modes and takeover
        self.modes = ModesJob(link, instance_id, self.out, self.counters)  # a component
        self.failsafe = FailsafeJob(config, self.out, self.counters)  # a component
        self.takeoff_job = TakeoffJob(link, self.out)
        self.setpoints = SetpointJob(link, self.out, self.counters)  # a component
        # OBSTACLE_DISTANCE from start-up, whatever the link, mode or phase
        self.proximity = ProximitySender(config.proximity) if config.proximity.enabled else None
        self.proximity_job = ProximityJob(self.proximity, self.out)  # a component
        self.status = StatusJob(
            self.counters,
            self.telemetry,
            self.modes,
            self.failsafe,
            self.frames,
            self.setpoints,
            self.takeoff_job,
            self.proximity,
        )  # a component: reads the others
        self._reset_vehicle_state()

    # ---- what the adapters read ----------------------------------------------------
    def stats(self) -> dict[str, Any]:
        """Counters and state for the exit statistics; ``phases``: where the work went."""
        return {**self.status.stats(), "phases": self.phases.as_dict()}

    def progress_text(self) -> str:
        """One line for the periodic progress log (time, position, phase, mode, health)."""
        return self.status.progress_text(self._now_s)

    def _state(self) -> CompanionState:
        """The state in our heartbeat and the status."""
        return self.status.state(self.link.up, self._may_steer(self._now_s))

    @property
    def link_up(self) -> bool:
        """An autopilot message arrived within the link timeout."""
        return self.link.up

    @property
    def autopilot_seen(self) -> bool:
        """An autopilot heartbeat arrived since the (re)connection."""
        return self.setpoints.policy is not None

    @property
    def flying(self) -> bool:
        """The companion steers or holds the vehicle (frames are needed)."""
        return self.modes.phase in (ControlPhase.ACTIVE, ControlPhase.HOLD)

    @property
    def mission(self) -> Mission:
        """Waypoints around the avoidance pipeline (the frame job's; new at a reset)."""
        return self.frames.mission

    def frame_time_plausible(self, capture_ns: int, now_ns: int) -> bool | None:
        """Capture time within the window around the clock model's now (any thread)."""
        return self.telemetry.frame_time_plausible(capture_ns, now_ns)

    @property
    def clock(self) -> ClockModel:
        """The frame clock and the autopilot's TIMESYNC fit (the telemetry job's)."""
        return self.telemetry.clock

    @property
    def poses(self) -> PoseHistory:
        """The pose history on the frame clock (the telemetry job's)."""
        return self.telemetry.poses

    def frame_clock_rate(self) -> float:
        """Frame-clock seconds per host second: the service's OBSTACLE_DISTANCE watchdog
        carries positions forward with it (:mod:`companion.proximity.stream`)."""
        return self.telemetry.frame_clock_rate()

    @property
    def fatal(self) -> str | None:
        """A terminal error (a refused takeoff): the process stops."""
        return self.takeoff_job.fatal

    # ---- per-connection state ------------------------------------------------------
    def _reset_vehicle_state(self, *, telemetry: bool = True) -> None:
        """Link lost or autopilot restarted: everything learnt about the vehicle goes
        (``telemetry=False``: the telemetry job saw the restart and started over itself)."""
        self.frames.reset()
        if telemetry:
            self.telemetry.reset()
        self.streams.reset()
        self.modes.reset()
        self.setpoints.reset()
        self.params.reset()  # the autopilot's WPNAV_SPEED, asked for again
        # failsafe
        self.failsafe.reset()
        # takeoff
        self.takeoff_job.reset()

    # ---- inputs ------------------------------------------------------------------
    def step(self, event: Input) -> list[Output]:
        """Handle one input; returns what the adapters must do, in order."""
        self._now_ns = event.now_ns
        self._now_s = event.now_ns * 1e-9
        self.out.begin(self._now_s)
        self.frames.measure_data_age(self._now_ns, self.telemetry.frame_clock_rate())
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
        return self.out.take()

    def _timers(self, now_s: float) -> None:
        """Every timer, in this order: heartbeat, OBSTACLE_DISTANCE, link loss; with the
        link up, TIMESYNC and streams, takeoff, mode requests, setpoint keep-alive."""
        if self.link.heartbeat_due(now_s):  # and the twin rule re-checked with it
            self.link.send_heartbeat(self._state(), now_s)
            self.modes.check_takeover(now_s)
        if self.proximity_job.due(now_s):  # between frames
            newest, last_capture_ns = self.poses.newest_ns, self.frames.last_capture_ns
            stamp_ns = last_capture_ns if last_capture_ns is not None else newest
            space = self.mission.pipeline.known_space
            self.proximity_job.on_timer(space, self._proximity_pose(), stamp_ns, now_s)
        if self.link.check_lost(now_s):
            self._reset_vehicle_state()
        if not self.link.up:
            self.link.report_silence(now_s)
            return
        self.streams.timers(now_s, self._now_ns)
        self._engage(self.takeoff_job.tick(now_s), now_s)
        self._after_phase_change(self.modes.tick(now_s), now_s)
        if self.setpoints.due(now_s, self.modes.must_stream()):  # keep-alive or stream
            self._resend_now(now_s)

    def _engage(self, engage: Engage | None, now_s: float) -> None:
        """The takeoff is over: the mode watch takes the heartbeat it held (at once)."""
        if engage is not None:
            self._after_phase_change(
                self.modes.on_heartbeat(engage.flavour, engage.custom_mode, now_s), now_s
            )

    def _after_phase_change(self, change: PhaseChange | None, now_s: float) -> None:
        """Engaging the control mode: the first setpoint goes out at once."""
        if change is not None and change.engaging and self.setpoints.policy is not None:
            self.setpoints.engaging()
            self._resend_now(now_s)

    def _check_failsafe(self, now_s: float) -> None:
        """Late inputs: a position hold in the control mode; lost inputs: the autopilot's
        hold mode (the last resort); healthy for the settle time: steer again."""
        now_frame = self.telemetry.now_frame_ns(self._now_ns)
        response = self.failsafe.update(
            now_frame,
            self.frames.newest_frame_ns,
            self.poses.newest_ns,
            autopilot_known=self.modes.flavour is not None,
            engaged=self.setpoints.engaged,
        )
        if response is None:
            return
        before = self.modes.phase
        if response is Response.STEER:  # guidance's setpoints again (the control mode)
            policy = self.setpoints.policy
            if self.failsafe.end_hold() and policy is not None:
                policy.reset()  # the next guidance setpoint goes out at once
            request = self.modes.set_hold(now_s, False)
            if request is not None:
                self.modes.request(request)
        else:
            self.failsafe.start_hold(response, self._hold_view())
            request = None
            if response is Response.HOLD_MODE:
                request = self.modes.set_hold(now_s, True)
            what = request.name if request is not None else "hold position"
            self.failsafe.report_hold(what, now_frame, self.frames.newest_frame_ns)
            if request is not None:
                self.modes.request(request)
            else:
                self._resend_now(now_s)
        self._after_phase_change(self.modes.changed(before), now_s)

    def _hold_view(self) -> HoldView:
        """The newest pose, the last frame's boundaries, the latency budget and the map's
        question for a way out of them."""
        newest = self.poses.newest_ns
        pose = None if newest is None else self.poses.at(newest).pose
        boundaries = self.frames.boundaries
        check = None
        if pose is not None:
            check = self.frames.mission.pipeline.way_check(boundaries, pose.yaw_rad)
        return HoldView(pose, boundaries, self.frames.data_age.budget_s(), check)

    def _recheck_hold_target(self, pos_ned_m) -> None:
        """A processed frame in a position hold: the target moved out of a boundary the
        frame shows is sent at once (when our setpoints are flown)."""
        target = self.failsafe.recheck_target(pos_ned_m, self._hold_view())
        if target is None:
            return
        if (
            self.modes.steering
            and self.setpoints.policy is not None
            and self._may_steer(self._now_s)
        ):
            self._send_target(target, self._now_s, None)

    def _in_control(self, now_s: float) -> bool:
        """The autopilot is in our control mode and we may steer: guidance runs (healthy
        or in the failsafe's position hold); else (a pilot's mode) a frame feeds only
        the map and the report (issue 34)."""
        return self.modes.steering and self.setpoints.policy is not None and self._may_steer(now_s)

    def _steering(self, now_s: float) -> bool:
        """Our setpoints are flown now: in control, with healthy inputs."""
        return self._in_control(now_s) and self.failsafe.status.health.ok

    # ---- setpoints: which target when (the setpoint job carries it out) ------------
    def _send_target(self, target: PositionTarget, now_s: float, frame_ns: int | None) -> None:
        """``target`` stamped with the frame's time on the autopilot clock (else the
        newest autopilot time)."""
        ap_ns = None if frame_ns is None else self.clock.frame_to_autopilot_ns(frame_ns)
        last_boot_ms = self.telemetry.last_boot_ms
        if ap_ns is None:
            ap_ns = (last_boot_ms or 0) * 1_000_000
        self.setpoints.send(target, now_s, ap_ns // 1_000_000, last_boot_ms)

    def _resend_now(self, now_s: float) -> None:
        """Keep-alive / PX4 stream / hold: (re)send the appropriate target."""
        policy, modes, hold = self.setpoints.policy, self.modes, self.failsafe
        if policy is None or not self._may_steer(now_s):
            return
        healthy = hold.status.health.ok
        if modes.streaming_hold or (modes.steering and hold.hold is not Response.STEER):
            target = hold.hold_target or hold.current_hold(self._hold_view())
        elif modes.steering and not healthy and modes.must_stream():
            target = hold.current_hold(self._hold_view())
        elif modes.steering and (healthy or policy.last is None):
            target = policy.last
            if target is None and modes.must_stream():
                target = hold.current_hold(self._hold_view())
        else:
            return
        if target is not None:
            self._send_target(target, now_s, None)

    def _state_speed_limit(self, envelope, now_s: float) -> None:
        """ArduPilot: the envelope's speed limit below the autopilot's WPNAV_SPEED, asked
        for first (:class:`~companion.core.param_job.ParamJob`): never state a speed before
        the pilot's own limit is known, the carrot bounds the speed meanwhile; other
        autopilots: the carrot alone."""
        flavour = self.modes.flavour
        if flavour is None or not profile_for(flavour).states_speed_limit:
            return
        wpnav_speed_mps = self.params.wpnav_speed_mps
        if wpnav_speed_mps is None:
            self.params.request_if_due(now_s)
        else:
            self.setpoints.state_speed_limit(envelope, wpnav_speed_mps, now_s)

    def _may_steer(self, now_s: float) -> bool:
        """Alone on the link, and it was heard long enough to know (wall seconds)."""
        return not self.modes.takeover_blocked and now_s >= self.link.listen_until_s

    # ---- messages: each to the job that reads it -----------------------------------
    def _receive(self, msg, now_s: float) -> None:
        try:
            self._on_message(msg, now_s)
        except Exception as exc:  # one handler's bug must not stop the companion
            self.link.handler_error(msg, exc)

    def _on_message(self, msg, now_s: float) -> None:
        """Our twin's heartbeat, another source's setpoints, the autopilot's messages."""
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
        if mtype in SETPOINT_MESSAGES and getattr(msg, "target_system", 0) == cfg.target_system:
            self.modes.on_foreign_setpoint(now_s, src)
            return
        if msg.get_srcSystem() != cfg.target_system:
            return
        from_autopilot = msg.get_srcComponent() == cfg.target_component
        if mtype == "HEARTBEAT":
            if from_autopilot and is_autopilot_heartbeat(msg.autopilot, msg.type):
                self._link_alive(now_s)
                self._on_heartbeat(msg, now_s)
            return
        if from_autopilot:
            self._link_alive(now_s)
            self._on_autopilot_message(msg, mtype, now_s)

    def _on_autopilot_message(self, msg, mtype: str, now_s: float) -> None:
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

    def _link_alive(self, now_s: float) -> None:
        if self.link.alive(now_s):  # the link came up: streams and TIMESYNC at once
            self.streams.link_up(now_s)

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

    def _on_heartbeat(self, msg, now_s: float) -> None:
        """The autopilot's heartbeat: found (setpoint policy, takeoff), then the takeoff's
        while it runs, else the mode watch's."""
        flavour = detect_flavour(msg.autopilot)
        if self.setpoints.policy is None:  # first heartbeat since the (re)start
            self.setpoints.found(flavour)
            self.out.event("autopilot", flavour=flavour.value, mode=msg.custom_mode)
            _log.info(
                "autopilot found: %s (system %d), control mode %s",
                flavour.value,
                msg.get_srcSystem(),
                control_mode(flavour).name,
            )
            if self.config.link.takeoff_alt_m > 0:
                self.takeoff_job.start(flavour, now_s)
        if self.takeoff_job.busy:
            armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            engage = self.takeoff_job.on_heartbeat(flavour, msg.custom_mode, armed, now_s)
            self._engage(engage, now_s)
            return
        self._after_phase_change(self.modes.on_heartbeat(flavour, msg.custom_mode, now_s), now_s)

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

    # ---- frames ----------------------------------------------------------------------
    def _on_frame(self, frame: StereoFrame, recv_ns: int) -> None:
        """A frame: admitted with its pose, the mission stepped, its setpoint (when the
        companion steers), speed limit, reports, OBSTACLE_DISTANCE and status."""
        lookup = self._admit(frame)
        if lookup is None:
            return
        assert lookup.pose is not None
        pose = dataclasses.replace(lookup.pose, h_acc_m=self.telemetry.stated_h_acc_m(self._now_s))
        # Whether the vehicle flies what this frame yields (not in our failsafe hold, a
        # pilot's mode or beside another source): time it does not, guidance does not
        # count as its own lack of progress.
        now_frame = self.telemetry.now_frame_ns(self._now_ns)
        age_s = None if now_frame is None else (now_frame - frame.capture_ns) * 1e-9
        result = self.frames.step(
            frame, pose, self._steering(self._now_s), age_s, self._in_control(self._now_s)
        )
        if result is None:
            return
        out = result.output
        self.frames.processed(frame.capture_ns, result, age_s, self._now_ns)
        self._recheck_hold_target(pose.pos_ned_m)
        self._check_failsafe(self._now_s)
        sent = False
        target = PositionTarget(tuple(float(x) for x in out.setpoint_ned_m), float(out.yaw_rad))
        if out.guided and self._steering(self._now_s):  # never a frame guidance skipped
            policy = self.setpoints.policy
            assert policy is not None
            if policy.on_new_target(target, self._now_s):
                self._send_target(target, self._now_s, frame.capture_ns)
                sent = True
            self._state_speed_limit(out.envelope, self._now_s)
        self.setpoints.check_overspeed(out.envelope, self._now_s)
        self.frames.report(result)
        if self.proximity is not None:
            fallback = pose if self.telemetry.position_host_ns is None else None
            space, pose_now = self.mission.pipeline.known_space, self._proximity_pose()
            with self.phases.timed(Phase.SECTORS):
                self.proximity_job.on_frame(
                    frame.capture_ns, space, pose_now, fallback, self._now_s
                )
        host_capture = frame.capture_ns if self.clock.frame_clock is FrameClock.HOST else None
        with self.phases.timed(Phase.STATUS):
            document = self.status.frame_status(
                result, lookup.status, pose, sent, self._state(), self._now_s
            )
        self.out.append(Status(document, recv_ns, self._now_ns, host_capture))
        if self.report_pipeline:  # a viewer is attached (companion.viz)
            pipeline = self.mission.pipeline
            self.out.append(
                FrameProcessed(frame, pose, result, pipeline.goal_ned_m, pipeline.known_space, sent)
            )

    def _admit(self, frame: StereoFrame) -> PoseLookup | None:
        """The pose lookup at the frame's capture time, or None: the frame is dropped
        (implausible time, during a takeoff, not newer than the last, no usable pose)."""
        if self.telemetry.frame_time_plausible(frame.capture_ns, self._now_ns) is False:
            # frames never move the clock nor reset the mission: only telemetry may
            self.counters.frames_implausible_time += 1
            self.out.dropped(
                "frames_implausible_time",
                self.counters.frames_implausible_time,
                "frame",
                (frame.sequence, frame.capture_ns),
            )
            return None
        if self.takeoff_job.busy:  # not steered on: it proves the camera works
            self.telemetry.observe(frame.capture_ns)
            self.frames.during_takeoff(frame.capture_ns)
            self._engage(self.takeoff_job.on_frame(self._now_s), self._now_s)
            return None
        lookup = self.poses.at(frame.capture_ns)
        if not self.frames.admit(frame, lookup):
            return None
        self.telemetry.observe(frame.capture_ns)
        return lookup

    def _proximity_pose(self):
        """Where the vehicle is at an OBSTACLE_DISTANCE send: the newest pose carried
        forward over the host time since its position came, on the frame clock."""
        newest, host_ns = self.poses.newest_ns, self.telemetry.position_host_ns
        if newest is None or host_ns is None:
            return None, None
        pose = self.poses.at(newest).pose
        age_s = (self._now_ns - host_ns) * 1e-9 * self.telemetry.frame_clock_rate()
        return self.proximity_job.pose_at_send(pose, None if pose is None else age_s)
