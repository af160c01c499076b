"""The core's components on their own (companion/core/*_job.py that own their state):
typed inputs in, their messages in the Outbox, typed decisions out."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.clock_model import FrameClock, SyncSample
from companion.config import CompanionConfig, FailsafeConfig, LinkConfig
from companion.core.counters import CoreCounters
from companion.core.events import Event, SendMavlink, SendSetpoint
from companion.core.failsafe_job import FailsafeJob, HoldView
from companion.core.frame_job import FrameJob
from companion.core.link_job import LISTEN_BEFORE_STEERING_S, LinkJob
from companion.core.modes_job import ModesJob, PhaseChange
from companion.core.outbox import Outbox
from companion.core.param_job import WPNAV_SPEED, ParamJob
from companion.core.proximity_job import ProximityJob
from companion.core.setpoint_job import SetpointJob
from companion.core.status_job import StateView, StatusJob, companion_state
from companion.core.streams_job import STREAMS, StreamsJob
from companion.core.takeoff_job import TakeoffJob
from companion.core.telemetry_job import H_ACC_MAX_AGE_S, Restarted, TelemetryJob
from companion.failsafe import Response
from companion.link.flavour import Flavour
from companion.link.messages import CompanionState
from companion.link.mode_watch import ControlPhase
from companion.link.setpoints import PositionTarget
from companion.pipeline import PoseAtCapture
from companion.pose_history import PoseLookup, PoseStatus
from companion.proximity.sender import POSE_STALE_S, ProximitySender


def _sent(out: Outbox) -> list:
    return [o.message for o in out.take() if isinstance(o, SendMavlink)]


def _outbox() -> Outbox:
    out = Outbox(CoreCounters())
    out.begin(0.0)
    return out


def _param_value(name: str, value: float):
    return mavlink.MAVLink_param_value_message(
        name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32, 1, 0
    )


def test_wpnav_speed_is_asked_for_every_2_s_at_most_5_times():
    out = _outbox()
    params = ParamJob(LinkConfig(), out)
    asked_at = []
    for tenth in range(0, 200):  # 20 s of steps at 10 Hz
        now_s = tenth / 10.0
        params.request_if_due(now_s)
        if _sent(out):
            asked_at.append(now_s)
    assert asked_at == pytest.approx([0.0, 2.0, 4.0, 6.0, 8.0])
    assert params.wpnav_speed_mps is None


def test_a_reported_wpnav_speed_stops_the_requests_and_other_values_are_ignored():
    out = _outbox()
    params = ParamJob(LinkConfig(), out)
    params.request_if_due(0.0)
    assert len(_sent(out)) == 1
    for name, value in (("WPNAV_ACCEL", 250.0), (WPNAV_SPEED, math.nan), (WPNAV_SPEED, -1.0)):
        params.on_param_value(_param_value(name, value))
        assert params.wpnav_speed_mps is None
    params.on_param_value(_param_value(WPNAV_SPEED, 550.0))  # [cm/s]
    assert params.wpnav_speed_mps == pytest.approx(5.5)
    params.request_if_due(10.0)
    assert _sent(out) == []
    params.reset()  # a new connection: asked for again
    assert params.wpnav_speed_mps is None
    params.request_if_due(10.0)
    assert len(_sent(out)) == 1


def test_streams_are_requested_each_second_until_every_one_is_acknowledged():
    out = _outbox()
    link = LinkConfig()
    streams = StreamsJob(link, out, CoreCounters())
    streams.link_up(0.0)
    rounds = []
    for tenth in range(0, 40):
        now_s = tenth / 10.0
        if tenth == 25:  # both acknowledged after the third round
            for _ in STREAMS:
                streams.on_stream_ack(True)
        streams.timers(now_s, round(now_s * 1e9))
        ids = [m.param1 for m in _sent(out) if m.get_type() == "COMMAND_LONG"]
        if ids:
            assert ids == list(STREAMS)
            rounds.append(now_s)
    assert rounds == pytest.approx([0.0, 1.0, 2.0])


def test_timesync_answers_the_autopilot_and_matches_our_requests():
    out = _outbox()
    counters = CoreCounters()
    streams = StreamsJob(LinkConfig(), out, counters)
    streams.link_up(0.0)
    streams.timers(0.0, 1_000)
    (request,) = [m for m in _sent(out) if m.get_type() == "TIMESYNC"]
    assert (request.tc1, request.ts1) == (0, 1_000)
    # the autopilot asks for our time: answered, no sample
    ask = mavlink.MAVLink_timesync_message(0, 77)
    assert streams.on_timesync(ask, 5_000) is None
    (reply,) = _sent(out)
    assert (reply.tc1, reply.ts1) == (5_000, 77)
    # an answer to no request of ours: counted, no sample
    assert streams.on_timesync(mavlink.MAVLink_timesync_message(9, 999), 6_000) is None
    assert counters.timesync_unmatched == 1
    # the answer to ours: its sample, once
    answer = mavlink.MAVLink_timesync_message(42_000, 1_000)
    assert streams.on_timesync(answer, 7_000) == SyncSample(1_000, 42_000, 7_000)
    assert streams.on_timesync(answer, 8_000) is None
    assert counters.timesync_unmatched == 2


def _view(**kw) -> StateView:
    fields = dict(
        link_up=True,
        link_lost_before=False,
        may_steer=True,
        phase=ControlPhase.ACTIVE,
        hold=Response.STEER,
        steering=True,
        health_ok=True,
        frame_processed=True,
    )
    return StateView(**{**fields, **kw})


@pytest.mark.parametrize(
    ("change", "state"),
    [
        ({}, CompanionState.ACTIVE),
        ({"link_up": False}, CompanionState.BOOT),
        ({"link_up": False, "link_lost_before": True}, CompanionState.LINK_LOST),
        ({"may_steer": False, "phase": ControlPhase.HOLD}, CompanionState.STANDBY),
        ({"phase": ControlPhase.HOLD}, CompanionState.HOLD),
        ({"hold": Response.HOLD_POSITION}, CompanionState.HOLD),
        ({"health_ok": False}, CompanionState.STANDBY),
        ({"steering": False, "frame_processed": False}, CompanionState.BOOT),
    ],
)
def test_the_companion_state_follows_link_takeover_hold_and_health_in_that_order(change, state):
    assert companion_state(_view(**change)) is state


def _telemetry(frame_clock: FrameClock = FrameClock.AUTOPILOT):
    counters = CoreCounters()
    link = LinkConfig(frame_clock=frame_clock)
    return TelemetryJob(link, FailsafeConfig(), _outbox(), counters), counters


def _position(boot_ms: int, x: float = 1.0, vx: float = 0.5):
    return mavlink.MAVLink_local_position_ned_message(boot_ms, x, 2.0, -3.0, vx, 0.0, 0.0)


def test_telemetry_goes_into_the_pose_history_on_the_autopilot_frame_clock():
    job, counters = _telemetry()
    assert job.on_local_position(_position(1_000), 0.0, 5) is None
    attitude = mavlink.MAVLink_attitude_message(1_000, 0.1, -0.2, 1.5, 0, 0, 0)
    assert job.on_attitude(attitude, 0.0) is None
    assert (
        job.on_attitude(mavlink.MAVLink_attitude_message(1_010, 0, 0, 1.5, 0, 0, 0), 0.01) is None
    )
    # frames on the autopilot clock: time_boot_ms is the frame clock, exactly
    assert job.poses.newest_ns == 1_000_000_000  # the newest with position and attitude
    assert job.telemetry_newest_ns == job.newest_seen_ns == 1_010_000_000
    assert job.now_frame_ns(123) == 1_010_000_000  # the newest stamp is "now"
    assert (job.position_host_ns, job.last_boot_ms) == (5, 1_010)
    pose = job.poses.at(1_000_000_000).pose
    assert pose.pos_ned_m == pytest.approx((1.0, 2.0, -3.0))
    assert pose.yaw_rad == pytest.approx(1.5)
    job.observe(2_000_000_000)  # a frame's capture time moves "now", not the telemetry's
    assert (job.newest_seen_ns, job.telemetry_newest_ns) == (2_000_000_000, 1_010_000_000)
    assert counters.telemetry_out_of_range == counters.telemetry_implausible_time == 0


def test_out_of_range_telemetry_is_dropped_and_counted():
    job, counters = _telemetry()
    job.on_local_position(_position(1_000, x=math.nan), 0.0, 0)
    job.on_local_position(_position(1_000, vx=301.0), 0.0, 0)  # > 300 m/s
    job.on_attitude(mavlink.MAVLink_attitude_message(1_000, 0.0, 0.0, 7.0, 0, 0, 0), 0.0)
    assert counters.telemetry_out_of_range == 3
    assert job.poses.newest_ns is None and job.last_boot_ms is None


def test_a_time_base_that_goes_back_is_a_restart_once_three_stamps_agree():
    job, counters = _telemetry()
    for i in range(5):  # 50 Hz from 10 s
        assert job.on_local_position(_position(10_000 + 20 * i), 0.02 * i, i) is None
    attitude = mavlink.MAVLink_attitude_message(10_080, 0.0, 0.0, 0.0, 0, 0, 0)
    job.on_attitude(attitude, 0.08)
    assert job.poses.newest_ns == 10_080_000_000
    verdicts = [job.on_local_position(_position(200 + 20 * i), 0.1 + 0.02 * i, 9) for i in range(3)]
    # two dropped (one bad stamp must not reset a mission), the third starts over
    assert verdicts[:2] == [None, None] and counters.telemetry_implausible_time == 2
    assert verdicts[2] == Restarted("time_boot_ms 10080 → 240")
    # the stamp that showed it starts the new time base and is kept; nothing older is
    assert job.last_boot_ms == 240 and job.position_host_ns == 9
    assert job.telemetry_newest_ns == job.newest_seen_ns == 240_000_000
    assert job.poses.newest_ns is None  # the old attitude went with the old time base


def test_the_stated_accuracy_is_used_for_5_s_and_none_means_none():
    job, _ = _telemetry()
    gps = mavlink.MAVLink_gps_raw_int_message(0, 3, 0, 0, 0, 0, 0, 0, 0, 0, h_acc=350)
    job.on_gps_raw(gps, 10.0)
    assert job.stated_h_acc_m(10.0 + H_ACC_MAX_AGE_S) == pytest.approx(0.35)
    assert job.stated_h_acc_m(10.0 + H_ACC_MAX_AGE_S + 1e-6) is None
    for none_stated in (0, 0xFFFFFFFF):
        job.on_gps_raw(mavlink.MAVLink_gps_raw_int_message(*[0] * 10, h_acc=none_stated), 11.0)
        assert job.stated_h_acc_m(11.0) is None


def test_the_frame_clock_rate_is_the_timesync_fit_on_the_autopilot_clock_only():
    job, _ = _telemetry()
    assert job.frame_clock_rate() == 1.0  # no fit yet: the default rate
    host = _telemetry(FrameClock.HOST)[0]
    # autopilot time at 4x host time (plant-sim --speedup 4), round trips of 2 ms
    for i in range(40):
        host_ns = i * 100_000_000
        sample = SyncSample(host_ns, 4 * (host_ns + 1_000_000), host_ns + 2_000_000)
        assert job.on_sync_sample(sample) is None
        host.on_sync_sample(sample)
    assert job.frame_clock_rate() == pytest.approx(4.0, rel=1e-9)
    assert host.frame_clock_rate() == 1.0  # frames on the host clock: host seconds
    # the autopilot's clock went back: a restart, and the fit starts over
    back = SyncSample(4_000_000_000, 1_000, 4_002_000_000)
    assert job.on_sync_sample(back) == Restarted("TIMESYNC went backwards")
    assert job.frame_clock_rate() == 1.0 and job.poses.newest_ns is None


_LOITER, _GUIDED = 5, 4  # ArduCopter custom modes


def _events(out: Outbox) -> list:
    return [o for o in out.take() if isinstance(o, Event)]


def test_the_mode_is_requested_acknowledged_engaged_then_released_by_the_pilot():
    out, counters = _outbox(), CoreCounters()
    modes = ModesJob(LinkConfig(), 7, out, counters)
    assert modes.on_heartbeat(Flavour.ARDUPILOT, _LOITER, 0.0) == PhaseChange(
        ControlPhase.NO_AUTOPILOT, ControlPhase.REQUESTED
    )
    assert [e.fields["phase"] for e in _events(out)] == ["requested"]
    assert modes.tick(0.0) is None  # the request is sent, the phase stays
    (request,) = _sent(out)
    assert (request.command, request.param2) == (mavlink.MAV_CMD_DO_SET_MODE, _GUIDED)
    assert counters.mode_requests == 1
    change = modes.on_mode_ack(True, "MAV_RESULT_ACCEPTED", 0.1)
    assert change == PhaseChange(ControlPhase.REQUESTED, ControlPhase.ACTIVE) and change.engaging
    assert modes.steering and not modes.must_stream()  # ArduPilot: setpoints persist
    assert modes.on_heartbeat(Flavour.ARDUPILOT, _GUIDED, 1.0) is None  # no change: nothing
    out.take()
    released = modes.on_heartbeat(Flavour.ARDUPILOT, _LOITER, 5.0)  # the pilot takes over
    assert released == PhaseChange(ControlPhase.ACTIVE, ControlPhase.RELEASED)
    assert not released.engaging and counters.mode_releases == 1
    out.take()  # the release's notice and event
    assert modes.tick(6.0) is None and _sent(out) == []  # never asked again after a release
    modes.reset()
    assert modes.phase is ControlPhase.NO_AUTOPILOT and modes.flavour is None


def test_a_foreign_setpoint_source_blocks_steering_until_quiet_for_3_s():
    out, counters = _outbox(), CoreCounters()
    modes = ModesJob(LinkConfig(), 7, out, counters)
    modes.on_foreign_setpoint(10.0, (1, 191))
    assert modes.takeover_blocked and counters.takeover_refusals == 1
    assert [(e.name, e.fields["blocked"]) for e in _events(out)] == [("takeover", True)]
    modes.on_foreign_setpoint(11.0, (1, 191))  # still there: said once
    modes.check_takeover(11.0 + modes.takeover.quiet_s - 0.01)
    assert modes.takeover_blocked and counters.takeover_refusals == 1 and _events(out) == []
    modes.check_takeover(11.0 + modes.takeover.quiet_s + 0.01)
    assert not modes.takeover_blocked
    assert [(e.name, e.fields["blocked"]) for e in _events(out)] == [("takeover", False)]


_S = 1_000_000_000  # ns per s


def test_late_frames_hold_at_the_braking_point_lost_frames_escalate_and_healthy_resumes():
    out, counters = _outbox(), CoreCounters()
    config = CompanionConfig()
    job = FailsafeJob(config, out, counters)
    fresh = dict(autopilot_known=True, engaged=True)
    assert job.update(1 * _S, 1 * _S, 1 * _S, **fresh) is None  # healthy, steering
    late = (1 * _S + 1.5 * _S, 1 * _S, int(2.5 * _S))  # frames 1.5 s old > 1.0 s timeout
    assert job.update(*late, autopilot_known=True, engaged=False) is None  # nothing to hold
    assert job.update(*late, autopilot_known=False, engaged=True) is None  # (a takeoff)
    assert job.update(*late, **fresh) is Response.HOLD_POSITION
    pose = PoseAtCapture(np.array([0.0, 0.0, -7.0]), np.array([2.0, 0.0, 0.0]), np.eye(3))
    view = HoldView(pose, (), latency_s=0.2)
    job.start_hold(Response.HOLD_POSITION, view)
    accel = config.envelope.accel_mps2
    brake_m = 0.2 * 2.0 + 2.0**2 / (2.0 * accel)  # τ·v + v²/(2a)
    assert job.hold_target.pos_ned_m == pytest.approx((brake_m, 0.0, -7.0))
    assert (counters.hold_commands, counters.mode_holds) == (1, 0)
    latched = job.hold_target
    lost = (int(3.5 * _S), 1 * _S, int(3.5 * _S))  # frames 2.5 s old > 2.0 s: lost
    assert job.update(*lost, **fresh) is Response.HOLD_MODE
    job.start_hold(Response.HOLD_MODE, HoldView(pose, (), latency_s=0.5))
    assert job.hold_target is latched  # latched at the hold's start
    assert (counters.hold_commands, counters.mode_holds) == (1, 1)
    assert job.update(int(3.6 * _S), int(3.6 * _S), int(3.6 * _S), **fresh) is None  # settling
    assert job.update(int(4.7 * _S), int(4.7 * _S), int(4.7 * _S), **fresh) is Response.STEER
    out.take()
    assert job.end_hold() and job.hold is Response.STEER and job.hold_target is None
    assert [e.name for e in out.take() if isinstance(e, Event)] == ["resume"]
    assert not job.end_hold()  # no hold: nothing said


def test_a_hold_target_inside_a_boundary_moves_out_once_and_is_said_once():
    out, counters = _outbox(), CoreCounters()
    job = FailsafeJob(CompanionConfig(), out, counters)
    pose = PoseAtCapture(np.array([0.0, 0.0, -7.0]), np.zeros(3), np.eye(3))
    job.start_hold(Response.HOLD_POSITION, HoldView(pose, (), latency_s=0.2))
    assert job.hold_target.pos_ned_m == pytest.approx((0.0, 0.0, -7.0))

    class Ball:  # the vehicle 0.4 m inside a boundary to its north
        center_ned_m = np.array([0.6, 0.0, -7.0])
        radius_m = 1.0

    inside = HoldView(pose, (Ball(),), latency_s=0.2)
    moved = job.recheck_target(pose.pos_ned_m, inside)
    assert moved is job.hold_target and moved.pos_ned_m[0] < 0.6 - 1.0  # out, to the south
    assert job.recheck_target(pose.pos_ned_m, inside) is None  # the same target: not resent
    assert counters.hold_targets_moved == 1
    told = [e for e in out.take() if isinstance(e, Event) and e.name == "hold_target_moved"]
    assert len(told) == 1


def test_setpoints_are_stamped_kept_alive_per_flavour_and_steering_is_said_once():
    for flavour, period_s in ((Flavour.ARDUPILOT, 0.5), (Flavour.PX4, 1.0 / 20.0)):
        out, counters = _outbox(), CoreCounters()
        job = SetpointJob(LinkConfig(), out, counters)
        assert not job.due(0.0, must_stream=True)  # no autopilot: no policy
        job.found(flavour)
        target = PositionTarget((1.0, 2.0, -7.0), 0.5)
        job.send(target, 10.0, time_boot_ms=1_234, last_boot_ms=1_240)
        job.send(target, 10.1, time_boot_ms=1_334, last_boot_ms=1_340)
        items = out.take()
        sent = [o for o in items if isinstance(o, SendSetpoint)]
        assert [o.message.time_boot_ms for o in sent] == [1_234, 1_334]
        assert all(o.target == target for o in sent) and counters.setpoints_sent == 2
        (steering,) = [o.fields for o in items if isinstance(o, Event)]
        assert steering["autopilot_time_s"] == pytest.approx(1.240)  # the first only
        assert not job.due(10.1 + period_s * 0.99, must_stream=False)
        assert job.due(10.1 + period_s * 1.01, must_stream=False)
        job.reset()
        assert job.policy is None and not job.engaged


class _Envelope:
    speed_limit_mps = 7.3
    speed_mps = 2.0
    path_dir_ned = np.array([1.0, 0.0, 0.0])  # level: no climb or descent statement
    overspeed = True


def test_the_stated_speed_is_the_envelopes_below_wpnav_speed_rounded_down():
    out, counters = _outbox(), CoreCounters()
    job = SetpointJob(LinkConfig(), out, counters)
    job.state_speed_limit(_Envelope(), 5.1, 0.0)  # the pilot's own limit is lower
    speeds = [(m.param1, m.param2) for m in _sent(out)]
    assert speeds[0] == (1.0, pytest.approx(5.0))  # ground speed, 5.1 → 5.0 (0.25 steps)
    job.state_speed_limit(_Envelope(), 9.0, 0.25)  # a raise is paced (0.5 s)
    assert [m.param1 for m in _sent(out)] == []
    job.state_speed_limit(_Envelope(), 9.0, 0.5 + job.speed_policy.raise_period_s)
    assert [(m.param1, m.param2) for m in _sent(out)] == [(1.0, 7.25)]  # 7.3 → 7.25
    job.found(Flavour.ARDUPILOT)
    job.engaging()  # into GUIDED: ArduCopter forgot it; said again at once
    job.state_speed_limit(_Envelope(), 9.0, 0.6 + job.speed_policy.raise_period_s)
    assert [(m.param1, m.param2) for m in _sent(out)] == [(1.0, 7.25)]
    job.on_speed_ack(True, 0)
    job.on_speed_ack(False, 4)
    job.on_speed_ack(False, 4)
    assert (counters.speed_limits_accepted, counters.speed_limits_refused) == (1, 2)


def test_overspeed_is_counted_every_frame_and_said_every_5_s():
    out, counters = _outbox(), CoreCounters()
    job = SetpointJob(LinkConfig(), out, counters)
    for tenth in range(0, 120):  # 12 s of frames at 10 Hz, all over the limit
        job.check_overspeed(_Envelope(), tenth / 10.0)
    said = [m for m in _sent(out) if m.get_type() == "STATUSTEXT"]
    assert counters.overspeed_frames == 120 and len(said) == 3  # at 0, 5 and 10 s
    assert said[0].text.startswith("Speed 2.0 m/s above limit 7.3 m/s")


def test_the_link_comes_up_listens_first_and_is_lost_after_the_timeout():
    out, counters = _outbox(), CoreCounters()
    failsafe = FailsafeConfig()
    link = LinkJob(LinkConfig(), failsafe, 0xABCD, out, counters)
    assert not link.up and link.listen_until_s == math.inf  # never steer before a link
    assert link.alive(10.0) and not link.alive(10.2)  # up once
    assert link.listen_until_s == pytest.approx(10.0 + LISTEN_BEFORE_STEERING_S)
    assert [e.name for e in _events(out)] == ["link_up"]
    silent_until = 10.2 + failsafe.link_timeout_s
    assert not link.check_lost(silent_until)  # exactly the timeout: still up
    assert link.check_lost(silent_until + 0.01) and not link.up
    assert not link.check_lost(silent_until + 1.0)  # lost once
    assert counters.link_losses == 1
    (lost,) = _events(out)
    assert lost.fields["silent_s"] == pytest.approx(failsafe.link_timeout_s + 0.01)


def test_our_heartbeat_goes_once_per_period_with_the_state_and_our_id():
    out = _outbox()
    link = LinkJob(LinkConfig(), FailsafeConfig(), 0xABCD, out, CoreCounters())
    period_s = LinkConfig().heartbeat_period_s
    sent_at = []
    for tenth in range(0, 35):
        now_s = tenth / 10.0
        if link.heartbeat_due(now_s):
            link.send_heartbeat(CompanionState.STANDBY, now_s)
            (hb,) = _sent(out)
            assert hb.custom_mode == 0xABCD
            sent_at.append(now_s)
    assert sent_at == pytest.approx([0.0, period_s, 2 * period_s, 3 * period_s])


def test_silence_is_reported_after_3_s_then_every_5_s_and_handler_errors_once_per_kind(
    caplog,
):
    out, counters = _outbox(), CoreCounters()
    link = LinkJob(LinkConfig(), FailsafeConfig(), 1, out, counters)
    for tenth in range(0, 150):  # 15 s without the autopilot
        link.report_silence(tenth / 10.0)
    said = [e.fields["silent_s"] for e in _events(out) if e.name == "no_autopilot"]
    assert said == pytest.approx([3.0, 8.0, 13.0])
    msg = mavlink.MAVLink_attitude_message(0, 0.0, 0.0, 0.0, 0, 0, 0)
    caplog.clear()
    for _ in range(3):
        link.handler_error(msg, ValueError("bad"))
    link.handler_error(msg, KeyError("other"))
    assert counters.handler_errors == 4
    logged = [r.getMessage() for r in caplog.records if "message dropped" in r.getMessage()]
    assert len(logged) == 2  # ATTITUDE:ValueError, ATTITUDE:KeyError


class _Frame:
    def __init__(self, sequence: int, capture_ns: int) -> None:
        self.sequence, self.capture_ns = sequence, capture_ns


def test_frames_are_admitted_newer_and_with_a_pose_only_each_drop_counted():
    out, counters = _outbox(), CoreCounters()
    frames = FrameJob(CompanionConfig(), out, counters)
    pose = PoseAtCapture(np.zeros(3), np.zeros(3), np.eye(3))
    ok = PoseLookup(PoseStatus.OK, pose)
    assert frames.admit(_Frame(0, 100), PoseLookup(PoseStatus.EMPTY)) is False
    assert frames.admit(_Frame(1, 200), PoseLookup(PoseStatus.TOO_NEW)) is False
    assert frames.admit(_Frame(2, 300), PoseLookup(PoseStatus.EXTRAPOLATED, pose))
    assert frames.admit(_Frame(3, 300), ok) is False  # not newer than the last admitted
    assert frames.admit(_Frame(4, 250), ok) is False
    assert frames.admit(_Frame(5, 400), ok) and frames.last_capture_ns == 400
    assert (counters.pose_empty, counters.pose_too_new, counters.pose_extrapolated) == (1, 1, 1)
    assert counters.frames_stale == 2
    frames.during_takeoff(350)  # proves the camera works (health), not admitted
    assert frames.newest_frame_ns == 350 and frames.last_capture_ns == 400
    assert counters.frames_during_takeoff == 1


def test_a_commands_data_age_is_its_age_at_the_step_plus_the_compute_time_on_the_frame_clock():
    out, counters = _outbox(), CoreCounters()
    frames = FrameJob(CompanionConfig(), out, counters)

    class _Envelope:
        speed_limit_mps = 3.25

    class _Output:
        envelope = _Envelope()
        boundaries = ("b",)
        guided = True  # guidance ran (a reporting-only frame states no speed limit)

    class _Result:
        output = _Output()

    frames.processed(5 * _S, _Result(), 0.12, now_ns=100 * _S)
    assert (frames.newest_frame_ns, frames.speed_limit_mps, frames.boundaries) == (
        5 * _S,
        3.25,
        ("b",),
    )
    assert counters.frames_processed == 1
    frames.measure_data_age(100 * _S + 30_000_000, frame_clock_rate=4.0)  # 30 ms host at 4x
    frames.measure_data_age(101 * _S, frame_clock_rate=4.0)  # taken once
    stats = frames.data_age.stats()
    assert stats.samples == 1 and stats.p50_s == pytest.approx(0.12 + 0.030 * 4.0)


def _status(config: CompanionConfig):
    out, counters = _outbox(), CoreCounters()
    frames = FrameJob(config, out, counters)
    status = StatusJob(
        counters,
        TelemetryJob(config.link, config.failsafe, out, counters),
        ModesJob(config.link, 1, out, counters),
        FailsafeJob(config, out, counters),
        frames,
        SetpointJob(config.link, out, counters),
        TakeoffJob(config.link, out),
        None,
    )
    return status, frames, counters


def test_status_reads_the_components_state_and_figures_before_and_after_a_frame():
    config = CompanionConfig()
    status, frames, counters = _status(config)
    assert status.state(link_up=False, may_steer=False) is CompanionState.BOOT
    counters.link_losses = 1
    assert status.state(link_up=False, may_steer=False) is CompanionState.LINK_LOST
    assert status.state(link_up=True, may_steer=False) is CompanionState.STANDBY
    figures = status.pipeline_figures()
    assert figures["latency_budget_s"] == pytest.approx(config.envelope.latency_s)
    assert figures["rate_hz"] is figures["speed_limit_mps"] is figures["data_age_p50_ms"] is None
    for i in range(11):  # ten commands at 10 Hz, data age 0.2 s each
        frames.data_age.add(i * _S // 10, 0.2)
    frames.speed_limit_mps = 2.5
    figures = status.pipeline_figures()
    assert figures["rate_hz"] == pytest.approx(10.0)
    assert figures["data_age_p50_ms"] == pytest.approx(200.0)
    assert figures["speed_limit_mps"] == 2.5
    stats = status.stats()
    assert stats["link_losses"] == 1 and stats["flavour"] is None and stats["takeoff"] is None
    assert "OBSTACLE_DISTANCE off" in status.progress_text(0.0)


def test_obstacle_distance_is_seen_from_the_position_carried_forward_or_not_at_all():
    out = _outbox()
    job = ProximityJob(ProximitySender(CompanionConfig().proximity), out)
    pose = PoseAtCapture(np.array([1.0, 2.0, -7.0]), np.array([2.0, -1.0, 0.0]), np.eye(3))
    pos, yaw = job.pose_at_send(pose, 0.25)
    assert pos == pytest.approx([1.5, 1.75, -7.0]) and yaw == pytest.approx(0.0)  # p + v·t
    assert job.pose_at_send(pose, POSE_STALE_S + 0.01) == (None, None)  # stale: counted
    assert job.pose_at_send(None, None) == (None, None)  # no telemetry: not counted
    assert job.sender.stale_pose == 1
    assert job.due(0.0)
    job.on_timer(None, (None, None), stamp_ns=5_000_123_456, now_s=0.0)
    (msg,) = _sent(out)
    assert msg.get_type() == "OBSTACLE_DISTANCE" and msg.time_usec == 5_000_123
    assert not job.due(0.01)  # just sent
    off = ProximityJob(None, out)
    assert not off.due(100.0)
    off.on_frame(1, None, (None, None), pose, 100.0)  # turned off: nothing
    assert _sent(out) == []
